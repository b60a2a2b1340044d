"""Task plug-ins: one module per task, each a registered :class:`~resti_lib.tasks.base.Task`.

:func:`register_task` adds a task to :data:`REGISTRY` (keyed by the legacy ``Task`` name);
:func:`task_for` returns it. The built-in tasks are the modules listed in :data:`BUILTIN`, imported
on first use; a task defined elsewhere (a test, a user package) registers itself when its module is
imported. :func:`read_contract` reads any legacy row's contract through its task.
"""

from __future__ import annotations

import importlib

from .base import Task

REGISTRY: dict[str, Task] = {}

#: Built-in task modules (``resti_lib.tasks.<module>``), imported on first lookup.
BUILTIN = ("grounding", "orientation", "dimensional", "relation", "displacement", "speed", "pose", "trajectory")
_loaded = False


def register_task(cls: type[Task]) -> type[Task]:
    """Class decorator: instantiate ``cls`` and register it under ``cls.name``."""
    if not cls.name:
        raise ValueError(f"{cls.__name__} has no task name")
    REGISTRY[cls.name] = cls()
    return cls


def _load_builtin() -> None:
    global _loaded
    if not _loaded:
        _loaded = True
        for m in BUILTIN:
            importlib.import_module(f"{__name__}.{m}")


def task_for(name: str) -> Task:
    """The registered task of a legacy ``Task`` name; ``KeyError`` for an unknown name."""
    if name not in REGISTRY:
        _load_builtin()
    return REGISTRY[name]


def read_contract(row: dict, *, video_map: dict | None = None):
    """The contract of a legacy row, read by its task."""
    return task_for(row["Task"]).read_contract(row, video_map)


__all__ = ["BUILTIN", "REGISTRY", "Task", "read_contract", "register_task", "task_for"]
