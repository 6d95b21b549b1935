//! The deformation field: scan → CAD matches (curvature-aware, same face), the Gauss-Newton fit
//! of the B-spline field, and moving contours through it.

use super::*;

/// Levenberg-Marquardt damping of the field's Gauss-Newton step, relative to the mean data
/// weight per unknown.
pub const FIELD_DAMPING: f64 = 1e-3;

/// CAD candidates per scan point; the one whose surface passes closest wins.
pub const MATCH_CANDIDATES: usize = 6;

/// Neighbours used to estimate each CAD point's shape operator.
pub const CURVATURE_NEIGHBOURS: usize = 6;

/// The shape operator `S` of each CAD point (`n(c + t) ≈ n(c) + S t` for a tangential `t`),
/// least squares over its [`CURVATURE_NEIGHBOURS`] nearest neighbours' normals. The residual
/// `n·(q − c) + ½ tᵀ S t` is then the distance to the osculating quadric instead of the tangent
/// plane: without it a scan point on a 1.2 mm hole wall, 0.12 mm from its nearest CAD sample,
/// reads `t²/2R ≈ 6 µm` off, always toward the hole, and half-visible holes shift by that.
#[must_use]
pub fn shape_operators(cad: &PointCloud, tree: &kdtree::KdTree) -> Vec<Matrix3<f64>> {
    let pts = cad.points();
    let Some(normals) = cad.normals() else {
        return vec![Matrix3::zeros(); pts.len()];
    };
    pts.par_iter()
        .zip(normals.par_iter())
        .map_init(Scratch::default, |scratch, (c, n)| {
            // Tangent basis.
            let helper = if n.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            };
            let e1 = n.cross(&helper).normalize();
            let e2 = n.cross(&e1);
            let mut ata = nalgebra::Matrix3::<f64>::zeros();
            let mut atb = Vector3::zeros();
            for nb in tree.knn_within(c, CURVATURE_NEIGHBOURS + 1, f64::INFINITY, scratch) {
                let d = pts[nb.index] - c;
                let dn = normals[nb.index] - n;
                // Only neighbours on the same smooth face (normals within ~25°).
                if d.norm_squared() == 0.0 || normals[nb.index].dot(n) < MIN_SAME_FACE_COS {
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
            let Some(abc) = (ata + Matrix3::identity() * 1e-12)
                .try_inverse()
                .map(|inv| inv * atb)
            else {
                return Matrix3::zeros();
            };
            let (a, b, cc) = (abc[0], abc[1], abc[2]);
            a * e1 * e1.transpose()
                + b * (e1 * e2.transpose() + e2 * e1.transpose())
                + cc * e2 * e2.transpose()
        })
        .collect()
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

/// Matches of the field's points: scan point `q` (CAD frame) to its CAD point under the current
/// field (`F⁻¹(q)`'s nearest CAD point), with the residual along the carried normal.
/// A scan point's match: CAD index, CAD point, carried normal, field Jacobian at the CAD point,
/// residual (mm).
pub(crate) type Matched = (usize, Point3, Vector3, Matrix3<f64>, f64);

pub(crate) fn match_points(
    points: &[Point3],
    target: &IcpTarget,
    curvature: &[Matrix3<f64>],
    field: Option<&BSplineField>,
    max_distance_mm: f64,
) -> Vec<Option<Matched>> {
    let cad = target.cloud().points();
    let normals = target.cloud().normals();
    let d2max = max_distance_mm * max_distance_mm;
    points
        .par_iter()
        .map_init(Scratch::default, |scratch, q| {
            let p = field.map_or(*q, |f| f.inverse_apply(q, 2));
            // Of the nearest CAD points, the one whose surface passes closest to q: near an
            // edge the nearest sample may lie on the other face (a top-face scan point 0.1 mm
            // from a rim finds a wall sample), and its plane would pull sideways.
            let mut best: Option<(f64, usize, Point3, Vector3, Matrix3<f64>, f64)> = None;
            // The field at the nearest candidate; the others (within a millimetre) use its
            // first-order expansion `d(c) ≈ d₀ + J₀ (c − c₀)` and its normal map.
            let mut at_nearest: Option<(Point3, Vector3, Matrix3<f64>, Matrix3<f64>)> = None;
            for nb in target
                .tree()
                .knn_within(&p, MATCH_CANDIDATES, d2max, scratch)
            {
                let c = cad[nb.index];
                let n0 = normals.map_or(Vector3::z(), |ns| ns[nb.index]);
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
                // Distance to the osculating quadric (see `shape_operators`).
                let diff = q - (c + d);
                let t = diff - n * n.dot(&diff);
                let s = curvature
                    .get(nb.index)
                    .copied()
                    .unwrap_or_else(Matrix3::zeros);
                let r = -(n.dot(&diff) + 0.5 * (t.transpose() * s * t)[(0, 0)]);
                if best.is_none_or(|b| r.abs() < b.0) {
                    best = Some((r.abs(), nb.index, c, n, j, r));
                }
            }
            let (_, index, c, n, j, r) = best?;
            Some((index, c, n, j, r))
        })
        .collect()
}

pub(crate) fn final_matches(
    points: &[Point3],
    target: &IcpTarget,
    curvature: &[Matrix3<f64>],
    field: Option<&BSplineField>,
    max_distance_mm: f64,
) -> Vec<Match> {
    match_points(points, target, curvature, field, max_distance_mm)
        .into_iter()
        .zip(points)
        .filter_map(|(m, q)| m.map(|(_, _, n, _, r)| Match { q: *q, n, r }))
        .collect()
}

/// Fits the displacement field (CAD frame) to the scan points `q` (CAD frame).
pub(crate) fn fit_field(
    points: &[Point3],
    target: &IcpTarget,
    curvature: &[Matrix3<f64>],
    settings: &DeformationSettings,
) -> Result<(BSplineField, Vec<Match>)> {
    let bounds = target
        .cloud()
        .bounds()
        .ok_or(RegisterError::EmptyCloud { which: "CAD" })?;
    let pad = Vector3::repeat(0.25 * settings.spacing_mm);
    let mut field = BSplineField::zero(
        &(bounds.min - pad),
        &(bounds.max + pad),
        settings.spacing_mm,
    );
    let dim = 3 * field.len();
    let stencils = field.second_differences();
    let kernel = RobustKernel::Huber {
        k_mm: settings.huber_mm,
    };
    let shrink_steps = settings.iterations.saturating_sub(3).max(1);
    let ratio = settings.max_distance_end_mm / settings.max_distance_start_mm;
    for it in 0..settings.iterations {
        let t = (it as f64 / shrink_steps as f64).min(1.0);
        let max_d = settings.max_distance_start_mm * ratio.powf(t);
        let matched = match_points(points, target, curvature, Some(&field), max_d);
        let pairs: Vec<(Point3, Vector3, f64, f64)> = matched
            .iter()
            .filter_map(|m| m.map(|(_, c, n, _, r)| (c, n, r, kernel.weight(r))))
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
        let (mut h, mut g) = field_normal_equations(&field, &pairs);
        // Smoothness: λ Σ |Σ cₘ δₘ|² per component, λ relative to the mean data weight.
        let mean_diag = h.diagonal().sum() / dim as f64;
        let lambda = settings.smoothness * mean_diag;
        let coeffs = field.coefficients();
        for (ix, c) in &stencils {
            for x in 0..3 {
                let e: f64 = (0..3).map(|m| c[m] * coeffs[ix[m]][x]).sum();
                for a in 0..3 {
                    g[3 * ix[a] + x] += lambda * c[a] * e;
                    for b in 0..3 {
                        h[(3 * ix[a] + x, 3 * ix[b] + x)] += lambda * c[a] * c[b];
                    }
                }
            }
        }
        // Levenberg-Marquardt damping: directions neither the data nor the prior fix (control
        // points far from the scan) take no step instead of an arbitrary one.
        for i in 0..dim {
            h[(i, i)] += FIELD_DAMPING * mean_diag.max(f64::MIN_POSITIVE);
        }
        let step = solve_banded_spd(&h, &(-&g), field.bandwidth()).ok_or_else(|| {
            RegisterError::Singular {
                stage: format!("deformation field, iteration {it}"),
                eigenvalues: Vec::new(),
            }
        })?;
        if step.iter().any(|v| !v.is_finite()) {
            return Err(RegisterError::NonFinite {
                what: format!("deformation field step, iteration {it}"),
            });
        }
        field.add_step(step.as_slice());
    }
    let matches = final_matches(
        points,
        target,
        curvature,
        Some(&field),
        settings.max_distance_end_mm,
    );
    Ok((field, matches))
}

/// `Σ w a aᵀ` and `Σ w a r` with `a = Bₖ(c) n'` (the residual's gradient in `δₖ`), accumulated
/// per grid cell (the points of a cell share their 27 control points, so each cell is one dense
/// 81-column product `Aᵀ W A`), cells in parallel, scattered in cell order (deterministic).
pub(crate) fn field_normal_equations(
    field: &BSplineField,
    pairs: &[(Point3, Vector3, f64, f64)],
) -> (DMatrix<f64>, DVector<f64>) {
    const LOCAL: usize = 3 * SUPPORT;
    let dim = 3 * field.len();
    let mut keyed: Vec<(usize, usize)> = pairs
        .par_iter()
        .enumerate()
        .map(|(i, p)| (field.cell_index(&p.0), i))
        .collect();
    keyed.par_sort_unstable();
    let mut groups: Vec<&[(usize, usize)]> = Vec::new();
    let mut start = 0;
    while start < keyed.len() {
        let mut end = start + 1;
        while end < keyed.len() && keyed[end].0 == keyed[start].0 {
            end += 1;
        }
        groups.push(&keyed[start..end]);
        start = end;
    }
    let locals: Vec<([usize; SUPPORT], DMatrix<f64>, DVector<f64>)> = groups
        .par_iter()
        .map(|group| {
            let n = group.len();
            let mut a = DMatrix::<f64>::zeros(n, LOCAL);
            let mut aw = DMatrix::<f64>::zeros(n, LOCAL);
            let mut gl = DVector::<f64>::zeros(LOCAL);
            let mut index = [0usize; SUPPORT];
            for (row, &(_, i)) in group.iter().enumerate() {
                let (c, nrm, r, w) = pairs[i];
                let (wt_index, wt_value) = field.values(&c);
                index = wt_index;
                for k in 0..SUPPORT {
                    for x in 0..3 {
                        let v = wt_value[k] * nrm[x];
                        a[(row, 3 * k + x)] = v;
                        aw[(row, 3 * k + x)] = w * v;
                        gl[3 * k + x] += w * v * r;
                    }
                }
            }
            (index, aw.transpose() * a, gl)
        })
        .collect();
    let mut h = DMatrix::<f64>::zeros(dim, dim);
    let mut g = DVector::<f64>::zeros(dim);
    for (index, hl, gl) in &locals {
        for ka in 0..SUPPORT {
            for x in 0..3 {
                let ra = 3 * index[ka] + x;
                g[ra] += gl[3 * ka + x];
                for kb in 0..SUPPORT {
                    for y in 0..3 {
                        h[(ra, 3 * index[kb] + y)] += hl[(3 * ka + x, 3 * kb + y)];
                    }
                }
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
