"""One module per task: ``audit(rows, ctx, params) -> list[Outcome]`` (see :mod:`resti_lib.tasks.base`)."""

from __future__ import annotations

import importlib

MODULES = {
    "3D Video Grounding": "grounding",
    "Ego-Centric Orientation": "orientation",
    "Dimensional Measurement": "dimensional",
    "Spatial Relation": "relation",
    "Displacement & Path Length": "displacement",
    "Speed & Acceleration": "speed",
    "Pose Estimation": "pose",
    "Trajectory Description": "trajectory",
}


def module_for(task: str):
    """The task module (``resti_lib.tasks.<name>``); unknown task names raise ``KeyError``."""
    return importlib.import_module(f"resti_lib.tasks.{MODULES[task]}")
