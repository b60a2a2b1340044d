"""Displacement & Path Length: endpoint displacement and integrated path of a named subject.

Contract (stated in the rewritten question):

``displacement``
    ``|p(t1) - p(t0)|``, the straight-line distance between the subject's positions at the two
    asked times (:func:`resti_lib.geometry.trajectory.endpoint_displacement`).
``path_length``
    The trajectory length ``sum |Δp|`` over ``p(t0)``, every source sample strictly inside the
    interval and ``p(t1)`` (:func:`resti_lib.geometry.trajectory.path_length`); "total distance
    traveled" and "how far has X traveled" name it.

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
from ..adjudicate import verdict_for
from ..contract import parse_question
from ..errors import ContractError
from ..geometry import trajectory as G
from .base import AnswerSpec, Outcome
from .motion import ambiguous_subject, camera_subject, source_frames, waymo_object_subject
from .referents import SceneView
from .scalar_audit import (
    Excluded,
    compare,
    new_outcome,
    question_defects,
    rule_for,
    scatter_by_source,
    subject_phrase,
    value_table,
)

TASK = "Displacement & Path Length"
UNIT = "m"
WORDING = {
    "displacement": "displacement (straight-line distance between its start and end positions)",
    "path_length": "trajectory length (total distance traveled along its path)",
}


def operator_of(c: dict, question: str) -> str:
    """``displacement`` or ``path_length``: "how far ... traveled" names the distance traveled (path)."""
    q = " ".join(str(question).lower().split())
    if "how far" in q and "travel" in q:
        return "path_length"
    return c["operator"] if c["operator"] in WORDING else "displacement"


def measure(track, op: str, t0: float, t1: float, params: dict) -> tuple[float, dict]:
    """The operator's value on a track (metres) and the geometry evidence."""
    tol = float(params.get("time_tol", 1e-3))
    rule = str(params.get("pose_rule", "linear"))
    if op == "displacement":
        return G.endpoint_displacement(track, t0, t1, rule=rule, tol=tol)
    return G.path_length(track, t0, t1, rule=rule, tol=tol, gaps=str(params.get("path_gaps", "error")))


def question_text(op: str, subject: str, t0: float, t1: float) -> str:
    return f"What is the {WORDING[op]} of {subject} between t={V.format_seconds(t0)} s and t={V.format_seconds(t1)} s? (unit: {UNIT})"


def audit_row(r: dict, ctx, params: dict, views: dict) -> Outcome:
    """One legacy row -> its outcome."""
    o = new_outcome(r, TASK)
    c = parse_question(r, video_map=ctx.video_map).to_dict()
    op = operator_of(c, r.get("Question", ""))
    c["operator"] = op
    c["missing"] = [m for m in c["missing"] if m != "statistic"]
    o.contract = c
    o.defects = question_defects(c)
    if len(c["times"]) != 2:
        return o.exclude("unsupported_question", question=r.get("Question"))
    t0, t1 = float(c["times"][0]), float(c["times"][1])
    if t1 <= t0:
        o.defects.append("zero_length_interval")
        return o.exclude("zero_length_interval", t=[t0, t1], kind=op)
    video = str(r["Video"])
    if video not in views:
        views[video] = SceneView.open(ctx, video, params)
    view = views[video]
    rule = rule_for(params, o.source)
    detail = r.get("Answer Detail")
    ent = c["entity"]

    def value_fn(track):
        return measure(track, op, t0, t1, params)[0]

    try:
        if ent.get("kind") == "camera":
            subj = camera_subject(view)
        elif ent.get("kind") == "ambiguous":
            subj = ambiguous_subject(view, ent.get("description"), t0, t1, value_fn, params)
        elif view.source == "Waymo":
            subj = waymo_object_subject(view, ent.get("description"), t0, t1, value_fn, detail, UNIT, rule, params,
                                        presupposes_motion="travel" in str(r.get("Question", "")).lower())
        else:
            raise Excluded("unsupported_question", None, note=f"{view.source} objects are static annotations "
                                                              "with no motion track", phrase=ent.get("description"))
        value, gev = measure(subj.track, op, t0, t1, params)
    except Excluded as e:
        return e.apply(o)
    except ContractError as e:
        return o.exclude("invalid_pose_at_time", t=[t0, t1], error=str(e))
    t1_used = float(gev.get("t1_used", t1))
    cmp_ = compare(detail, value, UNIT, rule)
    o.verdict = verdict_for(cmp_["comparable"], cmp_["agrees"])
    if o.verdict == "corrected":
        o.defects.append("value_mismatch")
    other = "path_length" if op == "displacement" else "displacement"
    try:
        alt = measure(subj.track, other, t0, t1_used, params)[0]
    except ContractError:
        alt = None
    o.evidence.update({"operator": op, "value_si": value, "comparison": cmp_, "geometry": gev,
                       "other_operator": {other: alt}, **subj.evidence})
    o.contract.update({"entity": {**ent, **subj.entity}, "times": [t0, t1_used], "unit": UNIT, "unit_stated": True,
                       "frame": subj.track.name, "missing": [],
                       "legacy_missing": list(o.contract.get("missing", []))})
    o.source_files = list(subj.files)
    o.frames = source_frames(subj.track, t0, t1_used, **({"shortened_to": gev["shortened_to"]}
                                                       if gev.get("shortened_to") is not None else {}))
    o.transform_chain = subj.evidence.get("transform_chain", "")
    o.question = question_text(op, subject_phrase(subj, ent.get("description")), t0, t1_used)
    o.prompt = r.get("Prompt") or ""
    o.time_start, o.time_end = t0, t1_used
    o.answer = AnswerSpec("scalar", value, UNIT, int(params.get("decimals", 2)))
    return o


def audit(rows: pd.DataFrame, ctx, params: dict) -> list[Outcome]:
    """Displacement & Path Length outcomes, one per legacy row (module docstring)."""
    views: dict = {}
    return [audit_row(r, ctx, params, views) for r in rows.to_dict("records")]


# --------------------------------------------------------------------------------- notebook aids


def diagnosis(run) -> pd.DataFrame:
    """Per row: operator, legacy and source values, the other operator's value, verdict and defects."""
    df = value_table(run.outcomes)
    df["other_operator_si"] = [next(iter((o.evidence.get("other_operator") or {None: None}).values()))
                               for o in run.outcomes]
    df["subject"] = [o.evidence.get("subject") for o in run.outcomes]
    return df


def plot_legacy_vs_source(run, path: str | Path) -> Path:
    """Legacy against reconstructed values per source (accepted rows)."""
    df = value_table(run.outcomes)
    df = df[df["verdict"] != "excluded"]
    return scatter_by_source(df, path, xlabel="source value (m)", ylabel="legacy value (m)",
                             title="Displacement & Path Length: legacy vs source")
