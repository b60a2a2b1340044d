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
    frame's intrinsics, :func:`resti_lib.referents.box_visibility`).
``object_distance``
    Minimum Euclidean distance between the two solid oriented boxes
    (:func:`resti_lib.referents.box_box_distance`; 0 when they touch or overlap).

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

import re
from pathlib import Path

import pandas as pd

from .. import values as V
from ..adjudicate import Diagnosis, agrees_scalar, compare_scalar
from ..contract import Contract, base_contract, description, instant, object_pair
from ..errors import ContractError
from ..measure.objects import CHAIN
from ..referents import Instance, Referent, SceneView, Snapshot, noun_phrase, read_phrase
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
    "ScanNet": "Height is the vertical extent of the object's bounding box in the gravity-aligned scene frame; "
               "length and width are its larger and smaller horizontal extents.",
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
    legacy_kind = V.Scalar
    operators = ("dimension", "distance_to_camera", "object_distance")

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
        return m.value, {"labels": [e["label"] for e in evs], "ids": m.evidence["ids"], "frame": m.evidence["frame"],
                         "geometry": m.evidence["geometry"], "nearest_points": m.evidence["nearest_points"]}

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
        rule = rule_for(case.params, case.source)
        cmp = compare_scalar(case.legacy, case.value, unit, rule)
        d = Diagnosis(bool(cmp["comparable"]), cmp["agrees"])
        alt = self._other_convention(op, case.contract.params.get("dimension"), ev, case.legacy, unit, rule)
        if d.final_verdict == "corrected" and alt:
            d.verdict = "re-contracted"
            ev["legacy_convention"] = alt
        if d.final_verdict == "corrected":
            d.defects.append("value_mismatch")
        d.evidence = {"operator": op, "value_si": case.value, "comparison": cmp, **ev}
        case.diagnosis = d

    @staticmethod
    def _other_convention(op: str, which: str | None, ev: dict, legacy, unit: str, rule) -> str | None:
        """The legacy convention when a ScanNet length/width equals an annotation-frame axis extent instead.

        Annotation-frame axis-aligned extents name "length" and "width" after the scene's x and y axes,
        not after the object; a legacy value that agrees with that reading (and not with the larger /
        smaller horizontal extent) is re-contracted, not corrected.
        """
        if op != "dimension" or which not in ("length", "width") or "aabb_ann_m" not in ev:
            return None
        k = 0 if which == "length" else 1
        if agrees_scalar(legacy, ev["aabb_ann_m"][k], unit, rule):
            return (f"{which} read as the extent along the annotation frame's {'xy'[k]} axis "
                    f"({ev['aabb_ann_m'][k]:.4f} m), not the {'larger' if k == 0 else 'smaller'} horizontal extent")
        return None

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
