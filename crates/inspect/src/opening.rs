//! The share of a hole or slot still covered: a grid across the opening at the face's level,
//! each node covered when a scan point lies at it; and, where the scan sees a film from both
//! sides, its thickness ([`read_opening`]).
//!
//! A closed contour rims an opening when, seen along its feature vector (the face's normal),
//! most of what it encloses is not material: a ray cast down the normal from the face's level
//! at a grid node meets the CAD's surface within `opening_depth_mm` only over material. The
//! face's level at a node is interpolated from the rim's heights (inverse squared distance to
//! the rim's points, weights `1/d⁴`), so a twisted or cambered face is followed.

use parry3d_f64::query::{Ray, RayCast};
use trim_geom::mesh::Mesh;
use trim_geom::{KdTree, Point3, Vector3};

use crate::contours::ContourGeometry;
use crate::settings::InspectSettings;

/// Where the rays start above the face's level, mm.
const RAY_START_MM: f64 = 0.05;

/// A contour rims an opening when at least this share of its enclosed nodes is open.
const OPEN_SHARE: f64 = 0.5;

/// The most grid nodes one opening is measured on (the step grows past it).
const MAX_NODES: usize = 200_000;

/// A film's two levels are told apart only when they stand at least this many noise standard
/// deviations apart: one face read with noise, split in two at its mean, has its halves'
/// medians about 1.35 σ apart, and the thinnest film expected (50 µm) stands 5 σ thick at the
/// scans' 10 µm.
pub const FILM_SEPARATION_SIGMAS: f64 = 4.0;

/// Each of a film's two sides needs at least this many readings to be measured.
pub const MIN_FILM_SIDE_READINGS: usize = 20;

/// Each side is a face read with the noise: its spread (1.4826 × the median absolute
/// deviation) must be within this many noise σ. Readings spread down a thickness (a free edge
/// seen side on, a cut's wall) are no face, and a split of them is no thickness.
pub const FILM_SIDE_SPREAD_SIGMAS: f64 = 1.5;

/// The standard deviation of a median of n normal readings is this times σ/√n.
const MEDIAN_EFFICIENCY: f64 = 1.2533;

/// A film thickness's standard uncertainty beyond the noise's, µm: what the registration's
/// local fit and the part's deformation across the film add. On the synthetic cores (tune
/// seeds 31–34 with two views, seeds 31 and 32 with three and four: 107 films read from both
/// sides) the errors were −1.5 µm on average, 3.2 µm rms, worst −11.3 µm; twice the noise's
/// uncertainty alone held 93 of the 107, twice its sum in quadrature with this 106 (DESIGN.md,
/// "Inspection" step 7).
pub const FILM_SYSTEMATIC_UM: f64 = 3.0;

/// An opening's grid, CAD frame.
#[derive(Debug, Clone)]
pub struct Opening {
    /// The grid's nodes at the face's level, mm (those of the open region, clear of the rim).
    pub nodes: Vec<Point3>,
    /// Each node's place on the grid (column, row), parallel to `nodes`.
    pub cells: Vec<[i32; 2]>,
    /// Each node's distance from the rim across the face, mm, parallel to `nodes`.
    pub rim_distance_mm: Vec<f64>,
    /// The arc length (along the contour, mm) of each node's nearest rim point, parallel to
    /// `nodes`.
    pub rim_arc_mm: Vec<f64>,
    /// The rim's whole length, mm (arc lengths wrap around it).
    pub rim_length_mm: f64,
    /// The grid's step, mm.
    pub step_mm: f64,
    /// The face's normal (the contour's feature vector).
    pub normal: Vector3,
}

/// A film's thickness read from both of its sides: the spread along the opening's normal
/// between its upper side's readings and its underside's, where the scan sees both.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FilmThickness {
    /// The thickness, µm: the upper side's median reading less the underside's.
    pub thickness_um: f64,
    /// Its standard uncertainty, µm: the two medians' standard deviations from the noise and
    /// [`FILM_SYSTEMATIC_UM`], added in quadrature.
    pub uncertainty_um: f64,
    /// Readings of the upper side.
    pub upper_readings: usize,
    /// Readings of the underside.
    pub underside_readings: usize,
}

/// A stretch of an opening's rim with a burr web standing into the opening
/// ([`read_opening`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WebStretch {
    /// Where the stretch starts along the contour, mm of arc length.
    pub start_mm: f64,
    /// Where it ends, mm.
    pub end_mm: f64,
    /// How far from the rim, across the face, the web's readings reach, mm.
    pub reach_mm: f64,
}

impl WebStretch {
    /// Whether a rim point at `arc_mm` is within the web's reach of the stretch, around a rim
    /// `length_mm` long (a web ending inside a bin covers nodes past its end too).
    fn holds(&self, arc_mm: f64, length_mm: f64) -> bool {
        let (lo, hi) = (self.start_mm - self.reach_mm, self.end_mm + self.reach_mm);
        [arc_mm - length_mm, arc_mm, arc_mm + length_mm]
            .iter()
            .any(|a| (lo..=hi).contains(a))
    }
}

/// What the scan shows over an opening.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OpeningReading {
    /// The covered share of its nodes.
    pub covered_share: f64,
    /// The film's thickness where both its sides are seen; none otherwise.
    pub film: Option<FilmThickness>,
}

/// The opening a closed contour rims, or none (an open contour, or one around material).
#[must_use]
pub fn opening_of(g: &ContourGeometry, mesh: &Mesh, settings: &InspectSettings) -> Option<Opening> {
    if !g.closed {
        return None;
    }
    let n = g.feature.into_inner();
    let e1 = n
        .cross(&Vector3::x())
        .try_normalize(1e-9)
        .unwrap_or_else(|| {
            n.cross(&Vector3::y())
                .try_normalize(1e-9)
                .unwrap_or_else(Vector3::z)
        });
    let e2 = n.cross(&e1);
    let centre =
        g.points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / g.points.len() as f64;
    let centre = Point3::from(centre);
    let rim: Vec<(f64, f64, f64)> = g
        .points
        .iter()
        .map(|p| {
            let d = p - centre;
            (d.dot(&e1), d.dot(&e2), d.dot(&n))
        })
        .collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for (a, b, _) in &rim {
        lo = [lo[0].min(*a), lo[1].min(*b)];
        hi = [hi[0].max(*a), hi[1].max(*b)];
    }
    let area = (hi[0] - lo[0]) * (hi[1] - lo[1]);
    let step = settings
        .opening_grid_mm
        .max((area / MAX_NODES as f64).sqrt());
    let (na, nb) = (
        ((hi[0] - lo[0]) / step).ceil() as usize,
        ((hi[1] - lo[1]) / step).ceil() as usize,
    );
    let mut enclosed = 0usize;
    let mut open = Vec::new();
    let mut cells = Vec::new();
    let (mut rim_distance_mm, mut rim_arc_mm) = (Vec::new(), Vec::new());
    let trimesh = mesh.trimesh();
    for i in 0..na {
        for j in 0..nb {
            let a = lo[0] + (i as f64 + 0.5) * step;
            let b = lo[1] + (j as f64 + 0.5) * step;
            let (inside, rim_distance, (k, t)) = place(&rim, a, b);
            // Nodes near the rim are left out: a film there cannot be told from the wall's top.
            if !inside || rim_distance < settings.opening_rim_clearance_mm {
                continue;
            }
            let Some(height) = face_height(&rim, a, b) else {
                continue;
            };
            enclosed += 1;
            let node = centre + e1 * a + e2 * b + n * height;
            let ray = Ray::new(node + n * RAY_START_MM, -n);
            let material = trimesh
                .cast_local_ray(&ray, RAY_START_MM + settings.opening_depth_mm, true)
                .is_some();
            if !material {
                open.push(node);
                rim_distance_mm.push(rim_distance);
                let next = g.arc_mm.get(k + 1).copied().unwrap_or(g.arc_mm[k]);
                rim_arc_mm.push(g.arc_mm[k] + t * (next - g.arc_mm[k]));
                cells.push([
                    i32::try_from(i).unwrap_or(i32::MAX),
                    i32::try_from(j).unwrap_or(i32::MAX),
                ]);
            }
        }
    }
    (enclosed > 0 && open.len() as f64 >= OPEN_SHARE * enclosed as f64).then_some(Opening {
        nodes: open,
        cells,
        rim_distance_mm,
        rim_arc_mm,
        rim_length_mm: g.length_mm(),
        step_mm: step,
        normal: n,
    })
}

/// Whether `(a, b)` is inside the rim polygon (even-odd), its distance from the rim, and where
/// its nearest rim point lies (segment, fraction along it).
fn place(rim: &[(f64, f64, f64)], a: f64, b: f64) -> (bool, f64, (usize, f64)) {
    let mut inside = false;
    let mut best = f64::INFINITY;
    let mut nearest = (0, 0.0);
    for (k, w) in rim.windows(2).enumerate() {
        let ((a0, b0, _), (a1, b1, _)) = (w[0], w[1]);
        if (b0 > b) != (b1 > b) && a < a0 + (b - b0) * (a1 - a0) / (b1 - b0) {
            inside = !inside;
        }
        let (da, db) = (a1 - a0, b1 - b0);
        let len2 = da * da + db * db;
        let t = if len2 > 0.0 {
            (((a - a0) * da + (b - b0) * db) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let d2 = (a0 + t * da - a).powi(2) + (b0 + t * db - b).powi(2);
        if d2 < best {
            best = d2;
            nearest = (k, t);
        }
    }
    (inside, best.sqrt(), nearest)
}

/// The face's height at `(a, b)`, interpolated from the rim's heights (weights `1/d⁴` to the
/// rim's points but its last, as each segment's first), or none for an empty rim. Computed only
/// for the nodes kept: it visits every rim point.
fn face_height(rim: &[(f64, f64, f64)], a: f64, b: f64) -> Option<f64> {
    let (mut wsum, mut hsum) = (0.0, 0.0);
    for w in rim.windows(2) {
        let (a0, b0, h0) = w[0];
        let v2 = (a0 - a).powi(2) + (b0 - b).powi(2);
        let w = 1.0 / (v2 * v2).max(1e-12);
        wsum += w;
        hsum += w * h0;
    }
    (wsum > 0.0).then(|| hsum / wsum)
}

/// The covered share of the opening and, where the scan sees the film from both sides, its
/// thickness; `noise_mm` is the scan's noise σ.
///
/// `webs` are the stretches of the rim whose burr web was measured (start and end arc length
/// along the contour, and how far the web and what reads as it reach across the face, mm): a
/// web standing into the opening covers the nodes next to the rim, and that is excess, judged
/// as such, not a film. Nodes whose nearest rim point lies in such a stretch and that lie
/// within its reach of the rim are left out of the covered share (not of the film's reading).
///
/// The thickness is read from the covered nodes inside the film: those whose neighbours
/// within `2·opening_support_mm` and a grid step are all covered nodes of the grid. The
/// covered region reaches `opening_support_mm` (and the noise) past the film's free edge, so
/// such a node lies more than `opening_support_mm` inside it, and clear of the rim: its
/// readings are the film's two faces only, not the free edge (read all down its thickness)
/// nor the wall's top. Those readings (each scan point once) are split in two at the least
/// squared error (the optimal 1-D two-means split, each side at least
/// [`MIN_FILM_SIDE_READINGS`]); the thickness is the upper side's median less the lower
/// side's. It is given only when the two stand at least [`FILM_SEPARATION_SIGMAS`] noise σ
/// apart (a film seen from one side only is one level, and its split is noise) and each side
/// spreads no more than [`FILM_SIDE_SPREAD_SIGMAS`] σ (a face, not readings strung down a
/// thickness); none when no node is inside the film.
#[must_use]
pub fn read_opening(
    opening: &Opening,
    tree: &KdTree,
    points: &[Point3],
    noise_mm: f64,
    webs: &[WebStretch],
    settings: &InspectSettings,
) -> OpeningReading {
    let supports = node_supports(opening, tree, points, settings);
    let beyond_webs: Vec<&Vec<(usize, f64)>> = supports
        .iter()
        .zip(opening.rim_arc_mm.iter().zip(&opening.rim_distance_mm))
        .filter(|(_, (arc, distance))| {
            !webs
                .iter()
                .any(|w| **distance <= w.reach_mm && w.holds(**arc, opening.rim_length_mm))
        })
        .map(|(s, _)| s)
        .collect();
    OpeningReading {
        covered_share: share_of(&beyond_webs),
        film: film_thickness(opening, &supports, noise_mm, settings),
    }
}

/// Per node, the scan points supporting it: (index into `points`, offset along the normal
/// from the node's face level, mm), those within `opening_support_mm` across and
/// `opening_depth_mm` along.
fn node_supports(
    opening: &Opening,
    tree: &KdTree,
    points: &[Point3],
    settings: &InspectSettings,
) -> Vec<Vec<(usize, f64)>> {
    let (support, depth) = (settings.opening_support_mm, settings.opening_depth_mm);
    let radius = support.hypot(depth);
    opening
        .nodes
        .iter()
        .map(|node| {
            tree.within_radius_unsorted(node, radius)
                .iter()
                .filter_map(|nb| {
                    let d = points[nb.index] - *node;
                    let along = d.dot(&opening.normal);
                    let across2 = d.norm_squared() - along * along;
                    (along.abs() <= depth && across2 <= support * support)
                        .then_some((nb.index, along))
                })
                .collect()
        })
        .collect()
}

/// The share of nodes with at least one supporting point.
fn share_of<S: AsRef<[(usize, f64)]>>(supports: &[S]) -> f64 {
    let covered = supports.iter().filter(|s| !s.as_ref().is_empty()).count();
    covered as f64 / supports.len().max(1) as f64
}

/// A film's thickness where the scan sees both its sides, from each node's `supports`
/// ([`node_supports`]); the rule is [`read_opening`]'s.
fn film_thickness(
    opening: &Opening,
    supports: &[Vec<(usize, f64)>],
    noise_mm: f64,
    settings: &InspectSettings,
) -> Option<FilmThickness> {
    let covered: std::collections::HashSet<[i32; 2]> = opening
        .cells
        .iter()
        .zip(supports)
        .filter(|(_, s)| !s.is_empty())
        .map(|(c, _)| *c)
        .collect();
    let reach = 2.0 * settings.opening_support_mm / opening.step_mm + 1.0;
    let r = reach.ceil() as i32;
    let neighbours: Vec<[i32; 2]> = (-r..=r)
        .flat_map(|di| (-r..=r).map(move |dj| [di, dj]))
        .filter(|[di, dj]| f64::from(di * di + dj * dj) <= reach * reach)
        .collect();
    let mut seen = std::collections::HashSet::new();
    let mut readings: Vec<f64> = Vec::new();
    for (cell, support) in opening.cells.iter().zip(supports) {
        let inside = !support.is_empty()
            && neighbours
                .iter()
                .all(|[di, dj]| covered.contains(&[cell[0] + di, cell[1] + dj]));
        if inside {
            readings.extend(
                support
                    .iter()
                    .filter(|(index, _)| seen.insert(*index))
                    .map(|(_, along)| *along),
            );
        }
    }
    if readings.len() < 2 * MIN_FILM_SIDE_READINGS {
        return None;
    }
    readings.sort_by(f64::total_cmp);
    let split = two_means_split(&readings, MIN_FILM_SIDE_READINGS)?;
    let (lower, upper) = readings.split_at(split);
    let thickness_mm = median(upper) - median(lower);
    let face_like = |side: &[f64]| spread(side) <= FILM_SIDE_SPREAD_SIGMAS * noise_mm;
    if thickness_mm < FILM_SEPARATION_SIGMAS * noise_mm || !face_like(lower) || !face_like(upper) {
        return None;
    }
    let noise_u_mm =
        MEDIAN_EFFICIENCY * noise_mm * (1.0 / lower.len() as f64 + 1.0 / upper.len() as f64).sqrt();
    Some(FilmThickness {
        thickness_um: thickness_mm * 1e3,
        uncertainty_um: (noise_u_mm * 1e3).hypot(FILM_SYSTEMATIC_UM),
        upper_readings: upper.len(),
        underside_readings: lower.len(),
    })
}

/// The split `k` of sorted `values` into `[..k]` and `[k..]` with the least summed squared
/// deviation from each part's mean, each part at least `min` long; none when there are fewer
/// than `2·min` values.
fn two_means_split(values: &[f64], min: usize) -> Option<usize> {
    let n = values.len();
    if n < 2 * min || min == 0 {
        return None;
    }
    let (mut sum, mut sum2) = (vec![0.0; n + 1], vec![0.0; n + 1]);
    for (i, v) in values.iter().enumerate() {
        sum[i + 1] = sum[i] + v;
        sum2[i + 1] = sum2[i] + v * v;
    }
    // Σ(x − x̄)² over [a, b) = Σx² − (Σx)²/len.
    let ss = |a: usize, b: usize| {
        let (s, s2) = (sum[b] - sum[a], sum2[b] - sum2[a]);
        s2 - s * s / (b - a) as f64
    };
    (min..=n - min).min_by(|&a, &b| (ss(0, a) + ss(a, n)).total_cmp(&(ss(0, b) + ss(b, n))))
}

/// The spread of sorted, non-empty `values`: 1.4826 × their median absolute deviation (the
/// standard deviation, for normal readings).
fn spread(values: &[f64]) -> f64 {
    let m = median(values);
    let mut deviations: Vec<f64> = values.iter().map(|v| (v - m).abs()).collect();
    deviations.sort_by(f64::total_cmp);
    1.4826 * median(&deviations)
}

/// The median of sorted, non-empty `values`.
fn median(values: &[f64]) -> f64 {
    let n = values.len();
    if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::draws::Draws;

    const SIGMA_MM: f64 = 0.01;
    /// A 3 × 3 mm opening on a 0.1 mm grid in the z = 0 face.
    const SIDE: i32 = 30;
    const STEP_MM: f64 = 0.1;

    fn square_opening() -> Opening {
        let cells: Vec<[i32; 2]> = (0..SIDE)
            .flat_map(|i| (0..SIDE).map(move |j| [i, j]))
            .collect();
        Opening {
            nodes: cells
                .iter()
                .map(|[i, j]| {
                    Point3::new(
                        (f64::from(*i) + 0.5) * STEP_MM,
                        (f64::from(*j) + 0.5) * STEP_MM,
                        0.0,
                    )
                })
                .collect(),
            rim_distance_mm: cells
                .iter()
                .map(|[i, j]| {
                    let (x, y) = (f64::from(*i) + 0.5, f64::from(*j) + 0.5);
                    let side = f64::from(SIDE);
                    x.min(y).min(side - x).min(side - y) * STEP_MM
                })
                .collect(),
            rim_arc_mm: cells.iter().map(|&c| square_rim_arc(c)).collect(),
            rim_length_mm: 4.0 * f64::from(SIDE) * STEP_MM,
            cells,
            step_mm: STEP_MM,
            normal: Vector3::z(),
        }
    }

    /// The arc length of a node's nearest rim point on the square's rim, run from (0, 0)
    /// along +x, then +y, then back along −x and −y.
    fn square_rim_arc([i, j]: [i32; 2]) -> f64 {
        let side = f64::from(SIDE) * STEP_MM;
        let (x, y) = (
            (f64::from(i) + 0.5) * STEP_MM,
            (f64::from(j) + 0.5) * STEP_MM,
        );
        let nearest = [y, side - x, side - y, x];
        let k = (0..4)
            .min_by(|&a, &b| nearest[a].total_cmp(&nearest[b]))
            .unwrap_or(0);
        match k {
            0 => x,
            1 => side + y,
            2 => 3.0 * side - x,
            _ => 4.0 * side - y,
        }
    }

    /// A film over `x < 2 mm` of the opening, `thickness_mm` thick below the face, read with
    /// σ = 10 µm: 2000 points on its upper side, `underside` on its underside (over `x < 1.5`,
    /// the part a view from below sees through the opening), 300 on its free edge (all down
    /// its thickness).
    fn film_scan(thickness_mm: f64, underside: usize, seed: u64) -> Vec<Point3> {
        let mut d = Draws(seed);
        let mut points = Vec::new();
        let mut noisy = |d: &mut Draws, x: f64, y: f64, z: f64| {
            points.push(Point3::new(
                x + SIGMA_MM * d.gauss(),
                y + SIGMA_MM * d.gauss(),
                z + SIGMA_MM * d.gauss(),
            ));
        };
        for _ in 0..2000 {
            let (x, y) = (2.0 * d.uniform(), 3.0 * d.uniform());
            noisy(&mut d, x, y, 0.0);
        }
        for _ in 0..underside {
            let (x, y) = (1.5 * d.uniform(), 3.0 * d.uniform());
            noisy(&mut d, x, y, -thickness_mm);
        }
        for _ in 0..300 {
            let (y, z) = (3.0 * d.uniform(), -thickness_mm * d.uniform());
            noisy(&mut d, 2.0, y, z);
        }
        points
    }

    fn read(points: &[Point3]) -> OpeningReading {
        read_with_webs(points, &[])
    }

    fn read_with_webs(points: &[Point3], webs: &[WebStretch]) -> OpeningReading {
        let tree = KdTree::build(points);
        read_opening(
            &square_opening(),
            &tree,
            points,
            SIGMA_MM,
            webs,
            &InspectSettings::default(),
        )
    }

    /// A burr web standing 0.3 mm into the opening from one stretch of its rim (x in
    /// 0.5–2.5 mm of the y = 0 side), read with σ = 10 µm: 800 points on its upper side.
    fn web_scan(seed: u64) -> Vec<Point3> {
        let mut d = Draws(seed);
        (0..800)
            .map(|_| {
                Point3::new(
                    0.5 + 2.0 * d.uniform() + SIGMA_MM * d.gauss(),
                    0.3 * d.uniform() + SIGMA_MM * d.gauss(),
                    SIGMA_MM * d.gauss(),
                )
            })
            .collect()
    }

    /// A web standing into an opening covers the nodes next to its stretch of rim: read as a
    /// cover without its stretch (a web is no film), not with it; nodes beyond the web's reach
    /// or off its stretch still count, so a film next to a web still reads.
    #[test]
    fn a_web_on_the_rim_is_not_read_as_a_cover() {
        let web = web_scan(5);
        let plain = read(&web);
        assert!(plain.covered_share > 0.05, "{plain:?}");
        // The web's stretch, its reach (0.3 mm) plus the support (0.15) and 3.5σ.
        let stretch = WebStretch {
            start_mm: 0.5,
            end_mm: 2.5,
            reach_mm: 0.3 + 0.15 + 0.035,
        };
        let judged = read_with_webs(&web, &[stretch]);
        assert!(judged.covered_share < 0.005, "{judged:?}");
        // With a film over x < 2 mm besides, the share is the film's: its nodes away from the
        // web's stretch all count.
        let mut both = film_scan(0.1, 0, 31);
        both.extend(web);
        let r = read_with_webs(&both, &[stretch]);
        assert!((0.6..=0.75).contains(&r.covered_share), "{r:?}");
    }

    /// Seen from both sides, a film 50–200 µm thick (the synthetic films' range) reads within
    /// 3 µm of its thickness, its free edge (read all down its thickness) left out; its
    /// standard uncertainty is the systematic term's and at most 1 µm more with hundreds of
    /// readings a side.
    #[test]
    fn a_film_seen_from_both_sides_reads_its_thickness() {
        for (k, thickness_mm) in [0.05, 0.12, 0.2].into_iter().enumerate() {
            let r = read(&film_scan(thickness_mm, 600, 7 + k as u64));
            let film = r.film.expect("both sides seen");
            assert!(
                (film.thickness_um - thickness_mm * 1e3).abs() <= 3.0,
                "{thickness_mm} mm read {film:?}"
            );
            assert!(
                (FILM_SYSTEMATIC_UM..FILM_SYSTEMATIC_UM + 1.0).contains(&film.uncertainty_um),
                "{film:?}"
            );
            assert!(
                film.underside_readings >= MIN_FILM_SIDE_READINGS,
                "{film:?}"
            );
            // x < 2 mm of 3 mm covered, and the nodes within the support past the free edge.
            assert!((0.66..=0.75).contains(&r.covered_share), "{r:?}");
        }
    }

    /// Seen from above only, a film has no thickness to read, however thick: its upper side
    /// and free edge alone are not taken for two sides.
    #[test]
    fn a_film_seen_from_one_side_has_no_thickness() {
        for (k, thickness_mm) in [0.05, 0.2].into_iter().enumerate() {
            let r = read(&film_scan(thickness_mm, 0, 21 + k as u64));
            assert_eq!(r.film, None, "{thickness_mm} mm");
            assert!(r.covered_share > 0.6, "{r:?}");
        }
    }

    /// The two-means split puts the boundary in the gap of two well separated levels and
    /// keeps each side at least `min` long.
    #[test]
    fn the_split_lands_in_the_gap() {
        let mut v: Vec<f64> = (0..30).map(|i| f64::from(i) * 1e-3).collect();
        v.extend((0..12).map(|i| 1.0 + f64::from(i) * 1e-3));
        assert_eq!(two_means_split(&v, 5), Some(30));
        assert_eq!(two_means_split(&v, 13), Some(29));
        assert_eq!(two_means_split(&v[..9], 5), None);
    }
}
