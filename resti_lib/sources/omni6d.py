"""Omni6DPose ROPE readers: per-frame ``<frame>_meta.json`` and ``Meta/real_obj_meta.json``.

Layout: ``../shared/formats/omni6dpose.md``. Files are parsed with the official dataclasses
(``cutoop.image_meta.ImageMetaData``, ``cutoop.obj_meta.ObjectMetaData``); images are never read.

Frames and conventions
----------------------
- Quaternions are scalar-first ``(w, x, y, z)`` (converted with
  :func:`resti_lib.geometry.frames.quat_wxyz_to_matrix`).
- Object ``quaternion_wxyz``/``translation``: ``T_cam_from_obj`` in the frame's camera. Their
  camera axes are *verified*, not assumed (:meth:`RopeScene.object_axes`): under the right reading
  the valid objects lie in front of the camera and project inside the image with the frame's
  intrinsics. Outputs use OpenCV camera axes (+X right, +Y down, +Z forward).
- Real ROPE frames store the camera pose as identity and ``world_translation`` as zeros: the
  camera motion is recovered from the objects (:meth:`RopeScene.object_camera_poses`). Objects
  that stay static relative to each other are found first (pairwise relative poses constant over
  every frame both are annotated in; the largest mutually consistent set wins); moving or
  re-placed objects are left out and named in the evidence. With the first frame's camera as the
  world, ``T_c0_from_cam(k) = T_c0_from_obj @ T_cam(k)_from_obj^-1`` averaged over the static
  objects annotated in frame ``k`` (objects first seen later are placed in ``c0`` through a frame
  that also shows an already placed one). A frame that shows no static object has no camera pose
  (NaN: an invalid sample of the track).
- A stored camera pose that carries motion (synthetic SOPE-style scenes) is used only after it
  agrees with the objects (:meth:`RopeScene.verify_camera_convention`: its direction,
  ``world_from_cam`` or ``cam_from_world``, and camera axes, OpenCV or OpenGL, are the reading
  whose first-frame-relative track matches the objects' track within ``agree_tol_m`` /
  ``agree_tol_deg``). Otherwise the objects' track is used and the evidence says why.
- The trajectory world is the camera frame at the sequence's first frame, as the ``pose`` contract
  states; ``t = frame / fps`` (30 Hz). World up in that frame: the stored scene frame's up when the
  stored camera pose is used, otherwise the consensus of the static objects' up axes
  (``tag.upAxis`` of the object meta; objects stand upright on the table).
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
from scipy.spatial.transform import Rotation

from resti_lib.errors import SourceError
from resti_lib.geometry.frames import check_rotation, invert_T, make_T, quat_wxyz_to_matrix
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
#: two objects are static relative to each other when their relative pose stays within these of
#: its reference over every frame annotating both (annotation noise of real ROPE is far below)
STATIC_TOL_M = 0.01
STATIC_TOL_DEG = 2.0
#: a stored camera track is used only when it matches the objects' track within these
AGREE_TOL_M = 0.005
AGREE_TOL_DEG = 0.5
#: stored camera poses closer than this to the first frame's (entries) carry no motion
NO_MOTION_TOL = 1e-9
#: object up axes within this angle of each other vote for the same world up
UP_CONSENSUS_DEG = 15.0


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
        raise SourceError(f"cannot read: {e}", file=path) from None
    except json.JSONDecodeError as e:
        raise SourceError(f"invalid JSON: {e.msg}", file=path, row=e.lineno) from None


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
        raise SourceError(f"not a ROPE frame meta: {e}", file=path, field=_missing_field(e)) from None


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
        raise SourceError(f"not an object meta file: {e}", file=path, field=_missing_field(e)) from None


def _numbers(x, n: int, *, file: Path, row: object, field: str) -> np.ndarray:
    """``n`` finite numbers from a JSON list (a string, a boolean or a missing entry is damage)."""
    if not isinstance(x, (list, tuple)) or len(x) != n or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in x):
        raise SourceError(f"must be a list of {n} numbers, got {str(x)[:60]!r}", file=file, row=row, field=field)
    a = np.asarray(x, dtype=np.float64)
    if not np.isfinite(a).all():
        raise SourceError(f"must be {n} finite numbers, got {a.tolist()}", file=file, row=row, field=field)
    return a


def _pose(q, t, *, file: Path, row: object, field: str) -> np.ndarray:
    q = _numbers(q, 4, file=file, row=row, field=field)
    t = _numbers(t, 3, file=file, row=row, field=field.replace("quaternion", "translation"))
    if t.shape != (3,) or not np.isfinite(t).all():
        raise SourceError(f"translation must be 3 finite numbers, got {t.tolist()}", file=file, row=row,
                         field=field.replace("quaternion", "translation"))
    R = quat_wxyz_to_matrix(q, file=file, row=row, field=field)
    return make_T(R, t)


def _angle_deg(R: np.ndarray) -> np.ndarray:
    """Rotation angle(s) of ``R`` ``[..., 3, 3]`` in degrees."""
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _relative_spread(Ta: np.ndarray, Tb: np.ndarray) -> tuple[float, float]:
    """Largest deviation (m, deg) of ``T_a_from_b`` over frames from its reference value.

    ``Ta``/``Tb`` are ``T_cam_from_obj`` of two objects over the frames annotating both; the
    reference is the frame whose relative translation is nearest the component-wise median.
    """
    rel = invert_T(Ta) @ Tb
    t = rel[:, :3, 3]
    ref = int(np.argmin(np.linalg.norm(t - np.median(t, axis=0), axis=1)))
    dt = np.linalg.norm(t - t[ref], axis=1)
    dr = _angle_deg(np.swapaxes(rel[ref, :3, :3], 0, 1)[None] @ rel[:, :3, :3])
    return float(dt.max()), float(dr.max())


def _maximal_cliques(nodes: list[str], adj: dict[str, set[str]]) -> list[set[str]]:
    """Every maximal clique of a small undirected graph (Bron-Kerbosch with pivoting)."""
    out: list[set[str]] = []

    def grow(r: set[str], p: set[str], x: set[str]) -> None:
        if not p and not x:
            out.append(r)
            return
        pivot = max(p | x, key=lambda u: (len(adj[u] & p), u))
        for v in sorted(p - adj[pivot]):
            grow(r | {v}, p & adj[v], x & adj[v])
            p = p - {v}
            x = x | {v}

    grow(set(), set(nodes), set())
    return out


def _mean_pose(Ts: list[np.ndarray]) -> tuple[np.ndarray, float, float]:
    """Consensus of rigid poses (mean translation, chordal mean rotation) and the largest deviation
    of a member from it (m, deg)."""
    if len(Ts) == 1:
        return Ts[0].copy(), 0.0, 0.0
    A = np.stack(Ts)
    t = A[:, :3, 3].mean(axis=0)
    R = Rotation.from_matrix(A[:, :3, :3]).mean().as_matrix()
    dt = float(np.linalg.norm(A[:, :3, 3] - t, axis=1).max())
    dr = float(_angle_deg(R.T[None] @ A[:, :3, :3]).max())
    return make_T(R, t), dt, dr


def _up_axis(tag) -> tuple[np.ndarray, str]:
    """Object-space up direction from ``tag.upAxis`` (``"y"``, ``"-z"`` ...); ``+y`` when absent."""
    axes = list(getattr(tag, "upAxis", None) or []) if tag is not None else []
    name = str(axes[0]).strip().lower() if axes else "y"
    sign = -1.0 if name.startswith("-") else 1.0
    letter = name.lstrip("+-")
    if letter not in ("x", "y", "z"):
        letter, sign, name = "y", 1.0, "y"
    v = np.zeros(3)
    v["xyz".index(letter)] = sign
    return v, (name if axes else "y (upAxis not given)")


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
    static_tol_m, static_tol_deg : float
        Two objects are static relative to each other when their relative pose deviates by at most
        these over every frame annotating both.
    agree_tol_m, agree_tol_deg : float
        A stored camera pose that carries motion is used only when its track matches the objects'
        track within these at every frame.
    """

    def __init__(self, root: str | Path, scene: str, fps: float = 30.0, *, static_tol_m: float = STATIC_TOL_M,
                 static_tol_deg: float = STATIC_TOL_DEG, agree_tol_m: float = AGREE_TOL_M,
                 agree_tol_deg: float = AGREE_TOL_DEG):
        self.root = Path(root)
        self.scene = str(scene)
        self.fps = float(fps)
        self.static_tol_m = float(static_tol_m)
        self.static_tol_deg = float(static_tol_deg)
        self.agree_tol_m = float(agree_tol_m)
        self.agree_tol_deg = float(agree_tol_deg)
        self.dir = self.root / "ROPE" / self.scene
        if not self.dir.is_dir():
            raise SourceError("ROPE scene folder not found", file=self.dir, field="sequence")
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
                raise SourceError("frame id is not a number", file=p, field="frame")
            out.append(int(stem))
        if not out:
            raise SourceError("no <frame>_meta.json files", file=self.dir, field="frame")
        return sorted(out)

    def meta_path(self, frame: int) -> Path:
        return self.dir / f"{int(frame):06d}_meta.json"

    def meta(self, frame: int):
        """The frame's ``ImageMetaData`` (cached)."""
        frame = int(frame)
        if frame not in self._meta:
            p = self.meta_path(frame)
            if not p.exists():
                raise SourceError(f"no meta for frame {frame}", file=p, row=frame, field="frame")
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

    def _objects(self, frame: int, *, world: bool = False) -> list[tuple[Any, np.ndarray, np.ndarray | None]]:
        """(object, T_cam_from_obj as stored, T_world_from_obj or None) per object of the frame.

        The stored world pose (``world=True``) is meaningful only in synthetic SOPE-style scenes;
        real ROPE frames store ``world_translation`` as zeros.
        """
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

    # -- object poses in the camera
    @cached_property
    def object_axes(self) -> tuple[str, dict]:
        """Camera axes of the stored object poses, verified against the intrinsics.

        Under the right reading (``opencv``: +Z forward; ``opengl``: +Z backward, +Y up) the valid
        objects' centres lie in front of the camera and project inside the image: the reading with
        at least 90 % of the centres in front and half of them inside the image holds (the two
        readings disagree on the sign of every depth, so at most one holds).

        Raises
        ------
        InputError
            No valid object is annotated, or neither reading places the objects in view.
        """
        pts, K = [], []
        for f in self.frames:
            intr = self.intrinsics(f)
            for o, Tc, _ in self._objects(f):
                if bool(getattr(o, "is_valid", True)):
                    pts.append(Tc[:3, 3])
                    K.append([intr["fx"], intr["fy"], intr["cx"], intr["cy"], intr["width"], intr["height"]])
        if not pts:
            raise SourceError("no valid object is annotated: the camera motion cannot be recovered",
                             file=self.dir, field="objects")
        P, K = np.array(pts), np.array(K)
        cands = []
        for axes, flip in (("opencv", np.ones(3)), ("opengl", np.array([1.0, -1.0, -1.0]))):
            p = P * flip
            z = p[:, 2]
            front = z > 0
            with np.errstate(divide="ignore", invalid="ignore"):
                u = K[:, 0] * p[:, 0] / z + K[:, 2]
                v = K[:, 1] * p[:, 1] / z + K[:, 3]
            inside = front & (u >= 0) & (u < K[:, 4]) & (v >= 0) & (v < K[:, 5])
            cands.append({"axes": axes, "n_objects": len(p), "n_positive_depth": int(front.sum()),
                          "n_inside_image": int(inside.sum()), "inside_fraction": float(inside.mean()),
                          "holds": bool(front.mean() >= 0.9 and inside.mean() >= 0.5)})
        holding = [c for c in cands if c["holds"]]
        ev = {"check": "valid objects' camera-frame centres: depth > 0 (90 % at least) and projection inside the "
                       "image with the frame intrinsics (half at least)", "candidates": cands}
        if not holding:
            raise SourceError("no camera-axis convention places the annotated objects in front of the camera "
                             "and inside the image", file=self.dir, field="objects")
        return max(holding, key=lambda c: c["inside_fraction"])["axes"], ev

    def _cam_from_obj_cv(self, Tc: np.ndarray) -> np.ndarray:
        return T_GL_FROM_CV @ Tc if self.object_axes[0] == "opengl" else Tc

    @cached_property
    def _observations(self) -> dict[str, dict]:
        """oid -> ``{"k": frame indices, "T": T_cam_from_obj [n, 4, 4] (OpenCV axes)}``, valid objects."""
        obs: dict[str, dict] = {}
        for k, f in enumerate(self.frames):
            seen = set()
            for o, Tc, _ in self._objects(f):
                oid = str(o.meta.oid)
                if not bool(getattr(o, "is_valid", True)) or oid in seen:
                    continue
                seen.add(oid)
                T = self._cam_from_obj_cv(Tc)
                check_rotation(T[:3, :3], tol=ROTATION_TOL, file=self.meta_path(f), row=oid, field="quaternion_wxyz")
                d = obs.setdefault(oid, {"k": [], "T": []})
                d["k"].append(k)
                d["T"].append(T)
        return {oid: {"k": np.array(d["k"]), "T": np.stack(d["T"])} for oid, d in sorted(obs.items())}

    @cached_property
    def static_objects(self) -> tuple[list[str], dict]:
        """The objects static relative to each other, and the evidence.

        Every pair of objects annotated together in some frames is *consistent* when its relative
        pose stays within ``static_tol_m`` / ``static_tol_deg`` of its reference over all those
        frames. The static set is the largest set of pairwise compatible objects (no inconsistent
        pair; ties: more annotated frames, then object id). Objects outside it moved or were
        re-placed during the sequence (or their annotation is inconsistent): they are left out of
        the camera track, each with the objects it disagrees with and the largest deviation.
        """
        obs = self._observations
        ids = list(obs)
        pairs: dict[tuple[str, str], dict] = {}
        adj: dict[str, set[str]] = {a: set() for a in ids}
        for i, a in enumerate(ids):
            for b in ids[i + 1:]:
                ka, kb = obs[a]["k"], obs[b]["k"]
                common, ia, ib = np.intersect1d(ka, kb, return_indices=True)
                if common.size:
                    dt, dr = _relative_spread(obs[a]["T"][ia], obs[b]["T"][ib])
                    ok = dt <= self.static_tol_m and dr <= self.static_tol_deg
                    pairs[(a, b)] = {"frames": int(common.size), "max_deviation_m": dt,
                                     "max_deviation_deg": dr, "consistent": ok}
                else:
                    ok = True
                if ok:
                    adj[a].add(b)
                    adj[b].add(a)
        cover = {a: len(obs[a]["k"]) for a in ids}
        cliques = _maximal_cliques(ids, adj) if ids else []
        best = min(cliques, key=lambda c: (-len(c), -sum(cover[a] for a in c), sorted(c))) if cliques else set()
        static = [a for a in ids if a in best]
        left_out = []
        for a in ids:
            if a in best:
                continue
            bad = [(b, p) for (x, y), p in pairs.items() for b in ((y,) if x == a else (x,) if y == a else ())
                   if not p["consistent"] and b in best]
            left_out.append({"oid": a, "reason": "moves relative to the static objects (moved or re-placed)"
                             if bad else "not in the largest consistent set",
                             "inconsistent_with": [b for b, _ in bad],
                             "max_deviation_m": max((p["max_deviation_m"] for _, p in bad), default=None),
                             "max_deviation_deg": max((p["max_deviation_deg"] for _, p in bad), default=None)})
        ev = {"n_objects": len(ids), "static_objects": static, "left_out": left_out,
              "tolerance": {"m": self.static_tol_m, "deg": self.static_tol_deg},
              "n_pairs_checked": len(pairs), "n_inconsistent_pairs": sum(not p["consistent"] for p in pairs.values()),
              "rule": "objects whose pairwise relative poses stay constant over every frame annotating both; "
                      "the largest such set"}
        if len(static) == 1 and len(ids) > 1:
            ev["note"] = "one object only: that it is static cannot be checked against another"
        return static, ev

    @cached_property
    def object_camera_poses(self) -> tuple[np.ndarray, dict]:
        """``T_c0_from_cam`` per frame (OpenCV axes) from the static objects, and the evidence.

        ``c0`` is the camera of the first frame showing a static object (normally the first frame).
        Static objects are placed in ``c0`` from the first frame that shows them together with an
        already placed one; each frame's camera is then the consensus of
        ``T_c0_from_obj @ T_cam_from_obj^-1`` over the static objects it shows. Frames showing none
        get NaN (an invalid pose).
        """
        obs = self._observations
        static, sev = self.static_objects
        n = len(self.frames)
        at: list[dict[str, np.ndarray]] = [{} for _ in range(n)]
        for oid in static:
            for k, T in zip(obs[oid]["k"], obs[oid]["T"]):
                at[int(k)][oid] = T
        T = np.full((n, 4, 4), np.nan)
        first = next((k for k in range(n) if at[k]), None)
        if first is None:
            raise SourceError("no frame shows a static object: the camera motion cannot be recovered",
                             file=self.dir, field="objects")
        placed = {oid: Tc.copy() for oid, Tc in at[first].items()}
        grew = True
        while grew:
            grew = False
            for k in range(n):
                known = [o for o in at[k] if o in placed]
                new = [o for o in at[k] if o not in placed]
                if not known or not new:
                    continue
                Tk, _, _ = _mean_pose([placed[o] @ invert_T(at[k][o]) for o in known])
                for o in new:
                    placed[o] = Tk @ at[k][o]
                grew = True
        spread_m, spread_deg, used = np.zeros(n), np.zeros(n), np.zeros(n, int)
        for k in range(n):
            known = [o for o in at[k] if o in placed]
            if not known:
                continue
            T[k], spread_m[k], spread_deg[k] = _mean_pose([placed[o] @ invert_T(at[k][o]) for o in known])
            used[k] = len(known)
        T[first] = np.eye(4)
        ok = used > 0
        ev = {**sev, "first_frame": int(self.frames[first]), "n_frames": n,
              "frames_without_static_object": int((~ok).sum()),
              "objects_per_frame": {"min": int(used[ok].min()), "median": float(np.median(used[ok])),
                                    "max": int(used[ok].max())},
              "max_consensus_spread_m": float(spread_m.max()), "max_consensus_spread_deg": float(spread_deg.max()),
              "unplaced_static_objects": sorted(set(static) - set(placed)),
              "chain": "T_c0<-cam(k) = mean over static objects o of T_c0<-o T_cam(k)<-o^-1"}
        self._placed = placed
        return T, ev

    # -- the stored camera pose
    def _world_from_cv(self, frame: int, direction: str, axes: str) -> np.ndarray:
        P = self.stored_camera_pose(frame)
        T_world_from_cam = P if direction == "world_from_cam" else invert_T(P)
        return T_world_from_cam @ T_GL_FROM_CV if axes == "opengl" else T_world_from_cam

    def verify_camera_convention(self) -> tuple[dict, dict]:
        """Decide where the camera motion comes from: the stored camera pose or the objects.

        A stored camera pose that is the same in every frame (identity in real ROPE) carries no
        motion: the objects' track (:attr:`object_camera_poses`) is used. Otherwise each reading
        of :data:`CONVENTIONS` is rebased to the objects' first frame and compared with the
        objects' track at every frame both know; a reading *holds* when it stays within
        ``agree_tol_m`` / ``agree_tol_deg``. The holding reading with the smallest residual is used;
        when none holds the objects' track is used and the evidence says the stored pose disagreed.

        Returns
        -------
        convention : ``{"camera": "objects"|"stored", "direction", "axes", "object_axes"}``
            (``direction``/``axes`` None for ``objects``)
        evidence : the object track's evidence plus the stored pose's check.
        """
        obj_axes, axes_ev = self.object_axes
        T_obj, oev = self.object_camera_poses
        frames = self.frames
        P = np.stack([self.stored_camera_pose(f) for f in frames])
        moving = bool(np.abs(P - P[0]).max() > NO_MOTION_TOL)
        ev = {"objects": oev, "object_axes_check": axes_ev}
        conv = {"camera": "objects", "direction": None, "axes": None, "object_axes": obj_axes}
        if not moving:
            ev["stored_camera"] = "the same pose in every frame: carries no motion"
            return conv, ev
        first = frames.index(oev["first_frame"])
        ok = np.isfinite(T_obj).all(axis=(1, 2))
        cands = []
        for direction, axes in CONVENTIONS:
            W = np.stack([self._world_from_cv(f, direction, axes) for f in frames])
            rel = invert_T(W[first]) @ W
            dt = np.linalg.norm(rel[ok, :3, 3] - T_obj[ok, :3, 3], axis=1)
            dr = _angle_deg(np.swapaxes(rel[ok, :3, :3], 1, 2) @ T_obj[ok, :3, :3])
            cands.append({"direction": direction, "axes": axes, "max_residual_m": float(dt.max()),
                          "max_residual_deg": float(dr.max()), "frames_compared": int(ok.sum()),
                          "holds": bool(dt.max() <= self.agree_tol_m and dr.max() <= self.agree_tol_deg)})
        ev["stored_camera"] = {"carries_motion": True, "candidates": cands,
                               "tolerance": {"m": self.agree_tol_m, "deg": self.agree_tol_deg}}
        holding = [c for c in cands if c["holds"]]
        if not holding:
            ev["stored_camera"]["used"] = False
            ev["stored_camera"]["note"] = "no reading of the stored camera pose agrees with the objects: not used"
            return conv, ev
        best = min(holding, key=lambda c: (c["max_residual_m"], c["max_residual_deg"]))
        ev["stored_camera"]["used"] = True
        return {"camera": "stored", "direction": best["direction"], "axes": best["axes"],
                "object_axes": obj_axes}, ev

    @cached_property
    def convention(self) -> tuple[dict, dict]:
        """:meth:`verify_camera_convention` (cached)."""
        return self.verify_camera_convention()

    # -- tracks and boxes
    def camera_track(self, *, rebase: bool = True) -> PoseTrack:
        """Camera poses (OpenCV axes) at ``t = frame / fps``; frames with no known pose are invalid.

        From the objects: ``T_c0_from_cam(t)`` whatever ``rebase`` (real ROPE has no scene frame).
        From a verified stored pose: ``rebase=True`` gives ``T_c0_from_cam(t)``, ``rebase=False``
        ``T_scene_from_cam(t)`` in the stored scene frame.
        """
        key = ("camera_track", rebase)
        if key in self._memo:
            return self._memo[key]
        conv, ev = self.convention
        frames = self.frames
        if conv["camera"] == "stored":
            T = np.stack([self._world_from_cv(f, conv["direction"], conv["axes"]) for f in frames])
            for k, f in enumerate(frames):
                check_rotation(T[k, :3, :3], tol=ROTATION_TOL, file=self.meta_path(f), row="camera",
                               field="camera.quaternion")
            if rebase:
                T = invert_T(T[0]) @ T
            world = "camera at first frame" if rebase else "ROPE scene frame"
            source = f"{self.dir} (stored camera pose, agrees with the objects)"
        else:
            T = self.object_camera_poses[0]
            world = f"camera at frame {ev['objects']['first_frame']}"
            source = f"{self.dir} (camera from static objects)"
        track = PoseTrack(np.array(frames) / self.fps, T, name=f"ROPE {self.scene} camera", source=source,
                          meta={"frames": np.array(frames), "convention": conv, "world": world,
                                "evidence": self.camera_evidence()})
        self._memo[key] = track
        return track

    def camera_evidence(self) -> dict:
        """Compact evidence of the camera track: where it comes from, the static objects and the ones
        left out, frames without a pose, consensus spread, the world up used."""
        conv, ev = self.convention
        o = ev["objects"]
        out = {"camera_source": "stored camera pose (agrees with the objects)" if conv["camera"] == "stored"
               else "static objects' camera-frame poses, inverted frame by frame",
               "static_objects": o["static_objects"], "left_out": o["left_out"],
               "first_frame": o["first_frame"], "frames_without_static_object": o["frames_without_static_object"],
               "max_consensus_spread_m": o["max_consensus_spread_m"],
               "max_consensus_spread_deg": o["max_consensus_spread_deg"], "object_axes": conv["object_axes"],
               "stored_camera": ev["stored_camera"] if isinstance(ev["stored_camera"], str)
               else {k: v for k, v in ev["stored_camera"].items() if k != "candidates"}}
        if conv["camera"] == "stored":
            out["stored_camera_reading"] = {"direction": conv["direction"], "axes": conv["axes"]}
        return out

    @cached_property
    def gravity(self) -> tuple[np.ndarray, dict]:
        """World up in the first camera frame from the static objects' up axes, and the evidence.

        Each static object's up axis (``tag.upAxis`` of the object meta, object space; +y when not
        given, or without the object meta file) is expressed in ``c0``; the direction shared (within
        :data:`UP_CONSENSUS_DEG`) by the most objects wins and its members are averaged.
        """
        self.object_camera_poses  # noqa: B018 -- places the static objects in c0 (self._placed)
        # the up axes need the object meta; without the file every object takes +y (Omni6DPose objects
        # are modelled y-up); a damaged file is an error
        inst = self.object_meta.instance_dict if self.obj_meta_path.exists() else {}
        vecs, names = [], []
        for oid, Tc0 in sorted(self._placed.items()):
            tag = getattr(inst[oid], "tag", None) if oid in inst else None
            v, axis = _up_axis(tag)
            vecs.append(Tc0[:3, :3] @ v)
            names.append((oid, axis))
        if not vecs:
            return np.array([0.0, -1.0, 0.0]), {"method": "no static object: the first camera's -Y assumed"}
        V = np.array(vecs)
        cos_tol = np.cos(np.radians(UP_CONSENSUS_DEG))
        agree = (V @ V.T) >= cos_tol
        best = int(np.argmax(agree.sum(axis=1)))
        members = np.flatnonzero(agree[best])
        up = V[members].sum(axis=0)
        up /= np.linalg.norm(up)
        spread = float(np.degrees(np.arccos(np.clip(V[members] @ up, -1, 1))).max())
        return up, {"method": "consensus of the static objects' up axes (object meta tag.upAxis)",
                    "objects": [{"oid": o, "up_axis": a, "agrees": bool(agree[best, i])}
                                for i, (o, a) in enumerate(names)],
                    "n_agreeing": int(members.size), "spread_deg": spread, "up_c0": up.tolist()}

    def world_up_in_track_frame(self, up_scene: np.ndarray) -> np.ndarray:
        """World up in the rebased (first-camera) frame.

        With a verified stored camera pose: the scene-frame direction ``up_scene`` moved into ``c0``.
        From the objects (real ROPE, no scene frame): :attr:`gravity`; ``up_scene`` is not used.
        """
        conv, _ = self.convention
        if conv["camera"] == "stored":
            R = invert_T(self._world_from_cv(self.frames[0], conv["direction"], conv["axes"]))[:3, :3]
            return R @ np.asarray(up_scene, dtype=np.float64)
        return self.gravity[0].copy()

    def camera_notes(self, up_scene) -> list[str]:
        """Short evidence lines for ``resti measure``: the camera source, the static objects and the ones
        left out, and where world up comes from."""
        ev = self.camera_evidence()
        left = ", ".join(f"{x['oid']} ({x['reason']})" for x in ev["left_out"]) or "none"
        up = (f"up = scene {list(up_scene)}" if self.convention[0]["camera"] == "stored" else
              f"up = static objects' up axes ({self.gravity[1].get('n_agreeing', 0)} agree): "
              f"{np.round(self.gravity[0], 6).tolist()} in the first camera")
        return [f"camera: {ev['camera_source']}", f"static objects: {', '.join(ev['static_objects'])}",
                f"left out: {left}", up]

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
        for o, Tc, _ in self._objects(frame):
            oid = o.meta.oid
            if oid not in inst:
                raise SourceError(f"object {oid} is not in the object meta", file=self.obj_meta_path,
                                 row=oid, field="instance_dict")
            check_rotation(Tc[:3, :3], tol=ROTATION_TOL, file=self.meta_path(frame), row=oid,
                           field="quaternion_wxyz")
            T = self._cam_from_obj_cv(Tc)
            lwh = np.asarray(o.meta.scale, dtype=np.float64) * np.asarray(inst[oid].dimensions, dtype=np.float64)
            out.append({"oid": oid, "class_name": o.meta.class_name, "mask_id": int(o.mask_id),
                        "is_valid": bool(o.is_valid), "center": T[:3, 3].copy(), "R": T[:3, :3].copy(),
                        "lwh": lwh, "bbox_side_len": np.asarray(o.meta.bbox_side_len, dtype=np.float64)})
        self._memo[key] = out
        return [dict(b) for b in out]

    def object_track(self, oid: str, *, rebase: bool = True) -> PoseTrack:
        """Object poses ``T_c0_from_obj`` (``rebase``) or ``T_scene_from_obj`` over the frames listing it.

        Chain: camera track at the frame @ the object's camera-frame pose (``T_cam_from_obj``);
        invalid where the camera pose of the frame is unknown.
        """
        key = ("object_track", oid, rebase)
        if key in self._memo:
            return self._memo[key]
        cam = self.camera_track(rebase=rebase)
        T, times = [], []
        for k, f in enumerate(self.frames):
            for o, Tc, _ in self._objects(f):
                if o.meta.oid == oid:
                    T.append(cam.T[k] @ self._cam_from_obj_cv(Tc))
                    times.append(cam.times[k])
                    break
        if not T:
            raise SourceError(f"object {oid} appears in no frame", file=self.dir, row=oid, field="oid")
        track = PoseTrack(np.array(times), np.stack(T), name=f"ROPE {self.scene} object {oid}",
                          source=str(self.dir), meta={"oid": oid, "convention": self.convention[0],
                                                      "static": oid in self.static_objects[0]})
        self._memo[key] = track
        return track
