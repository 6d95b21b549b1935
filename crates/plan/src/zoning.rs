//! Zoning: contours grouped so one machine orientation serves each group (paper §2.4,
//! DESIGN.md "Zoning").
//!
//! - **Samples** (paper Eq. 9–10): one 6-D sample per piece, `(w·(c − m)/d, u, v, w)` with `c`
//!   the piece's centroid, `m` the centre of the part's bounding box, `d` the bounding-box
//!   diagonal and `w` [`ZoningSettings::position_weight`]. The paper divides each coordinate by
//!   its maximum, which depends on where the work-piece origin is; dividing by the part's extent
//!   does not.
//! - **k-means** through linfa-clustering: k-means++ seeding, [`ZoningSettings::restarts`] runs,
//!   a fixed seed (so the result is deterministic).
//! - **Zone axis**: the direction that minimises the largest angle to the zone's feature
//!   vectors (every point's, not only the contours' means): the best of the normalised mean,
//!   the first vector, and a Bădoiu–Clarkson iteration on the sphere ([`AXIS_ITERATIONS`] steps
//!   toward the farthest vector). The minimax axis can admit zones the mean would refuse; the largest
//!   incidence it reports is the exact largest angle to the axis it returns.
//! - **Automatic k**: k doubles from 1 until every zone keeps every feature vector within the
//!   limit of its axis, then bisects; the k returned is feasible and k − 1 was tried and is not
//!   (for this seed). If no k up to [`ZoningSettings::max_auto_k`] is feasible, violating zones
//!   are split greedily in two (the farthest pair of contour directions as seeds) until all
//!   comply; a single piece always complies (see [`crate::piece`]), so this terminates.
//! - **Merging** ([`ZoningSettings::merge`]): k-means does not know the constraint, so the
//!   smallest feasible k usually still has zones that could share an orientation. Pairs of
//!   zones are merged, closest axes first, while the union keeps the incidence limit and its
//!   in-plane extent fits `merge_radius_mm` (the planner passes the field radius, or for a
//!   non-telecentric lens the radius whose ray angle fits the lens budget), so merges do not
//!   just create zones the field sectioning must cut apart again.

use std::collections::BTreeMap;

use linfa::DatasetBase;
use linfa::traits::{Fit, Predict};
use linfa_clustering::{KMeans, KMeansInit};
use ndarray::Array2;
use rand_xoshiro_06::Xoshiro256Plus;
use rand_xoshiro_06::rand_core::SeedableRng;
use trim_geom::{ContourId, Point3, UnitVector3, Vector3};

use crate::error::PlanError;
use crate::piece::{Piece, angle_rad};
pub use trim_cell::plan_settings::{
    DEFAULT_MAX_AUTO_K, DEFAULT_POSITION_WEIGHT, ZoningMethod, ZoningSettings,
};

/// Steps of the minimax-axis iteration (its error shrinks like 1/√steps of the cone angle).
pub const AXIS_ITERATIONS: usize = 64;

/// k-means stops when the centroids move less than this (sample units).
pub const KMEANS_TOLERANCE: f64 = 1e-9;

/// One zone of the zoning result (before field sectioning).
#[derive(Debug, Clone, PartialEq)]
pub struct ZoneGroup {
    /// Indices into the pieces, ascending.
    pub pieces: Vec<usize>,
    /// The zone axis (work-piece frame, unit): the minimax direction of its feature vectors.
    pub axis: UnitVector3,
    /// The mean of its pieces' centroids (mm, work-piece frame).
    pub centre: Point3,
    /// The largest angle between a feature vector of the zone and its axis (radians).
    pub max_incidence_rad: f64,
    /// The largest angle between two contour (piece) feature vectors of the zone (radians):
    /// paper Table 1's "included angle".
    pub max_pairwise_rad: f64,
}

impl ZoneGroup {
    /// The sorted, deduplicated input contour ids of the zone.
    #[must_use]
    pub fn contour_ids(&self, pieces: &[Piece]) -> Vec<ContourId> {
        let mut ids: Vec<ContourId> = self.pieces.iter().map(|&i| pieces[i].contour).collect();
        ids.sort_unstable();
        ids.dedup();
        ids
    }
}

/// The zoning result.
#[derive(Debug, Clone, PartialEq)]
pub struct Zoning {
    /// The zones, ordered by their first piece.
    pub groups: Vec<ZoneGroup>,
    /// The k of the k-means run the zones came from.
    pub k: usize,
    /// Whether k was chosen automatically.
    pub automatic: bool,
    /// How many greedy splits were needed after k-means (0 when k-means alone complied).
    pub greedy_splits: usize,
    /// How many merges followed.
    pub merges: usize,
}

/// The minimax axis of a set of unit vectors and its largest angle (radians): the better of
/// the normalised mean and [`AXIS_ITERATIONS`] Bădoiu–Clarkson steps from it.
#[must_use]
pub fn zone_axis(directions: &[Vector3]) -> (UnitVector3, f64) {
    // Comparisons on dot products (the largest angle is the smallest dot); the exact angle of
    // the winner is computed once at the end with the robust atan2 form.
    let min_dot = |c: &Vector3| {
        directions
            .iter()
            .map(|d| c.dot(d))
            .fold(f64::INFINITY, f64::min)
    };
    let farthest = |c: &Vector3| {
        directions
            .iter()
            .min_by(|a, b| c.dot(a).total_cmp(&c.dot(b)))
            .copied()
    };
    let sum: Vector3 = directions.iter().sum();
    let mut c = if sum.norm() > 1e-12 {
        sum.normalize()
    } else {
        directions.first().copied().unwrap_or_else(Vector3::z)
    };
    let mut best = (c, min_dot(&c));
    if let Some(first) = directions.first() {
        let m = min_dot(first);
        if m > best.1 {
            best = (*first, m);
        }
    }
    for i in 1..=AXIS_ITERATIONS {
        let Some(far) = farthest(&c) else {
            break;
        };
        let next = c + (far - c) / (i as f64 + 1.0);
        if next.norm() < 1e-12 {
            break;
        }
        c = next.normalize();
        let m = min_dot(&c);
        if m > best.1 {
            best = (c, m);
        }
    }
    let axis = best.0;
    let max_angle = directions
        .iter()
        .map(|d| angle_rad(&axis, d))
        .fold(0.0, f64::max);
    (UnitVector3::new_unchecked(axis), max_angle)
}

/// The 6-D k-means samples of the pieces (see the module docs), one row per piece.
pub fn samples(pieces: &[Piece], position_weight: f64) -> Result<Array2<f64>, PlanError> {
    for p in pieces {
        for (i, (pt, f)) in p.points.iter().zip(&p.features).enumerate() {
            if !pt.coords.iter().all(|v| v.is_finite()) {
                return Err(PlanError::NonFinite {
                    contour: p.contour,
                    what: "point",
                    index: i,
                });
            }
            if !f.iter().all(|v| v.is_finite()) {
                return Err(PlanError::NonFinite {
                    contour: p.contour,
                    what: "feature vector",
                    index: i,
                });
            }
        }
    }
    let bounds = trim_geom::Aabb::around(pieces.iter().flat_map(|p| p.points.iter()))
        .ok_or(PlanError::EmptyPath)?;
    let centre = bounds.center();
    let diagonal = bounds.diagonal();
    let scale = if diagonal > 0.0 {
        position_weight / diagonal
    } else {
        0.0
    };
    let mut out = Array2::zeros((pieces.len(), 6));
    for (row, p) in pieces.iter().enumerate() {
        let c = (p.centroid() - centre) * scale;
        let f = p.feature();
        for (col, v) in [c.x, c.y, c.z, f.x, f.y, f.z].into_iter().enumerate() {
            out[(row, col)] = v;
        }
    }
    Ok(out)
}

/// k-means labels of the samples (k-means++, `restarts` runs, seeded).
pub fn kmeans_labels(
    records: &Array2<f64>,
    k: usize,
    settings: &ZoningSettings,
) -> Result<Vec<usize>, PlanError> {
    if k > records.nrows() {
        return Err(PlanError::TooManyZones {
            k,
            contours: records.nrows(),
        });
    }
    let rng = Xoshiro256Plus::seed_from_u64(settings.seed);
    let model = KMeans::params_with_rng(k, rng)
        .n_runs(settings.restarts)
        .tolerance(KMEANS_TOLERANCE)
        .max_n_iterations(settings.max_iterations)
        .init_method(KMeansInit::KMeansPlusPlus)
        .fit(&DatasetBase::from(records.clone()))
        .map_err(|e| PlanError::KMeans {
            k,
            message: e.to_string(),
        })?;
    Ok(model.predict(records).to_vec())
}

/// Builds a zone from piece indices (computes axis, centre, incidence, pairwise angle).
#[must_use]
pub fn make_group(pieces: &[Piece], mut members: Vec<usize>, with_pairwise: bool) -> ZoneGroup {
    members.sort_unstable();
    let directions: Vec<Vector3> = members
        .iter()
        .flat_map(|&i| pieces[i].distinct_features())
        .collect();
    let (axis, max_incidence_rad) = zone_axis(&directions);
    let centre_sum: Vector3 = members.iter().map(|&i| pieces[i].centroid().coords).sum();
    let centre = Point3::from(centre_sum / members.len().max(1) as f64);
    let max_pairwise_rad = if with_pairwise {
        let means: Vec<Vector3> = members
            .iter()
            .map(|&i| pieces[i].feature().into_inner())
            .collect();
        let mut m: f64 = 0.0;
        for (i, a) in means.iter().enumerate() {
            for b in &means[i + 1..] {
                m = m.max(angle_rad(a, b));
            }
        }
        m
    } else {
        0.0
    };
    ZoneGroup {
        pieces: members,
        axis,
        centre,
        max_incidence_rad,
        max_pairwise_rad,
    }
}

/// Groups labels into zones (empty clusters dropped), ordered by first piece.
fn groups_from_labels(pieces: &[Piece], labels: &[usize]) -> Vec<ZoneGroup> {
    let mut by_label: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for (i, &l) in labels.iter().enumerate() {
        by_label.entry(l).or_default().push(i);
    }
    let mut groups: Vec<ZoneGroup> = by_label
        .into_values()
        .map(|m| make_group(pieces, m, false))
        .collect();
    groups.sort_by_key(|g| g.pieces[0]);
    groups
}

fn complies(groups: &[ZoneGroup], limit_rad: f64) -> bool {
    groups.iter().all(|g| g.max_incidence_rad <= limit_rad)
}

/// Splits a violating zone in two: seeds are the piece farthest from the axis and the piece
/// farthest from that one; every piece joins the nearer seed (by mean feature).
fn split_group(pieces: &[Piece], g: &ZoneGroup) -> Option<(ZoneGroup, ZoneGroup)> {
    if g.pieces.len() < 2 {
        return None;
    }
    let feature = |i: usize| pieces[i].feature().into_inner();
    let axis = g.axis.into_inner();
    let by = |reference: Vector3| {
        move |a: &&usize, b: &&usize| {
            angle_rad(&reference, &feature(**a)).total_cmp(&angle_rad(&reference, &feature(**b)))
        }
    };
    let seed_a = *g.pieces.iter().max_by(by(axis))?;
    let seed_b = *g.pieces.iter().max_by(by(feature(seed_a)))?;
    let (fa, fb) = (feature(seed_a), feature(seed_b));
    let (mut left, mut right) = (Vec::new(), Vec::new());
    for &i in &g.pieces {
        if i == seed_a
            || (i != seed_b && angle_rad(&fa, &feature(i)) <= angle_rad(&fb, &feature(i)))
        {
            left.push(i);
        } else {
            right.push(i);
        }
    }
    if left.is_empty() || right.is_empty() {
        return None;
    }
    Some((
        make_group(pieces, left, false),
        make_group(pieces, right, false),
    ))
}

/// The in-plane radius of a zone about its bounding-box centre: the half diagonal of the
/// bounding box of its points in the plane across its axis (mm).
#[must_use]
pub fn in_plane_radius_mm(pieces: &[Piece], group: &ZoneGroup) -> f64 {
    let frame = trim_cell::frame::paper_frame(&group.axis);
    let (x, y) = (frame.x_axis(), frame.y_axis());
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in group.pieces.iter().flat_map(|&i| pieces[i].points.iter()) {
        let uv = [p.coords.dot(&x), p.coords.dot(&y)];
        for k in 0..2 {
            lo[k] = lo[k].min(uv[k]);
            hi[k] = hi[k].max(uv[k]);
        }
    }
    0.5 * (hi[0] - lo[0]).hypot(hi[1] - lo[1])
}

/// Merges zones, closest axes first, while the union keeps every feature vector within
/// `limit_rad` of its axis and fits `max_radius_mm` in plane. Returns the zones and the
/// number of merges. Only pairs whose axes are within 2·limit can comply, so only those are
/// tried; a pair that failed is not tried again until one of its zones changes.
#[must_use]
pub fn merge_groups(
    pieces: &[Piece],
    groups: Vec<ZoneGroup>,
    limit_rad: f64,
    max_radius_mm: f64,
) -> (Vec<ZoneGroup>, usize) {
    let mut next_id = groups.len();
    let mut zones: Vec<(usize, ZoneGroup)> = groups.into_iter().enumerate().collect();
    let mut failed: std::collections::HashSet<(usize, usize)> = std::collections::HashSet::new();
    let mut merges = 0;
    loop {
        let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
        for a in 0..zones.len() {
            for b in a + 1..zones.len() {
                let angle = angle_rad(&zones[a].1.axis, &zones[b].1.axis);
                let key = (zones[a].0.min(zones[b].0), zones[a].0.max(zones[b].0));
                if angle <= 2.0 * limit_rad && !failed.contains(&key) {
                    pairs.push((angle, a, b));
                }
            }
        }
        pairs.sort_by(|p, q| p.0.total_cmp(&q.0).then(p.1.cmp(&q.1)).then(p.2.cmp(&q.2)));
        let mut merged = None;
        for (_, a, b) in pairs {
            let mut members = zones[a].1.pieces.clone();
            members.extend_from_slice(&zones[b].1.pieces);
            let union = make_group(pieces, members, false);
            if union.max_incidence_rad <= limit_rad
                && in_plane_radius_mm(pieces, &union) <= max_radius_mm
            {
                merged = Some((a, b, union));
                break;
            }
            failed.insert((zones[a].0.min(zones[b].0), zones[a].0.max(zones[b].0)));
        }
        let Some((a, b, union)) = merged else {
            break;
        };
        zones[a] = (next_id, union);
        next_id += 1;
        zones.remove(b);
        merges += 1;
    }
    (zones.into_iter().map(|z| z.1).collect(), merges)
}

/// Zones the pieces so that every feature vector lies within `limit_rad` of its zone's axis
/// (see the module docs for the procedure). With a fixed k, a violating zone is an error.
pub fn zone_pieces(
    pieces: &[Piece],
    limit_rad: f64,
    settings: &ZoningSettings,
    merge_radius_mm: f64,
) -> Result<Zoning, PlanError> {
    settings.validate()?;
    if pieces.is_empty() {
        return Err(PlanError::EmptyPath);
    }
    let records = samples(pieces, settings.position_weight)?;
    let n = pieces.len();
    let run = |k: usize| -> Result<Vec<ZoneGroup>, PlanError> {
        Ok(groups_from_labels(
            pieces,
            &kmeans_labels(&records, k, settings)?,
        ))
    };
    let finish = |groups: Vec<ZoneGroup>, k: usize, automatic: bool, greedy_splits: usize| {
        let (groups, merges) = if settings.merge && automatic {
            merge_groups(pieces, groups, limit_rad, merge_radius_mm)
        } else {
            (groups, 0)
        };
        let mut groups: Vec<ZoneGroup> = groups
            .into_iter()
            .map(|g| make_group(pieces, g.pieces, true))
            .collect();
        groups.sort_by_key(|g| g.pieces[0]);
        Zoning {
            groups,
            k,
            automatic,
            greedy_splits,
            merges,
        }
    };

    if let Some(k) = settings.k {
        if k > n {
            return Err(PlanError::TooManyZones { k, contours: n });
        }
        let groups = run(k)?;
        if let Some((zone, g)) = groups
            .iter()
            .enumerate()
            .find(|(_, g)| g.max_incidence_rad > limit_rad)
        {
            return Err(PlanError::IncidenceLimit {
                zone,
                contours: g.contour_ids(pieces),
                incidence_deg: g.max_incidence_rad.to_degrees(),
                limit_deg: limit_rad.to_degrees(),
                k,
            });
        }
        return Ok(finish(groups, k, false, 0));
    }

    // Doubling, then bisection between the last infeasible and the first feasible k.
    let cap = n.min(settings.max_auto_k);
    let mut tried: BTreeMap<usize, Vec<ZoneGroup>> = BTreeMap::new();
    let mut feasible = |k: usize| -> Result<bool, PlanError> {
        crate::error::check_cancel()?;
        let groups = run(k)?;
        let ok = complies(&groups, limit_rad);
        tried.insert(k, groups);
        Ok(ok)
    };
    let mut lo = 0;
    let mut hi = None;
    let mut k = 1;
    loop {
        if feasible(k)? {
            hi = Some(k);
            break;
        }
        lo = k;
        if k >= cap {
            break;
        }
        k = (2 * k).min(cap);
    }
    if let Some(mut h) = hi {
        while h - lo > 1 {
            let mid = (lo + h) / 2;
            if feasible(mid)? {
                h = mid;
            } else {
                lo = mid;
            }
        }
        let groups = tried.remove(&h).unwrap_or_default();
        return Ok(finish(groups, h, true, 0));
    }

    // Guarantee: split violating zones until every zone complies.
    let mut groups = tried.remove(&cap).unwrap_or_default();
    let mut splits = 0;
    while let Some(pos) = groups.iter().position(|g| g.max_incidence_rad > limit_rad) {
        crate::error::check_cancel()?;
        let Some((a, b)) = split_group(pieces, &groups[pos]) else {
            // A single piece over the limit cannot be split further; validation reports it.
            break;
        };
        groups[pos] = a;
        groups.push(b);
        splits += 1;
    }
    groups.sort_by_key(|g| g.pieces[0]);
    Ok(finish(groups, cap, true, splits))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn piece(id: ContourId, at: [f64; 3], feature: Vector3) -> Piece {
        let p = Point3::from(at);
        Piece {
            contour: id,
            points: vec![p, p + Vector3::new(0.5, 0.0, 0.0)],
            features: vec![feature.normalize(); 2],
            source: vec![0.0, 1.0],
        }
    }

    fn tilted(deg_x: f64, deg_y: f64) -> Vector3 {
        Vector3::new(deg_x.to_radians().tan(), deg_y.to_radians().tan(), 1.0).normalize()
    }

    #[test]
    fn minimax_axis_beats_the_mean_on_skewed_sets() {
        // Nine vectors near one edge, one on the other: the mean leans to the nine.
        let mut dirs: Vec<Vector3> = (0..9).map(|_| tilted(-4.0, 0.0)).collect();
        dirs.push(tilted(4.0, 0.0));
        let (axis, max) = zone_axis(&dirs);
        assert!(max < 4.1f64.to_radians(), "{}", max.to_degrees());
        assert!(axis.x.abs() < 0.01);
        let mean = dirs.iter().sum::<Vector3>().normalize();
        let mean_max = dirs.iter().map(|d| angle_rad(&mean, d)).fold(0.0, f64::max);
        assert!(mean_max > 6.0f64.to_radians());
    }

    #[test]
    fn automatic_k_is_smallest_feasible_and_deterministic() {
        // Three direction families, 10° apart, 8 contours each at scattered positions.
        let mut pieces = Vec::new();
        for (f, d) in [tilted(0.0, 0.0), tilted(10.0, 0.0), tilted(0.0, 10.0)]
            .iter()
            .enumerate()
        {
            for i in 0..8 {
                let id = (f * 8 + i) as ContourId;
                pieces.push(piece(id, [i as f64 * 3.0, f as f64, 0.0], *d));
            }
        }
        let limit = 5f64.to_radians();
        let z = zone_pieces(&pieces, limit, &ZoningSettings::default(), f64::INFINITY).unwrap();
        assert!(z.automatic);
        assert!(z.groups.iter().all(|g| g.max_incidence_rad <= limit));
        assert_eq!(z.greedy_splits, 0);
        assert!(z.k >= 3);
        // k − 1 does not comply (the bisection invariant).
        let fewer = groups_from_labels(
            &pieces,
            &kmeans_labels(
                &samples(&pieces, DEFAULT_POSITION_WEIGHT).unwrap(),
                z.k - 1,
                &ZoningSettings::default(),
            )
            .unwrap(),
        );
        assert!(!complies(&fewer, limit));
        let again = zone_pieces(&pieces, limit, &ZoningSettings::default(), f64::INFINITY).unwrap();
        assert_eq!(z, again);
    }

    #[test]
    fn refuses_too_many_zones_and_nan() {
        let pieces = vec![
            piece(1, [0.0; 3], Vector3::z()),
            piece(2, [1.0, 0.0, 0.0], Vector3::z()),
        ];
        let settings = ZoningSettings {
            k: Some(3),
            ..ZoningSettings::default()
        };
        let e = zone_pieces(&pieces, 0.1, &settings, f64::INFINITY).unwrap_err();
        assert!(
            matches!(e, PlanError::TooManyZones { k: 3, contours: 2 }),
            "{e}"
        );
        let mut bad = pieces.clone();
        bad[1].features[0] = Vector3::new(f64::NAN, 0.0, 1.0);
        let e = zone_pieces(&bad, 0.1, &ZoningSettings::default(), f64::INFINITY).unwrap_err();
        assert!(e.to_string().contains("contour 2"), "{e}");
    }

    #[test]
    fn greedy_fallback_always_complies() {
        // max_auto_k = 1 forces the fallback on 6 contours spread over 30°.
        let pieces: Vec<Piece> = (0..6)
            .map(|i| piece(i, [0.0, i as f64, 0.0], tilted(6.0 * i as f64, 0.0)))
            .collect();
        let settings = ZoningSettings {
            max_auto_k: 1,
            ..ZoningSettings::default()
        };
        let limit = 5f64.to_radians();
        let z = zone_pieces(&pieces, limit, &settings, f64::INFINITY).unwrap();
        assert!(z.greedy_splits > 0);
        assert!(z.groups.iter().all(|g| g.max_incidence_rad <= limit));
        let mut all: Vec<usize> = z.groups.iter().flat_map(|g| g.pieces.clone()).collect();
        all.sort_unstable();
        assert_eq!(all, (0..6).collect::<Vec<_>>());
    }
}
