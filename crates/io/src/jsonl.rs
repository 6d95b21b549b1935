//! Append-only files of JSON lines (the run journal, the digital twin's landed cuts): read whole,
//! with a torn last line (a crash mid-write, no newline) ignored and any other bad line an
//! error; reopened for appending with that torn line cut off first, so the next line starts on
//! a line of its own.

use std::fs::{File, OpenOptions};
use std::path::Path;

use serde::de::DeserializeOwned;

/// A JSON-lines file as read.
#[derive(Debug, Clone, PartialEq)]
pub struct JsonLines<T> {
    /// Each non-blank whole line's value, with its 1-based line number, in order.
    pub values: Vec<(usize, T)>,
    /// Whether the last line was torn (left out).
    pub torn_tail: bool,
    /// Bytes up to the end of the last whole line (where a torn tail starts).
    pub good_len: u64,
}

/// Why a JSON-lines file could not be read.
#[derive(Debug)]
pub enum ReadError {
    /// The file could not be read.
    Io(std::io::Error),
    /// A line other than a torn last one is not a `T`.
    BadLine {
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        what: String,
    },
}

/// Reads `path` whole (see the module).
pub fn read<T: DeserializeOwned>(path: &Path) -> Result<JsonLines<T>, ReadError> {
    let text = std::fs::read_to_string(path).map_err(ReadError::Io)?;
    let lines: Vec<&str> = text.split_inclusive('\n').collect();
    let mut out = JsonLines {
        values: Vec::new(),
        torn_tail: false,
        good_len: text.len() as u64,
    };
    for (i, line) in lines.iter().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        match serde_json::from_str(line) {
            Ok(v) => out.values.push((i + 1, v)),
            Err(_) if i + 1 == lines.len() && !line.ends_with('\n') => {
                out.torn_tail = true;
                out.good_len -= line.len() as u64;
            }
            Err(e) => {
                return Err(ReadError::BadLine {
                    line: i + 1,
                    what: e.to_string(),
                });
            }
        }
    }
    Ok(out)
}

/// Opens `path` for appending (created when `create` and missing), cut to `torn_at` bytes and
/// synced first when given: [`JsonLines::torn_at`] of what [`read`] found in it.
///
/// A whole last line without its newline (the write cut after the value's last byte) is
/// kept, as [`read`] kept it, and the newline is added, so that the next line does not run on
/// from it (which would make the file unreadable from there).
pub fn open_append(path: &Path, torn_at: Option<u64>, create: bool) -> std::io::Result<File> {
    let mut file = OpenOptions::new()
        .create(create)
        .read(true)
        .append(true)
        .open(path)?;
    if let Some(len) = torn_at {
        // The only change to written bytes.
        file.set_len(len)?;
        file.sync_data()?;
    }
    let len = file.metadata()?.len();
    if len > 0 {
        use std::io::{Read as _, Seek as _, SeekFrom, Write as _};
        let mut last = [0u8; 1];
        file.seek(SeekFrom::Start(len - 1))?;
        file.read_exact(&mut last)?;
        if last[0] != b'\n' {
            file.write_all(b"\n")?;
            file.sync_data()?;
        }
    }
    Ok(file)
}

impl<T> JsonLines<T> {
    /// Where a torn last line starts, when there is one: what [`open_append`] cuts off.
    #[must_use]
    pub fn torn_at(&self) -> Option<u64> {
        self.torn_tail.then_some(self.good_len)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write as _;

    #[test]
    fn a_torn_last_line_is_left_out_and_cut_off_before_appending() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("log.jsonl");
        std::fs::write(&path, "[1]\n\n[2]\n[3, 4").unwrap();
        let lines: JsonLines<Vec<i32>> = read(&path).unwrap();
        assert_eq!(lines.values, vec![(1, vec![1]), (3, vec![2])]);
        assert!(lines.torn_tail);
        assert_eq!(lines.good_len, 9);
        let mut file = open_append(&path, lines.torn_at(), false).unwrap();
        file.write_all(b"[5]\n").unwrap();
        drop(file);
        let again: JsonLines<Vec<i32>> = read(&path).unwrap();
        assert_eq!(again.values, vec![(1, vec![1]), (3, vec![2]), (4, vec![5])]);
        assert!(!again.torn_tail);
    }

    #[test]
    fn a_whole_last_line_without_its_newline_is_kept_and_the_next_starts_on_its_own() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("log.jsonl");
        std::fs::write(&path, "[1]\n[2]").unwrap();
        let lines: JsonLines<Vec<i32>> = read(&path).unwrap();
        assert_eq!(lines.values, vec![(1, vec![1]), (2, vec![2])]);
        assert!(!lines.torn_tail);
        let mut file = open_append(&path, lines.torn_at(), false).unwrap();
        file.write_all(b"[3]\n").unwrap();
        drop(file);
        let again: JsonLines<Vec<i32>> = read(&path).unwrap();
        assert_eq!(again.values, vec![(1, vec![1]), (2, vec![2]), (3, vec![3])]);
    }

    #[test]
    fn a_bad_line_before_the_last_is_an_error_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("log.jsonl");
        std::fs::write(&path, "[1]\nnope\n[2]\n").unwrap();
        match read::<Vec<i32>>(&path) {
            Err(ReadError::BadLine { line, .. }) => assert_eq!(line, 2),
            other => panic!("{other:?}"),
        }
        // A bad last line that ends with a newline was written whole: an error too.
        std::fs::write(&path, "[1]\nnope\n").unwrap();
        assert!(matches!(
            read::<Vec<i32>>(&path),
            Err(ReadError::BadLine { line: 2, .. })
        ));
        assert!(matches!(
            read::<Vec<i32>>(&dir.path().join("missing.jsonl")),
            Err(ReadError::Io(_))
        ));
    }
}
