//! The registration's settings (job.toml `[register]`) and their checks.
use crate::error::{RegisterError, Result};
use crate::icp::PyramidLevel;
use trim_geom::{Num, Vector3};

/// What the registration does.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// Coarse similarity, then the deformation field (the default).
    #[default]
    Regional,
    /// Coarse similarity only (a rigid-plus-scale part).
    Global,
}

/// Which CAD faces take part after the capture.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Visibility {
    /// The faces the scan shows: CAD points within `visible_within_mm` of the scan at the
    /// captured pose (the default: it needs no view, and a scanner fixed to the machine may
    /// look from several directions).
    #[default]
    Support,
    /// The faces toward an assumed view (`scanner_viewpoint_mm` or `view_direction`, culled at
    /// `facing_min_cos`).
    View,
}

/// Where the coarse stage starts.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum CoarseInit {
    /// The fixture's nominal pose as given.
    Nominal,
    /// The nominal rotation; the translation that matches the centroids of the scan and of the
    /// visible CAD.
    Centroid,
    /// Centroids, and the principal axes of the scan and the visible CAD (the sign choice
    /// nearest the nominal rotation; the nominal rotation when the axes are ambiguous or beyond
    /// `capture_rotation_deg` from it).
    #[default]
    PrincipalAxes,
}

/// The coarse stage.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct CoarseSettings {
    /// Where to start. When that start does not lay the scan on the CAD, further starts are
    /// tried (the nominal rotation, the principal axes, the nominal rotation turned by ±15°
    /// about each principal axis) and the best kept.
    pub init: CoarseInit,
    /// Capture range, rotation: the part may sit up to this far from the fixture's nominal
    /// pose (job.toml [part.scan_from_cad], `register --initial`), degrees. A fit that puts it
    /// more than 1° beyond is refused.
    pub capture_rotation_deg: f64,
    /// Capture range, translation: how far the CAD's centroid may sit from where the nominal
    /// pose puts it, mm. A fit that puts it more than 1 mm beyond is refused.
    pub capture_translation_mm: f64,
    /// A voxel must hold this many scan points to count (drops isolated outliers).
    pub min_voxel_points: usize,
    /// Pyramid levels, coarse to fine (scan voxel size, maximum distance, iterations).
    pub levels: Vec<PyramidLevel>,
    /// Estimate a uniform scale at the finest level (the coarser levels are rigid: a scan → CAD fit
    /// with a free scale at coarse resolution can shrink the scan onto the surface).
    pub with_scale: bool,
    /// Huber threshold as a fraction of each level's maximum distance.
    pub huber_fraction: f64,
    /// When the part is refused (`GlobalQuality::refused`), register it once more with the
    /// coarse refinement also started 1.5 and 3 mm either way along the part's long axis, the
    /// best fitting start kept, and take that registration when it is not refused
    /// (`GlobalQuality::slide_retry`): a coarse fit slid along the span is refused by the
    /// openings check, and most settle back from a start nearer the truth.
    pub slide_retry: bool,
}

impl Default for CoarseSettings {
    fn default() -> Self {
        let level = |voxel_mm, max_correspondence_distance_mm, max_iterations| PyramidLevel {
            voxel_mm,
            max_correspondence_distance_mm,
            max_iterations,
        };
        CoarseSettings {
            init: CoarseInit::PrincipalAxes,
            capture_rotation_deg: 20.0,
            capture_translation_mm: 20.0,
            min_voxel_points: 3,
            levels: vec![
                level(2.0, 12.0, 30),
                level(1.0, 4.0, 30),
                level(0.5, 1.5, 10),
            ],
            with_scale: true,
            huber_fraction: 0.25,
            slide_retry: true,
        }
    }
}

/// The deformation-field stage.
#[derive(
    Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema,
)]
#[serde(deny_unknown_fields, default)]
pub struct DeformationSettings {
    /// Control-point spacing, mm.
    pub spacing_mm: f64,
    /// Scan thinning voxel for the fit (one real point kept per voxel), mm.
    pub voxel_mm: f64,
    /// Gauss-Newton iterations (20 measured better on the outside tune seeds but left more
    /// contours silent on the report seeds and cost 0.7 s: DESIGN.md "Registration", step 4).
    pub iterations: usize,
    /// Maximum correspondence distance at the first iteration, mm.
    pub max_distance_start_mm: f64,
    /// …shrinking geometrically to this by iteration `iterations − 3`, mm.
    pub max_distance_end_mm: f64,
    /// Huber threshold, mm.
    pub huber_mm: f64,
    /// Weight of the second-difference prior relative to the mean data weight per unknown.
    /// 0.1 halves the false alarms on the outside cases but left 6 contours silent on the
    /// report seeds where 0.03 leaves 4, so it stays 0.03 (DESIGN.md "Registration", step 4).
    pub smoothness: f64,
    /// Let the part bend freely: the prior penalises third (not second) differences of the
    /// displacement along the part's thin axis, so a bend or sag costs nothing; the in-plane
    /// displacement keeps second differences. Without it a 0.5 mm bend is pulled flat by up to
    /// 20 µm.
    pub free_bending: bool,
    /// With `free_bending`, let the part bend freely in its own plane too: third differences
    /// of every component, so any quadratic displacement costs nothing (a sintered core bends
    /// along a direction up to 30° off its thin axis, and the second-difference in-plane prior
    /// pulled that part of the bend flat by up to 0.1 mm at the part's ends).
    pub in_plane_bending: bool,
    /// With `free_bending`, bend the part as a beam does (Euler–Bernoulli: cross-sections stay
    /// plane and normal to the span): the prior also penalises the change along the span of
    /// each cross-section's shear, `∂²d_a/∂l² + ∂²d_l/∂a∂l` (a across, l along the span), so a
    /// bend seen on the faces and edges carries the along-span motion the data cannot see (a
    /// strip along the leading edge slides with the bend, as the material does). Without it
    /// that motion is free under the prior: a core bent in its own plane had its edge strips
    /// near the tip left tenths of a millimetre behind along the span while the field fitted
    /// the scan to its noise. Outside tune seeds 2001–2040: contours over 30 µm 171 → 97 of
    /// 1910 (most of the 97 in the two parts refused), parts refused 5 → 2.
    pub beam_kinematics: bool,
    /// Leave out scan points whose CAD match lies within about one CAD sample spacing of a sharp
    /// edge (a neighbour's normal more than ~25° off): which face such a noisy point belongs to
    /// is a guess biased toward the material, which shifted half-seen walls by up to 20 µm.
    pub exclude_edges: bool,
    /// Gauss-Newton iterations before `iterations`, on every eighth point, with the maximum
    /// distance shrinking from twice `max_distance_start_mm` to it. The coarse similarity has
    /// one scale; a core shrunk ±2 % per axis is left up to 1.5 mm off at its ends, where only
    /// the end faces, holes and slot ends can pull the field, and under the main iterations'
    /// fast-shrinking reach they fell out of it first (outside tune seeds 2025, 2037 refused,
    /// 1.1–1.5 mm off). 6 measured on tune seeds 2001–2080: contours over 30 µm 169 → 81 of
    /// 3,900 (10: 86), at a fraction of `iterations`' cost (DESIGN.md "Registration", step 4).
    pub warmup_iterations: usize,
}

impl Default for DeformationSettings {
    fn default() -> Self {
        DeformationSettings {
            spacing_mm: 20.0,
            voxel_mm: 0.4,
            iterations: 10,
            max_distance_start_mm: 1.5,
            max_distance_end_mm: 0.1,
            huber_mm: 0.02,
            smoothness: 0.03,
            free_bending: true,
            in_plane_bending: true,
            beam_kinematics: true,
            exclude_edges: true,
            warmup_iterations: 0,
        }
    }
}

/// The per-contour quality tests.
#[derive(
    Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema,
)]
#[serde(deny_unknown_fields, default)]
pub struct QualitySettings {
    /// A contour point is covered when a matched scan point lies within this, mm.
    pub coverage_radius_mm: f64,
    /// Scan points within this of a contour make its local patch, mm.
    pub patch_radius_mm: f64,
    /// Flag a contour covered on less than this fraction of its points.
    pub min_coverage: f64,
    /// Flag a contour whose patch residual (RMS, mm) exceeds this.
    pub max_residual_mm: f64,
    /// Flag a contour whose predicted error bound (`predicted_max_error_um`: the field's
    /// posterior deviation across it, its residual, coverage and distance to supporting data)
    /// exceeds this, µm.
    pub tolerance_um: f64,
    /// The surroundings within this (mm) give `support_ratio` and the support distance (capped
    /// at this).
    pub support_radius_mm: f64,
    /// The part is in doubt when more than this fraction of its contours is flagged (or over
    /// the tolerance by `part_bound_um`). It is also in doubt when a strip's edge lies off the
    /// scan (`edge_off_scan`).
    pub max_untrusted_fraction: f64,
    /// In a part in doubt, a contour stays trusted only while its bound is within this
    /// fraction of `tolerance_um`; the others are flagged `part_in_doubt`. 0 flags every
    /// contour of such a part. Half the tolerance: over the outside generator's tune pool the
    /// contours over 30 µm that the part's doubt had to catch carried bounds of 21–30 µm
    /// (DESIGN.md, "Registration", step 5).
    pub doubt_bound_fraction: f64,
    /// Refuse the whole registration when fewer than this fraction of scan points lie within
    /// `overlap_distance_mm` of the CAD after the coarse stage.
    pub min_overlap: f64,
    /// Distance for the overlap test, mm.
    pub overlap_distance_mm: f64,
    /// Fit the field a second time with its control points at 0.75× the spacing and widen each
    /// contour's bound by how far the two fits disagree on it (`model_disagreement_mm`): where
    /// the data fix the contour they agree; where the smoothness prior decides (a corner with
    /// little data, an end the scanner barely saw) they do not. The second fit holds the first
    /// one's final matches fixed: one linear solve per Gauss-Newton step of the first.
    pub model_check: bool,
    /// Condition the field on the edges the scan shows (`regional::edge_terms`): each open
    /// contour's stretches, located in the raw scan, observe the displacement across the edge
    /// that the faces do not fix (a strip's slide along the span, a corner's along the chord).
    /// A gap over the tolerance that the scan showed before the terms moved the field still
    /// flags the strip `edge_off_scan` (and puts the part in doubt) when the terms left a
    /// reading out for the material beyond it (a slide corrected from one end only shows its
    /// gap there and not after, and the end left out shows no gap of its own) or did not run;
    /// otherwise the gap after counts (a reading gated as implausible is read again after).
    pub edge_terms: bool,
    /// Flag a trusted contour `p95_risk` when the chance that it lies farther across than the
    /// cross-edge P95 limit (0.4 × `tolerance_um`, 12 µm of 30) exceeds this (`p95_risk` in
    /// the report). 1, the default, flags none: the bound against `tolerance_um` guards the
    /// trim. A shop that must hold the P95 on every contour sets, e.g., 0.05 and pays in
    /// contours flagged (on the outside tune cases at 200k points, 0.05 flags about 5 % more
    /// of the good contours; DESIGN.md, "The P95 risk").
    pub max_p95_risk: f64,
}

impl Default for QualitySettings {
    fn default() -> Self {
        QualitySettings {
            coverage_radius_mm: 0.75,
            patch_radius_mm: 1.5,
            min_coverage: 0.6,
            max_residual_mm: 0.05,
            tolerance_um: 30.0,
            max_untrusted_fraction: 0.5,
            doubt_bound_fraction: 0.5,
            support_radius_mm: 15.0,
            min_overlap: 0.3,
            overlap_distance_mm: 1.0,
            model_check: true,
            edge_terms: true,
            max_p95_risk: 1.0,
        }
    }
}

/// Registration settings: the `[register]` table of job.toml.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct RegisterSettings {
    /// Regional (field) or global (similarity only).
    pub mode: Mode,
    /// The scanner's position in the scan frame, mm. When absent the scanner is taken to look along
    /// `−view_direction` from infinitely far.
    pub scanner_viewpoint_mm: Option<[f64; 3]>,
    /// Direction toward the scanner in the scan frame (used without a viewpoint).
    pub view_direction: [f64; 3],
    /// CAD points whose normal makes `cos < facing_min_cos` with the direction to the scanner are
    /// culled (−0.2 keeps walls up to 102° off the view).
    pub facing_min_cos: f64,
    /// Which CAD faces take part after the capture (the capture itself uses the view).
    pub visibility: Visibility,
    /// With `visibility = "support"`: a CAD point takes part when a scan voxel lies within
    /// this of it at the captured pose, mm.
    pub visible_within_mm: f64,
    /// Points sampled from a CAD mesh.
    pub cad_sample_points: usize,
    /// The coarse stage: a global similarity from the fixture pose.
    pub coarse: CoarseSettings,
    /// The field stage: a smooth deformation field over the part.
    pub field: DeformationSettings,
    /// The quality tests that flag a contour untrustworthy.
    pub quality: QualitySettings,
}

impl Default for RegisterSettings {
    fn default() -> Self {
        RegisterSettings {
            mode: Mode::Regional,
            scanner_viewpoint_mm: None,
            view_direction: [0.0, 0.0, 1.0],
            facing_min_cos: -0.2,
            visibility: Visibility::Support,
            visible_within_mm: 1.5,
            cad_sample_points: 300_000,
            coarse: CoarseSettings::default(),
            field: DeformationSettings::default(),
            quality: QualitySettings::default(),
        }
    }
}

/// The most points sampled from a CAD mesh (`cad_sample_points`): 10 million points with
/// normals, their kd-tree and the registration's working copies take a few GB; more exhausts the
/// memory of a cell PC instead of being refused.
pub const MAX_CAD_SAMPLE_POINTS: usize = 10_000_000;

/// The ranges of the quality gates (job.toml `[register.quality]`, `[register.coarse]`): a
/// value outside switches the gate off, or flags every contour, and is refused by name. Each
/// is (smallest, largest), both allowed.
pub mod gate {
    /// `quality.tolerance_um`: above 100 µm (over 3× the ±30 µm product tolerance of the
    /// paper's cores) a predicted error bound no longer guards the trim.
    pub const TOLERANCE_UM: (f64, f64) = (1.0, 100.0);
    /// `quality.min_coverage`: below 0.2 a contour four-fifths unseen passes.
    pub const MIN_COVERAGE: (f64, f64) = (0.2, 1.0);
    /// `quality.min_overlap`: below 0.05 a scan that barely meets the CAD passes.
    pub const MIN_OVERLAP: (f64, f64) = (0.05, 1.0);
    /// `quality.max_untrusted_fraction`: a stricter part-level gate is always safe (0 doubts
    /// any part with a flagged contour); 1 never doubts the part for its count of flags.
    pub const MAX_UNTRUSTED_FRACTION: (f64, f64) = (0.0, 1.0);
    /// `quality.doubt_bound_fraction`: 0 flags every contour of a part in doubt; 1 trusts the
    /// bounds of a part in doubt as those of any other.
    pub const DOUBT_BOUND_FRACTION: (f64, f64) = (0.0, 1.0);
    /// `quality.max_p95_risk`: 0 flags every contour with a posterior; 1 flags none.
    pub const MAX_P95_RISK: (f64, f64) = (0.0, 1.0);
    /// `quality.max_residual_mm`: above 0.5 mm a patch that misses the surface passes.
    pub const MAX_RESIDUAL_MM: (f64, f64) = (0.001, 0.5);
    /// `quality.coverage_radius_mm`: above 5 mm any scan point nearby covers a contour.
    pub const COVERAGE_RADIUS_MM: (f64, f64) = (0.01, 5.0);
    /// `quality.overlap_distance_mm`: above 10 mm any scan overlaps the CAD.
    pub const OVERLAP_DISTANCE_MM: (f64, f64) = (0.01, 10.0);
    /// `quality.patch_radius_mm`: the patch a contour's residual is measured on.
    pub const PATCH_RADIUS_MM: (f64, f64) = (0.01, 20.0);
    /// `quality.support_radius_mm`: the surroundings that give the support ratio.
    pub const SUPPORT_RADIUS_MM: (f64, f64) = (0.1, 100.0);
    /// `coarse.capture_translation_mm`: beyond 200 mm the capture test refuses nothing on a
    /// part of this size.
    pub const CAPTURE_TRANSLATION_MM: (f64, f64) = (0.01, 200.0);
}

/// Refuses `v` outside `[lo, hi]` (or non-finite), naming the key.
pub(crate) fn within(name: &str, v: f64, (lo, hi): (f64, f64)) -> Result<()> {
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(RegisterError::setting(
            name,
            format!("must be in [{}, {}], got {}", Num(lo), Num(hi), Num(v)),
        ))
    }
}

pub(crate) fn positive(name: &str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(RegisterError::setting(
            name,
            format!("must be finite and > 0, got {}", Num(v)),
        ))
    }
}

/// The most iterations a coarse level may take (`coarse.levels[k].max_iterations`): the
/// defaults take 30–50 and converge well before; a count of millions only made the command run
/// for hours.
pub const MAX_COARSE_ITERATIONS: usize = 1000;

/// The most Gauss-Newton iterations of the field (`field.iterations`, and as many warm-up
/// iterations): the default takes 10, and 20 measured no better (DESIGN.md); 1,000 take a
/// minute or so on a 500k scan (the Python cancel test runs that many to be interrupted).
pub const MAX_FIELD_ITERATIONS: usize = 1000;

impl RegisterSettings {
    /// Refuses out-of-range values, naming the key as in job.toml (`register.field.spacing_mm`).
    pub fn validate(&self) -> Result<()> {
        if let Some(v) = self.scanner_viewpoint_mm
            && !v.iter().all(|c| c.is_finite())
        {
            return Err(RegisterError::setting(
                "scanner_viewpoint_mm",
                "must be finite",
            ));
        }
        let d = Vector3::from(self.view_direction);
        if !(d.iter().all(|c| c.is_finite()) && d.norm() > 0.0) {
            return Err(RegisterError::setting(
                "view_direction",
                "must be a finite non-zero vector",
            ));
        }
        if !(-1.0..=1.0).contains(&self.facing_min_cos) {
            return Err(RegisterError::setting(
                "facing_min_cos",
                "must be in [−1, 1]",
            ));
        }
        positive("visible_within_mm", self.visible_within_mm)?;
        if !(1000..=MAX_CAD_SAMPLE_POINTS).contains(&self.cad_sample_points) {
            return Err(RegisterError::setting(
                "cad_sample_points",
                format!(
                    "must be in [1000, {MAX_CAD_SAMPLE_POINTS}], got {}",
                    self.cad_sample_points
                ),
            ));
        }
        if self.coarse.levels.is_empty() {
            return Err(RegisterError::setting(
                "coarse.levels",
                "needs at least one level",
            ));
        }
        for (k, l) in self.coarse.levels.iter().enumerate() {
            positive(&format!("coarse.levels[{k}].voxel_mm"), l.voxel_mm)?;
            positive(
                &format!("coarse.levels[{k}].max_correspondence_distance_mm"),
                l.max_correspondence_distance_mm,
            )?;
            if !(1..=MAX_COARSE_ITERATIONS).contains(&l.max_iterations) {
                return Err(RegisterError::setting(
                    format!("coarse.levels[{k}].max_iterations"),
                    format!(
                        "must be in [1, {MAX_COARSE_ITERATIONS}], got {}",
                        l.max_iterations
                    ),
                ));
            }
        }
        positive("coarse.huber_fraction", self.coarse.huber_fraction)?;
        positive(
            "coarse.capture_rotation_deg",
            self.coarse.capture_rotation_deg,
        )?;
        if self.coarse.capture_rotation_deg > 180.0 {
            return Err(RegisterError::setting(
                "coarse.capture_rotation_deg",
                format!(
                    "must be at most 180, got {}",
                    self.coarse.capture_rotation_deg
                ),
            ));
        }
        within(
            "coarse.capture_translation_mm",
            self.coarse.capture_translation_mm,
            gate::CAPTURE_TRANSLATION_MM,
        )?;
        let f = &self.field;
        positive("field.spacing_mm", f.spacing_mm)?;
        positive("field.voxel_mm", f.voxel_mm)?;
        positive("field.max_distance_start_mm", f.max_distance_start_mm)?;
        positive("field.max_distance_end_mm", f.max_distance_end_mm)?;
        positive("field.huber_mm", f.huber_mm)?;
        if !(f.smoothness.is_finite() && f.smoothness >= 0.0) {
            return Err(RegisterError::setting(
                "field.smoothness",
                "must be finite and ≥ 0",
            ));
        }
        if !(1..=MAX_FIELD_ITERATIONS).contains(&f.iterations) {
            return Err(RegisterError::setting(
                "field.iterations",
                format!(
                    "must be in [1, {MAX_FIELD_ITERATIONS}], got {}",
                    f.iterations
                ),
            ));
        }
        if f.warmup_iterations > MAX_FIELD_ITERATIONS {
            return Err(RegisterError::setting(
                "field.warmup_iterations",
                format!(
                    "must be in [0, {MAX_FIELD_ITERATIONS}], got {}",
                    f.warmup_iterations
                ),
            ));
        }
        if f.max_distance_end_mm > f.max_distance_start_mm {
            return Err(RegisterError::setting(
                "field.max_distance_end_mm",
                format!(
                    "must not exceed field.max_distance_start_mm ({} mm; the reach shrinks from it), got {} mm",
                    f.max_distance_start_mm, f.max_distance_end_mm
                ),
            ));
        }
        let q = &self.quality;
        for (name, v, range) in [
            (
                "quality.coverage_radius_mm",
                q.coverage_radius_mm,
                gate::COVERAGE_RADIUS_MM,
            ),
            (
                "quality.patch_radius_mm",
                q.patch_radius_mm,
                gate::PATCH_RADIUS_MM,
            ),
            (
                "quality.max_residual_mm",
                q.max_residual_mm,
                gate::MAX_RESIDUAL_MM,
            ),
            (
                "quality.support_radius_mm",
                q.support_radius_mm,
                gate::SUPPORT_RADIUS_MM,
            ),
            (
                "quality.overlap_distance_mm",
                q.overlap_distance_mm,
                gate::OVERLAP_DISTANCE_MM,
            ),
            ("quality.min_coverage", q.min_coverage, gate::MIN_COVERAGE),
            ("quality.tolerance_um", q.tolerance_um, gate::TOLERANCE_UM),
            ("quality.min_overlap", q.min_overlap, gate::MIN_OVERLAP),
        ] {
            within(name, v, range)?;
        }
        within(
            "quality.max_untrusted_fraction",
            q.max_untrusted_fraction,
            gate::MAX_UNTRUSTED_FRACTION,
        )?;
        within(
            "quality.doubt_bound_fraction",
            q.doubt_bound_fraction,
            gate::DOUBT_BOUND_FRACTION,
        )?;
        within("quality.max_p95_risk", q.max_p95_risk, gate::MAX_P95_RISK)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every gate has a range: a value that would switch it off (or a point count that would
    /// exhaust the memory) is refused, naming the key; the defaults and the ends pass.
    #[test]
    fn gates_and_point_counts_are_refused_by_key_outside_their_ranges() {
        RegisterSettings::default().validate().unwrap();
        type Set = fn(&mut RegisterSettings, f64);
        let cases: [(&str, Set, (f64, f64)); 9] = [
            (
                "quality.tolerance_um",
                |s, v| s.quality.tolerance_um = v,
                gate::TOLERANCE_UM,
            ),
            (
                "quality.min_coverage",
                |s, v| s.quality.min_coverage = v,
                gate::MIN_COVERAGE,
            ),
            (
                "quality.min_overlap",
                |s, v| s.quality.min_overlap = v,
                gate::MIN_OVERLAP,
            ),
            (
                "quality.max_residual_mm",
                |s, v| s.quality.max_residual_mm = v,
                gate::MAX_RESIDUAL_MM,
            ),
            (
                "quality.coverage_radius_mm",
                |s, v| s.quality.coverage_radius_mm = v,
                gate::COVERAGE_RADIUS_MM,
            ),
            (
                "quality.overlap_distance_mm",
                |s, v| s.quality.overlap_distance_mm = v,
                gate::OVERLAP_DISTANCE_MM,
            ),
            (
                "quality.patch_radius_mm",
                |s, v| s.quality.patch_radius_mm = v,
                gate::PATCH_RADIUS_MM,
            ),
            (
                "quality.support_radius_mm",
                |s, v| s.quality.support_radius_mm = v,
                gate::SUPPORT_RADIUS_MM,
            ),
            (
                "coarse.capture_translation_mm",
                |s, v| s.coarse.capture_translation_mm = v,
                gate::CAPTURE_TRANSLATION_MM,
            ),
        ];
        for (key, set, (lo, hi)) in cases {
            for ok in [lo, hi] {
                let mut s = RegisterSettings::default();
                set(&mut s, ok);
                assert!(s.validate().is_ok(), "{key} = {ok}");
            }
            for bad in [0.0, lo * 0.5, hi * 1.5, 1e12, f64::NAN, f64::INFINITY] {
                let mut s = RegisterSettings::default();
                set(&mut s, bad);
                let e = s.validate().expect_err(key).to_string();
                assert!(e.contains(key), "{key} = {bad}: {e}");
            }
        }
        for (v, ok) in [
            (0.0, true),
            (1.0, true),
            (-0.01, false),
            (1.01, false),
            (f64::NAN, false),
        ] {
            let mut s = RegisterSettings::default();
            s.quality.max_p95_risk = v;
            match s.validate() {
                Ok(()) => assert!(ok, "quality.max_p95_risk = {v} accepted"),
                Err(e) => {
                    assert!(!ok, "quality.max_p95_risk = {v}: {e}");
                    assert!(e.to_string().contains("quality.max_p95_risk"), "{e}");
                }
            }
        }
        for (n, ok) in [
            (999, false),
            (1000, true),
            (MAX_CAD_SAMPLE_POINTS, true),
            (MAX_CAD_SAMPLE_POINTS + 1, false),
            (usize::MAX, false),
        ] {
            let s = RegisterSettings {
                cad_sample_points: n,
                ..RegisterSettings::default()
            };
            match s.validate() {
                Ok(()) => assert!(ok, "cad_sample_points = {n} accepted"),
                Err(e) => {
                    assert!(!ok, "cad_sample_points = {n}: {e}");
                    assert!(e.to_string().contains("cad_sample_points"), "{e}");
                }
            }
        }
    }

    /// Iteration counts have an upper end (a count of millions ran for hours), and the field's
    /// reach must shrink, not grow; each refusal names its key.
    #[test]
    fn iteration_counts_and_the_fields_reach_are_refused_by_key_outside_their_ranges() {
        type Set = fn(&mut RegisterSettings);
        let cases: [(&str, Set); 6] = [
            ("field.iterations", |s| s.field.iterations = 0),
            ("field.iterations", |s| {
                s.field.iterations = MAX_FIELD_ITERATIONS + 1;
            }),
            ("field.warmup_iterations", |s| {
                s.field.warmup_iterations = 100_000_000;
            }),
            ("coarse.levels[0].max_iterations", |s| {
                s.coarse.levels[0].max_iterations = MAX_COARSE_ITERATIONS + 1;
            }),
            ("coarse.levels[0].max_iterations", |s| {
                s.coarse.levels[0].max_iterations = 0;
            }),
            ("field.max_distance_end_mm", |s| {
                s.field.max_distance_end_mm = 2.0 * s.field.max_distance_start_mm;
            }),
        ];
        for (key, set) in cases {
            let mut s = RegisterSettings::default();
            set(&mut s);
            let e = s.validate().expect_err(key).to_string();
            assert!(e.contains(key), "{key}: {e}");
        }
        let mut s = RegisterSettings::default();
        s.field.iterations = MAX_FIELD_ITERATIONS;
        s.field.warmup_iterations = MAX_FIELD_ITERATIONS;
        s.coarse.levels[0].max_iterations = MAX_COARSE_ITERATIONS;
        s.validate().unwrap();
    }
}
