//! Numbers as an error message shows them: a value a user mistyped as `1e-300` reads back as
//! `1e-300`, not as 300 zeros (Rust's `Display` for `f64` never uses an exponent).

use std::fmt;

/// An `f64` shown as `Display` does in the range people type (`0.25`, `12`, `-3.5`), and with an
/// exponent beyond it (`1e-300`, `2.5e18`). NaN and infinities read as `NaN`, `inf`, `-inf`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

/// Magnitudes at or above this are shown with an exponent.
const LARGE: f64 = 1e15;
/// Non-zero magnitudes below this are shown with an exponent.
const SMALL: f64 = 1e-6;

impl fmt::Display for Num {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let x = self.0;
        let m = x.abs();
        if x.is_finite() && m != 0.0 && !(SMALL..LARGE).contains(&m) {
            write!(f, "{x:e}")
        } else {
            write!(f, "{x}")
        }
    }
}

/// `value` as text, with a number that `Display` spelt out in full (`0.000…0001`) shown as
/// [`Num`] shows it. Integers (at most 20 digits) and short decimals are left as they are. For
/// error constructors that take any displayable value.
pub fn compact(value: impl fmt::Display) -> String {
    let text = value.to_string();
    match text.parse::<f64>() {
        Ok(x) if text.len() > 24 => Num(x).to_string(),
        _ => text,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn typed_numbers_read_as_typed_and_extreme_ones_with_an_exponent() {
        let shown = |x: f64| Num(x).to_string();
        assert_eq!(shown(0.25), "0.25");
        assert_eq!(shown(12.0), "12");
        assert_eq!(shown(-3.5), "-3.5");
        assert_eq!(shown(0.0), "0");
        assert_eq!(shown(1e-3), "0.001");
        assert_eq!(shown(1e-300), "1e-300");
        assert_eq!(shown(-1e300), "-1e300");
        assert_eq!(shown(2.5e18), "2.5e18");
        assert_eq!(shown(f64::NAN), "NaN");
        assert_eq!(shown(f64::NEG_INFINITY), "-inf");
        assert_eq!(compact(1e-300), "1e-300");
        assert_eq!(compact(0.5), "0.5");
        assert_eq!(compact("unset (derived: 1 mm)"), "unset (derived: 1 mm)");
        assert_eq!(compact(u64::MAX), u64::MAX.to_string());
        assert_eq!(compact(1e300), "1e300");
    }
}
