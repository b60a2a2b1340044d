"""Shared steps of the scalar tasks: answer units, the legacy tie-break, tables and figures.

The comparison rule (stated in every outcome's evidence): the legacy Answer Detail and the source
value agree when ``|legacy - source| <= half a unit in the legacy's last printed place + abs_tol +
rel_tol * |source|`` (SI units; :func:`resti_lib.adjudicate.compare_scalar`). ``abs_tol`` and
``rel_tol`` come from the task params (``rule``), optionally per source; they absorb the
difference between interpolating the source at the asked time and the nearest-frame value a legacy
construction may have used, and are far below the size of a genuine value error.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .. import values as V
from ..adjudicate import Rule, agrees_scalar, rule_for
from ..sources.referents import noun_phrase
from .base import Case, Outcome

__all__ = ["rule_for", "scatter_by_source", "subject_phrase", "tie_break_by_legacy", "to_unit",
           "unit_for", "value_table", "verdict_counts"]


def unit_for(params: dict, source: str) -> str:
    """The answer unit of a source (params ``units``: Omni6DPose desktop objects in centimetres)."""
    return (params.get("units") or {}).get(source, "m")


def to_unit(value_si: float, unit: str) -> float:
    return float(value_si) / V.si_factor(unit)


def subject_phrase(subj, desc: str | None) -> str:
    """The subject of a motion question: ``"the camera"`` or ``"the <object> (its 3D box centre)"``."""
    if subj.kind == "camera":
        return "the camera"
    return f"{noun_phrase(desc)} (its 3D box centre)"


def set_rule(case: Case, rule: Rule) -> Rule:
    """Record the comparison rule of a row (evidence of the option spec) and return it."""
    case.rule = rule.to_dict()
    return rule


def tie_break_by_legacy(ids: list[str], values_si: list[float], legacy: V.Value | None, unit: str, rule: Rule, *,
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
    agree = [k for k, v in enumerate(values_si) if agrees_scalar(legacy, v, unit, rule)]
    ev.update({"tie_break": "the legacy value agrees with exactly one candidate" if len(agree) == 1 else
               f"the legacy value agrees with {len(agree)} candidates", "n_agreeing": len(agree)})
    if len(agree) > 1:
        printed = {V.format_scalar(to_unit(values_si[k], unit), unit, decimals) for k in agree}
        if len(printed) == 1:
            ev["tie_break"] += f"; they all print {printed.pop()}: the answer is unique, the instance is not"
            return agree[0], ev
    return (agree[0] if len(agree) == 1 else None), ev


def tie_break_enabled(params: dict, source: str) -> bool:
    """Params ``legacy_tie_break`` (the task's params file): one flag or a per-source mapping."""
    tb = params["legacy_tie_break"]
    return bool(tb.get(source, False) if isinstance(tb, dict) else tb)


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
    :func:`resti_lib.io.figures.scatter_panels` (one legend below the panels, no overlapping titles).
    """
    from ..io.figures import scatter_panels

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
