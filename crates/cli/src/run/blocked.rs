//! Blocked openings become hatch regions (issue 23, "Detect before trimming"; `[trim]
//! hatch_blocked`). Where the first scan is inspected (`[trim] only_detected`) and in `run
//! --verify`'s retrims, every contour rimming an opening that is blocked — its
//! `blocked_fraction` above the inspection's `max_blocked_fraction`, the share that fails it —
//! is hatched: the registered rim, moved half a kerf (less its chords' sagitta) into the
//! opening, bounds a region of tracks
//! a pitch of 3/4 of the kerf apart along the opening's long axis, on the face continued over
//! the opening (`trim_plan::hatch::opening`). Trimming the rim alone removes nothing over the
//! opening.
//!
//! *Passes.* Where the scan sees the film from both sides (a view from below sees its
//! underside through the opening), the inspection measures its thickness
//! (`trim_inspect::opening::read_opening`: the spread along the normal between its upper
//! side's readings and its underside's), and every track gets the passes that cut through
//! that thickness plus `coverage_factor` (2) standard uncertainties, so a film read a few µm
//! thin is still cut through. Where only one side is seen the thickness is unknown, and the
//! tracks get the passes through `[trim] film_thickness_um` (the thickest film expected,
//! default 200 µm): a thinner film is cut through sooner and the extra passes mark the hole's
//! air, a thicker one stands and `--verify`'s rescan finds it. Which of the two each opening
//! got is recorded.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use anyhow::Context;
use serde::Serialize;
use trim_cell::process::MAX_PASSES;
use trim_geom::formats::write_path;
use trim_geom::{Contour, Path as TrimPath};
use trim_inspect::opening::FilmThickness;
use trim_inspect::{ContourInspection, InspectSettings};
use trim_plan::hatch::opening::{chord_sagitta_mm, film_settings, hatch_opening};

use crate::config::JobConfig;
use crate::hatch::as_region_tracks;

/// Whether the inspection says the contour's opening is blocked: more of it covered than
/// `max_blocked_fraction`, the share that fails the contour.
pub(super) fn is_blocked(c: &ContourInspection, settings: &InspectSettings) -> bool {
    c.blocked_fraction
        .is_some_and(|b| b > settings.max_blocked_fraction)
}

/// One blocked opening's hatch.
#[derive(Debug, Clone, Serialize)]
pub(super) struct BlockedHatch {
    /// The rim contour's id.
    pub(super) contour: i64,
    /// The inspection's covered share of its opening.
    pub(super) blocked_fraction: f64,
    /// The hatch region's index among the job's regions (its tracks' ids,
    /// `trim_plan::hatch::track_ids`).
    pub(super) region: usize,
    /// Its tracks (outline included).
    pub(super) tracks: usize,
    /// The film's thickness the passes cut through, µm: measured, or `[trim]
    /// film_thickness_um`.
    pub(super) film_thickness_um: f64,
    /// Where that thickness comes from.
    pub(super) thickness_from: ThicknessFrom,
    /// The measured thickness's standard uncertainty, µm (none when not measured).
    pub(super) film_thickness_uncertainty_um: Option<f64>,
    /// The passes of every track.
    pub(super) passes: u32,
}

/// Where a film's thickness comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub(super) enum ThicknessFrom {
    /// Measured from the scan's readings of both its sides.
    Measured,
    /// `[trim] film_thickness_um`: only one side is seen.
    Config,
}

impl ThicknessFrom {
    fn words(self) -> &'static str {
        match self {
            ThicknessFrom::Measured => "measured",
            ThicknessFrom::Config => "[trim] film_thickness_um (one side seen)",
        }
    }
}

/// The blocked openings' hatches of one job: the tracks to plan, each track's passes, and the
/// record.
#[derive(Debug, Default)]
pub(super) struct BlockedHatches {
    pub(super) tracks: Vec<Contour>,
    pub(super) passes: BTreeMap<i64, u32>,
    pub(super) openings: Vec<BlockedHatch>,
}

impl BlockedHatches {
    /// The rims hatched.
    #[cfg_attr(
        not(feature = "sim"),
        expect(
            dead_code,
            reason = "used by --verify's retrims, which need the simulators"
        )
    )]
    pub(super) fn contours(&self) -> BTreeSet<i64> {
        self.openings.iter().map(|o| o.contour).collect()
    }

    /// One line for stdout (none when nothing is hatched).
    pub(super) fn line(&self) -> Option<String> {
        (!self.openings.is_empty()).then(|| {
            let list: Vec<String> = self
                .openings
                .iter()
                .map(|o| {
                    let film = match o.thickness_from {
                        ThicknessFrom::Measured => {
                            format!("film {:.0} µm measured", o.film_thickness_um)
                        }
                        ThicknessFrom::Config => {
                            format!("film {:.0} µm from the job", o.film_thickness_um)
                        }
                    };
                    format!(
                        "contour {} ({:.0} % covered, {film}, {} tracks × {} passes)",
                        o.contour,
                        100.0 * o.blocked_fraction,
                        o.tracks,
                        o.passes
                    )
                })
                .collect();
            format!("blocked openings hatched: {}", list.join(", "))
        })
    }
}

/// The section of report.md for `openings` (empty when nothing is hatched): the passes cut
/// through each film's measured thickness, or `film_thickness_um` where only one side is seen,
/// at `depth_per_pass_um`.
pub(super) fn markdown(
    openings: &[BlockedHatch],
    film_thickness_um: f64,
    depth_per_pass_um: f64,
) -> String {
    use std::fmt::Write as _;
    if openings.is_empty() {
        return String::new();
    }
    let mut md = format!(
        "\n## Blocked openings hatched (`[trim] hatch_blocked`)\n\nEach rim whose opening the inspection finds more than `max_blocked_fraction` (10 %) covered is hatched inside (the rim moved half a kerf inward, pitch 3/4 of the kerf). Where the scan sees a film from both sides its thickness is measured (its upper side's readings less its underside's along the normal), and the passes cut through it plus twice its standard uncertainty; where only one side is seen they cut through `[trim] film_thickness_um` = {film_thickness_um:.0} µm. {depth_per_pass_um:.0} µm per pass.\n\n| contour | covered % | film thickness (µm) | thickness from | hatch region | tracks | passes |\n|---|---|---|---|---|---|---|\n"
    );
    for o in openings {
        let thickness = match o.film_thickness_uncertainty_um {
            Some(u) => format!("{:.0} ± {u:.1}", o.film_thickness_um),
            None => format!("{:.0}", o.film_thickness_um),
        };
        let _ = writeln!(
            md,
            "| {} | {:.0} | {thickness} | {} | {} | {} | {} |",
            o.contour,
            100.0 * o.blocked_fraction,
            o.thickness_from.words(),
            o.region,
            o.tracks,
            o.passes
        );
    }
    md
}

/// The thickness a blocked opening's tracks cut through (µm), where it comes from, its
/// standard uncertainty, and the passes (capped at [`MAX_PASSES`]): through the measured
/// `film` plus `coverage_factor` standard uncertainties, or through `[trim]
/// film_thickness_um` where the film was not measured.
fn film_passes(
    film: Option<&FilmThickness>,
    coverage_factor: f64,
    config: &JobConfig,
) -> (f64, ThicknessFrom, Option<f64>, u32) {
    let process = &config.plan.process;
    match film {
        Some(f) => {
            let cut_um = f.thickness_um + coverage_factor * f.uncertainty_um;
            (
                f.thickness_um,
                ThicknessFrom::Measured,
                Some(f.uncertainty_um),
                process.passes_through(cut_um * 1e-3).unwrap_or(MAX_PASSES),
            )
        }
        None => {
            let t_um = config.plan.trim.film_thickness_um;
            (
                t_um,
                ThicknessFrom::Config,
                None,
                process.passes_through(t_um * 1e-3).unwrap_or(MAX_PASSES),
            )
        }
    }
}

/// Hatches the blocked openings among `inspected` whose contours are in `allowed`, on their
/// registered rims (`registered`, work-piece frame); the regions are numbered from
/// `first_region`, their tracks written to `out_dir/blocked_<contour>.csv`, each track with the
/// passes through its film's measured thickness or `[trim] film_thickness_um` ([`film_passes`]).
/// Nothing when `[trim] hatch_blocked` is off. A rim that cannot be hatched (too narrow for the
/// inset, say) is an error naming the contour.
pub(super) fn hatch_blocked<'a>(
    inspected: impl IntoIterator<Item = &'a ContourInspection>,
    settings: &InspectSettings,
    registered: &TrimPath,
    allowed: &BTreeSet<i64>,
    first_region: usize,
    config: &JobConfig,
    out_dir: &Path,
) -> anyhow::Result<BlockedHatches> {
    let mut out = BlockedHatches::default();
    if !config.plan.trim.hatch_blocked {
        return Ok(out);
    }
    let kerf_mm = config.plan.process.kerf_width_mm(&config.plan.beam);
    let hatching = film_settings(kerf_mm).context("trim.hatch_blocked: the film's hatch")?;
    let half_kerf_mm = config.plan.kerf_offset_mm().unwrap_or(0.0);
    for c in inspected
        .into_iter()
        .filter(|c| is_blocked(c, settings) && allowed.contains(&c.id))
    {
        let Some(rim) = registered.contours().iter().find(|r| r.id() == c.id) else {
            continue;
        };
        let region = first_region + out.openings.len();
        // The kerf reaches the rim's arcs between its points, not only its chords.
        let inset_mm = (half_kerf_mm - chord_sagitta_mm(rim)).max(0.0);
        let hatch = hatch_opening(rim, inset_mm, &hatching).with_context(|| {
            format!(
                "trim.hatch_blocked: hatching the film over contour {}'s opening",
                c.id
            )
        })?;
        let path = hatch.to_path()?;
        write_path(&out_dir.join(format!("blocked_{}.csv", c.id)), &path)?;
        let tracks = as_region_tracks(&path, region)?;
        let (film_thickness_um, thickness_from, film_thickness_uncertainty_um, passes) =
            film_passes(c.film.as_ref(), settings.coverage_factor, config);
        out.passes.extend(tracks.iter().map(|t| (t.id(), passes)));
        out.openings.push(BlockedHatch {
            contour: c.id,
            blocked_fraction: c.blocked_fraction.unwrap_or(0.0),
            region,
            tracks: tracks.len(),
            film_thickness_um,
            thickness_from,
            film_thickness_uncertainty_um,
            passes,
        });
        out.tracks.extend(tracks);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A measured film is cut through its thickness plus twice its standard uncertainty; one
    /// seen from one side only through `[trim] film_thickness_um`; the report says which.
    #[test]
    fn a_measured_film_gets_the_passes_of_its_thickness_and_the_report_says_so() {
        let config = JobConfig::default();
        assert!((config.plan.process.depth_per_pass_um - 40.0).abs() < 1e-12);
        assert!((config.plan.trim.film_thickness_um - 200.0).abs() < 1e-12);
        let film = |thickness_um, uncertainty_um| FilmThickness {
            thickness_um,
            uncertainty_um,
            upper_readings: 400,
            underside_readings: 100,
        };
        // 78 + 2·0.9 = 79.8 µm: 2 passes of 40 µm.
        let thin = film_passes(Some(&film(78.0, 0.9)), 2.0, &config);
        assert_eq!(thin, (78.0, ThicknessFrom::Measured, Some(0.9), 2));
        // 78 + 2·1.5 = 81 µm: one pass more, rather than a 1 µm skin left standing.
        assert_eq!(film_passes(Some(&film(78.0, 1.5)), 2.0, &config).3, 3);
        let unseen = film_passes(None, 2.0, &config);
        assert_eq!(unseen, (200.0, ThicknessFrom::Config, None, 5));

        let hatch =
            |contour, (film_thickness_um, thickness_from, uncertainty, passes)| BlockedHatch {
                contour,
                blocked_fraction: 0.5,
                region: 0,
                tracks: 40,
                film_thickness_um,
                thickness_from,
                film_thickness_uncertainty_um: uncertainty,
                passes,
            };
        let openings = [hatch(6, thin), hatch(19, unseen)];
        let md = markdown(&openings, 200.0, 40.0);
        assert!(
            md.contains("| 6 | 50 | 78 ± 0.9 | measured | 0 | 40 | 2 |"),
            "{md}"
        );
        assert!(
            md.contains(
                "| 19 | 50 | 200 | [trim] film_thickness_um (one side seen) | 0 | 40 | 5 |"
            ),
            "{md}"
        );
        let line = BlockedHatches {
            openings: openings.to_vec(),
            ..BlockedHatches::default()
        }
        .line()
        .expect("a line");
        assert!(
            line.contains("contour 6 (50 % covered, film 78 µm measured, 40 tracks × 2 passes)"),
            "{line}"
        );
        assert!(line.contains("film 200 µm from the job"), "{line}");
    }
}
