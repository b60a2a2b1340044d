"""Where inputs and outputs live. Built from ``__file__`` so any working directory works.

``RESTI_SHARED`` (environment), when set, replaces ``<repo>/../shared`` everywhere.
"""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = ROOT / "notebooks"
PARAMS = ROOT / "params"
OUTPUTS = ROOT / "outputs"


def shared_dir() -> Path:
    """The shared real-data folder (``$RESTI_SHARED`` or ``<repo>/../shared``)."""
    env = os.environ.get("RESTI_SHARED")
    return Path(env).expanduser().resolve() if env else (ROOT.parent / "shared").resolve()


def resti_v5_dir() -> Path:
    return shared_dir() / "data" / "resti_v5"


def real_waymo_vehicle_pose() -> Path:
    return (shared_dir() / "data" / "waymo_v2" / "vehicle_pose"
            / "10023947602400723454_1120_000_1140_000.parquet")


def resolve(path: str | os.PathLike, base: Path = ROOT) -> Path:
    """Resolve a params path: ``${SHARED}`` expands to :func:`shared_dir`, relative paths to ``base``."""
    text = str(path).replace("${SHARED}", str(shared_dir()))
    p = Path(text).expanduser()
    return p if p.is_absolute() else (base / p)
