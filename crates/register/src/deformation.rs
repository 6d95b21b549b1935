//! A smooth displacement field over the part: a uniform quadratic B-spline (C¹) free-form
//! deformation (Rueckert et al., "Nonrigid registration using free-form deformations", IEEE TMI
//! 18(8), 1999, Eq. 3, with quadratic instead of cubic basis functions).
//!
//! `d(x) = Σₖ Bₖ(x) δₖ` over a grid of control displacements `δₖ` with spacing `h`;
//! `F(x) = x + d(x)`. In a cell with local coordinate `t ∈ [0, 1)` the 1-D basis is
//! `B₀ = (1 − t)²/2`, `B₁ = (−2t² + 2t + 1)/2`, `B₂ = t²/2`; the 3-D weights are their products.
//! Quadratic B-splines reproduce every polynomial of degree ≤ 2 per axis, so bending, twist and
//! anisotropic scale are in the span.

use nalgebra::Matrix3;
use trim_geom::{Point3, Vector3};

/// Control points influencing one position (3 per axis).
pub const SUPPORT: usize = 27;

/// The basis weights of one position: control indices, weights and spatial gradients.
#[derive(Debug, Clone, Copy)]
pub struct Weights {
    /// Flat control-point indices.
    pub index: [usize; SUPPORT],
    /// `Bₖ(x)`.
    pub value: [f64; SUPPORT],
    /// `∇Bₖ(x)`, per mm.
    pub gradient: [Vector3; SUPPORT],
    /// The flat index of the grid cell: positions in one cell share `index`.
    pub cell: usize,
}

/// A quadratic B-spline displacement field on an axis-aligned grid (frame of the points it is
/// evaluated at, mm).
#[derive(Debug, Clone, PartialEq)]
pub struct BSplineField {
    origin: Point3,
    spacing_mm: f64,
    cells: [usize; 3],
    /// Axes by increasing control-point count: the flat index runs fastest along `order[0]`,
    /// so the normal matrix is banded with the smallest bandwidth.
    order: [usize; 3],
    coefficients: Vec<Vector3>,
}

fn basis(t: f64) -> ([f64; 3], [f64; 3]) {
    (
        [
            0.5 * (1.0 - t) * (1.0 - t),
            0.5 * (-2.0 * t * t + 2.0 * t + 1.0),
            0.5 * t * t,
        ],
        [t - 1.0, 1.0 - 2.0 * t, t],
    )
}

/// A finite-difference stencil over control points: their flat indices and coefficients.
pub type Stencil = (Vec<usize>, Vec<f64>);

impl BSplineField {
    /// A zero field covering the box `[min, max]` with cells of `spacing_mm` (at least one per
    /// axis).
    #[must_use]
    pub fn zero(min: &Point3, max: &Point3, spacing_mm: f64) -> Self {
        let extent = max - min;
        let cells = [0, 1, 2].map(|a| ((extent[a] / spacing_mm).ceil() as usize).max(1));
        let n = (cells[0] + 2) * (cells[1] + 2) * (cells[2] + 2);
        let mut order = [0, 1, 2];
        order.sort_by_key(|&a| (cells[a], a));
        BSplineField {
            origin: *min,
            spacing_mm,
            cells,
            order,
            coefficients: vec![Vector3::zeros(); n],
        }
    }

    /// Control points per axis (`cells + 2`).
    #[must_use]
    pub fn dims(&self) -> [usize; 3] {
        self.cells.map(|c| c + 2)
    }

    /// Number of control points.
    #[must_use]
    pub fn len(&self) -> usize {
        self.coefficients.len()
    }

    /// Whether the field has no control points (never: at least 27).
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.coefficients.is_empty()
    }

    /// Grid spacing, mm.
    #[must_use]
    pub fn spacing_mm(&self) -> f64 {
        self.spacing_mm
    }

    /// The control displacements, mm.
    #[must_use]
    pub fn coefficients(&self) -> &[Vector3] {
        &self.coefficients
    }

    /// Adds `step` (3 entries per control point) to the control displacements.
    pub fn add_step(&mut self, step: &[f64]) {
        for (k, c) in self.coefficients.iter_mut().enumerate() {
            *c += Vector3::new(step[3 * k], step[3 * k + 1], step[3 * k + 2]);
        }
    }

    /// The flat index of control point `(i, j, k)` (along x, y, z).
    #[must_use]
    pub fn flat(&self, i: usize, j: usize, k: usize) -> usize {
        let d = self.dims();
        let ijk = [i, j, k];
        let [a, b, c] = self.order;
        ijk[a] + d[a] * (ijk[b] + d[b] * ijk[c])
    }

    /// The half-bandwidth of the normal matrix in unknowns (3 per control point): control
    /// points sharing a cell differ by at most this in flat index, times 3, plus 2.
    #[must_use]
    pub fn bandwidth(&self) -> usize {
        let d = self.dims();
        let [a, b, _] = self.order;
        3 * (2 + 2 * d[a] + 2 * d[a] * d[b]) + 2
    }

    /// The half-bandwidth in unknowns once a prior of [`Self::differences`] of `order` is
    /// added: its stencils reach `order` control points along an axis (at least the two of a
    /// cell).
    #[must_use]
    pub fn bandwidth_with_prior(&self, order: usize) -> usize {
        let d = self.dims();
        let [a, b, _] = self.order;
        let reach = order.max(2);
        3 * (reach * (1 + d[a] + d[a] * d[b])) + 2
    }

    /// The cell of `x` (per axis) and its 1-D basis values and derivatives (per mm).
    #[inline]
    fn locate(&self, x: &Point3) -> ([usize; 3], [[f64; 3]; 3], [[f64; 3]; 3]) {
        let h = self.spacing_mm;
        let mut cell = [0usize; 3];
        let mut b = [[0.0; 3]; 3];
        let mut db = [[0.0; 3]; 3];
        for a in 0..3 {
            let s = (x[a] - self.origin[a]) / h;
            let i = (s.floor().max(0.0) as usize).min(self.cells[a] - 1);
            let (v, d) = basis(s - i as f64);
            cell[a] = i;
            b[a] = v;
            db[a] = d.map(|g| g / h);
        }
        (cell, b, db)
    }

    /// The flat-index step of one control point along each axis (x, y, z): [`Self::flat`] is
    /// `i·s₀ + j·s₁ + k·s₂`.
    #[inline]
    fn strides(&self) -> [usize; 3] {
        let d = self.dims();
        let [a, b, c] = self.order;
        let mut s = [0; 3];
        s[a] = 1;
        s[b] = d[a];
        s[c] = d[a] * d[b];
        s
    }

    /// The flat index of the grid cell holding `x` (as [`Weights::cell`]).
    #[must_use]
    pub fn cell_index(&self, x: &Point3) -> usize {
        let (cell, _, _) = self.locate(x);
        cell[0] + self.cells[0] * (cell[1] + self.cells[1] * cell[2])
    }

    /// The control indices and basis values at `x` (as [`Weights::index`] and
    /// [`Weights::value`], without the gradients).
    #[must_use]
    #[inline]
    pub fn values(&self, x: &Point3) -> ([usize; SUPPORT], [f64; SUPPORT]) {
        let (cell, b, _) = self.locate(x);
        let s = self.strides();
        let base = cell[0] * s[0] + cell[1] * s[1] + cell[2] * s[2];
        let mut index = [0; SUPPORT];
        let mut value = [0.0; SUPPORT];
        let mut n = 0;
        for k in 0..3 {
            for j in 0..3 {
                for i in 0..3 {
                    index[n] = base + i * s[0] + j * s[1] + k * s[2];
                    value[n] = b[0][i] * b[1][j] * b[2][k];
                    n += 1;
                }
            }
        }
        (index, value)
    }

    /// The basis weights at `x` (outside the box the edge cells' polynomials extend).
    #[must_use]
    pub fn weights(&self, x: &Point3) -> Weights {
        let (cell, b, db) = self.locate(x);
        let s = self.strides();
        let base = cell[0] * s[0] + cell[1] * s[1] + cell[2] * s[2];
        let mut w = Weights {
            index: [0; SUPPORT],
            value: [0.0; SUPPORT],
            gradient: [Vector3::zeros(); SUPPORT],
            cell: cell[0] + self.cells[0] * (cell[1] + self.cells[1] * cell[2]),
        };
        let mut n = 0;
        for k in 0..3 {
            for j in 0..3 {
                for i in 0..3 {
                    w.index[n] = base + i * s[0] + j * s[1] + k * s[2];
                    w.value[n] = b[0][i] * b[1][j] * b[2][k];
                    w.gradient[n] = Vector3::new(
                        db[0][i] * b[1][j] * b[2][k],
                        b[0][i] * db[1][j] * b[2][k],
                        b[0][i] * b[1][j] * db[2][k],
                    );
                    n += 1;
                }
            }
        }
        w
    }

    /// The displacement `d(x)`, mm. Summed over the control points as [`Self::values`] lists
    /// them, the same terms in the same order as [`Self::displacement_from`], without building
    /// the 27 indices and values first (returned by value, they were copied on every call).
    #[must_use]
    pub fn displacement(&self, x: &Point3) -> Vector3 {
        let (cell, b, _) = self.locate(x);
        let s = self.strides();
        let base = cell[0] * s[0] + cell[1] * s[1] + cell[2] * s[2];
        let mut d = Vector3::zeros();
        for k in 0..3 {
            for j in 0..3 {
                for i in 0..3 {
                    let value = b[0][i] * b[1][j] * b[2][k];
                    d += value * self.coefficients[base + i * s[0] + j * s[1] + k * s[2]];
                }
            }
        }
        d
    }

    /// The displacement at a point whose control indices and basis values ([`Self::values`])
    /// were taken before, mm: the same field evaluated again without locating the point.
    #[must_use]
    #[inline]
    pub fn displacement_from(&self, index: &[usize; SUPPORT], value: &[f64; SUPPORT]) -> Vector3 {
        (0..SUPPORT)
            .map(|n| value[n] * self.coefficients[index[n]])
            .sum()
    }

    /// The displacement and its Jacobian `∂d/∂x` at `x`: the terms of [`Self::weights`] in its
    /// order, without building them first (as [`Self::displacement`]).
    #[must_use]
    pub fn displacement_and_jacobian(&self, x: &Point3) -> (Vector3, Matrix3<f64>) {
        let (cell, b, db) = self.locate(x);
        let s = self.strides();
        let base = cell[0] * s[0] + cell[1] * s[1] + cell[2] * s[2];
        let mut d = Vector3::zeros();
        let mut jac = Matrix3::zeros();
        for k in 0..3 {
            for j in 0..3 {
                for i in 0..3 {
                    let c = self.coefficients[base + i * s[0] + j * s[1] + k * s[2]];
                    let value = b[0][i] * b[1][j] * b[2][k];
                    let gradient = Vector3::new(
                        db[0][i] * b[1][j] * b[2][k],
                        b[0][i] * db[1][j] * b[2][k],
                        b[0][i] * b[1][j] * db[2][k],
                    );
                    d += value * c;
                    jac += c * gradient.transpose();
                }
            }
        }
        (d, jac)
    }

    /// `F(x) = x + d(x)`.
    #[must_use]
    pub fn apply(&self, x: &Point3) -> Point3 {
        x + self.displacement(x)
    }

    /// A normal (or feature vector) carried by `F` at `x`: `(I + ∂d/∂x)⁻ᵀ n`, unit length.
    #[must_use]
    pub fn apply_normal(&self, x: &Point3, n: &Vector3) -> Vector3 {
        let (_, j) = self.displacement_and_jacobian(x);
        let m = Matrix3::identity() + j;
        let out = m.try_inverse().map_or(*n, |inv| inv.transpose() * n);
        let norm = out.norm();
        if norm > 0.0 { out / norm } else { *n }
    }

    /// `F⁻¹(y)` by fixed-point iteration `x ← y − d(x)` (converges while `|∂d/∂x| < 1`).
    #[must_use]
    pub fn inverse_apply(&self, y: &Point3, iterations: usize) -> Point3 {
        let mut x = *y;
        for _ in 0..iterations {
            x = y - self.displacement(&x);
        }
        x
    }

    /// The `order`-th finite differences of the control displacements along each axis (per
    /// displacement component): order 2 is `δ₋ − 2δ₀ + δ₊` (affine fields have zero energy),
    /// order 3 is `−δ₀ + 3δ₁ − 3δ₂ + δ₃` (fields quadratic along each axis, such as a bend or a
    /// twist, have zero energy). Returns the stencils as `(indices, coefficients)`; orders other
    /// than 1–3 give none.
    #[must_use]
    pub fn differences(&self, order: usize) -> Vec<Stencil> {
        self.differences_along(order)
            .into_iter()
            .map(|(_, s)| s)
            .collect()
    }

    /// [`Self::differences`], each stencil with the grid axis (0 = x, 1 = y, 2 = z) it runs
    /// along.
    #[must_use]
    pub fn differences_along(&self, order: usize) -> Vec<(usize, Stencil)> {
        let coefficients: Vec<f64> = match order {
            1 => vec![-1.0, 1.0],
            2 => vec![1.0, -2.0, 1.0],
            3 => vec![-1.0, 3.0, -3.0, 1.0],
            _ => return Vec::new(),
        };
        let d = self.dims();
        let mut out = Vec::new();
        for k in 0..d[2] {
            for j in 0..d[1] {
                for i in 0..d[0] {
                    let start = [i, j, k];
                    for axis in 0..3 {
                        if start[axis] + order >= d[axis] {
                            continue;
                        }
                        let index = (0..=order)
                            .map(|m| {
                                let mut at = start;
                                at[axis] += m;
                                self.flat(at[0], at[1], at[2])
                            })
                            .collect();
                        out.push((axis, (index, coefficients.clone())));
                    }
                }
            }
        }
        out
    }

    /// The second-difference smoothness operator: for every control point with neighbours on
    /// both sides along an axis, the stencil `δ₋ − 2δ₀ + δ₊` (per displacement component).
    /// Returns the stencils as `(indices, coefficients)`; affine fields have zero energy.
    #[must_use]
    pub fn second_differences(&self) -> Vec<([usize; 3], [f64; 3])> {
        let d = self.dims();
        let mut out = Vec::new();
        for k in 0..d[2] {
            for j in 0..d[1] {
                for i in 0..d[0] {
                    let c = self.flat(i, j, k);
                    if i > 0 && i + 1 < d[0] {
                        out.push((
                            [self.flat(i - 1, j, k), c, self.flat(i + 1, j, k)],
                            [1.0, -2.0, 1.0],
                        ));
                    }
                    if j > 0 && j + 1 < d[1] {
                        out.push((
                            [self.flat(i, j - 1, k), c, self.flat(i, j + 1, k)],
                            [1.0, -2.0, 1.0],
                        ));
                    }
                    if k > 0 && k + 1 < d[2] {
                        out.push((
                            [self.flat(i, j, k - 1), c, self.flat(i, j, k + 1)],
                            [1.0, -2.0, 1.0],
                        ));
                    }
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_partition_unity_and_reproduce_quadratics() {
        let mut f = BSplineField::zero(
            &Point3::new(-20.0, -50.0, -5.0),
            &Point3::new(20.0, 50.0, 5.0),
            10.0,
        );
        // Fit a quadratic field exactly by least squares on samples, then check it elsewhere.
        let target = |p: &Point3| {
            Vector3::new(
                1e-3 * p.y * p.y,
                2e-3 * p.x * p.y,
                0.01 * p.z - 1e-4 * p.x * p.x,
            )
        };
        let n = 3 * f.len();
        let mut h = nalgebra::DMatrix::<f64>::zeros(n, n);
        let mut g = nalgebra::DVector::<f64>::zeros(n);
        for i in 0..20 {
            for j in 0..50 {
                for k in 0..5 {
                    let p = Point3::new(
                        -19.0 + 2.0 * f64::from(i),
                        -49.0 + 2.0 * f64::from(j),
                        -4.0 + 2.0 * f64::from(k),
                    );
                    let w = f.weights(&p);
                    let t = target(&p);
                    for a in 0..SUPPORT {
                        for b in 0..SUPPORT {
                            for c in 0..3 {
                                h[(3 * w.index[a] + c, 3 * w.index[b] + c)] +=
                                    w.value[a] * w.value[b];
                            }
                        }
                        for c in 0..3 {
                            g[3 * w.index[a] + c] += w.value[a] * t[c];
                        }
                    }
                }
            }
        }
        for i in 0..n {
            h[(i, i)] += 1e-9;
        }
        let step = h.cholesky().unwrap().solve(&g);
        f.add_step(step.as_slice());
        let w = f.weights(&Point3::new(3.3, -7.1, 1.2));
        assert!((w.value.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        for p in [Point3::new(3.3, -7.1, 1.2), Point3::new(-17.0, 44.0, -3.0)] {
            let (d, j) = f.displacement_and_jacobian(&p);
            // The three evaluations sum the same terms in the same order: equal to the bit
            // (the fit's thresholds amplify a last-bit difference).
            let (index, value) = f.values(&p);
            assert_eq!(d, f.displacement(&p));
            assert_eq!(d, f.displacement_from(&index, &value));
            assert!((d - target(&p)).norm() < 1e-6, "{d} vs {}", target(&p));
            let e = 1e-5;
            let fd = (f.displacement(&(p + Vector3::x() * e))
                - f.displacement(&(p - Vector3::x() * e)))
                / (2.0 * e);
            assert!((j.column(0) - fd).norm() < 1e-6);
            let y = f.apply(&p);
            assert!((f.inverse_apply(&y, 20) - p).norm() < 1e-9);
        }
        // The strided indices are `flat`'s.
        let p = Point3::new(3.3, -7.1, 1.2);
        let (index, value) = f.values(&p);
        let w = f.weights(&p);
        assert_eq!(index, w.index);
        assert_eq!(value, w.value);
        assert_eq!(f.cell_index(&p), w.cell);
        let d = f.dims();
        let s = f.strides();
        for (i, j, k) in [(0, 0, 0), (1, 2, 3), (d[0] - 1, d[1] - 1, d[2] - 1)] {
            assert_eq!(f.flat(i, j, k), i * s[0] + j * s[1] + k * s[2]);
        }
        // Affine fields have zero smoothness energy.
        let mut affine =
            BSplineField::zero(&Point3::origin(), &Point3::new(30.0, 30.0, 30.0), 10.0);
        let d = affine.dims();
        let mut step = vec![0.0; 3 * affine.len()];
        for k in 0..d[2] {
            for j in 0..d[1] {
                for i in 0..d[0] {
                    let idx = affine.flat(i, j, k);
                    step[3 * idx] = 0.1 * i as f64 - 0.2 * k as f64;
                }
            }
        }
        affine.add_step(&step);
        for (ix, c) in affine.second_differences() {
            let e: f64 = (0..3).map(|m| c[m] * affine.coefficients()[ix[m]].x).sum();
            assert!(e.abs() < 1e-12);
        }
    }
}
