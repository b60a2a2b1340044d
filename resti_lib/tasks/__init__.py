"""Task plug-ins: one module per task, each a registered :class:`~resti_lib.tasks.base.Task`.

The registry is the only list of tasks. Everything that needs to know the tasks reads it: the
schema check of a legacy or release file (:func:`names`), the stages of the main job (each task's
notebook and params file), the option stage and ``resti verify`` (:func:`interface`: each task's
answer kind, comparison rule and question reader), the report's figures (each task's
:attr:`~resti_lib.tasks.base.Task.figures`) and the order of every table (:func:`all_tasks`).

:func:`register_task` validates a task class and adds it under its legacy ``Task`` name (a second
task of the same name is refused). The built-in tasks are the modules of this package that define
one; they are found and imported on first use, so adding a task is adding its module (with its
params file and notebook). A task defined elsewhere (a test, a user package) registers itself
when its module is imported.
"""

from __future__ import annotations

import importlib
import pkgutil

from ..errors import InputError
from .base import KINDS, Task

REGISTRY: dict[str, Task] = {}

#: Modules of this package that hold shared machinery, not a task.
_SHARED = frozenset({"base", "run", "motion", "scalar_audit"})
_loaded = False


def register_task(cls: type[Task]) -> type[Task]:
    """Class decorator: validate ``cls``, instantiate it and register it under ``cls.name``."""
    problems = cls.descriptor_problems()
    if problems:
        raise ValueError(f"task class {cls.__name__}: " + "; ".join(problems))
    known = REGISTRY.get(cls.name)
    if known is not None and (type(known).__module__, type(known).__qualname__) != (cls.__module__, cls.__qualname__):
        raise ValueError(f"task {cls.name!r} is already registered by {type(known).__module__}."
                         f"{type(known).__qualname__}")
    clash = [t.name for t in REGISTRY.values() if t.name != cls.name
             and (t.params_name == cls.params_name or t.notebook == cls.notebook)]
    if clash:
        raise ValueError(f"task {cls.name!r}: params file or notebook already used by {clash}")
    REGISTRY[cls.name] = cls()
    return cls


def unregister_task(name: str) -> None:
    """Remove a task registered by :func:`register_task` (a plug-in that is unloaded, a test's task)."""
    REGISTRY.pop(name, None)


def _load_builtin() -> None:
    global _loaded
    if not _loaded:
        _loaded = True
        for m in sorted(info.name for info in pkgutil.iter_modules(__path__)):
            if m not in _SHARED:
                importlib.import_module(f"{__name__}.{m}")


def all_tasks() -> list[Task]:
    """Every registered task, in benchmark order (:attr:`Task.order`, then name)."""
    _load_builtin()
    return sorted(REGISTRY.values(), key=lambda t: (t.order, t.name))


def names() -> tuple[str, ...]:
    """The legacy ``Task`` names of every registered task, in benchmark order."""
    return tuple(t.name for t in all_tasks())


def task_for(name: str) -> Task:
    """The registered task of a legacy ``Task`` name; ``KeyError`` for an unknown name."""
    if name not in REGISTRY:
        _load_builtin()
    return REGISTRY[name]


def read_contract(row: dict, *, video_map: dict | None = None):
    """The contract of a legacy row, read by its task."""
    return task_for(row["Task"]).read_contract(row, video_map)


def interface(options: dict | None = None, settings: dict | None = None):
    """The answer interface of a run (:class:`~resti_lib.options.spec.Interface`): the option params
    (``params/options.yaml`` deep-merged with ``options``) and, per registered task, its answer kind,
    its comparison rule per source (the adjudication tolerance, which is also the separation floor
    of its candidates) and its question reader. ``settings``: per task name, the task's params as
    the run gives them (defaults: ``params/<task>.yaml``)."""
    from ..options.spec import Interface, load_option_params

    settings = settings or {}
    unknown = sorted(set(settings) - set(names()))
    if unknown:
        raise InputError(f"settings for unknown task(s) {unknown}; tasks: {list(names())}")
    return Interface(load_option_params(options), {t.name: t.interface(t.settings(settings.get(t.name)))
                                                   for t in all_tasks()})


__all__ = ["KINDS", "REGISTRY", "Task", "all_tasks", "interface", "names", "read_contract", "register_task",
           "task_for", "unregister_task"]
