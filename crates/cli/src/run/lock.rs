//! One writer per run folder: the process that writes a run folder (a fresh `run --out DIR`,
//! or `run --resume DIR`, which also writes every `retrim_<k>/` under it) holds an exclusive
//! advisory lock on `DIR/.lock` for as long as it writes.
//!
//! Without it two processes could append to one journal and drive the cell from two plans at
//! once: a resume started while the stopped run still lives (its way down is slow, or it was
//! never stopped), or the same `--out` given twice. The lock is the operating system's
//! (`flock` on Unix, `LockFileEx` on Windows, through `std::fs::File::try_lock`), so it dies
//! with the process however it ends: a run killed with SIGKILL or by a power cut leaves no
//! stale lock, and `--resume` needs no clean-up first. The file itself stays in the folder,
//! holding the last writer's process id; only a held lock refuses, never the file's presence
//! (removing the file on exit would let a third process lock a fresh inode while a second
//! still waited on the old one).

use std::fs::{File, OpenOptions, TryLockError};
use std::io::Write as _;
use std::path::Path;

use super::files::LOCK;
use crate::exit::{Exit, Failure};

/// The held lock of one run folder; released when dropped or when the process ends.
#[derive(Debug)]
pub(super) struct RunLock {
    /// Holds the lock: closing the file releases it.
    _file: File,
}

impl RunLock {
    /// Locks `run_dir` for this process, writing its process id into the lock file. Refused
    /// (exit 1) at once, naming the folder and the holder's process id, when another process
    /// holds it; refused too when the lock file cannot be opened or locked at all (a folder
    /// that cannot be locked is not written unguarded).
    pub(super) fn acquire(run_dir: &Path) -> anyhow::Result<RunLock> {
        let path = run_dir.join(LOCK);
        let refuse = |why: String| Failure::with_exit(Exit::Refused, anyhow::anyhow!(why));
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|e| {
                refuse(format!(
                    "cannot open {} to lock the run folder: {e}",
                    path.display()
                ))
            })?;
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                let holder = std::fs::read_to_string(&path)
                    .ok()
                    .and_then(|text| text.trim().parse::<u32>().ok())
                    .map_or_else(
                        || "process id not yet written".to_owned(),
                        |pid| format!("PID {pid}"),
                    );
                return Err(refuse(format!(
                    "{} is in use by another trimctl ({holder}, holding {}): a run folder is written by one process at a time; wait for it to end or stop it, then continue with trimctl run --resume {}",
                    run_dir.display(),
                    path.display(),
                    run_dir.display()
                )));
            }
            Err(TryLockError::Error(e)) => {
                return Err(refuse(format!("cannot lock {}: {e}", path.display())));
            }
        }
        // The holder's id, for the refusal above: written whole over the last writer's.
        let written = file
            .set_len(0)
            .and_then(|()| writeln!(file, "{}", std::process::id()))
            .and_then(|()| file.sync_all());
        written.map_err(|e| refuse(format!("cannot write {}: {e}", path.display())))?;
        Ok(RunLock { _file: file })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A second lock on a held folder is refused naming the folder and the holder's process id
    /// (flock locks are per open file, so a second open in the same process conflicts as
    /// another process's would); once the first is released the folder can be locked again.
    #[test]
    fn a_held_folder_is_refused_naming_it_and_its_holder() {
        let dir = tempfile::tempdir().expect("a folder");
        let first = RunLock::acquire(dir.path()).expect("the first lock");
        let e = RunLock::acquire(dir.path()).expect_err("held");
        let failure = e
            .downcast_ref::<Failure>()
            .expect("a failure with its exit");
        assert_eq!(failure.exit, Exit::Refused);
        let text = format!("{e:#}");
        assert!(
            text.contains(&format!("{} is in use", dir.path().display())),
            "{text}"
        );
        assert!(
            text.contains(&format!("PID {}", std::process::id())),
            "{text}"
        );
        drop(first);
        // A sibling test that spawns a process (the rescan tests) forks this test binary: the
        // child shares the open lock file until its exec closes it, so the released lock can
        // read as held for that instant. Retried for a bounded time, never forever.
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
        let again = loop {
            match RunLock::acquire(dir.path()) {
                Ok(lock) => break lock,
                Err(e) if std::time::Instant::now() < deadline => {
                    drop(e);
                    std::thread::sleep(std::time::Duration::from_millis(20));
                }
                Err(e) => panic!("free again: {e:#}"),
            }
        };
        let pid = std::fs::read_to_string(dir.path().join(LOCK)).expect("the lock file");
        assert_eq!(pid.trim(), std::process::id().to_string());
        drop(again);
    }

    /// A folder that does not exist cannot be locked, and the error names the lock file.
    #[test]
    fn a_missing_folder_is_refused_naming_the_lock_file() {
        let dir = tempfile::tempdir().expect("a folder");
        let missing = dir.path().join("nowhere");
        let e = format!("{:#}", RunLock::acquire(&missing).expect_err("no folder"));
        assert!(e.contains(&missing.join(LOCK).display().to_string()), "{e}");
    }
}
