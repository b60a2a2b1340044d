"""Dimensional Measurement: one named dimension, camera-to-box distance, box-to-box distance.

Contract per operator (the rewritten question states each part):

``dimension``
    One edge length of the matched instance's box. ScanNet: the gravity-upright oriented box of
    the instance's mesh vertices in the annotation frame (height vertical; length and width the
    larger and smaller horizontal extents). Waymo: the LiDAR box at the asked frame (length =
    size.x along the heading, width = size.y across it, height = size.z). Omni6DPose:
    ``scale * dimensions`` of the object meta along the object's own x, y, z box axes.
``distance_to_camera``
    Distance from the camera's optical centre to the nearest point of the solid box at the asked
    time (0 inside the box); the referent must be visible in that frame (frustum test with the
    frame's intrinsics, :func:`resti_lib.tasks.referents.box_visibility`).
``object_distance``
    Minimum Euclidean distance between the two solid oriented boxes
    (:func:`resti_lib.tasks.referents.box_box_distance`; 0 when they touch or overlap).

ScanNet box convention (diagnosed per task, as Speed diagnoses its statistic): every ScanNet value
is computed under the tight gravity-upright box (footprint = minimum-area rectangle; length and
width its longer and shorter horizontal sides) and under the axis-aligned box in the annotation
frame (length / width = extents along the annotation frame's x / y axes, the box of 3D grounding
datasets). The legacy convention is the one matched by the majority of the rows that match exactly
one of the two; a row whose legacy value agrees only under it is *re-contracted* (the clarified
question states the tight box), one that agrees only under the other convention is a chance
agreement (*corrected*, noted). With no majority each row keeps its own match. The counts and the
decision are in every ScanNet row's evidence (``box_convention``).

Referents: the description's head noun must name exactly one source instance (ScanNet and
Omni6DPose: among the sequence's instances of that label; Waymo: among the boxes of the noun's
type and size class visible in the video's camera at the asked frame; distances: among the
instances visible at the asked frame). Otherwise the row is excluded with ``grouped_referent``,
``no_source_instance``, ``ambiguous_instance`` (counts, candidate ids and the value spread across
them) or ``not_visible_at_frame`` (visibility per candidate, frame).

``dimension`` and ``distance_to_camera`` are also operators of ``resti measure``
(:mod:`resti_lib.measure`): the functions below are the single code path of both.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pandas as pd

from .. import values as V
from ..adjudicate import verdict_for
from ..contract import parse_question
from ..errors import ContractError
from ..measure import MeasureContext, register_operator
from .base import AnswerSpec, Outcome
from .referents import Instance, SceneView, Snapshot, box_box_distance, read_phrase
from .scalar_audit import (
    Excluded,
    agrees_si,
    compare,
    new_outcome,
    question_defects,
    rule_for,
    scatter_by_source,
    the_phrase,
    tie_break_by_legacy,
    to_unit,
    unit_for,
    value_table,
)

TASK = "Dimensional Measurement"
#: Where the legacy value may decide between candidate instances: Waymo boxes carry only a coarse
#: type, so several boxes of one type in view are the normal case and the legacy value is the only
#: evidence of the box a description was written for. ScanNet / Omni6DPose labels name the object
#: class: several instances of the named class are the benchmark's ambiguity defect.
LEGACY_TIE_BREAK = {"ScanNet": False, "Waymo": True, "Omni6DPose": False}
DIMS = ("length", "width", "height")

DIM_WORDING = {
    "ScanNet": "The box is the object's tight upright bounding box in the gravity-aligned scene frame (its "
               "footprint is the smallest-area rectangle around the object); height is its vertical extent, "
               "length and width are its longer and shorter horizontal sides.",
    "Waymo": "Length, width and height are the box dimensions along its heading, across it, and vertically.",
    "Omni6DPose": "Length, width and height are the edge lengths of its annotated bounding box along the "
                  "object's own x, y and z axes.",
}
CHAIN = {
    "ScanNet": "tight upright box of A·v (annotation frame) -> A^-1 (raw); camera P(t) = T_raw<-cam",
    "Waymo": "T_world<-box = world_from_vehicle(frame) [yaw(heading) | centre]; camera world_from_vehicle @ "
             "extrinsic @ waymo->opencv",
    "Omni6DPose": "T_cam<-obj (frame meta, OpenCV axes); lwh = scale * dimensions",
}


# ------------------------------------------------------------------------------------ operators


def dimension_value(inst: Instance, which: str) -> float:
    """The named edge length (metres) of an instance's box under its source convention."""
    if which not in DIMS:
        raise ContractError(f"unknown dimension {which!r} (length, width, height)")
    return float(inst.dims[DIMS.index(which)])


def camera_distance(view: SceneView, snap: Snapshot, inst: Instance) -> tuple[float, dict]:
    """Camera centre to nearest box point at the snapshot's time (metres) and evidence."""
    d, ev = view.camera_distance(snap, inst)
    ev["geometry"] = "Euclidean distance from the camera optical centre to the nearest point of the solid box"
    return d, ev


def pair_distance(a: Instance, b: Instance) -> tuple[float, dict]:
    """Minimum distance between two boxes given in one frame (metres) and evidence."""
    d, pa, pb = box_box_distance(a.box, b.box)
    return d, {"geometry": "minimum Euclidean distance between the two solid oriented boxes (0 when they "
                           "touch or overlap), bounded least squares over box-local coordinates",
               "nearest_points": [pa.tolist(), pb.tolist()]}


def _measure_view(ctx: MeasureContext) -> SceneView:
    cam = None
    if ctx.source == "Waymo":
        from ..sources.waymo import camera_number

        cam = camera_number(ctx.camera) if ctx.camera not in (None, "") else None
    return SceneView(ctx.source, ctx.scene, cam, vis=ctx.params.get("visibility"))


def _instance_at(view: SceneView, inst_id, t: float | None) -> tuple[Instance, Snapshot | None]:
    if view.source == "ScanNet" or (view.source == "Omni6DPose" and t is None):
        for i in view.all_instances():
            if i.id == str(inst_id):
                return i, None
        raise ContractError(f"{view.source} {view.name}: no object with id {inst_id!r}")
    snap = view.snapshot(t)
    for i in snap.instances:
        if i.id == str(inst_id):
            return i, snap
    raise ContractError(f"{view.source} {view.name}: object {inst_id!r} is not annotated at t={t} s")


@register_operator("dimension", unit=None, n_times=(1, 2))
def _op_dimension(ctx: MeasureContext):
    """``{"length", "width", "height"}`` (m) of the object's box (source conventions in the evidence)."""
    if ctx.entity.get("kind") != "object":
        raise ContractError("dimension needs an object entity")
    view = _measure_view(ctx)
    t = ctx.t0 if view.source == "Waymo" else None
    inst, _ = _instance_at(view, ctx.entity["id"], t)
    value = {k: dimension_value(inst, k) for k in DIMS}
    return value, {"convention": inst.dims_rule, "label": inst.label, "frame": inst.frame,
                   "transform_chain": CHAIN[view.source]}


@register_operator("distance_to_camera", unit="m", n_times=(1,))
def _op_distance_to_camera(ctx: MeasureContext):
    """Distance (m) from the camera centre to the nearest point of the object's box at ``times[0]``."""
    if ctx.entity.get("kind") != "object":
        raise ContractError("distance_to_camera needs an object entity")
    view = _measure_view(ctx)
    if view.source == "Waymo" and view.camera is None:
        raise ContractError("Waymo distance_to_camera needs 'camera' (FRONT ... or 1-5)")
    snap = view.snapshot(ctx.t0)
    inst = next((i for i in snap.instances if i.id == str(ctx.entity["id"])), None)
    if inst is None:
        raise ContractError(f"object {ctx.entity['id']!r} is not annotated at t={ctx.t0} s")
    d, ev = camera_distance(view, snap, inst)
    ev.update({"visibility": view.visibility(snap, inst), "snapshot": snap.evidence,
               "transform_chain": CHAIN[view.source]})
    return d, ev


# ----------------------------------------------------------------------------------------- audit


def _resolve_label(view: SceneView, desc: str | None):
    """Phrase, label and predicate of a description; raises Excluded for groups / no source label."""
    ph = read_phrase(desc)
    label, plural, mev, pred = view.matcher(ph)
    if ph.grouped or plural:
        raise Excluded("grouped_referent", "grouped_referent", phrase=desc, marker=ph.grouped or f"plural: "
                        f"{mev.get('matched')}", label=label)
    if label is None or not any(pred(i) for i in view.all_instances()):
        raise Excluded("no_source_instance", "no_source_instance", phrase=desc, head=ph.head, label=label,
                        labels_in_sequence=view.labels(), **({"noun_class": mev} if view.source == "Waymo" else {}))
    return ph, label, pred, mev


def _visible_candidates(view: SceneView, snap: Snapshot, pred) -> tuple[list, list, list[dict]]:
    cands = [i for i in snap.instances if pred(i)]
    vis = [view.visibility(snap, i) for i in cands]
    visible = [i for i, v in zip(cands, vis) if v["visible"]]
    return cands, visible, vis


def _tie_break(view: SceneView, pool: list, values: list[float], o: Outcome, params: dict):
    """The legacy value as a tie-breaker among candidates (params ``legacy_tie_break`` per source)."""
    tb = params.get("legacy_tie_break", LEGACY_TIE_BREAK)
    enabled = bool(tb.get(view.source, False) if isinstance(tb, dict) else tb)
    return tie_break_by_legacy([i.id for i in pool], values, o.legacy_detail, unit_for(params, view.source),
                               rule_for(params, view.source), enabled=enabled)


def _spread(values: list[float]) -> float:
    return float(max(values) - min(values)) if values else 0.0


def _dimension(o: Outcome, c: dict, view: SceneView, params: dict) -> tuple[float, dict]:
    """The asked edge length (m) of the one instance the description names; raises Excluded."""
    which = c["params"].get("dimension")
    desc = c["entity"].get("description")
    t = float(c["times"][0])
    _ph, label, pred, mev = _resolve_label(view, desc)
    ev: dict = {"label": label, "match": mev}
    if view.source == "Waymo":
        snap = view.snapshot(t)
        cands, visible, vis = _visible_candidates(view, snap, pred)
        ev.update({"t_frame": snap.evidence.get("t_frame"), "n_instances": len(cands),
                   "n_visible_instances": len(visible)})
        if not visible:
            raise Excluded("not_visible_at_frame", "not_visible", t=t,
                           visibility=[{"id": i.id, **v} for i, v in zip(cands, vis)], **ev)
        pool = visible
        o.frames = {"t": t, "t_frame": snap.evidence.get("t_frame"),
                    "frame_timestamp_micros": snap.evidence.get("frame_timestamp_micros")}
        o.source_files = snap.evidence["files"]
    else:
        pool = [i for i in view.all_instances() if pred(i)]
        ev["n_instances"] = len(pool)
        try:
            snap = view.snapshot(t)
            seen = [i for i in snap.instances if pred(i)]
            ev["n_visible_instances"] = sum(view.visibility(snap, i)["visible"] for i in seen)
            ev["frame"] = snap.evidence.get("frame")
            o.frames = {"t": t, "frame": snap.evidence.get("frame")}
            o.source_files = snap.evidence["files"]
        except ContractError as e:
            ev["visibility_note"] = f"no camera at t={t} s: {e}"
    if len(pool) > 1:
        vals = [dimension_value(i, which) for i in pool]
        k, tev = _tie_break(view, pool, vals, o, params)
        if k is None:
            raise Excluded("ambiguous_instance", "multiple_instances", asked=which,
                           candidates=[i.id for i in pool], value_spread_m=round(_spread(vals), 6), **ev, **tev)
        ev["referent"] = tev
        pool = [pool[k]]
    inst = pool[0]
    if view.source == "ScanNet":
        o.source_files = sorted(set(o.source_files) | {v for v in inst.extra["files"].values() if v})
    ev.update({"id": inst.id, "convention": inst.dims_rule, "dims_m": inst.dims.tolist()})
    if "aabb_ann_m" in inst.extra:
        ev["aabb_ann_m"] = inst.extra["aabb_ann_m"]
        ev["box_hypotheses"] = {"tight": dimension_value(inst, which),
                                "axis_aligned": float(inst.extra["aabb_ann_m"][DIMS.index(which)])}
    o.contract["entity"].update({"id": inst.id, "label": inst.label})
    o.contract["frame"] = "object box (" + inst.dims_rule + ")"
    o.transform_chain = CHAIN[view.source]
    return dimension_value(inst, which), ev


def _axis_aligned(view: SceneView, inst: Instance) -> Instance | None:
    """A ScanNet instance with its annotation-frame axis-aligned box (raw frame), or None."""
    if view.source != "ScanNet":
        return None
    src = view.seq.instance(int(inst.id))
    if src.axis_alignment is None:
        return None
    return dataclasses.replace(inst, box=src.aabb_raw)


def _distance(o: Outcome, c: dict, view: SceneView, params: dict) -> tuple[float, dict]:
    """Camera-to-box distance (m) at the asked time of the one visible instance named; raises Excluded."""
    desc = c["entity"].get("description")
    t = float(c["times"][0])
    _ph, label, pred, mev = _resolve_label(view, desc)
    snap = view.snapshot(t)
    cands, visible, vis = _visible_candidates(view, snap, pred)
    frame = snap.evidence.get("frame", snap.evidence.get("t_frame"))
    ev = {"label": label, "match": mev, "frame": frame, "t": t, "n_instances": len(cands),
          "n_visible_instances": len(visible)}
    o.frames = {"t": t, **{k: snap.evidence[k] for k in ("frame", "t_frame", "frame_timestamp_micros")
                          if k in snap.evidence}}
    o.source_files = list(snap.evidence["files"])
    if not visible:
        raise Excluded("not_visible_at_frame", "not_visible",
                        visibility=[{"id": i.id, **v} for i, v in zip(cands, vis)], **ev)
    if len(visible) > 1:
        vals = [camera_distance(view, snap, i)[0] for i in visible]
        k, tev = _tie_break(view, visible, vals, o, params)
        if k is None:
            raise Excluded("ambiguous_instance", "multiple_instances", candidates=[i.id for i in visible],
                           value_spread_m=round(_spread(vals), 6), **ev, **tev)
        ev["referent"] = tev
        visible = [visible[k]]
    inst = visible[0]
    d, dev = camera_distance(view, snap, inst)
    ev.update({"id": inst.id, "visibility": vis[cands.index(inst)], **dev})
    alt = _axis_aligned(view, inst)
    if alt is not None:
        ev["box_hypotheses"] = {"tight": d, "axis_aligned": camera_distance(view, snap, alt)[0]}
    o.contract["entity"].update({"id": inst.id, "label": inst.label})
    o.contract["frame"] = snap.frame
    o.transform_chain = CHAIN[view.source]
    return d, ev


def _pair(o: Outcome, c: dict, view: SceneView, params: dict) -> tuple[float, dict]:
    """Box-to-box minimum distance (m) of the two instances named; raises Excluded."""
    descs = list(c["entity"].get("descriptions") or [])
    t = float(c["times"][0])
    pools, evs = [], []
    for desc in descs:
        ph, label, pred, _mev = _resolve_label(view, desc)
        if view.source == "Waymo":
            snap = view.snapshot(t)
            _, pool, _ = _visible_candidates(view, snap, pred)
            if not pool:
                raise Excluded("not_visible_at_frame", "not_visible", label=label, t=t)
        else:
            pool = [i for i in view.all_instances() if pred(i)]
        pools.append(pool)
        evs.append({"label": label, "n_instances": len(pool), "head": ph.head})
    if len(pools) != 2:
        raise Excluded("unsupported_question", None, descriptions=descs)
    boxes = [[view.world_box(i.id, t) for i in pool] for pool in pools]
    pairs = [(a, b) for a in boxes[0] for b in boxes[1] if a.id != b.id]
    if len(pairs) != 1:
        vals = [pair_distance(a, b)[0] for a, b in pairs]
        raise Excluded("ambiguous_instance", "multiple_instances", labels=[e["label"] for e in evs],
                        n_pairs=len(pairs), value_spread_m=round(_spread(vals), 6),
                        n_instances=[e["n_instances"] for e in evs])
    a, b = pairs[0]
    d, dev = pair_distance(a, b)
    alt = [_axis_aligned(view, x) for x in (a, b)]
    if all(x is not None for x in alt):
        dev["box_hypotheses"] = {"tight": d, "axis_aligned": pair_distance(*alt)[0]}
    o.contract["entity"].update({"ids": [a.id, b.id], "labels": [a.label, b.label]})
    o.contract["frame"] = a.frame
    o.transform_chain = CHAIN[view.source]
    o.frames = {"t": t}
    return d, {"labels": [e["label"] for e in evs], "ids": [a.id, b.id], "frame": a.frame, **dev}


BOX_CONVENTIONS = {
    "tight": "tight gravity-upright box (footprint = minimum-area rectangle; length / width = its longer / "
             "shorter horizontal side)",
    "axis_aligned": "axis-aligned box in the annotation frame (length / width = extents along the annotation "
                    "frame's x / y axes)",
}


def box_convention(pending: list[tuple], mixed_share: float = 0.25) -> dict:
    """The box convention of the legacy ScanNet values: the majority of the rows that match exactly one.

    ``pending``: ``(outcome, matches)`` with ``matches = {"tight": bool, "axis_aligned": bool}``.
    Returns the counts, ``convention`` (``tight`` / ``axis_aligned`` / None when undetermined),
    ``decided_by`` and ``mixed`` (the minority has at least ``mixed_share`` of the discriminating rows).
    """
    d = {"n_rows": len(pending), "n_tight_only": 0, "n_axis_aligned_only": 0, "n_both": 0, "n_neither": 0}
    for _o, m in pending:
        key = {(True, False): "n_tight_only", (False, True): "n_axis_aligned_only", (True, True): "n_both",
               (False, False): "n_neither"}[(m["tight"], m["axis_aligned"])]
        d[key] += 1
    lo, hi = sorted((d["n_tight_only"], d["n_axis_aligned_only"]))
    d["mixed"] = bool(hi and lo / (lo + hi) >= mixed_share)
    if d["n_tight_only"] != d["n_axis_aligned_only"]:
        d["convention"] = "tight" if d["n_tight_only"] > d["n_axis_aligned_only"] else "axis_aligned"
        d["decided_by"] = "majority of discriminating rows"
    else:
        d["convention"], d["decided_by"] = None, "undetermined: each row keeps the convention it matches"
    if d["convention"]:
        d["description"] = BOX_CONVENTIONS[d["convention"]]
    return d


def _adjudicate_boxes(pending: list[tuple], params: dict) -> None:
    """Verdicts of the ScanNet rows under the task's diagnosed box convention (module docstring)."""
    g = box_convention(pending, float(params.get("mixed_share", 0.25)))
    for o, m in pending:
        o.evidence["box_convention"] = dict(g)
        if m["tight"] or not m["axis_aligned"]:
            continue  # agrees under the tight box (verdict as compared), or under neither (corrected)
        if g["convention"] == "tight" and not g["mixed"]:
            o.evidence["coincidence"] = ("the legacy value also agrees with the axis-aligned box, a chance agreement "
                                         "in a task whose rows use the tight box")
            continue
        o.verdict = "re-contracted"
        o.defects = [x for x in o.defects if x != "value_mismatch"]
        hyp = o.evidence["box_hypotheses"]
        o.evidence["legacy_convention"] = (f"{BOX_CONVENTIONS['axis_aligned']}: {hyp['axis_aligned']:.4f} m "
                                           f"(tight box: {hyp['tight']:.4f} m)")


_OTHER_DIMS = re.compile(r"\b(diameter|radius|depth|thickness|volume|circumference|perimeter|area|size)\b",
                         re.IGNORECASE)
_BETWEEN = re.compile(r"\bbetween\s+(.+?)\?", re.IGNORECASE)


def _unsupported(o: Outcome, r: dict) -> Outcome:
    """Exclude a question no operator of the task reads, with the most specific reason."""
    q = " ".join(str(r.get("Question") or "").split())
    m = _OTHER_DIMS.search(q)
    if m:
        return o.exclude("undefined_dimension", asked=m.group(1).lower(), question=q,
                         note="only length, width and height have a box convention")
    b = _BETWEEN.search(q)
    if b and "distance" in q.lower():
        ph = read_phrase(b.group(1))
        words = ph.head.split()
        if ph.grouped or (words and words[-1].endswith("s")):
            o.defects.append("grouped_referent")
            return o.exclude("grouped_referent", phrase=b.group(1), marker=ph.grouped or f"plural: {words[-1]}")
    return o.exclude("unsupported_question", question=q)


def _question(c: dict, source: str, unit: str, t: float) -> str:
    op = c["operator"]
    if op == "dimension":
        return (f"What is the {c['params']['dimension']} of {the_phrase(c['entity'].get('description'))}? "
                f"{DIM_WORDING[source]} (unit: {unit})")
    if op == "distance_to_camera":
        return (f"At t={V.format_seconds(t)} s, what is the distance from the camera to the nearest point of the bounding box "
                f"of {the_phrase(c['entity'].get('description'))}? (unit: {unit})")
    a, b = (c["entity"].get("descriptions") or ["object", "object"])[:2]
    when = f"At t={V.format_seconds(t)} s, what" if source == "Waymo" else "What"
    return (f"{when} is the minimum surface-to-surface distance between the bounding boxes of {the_phrase(a)} and "
            f"{the_phrase(b)}? (unit: {unit})")


def audit(rows: pd.DataFrame, ctx, params: dict) -> list[Outcome]:
    """Dimensional Measurement outcomes, one per legacy row (see the module docstring)."""
    outs = []
    views: dict[str, SceneView] = {}
    pending: list[tuple] = []  # ScanNet rows waiting for the task's box convention
    for r in rows.to_dict("records"):
        o = new_outcome(r, TASK)
        c = parse_question(r, video_map=ctx.video_map).to_dict()
        o.contract = c
        o.defects = question_defects(c)
        outs.append(o)
        op = c["operator"]
        if op not in ("dimension", "distance_to_camera", "object_distance"):
            _unsupported(o, r)
            continue
        video = str(r["Video"])
        if video not in views:
            views[video] = SceneView.open(ctx, video, params)
        view = views[video]
        unit = unit_for(params, o.source)
        t = float(c["times"][0])
        try:
            fn = {"dimension": _dimension, "distance_to_camera": _distance, "object_distance": _pair}[op]
            value, ev = fn(o, c, view, params)
        except Excluded as e:
            e.apply(o)
            continue
        except ContractError as e:
            o.exclude("invalid_pose_at_time", t=t, error=str(e))
            continue
        cmp_ = compare(r.get("Answer Detail"), value, unit, rule_for(params, o.source))
        o.verdict = verdict_for(cmp_["comparable"], cmp_["agrees"])
        if o.verdict == "corrected":
            o.defects.append("value_mismatch")
        if "box_hypotheses" in ev and cmp_["comparable"]:
            rule = rule_for(params, o.source)
            pending.append((o, {k: agrees_si(r.get("Answer Detail"), v, unit, rule)
                                for k, v in ev["box_hypotheses"].items()}))
        o.evidence.update({"operator": op, "value_si": value, "comparison": cmp_, **ev})
        o.contract.update({"unit": unit, "unit_stated": True, "times": [t]})
        o.contract["legacy_missing"], o.contract["missing"] = list(o.contract["missing"]), []
        o.question = _question(c, o.source, unit, t)
        o.prompt = r.get("Prompt") or ""
        if op == "distance_to_camera":
            o.time_start = o.time_end = t
        else:
            o.time_start, o.time_end = float(r["time_start"]), float(r["time_end"])
        o.answer = AnswerSpec("scalar", to_unit(value, unit), unit, int(params.get("decimals", 2)))
    _adjudicate_boxes(pending, params)
    return outs


# --------------------------------------------------------------------------------- notebook aids


def diagnosis(run) -> pd.DataFrame:
    """Per row: operator, legacy and source values (SI), residual, verdict, reasons and defects."""
    return value_table(run.outcomes)


def plot_legacy_vs_source(run, path: str | Path) -> Path:
    """Scatter of legacy against reconstructed values per source (accepted rows)."""
    df = value_table(run.outcomes)
    df = df[df["verdict"] != "excluded"]
    return scatter_by_source(df, path, xlabel="source value (m)", ylabel="legacy value (m)",
                             title="Dimensional Measurement: legacy vs source")


def exclusion_table(run) -> pd.DataFrame:
    """Excluded rows with their reason and the main evidence (counts, spread, frame)."""
    recs = []
    for o in run.outcomes:
        if o.verdict != "excluded":
            continue
        e = o.evidence
        recs.append({"row": o.row, "source": o.source, "reason": ",".join(o.reasons), "label": e.get("label"),
                     "n_instances": e.get("n_instances"), "n_visible": e.get("n_visible_instances"),
                     "value_spread_m": e.get("value_spread_m"), "frame": e.get("frame"),
                     "phrase": e.get("phrase")})
    return pd.DataFrame(recs)
