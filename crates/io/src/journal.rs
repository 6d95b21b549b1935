//! The run journal: an append-only file of JSON lines, fsync'd after every entry, so a crash
//! or a fault never loses a finished layer and `resume` knows where to continue.
//!
//! Entries: `start` (the job's digest), `layer_begin` (a list for a layer is about to be loaded:
//! its first vector and its galvo tag), `layer_done`, `layer_cut` (a layer stopped midway, with
//! how many of its vectors were marked when known), `cut_layer_choice` (resume could not tell how
//! far a cut layer got, and the operator chose to redo or skip it). A torn last line (a crash
//! mid-write, no newline) is ignored and cut off on resume; any other bad line is an error.
//!
//! Lines go to a [`JournalSink`]: the file (write, then `fsync`), or in tests a stand-in that
//! fails on demand ([`Journal::wrap_sink`]). [`Journal::append_within`] bounds a write: it runs
//! on a thread of its own, and a write that has not returned within the timeout (a hung disk) is
//! abandoned; the journal then refuses every later append.

use std::collections::BTreeSet;
use std::fs::{File, OpenOptions};
use std::io::Write;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use trim_cell::job::{Job, LayerKey};

/// One journal line.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Entry {
    /// A run started (or resumed).
    Start {
        /// FNV-1a 64 of the job's JSON: resume refuses another job.
        job_digest: String,
        /// Layers in the job.
        layers: usize,
        /// Wall-clock time (ns since the Unix epoch).
        time_ns: u64,
        /// Whether this is a resume.
        resume: bool,
    },
    /// A list for a layer is about to be loaded.
    LayerBegin {
        /// The layer.
        key: LayerKey,
        /// The first vector of the list (0 unless resumed midway).
        first_vector: u32,
        /// Vectors in the layer.
        vectors: u32,
        /// The galvo list tag.
        tag: u32,
    },
    /// A layer is finished: every vector marked.
    LayerDone {
        /// The layer.
        key: LayerKey,
        /// Vectors in the layer.
        vectors: u32,
    },
    /// A layer stopped midway.
    LayerCut {
        /// The layer.
        key: LayerKey,
        /// Vectors of the layer marked, when known.
        vectors_done: Option<u32>,
        /// Why it stopped.
        reason: String,
    },
    /// Resume could not tell how far a cut layer got (the galvo lost its list: a controller
    /// restart, a crash of the host) and the operator chose what to do with it.
    CutLayerChoice {
        /// The layer.
        key: LayerKey,
        /// Redo or skip.
        choice: CutLayer,
        /// The first vector of the attempt whose progress is unknown (vectors before it were
        /// marked by earlier attempts, as journaled).
        first_vector: u32,
        /// Vectors in the layer.
        vectors: u32,
        /// Redo: how many vectors may be marked twice (`vectors − first_vector`); skip: 0.
        vectors_maybe_twice: u32,
        /// Why resume could not tell.
        reason: String,
    },
}

/// What to do with a layer cut at a point resume cannot tell (`trimctl run --cut-layer`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CutLayer {
    /// Mark the layer again from the first vector of the unknown attempt: vectors that attempt
    /// did mark are marked twice.
    Redo,
    /// Leave the layer out (never marked by this run); the run's report lists it.
    Skip,
}

impl std::fmt::Display for CutLayer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            CutLayer::Redo => "redo",
            CutLayer::Skip => "skip",
        })
    }
}

/// Where journal lines go.
pub trait JournalSink: Send {
    /// Writes one whole line (with its newline) and makes it durable before returning.
    fn append_line(&mut self, line: &[u8]) -> std::io::Result<()>;
}

impl JournalSink for File {
    fn append_line(&mut self, line: &[u8]) -> std::io::Result<()> {
        self.write_all(line)?;
        self.sync_data()
    }
}

/// A journal that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum JournalError {
    /// Reading or writing failed.
    #[error("journal {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// A line is not a journal entry.
    #[error("journal {path} line {line}: {what}")]
    BadLine {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        what: String,
    },
    /// The journal belongs to another job.
    #[error("journal {path} is for another job (digest {found}, this job {expected})")]
    OtherJob {
        /// The file.
        path: PathBuf,
        /// The journal's digest.
        found: String,
        /// This job's digest.
        expected: String,
    },
    /// The journal holds no `start` entry (empty, or cut before its first line ended): the run
    /// that made it stopped before anything was switched on.
    #[error(
        "journal {0} has no start entry (it is empty or was cut inside its first line): no layer was begun, so there is nothing to resume; remove it to start over"
    )]
    NoStart(PathBuf),
    /// A fresh run was asked for but the journal exists.
    #[error("journal {0} exists: resume the run, or remove the journal to start over")]
    Exists(PathBuf),
    /// Resume was asked for but there is no journal.
    #[error("journal {0} does not exist: nothing to resume")]
    Missing(PathBuf),
    /// A write (with its fsync) did not return in time: the disk hangs. The write is
    /// abandoned; the journal takes no more entries.
    #[error(
        "journal {path}: the write and fsync did not return within {timeout_ms} ms (a hung disk?)"
    )]
    Timeout {
        /// The file.
        path: PathBuf,
        /// The timeout (ms).
        timeout_ms: u64,
    },
}

/// What a journal says about a run.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct JournalState {
    /// Finished layers.
    pub finished: BTreeSet<LayerKey>,
    /// The last `layer_begin` with no `layer_done` after it.
    pub open_begin: Option<Entry>,
    /// The last `layer_cut` for that layer.
    pub open_cut: Option<Entry>,
    /// Layers left out by a `cut_layer_choice` of `skip`.
    pub left_out: BTreeSet<LayerKey>,
    /// `layer_begin` entries so far (the next tag counts on from it).
    pub begins: u32,
    /// Whether the last line was torn (ignored).
    pub torn_tail: bool,
    /// Bytes up to the end of the last whole line (where a torn tail starts).
    pub good_len: u64,
    /// Every entry, in order.
    pub entries: Vec<Entry>,
}

/// An open journal (append only).
pub struct Journal {
    path: PathBuf,
    sink: Box<dyn JournalSink>,
    digest: String,
    begins: u32,
}

impl std::fmt::Debug for Journal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Journal")
            .field("path", &self.path)
            .field("digest", &self.digest)
            .field("begins", &self.begins)
            .finish_non_exhaustive()
    }
}

/// Where lines go after a write was abandoned: nowhere, with the reason.
struct AbandonedSink(String);

impl JournalSink for AbandonedSink {
    fn append_line(&mut self, _line: &[u8]) -> std::io::Result<()> {
        Err(std::io::Error::other(self.0.clone()))
    }
}

/// A placeholder sink while [`Journal::wrap_sink`] swaps sinks; it is never written to.
struct NullSink;

impl JournalSink for NullSink {
    fn append_line(&mut self, _line: &[u8]) -> std::io::Result<()> {
        Err(std::io::Error::other("journal sink being replaced"))
    }
}

/// FNV-1a 64 of the job's JSON, hex.
#[must_use]
pub fn job_digest(job: &Job) -> String {
    let text = serde_json::to_string(job).unwrap_or_default();
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in text.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    format!("{h:016x}")
}

fn io(path: &Path) -> impl Fn(std::io::Error) -> JournalError + '_ {
    move |source| JournalError::Io {
        path: path.to_owned(),
        source,
    }
}

/// Reads a journal without opening it for writing.
pub fn read(path: &Path) -> Result<JournalState, JournalError> {
    let lines = crate::jsonl::read::<Entry>(path).map_err(|e| match e {
        crate::jsonl::ReadError::Io(e) => io(path)(e),
        crate::jsonl::ReadError::BadLine { line, what } => JournalError::BadLine {
            path: path.to_owned(),
            line,
            what,
        },
    })?;
    if lines.torn_tail {
        tracing::warn!(path = %path.display(), "journal: torn last line ignored");
    }
    let mut st = JournalState {
        torn_tail: lines.torn_tail,
        good_len: lines.good_len,
        ..JournalState::default()
    };
    for (_, entry) in lines.values {
        match &entry {
            Entry::LayerBegin { .. } => {
                st.begins += 1;
                st.open_begin = Some(entry.clone());
                st.open_cut = None;
            }
            Entry::LayerDone { key, .. } => {
                st.finished.insert(*key);
                if matches!(&st.open_begin, Some(Entry::LayerBegin { key: k, .. }) if k == key) {
                    st.open_begin = None;
                    st.open_cut = None;
                }
            }
            Entry::LayerCut { .. } => st.open_cut = Some(entry.clone()),
            Entry::CutLayerChoice {
                key,
                choice: CutLayer::Skip,
                ..
            } => {
                st.left_out.insert(*key);
                if matches!(&st.open_begin, Some(Entry::LayerBegin { key: k, .. }) if k == key) {
                    st.open_begin = None;
                    st.open_cut = None;
                }
            }
            Entry::CutLayerChoice { .. } | Entry::Start { .. } => {}
        }
        st.entries.push(entry);
    }
    Ok(st)
}

impl Journal {
    /// Creates a journal for a fresh run; refuses an existing file.
    pub fn create(path: &Path, job: &Job) -> Result<Journal, JournalError> {
        let file = OpenOptions::new()
            .create_new(true)
            .append(true)
            .open(path)
            .map_err(|e| {
                if e.kind() == std::io::ErrorKind::AlreadyExists {
                    JournalError::Exists(path.to_owned())
                } else {
                    io(path)(e)
                }
            })?;
        let mut j = Journal {
            path: path.to_owned(),
            sink: Box::new(file),
            digest: job_digest(job),
            begins: 0,
        };
        j.append(&Entry::Start {
            job_digest: j.digest.clone(),
            layers: job.layers().count(),
            time_ns: crate::tap::now_ns(),
            resume: false,
        })?;
        // The file's entry in its folder reaches the disk too: each append is flushed to the
        // file, but after a power cut a journal whose folder entry was never written would be
        // gone, and a retrim folder without its journal reads as never started (its layers
        // would be marked again).
        if let Some(folder) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::File::open(folder)
                .and_then(|f| f.sync_all())
                .map_err(io(folder))?;
        }
        Ok(j)
    }

    /// Opens an existing journal of this job to resume; returns what it says.
    pub fn resume(path: &Path, job: &Job) -> Result<(Journal, JournalState), JournalError> {
        if !path.exists() {
            return Err(JournalError::Missing(path.to_owned()));
        }
        let st = read(path)?;
        let digest = job_digest(job);
        let found = st.entries.iter().find_map(|e| match e {
            Entry::Start { job_digest, .. } => Some(job_digest.clone()),
            _ => None,
        });
        let Some(found) = found else {
            return Err(JournalError::NoStart(path.to_owned()));
        };
        if found != digest {
            return Err(JournalError::OtherJob {
                path: path.to_owned(),
                found,
                expected: digest,
            });
        }
        let file = crate::jsonl::open_append(path, st.torn_tail.then_some(st.good_len), false)
            .map_err(io(path))?;
        let mut j = Journal {
            path: path.to_owned(),
            sink: Box::new(file),
            digest,
            begins: st.begins,
        };
        j.append(&Entry::Start {
            job_digest: j.digest.clone(),
            layers: job.layers().count(),
            time_ns: crate::tap::now_ns(),
            resume: true,
        })?;
        Ok((j, st))
    }

    /// The tag of the next list: unique per attempt within this journal, the digest's low bits
    /// in the high half so another job's list is not mistaken for this one's.
    pub fn next_tag(&mut self) -> u32 {
        self.begins += 1;
        self.current_tag()
    }

    /// The tag [`Journal::next_tag`] gave last.
    #[must_use]
    pub fn current_tag(&self) -> u32 {
        let high = u32::from_str_radix(&self.digest[12..16], 16).unwrap_or(0) << 16;
        high | (self.begins & 0xFFFF)
    }

    fn line(&self, entry: &Entry) -> Result<String, JournalError> {
        let mut line = serde_json::to_string(entry).map_err(|e| JournalError::Io {
            path: self.path.clone(),
            source: std::io::Error::other(e),
        })?;
        line.push('\n');
        Ok(line)
    }

    /// Appends an entry and fsyncs, on the caller's thread (no bound on a hung disk: the
    /// executor uses [`Journal::append_within`]).
    pub fn append(&mut self, entry: &Entry) -> Result<(), JournalError> {
        let line = self.line(entry)?;
        self.sink
            .append_line(line.as_bytes())
            .map_err(io(&self.path))
    }

    /// Appends an entry and fsyncs within `timeout`: the write runs on a thread of its own
    /// (an OS thread, not the runtime's blocking pool, so a write hung for good never holds up
    /// the runtime's shutdown). Past the timeout the write is abandoned ([`JournalError::Timeout`])
    /// and every later append fails at once.
    pub async fn append_within(
        &mut self,
        entry: &Entry,
        timeout: std::time::Duration,
    ) -> Result<(), JournalError> {
        let line = self.line(entry)?;
        let timeout_ms = u64::try_from(timeout.as_millis()).unwrap_or(u64::MAX);
        let abandoned = format!(
            "an earlier write did not return within {timeout_ms} ms: the journal is abandoned"
        );
        let mut sink = std::mem::replace(&mut self.sink, Box::new(AbandonedSink(abandoned)));
        let (tx, rx) = tokio::sync::oneshot::channel();
        std::thread::Builder::new()
            .name("journal-write".into())
            .spawn(move || {
                let result = sink.append_line(line.as_bytes());
                // Nobody listens when the write was abandoned: the sink is dropped here.
                let _ = tx.send((sink, result));
            })
            .map_err(io(&self.path))?;
        match tokio::time::timeout(timeout, rx).await {
            Ok(Ok((sink, result))) => {
                self.sink = sink;
                result.map_err(io(&self.path))
            }
            Ok(Err(_)) => Err(io(&self.path)(std::io::Error::other(
                "the journal write thread ended without an answer (it panicked)",
            ))),
            Err(_) => Err(JournalError::Timeout {
                path: self.path.clone(),
                timeout_ms,
            }),
        }
    }

    /// Replaces where lines go by `wrap(current)`: tests wrap the file in a sink that fails
    /// on demand (a full disk, an I/O error).
    pub fn wrap_sink(&mut self, wrap: impl FnOnce(Box<dyn JournalSink>) -> Box<dyn JournalSink>) {
        let current = std::mem::replace(&mut self.sink, Box::new(NullSink));
        self.sink = wrap(current);
    }

    /// The file.
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use trim_cell::job::{JobSettings, TimeEstimate, ValidationReport};

    fn job() -> Job {
        Job {
            version: 1,
            layer_step_mm: 0.1,
            focus_half_length_mm: 0.4,
            zones: vec![],
            settings: JobSettings {
                lens: Default::default(),
                plan: trim_cell::plan_settings::PlanSettings::default(),
            },
            validation: ValidationReport::default(),
            estimate: TimeEstimate::default(),
            kerf: None,
        }
    }

    #[test]
    fn entries_survive_reopen_and_a_torn_tail_is_ignored() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.journal");
        let j0 = job();
        let k = LayerKey { zone: 0, layer: 1 };
        {
            let mut j = Journal::create(&path, &j0).unwrap();
            let tag = j.next_tag();
            j.append(&Entry::LayerBegin {
                key: k,
                first_vector: 0,
                vectors: 5,
                tag,
            })
            .unwrap();
            j.append(&Entry::LayerDone { key: k, vectors: 5 }).unwrap();
            let k2 = LayerKey { zone: 1, layer: 0 };
            let tag = j.next_tag();
            j.append(&Entry::LayerBegin {
                key: k2,
                first_vector: 0,
                vectors: 3,
                tag,
            })
            .unwrap();
            j.append(&Entry::LayerCut {
                key: k2,
                vectors_done: Some(2),
                reason: "test".into(),
            })
            .unwrap();
        }
        assert!(matches!(
            Journal::create(&path, &j0),
            Err(JournalError::Exists(_))
        ));
        // A crash mid-write.
        std::fs::OpenOptions::new()
            .append(true)
            .open(&path)
            .unwrap()
            .write_all(b"{\"kind\":\"layer_do")
            .unwrap();
        let (mut j, st) = Journal::resume(&path, &j0).unwrap();
        assert!(st.torn_tail);
        assert_eq!(st.finished.iter().copied().collect::<Vec<_>>(), vec![k]);
        assert!(matches!(
            st.open_begin,
            Some(Entry::LayerBegin {
                first_vector: 0,
                vectors: 3,
                ..
            })
        ));
        assert!(matches!(
            st.open_cut,
            Some(Entry::LayerCut {
                vectors_done: Some(2),
                ..
            })
        ));
        assert_eq!(st.begins, 2);
        assert_eq!(j.next_tag() & 0xFFFF, 3);
        j.append(&Entry::LayerDone {
            key: LayerKey { zone: 1, layer: 0 },
            vectors: 3,
        })
        .unwrap();
        let st = read(&path).unwrap();
        assert!(!st.torn_tail);
        assert_eq!(st.finished.len(), 2);
        assert!(st.open_begin.is_none());
        let mut other = job();
        other.layer_step_mm = 0.2;
        assert!(matches!(
            Journal::resume(&path, &other),
            Err(JournalError::OtherJob { .. })
        ));
        assert!(matches!(
            Journal::resume(&dir.path().join("none"), &j0),
            Err(JournalError::Missing(_))
        ));
        // Empty, or cut inside its start line: not "another job".
        for text in ["", "{\"kind\":\"start\",\"job_di"] {
            let cut = dir.path().join("cut.journal");
            std::fs::write(&cut, text).unwrap();
            let e = Journal::resume(&cut, &j0).expect_err("refused");
            assert!(matches!(e, JournalError::NoStart(_)), "{text:?}: {e}");
            assert!(e.to_string().contains("has no start entry"), "{e}");
        }
    }

    #[test]
    fn a_bad_line_in_the_middle_is_an_error_with_its_number() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("j");
        std::fs::write(&path, "{\"kind\":\"nope\"}\n{\"kind\":\"layer_done\",\"key\":{\"zone\":0,\"layer\":0},\"vectors\":1}\n").unwrap();
        match read(&path) {
            Err(JournalError::BadLine { line, .. }) => assert_eq!(line, 1),
            other => panic!("{other:?}"),
        }
    }
}
