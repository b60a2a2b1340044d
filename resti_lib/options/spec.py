"""The option spec of a row: what the option stage and the option checks need to know about it.

An :class:`OptionSpec` holds the row's answer (parsed once through :mod:`resti_lib.values`), its
kind, unit and printed decimals, the adjudication rule of its task, and the question's observables
(:mod:`resti_lib.options.observables`). The separation floors and plausibility bounds it implies are
computed here, once, for the builder (:mod:`resti_lib.options.stage`) and for ``resti verify``
(:mod:`resti_lib.options.checks`), so the two cannot disagree.

Parameters come from ``params/options.yaml`` (:func:`load_option_params`); the adjudication rule of
each task from that task's own params file (:func:`task_rule`), where the task states it.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from .. import SOURCES, defaults
from .. import values as V
from ..errors import InputError
from ..geometry.frames import rotation_angle_deg
from .observables import Observables, observables_of

OPTION_PARAMS = "params/options.yaml"

#: Where each task states its adjudication tolerance: (params file, key, how to read it).
_RULE_KEYS = {
    "Dimensional Measurement": ("dimensional", "rule"),
    "Displacement & Path Length": ("displacement", "rule"),
    "Speed & Acceleration": ("speed", "rule"),
    "Ego-Centric Orientation": ("orientation", "angle_abs_tol_deg"),
    "3D Video Grounding": ("grounding", "centre_abs_tol_m"),
    "Pose Estimation": ("pose", "compare_abs_tol"),
    "Trajectory Description": ("trajectory", "compare_abs_tol_m"),
}


@dataclass(frozen=True)
class Rule:
    """Two values agree when they differ by at most half a printed unit + ``abs_tol`` + ``rel_tol``·|v|."""

    abs_tol: float = 0.0
    rel_tol: float = 0.0

    def tolerance(self, value: float, ulp: float) -> float:
        return 0.5 * ulp + self.abs_tol + self.rel_tol * abs(value)


def _merge(base: dict, over: dict | None) -> dict:
    out = copy.deepcopy(base)
    for k, v in (over or {}).items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def load_option_params(overrides: dict | None = None) -> dict:
    """``params/options.yaml`` deep-merged with ``overrides`` (same nesting)."""
    base = defaults.load("options")
    unknown = sorted(set(overrides or {}) - set(base))
    if unknown:
        raise InputError(f"unknown option parameter group(s) {unknown}; known: {sorted(base)}", file=OPTION_PARAMS)
    return _merge(base, overrides) if overrides else base  # base is already a copy


def per_source(table, source: str, default=None):
    """``table[source]`` when ``table`` is keyed by source, else ``table`` itself."""
    if isinstance(table, dict) and any(s in table for s in SOURCES):
        return table.get(source, default)
    return table if table is not None else default


@lru_cache(maxsize=16)
def task_rule(task: str) -> Rule:
    """The adjudication rule a task states in its params file (no rule: exact agreement)."""
    where = _RULE_KEYS.get(task)
    if where is None:
        return Rule()
    f, key = where
    try:
        v = defaults.load(f).get(key)
    except InputError:
        return Rule()
    if isinstance(v, dict):
        return Rule(float(v.get("abs_tol", 0.0)), float(v.get("rel_tol", 0.0)))
    if isinstance(v, (int, float)):
        return Rule(float(v), 0.0)
    return Rule()


def kind_of(v: V.Value) -> str:
    if isinstance(v, V.Scalar):
        return "angle" if v.is_angle else "scalar"
    return v.kind


@dataclass
class OptionSpec:
    """Everything the option stage needs to know about one accepted row."""

    rid: str
    task: str
    source: str
    kind: str
    value: V.Value
    detail: str
    obs: Observables
    rule: Rule
    labels: tuple = ()
    extra: dict = field(default_factory=dict)

    @property
    def decimals(self) -> int:
        return int(getattr(self.value, "decimals", 0) or 0)

    @property
    def unit(self) -> str | None:
        return getattr(self.value, "unit", None)

    @property
    def ulp(self) -> float:
        return 10.0 ** -self.decimals

    def to_dict(self) -> dict:
        return {"kind": self.kind, "unit": self.unit, "decimals": self.decimals,
                "rule": {"abs_tol": self.rule.abs_tol, "rel_tol": self.rule.rel_tol},
                "observables": self.obs.to_dict()}


def spec_of(row: dict, rid: str | None = None, extra: dict | None = None) -> OptionSpec:
    """The option spec of one ReSTI-schema row (``extra``: what the task knows beyond the row, e.g.
    the subject's source class)."""
    rid = str(rid if rid is not None else (row.get("ReSTI ID") or row.get("Legacy Row Key") or ""))
    detail = row.get("Answer Detail")
    v = V.parse(detail, row=rid, field="Answer Detail")
    if not v.finite():
        raise InputError("Answer Detail is not finite", row=rid, field="Answer Detail")
    obs = observables_of(row)
    if extra and extra.get("subject_class"):
        obs = Observables(**{**obs.__dict__, "subject_class": str(extra["subject_class"])})
    labels = ()
    if isinstance(v, V.Label):
        c = row.get("Candidates") if isinstance(row.get("Candidates"), dict) else {}
        labels = tuple(sorted(str(s) for s in c.values()))
    return OptionSpec(rid, str(row.get("Task")), str(row.get("Source")), kind_of(v), v, str(detail), obs,
                      task_rule(str(row.get("Task"))), labels, dict(extra or {}))


# ------------------------------------------------------------------------------ floors and bounds

def speed_bound(params: dict, source: str, subject_class: str) -> float:
    t = params["plausibility"]["max_speed_m_s"].get(source, {})
    if isinstance(t, (int, float)):
        return float(t)
    return float(t.get(subject_class, t.get("default", math.inf)))


def scalar_bounds(spec: OptionSpec, params: dict) -> tuple[float, float]:
    """Physically possible range of a magnitude (in the answer's unit) given the question.

    The source answer is possible by definition: where it exceeds the configured bound, the bound
    widens to a quarter above it (the answer is never the only candidate inside the bound)."""
    pl = params["plausibility"]
    o = spec.obs
    per_unit = spec.value.si_per_unit if isinstance(spec.value, V.Scalar) else 1.0
    hi = math.inf
    q = o.quantity
    if q in ("displacement", "path_length", "trajectory"):
        if o.window_s and o.window_s > 0:
            hi = speed_bound(params, spec.source, o.subject_class) * o.window_s
    elif q == "speed":
        hi = speed_bound(params, spec.source, o.subject_class)
    elif q == "acceleration":
        hi = float(per_source(pl["max_accel_m_s2"], spec.source, math.inf))
    elif q in ("length", "width", "height"):
        hi = float(per_source(pl["max_size_m"], spec.source, math.inf))
    elif q in ("distance_to_camera", "surface_distance", "distance"):
        hi = float(per_source(pl["max_depth_m"], spec.source, math.inf))
    v = spec.value
    answer = v.total_distance if isinstance(v, V.Trajectory) else (v.value if isinstance(v, V.Scalar) else 0.0)
    return 0.0, max(hi / per_unit, 1.25 * answer)


def scalar_gap(spec: OptionSpec, params: dict, x: float) -> float:
    """Smallest distance between two adjacent candidate values near ``x`` (answer units)."""
    sep = params["separation"]["scalar"]
    ulp = spec.ulp
    per_unit = spec.value.si_per_unit if isinstance(spec.value, V.Scalar) else 1.0
    rule_tol = spec.rule.tolerance(x * per_unit, ulp * per_unit) / per_unit
    return max(sep["min_gap_ulps"] * ulp, rule_tol, 1e-12)


def angle_gap(spec: OptionSpec, params: dict) -> float:
    return max(float(params["separation"]["angle"]["min_sep_deg"]), spec.rule.tolerance(0.0, spec.ulp))


def box_floors(spec: OptionSpec, params: dict) -> dict:
    return dict(per_source(params["separation"]["box"], spec.source, {}))


def pose_floors(spec: OptionSpec, params: dict) -> dict:
    return dict(per_source(params["separation"]["pose"], spec.source, {}))


def box_separation(a: V.Box, b: V.Box, floors: dict) -> float:
    """How far apart two boxes are in units of the floors: the largest of centre distance / floor
    (``centre_m`` or ``centre_rel`` of the mean depth), rotation angle / ``rot_deg`` and max abs
    log-edge difference / ``log_dims``. Below 1 the two agree within every floor: both would be
    read as the same box."""
    ca, cb = np.asarray(a.center, float), np.asarray(b.center, float)
    fc = max(floors.get("centre_m", 0.0), floors.get("centre_rel", 0.0) * 0.5 * (abs(ca[2]) + abs(cb[2])))
    parts = [np.linalg.norm(ca - cb) / fc if fc > 0 else math.inf]
    fd = floors.get("log_dims", 0.0)
    la = np.log(np.maximum(np.asarray(a.lwh, float), 1e-9))
    lb = np.log(np.maximum(np.asarray(b.lwh, float), 1e-9))
    parts.append(float(np.max(np.abs(la - lb))) / fd if fd > 0 else math.inf)
    fr = floors.get("rot_deg", 0.0)
    if a.R is not None and b.R is not None:
        parts.append(rotation_angle_deg(a.R, b.R) / fr if fr > 0 else math.inf)
    return float(max(parts))


def pose_separation(a: V.Pose, b: V.Pose, floors: dict) -> float:
    """Translation distance / ``trans_m`` or rotation angle / ``rot_deg``, whichever is larger."""
    ft, fr = floors.get("trans_m", 0.0), floors.get("rot_deg", 0.0)
    dt = float(np.linalg.norm(np.asarray(a.t, float) - np.asarray(b.t, float)))
    parts = [dt / ft if ft > 0 else math.inf, rotation_angle_deg(a.R, b.R) / fr if fr > 0 else math.inf]
    return float(max(parts))


__all__ = ["OptionSpec", "Rule", "spec_of", "load_option_params", "task_rule", "kind_of", "per_source",
           "speed_bound", "scalar_bounds", "scalar_gap", "angle_gap", "box_floors", "pose_floors",
           "box_separation", "pose_separation", "OPTION_PARAMS"]
