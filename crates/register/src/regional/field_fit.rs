//! The deformation field: scan → CAD matches (curvature-aware, same face), the Gauss-Newton fit
//! of the B-spline field, and moving contours through it.

use super::settings::DeformationSettings;
use crate::banded::{BandedCholesky, solve_banded_spd};
use crate::deformation::{BSplineField, SUPPORT};
use crate::error::{RegisterError, Result};
use crate::icp::IcpTarget;
use crate::kdtree;
use crate::kdtree::Scratch;
use crate::kernel::RobustKernel;
use crate::reduce::chunked_sum;
use nalgebra::{DMatrix, DVector, Matrix3, SymmetricEigen};
use rayon::prelude::*;
use trim_geom::{Aabb, Contour, Point3, PointCloud, Similarity3, Vector3};

/// Levenberg-Marquardt damping of the field's Gauss-Newton step, relative to the mean data
/// weight per unknown.
pub const FIELD_DAMPING: f64 = 1e-3;

/// The first half of the field's iterations use every this-many-th scan point: they only have
/// to bring the field near, the second half decide the result. Halves their cost (seeded
/// cases: worst cross-edge P95 within ±0.5 µm of using every point throughout).
pub const EARLY_STRIDE: usize = 2;

/// CAD candidates per scan point; the one whose surface passes closest wins.
pub const MATCH_CANDIDATES: usize = 4;

/// Neighbours used to estimate each CAD point's shape operator.
pub const CURVATURE_NEIGHBOURS: usize = 6;

/// The local shape of one CAD point, as the field's matching uses it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalShape {
    /// The shape operator `S` (`n(c + t) ≈ n(c) + S t` for a tangential `t`), CAD frame.
    pub operator: Matrix3<f64>,
    /// A neighbour lies across an edge (its normal differs by more than
    /// [`MIN_SAME_FACE_COS`]): the point is within about one sample spacing of a sharp edge.
    pub near_edge: bool,
}

/// The local shape of each CAD point. The shape operator is fitted by least squares over its
/// [`CURVATURE_NEIGHBOURS`] nearest neighbours' normals on the same face. The residual
/// `n·(q − c) + ½ tᵀ S t` is then the distance to the osculating quadric instead of the tangent
/// plane: without it a scan point on a 1.2 mm hole wall, 0.12 mm from its nearest CAD sample,
/// reads `t²/2R ≈ 6 µm` off, always toward the hole, and half-visible holes shift by that.
/// A neighbour across an edge marks the point [`LocalShape::near_edge`].
#[must_use]
pub fn local_shapes(cad: &PointCloud, tree: &kdtree::KdTree) -> Vec<LocalShape> {
    let pts = cad.points();
    let Some(normals) = cad.normals() else {
        let flat = LocalShape {
            operator: Matrix3::zeros(),
            near_edge: false,
        };
        return vec![flat; pts.len()];
    };
    pts.par_iter()
        .zip(normals.par_iter())
        .map_init(Scratch::default, |scratch, (c, n)| {
            let (e1, e2) = trim_geom::math::tangent_basis(n);
            let mut ata = nalgebra::Matrix3::<f64>::zeros();
            let mut atb = Vector3::zeros();
            let mut near_edge = false;
            for nb in tree.knn_within(c, CURVATURE_NEIGHBOURS + 1, f64::INFINITY, scratch) {
                let d = pts[nb.index] - c;
                let dn = normals[nb.index] - n;
                // Only neighbours on the same smooth face (normals within ~25°).
                if normals[nb.index].dot(n) < MIN_SAME_FACE_COS {
                    near_edge = true;
                    continue;
                }
                if d.norm_squared() == 0.0 {
                    continue;
                }
                let (t1, t2) = (d.dot(&e1), d.dot(&e2));
                let (g1, g2) = (dn.dot(&e1), dn.dot(&e2));
                // S = [[a, b], [b, c]]: g1 = a t1 + b t2, g2 = b t1 + c t2.
                for (row, rhs) in [
                    (Vector3::new(t1, t2, 0.0), g1),
                    (Vector3::new(0.0, t1, t2), g2),
                ] {
                    ata += row * row.transpose();
                    atb += row * rhs;
                }
            }
            let operator = (ata + Matrix3::identity() * 1e-12)
                .try_inverse()
                .map_or_else(Matrix3::zeros, |inv| {
                    let abc = inv * atb;
                    let (a, b, cc) = (abc[0], abc[1], abc[2]);
                    a * e1 * e1.transpose()
                        + b * (e1 * e2.transpose() + e2 * e1.transpose())
                        + cc * e2 * e2.transpose()
                });
            LocalShape {
                operator,
                near_edge,
            }
        })
        .collect()
}

/// A field point's scan normal (the least-variance direction of its nearest scan points) must
/// agree with its CAD match's carried normal to this (cosine, 45.6°) for the fit to use the
/// match: a burr web or a film over a hole, matched to the wall beside it, turns away from it.
/// Chosen on the project's seeded one-view cores 201–212 (0.5, 0.7 and 0.85 alike).
pub const SCAN_NORMAL_MIN_COS: f64 = 0.7;

/// A scan point matches a CAD point only within this many CAD sample spacings of it across the
/// CAD normal: a point beyond the surface's extent (a web standing off an edge, in the wall's
/// plane; a film over an opening) lies on no CAD face, however near its plane, while a point
/// on a face always has a sample within about one spacing, whatever the misalignment along
/// it. Chosen on the project's seeded cores 201–212 (1.5 to 4 registered all; see DESIGN.md).
pub const TANGENT_GATE_SPACINGS: f64 = 3.0;

/// What a scan point must satisfy, beside the distance, to be matched.
pub(crate) struct Gates<'a> {
    /// Each point's scan normal (CAD frame; zero where unknown), to agree with its match's
    /// carried normal within [`SCAN_NORMAL_MIN_COS`].
    pub(crate) scan_normals: Option<&'a [Vector3]>,
    /// The largest offset from the matched CAD point across its normal, mm (0: none).
    pub(crate) tangent_mm: f64,
    /// Leave out a point whose best CAD point is [`LocalShape::near_edge`]
    /// (`field.exclude_edges`).
    pub(crate) exclude_edges: bool,
}

/// Whether a scan normal (zero: unknown) agrees with a CAD normal.
fn agrees(scan_normal: &Vector3, cad_normal: &Vector3) -> bool {
    *scan_normal == Vector3::zeros() || scan_normal.dot(cad_normal).abs() >= SCAN_NORMAL_MIN_COS
}

/// Scan points whose spread gives a field point's own normal.
pub const SCAN_NORMAL_NEIGHBOURS: usize = 12;

/// …found within this, mm (fewer than six: no normal, the point matched as before).
pub const SCAN_NORMAL_RADIUS_MM: f64 = 0.3;

/// Each field point's surface normal from the scan around it (`picked` indexes `scan`), in the
/// scan frame; the zero vector where too few scan points lie near. Also returns the kd-tree of
/// the whole scan (scan frame) it searched. [`turn_normals`] carries them into the CAD frame.
pub(crate) fn scan_normals(scan: &[Point3], picked: &[usize]) -> (Vec<Vector3>, kdtree::KdTree) {
    let tree = kdtree::KdTree::build(scan);
    let d2 = SCAN_NORMAL_RADIUS_MM * SCAN_NORMAL_RADIUS_MM;
    let normals = picked
        .par_iter()
        .map_init(Scratch::default, |scratch, &i| {
            let nb = tree.knn_within(&scan[i], SCAN_NORMAL_NEIGHBOURS, d2, scratch);
            if nb.len() < 6 {
                return Vector3::zeros();
            }
            let pts: Vec<Point3> = nb.iter().map(|n| scan[n.index]).collect();
            let (_, cov) = super::coarse::moments(&pts);
            let eig = SymmetricEigen::new(cov);
            eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned()
        })
        .collect();
    (normals, tree)
}

/// [`scan_normals`]' normals turned by `rotation` (into the CAD frame), the zero vectors (no
/// normal) left as they are.
pub(crate) fn turn_normals(
    normals: &[Vector3],
    rotation: &nalgebra::UnitQuaternion<f64>,
) -> Vec<Vector3> {
    normals
        .par_iter()
        .map(|n| {
            if *n == Vector3::zeros() {
                *n
            } else {
                rotation * n
            }
        })
        .collect()
}

/// The CAD sample's typical spacing: the median distance from a point to its nearest other
/// point, over an even subset of 512 points, mm.
pub(crate) fn cad_spacing_mm(target: &IcpTarget) -> f64 {
    let pts = target.cloud().points();
    let step = (pts.len() / 512).max(1);
    let mut scratch = Scratch::default();
    let mut d: Vec<f64> = pts
        .iter()
        .step_by(step)
        .filter_map(|p| {
            target
                .tree()
                .knn_within(p, 2, f64::INFINITY, &mut scratch)
                .get(1)
                .map(|n| n.distance_sq.sqrt())
        })
        .collect();
    if d.is_empty() {
        return 0.0;
    }
    let mid = d.len() / 2;
    *d.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// Neighbours whose normals differ by more than this (cosine) lie across an edge.
pub const MIN_SAME_FACE_COS: f64 = 0.9;

/// One scan point matched to the CAD in the field's last iteration (CAD frame).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Match {
    /// The scan point, CAD frame.
    pub(crate) q: Point3,
    /// Deformed CAD normal.
    pub(crate) n: Vector3,
    /// Point-to-plane residual, mm.
    pub(crate) r: f64,
}

/// A scan point's match: CAD index, CAD point, carried normal, residual (mm).
pub(crate) type Matched = (usize, Point3, Vector3, f64);

/// A field point's CAD candidates from its last neighbour search: where the search was made
/// (CAD frame), within which squared distance (mm²), and the candidates found.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Candidates {
    at: Point3,
    distance_sq: f64,
    count: u8,
    index: [u32; MATCH_CANDIDATES],
}

impl Default for Candidates {
    fn default() -> Self {
        Candidates {
            at: Point3::origin(),
            distance_sq: -1.0,
            count: 0,
            index: [0; MATCH_CANDIDATES],
        }
    }
}

/// A field point's candidates are searched again only once it has moved this far (mm, CAD
/// frame) from where they were searched, or when its maximum distance grew: in the last
/// iterations the field moves points by micrometres, and the nearest few CAD samples (0.1–0.2
/// mm apart) are the same.
pub const CANDIDATE_REUSE_MM: f64 = 0.005;

/// Matches of the field's points: scan point `q` (CAD frame) to its CAD point under the current
/// field (`F⁻¹(q)`'s nearest CAD point), with the residual along the carried normal. With
/// `exclude_edges`, a point whose best CAD point is [`LocalShape::near_edge`] has no match: which
/// face a noisy point a few tens of micrometres from a rim belongs to is a guess, and the
/// guesses lean one way (a top-face point read against a wall plane always lies inside the
/// material), so near a wall the scanner sees on one side only they shifted the wall by up to
/// 20 µm. `shapes` may be empty (no curvature, no edges known).
pub(crate) fn match_points(
    points: &[Point3],
    gates: &Gates<'_>,
    target: &IcpTarget,
    shapes: &[LocalShape],
    field: Option<&BSplineField>,
    max_distance_mm: f64,
    cache: Option<&mut [Candidates]>,
) -> Vec<Option<Matched>> {
    let cad = target.cloud().points();
    let normals = target.cloud().normals();
    let d2max = max_distance_mm * max_distance_mm;
    let tangent2 = gates.tangent_mm * gates.tangent_mm;
    let reuse2 = CANDIDATE_REUSE_MM * CANDIDATE_REUSE_MM;
    let mut none: Vec<Candidates> = Vec::new();
    let cache: &mut [Candidates] = match cache {
        Some(c) if c.len() == points.len() => c,
        _ => {
            none.resize(points.len(), Candidates::default());
            &mut none
        }
    };
    points
        .par_iter()
        .zip(cache.par_iter_mut())
        .enumerate()
        .map_init(Scratch::default, |scratch, (i, (q, cached))| {
            let p = field.map_or(*q, |f| f.inverse_apply(q, 2));
            if !(cached.distance_sq >= d2max && (p - cached.at).norm_squared() <= reuse2) {
                let found = target
                    .tree()
                    .knn_within(&p, MATCH_CANDIDATES, d2max, scratch);
                let mut index = [0u32; MATCH_CANDIDATES];
                for (slot, nb) in index.iter_mut().zip(found) {
                    *slot = nb.index as u32;
                }
                *cached = Candidates {
                    at: p,
                    distance_sq: d2max,
                    count: found.len() as u8,
                    index,
                };
            }
            // The candidates within the distance, nearest first (ties by index, as the search).
            let mut near: [(f64, usize); MATCH_CANDIDATES] = [(f64::INFINITY, 0); MATCH_CANDIDATES];
            let mut count = 0;
            for &index in &cached.index[..usize::from(cached.count)] {
                let index = index as usize;
                let d2 = (cad[index] - p).norm_squared();
                if d2 <= d2max {
                    near[count] = (d2, index);
                    count += 1;
                }
            }
            near[..count].sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            // Of the nearest CAD points, the one whose surface passes closest to q: near an
            // edge the nearest sample may lie on the other face (a top-face scan point 0.1 mm
            // from a rim finds a wall sample), and its plane would pull sideways.
            let mut best: Option<(f64, usize, Point3, Vector3, f64)> = None;
            // The field at the nearest candidate; the others (within a millimetre) use its
            // first-order expansion `d(c) ≈ d₀ + J₀ (c − c₀)` and its normal map.
            let mut at_nearest: Option<(Point3, Vector3, Matrix3<f64>, Matrix3<f64>)> = None;
            for &(_, nb_index) in &near[..count] {
                let c = cad[nb_index];
                let n0 = normals.map_or(Vector3::z(), |ns| ns[nb_index]);
                let (c0, d0, j, normal_map) = *at_nearest.get_or_insert_with(|| {
                    let (d, j) = field.map_or((Vector3::zeros(), Matrix3::zeros()), |f| {
                        f.displacement_and_jacobian(&c)
                    });
                    let m = (Matrix3::identity() + j)
                        .try_inverse()
                        .map_or_else(Matrix3::identity, |inv| inv.transpose());
                    (c, d, j, m)
                });
                let d = d0 + j * (c - c0);
                let n = (normal_map * n0)
                    .try_normalize(f64::MIN_POSITIVE)
                    .unwrap_or(n0);
                let diff = q - (c + d);
                let t = diff - n * n.dot(&diff);
                // A scan point beyond the CAD surface's extent (over its edge or an opening)
                // does not lie on it, however near its plane.
                if tangent2 > 0.0 && t.norm_squared() > tangent2 {
                    continue;
                }
                // Distance to the osculating quadric (see `shape_operators`).
                let s = shapes
                    .get(nb_index)
                    .map_or_else(Matrix3::zeros, |l| l.operator);
                let r = -(n.dot(&diff) + 0.5 * (t.transpose() * s * t)[(0, 0)]);
                if best.is_none_or(|b| r.abs() < b.0) {
                    best = Some((r.abs(), nb_index, c, n, r));
                }
            }
            let (_, index, c, n, r) = best?;
            if gates.exclude_edges && shapes.get(index).is_some_and(|l| l.near_edge) {
                return None;
            }
            // A scan point whose own surface turns away from its CAD face's (a burr web or a
            // film standing over a hole, matched to the wall beside it) has no match.
            if let Some(ns) = gates.scan_normals
                && !agrees(&ns[i], &n)
            {
                return None;
            }
            Some((index, c, n, r))
        })
        .collect()
}

pub(crate) fn final_matches(
    points: &[Point3],
    target: &IcpTarget,
    shapes: &[LocalShape],
    field: Option<&BSplineField>,
    max_distance_mm: f64,
) -> Vec<Match> {
    let gates = Gates {
        scan_normals: None,
        tangent_mm: 0.0,
        exclude_edges: false,
    };
    match_points(points, &gates, target, shapes, field, max_distance_mm, None)
        .into_iter()
        .zip(points)
        .filter_map(|(m, q)| m.map(|(_, _, n, r)| Match { q: *q, n, r }))
        .collect()
}

/// The fitted field, its final matches and its posterior, and the model check's field.
pub(crate) struct FieldFit {
    pub(crate) field: BSplineField,
    pub(crate) matches: Vec<Match>,
    pub(crate) posterior: Option<FieldPosterior>,
    pub(crate) check: Option<ModelCheck>,
}

/// The model check's field (`quality.model_check`, [`check_field`]) and its own posterior, so
/// that the edge terms condition it as they do the fit.
pub(crate) struct ModelCheck {
    pub(crate) field: BSplineField,
    pub(crate) posterior: Option<CheckPosterior>,
}

/// The model check's posterior as the fit's is taken ([`FieldPosterior`]: the same share of
/// the prior and damping), kept factored: the edge terms only need its products with their
/// rows, `C hᵀ = σ² H⁻¹ hᵀ`, one banded solve each, not the whole inverse.
pub(crate) struct CheckPosterior {
    factor: BandedCholesky,
    sigma2: f64,
}

impl CheckPosterior {
    /// The posterior `σ² H⁻¹` of the information matrix `h` (half-bandwidth `bandwidth`);
    /// `None` when `h` is not positive definite.
    pub(crate) fn new(h: &DMatrix<f64>, bandwidth: usize, sigma2: f64) -> Option<Self> {
        BandedCholesky::factor(h, bandwidth).map(|factor| CheckPosterior { factor, sigma2 })
    }

    /// `C hᵀ` for the sparse row `row` (3 unknowns per control point); `None` when the solve
    /// fails.
    pub(crate) fn sigma_h(&self, row: &[(usize, f64)]) -> Option<DVector<f64>> {
        let mut h = DVector::zeros(self.factor.dim());
        for &(j, v) in row {
            h[j] += v;
        }
        self.factor.solve(&h).map(|x| x * self.sigma2)
    }
}

/// Fits the displacement field (CAD frame) to the scan points `q` (CAD frame), with its final
/// matches and its posterior; with `check`, also the model check's field (see [`check_field`]).
///
/// `beside` is work of the caller's that needs nothing of the fit: it runs after the
/// posterior, on the core the posterior leaves while the model check's solves (one core,
/// most of its time) go on, and its result is returned with the fit.
#[allow(clippy::too_many_arguments)]
pub(crate) fn fit_field<T: Send>(
    points: &[Point3],
    scan_normals: &[Vector3],
    target: &IcpTarget,
    shapes: &[LocalShape],
    settings: &DeformationSettings,
    check: Option<&DeformationSettings>,
    beside: impl FnOnce() -> T + Send,
) -> Result<(FieldFit, T)> {
    let tangent_mm = TANGENT_GATE_SPACINGS * cad_spacing_mm(target);
    let mut candidates = vec![Candidates::default(); points.len()];
    let (field, prior) = solve_field(
        points,
        scan_normals,
        tangent_mm,
        target,
        shapes,
        settings,
        &mut candidates,
    )?;
    // All final matches, edges, burrs and films included (the tangential gate only drops points
    // that lie on no CAD face), for the quality report (coverage and residuals are about what
    // the scanner saw); the posterior from those the fit used.
    let gates = Gates {
        scan_normals: None,
        tangent_mm,
        exclude_edges: false,
    };
    let matched = match_points(
        points,
        &gates,
        target,
        shapes,
        Some(&field),
        settings.max_distance_end_mm,
        Some(&mut candidates),
    );
    let fitted: Vec<Option<Matched>> = matched
        .iter()
        .zip(scan_normals)
        .map(|(m, ns)| {
            m.filter(|(index, _, n, ..)| {
                !(settings.exclude_edges && shapes.get(*index).is_some_and(|l| l.near_edge))
                    && agrees(ns, n)
            })
        })
        .collect();
    // The check's solves and the posterior's inverse (then `beside`) are independent: one
    // core each.
    let cancel = trim_geom::cancel::current();
    let (check, (posterior, beside)) = rayon::join(
        || {
            cancel.run(|| {
                check
                    .map(|c| check_field(&field, &fitted, target, c))
                    .transpose()
            })
        },
        || {
            let posterior = field_posterior(&field, &fitted, &prior, settings);
            (posterior, beside())
        },
    );
    let check = check?;
    let matches = matched
        .into_iter()
        .zip(points)
        .filter_map(|(m, q)| m.map(|(_, _, n, r)| Match { q: *q, n, r }))
        .collect();
    Ok((
        FieldFit {
            field,
            matches,
            posterior,
            check,
        },
        beside,
    ))
}

/// One match of the model check: its CAD point, carried normal, residual without the fit's
/// displacement (mm), and its basis indices and values on the check's grid.
type CheckMatch = (Point3, Vector3, f64, [usize; SUPPORT], [f64; SUPPORT]);

/// The model check's field (`quality.model_check`): the same data as the fit, the fit's final
/// matches `fitted` (their CAD points and carried normals held fixed), fitted under `settings`
/// (another control spacing) from zero. Where the data fix the contour, the two fields agree;
/// where the smoothness prior decides, they differ by what the two priors make of it. The
/// residual is linear in the field for fixed matches, so each pass is one solve, with the Huber
/// weights of the last (re-weighted each pass, so that the check weighs the data as a fit of
/// its own would, not as the fit did: with the fit's weights held, a part 1 mm off read half
/// the disagreement). The normal matrix is carried from pass to pass and only the matches whose
/// weight changed are added again (an inlier's weight stays 1), so a pass costs a fraction of a
/// full build. It takes as many damped passes as the fit took Gauss-Newton steps: where
/// neither the data nor the prior fix a direction well, the damping holds both fields equally
/// near zero (three passes left the check short of the fit there, and the difference read as
/// disagreement: the demo part's end strips 33 µm instead of 18 µm).
fn check_field(
    field: &BSplineField,
    fitted: &[Option<Matched>],
    target: &IcpTarget,
    settings: &DeformationSettings,
) -> Result<ModelCheck> {
    let (mut check, prior) = zero_field(target, settings)?;
    let kernel = RobustKernel::Huber {
        k_mm: settings.huber_mm,
    };
    // Each match's residual with the fit's displacement taken out: `r₀ = r − n·d(c)`, and its
    // basis values on the check's grid.
    let base: Vec<CheckMatch> = fitted
        .par_iter()
        .filter_map(|m| {
            m.map(|(_, c, n, r)| {
                let (index, value) = check.values(&c);
                (c, n, r - n.dot(&field.displacement(&c)), index, value)
            })
        })
        .collect();
    let dim = 3 * check.len();
    // The data's normal matrix under the last pass's weights: only the matches whose weight
    // changed (those beyond the Huber threshold; an inlier's stays 1) are added again, by the
    // change, so a pass costs a fraction of a full build and gives the same matrix.
    let mut weights = vec![0.0; base.len()];
    let mut h = DMatrix::<f64>::zeros(dim, dim);
    for pass in 0..settings.iterations {
        trim_geom::cancel::check()?;
        let residuals: Vec<f64> = base
            .par_iter()
            .map(|(_, n, r0, index, value)| r0 + n.dot(&check.displacement_from(index, value)))
            .collect();
        let changed: Vec<(Point3, Vector3, f64, f64)> = base
            .iter()
            .zip(&residuals)
            .zip(weights.iter_mut())
            .filter_map(|(((c, n, ..), &r), w)| {
                let new = kernel.weight(r);
                let delta = new - *w;
                *w = new;
                (delta != 0.0).then_some((*c, *n, r, delta))
            })
            .collect();
        h += field_normal_equations(&check, &changed).0;
        // g = Σ w a r at the current residuals (deterministic whatever the thread count).
        let g = chunked_sum(
            base.len(),
            DVector::<f64>::zeros(dim),
            |g, i| {
                let (_, n, _, index, value) = &base[i];
                let wr = weights[i] * residuals[i];
                for (&k, &v) in index.iter().zip(value) {
                    for x in 0..3 {
                        g[3 * k + x] += wr * v * n[x];
                    }
                }
            },
            |a, b| *a += b,
        );
        damped_solve(
            &mut check,
            h.clone(),
            g,
            &prior,
            settings.smoothness,
            &format!("model check, pass {pass}"),
        )?;
    }
    // Its posterior at its own final residuals and weights, as the fit's is taken: the matrix
    // carried on once more, by the matches whose weight the last solve changed.
    let pairs: Vec<(Point3, Vector3, f64, f64)> = base
        .par_iter()
        .map(|(c, n, r0, index, value)| {
            let r = r0 + n.dot(&check.displacement_from(index, value));
            (*c, *n, r, kernel.weight(r))
        })
        .collect();
    let changed: Vec<(Point3, Vector3, f64, f64)> = pairs
        .iter()
        .zip(&weights)
        .filter(|(p, w)| p.3 != **w)
        .map(|(&(c, n, r, w), old)| (c, n, r, w - old))
        .collect();
    h += field_normal_equations(&check, &changed).0;
    let information = Information::from_data(h, &pairs, settings);
    let h = information.with_prior(&check, &prior, &PriorTerm::posterior_share);
    let posterior = CheckPosterior::new(
        &h,
        check.bandwidth_with_prior(PRIOR_REACH),
        information.sigma2,
    );
    Ok(ModelCheck {
        field: check,
        posterior,
    })
}

/// The displacement field alone (CAD frame), and the prior it was fitted under: the
/// Gauss-Newton iterations of [`fit_field`] without its final matches and posterior.
///
/// First `field.warmup_iterations` on every [`WARMUP_STRIDE`]-th point, the maximum distance
/// shrinking from [`WARMUP_REACH_FACTOR`] × `max_distance_start_mm` to it; then
/// `field.iterations`, the maximum distance shrinking from `max_distance_start_mm` to
/// `max_distance_end_mm` by iteration `iterations − 3`, the first half on every
/// [`EARLY_STRIDE`]-th point.
fn solve_field(
    points: &[Point3],
    scan_normals: &[Vector3],
    tangent_mm: f64,
    target: &IcpTarget,
    shapes: &[LocalShape],
    settings: &DeformationSettings,
    candidates: &mut [Candidates],
) -> Result<(BSplineField, Vec<PriorTerm>)> {
    let (mut field, prior) = zero_field(target, settings)?;
    let mut early_candidates = vec![Candidates::default(); points.len().div_ceil(EARLY_STRIDE)];
    let kernel = RobustKernel::Huber {
        k_mm: settings.huber_mm,
    };
    let shrink_steps = settings.iterations.saturating_sub(3).max(1);
    let ratio = settings.max_distance_end_mm / settings.max_distance_start_mm;
    // The points are in voxel order, so every k-th is an even thinning.
    let early: Vec<Point3> = points.iter().step_by(EARLY_STRIDE).copied().collect();
    let warm: Vec<Point3> = points.iter().step_by(WARMUP_STRIDE).copied().collect();
    let early_n: Vec<Vector3> = scan_normals.iter().step_by(EARLY_STRIDE).copied().collect();
    let warm_n: Vec<Vector3> = scan_normals
        .iter()
        .step_by(WARMUP_STRIDE)
        .copied()
        .collect();
    let warmup = settings.warmup_iterations;
    for it in 0..warmup + settings.iterations {
        trim_geom::cancel::check()?;
        let (sample, sample_normals, max_d, cache) = if it < warmup {
            let f = it as f64 / (warmup - 1).max(1) as f64;
            let reach = WARMUP_REACH_FACTOR.powf(1.0 - f);
            (
                &warm[..],
                &warm_n[..],
                settings.max_distance_start_mm * reach,
                None,
            )
        } else {
            let k = it - warmup;
            let t = (k as f64 / shrink_steps as f64).min(1.0);
            let max_d = settings.max_distance_start_mm * ratio.powf(t);
            if k < settings.iterations / 2 {
                (
                    &early[..],
                    &early_n[..],
                    max_d,
                    Some(&mut early_candidates[..]),
                )
            } else {
                (points, scan_normals, max_d, Some(&mut *candidates))
            }
        };
        let gates = Gates {
            scan_normals: Some(sample_normals),
            tangent_mm,
            exclude_edges: settings.exclude_edges,
        };
        let matched = match_points(sample, &gates, target, shapes, Some(&field), max_d, cache);
        let pairs: Vec<(Point3, Vector3, f64, f64)> = matched
            .iter()
            .filter_map(|m| m.map(|(_, c, n, r)| (c, n, r, kernel.weight(r))))
            .collect();
        let needed = 3 * SUPPORT;
        if pairs.len() < needed {
            return Err(RegisterError::TooFewCorrespondences {
                stage: format!("deformation field, iteration {it}"),
                needed,
                got: pairs.len(),
                max_distance_mm: max_d,
            });
        }
        damped_step(
            &mut field,
            &pairs,
            &prior,
            settings.smoothness,
            &format!("deformation field, iteration {it}"),
        )?;
    }
    Ok((field, prior))
}

/// Refuses a field over `bounds` (the CAD's, padded as [`zero_field`] pads them) whose grid at
/// `spacing_mm × ratio` (`ratio`: 1 for the fit, [`MODEL_CHECK_SPACING_RATIO`](super::quality::MODEL_CHECK_SPACING_RATIO) for the model
/// check's finer grid) would have more than [`MAX_FIELD_CONTROL_POINTS`], naming
/// `field.spacing_mm` and the smallest spacing within the limit.
pub(crate) fn check_field_size(bounds: &Aabb, spacing_mm: f64, ratio: f64) -> Result<()> {
    let control_points = |spacing: f64| {
        let pad = 0.25 * spacing;
        (0..3)
            .map(|a| {
                ((bounds.max[a] - bounds.min[a] + 2.0 * pad) / spacing)
                    .ceil()
                    .max(1.0)
                    + 2.0
            })
            .product::<f64>()
    };
    let needed = control_points(spacing_mm * ratio);
    if needed <= MAX_FIELD_CONTROL_POINTS as f64 {
        return Ok(());
    }
    // The smallest spacing (to 10 %) within the limit, to suggest.
    let mut enough = spacing_mm;
    while control_points(enough * ratio) > MAX_FIELD_CONTROL_POINTS as f64 {
        enough *= 1.1;
    }
    let extent = bounds.extent();
    let grid = if ratio == 1.0 {
        String::new()
    } else {
        format!(" (the model check's grid, at {ratio} × the spacing)")
    };
    Err(RegisterError::setting(
        "field.spacing_mm",
        format!(
            "{spacing_mm} mm makes a field of {needed:.0} control points{grid} over the CAD's {:.0} × {:.0} × {:.0} mm, more than {MAX_FIELD_CONTROL_POINTS} (its normal matrix is dense): use at least {enough:.1} mm (the default is 20)",
            extent.x, extent.y, extent.z
        ),
    ))
}

/// The most control points a field may have (the fit's or the model check's): its normal
/// matrix is dense, `(3n)²` numbers, and the posterior inverts it; 2,000 is 290 MB a copy. The
/// default spacing gives 100–300 on a core; a spacing of 1 mm asked for 141 GB and aborted.
pub const MAX_FIELD_CONTROL_POINTS: usize = 2000;

/// The field's warm-up iterations (`field.warmup_iterations`) use every this-many-th point:
/// they only have to bring the field within the main iterations' reach.
pub const WARMUP_STRIDE: usize = 8;

/// The warm-up's maximum distance starts at this multiple of `field.max_distance_start_mm` and
/// shrinks geometrically to it.
pub const WARMUP_REACH_FACTOR: f64 = 2.0;

/// The zero field over the CAD (its bounds padded by a quarter of the control spacing) and
/// its smoothness prior: where the fit and the model check start.
fn zero_field(
    target: &IcpTarget,
    settings: &DeformationSettings,
) -> Result<(BSplineField, Vec<PriorTerm>)> {
    let bounds = target
        .cloud()
        .bounds()
        .ok_or(RegisterError::EmptyCloud { which: "CAD" })?;
    let pad = Vector3::repeat(0.25 * settings.spacing_mm);
    let (min, max) = (bounds.min - pad, bounds.max + pad);
    check_field_size(&bounds, settings.spacing_mm, 1.0)?;
    let field = BSplineField::zero(&min, &max, settings.spacing_mm);
    let prior = prior_terms(&field, target.cloud().points(), settings);
    Ok((field, prior))
}

/// One damped Gauss-Newton step of `field` on the weighted point-to-plane `pairs` under the
/// smoothness `prior` (weight `smoothness` × the mean data weight per unknown), applied to it.
/// Levenberg-Marquardt damping: directions neither the data nor the prior fix (control points
/// far from the scan) take no step instead of an arbitrary one. `stage` names the step in an
/// error.
fn damped_step(
    field: &mut BSplineField,
    pairs: &[(Point3, Vector3, f64, f64)],
    prior: &[PriorTerm],
    smoothness: f64,
    stage: &str,
) -> Result<()> {
    let (h, g) = field_normal_equations(field, pairs);
    damped_solve(field, h, g, prior, smoothness, stage)
}

/// The step of [`damped_step`] from the data's normal equations `h`, `g` (the prior and the
/// damping added here), applied to `field`.
fn damped_solve(
    field: &mut BSplineField,
    mut h: DMatrix<f64>,
    mut g: DVector<f64>,
    prior: &[PriorTerm],
    smoothness: f64,
    stage: &str,
) -> Result<()> {
    let dim = 3 * field.len();
    let mean_diag = h.diagonal().sum() / dim as f64;
    add_prior(&mut h, &mut g, field, prior, smoothness * mean_diag);
    for i in 0..dim {
        h[(i, i)] += FIELD_DAMPING * mean_diag.max(f64::MIN_POSITIVE);
    }
    let step =
        solve_banded_spd(&h, &(-&g), field.bandwidth_with_prior(PRIOR_REACH)).ok_or_else(|| {
            RegisterError::Singular {
                stage: stage.to_string(),
                eigenvalues: Vec::new(),
            }
        })?;
    if step.iter().any(|v| !v.is_finite()) {
        return Err(RegisterError::NonFinite {
            what: format!("{stage}: step"),
        });
    }
    field.add_step(step.as_slice());
    Ok(())
}

/// The posterior that bounds a contour's error is taken under this fraction of the fit's prior
/// and damping: the prior is a smoothness assumption, not a measurement, and where the data
/// do not fix a direction (a strip sliding along itself far from any wall or rim) a posterior
/// under the full prior is confident exactly where the fit is blind.
/// Chosen on the outside generator's tune seeds 2001–2010: at 1 a fifth of the contours over
/// 30 µm were trusted; at 0.1 none (at 0.3, 8 of 17). The terms on the displacement along the
/// part's span (`PriorKind::Span`, `PriorKind::Beam`) keep
/// `POSTERIOR_SPAN_PRIOR_SCALE` instead.
pub const POSTERIOR_PRIOR_SCALE: f64 = 0.1;

/// The share of the fit's prior the posterior keeps on the displacement along the span: its
/// second differences (an anisotropic shrinkage, affine, costs nothing) and the beam's
/// sections (a bend carries them). These are a pressed and sintered core's kinematics, not a
/// smoothness guess; under a tenth of them the posterior let a strip's end slide along the span
/// by the prior's whole slack, and that slack set the bound of most good strips (outside tune
/// seeds 2001–2080: 377 of the 383 false alarms in parts not refused were a strip's end). A
/// core whose shrinkage varies along its span (a density gradient from pressing) bends this
/// assumption; DESIGN.md, "The posterior along the span", gives what was measured.
pub const POSTERIOR_SPAN_PRIOR_SCALE: f64 = 1.0;

/// The fitted field's posterior covariance (Laplace approximation at the solution): the
/// Gauss-Newton matrix of the last matches with the prior and the damping, `H`, inverted and
/// scaled by the Huber-weighted residual variance, `C = σ² H⁻¹` (unknowns `3k + axis`, mm²).
#[derive(Debug, Clone)]
pub struct FieldPosterior {
    covariance: DMatrix<f64>,
    /// The same under [`POSTERIOR_PRIOR_SCALE`] of every prior term, the span's too: what the
    /// part's doubt counts contours by (`quality::judge_part`), as it was calibrated.
    part_covariance: Option<DMatrix<f64>>,
    /// The residual standard deviation `σ`, mm.
    pub sigma_mm: f64,
}

impl FieldPosterior {
    /// The covariance of the control displacements (3 per control point, CAD frame, mm²).
    pub(crate) fn covariance(&self) -> &DMatrix<f64> {
        &self.covariance
    }

    /// See [`FieldPosterior::part_covariance`].
    pub(crate) fn part_covariance(&self) -> Option<&DMatrix<f64>> {
        self.part_covariance.as_ref()
    }

    /// A posterior with the given covariance (tests).
    #[cfg(test)]
    pub(crate) fn from_covariance(covariance: DMatrix<f64>) -> Self {
        FieldPosterior {
            covariance,
            part_covariance: None,
            sigma_mm: 0.01,
        }
    }

    /// Takes `reduction` (symmetric, what a conditioning explained) off the covariance.
    pub(crate) fn subtract(&mut self, reduction: &DMatrix<f64>) {
        self.covariance -= reduction;
        self.covariance = (&self.covariance + self.covariance.transpose()) * 0.5;
    }

    /// Adds the possible move `k` to the covariance: `Σ ← Σ + k kᵀ`.
    pub(crate) fn widen(&mut self, k: &DVector<f64>) {
        self.covariance.ger(1.0, k, k, 1.0);
    }

    /// The same on the part's covariance ([`FieldPosterior::part_covariance`]).
    pub(crate) fn widen_part(&mut self, k: &DVector<f64>) {
        if let Some(c) = self.part_covariance.as_mut() {
            c.ger(1.0, k, k, 1.0);
        }
    }

    /// Takes `reduction` off the part's covariance ([`FieldPosterior::part_covariance`]).
    pub(crate) fn subtract_part(&mut self, reduction: &DMatrix<f64>) {
        if let Some(c) = self.part_covariance.as_mut() {
            *c -= reduction;
            *c = (&*c + c.transpose()) * 0.5;
        }
    }

    /// The covariance of the displacement `d(x)` at `x` (CAD frame, mm²).
    #[must_use]
    pub fn displacement_covariance(&self, field: &BSplineField, x: &Point3) -> Matrix3<f64> {
        block_covariance(&self.covariance, field, x)
    }
}

/// `Σₐ Σᵦ Bₐ(x) Bᵦ(x) Cₐᵦ`: the covariance of `d(x)` from the control displacements' `c`
/// (symmetric). Each pair `a < b` is read once, `Cᵦₐ = Cₐᵦᵀ`: half the 3 × 3 blocks gathered
/// from the dense matrix, which is what the sum costs.
pub(crate) fn block_covariance(c: &DMatrix<f64>, field: &BSplineField, x: &Point3) -> Matrix3<f64> {
    let (index, value) = field.values(x);
    let mut diagonal = Matrix3::zeros();
    let mut upper = Matrix3::zeros();
    for a in 0..SUPPORT {
        if value[a] == 0.0 {
            continue;
        }
        let ra = 3 * index[a];
        diagonal += c.fixed_view::<3, 3>(ra, ra) * (value[a] * value[a]);
        for b in a + 1..SUPPORT {
            let w = value[a] * value[b];
            if w == 0.0 {
                continue;
            }
            upper += c.fixed_view::<3, 3>(ra, 3 * index[b]) * w;
        }
    }
    diagonal + upper + upper.transpose()
}

/// The posterior of the field at its last matches (see [`FieldPosterior`]); `None` when the
/// matrix cannot be inverted.
fn field_posterior(
    field: &BSplineField,
    matched: &[Option<Matched>],
    prior: &[PriorTerm],
    settings: &DeformationSettings,
) -> Option<FieldPosterior> {
    let kernel = RobustKernel::Huber {
        k_mm: settings.huber_mm,
    };
    let pairs: Vec<(Point3, Vector3, f64, f64)> = matched
        .iter()
        .filter_map(|m| m.map(|(_, c, n, r)| (c, n, r, kernel.weight(r))))
        .collect();
    posterior_of(field, &pairs, prior, settings)
}

/// The posterior of `field` at the weighted point-to-plane `pairs` `(CAD point, normal,
/// residual, weight)` under `prior` ([`FieldPosterior`]), and the part's covariance
/// ([`FieldPosterior::part_covariance`]). `None` when the matrix cannot be inverted.
fn posterior_of(
    field: &BSplineField,
    pairs: &[(Point3, Vector3, f64, f64)],
    prior: &[PriorTerm],
    settings: &DeformationSettings,
) -> Option<FieldPosterior> {
    let information = Information::new(field, pairs, settings);
    let sigma2 = information.sigma2;
    // `H` is banded (the prior's reach): its banded factor gives the inverse in a third of a
    // dense Cholesky inverse's work.
    let bandwidth = field.bandwidth_with_prior(PRIOR_REACH);
    let inverse =
        |h: DMatrix<f64>| BandedCholesky::factor(&h, bandwidth).map(|c| c.inverse() * sigma2);
    let scale = POSTERIOR_PRIOR_SCALE;
    let (covariance, part_covariance) = rayon::join(
        || inverse(information.with_prior(field, prior, &PriorTerm::posterior_share)),
        || inverse(information.with_prior(field, prior, &|_| scale)),
    );
    Some(FieldPosterior {
        covariance: covariance?,
        part_covariance,
        sigma_mm: sigma2.sqrt(),
    })
}

/// What weighted point-to-plane pairs tell about a field: the data's Gauss-Newton matrix, its
/// mean diagonal (the prior's and the damping's unit) and the residual variance per unit weight.
struct Information {
    data: DMatrix<f64>,
    mean_diag: f64,
    /// The prior's weight: the smoothness × the mean data weight per unknown.
    smoothness_weight: f64,
    sigma2: f64,
}

impl Information {
    fn new(
        field: &BSplineField,
        pairs: &[(Point3, Vector3, f64, f64)],
        settings: &DeformationSettings,
    ) -> Self {
        Information::from_data(field_normal_equations(field, pairs).0, pairs, settings)
    }

    /// The same from the data's matrix `data` of `pairs`, built already.
    fn from_data(
        data: DMatrix<f64>,
        pairs: &[(Point3, Vector3, f64, f64)],
        settings: &DeformationSettings,
    ) -> Self {
        let dim = data.nrows();
        let mean_diag = data.diagonal().sum() / dim as f64;
        let (wr2, w): (f64, f64) = pairs
            .iter()
            .fold((0.0, 0.0), |(a, b), p| (a + p.3 * p.2 * p.2, b + p.3));
        // Residual variance per unit weight, the fitted unknowns' degrees of freedom taken out
        // (at most `dim`; the prior fixes most of them).
        let sigma2 = wr2 / (w - dim as f64).max(1.0);
        Information {
            data,
            mean_diag,
            smoothness_weight: settings.smoothness * mean_diag,
            sigma2,
        }
    }

    /// The data's matrix with the prior, each term at `share` of its weight, and
    /// [`POSTERIOR_PRIOR_SCALE`] of the fit's damping.
    fn with_prior(
        &self,
        field: &BSplineField,
        prior: &[PriorTerm],
        share: &(dyn Fn(&PriorTerm) -> f64 + Sync),
    ) -> DMatrix<f64> {
        let dim = self.data.nrows();
        let mut h = self.data.clone();
        let mut g = DVector::zeros(dim);
        add_prior_weighted(&mut h, &mut g, field, prior, self.smoothness_weight, share);
        for i in 0..dim {
            h[(i, i)] +=
                POSTERIOR_PRIOR_SCALE * FIELD_DAMPING * self.mean_diag.max(f64::MIN_POSITIVE);
        }
        h
    }
}

/// Control points one prior stencil spans beyond its first (third differences).
pub const PRIOR_REACH: usize = 3;

/// One term of the smoothness prior: a finite-difference stencil over control points, each
/// control displacement taken along its own direction, `e = Σₘ aₘ·δₘ` (CAD frame); the prior
/// adds `λ e²`. A stencil over one component along an axis has every `aₘ = cₘ v`; a beam term
/// mixes components.
pub(crate) struct PriorTerm {
    entries: Vec<(usize, Vector3)>,
    kind: PriorKind,
}

/// What a prior term constrains (see [`prior_terms`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PriorKind {
    /// The displacement along the span (second differences).
    Span,
    /// The beam's sections ([`beam_terms`]).
    Beam,
    /// Anything else: the chord and thin-axis components, or every component without
    /// `free_bending`.
    Other,
}

impl PriorTerm {
    /// The stencil `(index, coefficients)` applied to the displacement's component along `v`.
    fn along((index, coefficients): &(Vec<usize>, Vec<f64>), v: &Vector3, kind: PriorKind) -> Self {
        PriorTerm {
            entries: index
                .iter()
                .zip(coefficients)
                .map(|(&i, &c)| (i, v * c))
                .collect(),
            kind,
        }
    }

    /// The share of the fit's weight the posterior gives this term ([`POSTERIOR_PRIOR_SCALE`],
    /// [`POSTERIOR_SPAN_PRIOR_SCALE`]).
    fn posterior_share(&self) -> f64 {
        match self.kind {
            PriorKind::Span | PriorKind::Beam => POSTERIOR_SPAN_PRIOR_SCALE,
            PriorKind::Other => POSTERIOR_PRIOR_SCALE,
        }
    }

    /// The term's value `e` for the control displacements `coefficients`.
    fn value(&self, coefficients: &[Vector3]) -> f64 {
        self.entries
            .iter()
            .map(|(k, a)| a.dot(&coefficients[*k]))
            .sum()
    }
}

/// The part's thin and long axes, CAD frame: the least principal axis of the CAD points (a
/// slab's normal) and the greatest (a core's span).
pub(crate) fn thin_and_long_axes(points: &[Point3]) -> (Vector3, Vector3) {
    let n = points.len().max(1) as f64;
    let mean = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let cov: Matrix3<f64> = points
        .iter()
        .map(|p| (p.coords - mean) * (p.coords - mean).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    let eig = SymmetricEigen::new(cov);
    let imin = eig.eigenvalues.imin();
    let imax = eig.eigenvalues.imax();
    (
        eig.eigenvectors.column(imin).into_owned(),
        eig.eigenvectors.column(imax).into_owned(),
    )
}

/// The prior's terms. Without `free_bending`: second differences of each displacement
/// component (affine motion free). With it: second differences of the displacement across the
/// part's thin axis `u` and third differences of its component along `u`, so a bend (a
/// displacement along `u` quadratic along the part) costs nothing while the in-plane motion,
/// which only walls and rims fix, stays as stiff as before; `in_plane_bending` frees the bend
/// in the chord direction too; `beam_kinematics` adds [`beam_terms`].
pub(crate) fn prior_terms(
    field: &BSplineField,
    cad: &[Point3],
    settings: &DeformationSettings,
) -> Vec<PriorTerm> {
    if !settings.free_bending {
        return field
            .differences(2)
            .iter()
            .flat_map(|s| {
                [Vector3::x(), Vector3::y(), Vector3::z()]
                    .map(|v| PriorTerm::along(s, &v, PriorKind::Other))
            })
            .collect();
    }

    let (u, long) = thin_and_long_axes(cad);
    // The grid axis nearest the part's long axis: a beam bends along it in any direction
    // across it, so the displacement across both the thin and the long axis (the chord
    // direction) takes third differences along that axis alone; along the long axis it stays
    // affine (second differences), as without `in_plane_bending`.
    let chord = u.cross(&long).normalize();
    let along_long = chord.cross(&u).normalize();
    let long_axis = long.iamax();
    let second = field.differences_along(2);
    let third = field.differences_along(3);
    let chord_third = |axis: usize| settings.in_plane_bending && axis == long_axis;
    let mut terms: Vec<PriorTerm> = second
        .iter()
        .map(|(_, s)| PriorTerm::along(s, &along_long, PriorKind::Span))
        .chain(
            second
                .iter()
                .filter(|(axis, _)| !chord_third(*axis))
                .map(|(_, s)| PriorTerm::along(s, &chord, PriorKind::Other)),
        )
        .chain(
            third
                .iter()
                .filter(|(axis, _)| chord_third(*axis))
                .map(|(_, s)| PriorTerm::along(s, &chord, PriorKind::Other)),
        )
        .chain(
            third
                .iter()
                .map(|(_, s)| PriorTerm::along(s, &u, PriorKind::Other)),
        )
        .collect();
    if settings.beam_kinematics {
        terms.extend(beam_terms(field, long_axis, [chord.iamax(), u.iamax()]));
    }
    terms
}

/// Euler–Bernoulli kinematics on the grid: for each grid axis `a` across the span (the ones
/// nearest the chord and the thin axis) and the span's grid axis `l`, the change along the span
/// of the cross-section's shear, `∂²d_a/∂l² + ∂²d_l/∂a∂l`, at every control point with
/// neighbours on both sides along both axes: `(δ₋ₗ − 2δ₀ + δ₊ₗ)·eₐ + ¼(δ₊ₐ₊ₗ − δ₊ₐ₋ₗ − δ₋ₐ₊ₗ +
/// δ₋ₐ₋ₗ)·eₗ`. A bend `d_a = κ l²/2` with its plane sections `d_l = −κ a l` (and any affine
/// motion, a twist about the span, a shear constant along it) costs nothing; an along-span
/// slide that grows along the span and across it without the bend that would carry it
/// (`d_l = c a l` alone) costs as a bend of the same size would. Axes that coincide give none.
fn beam_terms(field: &BSplineField, l: usize, across: [usize; 2]) -> Vec<PriorTerm> {
    let d = field.dims();
    let el = Vector3::ith(l, 1.0);
    let mut out = Vec::new();
    for (n, &a) in across.iter().enumerate() {
        // A part turned so that its chord and thin axis lie nearest the same grid axis gets
        // that axis's terms once.
        if a == l || across[..n].contains(&a) {
            continue;
        }
        let ea = Vector3::ith(a, 1.0);
        for k in 0..d[2] {
            for j in 0..d[1] {
                for i in 0..d[0] {
                    let c = [i, j, k];
                    if c[a] == 0 || c[a] + 1 >= d[a] || c[l] == 0 || c[l] + 1 >= d[l] {
                        continue;
                    }
                    let at = |da: isize, dl: isize| {
                        let mut p = c;
                        p[a] = p[a].wrapping_add_signed(da);
                        p[l] = p[l].wrapping_add_signed(dl);
                        field.flat(p[0], p[1], p[2])
                    };
                    out.push(PriorTerm {
                        kind: PriorKind::Beam,
                        entries: vec![
                            (at(0, -1), ea),
                            (at(0, 0), ea * -2.0),
                            (at(0, 1), ea),
                            (at(1, 1), el * 0.25),
                            (at(1, -1), el * -0.25),
                            (at(-1, 1), el * -0.25),
                            (at(-1, -1), el * 0.25),
                        ],
                    });
                }
            }
        }
    }
    out
}

/// Adds `λ Σ e²`, `e = Σₘ aₘ·δₘ` (gradient and Gauss-Newton matrix), to the normal equations.
pub(crate) fn add_prior(
    h: &mut DMatrix<f64>,
    g: &mut DVector<f64>,
    field: &BSplineField,
    prior: &[PriorTerm],
    lambda: f64,
) {
    add_prior_weighted(h, g, field, prior, lambda, &|_| 1.0);
}

/// [`add_prior`] with each term's `λ` times `share(term)`.
fn add_prior_weighted(
    h: &mut DMatrix<f64>,
    g: &mut DVector<f64>,
    field: &BSplineField,
    prior: &[PriorTerm],
    lambda: f64,
    share: &dyn Fn(&PriorTerm) -> f64,
) {
    let coeffs = field.coefficients();
    for t in prior {
        let lambda = lambda * share(t);
        let e = t.value(coeffs);
        for (ia, a) in &t.entries {
            for x in 0..3 {
                g[3 * ia + x] += lambda * a[x] * e;
            }
            for (ib, b) in &t.entries {
                for x in 0..3 {
                    for y in 0..3 {
                        h[(3 * ia + x, 3 * ib + y)] += lambda * a[x] * b[y];
                    }
                }
            }
        }
    }
}

/// Basis pairs `(k, l)`, `k ≤ l`, of one cell's control points.
const BASIS_PAIRS: usize = SUPPORT * (SUPPORT + 1) / 2;

/// Points whose products [`field_normal_equations`] adds to a cell's sums in one pass.
const BATCH: usize = 4;

/// `row[m] += Σⱼ s[j] bb[j][m]` for a full batch, the terms added in the batch's order (as one
/// point at a time would round). Fixed-size arrays and an indexed loop: the zipped iterators it
/// replaces kept their bounds and zip bookkeeping in the loop (8 % of the normal equations'
/// samples) and the compiler did not vectorise it.
#[inline]
fn add_batch(row: &mut [f64; BASIS_PAIRS], bb: &[[f64; BASIS_PAIRS]; BATCH], s: &[f64; BATCH]) {
    let [b0, b1, b2, b3] = bb;
    let [s0, s1, s2, s3] = *s;
    for m in 0..BASIS_PAIRS {
        row[m] = row[m] + s0 * b0[m] + s1 * b1[m] + s2 * b2[m] + s3 * b3[m];
    }
}

/// `Σ w a aᵀ` and `Σ w a r` with `a = Bₖ(c) n'` (the residual's gradient in `δₖ`), accumulated
/// per grid cell (the points of a cell share their 27 control points), cells in parallel,
/// scattered in cell order (deterministic). The gradient is a Kronecker product, `a = b ⊗ n`
/// (`b` the 27 basis values, `n` the carried normal), so a cell's 81 × 81 block is
/// `Σ w (b bᵀ) ⊗ (n nᵀ)`: for each of the six distinct products `w nᵢ nⱼ` the symmetric
/// `Σ (w nᵢ nⱼ) b bᵀ`, 6 × 378 multiply-adds per point where the dense product `Aᵀ W A` took
/// 81² (a third of the field's time on the outside 500k case before 2026-11-27).
pub(crate) fn field_normal_equations(
    field: &BSplineField,
    pairs: &[(Point3, Vector3, f64, f64)],
) -> (DMatrix<f64>, DVector<f64>) {
    const LOCAL: usize = 3 * SUPPORT;
    /// The distinct normal products `(i, j)`, `i ≤ j`.
    const NORMAL_PAIRS: [(usize, usize); 6] = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];
    let dim = 3 * field.len();
    let mut keyed: Vec<(usize, usize)> = pairs
        .par_iter()
        .enumerate()
        .map(|(i, p)| (field.cell_index(&p.0), i))
        .collect();
    keyed.par_sort_unstable();
    let groups: Vec<&[(usize, usize)]> = keyed.chunk_by(|a, b| a.0 == b.0).collect();
    let locals: Vec<([usize; SUPPORT], Vec<f64>, [f64; LOCAL])> = groups
        .par_iter()
        .map(|group| {
            // acc[q·BASIS_PAIRS + m]: Σ (w nᵢ nⱼ) b_k b_l for NORMAL_PAIRS[q] and pair m.
            let mut acc = vec![0.0; NORMAL_PAIRS.len() * BASIS_PAIRS];
            let mut gl = [0.0; LOCAL];
            // The products of BATCH points at a time, added to `acc` in one pass: each sum
            // takes its terms in the points' order as one point at a time would (the same
            // rounding), but loads and stores `acc` once per batch, not once per point.
            let mut bb = [[0.0; BASIS_PAIRS]; BATCH];
            let mut sw = [[0.0; BATCH]; NORMAL_PAIRS.len()];
            let mut index = [0usize; SUPPORT];
            for batch in group.chunks(BATCH) {
                for (j, &(_, i)) in batch.iter().enumerate() {
                    let (c, nrm, r, w) = pairs[i];
                    let (wt_index, b) = field.values(&c);
                    index = wt_index;
                    let mut m = 0;
                    for k in 0..SUPPORT {
                        for l in k..SUPPORT {
                            bb[j][m] = b[k] * b[l];
                            m += 1;
                        }
                        for x in 0..3 {
                            gl[3 * k + x] += w * r * b[k] * nrm[x];
                        }
                    }
                    for (q, &(x, y)) in NORMAL_PAIRS.iter().enumerate() {
                        sw[q][j] = w * nrm[x] * nrm[y];
                    }
                }
                let (rows, _) = acc.as_chunks_mut::<BASIS_PAIRS>();
                for (row, s) in rows.iter_mut().zip(&sw) {
                    if batch.len() == BATCH {
                        add_batch(row, &bb, s);
                    } else {
                        for j in 0..batch.len() {
                            for (a, v) in row.iter_mut().zip(&bb[j]) {
                                *a += s[j] * v;
                            }
                        }
                    }
                }
            }
            (index, acc, gl)
        })
        .collect();
    // The normal-product slot of components (x, y).
    let slot = |x: usize, y: usize| {
        let (i, j) = if x <= y { (x, y) } else { (y, x) };
        NORMAL_PAIRS
            .iter()
            .position(|&p| p == (i, j))
            .unwrap_or_default()
    };
    let slots: [[usize; 3]; 3] = [0, 1, 2].map(|x| [0, 1, 2].map(|y| slot(x, y)));
    let mut h = DMatrix::<f64>::zeros(dim, dim);
    let mut g = DVector::<f64>::zeros(dim);
    for (index, acc, gl) in &locals {
        let mut m = 0;
        for k in 0..SUPPORT {
            for x in 0..3 {
                g[3 * index[k] + x] += gl[3 * k + x];
            }
            for l in k..SUPPORT {
                for x in 0..3 {
                    for y in 0..3 {
                        let v = acc[slots[x][y] * BASIS_PAIRS + m];
                        let (ra, rb) = (3 * index[k] + x, 3 * index[l] + y);
                        h[(ra, rb)] += v;
                        if k != l {
                            h[(rb, ra)] += v;
                        }
                    }
                }
                m += 1;
            }
        }
    }
    (h, g)
}

pub(crate) fn move_contour(
    c: &Contour,
    field: Option<&BSplineField>,
    scan_from_cad: &Similarity3,
) -> Result<Contour> {
    let rot = scan_from_cad.isometry.rotation;
    let points: Vec<Point3> = c
        .points()
        .iter()
        .map(|p| scan_from_cad * field.map_or(*p, |f| f.apply(p)))
        .collect();
    let features: Vec<Vector3> = c
        .points()
        .iter()
        .zip(c.features())
        .map(|(p, n)| rot * field.map_or(*n, |f| f.apply_normal(p, n)))
        .collect();
    Ok(Contour::with_features(c.id(), points, features)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::regional::MODEL_CHECK_SPACING_RATIO;

    /// The beam terms' energy `Σ e²` of the field whose control displacement at grid point
    /// `(i, j, k)` (mm from the first) is `d`.
    fn beam_energy(d: impl Fn(f64, f64, f64) -> Vector3) -> f64 {
        let mut field = BSplineField::zero(
            &Point3::new(-20.0, -4.0, 0.0),
            &Point3::new(20.0, 4.0, 100.0),
            10.0,
        );
        let dims = field.dims();
        let mut step = vec![0.0; 3 * field.len()];
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let h = field.spacing_mm();
                    let v = d(i as f64 * h, j as f64 * h, k as f64 * h);
                    let at = 3 * field.flat(i, j, k);
                    step[at..at + 3].copy_from_slice(v.as_slice());
                }
            }
        }
        field.add_step(&step);
        let terms = beam_terms(&field, 2, [0, 1]);
        assert!(!terms.is_empty());
        terms
            .iter()
            .map(|t| t.value(field.coefficients()).powi(2))
            .sum()
    }

    /// The posterior keeps the span's prior terms and the beam's whole and a tenth of the rest:
    /// its matrix equals the span and beam terms added at full weight plus the others at
    /// [`POSTERIOR_PRIOR_SCALE`]; the terms along the span are the second differences of the
    /// displacement along the long axis.
    #[test]
    fn the_posterior_keeps_the_spans_prior_whole_and_a_tenth_of_the_rest() {
        let field = BSplineField::zero(
            &Point3::new(-20.0, -4.0, 0.0),
            &Point3::new(20.0, 4.0, 100.0),
            10.0,
        );
        // A part long along z, thin along y.
        let cad: Vec<Point3> = (0..400)
            .map(|i| {
                let t = f64::from(i);
                Point3::new(15.0 * (t * 0.37).sin(), 2.0 * (t * 0.91).cos(), t * 0.25)
            })
            .collect();
        let terms = prior_terms(&field, &cad, &DeformationSettings::default());
        let count = |k: PriorKind| terms.iter().filter(|t| t.kind == k).count();
        assert!(count(PriorKind::Span) > 0 && count(PriorKind::Beam) > 0);
        assert!(count(PriorKind::Other) > 0);
        for t in terms.iter().filter(|t| t.kind == PriorKind::Span) {
            for (_, a) in &t.entries {
                // Along the CAD's longest principal axis, within a degree of z here.
                assert!(
                    a.x.hypot(a.y) < 0.02 * a.norm(),
                    "span term off the span: {a:?}"
                );
            }
        }
        let dim = 3 * field.len();
        let build = |pick: &dyn Fn(&PriorTerm) -> f64| {
            let (mut h, mut g) = (DMatrix::zeros(dim, dim), DVector::zeros(dim));
            add_prior_weighted(&mut h, &mut g, &field, &terms, 2.0, &pick);
            h
        };
        let posterior = build(&PriorTerm::posterior_share);
        let parts = build(&|t: &PriorTerm| match t.kind {
            PriorKind::Span | PriorKind::Beam => 1.0,
            PriorKind::Other => 0.0,
        }) + build(&|t: &PriorTerm| match t.kind {
            PriorKind::Other => POSTERIOR_PRIOR_SCALE,
            _ => 0.0,
        });
        assert!((&posterior - &parts).amax() < 1e-12);
        let whole = build(&|_: &PriorTerm| 1.0);
        assert!(
            (&posterior - &whole).amax() > 1e-3,
            "the rest is not relaxed"
        );
    }

    /// The model check's carried normal matrix (only matches whose Huber weight changed added
    /// back) gives the field of a full re-weighted rebuild every pass: matches on a slab's two
    /// faces, a third of them 30–60 µm off (beyond the 20 µm Huber threshold, so their weights
    /// change from pass to pass), against the fit's field.
    #[test]
    fn the_model_check_equals_a_rebuild_every_pass() {
        let mut points = Vec::new();
        let mut normals = Vec::new();
        for i in 0..40 {
            for k in 0..100 {
                for (y, n) in [(-4.0, -1.0), (4.0, 1.0)] {
                    points.push(Point3::new(-20.0 + f64::from(i), y, f64::from(k)));
                    normals.push(Vector3::new(0.0, n, 0.0));
                }
            }
        }
        let target = IcpTarget::new(
            PointCloud::with_normals(points.clone(), normals.clone())
                .unwrap_or_else(|e| panic!("{e}")),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let settings = DeformationSettings {
            spacing_mm: 15.0,
            ..DeformationSettings::default()
        };
        let (mut field, _) = zero_field(&target, &settings).unwrap_or_else(|e| panic!("{e}"));
        let step: Vec<f64> = (0..3 * field.len())
            .map(|i| 0.01 * ((i as f64) * 0.7).sin())
            .collect();
        field.add_step(&step);
        let fitted: Vec<Option<Matched>> = points
            .iter()
            .zip(&normals)
            .enumerate()
            .map(|(i, (c, n))| {
                let r = if i % 3 == 0 {
                    0.03 + 0.03 * ((i as f64) * 0.37).sin().abs()
                } else {
                    0.005 * ((i as f64) * 0.11).cos()
                };
                Some((i, *c, *n, r))
            })
            .collect();
        let check_settings = DeformationSettings {
            spacing_mm: settings.spacing_mm * MODEL_CHECK_SPACING_RATIO,
            ..settings
        };
        let check = check_field(&field, &fitted, &target, &check_settings)
            .unwrap_or_else(|e| panic!("{e}"))
            .field;

        // The same passes, the normal equations built from every match each time.
        let (mut rebuilt, prior) =
            zero_field(&target, &check_settings).unwrap_or_else(|e| panic!("{e}"));
        let kernel = RobustKernel::Huber {
            k_mm: check_settings.huber_mm,
        };
        let mut weights_changed = false;
        let mut last: Vec<f64> = Vec::new();
        for pass in 0..check_settings.iterations {
            let pairs: Vec<(Point3, Vector3, f64, f64)> = fitted
                .iter()
                .flatten()
                .map(|&(_, c, n, r)| {
                    let r = r - n.dot(&field.displacement(&c)) + n.dot(&rebuilt.displacement(&c));
                    (c, n, r, kernel.weight(r))
                })
                .collect();
            let weights: Vec<f64> = pairs.iter().map(|p| p.3).collect();
            weights_changed |= pass > 0 && weights != last;
            last = weights;
            damped_step(
                &mut rebuilt,
                &pairs,
                &prior,
                check_settings.smoothness,
                "rebuilt",
            )
            .unwrap_or_else(|e| panic!("{e}"));
        }
        assert!(weights_changed, "the case does not change a Huber weight");
        let worst = check
            .coefficients()
            .iter()
            .zip(rebuilt.coefficients())
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        let largest = rebuilt
            .coefficients()
            .iter()
            .map(|c| c.norm())
            .fold(0.0, f64::max);
        assert!(largest > 1e-3, "the check field is {largest} mm");
        assert!(
            worst < 1e-9,
            "the check differs from the rebuild by {worst} mm"
        );
    }

    /// The Kronecker-structured normal equations equal the dense `Σ w a aᵀ`, `Σ w a r` with
    /// `a = Bₖ(c) n` built entry by entry.
    #[test]
    fn the_normal_equations_equal_the_dense_sums() {
        let field = BSplineField::zero(
            &Point3::new(-20.0, -4.0, 0.0),
            &Point3::new(20.0, 4.0, 100.0),
            10.0,
        );
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut draw = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let pairs: Vec<(Point3, Vector3, f64, f64)> = (0..500)
            .map(|_| {
                let c = Point3::new(-20.0 + 40.0 * draw(), -4.0 + 8.0 * draw(), 100.0 * draw());
                let n = Vector3::new(draw() - 0.5, draw() - 0.5, draw() - 0.5).normalize();
                (c, n, 0.1 * (draw() - 0.5), 0.2 + draw())
            })
            .collect();
        let (h, g) = field_normal_equations(&field, &pairs);
        let dim = 3 * field.len();
        let mut h_dense = DMatrix::<f64>::zeros(dim, dim);
        let mut g_dense = DVector::<f64>::zeros(dim);
        for (c, n, r, w) in &pairs {
            let (index, value) = field.values(c);
            let mut a = DVector::<f64>::zeros(dim);
            for k in 0..SUPPORT {
                for x in 0..3 {
                    a[3 * index[k] + x] += value[k] * n[x];
                }
            }
            h_dense += &a * a.transpose() * *w;
            g_dense += &a * (*w * *r);
        }
        assert!((&h - &h_dense).amax() < 1e-12 * h_dense.amax(), "H");
        assert!(
            (&g - &g_dense).amax() < 1e-12 * g_dense.amax().max(1e-300),
            "g"
        );
    }

    #[test]
    fn a_beam_bend_a_twist_and_affine_motion_cost_nothing_a_bare_along_span_shear_does() {
        let kappa = 1e-4;
        // A bend across the span in x and in y, each with its plane sections.
        let bend = beam_energy(|x, y, z| {
            Vector3::new(
                kappa * z * z / 2.0,
                0.5 * kappa * z * z / 2.0,
                -kappa * x * z - 0.5 * kappa * y * z,
            )
        });
        // A twist about the span and an anisotropic, sheared affine map.
        let twist = beam_energy(|x, y, z| Vector3::new(-1e-4 * z * y, 1e-4 * z * x, 0.0));
        let affine = beam_energy(|x, y, z| {
            Vector3::new(0.01 * x + 0.003 * z, -0.02 * y, 0.015 * z + 0.002 * x)
        });
        // The slide of the edges along the span that a bend would carry, without the bend.
        let shear = beam_energy(|x, _, z| Vector3::new(0.0, 0.0, -kappa * x * z));
        assert!(bend < 1e-20, "bend {bend:e}");
        assert!(twist < 1e-20, "twist {twist:e}");
        assert!(affine < 1e-20, "affine {affine:e}");
        // Each interior term sees κh² = 0.01 mm.
        assert!(shear > 1e-5, "shear {shear:e}");
    }
}
