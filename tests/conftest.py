"""Shared fixtures. Real-data tests skip without ../shared (or $RESTI_SHARED), unless CI=true."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from resti_lib import paths


def _require(path: Path, what: str) -> Path:
    if path.exists():
        return path
    msg = f"{what} not found at {path} (set RESTI_SHARED to the folder holding data/)"
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(f"CI=true requires the shared data: {msg}")
    pytest.skip(msg)


@pytest.fixture(scope="session")
def resti_v5_dir() -> Path:
    """The public ReSTI v5 release (real data)."""
    return _require(paths.resti_v5_dir(), "ReSTI v5 release")


@pytest.fixture(scope="session")
def real_vehicle_pose() -> Path:
    """The real Waymo v2 vehicle_pose parquet (199 frames)."""
    return _require(paths.real_waymo_vehicle_pose(), "real Waymo v2 vehicle_pose file")


@pytest.fixture(scope="session")
def real_samples() -> Path:
    """Small real source files (ScanNet scene0000_00, a ROPE frame, Waymo camera_hkp), byte-exact."""
    return _require(paths.shared_dir() / "data" / "real_samples", "real source samples")


@pytest.fixture(scope="session")
def miniworld(tmp_path_factory) -> Path:
    """The default mini-world (seed 0), generated once per session into a temporary folder."""
    from resti_lib.synth import generate

    out = tmp_path_factory.mktemp("miniworld")
    generate(out, seed=0)
    return out

