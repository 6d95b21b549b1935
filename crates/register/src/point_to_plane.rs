//! The linearised point-to-plane and point-to-point problems, and their Gauss-Newton step.
//!
//! An incremental similarity about a centre `c` acts as `x' = c + t + e^σ·R(ω)·(x − c)`. To
//! first order `x' ≈ x + ω × (x − c) + t + σ·(x − c)`, so the point-to-plane residual
//! `r = (x − q)·n` (Chen & Medioni 1992; Low 2004, Eq. 6–8) has the Jacobian row
//! `J = [ (x − c) × n,  n,  (x − c)·n ]` in `δ = (ω, t, σ)`, and each point-to-point residual
//! component `k` has `Jₖ = [ (x − c) × eₖ,  eₖ,  (x − c)ₖ ]`. The step solves the normal
//! equations `(Σ w JᵀJ) δ = −Σ w Jᵀ r` (6×6 rigid, 7×7 with scale).

use nalgebra::{SMatrix, SVector, SymmetricEigen, Translation3, UnitQuaternion};
use trim_geom::{Point3, Similarity3, Vector3};

use crate::error::{RegisterError, Result};
use crate::reduce::chunked_sum;

/// 7×7 normal matrix.
pub type Matrix7 = SMatrix<f64, 7, 7>;
/// 7-vector.
pub type Vector7 = SVector<f64, 7>;

/// A step is refused when the smallest eigenvalue of the (per-weight) normal matrix is below
/// this fraction of the largest: the data does not fix some direction.
pub const MIN_EIGENVALUE_RATIO: f64 = 1e-12;

/// One correspondence: current source point `x`, target point `q`, target unit normal `n` (zero
/// for point-to-point), IRLS weight `w`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pair {
    /// The source point in the target frame (current estimate), mm.
    pub x: Point3,
    /// The target point, mm.
    pub q: Point3,
    /// The target's unit normal at `q` (point-to-plane only).
    pub n: Vector3,
    /// The weight.
    pub w: f64,
}

/// The accumulated normal equations `H δ = −g`, with the weight sum and weighted squared
/// residual sum.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalEquations {
    /// `Σ w JᵀJ`.
    pub h: Matrix7,
    /// `Σ w Jᵀ r`.
    pub g: Vector7,
    /// `Σ w`.
    pub weight: f64,
    /// `Σ w r²`, mm².
    pub weighted_sq: f64,
}

impl NormalEquations {
    fn zero() -> Self {
        NormalEquations {
            h: Matrix7::zeros(),
            g: Vector7::zeros(),
            weight: 0.0,
            weighted_sq: 0.0,
        }
    }

    fn add(&mut self, other: &Self) {
        self.h += other.h;
        self.g += other.g;
        self.weight += other.weight;
        self.weighted_sq += other.weighted_sq;
    }

    fn add_row(&mut self, j: &Vector7, r: f64, w: f64) {
        // Only the upper triangle; mirrored once at the end.
        for a in 0..7 {
            let wja = w * j[a];
            for b in a..7 {
                self.h[(a, b)] += wja * j[b];
            }
            self.g[a] += wja * r;
        }
        self.weight += w;
        self.weighted_sq += w * r * r;
    }

    fn mirror(&mut self) {
        for a in 0..7 {
            for b in 0..a {
                self.h[(a, b)] = self.h[(b, a)];
            }
        }
    }

    /// The eigenvalues (ascending) of the per-weight normal matrix: the leading 6×6 block for a
    /// rigid problem, all 7×7 with scale.
    #[must_use]
    pub fn eigenvalues(&self, with_scale: bool) -> Vec<f64> {
        let norm = if self.weight > 0.0 { self.weight } else { 1.0 };
        let mut v: Vec<f64> = if with_scale {
            SymmetricEigen::new(self.h / norm)
                .eigenvalues
                .iter()
                .copied()
                .collect()
        } else {
            let h6: SMatrix<f64, 6, 6> = self.h.fixed_view::<6, 6>(0, 0).into();
            SymmetricEigen::new(h6 / norm)
                .eigenvalues
                .iter()
                .copied()
                .collect()
        };
        v.sort_by(f64::total_cmp);
        v
    }
}

/// The weighted centroid of the pairs' source points.
#[must_use]
pub fn weighted_centre(pairs: &[Pair]) -> Point3 {
    let (sum, w) = chunked_sum(
        pairs.len(),
        (Vector3::zeros(), 0.0),
        |acc, i| {
            acc.0 += pairs[i].w * pairs[i].x.coords;
            acc.1 += pairs[i].w;
        },
        |a, b| {
            a.0 += b.0;
            a.1 += b.1;
        },
    );
    if w > 0.0 {
        Point3::from(sum / w)
    } else {
        Point3::origin()
    }
}

/// Accumulates the point-to-plane normal equations about `centre` (deterministic, parallel).
#[must_use]
pub fn point_to_plane_equations(pairs: &[Pair], centre: &Point3) -> NormalEquations {
    let mut eq = chunked_sum(
        pairs.len(),
        NormalEquations::zero(),
        |acc, i| {
            let p = &pairs[i];
            let d = p.x - centre;
            let c = d.cross(&p.n);
            let j = Vector7::from_column_slice(&[c.x, c.y, c.z, p.n.x, p.n.y, p.n.z, d.dot(&p.n)]);
            acc.add_row(&j, (p.x - p.q).dot(&p.n), p.w);
        },
        NormalEquations::add,
    );
    eq.mirror();
    eq
}

/// Accumulates the point-to-point normal equations about `centre` (three rows per pair).
#[must_use]
pub fn point_to_point_equations(pairs: &[Pair], centre: &Point3) -> NormalEquations {
    let mut eq = chunked_sum(
        pairs.len(),
        NormalEquations::zero(),
        |acc, i| {
            let p = &pairs[i];
            let d = p.x - centre;
            let r = p.x - p.q;
            for k in 0..3 {
                let mut e = Vector3::zeros();
                e[k] = 1.0;
                let c = d.cross(&e);
                let j = Vector7::from_column_slice(&[c.x, c.y, c.z, e.x, e.y, e.z, d[k]]);
                acc.add_row(&j, r[k], p.w);
            }
        },
        NormalEquations::add,
    );
    eq.mirror();
    eq
}

/// Solves the normal equations for the increment and returns it as a transform in the target
/// frame (`new_target_from_source = increment · old`). Refuses a singular system, naming
/// `stage`.
pub fn solve_increment(
    eq: &NormalEquations,
    centre: &Point3,
    with_scale: bool,
    stage: &str,
) -> Result<Similarity3> {
    let eig = eq.eigenvalues(with_scale);
    let (lo, hi) = (eig[0], eig[eig.len() - 1]);
    if !(hi > 0.0 && lo > MIN_EIGENVALUE_RATIO * hi) {
        return Err(RegisterError::Singular {
            stage: stage.to_string(),
            eigenvalues: eig,
        });
    }
    let delta: Vector7 = if with_scale {
        eq.h.cholesky()
            .map(|c| c.solve(&(-eq.g)))
            .ok_or_else(|| RegisterError::Singular {
                stage: stage.to_string(),
                eigenvalues: eig.clone(),
            })?
    } else {
        let h6: SMatrix<f64, 6, 6> = eq.h.fixed_view::<6, 6>(0, 0).into();
        let g6: SVector<f64, 6> = eq.g.fixed_rows::<6>(0).into();
        let d6 = h6
            .cholesky()
            .map(|c| c.solve(&(-g6)))
            .ok_or_else(|| RegisterError::Singular {
                stage: stage.to_string(),
                eigenvalues: eig.clone(),
            })?;
        Vector7::from_column_slice(&[d6[0], d6[1], d6[2], d6[3], d6[4], d6[5], 0.0])
    };
    if delta.iter().any(|v| !v.is_finite()) {
        return Err(RegisterError::NonFinite {
            what: format!("{stage}: Gauss-Newton step"),
        });
    }
    Ok(increment(&delta, centre))
}

/// The similarity `x ↦ c + t + e^σ R(ω)(x − c)` of a step `δ = (ω, t, σ)`.
#[must_use]
pub fn increment(delta: &Vector7, centre: &Point3) -> Similarity3 {
    let omega = Vector3::new(delta[0], delta[1], delta[2]);
    let t = Vector3::new(delta[3], delta[4], delta[5]);
    let scale = delta[6].exp();
    let to_origin = Similarity3::from_parts(
        Translation3::from(-centre.coords),
        UnitQuaternion::identity(),
        1.0,
    );
    let about = Similarity3::from_parts(
        Translation3::from(centre.coords + t),
        UnitQuaternion::from_scaled_axis(omega),
        scale,
    );
    about * to_origin
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_step_recovers_a_small_motion_on_a_box() {
        // Points on the six faces of a box, normals outward: every direction is constrained.
        let truth = Similarity3::new(
            Vector3::new(0.01, -0.02, 0.005),
            Vector3::new(0.001, 0.002, -0.001),
            1.0,
        );
        let mut pairs = Vec::new();
        for i in -5..=5 {
            for j in -5..=5 {
                let (a, b) = (f64::from(i), f64::from(j));
                for (q, n) in [
                    (Point3::new(a, b, 5.0), Vector3::z()),
                    (Point3::new(a, b, -5.0), -Vector3::z()),
                    (Point3::new(a, 5.0, b), Vector3::y()),
                    (Point3::new(a, -5.0, b), -Vector3::y()),
                    (Point3::new(5.0, a, b), Vector3::x()),
                    (Point3::new(-5.0, a, b), -Vector3::x()),
                ] {
                    // The source point is the target point moved by truth⁻¹.
                    pairs.push(Pair {
                        x: truth.inverse() * q,
                        q,
                        n,
                        w: 1.0,
                    });
                }
            }
        }
        let c = weighted_centre(&pairs);
        let eq = point_to_plane_equations(&pairs, &c);
        let inc = solve_increment(&eq, &c, true, "test").unwrap();
        assert!((inc.to_homogeneous() - truth.to_homogeneous()).norm() < 1e-4);
        let eq2 = point_to_point_equations(&pairs, &c);
        assert_eq!(eq2.eigenvalues(true).len(), 7);
    }

    #[test]
    fn a_plane_is_singular() {
        let pairs: Vec<Pair> = (0..100)
            .map(|i| {
                let p = Point3::new(f64::from(i % 10), f64::from(i / 10), 0.0);
                Pair {
                    x: p,
                    q: p,
                    n: Vector3::z(),
                    w: 1.0,
                }
            })
            .collect();
        let c = weighted_centre(&pairs);
        let eq = point_to_plane_equations(&pairs, &c);
        assert!(matches!(
            solve_increment(&eq, &c, false, "plane"),
            Err(RegisterError::Singular { .. })
        ));
    }
}
