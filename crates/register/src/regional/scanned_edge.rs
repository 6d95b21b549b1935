//! The scanned edge as a check on the registered contours (DESIGN.md, Registration step 5,
//! "The scanned edge as a check").
//!
//! A part that slides along a direction its surfaces do not fix (a core's span) keeps the
//! field's residuals small and its posterior confident, while every edge across that direction
//! moves: the root and tip strips, the ends of slots. The scan shows where such an edge really
//! is. For each stretch of [`EDGE_STRETCH_MM`] of a registered contour (scan frame), the scan
//! points beside it are taken in the contour's local frame (tangent `t`, feature vector `f`,
//! and `b = t × f` across the edge in the face), turned so that the face lies at `b < 0`:
//! - when the scanner saw at least [`EDGE_MIN_WALL_POINTS`] of the wall below the edge, the
//!   edge is where a line fitted to the wall points' `b` against their depth meets the face;
//! - otherwise the edge is where the face points end: the maximum-likelihood position `e` of a
//!   step blurred by the scan noise (points spread evenly over `b < e` within
//!   [`EDGE_WINDOW_MM`], each displaced by the noise, with a small share of outliers).
//!
//! Only one side of the answer tests the registration. Scan material beyond the registered
//! edge is also what a burr looks like (flash standing off the edge, the thing the laser is
//! there to remove), so it proves nothing. The registered edge lying beyond the material the
//! scan shows, by `gap = −e − 2σₑ`, is what no burr can cause: a gap wider than the tolerance
//! says the registration put that edge where the part is not, and, since the field is smooth,
//! that the part's other edges along the same direction moved with it (outside report parts
//! 1045 and 1084: the tip and root strips showed gaps of 34–52 µm while the leading-edge strips,
//! slid along themselves by 33–39 µm, stayed trusted).
//!
//! A hole's rim (a closed contour up to [`RIM_MAX_LENGTH_MM`]) is read as one edge fitted over
//! the whole rim, slid and resized ([`rim_edges`]), and reported in arcs like a strip's
//! stretches. Only the slide says where the part lies ([`ScannedEdge::slide_gap_mm`]): the
//! field cannot resize a hole.

use rayon::prelude::*;
use trim_geom::stats::{golden_section_min, normal_cdf, normal_cdf_integral};
use trim_geom::{Contour, Point3, Vector3};

use crate::kdtree::{KdTree, Scratch};

/// Half-width of the strip beside the contour in which scan points locate the edge, mm.
pub const EDGE_WINDOW_MM: f64 = 0.4;
/// Length of contour over which one edge position is measured, mm (a contour shorter than
/// this is one stretch).
pub const EDGE_STRETCH_MM: f64 = 20.0;
/// Fewest face points that locate an edge in one stretch.
pub const EDGE_MIN_FACE_POINTS: usize = 50;
/// Fewest wall points (below the face, within [`EDGE_WALL_REACH_MM`] of the edge across it)
/// that locate the edge from the wall instead of the face.
pub const EDGE_MIN_WALL_POINTS: usize = 30;
/// How far across the edge wall points may lie, mm, and how deep below the face.
pub const EDGE_WALL_REACH_MM: f64 = 0.08;
/// See [`EDGE_WALL_REACH_MM`].
pub const EDGE_WALL_DEPTH_MM: f64 = 0.3;
/// Share of outliers in the face's step model.
pub const EDGE_OUTLIER_SHARE: f64 = 0.01;
/// Standard deviations of its own estimate the edge must lie inside the registered contour
/// before the difference counts as a gap.
pub const EDGE_GAP_SIGMAS: f64 = 2.0;
/// The same for a rim's arcs: the three-unknown fit over a small hole's few face points has a
/// longer tail than its curvature says. On the project's own one-view cores (200k points; the
/// sweep `benches/outside/run --generator own --set tune` and two ad hoc sweeps of seeds
/// 600–679, 1,182 correctly registered rims of 100 or more face points), rims of 150 or more
/// points read a false gap over the tolerance at 2σ on 2 of 566 (31 and 33 µm, each refusing a
/// good part), at 2.5σ on none; rims over 30 µm off show a gap on 41 of 58 at 2σ, 36 at 2.5σ.
pub const RIM_GAP_SIGMAS: f64 = 2.5;
/// Face points this far beyond the registered contour, mm, count as flash (see
/// [`ScannedEdge::flash_share`]): twice the tolerance, beyond what a registration that passes
/// the check leaves.
pub const EDGE_FLASH_MM: f64 = 0.06;
/// See [`ScannedEdge::flash_share`].
pub const EDGE_FLASH_SHARE: f64 = 0.02;
/// Arcs a closed rim's fitted edge is reported in (see [`rim_edges`]), at least.
pub const RIM_STRETCHES: usize = 8;
/// Length of those arcs on a larger rim, mm.
pub const RIM_ARC_MM: f64 = 1.2;
/// Longest closed contour read as a rim, mm: a hole. Outside tune seeds 2041 and 2069 read
/// slots of 52–65 mm slid 90–140 µm along their axes, from their end caps alone, where the truth
/// was within 1 µm; own seed 5 read its 83 mm outline loop the same way. A slot's slide along
/// its axis shows only at its caps, whose few points the step model misreads.
pub const RIM_MAX_LENGTH_MM: f64 = 15.0;
/// Fewest face points that fit a rim's edge (three unknowns over the whole rim). First chosen
/// on the outside generator's tune seeds 2001–2036: rims of 40–80 face points read false gaps
/// over the tolerance on 26 of 379 correctly registered rims (a dropout near the rim reads as
/// the edge receding there, and so few points cannot tell), those of 80–120 on none of 35 (the
/// widest 21 µm at 96 points). Raised from 100 on the project's own cores, seeds 600–639 of
/// DESIGN.md's sweep (200k points, 1–4 views): rims of 100–149 face points read false gaps of
/// 39 and 47 µm on 2 of 147 correctly registered rims, each refusing a good one-view part (an
/// arc of a 1.2 mm hole with no face point within 80 µm of the rim happens by chance at that
/// density), those of 150–249 on none of 128 (the widest 18.6 µm).
pub const RIM_MIN_FACE_POINTS: usize = 150;
/// Face points this far inside a rim's opening, mm, are a film over it (a blockage, which the
/// rim's step model does not describe) where more than [`EDGE_FLASH_SHARE`] of them stand there.
/// A hole slid this far is not read either (nor is a fit that finds a slide over 0.2 mm): the
/// strips' scanned edges and the opening check are left to judge the part.
pub const RIM_FILM_MM: f64 = 0.15;
/// The scan noise is taken as at least this, mm (a face fitted closer than this is a face the
/// scanner saw from one side; the step model needs a blur).
pub const EDGE_MIN_NOISE_MM: f64 = 0.002;

/// How one stretch's edge was located.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EdgeFrom {
    /// From the wall below the edge.
    Wall,
    /// From where the face points end.
    Face,
}

/// One stretch's scanned edge, relative to the registered contour.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScannedEdge {
    /// Arc length of the stretch's middle from the contour's first point, mm.
    pub at_mm: f64,
    /// Where the scan shows the edge, across the contour in the face, mm: negative when the
    /// registered contour lies beyond the material, positive when material (or a burr) stands
    /// beyond it.
    pub offset_mm: f64,
    /// The offset's standard deviation, mm.
    pub sigma_mm: f64,
    /// Scan points that located it.
    pub points: usize,
    /// How.
    pub from: EdgeFrom,
    /// The stretch's first and last contour points.
    pub first: usize,
    /// See `first`.
    pub last: usize,
    /// The share of the stretch's face points standing more than [`EDGE_FLASH_MM`] beyond the
    /// registered contour: flash (a burr web in the face's plane) where it is more than
    /// [`EDGE_FLASH_SHARE`], since no registration error this check can pass leaves that much
    /// face out there.
    pub flash_share: f64,
    /// `+1` when the offset is measured along `t × f` (tangent, feature vector), `−1` when
    /// against it: the side away from the material.
    pub outward: f64,
    /// The confidence its gap is taken at, standard deviations: [`EDGE_GAP_SIGMAS`] for a
    /// strip's stretch, `RIM_GAP_SIGMAS` for a rim's arc.
    pub gap_sigmas: f64,
    /// For a rim's arc, the part of the offset that is the rim's change of size (`c` of
    /// [`rim_edges`], the same on every arc; negative: the scan reads the opening larger than
    /// the registered rim); 0 for a strip's stretch. The rest, `offset_mm − size_mm`, is the
    /// rim's slide.
    pub size_mm: f64,
    /// The standard deviation of the slide's part, `offset_mm − size_mm`, mm: `sigma_mm` for a
    /// strip's stretch.
    pub slide_sigma_mm: f64,
}

impl ScannedEdge {
    /// How far the registered contour lies beyond the scanned material at
    /// [`ScannedEdge::gap_sigmas`] confidence, mm (negative: no gap shown).
    #[must_use]
    pub fn gap_mm(&self) -> f64 {
        -self.offset_mm - self.gap_sigmas * self.sigma_mm
    }

    /// The part of [`ScannedEdge::gap_mm`] a misregistration can make, mm. For a strip's
    /// stretch it is the gap. For the arc of a rim that the scan reads larger than the
    /// registered one all round (`size_mm < 0`: points lost at its edge, or the part's own
    /// hole), it is the gap its slide alone shows, at the slide's own deviation, where that is
    /// narrower than the gap: the field cannot resize a hole, so that size says nothing about
    /// where the part lies (outside fresh part 8188 at 500k: a lower hole rim 4 µm off read
    /// 35 µm larger than registered and 48 µm slid, a gap of 42 µm; its slide's alone is under
    /// the tolerance). A rim read
    /// smaller keeps its whole gap: material beyond a rim may be a burr, which proves nothing
    /// (a web on one side of a hole fits as a smaller rim slid toward it, and the slide alone
    /// would read a gap on the other side).
    #[must_use]
    pub fn slide_gap_mm(&self) -> f64 {
        let gap = self.gap_mm();
        if self.size_mm < 0.0 {
            gap.min(-(self.offset_mm - self.size_mm) - self.gap_sigmas * self.slide_sigma_mm)
        } else {
            gap
        }
    }

    /// Whether the stretch's face runs on beyond the contour ([`ScannedEdge::flash_share`] over
    /// `EDGE_FLASH_SHARE`): a burr web, which neither moves the field nor flags the strip.
    #[must_use]
    pub fn is_flash(&self) -> bool {
        self.flash_share > EDGE_FLASH_SHARE
    }

    /// Whether it shows more material beyond the contour than
    /// [`super::quality::MATERIAL_BEYOND_MM`], flash aside: a low burr or the part lying out
    /// there. Such a reading flags its strip (`material_beyond`) and, instead of moving the
    /// field, widens its posterior (`edge_terms`); every other reading that is not flash may
    /// move the field.
    #[must_use]
    pub fn shows_material_beyond(&self) -> bool {
        !self.is_flash() && self.offset_mm > super::quality::MATERIAL_BEYOND_MM
    }
}

/// The widest gap over `edges`, µm ([`ScannedEdge::gap_mm`]); `None` without readings.
#[must_use]
pub fn widest_gap_um(edges: &[ScannedEdge]) -> Option<f64> {
    widest_um(edges, ScannedEdge::gap_mm, None)
}

/// The widest of `gap` over `edges` and of `before`, µm; `None` without either.
fn widest_um(
    edges: &[ScannedEdge],
    gap: impl Fn(&ScannedEdge) -> f64,
    before: Option<f64>,
) -> Option<f64> {
    edges
        .iter()
        .map(|e| 1e3 * gap(e))
        .chain(before)
        .reduce(f64::max)
}

/// The readings that may move the field (`edge_terms`) and whose gap before the update counts:
/// a strip's [`scanned_edges`], none of a rim's. The terms' floors were measured on strips, so a
/// rim checks the registration but does not move it, and its reading after the update is an
/// independent check (own seed 5's outline loop read a 130 µm slide before the strips' terms
/// and none after, with the part within 1 µm).
pub(crate) fn strip_edges(contour: &Contour, scan: &[Point3], tree: &KdTree) -> Vec<ScannedEdge> {
    if super::quality::is_open(contour.points()) {
        scanned_edges(contour, scan, tree)
    } else {
        Vec::new()
    }
}

/// A contour's scanned-edge gap, µm: the widest of its readings after the edge terms and of
/// its strip readings before them (`before`, [`widest_gap_um`] of [`strip_edges`]). A part the
/// terms correct from one end only (a reading of material beyond the contour is left out as
/// possible flash) shows its gap there before and no longer after, so both count; `register`
/// passes no `before` unless the terms left a reading out for the material beyond it
/// (`EdgeTermSummary::gaps_before`).
pub(crate) fn contour_gap_um(after: &[ScannedEdge], before: Option<f64>) -> Option<f64> {
    widest_um(after, ScannedEdge::gap_mm, before)
}

/// The same over the slides' gaps ([`ScannedEdge::slide_gap_mm`]): what puts the part in
/// doubt. `before` is a strip's, whose slide gap is its gap.
pub(crate) fn contour_slide_gap_um(after: &[ScannedEdge], before: Option<f64>) -> Option<f64> {
    widest_um(after, ScannedEdge::slide_gap_mm, before)
}

/// The scanned edges of every stretch of `contour` (scan frame, with its per-point feature
/// vectors), from the scan points `scan` indexed by `tree`. Stretches the scan does not show
/// well enough are left out.
pub fn scanned_edges(contour: &Contour, scan: &[Point3], tree: &KdTree) -> Vec<ScannedEdge> {
    let p = contour.points();
    let n = p.len();
    if n < 2 {
        return Vec::new();
    }
    // Arc length, tangents and the across-edge direction at every point.
    let mut s = vec![0.0; n];
    for i in 1..n {
        s[i] = s[i - 1] + (p[i] - p[i - 1]).norm();
    }
    let length = s[n - 1];
    if length.is_nan() || length <= 0.0 {
        return Vec::new();
    }
    let frames: Vec<Option<(Vector3, Vector3, Vector3, f64)>> = (0..n)
        .map(|i| {
            // Central differences, one-sided at the ends.
            let end = i == 0 || i == n - 1;
            let (a, b) = match i {
                0 => (p[0], p[1]),
                i if end => (p[i - 1], p[i]),
                i => (p[i - 1], p[i + 1]),
            };
            let t = trim_geom::math::unit_or_none(&(b - a), 1e-9)?;
            let f = contour.features()[i];
            let across = trim_geom::math::unit_or_none(&t.cross(&f), 1e-9)?;
            let normal = across.cross(&t);
            // Half the local spacing: the slice of scan points this point answers for.
            let half = (b - a).norm() * if end { 0.5 } else { 0.25 };
            Some((t, normal, across, half))
        })
        .collect();
    let open = super::quality::is_open(p);
    if !open && length > RIM_MAX_LENGTH_MM {
        return Vec::new();
    }
    let stretches = if open {
        ((length / EDGE_STRETCH_MM).round() as usize).max(1)
    } else {
        ((length / RIM_ARC_MM).round() as usize).max(RIM_STRETCHES)
    };
    let stretch_of = |i: usize| (((s[i] / length) * stretches as f64) as usize).min(stretches - 1);

    // The scan points near the contour, each with the contour point it lies beside.
    let contour_tree = KdTree::build(p);
    let reach = EDGE_WINDOW_MM + 0.05;
    // `(contour point, height above the face, offset across the edge)`.
    let mut near: Vec<(usize, f64, f64)> = Vec::new();
    let mut seen = std::collections::HashSet::new();
    let mut scratch = Scratch::default();
    let mut last = f64::NEG_INFINITY;
    for i in 0..n {
        if s[i] - last < 0.5 * EDGE_WINDOW_MM && i != n - 1 {
            continue;
        }
        last = s[i];
        let found: Vec<usize> = tree
            .within(&p[i], reach * reach, &mut scratch)
            .iter()
            .map(|nb| nb.index)
            .collect();
        for j in found {
            if !seen.insert(j) {
                continue;
            }
            let q = scan[j];
            let Some(k) = contour_tree.nearest_within(&q, f64::INFINITY) else {
                continue;
            };
            let k = k.index;
            if k < 3 || k + 3 >= n {
                continue;
            }
            let Some((t, normal, across, half)) = frames[k] else {
                continue;
            };
            let d = q - p[k];
            if d.dot(&t).abs() > half + 1e-9 {
                continue;
            }
            let (h, b) = (d.dot(&normal), d.dot(&across));
            if b.abs() < EDGE_WINDOW_MM {
                near.push((k, h, b));
            }
        }
    }
    let mut bounds = vec![(usize::MAX, 0); stretches];
    for i in 0..n {
        let b = &mut bounds[stretch_of(i)];
        *b = (b.0.min(i), b.1.max(i));
    }
    if !open {
        let across: Vec<Option<Vector3>> = frames.iter().map(|f| f.map(|f| f.2)).collect();
        return rim_edges(contour, &across, &s, &near, &bounds);
    }
    let mut by_stretch: Vec<Vec<(f64, f64)>> = vec![Vec::new(); stretches];
    for &(k, h, b) in &near {
        by_stretch[stretch_of(k)].push((h, b));
    }
    by_stretch
        .into_par_iter()
        .zip(bounds)
        .enumerate()
        .filter_map(|(j, (readings, (first, last)))| {
            let at_mm = (j as f64 + 0.5) * length / stretches as f64;
            locate(&readings).map(|l| ScannedEdge {
                at_mm,
                offset_mm: l.offset_mm,
                sigma_mm: l.sigma_mm,
                points: l.points,
                from: l.from,
                first,
                last,
                flash_share: l.flash_share,
                outward: l.outward,
                gap_sigmas: EDGE_GAP_SIGMAS,
                size_mm: 0.0,
                slide_sigma_mm: l.sigma_mm,
            })
        })
        .collect()
}

/// The edge from one stretch's readings `(height above the face, offset across the edge)`:
/// One stretch's edge as [`locate`] finds it (see [`ScannedEdge`]).
struct Located {
    offset_mm: f64,
    sigma_mm: f64,
    points: usize,
    from: EdgeFrom,
    flash_share: f64,
    outward: f64,
}

/// See [`Located`]; `None` when too few points show the edge.
fn locate(readings: &[(f64, f64)]) -> Option<Located> {
    // The noise from the face's spread about its median height (within 50 µm of it).
    let (mid, sigma) = face_level(readings.iter().map(|r| r.0), EDGE_MIN_FACE_POINTS)?;
    let face: Vec<f64> = readings
        .iter()
        .filter(|r| (r.0 - mid).abs() < 3.0 * sigma)
        .map(|r| r.1)
        .collect();
    // Turn the frame so that the face lies at b < 0.
    let sign = material_sign(face.iter().copied());
    let wall: Vec<(f64, f64)> = readings
        .iter()
        .map(|&(h, b)| (h - mid, sign * b))
        .filter(|&(h, b)| {
            h < -3.0 * sigma && h > -EDGE_WALL_DEPTH_MM && b.abs() < EDGE_WALL_REACH_MM
        })
        .collect();
    let face: Vec<f64> = face.into_iter().map(|b| sign * b).collect();
    let flash_share =
        face.iter().filter(|&&b| b > EDGE_FLASH_MM).count() as f64 / face.len().max(1) as f64;
    let located = |(offset_mm, sigma_mm, points, from)| Located {
        offset_mm,
        sigma_mm,
        points,
        from,
        flash_share,
        outward: sign,
    };
    if wall.len() >= EDGE_MIN_WALL_POINTS {
        return wall_edge(&wall, sigma).map(|(e, sd, k)| located((e, sd, k, EdgeFrom::Wall)));
    }
    if face.len() < EDGE_MIN_FACE_POINTS {
        return None;
    }
    let (e, sd) = face_edge(&face, sigma)?;
    Some(located((e, sd, face.len(), EdgeFrom::Face)))
}

/// The face's height (the median of the heights within 50 µm of the contour) and the scan noise
/// (1.4826 × their MAD, at least [`EDGE_MIN_NOISE_MM`]); `None` with fewer than `least` heights.
fn face_level(heights: impl Iterator<Item = f64>, least: usize) -> Option<(f64, f64)> {
    let mut heights: Vec<f64> = heights.filter(|h| h.abs() < 0.05).collect();
    if heights.len() < least {
        return None;
    }
    let mid = median(&mut heights);
    let mut dev: Vec<f64> = heights.iter().map(|h| (h - mid).abs()).collect();
    Some((mid, (1.4826 * median(&mut dev)).max(EDGE_MIN_NOISE_MM)))
}

/// `−1` when most of the face offsets `b` are positive, else `+1`: the sign that turns the
/// frame so that the face (the material) lies at `b < 0`.
fn material_sign(b: impl Iterator<Item = f64>) -> f64 {
    let (above, below) = b.fold((0, 0), |(a, n), b| {
        (a + usize::from(b > 0.0), n + usize::from(b < 0.0))
    });
    if above > below { -1.0 } else { 1.0 }
}

/// The negative log-likelihood of a face point at `b` across the edge for an edge at `e`: a
/// uniform density over `b < e` within ±[`EDGE_WINDOW_MM`], blurred by `sigma`, with a share
/// [`EDGE_OUTLIER_SHARE`] of outliers.
fn step_nll(e: f64, b: f64, sigma: f64) -> f64 {
    let w = EDGE_WINDOW_MM;
    let eps = EDGE_OUTLIER_SHARE;
    // ∫_{−w}^{w} Φ((e − x)/σ) dx: `e + w` to within `σ·φ(8)` (10⁻¹⁵ σ) where the edge lies
    // 8σ inside the window, which saves three of the four special functions of a point.
    let z = if w - e.abs() > 8.0 * sigma {
        e + w
    } else {
        sigma * (normal_cdf_integral((e + w) / sigma) - normal_cdf_integral((e - w) / sigma))
    };
    -((1.0 - eps) * normal_cdf((e - b) / sigma) / z + eps / (2.0 * w)).ln()
}

/// A closed rim's scanned edge. A hole or slot slid by `δ` shows `δ` beyond the material on
/// one side and inside it on the other, which one offset per stretch averages away, and a
/// rim's face points are too few to read it arc by arc (the outside scans: 40–100 over
/// a hole). So the edge at rim point `k` is modelled as `e_k = c + δ·u_k` over the whole
/// rim (`u_k` its outward direction, away from the material; `δ` in the rim's mean plane; `c`
/// a change of size), fitted by maximum likelihood on the step model of [`face_edge`], and
/// reported as [`RIM_STRETCHES`] or more arcs, each read at its middle point with the
/// deviation of `e` there from the fit's curvature. A slot slid along its axis shows the slide
/// at its ends' arcs, but only there, and those few points misread it: rims longer than
/// [`RIM_MAX_LENGTH_MM`] are not read. The widest gap over the arcs' middles is short of the
/// model's widest by at most `|δ|(1 − cos(π/arcs))`. Each arc carries `c` as its
/// [`ScannedEdge::size_mm`] and the deviation of `δ·u` alone as its `slide_sigma_mm`.
fn rim_edges(
    contour: &Contour,
    across: &[Option<Vector3>],
    s: &[f64],
    near: &[(usize, f64, f64)],
    arcs: &[(usize, usize)],
) -> Vec<ScannedEdge> {
    let Some(fit) = fit_rim(contour, across, near) else {
        return Vec::new();
    };
    arcs.iter()
        .filter(|(first, last)| first <= last)
        .filter_map(|&(first, last)| {
            let m = (first + last) / 2;
            let v = fit.row(across[m]?);
            let offset_mm = v.dot(&fit.theta);
            let var = (v.transpose() * fit.cov * v)[(0, 0)];
            let slide = nalgebra::Vector3::new(0.0, v[1], v[2]);
            let slide_var = (slide.transpose() * fit.cov * slide)[(0, 0)];
            (offset_mm.is_finite() && var > 0.0 && slide_var >= 0.0).then(|| ScannedEdge {
                at_mm: s[m],
                offset_mm,
                sigma_mm: var.sqrt(),
                points: fit.points,
                from: EdgeFrom::Face,
                first,
                last,
                flash_share: fit.flash_share,
                outward: fit.sign,
                gap_sigmas: RIM_GAP_SIGMAS,
                size_mm: fit.theta[0],
                slide_sigma_mm: slide_var.sqrt(),
            })
        })
        .collect()
}

/// The rim's fit `θ = (c, δ₁, δ₂)` (see [`rim_edges`]) and its covariance.
struct RimFit {
    theta: nalgebra::Vector3<f64>,
    cov: nalgebra::Matrix3<f64>,
    /// The rim plane's basis.
    e1: Vector3,
    e2: Vector3,
    sign: f64,
    points: usize,
    flash_share: f64,
}

impl RimFit {
    /// The row of `e` at a rim point whose across direction is `across`.
    fn row(&self, across: Vector3) -> nalgebra::Vector3<f64> {
        let u = across * self.sign;
        nalgebra::Vector3::new(1.0, u.dot(&self.e1), u.dot(&self.e2))
    }
}

/// The rim's edge from its scan points `near` (see [`rim_edges`]); `None` when too few, under a
/// film, or not fitted within the window.
fn fit_rim(
    contour: &Contour,
    across: &[Option<Vector3>],
    near: &[(usize, f64, f64)],
) -> Option<RimFit> {
    let (mid, sigma) = face_level(near.iter().map(|r| r.1), RIM_MIN_FACE_POINTS)?;
    let face: Vec<(usize, f64)> = near
        .iter()
        .filter(|r| (r.1 - mid).abs() < 3.0 * sigma)
        .map(|r| (r.0, r.2))
        .collect();
    if face.len() < RIM_MIN_FACE_POINTS {
        return None;
    }
    let sign = material_sign(face.iter().map(|f| f.1));
    let film = face.iter().filter(|f| sign * f.1 > RIM_FILM_MM).count() as f64;
    let flash_share = film / face.len() as f64;
    if flash_share > EDGE_FLASH_SHARE {
        return None;
    }
    let mean_f = contour
        .features()
        .iter()
        .fold(Vector3::zeros(), |a, f| a + f)
        .try_normalize(1e-9)?;
    let (e1, e2) = trim_geom::math::tangent_basis(&mean_f);
    let mut fit = RimFit {
        theta: nalgebra::Vector3::zeros(),
        cov: nalgebra::Matrix3::zeros(),
        e1,
        e2,
        sign,
        points: face.len(),
        flash_share,
    };
    let data: Vec<(nalgebra::Vector3<f64>, f64)> = face
        .iter()
        .filter_map(|&(k, b)| Some((fit.row(across[k]?), sign * b)))
        .collect();
    let nll = |t: &nalgebra::Vector3<f64>| -> f64 {
        data.iter()
            .map(|(v, b)| step_nll(v.dot(t), *b, sigma))
            .sum()
    };
    // Gradient and Gauss-Newton-like Hessian from each point's derivatives along `e`.
    let h = 3e-4;
    let derivatives = |t: &nalgebra::Vector3<f64>| {
        let mut g = nalgebra::Vector3::zeros();
        let mut hess = nalgebra::Matrix3::zeros();
        for (v, b) in &data {
            let e = v.dot(t);
            let (lo, at, hi) = (
                step_nll(e - h, *b, sigma),
                step_nll(e, *b, sigma),
                step_nll(e + h, *b, sigma),
            );
            g += v * ((hi - lo) / (2.0 * h));
            hess += v * v.transpose() * ((hi - 2.0 * at + lo) / (h * h));
        }
        (g, hess)
    };
    // Start from the best common offset (to 10⁻⁴ µm: 30 golden steps over ±0.24 mm), then
    // damped Newton steps on all three.
    let w = EDGE_WINDOW_MM;
    fit.theta[0] = golden_section_min(
        |c| nll(&nalgebra::Vector3::new(c, 0.0, 0.0)),
        -0.6 * w,
        0.6 * w,
        30,
    );
    let mut f = nll(&fit.theta);
    let mut lambda = 1e-3;
    for _ in 0..50 {
        let (g, hess) = derivatives(&fit.theta);
        let damped = hess
            + nalgebra::Matrix3::from_diagonal(&hess.diagonal().map(|d| lambda * d.abs().max(1.0)));
        let Some(step) = damped.cholesky().map(|c| -c.solve(&g)) else {
            lambda *= 10.0;
            continue;
        };
        let next = fit.theta + step;
        let f_next = nll(&next);
        if f_next < f {
            fit.theta = next;
            f = f_next;
            lambda = (lambda / 3.0).max(1e-9);
            // 0.1 µm: well under the readings' deviations.
            if step.norm() < 1e-4 {
                break;
            }
        } else {
            lambda *= 4.0;
            if lambda > 1e9 {
                break;
            }
        }
    }
    let (_, hess) = derivatives(&fit.theta);
    fit.cov = hess.cholesky()?.inverse();
    let slide = fit.theta.fixed_rows::<2>(1).norm();
    (fit.theta[0].abs() < 0.59 * w && slide < 0.5 * w).then_some(fit)
}

/// The wall's line `b = c₀ + c₁·h`, fitted twice (the second time without points beyond 3
/// robust deviations): the edge is `c₀`, where it meets the face. `(c₀, σ, points kept)`.
fn wall_edge(wall: &[(f64, f64)], sigma: f64) -> Option<(f64, f64, usize)> {
    let fit = |pts: &[(f64, f64)]| -> Option<(f64, f64)> {
        let k = pts.len() as f64;
        let (sh, sb) = pts.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
        let (mh, mb) = (sh / k, sb / k);
        let (shh, shb) = pts.iter().fold((0.0, 0.0), |a, p| {
            (a.0 + (p.0 - mh) * (p.0 - mh), a.1 + (p.0 - mh) * (p.1 - mb))
        });
        if shh.is_nan() || shh <= 1e-12 {
            return None;
        }
        let c1 = shb / shh;
        Some((mb - c1 * mh, c1))
    };
    let (c0, c1) = fit(wall)?;
    let mut res: Vec<f64> = wall.iter().map(|p| p.1 - c0 - c1 * p.0).collect();
    let mut dev: Vec<f64> = res.iter().map(|r| r.abs()).collect();
    let spread = 1.4826 * median(&mut dev);
    let cut = 3.0 * spread.max(sigma);
    let kept: Vec<(f64, f64)> = wall
        .iter()
        .zip(&mut res)
        .filter(|(_, r)| r.abs() < cut)
        .map(|(p, _)| *p)
        .collect();
    if kept.len() < EDGE_MIN_WALL_POINTS {
        return None;
    }
    let (c0, _) = fit(&kept)?;
    // The intercept's spread, doubled for the line's slope and the noise along the wall.
    let sd = 2.0 * spread.max(0.5 * sigma) / (kept.len() as f64).sqrt();
    Some((c0, sd, kept.len()))
}

/// The maximum-likelihood end `e` of the face points `b` (face at `b < e`) and its standard
/// deviation from the likelihood's curvature.
fn face_edge(b: &[f64], sigma: f64) -> Option<(f64, f64)> {
    let w = EDGE_WINDOW_MM;
    let nll = |e: f64| -> f64 { b.iter().map(|&x| step_nll(e, x, sigma)).sum() };
    let e = golden_section_min(nll, -0.6 * w, 0.6 * w, 60);
    let h = 3e-4;
    let curvature = (nll(e + h) - 2.0 * nll(e) + nll(e - h)) / (h * h);
    (curvature > 0.0 && e.abs() < 0.59 * w).then(|| (e, 1.0 / curvature.sqrt()))
}

/// The median of `v` (reordered), or 0 when empty.
fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let m = v.len() / 2;
    *v.select_nth_unstable_by(m, f64::total_cmp).1
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// A contour along x over `length` mm at y = 0 on the face z = 0 (feature +z), and scan
    /// points of that face over `y < edge` (material on −y) at `density` per mm², with noise
    /// `sigma` along z and y; with `wall`, also the wall below the edge down to 0.5 mm.
    fn case(edge: f64, sigma: f64, density: f64, wall: bool, seed: u64) -> (Contour, Vec<Point3>) {
        let length = 12.0;
        let points: Vec<Point3> = (0..=240)
            .map(|i| Point3::new(length * i as f64 / 240.0, 0.0, 0.0))
            .collect();
        let contour = Contour::new(7, points, Vector3::z()).unwrap();
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let noise = Normal::new(0.0, sigma).unwrap();
        let mut scan = Vec::new();
        let face_area = length * 2.0;
        for _ in 0..(density * face_area) as usize {
            let x = rng.random_range(0.0..length);
            let y = rng.random_range(edge - 2.0..edge);
            scan.push(Point3::new(
                x,
                y + noise.sample(&mut rng),
                noise.sample(&mut rng),
            ));
        }
        if wall {
            for _ in 0..(density * length * 0.5) as usize {
                let x = rng.random_range(0.0..length);
                let z = rng.random_range(-0.5..0.0);
                scan.push(Point3::new(x, edge + noise.sample(&mut rng), z));
            }
        }
        (contour, scan)
    }

    fn edges(contour: &Contour, scan: &[Point3]) -> Vec<ScannedEdge> {
        scanned_edges(contour, scan, &KdTree::build(scan))
    }

    #[test]
    fn the_face_locates_an_edge_inside_the_registered_contour() {
        // The scan's face ends 50 µm short of the registered contour: a 50 µm gap, measured to
        // within a few µm, and over the 30 µm tolerance at 2σ.
        for seed in 0..5 {
            let (contour, scan) = case(-0.05, 0.010, 60.0, false, seed);
            let found = edges(&contour, &scan);
            assert_eq!(found.len(), 1, "one stretch for a 12 mm contour");
            let e = found[0];
            assert_eq!(e.from, EdgeFrom::Face);
            assert!(
                (e.offset_mm + 0.05).abs() < 0.008,
                "offset {} mm",
                e.offset_mm
            );
            assert!(
                e.sigma_mm > 0.0005 && e.sigma_mm < 0.006,
                "σ {} mm",
                e.sigma_mm
            );
            assert!(e.gap_mm() > 0.030, "gap {} mm", e.gap_mm());
        }
    }

    #[test]
    fn a_contour_on_the_edge_shows_no_gap() {
        // Over 20 scans of a contour placed on the edge: each offset within 3.5 of its own σ,
        // their mean within 4 µm of zero, and no gap near the tolerance.
        let mut sum = 0.0;
        for seed in 0..20 {
            let (contour, scan) = case(0.0, 0.012, 40.0, false, seed);
            let e = edges(&contour, &scan)[0];
            assert!(e.offset_mm.abs() < 3.5 * e.sigma_mm, "seed {seed}: {e:?}");
            assert!(e.gap_mm() < 0.015, "seed {seed}: gap {} mm", e.gap_mm());
            sum += e.offset_mm;
        }
        assert!((sum / 20.0).abs() < 0.004, "mean offset {} mm", sum / 20.0);
    }

    #[test]
    fn the_wall_locates_the_edge_when_the_scanner_saw_it() {
        let (contour, scan) = case(-0.04, 0.008, 60.0, true, 3);
        let e = edges(&contour, &scan)[0];
        assert_eq!(e.from, EdgeFrom::Wall);
        assert!(
            (e.offset_mm + 0.04).abs() < 0.005,
            "offset {} mm",
            e.offset_mm
        );
        assert!(e.gap_mm() > 0.030, "gap {} mm", e.gap_mm());
    }

    #[test]
    fn a_burr_beyond_the_edge_is_no_gap() {
        // Flash in the face's plane standing 0.3 mm off the edge along the whole contour: the
        // face appears to extend beyond the registered contour, which proves nothing about the
        // registration (the gap is negative: no refusal).
        let (contour, mut scan) = case(0.0, 0.010, 60.0, false, 4);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
        for _ in 0..(60.0 * 12.0 * 0.3) as usize {
            let x = rng.random_range(0.0..12.0);
            let y = rng.random_range(0.0..0.3);
            scan.push(Point3::new(x, y, 0.0));
        }
        let e = edges(&contour, &scan)[0];
        assert!(e.offset_mm > 0.1, "offset {} mm", e.offset_mm);
        assert!(e.gap_mm() < 0.0, "gap {} mm", e.gap_mm());
    }

    /// A plate (z = 0) with a hole of radius 1.5 mm centred at `centre` in x, scanned at
    /// `density` per mm² with noise `sigma`, and the registered rim: the hole's circle about
    /// the origin (feature vector +z).
    fn holed_plate(centre: f64, sigma: f64, density: f64, seed: u64) -> (Contour, Vec<Point3>) {
        holed_plate_grown(centre, 0.0, sigma, density, seed)
    }

    /// [`holed_plate`] with the scan's hole `grown` mm wider in radius than the rim.
    fn holed_plate_grown(
        centre: f64,
        grown: f64,
        sigma: f64,
        density: f64,
        seed: u64,
    ) -> (Contour, Vec<Point3>) {
        let r = 1.5;
        let rim: Vec<Point3> = (0..=300)
            .map(|i| {
                let a = std::f64::consts::TAU * i as f64 / 300.0;
                Point3::new(r * a.cos(), r * a.sin(), 0.0)
            })
            .collect();
        let rim = Contour::new(1, rim, Vector3::z()).unwrap();
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let noise = Normal::new(0.0, sigma).unwrap();
        let mut scan = Vec::new();
        for _ in 0..(density * 36.0) as usize {
            let (x, y) = (rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0));
            if (x - centre).hypot(y) < r + grown {
                continue;
            }
            scan.push(Point3::new(
                x + noise.sample(&mut rng),
                y,
                noise.sample(&mut rng),
            ));
        }
        (rim, scan)
    }

    #[test]
    fn a_rim_is_read_in_arcs_and_a_slid_hole_shows_a_gap() {
        // In place: eight arcs, each offset within 3.5 of its σ, their mean within 5 µm (the
        // face beside a hole widens away from the rim, which reads the edge a few µm back),
        // and no gap near the tolerance.
        let mut sum = 0.0;
        for seed in 0..5 {
            let (rim, scan) = holed_plate(0.0, 0.010, 150.0, seed);
            let found = edges(&rim, &scan);
            assert_eq!(found.len(), RIM_STRETCHES, "seed {seed}: {found:?}");
            for e in &found {
                assert_eq!(e.from, EdgeFrom::Face);
                // A rim's gap is taken at 2.5σ, a strip's at 2σ (below).
                assert_eq!(e.gap_sigmas, RIM_GAP_SIGMAS);
                let gap = -e.offset_mm - RIM_GAP_SIGMAS * e.sigma_mm;
                assert!((e.gap_mm() - gap).abs() < 1e-15, "seed {seed}: {e:?}");
                // The slide's gap leaves out a size read larger than the rim, not smaller.
                let slide = if e.size_mm < 0.0 {
                    gap.min(-(e.offset_mm - e.size_mm) - RIM_GAP_SIGMAS * e.slide_sigma_mm)
                } else {
                    gap
                };
                assert!(
                    (e.slide_gap_mm() - slide).abs() < 1e-15,
                    "seed {seed}: {e:?}"
                );
                assert!(e.offset_mm.abs() < 3.5 * e.sigma_mm, "seed {seed}: {e:?}");
                assert!(e.gap_mm() < 0.020, "seed {seed}: {e:?}");
                sum += e.offset_mm;
            }
        }
        let mean = sum / (5 * RIM_STRETCHES) as f64;
        assert!(mean.abs() < 0.005, "mean offset {mean} mm");
        // The real hole 60 µm along +x of the registered rim (the arcs' ends at 0° and 45°:
        // the slide toward an arc's end, the least favourable): the arcs facing −x lie beyond
        // the material by 0.7–1 of the slide, a gap over the 30 µm tolerance; those facing +x
        // show material beyond them by as much.
        for seed in 0..5 {
            let (rim, scan) = holed_plate(0.060, 0.010, 150.0, seed);
            let found = edges(&rim, &scan);
            assert_eq!(found.len(), RIM_STRETCHES, "seed {seed}: {found:?}");
            let widest = found.iter().map(|e| e.gap_mm()).fold(f64::MIN, f64::max);
            let deepest = found.iter().map(|e| e.offset_mm).fold(f64::MAX, f64::min);
            let highest = found.iter().map(|e| e.offset_mm).fold(f64::MIN, f64::max);
            assert!(
                widest > 0.030,
                "seed {seed}: widest gap {widest} mm: {found:?}"
            );
            assert!(
                (-0.075..=-0.042).contains(&deepest),
                "seed {seed}: deepest {deepest} mm"
            );
            assert!(
                (0.042..=0.072).contains(&highest),
                "seed {seed}: highest {highest} mm"
            );
        }
    }

    #[test]
    fn a_rim_moves_no_field_and_a_strips_gap_before_the_update_counts() {
        // A slid hole's rim shows its gap when checked, but gives the edge terms nothing: its
        // gap before the update cannot put the part in doubt.
        let (rim, scan) = holed_plate(0.060, 0.010, 150.0, 0);
        let tree = KdTree::build(&scan);
        assert!(widest_gap_um(&scanned_edges(&rim, &scan, &tree)).is_some_and(|g| g > 30.0));
        assert!(strip_edges(&rim, &scan, &tree).is_empty());
        // A strip 50 µm beyond the material gives the terms its reading; once they have moved
        // the field onto the edge it reads in place, and its gap before still counts.
        let (strip, scan) = case(-0.05, 0.010, 60.0, false, 0);
        let tree = KdTree::build(&scan);
        let readings = strip_edges(&strip, &scan, &tree);
        assert!(readings.iter().all(|e| e.gap_sigmas == EDGE_GAP_SIGMAS));
        let before = widest_gap_um(&readings);
        assert!(before.is_some_and(|g| g > 30.0), "{before:?}");
        let (_, moved) = case(0.0, 0.010, 60.0, false, 0);
        let after = edges(&strip, &moved);
        assert!(widest_gap_um(&after).is_some_and(|g| g < 30.0), "{after:?}");
        assert_eq!(contour_gap_um(&after, before), before);
        assert_eq!(contour_gap_um(&after, None), widest_gap_um(&after));
        assert_eq!(contour_gap_um(&[], None), None);
    }

    #[test]
    fn a_rim_read_larger_all_round_shows_its_size_and_no_slide() {
        // The scan's hole 60 µm wider in radius than the rim (its points lost at the edge, or
        // the part's own hole): every arc reads the rim beyond the material, by its size; the
        // slide alone shows no gap. Slid 100 µm as well, the slide shows on the side it left.
        // Read smaller (60 µm less in radius: material beyond the rim all round, as a burr
        // ring would show), the slide's gap is the whole gap: none.
        for seed in 0..5 {
            let (rim, scan) = holed_plate_grown(0.0, -0.060, 0.010, 150.0, seed);
            let found = edges(&rim, &scan);
            assert_eq!(found.len(), RIM_STRETCHES, "seed {seed}");
            for e in &found {
                assert!(e.size_mm > 0.045, "seed {seed}: size {} mm", e.size_mm);
                assert_eq!(e.slide_gap_mm(), e.gap_mm());
                assert!(e.gap_mm() < 0.0, "seed {seed}: {e:?}");
            }
        }
        for seed in 0..5 {
            let (rim, scan) = holed_plate_grown(0.0, 0.060, 0.010, 150.0, seed);
            let found = edges(&rim, &scan);
            assert_eq!(found.len(), RIM_STRETCHES, "seed {seed}");
            for e in &found {
                assert!(
                    (e.size_mm + 0.060).abs() < 0.015,
                    "seed {seed}: size {} mm",
                    e.size_mm
                );
                assert!(e.gap_mm() > 0.030, "seed {seed}: gap {} mm", e.gap_mm());
                assert!(
                    e.slide_gap_mm() < 0.015,
                    "seed {seed}: slide gap {} mm: {e:?}",
                    e.slide_gap_mm()
                );
                assert!(e.slide_sigma_mm > 0.0 && e.slide_sigma_mm <= e.sigma_mm + 1e-12);
            }
            let (rim, scan) = holed_plate_grown(0.100, 0.060, 0.010, 150.0, seed);
            let slid = contour_slide_gap_um(&edges(&rim, &scan), None);
            assert!(slid.is_some_and(|g| g > 30.0), "seed {seed}: {slid:?}");
        }
    }

    #[test]
    fn a_sparse_rim_shows_no_false_gap_and_a_gross_slide() {
        // 60 points per mm² (about 220 face points over the rim, [`RIM_MIN_FACE_POINTS`] is
        // 150) over 20 scans: in place, no gap over 25 µm; slid 100 µm, each shows a gap over
        // the 30 µm tolerance. At 30 per mm² (about 110) the rim is not read.
        let (rim, scan) = holed_plate(0.0, 0.010, 30.0, 0);
        assert!(edges(&rim, &scan).is_empty());
        for seed in 0..20 {
            let (rim, scan) = holed_plate(0.0, 0.010, 60.0, seed);
            let found = edges(&rim, &scan);
            assert!(!found.is_empty(), "seed {seed}");
            let widest = found.iter().map(|e| e.gap_mm()).fold(f64::MIN, f64::max);
            assert!(widest < 0.025, "seed {seed}: in place, gap {widest} mm");
            let (rim, scan) = holed_plate(0.100, 0.010, 60.0, seed);
            let found = edges(&rim, &scan);
            let widest = found.iter().map(|e| e.gap_mm()).fold(f64::MIN, f64::max);
            assert!(
                widest > 0.030,
                "seed {seed}: slid, gap {widest} mm: {found:?}"
            );
        }
    }

    #[test]
    fn a_film_over_the_opening_is_not_read() {
        // A film over the whole hole, and a flange 0.25 mm wide over the +x half of the rim
        // only (which a slid, widened edge would otherwise fit, reading a gap on the −x
        // side): face points inside the rim, the step model does not hold, and the rim is not
        // read (no gap, no reading).
        for (inner, from_x) in [(0.0, -1.5), (1.25, 0.0)] {
            let (rim, mut scan) = holed_plate(0.0, 0.010, 150.0, 3);
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
            for _ in 0..(150.0 * 7.0) as usize {
                let (x, y): (f64, f64) = (rng.random_range(-1.5..1.5), rng.random_range(-1.5..1.5));
                let r = x.hypot(y);
                if r < 1.5 && r > inner && x > from_x {
                    scan.push(Point3::new(x, y, 0.0));
                }
            }
            assert!(
                edges(&rim, &scan).is_empty(),
                "film from r = {inner}, x = {from_x}"
            );
        }
    }

    #[test]
    fn short_contours_and_bare_stretches_are_not_measured() {
        // A stretch with too few face points.
        let (contour, scan) = case(0.0, 0.01, 1.0, false, 1);
        assert!(edges(&contour, &scan).is_empty());
        // No scan at all.
        assert!(edges(&contour, &[]).is_empty());
    }
}
