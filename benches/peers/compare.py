"""Peer comparison in one run (see ./run): ICP against Open3D and small_gicp, and the whole
`trimctl register` against the paper's method on Open3D (paper_open3d.py).

Part 1, point-to-plane ICP, same clouds for all three:
- lidar-pair: small_gicp's real 70k-point scan pair with ground truth (tests/data), metres,
  0.25 m voxels, correspondences within 1 m, from the identity;
- core 500k: a trimctl synthetic core with a 500 000-point scan, re-posed rigidly only (2°, 1 mm)
  so a rigid transform is the truth; scan → CAD points, mm, correspondences within 2 mm, from
  the nominal pose; once on 0.5 mm voxels and once at full resolution.
Fairness: each library gets the same down-sampled clouds (Open3D's voxel filter) and the same
target normals, computed once (Open3D, 10 nearest neighbours, oriented toward the sensor) and
passed to Open3D in the cloud and to trimctl in the PLY (icp_bench uses the file's normals and
estimates none). small_gicp 1.0.1's Python binding has no way to take normals (its
PointCloud(points) constructor only): it estimates its own from the same 10 neighbours by the same
PCA, and the table gives the largest angle between those and the shared ones. The stopping rule is
a fixed iteration count (--iterations, 30) with every convergence test disabled (Open3D's
relative fitness and RMSE thresholds 0, small_gicp's and trimctl's rotation and translation
epsilons 0; all three test with a strict `<`). One stop remains that Python cannot switch off:
small_gicp's `align` runs Levenberg-Marquardt, which ends the run when ten ever more damped steps
all fail to lower the error (at its numerical optimum). The table prints the iterations each ran
(Open3D's legacy result has no count: it is read from Open3D's debug log of one extra, untimed
run). Per iteration each does one correspondence search (Open3D and trimctl one more, for the
final fitness), a 6×6 Gauss-Newton solve (small_gicp: LM, its trial steps re-evaluate the error
on the same correspondences). Timed:
each library's one registration call, target kd-tree build included, normal estimation not, median
of --repeat runs. Open3D and small_gicp run in this process; trimctl's icp_bench times itself in
its process (file reading not timed).

Part 2, CLI level: a synthetic core with a 500 000-point scan, deformed (the criterion bench
`register/full/500k`'s case: seed 20261121, sag 0.5 mm, twist 1°, scale range 0.02, 5° / 3 mm
fixture error), at the size a CAM export and a fine CAD give: a path of 0.05 mm spacing (~18k
rows) and a CAD mesh of 0.35 mm steps (~122k triangles), written by `trimctl synth` as cad.stl,
binary scan.ply, path.csv, truth.csv.
`trimctl register --cad cad.stl --scan scan.ply --path path.csv --viewpoint ...` and
`python paper_open3d.py --cad cad.stl --scan scan.ply --path path.csv` each run as a whole
process (start, file reading and writing included), alternately, --cli-repeat times; medians.
Both results are scored against truth.csv: pointwise (each point against its own true position)
and cross-edge (distance to the true contour polyline), P95 (nearest rank) and max.

Threads: the process and its children are pinned to the first --threads CPUs and every library
is capped at --threads (OMP_NUM_THREADS, small_gicp's num_threads, RAYON_NUM_THREADS). The table
goes to stdout and, with everything else measured, to --json (default results/peers-<time>.json).
"""

import argparse
import hashlib
import importlib.metadata
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
DATA = ROOT / "tests" / "data"
# Built by ./run. Copied into the run's temporary folder first (Tools), so that someone else's
# build in the shared target folder cannot swap them mid-run.
ICP_BENCH = ROOT / "target" / "release" / "examples" / "icp_bench"
TRIMCTL = ROOT / "target" / "release" / "trimctl"
PAPER = HERE / "paper_open3d.py"
NORMAL_NEIGHBOURS = 10
# The criterion bench register/full/500k's synthetic case (benches/register.rs).
CORE_SEED = 20_261_121
CORE_SCAN_POINTS = 500_000
CORE_ARGS = ["--sag", "0.5", "--twist", "1", "--scale-range", "0.02",
             # ~18k path rows and ~122k CAD triangles, as the outside cases (issue 21).
             "--path-spacing", "0.05", "--mesh-step", "0.35"]
# The goal: trimctl register at least this many times faster than the paper on Open3D.
GOAL_SPEEDUP = 10.0


def errors(T, truth):
    d = np.linalg.inv(truth) @ T
    angle = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
    return float(angle), float(np.linalg.norm(d[:3, 3]))


def with_shared_normals(o3d, cloud, viewpoint):
    """A copy of the cloud's points with normals estimated once, for every library."""
    out = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(cloud.points)))
    out.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(NORMAL_NEIGHBOURS))
    out.orient_normals_towards_camera_location(viewpoint)
    return out


def capture_fd1(fn):
    """Runs fn() with file descriptor 1 (C++ std::cout) sent to a file; returns (value, text)."""
    sys.stdout.flush()
    saved = os.dup(1)
    with tempfile.TemporaryFile(mode="w+") as f:
        os.dup2(f.fileno(), 1)
        try:
            value = fn()
        finally:
            sys.stdout.flush()
            os.dup2(saved, 1)
            os.close(saved)
        f.seek(0)
        return value, f.read()


def run_open3d(o3d, src, tgt, max_dist, init, repeat, iterations):
    reg = o3d.pipelines.registration
    # Thresholds 0: Open3D stops when both changes are `<` them, which never happens.
    crit = reg.ICPConvergenceCriteria(relative_fitness=0.0, relative_rmse=0.0, max_iteration=iterations)
    call = lambda: reg.registration_icp(src, tgt, max_dist, init, reg.TransformationEstimationPointToPlane(), crit)  # noqa: E731
    times, result = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = call()
        times.append(time.perf_counter() - t0)
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Debug)
    try:
        _, log = capture_fd1(call)
    finally:
        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    ran = len(re.findall(r"ICP Iteration #\d+", log))
    return {"median_s": float(np.median(times)), "times_s": times, "iterations": ran,
            "T": np.asarray(result.transformation), "fitness": result.fitness}


def run_small_gicp(sg, src, tgt, max_dist, init, repeat, threads, iterations):
    s = sg.PointCloud(np.asarray(src.points))
    t = sg.PointCloud(np.asarray(tgt.points))
    # small_gicp 1.0.1 cannot be given normals: the same estimate (10 neighbours, PCA), then the
    # largest angle to the shared normals (sign-free: point-to-plane does not see the sign).
    sg.estimate_normals(t, num_neighbors=NORMAL_NEIGHBOURS, num_threads=threads)
    cos = np.abs(np.sum(t.normals()[:, :3] * np.asarray(tgt.normals), axis=1))
    angles = np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))
    times, result = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        tree = sg.KdTree(t, num_threads=threads)
        result = sg.align(t, s, tree, init_T_target_source=init, registration_type="PLANE_ICP",
                          max_correspondence_distance=max_dist, num_threads=threads,
                          max_iterations=iterations, rotation_epsilon=0.0, translation_epsilon=0.0)
        times.append(time.perf_counter() - t0)
    # `iterations` is the index of its last iteration (optimizer.hpp: `result.iterations = i`).
    return {"median_s": float(np.median(times)), "times_s": times, "iterations": int(result.iterations) + 1,
            "T": np.asarray(result.T_target_source), "num_inliers": int(result.num_inliers),
            "normal_angle_max_deg": float(angles.max()),
            "normal_angle_p99_deg": float(np.quantile(angles, 0.99))}


class Tools:
    """This run's copies of trimctl and icp_bench."""

    def __init__(self, folder):
        folder.mkdir()
        self.trimctl, self.icp_bench = folder / "trimctl", folder / "icp_bench"
        shutil.copy2(TRIMCTL, self.trimctl)
        shutil.copy2(ICP_BENCH, self.icp_bench)


def run_trimctl(tools, o3d, src, tgt, max_dist, init, repeat, threads, iterations, tmp):
    sp, tp = Path(tmp) / "source.ply", Path(tmp) / "target.ply"
    o3d.io.write_point_cloud(str(sp), src, write_ascii=False)
    o3d.io.write_point_cloud(str(tp), tgt, write_ascii=False)  # x y z nx ny nz as double
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    cmd = [str(tools.icp_bench), str(sp), str(tp), "--max-dist", str(max_dist), "--iterations", str(iterations),
           "--translation-eps", "0", "--rotation-eps-rad", "0",
           "--repeat", str(repeat), "--init", *[repr(float(v)) for v in init.reshape(-1)]]
    out = json.loads(subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout)
    return {"median_s": out["median_s"], "times_s": out["times_s"], "iterations": out["iterations"],
            "T": np.array(out["target_from_source"]), "fitness": out["fitness"]}


def synth(tools, out, seed, scan_points, extra):
    subprocess.run([str(tools.trimctl), "synth", "--out", str(out), "--seed", str(seed),
                    "--scan-points", str(scan_points), *extra], check=True, capture_output=True)
    return json.loads((out / "case.json").read_text())


def icp_level(tools, o3d, sg, a, tmp):
    lidar = DATA / "lidar-pair"
    cases = []
    src = o3d.io.read_point_cloud(str(lidar / "source.ply")).voxel_down_sample(0.25)
    tgt = o3d.io.read_point_cloud(str(lidar / "target.ply")).voxel_down_sample(0.25)
    cases.append(("lidar-pair", src, with_shared_normals(o3d, tgt, np.zeros(3)), 1.0,
                  np.eye(4), np.loadtxt(lidar / "T_target_source.txt"), "m"))
    core = Path(tmp) / "core-rigid"
    info = synth(tools, core, 5, CORE_SCAN_POINTS, ["--sag", "0", "--twist", "0", "--scale-range", "0",
                                             "--pose-deg", "2", "--pose-mm", "1"])
    truth = np.linalg.inv(np.array(info["scan_from_cad_true"]))  # cad_from_scan
    viewpoint = np.array(info["scanner_in_scan_mm"])
    # Target normals oriented toward the scanner (the nominal pose is the identity, so the scan
    # and CAD frames nearly agree); point-to-plane ICP does not see their sign anyway.
    scan = o3d.io.read_point_cloud(str(core / "scan.ply"))
    cad = o3d.io.read_point_cloud(str(core / "cad_points.ply"))
    for label, voxel in (("core 500k, 0.5 mm voxels", 0.5), ("core 500k, full", 0.0)):
        s = scan.voxel_down_sample(voxel) if voxel else scan
        t = cad.voxel_down_sample(voxel) if voxel else cad
        cases.append((label, s, with_shared_normals(o3d, t, viewpoint), 2.0, np.eye(4), truth, "mm"))
    rows = []
    for name, src, tgt, max_dist, init, truth, unit in cases:
        repeat = a.repeat if len(src.points) < 200_000 else max(3, a.repeat // 2)
        print(f"  ICP {name}: {len(src.points)} → {len(tgt.points)} points, {repeat} runs each", file=sys.stderr)
        res = {
            "Open3D": run_open3d(o3d, src, tgt, max_dist, init, repeat, a.iterations),
            "small_gicp": run_small_gicp(sg, src, tgt, max_dist, init, repeat, a.threads, a.iterations),
            "trimctl": run_trimctl(tools, o3d, src, tgt, max_dist, init, repeat, a.threads, a.iterations, tmp),
        }
        ours = res["trimctl"]["median_s"]
        for lib, r in res.items():
            ang, trans = errors(r["T"], truth)
            rows.append({
                "data": name, "source_points": len(src.points), "target_points": len(tgt.points),
                "library": lib, "median_ms": r["median_s"] * 1e3, "best_ms": min(r["times_s"]) * 1e3, "runs": repeat,
                "trimctl_over_library": ours / r["median_s"], "iterations": r["iterations"],
                "rotation_error_deg": ang, "translation_error": trans, "unit": unit,
                "times_s": r["times_s"],
                **{k: v for k, v in r.items() if k.startswith("normal_angle")},
            })
    return rows


def read_path(path):
    table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    ids = table[:, 0].astype(np.int64)
    out = {}
    for cid in dict.fromkeys(ids):
        out[int(cid)] = table[ids == cid, 1:4]
    return out


def path_errors(registered, truth):
    """Pointwise and cross-edge errors (mm) as trim_register::eval::path_errors."""
    reg, tru = read_path(registered), read_path(truth)
    if reg.keys() != tru.keys():
        raise ValueError(f"{registered}: contours differ from the truth's")
    pointwise, cross = [], []
    for cid, p in reg.items():
        q = tru[cid]
        if len(p) != len(q):
            raise ValueError(f"{registered}: contour {cid} has {len(p)} points, truth {len(q)}")
        pointwise.append(np.linalg.norm(p - q, axis=1))
        a, b = (q[:-1], q[1:]) if len(q) > 1 else (q, q)
        ab = b - a
        len_sq = np.maximum(np.sum(ab * ab, axis=1), 1e-300)
        t = np.clip(np.einsum("nsk,sk->ns", p[:, None, :] - a[None], ab) / len_sq, 0.0, 1.0)
        d = np.linalg.norm(p[:, None, :] - (a[None] + t[..., None] * ab[None]), axis=2)
        cross.append(d.min(axis=1))
    pointwise, cross = np.concatenate(pointwise), np.concatenate(cross)

    def p95(v):
        return float(np.sort(v)[max(1, int(np.ceil(0.95 * len(v)))) - 1])

    return {"pointwise_p95_um": p95(pointwise) * 1e3, "pointwise_max_um": float(pointwise.max()) * 1e3,
            "cross_edge_p95_um": p95(cross) * 1e3, "cross_edge_max_um": float(cross.max()) * 1e3,
            "points": int(len(pointwise))}


def cli_level(tools, a, tmp):
    core = Path(tmp) / "core-deformed"
    info = synth(tools, core, CORE_SEED, CORE_SCAN_POINTS, CORE_ARGS)
    viewpoint = ",".join(repr(float(v)) for v in info["scanner_in_scan_mm"])
    files = ["--cad", str(core / "cad.stl"), "--scan", str(core / "scan.ply"), "--path", str(core / "path.csv")]
    env = dict(os.environ, RAYON_NUM_THREADS=str(a.threads), OMP_NUM_THREADS=str(a.threads))
    commands = {
        "trimctl register": [str(tools.trimctl), "register", *files, "--viewpoint", viewpoint,
                             "--out", str(core / "trimctl.csv"), "--report", str(core / "registration.json")],
        "paper on Open3D": [sys.executable, str(PAPER), *files, "--out", str(core / "paper.csv"),
                            "--timings", str(core / "paper_timings.json")],
    }
    outputs = {"trimctl register": core / "trimctl.csv", "paper on Open3D": core / "paper.csv"}
    times = {k: [] for k in commands}
    digests = {k: set() for k in commands}
    stderr = {}
    paper_in_process = []
    for i in range(a.cli_repeat):
        order = list(commands) if i % 2 == 0 else list(commands)[::-1]
        for name in order:
            t0 = time.perf_counter()
            done = subprocess.run(commands[name], env=env, capture_output=True, text=True)
            times[name].append(time.perf_counter() - t0)
            if done.returncode != 0:
                raise RuntimeError(f"{name} failed ({done.returncode}):\n{done.stderr}")
            stderr[name] = done.stderr
            digests[name].add(hashlib.sha256(outputs[name].read_bytes()).hexdigest())
            if name == "paper on Open3D":
                paper_in_process.append(json.loads((core / "paper_timings.json").read_text()))
        print(f"  CLI run {i + 1}/{a.cli_repeat}: " + ", ".join(f"{k} {v[-1]:.2f} s" for k, v in times.items()),
              file=sys.stderr)
    rows = {}
    for name in commands:
        rows[name] = {
            "median_s": float(np.median(times[name])), "times_s": times[name],
            "identical_outputs": len(digests[name]) == 1,
            **path_errors(outputs[name], core / "truth.csv"),
            "stderr_last_run": stderr[name],
        }
    import_s = [p["timings_s"]["start + import"] for p in paper_in_process]
    rows["paper on Open3D"]["start_import_median_s"] = float(np.median(import_s))
    rows["paper on Open3D"]["stage_timings_s"] = {
        k: float(np.median([p["timings_s"][k] for p in paper_in_process])) for k in paper_in_process[0]["timings_s"]}
    rows["paper on Open3D"]["contours_kept_coarse"] = paper_in_process[-1]["contours_kept_coarse"]
    ours, theirs = rows["trimctl register"]["median_s"], rows["paper on Open3D"]["median_s"]
    report = json.loads((core / "registration.json").read_text())
    summary = {
        "case": {"seed": CORE_SEED, "scan_points": CORE_SCAN_POINTS, "synth_args": CORE_ARGS,
                 "contours": len(read_path(core / "path.csv")),
                 "path_rows": sum(len(c) for c in read_path(core / "path.csv").values()),
                 # Binary STL: an 84-byte header, then 50 bytes per triangle.
                 "cad_triangles": ((core / "cad.stl").stat().st_size - 84) // 50,
                 "trimctl_flagged_contours": sum(1 for c in report.get("contours", []) if not c.get("trustworthy", True))},
        "runs": a.cli_repeat,
        "speedup": theirs / ours,
        "speedup_without_python_start_import": (theirs - rows["paper on Open3D"]["start_import_median_s"]) / ours,
        "goal": GOAL_SPEEDUP,
        "rows": rows,
    }
    return summary


def versions(tools):
    def run(cmd):
        try:
            return subprocess.run(cmd, capture_output=True, text=True, check=True, cwd=ROOT).stdout.strip()
        except (OSError, subprocess.CalledProcessError) as e:
            return f"unknown ({e})"

    import open3d
    return {
        "Open3D": open3d.__version__,
        "small_gicp": importlib.metadata.version("small_gicp"),
        "numpy": np.__version__,
        "python": sys.version.split()[0],
        "trimctl": run([str(tools.trimctl), "--version"]),
        "trimctl git": run(["git", "describe", "--always", "--dirty", "--abbrev=10"]),
    }


def print_tables(result):
    v, a = result["versions"], result["settings"]
    print(f"versions: Open3D {v['Open3D']}, small_gicp {v['small_gicp']}, {v['trimctl']} ({v['trimctl git']}), "
          f"numpy {v['numpy']}, Python {v['python']}")
    print(f"threads: {a['threads']} per library, pinned to CPUs {a['cpus']}; load average "
          f"{result['load_before']} before, {result['load_after']} after")
    if result.get("icp"):
        print()
        print(f"point-to-plane ICP, at most {a['iterations']} iterations (convergence tests off), shared target "
              f"normals, kd-tree build + ICP; trimctl / library: ratio of medians, below 1 trimctl is faster")
        print("| data | source → target pts | library | iterations | runs | median ms | best ms | trimctl / library "
              "| rotation error deg | translation error |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for r in result["icp"]:
            lib = r["library"]
            if "normal_angle_max_deg" in r:
                lib += f" (own normals, ≤ {r['normal_angle_max_deg']:.2g}° off)"
            print(f"| {r['data']} | {r['source_points']} → {r['target_points']} | {lib} | {r['iterations']} | "
                  f"{r['runs']} | {r['median_ms']:.2f} | {r['best_ms']:.2f} | {r['trimctl_over_library']:.2f} | "
                  f"{r['rotation_error_deg']:.4f} | {r['translation_error']:.4f} {r['unit']} |")
    cli = result.get("cli")
    if cli:
        print()
        c = cli["case"]
        print(f"CLI level, whole process (start, read, register, write), {cli['runs']} runs each, alternating; "
              f"synthetic core seed {c['seed']}, {c['scan_points']} scan points, {c['contours']} contours, "
              f"{c['path_rows']} path rows, {c['cad_triangles']} CAD triangles; "
              f"errors against truth.csv")
        print("| command | median s | runs s | pointwise P95 / max µm | cross-edge P95 / max µm | same output each run |")
        print("|---|---|---|---|---|---|")
        for name, r in cli["rows"].items():
            runs = ", ".join(f"{t:.2f}" for t in r["times_s"])
            print(f"| {name} | {r['median_s']:.3f} | {runs} | {r['pointwise_p95_um']:.1f} / {r['pointwise_max_um']:.1f} | "
                  f"{r['cross_edge_p95_um']:.1f} / {r['cross_edge_max_um']:.1f} | {'yes' if r['identical_outputs'] else 'no'} |")
        p = cli["rows"]["paper on Open3D"]
        stages = ", ".join(f"{k} {s:.2f}" for k, s in p["stage_timings_s"].items())
        print(f"paper on Open3D in process (median s): {stages}")
        verdict = "meets" if cli["speedup"] >= cli["goal"] else "misses"
        print(f"trimctl register is {cli['speedup']:.1f}× faster than the paper's method on Open3D "
              f"({cli['speedup_without_python_start_import']:.1f}× without Python's start and import); "
              f"{verdict} the {cli['goal']:.0f}× goal")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=10, help="ICP runs per library (half, at least 3, at ≥ 200k points)")
    ap.add_argument("--iterations", type=int, default=30, help="fixed ICP iteration count")
    ap.add_argument("--cli-repeat", type=int, default=5, help="whole-process runs of each CLI")
    ap.add_argument("--skip-icp", action="store_true")
    ap.add_argument("--skip-cli", action="store_true")
    ap.add_argument("--json", type=Path, help="default: benches/peers/results/peers-<time>.json")
    a = ap.parse_args()
    cpus = sorted(os.sched_getaffinity(0))[: a.threads]
    os.sched_setaffinity(0, cpus)  # children inherit it
    os.environ["OMP_NUM_THREADS"] = str(a.threads)
    os.environ["RAYON_NUM_THREADS"] = str(a.threads)
    import open3d as o3d
    import small_gicp as sg
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)

    result = {"settings": {**vars(a), "json": str(a.json), "cpus": cpus},
              "load_before": [round(x, 2) for x in os.getloadavg()], "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    with tempfile.TemporaryDirectory() as tmp:
        tools = Tools(Path(tmp) / "bin")
        result["versions"] = versions(tools)
        if not a.skip_icp:
            result["icp"] = icp_level(tools, o3d, sg, a, tmp)
        if not a.skip_cli:
            result["cli"] = cli_level(tools, a, tmp)
    result["load_after"] = [round(x, 2) for x in os.getloadavg()]
    print_tables(result)
    out = a.json or HERE / "results" / f"peers-{time.strftime('%Y%m%d-%H%M%S')}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1, default=lambda x: x.tolist() if hasattr(x, "tolist") else str(x)))
    print(f"\nwritten: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
