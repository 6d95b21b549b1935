//! The digital twin's landed cuts of a `--verify` run, kept as they land in each folder the run
//! executes in (the job's and each `retrim_<k>/`): `twin_cuts.jsonl`, one [`LandedCut`] a line
//! (`{"from": [x, y, z], "to": [x, y, z]}`, work-piece frame, mm).
//!
//! The twin's part after the rounds so far is the demo part made again (`verify_state.json`)
//! and trimmed by each folder's cuts in turn, one [`trim_sim::twin_part::TwinPart::trim`] a
//! round, as the loop did: so a resumed run inspects the part an uninterrupted one would. Each
//! cut is written before the galvo's list goes on ([`trim_sim::twin::Twin::on_cut`]), so a
//! layer the journal calls done has all its cuts here, and a kill loses nothing that landed (a
//! layer cut by the kill and redone with `--cut-layer redo` lands twice, as on a real part).
//! Like the journal the file is appended to; a torn last line (a kill mid-write) is cut off
//! before the next execution appends, and ignored when read.

use std::fs::File;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use anyhow::Context;
use trim_io::jsonl;
use trim_sim::ablation::LandedCut;

use super::execute::TwinLink;
use super::files;

/// The open log of one execution.
pub(super) struct CutsLog {
    path: PathBuf,
    shared: Arc<Mutex<LogFile>>,
}

/// The file and the first write that failed (the twin's sink cannot return it).
struct LogFile {
    file: File,
    error: Option<std::io::Error>,
}

/// Keeps every cut `twin`'s twin lands from now on in `dir/twin_cuts.jsonl` (created, or
/// appended to after any torn last line); `None` without a twin (a real galvo).
pub(super) fn attach(twin: &TwinLink, dir: &Path) -> anyhow::Result<Option<CutsLog>> {
    let Some(t) = &twin.twin else {
        return Ok(None);
    };
    let path = dir.join(files::TWIN_CUTS);
    let file = open_for_append(&path).with_context(|| format!("cannot open {}", path.display()))?;
    let shared = Arc::new(Mutex::new(LogFile { file, error: None }));
    let sink = Arc::clone(&shared);
    t.on_cut(Box::new(move |cut: &LandedCut| {
        let mut log = sink
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if log.error.is_some() {
            return;
        }
        let written = serde_json::to_vec(cut)
            .map_err(std::io::Error::other)
            .and_then(|mut line| {
                line.push(b'\n');
                log.file.write_all(&line)
            });
        if let Err(e) = written {
            log.error = Some(e);
        }
    }));
    Ok(Some(CutsLog { path, shared }))
}

/// Opens `path` for appending (created when missing), its torn last line cut off first.
fn open_for_append(path: &Path) -> anyhow::Result<File> {
    let torn_at = match jsonl::read::<LandedCut>(path) {
        Ok(lines) => lines.torn_at(),
        Err(jsonl::ReadError::Io(e)) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => return Err(read_error(path, e)),
    };
    Ok(jsonl::open_append(path, torn_at, true)?)
}

/// `e` as an error naming `path` (and the line).
fn read_error(path: &Path, e: jsonl::ReadError) -> anyhow::Error {
    match e {
        jsonl::ReadError::Io(e) => anyhow::Error::new(e).context(format!(
            "cannot read {}: the twin's landed cuts are needed to recreate its part",
            path.display()
        )),
        jsonl::ReadError::BadLine { line, what } => {
            anyhow::anyhow!("{} line {line}: not a landed cut: {what}", path.display())
        }
    }
}

impl CutsLog {
    /// Syncs the file; the first write that failed, naming the file.
    pub(super) fn finish(self) -> anyhow::Result<()> {
        let mut log = self
            .shared
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(e) = log.error.take() {
            return Err(e).with_context(|| {
                format!(
                    "cannot write the twin's landed cuts to {}; the twin's part cannot be recreated from it",
                    self.path.display()
                )
            });
        }
        log.file
            .sync_data()
            .with_context(|| format!("cannot sync {}", self.path.display()))
    }
}

/// Every cut `dir/twin_cuts.jsonl` holds, in the order they landed (a torn last line left out).
/// A missing file or a line that is not a cut is an error naming the file (and the line).
pub(super) fn read(dir: &Path) -> anyhow::Result<Vec<LandedCut>> {
    let path = dir.join(files::TWIN_CUTS);
    let lines = jsonl::read::<LandedCut>(&path).map_err(|e| read_error(&path, e))?;
    Ok(lines.values.into_iter().map(|(_, cut)| cut).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use trim_geom::Point3;

    fn cut(x: f64) -> LandedCut {
        LandedCut {
            from: Point3::new(x, 0.1 + 0.2, -3.0),
            to: Point3::new(x + 1.0 / 3.0, 2.0, -3.0),
        }
    }

    fn line(c: &LandedCut) -> String {
        format!("{}\n", serde_json::to_string(c).expect("json"))
    }

    #[test]
    fn cuts_read_back_exactly_and_a_torn_last_line_is_cut_off_before_appending() {
        let dir = tempfile::tempdir().expect("a temporary folder");
        let path = dir.path().join(files::TWIN_CUTS);
        let torn = &line(&cut(2.0))[..20];
        trim_geom::fs::write_atomic(&path, format!("{}{torn}", line(&cut(1.0)))).expect("written");
        assert_eq!(read(dir.path()).expect("read"), vec![cut(1.0)]);
        let mut file = open_for_append(&path).expect("opened");
        file.write_all(line(&cut(3.0)).as_bytes())
            .expect("appended");
        drop(file);
        assert_eq!(read(dir.path()).expect("read"), vec![cut(1.0), cut(3.0)]);
    }

    #[test]
    fn a_missing_log_or_a_bad_line_is_refused_naming_the_file() {
        let dir = tempfile::tempdir().expect("a temporary folder");
        let e = format!("{:#}", read(dir.path()).expect_err("missing"));
        assert!(e.contains("twin_cuts.jsonl"), "{e}");
        trim_geom::fs::write_atomic(
            dir.path().join(files::TWIN_CUTS),
            format!("{}{{\"from\": 1}}\n{}", line(&cut(1.0)), line(&cut(2.0))),
        )
        .expect("written");
        let e = format!("{:#}", read(dir.path()).expect_err("corrupt"));
        assert!(e.contains("twin_cuts.jsonl line 2"), "{e}");
    }
}
