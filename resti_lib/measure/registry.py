"""The operator registry, its one table of defaults and the context an operator evaluates in.

An operator is a registered function ``fn(ctx: MeasureContext) -> (value, evidence)``. It may
return ``(None, evidence)`` when the source admits no value for the contract (e.g. no dominant
relation); the evidence then carries ``"no_value"``, a sentence saying why.

Defaults of every operator knob live in ``params/measure.yaml`` (:func:`resti_lib.defaults.setting`):
``resti measure`` and the task notebooks call the same operators with the same defaults, so a
contract evaluates the same way from either entry point.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from .. import values as V
from ..defaults import setting
from ..errors import ContractError
from ..geometry.trajectory import PoseTrack
from ..sources.context import derived

__all__ = ["OPERATORS", "EntityTrack", "MeasureContext", "OperatorSpec", "convert_unit", "register_operator",
           "setting"]


# ---------------------------------------------------------------------------------------------
# registry

@dataclass(frozen=True)
class OperatorSpec:
    """A registered operator: ``fn(ctx) -> (value, evidence)``; ``unit`` is its SI output unit
    (None for structured values); ``n_times`` the accepted lengths of ``times``; ``entities`` the
    entity kinds it takes."""

    name: str
    fn: Callable[[MeasureContext], tuple[Any, dict]]
    unit: str | None
    n_times: tuple[int, ...]
    entities: tuple[str, ...]
    doc: str = ""


OPERATORS: dict[str, OperatorSpec] = {}
ENTITY_KINDS = ("camera", "ego", "vehicle", "object", "object_pair")


def register_operator(name: str, *, unit: str | None = None, n_times: tuple[int, ...] = (2,),
                      entities: tuple[str, ...] = ("camera", "ego", "vehicle", "object")
                      ) -> Callable[[Callable], Callable]:
    """Decorator registering ``fn(ctx) -> (value, evidence)`` as operator ``name``.

    Parameters
    ----------
    unit : SI unit of the value (``m``, ``deg``, ``m/s``, ``m/s^2``) or None (structured value).
    n_times : allowed numbers of contract times (``(1,)`` for instants, ``(2,)`` for intervals).
    entities : entity kinds the operator takes.
    """

    def deco(fn: Callable) -> Callable:
        if name in OPERATORS and OPERATORS[name].fn is not fn:
            raise ValueError(f"operator {name!r} is already registered")
        OPERATORS[name] = OperatorSpec(name, fn, unit, tuple(n_times), tuple(entities), (fn.__doc__ or "").strip())
        return fn

    return deco


# ---------------------------------------------------------------------------------------------
# units

_OPERATOR_UNITS = {"m": "m", "cm": "cm", "deg": "°", "m/s": "m/s", "m/s^2": "m/s²"}


def convert_unit(value: float, from_unit: str, to_unit: str | None) -> tuple[float, str]:
    """Convert a scalar between the contract units (``m``, ``cm``, ``deg``, ``m/s``, ``m/s^2``);
    factors from :mod:`resti_lib.values`."""
    if to_unit is None:
        return value, from_unit
    text = str(to_unit).strip()
    canon = V.canonical_unit(text)
    if canon is None or canon not in _OPERATOR_UNITS.values():
        raise ContractError(f"unknown unit {to_unit!r} (m, cm, deg, m/s, m/s^2)")
    to = next(k for k, v in _OPERATOR_UNITS.items() if v == canon)
    if to == from_unit:
        return value, to
    src = _OPERATOR_UNITS[from_unit]
    if V.unit_dimension(src) != V.unit_dimension(canon):
        raise ContractError(f"cannot express a value in {from_unit} as {to}")
    return value * V.si_factor(src) / V.si_factor(canon), to


# ---------------------------------------------------------------------------------------------
# context

_SOURCE_NAMES = {"scannet": "ScanNet", "waymo": "Waymo", "omni6dpose": "Omni6DPose", "omni6d": "Omni6DPose",
                 "rope": "Omni6DPose"}
_ROOT_KEYS = {"ScanNet": "scannet_root", "Waymo": "waymo_root", "Omni6DPose": "omni6d_root"}


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
    """One contract being evaluated: parsed fields, params, and the sources it reads.

    Attributes
    ----------
    contract, params : the raw inputs. source : ``ScanNet`` | ``Waymo`` | ``Omni6DPose``.
    sequence : str. camera : Waymo camera (as given) or None. entity : dict. times : list[float].
    operator : str. rule, tol : pose-interpolation rule and time tolerance (settings
    ``pose_rule``, ``time_tol``). sources : the :class:`~resti_lib.sources.context.SourceContext`
    that opens (and keeps) the source sequences and the tracks derived from them.
    """

    def __init__(self, contract: dict, params: dict, sources=None):
        if not isinstance(contract, dict):
            raise ContractError(f"a contract must be a JSON object, got {type(contract).__name__}")
        self.contract = contract
        self.params = params or {}
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
        if not isinstance(ent, dict) or ent.get("kind") not in ENTITY_KINDS:
            raise ContractError(f"entity must be {{'kind': 'camera'}} or {{'kind': 'object', 'id': ...}}, "
                                f"got {ent!r}")
        if ent["kind"] == "object" and ent.get("id") is None:
            raise ContractError("object entity lacks 'id'")
        if ent["kind"] == "object_pair" and (not isinstance(ent.get("ids"), (list, tuple)) or len(ent["ids"]) != 2):
            raise ContractError("object_pair entity needs 'ids': [a, b]")
        self.entity = ent
        times = contract["times"]
        if not isinstance(times, (list, tuple)) or not times:
            raise ContractError(f"times must be [t] or [t0, t1], got {times!r}")
        self.times = [_fnum(t, "time") for t in times]
        self.operator = str(contract["operator"])
        self.rule = str(self.setting("pose_rule"))
        self.tol = float(self.setting("time_tol"))
        self.evidence: dict[str, Any] = {}
        if sources is None:
            from ..sources.context import SourceContext

            sources = SourceContext.from_params({k: self.params.get(k) for k in
                                                 ("scannet_root", "waymo_root", "omni6d_root", "scannet_fps",
                                                  "omni6d_fps")})
        self.sources = sources

    def setting(self, key: str) -> Any:
        """An operator knob: the params' value, else its default (``params/measure.yaml``)."""
        return setting(self.params, key)

    # -- sources
    @property
    def scene(self):
        """The opened sequence: ``ScanNetScene``, ``WaymoSegment`` or ``RopeScene`` (kept by the sources)."""
        key = _ROOT_KEYS[self.source]
        if getattr(self.sources, key, None) is None:
            raise ContractError(f"params lack {key!r} (needed for {self.source})")
        opener = {"ScanNet": "scannet", "Waymo": "waymo", "Omni6DPose": "rope"}[self.source]
        return getattr(self.sources, opener)(self.sequence)

    def _cached_track(self, key: tuple, make: Callable[[], EntityTrack]) -> EntityTrack:
        return derived(self.scene, ("entity_track",) + key, make)

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
        up_scene = self.setting("omni6d_up")

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
        if kind != "object":
            raise ContractError(f"operator {self.operator!r} takes one entity, got {kind!r}")
        oid = self.entity["id"]
        if self.source == "ScanNet":
            raise ContractError(f"ScanNet object {oid}: instances are static mesh annotations with no "
                                "motion track")
        if self.source == "Waymo":
            return self._cached_track(("object", str(oid)), lambda: EntityTrack(
                self.scene.object_track(str(oid)), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), "Waymo segment world frame",
                f"object {oid} (LiDAR box track, forward = box +X)"))
        up_scene = self.setting("omni6d_up")
        fwd = tuple(float(x) for x in self.setting("omni6d_object_forward"))

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
