//! The one nonlinear least-squares solver of the calibrations (DESIGN.md "Calibration"):
//! MINPACK's Levenberg–Marquardt (the `levenberg-marquardt` crate, on nalgebra) over a residual
//! function, with a central-difference Jacobian. The cell calibration ([`crate::cell_calibration`]) and the
//! move-model fit ([`crate::timing_fit`]) both use it.
//!
//! Non-finite residuals at a trial point make the solver reject that step and shrink its trust
//! region (the crate's NaN/∞ handling); a solution whose residuals are not finite is never
//! returned: the start is returned instead.

use std::cell::Cell;

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned};

/// The central-difference step of the Jacobian, relative to `1 + |x_k|`.
pub const JACOBIAN_STEP: f64 = 1e-6;

/// Residual evaluations the solver may make, per parameter + 1 (MINPACK's `maxfev` factor).
const PATIENCE: usize = 100;

/// A residual function: the residuals at the parameters `x`.
pub type Residuals<'a> = &'a dyn Fn(&DVector<f64>) -> DVector<f64>;

/// A solved problem.
#[derive(Debug, Clone, PartialEq)]
pub struct Solution {
    /// The parameters at the minimum.
    pub x: DVector<f64>,
    /// The residuals there.
    pub residuals: DVector<f64>,
    /// Σ r² there.
    pub cost: f64,
    /// Iterations: the Jacobians the solver asked for (one per accepted step, and the first).
    pub iterations: usize,
    /// Residual evaluations the solver made (the Jacobians' not counted).
    pub evaluations: usize,
    /// Whether the solver ended on one of its convergence tests (MINPACK's `info` 1–4), not on
    /// its evaluation budget or a numerical failure.
    pub converged: bool,
}

/// The Jacobian of `residuals` at `x` by central differences (step [`JACOBIAN_STEP`]).
#[must_use]
pub fn jacobian(x: &DVector<f64>, residuals: Residuals<'_>) -> DMatrix<f64> {
    let mut columns = Vec::with_capacity(x.len());
    for k in 0..x.len() {
        let h = JACOBIAN_STEP * (1.0 + x[k].abs());
        let (mut xp, mut xm) = (x.clone(), x.clone());
        xp[k] += h;
        xm[k] -= h;
        columns.push((residuals(&xp) - residuals(&xm)) / (2.0 * h));
    }
    if columns.is_empty() {
        return DMatrix::zeros(residuals(x).len(), 0);
    }
    DMatrix::from_columns(&columns)
}

/// Minimises Σ r(x)² from `x0`.
#[must_use]
pub fn minimize(x0: DVector<f64>, residuals: Residuals<'_>) -> Solution {
    let problem = Problem {
        x: x0.clone(),
        residuals,
        jacobians: Cell::new(0),
    };
    let (problem, report) = LevenbergMarquardt::new()
        .with_patience(PATIENCE)
        .minimize(problem);
    let iterations = problem.jacobians.get();
    let r = residuals(&problem.x);
    let cost = r.norm_squared();
    let (x, r, cost) = if cost.is_finite() {
        (problem.x, r, cost)
    } else {
        let r0 = residuals(&x0);
        let cost0 = r0.norm_squared();
        (x0, r0, cost0)
    };
    Solution {
        x,
        residuals: r,
        cost,
        iterations,
        evaluations: report.number_of_evaluations,
        converged: report.termination.was_successful(),
    }
}

/// The solver's view of a residual function.
struct Problem<'a> {
    x: DVector<f64>,
    residuals: Residuals<'a>,
    /// Jacobians asked for so far (the solver's iterations).
    jacobians: Cell<usize>,
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.x.copy_from(x);
    }

    fn params(&self) -> DVector<f64> {
        self.x.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        Some((self.residuals)(&self.x))
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        self.jacobians.set(self.jacobians.get() + 1);
        let j = jacobian(&self.x, self.residuals);
        j.iter().all(|v| v.is_finite()).then_some(j)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock as least squares, r = (10·(y − x²), 1 − x): the minimum at (1, 1), cost 0.
    #[test]
    fn solves_rosenbrock_from_the_classic_start() {
        let r = |x: &DVector<f64>| DVector::from_vec(vec![10.0 * (x[1] - x[0] * x[0]), 1.0 - x[0]]);
        let s = minimize(DVector::from_vec(vec![-1.2, 1.0]), &r);
        assert!(
            (s.x[0] - 1.0).abs() < 1e-9 && (s.x[1] - 1.0).abs() < 1e-9,
            "{:?}",
            s.x
        );
        assert!(s.cost < 1e-18, "{}", s.cost);
        assert!(s.converged);
    }

    /// An exponential fit y = a·e^(b·t) on exact data recovers (a, b); the central-difference
    /// Jacobian matches the analytic one.
    #[test]
    fn fits_an_exponential_and_differentiates_it() {
        let t: Vec<f64> = (0..20).map(|i| f64::from(i) * 0.1).collect();
        let y: Vec<f64> = t.iter().map(|t| 2.5 * (-1.3 * t).exp()).collect();
        let r = |x: &DVector<f64>| {
            DVector::from_iterator(
                t.len(),
                t.iter().zip(&y).map(|(t, y)| x[0] * (x[1] * t).exp() - y),
            )
        };
        let x = DVector::from_vec(vec![1.0, 0.0]);
        let j = jacobian(&x, &r);
        for (i, t) in t.iter().enumerate() {
            assert!((j[(i, 0)] - (x[1] * t).exp()).abs() < 1e-8);
            assert!((j[(i, 1)] - x[0] * t * (x[1] * t).exp()).abs() < 1e-8);
        }
        let s = minimize(x, &r);
        assert!(
            (s.x[0] - 2.5).abs() < 1e-8 && (s.x[1] + 1.3).abs() < 1e-8,
            "{:?}",
            s.x
        );
    }

    /// Where the residuals are not finite (here: x < 0), the solver steps back; a start whose
    /// every step leaves the finite region is returned as it was.
    #[test]
    fn never_returns_non_finite_residuals() {
        // r = sqrt(x) − 0.5: minimum at x = 0.25; NaN for x < 0.
        let r = |x: &DVector<f64>| DVector::from_vec(vec![x[0].sqrt() - 0.5]);
        let s = minimize(DVector::from_vec(vec![4.0]), &r);
        assert!(s.cost.is_finite());
        assert!((s.x[0] - 0.25).abs() < 1e-9, "{:?}", s.x);
        let nan = |_: &DVector<f64>| DVector::from_vec(vec![f64::NAN]);
        let s = minimize(DVector::from_vec(vec![1.0]), &nan);
        assert_eq!(s.x[0], 1.0);
        assert!(!s.converged);
    }
}
