//! What a `trimctl run --verify` run keeps in its folder so that, stopped anywhere, `trimctl run
//! --resume RUN` can carry it to the end (DESIGN.md "Ablation and the twin's part", `--verify`):
//!
//! - `verify_state.json` ([`VerifyState`]): that the run verifies, its `--rounds`, and for the
//!   built-in demo the spec its part was made from (the twin's part is made again from it and
//!   trimmed by the landed cuts of each execution, [`super::twin_cuts`]); written once, before
//!   the job's first layer;
//! - `verify.json`: the inspections done so far ([`Round`]s), rewritten after each one; a
//!   round is recorded only once its retrim, if any, is planned (`retrim_<k>/plan.json`), so a
//!   recorded round never needs inspecting again.
//!
//! Both are written whole to a temporary file that is then renamed over the old one: a kill
//! leaves the old file or the new one, never half of one.

use std::path::Path;

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};

use super::inputs::DemoSpec;
use super::verify::Round;
use super::{MAX_VERIFY_ROUNDS as MAX_ROUNDS, files};

/// The version of `verify_state.json` this trimctl writes and reads.
pub(super) const VERIFY_STATE_VERSION: u32 = 1;

/// `verify_state.json`: how the run's verify loop was asked for.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct VerifyState {
    /// [`VERIFY_STATE_VERSION`].
    pub(super) version: u32,
    /// `--rounds`: the most retrims (1–[`MAX_ROUNDS`]).
    pub(super) rounds: u32,
    /// The built-in demo part's spec (`--demo-seed`, `--demo-blockages`); null for a part of the
    /// job's own files (each inspection then waits for the cell's rescan, job.toml `[verify]`).
    pub(super) demo: Option<DemoSpec>,
}

impl VerifyState {
    /// Writes `run_dir/verify_state.json` (atomically).
    pub(super) fn save(&self, run_dir: &Path) -> anyhow::Result<()> {
        let text = serde_json::to_string_pretty(self).context("serialising the verify state")?;
        write_atomic(&run_dir.join(files::VERIFY_STATE), text.as_bytes())
    }

    /// `run_dir/verify_state.json`, or `None` when the run was not started with `--verify`
    /// (no such file). A file that cannot be read, is not the state, is of another version or
    /// holds rounds out of range is an error naming it.
    pub(super) fn load(run_dir: &Path) -> anyhow::Result<Option<VerifyState>> {
        let path = run_dir.join(files::VERIFY_STATE);
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
        };
        let state: VerifyState = serde_json::from_str(&text).with_context(|| {
            format!(
                "{}: not the state of a --verify run (corrupt?); the verify loop cannot be continued",
                path.display()
            )
        })?;
        if state.version != VERIFY_STATE_VERSION {
            bail!(
                "{}: version {}, this trimctl reads version {VERIFY_STATE_VERSION}",
                path.display(),
                state.version
            );
        }
        if !(1..=MAX_ROUNDS).contains(&state.rounds) {
            bail!(
                "{}: rounds = {}, expected 1–{MAX_ROUNDS}",
                path.display(),
                state.rounds
            );
        }
        if let Some(demo) = &state.demo
            && !(0.0..=1.0).contains(&demo.blockages)
        {
            bail!(
                "{}: demo.blockages = {}, expected a share in [0, 1]",
                path.display(),
                demo.blockages
            );
        }
        Ok(Some(state))
    }
}

/// Writes `run_dir/verify.json` (atomically): the rounds so far.
pub(super) fn save_rounds(run_dir: &Path, rounds: &[Round]) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(rounds).context("serialising the rounds")?;
    write_atomic(&run_dir.join(files::VERIFY), text.as_bytes())
}

/// The rounds `run_dir/verify.json` records (none when there is no such file: no inspection
/// was recorded yet). Refused, naming the file, when it is not a list of rounds, when they are
/// not inspections 1, 2, … in order, when a round before the last was not followed by a retrim
/// (the loop would have ended there), or when there are more than `max_rounds` + 1.
pub(super) fn load_rounds(run_dir: &Path, max_rounds: u32) -> anyhow::Result<Vec<Round>> {
    let path = run_dir.join(files::VERIFY);
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    };
    let rounds: Vec<Round> = serde_json::from_str(&text).with_context(|| {
        format!(
            "{}: not a list of verify rounds (corrupt?); the verify loop cannot be continued",
            path.display()
        )
    })?;
    for (i, r) in rounds.iter().enumerate() {
        let expected = u32::try_from(i + 1).unwrap_or(u32::MAX);
        if r.inspection != expected {
            bail!(
                "{}: round {} is inspection {}, expected {expected} (the rounds must be 1, 2, … once each)",
                path.display(),
                i + 1,
                r.inspection
            );
        }
        if i + 1 < rounds.len() && !r.retrimmed {
            bail!(
                "{}: inspection {} was not followed by a retrim, yet inspection {} is recorded",
                path.display(),
                r.inspection,
                r.inspection + 1
            );
        }
    }
    if rounds.len() > max_rounds as usize + 1 {
        bail!(
            "{}: {} inspections recorded, more than --rounds {max_rounds} allows ({})",
            path.display(),
            rounds.len(),
            max_rounds + 1
        );
    }
    Ok(rounds)
}

/// Writes `bytes` to `path` whole or not at all ([`trim_geom::fs::write_atomic`]): a reader
/// finds the old content or the new, never a part.
pub(super) fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    trim_geom::fs::write_atomic(path, bytes)
        .with_context(|| format!("cannot write {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn round(inspection: u32, retrimmed: bool) -> Round {
        Round {
            inspection,
            pass: 40,
            fail: usize::from(retrimmed),
            undecided: 0,
            failing: if retrimmed { vec![3] } else { Vec::new() },
            true_residual_max_um: Some(1.25),
            true_gouge_max_um: Some(8.0),
            true_residual_p95_um: Some(0.1 + 0.2),
            true_gouge_p95_um: None,
            true_film_covered_max: Some(0.0),
            hatched: Vec::new(),
            retrimmed,
        }
    }

    #[test]
    fn the_state_and_the_rounds_read_back_as_written() {
        let dir = tempfile::tempdir().expect("a temporary folder");
        assert_eq!(VerifyState::load(dir.path()).expect("no state"), None);
        assert!(load_rounds(dir.path(), 2).expect("no rounds").is_empty());
        let state = VerifyState {
            version: VERIFY_STATE_VERSION,
            rounds: 2,
            demo: Some(DemoSpec {
                seed: 7,
                blockages: 0.15,
                burred: true,
            }),
        };
        state.save(dir.path()).expect("saved");
        assert_eq!(
            VerifyState::load(dir.path()).expect("read"),
            Some(state.clone())
        );
        let rounds = vec![round(1, true), round(2, false)];
        save_rounds(dir.path(), &rounds).expect("saved");
        let back = load_rounds(dir.path(), 2).expect("read");
        // Bit for bit: summary.json copies these into "verify".
        assert_eq!(
            serde_json::to_string(&back).expect("json"),
            serde_json::to_string(&rounds).expect("json")
        );
        // No temporary file is left beside them.
        let names: Vec<String> = std::fs::read_dir(dir.path())
            .expect("listed")
            .map(|e| {
                e.expect("an entry")
                    .file_name()
                    .to_string_lossy()
                    .into_owned()
            })
            .collect();
        assert!(names.iter().all(|n| !n.ends_with(".tmp")), "{names:?}");
    }

    #[test]
    fn a_corrupt_state_or_bad_rounds_are_refused_naming_the_file() {
        let dir = tempfile::tempdir().expect("a temporary folder");
        let state = dir.path().join(files::VERIFY_STATE);
        for (text, says) in [
            ("{\"version\": 1, \"rounds\"", "corrupt"),
            (
                "{\"version\": 9, \"rounds\": 2, \"demo\": null}",
                "version 9",
            ),
            (
                "{\"version\": 1, \"rounds\": 0, \"demo\": null}",
                "rounds = 0",
            ),
            (
                "{\"version\": 1, \"rounds\": 2, \"demo\": {\"seed\": 1, \"blockages\": 2.0, \"burred\": true}}",
                "demo.blockages",
            ),
        ] {
            trim_geom::fs::write_atomic(&state, text).expect("written");
            let e = format!("{:#}", VerifyState::load(dir.path()).expect_err(text));
            assert!(e.contains("verify_state.json") && e.contains(says), "{e}");
        }
        let verify = dir.path().join(files::VERIFY);
        let json = |rounds: &[Round]| serde_json::to_string(rounds).expect("json");
        for (text, says) in [
            ("[{\"inspection\": 1", "corrupt".to_owned()),
            (
                &*json(&[round(1, true), round(1, false)]),
                "round 2 is inspection 1".to_owned(),
            ),
            (
                &*json(&[round(2, false)]),
                "round 1 is inspection 2".to_owned(),
            ),
            (
                &*json(&[round(1, false), round(2, false)]),
                "not followed by a retrim".to_owned(),
            ),
            (
                &*json(&[round(1, true), round(2, true), round(3, false)]),
                "more than --rounds 1".to_owned(),
            ),
        ] {
            trim_geom::fs::write_atomic(&verify, text).expect("written");
            let e = format!("{:#}", load_rounds(dir.path(), 1).expect_err(text));
            assert!(e.contains("verify.json") && e.contains(&says), "{e}");
        }
    }
}
