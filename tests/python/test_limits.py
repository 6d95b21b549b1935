"""Settings that would exhaust the memory or switch a safety gate off raise ``ValueError`` naming
the key, instead of aborting the interpreter or passing everything."""

import numpy as np
import pytest

import trimctl


@pytest.mark.parametrize("key", ["scan_points", "cad_points"])
@pytest.mark.parametrize("value", [10**12, 10**30])
def test_a_huge_point_count_raises_value_error_naming_the_key(key, value):
    # 10**12 points would ask for tens of terabytes (an abort in the allocator, taking the
    # interpreter down); 10**30 does not fit a usize.
    with pytest.raises(ValueError, match=key):
        trimctl.synth(seed=1, **{key: value})


@pytest.mark.parametrize("value", [0.05, -0.03, float("nan")])
def test_a_shrinkage_gradient_out_of_range_raises_value_error_naming_the_key(value):
    # The change of shrinkage along the span is bounded by 2 % end to end.
    with pytest.raises(ValueError, match="shrink_gradient"):
        trimctl.synth(seed=1, shrink_gradient=value)


def tiny_inputs():
    rng = np.random.default_rng(1)
    cad = rng.uniform(-1.0, 1.0, (100, 3))
    normals = np.tile([0.0, 0.0, 1.0], (100, 1))
    path = trimctl.Path(np.array([0, 0]), np.array([[0.0, 0, 0], [1.0, 0, 0]]),
                        np.array([[0.0, 0, 1], [0.0, 0, 1]]))
    return cad, normals, path


@pytest.mark.parametrize(
    "settings, key",
    [
        ({"cad_sample_points": 10**12}, "cad_sample_points"),
        ({"quality": {"tolerance_um": 1e9}}, "quality.tolerance_um"),
        ({"quality": {"min_coverage": 0.0}}, "quality.min_coverage"),
        ({"quality": {"min_overlap": 0.0}}, "quality.min_overlap"),
        ({"quality": {"coverage_radius_mm": 1e6}}, "quality.coverage_radius_mm"),
    ],
)
def test_a_setting_that_switches_a_gate_off_raises_value_error_naming_the_key(settings, key):
    cad, normals, path = tiny_inputs()
    with pytest.raises(ValueError, match=key):
        trimctl.register_path(cad, cad, path, cad_normals=normals, settings=settings)
