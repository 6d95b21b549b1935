"""trimctl.merge_scans: scans of one clamped part taken at several machine poses, carried into
the work-piece frame through [machine] and [calibration] and merged, as `trimctl register
--scan A --scan B --poses poses.csv` does; the merged cloud registers as the single one."""

import numpy as np
import pytest

import trimctl

# A calibrated A/C cell: the A line through rot_point + (0, y_offset, z_offset + tool_offset)
# along +X, C through rot_point along +Z (DESIGN.md "Frames"), the scanner turned and shifted
# on the head, the work piece off the table's origin.
MACHINE = {
    "kinematics": "xyzac-trt",
    "rot_point_mm": [1.5, -2.0, 3.0],
    "y_offset_mm": 20.0,
    "z_offset_mm": 10.0,
    "tool_offset_mm": 4.0,
    "workpiece_origin_mm": [2.0, -1.5, 4.0],
}


def _rx(deg):
    a = np.radians(deg)
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


def _rz(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


SCANNER_R = _rz(1.7) @ _rx(-0.9)
SCANNER_T = np.array([1.0, -2.0, 150.0])
SETTINGS = {
    "machine": MACHINE,
    "calibration": {
        "scanner_rotation": SCANNER_R.tolist(),
        "scanner_translation_mm": SCANNER_T.tolist(),
    },
}
POSES = [
    {"xyz_mm": [5.0, -3.0, 20.0], "tilt_deg": 0.0, "c_deg": 0.0},
    {"xyz_mm": np.array([-12.0, 8.0, 35.0]), "tilt_deg": -25.0, "c_deg": 140.0},
]


def seen_at(points, pose):
    """Where the scanner sees work-piece points with the machine at ``pose``, written out from
    the chain (independent of the Rust code): the table point p + origin is at
    Rot_A(A)·Rot_C(C)·(p + origin) in the machine frame, and there at (X, Y, Z) + R·s + t."""
    rot = np.array(MACHINE["rot_point_mm"])
    a_point = rot + [0.0, MACHINE["y_offset_mm"], MACHINE["z_offset_mm"] + MACHINE["tool_offset_mm"]]
    table = points + np.array(MACHINE["workpiece_origin_mm"])
    after_c = (table - rot) @ _rz(pose["c_deg"]).T + rot
    machine = (after_c - a_point) @ _rx(pose["tilt_deg"]).T + a_point
    return (machine - np.asarray(pose["xyz_mm"], dtype=float) - SCANNER_T) @ SCANNER_R


# The merged cloud differs from the single one by ~1e-13 mm, and registration turns that into
# a few µm (which point of a voxel the field takes changes; measured 3.2 µm on this case, as
# `register_poses.rs` allows 2 µm on the CLI's): the paths agree within this, µm.
SAME_PATH_UM = 5.0
# A contour whose bound sits at the trust threshold may flip with it (measured: 1 of 52).
FLIPPED_AT_MOST = 1
# One side alone leaves at least this many more contours untrusted (measured: 19 more).
MORE_FLAGGED_ONE_SIDE = 5


@pytest.fixture(scope="module")
def case():
    # The demo cell's three fixed views, enough points to register every side (4 of 52
    # contours flagged).
    return trimctl.synth(seed=5, scan_points=150_000, cad_points=60_000, scanner_views=3)


@pytest.fixture(scope="module")
def two_views(case):
    """The demo scan split by the side of the part it lies on (across its thinnest axis), each
    side as the scanner saw it at its pose."""
    scan = case.scan
    centred = scan - scan.mean(axis=0)
    thinnest = np.linalg.eigh(np.cov(centred.T))[1][:, 0]
    upper = centred @ thinnest >= 0.0
    sides = [scan[upper], scan[~upper]]
    return sides, [seen_at(side, pose) for side, pose in zip(sides, POSES)]


def test_two_views_merge_into_the_single_cloud_and_register_as_it(case, two_views):
    sides, views = two_views
    assert all(len(v) > 10_000 for v in views)
    merged = trimctl.merge_scans(views, POSES, settings=SETTINGS)
    whole = np.concatenate(sides)
    assert merged.shape == whole.shape and merged.dtype == np.float64
    assert np.abs(merged - whole).max() < 1e-9
    # [machine] and [calibration] apply: through the nominal cell the views land elsewhere.
    nominal = trimctl.merge_scans(views, POSES)
    assert np.abs(nominal - whole).max() > 1.0
    # settings itself is not changed.
    assert isinstance(POSES[1]["xyz_mm"], np.ndarray) and "calibration" in SETTINGS

    # register_path takes the merged cloud: the same registration as the single cloud.
    options = dict(
        cad_normals=case.cad_normals,
        init=case.scan_from_cad_nominal,
        settings={"cad_sample_points": 60_000},
    )
    a = trimctl.register_path(case.cad_points, whole, case.path, **options)
    b = trimctl.register_path(case.cad_points, merged, case.path, **options)
    assert a.refused is None and b.refused is None
    assert len(set(a.untrustworthy) ^ set(b.untrustworthy)) <= FLIPPED_AT_MOST
    np.testing.assert_array_equal(a.path.ids, b.path.ids)
    assert np.abs(a.path.points - b.path.points).max() * 1e3 < SAME_PATH_UM
    # One view alone leaves the other side's contours without data.
    one = trimctl.merge_scans(views[:1], POSES[:1], settings=SETTINGS)
    c = trimctl.register_path(case.cad_points, one, case.path, **options)
    assert len(c.untrustworthy) >= len(a.untrustworthy) + MORE_FLAGGED_ONE_SIDE


def test_a_bc_cell_carries_its_tilt_as_b():
    # On a B/C cell tilt_deg is B, about the B line (+Y through rot_point + (x_offset, 0, dz)).
    points = np.array([[1.0, 2.0, 3.0], [-4.0, 0.5, 2.0]])
    pose = {"xyz_mm": [0.0, 0.0, 0.0], "tilt_deg": 90.0, "c_deg": 0.0}
    settings = {"machine": {"kinematics": "xyzbc-trt", "x_offset_mm": 0.0, "z_offset_mm": 0.0,
                            "b_limits_deg": [-120.0, 120.0]}}
    # Rot_B(90°) about +Y through the origin takes (x, y, z) to (z, y, −x): the scanner sees
    # that, and the merge takes it back.
    seen = np.array([[3.0, 2.0, -1.0], [2.0, 0.5, 4.0]])
    merged = trimctl.merge_scans([seen], [pose], settings=settings)
    assert np.abs(merged - points).max() < 1e-12


def test_bad_input_raises_value_error_naming_it(two_views):
    _, views = two_views
    good = views[0][:100]
    nan = good.copy()
    nan[7, 1] = np.nan
    cases = [
        (([good, nan], POSES), r"scans\[1\]: row 7 column 1 is NaN"),
        (([good], POSES), r"scans, poses: 1 scans but 2 poses"),
        (([good, np.zeros((0, 3))], POSES), r"scans\[1\]: no points"),
        (([good, good[:, :2].copy()], POSES), r"scans\[1\]: expected shape \(N, 3\), got \(100, 2\)"),
        (([good, good.astype(np.float32)], POSES), r"scans\[1\]: expected a numpy float64 array"),
        (([good, good[:, 0].copy()], POSES), r"scans\[1\]: expected a numpy float64 array"),
        ((good, POSES), r"scans: expected a sequence of \(N, 3\) arrays, got one array"),
        (([], []), r"no scans to merge"),
        (([good], [POSES[0], POSES[1]]), r"1 scans but 2 poses"),
        (([good], [{"xyz_mm": [0.0, 0.0, 0.0], "c_deg": float("nan")}]), r"poses\[0\]\.c_deg: nan"),
        (([good], [{"xyz_mm": [0.0, np.inf, 0.0]}]), r"poses\[0\]\.xyz_mm: inf"),
        (([good], [{"a_deg": 10.0}]), r"poses\[0\]: .*unknown field `a_deg`"),
        (([good], [{"xyz_mm": [0.0, 0.0]}]), r"poses\[0\]: xyz_mm"),
        (([good], [[0.0, 0.0, 0.0, 0.0, 0.0]]), r"poses\[0\]: expected a mapping"),
        (([good], POSES[0]), r"poses: expected a sequence of poses"),
        (
            ([np.full((3, 3), 1.5e308)], [{"xyz_mm": [0.0, 0.0, 0.0], "c_deg": 45.0}]),
            r"scans\[0\] through \[calibration\] at its pose: transformed point 0 is not finite",
        ),
        (
            ([good], [{"xyz_mm": [250.0, 0.0, 0.0]}]),
            r"scans\[0\]: the pose joint X = 250\.000 mm outside \[-200\.0, 200\.0\]: outside the "
            r"\[machine\] limits",
        ),
    ]
    for (scans, poses), message in cases:
        with pytest.raises(ValueError, match=message):
            trimctl.merge_scans(scans, poses)
    with pytest.raises(ValueError, match="machine"):
        trimctl.merge_scans([good], [POSES[0]], settings={"machine": {"kinematics": "hexapod"}})
    with pytest.raises(TypeError):
        trimctl.merge_scans([good], [POSES[0]], {"machine": MACHINE})  # settings is keyword-only


def _write_poses(path, header, rows):
    lines = [header] + [
        "%s,%r,%r,%r,%r,%r" % (name, *pose["xyz_mm"], pose["tilt_deg"], pose["c_deg"])
        for name, pose in rows
    ]
    path.write_text("\n".join(lines) + "\n")


def test_scan_files_merge_at_their_poses_as_the_arrays_do(tmp_path, two_views):
    # The CLI's files (register --scan A --scan B --poses poses.csv) from Python: the same
    # cloud as merge_scans on the arrays with the poses read back from the file.
    _, views = two_views
    files = [tmp_path / "side0.ply", tmp_path / "side1.ply"]
    for f, v in zip(files, views):
        trimctl.write_points(str(f), v)
    poses_csv = tmp_path / "poses.csv"
    # Out of order, with a comment and a blank line: rows are matched by file name.
    poses = [{**p, "xyz_mm": [float(x) for x in p["xyz_mm"]]} for p in POSES]
    _write_poses(poses_csv, "# taken 2026-12-03\nscan,x,y,z,a,c\n", [("side1.ply", poses[1]), ("side0.ply", poses[0])])

    read = trimctl.read_poses(poses_csv)
    assert read.kinematics == "xyzac-trt" and read.path == str(poses_csv)
    assert [name for name, _ in read.rows] == ["side1.ply", "side0.ply"]
    assert read.pose_of(files[0]) == poses[0] and read.pose_of(str(files[1])) == poses[1]
    with pytest.raises(KeyError, match=r"no pose for scan other\.ply in .*poses\.csv"):
        read.pose_of(tmp_path / "other.ply")

    from_files = trimctl.merge_scan_files(files, poses_csv, settings=SETTINGS)
    from_arrays = trimctl.merge_scans(
        [trimctl.read_points(str(f))[0] for f in files],
        [read.pose_of(f) for f in files],
        settings=SETTINGS,
    )
    assert from_files.shape == (sum(len(v) for v in views), 3)
    # Both read the same files: the same cloud to the bit.
    np.testing.assert_array_equal(from_files, from_arrays)
    whole = np.concatenate(two_views[0])
    assert np.abs(from_files - whole).max() < 1e-6


def test_scan_files_with_bad_poses_raise_errors_naming_the_file(tmp_path, two_views):
    _, views = two_views
    scan = tmp_path / "side0.ply"
    trimctl.write_points(str(scan), views[0][:200])
    pose = {"xyz_mm": [0.0, 0.0, 0.0], "tilt_deg": 0.0, "c_deg": 0.0}
    good = tmp_path / "poses.csv"
    _write_poses(good, "scan,x,y,z,a,c", [("side0.ply", pose)])
    bc = tmp_path / "bc.csv"
    _write_poses(bc, "scan,x,y,z,b,c", [("side0.ply", pose)])
    assert trimctl.read_poses(bc).kinematics == "xyzbc-trt"
    bad_value = tmp_path / "bad_value.csv"
    bad_value.write_text("scan,x,y,z,a,c\nside0.ply,0,0,nan,0,0\n")
    short = tmp_path / "short.csv"
    short.write_text("scan,x,y,z,a,c\n\nside0.ply,0,0,0,0\n")
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    header = tmp_path / "header.csv"
    header.write_text("scan,x,y,z\n")
    twice = tmp_path / "twice.csv"
    twice.write_text("scan,x,y,z,a,c\nside0.ply,0,0,0,0,0\nside0.ply,0,0,0,0,90\n")
    for path, message in [
        (bad_value, r"bad_value\.csv:2: column 4 \(z\): \"nan\" is not a finite number"),
        (twice, r"twice\.csv:3: scan side0\.ply already has a pose on line 2"),
        (short, r"short\.csv:3: expected 6 columns, got 5"),
        (empty, r"empty\.csv: empty file"),
        (header, r"header\.csv:1: expected the header scan,x,y,z,a,c"),
        (tmp_path / "missing.csv", r"cannot read .*missing\.csv"),
    ]:
        with pytest.raises(trimctl.FileFormatError, match=message):
            trimctl.read_poses(path)
        with pytest.raises(trimctl.FileFormatError, match=message):
            trimctl.merge_scan_files([scan], path)
    # A B/C header on the default A/C cell, and the other way round.
    with pytest.raises(ValueError, match=r"bc\.csv: the header names a xyzbc-trt cell, the job's \[machine\] is xyzac-trt"):
        trimctl.merge_scan_files([scan], bc)
    with pytest.raises(ValueError, match=r"the header names a xyzac-trt cell"):
        trimctl.merge_scan_files([scan], good, settings={"machine": {"kinematics": "xyzbc-trt"}})
    # A scan without a row is refused before any file is read; an unreadable scan names itself.
    with pytest.raises(ValueError, match=r"other\.ply: no pose for scan other\.ply in .*poses\.csv"):
        trimctl.merge_scan_files([scan, tmp_path / "other.ply"], good)
    truncated = tmp_path / "cut.ply"
    truncated.write_bytes(scan.read_bytes()[:300])
    _write_poses(good, "scan,x,y,z,a,c", [("side0.ply", pose), ("cut.ply", pose)])
    with pytest.raises(trimctl.FileFormatError, match=r"reading .*cut\.ply"):
        trimctl.merge_scan_files([scan, truncated], good)
    with pytest.raises(ValueError, match=r"files: expected a sequence of scan files, got one path"):
        trimctl.merge_scan_files(scan, good)
    with pytest.raises(ValueError, match="no scans to merge"):
        trimctl.merge_scan_files([], good)
    # The same scan twice would be merged twice (and two folders' files of one name share a row).
    with pytest.raises(ValueError, match=r"share the file name side0\.ply, which names their row in .*poses\.csv"):
        trimctl.merge_scan_files([scan, scan], good)
