//! `trimctl run --live`: the address is checked, and a port that cannot be listened on is
//! refused before anything else is done (exit 1, one line naming the address). The live view
//! itself is tested end to end by tests/python/test_live_view.py.

use std::process::Command;

const TRIMCTL: &str = env!("CARGO_BIN_EXE_trimctl");

#[test]
fn a_bad_address_is_refused_with_what_is_wrong() {
    for (value, why) in [
        ("8765", "no ':PORT'"),
        ("localhost:http", "not a number"),
        ("job.toml", "give the job file before --live"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let out = Command::new(TRIMCTL)
            .args(["run", "--out"])
            .arg(dir.path().join("run"))
            .args(["--live", value])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{value}: {stderr}");
        assert!(
            stderr.contains("expected HOST:PORT") && stderr.contains(why),
            "{value}: {stderr}"
        );
        assert!(
            !dir.path().join("run").exists(),
            "{value}: a run folder was made"
        );
    }
    // A dry run executes nothing, so it has nothing to serve.
    let out = Command::new(TRIMCTL)
        .args(["run", "--dry-run", "--live"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("--dry-run"), "{stderr}");
}

#[test]
fn a_taken_port_is_refused_before_the_run_starts() {
    let holder = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = holder.local_addr().unwrap().port();
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(TRIMCTL)
        .args(["run", "--out"])
        .arg(dir.path().join("run"))
        .arg(format!("--live=127.0.0.1:{port}"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!("--live: cannot listen on 127.0.0.1:{port}")),
        "{stderr}"
    );
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(!dir.path().join("run").exists(), "a run folder was made");
}
