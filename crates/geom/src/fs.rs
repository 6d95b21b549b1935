//! Writing a file whole or not at all: [`write_atomic`] writes beside the file and renames
//! over it, so a failed write (a full disk, a killed process) leaves the file as it was instead
//! of a truncated one that may still parse (a path CSV cut at a line end reads as fewer
//! contours, and a cut number as another number).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Temporary names taken by this process, so that two threads writing one file do not share one.
static NEXT: AtomicU64 = AtomicU64::new(0);

/// As [`std::fs::write`], but the file is replaced whole or not at all: `contents` go into a
/// temporary file in the same folder, flushed to the disk, which is then renamed over `path`.
/// On an error the temporary file is removed and `path` is untouched. A symbolic link is
/// followed (the file it names is replaced, the link stays); a path that is not a regular file
/// (`/dev/stdout`, a FIFO) is written directly.
///
/// # Errors
/// Those of creating, writing, flushing or renaming the file.
pub fn write_atomic(path: impl AsRef<Path>, contents: impl AsRef<[u8]>) -> std::io::Result<()> {
    let path = path.as_ref();
    let target = match std::fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => std::fs::canonicalize(path)?,
        _ => path.to_path_buf(),
    };
    if std::fs::metadata(&target).is_ok_and(|m| !m.is_file()) {
        return std::fs::write(&target, contents);
    }
    let temporary = temporary_beside(&target)?;
    let written = (|| {
        let mut file = std::fs::File::create(&temporary)?;
        file.write_all(contents.as_ref())?;
        file.sync_data()?;
        drop(file);
        std::fs::rename(&temporary, &target)
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&temporary);
    }
    written
}

/// A name in `target`'s folder for its temporary copy (`.NAME.PID.N.tmp`).
fn temporary_beside(target: &Path) -> std::io::Result<PathBuf> {
    let name = target.file_name().ok_or_else(|| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("{} names no file", target.display()),
        )
    })?;
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    let temporary = format!(".{}.{}.{n}.tmp", name.to_string_lossy(), std::process::id());
    Ok(target.with_file_name(temporary))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replaces_the_file_whole_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("path.csv");
        std::fs::write(&file, "old").unwrap();
        write_atomic(&file, "new contents").unwrap();
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "new contents");
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "a temporary file was left: {names:?}");
    }

    /// The old file is replaced by another, never rewritten in place: a reader that opened it
    /// before still reads it whole (a write truncating it in place, which a full disk then cut
    /// short, is what lost the old path).
    #[test]
    fn the_old_file_is_replaced_not_rewritten_in_place() {
        use std::io::Read as _;
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("path.csv");
        std::fs::write(&file, "old contents").unwrap();
        let mut before = std::fs::File::open(&file).unwrap();
        write_atomic(&file, "new").unwrap();
        let mut seen = String::new();
        before.read_to_string(&mut seen).unwrap();
        assert_eq!(seen, "old contents");
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "new");
    }

    #[test]
    fn a_write_that_cannot_be_made_leaves_the_old_file_and_nothing_else() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("out.csv");
        std::fs::write(&file, "old").unwrap();
        // A folder that does not exist, and a folder where the file should be: each write
        // fails, and nothing is left behind.
        let missing = dir.path().join("no_such_folder").join("out.csv");
        assert!(write_atomic(&missing, "new").is_err());
        let folder = dir.path().join("folder");
        std::fs::create_dir(&folder).unwrap();
        assert!(write_atomic(&folder, "new").is_err());
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "old");
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 2, "a temporary file was left: {names:?}");
    }

    #[test]
    fn a_symbolic_link_is_followed_and_kept() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("real.csv");
        let link = dir.path().join("link.csv");
        std::fs::write(&file, "old").unwrap();
        std::os::unix::fs::symlink(&file, &link).unwrap();
        write_atomic(&link, "new").unwrap();
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "new");
    }
}
