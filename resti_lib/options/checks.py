"""Structural checks of the answer interface, one registered function per check.

Each row check receives a :class:`ParsedRow` and returns ``None`` (pass) or a short message (fail).
``resti verify`` runs every registered check over every accepted row and reports, per check, the
ids of the failing rows. New checks plug in with ``@row_check("name")``.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .. import LETTERS
from .. import values as V
from ..errors import InputError


@dataclass
class ParsedRow:
    """A row with its candidates parsed once (``values`` letter -> Value; ``errors`` letter -> text)."""

    rid: object
    task: str
    source: str
    candidates: dict
    answer: str
    detail: str
    values: dict
    errors: dict
    detail_value: object | None
    detail_error: str | None
    time_start: object
    time_end: object
    record: dict | None = None
    iface: object | None = None  # the answer interface (options.spec.Interface) the spec checks read
    spec_read: tuple | None = field(default=None, repr=False, compare=False)  # (spec, params) once read

    @property
    def complete(self) -> bool:
        return not self.errors and sorted(self.values) == list(LETTERS)


def _text(v) -> str | None:
    return v if isinstance(v, str) else None


def parse_row(r: dict, rid: object, iface=None) -> ParsedRow:
    """Parse a row once. Fields of the wrong type (a list as Task, a number as a candidate) are kept
    out of the parsed values, so every check sees plain text and reports instead of failing.
    ``iface``: the answer interface (:class:`resti_lib.options.spec.Interface`) the task-aware checks
    read (kind, separation, plausibility, format); the release's own, as ``resti verify`` reads it."""
    raw = r.get("Candidates") if isinstance(r.get("Candidates"), dict) else {}
    cand = {str(k): v for k, v in raw.items()}
    vals, errs = {}, {}
    for k, s in cand.items():
        if not isinstance(s, str):
            errs[k] = f"candidate is a {type(s).__name__}, not text"
            continue
        try:
            vals[k] = V.parse(s, row=rid, field=f"Candidates.{k}")
        except InputError as e:
            errs[k] = e.message
    dv, de = None, None
    detail = r.get("Answer Detail")
    if not isinstance(detail, str):
        de = f"Answer Detail is {type(detail).__name__}, not text"
    else:
        try:
            dv = V.parse(detail, row=rid, field="Answer Detail")
        except InputError as e:
            de = e.message
    return ParsedRow(rid=rid, task=_text(r.get("Task")), source=_text(r.get("Source")), candidates=cand,
                     answer=_text(r.get("Answer")), detail=_text(detail), values=vals, errors=errs,
                     detail_value=dv, detail_error=de, time_start=r.get("time_start"),
                     time_end=r.get("time_end"), record=r, iface=iface)


RowCheck = Callable[[ParsedRow], "str | None"]
ROW_CHECKS: dict[str, RowCheck] = {}


def row_check(name: str):
    def deco(fn: RowCheck) -> RowCheck:
        ROW_CHECKS[name] = fn
        return fn
    return deco


def rotation_tolerance(decimals: int) -> float:
    """Tolerance on max|RRᵀ−I| and |det R − 1| for entries printed with ``decimals`` decimals.

    Rounding an exact rotation moves each entry by at most ε = 0.5·10⁻ᵈ, which bounds the error by
    2√3·ε ≈ 1.7·10⁻ᵈ. Distractors built from separately rounded components reach about 2.7·10⁻ᵈ
    (ReSTI v5 poses: 0.0265 at two decimals), so the check allows 3·10⁻ᵈ: still far below any
    real defect (a reflected or sheared matrix is off by order 1).
    """
    return 3.0 * 10.0 ** -decimals


@row_check("five_candidates")
def _five(p: ParsedRow):
    keys = sorted(p.candidates)
    return None if keys == list(LETTERS) else f"candidate letters {keys}"


@row_check("parseable")
def _parseable(p: ParsedRow):
    if p.errors:
        return "; ".join(f"{k}: {m}" for k, m in sorted(p.errors.items()))
    if p.detail_error:
        return f"Answer Detail: {p.detail_error}"
    return None


@row_check("key_detail_agreement")
def _key_detail(p: ParsedRow):
    keyed = p.candidates.get(p.answer)
    if keyed is None:
        return f"answer letter {p.answer!r} is not a candidate"
    if keyed == p.detail:
        return None
    kv = p.values.get(p.answer)
    if kv is not None and p.detail_value is not None and V.agree(kv, p.detail_value):
        return f"keyed {keyed!r} equals detail {p.detail!r} only after rounding"
    return f"keyed {keyed!r} != detail {p.detail!r}"


@row_check("distinct_strings")
def _distinct(p: ParsedRow):
    strs = [" ".join(str(s).split()) for s in p.candidates.values()]
    dup = sorted({s for s in strs if strs.count(s) > 1})
    return f"repeated candidate(s) {dup}" if dup else None


@row_check("numeric_duplicates")
def _numeric_dup(p: ParsedRow):
    seen: dict = {}
    for k in sorted(p.values):
        v = p.values[k]
        seen.setdefault(v.key(), []).append(k)
    groups = [ks for ks in seen.values() if len(ks) > 1
              and len({" ".join(p.candidates[k].split()) for k in ks}) > 1]
    return f"same value, different text: {groups}" if groups else None


@row_check("same_kind")
def _same_kind(p: ParsedRow):
    if p.iface is None:
        raise ValueError("the same_kind check needs the answer interface (parse_row iface=)")
    want = p.iface.kind(p.task)
    if want is None and p.task is not None:
        return f"no registered task {p.task!r} states the kind of its answers"
    kinds = {k: v.kind for k, v in p.values.items()}
    bad = {k: kd for k, kd in kinds.items() if want and kd != want}
    if bad:
        return f"expected {want} values, got {bad}"
    dims = {v.dimension for v in p.values.values() if isinstance(v, V.Scalar)}
    if len(dims) > 1:
        return f"mixed dimensions {sorted(dims)}"
    return None


@row_check("finite_values")
def _finite(p: ParsedRow):
    bad = sorted(k for k, v in p.values.items() if not v.finite())
    if p.detail_value is not None and not p.detail_value.finite():
        bad.append("Answer Detail")
    return f"non-finite value in {bad}" if bad else None


@row_check("time_order")
def _times(p: ParsedRow):
    try:
        if isinstance(p.time_start, (str, bool)) or isinstance(p.time_end, (str, bool)):
            raise TypeError
        ts, te = float(p.time_start), float(p.time_end)
    except (TypeError, ValueError, OverflowError):
        return f"times not numeric ({p.time_start!r}, {p.time_end!r})"
    if not (math.isfinite(ts) and math.isfinite(te)):
        return f"non-finite time ({ts}, {te})"
    if ts < 0 or te < ts:
        return f"time order violated (0 <= {ts} <= {te})"
    return None


@row_check("rotation_validity")
def _rotations(p: ParsedRow):
    msgs = []
    for k, v in sorted(p.values.items()):
        R = getattr(v, "R", None)
        if R is None or not v.finite():
            continue
        R = np.array(R, dtype=float)
        tol = rotation_tolerance(v.decimals)
        orth = float(np.abs(R @ R.T - np.eye(3)).max())
        det = float(np.linalg.det(R))
        if orth > tol or abs(det - 1.0) > tol:
            msgs.append(f"{k}: |RRᵀ−I|={orth:.3g}, det={det:.4f} (tol {tol:.3g})")
    return "; ".join(msgs) or None


@row_check("box_consistency")
def _boxes(p: ParsedRow):
    msgs = []
    for k, v in sorted(p.values.items()):
        if not isinstance(v, V.Box) or not v.finite():
            continue
        if min(v.lwh) <= 0:
            msgs.append(f"{k}: non-positive edge length {v.lwh}")
        if v.R is not None and v.heading is not None:
            R = np.array(v.R)
            h = V.box_heading(R)
            eps = 0.5 * 10.0 ** -v.decimals
            scale = max(math.hypot(R[0, 0], R[1, 0]), 1e-6)
            tol = math.degrees(2 * eps / scale) + 0.005 + 1e-9
            if abs(float(V.wrap_degrees(h - v.heading))) > tol:
                msgs.append(f"{k}: C_heading {v.heading} != atan2(R10,R00) {h:.3f}")
    return "; ".join(msgs) or None


# Physically possible values of the benchmark's answers: a magnitude is never negative, a signed
# angle lies in [-180°, 180°], and no distance, speed or acceleration of a room, a street scene or
# a desktop comes near these ceilings (ReSTI v5: lengths <= 464 m, pose translations <= 42.4 km in
# Waymo's world frame, speeds <= 33.8 m/s, accelerations <= 0.42 m/s²).
VALUE_CEILING = {"length": 1.0e6, "speed": 1.0e3, "acceleration": 1.0e3}  # m, m/s, m/s²
ANGLE_LIMIT_DEG = 180.0


def range_problems(v) -> list[str]:
    """Why a parsed value is outside the physically possible range (empty when it is inside)."""
    if not v.finite():
        return []  # reported by finite_values
    out = []
    if isinstance(v, V.Scalar):
        if v.is_angle:
            if abs(v.value) > ANGLE_LIMIT_DEG:
                out.append(f"angle {v.text.strip()} outside [-180°, 180°]")
        elif v.dimension in VALUE_CEILING:
            if v.si < 0:
                out.append(f"negative {v.dimension} {v.text.strip()}")
            elif v.si > VALUE_CEILING[v.dimension]:
                out.append(f"{v.dimension} {v.text.strip()} above {VALUE_CEILING[v.dimension]:g} (SI)")
    elif isinstance(v, V.Box):
        if max(abs(x) for x in v.center) > VALUE_CEILING["length"]:
            out.append(f"box centre {v.center} farther than {VALUE_CEILING['length']:g} m")
        if max(v.lwh) > VALUE_CEILING["length"]:
            out.append(f"box edge lengths {v.lwh} above {VALUE_CEILING['length']:g} m")
        if v.heading is not None and abs(v.heading) > ANGLE_LIMIT_DEG:
            out.append(f"box heading {v.heading} outside [-180°, 180°]")
    elif isinstance(v, V.Pose):
        if max(abs(x) for x in v.t) > VALUE_CEILING["length"]:
            out.append(f"pose translation {v.t} farther than {VALUE_CEILING['length']:g} m")
    elif isinstance(v, V.Trajectory):
        for kind, x in v.segments:
            if kind == "move" and not 0.0 <= x <= VALUE_CEILING["length"]:
                out.append(f"move {x} m outside [0, {VALUE_CEILING['length']:g}] m")
            if kind == "turn" and abs(x) > ANGLE_LIMIT_DEG:
                out.append(f"turn {x}° outside [-180°, 180°]")
    return out


@row_check("value_ranges")
def _ranges(p: ParsedRow):
    msgs = [f"{k}: {m}" for k, v in sorted(p.values.items()) for m in range_problems(v)]
    if p.detail_value is not None:
        msgs += [f"Answer Detail: {m}" for m in range_problems(p.detail_value)]
    return "; ".join(msgs) or None


# ---------------------------------------------------------------------------------------------
# The answer interface's requirements (params/options.yaml; the option stage builds to them):
# separation, physical possibility given the question, formatting that marks no candidate.

def _spec(p: ParsedRow):
    """The row's option spec and the option params, or None when the row cannot be read."""
    from .spec import spec_of

    if p.iface is None:
        raise ValueError("the answer-interface checks need the interface the options were built with (parse_row iface=)")
    if p.spec_read is None:  # read once per row: several checks ask
        p.spec_read = (None, None)
        if p.record is not None and p.detail_value is not None and p.complete:
            try:
                p.spec_read = (spec_of(p.record, str(p.rid), iface=p.iface), p.iface.options)
            except InputError:
                pass
    return p.spec_read


@row_check("separation")
def _separation(p: ParsedRow):
    """No two candidates within the task's adjudication rule or the separation floors of each other."""
    from .spec import angle_gap, box_floors, box_separation, pose_floors, pose_separation, scalar_gap

    spec, params = _spec(p)
    if spec is None:
        return None
    vals = [p.values[k] for k in LETTERS]
    kind = spec.kind
    msgs = []
    if kind in ("scalar", "angle", "trajectory"):
        if kind == "trajectory":
            # like with like: the totals of two descriptions of one shape (the same moves and turn
            # directions); a straight path and a turning one are told apart by their shape
            shapes: dict = {}
            for v in vals:
                if v.segments:
                    shapes.setdefault(v.structure, []).append(v.total_distance)
            runs = [sorted(x) for x in shapes.values()]
        else:
            runs = [sorted(v.value for v in vals)]
        rel = params["separation"]["trajectory" if kind == "trajectory" else "scalar"]["min_rel_gap"] \
            if kind != "angle" else 0.0
        for xs in runs:
            for a, b in zip(xs, xs[1:]):
                need = angle_gap(spec, params) if kind == "angle" else (
                    scalar_gap(spec, params, b) if kind == "scalar" else 0.0)
                if b - a < need - 1e-9 or (rel and b - a < rel * abs(b) - 1e-12):
                    msgs.append(f"{a:g} and {b:g} closer than the floor")
        xs = runs[0]
        if kind == "angle" and len(xs) > 1 and xs[0] + 360.0 - xs[-1] < angle_gap(spec, params) - 1e-9:
            msgs.append(f"{xs[0]:g} and {xs[-1]:g} closer than the floor across ±180")
    elif kind in ("box", "pose"):
        fl = box_floors(spec, params) if kind == "box" else pose_floors(spec, params)
        sep = box_separation if kind == "box" else pose_separation
        for i in range(5):
            for j in range(i + 1, 5):
                if sep(vals[i], vals[j], fl) < 1.0 - 1e-9:
                    msgs.append(f"{LETTERS[i]} and {LETTERS[j]} within the floors {fl}")
        if kind == "pose":
            rots = [tuple(np.round(np.array(v.R, float), 9).ravel()) for v in vals]
            rep = sorted({LETTERS[i] for i in range(5) for j in range(5) if i != j and rots[i] == rots[j]})
            if rep:
                msgs.append(f"candidates {rep} print the same rotation")
    return "; ".join(msgs) or None


@row_check("plausible_given_question")
def _plausible(p: ParsedRow):
    """Every candidate physically possible given what the question states."""
    from .spec import per_source, scalar_bounds, speed_bound

    spec, params = _spec(p)
    if spec is None:
        return None
    msgs = []
    o = spec.obs
    pl = params["plausibility"]
    for k in LETTERS:
        v = p.values[k]
        if spec.kind == "scalar":
            _, hi = scalar_bounds(spec, params)
            if v.value < 0:
                msgs.append(f"{k}: negative magnitude {v.text}")
            elif v.value > hi + 1e-9:
                msgs.append(f"{k}: {v.text} beyond {hi:g}{v.unit} possible for {o.quantity} "
                            f"over {o.window_s}s" if o.window_s else f"{k}: {v.text} beyond {hi:g}{v.unit}")
        elif spec.kind == "angle":
            if not -180.0 <= v.value < 180.0:
                msgs.append(f"{k}: heading {v.text} outside [-180, 180)")
        elif spec.kind == "trajectory" and v.segments:
            _, hi = scalar_bounds(spec, params)
            if v.total_distance > hi + 1e-9:
                msgs.append(f"{k}: total {v.total_distance:g}m beyond {hi:g}m over {o.window_s}s")
        elif spec.kind == "box":
            mx = float(per_source(pl["max_size_m"], spec.source, math.inf))
            if max(v.lwh) > mx:
                msgs.append(f"{k}: edge {max(v.lwh):g}m beyond {mx:g}m")
            dmin = float(per_source(pl["min_depth_m"], spec.source, 0.0))
            dmax = float(per_source(pl["max_depth_m"], spec.source, math.inf))
            if v.center[2] > 0 and not dmin <= v.center[2] <= dmax:
                msgs.append(f"{k}: depth {v.center[2]:g}m outside [{dmin:g}, {dmax:g}]")
        elif spec.kind == "pose" and o.premise is not None and o.window_s:
            vmax = speed_bound(params, spec.source, o.subject_class)
            d = float(np.linalg.norm(np.array(v.t) - o.premise[:3, 3]))
            if d / o.window_s > vmax + 1e-9:
                msgs.append(f"{k}: {d:.2f}m from the premise in {o.window_s:g}s (> {vmax:g} m/s)")
    return "; ".join(msgs) or None


_NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def _skeleton(text: str) -> str:
    return _NUMBER.sub("#", text)


@row_check("format_consistency")
def _format(p: ParsedRow):
    """No candidate marked by its printing: one layout (key order, spacing, units), the answer's
    printed decimals, and every candidate exactly what the formatter prints for its own value."""
    spec, _ = _spec(p)
    if spec is None or spec.kind in ("label", "trajectory"):
        return None
    texts = [p.candidates[k] for k in LETTERS]
    msgs = []
    if len({_skeleton(t) for t in texts}) > 1:
        msgs.append("candidates differ in layout (keys, spacing, units or phrase)")
    for k in LETTERS:
        v = p.values[k]
        t = p.candidates[k]
        if isinstance(v, V.Scalar):
            want = (V.format_angle(v.value, spec.decimals) if v.is_angle
                    else V.format_scalar(v.value, v.unit, spec.decimals))
            if t != want:
                msgs.append(f"{k}: {t!r} is not printed like the answer ({want!r})")
        elif isinstance(v, V.Pose):
            want = V.format_pose(v.matrix, spec.decimals, compact=spec.value.compact)
            if t != want:
                msgs.append(f"{k}: pose not printed like the answer")
        elif isinstance(v, V.Box) and v.R is not None:
            want = V.format_box(v.center, v.lwh, v.R)
            R = np.array(v.R)
            # the printed heading is atan2 of the exact rotation: within what its printed entries allow
            scale = max(math.hypot(R[0, 0], R[1, 0]), 1e-9)
            tol = math.degrees(2 * 0.5e-6 / scale) + 0.01
            off = abs(float(V.wrap_degrees((v.heading or 0.0) - V.box_heading(R))))
            obj = json.loads(want)
            obj["C_heading"] = v.heading  # compared on its own, above: the rest must print exactly
            same = json.dumps(obj, separators=(",", ":"), sort_keys=True) == t
            if not same or (off > tol and t != p.detail):
                msgs.append(f"{k}: box not printed like the answer")
    return "; ".join(msgs) or None
