"""Omni6DPose ROPE scenes in the exact metadata layout (``../shared/formats/omni6dpose.md``).

A scene is a table (world frame: table top at z = 0, +Z up) with objects, filmed by a hand-held
camera at 30 FPS that orbits the table. In one default scene (``MOVING_SCENE``) one object is
picked up and put down elsewhere during the video (slid and turned on the table: a re-placed
object); every other object is static. Every frame gets a ``<frame>_meta.json`` with all fields of
``cutoop.image_meta.ImageMetaData``; ``Meta/real_obj_meta.json`` holds the object meta
(``cutoop.obj_meta.ObjectMetaData``, objects stand upright: ``upAxis`` z).

Frames are written the real way by default (``camera_pose="identity"``, as real ROPE frames,
``../shared/data/real_samples/``): the camera pose is identity, every object's
``world_translation`` is zero and its world rotation identity; the object poses
(``quaternion_wxyz``, ``translation``) are ``T_cam<-object`` in the OpenCV camera of the frame, so
the camera motion can only be recovered from the static objects. ``world_from_camera`` /
``camera_from_world`` write a SOPE-style stored camera pose that carries the motion (and the
objects' world poses) instead, for readers that verify a stored pose against the objects.
The truth is the world model (camera ``T_world<-cam`` and object poses per frame), never a reading
of the written files.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .common import (
    in_view,
    inv_T,
    look_rotation,
    make_T,
    point_box_distance,
    quat_wxyz_from_matrix,
    rot_z,
    round_list,
    smoothstep,
    stable_seed,
    write_json,
)

FPS = 30.0
IMAGE_SIZE = (1280, 720)
K_ROPE = (915.0556030273438, 914.1288452148438, 641.2314453125, 363.4847412109375)
#: how the camera pose is written: "identity" (real ROPE) or a SOPE-style pose carrying the motion
CONVENTIONS = ("identity", "world_from_camera", "camera_from_world")

# class -> (label, object-space dimensions (x, y, z) before scale, descriptions, group phrases)
_CLASSES: dict[str, dict] = {
    "teddy_bear": {
        "label": 41,
        "dims": (0.20, 0.29, 0.19),
        "desc": ["A small brown teddy bear wearing a blue shirt"],
    },
    "mug": {
        "label": 12,
        "dims": (0.12, 0.09, 0.10),
        "desc": ["A white ceramic mug with a red logo", "A blue mug with a white handle"],
        "group": ["the pair of mugs", "both mugs on the table", "the two mugs"],
    },
    "laptop": {"label": 27, "dims": (0.33, 0.24, 0.22), "desc": ["A silver laptop with a black keyboard"]},
    "suitcase": {
        "label": 35,
        "dims": (0.34, 0.20, 0.42),
        "desc": ["A red suitcase with a telescoping handle"],
    },
    "bottle": {
        "label": 5,
        "dims": (0.07, 0.07, 0.23),
        "desc": ["A clear plastic bottle with a green cap", "A brown glass bottle without a label"],
        "group": ["the set of bottles", "both bottles", "the two bottles"],
    },
    "bowl": {"label": 7, "dims": (0.16, 0.16, 0.06), "desc": ["A white porcelain bowl with a blue rim"]},
    "shoe": {"label": 31, "dims": (0.28, 0.10, 0.11), "desc": ["A grey running shoe with white laces"]},
    "box": {"label": 6, "dims": (0.26, 0.19, 0.12), "desc": ["A brown cardboard box with tape on top"]},
    "book": {"label": 4, "dims": (0.22, 0.15, 0.035), "desc": ["A hardcover book with a blue cover"]},
    "remote_control": {
        "label": 29,
        "dims": (0.17, 0.05, 0.025),
        "desc": ["A black remote control with red buttons"],
    },
}
ABSENT_CLASSES = {"toy_train": "A wooden toy train with red wheels", "camera": "A black compact camera"}

#: Default scenes: (scene id, duration s, stacked pair present)
DEFAULT_SCENES = [("000900", 20.0, True), ("000901", 18.0, False), ("000902", 22.0, True)]
#: The default scene in which one object is re-placed during the video (its last object).
MOVING_SCENE = "000901"


@dataclass
class RopeObject:
    """One static ROPE object: class, scale, object-space dimensions and world pose."""

    mask_id: int
    oid: str
    class_name: str
    description: str
    scale: np.ndarray  # (3,)
    dims: np.ndarray  # object-space dimensions (3,)
    T_world: np.ndarray  # (4, 4) T_world<-object at frame 0 (box centred at the object origin)
    on_top_of: int | None = None  # mask id of the object it stands on
    track: np.ndarray | None = None  # (N, 4, 4) T_world<-object per frame when the object moves
    moved: tuple[int, int] | None = None  # first and last frame of the motion

    @property
    def side(self) -> np.ndarray:
        """Box side lengths in metres (``scale * dimensions`` = ``bbox_side_len``)."""
        return self.scale * self.dims

    def pose(self, k: int) -> np.ndarray:
        """``T_world<-object`` at frame ``k``."""
        return self.T_world if self.track is None else self.track[k]

    def poses(self, n: int) -> np.ndarray:
        """``T_world<-object`` at every frame ``(n, 4, 4)``."""
        return np.broadcast_to(self.T_world, (n, 4, 4)) if self.track is None else self.track


@dataclass
class RopeScene:
    """A generated ROPE scene and its by-construction truth.

    Attributes
    ----------
    name : str
        Six-digit scene id.
    cam_world : ndarray (N, 4, 4)
        ``T_world<-cam`` (OpenCV axes) per frame.
    objects : list of RopeObject
    tied_pair, clear_pairs : pairs of mask ids (A, B) for relation questions at frame 0
    """

    name: str
    cam_world: np.ndarray
    objects: list[RopeObject]
    tied_pair: tuple[int, int]
    clear_pair: tuple[int, int] = (0, 0)
    fps: float = FPS
    _vis: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return int(self.cam_world.shape[0])

    @property
    def video_end(self) -> float:
        """Time of the last frame, ``(N - 1) / fps``."""
        return (self.n_frames - 1) / self.fps

    def frame_of(self, t: float) -> int:
        """Frame index of timeline time ``t``."""
        return int(round(t * self.fps))

    def obj(self, mask_id: int) -> RopeObject:
        """Object by mask id."""
        return next(o for o in self.objects if o.mask_id == mask_id)

    def obj_in_cam(self, o: RopeObject, k: int) -> np.ndarray:
        """``T_cam<-object`` at frame ``k``."""
        return inv_T(self.cam_world[k]) @ o.pose(k)

    @property
    def mover(self) -> RopeObject | None:
        """The object that moves during the video, if any."""
        return next((o for o in self.objects if o.track is not None), None)

    def visible(self) -> np.ndarray:
        """(objects, frames) bool: the object centre projects inside the image."""
        if self._vis is None:
            inv = inv_T(self.cam_world)
            out = np.zeros((len(self.objects), self.n_frames), bool)
            for i, o in enumerate(self.objects):
                c = o.poses(self.n_frames)[:, :3, 3]
                pc = np.einsum("nij,nj->ni", inv[:, :3, :3], c) + inv[:, :3, 3]
                out[i] = in_view(K_ROPE, IMAGE_SIZE, pc, margin=0.0, min_depth=0.05)
            self._vis = out
        return self._vis

    # ------------------------------------------------------------------ truth (own numpy)
    def box_in_camera(self, o: RopeObject, k: int) -> dict:
        """Oriented object box in the OpenCV camera frame at frame ``k``."""
        T = self.obj_in_cam(o, k)
        R = T[:3, :3]
        return {
            "C_central_point": T[:3, 3].tolist(),
            "C_lwh": o.side.tolist(),
            "C_rotation_camera_from_box": R.tolist(),
            "C_heading": math.degrees(math.atan2(R[1, 0], R[0, 0])),
        }

    def legacy_heading(self, o: RopeObject, k: int) -> float:
        """The legacy yaw summary: rotation about the camera's vertical axis, degrees."""
        R = self.obj_in_cam(o, k)[:3, :3]
        return math.degrees(math.atan2(R[0, 2], R[2, 2]))

    def pose_rel(self, k: int) -> np.ndarray:
        """``T_cam0<-cam(k)``: the camera pose with the first frame as identity."""
        return inv_T(self.cam_world[0]) @ self.cam_world[k]

    def displacement(self, k0: int, k1: int) -> float:
        """Camera displacement between two frames (m)."""
        return float(np.linalg.norm(self.cam_world[k1, :3, 3] - self.cam_world[k0, :3, 3]))

    def path_length(self, k0: int, k1: int) -> float:
        """Camera path length summed over the frames in [k0, k1] (m)."""
        p = self.cam_world[k0 : k1 + 1, :3, 3]
        return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))

    def distance_to_camera(self, o: RopeObject, k: int) -> float:
        """Distance from the camera centre to the object box at frame ``k`` (m)."""
        T = o.pose(k)
        return point_box_distance(self.cam_world[k, :3, 3], T[:3, 3], o.side, T[:3, :3])

    def relation(self, a: int, b: int, k: int = 0) -> tuple[str | None, dict]:
        """Dominant relation of A relative to B seen from the camera at frame k.

        ``Directly above`` when A stands on B; else the larger of the lateral (camera x) and depth
        (camera z) offsets decides (Left/Right, Closer/Farther) when it exceeds the other by a
        factor 1.5; otherwise no dominant relation (None).
        """
        A, B = self.obj(a), self.obj(b)
        inv = inv_T(self.cam_world[k])
        d = (inv[:3, :3] @ A.pose(k)[:3, 3] + inv[:3, 3]) - (inv[:3, :3] @ B.pose(k)[:3, 3] + inv[:3, 3])
        ev = {"dx": float(d[0]), "dy": float(d[1]), "dz": float(d[2])}
        if A.on_top_of == b:
            return "Directly above", ev
        lat, dep = abs(d[0]), abs(d[2])
        if lat >= 1.5 * dep:
            return ("Right" if d[0] > 0 else "Left"), ev
        if dep >= 1.5 * lat:
            return ("Farther" if d[2] > 0 else "Closer"), ev
        return None, ev

    def describe(self, convention: str) -> dict:
        """Ground truth for world.json."""
        mv = self.mover
        moving = None
        if mv is not None:
            a, b = mv.moved
            d = mv.pose(b)[:3, 3] - mv.pose(a)[:3, 3]
            moving = {"mask_id": mv.mask_id, "oid": mv.oid, "frames": [a, b],
                      "displacement_m": round(float(np.linalg.norm(d)), 6),
                      "yaw_change_deg": round(math.degrees(math.atan2(
                          (mv.pose(a)[:3, :3].T @ mv.pose(b)[:3, :3])[1, 0],
                          (mv.pose(a)[:3, :3].T @ mv.pose(b)[:3, :3])[0, 0])), 6)}
        return {
            "scene": self.name,
            "n_frames": self.n_frames,
            "fps": self.fps,
            "camera_pose_convention": convention,
            "moving_object": moving,
            "tied_pair": list(self.tied_pair),
            "clear_pair": list(self.clear_pair),
            "objects": [
                {
                    "mask_id": o.mask_id,
                    "oid": o.oid,
                    "class_name": o.class_name,
                    "description": o.description,
                    "side_len": round_list(o.side),
                    "T_world_from_object": round_list(o.T_world, 9),
                    "on_top_of": o.on_top_of,
                }
                for o in self.objects
            ],
            "absent_classes": sorted(ABSENT_CLASSES),
        }


# ============================================================================== construction


def _camera(rng: np.random.Generator, n: int) -> np.ndarray:
    t = np.arange(n) / FPS
    r = 0.85 + 0.12 * np.sin(2 * math.pi * t / rng.uniform(9, 14) + rng.uniform(0, 6))
    phi0 = rng.uniform(-math.pi, math.pi)
    sweep = math.radians(rng.uniform(45, 70))
    phi = phi0 + sweep * np.sin(2 * math.pi * t / rng.uniform(16, 24))
    h = 0.55 + 0.1 * np.sin(2 * math.pi * t / rng.uniform(6, 10) + rng.uniform(0, 6))
    look = np.stack([0.04 * np.sin(t / 1.3), 0.04 * np.cos(t / 1.7), 0.05 + 0.02 * np.sin(t / 2.1)], axis=1)
    roll = np.radians(3.0) * np.sin(2 * math.pi * t / rng.uniform(4, 7))
    pos = np.stack([r * np.cos(phi), r * np.sin(phi), h], axis=1)
    out = np.zeros((n, 4, 4))
    for i in range(n):
        out[i] = make_T(look_rotation(look[i] - pos[i], roll=roll[i]), pos[i])
    return out


def _free(xy: np.ndarray, rad: float, placed: list[tuple[np.ndarray, float]]) -> bool:
    if np.linalg.norm(xy) > 0.5:
        return False
    return all(np.linalg.norm(xy - q) > rad + r + 0.02 for q, r in placed)


def _tied_position(
    rng: np.random.Generator,
    R0: np.ndarray,
    base: RopeObject,
    z: float,
    rad: float,
    placed: list[tuple[np.ndarray, float]],
) -> np.ndarray | None:
    """A table position whose camera-frame offset from ``base`` has |x| == |z| at frame 0.

    With ``d = c_A - c_B`` and camera axes ``x = R0[:, 0]``, ``z = R0[:, 2]`` (world), the tie
    ``(x - z) . d = 0`` fixes the component of the horizontal offset along ``g``, the horizontal
    part of ``x - z``; the component along its perpendicular is free.
    """
    g = (R0[:, 0] - R0[:, 2]).copy()
    g[2] = 0.0
    perp = np.array([-g[1], g[0], 0.0]) / np.linalg.norm(g)
    dz_world = z - base.T_world[2, 3]
    c = -dz_world * (R0[2, 0] - R0[2, 2]) / float(g @ g)
    for _ in range(400):
        r0 = 0.5 * float(np.linalg.norm(base.side[:2]))
        s = rng.uniform(r0 + rad + 0.03, r0 + rad + 0.15) * rng.choice([-1, 1])
        cand = base.T_world[:2, 3] + (s * perp + c * g)[:2]
        if _free(cand, rad, placed):
            return cand
    return None


def _place_objects(
    rng: np.random.Generator, R0: np.ndarray, classes: list[str], seed: int
) -> list[RopeObject] | None:
    """Objects on the table (object 1 tied with object 0 at frame 0); None when they do not fit."""
    objs: list[RopeObject] = []
    placed: list[tuple[np.ndarray, float]] = []
    counts: dict[str, int] = {}
    for i, cls in enumerate(classes):
        spec = _CLASSES[cls]
        dims = np.array(spec["dims"], float)
        scale = np.full(3, rng.uniform(0.9, 1.1))
        side = scale * dims
        rad = 0.5 * float(np.linalg.norm(side[:2]))
        yaw = rng.uniform(-math.pi, math.pi)
        z = side[2] / 2
        on_top = None
        xy = None
        if cls == "book" and i == len(classes) - 1 and classes[i - 1] == "box":
            base = objs[-1]
            xy = base.T_world[:2, 3] + rng.uniform(-0.02, 0.02, size=2)
            z = base.side[2] + side[2] / 2
            on_top = base.mask_id
        elif i in (1, 2):
            # object 1: tied with object 0 at frame 0 (equal lateral and depth offsets);
            # object 2: clearly to the left or right of object 0
            if i == 1:
                xy = _tied_position(rng, R0, objs[0], z, rad, placed)
            else:
                xy = _clear_position(rng, R0, objs[0], rad, placed)
            if xy is None:
                return None
        else:
            lim = 0.12 if i == 0 else 0.42
            for _ in range(300):
                cand = rng.uniform(-lim, lim, size=2)
                if _free(cand, rad, placed):
                    xy = cand
                    break
            else:
                return None
        if on_top is None:
            placed.append((xy, rad))
        k = counts.get(cls, 0)
        counts[cls] = k + 1
        descs = spec["desc"]
        objs.append(
            RopeObject(
                mask_id=i + 1,
                oid=f"omniobject3d-{cls}_{int(seed % 97) + 3 * i:03d}",
                class_name=str(cls),
                description=str(descs[k % len(descs)]),
                scale=scale,
                dims=dims,
                T_world=make_T(rot_z(yaw), [xy[0], xy[1], z]),
                on_top_of=on_top,
            )
        )
    return objs


def _clear_position(
    rng: np.random.Generator,
    R0: np.ndarray,
    base: RopeObject,
    rad: float,
    placed: list[tuple[np.ndarray, float]],
) -> np.ndarray | None:
    """A table position beside ``base`` along the camera's horizontal x axis at frame 0 (a clear
    Left/Right relation: the lateral offset is at least 3x the depth offset)."""
    ex = R0[:, 0].copy()
    ex[2] = 0.0
    ex /= np.linalg.norm(ex)
    r0 = 0.5 * float(np.linalg.norm(base.side[:2]))
    for _ in range(200):
        s = rng.uniform(r0 + rad + 0.05, r0 + rad + 0.15) * rng.choice([-1, 1])
        cand = base.T_world[:2, 3] + s * ex[:2]
        if _free(cand, rad, placed):
            return cand
    return None


def _move(rng: np.random.Generator, scene: RopeScene, o: RopeObject) -> bool:
    """Re-place object ``o`` during the video: slid 12-20 cm and turned 20-40 degrees on the table
    over 1.5-2.5 s (smoothstep), static before and after. False when no free spot is found."""
    n = scene.n_frames
    k0 = round(rng.uniform(0.3, 0.5) * n)
    k1 = min(k0 + round(rng.uniform(1.5, 2.5) * FPS), n - 1)
    rad = 0.5 * float(np.linalg.norm(o.side[:2]))
    placed = [(q.T_world[:2, 3], 0.5 * float(np.linalg.norm(q.side[:2]))) for q in scene.objects
              if q is not o and q.on_top_of is None]
    for _ in range(200):
        ang = rng.uniform(-math.pi, math.pi)
        dist = rng.uniform(0.12, 0.20)
        end = o.T_world[:2, 3] + dist * np.array([math.cos(ang), math.sin(ang)])
        if _free(end, rad, placed):
            break
    else:
        return False
    dyaw = math.radians(rng.uniform(20, 40)) * rng.choice([-1, 1])
    s = smoothstep((np.arange(n) - k0) / max(k1 - k0, 1))
    track = np.repeat(o.T_world[None], n, axis=0)
    for k in range(k0, n):
        xy = o.T_world[:2, 3] + s[k] * (end - o.T_world[:2, 3])
        track[k] = make_T(rot_z(s[k] * dyaw) @ o.T_world[:3, :3], [xy[0], xy[1], o.T_world[2, 3]])
    o.track, o.moved = track, (k0, k1)
    return True


def build_scene(name: str, duration: float, stacked: bool, seed: int, moving: bool = False) -> RopeScene:
    """Build one ROPE scene (world model only): camera orbit, then objects that fit the table;
    ``moving``: the last object is re-placed during the video (:func:`_move`)."""
    rng = np.random.default_rng(seed)
    n = int(round(duration * FPS))
    cam = _camera(rng, n)
    unique = [c for c in _CLASSES if "group" not in _CLASSES[c] and c not in ("box", "book")]
    for _ in range(200):
        repeated = "mug" if rng.random() < 0.6 else "bottle"
        chosen = [str(c) for c in rng.choice(unique, size=3, replace=False)]
        classes = chosen + [repeated, repeated] + (["box", "book"] if stacked else [])
        objs = _place_objects(rng, cam[0, :3, :3], classes, seed)
        if objs is None:
            continue
        scene = RopeScene(
            name=name,
            cam_world=cam,
            objects=objs,
            tied_pair=(objs[1].mask_id, objs[0].mask_id),
            clear_pair=(objs[2].mask_id, objs[0].mask_id),
        )
        rel, ev = scene.relation(*scene.clear_pair)
        if moving and not _move(rng, scene, scene.objects[-1]):
            continue
        if scene.visible()[:3, 0].all() and rel in ("Left", "Right") and abs(ev["dx"]) >= 3 * abs(ev["dz"]):
            return scene
    raise RuntimeError(f"cannot lay out the table of scene {name}")


# ================================================================================== writing


def _meta_frame(s: RopeScene, k: int, convention: str, visible: np.ndarray) -> dict:
    """One frame's meta. ``identity``: the camera pose is identity and the world poses are zero /
    identity (real ROPE); otherwise the stored camera pose and world poses carry the motion."""
    real = convention == "identity"
    if real:
        Tc = np.eye(4)
    else:
        Tc = s.cam_world[k] if convention == "world_from_camera" else inv_T(s.cam_world[k])
    fx, fy, cx, cy = K_ROPE
    objects = {}
    for i, o in enumerate(s.objects):
        if not visible[i, k]:
            continue
        T = s.obj_in_cam(o, k)
        objects[f"{o.mask_id}_{o.oid}"] = {
            "meta": {
                "oid": o.oid,
                "class_name": o.class_name,
                "class_label": _CLASSES[o.class_name]["label"],
                "instance_path": f"data/real_obj/{o.oid}/Aligned.obj",
                "scale": o.scale.tolist(),
                "is_background": False,
                "bbox_side_len": o.side.tolist(),
            },
            "quaternion_wxyz": quat_wxyz_from_matrix(T[:3, :3]),
            "translation": T[:3, 3].tolist(),
            "is_valid": True,
            "id": i + 1,
            "material": [],
            "world_quaternion_wxyz": [1.0, 0.0, 0.0, 0.0] if real else quat_wxyz_from_matrix(o.pose(k)[:3, :3]),
            "world_translation": [0.0, 0.0, 0.0] if real else o.pose(k)[:3, 3].tolist(),
        }
    return {
        "objects": objects,
        "camera": {
            "quaternion": quat_wxyz_from_matrix(Tc[:3, :3]),
            "translation": Tc[:3, 3].tolist(),
            "intrinsics": {
                "fx": fx,
                "fy": fy,
                "cx": cx,
                "cy": cy,
                "width": IMAGE_SIZE[0],
                "height": IMAGE_SIZE[1],
            },
            "scene_obj_path": "",
            "background_image_path": "",
            "background_depth_path": "",
            "distances": [],
            "kind": "" if real else "real",
        },
        "scene_dataset": "real" if real else "ROPE",
        "env_param": {},
        "face_up": True,
        "concentrated": False,
        "comments": "real scan video data" if real else "",
        "runtime_seed": -1,
        "baseline_dis": 0,
        "emitter_dist_l": 0,
    }


def write_scene(s: RopeScene, root: Path, convention: str = "identity") -> None:
    """Write ``ROPE/<scene>/<frame>_meta.json`` for every frame (``convention``: :data:`CONVENTIONS`)."""
    if convention not in CONVENTIONS:
        raise ValueError(f"camera convention must be one of {CONVENTIONS}, got {convention!r}")
    d = root / "ROPE" / s.name
    d.mkdir(parents=True, exist_ok=True)
    vis = s.visible()
    for k in range(s.n_frames):
        write_json(d / f"{k:06d}_meta.json", _meta_frame(s, k, convention, vis))


def write_object_meta(scenes: list[RopeScene], root: Path) -> None:
    """``Meta/real_obj_meta.json`` covering every object of every scene."""
    inst: dict[str, dict] = {}
    for s in scenes:
        for o in s.objects:
            spec = _CLASSES[o.class_name]
            inst[o.oid] = {
                "object_id": o.oid,
                "source": "omniobject3d",
                "name": o.oid,
                "obj_path": f"{o.oid}/Aligned.obj",
                "tag": {
                    "datatype": "test",
                    "sceneChanger": False,
                    "symmetry": {"any": False, "x": "none", "y": "none", "z": "none"},
                    "materialOptions": ["raw"],
                    "upAxis": ["z"],
                },
                "class_label": spec["label"],
                "class_name": o.class_name,
                "dimensions": o.dims.tolist(),
            }
    classes = sorted({v["class_name"] for v in inst.values()})
    class_list = [
        {
            "name": c,
            "label": _CLASSES[c]["label"],
            "instance_ids": sorted(k for k, v in inst.items() if v["class_name"] == c),
            "stat": {},
        }
        for c in classes
    ]
    write_json(root / "Meta" / "real_obj_meta.json", {"class_list": class_list, "instance_dict": inst})


def build_default(seed: int) -> list[RopeScene]:
    """The default ROPE scenes (six-digit ids from 000900)."""
    return [
        build_scene(name, dur, stacked, stable_seed(seed, f"omni6d|{name}"), moving=name == MOVING_SCENE)
        for name, dur, stacked in DEFAULT_SCENES
    ]
