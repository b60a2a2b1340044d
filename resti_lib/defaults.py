"""Defaults written once: ``params/*.yaml`` is their single source.

Module code that needs the default of a parameter reads it here, from the YAML a notebook or
``resti measure`` would be given, instead of keeping a second copy: :func:`load` returns one params
file, :func:`setting` one operator knob of ``params/measure.yaml`` (the defaults of every measure
operator, shared by ``resti measure`` and the task notebooks).
"""

from __future__ import annotations

import copy
from functools import cache
from typing import Any

import yaml

from . import paths
from .errors import InputError

__all__ = ["load", "merged", "setting"]


@cache
def _read(name: str) -> dict:
    path = paths.PARAMS / f"{name}.yaml"
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except OSError as e:
        raise InputError(f"cannot read the defaults: {e}", file=path) from None
    except yaml.YAMLError as e:
        raise InputError(f"invalid YAML: {e}", file=path) from None
    if not isinstance(data, dict):
        raise InputError("params must be a mapping", file=path)
    return data


def load(name: str) -> dict:
    """A copy of ``params/<name>.yaml`` (``name`` without the suffix)."""
    return copy.deepcopy(_read(name))


def merged(name: str, params: dict | None) -> dict:
    """``params/<name>.yaml`` overridden by ``params`` (None values do not override; mappings merge
    one level deep, so a per-source table may set one source)."""
    out = load(name)
    for k, v in (params or {}).items():
        if v is None:
            continue
        out[k] = {**out[k], **v} if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def setting(params: dict | None, key: str) -> Any:
    """An operator knob: ``params[key]`` when given (not None), else ``params/measure.yaml``."""
    v = (params or {}).get(key)
    if v is not None:
        return v
    d = _read("measure")
    if key not in d:
        raise KeyError(f"{key!r} is not an operator setting (params/measure.yaml)")
    return copy.deepcopy(d[key])
