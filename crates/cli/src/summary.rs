//! What `trimctl run` (and `register`, `plan`) print for people: the registration quality with
//! the worst contours, the zone table (the paper's Table 1), the time estimate, the execution
//! result, and the run report.

use std::fmt::Write as _;

use trim_cell::Job;
use trim_cell::job::LayerKey;
use trim_io::executor::{ExecError, RunSummary};
use trim_io::journal::CutLayer;
use trim_plan::planner::PlanOutput;
use trim_register::regional::{ContourQuality, EdgeFrom, QualityReport};

use crate::config::JobConfig;

/// How many of the worst contours the registration summary lists.
pub const WORST_CONTOURS: usize = 5;

/// Registration quality: global figures and the worst contours by predicted error bound.
#[must_use]
pub fn registration(report: &QualityReport) -> String {
    let mut s = String::new();
    let g = &report.global;
    let _ = writeln!(
        s,
        "registration: scale {:.5}, coarse rmse {:.1} µm, field rmse {}, overlap {:.0} %, {} of {} contours untrustworthy",
        g.scale,
        g.coarse_rmse_mm * 1e3,
        g.field_rmse_mm
            .map_or("-".to_string(), |r| format!("{:.1} µm", r * 1e3)),
        g.overlap * 100.0,
        g.untrustworthy,
        report.contours.len()
    );
    if let Some(r) = &g.slide_retry {
        let outcome = if r.taken {
            format!(
                "a coarse start {:+.1} mm along the part's long axis fits better (coarse rmse {:.1} → {:.1} µm) and is not refused: taken",
                r.shift_mm,
                r.first_coarse_rmse_mm * 1e3,
                g.coarse_rmse_mm * 1e3
            )
        } else if r.shift_mm == 0.0 {
            "no start slid along the part's long axis fits better: the refusal stands".to_string()
        } else {
            format!(
                "the start {:+.1} mm along the part's long axis fits better but is refused too: the first registration stands",
                r.shift_mm
            )
        };
        let _ = writeln!(
            s,
            "  the first registration was refused and retried: {outcome}"
        );
    }
    if let Some(reason) = &g.in_doubt {
        let _ = writeln!(s, "  part in doubt: {reason}");
    }
    if let Some(reason) = &g.edges_in_doubt {
        let _ = writeln!(s, "  edges in doubt: {reason}");
    }
    if let Some(reason) = &g.region_in_doubt {
        let _ = writeln!(s, "  a stretch of the part in doubt: {reason}");
    }
    if let Some(e) = &g.edge_terms {
        let _ = writeln!(
            s,
            "  scanned edges in the field: {} stretches used, {} implausible, {} with material beyond ({} of them widening the bounds); moved the path up to {:.1} µm",
            e.used,
            e.gated,
            e.flashed,
            e.widened,
            e.largest_shift_mm * 1e3
        );
    }
    if let Some(line) = p95_risk_line(report) {
        let _ = writeln!(s, "{line}");
    }
    let mut worst: Vec<_> = report.contours.iter().collect();
    // Untrustworthy first, then by predicted bound.
    worst.sort_by(|a, b| {
        a.trustworthy.cmp(&b.trustworthy).then(
            b.predicted_max_error_um
                .total_cmp(&a.predicted_max_error_um),
        )
    });
    let _ = writeln!(
        s,
        "  worst contours:  id  bound µm  residual µm  coverage %  P95 risk %  flags"
    );
    for c in worst.iter().take(WORST_CONTOURS) {
        let _ = writeln!(s, "{}", contour_row(c));
    }
    s
}

/// How many trusted contours are expected beyond the cross-edge P95 limit, and the three most at
/// risk (`None` without a posterior, in global mode).
fn p95_risk_line(report: &QualityReport) -> Option<String> {
    let g = &report.global;
    let expected = g.expected_over_p95?;
    let mut trusted: Vec<(&ContourQuality, f64)> = report
        .contours
        .iter()
        .filter(|c| c.trustworthy)
        .filter_map(|c| c.p95_risk.map(|r| (c, r)))
        .collect();
    trusted.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.id.cmp(&b.0.id)));
    let most: Vec<String> = trusted
        .iter()
        .take(3)
        .filter(|(_, r)| *r >= 0.005)
        .map(|(c, r)| {
            // A strip read across itself by its face's end alone: a view that sees the wall
            // below it would read it better.
            let face_only =
                !c.scan_edges.is_empty() && c.scan_edges.iter().all(|e| e.from == EdgeFrom::Face);
            format!(
                "{} {:.0} %{}",
                c.id,
                r * 1e2,
                if face_only { " (wall unseen)" } else { "" }
            )
        })
        .collect();
    Some(format!(
        "  cross-edge P95 limit {:.0} µm: {:.2} of the {} trusted contours expected beyond it{} (quality.max_p95_risk flags a contour over the chance you set)",
        g.p95_limit_um,
        expected,
        trusted.len(),
        if most.is_empty() {
            String::new()
        } else {
            format!(", most at risk: {}", most.join(", "))
        }
    ))
}

/// A contour's `p95_risk` in per cent, `-` without one.
fn risk_percent(c: &ContourQuality) -> String {
    c.p95_risk
        .map_or("-".to_owned(), |r| format!("{:.1}", r * 1e2))
}

/// One contour's row of the registration summary (see [`registration`]).
fn contour_row(c: &ContourQuality) -> String {
    let flags: Vec<String> = c.flags.iter().map(|f| format!("{f:?}")).collect();
    format!(
        "  {:>17}  {:>8.1}  {:>11}  {:>10.0}  {:>10}  {}",
        c.id,
        c.predicted_max_error_um,
        c.residual_rms_mm
            .map_or("-".to_owned(), |r| format!("{:.1}", r * 1e3)),
        c.coverage * 100.0,
        risk_percent(c),
        if flags.is_empty() {
            "-".into()
        } else {
            flags.join(",")
        }
    )
}

/// Every contour's quality as a markdown table, in path order (the run report).
#[must_use]
pub fn contour_table(report: &QualityReport) -> String {
    let mut s = String::from(
        "| contour | predicted max error µm | residual µm | coverage % | field σ µm | P95 risk % | support distance mm | flags | trusted |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for c in &report.contours {
        let flags: Vec<String> = c.flags.iter().map(|f| format!("{f:?}")).collect();
        let _ = writeln!(
            s,
            "| {} | {:.1} | {} | {:.0} | {:.1} | {} | {:.2} | {} | {} |",
            c.id,
            c.predicted_max_error_um,
            c.residual_rms_mm
                .map_or("-".to_owned(), |r| format!("{:.1}", r * 1e3)),
            c.coverage * 100.0,
            c.field_sigma_mm * 1e3,
            risk_percent(c),
            c.support_distance_mm,
            if flags.is_empty() {
                "-".into()
            } else {
                flags.join(", ")
            },
            if c.trustworthy { "yes" } else { "**no**" }
        );
    }
    s
}

/// How the zones came about: the covering's poses against its lower bound, or k-means' k.
#[must_use]
pub fn zoning(plan: &PlanOutput) -> String {
    match &plan.cover {
        Some(c) => format!(
            "pose covering: {} poses, lower bound {}; {} pieces, {} candidates, greedy {} → {} after {} merges, {} dropped, {} absorbed{}",
            c.poses,
            c.lower_bound,
            c.atoms,
            c.candidates,
            c.greedy_poses,
            c.poses,
            c.merges,
            c.dropped,
            c.absorbed,
            if c.uncovered_atoms > 0 {
                format!("; {} pieces out of reach", c.uncovered_atoms)
            } else {
                String::new()
            }
        ),
        None => format!(
            "k-means k = {}{}, {} merges, {} greedy splits",
            plan.k,
            if plan.automatic_k { ", automatic" } else { "" },
            plan.merges,
            plan.greedy_splits
        ),
    }
}

/// The zone table (paper Table 1 plus layers and lens incidence) and the time estimate.
#[must_use]
pub fn plan(plan: &PlanOutput) -> String {
    let job = &plan.job;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "plan: {} zones ({}), {} layers, ΔH = {:.3} mm, focus ±{:.3} mm",
        job.zones.len(),
        zoning(plan),
        job.zones.iter().map(|z| z.layers.len()).sum::<usize>(),
        job.layer_step_mm,
        job.focus_half_length_mm
    );
    s.push_str(&zone_table(plan));
    let e = &job.estimate;
    let _ = writeln!(
        s,
        "time estimate: {:.1} s (marking {:.1} s, jumps {:.1} s, machine moves {:.1} s, settle {:.1} s; laser on {:.1} %)",
        e.total_s,
        e.marking_s,
        e.jumping_s,
        e.motion_s - e.settle_s,
        e.settle_s,
        e.laser_on_fraction * 1e2
    );
    let v = &job.validation;
    let _ = writeln!(
        s,
        "validation: {} (focus deviation ≤ {:.3} mm, incidence ≤ {:.2}°, field |xy| ≤ {:.1} mm, round trip ≤ {:.2e} mm, commands land ≤ {:.2e} mm{})",
        if v.passed { "passed" } else { "FAILED" },
        v.max_focus_deviation_mm,
        v.max_incidence_deg,
        v.max_field_abs_mm,
        v.max_round_trip_error_mm,
        v.max_command_error_mm,
        if v.violations.is_empty() {
            String::new()
        } else {
            format!(", {} violations", v.violations.len())
        }
    );
    s.push_str(&kerf(job));
    s
}

/// The kerf compensation line: how far the lines stand out of the material, and every contour
/// left on its edge with why (its material side unknown).
#[must_use]
pub fn kerf(job: &trim_cell::Job) -> String {
    let Some(k) = &job.kerf else {
        return "kerf compensation: off (trim.kerf_compensation = false): every line on its edge\n"
            .to_owned();
    };
    let mut s = format!(
        "kerf compensation: {} contours offset {:.1} µm out of the material",
        k.compensated.len(),
        k.offset_mm * 1e3
    );
    if k.uncompensated.is_empty() {
        s.push('\n');
    } else {
        let _ = writeln!(
            s,
            "; {} left on the edge (material side unknown):",
            k.uncompensated.len()
        );
        for u in &k.uncompensated {
            let _ = writeln!(s, "  contour {}: {}", u.contour, u.reason);
        }
    }
    s
}

/// The zone table: the paper's Table 1 columns (zone, centre and axis (x, y, z, u, v, w),
/// largest included angle) plus the k-means cluster it is a section of, the largest incidence
/// without and with the lens ray angle, the layer count and the contour ids.
#[must_use]
pub fn zone_table(plan: &PlanOutput) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "  zone  cluster  centre (x, y, z, u, v, w)                                  pairwise°  incidence°  +lens°  layers  contours"
    );
    for r in &plan.table {
        let c = r.centre;
        let _ = writeln!(
            s,
            "  {:>4}  {:>7}  ({:>8.3}, {:>8.3}, {:>8.3}, {:>6.3}, {:>6.3}, {:>6.3})  {:>9.3}  {:>10.3}  {:>6.3}  {:>6}  {}",
            r.zone,
            r.cluster,
            c[0],
            c[1],
            c[2],
            c[3],
            c[4],
            c[5],
            r.max_pairwise_deg,
            r.max_incidence_deg,
            r.max_incidence_with_lens_deg,
            r.layers,
            trim_plan::hatch::track_ids::describe_contours(&r.contours)
        );
    }
    let unreachable = &plan.job.validation.unreachable_zones;
    if !unreachable.is_empty() {
        let _ = writeln!(
            s,
            "  UNREACHABLE within the axis limits: zones {unreachable:?} (drawn red in the SVG)"
        );
    }
    s
}

/// The execution result against the estimate, then the cut layer resume redid or skipped and
/// the layers left out.
#[must_use]
pub fn execution(run: &RunSummary, job: &Job) -> String {
    let mut s = execution_line(run, job);
    if let Some(c) = &run.cut_layer {
        let _ = match c.choice {
            CutLayer::Redo => writeln!(
                s,
                "cut layer {}: progress unknown; redone from vector {} of {}: up to {} vectors may be marked twice",
                c.key, c.first_vector, c.vectors, c.vectors_maybe_twice
            ),
            CutLayer::Skip => writeln!(
                s,
                "cut layer {}: progress unknown; skipped (left out, not marked again)",
                c.key
            ),
        };
    }
    if let Some(line) = left_out_line(&run.layers_left_out) {
        let _ = writeln!(s, "{line}");
    }
    s
}

/// The line naming the layers left out by `--cut-layer skip`; `None` when there are none.
#[must_use]
pub fn left_out_line<'a>(keys: impl IntoIterator<Item = &'a LayerKey>) -> Option<String> {
    let keys: Vec<String> = keys.into_iter().map(ToString::to_string).collect();
    (!keys.is_empty()).then(|| {
        format!(
            "layers left out (--cut-layer skip), not marked: {}",
            keys.join(", ")
        )
    })
}

/// A resume's section of the run report.
#[must_use]
pub fn resume_markdown(
    n: usize,
    job: &Job,
    outcome: &Result<RunSummary, ExecError>,
    wall_s: f64,
) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "\n## Resume {n}\n");
    match outcome {
        Ok(run) => {
            let _ = writeln!(s, "- outcome: finished in {wall_s:.1} s\n");
            let _ = writeln!(s, "```\n{}```", execution(run, job));
        }
        Err(e) => {
            let _ = writeln!(s, "- outcome: stopped: {e}");
        }
    }
    s
}

fn execution_line(run: &RunSummary, job: &Job) -> String {
    let overhead: Vec<f64> = run.layers.iter().map(|l| l.overhead_s).collect();
    let mean_overhead = if overhead.is_empty() {
        0.0
    } else {
        overhead.iter().sum::<f64>() / overhead.len() as f64
    };
    format!(
        "executed: {} layers marked, {} skipped (finished before), {} vectors; wall {:.1} s; galvo time {:.2} s simulated vs {:.2} s estimated; executor overhead {:.1} ms per layer (mean); job estimate {:.1} s\n",
        run.layers_marked,
        run.layers_skipped,
        run.vectors_marked,
        run.wall_s,
        run.galvo_modelled_s,
        run.galvo_estimate_s,
        mean_overhead * 1e3,
        job.estimate.total_s
    ) + &cycle_line(run)
}

/// The measured cycle split of a run (wall clock, s): the CNC's moves and settling (move
/// command to in position; the next list loads meanwhile), the galvo's lists (`EXECUTE` to done
/// seen) and the executor's overhead (the rest of each layer: emission on/off, journal).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct CycleSplit {
    /// Moves and settling.
    pub moves_settle_s: f64,
    /// Galvo lists (marking and jumps).
    pub lists_s: f64,
    /// Executor overhead.
    pub overhead_s: f64,
    /// Overhead per layer (ms).
    pub overhead_per_layer_ms: f64,
    /// Of it, in position → `EXECUTE` acknowledged, per layer (ms).
    pub to_execute_per_layer_ms: f64,
    /// Of it, done seen → journaled, per layer (ms).
    pub after_done_per_layer_ms: f64,
    /// The galvo lists' share of the layers' time (the laser's gate opens only within them).
    pub lists_fraction: f64,
}

/// The measured cycle split of `run`.
#[must_use]
pub fn cycle_split(run: &RunSummary) -> CycleSplit {
    let sum = |f: fn(&trim_io::executor::LayerTiming) -> f64| run.layers.iter().map(f).sum::<f64>();
    let per_layer_ms = |v: f64| {
        if run.layers.is_empty() {
            0.0
        } else {
            v / run.layers.len() as f64 * 1e3
        }
    };
    let (motion, list, overhead) = (
        sum(|l| l.motion_s),
        sum(|l| l.list_s),
        sum(|l| l.overhead_s),
    );
    let busy = motion + list + overhead;
    CycleSplit {
        moves_settle_s: motion,
        lists_s: list,
        overhead_s: overhead,
        overhead_per_layer_ms: per_layer_ms(overhead),
        to_execute_per_layer_ms: per_layer_ms(sum(|l| l.to_execute_s)),
        after_done_per_layer_ms: per_layer_ms(sum(|l| l.after_done_s)),
        lists_fraction: if busy > 0.0 { list / busy } else { 0.0 },
    }
}

fn cycle_line(run: &RunSummary) -> String {
    let c = cycle_split(run);
    format!(
        "cycle (measured): moves + settle {:.2} s, galvo lists {:.2} s, executor overhead {:.3} s ({:.2} ms per layer: in position → executing {:.2} ms, done → journaled {:.2} ms); galvo lists {:.1} % of the layers' time\n",
        c.moves_settle_s,
        c.lists_s,
        c.overhead_s,
        c.overhead_per_layer_ms,
        c.to_execute_per_layer_ms,
        c.after_done_per_layer_ms,
        c.lists_fraction * 1e2,
    )
}

/// The run report (markdown).
#[must_use]
pub fn report_markdown(
    config: &JobConfig,
    description: &str,
    registration_report: &QualityReport,
    plan_out: &PlanOutput,
    run: Option<&RunSummary>,
    stopped: Option<&str>,
    timings: &[(&str, f64)],
) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# trimctl run report\n");
    let _ = writeln!(s, "- part: {description}");
    let _ = writeln!(
        s,
        "- cell: cnc {}, galvo {}, laser {} ({})",
        config.cell.cnc, config.cell.galvo, config.cell.laser, config.cell.laser_profile
    );
    let outcome = match (run, stopped) {
        (Some(_), _) => "finished".to_string(),
        (None, Some(why)) => format!("stopped: {why}"),
        (None, None) => "not executed (dry run)".to_string(),
    };
    let _ = writeln!(s, "- outcome: {outcome}\n");
    let _ = writeln!(s, "## Stage timings\n\n| stage | wall s |\n|---|---|");
    for (name, t) in timings {
        let _ = writeln!(s, "| {name} | {t:.3} |");
    }
    let _ = writeln!(
        s,
        "\n## Registration\n\n```\n{}```",
        registration(registration_report)
    );
    let _ = writeln!(
        s,
        "\n### Contours\n\nThe predicted max error is the registration's own bound on the contour's largest cross-edge error (`predicted_max_error_um` in registration.json); a contour over the tolerance, or with too little coverage or too high a residual, is not trusted.\n\n{}",
        contour_table(registration_report)
    );
    let _ = writeln!(s, "\n## Plan\n\n```\n{}```", plan(plan_out));
    if let Some(r) = run {
        let _ = writeln!(
            s,
            "\n## Execution\n\n```\n{}```",
            execution(r, &plan_out.job)
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A report of four contours: risks 5 % (read from its face alone), 3 % (from its wall),
    /// 20 % (flagged), 0.1 %; `expected` as the report's sum.
    fn report(expected: Option<f64>) -> QualityReport {
        let contour = |id: i64, risk: f64, from: &str, trusted: bool| {
            serde_json::json!({
                "id": id, "points": 100, "scan_points": 100, "coverage": 1.0,
                "residual_rms_mm": 0.01, "degeneracy_ratio": 0.1,
                "weakest_direction": [0.0, 0.0, 1.0], "support_ratio": 0.1,
                "max_field_displacement_mm": 0.1, "field_sigma_mm": 0.006,
                "field_weak_direction": [1.0, 0.0, 0.0], "support_distance_mm": 0.4,
                "end_support_mm": 0.0, "cross_sigma_mm": 0.006, "p95_risk": risk,
                "scan_edges": [{"at_mm": 10.0, "offset_um": -4.0, "sigma_um": 6.6,
                                "points": 170, "from": from}],
                "predicted_max_error_um": 24.8, "part_bound_um": 26.9, "doubt_bound_um": 21.0,
                "flags": if trusted { vec![] } else { vec!["predicted_error"] },
                "trustworthy": trusted,
            })
        };
        let identity = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        serde_json::from_value(serde_json::json!({
            "global": {
                "scan_from_cad": identity, "scale": 1.0, "initial_scan_from_cad": identity,
                "fixture_offset": {"rotation_deg": 0.0, "translation_mm": 0.0},
                "coarse_starts": 1, "capture_score": 1.0, "coarse_rmse_mm": 0.1, "overlap": 1.0,
                "field_rmse_mm": 0.01, "field_points": 1000, "untrustworthy": 1,
                "p95_limit_um": 12.0, "expected_over_p95": expected,
            },
            "contours": [
                contour(1, 0.05, "face", true),
                contour(2, 0.03, "wall", true),
                contour(3, 0.20, "face", false),
                contour(4, 0.001, "wall", true),
            ],
            "timings_s": [],
        }))
        .unwrap()
    }

    #[test]
    fn the_p95_risk_line_names_the_trusted_contours_most_at_risk_and_an_unseen_wall() {
        let line = p95_risk_line(&report(Some(0.081))).unwrap();
        assert!(
            line.starts_with(
                "  cross-edge P95 limit 12 µm: 0.08 of the 3 trusted contours expected beyond it, most at risk: 1 5 % (wall unseen), 2 3 % ("
            ),
            "{line}"
        );
        // The flagged contour is not counted, and a risk under half a per cent is not named.
        assert!(
            !line.contains(" 3 20 %") && !line.contains("4 0 %"),
            "{line}"
        );
        // In global mode (no posterior) there is no line.
        assert_eq!(p95_risk_line(&report(None)), None);
        // The worst contours' table gives each risk in per cent.
        let table = registration(&report(Some(0.081)));
        assert!(table.contains("P95 risk %"), "{table}");
        assert!(table.contains("         5.0  -"), "{table}");
    }
}
