"""Defaults written once: ``params/*.yaml`` is their single source, and the schema of every params.

Module code that needs the default of a parameter reads it here, from the YAML a notebook or
``resti measure`` would be given, instead of keeping a second copy: :func:`load` returns one params
file, :func:`setting` one operator knob of ``params/measure.yaml`` (the defaults of every measure
operator, shared by ``resti measure`` and the task notebooks).

The schema of a params file is those defaults: :func:`check_params` refuses a key that no default
names (with the closest known one), a value whose type is not the default's (a number for a number,
an integer for an integer key, text for text, a mapping whose keys the default's mapping knows or a
per-source mapping of such values), and a number out of the range :data:`RANGES` states for its key
(tolerances at least 0, frame rates above 0, ...). Every error names the params file and the key.
"""

from __future__ import annotations

import copy
import difflib
import math
import re
from functools import cache
from typing import Any

import yaml

from . import paths
from .errors import InputError

__all__ = ["check_params", "load", "merged", "setting"]


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


# ------------------------------------------------------------------------------------------ schema

#: Keys whose values are integers (their defaults may be written as numbers or null).
INTEGER_KEYS = frozenset({"seed", "world_seed", "jobs", "decimals", "knn", "max_knn", "echo_knn", "max_tries", "min_group",
                          "max_iter", "n_estimators", "max_depth", "folds", "rounds"})
#: Key-name rules for numbers, first match wins: (pattern on the key, low, low included, what it means
#: [, high (included)]).
RANGES = (
    (r"tol", 0.0, True, "a tolerance is at least 0"),
    (r"fps$", 0.0, False, "a frame rate is above 0"),
    (r"^(seed|world_seed|decimals|echo_knn)$", 0.0, True, "at least 0"),
    (r"^jobs$", 1.0, True, "at least 1 parallel job"),
    (r"(factor|ratio|shrink)$", 0.0, False, "a factor is above 0"),
    (r"^width$", 0.0, True, "a share of a stratum, from 0 to 1", 1.0),
    (r"^(min|max)_", 0.0, True, "a bound is at least 0"),
    (r"(_m|_s|_deg|_m_s|_m_s2)$", 0.0, True, "a distance, duration or angle is at least 0"),
)
SOURCE_KEYS = ("ScanNet", "Waymo", "Omni6DPose")


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _range_problem(name: str, v: float) -> str | None:
    if not math.isfinite(v):
        return f"{v!r} is not a finite number"
    for pattern, low, inclusive, why, *high in RANGES:
        if re.search(pattern, name):
            ok = (v >= low if inclusive else v > low) and all(v <= h for h in high)
            return None if ok else f"{v!r} is out of range ({why})"
    return None


def _value_problem(name: str, v, default) -> str | None:
    """What is wrong with ``v`` given the default of its key (None when it fits)."""
    if name in INTEGER_KEYS:
        if v is None and default is None:
            return None
        if not (isinstance(v, int) and not isinstance(v, bool)):
            return f"{v!r} is not an integer"
        return _range_problem(name, v)
    if default is None:
        return _range_problem(name, v) if _is_number(v) else None
    if isinstance(default, bool):
        return None if isinstance(v, bool) else f"{v!r} is not true or false"
    if _is_number(default):
        return _range_problem(name, v) if _is_number(v) else f"{v!r} is not a number"
    if isinstance(default, str):
        return None if isinstance(v, str) else f"{v!r} is not text"
    if isinstance(default, list):
        if not isinstance(v, list):
            return f"{v!r} is not a list"
        if default and all(_is_number(x) for x in default):
            bad = [x for x in v if not _is_number(x)]
            return f"{bad[0]!r} in the list is not a number" if bad else None
        return None
    if isinstance(default, dict):
        if not isinstance(v, dict):
            return f"{str(v)[:60]!r} is not a mapping"
        if not default:  # free-form (e.g. extra synonyms)
            return None
        for k, x in v.items():
            if k in default:
                sub = _value_problem(k if k not in SOURCE_KEYS else name, x, default[k])
            elif k in SOURCE_KEYS:  # a per-source value: of the same form as the default
                sub = _value_problem(name, x, default if not any(s in default for s in SOURCE_KEYS)
                                     else next(default[s] for s in SOURCE_KEYS if s in default))
            else:
                close = difflib.get_close_matches(str(k), [str(d) for d in default], n=1)
                return f"unknown key {k!r}" + (f" (did you mean {close[0]!r}?)" if close else "")
            if sub:
                return f"{k}: {sub}"
        return None
    return None


def check_params(values: dict, defaults: dict, *, file=None, what: str = "params") -> None:
    """Refuse (:class:`~resti_lib.errors.InputError` naming ``file`` and the key) a key of ``values``
    that ``defaults`` does not know (with the closest known key), or a value that does not fit its
    default's type or its key's range (see the module docstring)."""
    if not isinstance(values, dict):
        raise InputError(f"{what} must be a mapping of names to values", file=file)
    for key, v in values.items():
        if key not in defaults:
            close = difflib.get_close_matches(str(key), [str(k) for k in defaults], n=1, cutoff=0.6)
            hint = f"; did you mean {close[0]!r}?" if close else f"; known: {', '.join(sorted(map(str, defaults)))}"
            raise InputError(f"unknown key {key!r} in the {what}{hint}", file=file, field=str(key))
        problem = _value_problem(str(key), v, defaults[key])
        if problem:
            raise InputError(f"{problem} (default: {defaults[key]!r})", file=file, field=str(key))
