//! The crates point one way (DESIGN.md "Crates", STYLE.md practice 2): geom ← register,
//! geom ← cell ← plan ← cli, cell ← io ← sim ← cli, cell ← calib ← cli; pybind on top. trim-io and
//! trim-calib never depend on trim-plan (they reach the cell and the Job through trim-cell), and
//! nothing in the workspace but the CLI links the simulators (trim-sim). tokio, pyo3 and clap
//! never reach geom, register, cell, plan or calib.

#![expect(
    clippy::unwrap_used,
    reason = "test helpers: a malformed cargo metadata output should fail the test loudly"
)]

use std::collections::{BTreeMap, BTreeSet};
use std::process::Command;

use serde_json::Value;

fn host_triple() -> String {
    let out = Command::new("rustc")
        .arg("-vV")
        .output()
        .expect("rustc -vV runs");
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .find_map(|l| l.strip_prefix("host: "))
        .expect("rustc -vV names the host")
        .to_string()
}

fn metadata() -> Value {
    let host = host_triple();
    let out = Command::new(env!("CARGO"))
        .args([
            "metadata",
            "--format-version",
            "1",
            "--filter-platform",
            &host,
        ])
        .current_dir(trimctl_tests::workspace_root())
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("cargo metadata prints JSON")
}

/// Normal (non-dev, non-build) dependencies of every package, by package name.
fn normal_deps(meta: &Value) -> BTreeMap<String, BTreeSet<String>> {
    let names: BTreeMap<&str, &str> = meta["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| (p["id"].as_str().unwrap(), p["name"].as_str().unwrap()))
        .collect();
    meta["resolve"]["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|node| {
            let deps = node["deps"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|d| {
                    d["dep_kinds"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .any(|k| k["kind"].is_null())
                })
                .map(|d| names[d["pkg"].as_str().unwrap()].to_string())
                .collect();
            (names[node["id"].as_str().unwrap()].to_string(), deps)
        })
        .collect()
}

fn reach(deps: &BTreeMap<String, BTreeSet<String>>, from: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut stack = vec![from.to_string()];
    while let Some(n) = stack.pop() {
        for d in deps.get(&n).into_iter().flatten() {
            if seen.insert(d.clone()) {
                stack.push(d.clone());
            }
        }
    }
    seen
}

#[test]
fn workspace_crates_point_one_way() {
    let deps = normal_deps(&metadata());
    let ours = [
        "trim-geom",
        "trim-register",
        "trim-inspect",
        "trim-cell",
        "trim-plan",
        "trim-calib",
        "trim-io",
        "trim-sim",
        "trim-synth",
        "trimctl",
        "trimctl-py",
    ];
    let allowed: BTreeMap<&str, &[&str]> = BTreeMap::from([
        ("trim-geom", &[][..]),
        // The synthetic part is geometry only.
        ("trim-synth", &["trim-geom"][..]),
        ("trim-register", &["trim-geom"][..]),
        // Inspection measures through the registration's fit, never the planner or the devices.
        ("trim-inspect", &["trim-geom", "trim-register"][..]),
        ("trim-cell", &["trim-geom"][..]),
        ("trim-plan", &["trim-geom", "trim-cell"][..]),
        ("trim-calib", &["trim-geom", "trim-cell"][..]),
        ("trim-io", &["trim-geom", "trim-cell"][..]),
        // The digital twin resolves the true cell against the PlanSettings and carries the
        // synthetic part through a run.
        (
            "trim-sim",
            &[
                "trim-geom",
                "trim-cell",
                "trim-plan",
                "trim-io",
                "trim-synth",
            ][..],
        ),
        (
            "trimctl",
            &[
                "trim-geom",
                "trim-register",
                "trim-inspect",
                "trim-cell",
                "trim-plan",
                "trim-calib",
                "trim-io",
                "trim-sim",
                "trim-synth",
            ][..],
        ),
        (
            "trimctl-py",
            &[
                "trim-geom",
                "trim-register",
                "trim-inspect",
                "trim-cell",
                "trim-plan",
                "trim-calib",
                "trim-synth",
            ][..],
        ),
    ]);
    for krate in ours {
        let inner: BTreeSet<&str> = deps[krate]
            .iter()
            .map(String::as_str)
            .filter(|d| ours.contains(d))
            .collect();
        let ok: BTreeSet<&str> = allowed[krate].iter().copied().collect();
        assert!(
            inner.is_subset(&ok),
            "{krate} depends on {inner:?}; only {ok:?} are allowed"
        );
    }
}

#[test]
fn io_and_calib_never_reach_the_planner() {
    let deps = normal_deps(&metadata());
    for krate in ["trim-io", "trim-calib", "trim-cell"] {
        let all = reach(&deps, krate);
        for banned in ["trim-plan", "linfa", "linfa-clustering"] {
            assert!(
                !all.contains(banned),
                "{krate} reaches {banned}: it should reach the cell and the Job through trim-cell"
            );
        }
    }
}

#[test]
fn only_the_cli_links_the_simulators() {
    let deps = normal_deps(&metadata());
    for (krate, direct) in &deps {
        assert!(
            krate == "trimctl" || !direct.contains("trim-sim"),
            "{krate} depends on trim-sim: only the CLI (feature `sim`) may"
        );
    }
}

#[test]
fn runtime_frameworks_stay_out_of_the_algorithm_crates() {
    let deps = normal_deps(&metadata());
    for krate in [
        "trim-geom",
        "trim-register",
        "trim-inspect",
        "trim-cell",
        "trim-plan",
        "trim-calib",
    ] {
        let all = reach(&deps, krate);
        for banned in ["tokio", "pyo3", "clap"] {
            assert!(!all.contains(banned), "{banned} reaches {krate}");
        }
    }
}
