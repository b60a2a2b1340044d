"""Speed & Acceleration: a named rate statistic, and acceleration with its estimator stated.

Rate statistics (the rewritten question names one):

``average_velocity``
    Magnitude of average velocity = endpoint displacement / Δt
    (:func:`resti_lib.geometry.trajectory.average_velocity`).
``average_speed``
    Average speed = path length / Δt (:func:`resti_lib.geometry.trajectory.average_speed`).

A legacy question that says "average speed" without naming path or displacement leaves the
statistic open (contract part ``statistic`` missing). Both values are computed; the legacy value
is compared with each under the task's comparison rule. Per source, the statistic of the legacy
construction is the one matched by the majority of rows that match exactly one of the two, and
every row of the source is read under it (a lone row agreeing with the other statistic is a chance
agreement, noted in its evidence). Only in a *mixed* source (the minority has at least
``mixed_share`` of those rows) does each row keep the statistic it matches.
When that statistic is displacement / Δt (decided by the row itself or by a majority, not by the
``default_statistic`` fallback), the row carries ``statistic_unnamed`` and
``speed_is_displacement_over_time`` (the "average speed" is the magnitude of average velocity).
The clarified question names the statistic; the row is *retained* when the legacy value agrees
under it and *corrected* (``value_mismatch``) otherwise.

``acceleration``
    Magnitude of the mean acceleration ``|v(t1) - v(t0)| / (t1 - t0)`` (measure operator
    ``acceleration``). Velocity estimator (stated in the question and the evidence): for Waymo
    objects the LiDAR box's annotated velocity (vehicle frame, rotated into the world by the frame's
    vehicle pose, linear between frames); otherwise central differences of the positions.

The per-source decision is :func:`resti_lib.tasks.motion.reading_per_source`, shared with the
"how far has X traveled" rows of Displacement & Path Length.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .. import values as V
from ..adjudicate import Diagnosis, agrees_scalar, compare_scalar
from ..errors import ContractError
from ..measure.motion import EST_STORED
from ..sources.referents import SceneView
from . import register_task
from .base import AnswerSpec, Case, Exclude
from .motion import (
    MotionTask,
    ambiguous_subject,
    camera_subject,
    reading_per_source,
    row_reading,
    source_frames,
    waymo_object_subject,
)
from .scalar_audit import rule_for, set_rule, subject_phrase, value_table

TASK = "Speed & Acceleration"
STATISTICS = {
    "average_velocity": "magnitude of average velocity = endpoint displacement / elapsed time",
    "average_speed": "average speed = path length / elapsed time",
}
READINGS = {"average_velocity": "velocity", "average_speed": "speed"}
UNITS = {"average_velocity": "m/s", "average_speed": "m/s", "acceleration": "m/s²"}


def operator_of(question: str) -> tuple[str, bool]:
    """The operator a question names, and whether it leaves the statistic open ("average speed"
    without path or displacement)."""
    ql = " ".join(str(question).lower().split())
    if "accelerat" in ql:
        return "acceleration", False
    op = "average_speed" if "speed" in ql else "average_velocity"
    return op, "average speed" in ql and not any(w in ql for w in ("path", "displacement", "endpoint"))


def question_text(op: str, subject: str, t0: float, t1: float, estimator: str | None = None) -> str:
    span = f"between t={V.format_seconds(t0)} s and t={V.format_seconds(t1)} s"
    if op == "average_velocity":
        return (f"What is the magnitude of the average velocity of {subject} {span}, computed as straight-line "
                f"endpoint displacement divided by elapsed time? (unit: m/s)")
    if op == "average_speed":
        return (f"What is the average speed of {subject} {span}, computed as the total distance traveled along "
                f"its path divided by elapsed time? (unit: m/s)")
    how = ("its annotated 3D-box velocities" if estimator == EST_STORED else
           "central differences of its positions")
    return (f"What is the magnitude of the mean acceleration of {subject} {span}, computed as the change of its "
            f"velocity divided by elapsed time with velocities from {how}? (unit: m/s²)")


@register_task
class Speed(MotionTask):
    name = TASK
    params_name = "speed"
    notebook = "06_speed"
    order = 5
    answer_kind = "scalar"
    follows = ("Displacement & Path Length",)
    quantity = "speed"
    figures = {
        "statistics": ("Speed & Acceleration: the legacy 'speed' against displacement/Δt (circles) and path/Δt "
                       "(triangles), per source: which statistic the legacy values are."),
        "legacy_vs_source": ("Speed & Acceleration: legacy against source value under the clarified contract."),
    }
    legacy_kind = V.Scalar
    operators = ("average_velocity", "average_speed", "acceleration")

    operator_of = staticmethod(operator_of)


    def quantity_of(self, question: str) -> str:
        return "acceleration" if operator_of(question)[0] == "acceleration" else "speed"

    def reconstruct(self, case: Case) -> None:
        c, params, r = case.contract, case.params, case.row
        if len(c.times) != 2:
            raise Exclude("unsupported_question", question=r.get("Question"))
        t0, t1 = float(c.times[0]), float(c.times[1])
        if t1 <= t0:
            case.outcome.defects.append("zero_length_interval")
            raise Exclude("zero_length_interval", t=[t0, t1], kind=c.operator)
        view = SceneView.open(case.ctx, str(r["Video"]), params)
        rule = set_rule(case, rule_for(params, case.source))
        ops = ("acceleration",) if c.operator == "acceleration" else ("average_velocity", "average_speed")

        def value_fn(entity: dict) -> float:
            return case.measure(c.operator, entity, [t0, t1]).value

        ent = c.entity
        try:
            if ent.get("kind") == "camera":
                subj = camera_subject(view)
            elif ent.get("kind") == "ambiguous":
                subj = ambiguous_subject(view, ent.get("description"), t0, t1, value_fn, params)
            elif view.source == "Waymo":
                subj = waymo_object_subject(view, ent.get("description"), t0, t1, value_fn, case.legacy,
                                            UNITS[c.operator], rule, params, presupposes_motion=True)
            else:
                raise Exclude("unsupported_question", note=f"{view.source} objects are static annotations",
                              phrase=ent.get("description"))
            measured = {op: case.measure(op, subj.entity, [t0, t1]) for op in ops}
        except ContractError as e:
            raise Exclude("invalid_pose_at_time", t=[t0, t1], error=str(e)) from None
        case.state.update(subj=subj, measured=measured, t0=t0, t1=t1)
        case.observables.update(subject=subject_phrase(subj, ent.get("description")),
                                subject_class=subj.entity.get("label", subj.kind))

    def diagnose_all(self, cases: list[Case]) -> None:
        rates = [k for k in cases if k.contract.operator != "acceleration"]
        match = {id(k): {op: agrees_scalar(k.legacy, k.state["measured"][op].value, "m/s", rule_for(k.params, k.source))
                         for op in STATISTICS} for k in rates}
        open_rows = [k for k in rates if "statistic" in k.contract.missing]
        groups = reading_per_source([(k.source, match[id(k)]) for k in open_rows], READINGS,
                                    str(cases[0].params["default_statistic"]) if cases else "average_velocity",
                                    float(cases[0].params["mixed_share"]) if cases else 0.0)
        for k in cases:
            if k.contract.operator != "acceleration":
                self._rate(k, match[id(k)], groups)
            else:
                self._acceleration(k)

    def _rate(self, k: Case, match: dict, groups: dict) -> None:
        defects, extra = [], {}
        if "statistic" in k.contract.missing:
            g = groups[k.source]
            op, determined, rev = row_reading(match, g)
            if op == "average_velocity" and determined:
                defects = ["statistic_unnamed", "speed_is_displacement_over_time"]
            extra = {"construction_statistic": {"source": k.source, **g}, **rev}
        else:
            op = k.contract.operator
        mv, ms = k.state["measured"]["average_velocity"], k.state["measured"]["average_speed"]
        m = k.state["measured"][op]
        ev_v = mv.evidence
        value = m.value
        cmp = compare_scalar(k.legacy, value, "m/s", rule_for(k.params, k.source))
        d = Diagnosis.from_comparison(
            cmp, operator=op, value_si=value, statistic=STATISTICS[op],
            hypotheses={"displacement_over_time": mv.value, "path_over_time": ms.value, "matches": match,
                        "displacement_m": ev_v["displacement_m"], "path_length_m": ms.evidence["path_length_m"],
                        "dt_s": ev_v["dt_s"]},
            **({"shortened_to": ev_v["shortened_to"]} if ev_v.get("shortened_to") else {}),
            **k.state["subj"].evidence, **extra)
        d.defects[:0] = defects
        k.diagnosis = d
        self._settle(k, op, value, float(ev_v.get("t1_used", k.state["t1"])), None)

    def _acceleration(self, k: Case) -> None:
        m = k.state["measured"]["acceleration"]
        value, aev = m.value, m.evidence
        cmp = compare_scalar(k.legacy, value, "m/s²", rule_for(k.params, k.source))
        k.diagnosis = Diagnosis.from_comparison(cmp, operator="acceleration", value_si=value, acceleration=aev,
                                                **k.state["subj"].evidence)
        # an interval ending in invalid poses was shortened: the question states the interval measured
        self._settle(k, "acceleration", value, float(aev.get("t1_used", k.state["t1"])), aev.get("estimator"))

    def _settle(self, k: Case, op: str, value: float, t1: float, estimator: str | None) -> None:
        c, subj, t0 = k.contract, k.state["subj"], k.state["t0"]
        c.entity = {**c.entity, **subj.entity}
        c.operator, c.times, c.unit, c.unit_stated, c.frame = op, [t0, t1], UNITS[op], True, subj.track.name
        c.params["statistic"] = STATISTICS.get(op, estimator)
        k.state["estimator"] = estimator
        k.value = value
        k.provenance(files=subj.files, frames=source_frames(subj.track, t0, t1),
                     chain=subj.evidence.get("transform_chain", ""))
        k.outcome.time_start, k.outcome.time_end = t0, t1
        k.answer = AnswerSpec("scalar", value, UNITS[op], int(k.params["decimals"]))

    def rewrite(self, case: Case) -> str:
        c = case.contract
        return question_text(c.operator, subject_phrase(case.state["subj"], c.entity.get("description")),
                             c.times[0], c.times[1], case.state.get("estimator"))


# --------------------------------------------------------------------------------- notebook aids


def statistic_split(run) -> pd.DataFrame:
    """Per source, the legacy "average speed" rows: how many stay valid under the clarified statistic
    (retained) and how many change (corrected), with the construction statistic (the report's 78 / 37)."""
    recs = {}
    for o in run.outcomes:
        g = o.evidence.get("construction_statistic")
        if not g:
            continue
        d = recs.setdefault(o.source, {"source": o.source, "average_speed_rows": 0, "valid_under_clarified": 0,
                                       "changed": 0, "construction_statistic": g["statistic"],
                                       "velocity_only": g["n_velocity_only"], "speed_only": g["n_speed_only"],
                                       "both": g["n_both"], "neither": g["n_neither"]})
        d["average_speed_rows"] += 1
        d["valid_under_clarified"] += o.verdict == "retained"
        d["changed"] += o.verdict == "corrected"
    return pd.DataFrame(list(recs.values()))


def diagnosis(run) -> pd.DataFrame:
    """Per row: legacy value, displacement/Δt, path/Δt, the chosen statistic, verdict and defects."""
    df = value_table(run.outcomes)
    hyp = [o.evidence.get("hypotheses") or {} for o in run.outcomes]
    df["displacement_over_time"] = [h.get("displacement_over_time", np.nan) for h in hyp]
    df["path_over_time"] = [h.get("path_over_time", np.nan) for h in hyp]
    return df


def plot_statistics(run, path: str | Path) -> Path:
    """Legacy "speed" against displacement/Δt and against path/Δt, per source (camera rate rows)."""
    from .scalar_audit import scatter_by_source

    df = diagnosis(run)
    df = df[df["verdict"].ne("excluded") & df["displacement_over_time"].notna()]
    return scatter_by_source(df, path, ylabel="legacy value (m/s)",
                             series=[("displacement_over_time", "displacement / Δt"),
                                     ("path_over_time", "path / Δt")],
                             title="Speed: legacy value vs displacement/Δt and path/Δt")


def plot_legacy_vs_source(run, path: str | Path) -> Path:
    """Legacy against reconstructed values under the clarified contract (accepted rows)."""
    from .scalar_audit import scatter_by_source

    df = value_table(run.outcomes)
    df = df[df["verdict"] != "excluded"]
    return scatter_by_source(df, path, xlabel="source value (SI)", ylabel="legacy value (SI)",
                             title="Speed & Acceleration: legacy vs source")
