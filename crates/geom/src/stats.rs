//! The standard normal distribution and a one-dimensional minimiser, shared by the fits that
//! locate an edge or a web from noisy scan points (registration's scanned-edge check,
//! inspection's burr heights) and by calibration's pivot search.

use std::f64::consts::{PI, SQRT_2};

/// The standard normal distribution function `Φ(z)` (through `libm::erfc`, so the lower tail
/// keeps its relative precision far out).
#[must_use]
pub fn normal_cdf(z: f64) -> f64 {
    0.5 * libm::erfc(-z / SQRT_2)
}

/// The standard normal's upper tail `1 − Φ(z)`.
#[must_use]
pub fn normal_upper_tail(z: f64) -> f64 {
    0.5 * libm::erfc(z / SQRT_2)
}

/// The standard normal density `φ(z)`.
#[must_use]
pub fn normal_pdf(z: f64) -> f64 {
    (-0.5 * z * z).exp() / (2.0 * PI).sqrt()
}

/// `ψ(z) = zΦ(z) + φ(z)`, the integral of Φ from −∞. Φ(z) is taken as the upper tail at −z,
/// which keeps its relative accuracy far out on the lower side (`1 − Q(z)` is all rounding
/// there, and ψ(z) ≈ φ(z)/z² is what is left of the difference).
#[must_use]
pub fn normal_cdf_integral(z: f64) -> f64 {
    z * normal_upper_tail(-z) + normal_pdf(z)
}

/// The minimiser of `f` over `[lo, hi]` by golden-section search: `steps` steps shrink the
/// bracket to `0.618^steps` of itself. `f` should be unimodal on the bracket; otherwise the
/// answer is a local minimum.
pub fn golden_section_min(mut f: impl FnMut(f64) -> f64, lo: f64, hi: f64, steps: usize) -> f64 {
    let (mut a, mut b) = (lo, hi);
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (f(c), f(d));
    for _ in 0..steps {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = f(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = f(d);
        }
    }
    0.5 * (a + b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_normal_distribution_matches_known_values() {
        // Φ(0) = ½, Φ(1.96) = 0.975002..., the far lower tail Φ(−8) = 6.22096e−16.
        assert!((normal_cdf(0.0) - 0.5).abs() < 1e-15);
        assert!((normal_cdf(1.959_963_984_540_054) - 0.975).abs() < 1e-12);
        assert!((normal_cdf(-8.0) / 6.220_960_574_271_785e-16 - 1.0).abs() < 1e-9);
        assert!((normal_upper_tail(8.0) / 6.220_960_574_271_785e-16 - 1.0).abs() < 1e-9);
        assert!((normal_pdf(0.0) - 0.398_942_280_401_432_7).abs() < 1e-15);
        // ψ' = Φ, and ψ(z) → z far up, → 0 far down.
        let h = 1e-5;
        let slope = (normal_cdf_integral(0.7 + h) - normal_cdf_integral(0.7 - h)) / (2.0 * h);
        assert!((slope - normal_cdf(0.7)).abs() < 1e-9);
        assert!((normal_cdf_integral(9.0) - 9.0).abs() < 1e-12);
        assert!(normal_cdf_integral(-9.0) > 0.0 && normal_cdf_integral(-9.0) < 1e-19);
    }

    #[test]
    fn golden_section_finds_a_parabolas_minimum() {
        // Within √ε of it: closer, the parabola's values differ by rounding alone.
        let x = golden_section_min(|x| (x - 0.3).powi(2) + 1.0, -1.0, 2.0, 60);
        assert!((x - 0.3).abs() < 1e-7, "{x}");
        // At the bracket's edge when the minimum lies outside it.
        let x = golden_section_min(|x| x, -1.0, 2.0, 60);
        assert!((x + 1.0).abs() < 1e-9, "{x}");
    }
}
