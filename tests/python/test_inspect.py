"""trimctl.inspect from Python: typed per-contour results (issue 23), bad input refused by name."""

import json
import subprocess

import numpy as np
import pytest

import trimctl
from conftest import trimctl_exe


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


# A core whose films a second view from below (15° off the thickness axis) sees from both sides,
# as `trimctl synth --seed 35 --burrs 0 --blockages 0.5 --dropouts 0 --views 2 --view-tilts 25,15`
# writes it (crates/cli/tests/inspect.rs inspects the same case).
FILM_SEED = 35
FILM_SCAN_POINTS = 300_000
# A film read by the CLI and by Python from the same scan: the two fit the same cloud to the same
# CAD from different CAD samples (the CLI samples the mesh, Python takes the case's points), so
# their registrations, and the films read through them, differ a little: on this case both
# measure the same 15 of 23 films, 0.6 µm apart at most (uncertainties 0.03 µm).
FILM_AGREEMENT_UM = 2.0


@pytest.fixture(scope="module")
def film_case(tmp_path_factory):
    """The case written by ``trimctl synth``, its truth and ``trimctl inspect``'s contours."""
    exe = trimctl_exe()
    tmp = tmp_path_factory.mktemp("film")
    case_dir, out = tmp / "case", tmp / "out"
    subprocess.run(
        [str(exe), "synth", "--seed", str(FILM_SEED), "--burrs", "0", "--blockages", "0.5",
         "--dropouts", "0", "--views", "2", "--view-tilts", "25,15",
         "--scan-points", str(FILM_SCAN_POINTS), "--out", str(case_dir)],
        check=True, capture_output=True,
    )
    run = subprocess.run(
        [str(exe), "inspect", "--cad", str(case_dir / "cad.stl"), "--path",
         str(case_dir / "path.csv"), "--scan", str(case_dir / "scan.ply"), "--out", str(out)],
        capture_output=True, text=True,
    )
    assert run.returncode == 1, run.stderr  # the blocked openings fail
    truth = json.loads((case_dir / "case.json").read_text())
    report = json.loads((out / "inspection.json").read_text())
    return case_dir, truth, {c["id"]: c for c in report["contours"]}


def test_the_film_thickness_is_typed_and_agrees_with_inspection_json(film_case):
    case_dir, truth, cli = film_case
    case = trimctl.synth(seed=FILM_SEED, burr_fraction=0.0, blockage_fraction=0.5, dropouts=0,
                         scanner_views=2, view_tilts_deg=[15.0], scan_points=FILM_SCAN_POINTS)
    scan, _ = trimctl.read_points(case_dir / "scan.ply")
    assert scan.shape == case.scan.shape and np.allclose(scan, case.scan, atol=1e-9), \
        "not the case the CLI inspected"
    # As the CLI: no viewpoint (the two views see both sides), the identity as the start.
    result = _inspect(case)
    drawn_um = {b["contour"]: b["thickness_mm"] * 1e3 for b in truth["blockages"]}
    both = 0
    for c in result.contours:
        j = cli[c.id]
        assert (c.film_thickness_um is None) == (c.film_uncertainty_um is None), c
        if c.id not in drawn_um:
            assert c.film_thickness_um is None and j["film_thickness_um"] is None, (c, j)
            continue
        if c.film_thickness_um is None:
            continue
        assert isinstance(c.film_thickness_um, float) and isinstance(c.film_uncertainty_um, float)
        assert abs(c.film_thickness_um - drawn_um[c.id]) <= 15.0, (c.id, c.film_thickness_um)
        assert 0.0 < c.film_uncertainty_um < 15.0, c.film_uncertainty_um
        if j["film_thickness_um"] is not None:
            both += 1
            assert abs(c.film_thickness_um - j["film_thickness_um"]) <= FILM_AGREEMENT_UM, (
                c.id, c.film_thickness_um, j["film_thickness_um"])
            assert abs(c.film_uncertainty_um - j["film_uncertainty_um"]) <= 0.5, (
                c.id, c.film_uncertainty_um, j["film_uncertainty_um"])
    cli_measured = sum(1 for j in cli.values() if j["film_thickness_um"] is not None)
    # Most of the films the CLI measured, Python measured too, and agrees on.
    assert cli_measured >= 1 and both >= 0.8 * cli_measured, (both, cli_measured)
