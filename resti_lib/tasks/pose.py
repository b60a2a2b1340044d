"""Pose Estimation: the camera pose at a stated time, in a stated world frame, axes and direction.

Contract per source (stated in every rewritten question and in the provenance)
------------------------------------------------------------------------------
- ScanNet: world = the raw scan frame; ``P(t) = T_raw<-cam(t)`` from the ``.sens`` stream
  (camera-to-world, OpenCV camera axes), ``t = frame / scannet_fps``.
- Waymo: world = the segment's world frame; ``P(t) = world_from_vehicle(t) @ extrinsic(camera)``
  re-expressed in OpenCV camera axes (``@ T_waymo_cam<-cv_cam``), ``t = (micros - first) / 1e6``.
- Omni6DPose: world = the OpenCV camera frame at the premise time (t = 0 s, the identity);
  ``P(t) = T_c0<-cam(t)`` after the stored camera convention is verified against the objects.

The pose at an asked time is the measure operator ``pose``: the source sample nearest to it
(``pose_rule: nearest``), within half the median sampling interval; an invalid pose there is an
exclusion (``invalid_pose_at_time``).

Diagnosis
---------
- Premise: the pose printed in the question is matched against the source (at the stated premise
  time, else the row's ``time_start``, else every sample); the rewritten question prints the
  source premise at the resolved time.
- ``premise_equals_target``: target time equal to the premise time, or target and premise poses
  that print identically -> excluded (defect ``premise_equals_answer``).
- ``premise_reveals_answer``: the printed premise is another row's answer (the legacy benchmark asks
  Waymo poses in converse pairs: the pose at t1 given t0, and at t0 given t1; no option design can
  hide that). The premise moves to the earliest whole second that no row of the recording asks
  (:meth:`Pose.contract_group`), the legacy premise time kept in the evidence; without such a
  second the row is excluded (``no_unrevealing_premise``).
- Timestamp search (:func:`timestamp_search`): for each legacy matrix, the source sample whose
  pose reproduces it best (largest absolute entry difference, ``residual``). A Waymo matrix that
  the asked sample does not reproduce but another sample does is ``waymo_pose_wrong_timestamp``;
  one that no sample reproduces is ``value_mismatch``.
- Comparison rule: entry-wise, half a unit of the last printed place + ``compare_abs_tol``.

Options: the option stage draws each distractor as a motion from the premise like the answers'
motions (:mod:`resti_lib.options.stage`), printed like the answer (compact JSON for Waymo).
"""

from __future__ import annotations

import json
import re
from collections import defaultdict
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd

from .. import values as V
from ..adjudicate import Diagnosis, Rule, same_quantity_agrees
from ..contract import NUM, Contract, base_contract, find_pose_json
from ..errors import ContractError, InputError
from ..geometry import trajectory as G
from ..geometry.frames import invert_T, rotation_angle_deg
from ..geometry.trajectory import PoseTrack
from ..io.figures import save_figure
from ..measure.motion import sample_window
from ..options.observables import sequence_of
from . import register_task
from .base import AnswerSpec, Case, Exclude, Outcome, Task

TASK = "Pose Estimation"

WORLD = {
    "ScanNet": "ScanNet raw scan coordinate frame",
    "Waymo": "Waymo world coordinate frame",
    "Omni6DPose": "OpenCV camera frame at the premise time",
}
CHAIN = {
    "ScanNet": "P(t) = T_raw<-cam(t) (.sens camera_to_world, OpenCV axes)",
    "Waymo": "P(t) = world_from_vehicle(t) @ extrinsic(camera) @ T_waymo_cam<-cv_cam",
    "Omni6DPose": "P(t) = T_c0<-cam(t0)^-1 @ T_c0<-cam(t), T_c0<-cam(t) = T_c0<-obj T_cam(t)<-obj^-1 over the "
                  "static objects (OpenCV axes)",
}
AXES = "OpenCV camera axes (+X right, +Y down, +Z forward)"


def _vec(T: np.ndarray) -> np.ndarray:
    """The 12 printed entries ``tx, ty, tz, r11 .. r33`` of pose(s) ``[..., 4, 4]``."""
    T = np.asarray(T, float)
    return np.concatenate([T[..., :3, 3], T[..., :3, :3].reshape(T.shape[:-2] + (9,))], axis=-1)


def _as_pose(T: np.ndarray, decimals: int) -> V.Pose:
    """An unrounded :class:`resti_lib.values.Pose` for comparisons (printed precision ``decimals``)."""
    T = np.asarray(T, float)
    return V.Pose(t=tuple(T[:3, 3]), R=tuple(tuple(r) for r in T[:3, :3]), text="", decimals=decimals)


# ------------------------------------------------------------------------------------ diagnosis


def pose_at_time(track: PoseTrack, t: float, rule: str = "nearest") -> tuple[np.ndarray, dict]:
    """``P(t)`` by ``rule`` within half the median sampling interval (the ``pose`` operator's window);
    evidence names the sample and its time.

    Raises
    ------
    ContractError
        Time outside the track, no sample within the tolerance, or an invalid pose there.
    """
    tol = sample_window(track)
    T, ev = G.pose_at(track, float(t), rule, tol)
    ev["tol_s"] = tol
    for key in ("frames", "micros"):
        if key in track.meta:
            ev["frame" if key == "frames" else "frame_timestamp_micros"] = [int(track.meta[key][i])
                                                                           for i in ev["indices"]]
    return T, ev


def timestamp_search(track: PoseTrack, legacy_T: np.ndarray, t_asked: float, *, decimals: int = 2,
                     abs_tol: float = 0.001, rule: str = "nearest") -> dict:
    """Which source sample reproduces a printed pose matrix? (the wrong-timestamp diagnosis)

    Every valid sample is compared with the legacy matrix entry-wise; ``residual`` is the largest
    absolute difference of the 12 printed entries. A sample *reproduces* the matrix when its
    residual is at most half a unit of the printed place plus ``abs_tol``.

    Returns
    -------
    dict
        ``asked_t``, ``asked_sample_t``, ``asked_residual``, ``best_t``, ``best_index``,
        ``best_residual``, ``reproduced_at_asked``, ``reproduced_elsewhere``, ``wrong_timestamp``
        (reproduced by another sample and not by the asked one), ``time_offset_s`` (best - asked
        sample), ``translation_change_m`` (legacy translation vs the source at the asked time),
        ``n_reproducing`` and the tolerance used.
    """
    legacy_T = np.asarray(legacy_T, float)
    tol = 0.5 * 10.0 ** -decimals + abs_tol
    T_ask, ev = pose_at_time(track, t_asked, rule)
    v = _vec(legacy_T)
    valid = np.flatnonzero(track.valid)
    res = np.abs(_vec(track.T[valid]) - v).max(axis=1)
    k = int(np.argmin(res))
    best = int(valid[k])
    r_ask = float(np.abs(_vec(T_ask) - v).max())
    reproducing = valid[res <= tol + 1e-12]
    elsewhere = [int(i) for i in reproducing if abs(track.times[i] - ev["times"][0]) > ev["tol_s"]]
    out = {"asked_t": float(t_asked), "asked_sample_t": float(ev["times"][0]), "asked_residual": r_ask,
           "best_t": float(track.times[best]), "best_index": best, "best_residual": float(res[k]),
           "tolerance": tol, "n_reproducing": int(reproducing.size),
           "reproduced_at_asked": bool(r_ask <= tol + 1e-12), "reproduced_elsewhere": bool(elsewhere),
           "translation_change_m": float(np.linalg.norm(legacy_T[:3, 3] - T_ask[:3, 3])),
           "rotation_change_deg": rotation_angle_deg(T_ask[:3, :3], legacy_T[:3, :3])}
    out["wrong_timestamp"] = bool(not out["reproduced_at_asked"] and out["reproduced_elsewhere"])
    out["time_offset_s"] = out["best_t"] - out["asked_sample_t"]
    if "micros" in track.meta:
        out["best_frame_timestamp_micros"] = int(track.meta["micros"][best])
    if "frames" in track.meta:
        out["best_frame"] = int(track.meta["frames"][best])
    return out


def resolve_premise(track: PoseTrack, premise: dict | None, candidates: list[float], *, decimals: int = 2,
                    abs_tol: float = 0.001, rule: str = "nearest") -> dict:
    """The premise time: the first candidate time whose source pose reproduces the printed premise,
    else the best-matching sample of the whole track (when it reproduces it), else the first
    candidate (``reproduced: False``). Without a printed premise the first candidate is used."""
    cands = [float(c) for c in dict.fromkeys(candidates)]
    if premise is None:
        return {"time": cands[0], "how": "stated", "printed": False}
    try:
        P = V.parse(json.dumps(premise))
    except InputError as e:
        return {"time": cands[0], "how": "stated", "printed": True, "unreadable": str(e)}
    tol = 0.5 * 10.0 ** -decimals + abs_tol
    tried = []
    for c in cands:
        try:
            T, _ = pose_at_time(track, c, rule)
        except ContractError as e:
            tried.append({"t": c, "error": str(e)})
            continue
        r = float(np.abs(_vec(T) - P.vector()).max())
        tried.append({"t": c, "residual": r})
        if r <= tol + 1e-12:
            return {"time": c, "how": "stated" if c == cands[0] else "time_start", "residual": r,
                    "reproduced": True, "tried": tried}
    try:  # the search compares against the asked sample, which may be invalid (failed tracking)
        s = timestamp_search(track, P.matrix, cands[0], decimals=decimals, abs_tol=abs_tol, rule=rule) \
            if np.isfinite(cands[0]) else None
    except ContractError as e:
        s = None
        tried.append({"t": cands[0], "search_error": str(e)})
    if s is not None and s["best_residual"] <= tol + 1e-12:
        return {"time": s["best_t"], "how": "search", "residual": s["best_residual"], "reproduced": True,
                "tried": tried}
    return {"time": cands[0], "how": "stated", "reproduced": False, "tried": tried,
            "best_search_residual": None if s is None else s["best_residual"]}


# ------------------------------------------------------------------------------------- the task


def question_text(source: str, t0: float, t1: float, premise_text: str | None) -> str:
    """The rewritten question: premise and target times, world frame, axes, matrix direction, unit."""
    if source == "Omni6DPose":
        return (f"Taking the camera pose at t={V.format_seconds(t0)} s as the identity and expressing the result in the OpenCV "
                f"camera frame of that instant (+X right, +Y down, +Z forward; translation in meters), what is "
                f"the camera pose at t={V.format_seconds(t1)} s, as the camera-to-reference matrix (mapping camera "
                f"coordinates at t={V.format_seconds(t1)} s into that frame)?")
    extra = " (vehicle pose composed with the camera extrinsic)" if source == "Waymo" else ""
    return (f"Given the camera pose at t={V.format_seconds(t0)} s in the {WORLD[source]}: {premise_text}, what is the camera "
            f"pose in the same coordinate frame at t={V.format_seconds(t1)} s? Poses are camera-to-world matrices{extra} "
            f"with OpenCV camera axes (+X right, +Y down, +Z forward); translation in meters.")


def camera_track(ctx, c: Contract, params: dict) -> tuple[PoseTrack, tuple, list[str]]:
    """The camera track of the contract's sequence, the world up in its frame and the files read."""
    if c.source == "ScanNet":
        sc = ctx.scannet(c.sequence)
        tr = sc.camera_track()
        return tr, (0.0, 0.0, 1.0), [tr.source, str(sc.meta_path)]
    if c.source == "Waymo":
        seg = ctx.waymo(c.sequence)
        if c.camera is None:
            raise InputError("Waymo video without a camera number", field="Video")
        tr = seg.camera_track(c.camera)
        return tr, (0.0, 0.0, 1.0), [str(seg.path("vehicle_pose")), str(seg.path("camera_calibration"))]
    rp = ctx.rope(c.sequence)
    tr = rp.camera_track(rebase=True)
    up = tuple(float(x) for x in rp.world_up_in_track_frame(np.asarray(params["omni6d_up"], float)))
    return tr, up, [str(rp.dir), str(rp.obj_meta_path)]


@register_task
class Pose(Task):
    name = TASK
    params_name = "pose"
    notebook = "08_pose"
    order = 8
    answer_kind = "pose"
    rule_key = "compare_abs_tol"
    quantity = "pose"
    figures = {
        "translation_change": ("Pose Estimation: translation change between each wrong-timestamp legacy matrix and the source "
                               "pose at the asked time (Waymo)."),
    }
    legacy_kind = V.Pose
    operators = ("pose",)
    setting_overrides = ("pose_rule",)  # the nearest sample, not interpolation
    missing_defects: ClassVar[dict] = {"time": "pose_time_omitted"}

    def read_contract(self, row: dict, video_map: dict | None = None) -> Contract:
        c, q = base_contract(row, "pose", video_map=video_map)
        ql = q.lower()
        t0, t1 = float(row.get("time_start") or 0.0), float(row.get("time_end") or 0.0)
        c.entity = {"kind": "camera"}
        premise = find_pose_json(q)
        all_t = [float(x) for x in re.findall(rf"t\s*=\s*({NUM})\s*s", q)]
        if len(all_t) >= 2:
            c.params["premise_time"], c.times, c.time_stated = all_t[0], [all_t[-1]], True
        elif len(all_t) == 1:
            c.params["premise_time"] = 0.0 if "initial" in ql else t0
            c.times, c.time_stated = [all_t[0]], True
        else:
            c.params["premise_time"], c.times = (0.0 if "initial" in ql else t0), [t1]
            c.miss("time")
        if premise is not None:
            c.params["premise_pose"] = premise
        if not any(w in ql for w in ("world coordinate", "coordinate frame", "same coordinate", "opencv")):
            c.miss("frame")
        return c

    def reconstruct(self, case: Case) -> None:
        c, r, p, o = case.contract, case.row, case.params, case.outcome
        dec, rule, mtol = int(p["decimals"]), str(p["pose_rule"]), float(p["match_abs_tol"])
        src = c.source
        track, up, files = camera_track(case.ctx, c, p)
        case.provenance(files=files, chain=CHAIN[src])
        if src == "Omni6DPose":  # where the camera motion comes from (static objects, left-out movers)
            o.evidence["camera_track"] = track.meta.get("evidence")
        o.evidence["legacy_missing"] = list(c.missing)
        t1 = float(c.times[0]) if c.times else float(r["time_end"])
        stated_t0 = float(c.params.get("premise_time", r.get("time_start") or 0.0))
        cands = [stated_t0, float(r.get("time_start") or 0.0)]
        prem = resolve_premise(track, c.params.get("premise_pose"), cands, decimals=dec, abs_tol=mtol, rule=rule)
        t0 = float(prem["time"])
        o.evidence["premise"] = prem
        try:
            m0 = case.measure("pose", {"kind": "camera"}, [t0])
            m1 = case.measure("pose", {"kind": "camera"}, [t1])
        except ContractError as e:
            raise Exclude("invalid_pose_at_time", error=str(e), premise_time=t0, target_time=t1) from None
        T0, T1 = np.asarray(m0.value, float), np.asarray(m1.value, float)
        e0, e1 = m0.evidence, m1.evidence
        o.frames = {"premise": e0, "target": e1}
        if src == "Omni6DPose" and not np.allclose(T0, np.eye(4), atol=1e-9):
            # the reference is the camera at the premise time: re-base the whole track on it
            base = invert_T(T0)
            track = PoseTrack(track.times, base @ track.T, name=track.name + " (re-based at the premise time)",
                              source=track.source, valid=track.valid, meta=track.meta)
            up = tuple(float(x) for x in base[:3, :3] @ np.asarray(up, float))
            T0, T1 = base @ T0, base @ T1
        compact = src == "Waymo"
        disp = float(np.linalg.norm(T1[:3, 3] - T0[:3, 3]))
        rot = rotation_angle_deg(T0[:3, :3], T1[:3, :3])
        same_time = abs(e1["times"][0] - e0["times"][0]) <= e0["tol_s"]
        same_print = V.format_pose(T0, dec, compact=compact) == V.format_pose(T1, dec, compact=compact)
        c.entity = {"kind": "camera", **({"camera": int(c.camera)} if c.camera is not None else {})}
        c.times = [t1]
        c.params = {k: v for k, v in c.params.items() if k != "premise_pose"}
        c.params.update({"premise_time": t0, "matrix": "camera-to-world", "axes": AXES})
        c.frame = WORLD[src]
        c.unit = "m"
        if same_time or same_print:
            o.defects.append("premise_equals_answer")
            raise Exclude("premise_equals_target", premise_time=t0, target_time=t1, displacement_m=disp,
                          rotation_deg=rot, same_time=bool(same_time), printed_identical=bool(same_print))
        o.evidence["premise_to_target"] = {"displacement_m": disp, "rotation_deg": rot}
        o.prompt = ""
        o.time_start, o.time_end = min(t0, t1), max(t0, t1)
        case.state.update(track=track, T0=T0, t0=t0, t1=t1, compact=compact, tol_s=float(e0["tol_s"]),
                          printed=src != "Omni6DPose")
        case.value = T1
        case.observables.update(subject="the camera", subject_class="camera", premise=T0, premise_time=t0,
                                target_time=t1, up=list(up))
        case.answer = AnswerSpec(kind="pose", value=T1, decimals=dec,
                                 options={"compact": compact})

    def contract_group(self, cases: list[Case]) -> None:
        """A premise that reveals another row's answer moves (:func:`premise_reveals`,
        :func:`unrevealing_premise_time`, per recording; the moved rows of a video share one time):
        defect ``premise_reveals_answer``, the legacy premise time kept in the evidence; a row whose
        recording offers no such time is excluded (``no_unrevealing_premise``)."""
        if not cases:
            return
        dec = int(cases[0].params["decimals"])
        recordings: dict[str, list[Case]] = defaultdict(list)
        for c in cases:
            if c.state.get("printed"):
                recordings[recording_of(c)].append(c)
        for rec in recordings.values():
            new_time: dict[str, float | None] = {}
            for case, revealed in premise_reveals(rec, dec):
                s, o = case.state, case.outcome
                o.defects.append("premise_reveals_answer")
                if o.video not in new_time:
                    new_time[o.video] = unrevealing_premise_time(case, rec, dec)
                t_new, legacy_t0 = new_time[o.video], s["t0"]
                if t_new is None:
                    o.exclude("no_unrevealing_premise", premise_time=legacy_t0, answer_of_rows=revealed)
                    continue
                m0 = case.measure("pose", {"kind": "camera"}, [t_new])
                T0, T1 = np.asarray(m0.value, float), case.value
                s.update(t0=t_new, T0=T0)
                case.contract.params["premise_time"] = t_new
                o.frames["premise"] = m0.evidence
                o.evidence["premise_moved"] = {"legacy_premise_time": legacy_t0, "premise_time": t_new,
                                               "answer_of_rows": revealed}
                o.evidence["premise_to_target"] = {"displacement_m": float(np.linalg.norm(T1[:3, 3] - T0[:3, 3])),
                                                   "rotation_deg": rotation_angle_deg(T0[:3, :3], T1[:3, :3])}
                o.time_start, o.time_end = min(t_new, s["t1"]), max(t_new, s["t1"])
                case.observables.update(premise=T0, premise_time=t_new)

    def diagnose(self, case: Case) -> None:
        p, legacy, T1 = case.params, case.legacy, case.value
        rule_c = Rule(abs_tol=float(p["compare_abs_tol"]))
        case.rule = rule_c.to_dict()
        if legacy is None:
            case.diagnosis = Diagnosis(False)
            return
        agrees = same_quantity_agrees(legacy, _as_pose(T1, legacy.decimals), rule_c)
        search = timestamp_search(case.state["track"], legacy.matrix, case.state["t1"], decimals=legacy.decimals,
                                  abs_tol=float(p["match_abs_tol"]), rule=str(p["pose_rule"]))
        d = Diagnosis(True, bool(agrees), evidence={
            "comparison": {"rule": rule_c.describe(), "agrees": bool(agrees),
                           "max_abs_entry_diff": float(np.abs(legacy.vector() - _vec(T1)).max())},
            "timestamp_search": search})
        if not agrees:
            d.defects.append("waymo_pose_wrong_timestamp" if case.source == "Waymo" and search["wrong_timestamp"]
                             else "value_mismatch")
        case.diagnosis = d

    def rewrite(self, case: Case) -> str:
        s = case.state
        return question_text(case.source, s["t0"], s["t1"], _printed(case, s["T0"], int(case.params["decimals"])))


# ------------------------------------------------------------------ premises that reveal answers


def _printed(case: Case, T: np.ndarray, dec: int) -> str:
    return V.format_pose(T, dec, compact=case.state["compact"])


def recording_of(case: Case) -> str:
    """The recording a reader sees a row in: the Waymo segment named in the video (its camera videos
    are one recording), else the video."""
    return sequence_of(case.outcome.video, case.source)[0]


def premise_reveals(rec: list[Case], decimals: int) -> list[tuple[Case, list[int]]]:
    """The rows of one recording (``rec``, with printed premises) whose premise reveals another row's
    answer, with those rows: the premise time is another row's target time (a converse pair; another
    camera of a Waymo segment is the answer up to the camera's mount), or the premise prints as the
    answer of another row of the same video (a camera at rest). Every pair is counted; a row may
    reveal several."""
    answers = [_printed(o, o.value, decimals) for o in rec]
    out = []
    for i, c in enumerate(rec):
        premise = _printed(c, c.state["T0"], decimals)
        hit = [o.outcome.row for j, o in enumerate(rec) if j != i and (
            abs(o.state["t1"] - c.state["t0"]) <= c.state["tol_s"]
            or (o.outcome.video == c.outcome.video and answers[j] == premise))]
        if hit:
            out.append((c, sorted(hit)))
    return out


def unrevealing_premise_time(case: Case, rec: list[Case], decimals: int) -> float | None:
    """The earliest whole second of the row's video that can be its premise without revealing an
    answer: no row of its recording ``rec`` asks it as a target, the camera's pose there is valid and
    prints unlike every answer of the video (its own included). None when no second qualifies. One
    rule for every moved row, so the moved rows of a video share one premise, as ScanNet's share the
    initial pose."""
    track: PoseTrack = case.state["track"]
    tol = case.state["tol_s"]
    targets = np.array([o.state["t1"] for o in rec], float)
    answers = {_printed(o, o.value, decimals) for o in rec if o.outcome.video == case.outcome.video}
    end = float(track.times[track.valid].max()) if track.valid.any() else -1.0
    for t in np.arange(0.0, np.floor(end) + 1.0):
        if np.any(np.abs(targets - t) <= tol):
            continue
        try:
            T = np.asarray(case.measure("pose", {"kind": "camera"}, [float(t)]).value, float)
        except ContractError:
            continue
        if _printed(case, T, decimals) not in answers:
            return float(t)
    return None


# ---------------------------------------------------------------------------------- reporting


def diagnosis_table(outcomes: list[Outcome], source: str | None = "Waymo") -> pd.DataFrame:
    """The timestamp diagnosis per row (accepted rows with a readable legacy matrix)."""
    recs = []
    for o in outcomes:
        s = o.evidence.get("timestamp_search")
        if s is None or (source is not None and o.source != source):
            continue
        recs.append({"row": o.row, "source": o.source, "video": o.video, "verdict": o.verdict,
                     "asked_t": s["asked_t"], "best_t": s["best_t"], "time_offset_s": s["time_offset_s"],
                     "asked_residual": s["asked_residual"], "best_residual": s["best_residual"],
                     "reproduced_at_asked": s["reproduced_at_asked"],
                     "wrong_timestamp": "waymo_pose_wrong_timestamp" in o.defects,
                     "translation_change_m": s["translation_change_m"],
                     "rotation_change_deg": s["rotation_change_deg"]})
    return pd.DataFrame(recs)


def wrong_timestamp_summary(table: pd.DataFrame) -> dict:
    """Counts and translation change (median, max) of the wrong-timestamp rows (the report's
    "90 of 121, 0.77 m, 31.6 m" line)."""
    if table.empty:
        return {"n_rows": 0, "n_wrong": 0, "median_translation_change_m": None, "max_translation_change_m": None}
    w = table[table["wrong_timestamp"]]
    return {"n_rows": len(table), "n_wrong": len(w),
            "median_translation_change_m": float(w["translation_change_m"].median()) if len(w) else None,
            "max_translation_change_m": float(w["translation_change_m"].max()) if len(w) else None}


def plot_translation_change(table: pd.DataFrame, path: str | Path, *, title: str = "") -> Path:
    """Histogram (log-spaced bins) of the translation change of the wrong-timestamp rows."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    w = table[table["wrong_timestamp"]] if len(table) else table
    fig, ax = plt.subplots(figsize=(5.0, 3.0))
    if len(w):
        x = np.maximum(w["translation_change_m"].to_numpy(float), 1e-3)
        bins = np.logspace(np.log10(x.min()) - 0.05, np.log10(x.max()) + 0.05, 16)
        ax.hist(x, bins=bins, color="#2c7fb8", edgecolor="white")
        ax.set_xscale("log")
        med = float(np.median(x))
        ax.axvline(med, color="k", ls="--", lw=0.8)
        ax.text(med, ax.get_ylim()[1] * 0.92, f" median {med:.2f} m", fontsize=7)
    else:
        ax.text(0.5, 0.5, "no wrong-timestamp rows", ha="center", transform=ax.transAxes)
    ax.set_xlabel("translation change: legacy matrix vs source pose at the asked time [m]")
    ax.set_ylabel("rows")
    s = wrong_timestamp_summary(table)
    ax.set_title(title or f"Waymo pose rows from a wrong timestamp: {s['n_wrong']} of {s['n_rows']}",
                 fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


__all__ = [
    "TASK",
    "Pose",
    "diagnosis_table",
    "plot_translation_change",
    "pose_at_time",
    "premise_reveals",
    "question_text",
    "recording_of",
    "resolve_premise",
    "timestamp_search",
    "unrevealing_premise_time",
    "wrong_timestamp_summary",
]
