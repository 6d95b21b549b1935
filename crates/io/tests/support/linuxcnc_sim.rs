//! A real, headless LinuxCNC for the tests that need one (`scripts/linuxcnc-sim`, following
//! docs/cnc/LINUXCNC.md), shared by trim-io's and trimctl's LinuxCNC tests (the latter include
//! this file by path). One instance per machine: each test uses its own port and run folder.
//!
//! A skip must show as one: libtest decides `#[ignore]` when the test is compiled, and whether
//! LinuxCNC is here is known only when it runs, so these test binaries run on libtest-mimic
//! (`harness = false`, [`run_test`]). Without LinuxCNC and with `TRIMCTL_SKIP_LINUXCNC=1` the
//! test is reported `ignored, needs LinuxCNC …` and counted in cargo test's summary
//! (`0 passed; 0 failed; 1 ignored`), not "ok"; without the variable it fails, saying how to
//! install LinuxCNC.

use std::path::PathBuf;
use std::process::{Command, ExitCode};
use std::time::Instant;

fn script() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scripts/linuxcnc-sim")
}

/// Why the test is skipped: `None` when LinuxCNC is installed; the reason when it is not and
/// `TRIMCTL_SKIP_LINUXCNC=1`. Without LinuxCNC and without the variable the test fails here,
/// saying how to install it.
pub fn skip_reason() -> Option<String> {
    let installed = Command::new("sh")
        .args(["-c", "command -v linuxcnc"])
        .output()
        .is_ok_and(|o| o.status.success());
    if installed {
        return None;
    }
    if std::env::var("TRIMCTL_SKIP_LINUXCNC").as_deref() == Ok("1") {
        return Some("needs LinuxCNC: not installed, and TRIMCTL_SKIP_LINUXCNC=1".to_owned());
    }
    panic!(
        "linuxcnc is not installed: run scripts/install-deps (Debian package linuxcnc-uspace, \
         --no-install-recommends), or set TRIMCTL_SKIP_LINUXCNC=1 to skip this test"
    );
}

/// The `main` of a LinuxCNC test binary: runs `test` as the trial `name` under libtest-mimic
/// (cargo test's arguments, filters and `--list` included), ignored at run time with the reason
/// from [`skip_reason`] (printed as a `SKIPPED:` line as well), failed if it panics.
pub fn run_test(name: &'static str, test: fn()) -> ExitCode {
    let args = libtest_mimic::Arguments::from_args();
    let trial = libtest_mimic::Trial::ignorable_test(name, move || {
        if let Some(why) = skip_reason() {
            eprintln!("SKIPPED: {name}: {why}");
            return Ok(libtest_mimic::Completion::ignored_with(why));
        }
        test();
        Ok(libtest_mimic::Completion::Completed)
    });
    libtest_mimic::run(&args, vec![trial]).exit_code()
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
