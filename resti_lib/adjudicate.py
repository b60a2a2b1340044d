"""Adjudication: retained / corrected / re-contracted / excluded, with the comparison rule stated.

* **retained** — the legacy value and the source value are the same quantity under comparable
  conventions and agree within the comparison rule;
* **corrected** — same quantity, the legacy value is wrong (beyond the rule);
* **re-contracted** — the value is derived under an explicit convention because the legacy one was
  invalid, unstated or incomparable (e.g. heading on the wrong plane);
* **excluded** — no uniquely scoreable answer (reason codes + evidence).

The comparison rule (:func:`same_quantity_agrees`): two values agree when they differ by at most
half a unit in the last printed place of the coarser one plus ``abs_tol`` and ``rel_tol·|v|``
(task params). Structured values compare field by field. :func:`read_legacy` parses a legacy
Answer Detail once (an unreadable one is *not comparable*), :func:`compare_scalar` compares it with
a source value, :class:`Diagnosis` carries a task's verdict ingredients.

The answer-layer defects of a legacy row (key–detail mismatch, exact and numeric duplicate
candidates, pose distractors that reuse the answer's rotation, the ±7.5°/±15° grid, the smallest
candidate being correct across a task and source) are one registry of checks
(:data:`ANSWER_CHECKS`, :func:`answer_check`), each named by a code of :mod:`resti_lib.defects`
(which gives its layer and category). :func:`answer_layer_defects` runs the row checks on one row,
:func:`group_shortcuts` the group checks on the rows of a task; both read the row alone, no
source data.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from . import values as V
from .defects import DEFECTS
from .errors import InputError


@dataclass(frozen=True)
class Rule:
    """Comparison rule: ``abs_tol`` in the value's SI unit (or degrees), ``rel_tol`` relative."""

    abs_tol: float = 0.0
    rel_tol: float = 0.0

    def tolerance(self, value: float, ulp: float) -> float:
        """How far two values near ``value`` may differ and still agree: half a printed unit ``ulp``
        (both in the same unit) + ``abs_tol`` + ``rel_tol``·|value|."""
        return 0.5 * ulp + self.abs_tol + self.rel_tol * abs(value)

    def describe(self) -> str:
        return (f"agree within half a unit of the coarser printed place + {self.abs_tol:g} "
                f"+ {self.rel_tol:g}·|value|")

    def to_dict(self) -> dict:
        return {"abs_tol": self.abs_tol, "rel_tol": self.rel_tol, "text": self.describe()}


def rule_for(params: dict, source: str, key: str = "rule") -> Rule:
    """The comparison rule of a source: params ``key`` = ``{abs_tol, rel_tol}``, per-source dicts of
    those, or one number (an absolute tolerance)."""
    r = params.get(key)
    if isinstance(r, (int, float)) and not isinstance(r, bool):
        return Rule(abs_tol=float(r))
    r = r or {}
    if source in r and isinstance(r[source], dict):
        r = r[source]
    return Rule(abs_tol=float(r.get("abs_tol", 0.0)), rel_tol=float(r.get("rel_tol", 0.0)))


def _ulp_si(v: V.Scalar) -> float:
    return 0.5 * 10.0 ** -v.decimals * v.si_per_unit


def same_quantity_agrees(legacy: V.Value, new: V.Value, rule: Rule) -> bool:
    """Do two values of the same quantity agree under ``rule``?"""
    if isinstance(legacy, V.Scalar) and isinstance(new, V.Scalar):
        if legacy.dimension != new.dimension:
            return False
        tol = max(_ulp_si(legacy), _ulp_si(new)) + rule.abs_tol + rule.rel_tol * abs(new.si)
        if legacy.is_angle:
            return abs(float(V.wrap_degrees(legacy.value - new.value))) <= tol + 1e-9
        return abs(legacy.si - new.si) <= tol + 1e-12
    return V.agree(legacy, new, abs_tol=rule.abs_tol, rel=rule.rel_tol)


def verdict_for(comparable: bool, agrees: bool | None) -> str:
    if not comparable:
        return "re-contracted"
    return "retained" if agrees else "corrected"


# ------------------------------------------------------------------------------ legacy values

_KIND_NAMES = {V.Scalar: "scalar", V.Pose: "pose", V.Box: "box", V.Trajectory: "trajectory", V.Label: "label"}


def read_legacy(row: dict, kind: type | tuple | None = None) -> tuple[V.Value | None, str | None]:
    """The legacy Answer Detail parsed once: ``(value, None)``, or ``(None, problem)`` when it is
    unreadable or not of ``kind`` (a :mod:`resti_lib.values` class or a tuple of them)."""
    try:
        v = V.parse(row.get("Answer Detail"), row=row.get("Legacy Row Key"), field="Answer Detail")
    except InputError as e:
        return None, e.message
    if kind is not None and not isinstance(v, kind):
        kinds = kind if isinstance(kind, tuple) else (kind,)
        want = " or ".join(_KIND_NAMES.get(k, k.__name__) for k in kinds)
        return None, f"Answer Detail is a {v.kind}, not a {want}"
    return v, None


def compare_scalar(legacy: V.Value | None, value_si: float, unit: str, rule: Rule) -> dict:
    """Compare a legacy value with a source value (SI) under ``rule``.

    Returns ``{"comparable", "agrees", "legacy_si", "source_si", "residual_si", "rule", "legacy_text"}``;
    ``comparable`` is false when the legacy value is missing or of another dimension.
    """
    out = {"rule": rule.describe(), "source_si": float(value_si),
           "legacy_text": legacy.text if legacy is not None else None}
    if legacy is None:
        out.update({"comparable": False, "agrees": None})
        return out
    new = V.parse(V.format_scalar(value_si / V.si_factor(unit), unit, 9))
    if not isinstance(legacy, V.Scalar) or legacy.dimension != new.dimension:
        out.update({"comparable": False, "agrees": None, "problem": f"legacy value is not a {new.dimension}"})
        return out
    agrees = same_quantity_agrees(legacy, new, rule)
    out.update({"comparable": True, "agrees": bool(agrees), "legacy_si": legacy.si,
                "residual_si": float(legacy.si - value_si)})
    return out


def agrees_scalar(legacy: V.Value | None, value_si: float, unit: str, rule: Rule) -> bool:
    """True when ``legacy`` is comparable and agrees with ``value_si``."""
    c = compare_scalar(legacy, value_si, unit, rule)
    return bool(c["comparable"] and c["agrees"])


@dataclass
class Diagnosis:
    """What a task's hypotheses concluded about one legacy value.

    ``comparable``/``agrees`` give the verdict (:func:`verdict_for`) unless ``verdict`` overrides it;
    ``defects`` are the source-layer codes found (``value_mismatch`` included when the task does not
    explain a corrected value otherwise); ``evidence`` goes into the row's evidence.
    """

    comparable: bool
    agrees: bool | None = None
    defects: list = field(default_factory=list)
    evidence: dict = field(default_factory=dict)
    verdict: str | None = None

    @property
    def final_verdict(self) -> str:
        return self.verdict or verdict_for(self.comparable, self.agrees)

    @classmethod
    def from_comparison(cls, cmp: dict, **evidence) -> Diagnosis:
        """The common case: corrected values carry ``value_mismatch``; the comparison is evidence."""
        d = cls(bool(cmp["comparable"]), cmp["agrees"], [], {"comparison": cmp, **evidence})
        if d.final_verdict == "corrected":
            d.defects.append("value_mismatch")
        return d


# ------------------------------------------------------------------------- answer-layer checks

@dataclass
class LegacyOptions:
    """A legacy row's five options parsed once (letters whose text is unreadable are left out)."""

    row: dict
    candidates: dict
    parsed: dict
    detail: V.Value | None

    @classmethod
    def of(cls, row: dict) -> LegacyOptions:
        cands = row.get("Candidates") if isinstance(row.get("Candidates"), dict) else {}
        parsed = {}
        for k, s in cands.items():
            try:
                parsed[k] = V.parse(s)
            except InputError:
                pass
        try:
            detail = V.parse(row.get("Answer Detail"))
        except InputError:
            detail = None
        return cls(row, cands, parsed, detail)


@dataclass(frozen=True)
class AnswerCheck:
    """A registered answer-layer check: ``fn`` returns evidence (a dict, possibly empty) when the
    row has the defect, None otherwise (group checks: row index -> evidence for a list of rows)."""

    code: str
    fn: Callable
    scope: str  # "row" | "group"
    description: str = ""

    @property
    def layer(self) -> str:
        return DEFECTS[self.code].layer

    @property
    def category(self) -> str:
        return DEFECTS[self.code].category


ANSWER_CHECKS: dict[str, AnswerCheck] = {}


def answer_check(code: str, *, scope: str = "row") -> Callable[[Callable], Callable]:
    """Register an answer-layer check under a defect code of :mod:`resti_lib.defects`."""
    if code not in DEFECTS or DEFECTS[code].layer != "answer":
        raise ValueError(f"{code!r} is not an answer-layer defect code")

    def deco(fn: Callable) -> Callable:
        ANSWER_CHECKS[code] = AnswerCheck(code, fn, scope, (fn.__doc__ or "").strip())
        return fn

    return deco


@answer_check("key_detail_mismatch")
def _key_detail(o: LegacyOptions) -> dict | None:
    """The keyed candidate disagrees with the Answer Detail (text differs and values disagree)."""
    keyed = o.candidates.get(o.row.get("Answer"))
    kv = o.parsed.get(o.row.get("Answer"))
    if keyed is not None and keyed != o.row.get("Answer Detail") and (
            kv is None or o.detail is None or not V.agree(kv, o.detail)):
        return {"keyed": keyed, "detail": o.row.get("Answer Detail")}
    return None


@answer_check("duplicate_options_exact")
def _duplicate_exact(o: LegacyOptions) -> dict | None:
    """Two candidates are the same string (whitespace runs collapsed)."""
    strs = [" ".join(str(s).split()) for s in o.candidates.values()]
    return {} if len(set(strs)) < len(strs) else None


@answer_check("duplicate_options_numeric")
def _duplicate_numeric(o: LegacyOptions) -> dict | None:
    """Two candidates differ in text but encode the same value."""
    keys: dict = {}
    for k, v in o.parsed.items():
        keys.setdefault(v.key(), set()).add(" ".join(o.candidates[k].split()))
    return {} if any(len(texts) > 1 for texts in keys.values()) else None


@answer_check("pose_identical_rotations")
def _pose_rotations(o: LegacyOptions) -> dict | None:
    """Pose distractors (options that are not the detail's value) reuse the detail's rotation."""
    if o.parsed and all(isinstance(v, V.Pose) for v in o.parsed.values()) and isinstance(o.detail, V.Pose):
        same = [k for k, v in o.parsed.items() if v.key() != o.detail.key() and np.allclose(v.R, o.detail.R)]
        if same:
            return {"identical_rotation_letters": sorted(same)}
    return None


@answer_check("orientation_symmetric_grid")
def _symmetric_grid(o: LegacyOptions) -> dict | None:
    """Distractors at -15, -7.5, +7.5 and +15 degrees around the answer."""
    d = o.detail
    if d is not None and isinstance(d, V.Scalar) and d.is_angle and len(o.parsed) == 5:
        offs = sorted(round(float(V.wrap_degrees(v.value - d.value)), 1) for v in o.parsed.values())
        if np.allclose(offs, [-15.0, -7.5, 0.0, 7.5, 15.0], atol=0.11):
            return {}
    return None


@answer_check("orientation_smallest_correct", scope="group")
def _smallest_correct(rows: list[dict], *, min_rows: int = 5, share: float = 0.9) -> dict[int, dict]:
    """In a (task, source) group of angle answers (heading changes) where the detail is the
    smallest candidate in at least ``share`` of at least ``min_rows`` rows, every such row carries
    the shortcut: a property of the construction, not of one row. Keyed by the answer kind (an
    angle), not by a task."""
    out: dict[int, dict] = {}
    groups: dict[tuple, list[tuple[int, float, dict]]] = {}
    for i, r in enumerate(rows):
        try:
            d = V.parse(r["Answer Detail"])
            vals = {k: V.parse(s) for k, s in r["Candidates"].items()}
        except (InputError, AttributeError, KeyError, TypeError):
            continue
        if not (isinstance(d, V.Scalar) and d.is_angle and vals
                and all(isinstance(v, V.Scalar) and v.is_angle for v in vals.values())):
            continue
        groups.setdefault((r.get("Task"), r.get("Source")), []).append((i, d.value, vals))
    for members in groups.values():
        if len(members) < min_rows:
            continue
        smallest = [i for i, d, vals in members if d <= min(v.value for v in vals.values()) + 1e-9]
        if len(smallest) >= share * len(members):
            for i in smallest:
                out[i] = {}
    return out


def answer_layer_defects(row: dict) -> tuple[list[str], dict]:
    """The row-scope answer-layer defects of one legacy row (registry order) and their evidence."""
    o = LegacyOptions.of(row)
    codes, ev = [], {}
    for code, chk in ANSWER_CHECKS.items():
        if chk.scope != "row":
            continue
        hit = chk.fn(o)
        if hit is not None:
            codes.append(code)
            ev.update(hit)
    return codes, ev


def group_shortcuts(rows: list[dict]) -> dict[int, list[str]]:
    """The group-scope answer-layer defects of a list of rows: row position -> codes."""
    out: dict[int, list[str]] = {}
    for code, chk in ANSWER_CHECKS.items():
        if chk.scope != "group":
            continue
        for i in sorted(chk.fn(rows)):
            out.setdefault(i, []).append(code)
    return out
