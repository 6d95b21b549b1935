"""The calibrated lens in the Python planner: `calibration` settings reach the planner, and each
layer's galvo commands undo the lens height term exactly, c = p·L/(L − h)."""

import numpy as np
import pytest

import trimctl


def test_commands_carry_the_height_term_of_the_calibrated_pivot():
    case = trimctl.synth(seed=4, scan_points=20_000, cad_points=20_000)
    pivot = 180.0
    plan = trimctl.plan(
        case.path,
        settings={"calibration": {"lens": {"pivot_to_focal_plane_mm": pivot}}},
    )
    assert plan.job["settings"]["lens"]["pivot_to_focal_plane_mm"] == pytest.approx(pivot)
    assert plan.job["validation"]["passed"], plan.job["validation"]["violations"][:5]
    checked = 0
    for zone in plan.zones:
        for layer in zone.layers:
            for (_, points), commands, heights in zip(layer.polylines, layer.commands, layer.heights_mm):
                assert commands.shape == points.shape
                expected = points * (pivot / (pivot - heights))[:, None]
                np.testing.assert_allclose(commands, expected, rtol=0, atol=1e-9)
                checked += len(points)
    assert checked > 100
    # Some points sit off the focal plane, so the term is not the identity.
    assert max(np.abs(h).max() for z in plan.zones for l in z.layers for h in l.heights_mm) > 0.05


def test_a_bad_calibration_key_is_refused_by_name():
    case = trimctl.synth(seed=4, scan_points=5_000, cad_points=5_000)
    with pytest.raises(ValueError, match="calibration.a_axis_direction"):
        trimctl.plan(case.path, settings={"calibration": {"a_axis_direction": [1.0, 0.5, 0.0]}})
