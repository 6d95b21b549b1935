"""examples/python/batch_dask.py plans a folder of parts on a Dask cluster: each part's plan
equals the plan of the same files made in this process, every worker's rayon pool holds the
threads asked for, and a part that fails is named without losing the others.

dask and distributed are imported unconditionally: scripts/python-env installs them, so a
missing one fails this module instead of skipping it."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import distributed  # noqa: F401  (fails here, not silently later, when it is missing)
import trimctl
from conftest import ROOT

SCRIPT = ROOT / "examples" / "python" / "batch_dask.py"
# Six parts, the demo part's generator at its default size with the demo's three scanner views.
# The test is about determinism across workers, so its parts must plan: registration's cautious
# bound (issue 21) flags one good contour on seeds 5, 6 and 7 of 1–12, so those are left out.
SEEDS = (1, 2, 3, 4, 8, 9)
RUN_TIMEOUT_S = 300


def write_part(folder, seed):
    """One part folder as `trimctl synth --out FOLDER --seed SEED` writes it (the files the
    script reads: the same generator and writers)."""
    case = trimctl.synth(seed=seed, scanner_views=3)
    folder.mkdir(parents=True)
    trimctl.write_points(folder / "scan.ply", case.scan)
    trimctl.write_points(folder / "cad_points.ply", case.cad_points, normals=case.cad_normals)
    trimctl.write_path(folder / "path.csv", case.path)
    (folder / "case.json").write_text(json.dumps(
        {"params": {"seed": seed}, "scan_from_cad_nominal": case.scan_from_cad_nominal.tolist()}))


def plan_here(folder, tmp):
    """The single-process plan of a part folder, with this process's own rayon pool (as many
    threads as cores): registered path CSV bytes and the Job."""
    scan, _ = trimctl.read_points(folder / "scan.ply")
    cad, normals = trimctl.read_points(folder / "cad_points.ply")
    init = np.asarray(json.loads((folder / "case.json").read_text())["scan_from_cad_nominal"])
    reg = trimctl.register_path(cad, scan, trimctl.read_path(folder / "path.csv"),
                                cad_normals=normals, init=init)
    assert not reg.untrustworthy, (folder.name, reg.untrustworthy)
    csv = tmp / f"{folder.name}-registered.csv"
    trimctl.write_path(csv, reg.path)
    return csv.read_bytes(), trimctl.plan(reg.path).job


@pytest.fixture(scope="module")
def parts(tmp_path_factory):
    """The six part folders and each one's single-process result."""
    root = tmp_path_factory.mktemp("batch")
    folder = root / "parts"
    expected = {}
    for seed in SEEDS:
        write_part(folder / f"core-{seed}", seed)
        expected[f"core-{seed}"] = plan_here(folder / f"core-{seed}", root)
    return folder, expected


def run_script(*args):
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)],
                          capture_output=True, text=True, timeout=RUN_TIMEOUT_S)


def assert_same_results(out, names, expected):
    for name in names:
        registered, job = expected[name]
        assert (out / name / "registered.csv").read_bytes() == registered, name
        # Exact: registration and planning give the same bits for any number of rayon threads
        # (fixed-chunk reductions added in order), and the Job's JSON round-trips every f64.
        assert json.loads((out / name / "plan.json").read_text()) == job, name
        assert not (out / name / "error.txt").exists(), name


def test_six_parts_on_two_workers_equal_the_single_process_plans(parts, tmp_path):
    folder, expected = parts
    out = tmp_path / "plans"
    r = run_script(folder, "--out", out, "--workers", 2, "--threads-per-worker", 1)
    assert r.returncode == 0, r.stdout + r.stderr
    progress = [l for l in r.stdout.splitlines() if l.startswith("[")]
    assert [l.split("]")[0] for l in progress] == [f"[{i}/6" for i in range(1, 7)], r.stdout
    assert sorted(l.split()[1].rstrip(":") for l in progress) == sorted(expected)
    assert "batch: 6 of 6 parts planned" in r.stdout, r.stdout

    summary = json.loads((out / "summary.json").read_text())
    # The cap holds: each worker process's rayon pool has one thread (threads counted in /proc),
    # where this process's has one per core.
    assert len(summary["workers"]) == 2
    for worker in summary["workers"].values():
        assert worker["rayon_threads"] == 1 and worker["RAYON_NUM_THREADS"] == "1", worker
    assert {p["status"] for p in summary["parts"].values()} == {"planned"}
    assert {p["rayon_threads"] for p in summary["parts"].values()} == {1}
    assert {p["worker"] for p in summary["parts"].values()} == set(summary["workers"])
    assert_same_results(out, expected, expected)


def test_rayon_threads_are_counted_as_the_pool_has_them():
    """The script's count of a worker's rayon threads is real: in a fresh process with
    RAYON_NUM_THREADS=3 it reads 0 before the first native call and 3 after."""
    code = (
        "import runpy, sys; m = runpy.run_path(sys.argv[1]); "
        "before = m['rayon_pool_threads'](); m['start_rayon_pool'](); "
        "print(before, m['rayon_pool_threads']())"
    )
    r = subprocess.run([sys.executable, "-c", code, str(SCRIPT)], capture_output=True, text=True,
                       env={**os.environ, "RAYON_NUM_THREADS": "3"}, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["0", "3"]


def test_a_failed_part_is_named_and_the_others_are_kept_on_a_running_scheduler(parts, tmp_path):
    folder, expected = parts
    batch = tmp_path / "parts"
    batch.mkdir()
    for name in ("core-1", "core-2"):
        (batch / name).symlink_to(folder / name)
    broken = batch / "core-broken"
    broken.mkdir()
    for f in ("scan.ply", "cad_points.ply"):
        (broken / f).symlink_to(folder / "core-1" / f)
    (broken / "path.csv").write_text("contour,x,y,z,u,v,w\n1,0,0,0,0,0,1\n1,1,0,zero,0,0,1\n")
    out = tmp_path / "plans"
    # A stale result of an earlier run must not survive the part's failure.
    (out / "core-broken").mkdir(parents=True)
    (out / "core-broken" / "plan.json").write_text("{}")

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        r = run_script(batch, "--out", out, "--scheduler", cluster.scheduler_address,
                       "--threads-per-worker", 1)
        assert r.returncode == 1, r.stdout + r.stderr
        assert "core-broken: FAILED: read: FileFormatError:" in r.stderr, r.stderr
        assert "path.csv: line 3" in r.stderr, r.stderr
        assert "batch: 2 of 3 parts planned, failed: core-broken" in r.stdout, r.stdout
        assert_same_results(out, ["core-1", "core-2"], expected)
        assert "read: FileFormatError" in (out / "core-broken" / "error.txt").read_text()
        assert not (out / "core-broken" / "plan.json").exists()
        summary = json.loads((out / "summary.json").read_text())
        assert summary["parts"]["core-broken"]["status"] == "failed"
        assert summary["scheduler"] == cluster.scheduler_address

        # The pools on these workers hold one thread now; rayon cannot change that in a running
        # process, so another cap is refused, naming the workers, before any part runs.
        again = run_script(batch, "--out", tmp_path / "again", "--scheduler",
                           cluster.scheduler_address, "--threads-per-worker", 2)
        assert again.returncode == 1, again.stdout + again.stderr
        assert "rayon pools already started with another size" in again.stderr, again.stderr
        assert all(w in again.stderr for w in cluster.scheduler_info["workers"]), again.stderr
        assert not (tmp_path / "again").exists()
