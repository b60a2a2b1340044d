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
    Magnitude of the mean acceleration ``|v(t1) - v(t0)| / (t1 - t0)``. Velocity estimator (stated
    in the question and the evidence): for Waymo objects the LiDAR box's annotated velocity
    (vehicle frame, rotated into the world by the frame's vehicle pose, linear between frames);
    otherwise central differences of the positions (:func:`resti_lib.geometry.trajectory.acceleration`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
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
    agrees_si,
    compare,
    new_outcome,
    question_defects,
    rule_for,
    subject_phrase,
    value_table,
)

TASK = "Speed & Acceleration"
STATISTICS = {
    "average_velocity": "magnitude of average velocity = endpoint displacement / elapsed time",
    "average_speed": "average speed = path length / elapsed time",
}
EST_STORED = ("mean acceleration |v(t1) - v(t0)| / (t1 - t0); v = the LiDAR box's annotated velocity (vehicle "
              "frame) rotated into the world frame by the frame's vehicle pose, linear between frames")
EST_CENTRAL = ("mean acceleration |v(t1) - v(t0)| / (t1 - t0); v at a sample by central differences of the "
               "positions (one-sided at a track end), linear between samples")


# ------------------------------------------------------------------------------------ operators


def rates(track, t0: float, t1: float, params: dict) -> dict:
    """Displacement / Δt and path / Δt of a track over ``[t0, t1]`` (m/s) with the geometry evidence."""
    tol = float(params.get("time_tol", 1e-3))
    rule = str(params.get("pose_rule", "linear"))
    v, ev_v = G.average_velocity(track, t0, t1, rule=rule, tol=tol)
    s, ev_s = G.average_speed(track, t0, t1, rule=rule, tol=tol, gaps=str(params.get("path_gaps", "error")))
    return {"average_velocity": v, "average_speed": s, "t1_used": float(ev_v.get("t1_used", t1)),
            "dt_s": ev_v["dt_s"], "displacement_m": ev_v["displacement_m"], "path_length_m": ev_s["path_length_m"],
            "shortened_to": ev_v.get("shortened_to")}


def stored_velocity_acceleration(seg, track, t0: float, t1: float) -> tuple[float, dict]:
    """Mean acceleration from a Waymo track's annotated box velocities (see module docstring).

    Raises ContractError when a needed velocity is missing (NaN) or a time lies outside the track.
    """
    spd = np.asarray(track.meta.get("speed"), float)
    if spd.ndim != 2 or spd.shape[0] != len(track):
        raise ContractError(f"{track.name}: no annotated velocities")
    ego = seg.ego_track()
    k = np.searchsorted(ego.meta["micros"], track.meta["micros"])
    R = ego.T[np.clip(k, 0, len(ego) - 1), :3, :3]
    v_world = np.einsum("nij,nj->ni", R, spd)
    times = track.times

    def v_at(t):
        if t < times[0] - 1e-3 or t > times[-1] + 1e-3:
            raise ContractError(f"{track.name}: t={t} s outside the track [{times[0]:.3f}, {times[-1]:.3f}] s")
        j = int(np.clip(np.searchsorted(times, t), 1, len(times) - 1))
        a = float(np.clip((t - times[j - 1]) / (times[j] - times[j - 1]), 0.0, 1.0))
        v = (1 - a) * v_world[j - 1] + a * v_world[j]
        if not np.isfinite(v).all():
            raise ContractError(f"{track.name}: annotated velocity missing near t={t} s")
        return v, [j - 1, j]

    v0, i0 = v_at(t0)
    v1, i1 = v_at(t1)
    acc = (v1 - v0) / (t1 - t0)
    return float(np.linalg.norm(acc)), {"estimator": EST_STORED, "v_t0": v0.tolist(), "v_t1": v1.tolist(),
                                        "samples_t0": i0, "samples_t1": i1, "vector": acc.tolist(),
                                        "dt_s": t1 - t0}


def acceleration_value(view: SceneView, subj, t0: float, t1: float, params: dict) -> tuple[float, dict]:
    """The acceleration of a subject: annotated velocities for Waymo objects, else central differences."""
    tol = float(params.get("time_tol", 1e-3))
    if view.source == "Waymo" and subj.kind == "object" and params.get("acceleration_estimator",
                                                                        "annotated_velocity") == "annotated_velocity":
        try:
            a, ev = stored_velocity_acceleration(view.seq, subj.track, t0, t1)
            try:
                ev["central_difference_check"] = G.acceleration(subj.track, t0, t1, tol=tol)[0]
            except ContractError as e:
                ev["central_difference_check"] = str(e)
            return a, ev
        except ContractError as e:
            fallback = str(e)
        a, ev = G.acceleration(subj.track, t0, t1, tol=tol)
        ev["note"] = f"annotated velocities unusable ({fallback}); central differences"
        return a, ev
    return G.acceleration(subj.track, t0, t1, tol=tol)


# ------------------------------------------------------------------------------------- wording


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


# ----------------------------------------------------------------------------------------- audit


def _subject(view: SceneView, c: dict, r: dict, t0: float, t1: float, value_fn, unit: str, params: dict):
    ent = c["entity"]
    if ent.get("kind") == "camera":
        return camera_subject(view)
    if ent.get("kind") == "ambiguous":
        return ambiguous_subject(view, ent.get("description"), t0, t1, value_fn, params)
    if view.source == "Waymo":
        return waymo_object_subject(view, ent.get("description"), t0, t1, value_fn, r.get("Answer Detail"), unit,
                                    rule_for(params, view.source), params, presupposes_motion=True)
    raise Excluded("unsupported_question", None, note=f"{view.source} objects are static annotations",
                   phrase=ent.get("description"))


def _finish(o: Outcome, r: dict, op: str, subj, value: float, unit: str, t0: float, t1: float, params: dict,
            estimator: str | None = None) -> None:
    ent = o.contract["entity"]
    o.contract.update({"entity": {**ent, **subj.entity}, "operator": op, "times": [t0, t1], "unit": unit,
                       "unit_stated": True, "frame": subj.track.name, "missing": [],
                       "legacy_missing": list(o.contract.get("missing", []))})
    o.contract["params"]["statistic"] = STATISTICS.get(op, estimator)
    o.source_files = list(subj.files)
    o.frames = source_frames(subj.track, t0, t1)
    o.transform_chain = subj.evidence.get("transform_chain", "")
    o.question = question_text(op, subject_phrase(subj, ent.get("description")), t0, t1, estimator)
    o.prompt = r.get("Prompt") or ""
    o.time_start, o.time_end = t0, t1
    o.answer = AnswerSpec("scalar", value, unit, int(params.get("decimals", 2)))


def _acceleration_row(o: Outcome, r: dict, c: dict, view: SceneView, t0: float, t1: float, params: dict) -> None:
    unit = "m/s²"

    def value_fn(track):
        from .motion import Subject

        return acceleration_value(view, Subject("object", track, "", {}, {}, []), t0, t1, params)[0]

    subj = _subject(view, c, r, t0, t1, value_fn, unit, params)
    value, aev = acceleration_value(view, subj, t0, t1, params)
    cmp_ = compare(r.get("Answer Detail"), value, unit, rule_for(params, o.source))
    o.verdict = verdict_for(cmp_["comparable"], cmp_["agrees"])
    if o.verdict == "corrected":
        o.defects.append("value_mismatch")
    o.evidence.update({"operator": "acceleration", "value_si": value, "comparison": cmp_, "acceleration": aev,
                       **subj.evidence})
    # an interval ending in invalid poses was shortened: the question states the interval measured
    _finish(o, r, "acceleration", subj, value, unit, t0, float(aev.get("t1_used", t1)), params,
            aev.get("estimator"))


def audit(rows: pd.DataFrame, ctx, params: dict) -> list[Outcome]:
    """Speed & Acceleration outcomes, one per legacy row (module docstring)."""
    views: dict = {}
    outs: list[Outcome] = []
    pending: list[tuple] = []  # rate rows waiting for the per-source statistic
    for r in rows.to_dict("records"):
        o = new_outcome(r, TASK)
        outs.append(o)
        c = parse_question(r, video_map=ctx.video_map).to_dict()
        o.contract = c
        o.defects = question_defects(c)
        if len(c["times"]) != 2:
            o.exclude("unsupported_question", question=r.get("Question"))
            continue
        t0, t1 = float(c["times"][0]), float(c["times"][1])
        if t1 <= t0:
            o.defects.append("zero_length_interval")
            o.exclude("zero_length_interval", t=[t0, t1], kind=c["operator"])
            continue
        video = str(r["Video"])
        if video not in views:
            views[video] = SceneView.open(ctx, video, params)
        view = views[video]
        try:
            if c["operator"] == "acceleration":
                _acceleration_row(o, r, c, view, t0, t1, params)
                continue
            op = c["operator"]

            def value_fn(track, op=op, t0=t0, t1=t1):
                return rates(track, t0, t1, params)[op]

            subj = _subject(view, c, r, t0, t1, value_fn, "m/s", params)
            rr = rates(subj.track, t0, t1, params)
        except Excluded as e:
            e.apply(o)
            continue
        except ContractError as e:
            o.exclude("invalid_pose_at_time", t=[t0, t1], error=str(e))
            continue
        rule = rule_for(params, o.source)
        detail = r.get("Answer Detail")
        match = {k: agrees_si(detail, rr[k], "m/s", rule) for k in STATISTICS}
        pending.append((o, r, c, subj, rr, match))
    _adjudicate_rates(pending, params)
    return outs


def construction_statistic(pending: list[tuple], default: str, mixed_share: float = 0.25) -> dict[str, dict]:
    """Per source: the statistic of the legacy "average speed" rows (majority of the rows that match one).

    A source is *mixed* when the minority statistic has at least ``mixed_share`` of the rows that
    match exactly one; there each such row keeps its own statistic.
    """
    out: dict[str, dict] = {}
    for o, _r, c, _s, _rr, match in pending:
        if "statistic" not in c["missing"]:
            continue
        d = out.setdefault(o.source, {"n_rows": 0, "n_velocity_only": 0, "n_speed_only": 0, "n_both": 0,
                                      "n_neither": 0})
        d["n_rows"] += 1
        key = {(True, False): "n_velocity_only", (False, True): "n_speed_only", (True, True): "n_both",
               (False, False): "n_neither"}[(match["average_velocity"], match["average_speed"])]
        d[key] += 1
    for d in out.values():
        lo, hi = sorted((d["n_velocity_only"], d["n_speed_only"]))
        d["mixed"] = bool(hi and lo / (lo + hi) >= mixed_share)
        if d["n_velocity_only"] > d["n_speed_only"]:
            d["statistic"], d["decided_by"] = "average_velocity", "majority of discriminating rows"
        elif d["n_speed_only"] > d["n_velocity_only"]:
            d["statistic"], d["decided_by"] = "average_speed", "majority of discriminating rows"
        else:
            d["statistic"], d["decided_by"] = default, "undetermined: params default_statistic"
    return out


def _adjudicate_rates(pending: list[tuple], params: dict) -> None:
    group = construction_statistic(pending, str(params.get("default_statistic", "average_velocity")),
                                   float(params.get("mixed_share", 0.25)))
    for o, r, c, subj, rr, match in pending:
        unnamed = "statistic" in c["missing"]
        if unnamed:
            g = group[o.source]
            own = [k for k, m in match.items() if m]
            determined = g["decided_by"].startswith("majority") or len(own) == 1
            # one construction per source unless the source is mixed: then each row keeps its own match
            legacy_stat = own[0] if (len(own) == 1 and (g["mixed"] or not g["decided_by"].startswith("majority"))) \
                else g["statistic"]
            if len(own) == 1 and legacy_stat != own[0]:
                o.evidence["coincidence"] = (f"the legacy value also agrees with {own[0]}, a chance agreement in a "
                                             f"source whose rows use {legacy_stat}")
            op = legacy_stat
            if legacy_stat == "average_velocity" and determined:
                o.defects += ["statistic_unnamed", "speed_is_displacement_over_time"]
            o.evidence["construction_statistic"] = {"source": o.source, **g}
            o.evidence["row_statistic"] = ("matched one statistic" if len(own) == 1 else
                                           "matched both (the source's statistic)" if own else
                                           "matched neither (the source's statistic)")
        else:
            op = c["operator"]
        value = rr[op]
        cmp_ = compare(r.get("Answer Detail"), value, "m/s", rule_for(params, o.source))
        o.verdict = verdict_for(cmp_["comparable"], cmp_["agrees"])
        if o.verdict == "corrected":
            o.defects.append("value_mismatch")
        o.evidence.update({"operator": op, "value_si": value, "comparison": cmp_, "statistic": STATISTICS[op],
                           "hypotheses": {"displacement_over_time": rr["average_velocity"],
                                          "path_over_time": rr["average_speed"], "matches": match,
                                          "displacement_m": rr["displacement_m"], "path_length_m": rr["path_length_m"],
                                          "dt_s": rr["dt_s"]},
                           **({"shortened_to": rr["shortened_to"]} if rr.get("shortened_to") else {}),
                           **subj.evidence})
        _finish(o, r, op, subj, value, "m/s", float(c["times"][0]), rr["t1_used"], params)


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
