"""Displacement & Path Length: endpoint displacement and integrated path of a named subject.

Contract (stated in the rewritten question):

``displacement``
    ``|p(t1) - p(t0)|``, the straight-line distance between the subject's positions at the two
    asked times (measure operator ``displacement``).
``path_length``
    The trajectory length ``sum |Δp|`` over ``p(t0)``, every source sample strictly inside the
    interval and ``p(t1)`` (measure operator ``path_length``); "total distance traveled" names it.

"How far has X traveled" leaves the statistic open (contract part ``statistic`` missing): both
values are measured and the legacy value is compared with each. Per source, the reading of the
legacy construction is the one matched by the majority of such rows that match exactly one
(:func:`resti_lib.tasks.motion.reading_per_source`, as Speed does for "average speed"); every such
row of the source is read under it (a mixed source keeps each row's own match). When that reading
is the displacement (decided by the rows, not by ``default_statistic``), the row carries
``statistic_unnamed`` and ``distance_traveled_is_displacement``; the rewritten question names the
statistic either way.

Positions: the camera's optical centre (ScanNet raw scan frame, Waymo segment world frame,
Omni6DPose first-camera frame) or a Waymo object's box centre (:mod:`resti_lib.tasks.motion`).
Poses at the asked times are linearly interpolated between source samples (a time within
``time_tol`` of a sample is that sample); an interval ending in invalid poses is shortened to the
last valid pose and the question states the shortened interval. Unit: metres.

Exclusions: ``zero_length_interval`` (t0 == t1), ``ambiguous_subject`` (bare "the car" on a Waymo
video with a tracked vehicle moving in view), ``ambiguous_instance`` / ``no_source_instance`` /
``grouped_referent`` / ``not_visible_at_frame`` for object subjects, ``invalid_pose_at_time``.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from .. import values as V
from ..adjudicate import Diagnosis, agrees_scalar, compare_scalar
from ..errors import ContractError
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
from .scalar_audit import rule_for, scatter_by_source, set_rule, subject_phrase, value_table

TASK = "Displacement & Path Length"
UNIT = "m"
WORDING = {
    "displacement": "displacement (straight-line distance between its start and end positions)",
    "path_length": "trajectory length (total distance traveled along its path)",
}
READINGS = {"displacement": "displacement", "path_length": "path"}
DEFECTS_OF_DISPLACEMENT_READING = ["statistic_unnamed", "distance_traveled_is_displacement"]


def operator_of(question: str) -> tuple[str, bool]:
    """The operator a question names and whether it leaves the statistic open: "how far ...
    traveled" reads literally as the distance traveled (path) but may have been built as the
    displacement."""
    ql = " ".join(str(question).lower().split())
    if "how far" in ql and "travel" in ql:
        return "path_length", True
    if any(w in ql for w in ("total distance", "trajectory length", "path length", "distance traveled")) \
            and "displacement" not in ql:
        return "path_length", False
    return "displacement", "how far" in ql


def question_text(op: str, subject: str, t0: float, t1: float) -> str:
    return (f"What is the {WORDING[op]} of {subject} between t={V.format_seconds(t0)} s and "
            f"t={V.format_seconds(t1)} s? (unit: {UNIT})")


@register_task
class Displacement(MotionTask):
    name = TASK
    params_name = "displacement"
    notebook = "05_displacement"
    order = 4
    answer_kind = "scalar"
    follows = ("Trajectory Description",)
    quantity = "displacement"
    figures = {
        "legacy_vs_source": ("Displacement & Path Length: legacy against source value per source (accepted rows; dashed: "
                             "equal)."),
    }
    legacy_kind = V.Scalar
    operators = ("displacement", "path_length")

    operator_of = staticmethod(operator_of)


    def quantity_of(self, question: str) -> str:
        return operator_of(question)[0]

    def reconstruct(self, case: Case) -> None:
        c, params, r = case.contract, case.params, case.row
        op = c.operator
        if len(c.times) != 2:
            raise Exclude("unsupported_question", question=r.get("Question"))
        t0, t1 = float(c.times[0]), float(c.times[1])
        if t1 <= t0:
            case.outcome.defects.append("zero_length_interval")
            raise Exclude("zero_length_interval", t=[t0, t1], kind=op)
        view = SceneView.open(case.ctx, str(r["Video"]), params)
        rule = set_rule(case, rule_for(params, case.source))
        ent = c.entity

        def value_fn(entity: dict) -> float:
            return case.measure(op, entity, [t0, t1]).value

        try:
            if ent.get("kind") == "camera":
                subj = camera_subject(view)
            elif ent.get("kind") == "ambiguous":
                subj = ambiguous_subject(view, ent.get("description"), t0, t1, value_fn, params)
            elif view.source == "Waymo":
                subj = waymo_object_subject(view, ent.get("description"), t0, t1, value_fn, case.legacy, UNIT, rule,
                                            params, presupposes_motion="travel" in str(r.get("Question", "")).lower())
            else:
                raise Exclude("unsupported_question", note=f"{view.source} objects are static annotations with no "
                                                           "motion track", phrase=ent.get("description"))
            m = case.measure(op, subj.entity, [t0, t1])
        except ContractError as e:
            raise Exclude("invalid_pose_at_time", t=[t0, t1], error=str(e)) from None
        values, evidence = {op: m.value}, {op: m.evidence}
        other = "path_length" if op == "displacement" else "displacement"
        try:
            mo = case.measure(other, subj.entity, [t0, float(m.evidence.get("t1_used", t1))])
            values[other], evidence[other] = mo.value, mo.evidence
        except ContractError:
            values[other] = None
        case.state.update(subj=subj, values=values, evidence=evidence, t0=t0, t1=t1)
        case.observables.update(subject=subject_phrase(subj, ent.get("description")),
                                subject_class=subj.entity.get("label", subj.kind))
        self._settle(case, op)

    def _settle(self, case: Case, op: str) -> None:
        """The answer under operator ``op``: value, contract, provenance."""
        s, c = case.state, case.contract
        value = s["values"][op]
        if value is None:
            raise Exclude("invalid_pose_at_time", t=[s["t0"], s["t1"]], operator=op,
                          error=f"{op} is undefined on the interval")
        gev = s["evidence"][op]
        t1_used = float(gev.get("t1_used", s["t1"]))
        subj = s["subj"]
        case.value = value
        c.operator = op
        c.entity = {**c.entity, **subj.entity}
        c.times = [s["t0"], t1_used]
        c.unit, c.unit_stated, c.frame = UNIT, True, subj.track.name
        case.provenance(files=subj.files, chain=subj.evidence.get("transform_chain", ""),
                        frames=source_frames(subj.track, s["t0"], t1_used,
                                             **({"shortened_to": gev["shortened_to"]}
                                                if gev.get("shortened_to") is not None else {})))
        case.outcome.time_start, case.outcome.time_end = s["t0"], t1_used
        case.answer = AnswerSpec("scalar", value, UNIT, int(case.params["decimals"]))

    def diagnose_all(self, cases: list[Case]) -> None:
        rule = {id(k): rule_for(k.params, k.source) for k in cases}
        open_rows = [k for k in cases if "statistic" in k.contract.missing]
        match = {id(k): {op: (k.state["values"][op] is not None
                              and agrees_scalar(k.legacy, k.state["values"][op], UNIT, rule[id(k)]))
                         for op in READINGS} for k in open_rows}
        groups = reading_per_source([(k.source, match[id(k)]) for k in open_rows], READINGS,
                                    str(cases[0].params["default_statistic"]) if cases else "path_length",
                                    float(cases[0].params["mixed_share"]) if cases else 0.0)
        for k in cases:
            extra: dict = {}
            if id(k) in match:
                op, determined, rev = row_reading(match[id(k)], groups[k.source])
                extra = {"construction_statistic": {"source": k.source, **groups[k.source]}, **rev,
                         "hypotheses": {"displacement_m": k.state["values"]["displacement"],
                                        "path_length_m": k.state["values"]["path_length"],
                                        "matches": match[id(k)]}}
                try:
                    self._settle(k, op)
                except Exclude as e:
                    e.apply(k.outcome)
                    continue
                defects = DEFECTS_OF_DISPLACEMENT_READING if op == "displacement" and determined else []
            else:
                defects = []
            op = k.contract.operator
            other = "path_length" if op == "displacement" else "displacement"
            cmp = compare_scalar(k.legacy, k.value, UNIT, rule[id(k)])
            d = Diagnosis.from_comparison(cmp, operator=op, value_si=k.value, geometry=k.state["evidence"][op],
                                          other_operator={other: k.state["values"][other]},
                                          **k.state["subj"].evidence, **extra)
            d.defects[:0] = defects
            k.diagnosis = d

    def rewrite(self, case: Case) -> str:
        c = case.contract
        return question_text(c.operator, subject_phrase(case.state["subj"], c.entity.get("description")),
                             c.times[0], c.times[1])


# --------------------------------------------------------------------------------- notebook aids


def diagnosis(run) -> pd.DataFrame:
    """Per row: operator, legacy and source values, the other operator's value, verdict and defects."""
    df = value_table(run.outcomes)
    df["other_operator_si"] = [next(iter((o.evidence.get("other_operator") or {None: None}).values()))
                               for o in run.outcomes]
    df["subject"] = [o.evidence.get("subject") for o in run.outcomes]
    df["reading"] = [(o.evidence.get("construction_statistic") or {}).get("statistic") for o in run.outcomes]
    return df


def reading_split(run) -> pd.DataFrame:
    """Per source, the "how far has X traveled" rows: the reading of the legacy construction and how
    many rows matched each reading."""
    recs = {}
    for o in run.outcomes:
        g = o.evidence.get("construction_statistic")
        if g:
            recs[o.source] = {"source": o.source, "reading": g["statistic"], "decided_by": g["decided_by"],
                              "rows": g["n_rows"], "displacement_only": g["n_displacement_only"],
                              "path_only": g["n_path_only"], "both": g["n_both"], "neither": g["n_neither"]}
    return pd.DataFrame(list(recs.values()))


def plot_legacy_vs_source(run, path: str | Path) -> Path:
    """Legacy against reconstructed values per source (accepted rows)."""
    df = value_table(run.outcomes)
    df = df[df["verdict"] != "excluded"]
    return scatter_by_source(df, path, xlabel="source value (m)", ylabel="legacy value (m)",
                             title="Displacement & Path Length: legacy vs source")


__all__ = ["TASK", "WORDING", "Displacement", "diagnosis", "operator_of", "plot_legacy_vs_source", "question_text",
           "reading_split"]
