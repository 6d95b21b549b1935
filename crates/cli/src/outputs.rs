//! Output files checked before the work: a command that would fail to write its second output
//! after hours (or seconds) of work has by then replaced its first, so each output's folder must
//! exist and the output must not be a folder before anything is computed.

use std::path::Path;

/// Refuses an output (`(flag, path)`) whose folder does not exist or is not a folder, or that is
/// itself a folder, naming the flag.
pub fn check(outputs: &[(&str, Option<&Path>)]) -> anyhow::Result<()> {
    for (flag, path) in outputs {
        let Some(path) = path else { continue };
        if path.is_dir() {
            anyhow::bail!("{flag} {}: is a folder, not a file", path.display());
        }
        let folder = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or_else(|| Path::new("."));
        if !folder.is_dir() {
            anyhow::bail!(
                "{flag} {}: its folder {} {}",
                path.display(),
                folder.display(),
                if folder.exists() {
                    "is not a folder"
                } else {
                    "does not exist"
                }
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_output_in_a_missing_folder_or_a_file_as_folder_is_refused_naming_the_flag() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("afile");
        std::fs::write(&file, "x").unwrap();
        check(&[("--out", Some(&dir.path().join("ok.csv"))), ("--svg", None)]).unwrap();
        let e = check(&[("--report", Some(&file.join("r.json")))])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--report") && e.contains("is not a folder"),
            "{e}"
        );
        let e = check(&[("--out", Some(&dir.path().join("no").join("x.csv")))])
            .unwrap_err()
            .to_string();
        assert!(e.contains("--out") && e.contains("does not exist"), "{e}");
        let e = check(&[("--out", Some(dir.path()))])
            .unwrap_err()
            .to_string();
        assert!(e.contains("is a folder"), "{e}");
    }
}
