"""Shared fixtures for the trimctl Python tests."""

import os
import pathlib

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
# The real data the tests read, in the repository (tests/data/README.md).
TEST_DATA = ROOT / "tests" / "data"


def trimctl_exe():
    """The ``trimctl`` binary the test command built (debug first, else release)."""
    target = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    for profile in ("debug", "release"):
        exe = target / profile / "trimctl"
        if exe.exists():
            return exe
    raise AssertionError("build trimctl first (the test command runs cargo test before pytest)")


@pytest.fixture
def rng():
    return np.random.default_rng(20261121)


@pytest.fixture
def plane_points():
    """A 20 × 20 grid on the plane z = 0.2 x (mm)."""
    i, j = np.meshgrid(np.arange(20) * 0.5, np.arange(20) * 0.5, indexing="ij")
    x, y = i.ravel(), j.ravel()
    return np.column_stack([x, y, 0.2 * x]).astype(np.float64)
