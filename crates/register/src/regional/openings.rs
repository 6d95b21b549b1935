//! The opening check: a closed contour's opening where the scan shows it.
//!
//! The field is fitted scan → CAD, point to plane. A scan point over an opening the registered
//! CAD puts in the wrong place finds no CAD face (the tangential gate drops it), and the CAD face
//! over the real opening finds no scan point: neither costs the fit anything. A part whose
//! holes' walls the scanner did not see can therefore slide along itself by a millimetre or more
//! with every match at the noise (outside tune seed 2070: 2.5 mm along the span; 2025: its root
//! end 1.2 mm off), and only the rims' own bounds, spread over many contours, used to refuse it.
//!
//! The check reads the absence of data as data. Around each closed contour it rasterises the
//! face's plane in a band about the registered rim. The CAD says, in its own frame, which cells
//! lie on material and which over the opening; the raw scan, at each cell carried by the field
//! and the similarity, says where it saw material. The opening's template (the CAD's cells) is
//! then slid over the scan's cells in the plane, up to [`OPENING_SEARCH_MM`] each way, to the
//! shift they agree best at. A registration that put the opening where the scanner saw it
//! gains nothing by sliding it; one that misplaced it gains the cells of the two crescents
//! between the registered and the real opening. A film over the opening, a dropout or a shadow
//! beside it change the agreement at every shift alike. Both together can read as a slide (a
//! film over a 2 mm hole with a 3 mm dropout beside it, on a plate: gain 1.4): the part is
//! then refused, which costs a rescan, not a part.

use super::quality::is_open;
use crate::deformation::BSplineField;
use crate::kdtree::{self};
use rayon::prelude::*;
use trim_geom::{Path, Point3, Similarity3, Vector3};

/// The raster's cell, mm.
pub const OPENING_CELL_MM: f64 = 0.125;
/// The band about the rim the opening's template covers, each way across it, mm (the scan's
/// raster reaches [`OPENING_SEARCH_MM`] farther, so every slide compares the whole template).
pub const OPENING_BAND_MM: f64 = 1.0;
/// The largest slide searched, each way along both of the plane's axes, mm.
pub const OPENING_SEARCH_MM: f64 = 1.5;
/// A cell sees material when a point (scan or CAD) lies within this, mm; a cell with no CAD
/// point within [`OPENING_CLEAR_MM`] lies over the opening; cells between are not used.
pub const OPENING_PROBE_RADIUS_MM: f64 = 0.15;
/// See [`OPENING_PROBE_RADIUS_MM`].
pub const OPENING_CLEAR_MM: f64 = 0.3;
/// A CAD point counts as the face's material when its normal is within this (cosine) of the
/// contour's feature vector (a hole wall's is not).
pub const OPENING_FACE_MIN_COS: f64 = 0.7;
/// An opening is misplaced when sliding it by at least [`OPENING_MIN_SLIDE_MM`] gains this
/// share of its cells' agreement (the cells over the CAD opening within the band).
pub const OPENING_MISMATCH_SHARE: f64 = 0.4;
/// See [`OPENING_MISMATCH_SHARE`].
pub const OPENING_MIN_SLIDE_MM: f64 = 0.3;
/// …and the part of the gain over the opening reaches this ([`OpeningCheck::cover_gain`]).
pub const OPENING_COVER_SHARE: f64 = 0.2;
/// Fewer cells over the opening than this: no check.
pub const OPENING_MIN_CELLS: usize = 30;

/// What sliding one closed contour's opening over the scan found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OpeningCheck {
    /// The slide the scan agrees best with, CAD frame, mm (zero: the opening is where the
    /// registration put it).
    pub slide_mm: Vector3,
    /// The agreement gained by that slide, in cells, over the cells over the CAD opening.
    pub gain: f64,
    /// The part of `gain` over the CAD opening: the share of its cells where the scan showed
    /// material that the slide lays on the scan's own opening. A slid opening gains there; a
    /// dropout or a shadow beside a hole in place does not (the opening already read empty).
    pub cover_gain: f64,
}

impl OpeningCheck {
    /// Whether the scan shows the opening misplaced: a slide of at least
    /// [`OPENING_MIN_SLIDE_MM`] that gains [`OPENING_MISMATCH_SHARE`] in agreement, and
    /// [`OPENING_COVER_SHARE`] of it over the opening itself.
    #[must_use]
    pub fn misplaced(&self) -> bool {
        self.slide_mm.norm() >= OPENING_MIN_SLIDE_MM
            && self.gain >= OPENING_MISMATCH_SHARE
            && self.cover_gain >= OPENING_COVER_SHARE
    }
}

/// A raster cell: CAD material (`Some(true)`), CAD opening (`Some(false)`) or unknown; whether
/// the scan saw material there; whether it belongs to the opening's template.
type Cell = (Option<bool>, bool, bool);

/// The opening check of every closed contour (`None` for open ones and for rims with fewer
/// than [`OPENING_MIN_CELLS`] cells over the opening). `cad` is the whole CAD sample with its
/// normals (not the visibility-culled target: a slid part's real openings lie over CAD the
/// scan does not support), `scan` the raw scan in its own frame.
#[must_use]
pub fn check_openings(
    path: &Path,
    field: Option<&BSplineField>,
    scan_from_cad: &Similarity3,
    cad: (&kdtree::KdTree, &[Point3], Option<&[Vector3]>),
    scan: &kdtree::KdTree,
) -> Vec<Option<OpeningCheck>> {
    path.contours()
        .par_iter()
        .map(|c| {
            let p = c.points();
            if is_open(p) || p.len() < 4 {
                return None;
            }
            let n = c.feature().into_inner();
            check_one(p, &n, field, scan_from_cad, cad, scan)
        })
        .collect()
}

fn check_one(
    rim: &[Point3],
    n: &Vector3,
    field: Option<&BSplineField>,
    scan_from_cad: &Similarity3,
    (cad_tree, cad_points, cad_normals): (&kdtree::KdTree, &[Point3], Option<&[Vector3]>),
    scan: &kdtree::KdTree,
) -> Option<OpeningCheck> {
    let centre = Point3::from(rim.iter().map(|q| q.coords).sum::<Vector3>() / rim.len() as f64);
    let (e1, e2) = trim_geom::math::tangent_basis(n);
    let h = OPENING_CELL_MM;
    let cell_of = |q: &Point3| {
        let d = q - centre;
        (
            (d.dot(&e1) / h).round() as i64,
            (d.dot(&e2) / h).round() as i64,
        )
    };
    // The raster: the rim's bounding box in the plane, widened by the band and the search; the
    // template is every cell within OPENING_BAND_MM of a rim point (the rim resampled finer
    // than a cell), the raster every cell within OPENING_SEARCH_MM more.
    let outer = OPENING_BAND_MM + OPENING_SEARCH_MM;
    let reach = (outer / h).ceil() as i64;
    let template_reach2 = (OPENING_BAND_MM / h).powi(2);
    let mut rim_cells = Vec::new();
    for k in 0..rim.len() {
        let (a, b) = (rim[k], rim[(k + 1) % rim.len()]);
        let steps = ((b - a).norm() / (0.5 * h)).ceil().max(1.0) as usize;
        for s in 0..steps {
            rim_cells.push(cell_of(&(a + (b - a) * (s as f64 / steps as f64))));
        }
    }
    let (i0, j0) = rim_cells
        .iter()
        .fold((i64::MAX, i64::MAX), |m, c| (m.0.min(c.0), m.1.min(c.1)));
    let (i1, j1) = rim_cells
        .iter()
        .fold((i64::MIN, i64::MIN), |m, c| (m.0.max(c.0), m.1.max(c.1)));
    let (i0, j0) = (i0 - reach, j0 - reach);
    let (ni, nj) = (
        (i1 + reach - i0 + 1) as usize,
        (j1 + reach - j0 + 1) as usize,
    );
    // 0: outside, 1: raster, 2: template (and raster). The disc of offsets is worked out once,
    // and each rim cell stamped once (the rim is resampled at half a cell, so most cells come
    // twice or more, and stamping is a maximum).
    let disc: Vec<(i64, i64, u8)> = (-reach..=reach)
        .flat_map(|di| (-reach..=reach).map(move |dj| (di, dj)))
        .filter_map(|(di, dj)| {
            let d2 = (di * di + dj * dj) as f64;
            (d2 * h * h <= outer * outer).then_some((
                di,
                dj,
                if d2 <= template_reach2 { 2 } else { 1 },
            ))
        })
        .collect();
    rim_cells.sort_unstable();
    rim_cells.dedup();
    let mut band = vec![0u8; ni * nj];
    for &(i, j) in &rim_cells {
        for &(di, dj, v) in &disc {
            let b = &mut band[(i + di - i0) as usize * nj + (j + dj - j0) as usize];
            *b = (*b).max(v);
        }
    }
    let r2 = OPENING_PROBE_RADIUS_MM * OPENING_PROBE_RADIUS_MM;
    let clear2 = OPENING_CLEAR_MM * OPENING_CLEAR_MM;
    let scale = scan_from_cad.scaling();
    // The field over the raster, to first order about the rim's centre (its control points lie
    // many times the raster's size apart).
    let (d0, jacobian) = field.map_or((Vector3::zeros(), nalgebra::Matrix3::zeros()), |f| {
        f.displacement_and_jacobian(&centre)
    });
    // Per cell: the CAD's state (material, opening, unknown or outside the band) and the scan's.
    // The cells go row by row, so the last cell's CAD point starts the next one's search (the
    // answer does not depend on it; the scan's answers, 0.15 mm off at most, start nothing
    // sooner) and one scratch serves every search.
    let mut scratch = kdtree::Scratch::default();
    let mut last_cad: Option<usize> = None;
    let cells: Vec<Option<Cell>> = (0..ni * nj)
        .map(|k| {
            if band[k] == 0 {
                return None;
            }
            let (i, j) = (i0 + (k / nj) as i64, j0 + (k % nj) as i64);
            let x = centre + e1 * (i as f64 * h) + e2 * (j as f64 * h);
            let hint = last_cad.map(|c| (c, &cad_points[c]));
            let near = cad_tree.nearest_from(&x, clear2, hint, &mut scratch);
            if let Some(nb) = near {
                last_cad = Some(nb.index);
            }
            let cad_state = match near {
                None => Some(false),
                Some(nb) if nb.distance_sq <= r2 => cad_normals
                    .is_none_or(|ns| ns[nb.index].dot(n) >= OPENING_FACE_MIN_COS)
                    .then_some(true),
                Some(_) => None,
            };
            // A material cell is read where the CAD face is (the raster's plane leaves a
            // curved face); one over the opening, in the plane.
            let at = match (cad_state, near) {
                (Some(true), Some(nb)) => {
                    let c = cad_points[nb.index];
                    let nc = cad_normals.map_or(*n, |ns| ns[nb.index]);
                    x - nc * nc.dot(&(x - c))
                }
                _ => x,
            };
            let moved = at + d0 + jacobian * (at - centre);
            let seen = scan.any_within(&(scan_from_cad * moved), r2 * scale * scale, &mut scratch);
            Some((cad_state, seen, band[k] == 2))
        })
        .collect();
    let opening_cells = cells
        .iter()
        .filter(|c| c.is_some_and(|c| c.2 && c.0 == Some(false)))
        .count();
    if opening_cells < OPENING_MIN_CELLS {
        return None;
    }
    // The template's known cells (row, column, CAD material), and what the scan saw per cell
    // (`None` outside the band): listed once, not found again among all cells per shift.
    let template: Vec<(i64, i64, bool)> = cells
        .iter()
        .enumerate()
        .filter_map(|(k, cell)| match cell {
            Some((Some(material), _, true)) => Some(((k / nj) as i64, (k % nj) as i64, *material)),
            _ => None,
        })
        .collect();
    let seen_at: Vec<Option<bool>> = cells.iter().map(|c| c.map(|(_, seen, _)| seen)).collect();
    // Agreement of the template slid by (di, dj) cells: CAD material where the scan saw
    // material, CAD opening where it saw none, over the template's known cells that land in
    // the band. Returns the sum and the opening cells' part of it.
    let agreement = |di: i64, dj: i64| -> (i64, i64) {
        let (mut sum, mut over_opening) = (0, 0);
        for &(i, j, material) in &template {
            let (i, j) = (i + di, j + dj);
            if i < 0 || j < 0 || i >= ni as i64 || j >= nj as i64 {
                continue;
            }
            if let Some(seen) = seen_at[i as usize * nj + j as usize] {
                let a = if material == seen { 1 } else { -1 };
                sum += a;
                if !material {
                    over_opening += a;
                }
            }
        }
        (sum, over_opening)
    };
    let search = (OPENING_SEARCH_MM / h).round() as i64;
    let at_zero = agreement(0, 0);
    let mut best = (at_zero.0, 0, 0);
    // A coarse pass every other cell, then the best one's neighbours.
    for di in (-search..=search).step_by(2) {
        for dj in (-search..=search).step_by(2) {
            let a = agreement(di, dj).0;
            if a > best.0 {
                best = (a, di, dj);
            }
        }
    }
    let (_, ci, cj) = best;
    for di in (ci - 1).max(-search)..=(ci + 1).min(search) {
        for dj in (cj - 1).max(-search)..=(cj + 1).min(search) {
            let a = agreement(di, dj).0;
            if a > best.0 {
                best = (a, di, dj);
            }
        }
    }
    let (a, di, dj) = best;
    let over_opening = agreement(di, dj).1;
    // Each disagreeing cell that turns agreeing moves a sum by 2.
    let share = |d: i64| d as f64 / (2.0 * opening_cells as f64);
    Some(OpeningCheck {
        slide_mm: e1 * (di as f64 * h) + e2 * (dj as f64 * h),
        gain: share(a - at_zero.0),
        cover_gain: share(over_opening - at_zero.1),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use trim_geom::Contour;

    /// Points on a 0.05 mm grid over the square `|x|, |y| ≤ 3` mm at `z = 0`, less those inside
    /// the circle of radius 1 mm about `hole` (when given) and those `keep` rejects.
    fn plate(hole: Option<(f64, f64)>, keep: impl Fn(f64, f64) -> bool) -> Vec<Point3> {
        let mut out = Vec::new();
        for i in -60..=60 {
            for j in -60..=60 {
                let (x, y) = (f64::from(i) * 0.05, f64::from(j) * 0.05);
                let inside = hole.is_some_and(|(a, b)| (x - a).hypot(y - b) < 1.0);
                if !inside && keep(x, y) {
                    out.push(Point3::new(x, y, 0.0));
                }
            }
        }
        out
    }

    /// The check of the CAD's hole (radius 1 mm about the origin) against `scan` as the scan.
    fn check(scan: &[Point3]) -> OpeningCheck {
        let rim: Vec<Point3> = (0..200)
            .map(|k| {
                let a = std::f64::consts::TAU * f64::from(k) / 200.0;
                Point3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        let path = Path::new(vec![Contour::new(0, rim, Vector3::z()).unwrap()]).unwrap();
        let cad_points = plate(Some((0.0, 0.0)), |_, _| true);
        let cad_normals = vec![Vector3::z(); cad_points.len()];
        let checks = check_openings(
            &path,
            None,
            &Similarity3::identity(),
            (
                &kdtree::KdTree::build(&cad_points),
                &cad_points,
                Some(&cad_normals),
            ),
            &kdtree::KdTree::build(scan),
        );
        checks[0].expect("a hole rim has cells over its opening")
    }

    #[test]
    fn a_hole_the_scan_shows_elsewhere_is_found_there_and_one_in_place_is_not() {
        let in_place = check(&plate(Some((0.0, 0.0)), |_, _| true));
        assert!(
            !in_place.misplaced() && in_place.gain == 0.0,
            "{in_place:?}"
        );
        // Measured: every slide found within a cell, gains 0.83 to 1.85.
        for slide in [0.5, 0.75, 1.0, 1.25] {
            let c = check(&plate(Some((slide, 0.0)), |_, _| true));
            assert!(
                c.misplaced() && (c.slide_mm - Vector3::x() * slide).norm() <= OPENING_CELL_MM,
                "hole {slide} mm off: {c:?}"
            );
        }
    }

    #[test]
    fn a_film_over_the_hole_or_a_dropout_beside_it_is_not_a_misplaced_hole() {
        // A film: the scan sees material over the whole opening.
        let film = check(&plate(None, |_, _| true));
        assert!(!film.misplaced(), "film: {film:?}");
        // A dropout 3 mm across beside the rim: unscanned material, none over the opening.
        let dropout = check(&plate(Some((0.0, 0.0)), |x, y| (x - 1.6).hypot(y) > 1.5));
        assert!(!dropout.misplaced(), "dropout: {dropout:?}");
    }
}
