"""ScanNet v2 scenes in the exact source layout (``../shared/formats/scannet.md``).

Each scene is a rectangular room whose annotation frame (``ann``: axis-aligned, floor at z = 0) is
chosen first. Objects are upright boxes along the walls, most aligned with the ann axes, some
free-standing pieces of furniture (:data:`TURNABLE`) turned 15-35 degrees about +Z; the camera walks
a smooth loop at walking speed and looks from object to object with some tilt and roll. The raw scan
frame is ``raw = A^-1 ann`` with ``A = axisAlignment`` a rotation about +Z plus a translation, so the
mesh and the poses are written in raw coordinates while instance boxes are ann-frame boxes.

Truth is kept exactly as the files hold it: ``A`` as parsed back from its 6-decimal text, poses as
float32 (the ``.sens`` precision), boxes computed from ``A @ float32 mesh vertices``. Two boxes per
instance: the *tight* upright box (the truth: footprint = minimum-area rectangle, length >= width,
:func:`.common.tight_upright_box`) and the *axis-aligned* box in the ann frame (``bmin``/``bmax``:
the legacy construction's box, extents along ann x, y, z). They differ for turned instances (and
name length / width differently for instances whose longer side runs along ann y).
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from .common import (
    aabb_distance,
    box_corners,
    in_view,
    look_rotation,
    make_T,
    point_box_distance,
    rot_x,
    rot_z,
    round_list,
    smoothstep,
    tight_upright_box,
    write_json,
)

FPS = 30.0
COLOR_SIZE = (1296, 968)
DEPTH_SIZE = (640, 480)

# label -> (size ranges along the wall / across / height, base height, descriptions, group phrases)
_LABELS: dict[str, dict] = {
    "door": {
        "size": ((0.8, 1.0), (0.05, 0.12), (1.95, 2.1)),
        "z": 0.0,
        "desc": [
            "White door with two black handles, wooden frame",
            "Brown wooden door with a silver round knob",
        ],
    },
    "table": {
        "size": ((1.0, 1.6), (0.6, 0.9), (0.7, 0.78)),
        "z": 0.0,
        "desc": ["Rectangular white table with thin metal legs", "Dark wooden dining table against the wall"],
    },
    "chair": {
        "size": ((0.45, 0.6), (0.45, 0.6), (0.8, 1.05)),
        "z": 0.0,
        "desc": [
            "Black office chair with armrests",
            "Grey padded chair with chrome legs",
            "Blue plastic chair with a curved back",
            "Wooden chair with a slatted back",
        ],
        "group": [
            "the two black office chairs",
            "both chairs along the wall",
            "the set of chairs in the room",
        ],
    },
    "bed": {
        "size": ((1.9, 2.1), (1.4, 1.7), (0.5, 0.65)),
        "z": 0.0,
        "desc": ["Double bed with a striped grey duvet"],
    },
    "sofa": {
        "size": ((1.7, 2.2), (0.8, 0.95), (0.75, 0.9)),
        "z": 0.0,
        "desc": ["Beige three-seat sofa with cushions", "Dark green fabric sofa"],
    },
    "cabinet": {
        "size": ((0.7, 1.1), (0.4, 0.6), (0.9, 1.4)),
        "z": 0.0,
        "desc": ["Tall white cabinet with two handles", "Low wooden cabinet with drawers"],
    },
    "refrigerator": {
        "size": ((0.65, 0.85), (0.6, 0.75), (1.6, 1.9)),
        "z": 0.0,
        "desc": ["White refrigerator beside the kitchen counter"],
    },
    "trash can": {
        "size": ((0.3, 0.4), (0.3, 0.4), (0.45, 0.7)),
        "z": 0.0,
        "desc": ["Small white trash can with a pedal lid", "Black trash can with a swing lid"],
        "group": ["the pair of trash cans", "both trash cans"],
    },
    "desk": {
        "size": ((1.2, 1.6), (0.6, 0.8), (0.72, 0.78)),
        "z": 0.0,
        "desc": ["Light wooden desk with a keyboard on it"],
    },
    "bookshelf": {
        "size": ((0.8, 1.2), (0.3, 0.4), (1.7, 2.0)),
        "z": 0.0,
        "desc": ["Tall bookshelf full of books", "White bookshelf with five shelves"],
    },
    "lamp": {
        "size": ((0.3, 0.45), (0.3, 0.45), (1.4, 1.7)),
        "z": 0.0,
        "desc": ["Tall floor lamp with a white shade"],
    },
    "armchair": {
        "size": ((0.75, 0.9), (0.75, 0.9), (0.8, 0.95)),
        "z": 0.0,
        "desc": ["Brown leather armchair in the corner"],
    },
    "tv stand": {
        "size": ((1.2, 1.8), (0.35, 0.5), (0.45, 0.6)),
        "z": 0.0,
        "desc": ["Black tv stand under the television"],
    },
    "dresser": {
        "size": ((0.9, 1.3), (0.45, 0.55), (0.8, 1.1)),
        "z": 0.0,
        "desc": ["White dresser with six drawers"],
    },
}
#: Free-standing furniture that may stand turned about +Z (probability, turn range in degrees).
TURNABLE = ("table", "desk", "sofa", "bed", "armchair", "dresser", "tv stand")
TURN_PROBABILITY = 0.6
TURN_DEG = (15.0, 35.0)

#: Labels that never appear in a scene; used for descriptions with no source instance.
ABSENT_LABELS = {
    "piano": "Black upright piano against the wall",
    "washing machine": "White front-loading washing machine",
    "aquarium": "Rectangular aquarium with blue gravel",
}

_SCENE_TYPES = ["Apartment", "Bedroom / Hotel", "Office", "Living room / Lounge", "Conference Room"]

#: Default scenes: (scene id, duration s, invalid frames at the end, (start, length) of a gap or None)
DEFAULT_SCENES = [
    ("scene0900_00", 50.0, 40, None),
    ("scene0901_00", 42.0, 0, (611, 14)),
    ("scene0901_01", 38.0, 25, None),
    ("scene0902_00", 45.0, 0, None),
]


@dataclass
class Instance:
    """One annotated instance (a segGroup): its ann-frame boxes as the files define them.

    ``bmin``/``bmax``: the axis-aligned box of the ann-frame vertices (the legacy convention);
    ``box_center``/``box_R``/``box_lwh``: the tight upright box (the truth); ``turn_deg``: how far
    the object stands turned from the room axes (0 for most).
    """

    object_id: int
    label: str
    description: str
    bmin: np.ndarray
    bmax: np.ndarray
    segments: list[int] = field(default_factory=list)
    raw_vertices: np.ndarray | None = None  # (8, 3) float32-exact box corners in the raw frame
    turn_deg: float = 0.0
    box_center: np.ndarray | None = None  # tight box centre (ann)
    box_R: np.ndarray | None = None  # R_ann<-box of the tight box
    box_lwh: np.ndarray | None = None  # tight box edge lengths (length >= width, height)

    @property
    def center(self) -> np.ndarray:
        """Axis-aligned box centre (ann frame); the tight box has the same centre (a box's vertices)."""
        return (self.bmin + self.bmax) / 2.0

    @property
    def size(self) -> np.ndarray:
        """Axis-aligned box edge lengths along ann x, y, z (the legacy convention)."""
        return self.bmax - self.bmin

    @property
    def turned(self) -> bool:
        """True when the object stands turned from the room axes."""
        return self.turn_deg != 0.0


@dataclass
class ScanNetScene:
    """A generated ScanNet scene and its by-construction truth.

    Attributes
    ----------
    name : str
        Scene id, e.g. ``scene0900_00``.
    A : ndarray (4, 4)
        ``axisAlignment = T_ann<-raw`` as parsed back from the written text.
    poses : ndarray (N, 4, 4)
        ``P(t) = T_raw<-cam`` per frame (float32 values), all ``-inf`` where invalid.
    valid : ndarray (N,) bool
    instances : list of Instance
    K : tuple
        Colour intrinsics ``(fx, fy, mx, my)``; ``COLOR_SIZE`` is the image size.
    """

    name: str
    A: np.ndarray
    poses: np.ndarray
    valid: np.ndarray
    instances: list[Instance]
    K: tuple[float, float, float, float]
    K_depth: tuple[float, float, float, float]
    scene_type: str
    room: tuple[float, float]
    absent_labels: list[str]
    fps: float = FPS
    _vis: np.ndarray | None = None
    _behind: np.ndarray | None = None

    # ------------------------------------------------------------------ basic accessors
    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return int(self.poses.shape[0])

    @property
    def video_end(self) -> float:
        """Time of the last frame, ``(N - 1) / fps``."""
        return (self.n_frames - 1) / self.fps

    @property
    def last_valid(self) -> int:
        """Index of the last valid pose."""
        return int(np.flatnonzero(self.valid)[-1])

    def frame_of(self, t: float) -> int:
        """Frame index of timeline time ``t``."""
        return int(round(t * self.fps))

    def cam_center_ann(self, f: int) -> np.ndarray:
        """Camera centre in the annotation frame."""
        return self.A[:3, :3] @ self.poses[f, :3, 3] + self.A[:3, 3]

    def instance(self, object_id: int) -> Instance:
        """Instance by objectId."""
        return next(i for i in self.instances if i.object_id == object_id)

    def labels(self) -> dict[str, list[Instance]]:
        """Instances grouped by label."""
        out: dict[str, list[Instance]] = {}
        for inst in self.instances:
            out.setdefault(inst.label, []).append(inst)
        return out

    # ------------------------------------------------------------------ visibility
    def _compute_visibility(self) -> None:
        """Fill the visibility caches."""
        n = self.n_frames
        vis = np.zeros((len(self.instances), n), bool)
        behind = np.zeros((len(self.instances), n), bool)
        Ainv = np.linalg.inv(self.A)
        ok = np.flatnonzero(self.valid)
        Pinv = np.linalg.inv(self.poses[ok])
        for i, inst in enumerate(self.instances):
            c_raw = Ainv[:3, :3] @ inst.center + Ainv[:3, 3]
            pc = np.einsum("nij,j->ni", Pinv[:, :3, :3], c_raw) + Pinv[:, :3, 3]
            vis[i, ok] = in_view(self.K, COLOR_SIZE, pc, margin=0.1, min_depth=0.5, max_depth=7.0)
            corners = box_corners(inst.center, inst.size) @ Ainv[:3, :3].T + Ainv[:3, 3]
            depth = np.einsum("nj,kj->nk", Pinv[:, 2, :3], corners) + Pinv[:, 2, 3][:, None]
            behind[i, ok] = np.all(depth < -0.2, axis=1)
        self._vis, self._behind = vis, behind

    def visible(self) -> np.ndarray:
        """(instances, frames) bool: the instance centre projects well inside the colour image."""
        if self._vis is None:
            self._compute_visibility()
        return self._vis

    def behind(self) -> np.ndarray:
        """(instances, frames) bool: every box corner lies behind the camera (outside the frustum)."""
        if self._behind is None:
            self._compute_visibility()
        return self._behind

    # ------------------------------------------------------------------ truth (own numpy)
    def box_in_camera(self, inst: Instance, f: int) -> dict:
        """The tight oriented box in the OpenCV camera frame: ``T_cam<-box = P^-1 A^-1 T_ann<-box``."""
        T = np.linalg.inv(self.poses[f]) @ np.linalg.inv(self.A)
        R = T[:3, :3] @ inst.box_R
        c = T[:3, :3] @ inst.box_center + T[:3, 3]
        return {
            "C_central_point": c.tolist(),
            "C_lwh": inst.box_lwh.tolist(),
            "C_rotation_camera_from_box": R.tolist(),
            "C_heading": math.degrees(math.atan2(R[1, 0], R[0, 0])),
        }

    def legacy_box_center(self, inst: Instance, f: int) -> np.ndarray:
        """The legacy centre ``P(t)^-1 c_ann`` (axis alignment omitted)."""
        Pinv = np.linalg.inv(self.poses[f])
        return Pinv[:3, :3] @ inst.center + Pinv[:3, 3]

    def legacy_heading(self, f: int) -> float:
        """The legacy yaw summary: heading of ``P(t)^-1`` (alignment omitted), degrees."""
        R = np.linalg.inv(self.poses[f])[:3, :3]
        return math.degrees(math.atan2(R[1, 0], R[0, 0]))

    def displacement(self, f0: int, f1: int) -> float:
        """Camera displacement between two frames (m)."""
        return float(np.linalg.norm(self.poses[f1, :3, 3] - self.poses[f0, :3, 3]))

    def path_length(self, f0: int, f1: int) -> float:
        """Camera path length summed over the frames in [f0, f1] (m)."""
        p = self.poses[f0 : f1 + 1, :3, 3]
        return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))

    def heading_change(self, f0: int, f1: int) -> float:
        """Gravity-horizontal heading change of the optical axis (raw +Z up), degrees."""
        from .common import horizontal_heading_change

        return horizontal_heading_change(
            self.poses[f0, :3, 2], self.poses[f1, :3, 2], np.array([0.0, 0.0, 1.0])
        )

    def legacy_xz_angle(self, f0: int, f1: int) -> float:
        """The legacy operator: camera column 2 projected on raw-world X-Z, signed endpoint angle."""
        a = self.poses[f0, [0, 2], 2]
        b = self.poses[f1, [0, 2], 2]
        # signed angle of the rotation about +Y taking a to b (X-Z plane, right-handed about +Y)
        return math.degrees(math.atan2(a[1] * b[0] - a[0] * b[1], a[0] * b[0] + a[1] * b[1]))

    def distance_to_camera(self, inst: Instance, f: int) -> float:
        """Distance from the camera centre to the instance's tight box at frame ``f`` (m)."""
        return point_box_distance(self.cam_center_ann(f), inst.box_center, inst.box_lwh, inst.box_R)

    def legacy_distance_to_camera(self, inst: Instance, f: int) -> float:
        """The legacy distance: camera centre to the axis-aligned ann box at frame ``f`` (m)."""
        return point_box_distance(self.cam_center_ann(f), inst.center, inst.size)

    def box_distance(self, a: Instance, b: Instance) -> float:
        """Minimum distance between two instance boxes (m); both must stand along the room axes
        (their tight and axis-aligned boxes coincide)."""
        if a.turned or b.turned:
            raise ValueError("box_distance is defined here for instances along the room axes only")
        return aabb_distance(a.bmin, a.bmax, b.bmin, b.bmax)

    def interval_ok(self, f0: int, f1: int) -> bool:
        """True when every pose in [f0, f1] is valid."""
        return 0 <= f0 <= f1 < self.n_frames and bool(np.all(self.valid[f0 : f1 + 1]))

    def describe(self) -> dict:
        """Ground truth for world.json."""
        inv = np.flatnonzero(~self.valid)
        return {
            "scene": self.name,
            "n_frames": self.n_frames,
            "fps": self.fps,
            "scene_type": self.scene_type,
            "room_size_m": list(self.room),
            "axis_alignment": round_list(self.A, 6),
            "invalid_frames": [int(x) for x in inv],
            "last_valid_frame": self.last_valid,
            "absent_labels": self.absent_labels,
            "instances": [
                {
                    "objectId": i.object_id,
                    "label": i.label,
                    "description": i.description,
                    "ann_min": round_list(i.bmin),
                    "ann_max": round_list(i.bmax),
                    "center_ann": round_list(i.center),
                    "size": round_list(i.size),
                    "turn_deg": round(i.turn_deg, 6),
                    "box_center_ann": round_list(i.box_center),
                    "box_lwh": round_list(i.box_lwh),
                    "box_yaw_deg": round(math.degrees(math.atan2(i.box_R[1, 0], i.box_R[0, 0])), 6),
                }
                for i in self.instances
            ],
        }


# ============================================================================== construction


def _place_objects(
    rng: np.random.Generator, W: float, D: float, turn_rng: np.random.Generator | None = None
) -> list[tuple[str, np.ndarray, np.ndarray, float, float]]:
    """Boxes along the walls, no overlaps: list of (label, min, max, turn, along-wall yaw) in the ann
    frame; ``min``/``max`` bound the (possibly turned) box, ``turn`` (rad) is drawn from ``turn_rng``
    for :data:`TURNABLE` labels, the yaw of the box's own x axis is ``base + turn``."""
    n_chairs = int(rng.integers(3, 5))
    pool = [k for k in _LABELS if k not in ("chair", "door", "trash can")]
    others = list(rng.choice(pool, size=5, replace=False))
    labels = ["door"] + ["chair"] * n_chairs + others
    if rng.random() < 0.5:
        labels += ["trash can", "trash can"]
    placed: list[tuple[str, np.ndarray, np.ndarray, float, float]] = []
    for label in labels:
        spec = _LABELS[label]
        turn = 0.0
        if turn_rng is not None and label in TURNABLE and turn_rng.random() < TURN_PROBABILITY:
            turn = math.radians(turn_rng.uniform(*TURN_DEG)) * float(turn_rng.choice([-1, 1]))
        for _ in range(400):
            along, across, height = (rng.uniform(*r) for r in spec["size"])
            wall = int(rng.integers(0, 4))
            gap = 0.02 if label == "door" else rng.uniform(0.05, 0.35)
            if label == "chair":
                gap = rng.uniform(0.3, 0.7)
            # footprint extents along and across the wall (of the turned box when turned)
            c, s_ = abs(math.cos(turn)), abs(math.sin(turn))
            e_al, e_ac = along * c + across * s_, along * s_ + across * c
            if wall in (0, 1):  # walls y = 0 / y = D, extent along x
                x0 = rng.uniform(0.1, W - e_al - 0.1)
                y0 = gap if wall == 0 else D - gap - e_ac
                lo, hi = np.array([x0, y0, 0.0]), np.array([x0 + e_al, y0 + e_ac, height])
                base = 0.0
            else:  # walls x = 0 / x = W, extent along y
                y0 = rng.uniform(0.1, D - e_al - 0.1)
                x0 = gap if wall == 2 else W - gap - e_ac
                lo, hi = np.array([x0, y0, 0.0]), np.array([x0 + e_ac, y0 + e_al, height])
                base = math.pi / 2
            lo[2] += spec["z"]
            hi[2] += spec["z"]
            if all(
                np.any(lo[:2] > b_hi[:2] + 0.1) or np.any(hi[:2] < b_lo[:2] - 0.1)
                for _, b_lo, b_hi, _, _ in placed
            ):
                placed.append((label, lo, hi, turn, (base, along, across)))
                break
    return placed


def _camera_path(
    rng: np.random.Generator, W: float, D: float, n: int, targets: list[np.ndarray]
) -> np.ndarray:
    """Ann-frame camera poses ``T_ann<-cam`` (n, 4, 4): a smooth loop looking from object to object."""
    t = np.arange(n) / FPS
    margin = 1.25
    cx, cy = W / 2, D / 2
    ax, ay = max(W / 2 - margin, 0.4), max(D / 2 - margin, 0.4)
    speed = rng.uniform(0.3, 0.45)
    Tx = 2 * math.pi * ax / speed * rng.uniform(0.9, 1.2)
    Ty = 2 * math.pi * ay / speed * rng.uniform(0.7, 1.0)
    px, py = rng.uniform(0, 2 * math.pi, size=2)
    pos = np.stack(
        [
            cx + ax * np.sin(2 * math.pi * t / Tx + px),
            cy + ay * np.sin(2 * math.pi * t / Ty + py),
            1.35 + 0.1 * np.sin(2 * math.pi * t / rng.uniform(7, 12)),
        ],
        axis=1,
    )
    # look-at targets: dwell on one object, then turn smoothly to the next
    order = rng.permutation(len(targets))
    dwell = rng.uniform(3.0, 5.5, size=64)
    starts = np.concatenate([[0.0], np.cumsum(dwell)])
    look = np.zeros((n, 3))
    for k in range(len(starts) - 1):
        a = targets[order[k % len(order)]]
        b = targets[order[(k + 1) % len(order)]]
        m = (t >= starts[k]) & (t < starts[k + 1])
        if not m.any():
            continue
        s = smoothstep((t[m] - (starts[k + 1] - 1.5)) / 1.5)[:, None]
        look[m] = a * (1 - s) + b * s
    # the gaze wanders around the target (a camera held by a person never centres an object exactly;
    # exact centring would put object centres on the optical axis, printed as 0.0)
    wander = np.stack([0.18 * np.sin(2 * math.pi * t / rng.uniform(3, 6) + rng.uniform(0, 6)),
                       0.18 * np.sin(2 * math.pi * t / rng.uniform(3, 6) + rng.uniform(0, 6)),
                       0.10 * np.sin(2 * math.pi * t / rng.uniform(3, 6) + rng.uniform(0, 6))], axis=1)
    look = look + wander
    tilt = np.radians(6.0) * np.sin(2 * math.pi * t / rng.uniform(5, 9) + rng.uniform(0, 6))
    roll = np.radians(3.0) * np.sin(2 * math.pi * t / rng.uniform(4, 8) + rng.uniform(0, 6))
    poses = np.zeros((n, 4, 4))
    for i in range(n):
        fwd = look[i] - pos[i]
        R = look_rotation(fwd, roll=roll[i]) @ rot_x(tilt[i])
        poses[i] = make_T(R, pos[i])
    return poses


def _fmt_mat(M: np.ndarray) -> str:
    return " ".join(f"{v:f}" for v in np.asarray(M, float).ravel())


def build_scene(
    name: str, duration: float, tail_invalid: int, gap: tuple[int, int] | None, seed: int
) -> ScanNetScene:
    """Build one scene (world model only; :func:`write_scene` writes its files)."""
    rng = np.random.default_rng(seed)
    W, D = float(rng.uniform(5.0, 7.0)), float(rng.uniform(4.5, 6.0))
    boxes = _place_objects(rng, W, D, np.random.default_rng([seed, 1]))

    # axisAlignment: rotation about +Z (never identity) plus a translation; parse back the text
    alpha = rng.choice([-1, 1]) * rng.uniform(math.radians(20), math.radians(160))
    A0 = make_T(rot_z(alpha), np.array([rng.uniform(-4, 4), rng.uniform(-4, 4), rng.uniform(-0.1, 0.1)]))
    A = np.array([float(x) for x in _fmt_mat(A0).split()]).reshape(4, 4)
    Ainv = np.linalg.inv(A)

    n = int(round(duration * FPS))
    targets = [(lo + hi) / 2 for _, lo, hi, _, _ in boxes]
    P_ann = _camera_path(rng, W, D, n, targets)
    poses = np.einsum("ij,njk->nik", Ainv, P_ann).astype(np.float32).astype(np.float64)
    valid = np.ones(n, bool)
    if tail_invalid:
        valid[n - tail_invalid :] = False
    if gap:
        valid[gap[0] : gap[0] + gap[1]] = False
    poses[~valid] = -np.inf

    # instances: ann AABB of A @ float32(raw vertices), exactly what the files will give
    instances = []
    used_desc: dict[str, int] = {}
    unit_box = np.asarray(trimesh.creation.box(extents=[1.0, 1.0, 1.0]).vertices)  # corners at +-0.5
    for oid, (label, lo, hi, turn, (base, along, across)) in enumerate(boxes):
        if turn:  # the box's own axes: x along the wall, turned by ``turn`` about +Z
            local = unit_box * np.array([along, across, hi[2] - lo[2]])
            corners_ann = (lo + hi) / 2 + local @ rot_z(base + turn).T
        else:
            corners_ann = (lo + hi) / 2 + unit_box * (hi - lo)
        raw32 = (corners_ann @ Ainv[:3, :3].T + Ainv[:3, 3]).astype(np.float32).astype(np.float64)
        back = raw32 @ A[:3, :3].T + A[:3, 3]
        k = used_desc.get(label, 0)
        used_desc[label] = k + 1
        descs = _LABELS[label]["desc"]
        bc, bR, blwh = tight_upright_box(back)
        instances.append(
            Instance(
                oid, str(label), str(descs[k % len(descs)]), back.min(0), back.max(0), raw_vertices=raw32,
                turn_deg=math.degrees(turn), box_center=bc, box_R=bR, box_lwh=blwh,
            )
        )
    K = (1170.187988, 1170.187988, 647.75, 483.75)
    K_depth = (571.623718, 571.623718, 319.5, 239.5)
    return ScanNetScene(
        name=name,
        A=A,
        poses=poses,
        valid=valid,
        instances=instances,
        K=K,
        K_depth=K_depth,
        scene_type=str(rng.choice(_SCENE_TYPES)),
        room=(W, D),
        absent_labels=sorted(ABSENT_LABELS),
    )


# ================================================================================== writing


def _scene_txt(s: ScanNetScene) -> str:
    fx, fy, mx, my = s.K
    dfx, dfy, dmx, dmy = s.K_depth
    lines = {
        "axisAlignment": _fmt_mat(s.A) + " ",
        "colorHeight": str(COLOR_SIZE[1]),
        "colorToDepthExtrinsics": _fmt_mat(np.eye(4)),
        "colorWidth": str(COLOR_SIZE[0]),
        "depthHeight": str(DEPTH_SIZE[1]),
        "depthWidth": str(DEPTH_SIZE[0]),
        "fx_color": f"{fx:f}",
        "fx_depth": f"{dfx:f}",
        "fy_color": f"{fy:f}",
        "fy_depth": f"{dfy:f}",
        "mx_color": f"{mx:f}",
        "mx_depth": f"{dmx:f}",
        "my_color": f"{my:f}",
        "my_depth": f"{dmy:f}",
        "numColorFrames": str(s.n_frames),
        "numDepthFrames": str(s.n_frames),
        "numIMUmeasurements": str(2 * s.n_frames + 17),
        "sceneType": s.scene_type,
    }
    return "".join(f"{k} = {v}\n" for k, v in lines.items())


def _intrinsic4(K: tuple[float, float, float, float]) -> np.ndarray:
    fx, fy, cx, cy = K
    return np.array([[fx, 0, cx, 0], [0, fy, cy, 0], [0, 0, 1, 0], [0, 0, 0, 1]], np.float64)


def _sens_bytes(s: ScanNetScene, rng: np.random.Generator) -> bytes:
    """The .sens stream: version-4 header, then per frame pose, timestamps, sizes and payloads."""
    name = b"StructureSensor"
    head = [struct.pack("<I", 4), struct.pack("<Q", len(name)), name]
    for M in (_intrinsic4(s.K), np.eye(4), _intrinsic4(s.K_depth), np.eye(4)):
        head.append(np.asarray(M, "<f4").tobytes())
    head.append(struct.pack("<ii", 2, 1))  # jpeg colour, zlib_ushort depth
    head.append(struct.pack("<IIII", COLOR_SIZE[0], COLOR_SIZE[1], DEPTH_SIZE[0], DEPTH_SIZE[1]))
    head.append(struct.pack("<f", 1000.0))
    head.append(struct.pack("<Q", s.n_frames))
    depth = zlib.compress(np.full((3, 4), 1500, "<u2").tobytes(), 9)
    lens = rng.integers(6, 30, size=s.n_frames)
    body = []
    for f in range(s.n_frames):
        ts = int(round(f * 1e6 / FPS))
        color = b"\xff\xd8" + bytes((f * 7 + k) % 256 for k in range(int(lens[f]))) + b"\xff\xd9"
        body.append(s.poses[f].astype("<f4").tobytes())
        body.append(struct.pack("<QQQQ", ts, ts, len(color), len(depth)))
        body.append(color)
        body.append(depth)
    return b"".join(head + body)


def _mesh(s: ScanNetScene, rng: np.random.Generator) -> tuple[trimesh.Trimesh, list[int]]:
    """The annotation mesh in raw coordinates and the per-vertex segment ids."""
    Ainv = np.linalg.inv(s.A)
    W, D = s.room
    verts, faces, colors, seg_of_vertex = [], [], [], []
    # floor: a 5x5 grid, four segments (one per quadrant); not annotated
    g = 5
    xs, ys = np.linspace(0, W, g), np.linspace(0, D, g)
    base = 0
    for j in range(g):
        for i in range(g):
            verts.append([xs[i], ys[j], 0.0])
            colors.append([150, 140, 120, 255])
            seg_of_vertex.append(10 + 2 * (i >= g // 2) + (j >= g // 2))
    for j in range(g - 1):
        for i in range(g - 1):
            a, b, c, d = (
                base + j * g + i,
                base + j * g + i + 1,
                base + (j + 1) * g + i,
                base + (j + 1) * g + i + 1,
            )
            faces += [[a, b, d], [a, d, c]]
    v_raw = list(
        (np.asarray(verts, float) @ Ainv[:3, :3].T + Ainv[:3, 3]).astype(np.float32).astype(np.float64)
    )
    box_faces = np.asarray(trimesh.creation.box(extents=[1.0, 1.0, 1.0]).faces)
    for inst in s.instances:
        off = len(v_raw)
        col = [int(c) for c in rng.integers(30, 230, size=3)] + [255]
        bottom, top = 1000 + 17 * inst.object_id, 1000 + 17 * inst.object_id + 5
        z_ann = inst.raw_vertices @ s.A[2, :3] + s.A[2, 3]
        for v, z in zip(inst.raw_vertices, z_ann):
            v_raw.append(v)
            colors.append(col)
            seg_of_vertex.append(top if z > inst.center[2] else bottom)
        faces += (box_faces + off).tolist()
        inst.segments = [bottom, top]
    v_raw = np.asarray(v_raw, float)
    mesh = trimesh.Trimesh(
        vertices=v_raw,
        faces=np.asarray(faces, np.int64),
        vertex_colors=np.asarray(colors, np.uint8),
        process=False,
    )
    return mesh, seg_of_vertex


def write_scene(s: ScanNetScene, scans_dir: Path, seed: int) -> dict:
    """Write every file of one scene under ``scans_dir/<scene>/``; return file counts/bytes."""
    rng = np.random.default_rng(seed)
    d = scans_dir / s.name
    (d / "pose").mkdir(parents=True, exist_ok=True)
    (d / "intrinsic").mkdir(parents=True, exist_ok=True)
    (d / f"{s.name}.txt").write_text(_scene_txt(s))
    (d / f"{s.name}.sens").write_bytes(_sens_bytes(s, rng))
    for f in range(s.n_frames):
        P = s.poses[f].astype(np.float32)
        (d / "pose" / f"{f}.txt").write_text(
            "".join(" ".join(f"{float(v):f}" for v in row) + "\n" for row in P)
        )
    for fname, M in (
        ("intrinsic_color.txt", _intrinsic4(s.K)),
        ("extrinsic_color.txt", np.eye(4)),
        ("intrinsic_depth.txt", _intrinsic4(s.K_depth)),
        ("extrinsic_depth.txt", np.eye(4)),
    ):
        (d / "intrinsic" / fname).write_text(
            "".join(" ".join(f"{float(v):f}" for v in row) + "\n" for row in np.asarray(M, np.float32))
        )
    mesh, seg_of_vertex = _mesh(s, rng)
    (d / f"{s.name}_vh_clean_2.ply").write_bytes(mesh.export(file_type="ply", encoding="binary"))
    segs = {
        "params": {
            "kThresh": "0.0001",
            "segMinVerts": "20",
            "minPoints": "750",
            "maxPoints": "-1",
            "thinThresh": "0.05",
            "flatThresh": "0.001",
            "minLength": "0.02",
            "maxLength": "1",
        },
        "sceneId": s.name,
        "segIndices": [int(x) for x in seg_of_vertex],
    }
    write_json(d / f"{s.name}_vh_clean_2.0.010000.segs.json", segs)
    agg = {
        "sceneId": f"scannet.{s.name}",
        "appId": "Aggregator.v2",
        "segGroups": [
            {"id": i.object_id, "objectId": i.object_id, "segments": i.segments, "label": i.label}
            for i in s.instances
        ],
        "segmentsFile": f"scannet.{s.name}_vh_clean_2.0.010000.segs.json",
    }
    write_json(d / f"{s.name}.aggregation.json", agg)
    return {"frames": s.n_frames}


def build_default(seed: int) -> list[ScanNetScene]:
    """The default scenes (ids >= scene0900 so they never look like real ScanNet scenes)."""
    from .common import stable_seed

    return [
        build_scene(name, dur, tail, gap, stable_seed(seed, f"scannet|{name}"))
        for name, dur, tail, gap in DEFAULT_SCENES
    ]
