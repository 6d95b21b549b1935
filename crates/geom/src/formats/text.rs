//! Text helpers shared by the readers: numbered lines over bytes, and number parsing with errors
//! that name the place.

use std::path::Path as FsPath;

use crate::error::{GeomError, Location, Result};

/// The lines of a byte buffer, numbered from 1, without their `\n` or `\r\n`.
pub(super) struct Lines<'a> {
    rest: &'a [u8],
    consumed: usize,
    line_no: usize,
}

impl<'a> Lines<'a> {
    pub(super) fn new(bytes: &'a [u8]) -> Self {
        Lines {
            rest: bytes,
            consumed: 0,
            line_no: 0,
        }
    }

    /// Lines numbered from `first_line_no` (for a body that follows a header).
    pub(super) fn starting_at(bytes: &'a [u8], first_line_no: usize) -> Self {
        Lines {
            rest: bytes,
            consumed: 0,
            line_no: first_line_no.saturating_sub(1),
        }
    }

    /// The byte offset of the first byte not yet returned.
    pub(super) fn offset(&self) -> usize {
        self.consumed
    }

    /// The bytes not yet returned.
    pub(super) fn remaining(&self) -> &'a [u8] {
        self.rest
    }
}

impl<'a> Iterator for Lines<'a> {
    type Item = (usize, &'a [u8]);

    fn next(&mut self) -> Option<Self::Item> {
        if self.rest.is_empty() {
            return None;
        }
        let (line, advance) = match self.rest.iter().position(|&b| b == b'\n') {
            Some(i) => (&self.rest[..i], i + 1),
            None => (self.rest, self.rest.len()),
        };
        self.rest = &self.rest[advance..];
        self.consumed += advance;
        self.line_no += 1;
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        Some((self.line_no, line))
    }
}

/// Warns (tracing, on the CLI's stderr) when the text in `bytes` does not end with a line end
/// after a line that holds data (not blank, not a `#` comment): a file cut while it was written
/// or copied reads without an error when the cut falls inside the last number, which is then
/// short (`12.3` for `12.3456`). Files trimctl writes end with one; a hand-edited file may not,
/// so this is a warning, not a refusal. Returns whether it warned.
pub fn warn_if_unterminated(bytes: &[u8], name: &FsPath) -> bool {
    if bytes.last().is_none_or(|&b| b == b'\n') {
        return false;
    }
    let (line_no, last) = Lines::new(bytes).last().unwrap_or((0, &[]));
    let text = String::from_utf8_lossy(last);
    let text = text.trim();
    if text.is_empty() || text.starts_with('#') {
        return false;
    }
    tracing::warn!(
        "{}: line {line_no}, the last, has no line end: if the file was cut while it was \
         written or copied, its last value may be short ({:?})",
        name.display(),
        truncate(text)
    );
    true
}

/// The line as UTF-8, or an error naming it.
pub(super) fn utf8<'a>(line: &'a [u8], name: &FsPath, line_no: usize) -> Result<&'a str> {
    std::str::from_utf8(line).map_err(|e| {
        GeomError::parse(
            name,
            Location::Line(line_no),
            format!("not valid UTF-8 text ({e})"),
        )
    })
}

/// Parses a decimal number; `what` names the value in the error ("x", "column u").
pub(super) fn parse_f64(token: &str, name: &FsPath, at: Location, what: &str) -> Result<f64> {
    token.parse::<f64>().map_err(|_| {
        GeomError::parse(
            name,
            at,
            format!("{what}: {:?} is not a number", truncate(token)),
        )
    })
}

/// Parses a finite decimal number: NaN and infinities are refused with `what` and the place. A
/// number written out that is too large for a double (`1e400`) is refused as that, not as the
/// "inf" it parses to, which the file does not say.
pub(super) fn parse_finite(token: &str, name: &FsPath, at: Location, what: &str) -> Result<f64> {
    let v = parse_f64(token, name, at, what)?;
    if v.is_finite() {
        return Ok(v);
    }
    let word = token
        .trim()
        .trim_start_matches(['+', '-'])
        .to_ascii_lowercase();
    let message = if v.is_infinite() && !word.starts_with("inf") {
        format!(
            "{what}: {} is too large for a double (at most ±{:e})",
            truncate(token),
            f64::MAX
        )
    } else {
        format!("{what}: {v} is not finite")
    };
    Err(GeomError::parse(name, at, message))
}

/// A token cut to a readable length for an error message.
pub(super) fn truncate(token: &str) -> String {
    const MAX_CHARS: usize = 40;
    if token.chars().count() <= MAX_CHARS {
        token.to_owned()
    } else {
        let mut s: String = token.chars().take(MAX_CHARS).collect();
        s.push('…');
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_are_numbered_and_stripped() {
        let mut l = Lines::new(b"a\r\nb\n\nc");
        assert_eq!(l.next(), Some((1, &b"a"[..])));
        assert_eq!(l.offset(), 3);
        assert_eq!(l.next(), Some((2, &b"b"[..])));
        assert_eq!(l.next(), Some((3, &b""[..])));
        assert_eq!(l.next(), Some((4, &b"c"[..])));
        assert_eq!(l.next(), None);
        assert_eq!(l.offset(), 7);
    }

    #[test]
    fn numbers_name_the_place() {
        let n = FsPath::new("f.xyz");
        let e = parse_finite("1x", n, Location::Line(3), "y").unwrap_err();
        assert_eq!(e.to_string(), "f.xyz: line 3: y: \"1x\" is not a number");
        let e = parse_finite("nan", n, Location::Line(4), "z").unwrap_err();
        assert_eq!(e.to_string(), "f.xyz: line 4: z: NaN is not finite");
        let e = parse_finite("-inf", n, Location::Line(5), "x").unwrap_err();
        assert_eq!(e.to_string(), "f.xyz: line 5: x: -inf is not finite");
        let e = parse_finite("-1e400", n, Location::Line(6), "x").unwrap_err();
        assert_eq!(
            e.to_string(),
            "f.xyz: line 6: x: -1e400 is too large for a double (at most ±1.7976931348623157e308)"
        );
        assert_eq!(truncate(&"9".repeat(50)).chars().count(), 41);
    }
}
