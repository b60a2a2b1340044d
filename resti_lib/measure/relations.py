"""Relation operators: the direction of a mounted camera (Waymo), the dominant relation of two
objects (Omni6DPose).

``mounted_relation``
    The camera's optical axis (Waymo camera +X) in the vehicle frame, from the calibration
    extrinsic ``T_vehicle<-cam``, gives a yaw; the label is the nearest of Front (0°), Front-Left
    (45°), Front-Right (-45°), Left (90°), Right (-90°) (and the Back bins). A yaw within
    ``mount_margin_deg`` of a bin edge has no dominant direction (no value).
``relative_position``
    From camera-frame geometry at ``times[0]``, with ``d = c_A - c_B`` (OpenCV axes): **Directly
    above** when A's centre lies over B's box footprint and above its top face (B's box axis closest
    to the scene up is the vertical one); else **Left/Right** when ``|d_x| >= dominance_ratio *
    |d_z|`` (sign of ``d_x``), **Closer/Farther** when ``|d_z| >= dominance_ratio * |d_x|`` (sign of
    ``d_z``); else no relation dominates (no value).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ContractError, InputError
from ..sources.referents import frame_of_time, omni_boxes_at
from ..sources.waymo import camera_number
from .registry import MeasureContext, register_operator

__all__ = ["MOUNT_CENTRES", "NAME_LABEL", "camera_up_at", "mount_relation", "name_mount_yaw", "relative_position"]

#: Bin centres of the mounted-camera labels (yaw of the optical axis in the vehicle frame, degrees).
MOUNT_CENTRES = {"Front": 0.0, "Front-Left": 45.0, "Front-Right": -45.0, "Left": 90.0, "Right": -90.0,
                 "Back": 180.0, "Back-Left": 135.0, "Back-Right": -135.0}
#: What the Waymo camera *name* says (CameraName enum 1..5): its mount label.
NAME_LABEL = {1: "Front", 2: "Front-Left", 3: "Front-Right", 4: "Left", 5: "Right"}


def name_mount_yaw(camera) -> float | None:
    """The nominal mount yaw (degrees, vehicle frame, +Y left) of a Waymo camera named by its number or
    enum name (``"2"``, 2 or ``"FRONT_LEFT"``: Front-Left, 45); None for a camera the enum does not name."""
    try:
        n = camera_number(camera)
    except InputError:
        return None
    return MOUNT_CENTRES[NAME_LABEL[n]]


def _circ(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


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


def camera_up_at(rope, frame: int, up_scene) -> np.ndarray:
    """The scene up direction in the OpenCV camera frame of a ROPE frame."""
    track = rope.camera_track(rebase=True)
    k = int(np.argmin(np.abs(track.times - frame / rope.fps)))
    return track.T[k, :3, :3].T @ rope.world_up_in_track_frame(np.asarray(up_scene, float))


@register_operator("mounted_relation", unit=None, n_times=(1, 2), entities=("camera",))
def _op_mounted_relation(ctx: MeasureContext) -> tuple[str | None, dict]:
    """Waymo: direction label of the contract's camera relative to the vehicle's forward axis."""
    if ctx.source != "Waymo" or ctx.camera in (None, ""):
        raise ContractError("mounted_relation needs a Waymo contract with a camera")
    cal = ctx.scene.camera_calibration(ctx.camera)
    label, ev = mount_relation(cal["extrinsic"], margin_deg=float(ctx.setting("mount_margin_deg")))
    ev["calibration_row"] = cal.get("row")
    if label is None:
        ev["no_value"] = f"no dominant mounted direction (yaw {ev['yaw_deg']:.1f} deg)"
    return label, ev


@register_operator("relative_position", unit=None, n_times=(1,), entities=("object", "object_pair"))
def _op_relative_position(ctx: MeasureContext) -> tuple[str | None, dict]:
    """Omni6DPose: relation of object A relative to B at ``times[0]`` (entity ``{"kind": "object_pair",
    "ids": [A, B]}``, or ``{"kind": "object", "id": A, "reference": B}``)."""
    ent = ctx.entity
    ids = ent.get("ids") if ent.get("kind") == "object_pair" else [ent.get("id"), ent.get("reference")]
    if ctx.source != "Omni6DPose" or ids is None or None in ids:
        raise ContractError("relative_position needs an Omni6DPose object pair (A relative to B)")
    rp = ctx.scene
    frame = frame_of_time(ctx.t0, rp.fps, rp.frames)
    here = {x.id: x.box for x in omni_boxes_at(rp, frame)}
    a, b = here.get(str(ids[0])), here.get(str(ids[1]))
    if a is None or b is None:
        raise ContractError(f"object not annotated at frame {frame}")
    up = camera_up_at(rp, frame, ctx.setting("omni6d_up"))
    label, ev = relative_position(a.center, b.center, b.R, b.lwh, up,
                                  dominance_ratio=float(ctx.setting("dominance_ratio")))
    ev["frame"] = frame
    if label is None:
        ev["no_value"] = f"no dominant relation (dominance {ev['dominance']:.2f})"
    return label, ev
