"""Measurement contracts as data: the operator registry and ``resti measure``.

A contract (``../shared/formats/contract.md``) names a source sequence, an entity, times and an
operator; :func:`evaluate_contract` evaluates it against the source files and returns
``{"value", "unit", "evidence"}`` or ``{"error": ...}`` -- never a made-up value. The task notebooks
take every value from the same operators through :func:`measure` (the raising form), with the
same defaults (``params/measure.yaml``): ``resti measure`` and a task cannot give two answers for
one contract.

Operators are registered functions (one module per family, imported below; this package imports
no task)::

    @register_operator("displacement", unit="m")
    def _displacement(ctx: MeasureContext) -> tuple[value, evidence]:
        ...

Conventions per source (stated in every evidence):

- ScanNet: world = raw scan frame, camera ``T_raw<-cam`` (OpenCV), up = raw +Z, ``t = frame/fps``.
- Waymo: world = segment world frame; the camera is ``world_from_vehicle @ extrinsic`` in OpenCV
  axes (forward +Z) when the contract names one, else the vehicle frame (forward +X) is the
  subject; objects are LiDAR box tracks (forward = box +X); up = world +Z.
- Omni6DPose: world = the camera frame at the sequence's first frame; up = the scene-frame
  direction ``omni6d_up`` (default +Z) expressed in that frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ContractError, InputError, SourceError
from . import boxes, motion, objects, relations, trajectory  # noqa: F401 -- they register the operators
from .cli import measure_main
from .registry import (
    OPERATORS,
    EntityTrack,
    MeasureContext,
    OperatorSpec,
    convert_unit,
    register_operator,
    setting,
)

__all__ = [
    "OPERATORS",
    "EntityTrack",
    "MeasureContext",
    "Measured",
    "OperatorSpec",
    "convert_unit",
    "evaluate_contract",
    "evaluate_contracts",
    "measure",
    "measure_main",
    "register_operator",
    "setting",
]


@dataclass
class Measured:
    """One evaluated contract: the value (None when the source admits none: ``no_value`` says why),
    its unit, the operator's evidence and what the context added (world, subject, files)."""

    value: Any
    unit: str | None
    evidence: dict
    context: dict = field(default_factory=dict)
    no_value: str | None = None


def measure(contract: dict, params: dict | None = None, *, sources=None) -> Measured:
    """Evaluate one contract with the registered operator; raises :class:`ContractError` (or
    :class:`InputError` for damaged source files) instead of returning an error record.

    ``sources``: the :class:`~resti_lib.sources.context.SourceContext` of the caller (a task run);
    built from ``params`` when absent.
    """
    ctx = MeasureContext(contract, params or {}, sources)
    spec = OPERATORS.get(ctx.operator)
    if spec is None:
        raise ContractError(f"unknown operator {ctx.operator!r} (known: {', '.join(sorted(OPERATORS))})")
    if len(ctx.times) not in spec.n_times:
        raise ContractError(f"operator {spec.name!r} takes {' or '.join(map(str, spec.n_times))} time(s), "
                            f"got {len(ctx.times)}")
    if ctx.entity["kind"] not in spec.entities:
        raise ContractError(f"operator {spec.name!r} takes a {' or '.join(spec.entities)} entity, "
                            f"got {ctx.entity['kind']!r}")
    value, ev = spec.fn(ctx)
    no_value = ev.pop("no_value", None) if isinstance(ev, dict) else None
    unit = spec.unit
    if value is not None and unit is not None and isinstance(value, (int, float)):
        value, unit = convert_unit(float(value), unit, contract.get("unit"))
    elif contract.get("unit") not in (None, "") and spec.unit is None:
        raise ContractError(f"operator {spec.name!r} has no scalar unit; got unit {contract.get('unit')!r}")
    base = {"source": ctx.source, "sequence": ctx.sequence, "entity": ctx.entity, "times": ctx.times,
            "operator": ctx.operator, **({"camera": ctx.camera} if ctx.camera not in (None, "") else {})}
    return Measured(value, unit, ev, {**base, **ctx.evidence}, no_value)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    if isinstance(x, Path):
        return str(x)
    return x


def evaluate_contract(contract: dict, params: dict, *, sources=None) -> dict:
    """Evaluate one contract.

    Parameters
    ----------
    contract : dict
        ``source, sequence, [camera], entity, times, operator, [unit]`` (formats/contract.md).
    params : dict
        ``scannet_root``, ``waymo_root``, ``omni6d_root``, ``scannet_fps``, ``omni6d_fps``, and any
        operator setting of ``params/measure.yaml`` (``pose_rule``, ``time_tol``, ``path_gaps``,
        ``omni6d_up``, trajectory knobs, ...); a setting not given takes its default there.
    sources : SourceContext, optional
        Shared between calls to reuse opened sources.

    Returns
    -------
    ``{"value", "unit", "evidence"}`` or ``{"error": message, "evidence": {...}}``.
    """
    ev: dict[str, Any] = {}
    try:
        m = measure(contract, params, sources=sources)
        ev.update(m.context)
        if m.value is None:
            raise ContractError(m.no_value or "the source admits no value")
        ev.update(m.evidence)
        return {"value": _jsonable(m.value), "unit": m.unit, "evidence": _jsonable(ev)}
    except SourceError:
        raise  # damaged or gapped source data: resti measure names it and exits 2
    except (ContractError, InputError) as e:
        return {"error": str(e), "evidence": _jsonable(ev)}
    except (ValueError, OSError, KeyError) as e:
        return {"error": f"{type(e).__name__}: {e}", "evidence": _jsonable(ev)}


def evaluate_contracts(contracts: dict | list, params: dict) -> dict | list:
    """Evaluate one contract or a list (same order), sharing opened sources."""
    from ..sources.context import SourceContext

    keys = ("scannet_root", "waymo_root", "omni6d_root", "scannet_fps", "omni6d_fps")
    sources = SourceContext.from_params({k: (params or {}).get(k) for k in keys})
    if isinstance(contracts, list):
        return [evaluate_contract(c, params, sources=sources) for c in contracts]
    return evaluate_contract(contracts, params, sources=sources)
