//! The error type of trim-cell: a setting out of range (naming its job.toml key) or a beam
//! outside the laser source's limits.

use trim_geom::Num;

/// A setting of the cell, the beam, the galvo or the machine that cannot be used.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CellError {
    /// A settings value is out of range. `key` is the dotted settings key (`beam.power_w`).
    #[error("setting {key} = {value}: {message}")]
    InvalidSetting {
        /// The dotted key, as in job.toml.
        key: &'static str,
        /// The value given, as text.
        value: String,
        /// What is accepted.
        message: String,
    },
    /// The beam's operating point is outside the laser source's limits (the `[limits]` table
    /// of its laser profile): one entry per limit broken.
    #[error(
        "the operating point is outside the limits of laser profile {profile:?}: {}",
        crate::beam::describe_violations(violations)
    )]
    OutsideLaserLimits {
        /// The laser profile's name.
        profile: String,
        /// Every limit the operating point breaks, in the order power, repetition rate, pulse
        /// energy.
        violations: Vec<crate::beam::LimitViolation>,
    },
}

impl CellError {
    /// An out-of-range setting.
    pub fn setting(key: &'static str, value: impl ToString, message: impl Into<String>) -> Self {
        CellError::InvalidSetting {
            key,
            value: trim_geom::number::compact(value.to_string()),
            message: message.into(),
        }
    }
}

/// Checks that `value` is finite and strictly positive.
pub fn require_positive(key: &'static str, value: f64) -> Result<(), CellError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(CellError::setting(
            key,
            value,
            "must be a finite number > 0",
        ))
    }
}

/// Checks that `value` is finite and within `[lo, hi]`.
pub fn require_range(key: &'static str, value: f64, lo: f64, hi: f64) -> Result<(), CellError> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(CellError::setting(
            key,
            value,
            format!("must be within [{}, {}]", Num(lo), Num(hi)),
        ))
    }
}

/// Checks that `value` is finite and within the open-closed interval `(lo, hi]`.
pub fn require_open_closed(
    key: &'static str,
    value: f64,
    lo: f64,
    hi: f64,
) -> Result<(), CellError> {
    if value.is_finite() && value > lo && value <= hi {
        Ok(())
    } else {
        Err(CellError::setting(
            key,
            value,
            format!("must be within ({}, {}]", Num(lo), Num(hi)),
        ))
    }
}
