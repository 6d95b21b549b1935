//! The expanded uncertainty of a contour's measurement and ISO 14253-1's decision rule.
//!
//! - `U = k·√(σ² + (b/2)²)`: σ the scan's noise (the standard uncertainty of one measured
//!   distance), `b` the registration's predicted largest error across the contour (its bound
//!   is about two standard deviations of the field's posterior plus the residual terms, so `b/2`
//!   is taken as the standard uncertainty the fit adds), `k` the coverage factor (2, ≈ 95 %).
//! - Conformance is proven when the measured deviation plus U stays within the tolerance;
//!   non-conformance when it exceeds the tolerance by more than U; in between neither is
//!   proven. A contour the scan does not cover is neither, whatever its measurement, unless it
//!   already fails on what was seen.

/// The decision for one contour.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Verdict {
    /// Conformance proven: deviation + U ≤ tolerance.
    Pass,
    /// Non-conformance proven: deviation − U > tolerance (or an opening still blocked).
    Fail,
    /// Neither proven (within U of the tolerance, or not covered by the scan).
    Undecided,
}

impl Verdict {
    /// `"pass"`, `"fail"` or `"undecided"`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Verdict::Pass => "pass",
            Verdict::Fail => "fail",
            Verdict::Undecided => "undecided",
        }
    }
}

/// The expanded uncertainty `U = k·√(σ² + (b/2)²)`, µm, from the noise σ (µm), the
/// registration's bound `b` for the contour (µm) and the coverage factor `k`.
#[must_use]
pub fn uncertainty_um(noise_um: f64, bound_um: f64, coverage_factor: f64) -> f64 {
    coverage_factor * (noise_um * noise_um + 0.25 * bound_um * bound_um).sqrt()
}

/// What a verdict is decided on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measured {
    /// Largest excess, µm (0 when none stands clearly above the noise).
    pub excess_height_um: f64,
    /// Largest gouge, µm (0 when none).
    pub gouge_depth_um: f64,
    /// Share of the opening still covered (none: no opening).
    pub blocked_fraction: Option<f64>,
    /// Share of the contour's bins the scan covers.
    pub coverage: f64,
    /// The expanded uncertainty U, µm.
    pub uncertainty_um: f64,
}

/// The decision rule's limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// The tolerance on excess and gouge, µm.
    pub tolerance_um: f64,
    /// Below this coverage a contour that does not fail is undecided.
    pub min_coverage: f64,
    /// An opening more covered than this fails.
    pub max_blocked_fraction: f64,
}

/// The verdict and its reason.
#[must_use]
pub fn decide(m: &Measured, limits: &Limits) -> (Verdict, String) {
    let (t, u) = (limits.tolerance_um, m.uncertainty_um);
    let worst = m.excess_height_um.max(m.gouge_depth_um);
    let what = if m.gouge_depth_um > m.excess_height_um {
        "gouge"
    } else {
        "excess"
    };
    let mut fails = Vec::new();
    if worst - u > t {
        fails.push(format!(
            "{what} {worst:.0} µm exceeds the tolerance {t:.0} µm by more than U = {u:.0} µm"
        ));
    }
    if let Some(b) = m.blocked_fraction
        && b > limits.max_blocked_fraction
    {
        fails.push(format!(
            "opening {:.0} % blocked (more than {:.0} %)",
            100.0 * b,
            100.0 * limits.max_blocked_fraction
        ));
    }
    if !fails.is_empty() {
        return (Verdict::Fail, fails.join("; "));
    }
    if m.coverage < limits.min_coverage {
        return (
            Verdict::Undecided,
            format!(
                "the scan covers {:.0} % of the contour (needs {:.0} %)",
                100.0 * m.coverage,
                100.0 * limits.min_coverage
            ),
        );
    }
    if worst + u <= t {
        (
            Verdict::Pass,
            format!("{what} {worst:.0} µm + U {u:.0} µm within the tolerance {t:.0} µm"),
        )
    } else {
        (
            Verdict::Undecided,
            format!(
                "{what} {worst:.0} µm is within U = {u:.0} µm of the tolerance {t:.0} µm: neither conformance nor non-conformance is proven"
            ),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIMITS: Limits = Limits {
        tolerance_um: 30.0,
        min_coverage: 0.9,
        max_blocked_fraction: 0.05,
    };

    fn measured(excess: f64, gouge: f64, u: f64) -> Measured {
        Measured {
            excess_height_um: excess,
            gouge_depth_um: gouge,
            blocked_fraction: None,
            coverage: 1.0,
            uncertainty_um: u,
        }
    }

    #[test]
    fn the_guard_bands_split_pass_undecided_and_fail() {
        // U = 10: pass up to 20, fail beyond 40, undecided between (both ends as ISO 14253-1).
        for (excess, want) in [
            (0.0, Verdict::Pass),
            (20.0, Verdict::Pass),
            (20.5, Verdict::Undecided),
            (30.0, Verdict::Undecided),
            (40.0, Verdict::Undecided),
            (40.5, Verdict::Fail),
            (300.0, Verdict::Fail),
        ] {
            assert_eq!(
                decide(&measured(excess, 0.0, 10.0), &LIMITS).0,
                want,
                "{excess}"
            );
            assert_eq!(
                decide(&measured(0.0, excess, 10.0), &LIMITS).0,
                want,
                "{excess}"
            );
        }
        // A measurement too uncertain for the tolerance never passes.
        assert_eq!(
            decide(&measured(0.0, 0.0, 31.0), &LIMITS).0,
            Verdict::Undecided
        );
        let (_, reason) = decide(&measured(0.0, 55.0, 10.0), &LIMITS);
        assert!(reason.contains("gouge 55"), "{reason}");
    }

    #[test]
    fn an_uncovered_contour_is_undecided_unless_what_was_seen_fails() {
        let thin = Measured {
            coverage: 0.5,
            ..measured(0.0, 0.0, 10.0)
        };
        let (v, reason) = decide(&thin, &LIMITS);
        assert_eq!(v, Verdict::Undecided);
        assert!(reason.contains("covers 50 %"), "{reason}");
        let failing = Measured {
            excess_height_um: 120.0,
            ..thin
        };
        assert_eq!(decide(&failing, &LIMITS).0, Verdict::Fail);
    }

    #[test]
    fn a_blocked_opening_fails() {
        let blocked = Measured {
            blocked_fraction: Some(0.4),
            ..measured(0.0, 0.0, 10.0)
        };
        let (v, reason) = decide(&blocked, &LIMITS);
        assert_eq!(v, Verdict::Fail);
        assert!(reason.contains("40 % blocked"), "{reason}");
        let open = Measured {
            blocked_fraction: Some(0.01),
            ..blocked
        };
        assert_eq!(decide(&open, &LIMITS).0, Verdict::Pass);
    }

    #[test]
    fn the_uncertainty_combines_noise_and_half_the_bound() {
        assert!((uncertainty_um(10.0, 0.0, 2.0) - 20.0).abs() < 1e-12);
        assert!((uncertainty_um(3.0, 8.0, 2.0) - 10.0).abs() < 1e-12);
    }
}
