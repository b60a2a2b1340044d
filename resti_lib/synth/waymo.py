"""Waymo Open Dataset v2 segments in the exact parquet layout (``../shared/formats/waymo_v2.md``).

A segment is ~20 s at 10 Hz. The ego drives a smooth route (speed profile plus 0-2 turns of known
angle) in an east-north-up world with large offsets. Tracked objects move on straight lines with
constant acceleration (or stand still), so displacement, path length and mean acceleration are
known exactly; boxes are written in the vehicle frame of their own frame timestamp.

Files: ``<root>/{vehicle_pose,camera_calibration,camera_image,lidar_box}/<segment>.parquet``.
Camera frames are Waymo's (+X forward, +Y left, +Z up); ``extrinsic = T_vehicle<-camera``.
``lidar_box`` speed and acceleration are the object's world-frame velocity and acceleration
expressed in the vehicle frame of the frame (not relative to the ego).
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa

from ..sources.waymo import CAMERA_NAMES
from .common import (
    T_WAYMO_FROM_CV,
    horizontal_heading_change,
    in_view,
    make_T,
    point_box_distance,
    rot_x,
    rot_y,
    rot_z,
    rot_z_batch,
    round_list,
    smoothstep,
    stable_seed,
    write_parquet,
)

N_FRAMES = 199
#: The relation label of each mounted camera relative to the car's forward direction.
CAMERA_RELATION = {1: "Front", 2: "Front-Left", 3: "Front-Right", 4: "Left", 5: "Right"}
TYPE_NAMES = {1: "VEHICLE", 2: "PEDESTRIAN", 3: "SIGN", 4: "CYCLIST"}

# camera -> (x, y, z in the vehicle frame, yaw deg, width, height, f, c_u, c_v, exposure offset s)
_CAMERAS = {
    1: (1.54, -0.02, 2.12, 0.0, 1920, 1280, 2063.0, 951.0, 645.0, 0.012),
    2: (1.50, 0.10, 2.11, 45.0, 1920, 1280, 2058.0, 963.0, 640.0, 0.008),
    3: (1.49, -0.10, 2.11, -45.0, 1920, 1280, 2061.0, 957.0, 636.0, 0.016),
    4: (1.43, 0.12, 2.10, 90.0, 1920, 886, 2052.0, 970.0, 446.0, 0.004),
    5: (1.43, -0.12, 2.10, -90.0, 1920, 886, 2055.0, 948.0, 441.0, 0.020),
}

# kind -> (type, (l, w, h), descriptions)
_KINDS = {
    "sedan": (
        1,
        (4.7, 1.9, 1.5),
        ["A dark blue sedan parked by the curb", "A silver sedan with tinted windows"],
    ),
    "minivan": (1, (5.1, 2.0, 1.8), ["A beige minivan with a roof rack"]),
    "truck": (1, (7.6, 2.6, 3.0), ["A white utility truck with a bucket lift"]),
    "pickup": (1, (5.6, 2.1, 1.9), ["A red pickup truck with a black bed cover"]),
    "hatchback": (1, (4.1, 1.8, 1.5), ["A small green hatchback car"]),
    "bus": (1, (12.0, 2.6, 3.2), ["A yellow school bus"]),
    "pedestrian": (2, (0.6, 0.6, 1.75), ["A pedestrian in a red jacket", "A pedestrian carrying a backpack"]),
    "cyclist": (4, (1.8, 0.7, 1.7), ["A cyclist wearing a yellow helmet"]),
    "sign": (
        3,
        (0.1, 0.8, 2.6),
        [
            "A red octagonal stop sign",
            "A yellow diamond warning sign",
            "A blue parking sign on a pole",
            "A white speed-limit sign",
            "A green street-name sign",
            "An orange road-work sign",
        ],
    ),
}
#: Descriptions of objects that never appear in a segment (no source instance).
ABSENT_DESCRIPTIONS = [
    "A red double-decker bus",
    "A police motorcycle with flashing lights",
    "A horse-drawn carriage",
]

_B64 = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_"


@dataclass
class TrackedObject:
    """One tracked object: straight-line motion with constant acceleration in the world."""

    oid: str
    kind: str
    type: int
    description: str
    size: np.ndarray  # (l, w, h)
    p0: np.ndarray  # world centre at t = 0
    u: np.ndarray  # unit direction of motion (world, horizontal)
    v0: float
    a: float
    moving: bool
    present: np.ndarray = field(default=None)  # (N,) bool, rows in lidar_box
    center_v: np.ndarray = field(default=None)  # (N, 3) vehicle-frame centre (NaN when absent)
    heading_v: np.ndarray = field(default=None)  # (N,)
    world: np.ndarray = field(default=None)  # (N, 3) world centre from the written rows

    def position(self, t: np.ndarray) -> np.ndarray:
        """World centre at times ``t`` (n, 3)."""
        s = self.v0 * t + 0.5 * self.a * t * t
        return self.p0 + np.outer(s, self.u)

    def velocity(self, t: np.ndarray) -> np.ndarray:
        """World velocity at times ``t`` (n, 3)."""
        return np.outer(self.v0 + self.a * t, self.u)


@dataclass
class WaymoSegment:
    """A generated segment and its by-construction truth.

    Attributes
    ----------
    name : str
        ``segment_context_name``.
    micros : ndarray (N,) int64
        Frame timestamps; the timeline is ``t = (micros - micros[0]) / 1e6``.
    W : ndarray (N, 4, 4)
        ``world_from_vehicle`` per frame (float64, as written).
    E : dict int -> ndarray (4, 4)
        ``T_vehicle<-camera`` (Waymo camera axes) per camera number.
    """

    name: str
    micros: np.ndarray
    W: np.ndarray
    E: dict[int, np.ndarray]
    intr: dict[int, tuple]
    objects: list[TrackedObject]
    turns: list[dict]
    ego_fn: object = None
    _vis: dict | None = None
    _loose: dict | None = None

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return int(self.micros.shape[0])

    @property
    def t(self) -> np.ndarray:
        """Timeline seconds of the frames."""
        return (self.micros - self.micros[0]) / 1e6

    @property
    def video_end(self) -> float:
        """Time of the last frame."""
        return float(self.t[-1])

    def frame_of(self, t: float) -> int:
        """Nearest frame to timeline time ``t``."""
        return int(np.argmin(np.abs(self.t - t)))

    def obj(self, oid: str) -> TrackedObject:
        """Object by laser_object_id."""
        return next(o for o in self.objects if o.oid == oid)

    # ------------------------------------------------------------------ camera geometry
    def T_cv_from_vehicle(self, cam: int) -> np.ndarray:
        """``T_cam<-vehicle`` with OpenCV camera axes."""
        return np.linalg.inv(self.E[cam] @ T_WAYMO_FROM_CV)

    def cam_pose_cv(self, k: int, cam: int) -> np.ndarray:
        """``T_world<-cam`` in OpenCV camera axes at frame ``k``."""
        return self.W[k] @ self.E[cam] @ T_WAYMO_FROM_CV

    def cam_centers(self, cam: int) -> np.ndarray:
        """World centre of camera ``cam`` at every frame (N, 3)."""
        return np.einsum("nij,j->ni", self.W[:, :3, :3], self.E[cam][:3, 3]) + self.W[:, :3, 3]

    def K(self, cam: int) -> tuple[float, float, float, float]:
        """Pinhole ``(f_u, f_v, c_u, c_v)``."""
        f_u, f_v, c_u, c_v = self.intr[cam][:4]
        return (f_u, f_v, c_u, c_v)

    def image_size(self, cam: int) -> tuple[int, int]:
        """Image ``(width, height)``."""
        return (int(self.intr[cam][9]), int(self.intr[cam][10]))

    def visible(self, cam: int) -> np.ndarray:
        """(objects, frames) bool: the box centre projects inside the image of ``cam`` (2-60 m)."""
        if self._vis is None:
            self._vis = {}
        if cam not in self._vis:
            T = self.T_cv_from_vehicle(cam)
            out = np.zeros((len(self.objects), self.n_frames), bool)
            for i, o in enumerate(self.objects):
                pc = o.center_v @ T[:3, :3].T + T[:3, 3]
                out[i] = (
                    in_view(self.K(cam), self.image_size(cam), pc, margin=0.05, min_depth=2.0, max_depth=60.0)
                    & o.present
                )
            self._vis[cam] = out
        return self._vis[cam]

    def seen_loosely(self, cam: int) -> np.ndarray:
        """(objects, frames) bool: any point of a 3x3x3 grid spanning the solid box (corners, edge
        and face midpoints, centre) projects inside the image of ``cam`` enlarged by 5 % per border, at
        a depth in (0.05, 100] m.

        A generous superset of :meth:`visible` and of any reasonable frustum test of the box: an
        object not seen loosely is out of every viewer's sight, so a referent is unique when no other
        object of its type is seen loosely.
        """
        if self._loose is None:
            self._loose = {}
        if cam not in self._loose:
            T = self.T_cv_from_vehicle(cam)
            f_u, f_v, c_u, c_v = self.K(cam)
            w, h = self.image_size(cam)
            s = np.linspace(-0.5, 0.5, 3)
            grid = np.array([[x, y, z] for x in s for y in s for z in s])
            out = np.zeros((len(self.objects), self.n_frames), bool)
            for i, o in enumerate(self.objects):
                ks = np.flatnonzero(o.present)
                R = rot_z_batch(o.heading_v[ks])  # (n, 3, 3) vehicle <- box
                pv = np.einsum("nij,pj->npi", R, grid * o.size) + o.center_v[ks][:, None, :]
                pc = pv @ T[:3, :3].T + T[:3, 3]
                z = pc[..., 2]
                with np.errstate(divide="ignore", invalid="ignore"):
                    u = f_u * pc[..., 0] / z + c_u
                    v = f_v * pc[..., 1] / z + c_v
                    ok = (z > 0.05) & (z <= 100.0)
                    ok &= (u >= -0.05 * w) & (u <= 1.05 * w) & (v >= -0.05 * h) & (v <= 1.05 * h)
                out[i, ks] = ok.any(axis=1)
            self._loose[cam] = out
        return self._loose[cam]

    # ------------------------------------------------------------------ truth (own numpy)
    def box_in_camera(self, o: TrackedObject, k: int, cam: int) -> dict:
        """Oriented box in the OpenCV frame of ``cam`` at frame ``k``."""
        T = self.T_cv_from_vehicle(cam)
        R = T[:3, :3] @ rot_z(float(o.heading_v[k]))
        c = T[:3, :3] @ o.center_v[k] + T[:3, 3]
        return {
            "C_central_point": c.tolist(),
            "C_lwh": o.size.tolist(),
            "C_rotation_camera_from_box": R.tolist(),
            "C_heading": math.degrees(math.atan2(R[1, 0], R[0, 0])),
        }

    def heading_change(self, k0: int, k1: int, cam: int) -> float:
        """Gravity-horizontal heading change of the camera's optical axis (degrees)."""
        f0 = (self.W[k0] @ self.E[cam])[:3, 0]
        f1 = (self.W[k1] @ self.E[cam])[:3, 0]
        return horizontal_heading_change(f0, f1, np.array([0.0, 0.0, 1.0]))

    def legacy_xz_angle(self, k0: int, k1: int, cam: int) -> float:
        """Legacy: column 2 of the (Waymo-axes) camera pose projected on world X-Z, endpoint angle."""
        a = (self.W[k0] @ self.E[cam])[[0, 2], 2]
        b = (self.W[k1] @ self.E[cam])[[0, 2], 2]
        return math.degrees(math.atan2(a[1] * b[0] - a[0] * b[1], a[0] * b[0] + a[1] * b[1]))

    def cam_displacement(self, k0: int, k1: int, cam: int) -> float:
        """Camera displacement between two frames (m)."""
        c = self.cam_centers(cam)
        return float(np.linalg.norm(c[k1] - c[k0]))

    def cam_path(self, k0: int, k1: int, cam: int) -> float:
        """Camera path length over the frames in [k0, k1] (m)."""
        c = self.cam_centers(cam)[k0 : k1 + 1]
        return float(np.sum(np.linalg.norm(np.diff(c, axis=0), axis=1)))

    def obj_path(self, o: TrackedObject, k0: int, k1: int) -> float:
        """Object path length over the frames in [k0, k1] (m)."""
        p = o.world[k0 : k1 + 1]
        return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))

    def obj_acceleration(self, o: TrackedObject, k0: int, k1: int) -> float:
        """|v(t1) - v(t0)| / (t1 - t0) of the world velocity (the written speed vectors rotated back)."""
        v0, v1 = o.velocity(np.array([self.t[k0], self.t[k1]]))
        return float(np.linalg.norm(v1 - v0) / (self.t[k1] - self.t[k0]))

    def distance_to_camera(self, o: TrackedObject, k: int, cam: int) -> float:
        """Distance from the camera centre to the object box at frame ``k`` (m)."""
        return point_box_distance(self.E[cam][:3, 3], o.center_v[k], o.size, rot_z(float(o.heading_v[k])))

    def trajectory_segments(self, cam: int) -> list[tuple[str, float]]:
        """Truth phrase segments: distances between turn midpoints, turn = heading change over it."""
        segs: list[tuple[str, float]] = []
        last = 0
        for turn in self.turns:
            ks = int(np.searchsorted(self.t, turn["t_start"], side="right") - 1)
            ke = int(np.searchsorted(self.t, turn["t_end"], side="left"))
            km = self.frame_of(0.5 * (turn["t_start"] + turn["t_end"]))
            segs.append(("move", self.cam_path(last, km, cam)))
            segs.append(("turn", self.heading_change(max(ks, 0), min(ke, self.n_frames - 1), cam)))
            last = km
        segs.append(("move", self.cam_path(last, self.n_frames - 1, cam)))
        return segs

    def describe(self) -> dict:
        """Ground truth for world.json."""
        return {
            "segment": self.name,
            "n_frames": self.n_frames,
            "first_micros": int(self.micros[0]),
            "last_t": self.video_end,
            "turns": self.turns,
            "cameras": {
                str(c): {"name": CAMERA_NAMES[c], "extrinsic": round_list(self.E[c], 9)}
                for c in sorted(self.E)
            },
            "objects": [
                {
                    "laser_object_id": o.oid,
                    "kind": o.kind,
                    "type": o.type,
                    "type_name": TYPE_NAMES[o.type],
                    "description": o.description,
                    "size": round_list(o.size),
                    "moving": o.moving,
                    "p0_world": round_list(o.p0),
                    "direction": round_list(o.u, 9),
                    "v0": round(o.v0, 9),
                    "a": round(o.a, 9),
                    "present_frames": [int(np.flatnonzero(o.present)[0]), int(np.flatnonzero(o.present)[-1])],
                }
                for o in self.objects
            ],
        }


# ============================================================================== construction


class _Ego:
    """Ego motion on a fine grid; pose at any time by interpolation of the grid."""

    def __init__(self, rng: np.random.Generator, n_turns: int, origin: np.ndarray):
        dt = 0.002
        self.tau = np.arange(-1.0, 22.0 + dt, dt)
        tau = self.tau
        v0, v1 = rng.uniform(4.0, 9.0), rng.uniform(6.0, 14.0)
        ta = rng.uniform(2.0, 10.0)
        v = v0 + (v1 - v0) * smoothstep((tau - ta) / 5.0) + 0.4 * np.sin(tau / rng.uniform(2.0, 4.0))
        self.turns: list[dict] = []
        yaw = np.full_like(tau, rng.uniform(-math.pi, math.pi))
        start = rng.uniform(3.0, 6.0)
        for _ in range(n_turns):
            dur = rng.uniform(3.0, 5.0)
            if start + dur > 17.0:
                break
            ang = rng.choice([-1.0, 1.0]) * rng.uniform(35.0, 95.0)
            yaw = yaw + math.radians(ang) * smoothstep((tau - start) / dur)
            self.turns.append(
                {"t_start": float(start), "t_end": float(start + dur), "yaw_change_deg": float(ang)}
            )
            start = start + dur + rng.uniform(4.0, 6.0)
        x = np.concatenate(
            [[0.0], np.cumsum(0.5 * (v[1:] * np.cos(yaw[1:]) + v[:-1] * np.cos(yaw[:-1])) * dt)]
        )
        y = np.concatenate(
            [[0.0], np.cumsum(0.5 * (v[1:] * np.sin(yaw[1:]) + v[:-1] * np.sin(yaw[:-1])) * dt)]
        )
        i0 = int(np.argmin(np.abs(tau)))
        x, y = x - x[i0], y - y[i0]
        grade = rng.uniform(-0.02, 0.02)
        s = np.concatenate([[0.0], np.cumsum(v[1:] * dt)])
        s = s - s[i0]
        self.x, self.y = x + origin[0], y + origin[1]
        self.z = origin[2] + grade * s + 0.05 * np.sin(tau / 3.0)
        self.yaw = yaw
        self.pitch = -np.arctan(grade) + np.radians(0.3) * np.sin(tau / 1.7)
        self.roll = np.radians(0.4) * np.sin(tau / 2.3 + 1.0)
        self.v = v

    def interp(self, arr: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Grid values interpolated at times ``t``."""
        return np.interp(t, self.tau, arr)

    def pose(self, t: np.ndarray) -> np.ndarray:
        """``world_from_vehicle`` at times ``t`` (n, 4, 4)."""
        t = np.atleast_1d(np.asarray(t, float))
        out = np.zeros((t.size, 4, 4))
        x, y, z = self.interp(self.x, t), self.interp(self.y, t), self.interp(self.z, t)
        yaw, pitch, roll = self.interp(self.yaw, t), self.interp(self.pitch, t), self.interp(self.roll, t)
        for i in range(t.size):
            out[i] = make_T(rot_z(yaw[i]) @ rot_y(pitch[i]) @ rot_x(roll[i]), [x[i], y[i], z[i]])
        return out

    def pos_dir(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Ego position and horizontal heading direction at time ``t``."""
        p = np.array([self.interp(self.x, t), self.interp(self.y, t), self.interp(self.z, t)], float)
        yaw = float(self.interp(self.yaw, t))
        return p, np.array([math.cos(yaw), math.sin(yaw), 0.0])


def _object_id(rng: np.random.Generator) -> str:
    return "".join(_B64[i] for i in rng.integers(0, 64, size=22))


def _make_objects(rng: np.random.Generator, ego: _Ego, E: dict[int, np.ndarray]) -> list[TrackedObject]:
    """Parked and moving vehicles, pedestrians, a cyclist and signs along the route; every camera
    gets one sign placed in its view at some time, so every camera video sees an object."""
    objs: list[TrackedObject] = []
    used_desc: set[str] = set()

    def desc(kind: str, moving: bool) -> str:
        # a moving object never gets a description that calls it parked
        fits = [d for d in _KINDS[kind][2] if not (moving and " parked" in d)] or _KINDS[kind][2]
        for d in fits:
            if d not in used_desc:
                used_desc.add(d)
                return d
        return fits[0]

    def add(kind, p0, u, v0, a, moving):
        typ, size, _ = _KINDS[kind]
        size = np.array(size) * rng.uniform(0.95, 1.05, size=3)
        p0 = np.array(p0, float)
        p0[2] += size[2] / 2
        objs.append(
            TrackedObject(
                _object_id(rng),
                str(kind),
                typ,
                desc(str(kind), moving),
                size,
                p0,
                np.array(u, float) / np.linalg.norm(u),
                float(v0),
                float(a),
                moving,
            )
        )

    left = lambda d: np.array([-d[1], d[0], 0.0])
    parked = list(
        rng.choice(["sedan", "minivan", "truck", "pickup", "hatchback", "bus"], size=4, replace=False)
    )
    for i, kind in enumerate(parked):
        tp = rng.uniform(1.0 + 4.5 * i, 4.0 + 4.5 * i)
        p, d = ego.pos_dir(tp)
        side = 1.0 if i % 2 == 0 else -1.0
        q = p + side * rng.uniform(4.0, 6.5) * left(d) + rng.uniform(10, 25) * d
        add(kind, q, d if rng.random() < 0.7 else -d, 0.0, 0.0, False)
    # lead car in the adjacent lane, same direction (the "car" of ambiguous-subject questions)
    p, d = ego.pos_dir(0.0)
    v_ego0 = float(ego.interp(ego.v, 0.0))
    a = rng.uniform(0.3, 1.2) * rng.choice([-1, 1])
    v0 = v_ego0 * rng.uniform(0.9, 1.2)
    a = max(a, (1.0 - v0) / 20.0)
    add("sedan", p + rng.uniform(14, 24) * d + 3.5 * left(d) * rng.choice([-1, 1]), d, v0, a, True)
    # oncoming vehicle
    a2 = rng.uniform(0.2, 0.8)
    oncoming = next(k for k in ("hatchback", "pickup", "minivan", "truck", "bus") if k not in parked)
    add(oncoming, p + rng.uniform(55, 75) * d + 3.6 * left(d), -d, rng.uniform(6, 10), -min(a2, 0.25), True)
    # pedestrians on the sidewalk
    for j in range(2):
        tp = rng.uniform(2.0, 14.0)
        q, dd = ego.pos_dir(tp)
        side = 1.0 if j == 0 else -1.0
        u = dd if rng.random() < 0.5 else -dd
        add(
            "pedestrian",
            q + side * rng.uniform(7.0, 9.0) * left(dd) + rng.uniform(8, 20) * dd,
            u,
            rng.uniform(1.0, 1.6),
            rng.uniform(0.02, 0.06) * rng.choice([-1, 1]),
            True,
        )
    # cyclist on the right, same direction
    add(
        "cyclist",
        p + rng.uniform(12, 25) * d - 2.6 * left(d),
        d,
        rng.uniform(4.0, 6.0),
        rng.uniform(0.1, 0.4),
        True,
    )
    # a stop sign
    q, dd = ego.pos_dir(rng.uniform(4.0, 12.0))
    add("sign", q + rng.uniform(6.0, 8.0) * left(dd) * rng.choice([-1, 1]) + 15 * dd, -dd, 0.0, 0.0, False)
    for cam in sorted(E):
        tc = rng.uniform(2.0, 15.0)
        T = ego.pose(tc)[0] @ E[cam]
        axis = T[:3, 0].copy()
        axis[2] = 0.0
        axis /= np.linalg.norm(axis)
        side = left(axis) * rng.uniform(3.0, 5.0) * rng.choice([-1, 1])
        dist = rng.uniform(14.0, 22.0) if cam in (1, 2, 3) else rng.uniform(8.0, 12.0)
        ground = np.array([0.0, 0.0, float(ego.interp(ego.z, tc)) - T[2, 3]])
        add("sign", T[:3, 3] + dist * axis + side + ground, -axis, 0.0, 0.0, False)
    return objs


def _segment_name(rng: np.random.Generator) -> str:
    num = "9" + "".join(str(d) for d in rng.integers(0, 10, size=19))
    a = int(rng.integers(100, 9000))
    ms = int(rng.integers(0, 1000))
    return f"{num}_{a}_{ms:03d}_{a + 20}_{ms:03d}"


def build_segment(seed: int, n_turns: int) -> tuple[WaymoSegment, _Ego]:
    """Build one segment (world model); :func:`write_segment` writes its parquet files."""
    rng = np.random.default_rng(seed)
    name = _segment_name(rng)
    start = int(1_550_000_000_000_000 + rng.integers(0, 60_000_000_000_000))
    jitter = rng.integers(-40, 41, size=N_FRAMES)
    jitter[0] = 0
    micros = start + np.arange(N_FRAMES, dtype=np.int64) * 100_000 + jitter
    t = (micros - micros[0]) / 1e6
    origin = np.array([rng.uniform(-9000, 9000), rng.uniform(-9000, 9000), rng.uniform(-50, 250)])
    ego = _Ego(rng, n_turns, origin)
    W = ego.pose(t)
    E, intr = {}, {}
    for cam, (x, y, z, yaw, w, h, f, cu, cv, _) in _CAMERAS.items():
        R = rot_z(math.radians(yaw + rng.uniform(-0.4, 0.4))) @ rot_y(math.radians(rng.uniform(-1.0, 1.0)))
        E[cam] = make_T(R @ rot_x(math.radians(rng.uniform(-0.3, 0.3))), [x, y, z])
        intr[cam] = (
            f * rng.uniform(0.995, 1.005),
            f * rng.uniform(0.995, 1.005),
            cu,
            cv,
            -0.32,
            0.12,
            0.0004,
            -0.0002,
            0.0,
            w,
            h,
        )
    objects = _make_objects(rng, ego, E)
    for o in objects:
        pw = o.position(t)
        dist = np.linalg.norm(pw[:, :2] - W[:, :2, 3], axis=1)
        o.present = dist <= 75.0
        Winv = np.linalg.inv(W)
        cv = np.einsum("nij,nj->ni", Winv[:, :3, :3], pw) + Winv[:, :3, 3]
        ego_yaw = np.arctan2(W[:, 1, 0], W[:, 0, 0])
        hw = math.atan2(o.u[1], o.u[0])
        o.heading_v = (hw - ego_yaw + math.pi) % (2 * math.pi) - math.pi
        o.center_v = np.where(o.present[:, None], cv, np.nan)
        o.world = np.einsum("nij,nj->ni", W[:, :3, :3], cv) + W[:, :3, 3]
        o.world[~o.present] = np.nan
    seg = WaymoSegment(
        name=name,
        micros=micros,
        W=W,
        E=E,
        intr=intr,
        objects=objects,
        turns=[{k: (round(v, 6) if isinstance(v, float) else v) for k, v in tr.items()} for tr in ego.turns],
    )
    return seg, ego


# ================================================================================== writing

_F16 = pa.list_(pa.float64(), 16)


def _tiny_jpeg(cam: int) -> bytes:
    from PIL import Image

    img = Image.new("RGB", (8, 6), (40 * cam, 120, 200 - 30 * cam))
    buf = io.BytesIO()
    img.save(buf, format="JPEG", quality=50)
    return buf.getvalue()


def write_segment(seg: WaymoSegment, ego: _Ego, root: Path) -> None:
    """Write the four components of one segment."""
    n, name = seg.n_frames, seg.name
    t = seg.t
    names = pa.array([name] * n, pa.string())
    write_parquet(
        root / "vehicle_pose" / f"{name}.parquet",
        pa.table(
            {
                "key.segment_context_name": names,
                "key.frame_timestamp_micros": pa.array(seg.micros, pa.int64()),
                "[VehiclePoseComponent].world_from_vehicle.transform": pa.array(
                    [m.ravel().tolist() for m in seg.W], _F16
                ),
            }
        ),
    )

    cams = sorted(seg.E)
    cal = {
        "key.segment_context_name": pa.array([name] * len(cams), pa.string()),
        "key.camera_name": pa.array(cams, pa.int8()),
    }
    for j, fld in enumerate(["f_u", "f_v", "c_u", "c_v", "k1", "k2", "p1", "p2", "k3"]):
        cal[f"[CameraCalibrationComponent].intrinsic.{fld}"] = pa.array(
            [seg.intr[c][j] for c in cams], pa.float64()
        )
    cal["[CameraCalibrationComponent].extrinsic.transform"] = pa.array(
        [seg.E[c].ravel().tolist() for c in cams], _F16
    )
    cal["[CameraCalibrationComponent].width"] = pa.array([seg.intr[c][9] for c in cams], pa.int32())
    cal["[CameraCalibrationComponent].height"] = pa.array([seg.intr[c][10] for c in cams], pa.int32())
    cal["[CameraCalibrationComponent].rolling_shutter_direction"] = pa.array([2] * len(cams), pa.int8())
    write_parquet(root / "camera_calibration" / f"{name}.parquet", pa.table(cal))

    rows_k = np.repeat(np.arange(n), len(cams))
    rows_c = np.tile(np.array(cams), n)
    offs = np.array([_CAMERAS[c][9] for c in rows_c])
    tp = t[rows_k] + offs
    P = ego.pose(tp)
    yaw_rate = np.gradient(ego.yaw, ego.tau)
    vel_x = ego.interp(ego.v * np.cos(ego.yaw), tp)
    vel_y = ego.interp(ego.v * np.sin(ego.yaw), tp)
    jpgs = {c: _tiny_jpeg(c) for c in cams}
    pose_ts = seg.micros[rows_k] / 1e6 + offs
    img = {
        "key.segment_context_name": pa.array([name] * len(rows_k), pa.string()),
        "key.frame_timestamp_micros": pa.array(seg.micros[rows_k], pa.int64()),
        "key.camera_name": pa.array(rows_c, pa.int8()),
        "[CameraImageComponent].image": pa.array([jpgs[c] for c in rows_c], pa.binary()),
        "[CameraImageComponent].pose.transform": pa.array([m.ravel().tolist() for m in P], _F16),
        "[CameraImageComponent].velocity.linear_velocity.x": pa.array(vel_x, pa.float32()),
        "[CameraImageComponent].velocity.linear_velocity.y": pa.array(vel_y, pa.float32()),
        "[CameraImageComponent].velocity.linear_velocity.z": pa.array(np.zeros(len(rows_k)), pa.float32()),
        "[CameraImageComponent].velocity.angular_velocity.x": pa.array(np.zeros(len(rows_k)), pa.float64()),
        "[CameraImageComponent].velocity.angular_velocity.y": pa.array(np.zeros(len(rows_k)), pa.float64()),
        "[CameraImageComponent].velocity.angular_velocity.z": pa.array(
            ego.interp(yaw_rate, tp), pa.float64()
        ),
        "[CameraImageComponent].pose_timestamp": pa.array(pose_ts, pa.float64()),
        "[CameraImageComponent].rolling_shutter_params.shutter": pa.array(
            np.full(len(rows_k), 0.004), pa.float64()
        ),
        "[CameraImageComponent].rolling_shutter_params.camera_trigger_time": pa.array(
            pose_ts - 0.012, pa.float64()
        ),
        "[CameraImageComponent].rolling_shutter_params.camera_readout_done_time": pa.array(
            pose_ts + 0.012, pa.float64()
        ),
    }
    write_parquet(root / "camera_image" / f"{name}.parquet", pa.table(img))

    ks, objs = [], []
    for o in seg.objects:
        for k in np.flatnonzero(o.present):
            ks.append(int(k))
            objs.append(o)
    order = sorted(range(len(ks)), key=lambda i: (ks[i], objs[i].oid))
    ks = [ks[i] for i in order]
    objs = [objs[i] for i in order]
    cen = np.array([o.center_v[k] for o, k in zip(objs, ks)])
    vel = np.array([seg.W[k, :3, :3].T @ o.velocity(np.array([t[k]]))[0] for o, k in zip(objs, ks)])
    acc = np.array([seg.W[k, :3, :3].T @ (o.a * o.u) for o, k in zip(objs, ks)])
    dist = np.linalg.norm(cen[:, :2], axis=1)
    npts = np.maximum(5, (4000.0 / np.maximum(dist, 3.0) ** 1.2)).astype(np.int64)
    box = {
        "key.segment_context_name": pa.array([name] * len(ks), pa.string()),
        "key.frame_timestamp_micros": pa.array(seg.micros[ks], pa.int64()),
        "key.laser_object_id": pa.array([o.oid for o in objs], pa.string()),
        "[LiDARBoxComponent].box.center.x": pa.array(cen[:, 0], pa.float64()),
        "[LiDARBoxComponent].box.center.y": pa.array(cen[:, 1], pa.float64()),
        "[LiDARBoxComponent].box.center.z": pa.array(cen[:, 2], pa.float64()),
        "[LiDARBoxComponent].box.size.x": pa.array([o.size[0] for o in objs], pa.float64()),
        "[LiDARBoxComponent].box.size.y": pa.array([o.size[1] for o in objs], pa.float64()),
        "[LiDARBoxComponent].box.size.z": pa.array([o.size[2] for o in objs], pa.float64()),
        "[LiDARBoxComponent].box.heading": pa.array(
            [float(o.heading_v[k]) for o, k in zip(objs, ks)], pa.float64()
        ),
        "[LiDARBoxComponent].type": pa.array([o.type for o in objs], pa.int8()),
        "[LiDARBoxComponent].num_lidar_points_in_box": pa.array(npts, pa.int64()),
        "[LiDARBoxComponent].num_top_lidar_points_in_box": pa.array(
            (npts * 0.8).astype(np.int64), pa.int64()
        ),
        "[LiDARBoxComponent].speed.x": pa.array(vel[:, 0], pa.float64()),
        "[LiDARBoxComponent].speed.y": pa.array(vel[:, 1], pa.float64()),
        "[LiDARBoxComponent].speed.z": pa.array(vel[:, 2], pa.float64()),
        "[LiDARBoxComponent].acceleration.x": pa.array(acc[:, 0], pa.float64()),
        "[LiDARBoxComponent].acceleration.y": pa.array(acc[:, 1], pa.float64()),
        "[LiDARBoxComponent].acceleration.z": pa.array(acc[:, 2], pa.float64()),
        "[LiDARBoxComponent].difficulty_level.detection": pa.array(np.where(dist > 40, 2, 1), pa.int8()),
        "[LiDARBoxComponent].difficulty_level.tracking": pa.array(np.where(dist > 40, 2, 1), pa.int8()),
    }
    write_parquet(root / "lidar_box" / f"{name}.parquet", pa.table(box))


#: Turns per default segment (coverage: none, one, two).
DEFAULT_TURNS = [1, 2, 0, 1]


def build_default(seed: int) -> list[tuple[WaymoSegment, _Ego]]:
    """The default segments (turn counts in ``DEFAULT_TURNS``)."""
    return [build_segment(stable_seed(seed, f"waymo|{i}"), n) for i, n in enumerate(DEFAULT_TURNS)]
