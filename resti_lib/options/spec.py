"""The option spec of a row: what the option stage and the option checks need to know about it.

An :class:`OptionSpec` holds the row's answer (parsed once through :mod:`resti_lib.values`), its
kind, unit and printed decimals, the adjudication rule of its task, and the question's observables
(:mod:`resti_lib.options.observables`). The separation floors and plausibility bounds it implies are
computed here, once, for the builder (:mod:`resti_lib.options.stage`) and for ``resti verify``
(:mod:`resti_lib.options.checks`), so the two cannot disagree.

Parameters come from the run's :class:`Interface`: ``params/options.yaml`` with the run's overrides
(:func:`load_option_params`) and each task's comparison rule and question reader, built by the task
registry (:func:`resti_lib.tasks.interface`) and recorded in ``release.json``.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from .. import SOURCES, defaults
from .. import values as V
from ..adjudicate import Rule
from ..errors import InputError
from ..geometry.frames import rotation_angle_deg
from .observables import Observables, observables_of

OPTION_PARAMS = "params/options.yaml"


@dataclass(frozen=True)
class TaskInterface:
    """What the answer interface knows of one task: the :mod:`resti_lib.values` kind of its answers,
    its comparison rule per source (the adjudication tolerance, which is also the separation floor
    of its candidates: two candidates the rule would call equal are never both offered) and its
    question reader (what a question measures). Built by the task (:meth:`resti_lib.tasks.base.Task.interface`)."""

    kind: str
    rules: Mapping[str, Rule]
    quantity_of: Callable[[str], str] = field(compare=False)

    def rule(self, source: str) -> Rule:
        return self.rules.get(source, Rule())


@dataclass(frozen=True)
class Interface:
    """The answer interface of a run or a release: the option params (``params/options.yaml`` with
    the run's overrides) and :class:`TaskInterface` per task. One object from the run's params to
    the option stage, ``release.json`` (:meth:`to_dict`) and back (:meth:`with_record`), so the
    options are checked against the params they were built with."""

    options: dict
    tasks: Mapping[str, TaskInterface]

    def task(self, name: str) -> TaskInterface | None:
        return self.tasks.get(name)

    def rule(self, task: str, source: str) -> Rule:
        t = self.tasks.get(task)
        return t.rule(source) if t else Rule()

    def kind(self, task: str) -> str | None:
        t = self.tasks.get(task)
        return t.kind if t else None

    def quantity_of(self, task: str, question: str) -> str:
        t = self.tasks.get(task)
        return t.quantity_of(question) if t else "value"

    def to_dict(self) -> dict:
        """The record written under ``answer_interface`` in ``release.json``."""
        return {"options": copy.deepcopy(self.options),
                "rules": {name: {s: {"abs_tol": r.abs_tol, "rel_tol": r.rel_tol} for s, r in sorted(t.rules.items())}
                          for name, t in self.tasks.items()}}

    def with_record(self, record: dict | None, *, file=None) -> Interface:
        """This interface with the option params and rules of a ``release.json`` record (a task the
        record does not name keeps its own; a record that is not one is refused by name)."""
        if record is None:
            return self
        if not isinstance(record, dict) or not isinstance(record.get("options"), dict) \
                or not isinstance(record.get("rules"), dict):
            raise InputError("answer_interface must hold the mappings options and rules", file=file,
                             field="answer_interface")
        tasks = dict(self.tasks)
        for name, by_source in record["rules"].items():
            if name not in tasks:
                continue
            try:
                rules = {str(s): Rule(float(r["abs_tol"]), float(r["rel_tol"])) for s, r in by_source.items()}
            except (KeyError, TypeError, ValueError, AttributeError):
                raise InputError(f"the rule of {name!r} is not {{source: {{abs_tol, rel_tol}}}}", file=file,
                                 field="answer_interface.rules") from None
            if any(not (math.isfinite(r.abs_tol) and math.isfinite(r.rel_tol)) or r.abs_tol < 0 or r.rel_tol < 0
                   for r in rules.values()):
                raise InputError(f"the rule of {name!r} has a negative or non-finite tolerance", file=file,
                                 field="answer_interface.rules")
            tasks[name] = TaskInterface(tasks[name].kind, rules, tasks[name].quantity_of)
        return Interface(load_option_params(record["options"]), tasks)


def deep_merge(base: dict, over: dict | None) -> dict:
    """``base`` with ``over`` merged in, mapping by mapping (copies)."""
    out = copy.deepcopy(base)
    for k, v in (over or {}).items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def load_option_params(overrides: dict | None = None) -> dict:
    """``params/options.yaml`` deep-merged with ``overrides`` (same nesting)."""
    base = defaults.load("options")
    unknown = sorted(set(overrides or {}) - set(base))
    if unknown:
        raise InputError(f"unknown option parameter group(s) {unknown}; known: {sorted(base)}", file=OPTION_PARAMS)
    return deep_merge(base, overrides) if overrides else base  # base is already a copy


def per_source(table, source: str, default=None):
    """``table[source]`` when ``table`` is keyed by source, else ``table`` itself."""
    if isinstance(table, dict) and any(s in table for s in SOURCES):
        return table.get(source, default)
    return table if table is not None else default


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


def spec_of(row: dict, rid: str | None = None, extra: dict | None = None, *, iface: Interface) -> OptionSpec:
    """The option spec of one ReSTI-schema row under the answer interface ``iface`` (its task's
    rule and question reader; ``extra``: what the task knows beyond the row, e.g. the subject's
    source class)."""
    rid = str(rid if rid is not None else (row.get("ReSTI ID") or row.get("Legacy Row Key") or ""))
    detail = row.get("Answer Detail")
    v = V.parse(detail, row=rid, field="Answer Detail")
    if not v.finite():
        raise InputError("Answer Detail is not finite", row=rid, field="Answer Detail")
    task, source = str(row.get("Task")), str(row.get("Source"))
    obs = observables_of(row, iface.quantity_of(task, row.get("Question")))
    if extra and extra.get("subject_class"):
        obs = Observables(**{**obs.__dict__, "subject_class": str(extra["subject_class"])})
    labels = ()
    if isinstance(v, V.Label):
        c = row.get("Candidates") if isinstance(row.get("Candidates"), dict) else {}
        labels = tuple(sorted(str(s) for s in c.values()))
    return OptionSpec(rid, task, source, kind_of(v), v, str(detail), obs, iface.rule(task, source), labels,
                      dict(extra or {}))


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


__all__ = ["Interface", "deep_merge", "OptionSpec", "Rule", "TaskInterface", "spec_of", "load_option_params", "kind_of",
           "per_source",
           "speed_bound", "scalar_bounds", "scalar_gap", "angle_gap", "box_floors", "pose_floors",
           "box_separation", "pose_separation", "OPTION_PARAMS"]
