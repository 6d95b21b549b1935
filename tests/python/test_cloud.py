"""Point-cloud processing and argument checks at the Python boundary."""

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
    down, normals = trimctl.voxel_downsample(pts, voxel=1.0)
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
        trimctl.voxel_downsample(plane_points, voxel=0.0)
    with pytest.raises(ValueError, match="either viewpoint or reference"):
        trimctl.estimate_normals(plane_points, viewpoint=(0, 0, 1), reference=(0, 0, 1))


def test_options_are_keyword_only(plane_points):
    with pytest.raises(TypeError):
        trimctl.estimate_normals(plane_points, 8)


def test_error_hierarchy():
    for cls in (trimctl.FileFormatError, trimctl.RegistrationError, trimctl.PlanningError,
                trimctl.InternalError):
        assert issubclass(cls, trimctl.TrimError)
