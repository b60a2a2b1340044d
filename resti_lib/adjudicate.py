"""Adjudication: retained / corrected / re-contracted / excluded, with the comparison rule stated.

* **retained** — the legacy value and the source value are the same quantity under comparable
  conventions and agree within the comparison rule;
* **corrected** — same quantity, the legacy value is wrong (beyond the rule);
* **re-contracted** — the value is derived under an explicit convention because the legacy one was
  invalid, unstated or incomparable (e.g. heading on the wrong plane);
* **excluded** — no uniquely scoreable answer (reason codes + evidence).

The comparison rule (:func:`same_quantity_agrees`): two values agree when they differ by at most
half a unit in the last printed place of the coarser one plus ``abs_tol`` and ``rel_tol·|v|``
(task params). Structured values compare field by field.

This module also detects the answer-layer defects of a legacy row (key–detail mismatch, exact and
numeric duplicate candidates, pose distractors that reuse the answer's rotation, the ±7.5°/±15°
grid), from the row alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import values as V
from .errors import InputError

VERDICTS = ("retained", "corrected", "re-contracted", "excluded")


@dataclass(frozen=True)
class Rule:
    """Comparison rule: ``abs_tol`` in the value's SI unit (or degrees), ``rel_tol`` relative."""

    abs_tol: float = 0.0
    rel_tol: float = 0.0

    def describe(self) -> str:
        return (f"agree within half a unit of the coarser printed place + {self.abs_tol:g} "
                f"+ {self.rel_tol:g}·|value|")


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


def answer_layer_defects(row: dict) -> tuple[list[str], dict]:
    """Answer-layer defects of one legacy row and the evidence (no source data needed)."""
    cands = row.get("Candidates") if isinstance(row.get("Candidates"), dict) else {}
    defects, ev = [], {}
    parsed = {}
    for k, s in cands.items():
        try:
            parsed[k] = V.parse(s)
        except InputError:
            pass
    detail = None
    try:
        detail = V.parse(row.get("Answer Detail"))
    except InputError:
        pass
    keyed = cands.get(row.get("Answer"))
    kv = parsed.get(row.get("Answer"))
    if keyed is not None and keyed != row.get("Answer Detail"):
        if kv is None or detail is None or not V.agree(kv, detail):
            defects.append("key_detail_mismatch")
            ev["keyed"], ev["detail"] = keyed, row.get("Answer Detail")
    strs = [" ".join(str(s).split()) for s in cands.values()]
    if len(set(strs)) < len(strs):
        defects.append("duplicate_options_exact")
    keys = {}
    for k, v in parsed.items():
        keys.setdefault(v.key(), set()).add(" ".join(cands[k].split()))
    if any(len(texts) > 1 for texts in keys.values()):
        defects.append("duplicate_options_numeric")
    if parsed and all(isinstance(v, V.Pose) for v in parsed.values()) and isinstance(detail, V.Pose):
        # distractors (options that are not the detail's value) reusing the detail's rotation
        same = [k for k, v in parsed.items() if v.key() != detail.key() and np.allclose(v.R, detail.R)]
        if same:
            defects.append("pose_identical_rotations")
            ev["identical_rotation_letters"] = sorted(same)
    if detail is not None and isinstance(detail, V.Scalar) and detail.is_angle and len(parsed) == 5:
        offs = sorted(round(float(V.wrap_degrees(v.value - detail.value)), 1) for v in parsed.values())
        if np.allclose(offs, [-15.0, -7.5, 0.0, 7.5, 15.0], atol=0.11):
            defects.append("orientation_symmetric_grid")
    return defects, ev


def group_shortcuts(rows: list[dict], *, min_rows: int = 5, share: float = 0.9) -> dict[int, list[str]]:
    """Group-level shortcut: in a (task, source) group where the detail is the smallest candidate in
    at least ``share`` of the rows, every such row carries ``orientation_smallest_correct`` (for
    Orientation) — a property of the construction, not of one row. Returns row index -> defects."""
    out: dict[int, list[str]] = {}
    groups: dict[tuple, list[int]] = {}
    for i, r in enumerate(rows):
        groups.setdefault((r.get("Task"), r.get("Source")), []).append(i)
    for (task, _source), idx in groups.items():
        if task != "Ego-Centric Orientation" or len(idx) < min_rows:
            continue
        smallest = []
        for i in idx:
            r = rows[i]
            try:
                vals = {k: V.parse(s).value for k, s in r["Candidates"].items()}
                d = V.parse(r["Answer Detail"]).value
            except (InputError, AttributeError, KeyError):
                continue
            if d <= min(vals.values()) + 1e-9:
                smallest.append(i)
        if len(smallest) >= share * len(idx):
            for i in smallest:
                out.setdefault(i, []).append("orientation_smallest_correct")
    return out
