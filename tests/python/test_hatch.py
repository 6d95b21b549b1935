"""trimctl.hatch: equal-spacing tracks on a scanned cylinder patch, and its errors."""

import numpy as np
import pytest

import trimctl

RADIUS_MM = 30.0
# Not a multiple of the pitch: no level line runs along the boundary itself.
HALF_MM = 8.1
PITCH_MM = 0.5
NOISE_MM = 0.01


def cylinder_scan(rng, n=40_000):
    """A patch of the cylinder x² + z² = R² (axis along y), 10 µm noise, a little beyond the
    boundary."""
    x = rng.uniform(-HALF_MM - 1.0, HALF_MM + 1.0, n)
    y = rng.uniform(-HALF_MM - 1.0, HALF_MM + 1.0, n)
    z = np.sqrt(RADIUS_MM**2 - x**2)
    pts = np.column_stack([x, y, z])
    return pts + rng.normal(0.0, NOISE_MM, pts.shape)


def square_boundary():
    """The square |x|, |y| ≤ HALF_MM on the cylinder, closed (last row repeats the first)."""
    s = np.linspace(-HALF_MM, HALF_MM, 41)
    edges = [
        np.column_stack([s, np.full_like(s, -HALF_MM)]),
        np.column_stack([np.full_like(s, HALF_MM), s]),
        np.column_stack([s[::-1], np.full_like(s, HALF_MM)]),
        np.column_stack([np.full_like(s, -HALF_MM), s[::-1]]),
    ]
    xy = np.vstack([e[:-1] for e in edges] + [edges[0][:1]])
    return np.column_stack([xy[:, 0], xy[:, 1], np.sqrt(RADIUS_MM**2 - xy[:, 0] ** 2)])


def test_tracks_are_one_pitch_apart_across_the_surface_and_carry_the_normal(rng):
    settings = {"outline": True}
    # Tracks along the cylinder's axis: their spacing runs around the curved direction.
    tracks = trimctl.hatch(
        cylinder_scan(rng), square_boundary(), pitch_mm=PITCH_MM, angle_deg=90.0, step_mm=0.02,
        settings=settings,
    )
    assert settings == {"outline": True}, "the caller's settings must not change"
    ids = tracks.contour_ids
    # Hatch levels across the region (16.2 mm, a little more around the curve) plus the outline.
    assert len(ids) == pytest.approx(2 * HALF_MM / PITCH_MM + 1, abs=2)
    # Neighbour spacing: each track's points to the nearest point of the next (the outline,
    # last, left out), measured in 3D across the curved surface; points 0.02 mm apart along a
    # track bias it by at most 0.01² / (2 × 0.5) mm.
    gaps = []
    for a, b in zip(ids[:-2], ids[1:-1]):
        pa, _ = tracks.contour(a)
        pb, _ = tracks.contour(b)
        inner = pa[(np.abs(pa[:, 0]) < HALF_MM - 1.0) & (np.abs(pa[:, 1]) < HALF_MM - 1.0)]
        if len(inner) == 0:
            continue
        d = np.linalg.norm(inner[:, None, :] - pb[None, :, :], axis=2).min(axis=1)
        gaps.extend(d.tolist())
    gaps = np.asarray(gaps)
    assert abs(gaps.mean() / PITCH_MM - 1.0) < 0.02, gaps.mean()
    assert gaps.std() / gaps.mean() < 0.05, gaps.std() / gaps.mean()
    # Every point is inside the boundary (0.02 mm) and on the surface; its feature vector is the
    # unit surface normal (radial, here).
    pts, normals = tracks.points, tracks.features
    assert np.all(np.abs(pts[:, :2]) <= HALF_MM + 0.02)
    # On the surface to within the scan noise (10 µm per coordinate) and the fit.
    assert np.abs(np.hypot(pts[:, 0], pts[:, 2]) - RADIUS_MM).max() < 0.02
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)
    radial = np.column_stack([pts[:, 0], np.zeros(len(pts)), pts[:, 2]]) / RADIUS_MM
    off_deg = np.degrees(np.arccos(np.clip((normals * radial).sum(axis=1), -1, 1)))
    # The normal of the fitted surface (10 µm noise): well inside the incidence budget.
    assert np.percentile(off_deg, 95) < 1.5, np.percentile(off_deg, 95)
    assert off_deg.max() < 3.0, off_deg.max()


def test_pitch_from_spot_and_overlap_and_the_slab_method(rng):
    scan, boundary = cylinder_scan(rng, 20_000), square_boundary()
    a = trimctl.hatch(scan, boundary, spot_diameter_mm=1.0, overlap=0.5, outline=False)
    b = trimctl.hatch(scan, boundary, pitch_mm=0.5, outline=False)
    assert len(a) == len(b)
    slab = trimctl.hatch(scan, boundary, pitch_mm=0.5, method="slab", outline=False)
    assert abs(len(slab) - len(b)) <= 1


def test_bad_input_is_refused_by_name(rng):
    scan, boundary = cylinder_scan(rng, 5_000), square_boundary()
    with pytest.raises(ValueError, match="pitch"):
        trimctl.hatch(scan, boundary, pitch_mm=0.5, spot_diameter_mm=1.0, overlap=0.5)
    with pytest.raises(ValueError, match="overlap"):
        trimctl.hatch(scan, boundary, spot_diameter_mm=1.0, overlap=1.5)
    with pytest.raises(ValueError, match="pitch_mm"):
        trimctl.hatch(scan, boundary, pitch_mm=-1.0)
    with pytest.raises(ValueError, match="method"):
        trimctl.hatch(scan, boundary, pitch_mm=0.5, method="zigzag")
    with pytest.raises(ValueError, match="not closed"):
        trimctl.hatch(scan, boundary[:-5], pitch_mm=0.5)
    bad = scan.copy()
    bad[7, 1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        trimctl.hatch(bad, boundary, pitch_mm=0.5)
    with pytest.raises(ValueError, match="boundary"):
        trimctl.hatch(scan, boundary[:, :2], pitch_mm=0.5)


def test_a_boundary_without_its_closing_row_is_closed_implicitly(rng):
    """A boundary is a polygon: without its last row (one 0.4 mm sample step short of the
    first) it is closed implicitly and hatched exactly as with it."""
    scan, boundary = cylinder_scan(rng, 10_000), square_boundary()
    closed = trimctl.hatch(scan, boundary, pitch_mm=1.0)
    implicit = trimctl.hatch(scan, boundary[:-1], pitch_mm=1.0)
    assert len(closed) > 5 and len(implicit) == len(closed)
    np.testing.assert_array_equal(implicit.points, closed.points)
