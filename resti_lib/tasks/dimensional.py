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
    frame's intrinsics, :func:`resti_lib.sources.referents.box_visibility`).
``object_distance``
    Minimum Euclidean distance between the two solid oriented boxes
    (:func:`resti_lib.sources.referents.box_box_distance`; 0 when they touch or overlap).

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

Every value is the measure operator of the same name (:mod:`resti_lib.measure.objects`), the one
``resti measure`` runs: the task resolves the description to instance ids, the operator measures.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pandas as pd

from .. import values as V
from ..adjudicate import Diagnosis, agrees_scalar, compare_scalar
from ..contract import Contract, base_contract, description, instant, object_pair
from ..errors import ContractError
from ..measure.objects import CHAIN, DIMS, camera_distance, pair_distance
from ..sources.referents import Instance, Referent, SceneView, Snapshot, noun_phrase, read_phrase
from . import register_task
from .base import AnswerSpec, Case, Exclude, Task
from .scalar_audit import (
    rule_for,
    scatter_by_source,
    set_rule,
    tie_break_by_legacy,
    tie_break_enabled,
    unit_for,
    value_table,
)

TASK = "Dimensional Measurement"

DIM_WORDING = {
    "ScanNet": "The box is the object's tight upright bounding box in the gravity-aligned scene frame (its "
               "footprint is the smallest-area rectangle around the object); height is its vertical extent, "
               "length and width are its longer and shorter horizontal sides.",
    "Waymo": "Length, width and height are the box dimensions along its heading, across it, and vertically.",
    "Omni6DPose": "Length, width and height are the edge lengths of its annotated bounding box along the "
                  "object's own x, y and z axes.",
}
PATTERNS = (r"bounding box of (?:the |a |an )?(.+?)[.?]?$", r"(?:length|width|height) of (?:the |a |an )?(.+?)\?",
            r"close is the camera to (?:the |a |an )?(.+?)(?: at |\?)")
_OTHER_DIMS = re.compile(r"\b(diameter|radius|depth|thickness|volume|circumference|perimeter|area|size)\b",
                         re.IGNORECASE)
_BETWEEN = re.compile(r"\bbetween\s+(.+?)\?", re.IGNORECASE)


def _spread(values: list[float]) -> float:
    return float(max(values) - min(values)) if values else 0.0


def _axis_aligned(view: SceneView, inst: Instance) -> Instance | None:
    """A ScanNet instance with its annotation-frame axis-aligned box (raw frame), or None."""
    if view.source != "ScanNet":
        return None
    src = view.seq.instance(int(inst.id))
    if src.axis_alignment is None:
        return None
    return dataclasses.replace(inst, box=src.aabb_raw)


BOX_CONVENTIONS = {
    "tight": "tight gravity-upright box (footprint = minimum-area rectangle; length / width = its longer / "
             "shorter horizontal side)",
    "axis_aligned": "axis-aligned box in the annotation frame (length / width = extents along the annotation "
                    "frame's x / y axes)",
}


def box_convention(pending: list[tuple], mixed_share: float) -> dict:
    """The box convention of the legacy ScanNet values: the majority of the rows that match exactly one.

    ``pending``: ``(diagnosis, matches)`` with ``matches = {"tight": bool, "axis_aligned": bool}``.
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
    """Verdicts of the ScanNet rows under the task's diagnosed box convention (module docstring).

    ``pending``: ``(diagnosis, matches)``; a diagnosis has ``verdict``, ``defects`` and ``evidence``
    (with ``box_hypotheses``)."""
    g = box_convention(pending, float(params["mixed_share"]))
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


def unsupported(question: str | None) -> Exclude:
    """The exclusion of a question no operator of the task reads, with the most specific reason."""
    q = " ".join(str(question or "").split())
    m = _OTHER_DIMS.search(q)
    if m:
        return Exclude("undefined_dimension", asked=m.group(1).lower(), question=q,
                       note="only length, width and height have a box convention")
    b = _BETWEEN.search(q)
    if b and "distance" in q.lower():
        ph = read_phrase(b.group(1))
        words = ph.head.split()
        if ph.grouped or (words and words[-1].endswith("s")):
            return Exclude("grouped_referent", defect="grouped_referent", phrase=b.group(1),
                           marker=ph.grouped or f"plural: {words[-1]}")
    return Exclude("unsupported_question", question=q)


@register_task
class Dimensional(Task):
    name = TASK
    params_name = "dimensional"
    notebook = "03_dimensional"
    order = 2
    answer_kind = "scalar"
    quantity = "distance"
    figures = {
        "legacy_vs_source": ("Dimensional Measurement: legacy against source value per source (accepted rows; dashed: equal)."),
    }
    legacy_kind = V.Scalar
    operators = ("dimension", "distance_to_camera", "object_distance")


    def quantity_of(self, question: str) -> str:
        """``length``, ``width`` or ``height`` of an object, its ``distance_to_camera``, the
        ``surface_distance`` of two objects, else a ``distance``."""
        q = " ".join(str(question or "").lower().split())
        if "surface-to-surface" in q or "surface to surface" in q:
            return "surface_distance"
        if "distance from the camera" in q:
            return "distance_to_camera"
        m = re.search(r"what is the (?:approximate )?(length|width|height)\b(?: \([^)]*\))? of\b", q)
        return m.group(1) if m else "distance"

    def read_contract(self, row: dict, video_map: dict | None = None) -> Contract:
        c, q = base_contract(row, video_map=video_map)
        ql = q.lower()
        m = re.search(r"\b(length|width|height)\b", ql)
        pair = object_pair(q)
        if pair and "distance" in ql:
            c.operator, c.entity = "object_distance", {"kind": "object_pair", "descriptions": list(pair)}
        elif "close is the camera" in ql or "from the camera" in ql or "camera to" in ql:
            c.operator, c.entity = "distance_to_camera", {"kind": "object", "description": description(row, q, PATTERNS)}
        elif m:
            c.operator, c.entity = "dimension", {"kind": "object", "description": description(row, q, PATTERNS)}
            c.params["dimension"] = m.group(1)
        c.times = instant(c, row)
        if c.operator != "unknown" and not c.unit_stated:
            c.miss("unit")
        return c

    # -- referents
    def _referent(self, view: SceneView, desc: str | None) -> Referent:
        """What a description names; raises Exclude for groups and descriptions with no source label."""
        ref = view.resolve(desc)
        if ref.grouped:
            raise Exclude("grouped_referent", defect="grouped_referent", phrase=desc, marker=ref.grouped,
                          label=ref.label)
        if ref.label is None or not any(view.matches(ref, i) for i in view.all_instances()):
            raise Exclude("no_source_instance", defect="no_source_instance", phrase=desc, head=ref.head,
                          label=ref.label, labels_in_sequence=view.labels(),
                          **({"noun_class": ref.evidence} if view.source == "Waymo" else {}))
        return ref

    @staticmethod
    def _visible(view: SceneView, snap: Snapshot, ref: Referent) -> tuple[list, list, list[dict]]:
        cands = [i for i in snap.instances if view.matches(ref, i)]
        vis = [view.visibility(snap, i) for i in cands]
        visible = [i for i, v in zip(cands, vis) if v["visible"]]
        return cands, visible, vis

    def _pick(self, case: Case, view: SceneView, pool: list, values: list[float]):
        """The legacy value as a tie-breaker among candidates (params ``legacy_tie_break`` per source)."""
        return tie_break_by_legacy([i.id for i in pool], values, case.legacy, unit_for(case.params, view.source),
                                   rule_for(case.params, view.source),
                                   enabled=tie_break_enabled(case.params, view.source))

    def _dimension(self, case: Case, view: SceneView, t: float) -> tuple[float, dict]:
        c, o = case.contract, case.outcome
        which = c.params.get("dimension")
        ref = self._referent(view, c.entity.get("description"))
        ev: dict = {"label": ref.label, "match": ref.evidence}
        if view.source == "Waymo":
            snap = view.snapshot(t)
            cands, visible, vis = self._visible(view, snap, ref)
            ev.update({"t_frame": snap.evidence.get("t_frame"), "n_instances": len(cands),
                       "n_visible_instances": len(visible)})
            if not visible:
                raise Exclude("not_visible_at_frame", defect="not_visible", t=t,
                              visibility=[{"id": i.id, **v} for i, v in zip(cands, vis)], **ev)
            pool = visible
            case.provenance(files=snap.evidence["files"],
                            frames={"t": t, "t_frame": snap.evidence.get("t_frame"),
                                    "frame_timestamp_micros": snap.evidence.get("frame_timestamp_micros")})
        else:
            pool = [i for i in view.all_instances() if view.matches(ref, i)]
            ev["n_instances"] = len(pool)
            try:
                snap = view.snapshot(t)
                seen = [i for i in snap.instances if view.matches(ref, i)]
                ev["n_visible_instances"] = sum(view.visibility(snap, i)["visible"] for i in seen)
                ev["frame"] = snap.evidence.get("frame")
                case.provenance(files=snap.evidence["files"], frames={"t": t, "frame": snap.evidence.get("frame")})
            except ContractError as e:
                ev["visibility_note"] = f"no camera at t={t} s: {e}"

        def value(inst: Instance) -> float:
            return float(case.measure("dimension", {"kind": "object", "id": inst.id}, [t]).value[which])

        if len(pool) > 1:
            vals = [value(i) for i in pool]
            k, tev = self._pick(case, view, pool, vals)
            if k is None:
                raise Exclude("ambiguous_instance", defect="multiple_instances", asked=which,
                              candidates=[i.id for i in pool], value_spread_m=round(_spread(vals), 6), **ev, **tev)
            ev["referent"] = tev
            pool = [pool[k]]
        inst = pool[0]
        if view.source == "ScanNet":
            o.source_files = sorted(set(o.source_files) | {v for v in inst.extra["files"].values() if v})
        ev.update({"id": inst.id, "convention": inst.dims_rule, "dims_m": inst.dims.tolist()})
        if "aabb_ann_m" in inst.extra:
            ev["aabb_ann_m"] = inst.extra["aabb_ann_m"]
            ev["box_hypotheses"] = {"tight": value(inst),
                                    "axis_aligned": float(inst.extra["aabb_ann_m"][DIMS.index(which)])}
        c.entity.update({"id": inst.id, "label": inst.label})
        c.frame = "object box (" + inst.dims_rule + ")"
        return value(inst), ev

    def _distance(self, case: Case, view: SceneView, t: float) -> tuple[float, dict]:
        c = case.contract
        ref = self._referent(view, c.entity.get("description"))
        snap = view.snapshot(t)
        cands, visible, vis = self._visible(view, snap, ref)
        frame = snap.evidence.get("frame", snap.evidence.get("t_frame"))
        ev = {"label": ref.label, "match": ref.evidence, "frame": frame, "t": t, "n_instances": len(cands),
              "n_visible_instances": len(visible)}
        case.provenance(files=snap.evidence["files"],
                        frames={"t": t, **{k: snap.evidence[k] for k in ("frame", "t_frame", "frame_timestamp_micros")
                                           if k in snap.evidence}})
        if not visible:
            raise Exclude("not_visible_at_frame", defect="not_visible",
                          visibility=[{"id": i.id, **v} for i, v in zip(cands, vis)], **ev)

        def measured(inst: Instance):
            return case.measure("distance_to_camera", {"kind": "object", "id": inst.id}, [t])

        if len(visible) > 1:
            vals = [measured(i).value for i in visible]
            k, tev = self._pick(case, view, visible, vals)
            if k is None:
                raise Exclude("ambiguous_instance", defect="multiple_instances", candidates=[i.id for i in visible],
                              value_spread_m=round(_spread(vals), 6), **ev, **tev)
            ev["referent"] = tev
            visible = [visible[k]]
        inst = visible[0]
        m = measured(inst)
        dev = {k: v for k, v in m.evidence.items() if k in ("camera_centre", "nearest_box_point", "frame", "geometry")}
        ev.update({"id": inst.id, "visibility": vis[cands.index(inst)], **dev})
        alt = _axis_aligned(view, inst)
        if alt is not None:
            ev["box_hypotheses"] = {"tight": m.value, "axis_aligned": camera_distance(view, snap, alt)[0]}
        c.entity.update({"id": inst.id, "label": inst.label})
        c.frame = snap.frame
        return m.value, ev

    def _pair(self, case: Case, view: SceneView, t: float) -> tuple[float, dict]:
        c = case.contract
        descs = list(c.entity.get("descriptions") or [])
        pools, evs = [], []
        for desc in descs:
            ref = self._referent(view, desc)
            if view.source == "Waymo":
                _, pool, _ = self._visible(view, view.snapshot(t), ref)
                if not pool:
                    raise Exclude("not_visible_at_frame", defect="not_visible", label=ref.label, t=t)
            else:
                pool = [i for i in view.all_instances() if view.matches(ref, i)]
            pools.append(pool)
            evs.append({"label": ref.label, "n_instances": len(pool), "head": ref.head})
        if len(pools) != 2:
            raise Exclude("unsupported_question", descriptions=descs)
        pairs = [(a.id, b.id) for a in pools[0] for b in pools[1] if a.id != b.id]

        def measured(ids):
            return case.measure("object_distance", {"kind": "object_pair", "ids": list(ids)}, [t])

        if len(pairs) != 1:
            vals = [measured(p).value for p in pairs]
            raise Exclude("ambiguous_instance", defect="multiple_instances", labels=[e["label"] for e in evs],
                          n_pairs=len(pairs), value_spread_m=round(_spread(vals), 6),
                          n_instances=[e["n_instances"] for e in evs])
        m = measured(pairs[0])
        c.entity.update({"ids": m.evidence["ids"], "labels": m.evidence["labels"]})
        c.frame = m.evidence["frame"]
        case.provenance(frames={"t": t})
        ev = {"labels": [e["label"] for e in evs], "ids": m.evidence["ids"], "frame": m.evidence["frame"],
              "geometry": m.evidence["geometry"], "nearest_points": m.evidence["nearest_points"]}
        alt = [_axis_aligned(view, view.world_box(i, t)) for i in pairs[0]]
        if all(x is not None for x in alt):
            ev["box_hypotheses"] = {"tight": m.value, "axis_aligned": pair_distance(*alt)[0]}
        return m.value, ev

    def reconstruct(self, case: Case) -> None:
        c, params = case.contract, case.params
        op = c.operator
        if op not in self.operators:
            raise unsupported(case.row.get("Question"))
        view = SceneView.open(case.ctx, str(case.row["Video"]), params)
        unit = unit_for(params, case.source)
        t = float(c.times[0])
        fn = {"dimension": self._dimension, "distance_to_camera": self._distance, "object_distance": self._pair}[op]
        try:
            value, ev = fn(case, view, t)
        except ContractError as e:
            raise Exclude("invalid_pose_at_time", t=t, error=str(e)) from None
        set_rule(case, rule_for(params, case.source))
        case.value = value
        case.state["ev"] = ev
        case.state["unit"] = unit
        c.unit, c.unit_stated, c.times = unit, True, [t]
        case.provenance(chain=CHAIN[view.source])
        o = case.outcome
        if op == "distance_to_camera":
            o.time_start = o.time_end = t
        else:
            o.time_start, o.time_end = float(case.row["time_start"]), float(case.row["time_end"])
        desc = c.entity.get("description") or (c.entity.get("descriptions") or [None])[0]
        case.observables.update(subject=noun_phrase(desc), subject_class=c.entity.get("label")
                                or c.entity.get("labels"), dimension=c.params.get("dimension"))
        case.answer = AnswerSpec("scalar", value / V.si_factor(unit), unit, int(params["decimals"]))

    def diagnose(self, case: Case) -> None:
        ev, unit, op = case.state["ev"], case.state["unit"], case.contract.operator
        cmp = compare_scalar(case.legacy, case.value, unit, rule_for(case.params, case.source))
        case.diagnosis = Diagnosis.from_comparison(cmp, operator=op, value_si=case.value, **ev)

    def diagnose_all(self, cases: list[Case]) -> None:
        pending = []  # ScanNet rows waiting for the task's box convention
        for k in cases:
            self.diagnose(k)
            d, hyp = k.diagnosis, k.state["ev"].get("box_hypotheses")
            if hyp and d.comparable:
                rule = rule_for(k.params, k.source)
                d.verdict = d.final_verdict
                pending.append((d, {x: agrees_scalar(k.legacy, v, k.state["unit"], rule) for x, v in hyp.items()}))
        if cases:
            _adjudicate_boxes(pending, cases[0].params)

    def rewrite(self, case: Case) -> str:
        c, source, unit, t = case.contract, case.source, case.state["unit"], float(case.contract.times[0])
        op = c.operator
        if op == "dimension":
            return (f"What is the {c.params['dimension']} of {noun_phrase(c.entity.get('description'))}? "
                    f"{DIM_WORDING[source]} (unit: {unit})")
        if op == "distance_to_camera":
            return (f"At t={V.format_seconds(t)} s, what is the distance from the camera to the nearest point of the "
                    f"bounding box of {noun_phrase(c.entity.get('description'))}? (unit: {unit})")
        a, b = (c.entity.get("descriptions") or ["object", "object"])[:2]
        when = f"At t={V.format_seconds(t)} s, what" if source == "Waymo" else "What"
        return (f"{when} is the minimum surface-to-surface distance between the bounding boxes of {noun_phrase(a)} "
                f"and {noun_phrase(b)}? (unit: {unit})")


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
