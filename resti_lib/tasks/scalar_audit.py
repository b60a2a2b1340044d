"""Shared steps of the scalar tasks: outcomes, comparison rule, question-layer defects, tables, figures.

The comparison rule (stated in every outcome's evidence): the legacy Answer Detail and the source
value agree when ``|legacy - source| <= half a unit in the legacy's last printed place + abs_tol +
rel_tol * |source|`` (SI units; :func:`resti_lib.adjudicate.same_quantity_agrees`). ``abs_tol`` and
``rel_tol`` come from the task params (``rule``), optionally per source; they absorb the
difference between interpolating the source at the asked time and the nearest-frame value a legacy
construction may have used, and are far below the size of a genuine value error.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .. import values as V
from ..adjudicate import Rule, same_quantity_agrees
from ..errors import InputError
from .base import Outcome

#: Default answer unit per source (Omni6DPose desktop objects in centimetres, as ReSTI v5).
DEFAULT_UNITS = {"ScanNet": "m", "Waymo": "m", "Omni6DPose": "cm"}
_SI = {"m": 1.0, "cm": 0.01, "mm": 0.001, "m/s": 1.0, "m/s²": 1.0}


class Excluded(Exception):
    """Raised inside a task's row audit: the row is excluded with ``reason`` (+ ``defect``) and evidence."""

    def __init__(self, reason: str, defect: str | None = None, **evidence):
        super().__init__(reason)
        self.reason, self.defect, self.evidence = reason, defect, evidence

    def apply(self, o: Outcome) -> Outcome:
        if self.defect and self.defect not in o.defects:
            o.defects.append(self.defect)
        return o.exclude(self.reason, **self.evidence)


def new_outcome(r: dict, task: str) -> Outcome:
    """An outcome for a legacy row (verdict filled in later)."""
    return Outcome(row=int(r["row"]), key=str(r["Legacy Row Key"]), task=task, source=str(r["Source"]),
                   video=str(r["Video"]), legacy_id=r.get("ID"), verdict="retained",
                   legacy_detail=None if r.get("Answer Detail") is None else str(r.get("Answer Detail")))


def rule_for(params: dict, source: str, key: str = "rule") -> Rule:
    """The comparison rule of a source: params ``rule`` = ``{abs_tol, rel_tol}`` or per-source dicts."""
    r = params.get(key) or {}
    if source in r and isinstance(r[source], dict):
        r = r[source]
    return Rule(abs_tol=float(r.get("abs_tol", 0.0)), rel_tol=float(r.get("rel_tol", 0.0)))


def unit_for(params: dict, source: str) -> str:
    units = {**DEFAULT_UNITS, **(params.get("units") or {})}
    return units[source]


def to_unit(value_si: float, unit: str) -> float:
    return float(value_si) / _SI[unit]


def the_phrase(desc: str | None) -> str:
    """``"the <description>"`` for question text: the leading article dropped, the first letter
    lower-cased unless the description opens with an acronym (``"A TV stand"`` -> ``"the TV stand"``)."""
    d = " ".join(str(desc or "object").split()).rstrip(".")
    for art in ("the ", "a ", "an "):
        if d.lower().startswith(art):
            d = d[len(art):]
            break
    return "the " + (d[0].lower() + d[1:] if d and not d[:2].isupper() else d)


def subject_phrase(subj, desc: str | None) -> str:
    """The subject of a motion question: ``"the camera"`` or ``"the <object> (its 3D box centre)"``."""
    if subj.kind == "camera":
        return "the camera"
    return f"{the_phrase(desc)} (its 3D box centre)"


def question_defects(contract: dict) -> list[str]:
    """Question-layer defect codes of the contract's missing parts (unit, subject)."""
    out = []
    if "unit" in contract.get("missing", []):
        out.append("unit_tag_missing")
    if "subject" in contract.get("missing", []):
        out.append("ambiguous_subject")
    return out


def compare(detail: object, value_si: float, unit: str, rule: Rule) -> dict:
    """Compare a legacy Answer Detail with a source value (SI) under ``rule``.

    Returns ``{"comparable", "agrees", "legacy_si", "source_si", "residual_si", "rule"}``;
    ``comparable`` is false when the detail is unreadable or of another dimension.
    """
    out = {"rule": rule.describe(), "source_si": float(value_si), "legacy_text": detail}
    try:
        legacy = V.parse(detail)
    except InputError as e:
        out.update({"comparable": False, "agrees": None, "problem": e.message})
        return out
    new = V.parse(V.format_scalar(to_unit(value_si, unit), unit, 9))
    if not isinstance(legacy, V.Scalar) or legacy.dimension != new.dimension:
        out.update({"comparable": False, "agrees": None, "problem": f"legacy value is not a {new.dimension}"})
        return out
    agrees = same_quantity_agrees(legacy, new, rule)
    out.update({"comparable": True, "agrees": bool(agrees), "legacy_si": legacy.si,
                "residual_si": float(legacy.si - value_si)})
    return out


def agrees_si(detail: object, value_si: float, unit: str, rule: Rule) -> bool:
    """True when ``detail`` is comparable and agrees with ``value_si``."""
    c = compare(detail, value_si, unit, rule)
    return bool(c["comparable"] and c["agrees"])


def tie_break_by_legacy(ids: list[str], values_si: list[float], detail: object, unit: str, rule: Rule, *,
                        enabled: bool, decimals: int = 2) -> tuple[int | None, dict]:
    """Pick one of several candidate instances by the legacy value, when enabled.

    Returns ``(index or None, evidence)``: the index of the only candidate whose value agrees with
    the legacy Answer Detail under ``rule`` (or the first of several agreeing candidates whose
    values print identically at ``decimals``: the answer is then unique although the instance is
    not); None otherwise or when the tie-break is disabled. The evidence lists every candidate's value.
    """
    ev = {"candidate_values_si": {str(i): round(float(v), 6) for i, v in zip(ids, values_si)}}
    if not enabled:
        return None, ev
    agree = [k for k, v in enumerate(values_si) if agrees_si(detail, v, unit, rule)]
    ev.update({"tie_break": "the legacy value agrees with exactly one candidate" if len(agree) == 1 else
               f"the legacy value agrees with {len(agree)} candidates", "n_agreeing": len(agree)})
    if len(agree) > 1:
        printed = {V.format_scalar(to_unit(values_si[k], unit), unit, decimals) for k in agree}
        if len(printed) == 1:
            ev["tie_break"] += f"; they all print {printed.pop()}: the answer is unique, the instance is not"
            return agree[0], ev
    return (agree[0] if len(agree) == 1 else None), ev


def value_table(outcomes: list[Outcome], *, value_key: str = "source_si") -> pd.DataFrame:
    """One line per outcome: legacy and source values (SI), residual, verdict, reasons, defects."""
    recs = []
    for o in outcomes:
        cmp_ = o.evidence.get("comparison") or {}
        recs.append({"row": o.row, "source": o.source, "video": o.video, "operator": o.contract.get("operator"),
                     "verdict": o.verdict, "reasons": ",".join(o.reasons),
                     "defects": ",".join(sorted(set(o.defects))), "legacy_si": cmp_.get("legacy_si", np.nan),
                     "source_si": cmp_.get(value_key, o.evidence.get("value_si", np.nan)),
                     "residual_si": cmp_.get("residual_si", np.nan)})
    return pd.DataFrame(recs)


def scatter_by_source(df: pd.DataFrame, path: str | Path, *, x: str = "source_si", y: str = "legacy_si",
                      xlabel: str = "source value (SI)", ylabel: str = "legacy value (SI)", title: str = "",
                      series: list[tuple[str, str]] | None = None) -> Path:
    """Legacy against reconstructed values, one panel per source, coloured by verdict (y = x dashed).

    ``series``: optional extra ``(x column, label)`` pairs plotted against ``y`` with other markers
    (e.g. the legacy speed against displacement/Δt and against path/Δt). Drawn by
    :func:`resti_lib.plots.scatter_panels` (one legend below the panels, no overlapping titles).
    """
    from ..plots import scatter_panels

    return scatter_panels(df, path, x=x, y=y, xlabel=xlabel, ylabel=ylabel, title=title, series=series)


def verdict_counts(outcomes: list[Outcome]) -> pd.DataFrame:
    """Verdict counts per (source, operator)."""
    df = pd.DataFrame([{"source": o.source, "operator": o.contract.get("operator"), "verdict": o.verdict}
                       for o in outcomes])
    if df.empty:
        return df
    t = df.pivot_table(index=["source", "operator"], columns="verdict", aggfunc="size", fill_value=0)
    t["total"] = t.sum(axis=1)
    return t.reset_index()


def attack_summary(accepted: list[dict], *, alpha: float = 0.05) -> pd.DataFrame:
    """Option-only attacks on the task's accepted rows (per source and pooled), Holm over the table."""
    from ..options.attacks import attack_table

    if not accepted:
        return pd.DataFrame()
    return attack_table(accepted, alpha=alpha)

