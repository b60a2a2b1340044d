"""Typed oriented boxes in the OpenCV camera frame: the ``box_in_camera`` operator.

One output contract for every source: the object's box at the asked frame as ``T_cam<-box`` in
OpenCV camera axes (+X right, +Y down, +Z forward) and its box-local edge lengths.

- ScanNet: ``T_cam<-box(t) = P(t)^-1 A^-1 T_ann<-box`` with ``A = axisAlignment = T_ann<-raw``,
  ``P(t) = T_raw<-cam`` at the frame of ``t`` and ``T_ann<-box`` the instance's tight
  gravity-upright box of ``A @ mesh vertices`` (footprint = minimum-area rectangle, length >=
  width, :func:`resti_lib.geometry.boxes.upright_oriented_box`).
- Waymo: the LiDAR box (vehicle frame of its frame timestamp) goes to the world through the
  vehicle pose of that frame and into the camera through the camera's vehicle pose and extrinsic:
  ``T_cam<-box = (W(t) E C)^-1 W(t) T_vehicle<-box`` with ``C = T_waymo_cam<-opencv_cam``.
- Omni6DPose: the ROPE object pose in the frame's camera, read under the verified camera
  convention (:meth:`resti_lib.sources.omni6d.RopeScene.object_boxes`).

Inverses of stored matrices are exact matrix inverses (``numpy.linalg.inv``): ScanNet's
``axisAlignment`` is printed with six decimals and poses are float32, so their rotation blocks are
orthonormal only to storage precision and a transpose would add that error to every centre.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import values as V
from ..defaults import setting
from ..errors import ContractError, InputError
from ..geometry.frames import T_WAYMO_CAM_FROM_CV_CAM, make_T
from ..sources.scannet import ScanNetScene
from ..sources.waymo import WaymoSegment, camera_number
from .registry import MeasureContext, register_operator

__all__ = ["CameraBox", "camera_box", "rope_box", "rope_frame", "scannet_ann_box", "scannet_box", "scannet_frame",
           "validate_box", "waymo_box", "waymo_cam_from_world", "waymo_frame"]

# =============================================================================== typed boxes


@dataclass
class CameraBox:
    """An oriented box in an OpenCV camera frame at one instant.

    Attributes
    ----------
    center : (3,) metres, camera frame.
    lwh : (3,) box-local edge lengths along box +X, +Y, +Z (metres).
    R : (3, 3) ``R_cam<-box``.
    chain : the transform chain, e.g. ``"P(t)^-1 A^-1 T_ann<-box"``.
    frames : frame index / timestamps used.
    files : source files read.
    """

    center: np.ndarray
    lwh: np.ndarray
    R: np.ndarray
    chain: str
    frames: dict = field(default_factory=dict)
    files: list = field(default_factory=list)

    @property
    def heading(self) -> float:
        """``degrees(atan2(R[1,0], R[0,0]))`` wrapped to [-180, 180) (a redundant summary)."""
        return V.box_heading(self.R)

    @property
    def T(self) -> np.ndarray:
        """``T_cam<-box`` (4x4)."""
        return make_T(self.R, self.center)

    def fields(self) -> dict:
        """The answer fields at full precision (``C_central_point``, ``C_lwh``, ...)."""
        return {"C_central_point": self.center.tolist(), "C_lwh": self.lwh.tolist(),
                "C_rotation_camera_from_box": self.R.tolist(), "C_heading": self.heading}

    def answer_value(self) -> dict:
        """The value an :class:`~resti_lib.tasks.base.AnswerSpec` of kind ``box`` takes."""
        return {"center": self.center.copy(), "lwh": self.lwh.copy(), "R": self.R.copy()}

    def text(self) -> str:
        return V.format_box(self.center, self.lwh, self.R)


def validate_box(box: CameraBox, *, rot_tol: float = 1e-5) -> dict:
    """Check a box before it becomes an answer; return the measured checks.

    Finite entries, positive edge lengths, ``|R R^T - I| <= rot_tol``, ``|det R - 1| <= rot_tol``
    and a round trip through :func:`resti_lib.values.format_box` / :func:`resti_lib.values.parse`
    that reproduces every field to its printed precision.

    Raises
    ------
    InputError
        Any check fails (the message names it).
    """
    c, d, R = np.asarray(box.center, float), np.asarray(box.lwh, float), np.asarray(box.R, float)
    if c.shape != (3,) or d.shape != (3,) or R.shape != (3, 3):
        raise InputError(f"box has wrong shapes {c.shape}, {d.shape}, {R.shape}", field="box")
    if not (np.isfinite(c).all() and np.isfinite(d).all() and np.isfinite(R).all()):
        raise InputError("box has non-finite entries", field="box")
    if (d <= 0).any():
        raise InputError(f"box has non-positive edge lengths {d.tolist()}", field="C_lwh")
    orth = float(np.abs(R @ R.T - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if orth > rot_tol:
        raise InputError(f"box rotation not orthonormal (max |R R^T - I| = {orth:.3g})", field="R")
    if abs(det - 1.0) > rot_tol:
        raise InputError(f"box rotation has det {det:.6f}", field="R")
    parsed = V.parse(box.text())
    rt = {
        "center": float(np.abs(np.array(parsed.center) - c).max()),
        "lwh": float(np.abs(np.array(parsed.lwh) - d).max()),
        "R": float(np.abs(np.array(parsed.R) - R).max()),
        "heading": float(abs(V.wrap_degrees(parsed.heading - box.heading))),
    }
    limits = {"center": 5e-4 + 1e-12, "lwh": 5e-4 + 1e-12, "R": 5e-7 + 1e-12, "heading": 5e-3 + 1e-9}
    bad = [k for k in rt if rt[k] > limits[k]]
    if bad:
        raise InputError(f"box does not round-trip through format_box ({bad})", field="box")
    return {"max_orthonormality_error": orth, "det": det, "round_trip_max_error": rt}


# ----------------------------------------------------------------------------------- sources

def inv(T: np.ndarray) -> np.ndarray:
    """Exact inverse of a stored 4x4 matrix (no orthonormality assumed)."""
    return np.linalg.inv(np.asarray(T, dtype=np.float64))


def scannet_frame(scene: ScanNetScene, t: float, *, tol: float) -> tuple[int, float]:
    """Sensor frame of time ``t`` (``round(t * fps)``) and its exact time; ContractError beyond ``tol``."""
    f = round(float(t) * scene.fps)
    tf = f / scene.fps
    if abs(tf - t) > tol:
        raise ContractError(f"{scene.scene}: t={t} s is {abs(tf - t):.4f} s from the nearest sensor frame {f} "
                            f"(tolerance {tol} s)")
    return f, tf


def scannet_ann_box(inst) -> tuple[np.ndarray, np.ndarray]:
    """``T_ann<-box`` and ``lwh`` of an instance: the tight gravity-upright box of ``A @ vertices``."""
    b = inst.obb_ann
    return make_T(b.R, b.center), np.asarray(b.lwh, dtype=np.float64)


def scannet_box(scene: ScanNetScene, object_id: int, t: float, *, tol: float = 0.004) -> CameraBox:
    """ScanNet box in the camera at ``t``: ``T_cam<-box = P(t)^-1 A^-1 T_ann<-box``.

    Raises
    ------
    InputError
        Unknown object, invalid pose at the frame, or no axisAlignment.
    ContractError
        ``t`` is not within ``tol`` of a sensor frame.
    """
    f, tf = scannet_frame(scene, t, tol=tol)
    P = scene.camera_pose(f)
    A = scene.axis_alignment
    inst = scene.instance(object_id)
    T_ann_box, lwh = scannet_ann_box(inst)
    T = inv(P) @ inv(A) @ T_ann_box
    files = [str(scene.meta_path), scene.camera_track().source, inst.source.get("aggregation"), inst.source.get("segs"),
             inst.source.get("ply")]
    return CameraBox(T[:3, 3].copy(), lwh, T[:3, :3].copy(), "P(t)^-1 A^-1 T_ann<-box",
                     {"frame": f, "t": tf, "fps": scene.fps}, [x for x in files if x])


def waymo_frame(seg: WaymoSegment, t: float, tol: float) -> tuple[int, int, float]:
    """(index, micros, time) of the vehicle_pose frame nearest ``t``; ContractError beyond ``tol``."""
    track = seg.ego_track()
    k = int(np.argmin(np.abs(track.times - t)))
    if abs(track.times[k] - t) > tol:
        raise ContractError(f"{seg.segment}: no frame within {tol} s of t={t} (nearest {track.times[k]:.6f} s)")
    return k, int(track.meta["micros"][k]), float(track.times[k])


def waymo_cam_from_world(seg: WaymoSegment, k: int, camera: int) -> np.ndarray:
    """``T_cam<-world`` (OpenCV axes) at vehicle_pose frame ``k``: ``(W E C)^-1``."""
    W = seg.ego_track().T[k]
    E = seg.camera_calibration(camera)["extrinsic"]
    return inv(W @ E @ T_WAYMO_CAM_FROM_CV_CAM)


def waymo_box(seg: WaymoSegment, laser_object_id: str, t: float, camera: int, *, tol: float = 0.05
              ) -> CameraBox:
    """Waymo box in a camera at ``t``: vehicle frame -> world (vehicle pose) -> camera (OpenCV)."""
    k, micros, tk = waymo_frame(seg, t, tol)
    b = seg.box_at(tk, str(laser_object_id), tol=1e-6)
    if b is None:
        raise InputError(f"object {laser_object_id} has no box at t={tk:.6f} s", file=seg.path("lidar_box"),
                         field="key.laser_object_id")
    T = waymo_cam_from_world(seg, k, camera) @ b["T_world_from_box"]
    return CameraBox(T[:3, 3].copy(), np.asarray(b["size"], float), T[:3, :3].copy(),
                     "(W(t) E C)^-1 W(t) T_vehicle<-box", {"frame_index": k, "micros": micros, "t": tk,
                                                           "camera": int(camera)},
                     [str(seg.path(c)) for c in ("vehicle_pose", "camera_calibration", "lidar_box")])


def rope_frame(rope, t: float, *, tol: float) -> tuple[int, float]:
    f = round(float(t) * rope.fps)
    tf = f / rope.fps
    if abs(tf - t) > tol:
        raise ContractError(f"ROPE {rope.scene}: t={t} s is not within {tol} s of a frame")
    if f not in set(rope.frames):
        raise InputError(f"no meta for frame {f}", file=rope.meta_path(f), row=f, field="frame")
    return f, tf


def rope_box(rope, oid: str, t: float, *, tol: float = 0.004) -> CameraBox:
    """Omni6DPose box in the camera at ``t`` under the verified camera convention."""
    f, tf = rope_frame(rope, t, tol=tol)
    boxes = [b for b in rope.object_boxes(f) if str(b["oid"]) == str(oid)]
    if not boxes:
        raise InputError(f"object {oid} is not annotated at frame {f}", file=rope.meta_path(f), row=f,
                         field="objects")
    b = boxes[0]
    return CameraBox(np.asarray(b["center"], float), np.asarray(b["lwh"], float), np.asarray(b["R"], float),
                     "T_cam<-obj (ROPE pose, verified convention, OpenCV axes)",
                     {"frame": f, "t": tf, "fps": rope.fps, "convention": rope.convention[0]},
                     [str(rope.meta_path(f)), str(rope.obj_meta_path)])



def camera_box(source: str, scene, object_id, t: float, *, camera=None, params: dict | None = None) -> CameraBox:
    """The object's box in the OpenCV camera frame at ``t`` (the ``box_in_camera`` value), with the
    frame tolerances of the settings ``frame_time_tol_s`` / ``waymo_frame_tol_s``."""
    if source == "ScanNet":
        return scannet_box(scene, int(object_id), t, tol=float(setting(params, "frame_time_tol_s")))
    if source == "Waymo":
        if camera in (None, ""):
            raise ContractError("Waymo box_in_camera needs 'camera' (FRONT ... or 1-5)")
        return waymo_box(scene, str(object_id), t, camera_number(camera),
                         tol=float(setting(params, "waymo_frame_tol_s")))
    return rope_box(scene, str(object_id), t, tol=float(setting(params, "frame_time_tol_s")))


@register_operator("box_in_camera", unit=None, n_times=(1,), entities=("object",))
def _op_box_in_camera(ctx: MeasureContext) -> tuple[Any, dict]:
    """The object's oriented box in the OpenCV camera frame at ``times[0]`` (ScanNet, Waymo, ROPE):
    ``{"C_central_point", "C_lwh", "C_rotation_camera_from_box", "C_heading"}``; the evidence holds
    the transform chain, frames, files and the box checks."""
    if ctx.entity.get("kind") != "object":
        raise ContractError("box_in_camera needs an object entity {'kind': 'object', 'id': ...}")
    box = camera_box(ctx.source, ctx.scene, ctx.entity["id"], ctx.times[0], camera=ctx.camera, params=ctx.params)
    checks = validate_box(box)
    ev = {"transform_chain": box.chain, "frames": box.frames, "files": box.files, "checks": checks,
          "axes": "OpenCV camera (+X right, +Y down, +Z forward)"}
    return box.fields(), ev
