"""Spatial Relation: mounted-camera directions (Waymo) and object-pair relations (Omni6DPose).

Waymo (:func:`mount_relation`)
------------------------------
"What is the orientation of the camera mounted on the moving car relative to the car's forward
direction?" The camera's optical axis (Waymo camera +X) in the vehicle frame, from the calibration
extrinsic ``T_vehicle<-cam``, gives a yaw; the label is the nearest of Front (0°), Front-Left
(45°), Front-Right (-45°), Left (90°, SIDE_LEFT), Right (-90°, SIDE_RIGHT). The camera *name* is
only a cross-check: the evidence carries both, and the calibration decides. A yaw within
``mount_margin_deg`` of a bin edge is not dominant (exclusion ``no_dominant_relation``).

Omni6DPose (:func:`relative_position`)
--------------------------------------
"What is the position of A relative to B at t?" Both referents are resolved in the ROPE scene by
the class named in their head noun phrase (one instance each, else ``no_source_instance`` /
``ambiguous_instance`` / ``grouped_referent``; phrase reading shared with the scalar tasks in
:mod:`resti_lib.tasks.referents`) and must be annotated and visible at the asked frame (frustum test
of the box with the frame's intrinsics, ``min_visible_fraction`` of its points in view, else
``not_visible_at_frame``). From camera-frame geometry at that
frame, with ``d = c_A - c_B`` (OpenCV axes):

- **Directly above**: A's centre lies over B's box footprint and above its top face (B's box axis
  closest to the scene up is the vertical one; up = the scene's +Z in the camera frame);
- else **Left/Right** when ``|d_x| >= dominance_ratio * |d_z|`` (sign of ``d_x``), **Closer/Farther**
  when ``|d_z| >= dominance_ratio * |d_x|`` (sign of ``d_z``);
- else no relation dominates: excluded ``no_dominant_relation`` with the margins as evidence.

Options are the fixed five labels of the source (``label_options``), so the label prior of a
task/source (the attack ``label_prior``) cannot be removed by the options: it is reported.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from .. import values as V
from ..adjudicate import verdict_for
from ..contract import parse_question
from ..errors import ContractError, InputError
from ..figures import save_figure
from ..measure import MeasureContext, register_operator
from . import referents as R
from .base import AnswerSpec, Outcome

TASK = "Spatial Relation"
MOUNT_LABELS = ["Front", "Front-Left", "Front-Right", "Left", "Right"]
OMNI_LABELS = ["Left", "Right", "Closer", "Farther", "Directly above"]
LABELS = {"Waymo": MOUNT_LABELS, "Omni6DPose": OMNI_LABELS}
#: Bin centres of the mounted-camera labels (yaw of the optical axis in the vehicle frame, degrees).
MOUNT_CENTRES = {"Front": 0.0, "Front-Left": 45.0, "Front-Right": -45.0, "Left": 90.0, "Right": -90.0,
                 "Back": 180.0, "Back-Left": 135.0, "Back-Right": -135.0}
#: What the camera *name* would say (CameraName enum 1..5).
NAME_LABEL = {1: "Front", 2: "Front-Left", 3: "Front-Right", 4: "Left", 5: "Right"}

#: Defaults of the task parameters (``params/relation.yaml`` overrides them).
DEFAULTS = {
    "dominance_ratio": 1.5,
    "mount_margin_deg": 5.0,
    "omni6d_up": [0.0, 0.0, 1.0],
    "near_m": 0.05,
    "far_m": 5.0,
    "min_visible_fraction": 0.5,
}


def _p(params: dict, key: str):
    v = params.get(key)
    return DEFAULTS[key] if v is None else v


def _circ(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


# ------------------------------------------------------------------------------------ operators


def mount_relation(extrinsic: np.ndarray, *, margin_deg: float = 5.0) -> tuple[str | None, dict]:
    """Direction label of a mounted camera from ``T_vehicle<-cam`` (Waymo camera axes, +X optical).

    Returns the nearest bin label (45° bins centred on the label directions) or None when the yaw
    lies within ``margin_deg`` of a bin edge; evidence: ``yaw_deg``, ``label``, ``edge_margin_deg``.
    """
    E = np.asarray(extrinsic, float)
    f = E[:3, :3] @ np.array([1.0, 0.0, 0.0])
    yaw = math.degrees(math.atan2(f[1], f[0]))
    dist = {k: _circ(yaw, c) for k, c in MOUNT_CENTRES.items()}
    label = min(dist, key=dist.get)
    margin = 22.5 - dist[label]
    ev = {"yaw_deg": yaw, "optical_axis_vehicle": f.tolist(), "nearest_label": label,
          "edge_margin_deg": margin, "required_margin_deg": float(margin_deg),
          "rule": "nearest of Front 0, Front-Left 45, Front-Right -45, Left 90, Right -90 (deg, vehicle +X "
                  "forward, +Y left)"}
    return (label if margin >= margin_deg else None), ev


def relative_position(c_a: np.ndarray, c_b: np.ndarray, R_b: np.ndarray, lwh_b: np.ndarray, up: np.ndarray, *,
                      dominance_ratio: float = 1.5) -> tuple[str | None, dict]:
    """Dominant relation of A relative to B from camera-frame geometry (rules in the module docstring).

    Parameters
    ----------
    c_a, c_b : centres of A and B in the camera frame (OpenCV axes, metres).
    R_b, lwh_b : B's box rotation ``R_cam<-box`` and side lengths (box-local x, y, z).
    up : the scene up direction in the same camera frame.

    Returns
    -------
    label or None, evidence (offsets, margins, the footprint test).
    """
    d = np.asarray(c_a, float) - np.asarray(c_b, float)
    up = np.asarray(up, float) / np.linalg.norm(up)
    R_b = np.asarray(R_b, float)
    lwh_b = np.asarray(lwh_b, float)
    db = R_b.T @ d
    ub = R_b.T @ up
    v = int(np.argmax(np.abs(ub)))
    hz = [i for i in range(3) if i != v]
    above_top = float(np.sign(ub[v]) * db[v] - 0.5 * lwh_b[v])
    footprint = [float(abs(db[i]) - 0.5 * lwh_b[i]) for i in hz]
    lat, dep = abs(float(d[0])), abs(float(d[2]))
    big, small = max(lat, dep), min(lat, dep)
    ev = {"dx": float(d[0]), "dy": float(d[1]), "dz": float(d[2]), "lateral_m": lat, "depth_m": dep,
          "dominance": (big / small) if small > 0 else float("inf"), "required_ratio": float(dominance_ratio),
          "margin_m": big - dominance_ratio * small, "height_above_top_m": above_top,
          "footprint_excess_m": footprint, "up_camera": up.tolist()}
    if above_top >= 0 and all(x <= 0 for x in footprint):
        return "Directly above", ev
    if lat >= dominance_ratio * dep:
        return ("Right" if d[0] > 0 else "Left"), ev
    if dep >= dominance_ratio * lat:
        return ("Farther" if d[2] > 0 else "Closer"), ev
    return None, ev


# ----------------------------------------------------------------------------- referents (ROPE)


def match_referent(description: str, instances: dict[str, dict]) -> dict:
    """Resolve a description to scene instances by the class named in its head noun phrase
    (:func:`resti_lib.tasks.referents.read_phrase` and ``match_labels``).

    Returns ``{"status": "ok"|"no_source_instance"|"ambiguous_instance"|"grouped_referent",
    "label", "oids", "n_instances", "head"}``.
    """
    ph = R.read_phrase(description)
    classes = sorted({e["class_name"] for e in instances.values()})
    label, plural, mev = R.match_labels(ph, classes)
    oids = sorted(k for k, e in instances.items() if e["class_name"] == label) if label else []
    out = {"label": label, "oids": oids, "n_instances": len(oids), "head": ph.head, "description": description}
    if label is None:
        out["status"] = "no_source_instance"
    elif ph.grouped or plural:
        out["status"] = "grouped_referent"
        out["group_marker"] = ph.grouped or f"plural: {mev.get('matched')}"
    elif len(oids) > 1:
        out["status"] = "ambiguous_instance"
    else:
        out["status"] = "ok"
    return out


# ------------------------------------------------------------------------------------- the task


def question_text(source: str, *, a: str | None = None, b: str | None = None, t: float = 0.0) -> str:
    """The rewritten question (v5 wording, frame and rule stated)."""
    if source == "Waymo":
        return ("What is the orientation of the camera mounted on the moving car relative to the car's forward "
                "direction? The answer is the horizontal direction of the camera's optical axis in the car's "
                "frame.")
    return (f"Viewed from the camera at t={V.format_seconds(t)} s: relative to the {b}, is the {a} to the left, to the right, "
            f"closer to the camera, farther from the camera, or directly above? Choose the single dominant "
            f"relation. Left and right are along the image's horizontal axis, closer and farther along the "
            f"camera's optical axis.")


def _new(r: dict) -> Outcome:
    return Outcome(row=int(r["row"]), key=r["Legacy Row Key"], task=TASK, source=str(r["Source"]),
                   video=str(r["Video"]), legacy_id=r.get("ID"), verdict="retained",
                   legacy_detail=str(r.get("Answer Detail")))


def _adjudicate(o: Outcome, r: dict, label: str) -> None:
    try:
        legacy = V.parse(r.get("Answer Detail"), row=o.row, field="Answer Detail")
        comparable = isinstance(legacy, V.Label)
    except InputError as e:
        legacy, comparable = None, False
        o.evidence["legacy_unreadable"] = str(e)
    agrees = comparable and legacy.key() == V.Label(label).key()
    o.evidence["comparison"] = {"rule": "same label (case and spacing ignored)", "legacy": r.get("Answer Detail"),
                                "source": label, "agrees": bool(agrees)}
    if comparable and not agrees:
        o.defects.append("value_mismatch")
    o.verdict = verdict_for(comparable, agrees if comparable else None)


def _audit_waymo(o: Outcome, r: dict, c, vs, ctx, params: dict) -> Outcome:
    if c.operator != "mounted_relation" or vs.camera is None:
        return o.exclude("unsupported_question", detail="Waymo relation rows must ask about the mounted camera",
                         operator=c.operator)
    seg = ctx.waymo(vs.sequence)
    cal = seg.camera_calibration(vs.camera)
    o.source_files = [str(seg.path("camera_calibration"))]
    o.transform_chain = "extrinsic(camera) = T_vehicle<-cam; optical axis = R @ [1, 0, 0] (Waymo camera +X)"
    o.frames = {"camera": int(vs.camera), "calibration_row": cal.get("row")}
    label, ev = mount_relation(cal["extrinsic"], margin_deg=float(_p(params, "mount_margin_deg")))
    ev["name_label"] = NAME_LABEL.get(int(vs.camera))
    ev["name_agrees_with_calibration"] = ev["name_label"] == ev["nearest_label"]
    o.evidence["mount"] = ev
    c.entity = {"kind": "camera", "camera": int(vs.camera)}
    c.frame = "vehicle frame (+X forward, +Y left, +Z up)"
    o.contract = c.to_dict()
    if label is None:
        return o.exclude("no_dominant_relation", yaw_deg=ev["yaw_deg"], edge_margin_deg=ev["edge_margin_deg"],
                         required_margin_deg=ev["required_margin_deg"], camera=int(vs.camera))
    if label not in MOUNT_LABELS:
        return o.exclude("unsupported_question", detail=f"camera faces {label}, not one of the five labels",
                         yaw_deg=ev["yaw_deg"])
    _adjudicate(o, r, label)
    o.question = question_text("Waymo")
    o.prompt = ""
    o.time_start, o.time_end = float(r.get("time_start") or 0.0), float(r.get("time_end") or 0.0)
    o.answer = AnswerSpec(kind="label", value=label, labels=list(MOUNT_LABELS))
    return o


def _audit_omni(o: Outcome, r: dict, c, vs, ctx, params: dict) -> Outcome:
    descs = (c.entity or {}).get("descriptions")
    if c.operator != "relative_position" or not descs:
        return o.exclude("unsupported_question", detail="no object pair in the question", operator=c.operator)
    rp = ctx.rope(vs.sequence)
    o.source_files = [str(rp.dir), str(rp.obj_meta_path)]
    o.transform_chain = "c_X = T_cam<-obj(frame) translation (OpenCV); up_cam = R_c0<-cam^T R_c0<-scene e_z"
    t = float(c.times[0]) if c.times else float(r.get("time_start") or 0.0)
    refs = [match_referent(d, R.omni_instances(rp)) for d in descs]
    o.evidence["referents"] = refs
    c.entity = {"kind": "object_pair", "descriptions": list(descs),
                "ids": [x["oids"][0] if x["status"] == "ok" else None for x in refs]}
    c.times = [t]
    o.frames = {"t": t}
    bad = [x for x in refs if x["status"] != "ok"]
    if bad:
        o.contract = c.to_dict()
        reasons = list(dict.fromkeys(x["status"] for x in bad))
        return o.exclude(*reasons, labels=[x["label"] for x in refs], n_instances=[x["n_instances"] for x in refs],
                         t=t)
    try:
        frame = R.frame_of_time(t, rp.fps, rp.frames)
    except ContractError as e:
        o.contract = c.to_dict()
        return o.exclude("not_visible_at_frame", t=t, detail=str(e))
    c.frame = f"OpenCV camera frame at t={V.format_seconds(t)} s (frame {frame})"
    o.contract = c.to_dict()
    o.frames = {"frame": frame, "t": t}
    intr = rp.intrinsics(frame)
    here = {b.id: b for b in R.omni_boxes_at(rp, frame)}
    boxes, vis = [], []
    for x in refs:
        b = here.get(x["oids"][0])
        if b is None:
            vis.append({"oid": x["oids"][0], "visible": False, "reason": "not annotated in the frame"})
            boxes.append(None)
            continue
        v = R.box_visibility(b.box, intr, near=float(_p(params, "near_m")), far=float(_p(params, "far_m")),
                             min_fraction=float(_p(params, "min_visible_fraction")))
        vis.append({"oid": x["oids"][0], **v})
        boxes.append(b.box)
    o.evidence["visibility"] = vis
    if not all(v["visible"] for v in vis):
        return o.exclude("not_visible_at_frame", frame=frame, labels=[x["label"] for x in refs],
                         visibility=vis)
    track = rp.camera_track(rebase=True)
    k = int(np.argmin(np.abs(track.times - frame / rp.fps)))
    up_c0 = rp.world_up_in_track_frame(np.asarray(_p(params, "omni6d_up"), float))
    up = track.T[k, :3, :3].T @ up_c0
    A, B = boxes
    label, ev = relative_position(A.center, B.center, B.R, B.lwh, up,
                                  dominance_ratio=float(_p(params, "dominance_ratio")))
    o.evidence["relation"] = ev
    if label is None:
        return o.exclude("no_dominant_relation", labels=[x["label"] for x in refs], frame=frame,
                         dx=ev["dx"], dy=ev["dy"], dz=ev["dz"], lateral_m=ev["lateral_m"], depth_m=ev["depth_m"],
                         dominance=ev["dominance"], required_ratio=ev["required_ratio"])
    _adjudicate(o, r, label)
    o.question = question_text("Omni6DPose", a=descs[0], b=descs[1], t=t)
    o.prompt = ""
    o.time_start = o.time_end = t
    o.answer = AnswerSpec(kind="label", value=label, labels=list(OMNI_LABELS))
    return o


def audit_row(r: dict, ctx, params: dict) -> Outcome:
    """One legacy row -> Outcome (see :func:`audit`)."""
    o = _new(r)
    c = parse_question(r, video_map=ctx.video_map)
    vs = ctx.locate(r["Video"])
    if vs.source == "Waymo":
        return _audit_waymo(o, r, c, vs, ctx, params)
    if vs.source == "Omni6DPose":
        return _audit_omni(o, r, c, vs, ctx, params)
    return o.exclude("unsupported_question", detail=f"no relation contract for {vs.source}")


def audit(rows: pd.DataFrame, ctx, params: dict) -> list[Outcome]:
    """Task-module entry point: one :class:`Outcome` per legacy Spatial Relation row."""
    return [audit_row(r, ctx, params) for r in rows.to_dict("records")]


# ---------------------------------------------------------------------------------- reporting


def diagnosis_table(outcomes: list[Outcome]) -> pd.DataFrame:
    """Per row: the label, the mount yaw and edge margin (Waymo) or the offsets and dominance (Omni)."""
    recs = []
    for o in outcomes:
        m, rel = o.evidence.get("mount"), o.evidence.get("relation")
        rec = {"row": o.row, "source": o.source, "video": o.video, "verdict": o.verdict,
               "reasons": ",".join(o.reasons), "legacy": o.legacy_detail,
               "label": o.answer.value if o.answer is not None else None}
        if m:
            rec.update({"yaw_deg": m["yaw_deg"], "edge_margin_deg": m["edge_margin_deg"],
                        "name_label": m["name_label"], "name_agrees": m["name_agrees_with_calibration"]})
        if rel:
            rec.update({"dx": rel["dx"], "dz": rel["dz"], "dominance": rel["dominance"],
                        "margin_m": rel["margin_m"], "height_above_top_m": rel["height_above_top_m"]})
        recs.append(rec)
    return pd.DataFrame(recs)


def label_counts(outcomes: list[Outcome]) -> pd.DataFrame:
    """Answer-label counts per source among accepted rows (the prior the label attack exploits)."""
    df = pd.DataFrame([{"source": o.source, "label": o.answer.value} for o in outcomes
                       if o.verdict != "excluded" and o.answer is not None])
    if df.empty:
        return df
    return df.value_counts(["source", "label"]).rename("rows").reset_index()


def plot_margins(table: pd.DataFrame, path: str | Path, *, dominance_ratio: float = 1.5) -> Path:
    """Omni6DPose pairs: |lateral| vs |depth| offsets with the dominance lines; excluded rows marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = table[table["source"] == "Omni6DPose"] if "dx" in table else table.iloc[0:0]
    fig, ax = plt.subplots(figsize=(4.2, 4.0))
    if len(t) and "dx" in t:
        t = t[t["dx"].notna()]
        lim = float(max(t["dx"].abs().max(), t["dz"].abs().max(), 0.05)) * 1.15
        xs = np.linspace(0, lim, 10)
        ax.plot(xs, xs / dominance_ratio, "k--", lw=0.7)
        ax.plot(xs / dominance_ratio, xs, "k--", lw=0.7)
        ax.fill_between(xs, xs / dominance_ratio, np.minimum(xs * dominance_ratio, lim), color="#eeeeee")
        exc = t["verdict"] == "excluded"
        ax.scatter(t.loc[~exc, "dx"].abs(), t.loc[~exc, "dz"].abs(), s=16, color="#2c7fb8", label="dominant")
        ax.scatter(t.loc[exc, "dx"].abs(), t.loc[exc, "dz"].abs(), s=22, marker="x", color="#d95f0e",
                   label="no dominant relation")
        ax.set_xlim(0, lim)
        ax.set_ylim(0, lim)
        ax.legend(frameon=False, fontsize=7)
    ax.set_xlabel("|lateral offset| along camera x [m]")
    ax.set_ylabel("|depth offset| along camera z [m]")
    ax.set_title(f"Omni6DPose pairs; grey: neither exceeds {dominance_ratio:g}x the other", fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


# ----------------------------------------------------------------------------- measure operators


@register_operator("mounted_relation", unit=None, n_times=(1, 2))
def _op_mounted_relation(mctx: MeasureContext) -> tuple[str, dict]:
    """Waymo: direction label of the contract's camera relative to the vehicle's forward axis."""
    if mctx.source != "Waymo" or mctx.camera in (None, ""):
        raise ContractError("mounted_relation needs a Waymo contract with a camera")
    cal = mctx.scene.camera_calibration(mctx.camera)
    label, ev = mount_relation(cal["extrinsic"], margin_deg=float(mctx.params.get("mount_margin_deg", 5.0)))
    if label is None:
        raise ContractError(f"no dominant mounted direction (yaw {ev['yaw_deg']:.1f} deg)")
    return label, ev


@register_operator("relative_position", unit=None, n_times=(1,))
def _op_relative_position(mctx: MeasureContext) -> tuple[str, dict]:
    """Omni6DPose: relation of object ``entity.id`` relative to ``entity.reference`` at ``times[0]``."""
    if mctx.source != "Omni6DPose" or mctx.entity.get("reference") is None:
        raise ContractError("relative_position needs an Omni6DPose object entity with 'id' and 'reference'")
    rp = mctx.scene
    frame = round(mctx.t0 * rp.fps)
    here = {x.id: x.box for x in R.omni_boxes_at(rp, frame)}
    a, b = here.get(str(mctx.entity["id"])), here.get(str(mctx.entity["reference"]))
    if a is None or b is None:
        raise ContractError(f"object not annotated at frame {frame}")
    track = rp.camera_track(rebase=True)
    k = int(np.argmin(np.abs(track.times - frame / rp.fps)))
    up = track.T[k, :3, :3].T @ rp.world_up_in_track_frame(np.asarray(mctx.params.get("omni6d_up", [0, 0, 1]),
                                                                        float))
    label, ev = relative_position(a.center, b.center, b.R, b.lwh, up,
                                  dominance_ratio=float(mctx.params.get("dominance_ratio", 1.5)))
    if label is None:
        raise ContractError(f"no dominant relation (dominance {ev['dominance']:.2f})")
    ev["frame"] = frame
    return label, ev


__all__ = [
    "DEFAULTS",
    "LABELS",
    "MOUNT_LABELS",
    "OMNI_LABELS",
    "TASK",
    "audit",
    "audit_row",
    "diagnosis_table",
    "label_counts",
    "match_referent",
    "mount_relation",
    "plot_margins",
    "question_text",
    "relative_position",
]
