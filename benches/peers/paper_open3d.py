"""The paper's registration on Open3D, as one process: the baseline `trimctl register` is timed
against in benches/peers/compare.py.

    paper_open3d.py --cad cad.stl --scan scan.ply --path path.csv --out registered.csv
                    [--initial scan_from_cad.txt] [--timings timings.json]

The method (papers/zone-layered-trimming-ceramic-core.txt §4, Fig. 19): "taking the points of
the CAD model as the source point cloud and the measured point cloud ... as the target point
cloud, the coarse registration is carried out based on the ICP registration algorithm"; the
template trajectory is moved by that transform; "taking the template trajectory points as the
reference points, the point cloud data is clipped within a specific range of the reference
points" in both clouds; each pair of sub-clouds is registered by "the scale ICP registration
algorithm, that is, the point cloud registration algorithm with scale scaling", and the result
moves that part of the trajectory. Open3D's ICP finds correspondences with its kd-tree
(KDTreeFlann); the clipping asks Open3D's other kd-tree (nanoflann), all of a contour's
segments in one call.

The paper gives no numbers (clip range, correspondence distance, iterations, sampling). This
script takes trimctl's own re-implementation of the paper, `trim_register::paper`
(`PaperSettings::default()`), number for number, so the Python and Rust baselines are one method:
- CAD: the STL sampled uniformly by area to 300 000 points (trimctl register's
  `cad_sample_points`), seed 1;
- coarse: rigid point-to-point ICP, CAD → scan, from the fixture's nominal pose (`--initial`,
  default identity), over a voxel pyramid of both clouds (2 / 1 / 0.5 mm voxels, correspondences
  within 12 / 4 / 1.5 mm, at most 30 iterations each; Open3D's default relative-change stop).
  The pyramid is not in the paper; it is what lets a rigid ICP reach a 5°, 3 mm fixture error,
  and it makes the baseline faster than one full-resolution ICP would be;
- regions: per contour (the CAM path's unit), the CAD points and the scan points within 3 mm of
  the coarsely moved contour polyline (capsules around its segments);
- local: scaled point-to-point ICP (Umeyama with scale) of the CAD clip onto the scan clip,
  correspondences within 1 mm, at most 50 iterations; the contour's points move by the result,
  its feature vectors by its rotation. A contour whose clip is empty keeps its coarse position
  (the paper has no failure handling; neither has `trim_register::paper`).

Threads: Open3D's OpenMP (OMP_NUM_THREADS); contours one after another.
"""

import time

T_START = time.perf_counter()

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import open3d as o3d  # noqa: E402

T_IMPORTED = time.perf_counter()

# trim_register::paper::PaperSettings::default() and trimctl register's CAD sampling.
CAD_SAMPLE_POINTS = 300_000
CAD_SAMPLE_SEED = 1
COARSE_LEVELS = [  # (voxel mm, max correspondence distance mm, max iterations)
    (2.0, 12.0, 30),
    (1.0, 4.0, 30),
    (0.5, 1.5, 30),
]
CLIP_RADIUS_MM = 3.0
LOCAL_MAX_DISTANCE_MM = 1.0
LOCAL_ITERATIONS = 50
PATH_HEADER = "contour,x,y,z,u,v,w"


def read_path(path):
    """The path CSV as [(contour id, points (n, 3), feature vectors (n, 3))], in file order."""
    with open(path) as f:
        header = f.readline().strip()
        if header != PATH_HEADER:
            raise ValueError(f"{path}: header {header!r}, expected {PATH_HEADER!r}")
        table = np.loadtxt(f, delimiter=",", ndmin=2)
    ids = table[:, 0].astype(np.int64)
    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    ends = np.r_[starts[1:], len(ids)]
    return [(int(ids[s]), table[s:e, 1:4], table[s:e, 4:7]) for s, e in zip(starts, ends)]


def write_path(path, contours):
    rows = [
        np.column_stack([np.full(len(p), cid, dtype=np.float64), p, f]) for cid, p, f in contours
    ]
    table = np.vstack(rows)
    with open(path, "w") as out:
        out.write(PATH_HEADER + "\n")
        for cid, *values in table.tolist():  # Python floats: repr is the shortest round trip
            out.write(f"{int(cid)}," + ",".join(map(repr, values)) + "\n")


def apply(T, points):
    return points @ T[:3, :3].T + T[:3, 3]


def rotate(T, vectors):
    """Feature vectors under a similarity: its rotation only (unit vectors stay unit)."""
    R = T[:3, :3] / np.cbrt(np.linalg.det(T[:3, :3]))
    return vectors @ R.T


class Clipper:
    """The points of a cloud within CLIP_RADIUS_MM of a polyline: Open3D's kd-tree
    (nanoflann, `multi_radius_search`) asked, for all of a contour's segments in one call, for
    the ball around each segment's midpoint that holds the segment's capsule. A point within the
    clip radius of the midpoint is in; only those in the shell beyond it get the exact capsule
    test (the same set as testing every pair, at a tenth of the work)."""

    def __init__(self, points):
        self.points = points
        self.nns = o3d.core.nns.NearestNeighborSearch(o3d.core.Tensor(points))
        self.nns.multi_radius_index()

    def near(self, polyline):
        a, b = (polyline[:-1], polyline[1:]) if len(polyline) > 1 else (polyline, polyline)
        ab = b - a
        half = 0.5 * np.linalg.norm(ab, axis=1)
        # Returns (indices, squared distances, splits), whatever its docstring's first line says.
        idx, d2, splits = self.nns.multi_radius_search(
            o3d.core.Tensor(0.5 * (a + b)), o3d.core.Tensor(CLIP_RADIUS_MM + half))
        idx, d2, splits = idx.numpy(), d2.numpy(), splits.numpy()
        if len(splits) != len(a) + 1:
            raise RuntimeError(f"multi_radius_search: {len(splits)} splits for {len(a)} queries")
        keep = np.zeros(len(self.points), dtype=bool)
        ball = d2 <= CLIP_RADIUS_MM**2
        keep[idx[ball]] = True
        shell = np.flatnonzero(~ball)
        seg = np.searchsorted(splits, shell, side="right") - 1
        p, sa, sab = self.points[idx[shell]], a[seg], ab[seg]
        len_sq = np.einsum("ij,ij->i", sab, sab)
        t = np.einsum("ij,ij->i", p - sa, sab) / np.maximum(len_sq, 1e-300)
        off = p - (sa + np.clip(t, 0.0, 1.0)[:, None] * sab)
        keep[idx[shell][np.einsum("ij,ij->i", off, off) <= CLIP_RADIUS_MM**2]] = True
        return np.flatnonzero(keep)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cad", required=True, help="CAD mesh (STL), CAD frame, mm")
    ap.add_argument("--scan", required=True, help="scan (PLY), scan frame, mm")
    ap.add_argument("--path", required=True, help="template path CSV, CAD frame")
    ap.add_argument("--out", required=True, help="registered path CSV, scan frame")
    ap.add_argument("--initial", help="nominal scan_from_cad: 16 numbers, row-major (default identity)")
    ap.add_argument("--timings", help="write stage timings (s) as JSON here")
    a = ap.parse_args()
    reg = o3d.pipelines.registration
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    timings = {"start + import": T_IMPORTED - T_START}

    t = time.perf_counter()
    mesh = o3d.io.read_triangle_mesh(a.cad)
    if len(mesh.triangles) == 0:
        sys.exit(f"{a.cad}: no triangles")
    o3d.utility.random.seed(CAD_SAMPLE_SEED)
    cad = mesh.sample_points_uniformly(number_of_points=CAD_SAMPLE_POINTS)
    scan = o3d.io.read_point_cloud(a.scan)
    if len(scan.points) == 0:
        sys.exit(f"{a.scan}: no points")
    contours = read_path(a.path)
    initial = np.eye(4) if a.initial is None else np.loadtxt(a.initial).reshape(4, 4)
    timings["read + sample CAD"] = time.perf_counter() - t

    # Coarse: rigid point-to-point ICP of the CAD points onto the scan.
    t = time.perf_counter()
    scan_from_cad = initial
    for voxel, max_dist, iterations in COARSE_LEVELS:
        src = cad.voxel_down_sample(voxel)
        tgt = scan.voxel_down_sample(voxel)
        result = reg.registration_icp(
            src, tgt, max_dist, scan_from_cad,
            reg.TransformationEstimationPointToPoint(with_scaling=False),
            reg.ICPConvergenceCriteria(max_iteration=iterations),
        )
        scan_from_cad = np.asarray(result.transformation)
    timings["coarse ICP"] = time.perf_counter() - t

    # Regions: per contour, both clouds clipped around the coarsely moved contour.
    t = time.perf_counter()
    cad_moved = o3d.geometry.PointCloud(cad).transform(scan_from_cad)
    cad_pts, scan_pts = np.asarray(cad_moved.points), np.asarray(scan.points)
    cad_clip, scan_clip = Clipper(cad_pts), Clipper(scan_pts)
    local_estimation = reg.TransformationEstimationPointToPoint(with_scaling=True)
    local_criteria = reg.ICPConvergenceCriteria(max_iteration=LOCAL_ITERATIONS)
    registered, kept_coarse = [], 0
    for cid, points, features in contours:
        moved, moved_f = apply(scan_from_cad, points), rotate(scan_from_cad, features)
        ci, si = cad_clip.near(moved), scan_clip.near(moved)
        if len(ci) == 0 or len(si) == 0:
            registered.append((cid, moved, moved_f))
            kept_coarse += 1
            continue
        fit = reg.registration_icp(
            cad_moved.select_by_index(ci), scan.select_by_index(si), LOCAL_MAX_DISTANCE_MM,
            np.eye(4), local_estimation, local_criteria,
        )
        T = np.asarray(fit.transformation)
        registered.append((cid, apply(T, moved), rotate(T, moved_f)))
    timings["regional scaled ICP"] = time.perf_counter() - t

    t = time.perf_counter()
    write_path(a.out, registered)
    timings["write path"] = time.perf_counter() - t
    timings["total in process"] = time.perf_counter() - T_START
    if a.timings:
        Path(a.timings).write_text(json.dumps({
            "timings_s": timings,
            "contours": len(contours),
            "contours_kept_coarse": kept_coarse,
            "cad_points": len(cad.points),
            "scan_points": len(scan.points),
            "scan_from_cad_coarse": scan_from_cad.tolist(),
            "open3d": o3d.__version__,
        }, indent=1))
    for name, s in timings.items():
        print(f"  {name:<24} {s:8.3f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
