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
//! *Passes.* The inspection sees whether an opening is covered, not how thick the cover is (a
//! film's underside shows, if at all, only to a view from below, and trim-inspect does not
//! estimate it), so every track gets the passes that cut through `[trim] film_thickness_um`
//! (the thickest film expected, default 200 µm) at `[process] depth_per_pass_um`. A thinner
//! film is cut through sooner and the extra passes mark the hole's air; a thicker one stands
//! and `--verify`'s rescan finds it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use anyhow::Context;
use serde::Serialize;
use trim_cell::process::MAX_PASSES;
use trim_geom::formats::write_path;
use trim_geom::{Contour, Path as TrimPath};
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
    /// The passes of every track.
    pub(super) passes: u32,
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
                    format!(
                        "contour {} ({:.0} % covered, {} tracks × {} passes)",
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

/// The section of report.md for `openings` (empty when nothing is hatched), the passes set for
/// a film `film_thickness_um` thick at `depth_per_pass_um`.
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
        "\n## Blocked openings hatched (`[trim] hatch_blocked`)\n\nEach rim whose opening the inspection finds more than `max_blocked_fraction` (10 %) covered is hatched inside (the rim moved half a kerf inward, pitch 3/4 of the kerf). The film's thickness is not measured: the passes cut through `[trim] film_thickness_um` = {film_thickness_um:.0} µm at {depth_per_pass_um:.0} µm per pass.\n\n| contour | covered % | hatch region | tracks | passes |\n|---|---|---|---|---|\n"
    );
    for o in openings {
        let _ = writeln!(
            md,
            "| {} | {:.0} | {} | {} | {} |",
            o.contour,
            100.0 * o.blocked_fraction,
            o.region,
            o.tracks,
            o.passes
        );
    }
    md
}

/// The passes a blocked opening's tracks get: through `[trim] film_thickness_um` (capped at
/// [`MAX_PASSES`]).
fn film_passes(config: &JobConfig) -> u32 {
    config
        .plan
        .process
        .passes_through(config.plan.trim.film_thickness_um * 1e-3)
        .unwrap_or(MAX_PASSES)
}

/// Hatches the blocked openings among `inspected` whose contours are in `allowed`, on their
/// registered rims (`registered`, work-piece frame); the regions are numbered from
/// `first_region`, their tracks written to `out_dir/blocked_<contour>.csv`. Nothing when `[trim]
/// hatch_blocked` is off. A rim that cannot be hatched (too narrow for the inset, say) is an
/// error naming the contour.
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
    let passes = film_passes(config);
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
        out.passes.extend(tracks.iter().map(|t| (t.id(), passes)));
        out.openings.push(BlockedHatch {
            contour: c.id,
            blocked_fraction: c.blocked_fraction.unwrap_or(0.0),
            region,
            tracks: tracks.len(),
            passes,
        });
        out.tracks.extend(tracks);
    }
    Ok(out)
}
