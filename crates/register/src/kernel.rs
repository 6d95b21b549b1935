//! Robust kernels: iteratively reweighted least squares weights `w(r)` for a residual `r` (mm).
//!
//! Huber: `w = 1` for `|r| ≤ k`, `k/|r|` beyond. Tukey's biweight: `w = (1 − (r/c)²)²` for
//! `|r| < c`, 0 beyond (Zhang, "Parameter estimation techniques", 1997, Table 1).

/// A robust kernel.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum RobustKernel {
    /// Plain least squares.
    #[default]
    None,
    /// Huber with threshold `k_mm`.
    Huber {
        /// Threshold, mm.
        k_mm: f64,
    },
    /// Tukey's biweight with cut-off `c_mm`.
    Tukey {
        /// Cut-off, mm.
        c_mm: f64,
    },
}

impl RobustKernel {
    /// The IRLS weight of residual `r_mm`.
    #[must_use]
    pub fn weight(&self, r_mm: f64) -> f64 {
        let a = r_mm.abs();
        match *self {
            RobustKernel::None => 1.0,
            RobustKernel::Huber { k_mm } => {
                if a <= k_mm {
                    1.0
                } else {
                    k_mm / a
                }
            }
            RobustKernel::Tukey { c_mm } => {
                if a < c_mm {
                    let q = a / c_mm;
                    (1.0 - q * q).powi(2)
                } else {
                    0.0
                }
            }
        }
    }

    /// Whether the kernel's parameter is finite and positive.
    #[must_use]
    pub fn is_valid(&self) -> bool {
        match *self {
            RobustKernel::None => true,
            RobustKernel::Huber { k_mm: v } | RobustKernel::Tukey { c_mm: v } => {
                v.is_finite() && v > 0.0
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_follow_the_definitions() {
        let h = RobustKernel::Huber { k_mm: 0.1 };
        assert_eq!(h.weight(0.05), 1.0);
        assert!((h.weight(-0.4) - 0.25).abs() < 1e-15);
        let t = RobustKernel::Tukey { c_mm: 1.0 };
        assert_eq!(t.weight(0.0), 1.0);
        assert!((t.weight(0.5) - 0.5625).abs() < 1e-15);
        assert_eq!(t.weight(1.0), 0.0);
        assert!(!RobustKernel::Huber { k_mm: 0.0 }.is_valid());
    }
}
