//! What an inspection measures and how it decides, with every value checked by key.

use crate::error::{InspectError, Result};
use trim_geom::Num;

/// The inspection's settings. Lengths in mm, deviations in µm (the tolerance's unit).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InspectSettings {
    /// Scan points within this distance of a contour (CAD frame) are measured for it, mm.
    pub band_mm: f64,
    /// The tolerance on excess and gouge, µm (the product's ±30 µm).
    pub tolerance_um: f64,
    /// The longest bin along each contour's arc length, mm (a contour is cut into equal bins of
    /// at most this): excess is found, and its length counted, per bin.
    pub bin_length_mm: f64,
    /// A bin has excess (or gouge) when at least this many of its points stand clearly above
    /// the noise outside (inside) the material; its height is the `min_points`-th largest
    /// distance, so fewer stray points (outliers) can neither make nor raise it.
    pub min_points: usize,
    /// A point stands clearly above the noise beyond this many noise standard deviations.
    pub noise_factor: f64,
    /// The scan's noise (standard deviation of a point's distance to the surface), µm; `None`:
    /// estimated from the measured points (1.4826 × their median absolute distance).
    pub noise_um: Option<f64>,
    /// A bin is covered when it holds at least this many scan points.
    pub min_bin_points: usize,
    /// Below this share of its bins covered, a contour that does not fail is `undecided`.
    pub min_coverage: f64,
    /// The coverage factor k of the expanded uncertainty `U = k·u` (2: about 95 %).
    pub coverage_factor: f64,
    /// An opening more than this share covered fails, whatever its excess.
    pub max_blocked_fraction: f64,
    /// Grid step across an opening when its covered share is measured, mm.
    pub opening_grid_mm: f64,
    /// A grid node of an opening is covered when a scan point lies within this distance of it
    /// across the face, mm.
    pub opening_support_mm: f64,
    /// …and within this distance of the face's level along its normal, mm (a film hangs its
    /// thickness below the face).
    pub opening_depth_mm: f64,
    /// Nodes this close to the rim are left out of the opening (the wall's own points), mm.
    pub opening_rim_clearance_mm: f64,
    /// Fixed-point iterations of the field's inverse, `x ← y − d(x)`.
    pub inverse_iterations: usize,
}

impl Default for InspectSettings {
    fn default() -> Self {
        InspectSettings {
            band_mm: 0.5,
            tolerance_um: 30.0,
            bin_length_mm: 1.0,
            min_points: 3,
            noise_factor: 3.5,
            noise_um: None,
            min_bin_points: 3,
            min_coverage: 0.9,
            coverage_factor: 2.0,
            max_blocked_fraction: 0.1,
            opening_grid_mm: 0.1,
            opening_support_mm: 0.15,
            opening_depth_mm: 0.3,
            opening_rim_clearance_mm: 0.15,
            inverse_iterations: 4,
        }
    }
}

impl InspectSettings {
    /// Refuses out-of-range values, naming the key.
    pub fn validate(&self) -> Result<()> {
        let check = |name: &'static str, ok: bool, what: &str, value: String| {
            if ok {
                Ok(())
            } else {
                Err(InspectError::InvalidSetting {
                    name,
                    message: format!("{what}, got {value}"),
                })
            }
        };
        let within = |v: f64, lo: f64, hi: f64| v.is_finite() && v > lo && v <= hi;
        check(
            "band_mm",
            within(self.band_mm, 0.0, 10.0),
            "must be > 0 and ≤ 10 mm",
            Num(self.band_mm).to_string(),
        )?;
        check(
            "tolerance_um",
            within(self.tolerance_um, 0.0, 1000.0),
            "must be > 0 and ≤ 1000 µm",
            Num(self.tolerance_um).to_string(),
        )?;
        check(
            "bin_length_mm",
            within(self.bin_length_mm, 0.0, 100.0),
            "must be > 0 and ≤ 100 mm",
            Num(self.bin_length_mm).to_string(),
        )?;
        check(
            "min_points",
            (1..=1000).contains(&self.min_points),
            "must be 1 to 1000",
            self.min_points.to_string(),
        )?;
        check(
            "noise_factor",
            within(self.noise_factor, 0.0, 20.0),
            "must be > 0 and ≤ 20",
            Num(self.noise_factor).to_string(),
        )?;
        if let Some(n) = self.noise_um {
            check(
                "noise_um",
                within(n, 0.0, 1000.0),
                "must be > 0 and ≤ 1000 µm",
                n.to_string(),
            )?;
        }
        check(
            "min_bin_points",
            (1..=100_000).contains(&self.min_bin_points),
            "must be 1 to 100000",
            self.min_bin_points.to_string(),
        )?;
        check(
            "min_coverage",
            within(self.min_coverage, 0.0, 1.0),
            "must be > 0 and ≤ 1",
            Num(self.min_coverage).to_string(),
        )?;
        check(
            "coverage_factor",
            within(self.coverage_factor, 0.0, 10.0),
            "must be > 0 and ≤ 10",
            Num(self.coverage_factor).to_string(),
        )?;
        check(
            "max_blocked_fraction",
            self.max_blocked_fraction.is_finite()
                && (0.0..1.0).contains(&self.max_blocked_fraction),
            "must be in [0, 1)",
            Num(self.max_blocked_fraction).to_string(),
        )?;
        check(
            "opening_grid_mm",
            within(self.opening_grid_mm, 0.001, 10.0),
            "must be > 0.001 and ≤ 10 mm",
            Num(self.opening_grid_mm).to_string(),
        )?;
        check(
            "opening_support_mm",
            within(self.opening_support_mm, 0.0, 10.0),
            "must be > 0 and ≤ 10 mm",
            Num(self.opening_support_mm).to_string(),
        )?;
        check(
            "opening_depth_mm",
            within(self.opening_depth_mm, 0.0, 10.0),
            "must be > 0 and ≤ 10 mm",
            Num(self.opening_depth_mm).to_string(),
        )?;
        check(
            "opening_rim_clearance_mm",
            self.opening_rim_clearance_mm.is_finite()
                && (0.0..=10.0).contains(&self.opening_rim_clearance_mm),
            "must be in [0, 10] mm",
            Num(self.opening_rim_clearance_mm).to_string(),
        )?;
        check(
            "inverse_iterations",
            (1..=100).contains(&self.inverse_iterations),
            "must be 1 to 100",
            self.inverse_iterations.to_string(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_bad_values_are_refused_by_key() {
        InspectSettings::default()
            .validate()
            .unwrap_or_else(|e| panic!("{e}"));
        for (s, key) in [
            (
                InspectSettings {
                    band_mm: 0.0,
                    ..InspectSettings::default()
                },
                "band_mm",
            ),
            (
                InspectSettings {
                    band_mm: -1.0,
                    ..InspectSettings::default()
                },
                "band_mm",
            ),
            (
                InspectSettings {
                    tolerance_um: f64::NAN,
                    ..InspectSettings::default()
                },
                "tolerance_um",
            ),
            (
                InspectSettings {
                    bin_length_mm: f64::INFINITY,
                    ..InspectSettings::default()
                },
                "bin_length_mm",
            ),
            (
                InspectSettings {
                    min_points: 0,
                    ..InspectSettings::default()
                },
                "min_points",
            ),
            (
                InspectSettings {
                    noise_um: Some(-2.0),
                    ..InspectSettings::default()
                },
                "noise_um",
            ),
            (
                InspectSettings {
                    max_blocked_fraction: 1.0,
                    ..InspectSettings::default()
                },
                "max_blocked_fraction",
            ),
        ] {
            let e = s
                .validate()
                .err()
                .map(|e| e.to_string())
                .unwrap_or_default();
            assert!(e.contains(key), "{key}: {e:?}");
        }
    }
}
