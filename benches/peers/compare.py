"""Point-to-plane ICP: Open3D vs small_gicp vs trimctl on the same clouds (see ./run).

Data:
- lidar-pair: small_gicp's real 70k-point scan pair with ground truth (tests/data), metres,
  0.25 m voxels, normals from 10 neighbours, correspondences within 1 m, from the identity.
- synthetic: a trimctl synthetic core (rigid re-pose only: 2 deg, 1 mm), its scan onto its CAD
  points, mm, 0.5 mm voxels, correspondences within 2 mm, from the nominal pose.

Each library gets the same down-sampled clouds (Open3D's voxel filter) and the same target
normals (Open3D's estimate, oriented toward the sensor), runs point-to-plane ICP for at most 30
iterations with the same thread count, and is timed over --repeat runs of its one registration
call (target kd-tree build + iterations). Errors are against the ground truth.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"
ICP_BENCH = ROOT / "target" / "release" / "examples" / "icp_bench"
TRIMCTL = ROOT / "target" / "release" / "trimctl"
MAX_ITERATIONS = 30


def errors(T, truth):
    d = np.linalg.inv(truth) @ T
    angle = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
    return angle, float(np.linalg.norm(d[:3, 3]))


def prepare(o3d, src_path, tgt_path, voxel, viewpoint):
    src = o3d.io.read_point_cloud(str(src_path)).voxel_down_sample(voxel)
    tgt = o3d.io.read_point_cloud(str(tgt_path)).voxel_down_sample(voxel)
    for pc in (src, tgt):
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(10))
        pc.orient_normals_towards_camera_location(viewpoint)
    return src, tgt


def run_open3d(o3d, src, tgt, max_dist, init, repeat):
    reg = o3d.pipelines.registration
    crit = reg.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=MAX_ITERATIONS)
    times, result = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = reg.registration_icp(src, tgt, max_dist, init, reg.TransformationEstimationPointToPlane(), crit)
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), np.asarray(result.transformation)


def run_small_gicp(sg, src, tgt, max_dist, init, repeat, threads):
    s = sg.PointCloud(np.asarray(src.points))
    t = sg.PointCloud(np.asarray(tgt.points))
    sg.estimate_normals(t, num_neighbors=10, num_threads=threads)
    times, result = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        tree = sg.KdTree(t, num_threads=threads)
        result = sg.align(t, s, tree, init_T_target_source=init, registration_type="PLANE_ICP",
                          max_correspondence_distance=max_dist, num_threads=threads,
                          max_iterations=MAX_ITERATIONS)
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), np.asarray(result.T_target_source)


def run_trimctl(o3d, src, tgt, max_dist, init, repeat, threads, tmp):
    sp, tp = Path(tmp) / "source.ply", Path(tmp) / "target.ply"
    o3d.io.write_point_cloud(str(sp), src, write_ascii=False)
    o3d.io.write_point_cloud(str(tp), tgt, write_ascii=False)
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    cmd = [str(ICP_BENCH), str(sp), str(tp), "--max-dist", str(max_dist), "--iterations", str(MAX_ITERATIONS),
           "--repeat", str(repeat), "--init", *[repr(float(v)) for v in init.reshape(-1)]]
    out = json.loads(subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout)
    return out["median_s"], np.array(out["target_from_source"])


def synthetic_case(tmp):
    out = Path(tmp) / "synth"
    subprocess.run([str(TRIMCTL), "synth", "--out", str(out), "--seed", "5", "--sag", "0", "--twist", "0",
                    "--scale-range", "0", "--pose-deg", "2", "--pose-mm", "1"], check=True, capture_output=True)
    info = json.loads((out / "case.json").read_text())
    scan_from_cad = np.array(info["scan_from_cad_true"])
    return out / "scan.ply", out / "cad_points.ply", np.linalg.inv(scan_from_cad), np.array(info["scanner_in_scan_mm"])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=10)
    a = ap.parse_args()
    os.environ["OMP_NUM_THREADS"] = str(a.threads)
    import open3d as o3d
    import small_gicp as sg
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        lidar = DATA / "lidar-pair"
        truth = np.loadtxt(lidar / "T_target_source.txt")
        src, tgt = prepare(o3d, lidar / "source.ply", lidar / "target.ply", 0.25, np.zeros(3))
        cases = [("lidar-pair", src, tgt, 1.0, np.eye(4), truth, "m")]
        s_path, t_path, synth_truth, viewpoint = synthetic_case(tmp)
        s_src = o3d.io.read_point_cloud(str(s_path)).voxel_down_sample(0.5)
        s_tgt = o3d.io.read_point_cloud(str(t_path)).voxel_down_sample(0.5)  # CAD normals kept
        cases.append(("synthetic core", s_src, s_tgt, 2.0, np.eye(4), synth_truth, "mm"))
        for name, src, tgt, max_dist, init, truth, unit in cases:
            res = {
                "Open3D": run_open3d(o3d, src, tgt, max_dist, init, a.repeat),
                "small_gicp": run_small_gicp(sg, src, tgt, max_dist, init, a.repeat, a.threads),
                "trimctl": run_trimctl(o3d, src, tgt, max_dist, init, a.repeat, a.threads, tmp),
            }
            ours = res["trimctl"][0]
            for lib, (median, T) in res.items():
                ang, trans = errors(T, truth)
                rows.append((name, len(src.points), lib, median * 1e3, ours / median, ang, trans, unit))
    print(f"point-to-plane ICP, {a.threads} threads, median of {a.repeat} runs (kd-tree build + ICP)")
    print("| data | source pts | library | median ms | trimctl / library | rotation error deg | translation error |")
    print("|---|---|---|---|---|---|---|")
    for name, n, lib, ms, ratio, ang, trans, unit in rows:
        print(f"| {name} | {n} | {lib} | {ms:.2f} | {ratio:.2f} | {ang:.4f} | {trans:.4f} {unit} |")


if __name__ == "__main__":
    sys.exit(main())
