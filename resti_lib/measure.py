"""Measurement contracts as data: an operator registry and ``resti measure``.

A contract (``../shared/formats/contract.md``) names a source sequence, an entity, times and an
operator; :func:`evaluate_contract` evaluates it against the source files and returns
``{"value", "unit", "evidence"}`` or ``{"error": ...}`` -- never a made-up value.

Operators are registered functions::

    @register_operator("displacement", unit="m")
    def _displacement(ctx: MeasureContext) -> tuple[value, evidence]:
        ...

and receive a :class:`MeasureContext` that resolves the source scene, the entity's pose track
(with its forward axis and world up) and the camera track. Task modules register further
operators (``box_in_camera``, ``dimension``, ``distance_to_camera`` ...) into the same registry;
an unknown operator name triggers one import of the ``resti_lib.tasks`` modules before failing.

Conventions per source (stated in every evidence):

- ScanNet: world = raw scan frame, camera ``T_raw<-cam`` (OpenCV), up = raw +Z, ``t = frame/fps``.
- Waymo: world = segment world frame; the camera is ``world_from_vehicle @ extrinsic`` in OpenCV
  axes (forward +Z) when the contract names one, else the vehicle frame (forward +X) is the
  subject; objects are LiDAR box tracks (forward = box +X); up = world +Z.
- Omni6DPose: world = the camera frame at the sequence's first frame; up = the scene-frame
  direction ``omni6d_up`` (params, default +Z) expressed in that frame.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import pkgutil
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from resti_lib import paths
from resti_lib.errors import ContractError, InputError
from resti_lib.geometry import trajectory as G
from resti_lib.geometry.trajectory import PoseTrack

__all__ = [
    "OPERATORS",
    "EntityTrack",
    "MeasureContext",
    "OperatorSpec",
    "convert_unit",
    "evaluate_contract",
    "evaluate_contracts",
    "measure_main",
    "register_operator",
]


# ---------------------------------------------------------------------------------------------
# registry

@dataclass(frozen=True)
class OperatorSpec:
    """A registered operator: ``fn(ctx) -> (value, evidence)``; ``unit`` is its SI output unit
    (None for structured values); ``n_times`` the accepted lengths of ``times``."""

    name: str
    fn: Callable[[MeasureContext], tuple[Any, dict]]
    unit: str | None
    n_times: tuple[int, ...]
    doc: str = ""


OPERATORS: dict[str, OperatorSpec] = {}


def register_operator(name: str, *, unit: str | None = None, n_times: tuple[int, ...] = (2,)
                      ) -> Callable[[Callable], Callable]:
    """Decorator registering ``fn(ctx) -> (value, evidence)`` as operator ``name``.

    Parameters
    ----------
    unit : SI unit of the value (``m``, ``deg``, ``m/s``, ``m/s^2``) or None (structured value).
    n_times : allowed numbers of contract times (``(1,)`` for instants, ``(2,)`` for intervals).
    """

    def deco(fn: Callable) -> Callable:
        if name in OPERATORS and OPERATORS[name].fn is not fn:
            raise ValueError(f"operator {name!r} is already registered")
        OPERATORS[name] = OperatorSpec(name, fn, unit, tuple(n_times), (fn.__doc__ or "").strip())
        return fn

    return deco


_TASK_IMPORT_FAILURES: dict[str, str] | None = None


def _import_task_operators() -> dict[str, str]:
    """Import every ``resti_lib.tasks`` module once so that their operators register.

    Returns the modules that failed to import (name -> error), reported with an unknown operator.
    """
    global _TASK_IMPORT_FAILURES
    if _TASK_IMPORT_FAILURES is not None:
        return _TASK_IMPORT_FAILURES
    _TASK_IMPORT_FAILURES = {}
    try:
        pkg = importlib.import_module("resti_lib.tasks")
    except ImportError as e:
        _TASK_IMPORT_FAILURES["resti_lib.tasks"] = str(e)
        return _TASK_IMPORT_FAILURES
    for m in pkgutil.iter_modules(getattr(pkg, "__path__", [])):
        name = f"resti_lib.tasks.{m.name}"
        try:
            importlib.import_module(name)
        except Exception as e:  # noqa: BLE001 -- reported with the unknown-operator error
            _TASK_IMPORT_FAILURES[name] = f"{type(e).__name__}: {e}"
    return _TASK_IMPORT_FAILURES


# ---------------------------------------------------------------------------------------------
# units

_UNIT_ALIASES = {"m": "m", "meter": "m", "meters": "m", "metre": "m", "metres": "m", "cm": "cm",
                 "deg": "deg", "°": "deg", "degree": "deg", "degrees": "deg", "m/s": "m/s",
                 "m/s^2": "m/s^2", "m/s²": "m/s^2", "m/s2": "m/s^2"}
_UNIT_SCALE = {("m", "cm"): 100.0, ("cm", "m"): 0.01}


def convert_unit(value: float, from_unit: str, to_unit: str | None) -> tuple[float, str]:
    """Convert a scalar between the contract units (``m``, ``cm``, ``deg``, ``m/s``, ``m/s^2``)."""
    if to_unit is None:
        return value, from_unit
    to = _UNIT_ALIASES.get(str(to_unit).strip())
    if to is None:
        raise ContractError(f"unknown unit {to_unit!r} (m, cm, deg, m/s, m/s^2)")
    if to == from_unit:
        return value, to
    if (from_unit, to) in _UNIT_SCALE:
        return value * _UNIT_SCALE[(from_unit, to)], to
    raise ContractError(f"cannot express a value in {from_unit} as {to}")


# ---------------------------------------------------------------------------------------------
# context

_SOURCE_NAMES = {"scannet": "ScanNet", "waymo": "Waymo", "omni6dpose": "Omni6DPose", "omni6d": "Omni6DPose",
                 "rope": "Omni6DPose"}


@dataclass
class EntityTrack:
    """An entity's pose track with the axes the heading operator needs."""

    track: PoseTrack
    forward_axis: tuple[float, float, float]
    up: tuple[float, float, float]
    world: str
    subject: str
    notes: list[str] = field(default_factory=list)


def _fnum(x: Any, what: str) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise ContractError(f"{what} must be a number, got {x!r}") from None
    if not math.isfinite(v):
        raise ContractError(f"{what} must be finite, got {x!r}")
    return v


class MeasureContext:
    """One contract being evaluated: parsed fields, params, and lazily loaded sources.

    Attributes
    ----------
    contract, params : the raw inputs. source : ``ScanNet`` | ``Waymo`` | ``Omni6DPose``.
    sequence : str. camera : Waymo camera (as given) or None. entity : dict. times : list[float].
    operator : str. rule, tol : pose-interpolation rule and time tolerance (params ``pose_rule``,
    ``time_tol``; defaults ``linear``, 1e-6 s).
    """

    def __init__(self, contract: dict, params: dict, cache: dict | None = None):
        if not isinstance(contract, dict):
            raise ContractError(f"a contract must be a JSON object, got {type(contract).__name__}")
        self.contract = contract
        self.params = params or {}
        self._cache = cache if cache is not None else {}
        for key in ("source", "sequence", "entity", "times", "operator"):
            if key not in contract:
                raise ContractError(f"contract lacks {key!r}")
        src = str(contract["source"]).strip()
        if src.lower() not in _SOURCE_NAMES:
            raise ContractError(f"unknown source {src!r} (ScanNet, Waymo, Omni6DPose)")
        self.source = _SOURCE_NAMES[src.lower()]
        self.sequence = str(contract["sequence"])
        self.camera = contract.get("camera")
        ent = contract["entity"]
        if not isinstance(ent, dict) or ent.get("kind") not in ("camera", "object", "ego", "vehicle"):
            raise ContractError(f"entity must be {{'kind': 'camera'}} or {{'kind': 'object', 'id': ...}}, "
                                f"got {ent!r}")
        if ent["kind"] == "object" and ent.get("id") is None:
            raise ContractError("object entity lacks 'id'")
        self.entity = ent
        times = contract["times"]
        if not isinstance(times, (list, tuple)) or not times:
            raise ContractError(f"times must be [t] or [t0, t1], got {times!r}")
        self.times = [_fnum(t, "time") for t in times]
        self.operator = str(contract["operator"])
        self.rule = str(self.params.get("pose_rule", "linear"))
        self.tol = float(self.params.get("time_tol", G.DEFAULT_TOL))
        self.evidence: dict[str, Any] = {}

    # -- params
    def _root(self, key: str) -> Path:
        val = self.params.get(key)
        if val in (None, ""):
            raise ContractError(f"params lack {key!r} (needed for {self.source})")
        return paths.resolve(val)

    def _fps(self, key: str) -> float:
        return float(self.params.get(key, 30.0) or 30.0)

    # -- sources
    @property
    def scene(self):
        """The loaded source object: ``ScanNetScene``, ``WaymoSegment`` or ``RopeScene`` (cached)."""
        if self.source == "ScanNet":
            from resti_lib.sources.scannet import ScanNetScene

            key = ("ScanNet", str(self._root("scannet_root")), self.sequence, self._fps("scannet_fps"))
            if key not in self._cache:
                self._cache[key] = ScanNetScene(key[1], self.sequence, fps=key[3])
        elif self.source == "Waymo":
            from resti_lib.sources.waymo import WaymoSegment

            key = ("Waymo", str(self._root("waymo_root")), self.sequence)
            if key not in self._cache:
                self._cache[key] = WaymoSegment(key[1], self.sequence)
        else:
            from resti_lib.sources.omni6d import RopeScene

            key = ("Omni6DPose", str(self._root("omni6d_root")), self.sequence, self._fps("omni6d_fps"))
            if key not in self._cache:
                self._cache[key] = RopeScene(key[1], self.sequence, fps=key[3])
        return self._cache[key]

    def _cached_track(self, key: tuple, make: Callable[[], EntityTrack]) -> EntityTrack:
        full = ("track", self.source, self.sequence) + key + (id(self.scene),)
        if full not in self._cache:
            self._cache[full] = make()
        return self._cache[full]

    def camera_track(self) -> EntityTrack:
        """The camera's track (OpenCV axes, forward +Z) -- for Waymo the contract must name a camera."""
        if self.source == "ScanNet":
            return self._cached_track(("camera",), lambda: EntityTrack(
                self.scene.camera_track(), (0.0, 0.0, 1.0), (0.0, 0.0, 1.0), "ScanNet raw scan frame",
                "camera (T_raw<-cam, OpenCV axes)"))
        if self.source == "Waymo":
            if self.camera in (None, ""):
                raise ContractError("Waymo camera entity needs 'camera' (FRONT ... or 1-5)")
            cam = self.camera
            return self._cached_track(("camera", str(cam)), lambda: EntityTrack(
                self.scene.camera_track(cam), (0.0, 0.0, 1.0), (0.0, 0.0, 1.0), "Waymo segment world frame",
                f"camera {cam} (world_from_vehicle @ extrinsic @ waymo->opencv)"))
        up_scene = self.params.get("omni6d_up", [0.0, 0.0, 1.0])

        def make() -> EntityTrack:
            sc = self.scene
            tr = sc.camera_track(rebase=True)
            up = tuple(float(x) for x in sc.world_up_in_track_frame(up_scene))
            return EntityTrack(tr, (0.0, 0.0, 1.0), up, "ROPE camera frame at the first frame",
                               "camera (T_c0<-cam, OpenCV axes)", sc.camera_notes(up_scene))

        return self._cached_track(("camera", str(up_scene)), make)

    def entity_track(self) -> EntityTrack:
        """The contract entity's track with its forward axis and world up."""
        kind = self.entity["kind"]
        if self.source == "Waymo" and (kind in ("ego", "vehicle") or (kind == "camera" and self.camera in (None, ""))):
            et = self._cached_track(("vehicle",), lambda: EntityTrack(
                self.scene.ego_track(), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), "Waymo segment world frame",
                "vehicle (world_from_vehicle; origin rear-axle centre, forward +X)"))
            if kind == "camera":
                et = EntityTrack(et.track, et.forward_axis, et.up, et.world, et.subject,
                                 ["no camera named: the vehicle frame is the subject"])
            return et
        if kind in ("camera", "ego", "vehicle"):
            return self.camera_track()
        oid = self.entity["id"]
        if self.source == "ScanNet":
            raise ContractError(f"ScanNet object {oid}: instances are static mesh annotations with no "
                                "motion track")
        if self.source == "Waymo":
            return self._cached_track(("object", str(oid)), lambda: EntityTrack(
                self.scene.object_track(str(oid)), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), "Waymo segment world frame",
                f"object {oid} (LiDAR box track, forward = box +X)"))
        up_scene = self.params.get("omni6d_up", [0.0, 0.0, 1.0])
        fwd = tuple(float(x) for x in self.params.get("omni6d_object_forward", [1.0, 0.0, 0.0]))

        def make() -> EntityTrack:
            sc = self.scene
            up = tuple(float(x) for x in sc.world_up_in_track_frame(up_scene))
            return EntityTrack(sc.object_track(str(oid)), fwd, up, "ROPE camera frame at the first frame",
                               f"object {oid} (T_c0<-obj via camera poses)",
                               [f"object forward = box {list(fwd)}", *sc.camera_notes(up_scene)])

        return self._cached_track(("object", str(oid), str(up_scene), fwd), make)

    @property
    def t0(self) -> float:
        return self.times[0]

    @property
    def t1(self) -> float:
        if len(self.times) < 2:
            raise ContractError(f"operator {self.operator!r} needs [t0, t1]")
        return self.times[1]


# ---------------------------------------------------------------------------------------------
# evaluation


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


def evaluate_contract(contract: dict, params: dict, *, cache: dict | None = None) -> dict:
    """Evaluate one contract.

    Parameters
    ----------
    contract : dict
        ``source, sequence, [camera], entity, times, operator, [unit]`` (formats/contract.md).
    params : dict
        ``scannet_root``, ``waymo_root``, ``omni6d_root``, ``scannet_fps``, ``omni6d_fps``;
        optional ``pose_rule`` (``linear``), ``time_tol`` (s), ``omni6d_up``, ``path_gaps``
        (``error`` | ``skip``), ``turn_*`` for trajectory operators.
    cache : dict, optional
        Shared between calls to reuse loaded sources.

    Returns
    -------
    ``{"value", "unit", "evidence"}`` or ``{"error": message, "evidence": {...}}``.
    """
    ev: dict[str, Any] = {}
    try:
        ctx = MeasureContext(contract, params, cache)
        ev.update({"source": ctx.source, "sequence": ctx.sequence, "entity": ctx.entity, "times": ctx.times,
                   "operator": ctx.operator})
        if ctx.camera not in (None, ""):
            ev["camera"] = ctx.camera
        failures: dict[str, str] = {}
        if ctx.operator not in OPERATORS:
            failures = _import_task_operators()
        spec = OPERATORS.get(ctx.operator)
        if spec is None:
            extra = f"; task modules that failed to import: {failures}" if failures else ""
            raise ContractError(f"unknown operator {ctx.operator!r} (known: {', '.join(sorted(OPERATORS))})"
                                + extra)
        if len(ctx.times) not in spec.n_times:
            raise ContractError(f"operator {spec.name!r} takes {' or '.join(map(str, spec.n_times))} time(s), "
                                f"got {len(ctx.times)}")
        value, op_ev = spec.fn(ctx)
        ev.update(ctx.evidence)
        ev.update(op_ev)
        unit = spec.unit
        if unit is not None and isinstance(value, (int, float)):
            value, unit = convert_unit(float(value), unit, contract.get("unit"))
        elif contract.get("unit") not in (None, "") and spec.unit is None:
            raise ContractError(f"operator {spec.name!r} has no scalar unit; got unit {contract.get('unit')!r}")
        return {"value": _jsonable(value), "unit": unit, "evidence": _jsonable(ev)}
    except (ContractError, InputError) as e:
        return {"error": str(e), "evidence": _jsonable(ev)}
    except (ValueError, OSError, KeyError) as e:
        return {"error": f"{type(e).__name__}: {e}", "evidence": _jsonable(ev)}


def evaluate_contracts(contracts: dict | list, params: dict) -> dict | list:
    """Evaluate one contract or a list (same order), sharing loaded sources."""
    cache: dict = {}
    if isinstance(contracts, list):
        return [evaluate_contract(c, params, cache=cache) for c in contracts]
    return evaluate_contract(contracts, params, cache=cache)


# ---------------------------------------------------------------------------------------------
# built-in operators


def _describe(ctx: MeasureContext, et: EntityTrack) -> None:
    ctx.evidence.update({"world": et.world, "subject": et.subject, "files": et.track.source,
                         "pose_rule": ctx.rule})
    if et.notes:
        ctx.evidence["notes"] = list(et.notes)


def _gaps(ctx: MeasureContext) -> str:
    return str(ctx.params.get("path_gaps", "error"))


@register_operator("pose", unit=None, n_times=(1, 2))
def _op_pose(ctx: MeasureContext) -> tuple[Any, dict]:
    """4x4 ``T_world<-entity`` (cameras: OpenCV axes) at ``times[0]``."""
    et = ctx.entity_track()
    _describe(ctx, et)
    T, ev = G.pose_at(et.track, ctx.t0, ctx.rule, ctx.tol)
    ev["matrix"] = f"T_world<-entity (entity-to-world, row-major); entity: {et.subject}"
    if "frames" in et.track.meta:
        ev["frames"] = [int(et.track.meta["frames"][i]) for i in ev["indices"]]
    if "micros" in et.track.meta:
        ev["frame_timestamp_micros"] = [int(et.track.meta["micros"][i]) for i in ev["indices"]]
    return T, ev


@register_operator("displacement", unit="m")
def _op_displacement(ctx: MeasureContext) -> tuple[Any, dict]:
    """|p(t1) - p(t0)| of the entity (m)."""
    et = ctx.entity_track()
    _describe(ctx, et)
    return G.endpoint_displacement(et.track, ctx.t0, ctx.t1, rule=ctx.rule, tol=ctx.tol)


@register_operator("path_length", unit="m")
def _op_path_length(ctx: MeasureContext) -> tuple[Any, dict]:
    """Integrated |Δp| over the source samples in [t0, t1] (m)."""
    et = ctx.entity_track()
    _describe(ctx, et)
    return G.path_length(et.track, ctx.t0, ctx.t1, rule=ctx.rule, tol=ctx.tol, gaps=_gaps(ctx))


@register_operator("average_velocity", unit="m/s")
def _op_average_velocity(ctx: MeasureContext) -> tuple[Any, dict]:
    """Magnitude of average velocity: displacement / (t1 - t0) (m/s)."""
    et = ctx.entity_track()
    _describe(ctx, et)
    return G.average_velocity(et.track, ctx.t0, ctx.t1, rule=ctx.rule, tol=ctx.tol)


@register_operator("average_speed", unit="m/s")
def _op_average_speed(ctx: MeasureContext) -> tuple[Any, dict]:
    """Path length / (t1 - t0) (m/s)."""
    et = ctx.entity_track()
    _describe(ctx, et)
    return G.average_speed(et.track, ctx.t0, ctx.t1, rule=ctx.rule, tol=ctx.tol, gaps=_gaps(ctx))


@register_operator("acceleration", unit="m/s^2")
def _op_acceleration(ctx: MeasureContext) -> tuple[Any, dict]:
    """Magnitude of the mean acceleration over [t0, t1] (m/s^2); estimator in the evidence."""
    et = ctx.entity_track()
    _describe(ctx, et)
    return G.acceleration(et.track, ctx.t0, ctx.t1, tol=ctx.tol)


@register_operator("heading_change", unit="deg")
def _op_heading_change(ctx: MeasureContext) -> tuple[Any, dict]:
    """Signed gravity-horizontal heading change of the entity's forward axis (deg, [-180, 180))."""
    et = ctx.entity_track()
    _describe(ctx, et)
    return G.heading_change(et.track, ctx.t0, ctx.t1, et.forward_axis, et.up, rule=ctx.rule, tol=ctx.tol)


# ---------------------------------------------------------------------------------------------
# command line


def _load_params(path: str | None) -> dict:
    if not path:
        return {}
    import yaml

    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text())
    except OSError as e:
        raise InputError(f"cannot read params: {e}", file=p) from None
    except yaml.YAMLError as e:
        raise InputError(f"invalid YAML: {e}", file=p) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError("params must be a mapping", file=p)
    return data


def _load_contracts(path: str) -> dict | list:
    try:
        text = sys.stdin.read() if path == "-" else Path(path).read_text()
    except OSError as e:
        raise InputError(f"cannot read contract: {e}", file=path) from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"invalid JSON: {e.msg}", file=path, row=e.lineno) from None
    if not isinstance(data, (dict, list)):
        raise InputError("a contract file holds one object or a list of objects", file=path)
    return data


def _human(i: int | None, c: dict, r: dict) -> str:
    head = f"[{i}] " if i is not None else ""
    what = f"{c.get('operator')} {c.get('source')} {c.get('sequence')} {c.get('entity')} t={c.get('times')}" \
        if isinstance(c, dict) else str(c)
    if "error" in r:
        return f"{head}{what}: ERROR {r['error']}"
    v = r["value"]
    if isinstance(v, float):
        v = f"{v:.6g}"
    elif isinstance(v, list):
        v = json.dumps(v)
    short = r["evidence"].get("shortened_to")
    note = f" (interval shortened to {short:.6f} s)" if isinstance(short, float) else ""
    return f"{head}{what}: {v} {r['unit'] or ''}{note}".rstrip()


def measure_main(argv: list[str] | None = None) -> int:
    """``resti measure CONTRACT.json --params PARAMS.yaml [--json]``.

    Returns the exit code: 0 when every contract evaluated, 1 when any gave an error, 2 when the
    contract or params file cannot be read.
    """
    ap = argparse.ArgumentParser(prog="resti measure", description="Evaluate measurement contracts "
                                 "(formats/contract.md) against the source datasets.")
    ap.add_argument("contract", help="CONTRACT.json: one contract object or a list ('-' = stdin)")
    ap.add_argument("--params", help="PARAMS.yaml with scannet_root / waymo_root / omni6d_root ...")
    ap.add_argument("--json", action="store_true", help="print {value, unit, evidence} as JSON")
    a = ap.parse_args(argv)
    try:
        params = _load_params(a.params)
        contracts = _load_contracts(a.contract)
    except InputError as e:
        print(f"resti measure: {e}", file=sys.stderr)
        return 2
    results = evaluate_contracts(contracts, params)
    listed = results if isinstance(results, list) else [results]
    if a.json:
        print(json.dumps(results, indent=1))
    else:
        cs = contracts if isinstance(contracts, list) else [contracts]
        for i, (c, r) in enumerate(zip(cs, listed)):
            print(_human(i if isinstance(contracts, list) else None, c, r))
    return 1 if any("error" in r for r in listed) else 0
