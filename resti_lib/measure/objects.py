"""Object operators: box dimensions, camera-to-box distance, box-to-box distance.

``dimension``
    ``{"length", "width", "height"}`` (m) of the object's box under its source convention
    (ScanNet: the tight gravity-upright box of the mesh vertices in the annotation frame;
    Waymo: the LiDAR box at ``times[0]``; Omni6DPose: ``scale * dimensions`` along the object axes).
``distance_to_camera``
    Distance (m) from the camera's optical centre to the nearest point of the solid box at
    ``times[0]`` (0 inside the box).
``object_distance``
    Minimum Euclidean distance (m) between two solid oriented boxes at ``times[0]`` (0 when they
    touch or overlap), entity ``{"kind": "object_pair", "ids": [a, b]}``.
"""

from __future__ import annotations

from ..errors import ContractError
from ..sources.referents import Instance, SceneView, Snapshot, box_box_distance
from ..sources.waymo import camera_number
from .registry import MeasureContext, register_operator

__all__ = ["CHAIN", "DIMS", "camera_distance", "dimension_value", "instance_at", "pair_distance", "scene_view"]

DIMS = ("length", "width", "height")
CHAIN = {
    "ScanNet": "tight upright box of A·v (annotation frame) -> A^-1 (raw); camera P(t) = T_raw<-cam",
    "Waymo": "T_world<-box = world_from_vehicle(frame) [yaw(heading) | centre]; camera world_from_vehicle @ "
             "extrinsic @ waymo->opencv",
    "Omni6DPose": "T_cam<-obj (frame meta, OpenCV axes); lwh = scale * dimensions",
}


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


def scene_view(ctx: MeasureContext) -> SceneView:
    """The contract's sequence as a :class:`~resti_lib.sources.referents.SceneView` (visibility settings of the params)."""
    cam = None
    if ctx.source == "Waymo":
        cam = camera_number(ctx.camera) if ctx.camera not in (None, "") else None
    return SceneView(ctx.source, ctx.scene, cam, vis=ctx.params.get("visibility"), params=ctx.params)


def instance_at(view: SceneView, inst_id, t: float | None) -> tuple[Instance, Snapshot | None]:
    """An instance by id: ScanNet (and Omni6DPose without a time) from the sequence, else at ``t``."""
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


@register_operator("dimension", unit=None, n_times=(1, 2), entities=("object",))
def _op_dimension(ctx: MeasureContext):
    """``{"length", "width", "height"}`` (m) of the object's box (source conventions in the evidence)."""
    if ctx.entity.get("kind") != "object":
        raise ContractError("dimension needs an object entity")
    view = scene_view(ctx)
    t = ctx.t0 if view.source == "Waymo" else None
    inst, _ = instance_at(view, ctx.entity["id"], t)
    value = {k: dimension_value(inst, k) for k in DIMS}
    return value, {"convention": inst.dims_rule, "label": inst.label, "frame": inst.frame,
                   "transform_chain": CHAIN[view.source]}


@register_operator("distance_to_camera", unit="m", n_times=(1,), entities=("object",))
def _op_distance_to_camera(ctx: MeasureContext):
    """Distance (m) from the camera centre to the nearest point of the object's box at ``times[0]``."""
    if ctx.entity.get("kind") != "object":
        raise ContractError("distance_to_camera needs an object entity")
    view = scene_view(ctx)
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


@register_operator("object_distance", unit="m", n_times=(1,), entities=("object_pair",))
def _op_object_distance(ctx: MeasureContext):
    """Minimum distance (m) between the boxes of ``entity.ids`` at ``times[0]`` (one common frame:
    ScanNet raw, Waymo world at the time, Omni6DPose first-camera frame)."""
    if ctx.entity.get("kind") != "object_pair":
        raise ContractError("object_distance needs an object_pair entity {'kind': 'object_pair', 'ids': [a, b]}")
    view = scene_view(ctx)
    a, b = (view.world_box(str(i), ctx.t0) for i in ctx.entity["ids"])
    d, ev = pair_distance(a, b)
    ev.update({"ids": [a.id, b.id], "labels": [a.label, b.label], "frame": a.frame,
               "transform_chain": CHAIN[view.source]})
    return d, ev
