//! Argument parsing of the built binary: exit codes follow the README (0 done, 1 bad input),
//! never clap's own 2, which the README reserves for a device fault.

use std::process::{Command, Output};

const TRIMCTL: &str = env!("CARGO_BIN_EXE_trimctl");

fn trimctl(args: &[&str]) -> Output {
    Command::new(TRIMCTL)
        .args(args)
        .output()
        .expect("trimctl runs")
}

fn text(o: &Output) -> String {
    format!(
        "stdout:\n{}\nstderr:\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

#[test]
fn usage_errors_exit_1() {
    for args in [
        &["--no-such-flag"][..],
        &["run", "--no-such-flag"],
        &["info"],                       // missing required FILE
        &["register", "--cad", "a.stl"], // missing required --scan, --path, --out
        &["sim", "motor"],               // value outside the enum
        &["run", "--cut-layer", "redo"], // requires --resume
        &["run", "--resume", "x", "--cut-layer", "twice"],
        &["no-such-command"],
        &[], // no command at all
    ] {
        let o = trimctl(args);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {}", text(&o));
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(
            stderr.contains("Usage:") || stderr.contains("error:"),
            "{args:?}: no usage message on stderr: {}",
            text(&o)
        );
    }
}

#[test]
fn help_and_version_exit_0_on_stdout() {
    for args in [&["--help"][..], &["-h"], &["run", "--help"], &["help"]] {
        let o = trimctl(args);
        assert_eq!(o.status.code(), Some(0), "{args:?}: {}", text(&o));
        assert!(
            String::from_utf8_lossy(&o.stdout).contains("Usage:"),
            "{args:?}: {}",
            text(&o)
        );
    }
    let o = trimctl(&["--version"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert_eq!(
        String::from_utf8_lossy(&o.stdout).trim(),
        format!("trimctl {}", env!("CARGO_PKG_VERSION"))
    );
}
