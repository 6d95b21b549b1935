//! Beam optics of the focused Gaussian beam (DESIGN.md "Beam", paper §2.1–2.2).
//!
//! SI inside the formulas, named units at the edges: the settings carry their unit in the name
//! (`power_w`, `wavelength_nm`, `focal_length_mm`), results too (`waist_radius_mm`).
//!
//! Corrections to the paper (DESIGN.md): the waist *radius* is `w0 = 2·M²·λ·f/(π·D)` (the
//! paper's Eq. 6 with 4 gives the diameter, while its quoted 20.4 µm is the radius), and the
//! Rayleigh length follows from it, `zR = π·w0²/(M²·λ)` (≈ 2.24 mm; the paper's printed
//! 4.994 mm is the major beam diameter at the lens, not zR).

use serde::{Deserialize, Serialize};

use crate::error::{CellError, require_open_closed, require_positive, require_range};

/// Step of the scan for [`Beam::max_incidence_for_line_width_rad`] (radians, 0.01°).
pub const INCIDENCE_SCAN_STEP_RAD: f64 = 0.01 * std::f64::consts::PI / 180.0;

/// The physical range of `beam.wavelength_nm` (nm): deep UV (an ArF excimer's 193 nm, with
/// margin) to the far infrared (a CO₂ laser's 10.6 µm, with margin).
pub const WAVELENGTH_RANGE_NM: (f64, f64) = (150.0, 20_000.0);

/// The physical range of `beam.focal_length_mm` (mm): the shortest focusing objective to the
/// longest f-theta scan lens a galvo cell carries.
pub const FOCAL_LENGTH_RANGE_MM: (f64, f64) = (5.0, 5_000.0);

/// The physical range of `beam.beam_diameter_mm` (mm): the raw beam of a fibre laser to the
/// widest beam expander's output a galvo's mirrors take.
pub const BEAM_DIAMETER_RANGE_MM: (f64, f64) = (0.1, 100.0);

/// The largest `beam.m_squared`: beyond it the beam is no near-Gaussian beam the formulas hold
/// for (a multimode industrial source is below 30).
pub const MAX_M_SQUARED: f64 = 100.0;

/// The physical range of `beam.power_w` (W): beyond the highest average power an ultrafast
/// source delivers (a few kW in research systems), with margin.
pub const POWER_RANGE_W: (f64, f64) = (1e-6, 20_000.0);

/// The physical range of `beam.repetition_rate_hz` (Hz): a single-shot source to a GHz burst,
/// with margin.
pub const REPETITION_RATE_RANGE_HZ: (f64, f64) = (1e-3, 1e11);

/// The largest `beam.fluence_threshold_ratio` (F0/Fth): far beyond any process window (2–50),
/// where the focus processing length stops being a layer's depth.
pub const MAX_FLUENCE_THRESHOLD_RATIO: f64 = 1e4;

/// Bisection steps after the scan brackets the limit (2⁻⁴⁰ of a step).
const INCIDENCE_BISECTION_STEPS: usize = 40;

/// The laser, lens and process figures (paper §2.1–2.2). Defaults are the paper's cell.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Beam {
    /// Average laser power P (W).
    pub power_w: f64,
    /// Pulse repetition rate h (Hz).
    pub repetition_rate_hz: f64,
    /// Wavelength λ (nm).
    pub wavelength_nm: f64,
    /// Beam quality factor M².
    pub m_squared: f64,
    /// Effective focal length f of the (f-theta) lens (mm).
    pub focal_length_mm: f64,
    /// Beam diameter D at the lens entrance (mm).
    pub beam_diameter_mm: f64,
    /// Fluence tolerance t: the fraction of the peak fluence that still processes (0.97 means
    /// within 3 % of F0); sets the focus processing length.
    pub fluence_tolerance: f64,
    /// F0/F_th: peak fluence over the material's ablation threshold.
    pub fluence_threshold_ratio: f64,
    /// The incidence θ at which the spot ratios are reported (degrees).
    pub incidence_deg: f64,
    /// The allowed relative change of the spot radius (line width) with incidence, e.g. 0.005 for
    /// ±0.5 %; sets [`Beam::max_incidence_for_line_width_rad`].
    pub line_width_tolerance: f64,
}

impl Default for Beam {
    fn default() -> Self {
        Beam {
            power_w: 53.59,
            repetition_rate_hz: 250_000.0,
            wavelength_nm: 532.0,
            m_squared: 1.1,
            focal_length_mm: 259.4,
            beam_diameter_mm: 4.7313,
            fluence_tolerance: 0.97,
            fluence_threshold_ratio: 2.0,
            incidence_deg: 5.0,
            line_width_tolerance: 0.005,
        }
    }
}

/// The figures `trimctl beam` prints, in the units of their names.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BeamReport {
    /// E = P/h (µJ), paper Eq. 4.
    pub pulse_energy_uj: f64,
    /// w0 (µm), DESIGN.md's corrected paper Eq. 6.
    pub waist_radius_um: f64,
    /// zR (mm), paper Eq. 5 with M².
    pub rayleigh_length_mm: f64,
    /// F0 = 2E/(π·w0²) (J/cm²), paper Eq. 2.
    pub peak_fluence_j_per_cm2: f64,
    /// The focus processing length zR·√(1/t − 1) (mm, each side of the focus).
    pub focus_half_length_mm: f64,
    /// r_min/r at θ, paper Eq. 7–8.
    pub spot_ratio_min: f64,
    /// r_max/r at θ, paper Eq. 7–8.
    pub spot_ratio_max: f64,
    /// The largest incidence that keeps both ratios within the line-width tolerance (degrees).
    pub max_incidence_for_line_width_deg: f64,
}

impl Beam {
    /// Refuses out-of-range values, naming the key (`beam.power_w`). The optics are held to
    /// physical ranges, so the figures derived from them (w0, zR, the layer step) are finite and
    /// of a size a cell can have: `wavelength_nm` within [`WAVELENGTH_RANGE_NM`],
    /// `focal_length_mm` within [`FOCAL_LENGTH_RANGE_MM`], `beam_diameter_mm` within
    /// [`BEAM_DIAMETER_RANGE_MM`], `m_squared` within [1, [`MAX_M_SQUARED`]]. The power and the
    /// repetition rate are held here to what a laser can be ([`POWER_RANGE_W`],
    /// [`REPETITION_RATE_RANGE_HZ`]); the laser profile's `[limits]` bound them closer
    /// ([`Beam::check_limits`]). `fluence_threshold_ratio` is within
    /// (1, [`MAX_FLUENCE_THRESHOLD_RATIO`]].
    pub fn validate(&self) -> Result<(), CellError> {
        let (lo, hi) = POWER_RANGE_W;
        require_range("beam.power_w", self.power_w, lo, hi)?;
        let (lo, hi) = REPETITION_RATE_RANGE_HZ;
        require_range("beam.repetition_rate_hz", self.repetition_rate_hz, lo, hi)?;
        let (lo, hi) = WAVELENGTH_RANGE_NM;
        require_range("beam.wavelength_nm", self.wavelength_nm, lo, hi)?;
        if !(self.m_squared.is_finite() && (1.0..=MAX_M_SQUARED).contains(&self.m_squared)) {
            return Err(CellError::setting(
                "beam.m_squared",
                self.m_squared,
                format!("must be within [1, {MAX_M_SQUARED}] (a Gaussian beam has M² = 1)"),
            ));
        }
        let (lo, hi) = FOCAL_LENGTH_RANGE_MM;
        require_range("beam.focal_length_mm", self.focal_length_mm, lo, hi)?;
        let (lo, hi) = BEAM_DIAMETER_RANGE_MM;
        require_range("beam.beam_diameter_mm", self.beam_diameter_mm, lo, hi)?;
        if !(self.fluence_tolerance.is_finite()
            && self.fluence_tolerance > 0.0
            && self.fluence_tolerance < 1.0)
        {
            return Err(CellError::setting(
                "beam.fluence_tolerance",
                self.fluence_tolerance,
                "must be within (0, 1)",
            ));
        }
        if !(self.fluence_threshold_ratio.is_finite()
            && self.fluence_threshold_ratio > 1.0
            && self.fluence_threshold_ratio <= MAX_FLUENCE_THRESHOLD_RATIO)
        {
            return Err(CellError::setting(
                "beam.fluence_threshold_ratio",
                self.fluence_threshold_ratio,
                format!(
                    "must be within (1, {MAX_FLUENCE_THRESHOLD_RATIO:e}] (at or below 1 nothing \
                     is ablated)"
                ),
            ));
        }
        require_range("beam.incidence_deg", self.incidence_deg, 0.0, 89.0)?;
        if self.fluence_threshold_ratio * self.incidence_deg.to_radians().cos() <= 1.0 {
            return Err(CellError::setting(
                "beam.incidence_deg",
                self.incidence_deg,
                "at this incidence F0·cos θ is below the ablation threshold",
            ));
        }
        require_open_closed(
            "beam.line_width_tolerance",
            self.line_width_tolerance,
            0.0,
            0.5,
        )?;
        Ok(())
    }

    /// E = P/h (J), paper Eq. 4.
    #[must_use]
    pub fn pulse_energy_j(&self) -> f64 {
        self.power_w / self.repetition_rate_hz
    }

    /// λ (m).
    fn wavelength_m(&self) -> f64 {
        self.wavelength_nm * 1e-9
    }

    /// w0 = 2·M²·λ·f/(π·D) (mm): the focused waist *radius* (paper Eq. 6 corrected).
    #[must_use]
    pub fn waist_radius_mm(&self) -> f64 {
        2.0 * self.m_squared * self.wavelength_m() * 1e3 * self.focal_length_mm
            / (std::f64::consts::PI * self.beam_diameter_mm)
    }

    /// zR = π·w0²/(M²·λ) (mm), paper Eq. 5 with the beam quality factor.
    #[must_use]
    pub fn rayleigh_length_mm(&self) -> f64 {
        let w0 = self.waist_radius_mm();
        std::f64::consts::PI * w0 * w0 / (self.m_squared * self.wavelength_m() * 1e3)
    }

    /// w(z) = w0·√(1 + (z/zR)²) (mm), paper Eq. 3; `z_mm` from the focus along the axis.
    #[must_use]
    pub fn radius_at_mm(&self, z_mm: f64) -> f64 {
        let q = z_mm / self.rayleigh_length_mm();
        self.waist_radius_mm() * (1.0 + q * q).sqrt()
    }

    /// Peak fluence F(z) = 2E/(π·w(z)²) (J/mm²), paper Eq. 2 with w(z).
    #[must_use]
    pub fn peak_fluence_j_per_mm2(&self, z_mm: f64) -> f64 {
        let w = self.radius_at_mm(z_mm);
        2.0 * self.pulse_energy_j() / (std::f64::consts::PI * w * w)
    }

    /// The focus processing length (paper §2.1 "LPL"): the largest |z| with
    /// F(z) ≥ t·F0, i.e. zR·√(1/t − 1) (mm, each side of the focus).
    #[must_use]
    pub fn focus_half_length_mm(&self) -> f64 {
        self.rayleigh_length_mm() * (1.0 / self.fluence_tolerance - 1.0).sqrt()
    }

    /// (r_min/r, r_max/r) at incidence θ (radians), paper Eq. 7–8: with k = F0/F_th,
    /// r² = (w0²/2)·ln k, r_min² = (w0²/2)·ln(k·cos θ), r_max = r_min/cos θ. `None` when
    /// F0·cos θ is at or below the threshold (no ablation).
    #[must_use]
    pub fn spot_ratios(&self, incidence_rad: f64) -> Option<(f64, f64)> {
        let k = self.fluence_threshold_ratio;
        let cos = incidence_rad.cos();
        let inner = (k * cos).ln();
        if !(inner > 0.0 && cos > 0.0) {
            return None;
        }
        let ratio_min = (inner / k.ln()).sqrt();
        Some((ratio_min, ratio_min / cos))
    }

    /// The largest incidence (radians) for which both spot ratios stay within
    /// `1 ± line_width_tolerance`: scanned from 0 in [`INCIDENCE_SCAN_STEP_RAD`] steps, then
    /// bisected to the first violation.
    #[must_use]
    pub fn max_incidence_for_line_width_rad(&self) -> f64 {
        let tol = self.line_width_tolerance;
        let within = |theta: f64| {
            self.spot_ratios(theta)
                .is_some_and(|(lo, hi)| (lo - 1.0).abs() <= tol && (hi - 1.0).abs() <= tol)
        };
        let mut good = 0.0;
        let max = std::f64::consts::FRAC_PI_2;
        while good + INCIDENCE_SCAN_STEP_RAD < max && within(good + INCIDENCE_SCAN_STEP_RAD) {
            good += INCIDENCE_SCAN_STEP_RAD;
        }
        let mut bad = (good + INCIDENCE_SCAN_STEP_RAD).min(max);
        for _ in 0..INCIDENCE_BISECTION_STEPS {
            let mid = 0.5 * (good + bad);
            if within(mid) {
                good = mid;
            } else {
                bad = mid;
            }
        }
        good
    }

    /// The figures `trimctl beam` prints. Validate first: an invalid beam gives NaN.
    #[must_use]
    pub fn report(&self) -> BeamReport {
        let (ratio_min, ratio_max) = self
            .spot_ratios(self.incidence_deg.to_radians())
            .unwrap_or((f64::NAN, f64::NAN));
        BeamReport {
            pulse_energy_uj: self.pulse_energy_j() * 1e6,
            waist_radius_um: self.waist_radius_mm() * 1e3,
            rayleigh_length_mm: self.rayleigh_length_mm(),
            // J/mm² → J/cm²: ×100.
            peak_fluence_j_per_cm2: self.peak_fluence_j_per_mm2(0.0) * 100.0,
            focus_half_length_mm: self.focus_half_length_mm(),
            spot_ratio_min: ratio_min,
            spot_ratio_max: ratio_max,
            max_incidence_for_line_width_deg: self.max_incidence_for_line_width_rad().to_degrees(),
        }
    }
}

/// Relative slack on a laser limit, so an operating point set exactly at a limit (40 W at
/// 1 MHz against 40 µJ) is not refused for the last bit of a floating-point division.
pub const LIMIT_RELATIVE_SLACK: f64 = 1e-9;

/// The operating limits of a laser source: the `[limits]` table of its laser profile
/// (`crates/io/profiles/*.toml`). Every profile states all four; there are no defaults, since
/// a guessed limit is worse than none.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct LaserLimits {
    /// The largest pulse energy E = P/h the source delivers (µJ).
    pub pulse_energy_uj_max: f64,
    /// The largest average power P (W).
    pub average_power_w_max: f64,
    /// The lowest repetition rate h the source is specified at (kHz).
    pub rep_rate_khz_min: f64,
    /// The highest repetition rate h (kHz).
    pub rep_rate_khz_max: f64,
}

/// One limit of [`LaserLimits`] an operating point breaks.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LimitViolation {
    /// What is limited, for people ("pulse energy").
    pub quantity: &'static str,
    /// The job.toml key(s) that set it (`beam.power_w`).
    pub key: &'static str,
    /// Its value at the operating point, in `unit`.
    pub value: f64,
    /// The profile's limit key (`limits.average_power_w_max`).
    pub limit: &'static str,
    /// The limit's value, in `unit`.
    pub bound: f64,
    /// The unit of `value` and `bound` ("W", "kHz", "µJ").
    pub unit: &'static str,
    /// True when the value is above the limit, false when below.
    pub above: bool,
}

impl std::fmt::Display for LimitViolation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Six decimals: 53.59 W / 250 kHz prints as 214.36 µJ, not its last binary digit.
        let round = |v: f64| (v * 1e6).round() / 1e6;
        let (value, bound) = (round(self.value), round(self.bound));
        write!(
            f,
            "{} {value} {unit} ({}) is {} {} = {bound} {unit}",
            self.quantity,
            self.key,
            if self.above { "above" } else { "below" },
            self.limit,
            unit = self.unit,
        )
    }
}

/// The violations as one line, "; " between them.
#[must_use]
pub fn describe_violations(violations: &[LimitViolation]) -> String {
    violations
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join("; ")
}

impl LaserLimits {
    /// Refuses a limit that is not a finite number > 0, or a repetition-rate range whose
    /// minimum is above its maximum, naming the key (`limits.rep_rate_khz_min`).
    pub fn validate(&self) -> Result<(), CellError> {
        require_positive("limits.pulse_energy_uj_max", self.pulse_energy_uj_max)?;
        require_positive("limits.average_power_w_max", self.average_power_w_max)?;
        require_positive("limits.rep_rate_khz_min", self.rep_rate_khz_min)?;
        require_positive("limits.rep_rate_khz_max", self.rep_rate_khz_max)?;
        if self.rep_rate_khz_min > self.rep_rate_khz_max {
            return Err(CellError::setting(
                "limits.rep_rate_khz_min",
                self.rep_rate_khz_min,
                format!(
                    "must not exceed limits.rep_rate_khz_max = {}",
                    self.rep_rate_khz_max
                ),
            ));
        }
        Ok(())
    }

    /// Every limit `beam`'s operating point (P, h and E = P/h) breaks, in the order power,
    /// repetition rate, pulse energy; empty when it is within all of them. A value within
    /// [`LIMIT_RELATIVE_SLACK`] of a limit is within it.
    #[must_use]
    pub fn violations(&self, beam: &Beam) -> Vec<LimitViolation> {
        let over = |value: f64, max: f64| value > max * (1.0 + LIMIT_RELATIVE_SLACK);
        let under = |value: f64, min: f64| value < min * (1.0 - LIMIT_RELATIVE_SLACK);
        let rep_rate_khz = beam.repetition_rate_hz * 1e-3;
        let pulse_energy_uj = beam.pulse_energy_j() * 1e6;
        let mut out = Vec::new();
        if over(beam.power_w, self.average_power_w_max) {
            out.push(LimitViolation {
                quantity: "average power",
                key: "beam.power_w",
                value: beam.power_w,
                limit: "limits.average_power_w_max",
                bound: self.average_power_w_max,
                unit: "W",
                above: true,
            });
        }
        let rate = |limit, bound, above| LimitViolation {
            quantity: "repetition rate",
            key: "beam.repetition_rate_hz",
            value: rep_rate_khz,
            limit,
            bound,
            unit: "kHz",
            above,
        };
        if under(rep_rate_khz, self.rep_rate_khz_min) {
            out.push(rate(
                "limits.rep_rate_khz_min",
                self.rep_rate_khz_min,
                false,
            ));
        }
        if over(rep_rate_khz, self.rep_rate_khz_max) {
            out.push(rate("limits.rep_rate_khz_max", self.rep_rate_khz_max, true));
        }
        if over(pulse_energy_uj, self.pulse_energy_uj_max) {
            out.push(LimitViolation {
                quantity: "pulse energy",
                key: "beam.power_w / beam.repetition_rate_hz",
                value: pulse_energy_uj,
                limit: "limits.pulse_energy_uj_max",
                bound: self.pulse_energy_uj_max,
                unit: "µJ",
                above: true,
            });
        }
        out
    }
}

impl Beam {
    /// Refuses an operating point outside `limits`, the limits of the laser profile `profile`
    /// ([`CellError::OutsideLaserLimits`], naming every limit broken). Validate the beam and
    /// the limits first.
    pub fn check_limits(&self, limits: &LaserLimits, profile: &str) -> Result<(), CellError> {
        let violations = limits.violations(self);
        if violations.is_empty() {
            Ok(())
        } else {
            Err(CellError::OutsideLaserLimits {
                profile: profile.to_owned(),
                violations,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A source modelled on the paper's stated laser (§4: 60 W, 30 µJ, 1 Hz–2 MHz).
    const PAPERS_STATED_SOURCE: LaserLimits = LaserLimits {
        pulse_energy_uj_max: 30.0,
        average_power_w_max: 60.0,
        rep_rate_khz_min: 0.001,
        rep_rate_khz_max: 2000.0,
    };

    #[test]
    fn the_papers_operating_point_breaks_its_stated_source_on_pulse_energy_only() {
        // 53.59 W at 250 kHz is 214.36 µJ: within 60 W and 1 Hz–2 MHz, 7× the 30 µJ.
        let v = PAPERS_STATED_SOURCE.violations(&Beam::default());
        assert_eq!(v.len(), 1, "{v:?}");
        assert_eq!(v[0].limit, "limits.pulse_energy_uj_max");
        assert!((v[0].value - 214.36).abs() < 1e-9 && v[0].bound == 30.0);
        let e = Beam::default()
            .check_limits(&PAPERS_STATED_SOURCE, "stated")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("\"stated\"")
                && e.contains("pulse energy 214.36")
                && e.contains("beam.power_w / beam.repetition_rate_hz")
                && e.contains("above limits.pulse_energy_uj_max = 30 µJ"),
            "{e}"
        );
        // At 2 MHz the same 53.59 W is 26.8 µJ: within every limit.
        let fast = Beam {
            repetition_rate_hz: 2e6,
            ..Beam::default()
        };
        fast.check_limits(&PAPERS_STATED_SOURCE, "stated").unwrap();
    }

    #[test]
    fn each_limit_is_named_when_broken_and_a_point_at_a_limit_passes() {
        let limits = LaserLimits {
            pulse_energy_uj_max: 40.0,
            average_power_w_max: 40.0,
            rep_rate_khz_min: 100.0,
            rep_rate_khz_max: 2000.0,
        };
        let at = |power_w: f64, repetition_rate_hz: f64| Beam {
            power_w,
            repetition_rate_hz,
            ..Beam::default()
        };
        // Exactly at the limits: 40 W at 1 MHz = 40 µJ; 4 W at 100 kHz; 40 W at 2 MHz.
        assert!(limits.violations(&at(40.0, 1e6)).is_empty());
        assert!(limits.violations(&at(4.0, 1e5)).is_empty());
        assert!(limits.violations(&at(40.0, 2e6)).is_empty());
        let named = |b: Beam| -> Vec<&'static str> {
            limits.violations(&b).iter().map(|v| v.limit).collect()
        };
        assert_eq!(named(at(40.001, 1.5e6)), ["limits.average_power_w_max"]);
        assert_eq!(named(at(40.0, 2.001e6)), ["limits.rep_rate_khz_max"]);
        assert_eq!(named(at(1.0, 99_999.0)), ["limits.rep_rate_khz_min"]);
        assert_eq!(named(at(20.0, 4.99e5)), ["limits.pulse_energy_uj_max"]);
        // Several at once, in the order power, rate, energy.
        assert_eq!(
            named(at(50.0, 50_000.0)),
            [
                "limits.average_power_w_max",
                "limits.rep_rate_khz_min",
                "limits.pulse_energy_uj_max"
            ]
        );
        let below = limits.violations(&at(1.0, 50_000.0));
        assert_eq!(
            below[0].to_string(),
            "repetition rate 50 kHz (beam.repetition_rate_hz) is below limits.rep_rate_khz_min = 100 kHz"
        );
    }

    #[test]
    fn limits_validate_names_the_key() {
        let good = PAPERS_STATED_SOURCE;
        good.validate().unwrap();
        for (bad, key) in [
            (
                LaserLimits {
                    pulse_energy_uj_max: 0.0,
                    ..good
                },
                "limits.pulse_energy_uj_max",
            ),
            (
                LaserLimits {
                    average_power_w_max: f64::NAN,
                    ..good
                },
                "limits.average_power_w_max",
            ),
            (
                LaserLimits {
                    rep_rate_khz_min: 3000.0,
                    ..good
                },
                "limits.rep_rate_khz_min",
            ),
            (
                LaserLimits {
                    rep_rate_khz_max: f64::INFINITY,
                    ..good
                },
                "limits.rep_rate_khz_max",
            ),
        ] {
            let e = bad.validate().unwrap_err().to_string();
            assert!(e.contains(key), "{key}: {e}");
        }
    }

    #[test]
    fn reproduces_the_papers_figures() {
        let b = Beam::default();
        b.validate().unwrap();
        let r = b.report();
        // Paper §2.1: E = 214.36 µJ (exact arithmetic of 53.59 W / 250 kHz).
        assert!((r.pulse_energy_uj - 214.36).abs() < 1e-9, "{r:?}");
        // w0 ≈ 20.4 µm (paper rounds to 0.1 µm).
        assert!((r.waist_radius_um - 20.4).abs() < 0.05, "{r:?}");
        // F0 = 32.7248 J/cm² (paper; within 0.05 %, the rounding of D).
        assert!((r.peak_fluence_j_per_cm2 - 32.7248).abs() < 0.016, "{r:?}");
        // "z can reach 0.4 mm" at 97 %: within 0.01 mm.
        assert!((r.focus_half_length_mm - 0.4).abs() < 0.01, "{r:?}");
        // 99.72 % and 100.11 % at F0/F_th = 2, θ = 5° (paper rounds to 0.01 %).
        assert!((r.spot_ratio_min * 100.0 - 99.72).abs() < 0.005, "{r:?}");
        assert!((r.spot_ratio_max * 100.0 - 100.11).abs() < 0.005, "{r:?}");
        // zR is computed, not the paper's 4.994 mm: π·w0²/(M²·λ) ≈ 2.24 mm.
        assert!((r.rayleigh_length_mm - 2.2396).abs() < 0.001, "{r:?}");
    }

    #[test]
    fn fluence_at_focus_half_length_is_the_tolerance() {
        let b = Beam::default();
        let z = b.focus_half_length_mm();
        let ratio = b.peak_fluence_j_per_mm2(z) / b.peak_fluence_j_per_mm2(0.0);
        assert!((ratio - b.fluence_tolerance).abs() < 1e-12);
        // w(zR) = √2·w0.
        let w = b.radius_at_mm(b.rayleigh_length_mm());
        assert!((w / b.waist_radius_mm() - 2f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn line_width_limit_is_where_a_ratio_leaves_the_tolerance() {
        let b = Beam::default();
        let theta = b.max_incidence_for_line_width_rad();
        // Closed form for the binding side (r_min): ln(k·cos θ)/ln k = (1 − tol)².
        let k = b.fluence_threshold_ratio;
        let expected = ((k.ln() * (1.0 - b.line_width_tolerance).powi(2)).exp() / k).acos();
        assert!((theta - expected).abs() < 1e-9, "{theta} vs {expected}");
        let (lo, hi) = b.spot_ratios(theta).unwrap();
        assert!(lo >= 1.0 - b.line_width_tolerance - 1e-9 && hi <= 1.0 + b.line_width_tolerance);
    }

    #[test]
    fn optics_outside_their_physical_range_are_refused_by_key() {
        /// Sets one optics key of a beam.
        type Set = fn(&mut Beam, f64);
        let cases: [(Set, &str, &[f64]); 7] = [
            (
                |b, v| b.power_w = v,
                "beam.power_w",
                &[1e300, 1e-300, 50_000.0, f64::INFINITY],
            ),
            (
                |b, v| b.repetition_rate_hz = v,
                "beam.repetition_rate_hz",
                &[1e300, 1e-300, 1e12],
            ),
            (
                |b, v| b.fluence_threshold_ratio = v,
                "beam.fluence_threshold_ratio",
                &[1e300, 2e4],
            ),
            (
                |b, v| b.wavelength_nm = v,
                "beam.wavelength_nm",
                &[1e300, 1e-300, 100.0, 50_000.0, f64::INFINITY],
            ),
            (
                |b, v| b.focal_length_mm = v,
                "beam.focal_length_mm",
                &[1e300, 1e9, 1.0, f64::NAN],
            ),
            (
                |b, v| b.beam_diameter_mm = v,
                "beam.beam_diameter_mm",
                &[1e-300, 1e300, 0.01, 1000.0],
            ),
            (|b, v| b.m_squared = v, "beam.m_squared", &[0.5, 1e6]),
        ];
        for (set, key, values) in cases {
            for &v in values {
                let mut b = Beam::default();
                set(&mut b, v);
                let e = b.validate().unwrap_err().to_string();
                assert!(e.contains(key), "{key} = {v}: {e}");
            }
        }
        // The ends of each range are inside it; every figure is then finite.
        for (wavelength_nm, focal_length_mm, beam_diameter_mm) in [
            (
                WAVELENGTH_RANGE_NM.0,
                FOCAL_LENGTH_RANGE_MM.0,
                BEAM_DIAMETER_RANGE_MM.1,
            ),
            (
                WAVELENGTH_RANGE_NM.1,
                FOCAL_LENGTH_RANGE_MM.1,
                BEAM_DIAMETER_RANGE_MM.0,
            ),
        ] {
            let b = Beam {
                wavelength_nm,
                focal_length_mm,
                beam_diameter_mm,
                ..Beam::default()
            };
            b.validate().unwrap();
            assert!(b.focus_half_length_mm().is_finite() && b.focus_half_length_mm() > 0.0);
        }
        // So are the power's, the rate's and the ratio's: the pulse energy and the focus
        // processing length stay finite and positive.
        for (power_w, repetition_rate_hz, fluence_threshold_ratio) in [
            (
                POWER_RANGE_W.0,
                REPETITION_RATE_RANGE_HZ.1,
                MAX_FLUENCE_THRESHOLD_RATIO,
            ),
            (POWER_RANGE_W.1, REPETITION_RATE_RANGE_HZ.0, 1.0 + 1e-9),
        ] {
            let b = Beam {
                power_w,
                repetition_rate_hz,
                fluence_threshold_ratio,
                incidence_deg: 0.0,
                ..Beam::default()
            };
            b.validate().unwrap();
            let e = b.pulse_energy_j();
            assert!(e.is_finite() && e > 0.0, "{e}");
            assert!(b.focus_half_length_mm().is_finite() && b.focus_half_length_mm() > 0.0);
        }
    }

    #[test]
    fn validate_names_the_key() {
        let b = Beam {
            power_w: -1.0,
            ..Beam::default()
        };
        assert!(
            b.validate()
                .unwrap_err()
                .to_string()
                .contains("beam.power_w")
        );
        let b = Beam {
            fluence_tolerance: 1.0,
            ..Beam::default()
        };
        assert!(
            b.validate()
                .unwrap_err()
                .to_string()
                .contains("beam.fluence_tolerance")
        );
        let b = Beam {
            m_squared: f64::NAN,
            ..Beam::default()
        };
        assert!(
            b.validate()
                .unwrap_err()
                .to_string()
                .contains("beam.m_squared")
        );
    }
}
