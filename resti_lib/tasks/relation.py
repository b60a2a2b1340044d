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
``ambiguous_instance`` / ``grouped_referent``; phrase reading of :mod:`resti_lib.sources.referents`) and
must be annotated and visible at the asked frame (frustum test of the box with the frame's
intrinsics, params ``visibility``, else ``not_visible_at_frame``). From camera-frame geometry at
that frame, with ``d = c_A - c_B`` (OpenCV axes):

- **Directly above**: A's centre lies over B's box footprint and above its top face (B's box axis
  closest to the scene up is the vertical one; up = the scene's +Z in the camera frame);
- else **Left/Right** when ``|d_x| >= dominance_ratio * |d_z|`` (sign of ``d_x``), **Closer/Farther**
  when ``|d_z| >= dominance_ratio * |d_x|`` (sign of ``d_z``);
- else no relation dominates: excluded ``no_dominant_relation`` with the margins as evidence.

Both values are the measure operators ``mounted_relation`` and ``relative_position``
(:mod:`resti_lib.measure.relations`).

Options are the fixed five labels of the source in a balanced letter order, so the label prior of
a task/source (the attack ``label_prior``) cannot be removed by the options: it is measured
(:mod:`resti_lib.options.structural`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .. import values as V
from ..adjudicate import Diagnosis
from ..contract import Contract, base_contract, instant, object_pair
from ..errors import ContractError
from ..io.figures import save_figure
from ..measure.relations import NAME_LABEL, mount_relation, relative_position
from ..sources.referents import (
    box_visibility,
    frame_of_time,
    noun_phrase,
    omni_boxes_at,
    omni_instances,
    resolve,
    visibility_rule,
)
from . import register_task
from .base import AnswerSpec, Case, Exclude, Outcome, Task

TASK = "Spatial Relation"
MOUNT_LABELS = ["Front", "Front-Left", "Front-Right", "Left", "Right"]
OMNI_LABELS = ["Left", "Right", "Closer", "Farther", "Directly above"]
LABELS = {"Waymo": MOUNT_LABELS, "Omni6DPose": OMNI_LABELS}
SAME_LABEL = "same label (case and spacing ignored)"


# ----------------------------------------------------------------------------- referents (ROPE)


def match_referent(description: str, instances: dict[str, dict]) -> dict:
    """Resolve a description to scene instances by the class named in its head noun phrase
    (:func:`resti_lib.sources.referents.resolve`).

    Returns ``{"status": "ok"|"no_source_instance"|"ambiguous_instance"|"grouped_referent",
    "label", "oids", "n_instances", "head"}``.
    """
    classes = sorted({e["class_name"] for e in instances.values()})
    ref = resolve(description, "Omni6DPose", classes)
    label = ref.label
    oids = sorted(k for k, e in instances.items() if e["class_name"] == label) if label else []
    out = {"label": label, "oids": oids, "n_instances": len(oids), "head": ref.head, "description": description}
    if label is None:
        out["status"] = "no_source_instance"
    elif ref.grouped:
        out["status"] = "grouped_referent"
        out["group_marker"] = ref.grouped
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


@register_task
class Relation(Task):
    name = TASK
    params_name = "relation"
    notebook = "04_relation"
    order = 3
    answer_kind = "label"
    rule_key = None
    quantity = "relation"
    figures = {
        "margins": ("Spatial Relation, Omni6DPose pairs: lateral against depth offset; grey: no direction dominates "
                    "by the ratio (excluded)."),
    }
    legacy_kind = V.Label
    operators = ("mounted_relation", "relative_position")
    setting_overrides = ("visibility",)  # its own frustum test

    def read_contract(self, row: dict, video_map: dict | None = None) -> Contract:
        c, q = base_contract(row, video_map=video_map)
        pair = object_pair(q)
        if "mounted" in q.lower():
            c.operator, c.entity = "mounted_relation", {"kind": "camera"}
        elif pair:
            c.operator, c.entity = "relative_position", {"kind": "object_pair", "descriptions": list(pair)}
            c.times = instant(c, row)
        return c

    def reconstruct(self, case: Case) -> None:
        if case.source == "Waymo":
            self._waymo(case)
        elif case.source == "Omni6DPose":
            self._omni(case)
        else:
            raise Exclude("unsupported_question", detail=f"no relation contract for {case.source}")

    def _waymo(self, case: Case) -> None:
        c, r = case.contract, case.row
        if c.operator != "mounted_relation" or c.camera is None:
            raise Exclude("unsupported_question", detail="Waymo relation rows must ask about the mounted camera",
                          operator=c.operator)
        seg = case.ctx.waymo(c.sequence)
        case.provenance(files=[str(seg.path("camera_calibration"))],
                        chain="extrinsic(camera) = T_vehicle<-cam; optical axis = R @ [1, 0, 0] (Waymo camera +X)")
        m = case.measure("mounted_relation", {"kind": "camera"}, c.times)
        ev = {k: v for k, v in m.evidence.items() if k != "calibration_row"}
        case.outcome.frames = {"camera": int(c.camera), "calibration_row": m.evidence.get("calibration_row")}
        ev["name_label"] = NAME_LABEL.get(int(c.camera))
        ev["name_agrees_with_calibration"] = ev["name_label"] == ev["nearest_label"]
        case.outcome.evidence["mount"] = ev
        c.entity = {"kind": "camera", "camera": int(c.camera)}
        c.frame = "vehicle frame (+X forward, +Y left, +Z up)"
        label = m.value
        if label is None:
            raise Exclude("no_dominant_relation", yaw_deg=ev["yaw_deg"], edge_margin_deg=ev["edge_margin_deg"],
                          required_margin_deg=ev["required_margin_deg"], camera=int(c.camera))
        if label not in MOUNT_LABELS:
            raise Exclude("unsupported_question", detail=f"camera faces {label}, not one of the five labels",
                          yaw_deg=ev["yaw_deg"])
        case.outcome.prompt = ""
        case.outcome.time_start, case.outcome.time_end = (float(r.get("time_start") or 0.0),
                                                         float(r.get("time_end") or 0.0))
        case.observables.update(subject=f"camera {int(c.camera)}", subject_class="camera")
        case.answer = AnswerSpec(kind="label", value=label, labels=list(MOUNT_LABELS))

    def _omni(self, case: Case) -> None:
        c, r, o, params = case.contract, case.row, case.outcome, case.params
        descs = (c.entity or {}).get("descriptions")
        if c.operator != "relative_position" or not descs:
            raise Exclude("unsupported_question", detail="no object pair in the question", operator=c.operator)
        rp = case.ctx.rope(c.sequence)
        case.provenance(files=[str(rp.dir), str(rp.obj_meta_path)],
                        chain="c_X = T_cam<-obj(frame) translation (OpenCV); up_cam = R_c0<-cam^T R_c0<-scene e_z")
        t = float(c.times[0]) if c.times else float(r.get("time_start") or 0.0)
        refs = [match_referent(d, omni_instances(rp)) for d in descs]
        o.evidence["referents"] = refs
        c.entity = {"kind": "object_pair", "descriptions": list(descs),
                    "ids": [x["oids"][0] if x["status"] == "ok" else None for x in refs]}
        c.times = [t]
        o.frames = {"t": t}
        bad = [x for x in refs if x["status"] != "ok"]
        if bad:
            reasons = list(dict.fromkeys(x["status"] for x in bad))
            raise Exclude(*reasons, labels=[x["label"] for x in refs], n_instances=[x["n_instances"] for x in refs],
                          t=t)
        try:
            frame = frame_of_time(t, rp.fps, rp.frames)
        except ContractError as e:
            raise Exclude("not_visible_at_frame", t=t, detail=str(e)) from None
        c.frame = f"OpenCV camera frame at t={V.format_seconds(t)} s (frame {frame})"
        o.frames = {"frame": frame, "t": t}
        intr = rp.intrinsics(frame)
        here = {b.id: b for b in omni_boxes_at(rp, frame)}
        near, far, min_fraction = visibility_rule(params.get("visibility"), "Omni6DPose")
        vis = []
        for x in refs:
            b = here.get(x["oids"][0])
            if b is None:
                vis.append({"oid": x["oids"][0], "visible": False, "reason": "not annotated in the frame"})
                continue
            v = box_visibility(b.box, intr, near=near, far=far, min_fraction=min_fraction)
            vis.append({"oid": x["oids"][0], **v})
        o.evidence["visibility"] = vis
        if not all(v["visible"] for v in vis):
            raise Exclude("not_visible_at_frame", frame=frame, labels=[x["label"] for x in refs], visibility=vis)
        m = case.measure("relative_position", {"kind": "object_pair", "ids": c.entity["ids"]}, [t])
        ev = {k: v for k, v in m.evidence.items() if k != "frame"}
        o.evidence["relation"] = ev
        if m.value is None:
            raise Exclude("no_dominant_relation", labels=[x["label"] for x in refs], frame=frame,
                          dx=ev["dx"], dy=ev["dy"], dz=ev["dz"], lateral_m=ev["lateral_m"], depth_m=ev["depth_m"],
                          dominance=ev["dominance"], required_ratio=ev["required_ratio"])
        o.prompt = ""
        o.time_start = o.time_end = t
        case.observables.update(subject=noun_phrase(descs[0]), reference=noun_phrase(descs[1]),
                                subject_class=[x["label"] for x in refs])
        case.state["descs"] = descs
        case.answer = AnswerSpec(kind="label", value=m.value, labels=list(OMNI_LABELS))

    def diagnose(self, case: Case) -> None:
        label = case.answer.value
        legacy = case.legacy
        comparable = legacy is not None
        agrees = comparable and legacy.key() == V.Label(label).key()
        case.rule = {"text": SAME_LABEL}
        d = Diagnosis(comparable, agrees if comparable else None, evidence={"comparison": {
            "rule": SAME_LABEL, "legacy": case.detail, "source": label, "agrees": bool(agrees)}})
        if comparable and not agrees:
            d.defects.append("value_mismatch")
        case.diagnosis = d

    def rewrite(self, case: Case) -> str:
        if case.source == "Waymo":
            return question_text("Waymo")
        a, b = case.state["descs"]
        return question_text("Omni6DPose", a=a, b=b, t=case.contract.times[0])


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


__all__ = [
    "LABELS",
    "MOUNT_LABELS",
    "OMNI_LABELS",
    "TASK",
    "Relation",
    "diagnosis_table",
    "label_counts",
    "match_referent",
    "mount_relation",
    "plot_margins",
    "question_text",
    "relative_position",
]
