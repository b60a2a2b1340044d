"""Omni6DPose ROPE readers: per-frame ``<frame>_meta.json`` and ``Meta/real_obj_meta.json``.

Layout: ``../shared/formats/omni6dpose.md``. Files are parsed with the official dataclasses
(``cutoop.image_meta.ImageMetaData``, ``cutoop.obj_meta.ObjectMetaData``); images are never read.

Frames and conventions
----------------------
- Quaternions are scalar-first ``(w, x, y, z)`` (converted with
  :func:`resti_lib.geometry.frames.quat_wxyz_to_matrix`).
- Object ``quaternion_wxyz``/``translation``: ``T_cam_from_obj`` in the frame's camera.
  ``world_quaternion_wxyz``/``world_translation``: ``T_world_from_obj`` in the scene frame.
- The stored camera pose's direction (world<-cam or cam<-world) and camera axes (OpenCV or
  OpenGL) are *verified*, not assumed: :meth:`RopeScene.verify_camera_convention` keeps the
  candidate under which the annotated objects lie in front of the camera and project inside the
  image with the frame's intrinsics.
- Outputs use OpenCV camera axes. The trajectory world is the camera frame at the sequence's
  first frame (``rebase=True``), as the ``pose`` contract states; ``t = frame / fps`` (30 Hz).
- Box side lengths in metres are ``scale * dimensions`` (``dimensions`` from the object meta).
"""

from __future__ import annotations

import json
import re
from functools import cached_property
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from resti_lib.errors import InputError
from resti_lib.geometry.frames import apply_T, check_rotation, invert_T, make_T, quat_wxyz_to_matrix
from resti_lib.geometry.trajectory import PoseTrack

try:
    from cutoop.image_meta import ImageMetaData
    from cutoop.obj_meta import ObjectMetaData

    HAVE_CUTOOP = True
except ImportError:  # pragma: no cover
    # cutoop is a declared dependency; this plain-JSON fallback only keeps the reader usable where
    # cutoop fails to import. It exposes the same attribute names but does not check field presence
    # as strictly as cutoop's dataclasses do.
    ImageMetaData = ObjectMetaData = None
    HAVE_CUTOOP = False

__all__ = ["CONVENTIONS", "HAVE_CUTOOP", "RopeScene", "load_frame_meta", "load_object_meta"]

#: OpenGL camera axes (+X right, +Y up, +Z backward) -> OpenCV: flip Y and Z.
T_GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])
#: candidate readings of the stored camera pose: (direction, camera axes)
CONVENTIONS = (("world_from_cam", "opencv"), ("cam_from_world", "opencv"),
               ("world_from_cam", "opengl"), ("cam_from_world", "opengl"))
ROTATION_TOL = 1e-4


def _missing_field(e: Exception) -> str | None:
    m = re.search(r"argument[s]?: '([^']+)'", str(e))
    return m.group(1) if m else None


def _plain(obj: Any) -> Any:
    if isinstance(obj, dict):
        return SimpleNamespace(**{k: _plain(v) for k, v in obj.items()})
    return obj


def _plain_image_meta(data: dict) -> SimpleNamespace:
    objs = []
    for k, v in data["objects"].items():
        o = _plain(v)
        o.mask_id = int(k.split("_")[0])
        objs.append(o)
    return SimpleNamespace(objects=objs, camera=_plain(data["camera"]),
                           scene_dataset=data.get("scene_dataset"))


def _read_json(path: Path) -> Any:
    """A JSON file's content; unreadable or invalid JSON is an InputError naming the file (and line)."""
    try:
        return json.loads(path.read_text())
    except OSError as e:
        raise InputError(f"cannot read: {e}", file=path) from None
    except json.JSONDecodeError as e:
        raise InputError(f"invalid JSON: {e.msg}", file=path, row=e.lineno) from None


def load_frame_meta(path: str | Path):
    """``<frame>_meta.json`` -> ``cutoop.image_meta.ImageMetaData``.

    Raises
    ------
    InputError
        Unreadable/invalid JSON or a field that cutoop's dataclasses require is missing.
    """
    path = Path(path)
    data = _read_json(path)
    try:
        if HAVE_CUTOOP:
            return ImageMetaData(**data)
        return _plain_image_meta(data)
    except (TypeError, KeyError, AttributeError, ValueError) as e:
        raise InputError(f"not a ROPE frame meta: {e}", file=path, field=_missing_field(e)) from None


def load_object_meta(path: str | Path):
    """``Meta/real_obj_meta.json`` -> ``cutoop.obj_meta.ObjectMetaData`` (``instance_dict[oid]``)."""
    path = Path(path)
    data = _read_json(path)
    try:
        if HAVE_CUTOOP:
            return ObjectMetaData(**data)
        return SimpleNamespace(class_list=data["class_list"],
                               instance_dict={k: _plain(v) for k, v in data["instance_dict"].items()})
    except (TypeError, KeyError, AttributeError, ValueError) as e:
        raise InputError(f"not an object meta file: {e}", file=path, field=_missing_field(e)) from None


def _pose(q, t, *, file: Path, row: object, field: str) -> np.ndarray:
    t = np.asarray(t, dtype=np.float64)
    if t.shape != (3,) or not np.isfinite(t).all():
        raise InputError(f"translation must be 3 finite numbers, got {t.tolist()}", file=file, row=row,
                         field=field.replace("quaternion", "translation"))
    R = quat_wxyz_to_matrix(q, file=file, row=row, field=field)
    return make_T(R, t)


class RopeScene:
    """One ROPE scene ``<root>/ROPE/<scene>/`` with object meta ``<root>/Meta/real_obj_meta.json``.

    Parameters
    ----------
    root : path
        The folder holding ``ROPE/`` and ``Meta/``.
    scene : str
        ROPE scene id (folder name, e.g. ``000123``).
    fps : float
        ``t = frame / fps`` (default 30).
    """

    def __init__(self, root: str | Path, scene: str, fps: float = 30.0):
        self.root = Path(root)
        self.scene = str(scene)
        self.fps = float(fps)
        self.dir = self.root / "ROPE" / self.scene
        if not self.dir.is_dir():
            raise InputError("ROPE scene folder not found", file=self.dir, field="sequence")
        self._meta: dict[int, Any] = {}
        self._memo: dict[tuple, Any] = {}  # derived tracks and boxes, computed once per scene

    @property
    def obj_meta_path(self) -> Path:
        return self.root / "Meta" / "real_obj_meta.json"

    @cached_property
    def frames(self) -> list[int]:
        """Frame ids with a ``<frame>_meta.json``, sorted."""
        out = []
        for p in self.dir.glob("*_meta.json"):
            stem = p.name[: -len("_meta.json")]
            if not stem.isdigit():
                raise InputError("frame id is not a number", file=p, field="frame")
            out.append(int(stem))
        if not out:
            raise InputError("no <frame>_meta.json files", file=self.dir, field="frame")
        return sorted(out)

    def meta_path(self, frame: int) -> Path:
        return self.dir / f"{int(frame):06d}_meta.json"

    def meta(self, frame: int):
        """The frame's ``ImageMetaData`` (cached)."""
        frame = int(frame)
        if frame not in self._meta:
            p = self.meta_path(frame)
            if not p.exists():
                raise InputError(f"no meta for frame {frame}", file=p, row=frame, field="frame")
            self._meta[frame] = load_frame_meta(p)
        return self._meta[frame]

    @cached_property
    def object_meta(self):
        return load_object_meta(self.obj_meta_path)

    def intrinsics(self, frame: int) -> dict:
        """``{"fx", "fy", "cx", "cy", "width", "height"}`` of the frame (pixels)."""
        k = self.meta(frame).camera.intrinsics
        return {"fx": float(k.fx), "fy": float(k.fy), "cx": float(k.cx), "cy": float(k.cy),
                "width": float(k.width), "height": float(k.height)}

    def stored_camera_pose(self, frame: int) -> np.ndarray:
        """The camera pose as stored (direction and axes not yet interpreted)."""
        cam = self.meta(frame).camera
        return _pose(cam.quaternion, cam.translation, file=self.meta_path(frame), row="camera",
                     field="camera.quaternion")

    def _objects(self, frame: int, *, world: bool) -> list[tuple[Any, np.ndarray, np.ndarray | None]]:
        """(object, T_cam_from_obj as stored, T_world_from_obj or None) per object of the frame."""
        path = self.meta_path(frame)
        out = []
        for o in self.meta(frame).objects:
            row = f"{o.mask_id}_{o.meta.oid}"
            Tc = _pose(o.quaternion_wxyz, o.translation, file=path, row=row, field="quaternion_wxyz")
            Tw = None
            if world:
                Tw = _pose(o.world_quaternion_wxyz, o.world_translation, file=path, row=row,
                           field="world_quaternion_wxyz")
            out.append((o, Tc, Tw))
        return out

    # -- convention
    def verify_camera_convention(self, frames: list[int] | None = None, *, min_inside: float = 0.9
                                 ) -> tuple[dict, dict]:
        """Decide how the stored camera pose is to be read, from the object annotations.

        For each candidate of :data:`CONVENTIONS` the objects' world centres
        (``world_translation``, valid objects only) are moved into the OpenCV camera frame; the
        candidate *holds* when every centre has positive depth and at least ``min_inside`` of them
        project inside the image with the frame's intrinsics. Among holding candidates the one
        whose camera-frame centres best match the stored camera-frame object translations wins
        (median residual, reported).

        Returns
        -------
        convention : ``{"direction": "world_from_cam"|"cam_from_world", "axes": "opencv"|"opengl",
            "object_axes": "opencv"|"opengl"}``
        evidence : per-candidate counts and residuals, frames checked.

        Raises
        ------
        InputError
            No candidate holds, or no object can be checked.
        """
        frames = self.frames if frames is None else [int(f) for f in frames]
        pts_world, pts_cam_stored, frame_of = [], [], []
        poses, intr = {}, {}
        for f in frames:
            poses[f] = self.stored_camera_pose(f)
            intr[f] = self.intrinsics(f)
            for o, Tc, Tw in self._objects(f, world=True):
                if not bool(getattr(o, "is_valid", True)):
                    continue
                pts_world.append(Tw[:3, 3])
                pts_cam_stored.append(Tc[:3, 3])
                frame_of.append(f)
        if not pts_world:
            raise InputError("no valid object with a world pose to verify the camera convention",
                             file=self.dir, field="objects")
        Pw = np.array(pts_world)
        Pc_stored = np.array(pts_cam_stored)
        fr = np.array(frame_of)
        # camera-frame object translations: OpenCV when they lie in front (+Z), OpenGL when behind
        obj_axes = "opencv" if np.median(Pc_stored[:, 2]) > 0 else "opengl"
        Pc_stored_cv = Pc_stored if obj_axes == "opencv" else Pc_stored * [1.0, -1.0, -1.0]
        cands = []
        for direction, axes in CONVENTIONS:
            pc = np.empty_like(Pw)
            for f in frames:
                m = fr == f
                if not m.any():
                    continue
                P = poses[f]
                T_cam_from_world = invert_T(P) if direction == "world_from_cam" else P
                T_cv_from_world = (T_GL_FROM_CV @ T_cam_from_world) if axes == "opengl" else T_cam_from_world
                pc[m] = apply_T(T_cv_from_world, Pw[m])
            z = pc[:, 2]
            front = z > 0
            K = np.array([[intr[f]["fx"], intr[f]["fy"], intr[f]["cx"], intr[f]["cy"], intr[f]["width"],
                           intr[f]["height"]] for f in fr])
            with np.errstate(divide="ignore", invalid="ignore"):
                u = K[:, 0] * pc[:, 0] / z + K[:, 2]
                v = K[:, 1] * pc[:, 1] / z + K[:, 3]
            inside = front & (u >= 0) & (u < K[:, 4]) & (v >= 0) & (v < K[:, 5])
            frac = float(inside.mean())
            resid = float(np.median(np.linalg.norm(pc - Pc_stored_cv, axis=1)))
            cands.append({"direction": direction, "axes": axes, "n_objects": len(Pw),
                          "n_positive_depth": int(front.sum()), "n_inside_image": int(inside.sum()),
                          "inside_fraction": frac, "median_residual_m": resid,
                          "holds": bool(front.all() and frac >= min_inside)})
        holding = [c for c in cands if c["holds"]]
        ev = {"frames_checked": [int(f) for f in frames[:50]], "n_frames_checked": len(frames),
              "min_inside": min_inside, "candidates": cands, "object_axes": obj_axes,
              "check": "valid objects' world centres moved into the camera: depth > 0 and "
                       "projection inside the image with the frame intrinsics"}
        if not holding:
            raise InputError("no camera-pose convention places the annotated objects in front of the "
                             "camera and inside the image", file=self.dir, field="camera")
        best = min(holding, key=lambda c: c["median_residual_m"])
        ev["ambiguous"] = len(holding) > 1
        return {"direction": best["direction"], "axes": best["axes"], "object_axes": obj_axes}, ev

    @cached_property
    def convention(self) -> tuple[dict, dict]:
        """``verify_camera_convention()`` over all frames (cached)."""
        return self.verify_camera_convention()

    def _world_from_cv(self, frame: int) -> np.ndarray:
        conv = self.convention[0]
        P = self.stored_camera_pose(frame)
        T_world_from_cam = P if conv["direction"] == "world_from_cam" else invert_T(P)
        return T_world_from_cam @ T_GL_FROM_CV if conv["axes"] == "opengl" else T_world_from_cam

    # -- tracks and boxes
    def camera_track(self, *, rebase: bool = True) -> PoseTrack:
        """Camera poses (OpenCV axes) at ``t = frame / fps``.

        ``rebase=True``: ``T_c0_from_cam(t)`` with ``c0`` the camera at the first frame;
        ``rebase=False``: ``T_scene_from_cam(t)`` in the stored scene frame.
        """
        key = ("camera_track", rebase)
        if key in self._memo:
            return self._memo[key]
        frames = self.frames
        T = np.stack([self._world_from_cv(f) for f in frames])
        for k, f in enumerate(frames):
            check_rotation(T[k, :3, :3], tol=ROTATION_TOL, file=self.meta_path(f), row="camera",
                           field="camera.quaternion")
        if rebase:
            T = invert_T(T[0]) @ T
        track = PoseTrack(np.array(frames) / self.fps, T, name=f"ROPE {self.scene} camera",
                          source=str(self.dir),
                          meta={"frames": np.array(frames), "convention": self.convention[0],
                                "world": "camera at first frame" if rebase else "ROPE scene frame"})
        self._memo[key] = track
        return track

    def world_up_in_track_frame(self, up_scene: np.ndarray) -> np.ndarray:
        """A scene-frame direction expressed in the rebased (first-camera) frame."""
        R = invert_T(self._world_from_cv(self.frames[0]))[:3, :3]
        return R @ np.asarray(up_scene, dtype=np.float64)

    def _cam_from_obj_cv(self, Tc: np.ndarray) -> np.ndarray:
        return T_GL_FROM_CV @ Tc if self.convention[0]["object_axes"] == "opengl" else Tc

    def object_boxes(self, frame: int) -> list[dict]:
        """Camera-frame boxes of the frame's objects (OpenCV axes).

        Each dict: ``oid``, ``class_name``, ``mask_id``, ``is_valid``, ``center`` (m),
        ``R`` (``R_cam_from_box``), ``lwh`` (= ``scale * dimensions``, m), ``bbox_side_len`` (as stored).
        """
        key = ("object_boxes", frame)
        if key in self._memo:
            return [dict(b) for b in self._memo[key]]
        inst = self.object_meta.instance_dict
        out = []
        for o, Tc, _ in self._objects(frame, world=False):
            oid = o.meta.oid
            if oid not in inst:
                raise InputError(f"object {oid} is not in the object meta", file=self.obj_meta_path,
                                 row=oid, field="instance_dict")
            T = self._cam_from_obj_cv(Tc)
            check_rotation(T[:3, :3], tol=ROTATION_TOL, file=self.meta_path(frame), row=oid,
                           field="quaternion_wxyz")
            lwh = np.asarray(o.meta.scale, dtype=np.float64) * np.asarray(inst[oid].dimensions, dtype=np.float64)
            out.append({"oid": oid, "class_name": o.meta.class_name, "mask_id": int(o.mask_id),
                        "is_valid": bool(o.is_valid), "center": T[:3, 3].copy(), "R": T[:3, :3].copy(),
                        "lwh": lwh, "bbox_side_len": np.asarray(o.meta.bbox_side_len, dtype=np.float64)})
        self._memo[key] = out
        return [dict(b) for b in out]

    def object_track(self, oid: str, *, rebase: bool = True) -> PoseTrack:
        """Object poses ``T_c0_from_obj`` (``rebase``) or ``T_scene_from_obj`` over the frames listing it.

        Chain: camera track at the frame @ the object's camera-frame pose (``T_cam_from_obj``).
        """
        key = ("object_track", oid, rebase)
        if key in self._memo:
            return self._memo[key]
        cam = self.camera_track(rebase=rebase)
        T, times = [], []
        for k, f in enumerate(self.frames):
            for o, Tc, _ in self._objects(f, world=False):
                if o.meta.oid == oid:
                    T.append(cam.T[k] @ self._cam_from_obj_cv(Tc))
                    times.append(cam.times[k])
                    break
        if not T:
            raise InputError(f"object {oid} appears in no frame", file=self.dir, row=oid, field="oid")
        track = PoseTrack(np.array(times), np.stack(T), name=f"ROPE {self.scene} object {oid}",
                          source=str(self.dir), meta={"oid": oid, "convention": self.convention[0]})
        self._memo[key] = track
        return track
