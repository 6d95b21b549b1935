"""trimctl.inspect from Python: typed per-contour results (issue 23), bad input refused by name."""

import numpy as np
import pytest

import trimctl


def _case(**burrs):
    return trimctl.synth(seed=5, scan_points=200_000, cad_points=100_000, dropouts=0, scanner_views=3, **burrs)


def _inspect(case, **options):
    return trimctl.inspect(
        case.cad_vertices,
        case.cad_triangles,
        case.cad_points,
        case.cad_normals,
        case.path,
        case.scan,
        init=case.scan_from_cad_nominal,
        **options,
    )


@pytest.fixture(scope="module")
def burred():
    return _case(burr_fraction=0.3, burr_height_mm=[0.1, 0.5])


def test_a_burred_core_fails_the_burred_contours_with_typed_results(burred):
    result = _inspect(burred)
    assert isinstance(result, trimctl.Inspection)
    assert result.tolerance_um == 30.0
    assert len(result.contours) == len(burred.path)
    c = result.contours[0]
    assert isinstance(c, trimctl.ContourInspection)
    assert c.verdict in ("pass", "fail", "undecided")
    assert c.coverage >= 0.0 and c.uncertainty_um > 0.0 and isinstance(c.reason, str)
    failed = result.ids("fail")
    # 30 % of 52 contours carry webs 100–500 µm tall: about 16 must fail, each with its height.
    assert 10 <= len(failed) <= 20, failed
    for c in result.contours:
        if c.verdict == "fail" and c.blocked_fraction is None:
            assert c.excess_height_um > 60.0, c
    assert "fail" in repr(result)


def test_a_clean_core_fails_nothing():
    result = _inspect(_case())
    assert result.ids("fail") == [], [c for c in result.contours if c.verdict == "fail"]
    assert len(result.ids("pass")) > len(result.contours) // 2


def test_bad_input_is_refused_by_name(burred):
    with pytest.raises(ValueError, match="band_mm"):
        _inspect(burred, band_mm=0.0)
    with pytest.raises(ValueError, match="verdict"):
        _inspect(burred, tolerance_um=30.0).ids("maybe")
    scan = burred.scan.copy()
    scan[7] = np.nan
    with pytest.raises(ValueError, match="scan"):
        trimctl.inspect(burred.cad_vertices, burred.cad_triangles, burred.cad_points,
                        burred.cad_normals, burred.path, scan, init=burred.scan_from_cad_nominal)
    with pytest.raises(ValueError, match="cad_triangles"):
        trimctl.inspect(burred.cad_vertices, -np.ones((3, 3)), burred.cad_points,
                        burred.cad_normals, burred.path, burred.scan)
