"""Shared fixtures of the Python tests: the real recordings of ../shared/fixtures/real (skipped,
with a message, where that folder is absent) and small synthetic events."""
import os
import pathlib

import numpy as np
import pytest

ROOT = pathlib.Path(os.environ.get("EVKIT_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))
REAL = ROOT.parent / "shared" / "fixtures" / "real"


@pytest.fixture
def real():
    """The path of a real recording, or a skip naming what is missing."""

    def path(name):
        p = REAL / name
        if not p.exists():
            pytest.skip(f"{name}: ../shared/fixtures/real is absent (a clone without shared/)")
        return p

    return path


@pytest.fixture
def events():
    """1,000 sorted events on a 64 x 48 sensor, as a structured array with tonic's field order."""
    rng = np.random.default_rng(7)
    n = 1000
    out = np.zeros(n, dtype=[("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
    out["t"] = 1_600_000_000_000_000 + np.sort(rng.integers(0, 50_000, n))
    out["x"] = rng.integers(0, 64, n)
    out["y"] = rng.integers(0, 48, n)
    out["p"] = rng.choice([-1, 1], n)
    return out
