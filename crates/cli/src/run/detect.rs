//! `[trim] only_detected`: detect before trimming (issue 23, §3). The first scan, carried into
//! the CAD frame through the run's own registration, is inspected as `trimctl inspect` does;
//! each contour is then called (see [`call`]) and only the ones that carry excess, or that the
//! scan covers too little to tell, are planned, each polyline with the passes its measured
//! excess height needs at `[process] depth_per_pass_um`.
//!
//! trim-inspect measures how far excess material stands off the nominal solid (the web's
//! height), not how thick the web is: seen from the scanner a web's thickness is hidden by its
//! own top (DESIGN.md "Inspection"). The passes therefore come from the height: a flash web is
//! no thicker than it stands tall, so passes through the height cut through the web. A web
//! thicker than it is tall is under-cut, and only `--verify`'s rescan finds it.
//!
//! The inspection of the first scan is written to `detect/` (inspection.json/csv,
//! deviation.png, report.html); the calls, to report.md and summary.json (`detection`).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use serde::Serialize;
use trim_cell::ProcessSettings;
use trim_cell::process::MAX_PASSES;
use trim_geom::formats::{Geometry, read_geometry};
use trim_geom::mesh::Mesh;
use trim_inspect::{ContourInspection, InspectSettings, Placement, Verdict, inspect};
use trim_register::regional::Registration;

use super::inputs::Inputs;
use super::{Timings, files};
use crate::config::JobConfig;
use crate::progress::stage;

/// What the first scan's inspection says of one contour, for trimming.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub(super) enum Call {
    /// Its excess exceeds the tolerance by more than U: a burr. Trimmed.
    Burr,
    /// The scan covers less of it than `min_coverage` and what was seen does not fail: nothing
    /// shows it clean. Trimmed.
    NotCovered,
    /// Excess was measured, within U of the tolerance: not shown to be within it. Trimmed.
    ExcessUndecided,
    /// Shown within the tolerance, or covered with no excess that could exceed it. Skipped.
    Clean,
    /// Fails on a gouge or a blocked opening, not on excess: trimming its edge removes nothing
    /// there (a film over an opening needs hatching). Skipped, and named on stderr.
    FailsWithoutExcess,
}

impl Call {
    /// Whether the contour is planned.
    pub(super) fn trimmed(self) -> bool {
        matches!(self, Call::Burr | Call::NotCovered | Call::ExcessUndecided)
    }

    fn words(self) -> &'static str {
        match self {
            Call::Burr => "burr: fails on excess",
            Call::NotCovered => "not covered enough to tell: trimmed",
            Call::ExcessUndecided => "excess within U of the tolerance: trimmed",
            Call::Clean => "clean: skipped",
            Call::FailsWithoutExcess => "fails on gouge or opening, not excess: not trimmed",
        }
    }
}

/// Where a trimmed contour's pass count comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub(super) enum PassesFrom {
    /// ⌈excess height / depth per pass⌉.
    Height,
    /// The height needs more than [`MAX_PASSES`]: capped there.
    HeightCapped,
    /// No excess seen (a contour not covered enough): one pass, what trimming every contour
    /// gives it.
    NothingSeen,
}

/// One contour's call.
#[derive(Debug, Clone, Serialize)]
pub(super) struct ContourCall {
    /// The contour's id.
    pub(super) id: i64,
    /// The inspection's verdict.
    pub(super) verdict: Verdict,
    /// The call.
    pub(super) call: Call,
    /// Whether it is planned.
    pub(super) trimmed: bool,
    /// Called for trimming but left out: registration flags it untrustworthy
    /// (`--skip-untrusted`).
    pub(super) untrusted: bool,
    /// The measured excess height, µm (0: none clearly above the noise).
    pub(super) excess_height_um: f64,
    /// The expanded uncertainty U, µm.
    pub(super) uncertainty_um: f64,
    /// The covered share of the contour.
    pub(super) coverage: f64,
    /// The passes each of its polylines gets (none: not trimmed).
    pub(super) passes: Option<u32>,
    /// What the passes come from (none: not trimmed).
    pub(super) passes_from: Option<PassesFrom>,
    /// The inspection's reason for the verdict.
    pub(super) reason: String,
}

/// The detection of a run: every contour's call.
#[derive(Debug, Clone, Serialize)]
pub(super) struct Detection {
    /// The tolerance judged against, µm.
    pub(super) tolerance_um: f64,
    /// The scan noise used, µm.
    pub(super) noise_um: f64,
    /// The depth one pass removes, µm (`[process]`).
    pub(super) depth_per_pass_um: f64,
    /// Per contour, in path order.
    pub(super) contours: Vec<ContourCall>,
    /// The blocked openings hatched (`[trim] hatch_blocked`; filled once planned).
    pub(super) blocked_hatched: Vec<super::blocked::BlockedHatch>,
    /// The film thickness their passes are set for where a film is seen from one side only,
    /// µm (`[trim] film_thickness_um`; a film seen from both sides is measured).
    pub(super) film_thickness_um: f64,
    /// The inspection of the first scan, per contour.
    #[serde(skip)]
    pub(super) inspected: Vec<ContourInspection>,
}

/// Calls one contour (rules in order, the first that holds):
/// 1. excess − U > tolerance: [`Call::Burr`] (whatever the coverage: what was seen fails);
/// 2. coverage < `min_coverage`: [`Call::NotCovered`];
/// 3. excess > 0 and excess + U > tolerance: [`Call::ExcessUndecided`];
/// 4. the verdict fails (a gouge, a blocked opening): [`Call::FailsWithoutExcess`];
/// 5. otherwise [`Call::Clean`].
///
/// A trimmed contour's passes: [`ProcessSettings::passes_through`] its excess height (capped at
/// [`MAX_PASSES`]); one pass when no excess was seen on it.
pub(super) fn call(
    c: &ContourInspection,
    settings: &InspectSettings,
    process: &ProcessSettings,
) -> ContourCall {
    let (h, u, t) = (c.excess_height_um, c.uncertainty_um, settings.tolerance_um);
    let call = if h - u > t {
        Call::Burr
    } else if c.coverage < settings.min_coverage {
        Call::NotCovered
    } else if h > 0.0 && h + u > t {
        Call::ExcessUndecided
    } else if c.verdict == Verdict::Fail {
        Call::FailsWithoutExcess
    } else {
        Call::Clean
    };
    let (passes, passes_from) = if !call.trimmed() {
        (None, None)
    } else if h <= 0.0 {
        (Some(1), Some(PassesFrom::NothingSeen))
    } else {
        match process.passes_through(h * 1e-3) {
            Some(n) => (Some(n), Some(PassesFrom::Height)),
            None => (Some(MAX_PASSES), Some(PassesFrom::HeightCapped)),
        }
    };
    ContourCall {
        id: c.id,
        verdict: c.verdict,
        call,
        trimmed: call.trimmed(),
        untrusted: false,
        excess_height_um: h,
        uncertainty_um: u,
        coverage: c.coverage,
        passes,
        passes_from,
        reason: c.reason.clone(),
    }
}

impl Detection {
    /// Leaves out of the trim the contours not in `trusted` (registration flags them
    /// untrustworthy and `--skip-untrusted` plans without them), so the record says what was
    /// planned.
    pub(super) fn leave_out_untrusted(&mut self, trusted: &BTreeSet<i64>) {
        for c in &mut self.contours {
            if c.trimmed && !trusted.contains(&c.id) {
                c.trimmed = false;
                c.untrusted = true;
                c.passes = None;
                c.passes_from = None;
            }
        }
    }

    /// The ids of the contours to trim.
    pub(super) fn trimmed(&self) -> BTreeSet<i64> {
        self.ids(|c| c.trimmed)
    }

    /// The ids of the contours with `call`.
    pub(super) fn with_call(&self, call: Call) -> BTreeSet<i64> {
        self.ids(|c| c.call == call)
    }

    fn ids(&self, keep: impl Fn(&ContourCall) -> bool) -> BTreeSet<i64> {
        self.contours
            .iter()
            .filter(|c| keep(c))
            .map(|c| c.id)
            .collect()
    }

    /// Each trimmed contour's passes.
    pub(super) fn passes(&self) -> BTreeMap<i64, u32> {
        self.contours
            .iter()
            .filter_map(|c| c.passes.map(|p| (c.id, p)))
            .collect()
    }

    /// One line for stdout.
    pub(super) fn line(&self) -> String {
        let n = |call| self.with_call(call).len();
        format!(
            "detect: {} of {} contours to trim ({} burr, {} not covered enough to tell, {} excess within U), {} clean skipped{}; passes {:?}",
            self.trimmed().len(),
            self.contours.len(),
            n(Call::Burr),
            n(Call::NotCovered),
            n(Call::ExcessUndecided),
            n(Call::Clean),
            match n(Call::FailsWithoutExcess) {
                0 => String::new(),
                k => format!(", {k} failing on gouge or opening left untrimmed"),
            },
            self.passes()
        )
    }

    /// The section of report.md.
    pub(super) fn markdown(&self) -> String {
        use std::fmt::Write as _;
        let mut md = format!(
            "\n## Detection before trimming (`[trim] only_detected`)\n\nThe first scan inspected through the run's registration (`{}/report.html`; tolerance {:.0} µm, noise {:.1} µm). Trimmed: {:?}. Skipped as clean: {:?}. Not covered enough to tell, trimmed: {:?}. Failing on gouge or opening, not trimmed: {:?}. Passes: ⌈excess height / {:.0} µm⌉ (the web's thickness is not measured; a web is taken to be no thicker than it is tall).\n\n| contour | verdict | excess µm | U µm | coverage % | call | passes |\n|---|---|---|---|---|---|---|\n",
            files::DETECT,
            self.tolerance_um,
            self.noise_um,
            self.trimmed(),
            self.with_call(Call::Clean),
            self.with_call(Call::NotCovered),
            self.with_call(Call::FailsWithoutExcess),
            self.depth_per_pass_um,
        );
        for c in &self.contours {
            let _ = writeln!(
                md,
                "| {} | {} | {:.0} | {:.0} | {:.0} | {} | {} |",
                c.id,
                c.verdict.as_str(),
                c.excess_height_um,
                c.uncertainty_um,
                100.0 * c.coverage,
                if c.untrusted {
                    format!(
                        "{}, but untrustworthy (--skip-untrusted): not planned",
                        c.call.words()
                    )
                } else {
                    c.call.words().to_owned()
                },
                match (c.passes, c.passes_from) {
                    (Some(p), Some(PassesFrom::HeightCapped)) => format!("{p} (capped)"),
                    (Some(p), Some(PassesFrom::NothingSeen)) => format!("{p} (no excess seen)"),
                    (Some(p), _) => p.to_string(),
                    (None, _) => "-".to_owned(),
                }
            );
        }
        md.push_str(&super::blocked::markdown(
            &self.blocked_hatched,
            self.film_thickness_um,
            self.depth_per_pass_um,
        ));
        md
    }
}

/// Inspects the first scan (`inputs.scan`, work-piece frame) through `registration` against
/// the CAD `mesh` ([`cad_mesh`]), writes `detect/` and calls every contour (printed by the
/// caller, once the untrusted contours are left out).
pub(super) fn detect(
    config: &JobConfig,
    inputs: &Inputs,
    mesh: &Mesh,
    registration: &Registration,
    run_dir: &Path,
    timings: &mut Timings,
) -> anyhow::Result<Detection> {
    let t = Instant::now();
    let spinner = stage("inspecting the first scan for burrs");
    let settings = InspectSettings::default();
    let placement = Placement::from_registration(registration);
    let result = inspect(
        mesh,
        &inputs.path,
        inputs.scan.points(),
        &placement,
        &settings,
    )
    .context("trim.only_detected: inspecting the first scan")?;
    drop(spinner);
    crate::inspect::write_inspection(
        &run_dir.join(files::DETECT),
        mesh,
        &inputs.path,
        &inputs.scan,
        &placement,
        &settings,
        &result,
    )?;
    let detection = Detection {
        tolerance_um: result.tolerance_um,
        noise_um: result.noise_um,
        depth_per_pass_um: config.plan.process.depth_per_pass_um,
        contours: result
            .contours
            .iter()
            .map(|c| call(c, &settings, &config.plan.process))
            .collect(),
        blocked_hatched: Vec::new(),
        film_thickness_um: config.plan.trim.film_thickness_um,
        inspected: result.contours,
    };
    timings.detect_s = t.elapsed().as_secs_f64();
    for c in detection
        .contours
        .iter()
        .filter(|c| c.call == Call::FailsWithoutExcess)
    {
        eprintln!(
            "trimctl run: contour {} fails inspection without excess ({}): trimming its edge does not fix it, so it is not trimmed",
            c.id, c.reason
        );
    }
    Ok(detection)
}

/// The CAD as a mesh: the demo part's own, or `part.cad` (a point cloud is refused: the
/// inspection measures distances to the CAD's surface). Read before registration, so a job
/// that cannot be inspected is refused first.
pub(super) fn cad_mesh(config: &JobConfig, inputs: &Inputs) -> anyhow::Result<Mesh> {
    if let Some(demo) = &inputs.demo {
        return demo.case.cad_mesh().context("the demo part's CAD mesh");
    }
    let file = config.part.cad.as_ref().context("part.cad is not given")?;
    match read_geometry(file).with_context(|| format!("part.cad {}", file.display()))? {
        Geometry::Mesh(m) => Ok(*m),
        _ => anyhow::bail!(
            "part.cad {} holds no mesh; detecting burrs (trim.only_detected) and inspecting the part (--verify) measure distances to the CAD's surface: give the STL or PLY mesh",
            file.display()
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inspected(
        id: i64,
        verdict: Verdict,
        excess_um: f64,
        u_um: f64,
        coverage: f64,
    ) -> ContourInspection {
        ContourInspection {
            id,
            verdict,
            excess_height_um: excess_um,
            excess_length_mm: 0.0,
            gouge_depth_um: 0.0,
            blocked_fraction: None,
            film: None,
            uncertainty_um: u_um,
            coverage,
            reason: String::new(),
            bound_um: 10.0,
            length_mm: 10.0,
            points: 100,
            excess_bins: Vec::new(),
            gouge_bins: Vec::new(),
        }
    }

    #[test]
    fn contours_are_called_by_excess_then_coverage_and_passes_follow_the_height() {
        let s = InspectSettings::default();
        let p = ProcessSettings::default();
        assert!((s.tolerance_um - 30.0).abs() < 1e-12 && (s.min_coverage - 0.9).abs() < 1e-12);
        assert!((p.depth_per_pass_um - 40.0).abs() < 1e-12);
        let cases = [
            // A 250 µm burr: ⌈250/40⌉ = 7 passes, even at 40 % coverage.
            (
                inspected(1, Verdict::Fail, 250.0, 25.0, 0.4),
                Call::Burr,
                Some(7),
            ),
            // 56 µm: 56 − 25 = 31 > 30 fails; 2 passes.
            (
                inspected(2, Verdict::Fail, 56.0, 25.0, 1.0),
                Call::Burr,
                Some(2),
            ),
            // 40 µm is within U of the tolerance: trimmed, one pass of 40 µm.
            (
                inspected(3, Verdict::Undecided, 40.0, 25.0, 1.0),
                Call::ExcessUndecided,
                Some(1),
            ),
            // Half covered, nothing seen: trimmed with the one pass a full job gives it.
            (
                inspected(4, Verdict::Undecided, 0.0, 25.0, 0.5),
                Call::NotCovered,
                Some(1),
            ),
            // Half covered, 50 µm seen (not failing): passes from what was seen.
            (
                inspected(5, Verdict::Undecided, 50.0, 25.0, 0.5),
                Call::NotCovered,
                Some(2),
            ),
            // Clean: passes, or covered and no excess at all though U alone is too large.
            (
                inspected(6, Verdict::Pass, 0.0, 25.0, 1.0),
                Call::Clean,
                None,
            ),
            (
                inspected(7, Verdict::Pass, 4.0, 25.0, 1.0),
                Call::Clean,
                None,
            ),
            (
                inspected(8, Verdict::Undecided, 0.0, 40.0, 0.95),
                Call::Clean,
                None,
            ),
            // A 2 mm web needs 50 passes: capped at 20.
            (
                inspected(9, Verdict::Fail, 2000.0, 25.0, 1.0),
                Call::Burr,
                Some(MAX_PASSES),
            ),
        ];
        for (c, want, passes) in &cases {
            let got = call(c, &s, &p);
            assert_eq!(got.call, *want, "contour {}", c.id);
            assert_eq!(got.passes, *passes, "contour {}", c.id);
            assert_eq!(got.trimmed, passes.is_some(), "contour {}", c.id);
        }
        assert_eq!(
            call(&cases[8].0, &s, &p).passes_from,
            Some(PassesFrom::HeightCapped)
        );
        // A gouge fails without excess: named, not trimmed.
        let mut gouged = inspected(10, Verdict::Fail, 0.0, 25.0, 1.0);
        gouged.gouge_depth_um = 90.0;
        let got = call(&gouged, &s, &p);
        assert_eq!((got.call, got.trimmed), (Call::FailsWithoutExcess, false));
        let d = Detection {
            tolerance_um: 30.0,
            noise_um: 10.0,
            depth_per_pass_um: 40.0,
            contours: cases.iter().map(|(c, _, _)| call(c, &s, &p)).collect(),
            blocked_hatched: Vec::new(),
            film_thickness_um: 200.0,
            inspected: Vec::new(),
        };
        assert_eq!(d.trimmed(), BTreeSet::from([1, 2, 3, 4, 5, 9]));
        assert_eq!(d.with_call(Call::Clean), BTreeSet::from([6, 7, 8]));
        assert_eq!(d.passes()[&1], 7);
        let md = d.markdown();
        assert!(md.contains("| 4 | undecided | 0 | 25 | 50 | not covered enough to tell: trimmed | 1 (no excess seen) |"), "{md}");
        assert!(md.contains("Skipped as clean: {6, 7, 8}"), "{md}");
        // A burr on a contour registration does not trust is not planned, and says so.
        let mut d = d;
        d.leave_out_untrusted(&BTreeSet::from([1, 3, 4, 5, 6, 7, 8, 9]));
        assert_eq!(d.trimmed(), BTreeSet::from([1, 3, 4, 5, 9]));
        assert!(!d.passes().contains_key(&2));
        assert!(d.markdown().contains("| 2 | fail | 56 | 25 | 100 | burr: fails on excess, but untrustworthy (--skip-untrusted): not planned | - |"));
    }
}
