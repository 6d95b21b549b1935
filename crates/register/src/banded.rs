//! Cholesky factorisation of a symmetric positive-definite matrix known to be banded (entries
//! beyond `bandwidth` from the diagonal are zero): `O(n·b²)` instead of `O(n³)`. Used for the
//! deformation field's normal equations, whose control points couple only within a cell.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

/// `Σ xᵢ yᵢ` over two slices of one length, in four running sums (the compiler keeps one strict
/// sum in order and cannot vectorise it; four independent ones it can): most of the factor's
/// time is these dot products.
fn dot(x: &[f64], y: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let (xc, yc) = (x.chunks_exact(4), y.chunks_exact(4));
    let (xr, yr) = (xc.remainder(), yc.remainder());
    for (a, b) in xc.zip(yc) {
        for k in 0..4 {
            acc[k] += a[k] * b[k];
        }
    }
    let tail: f64 = xr.iter().zip(yr).map(|(a, b)| a * b).sum();
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// The Cholesky factor `L` (`A = L Lᵀ`) of a symmetric positive-definite matrix with half-bandwidth
/// `bandwidth`, stored by rows within the band: factor once, then solve for as many right-hand
/// sides as needed (the model check solves ten with one matrix).
#[derive(Debug, Clone)]
pub struct BandedCholesky {
    n: usize,
    bw: usize,
    /// Row `i` holds `L[i][i − bw ..= i]` contiguously: `L[i][k]` at `l[i·(bw + 1) + k + bw − i]`.
    l: Vec<f64>,
    /// `first[i]`: the first column of row `i` of `A` (and so of `L`) that is not zero.
    first: Vec<usize>,
}

impl BandedCholesky {
    /// Factors `a`, reading only its lower triangle within `bandwidth`. `None` if `a` is not
    /// square or not positive definite.
    ///
    /// The factor keeps `A`'s profile (row `i` of `L` is zero before row `i` of `A`'s first
    /// nonzero), so each row's products start there: the field's matrices reach back less than
    /// the bandwidth their grid allows in most rows (the prior's third differences along the
    /// slowest axis reach farthest, the data only a cell), and the factor's work is the square
    /// of the reach.
    #[must_use]
    pub fn factor(a: &DMatrix<f64>, bandwidth: usize) -> Option<Self> {
        let n = a.nrows();
        if a.ncols() != n {
            return None;
        }
        let bw = bandwidth.min(n.saturating_sub(1));
        let w = bw + 1;
        let first: Vec<usize> = (0..n)
            .map(|i| {
                (i.saturating_sub(bw)..i)
                    .find(|&j| a[(i, j)] != 0.0)
                    .unwrap_or(i)
            })
            .collect();
        let mut l = vec![0.0; n * w];
        // Row by row: each entry is one contiguous dot product of two rows, over the columns
        // where both may be nonzero. The products start at a multiple of four columns from the
        // band's edge, so that each of `dot`'s four running sums takes the same nonzero terms
        // in the same order as over the whole band (the ones skipped are exact zeros): the
        // factor is the same to the bit, which the field's fit needs (its matches decide on
        // thresholds, and a last-bit change of a step moves a registered path by tenths of a
        // micrometre).
        for i in 0..n {
            let band_lo = i.saturating_sub(bw);
            for j in first[i]..=i {
                let lo = first[i].max(first[j]);
                let lo = band_lo + (lo - band_lo) / 4 * 4;
                // Σ_k L[i][k] L[j][k] over k in lo..j.
                let ri = &l[i * w + (lo + bw - i)..i * w + (j + bw - i)];
                let rj = &l[j * w + (lo + bw - j)..j * w + bw];
                let dot = dot(ri, rj);
                let v = a[(i, j)] - dot;
                if j == i {
                    if !(v > 0.0 && v.is_finite()) {
                        return None;
                    }
                    l[i * w + bw] = v.sqrt();
                } else {
                    l[i * w + (j + bw - i)] = v / l[j * w + bw];
                }
            }
        }
        Some(BandedCholesky { n, bw, l, first })
    }

    /// The matrix's order.
    #[must_use]
    pub fn dim(&self) -> usize {
        self.n
    }

    /// `L[i][k]` for `k` within the band of row `i`.
    fn at(&self, i: usize, k: usize) -> f64 {
        self.l[i * (self.bw + 1) + (k + self.bw - i)]
    }

    /// Solves `A x = b`. `None` if `b` does not have the matrix's size.
    #[must_use]
    pub fn solve(&self, b: &DVector<f64>) -> Option<DVector<f64>> {
        let (n, bw) = (self.n, self.bw);
        if b.len() != n {
            return None;
        }
        // Forward: L y = b.
        let mut y = b.clone();
        for i in 0..n {
            let mut s = y[i];
            for k in self.first[i]..i {
                s -= self.at(i, k) * y[k];
            }
            y[i] = s / self.at(i, i);
        }
        // Backward: Lᵀ x = y.
        let mut x = y;
        for i in (0..n).rev() {
            let mut s = x[i];
            for k in i + 1..(i + bw + 1).min(n) {
                s -= self.at(k, i) * x[k];
            }
            x[i] = s / self.at(i, i);
        }
        Some(x)
    }
}

impl BandedCholesky {
    /// The dense inverse `A⁻¹` (symmetric). Column `j` of the inverse is `L⁻ᵀ L⁻¹ eⱼ`; its
    /// entries from row `j` down need only the rows of `L` from `j` on (`L⁻¹ eⱼ` is zero above
    /// `j`), and both substitutions run within the band: about `n² · bandwidth`
    /// multiply-adds, a third of a dense Cholesky inverse's `n³` at the field's bandwidths. The
    /// columns are independent and solved in parallel; the upper triangle is mirrored.
    #[must_use]
    pub fn inverse(&self) -> DMatrix<f64> {
        let (n, bw) = (self.n, self.bw);
        let w = bw + 1;
        // `Lᵀ` within the band by rows: row `i` holds `L[i ..= i + bw][i]` contiguously
        // (zero past the last row), so that the backward substitution reads one contiguous
        // slice per entry as the forward one does.
        let mut lt = vec![0.0; n * w];
        for i in 0..n {
            for k in i..(i + w).min(n) {
                lt[i * w + (k - i)] = self.at(k, i);
            }
        }
        let columns: Vec<Vec<f64>> = (0..n)
            .into_par_iter()
            .map(|j| {
                // y = L⁻¹ eⱼ, from row j on (y[0] is row j).
                let m = n - j;
                let mut y = vec![0.0; m];
                y[0] = 1.0 / self.at(j, j);
                for i in j + 1..n {
                    let lo = self.first[i].max(j);
                    let row = &self.l[i * w + (lo + bw - i)..i * w + bw];
                    y[i - j] = -dot(row, &y[lo - j..i - j]) / self.at(i, i);
                }
                // x = L⁻ᵀ y, from the last row back to row j (x overwrites y).
                for i in (j..n).rev() {
                    let hi = (i + w).min(n);
                    let col = &lt[i * w + 1..i * w + (hi - i)];
                    let s = y[i - j] - dot(col, &y[i + 1 - j..hi - j]);
                    y[i - j] = s / self.at(i, i);
                }
                y
            })
            .collect();
        let mut inv = DMatrix::zeros(n, n);
        for (j, x) in columns.iter().enumerate() {
            for (k, &v) in x.iter().enumerate() {
                inv[(j + k, j)] = v;
                inv[(j, j + k)] = v;
            }
        }
        inv
    }
}

/// Solves `A x = b` for symmetric positive-definite `A` with half-bandwidth `bandwidth`
/// (reading only the lower triangle within the band). `None` if `A` is not positive definite.
#[must_use]
pub fn solve_banded_spd(
    a: &DMatrix<f64>,
    b: &DVector<f64>,
    bandwidth: usize,
) -> Option<DVector<f64>> {
    BandedCholesky::factor(a, bandwidth)?.solve(b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_dense_cholesky() {
        for bw in [0, 1, 7, 59, 100] {
            matches_dense_cholesky_at(60, bw);
        }
    }

    fn matches_dense_cholesky_at(n: usize, bw: usize) {
        let mut a = DMatrix::<f64>::zeros(n, n);
        for i in 0..n {
            for j in 0..n {
                if i.abs_diff(j) <= bw {
                    a[(i, j)] =
                        1.0 / (1.0 + (i as f64 - j as f64).abs()) + if i == j { 4.0 } else { 0.0 };
                }
            }
        }
        let b = DVector::from_fn(n, |i, _| (i as f64).sin());
        let dense = a.clone().cholesky().unwrap().solve(&b);
        let banded = solve_banded_spd(&a, &b, bw).unwrap();
        assert!((dense - banded).amax() < 1e-12);
        // One factor, further right-hand sides.
        let factor = BandedCholesky::factor(&a, bw).unwrap();
        let b2 = DVector::from_fn(n, |i, _| (i as f64).cos());
        let x2 = factor.solve(&b2).unwrap();
        assert!((&a * x2 - b2).amax() < 1e-10);
        assert!(factor.solve(&DVector::zeros(n + 1)).is_none());
        let inverse = factor.inverse();
        let dense_inverse = a.clone().cholesky().unwrap().inverse();
        assert!((&inverse - &dense_inverse).amax() < 1e-12);
        assert_eq!(inverse, inverse.transpose());
        let mut bad = a.clone();
        bad[(3, 3)] = -1.0;
        assert!(solve_banded_spd(&bad, &b, bw).is_none());
    }
}
