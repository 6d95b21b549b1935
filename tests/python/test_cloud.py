"""Point-cloud processing and argument checks at the Python boundary."""

import warnings

import numpy as np
import pytest

import trimctl


def test_normals_of_a_plane_point_toward_the_viewpoint(plane_points):
    normals = trimctl.estimate_normals(plane_points, k=8, viewpoint=(0.0, 0.0, 100.0))
    expected = np.array([-0.2, 0.0, 1.0]) / np.linalg.norm([-0.2, 0.0, 1.0])
    assert normals.shape == plane_points.shape
    assert normals.dtype == np.float64
    np.testing.assert_allclose(normals, np.tile(expected, (len(normals), 1)), atol=1e-9)
    down = trimctl.estimate_normals(plane_points, k=8, reference=(0.0, 0.0, -1.0))
    np.testing.assert_allclose(down[0], -expected, atol=1e-9)


def test_voxel_downsample_keeps_one_centroid_per_voxel():
    pts = np.array([[0.1, 0.1, 0.1], [0.3, 0.3, 0.3], [1.5, 0.1, 0.1]])
    down, normals = trimctl.voxel_downsample(pts, voxel_mm=1.0)
    assert normals is None
    assert down.shape == (2, 3)
    np.testing.assert_allclose(down[0], [0.2, 0.2, 0.2], atol=1e-12)


@pytest.mark.parametrize(
    "bad, fragment",
    [
        (np.zeros((5, 2)), "shape (N, 3)"),
        (np.zeros((5, 3), dtype=np.float32), "float64"),
        ([[0.0, 0.0, 0.0]], "numpy.asarray"),
        (np.array([[0.0, np.nan, 0.0]] * 5), "finite"),
        (np.array([[0.0, np.inf, 0.0]] * 5), "finite"),
    ],
)
def test_bad_arrays_raise_value_error_naming_the_argument(bad, fragment):
    with pytest.raises(ValueError, match="points") as e:
        trimctl.estimate_normals(bad, k=8)
    assert fragment in str(e.value)


def test_out_of_range_options_raise_value_error(plane_points):
    with pytest.raises(ValueError, match="k"):
        trimctl.estimate_normals(plane_points, k=2)
    with pytest.raises(ValueError, match="voxel"):
        trimctl.voxel_downsample(plane_points, voxel_mm=0.0)
    with pytest.raises(ValueError, match="either viewpoint or reference"):
        trimctl.estimate_normals(plane_points, viewpoint=(0, 0, 1), reference=(0, 0, 1))


def test_options_are_keyword_only(plane_points):
    with pytest.raises(TypeError):
        trimctl.estimate_normals(plane_points, 8)


def test_error_hierarchy():
    for cls in (trimctl.FileFormatError, trimctl.RegistrationError, trimctl.PlanningError,
                trimctl.InternalError):
        assert issubclass(cls, trimctl.TrimError)


def test_points_round_trip_through_ply(tmp_path, plane_points):
    normals = trimctl.estimate_normals(plane_points, k=8)
    f = tmp_path / "cloud.ply"
    trimctl.write_points(f, plane_points, normals=normals)
    pts, ns = trimctl.read_points(f)
    np.testing.assert_array_equal(pts, plane_points)
    np.testing.assert_allclose(ns, normals, atol=1e-15)


@pytest.mark.parametrize("ext", ["ply", "pcd", "xyz", "txt"])
def test_write_points_writes_the_format_its_extension_names(tmp_path, plane_points, ext):
    normals = trimctl.estimate_normals(plane_points, k=8)
    f = tmp_path / f"cloud.{ext}"
    trimctl.write_points(f, plane_points, normals=normals)
    head = f.read_bytes()[:8]
    expected = {"ply": b"ply\n", "pcd": b"# .PCD"}.get(ext)
    if expected is None:
        assert len(f.read_text().splitlines()[0].split()) == 6
    else:
        assert head.startswith(expected), head
    pts, ns = trimctl.read_points(f)
    np.testing.assert_array_equal(pts, plane_points)
    np.testing.assert_allclose(ns, normals, atol=1e-15)  # renormalised when read


def test_write_points_refuses_what_read_points_could_not_read_back(tmp_path, plane_points):
    for name, says in [("c.stl", "holds a mesh"), ("c.csv", "holds a trimming path"),
                       ("c.obj", "unknown extension .obj")]:
        with pytest.raises(trimctl.FileFormatError, match=says):
            trimctl.write_points(tmp_path / name, plane_points)
        assert not (tmp_path / name).exists()
    with pytest.raises(ValueError, match="no points to write"):
        trimctl.write_points(tmp_path / "empty.ply", np.zeros((0, 3)))
    assert not (tmp_path / "empty.ply").exists()


def test_read_points_of_real_scans():
    from conftest import TEST_DATA

    pts, normals = trimctl.read_points(TEST_DATA / "bunny" / "bun0.pcd")
    assert pts.shape == (397, 3) and normals is not None
    pts, normals = trimctl.read_points(TEST_DATA / "lidar-pair" / "source.ply")
    assert pts.shape == (69792, 3) and normals is None


def test_path_round_trip_and_accessors(tmp_path):
    ids = np.array([3, 3, 3, 7, 7])
    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [5, 5, 5], [6, 5, 5]], dtype=np.float64)
    feats = np.tile([0.0, 0.0, 2.0], (5, 1))
    path = trimctl.Path(ids, pts, feats)
    assert len(path) == 2 and path.num_points == 5 and path.contour_ids == [3, 7]
    np.testing.assert_array_equal(path.features, np.tile([0.0, 0.0, 1.0], (5, 1)))
    f = tmp_path / "path.csv"
    trimctl.write_path(f, path)
    back = trimctl.read_path(f)
    np.testing.assert_array_equal(back.ids, ids)
    np.testing.assert_array_equal(back.points, pts)
    c_pts, c_feats = back.contour(7)
    np.testing.assert_array_equal(c_pts, pts[3:])


def test_bad_paths_and_files_name_the_fault(tmp_path):
    with pytest.raises(ValueError, match="contour 9"):
        trimctl.Path([9], np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))
    with pytest.raises(ValueError, match="contiguous"):
        trimctl.Path([1, 1, 2, 2, 1, 1], np.arange(18.0).reshape(6, 3), np.tile([0.0, 0, 1], (6, 1)))
    bad = tmp_path / "bad.csv"
    bad.write_text("contour,x,y,z,u,v,w\n1,0,0,0,0,0,1\n1,abc,0,0,0,0,1\n")
    with pytest.raises(trimctl.FileFormatError, match=r"bad.csv.*line 3"):
        trimctl.read_path(bad)
    with pytest.raises(trimctl.FileFormatError, match="missing.ply"):
        trimctl.read_points(tmp_path / "missing.ply")
    empty = tmp_path / "empty.ply"
    empty.write_bytes(b"")
    with pytest.raises(trimctl.FileFormatError, match="empty.ply"):
        trimctl.read_points(empty)


def test_options_without_a_unit_are_refused_naming_the_new_name(plane_points):
    with pytest.raises(TypeError, match="voxel= was renamed voxel_mm="):
        trimctl.voxel_downsample(plane_points, voxel=1.0)
    with pytest.raises(TypeError, match="unexpected keyword argument 'voxels_mm'"):
        trimctl.voxel_downsample(plane_points, voxels_mm=1.0)
    scan = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    for old, new in [
        ("pitch", "pitch_mm"),
        ("spot_diameter", "spot_diameter_mm"),
        ("step", "step_mm"),
        ("chord_tolerance", "chord_tolerance_mm"),
    ]:
        with pytest.raises(TypeError, match=f"{old}= was renamed {new}="):
            trimctl.hatch(scan, scan, **{old: 0.5})
    path = trimctl.Path(np.array([1, 1]), scan[:2].copy(), np.tile([0.0, 0.0, 1.0], (2, 1)))
    for old, new in [("layer_step", "layer_step_mm"), ("field", "field_mm")]:
        with pytest.raises(TypeError, match=f"{old}= was renamed {new}="):
            trimctl.plan(path, **{old: 0.5})


def test_a_file_cut_inside_its_last_number_reads_with_a_trim_warning(tmp_path):
    path = tmp_path / "path.csv"
    # The last row's w was 1.25 when the copy was cut: the file still parses.
    path.write_text("contour,x,y,z,u,v,w\n3,0,0,0,0,0,1\n3,1,0,0,0,0,1.2")
    with pytest.warns(trimctl.TrimWarning,
                      match=r"path\.csv: line 3, the last, has no line end.*may be short"):
        p = trimctl.read_path(path)
    assert len(p) == 1
    assert issubclass(trimctl.TrimWarning, UserWarning)
    # A whole file reads without one; warnings as errors make the cut one an error.
    path.write_text("contour,x,y,z,u,v,w\n3,0,0,0,0,0,1\n3,1,0,0,0,0,1.25\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        trimctl.read_path(path)
    path.write_text("contour,x,y,z,u,v,w\n3,0,0,0,0,0,1\n3,1,0,0,0,0,1.2")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(trimctl.TrimWarning):
            trimctl.read_path(path)


def test_points_whose_neighbours_span_no_plane_warn_and_a_cloud_of_them_is_refused(plane_points):
    # Nine copies of one point off the plane: their 8 nearest neighbours are copies, so they
    # have no normal. The rest keep theirs; a TrimWarning counts the copies and names the first.
    copies = np.tile([[50.0, 50.0, 50.0]], (9, 1))
    cloud = np.vstack([plane_points, copies])
    with pytest.warns(trimctl.TrimWarning, match=rf"9 of {len(cloud)} points .* span no plane") as w:
        normals = trimctl.estimate_normals(cloud, k=8)
    assert f"the first is point {len(plane_points)}" in str(w[0].message)
    expected = np.array([-0.2, 0.0, 1.0]) / np.linalg.norm([-0.2, 0.0, 1.0])
    np.testing.assert_allclose(normals[: len(plane_points)],
                               np.tile(expected, (len(plane_points), 1)), atol=1e-9)
    with pytest.raises(ValueError, match="span a plane"):
        trimctl.estimate_normals(copies, k=8)
    # A plane 1e300 mm across is beyond what the kd-tree's squared distances hold: refused.
    with pytest.raises(ValueError, match="the cloud spans"):
        trimctl.estimate_normals(plane_points * 1e300, k=8)


def test_arguments_pyo3_converts_are_refused_naming_them(plane_points):
    # pyo3 names an argument only in a TypeError: k=-1 raised a bare OverflowError.
    for kwargs, error, message in [
        (dict(k=-1), ValueError, r"^k: expected a whole number of neighbours, got -1"),
        (dict(k=2**70), ValueError, r"^k: expected a whole number of neighbours"),
        (dict(k="8"), TypeError, r"k: expected a whole number of neighbours, got '8'"),
        (dict(viewpoint=(1.0, 2.0)), ValueError, r"^viewpoint: expected three numbers \(x, y, z\)"),
        (dict(reference=5), TypeError, r"reference: expected three numbers \(x, y, z\), got 5"),
    ]:
        with pytest.raises(error, match=message):
            trimctl.estimate_normals(plane_points, **kwargs)
    target = plane_points
    for kwargs, error, message in [
        (dict(max_iterations=-1), ValueError, r"^max_iterations: expected a whole number"),
        (dict(kernel=("huber",)), ValueError, r"^kernel: expected a \(name, threshold\) pair"),
    ]:
        with pytest.raises(error, match=message):
            trimctl.icp(plane_points + 0.01, target, **kwargs)
    # Good values still go through, numpy integers included.
    assert trimctl.estimate_normals(plane_points, k=np.int64(8)).shape == plane_points.shape
