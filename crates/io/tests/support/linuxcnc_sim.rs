//! A real, headless LinuxCNC for the tests that need one (`scripts/linuxcnc-sim`, following
//! docs/cnc/LINUXCNC.md), shared by trim-io's and trimctl's LinuxCNC tests (the latter include
//! this file by path). One instance per machine: each test uses its own port and run folder.

use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

fn script() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scripts/linuxcnc-sim")
}

/// Whether LinuxCNC is installed. Without it the test fails with a clear message, unless
/// `TRIMCTL_SKIP_LINUXCNC=1` (then `false`: the test is skipped, saying so).
pub fn available() -> bool {
    let installed = Command::new("sh")
        .args(["-c", "command -v linuxcnc"])
        .output()
        .is_ok_and(|o| o.status.success());
    if installed {
        return true;
    }
    if std::env::var("TRIMCTL_SKIP_LINUXCNC").as_deref() == Ok("1") {
        eprintln!("SKIPPED: linuxcnc is not installed and TRIMCTL_SKIP_LINUXCNC=1");
        return false;
    }
    panic!(
        "linuxcnc is not installed: run scripts/install-deps (Debian package linuxcnc-uspace, \
         --no-install-recommends), or set TRIMCTL_SKIP_LINUXCNC=1 to skip this test"
    );
}

/// A running LinuxCNC, stopped when dropped.
pub struct Instance {
    run_dir: String,
}

impl Instance {
    /// Starts LinuxCNC with linuxcncrsh on `port`, its run folder `TRIMCTL_LINUXCNC_RUN` or
    /// `default_run_dir`; a leftover instance from an aborted run is stopped first.
    pub fn start(port: u16, default_run_dir: &str) -> Instance {
        let run_dir =
            std::env::var("TRIMCTL_LINUXCNC_RUN").unwrap_or_else(|_| default_run_dir.into());
        let instance = Instance { run_dir };
        let _ = instance.script("stop").status();
        let t = Instant::now();
        let out = instance
            .script("start")
            .args(["--port", &port.to_string()])
            .output()
            .expect("run scripts/linuxcnc-sim");
        assert!(
            out.status.success(),
            "scripts/linuxcnc-sim start failed:\n{}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        eprintln!("linuxcnc started in {:.2} s", t.elapsed().as_secs_f64());
        instance
    }

    fn script(&self, verb: &str) -> Command {
        let mut c = Command::new(script());
        c.env("TRIMCTL_LINUXCNC_RUN", &self.run_dir).arg(verb);
        c
    }
}

impl Drop for Instance {
    fn drop(&mut self) {
        let t = Instant::now();
        let ok = self.script("stop").status().is_ok_and(|s| s.success());
        eprintln!(
            "linuxcnc stopped ({ok}) in {:.2} s",
            t.elapsed().as_secs_f64()
        );
    }
}
