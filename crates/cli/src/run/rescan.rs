//! `run --verify` on a part of the job's own files: each inspection's rescan comes from the
//! cell's scanner, as a file the run waits for or one a configured command writes (job.toml
//! `[verify]`). The part has not moved: the rescan is taken in the scanner frame at
//! `[part.scan_pose]`, as `part.scan` was, and carried into the work-piece frame the same way.
//! A part scanned as `part.scans` is rescanned at each of their poses (`{pose}` names which),
//! and the rescans are merged through the cell as the scans were (`trim_cell::scans_at_poses`):
//! the inspection sees every side the registration saw. trimctl does not move the machine to
//! those poses; the scan command, or the operator the run waits for, does.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime};

use anyhow::{Context, bail};
use trim_cell::cell_model::ScanPose;
use trim_cell::scans_at_poses;
use trim_geom::PointCloud;

use crate::config::{JobConfig, VerifyConfig};
use trim_geom::formats;

/// How often a wait looks again.
const POLL: Duration = Duration::from_millis(100);

/// A file counts as written when its size has not changed for this long (a scanner writing it
/// may still be at it when it first appears).
const SETTLED: Duration = Duration::from_millis(500);

/// A file's modification time may read this much before the clock at its writing (coarse file
/// system timestamps); a rescan counts when written at most this long before the round began.
const MTIME_SLACK: Duration = Duration::from_secs(1);

/// Where inspection `round`'s rescan appears: `[verify] scan_file` with `{round}` filled in,
/// relative to the run folder. At a pose of `part.scans` (`pose`, the scan's file stem),
/// `{pose}` becomes it; a `scan_file` without `{pose}` gets `_<pose>` before its extension, so
/// that the poses' rescans do not share a file.
pub(super) fn scan_file(
    verify: &VerifyConfig,
    run_dir: &Path,
    round: u32,
    pose: Option<&str>,
) -> PathBuf {
    let mut name = verify.scan_file.replace("{round}", &round.to_string());
    if let Some(pose) = pose {
        if name.contains("{pose}") {
            name = name.replace("{pose}", pose);
        } else {
            name = with_suffix(Path::new(&name), &format!("_{pose}"))
                .to_string_lossy()
                .into_owned();
        }
    }
    let file = PathBuf::from(name);
    if file.is_relative() {
        run_dir.join(file)
    } else {
        file
    }
}

/// `file` with `suffix` put before its extension.
fn with_suffix(file: &Path, suffix: &str) -> PathBuf {
    let stem = file
        .file_stem()
        .map_or_else(|| "rescan".into(), |s| s.to_string_lossy().into_owned());
    let name = match file.extension() {
        Some(ext) => format!("{stem}{suffix}.{}", ext.to_string_lossy()),
        None => format!("{stem}{suffix}"),
    };
    file.with_file_name(name)
}

/// Where inspection `round`'s second look is written: the round's scan file with `_again`
/// before its extension.
pub(super) fn scan_file_again(
    verify: &VerifyConfig,
    run_dir: &Path,
    round: u32,
    pose: Option<&str>,
) -> PathBuf {
    with_suffix(&scan_file(verify, run_dir, round, pose), "_again")
}

/// Inspection `round`'s rescan, work-piece frame: `[verify] scan_command` run to write it, or
/// the file waited for; either within `[verify] scan_timeout_s`. With `part.scans`, one rescan
/// at each of their poses, merged.
pub(super) fn rescan(config: &JobConfig, run_dir: &Path, round: u32) -> anyhow::Result<PointCloud> {
    look_everywhere(config, round, 1, |pose| {
        scan_file(&config.verify, run_dir, round, pose)
    })
}

/// A second look for inspection `round` when its rescan left contours uncovered: with a
/// `[verify] scan_command`, the command is run once more (`{look}` 2) to write
/// [`scan_file_again`] (at every pose, with `part.scans`), and that scan is returned,
/// work-piece frame; without one, none (a scan the run waits for is taken as given: the
/// operator is not asked for another).
pub(super) fn rescan_again(
    config: &JobConfig,
    run_dir: &Path,
    round: u32,
) -> anyhow::Result<Option<PointCloud>> {
    if config.verify.scan_command.is_empty() {
        return Ok(None);
    }
    look_everywhere(config, round, 2, |pose| {
        scan_file_again(&config.verify, run_dir, round, pose)
    })
    .map(Some)
}

/// Look `look` of inspection `round`, work-piece frame: at `[part.scan_pose]` to the file
/// `file(None)`, or with `part.scans` at each of their poses to `file(Some(stem))`, merged.
fn look_everywhere(
    config: &JobConfig,
    round: u32,
    look: u32,
    file: impl Fn(Option<&str>) -> PathBuf,
) -> anyhow::Result<PointCloud> {
    let what = if look > 1 {
        "the second look"
    } else {
        "the rescan"
    };
    let Some(poses) = config.rescan_poses()? else {
        let file = file(None);
        let cloud = scan(config, &file, (round, look), None)?;
        return config
            .workpiece_from_scan(&cloud)
            .with_context(|| format!("verify {round}: {what} {}", file.display()));
    };
    let mut scans: Vec<(ScanPose, PointCloud)> = Vec::with_capacity(poses.len());
    let mut files = Vec::with_capacity(poses.len());
    for (label, pose) in &poses {
        let file = file(Some(label));
        scans.push((
            *pose,
            scan(config, &file, (round, look), Some((label, pose)))?,
        ));
        files.push(file);
    }
    scans_at_poses::merge(&scans, &config.plan).map_err(|e| {
        // `merge` names a scan by its place (`scans[1]`); the operator knows it by its file.
        let named = files
            .iter()
            .enumerate()
            .fold(e.to_string(), |text, (k, f)| {
                text.replace(&format!("scans[{k}]"), &f.display().to_string())
            });
        anyhow::anyhow!("verify {round}: {what} at the poses of part.scans: {named}")
    })
}

/// Look `look` of inspection `round` (1, or 2 for a second look), written to `file` by the
/// scan command or, without one, waited for there, and read (scanner frame). `pose` is the
/// pose of `part.scans` it is taken at, by name, if any.
fn scan(
    config: &JobConfig,
    file: &Path,
    (round, look): (u32, u32),
    pose: Option<(&str, &ScanPose)>,
) -> anyhow::Result<PointCloud> {
    let verify = &config.verify;
    let what = if look > 1 {
        "the second look"
    } else {
        "the rescan"
    };
    let at = pose.map_or_else(String::new, |(label, p)| {
        format!(
            " at pose {label} (x {} y {} z {} mm, tilt {}°, c {}°)",
            p.xyz_mm[0], p.xyz_mm[1], p.xyz_mm[2], p.tilt_deg, p.c_deg
        )
    });
    // Only a file written from now on is this look's (one already there is an older scan,
    // e.g. the last round's when `scan_file` names no `{round}`).
    let since = SystemTime::now()
        .checked_sub(MTIME_SLACK)
        .unwrap_or(SystemTime::UNIX_EPOCH);
    let timeout = Duration::from_secs_f64(verify.scan_timeout_s);
    if verify.scan_command.is_empty() {
        println!(
            "verify {round}: waiting for the rescan of the part{at} at {} (timeout {} s)",
            file.display(),
            verify.scan_timeout_s
        );
        wait_for_file(file, since, timeout)
            .with_context(|| format!("verify {round}: no rescan{at} (job.toml [verify])"))?;
    } else {
        let label = pose.map(|(l, _)| l);
        run_scan_command(&verify.scan_command, file, (round, look, label), timeout)?;
        if !written_since(file, since) {
            bail!(
                "verify {round}: [verify] scan_command {:?} succeeded but wrote no {} ({what}{at})",
                verify.scan_command,
                file.display()
            );
        }
    }
    formats::read_points(file).with_context(|| format!("verify {round}: {what}{at}"))
}

/// Whether `file` exists and was written at or after `since`.
fn written_since(file: &Path, since: SystemTime) -> bool {
    std::fs::metadata(file)
        .and_then(|m| m.modified())
        .is_ok_and(|t| t >= since)
}

/// Waits until `file` has been written at or after `since` and its size has settled, or
/// `timeout` has passed.
fn wait_for_file(file: &Path, since: SystemTime, timeout: Duration) -> anyhow::Result<()> {
    let start = Instant::now();
    let mut last: Option<(u64, Instant)> = None;
    loop {
        trim_geom::cancel::check()?;
        if let Some(meta) = std::fs::metadata(file)
            .ok()
            .filter(|_| written_since(file, since))
        {
            let size = meta.len();
            match last {
                Some((s, since)) if s == size && size > 0 && since.elapsed() >= SETTLED => {
                    return Ok(());
                }
                Some((s, _)) if s == size => {}
                _ => last = Some((size, Instant::now())),
            }
        }
        if start.elapsed() >= timeout {
            bail!(
                "timed out after {:.1} s waiting for {}",
                timeout.as_secs_f64(),
                file.display()
            );
        }
        std::thread::sleep(POLL);
    }
}

/// Runs the scan command (`{scan}` → `file`, `{round}` → the round, `{look}` → 1, or 2 for a
/// second look, `{pose}` → the pose's name, or nothing, in every word), killing it when it
/// outlasts `timeout`; a failure names the command and the end of what it printed.
fn run_scan_command(
    command: &[String],
    file: &Path,
    (round, look, pose): (u32, u32, Option<&str>),
    timeout: Duration,
) -> anyhow::Result<()> {
    let words: Vec<String> = command
        .iter()
        .map(|w| {
            w.replace("{scan}", &file.to_string_lossy())
                .replace("{round}", &round.to_string())
                .replace("{look}", &look.to_string())
                .replace("{pose}", pose.unwrap_or(""))
        })
        .collect();
    let (program, args) = words
        .split_first()
        .context("verify.scan_command is empty")?;
    let at = pose.map_or_else(String::new, |p| format!(" at pose {p}"));
    if look > 1 {
        println!(
            "verify {round}: rescanning the part{at} again for the contours it left uncovered: {}",
            words.join(" ")
        );
    } else {
        println!(
            "verify {round}: rescanning the part{at}: {}",
            words.join(" ")
        );
    }
    let stderr_file = file.with_extension("scan_command.log");
    if let Some(dir) = file.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let log = std::fs::File::create(&stderr_file)
        .with_context(|| format!("cannot create {}", stderr_file.display()))?;
    let mut child = Command::new(program)
        .args(args)
        .stdin(Stdio::null())
        .stdout(log.try_clone()?)
        .stderr(log)
        .spawn()
        .with_context(|| {
            format!("verify {round}{at}: cannot start [verify] scan_command {program:?}")
        })?;
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait()? {
            break status;
        }
        let stop = if start.elapsed() >= timeout {
            Some(format!("timed out after {:.1} s", timeout.as_secs_f64()))
        } else {
            trim_geom::cancel::check().err().map(|e| e.to_string())
        };
        if let Some(why) = stop {
            let _ = child.kill();
            let _ = child.wait();
            bail!("verify {round}{at}: [verify] scan_command {words:?} {why}; it was stopped");
        }
        std::thread::sleep(POLL);
    };
    if !status.success() {
        let printed = std::fs::read_to_string(&stderr_file).unwrap_or_default();
        let tail: Vec<&str> = printed.lines().rev().take(5).collect();
        let tail: Vec<&str> = tail.into_iter().rev().collect();
        bail!(
            "verify {round}{at}: [verify] scan_command {words:?} failed ({status}); it printed:\n  {}",
            tail.join("\n  ")
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scan_file_fills_in_the_round_and_lies_in_the_run_folder_unless_absolute() {
        let mut v = VerifyConfig::default();
        assert_eq!(
            scan_file(&v, Path::new("/runs/a"), 2, None),
            PathBuf::from("/runs/a/rescan_2.ply")
        );
        v.scan_file = "/scans/part_{round}.xyz".to_owned();
        assert_eq!(
            scan_file(&v, Path::new("/runs/a"), 3, None),
            PathBuf::from("/scans/part_3.xyz")
        );
    }

    #[test]
    fn the_second_look_is_the_rounds_file_with_again_before_its_extension() {
        let mut v = VerifyConfig::default();
        assert_eq!(
            scan_file_again(&v, Path::new("/runs/a"), 2, None),
            PathBuf::from("/runs/a/rescan_2_again.ply")
        );
        v.scan_file = "/scans/part_{round}".to_owned();
        assert_eq!(
            scan_file_again(&v, Path::new("/runs/a"), 3, None),
            PathBuf::from("/scans/part_3_again")
        );
    }

    #[test]
    fn at_a_pose_of_the_parts_scans_the_file_names_the_pose() {
        let mut v = VerifyConfig::default();
        // No `{pose}`: the pose's name goes before the extension.
        assert_eq!(
            scan_file(&v, Path::new("/runs/a"), 2, Some("side0")),
            PathBuf::from("/runs/a/rescan_2_side0.ply")
        );
        assert_eq!(
            scan_file_again(&v, Path::new("/runs/a"), 2, Some("side0")),
            PathBuf::from("/runs/a/rescan_2_side0_again.ply")
        );
        v.scan_file = "/scans/{pose}/part_{round}.xyz".to_owned();
        assert_eq!(
            scan_file(&v, Path::new("/runs/a"), 3, Some("top")),
            PathBuf::from("/scans/top/part_3.xyz")
        );
        assert_eq!(
            scan_file_again(&v, Path::new("/runs/a"), 3, Some("top")),
            PathBuf::from("/scans/top/part_3_again.xyz")
        );
    }

    #[test]
    fn a_file_that_never_comes_times_out_naming_it_and_an_older_one_is_not_taken() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("never.ply");
        let err = wait_for_file(&file, SystemTime::now(), Duration::from_millis(300)).unwrap_err();
        assert!(err.to_string().contains("never.ply"), "{err}");
        assert!(err.to_string().contains("timed out"), "{err}");
        // A scan written before the wait began (the last round's) is not this round's.
        let old = dir.path().join("old.ply");
        trim_geom::fs::write_atomic(&old, "ply").unwrap();
        let since = SystemTime::now() + Duration::from_secs(1);
        assert!(wait_for_file(&old, since, Duration::from_millis(300)).is_err());
        // Written now, it is taken once its size has settled.
        assert!(wait_for_file(&old, SystemTime::UNIX_EPOCH, Duration::from_secs(5)).is_ok());
    }

    #[test]
    fn a_command_that_hangs_is_stopped_at_the_timeout_and_one_that_fails_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("scan.ply");
        let hang = ["sleep".to_owned(), "30".to_owned()];
        let start = Instant::now();
        let err =
            run_scan_command(&hang, &file, (1, 1, None), Duration::from_millis(300)).unwrap_err();
        assert!(start.elapsed() < Duration::from_secs(10), "not stopped");
        assert!(err.to_string().contains("timed out"), "{err}");
        let fail = [
            "sh".to_owned(),
            "-c".to_owned(),
            "echo scanner offline >&2; exit 3".to_owned(),
        ];
        let err =
            run_scan_command(&fail, &file, (2, 1, None), Duration::from_secs(10)).unwrap_err();
        let text = err.to_string();
        assert!(
            text.contains("scanner offline") && text.contains("verify 2"),
            "{text}"
        );
    }
}
