"""The registration benchmark's own scoring (benches/outside/outside.py, `--generator own`): the
true error of a contour is the largest of every registered point's distance to the true contour
and every true point's distance to the registered one, so a strip offset across itself reads
the offset, and a strip slid along itself reads the slide at its ends (which the cross-track
distance alone does not see)."""

import importlib.util

import numpy as np
import pytest

from conftest import ROOT

SPEC = importlib.util.spec_from_file_location("outside", ROOT / "benches" / "outside" / "outside.py")
outside = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(outside)


def write_path(fn, contours):
    """contours: {id: (n, 3) points}; feature vectors +z."""
    with open(fn, "w") as f:
        f.write("contour,x,y,z,u,v,w\n")
        for cid, pts in contours.items():
            for p in pts:
                f.write("%d,%.9f,%.9f,%.9f,0,0,1\n" % (cid, *p))


def strip(x0=0.0, y=0.0):
    x = np.linspace(0.0, 20.0, 401) + x0
    return np.column_stack([x, np.full_like(x, y), np.zeros_like(x)])


def rim(dx=0.0, r=1.2):
    a = np.linspace(0.0, 2 * np.pi, 200, endpoint=False)
    return np.column_stack([dx + r * np.cos(a), 5 + r * np.sin(a), np.zeros_like(a)])


@pytest.mark.parametrize("offset_mm", [0.0, 0.010, 0.045])
def test_an_offset_across_reads_as_the_offset(tmp_path, offset_mm):
    truth, reg = tmp_path / "truth.csv", tmp_path / "reg.csv"
    write_path(truth, {1: strip(), 2: rim()})
    write_path(reg, {1: strip(y=offset_mm), 2: rim(dx=offset_mm)})
    errors = outside.curve_errors(str(reg), str(truth), {2})
    assert errors["1"]["cross_max"] == pytest.approx(offset_mm, abs=1e-9)
    assert errors["1"]["curve_max"] == pytest.approx(offset_mm, abs=1e-9)
    # A rim moved by d lies d off at its widest (the chords cost under a micrometre).
    assert errors["2"]["curve_max"] == pytest.approx(offset_mm, abs=1e-3)


def test_a_slide_along_a_strip_shows_in_the_curve_error_only(tmp_path):
    truth, reg = tmp_path / "truth.csv", tmp_path / "reg.csv"
    write_path(truth, {1: strip()})
    write_path(reg, {1: strip(x0=0.030)})
    errors = outside.curve_errors(str(reg), str(truth), set())
    # Every registered point lies on the true line but the last 30 µm beyond its end ...
    assert errors["1"]["cross_max"] == pytest.approx(0.030, abs=1e-9)
    # ... and the true strip's first 30 µm has no registered point beside it.
    assert errors["1"]["curve_max"] == pytest.approx(0.030, abs=1e-9)
    write_path(reg, {1: strip()[3:-3]})
    errors = outside.curve_errors(str(reg), str(truth), set())
    # Stopping 0.15 mm short of both true ends: the cross-track distance sees nothing, the
    # curve error the missing ends.
    assert errors["1"]["cross_max"] == pytest.approx(0.0, abs=1e-9)
    assert errors["1"]["curve_max"] == pytest.approx(0.150, abs=1e-6)


def test_an_open_contour_is_not_closed_over_its_ends(tmp_path):
    # A U-shaped strip read as closed would take the segment between its ends as part of it.
    u = np.concatenate([strip(), strip()[::-1] + [0, 2.0, 0]])
    truth, reg = tmp_path / "truth.csv", tmp_path / "reg.csv"
    write_path(truth, {1: u})
    write_path(reg, {1: u + [0, 0, 0.005]})
    assert outside.curve_errors(str(reg), str(truth), set())["1"]["curve_max"] == pytest.approx(0.005)
    point = np.array([[0.0, 1.0, 0.0]])
    assert outside.point_to_polyline(point, u, closed=False)[0] == pytest.approx(1.0)
    assert outside.point_to_polyline(point, u, closed=True)[0] == pytest.approx(0.0)
