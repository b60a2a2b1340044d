"""Motion questions (Displacement & Path Length, Speed & Acceleration): their contract and subject.

:func:`read_motion_contract` reads the contract of a motion question (operator, subject, interval,
the statistic when the text leaves it open).

A question's subject is the camera (ScanNet: ``T_raw<-cam``; Waymo: the video's camera,
``world_from_vehicle @ extrinsic`` in OpenCV axes; Omni6DPose: the camera rebased to its first
frame) or a Waymo object track (LiDAR box centres in the segment world frame).

Waymo objects are matched in steps, each recorded in the evidence:

1. the description's head noun gives a box type and size class (:data:`referents.WAYMO_NOUNS`);
2. the track must cover the asked interval and be visible in the video's camera at one of its
   samples inside the interval at least (frustum test with the camera intrinsics);
3. a motion cue of the description ("parked") keeps static tracks; otherwise a question that
   presupposes motion ("traveled", "accelerating") keeps tracks that move at least
   ``min_motion_m`` over the interval, when any do;
4. when several remain, the legacy value may decide: the one track whose value (the task's
   measure operator on that track) agrees with the
   legacy Answer Detail (comparison rule of the task) is taken; otherwise ``ambiguous_instance``
   with every candidate's value and their spread.

A question whose subject is a bare "the car" / "the vehicle" on a Waymo video names two possible
subjects (the recording car, whose camera films, and the tracked cars): it is excluded with
``ambiguous_subject`` when some tracked vehicle of the segment moves during the interval (in view
or not: the recording car is never in view either), with the camera's and each candidate's value
and visibility in the evidence. Only when no tracked vehicle moves does the source decide (the
camera).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..contract import Contract, base_contract, description, interval
from ..defaults import setting
from ..errors import ContractError
from ..geometry import trajectory as G
from ..geometry.trajectory import PoseTrack
from ..sources.context import derived
from ..sources.referents import GENERIC_NOUNS, WAYMO_NOUNS, SceneView, box_from, box_visibility, in_camera, size_fits
from .base import Exclude, Task
from .scalar_audit import tie_break_by_legacy, tie_break_enabled

__all__ = ["Subject", "ambiguous_subject", "camera_subject", "read_motion_contract", "source_frames",
           "waymo_object_subject"]

CAMERA_WORDS = ("camera", "ego", "our car", "the vehicle we", "recording vehicle")
AMBIGUOUS_SUBJECTS = ("the car", "the vehicle")  # on Waymo: the ego car or another tracked car
SUBJECT_PATTERNS = (r"How far has (?:the |a |an )?(.+?) traveled", r"How quickly is (?:the |a |an )?(.+?) accelerating")


def read_motion_contract(row: dict, video_map: dict | None, operator: str) -> tuple[Contract, str]:
    """The contract of a motion question with its ``operator`` decided by the task; the subject
    (camera, object, or ambiguous "the car" on Waymo), the interval and the unit tag. Returns the
    contract and the lower-case question."""
    c, q = base_contract(row, operator, video_map=video_map)
    ql = q.lower()
    desc = description(row, q, SUBJECT_PATTERNS)
    if any(w in ql for w in CAMERA_WORDS):
        c.entity = {"kind": "camera"}
    elif c.source == "Waymo" and any(ql.startswith(f"how far has {w[4:]}") or f"has {w}" in ql
                                     for w in AMBIGUOUS_SUBJECTS) and desc in ("car", "vehicle"):
        c.entity = {"kind": "ambiguous", "candidates": ["camera", "object"], "description": desc}
        c.miss("subject")
    else:
        c.entity = {"kind": "object", "description": desc}
    c.times = interval(c, row)
    if not c.time_stated:
        c.miss("time")
    if not c.unit_stated:
        c.miss("unit")
    return c, ql


class MotionTask(Task):
    """What the motion tasks (Displacement, Speed) share: the contract of a motion question, whose
    operator each task reads from the wording (``operator_of``: operator, statistic left open)."""

    @staticmethod
    def operator_of(question: str) -> tuple[str, bool]:
        raise NotImplementedError

    def read_contract(self, row: dict, video_map: dict | None = None) -> Contract:
        op, open_statistic = self.operator_of(row.get("Question", ""))
        c, _ = read_motion_contract(row, video_map, op)
        if open_statistic:
            c.miss("statistic")
        return c


class Subject:
    """A resolved motion subject: its track, its entity for the measure operators, evidence."""

    def __init__(self, kind: str, track: PoseTrack, text: str, evidence: dict, entity: dict, files: list):
        self.kind, self.track, self.text, self.evidence, self.entity, self.files = (kind, track, text, evidence,
                                                                                     entity, files)


def source_frames(track: PoseTrack, t0: float, t1: float, **extra) -> dict:
    """Provenance of an interval: the asked times and the source frames nearest to them (ScanNet /
    ROPE frame numbers, Waymo frame timestamps in µs)."""
    idx = [int(np.argmin(np.abs(track.times - t))) for t in (t0, t1)]
    out = {"t0": float(t0), "t1": float(t1), "sample_indices": idx, **extra}
    if "frames" in track.meta:
        out["frames"] = [int(track.meta["frames"][i]) for i in idx]
    if "micros" in track.meta:
        out["frame_timestamp_micros"] = [int(track.meta["micros"][i]) for i in idx]
    return out


def camera_subject(view: SceneView) -> Subject:
    """The camera of the video (optical centre track, OpenCV axes)."""
    if view.source == "ScanNet":
        tr = view.seq.camera_track()
        files = [tr.source]
        chain = "P(t) = T_raw<-cam (.sens camera_to_world); position = camera centre"
    elif view.source == "Waymo":
        tr = _cam_track(view)
        files = [str(view.seq.path("vehicle_pose")), str(view.seq.path("camera_calibration"))]
        chain = "world_from_vehicle(t) @ extrinsic(camera) @ waymo->opencv; position = camera centre"
    else:
        tr = view.seq.camera_track(rebase=True)
        files = [str(view.seq.dir)]
        chain = ("T_c0<-cam(t) = T_c0<-obj T_cam(t)<-obj^-1 over the static ROPE objects (or a stored camera "
                 "pose that agrees with them), first frame as the world")
        return Subject("camera", tr, "the camera", {"subject": "camera", "track": tr.name, "transform_chain": chain,
                                                    "camera_track": tr.meta.get("evidence")},
                       {"kind": "camera"}, files)
    return Subject("camera", tr, "the camera", {"subject": "camera", "track": tr.name, "transform_chain": chain},
                   {"kind": "camera"}, files)


def _track(view: SceneView, oid: str) -> PoseTrack:
    return derived(view.seq, ("object_track", oid), lambda: view.seq.object_track(oid))


def _cam_track(view: SceneView) -> PoseTrack:
    return derived(view.seq, ("camera_track", view.camera), lambda: view.seq.camera_track(view.camera))


def _visible_samples(view: SceneView, tr: PoseTrack) -> np.ndarray:
    """Per sample of the track: is the box visible in the video's camera (computed once per track)."""
    key = ("visible_samples", tr.name, view.camera, view.near, view.far, view.min_fraction)
    return derived(view.seq, key, lambda: _visibility_of_samples(view, tr))


def _visibility_of_samples(view: SceneView, tr: PoseTrack) -> np.ndarray:
    cam = _cam_track(view)
    intr = view.seq.camera_calibration(view.camera)
    k = intr["intrinsics"]
    intr = {"fx": k["f_u"], "fy": k["f_v"], "cx": k["c_u"], "cy": k["c_v"], "width": intr["width"],
            "height": intr["height"]}
    Tc, _ = G.pose_at(cam, tr.times, "linear", view.time_tol, errors="nan")
    vis = np.zeros(len(tr.times), dtype=bool)
    for i in range(len(tr.times)):
        if not np.isfinite(Tc[i]).all():
            continue
        b = box_from(tr.T[i, :3, 3], tr.T[i, :3, :3], tr.meta["size"][i])
        v = box_visibility(in_camera(b, Tc[i]), intr, near=view.near, far=view.far, min_fraction=view.min_fraction)
        vis[i] = bool(v["visible"])
    return vis


def visible_in_interval(view: SceneView, tr: PoseTrack, t0: float, t1: float) -> dict:
    """How many of the track's samples inside ``[t0, t1]`` are visible in the video's camera."""
    tol = 1e-3
    idx = np.flatnonzero((tr.times >= t0 - tol) & (tr.times <= t1 + tol))
    vis = _visible_samples(view, tr)
    return {"n_samples": int(idx.size), "n_visible": int(vis[idx].sum())}


def _covers(tr: PoseTrack, t0: float, t1: float, tol: float = 0.06) -> bool:
    """The track has samples from ``t0`` to ``t1`` (within ``tol``, about half a Waymo frame)."""
    return bool(tr.times[0] <= t0 + tol and tr.times[-1] >= t1 - tol)


def waymo_object_subject(view: SceneView, desc: str | None, t0: float, t1: float,
                         value_fn: Callable[[dict], float], legacy, unit: str, rule, params: dict, *,
                         presupposes_motion: bool) -> Subject:
    """Resolve a Waymo object track by description (see the module docstring); raises Exclude.

    ``value_fn(entity)``: the task's value for a candidate entity (its measure operator)."""
    ref = view.resolve(desc)
    noun, mev = ref.label, ref.evidence
    if ref.grouped:
        raise Exclude("grouped_referent", defect="grouped_referent", phrase=desc, marker=ref.grouped)
    typed = [i for i in view.all_instances() if view.matches(ref, i)]
    ev = {"phrase": desc, "noun_class": mev, "n_type_and_size": len(typed)}
    if noun is None or not typed:
        raise Exclude("no_source_instance", defect="no_source_instance", **ev,
                      types_in_segment=view.labels())
    min_motion = float(params["min_motion_m"])
    tol = float(setting(params, "time_tol"))
    cands, seen = [], []
    for inst in typed:
        tr = _track(view, inst.id)
        if not _covers(tr, t0, t1):
            continue
        try:
            path, _ = G.path_length(tr, t0, t1, tol=tol, gaps="skip")
            value = float(value_fn({"kind": "object", "id": inst.id}))
        except ContractError:
            continue
        vis = visible_in_interval(view, tr, t0, t1)
        seen.append({"id": inst.id, "path_m": round(path, 6), **vis})
        if vis["n_visible"]:
            cands.append({"id": inst.id, "track": tr, "path_m": path, "value_si": value, **vis})
    ev["n_covering_and_visible"] = len(cands)
    if ref.phrase.motion == "static":
        wanted = [c for c in cands if c["path_m"] < min_motion]
        ev["motion_cue"] = "static"
    elif presupposes_motion or ref.phrase.motion == "moving":
        wanted = [c for c in cands if c["path_m"] >= min_motion]
        ev["motion_cue"] = "moving (presupposed by the question)" if presupposes_motion else "moving"
    else:
        wanted = cands
    if presupposes_motion and not wanted:
        # the question needs a moving object: a static one in view is not its referent
        moving_unseen = [s_ for s_ in seen if s_["path_m"] >= min_motion and not s_["n_visible"]]
        reason, defect = ("not_visible_at_frame", "not_visible") if moving_unseen else ("no_source_instance",
                                                                                        "no_source_instance")
        raise Exclude(reason, defect=defect, **ev, t=[t0, t1], camera=view.camera, covering_tracks=seen,
                      note="no moving track of the described class is seen by the camera during the interval")
    if not cands:
        raise Exclude("not_visible_at_frame", defect="not_visible", **ev, t=[t0, t1], camera=view.camera,
                      covering_tracks=seen,
                      note="no track of the described class covers the interval and is seen by the camera")
    cands = wanted or cands
    ev["n_after_motion_cue"] = len(cands)
    if len(cands) > 1:
        enabled = tie_break_enabled(params, "Waymo")
        k, tev = tie_break_by_legacy([c["id"] for c in cands], [c["value_si"] for c in cands], legacy, unit, rule,
                                     enabled=enabled)
        ev["referent"] = tev
        if k is None:
            vals = [c["value_si"] for c in cands]
            raise Exclude("ambiguous_instance", defect="multiple_instances", **ev,
                          candidates=[c["id"] for c in cands], value_spread_si=round(float(max(vals) - min(vals)), 6))
        cands = [cands[k]]
    c = cands[0]
    tr = c["track"]
    ev.update({"id": c["id"], "visible_samples": c["n_visible"], "samples": c["n_samples"],
               "track": tr.name, "subject": f"object {c['id']}",
               "transform_chain": "T_world<-box = world_from_vehicle(frame) [yaw(heading) | centre]; "
                                  "position = box centre"})
    return Subject("object", tr, "", ev, {"kind": "object", "id": c["id"], "label": noun, "type": tr.meta.get("type")},
                   [str(view.seq.path("lidar_box")), str(view.seq.path("vehicle_pose"))])


def ambiguous_subject(view: SceneView, desc: str | None, t0: float, t1: float,
                      value_fn: Callable[[dict], float], params: dict) -> Subject:
    """A bare "the car": excluded when a tracked vehicle moves, else the camera (the evidence says so)."""
    cam = camera_subject(view)
    ev = {"description": desc, "subjects": ["camera (recording vehicle)", "tracked vehicles"]}
    try:
        ev["camera_value_si"] = round(float(value_fn(cam.entity)), 6)
    except ContractError as e:
        ev["camera_error"] = str(e)
    objs = []
    if view.source == "Waymo":
        head = view.resolve(desc).head
        noun = head.split()[-1] if head else "car"
        typ, rng = WAYMO_NOUNS.get(noun if noun in GENERIC_NOUNS else "car")
        min_motion = float(params["min_motion_m"])
        for inst in view.all_instances():
            if inst.label != typ or not size_fits(inst.dims, rng):
                continue
            tr = _track(view, inst.id)
            if not _covers(tr, t0, t1):
                continue
            try:
                path, _ = G.path_length(tr, t0, t1, tol=float(setting(params, "time_tol")), gaps="skip")
                if path < min_motion:
                    continue
                objs.append({"id": inst.id, "value_si": round(float(value_fn({"kind": "object", "id": inst.id})), 6),
                             "path_m": round(path, 6),
                             "visible_samples": visible_in_interval(view, tr, t0, t1)["n_visible"]})
            except ContractError:
                continue
    ev.update({"object_candidates": objs, "n_object_candidates": len(objs)})
    if objs:
        raise Exclude("ambiguous_subject", **ev)
    cam.evidence.update({"subject_resolution": "no tracked vehicle moves in view during the interval: the "
                                               "recording vehicle's camera is the only candidate", **ev})
    return cam


# ------------------------------------------------------------------------ unnamed statistics


def reading_per_source(rows: list[tuple[str, dict]], names: dict[str, str], default: str,
                       mixed_share: float) -> dict[str, dict]:
    """Per source: the reading of the legacy rows whose question leaves the statistic open.

    ``rows``: ``(source, {reading: legacy agrees})`` per such row, two readings (``names`` gives
    their short names for the counts, e.g. ``{"average_velocity": "velocity", ...}``). The reading
    of a source is the one matched by the majority of its rows that match exactly one; ``default``
    when they tie. A source is *mixed* when the minority reading has at least ``mixed_share`` of
    those rows; there each such row keeps its own reading.
    """
    a, b = list(names)
    out: dict[str, dict] = {}
    for source, match in rows:
        d = out.setdefault(source, {"n_rows": 0, f"n_{names[a]}_only": 0, f"n_{names[b]}_only": 0, "n_both": 0,
                                    "n_neither": 0})
        d["n_rows"] += 1
        key = {(True, False): f"n_{names[a]}_only", (False, True): f"n_{names[b]}_only", (True, True): "n_both",
               (False, False): "n_neither"}[(bool(match[a]), bool(match[b]))]
        d[key] += 1
    for d in out.values():
        na, nb = d[f"n_{names[a]}_only"], d[f"n_{names[b]}_only"]
        lo, hi = sorted((na, nb))
        d["mixed"] = bool(hi and lo / (lo + hi) >= mixed_share)
        if na > nb:
            d["statistic"], d["decided_by"] = a, "majority of discriminating rows"
        elif nb > na:
            d["statistic"], d["decided_by"] = b, "majority of discriminating rows"
        else:
            d["statistic"], d["decided_by"] = default, "undetermined: params default_statistic"
    return out


def row_reading(match: dict, group: dict) -> tuple[str, bool, dict]:
    """The reading of one row in its source (:func:`reading_per_source`): ``(reading, determined,
    evidence)``; ``determined`` is false when only the params default decided it."""
    own = [k for k, m in match.items() if m]
    majority = group["decided_by"].startswith("majority")
    determined = majority or len(own) == 1
    reading = own[0] if (len(own) == 1 and (group["mixed"] or not majority)) else group["statistic"]
    ev = {"row_statistic": ("matched one statistic" if len(own) == 1 else
                            "matched both (the source's statistic)" if own else
                            "matched neither (the source's statistic)")}
    if len(own) == 1 and reading != own[0]:
        ev["coincidence"] = (f"the legacy value also agrees with {own[0]}, a chance agreement in a source whose "
                             f"rows use {reading}")
    return reading, determined, ev
