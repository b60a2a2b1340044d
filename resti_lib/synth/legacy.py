"""Legacy STI-Bench rows over the mini-world, built the way the legacy benchmark was.

``docs/legacy_miniworld.md`` is the specification: ground truth from the generated annotations,
templated question text, distractors from a log-sampled gap scaled by scenario, shuffled letters,
then the documented defects injected at known rows. Every row gets a manifest record with its true
contract, true value, the legacy value, the injected defect codes (``resti_lib.defects``) and the
expected verdict.

Rates are fixed counts per (task, source) group, chosen by a seeded permutation, so a world of
any size carries every defect class. Per-row randomness comes from
``default_rng(stable_seed(seed, row key))``.

Waymo object referents of kept rows are ones a viewer of the video can find (the audit excludes
the others as ``not_visible_at_frame`` / ``ambiguous_instance``): a motion subject (Displacement
"How far has the {desc} traveled ...", acceleration) is visible in the video's camera at one frame
of the asked interval at least, and a video whose camera never sees a mover is passed over when
those variants are assigned; a Dimensional referent is the only object of its type in view at the
asked frame (other objects of the type not even seen loosely, :meth:`WaymoSegment.seen_loosely`).

Unit tags: none of the legacy scalar templates (Displacement & Path Length, Speed & Acceleration,
Dimensional Measurement) states the unit of its answer, so every row of those tasks carries
``unit_tag_missing``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import LETTERS, SCENE_OF_SOURCE
from ..defects import DEFECTS, REASONS
from ..values import (
    format_angle,
    format_box,
    format_legacy_box,
    format_pose,
    format_scalar,
    format_trajectory,
)
from .common import rng_for, rot_z, wrap_deg
from .omni6d import _CLASSES as OMNI_CLASSES
from .omni6d import RopeScene
from .scannet import _LABELS as SCANNET_LABELS
from .scannet import ABSENT_LABELS, ScanNetScene
from .waymo import ABSENT_DESCRIPTIONS, CAMERA_RELATION, WaymoSegment

TASK_ORDER = (
    "Dimensional Measurement",
    "Speed & Acceleration",
    "Ego-Centric Orientation",
    "Trajectory Description",
    "3D Video Grounding",
    "Pose Estimation",
    "Spatial Relation",
    "Displacement & Path Length",
)

#: The task/source pairs of the legacy benchmark.
TASK_SOURCES = {
    "3D Video Grounding": ("ScanNet", "Waymo", "Omni6DPose"),
    "Ego-Centric Orientation": ("ScanNet", "Waymo"),
    "Pose Estimation": ("ScanNet", "Waymo", "Omni6DPose"),
    "Displacement & Path Length": ("ScanNet", "Waymo", "Omni6DPose"),
    "Speed & Acceleration": ("ScanNet", "Waymo", "Omni6DPose"),
    "Trajectory Description": ("Waymo",),
    "Dimensional Measurement": ("ScanNet", "Waymo", "Omni6DPose"),
    "Spatial Relation": ("Waymo", "Omni6DPose"),
}

#: Variant fractions per (task, source) group: (variant, fraction of the group, at least one).
VARIANTS: dict[tuple[str, str], list[tuple[str, float, bool]]] = {
    ("3D Video Grounding", "ScanNet"): [("ambiguous", 0.05, True)],
    ("Pose Estimation", "ScanNet"): [("premise", 0.04, True)],
    ("Pose Estimation", "Waymo"): [("premise", 0.04, True), ("wrong_timestamp", 0.72, True)],
    ("Displacement & Path Length", "ScanNet"): [("zero", 0.03, True), ("mismatch", 0.2, True)],
    ("Displacement & Path Length", "Waymo"): [
        ("zero", 0.03, True),
        ("ambiguous", 0.14, True),
        ("object", 0.22, True),
        ("mismatch", 0.15, True),
    ],
    ("Displacement & Path Length", "Omni6DPose"): [("zero", 0.03, True), ("mismatch", 0.2, True)],
    ("Speed & Acceleration", "ScanNet"): [("mismatch", 0.33, True)],
    ("Speed & Acceleration", "Waymo"): [
        ("accel", 0.28, True),
        ("accel_mismatch", 0.07, True),
        ("mismatch", 0.22, True),
    ],
    ("Speed & Acceleration", "Omni6DPose"): [("mismatch", 0.33, True)],
    ("Dimensional Measurement", "ScanNet"): [
        ("ambiguous", 0.15, True),
        ("grouped", 0.1, True),
        ("no_source", 0.08, True),
        ("not_visible", 0.08, True),
        ("mismatch", 0.12, True),
    ],
    ("Dimensional Measurement", "Waymo"): [("no_source", 0.1, True), ("mismatch", 0.2, True)],
    ("Dimensional Measurement", "Omni6DPose"): [
        ("ambiguous", 0.15, True),
        ("grouped", 0.15, True),
        ("mismatch", 0.15, True),
    ],
    ("Spatial Relation", "Omni6DPose"): [("no_dominant", 0.15, True)],
}
#: Fraction of grounding rows whose question names the sampled time (the rest: ``unnamed_frame``).
GROUNDING_NAMED = 0.4

# answer-layer rates (report: 1,014 / 2,064; 32 / 2,064; 25 / 2,064)
KEY_MISMATCH_RATE = 0.49
DUP_EXACT_RATE = 0.0155
DUP_NUMERIC_RATE = 0.012
_SCALAR_TASKS = ("Displacement & Path Length", "Speed & Acceleration", "Dimensional Measurement")
_DUP_EXACT_TASKS = _SCALAR_TASKS + ("Pose Estimation", "3D Video Grounding")

# distractor gap floors per scenario, in the answer unit
_FLOOR = {
    ("indoor", "m"): 0.05,
    ("outdoor", "m"): 0.5,
    ("desktop", "m"): 0.01,
    ("desktop", "cm"): 1.0,
    ("indoor", "m/s"): 0.02,
    ("outdoor", "m/s"): 0.3,
    ("desktop", "m/s"): 0.005,
    ("outdoor", "m/s²"): 0.1,
}
#: (shortest, longest) integer-second interval of Waymo object-subject rows: path length, acceleration.
_INTERVAL = {"path": (2, 12), "accel": (3, 12)}
_CENTER_GAP = {"indoor": (0.08, 0.8), "outdoor": (0.5, 4.0), "desktop": (0.01, 0.08)}
#: Legacy option leak of the scalar tasks (ReSTI report, "The choices reveal answers without video": the
#: median candidate is the answer on 46.9% of the 1,129 legacy scalar rows): this share of the legacy
#: scalar rows gets its four distractors split two below and two above the answer (where the value
#: leaves room below zero), the others a side at random per distractor. The pick is scored against the
#: legacy key, which points at a distractor on the key-detail mismatch rows (about half), so the share
#: is high: with the Orientation grid and smallest-answer rows the pooled median pick is 46.5% (73/157)
#: on the default world and 44.5% (518/1,163) at scale 1, against the report's 46.9%.
BALANCED_SHARE = 0.9
_POSE_GAP = {"ScanNet": (0.3, 2.0), "Waymo": (1.0, 20.0), "Omni6DPose": (0.05, 0.4)}


# =============================================================================== data classes


@dataclass
class Slot:
    """One legacy row position: which video/task/ID and which source sequence it uses."""

    video: str
    source: str
    task: str
    id: int
    sequence: str
    camera: int | None
    occurrence: int = 0  # index among rows of the same (video, task)
    variant: str = "normal"
    named: bool = False

    @property
    def key(self) -> str:
        """Stable text key of the slot (seeds its RNG)."""
        return f"{self.source}|{self.task}|{self.video}|{self.id}|{self.occurrence}"


@dataclass
class Draft:
    """A row before the answer layer: question, legacy answer and truth."""

    question: str
    prompt: str
    time_start: float
    time_end: float
    detail: str  # legacy Answer Detail
    cand_kind: str  # scalar | angle_grid | angle_smallest | pose | box | label | trajectory
    cand_args: dict
    contract: dict
    true_value: Any
    true_answer: str | None
    legacy_value: Any
    defects: list[str]
    verdict: str
    reasons: list[str] = field(default_factory=list)
    evidence: dict = field(default_factory=dict)
    premise: str | None = None  # Pose: the premise pose as the question prints it


@dataclass
class World:
    """The generated source sequences, by name."""

    scannet: dict[str, ScanNetScene]
    waymo: dict[str, WaymoSegment]
    omni: dict[str, RopeScene]


# ==================================================================================== helpers


def _t(t: float) -> str:
    """Question-text time: shortest exact decimal (``12``, ``12.5``, ``10.891767``)."""
    s = f"{round(float(t), 6):.6f}".rstrip("0").rstrip(".")
    return s if s else "0"


def _strip_article(desc: str) -> str:
    low = desc[0].lower() + desc[1:]
    for art in ("a ", "an ", "the "):
        if low.startswith(art):
            return low[len(art) :]
    return low


def _r(v: Any, nd: int = 9) -> Any:
    """Round floats (recursively) for the manifest."""
    if isinstance(v, float):
        return round(v, nd)
    if isinstance(v, dict):
        return {k: _r(x, nd) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_r(x, nd) for x in v]
    if isinstance(v, np.ndarray):
        return _r(v.tolist(), nd)
    if isinstance(v, np.generic):
        return _r(v.item(), nd)
    return v


def _perturb(rng: np.random.Generator, v: float, floor: float) -> float:
    """A clearly different value (value_mismatch): 12-45 % away and at least 3 floors."""
    d = max(abs(v) * rng.uniform(0.12, 0.45), 3 * floor * rng.uniform(1.0, 2.0))
    return v + d if (v - d < 0 or rng.random() < 0.5) else v - d


def _pose_dict(T: np.ndarray) -> dict:
    keys = ("tx", "ty", "tz", "r11", "r12", "r13", "r21", "r22", "r23", "r31", "r32", "r33")
    vals = [T[0, 3], T[1, 3], T[2, 3]] + [T[i, j] for i in range(3) for j in range(3)]
    return {k: float(v) for k, v in zip(keys, vals)}


def _box_true(box: dict) -> tuple[dict, str]:
    return box, format_box(box["C_central_point"], box["C_lwh"], box["C_rotation_camera_from_box"])


def _choose(rng: np.random.Generator, items: list) -> Any:
    return items[int(rng.integers(0, len(items)))]


class NoCandidate(Exception):
    """The sequence offers no (object, time) for this variant; the caller falls back."""


# ======================================================================= task builders: ScanNet


def _sn_frames(s: ScanNetScene, step: int = 3) -> np.ndarray:
    f = np.arange(0, s.n_frames, step)
    return f[s.valid[f]]


def _sn_interval(s: ScanNetScene, rng: np.random.Generator, lo: int = 2, hi: int = 20) -> tuple[int, int]:
    end = int(s.last_valid // 30)
    for _ in range(200):
        t0 = int(rng.integers(0, max(end - lo, 1)))
        t1 = min(t0 + int(rng.integers(lo, hi + 1)), end)
        if t1 > t0 and s.interval_ok(30 * t0, 30 * t1):
            return t0, t1
    raise NoCandidate("no valid interval")


def _sn_unique(s: ScanNetScene) -> list:
    labels = s.labels()
    return [i for i in s.instances if len(labels[i.label]) == 1]


def _sn_visible_frame(s: ScanNetScene, inst, rng: np.random.Generator) -> int:
    idx = s.instances.index(inst)
    fr = _sn_frames(s)
    ok = fr[s.visible()[idx, fr]]
    if ok.size == 0:
        raise NoCandidate("instance never visible")
    return int(_choose(rng, list(ok)))


def _sn_multi_visible(s: ScanNetScene, rng: np.random.Generator) -> tuple[str, int, list]:
    """A repeated label and a frame where >= 2 of its instances are visible."""
    vis = s.visible()
    fr = _sn_frames(s)
    options = []
    for label, insts in sorted(s.labels().items()):
        if len(insts) < 2:
            continue
        rows = [s.instances.index(i) for i in insts]
        n_vis = vis[rows][:, fr].sum(axis=0)
        for f in fr[n_vis >= 2]:
            options.append((label, int(f)))
    if not options:
        raise NoCandidate("no frame with several visible instances")
    label, f = _choose(rng, options)
    insts = s.labels()[label]
    visible = [i for i in insts if vis[s.instances.index(i), f]]
    return label, f, visible


def _wm_unique_visible(s: WaymoSegment, cam: int, loose: bool = False) -> list[tuple[int, int]]:
    """(object index, frame) pairs where the object is visible and the only visible one of its type.

    ``loose``: the other objects of the type must not even be seen loosely
    (:meth:`WaymoSegment.seen_loosely`, a superset of any frustum test of the box), so no viewer can
    find a second candidate at that frame.
    """
    vis = s.visible(cam)
    seen = s.seen_loosely(cam) if loose else vis
    types = np.array([o.type for o in s.objects])
    out = []
    for i, o in enumerate(s.objects):
        same = types == o.type
        same[i] = False
        n_other = seen[same].sum(axis=0)
        out += [(i, int(k)) for k in np.flatnonzero(vis[i] & (n_other == 0))]
    return out


def _wm_movers(s: WaymoSegment, what: str) -> list:
    """Subject pool of a Waymo motion row: ``"path"`` (moving vehicles and cyclists), ``"sedan"``
    (the moving sedans of bare "the car" questions) or ``"accel"`` (movers with |a| >= 0.1 m/s²)."""
    if what == "accel":
        return [o for o in s.objects if o.moving and abs(o.a) >= 0.1]
    movers = [o for o in s.objects if o.moving and o.kind != "pedestrian"]
    return [o for o in movers if o.kind == "sedan"] if what == "sedan" else movers


def _wm_seen_intervals(
    s: WaymoSegment, movers: list, cam: int, lo: int, hi: int
) -> list[tuple[int, int, int]]:
    """Every (object index, t0, t1) of integer seconds, ``lo <= t1 - t0 <= hi``, inside the object's
    track and with the object visible in ``cam`` at one frame of the interval at least."""
    vis = s.visible(cam)
    end = int(math.floor(s.video_end))
    out = []
    for o in movers:
        i = s.objects.index(o)
        for t0 in range(end - lo + 1):
            k0 = s.frame_of(t0)
            for t1 in range(t0 + lo, min(t0 + hi, end) + 1):
                k1 = s.frame_of(t1)
                if o.present[k0 : k1 + 1].all() and vis[i, k0 : k1 + 1].any():
                    out.append((i, t0, t1))
    return out


def _wm_object_interval(
    s: WaymoSegment,
    movers: list,
    cam: int,
    rng: np.random.Generator,
    lo: int,
    hi: int,
    need_visible: bool = True,
    seen_intervals: list[tuple[int, int, int]] | None = None,
):
    """An object and an integer-second interval inside its track.

    ``need_visible``: the object is visible in ``cam`` at one frame of the interval at least (the
    question's subject must be in the video); a random draw first, then one of ``seen_intervals``
    (:func:`_wm_seen_intervals`); :class:`NoCandidate` when the camera never sees a mover.
    Otherwise (the bare "the car" of ambiguous subjects) any mover of the segment qualifies.
    """
    vis = s.visible(cam)
    pool = [o for o in movers if vis[s.objects.index(o)].any()] if need_visible else movers
    for _ in range(200):
        if not pool:
            break
        o = _choose(rng, pool)
        pres = np.flatnonzero(o.present)
        ta, tb = int(math.ceil(s.t[pres[0]])), int(math.floor(s.t[pres[-1]]))
        if tb - ta < lo:
            continue
        t0 = int(rng.integers(ta, tb - lo + 1))
        t1 = min(t0 + int(rng.integers(lo, hi + 1)), tb)
        k0, k1 = s.frame_of(t0), s.frame_of(t1)
        if not o.present[k0 : k1 + 1].all():
            continue
        if need_visible and not vis[s.objects.index(o), k0 : k1 + 1].any():
            continue
        return o, t0, t1
    if need_visible:
        opts = seen_intervals if seen_intervals is not None else _wm_seen_intervals(s, movers, cam, lo, hi)
        if opts:
            i, t0, t1 = _choose(rng, opts)
            return s.objects[i], t0, t1
    raise NoCandidate("no tracked object seen by the camera over an interval")


# ========================================================================== the row builders


class Builder:
    """Builds the :class:`Draft` of one slot. One method per task; sources branch inside."""

    def __init__(self, world: World, seed: int):
        self.world = world
        self.seed = seed
        self._cache: dict = {}

    def cached(self, key: tuple, fn: Callable) -> Any:
        """Per-sequence lookups (candidate lists) computed once."""
        if key not in self._cache:
            self._cache[key] = fn()
        return self._cache[key]

    def seen_intervals(self, s: WaymoSegment, cam: int, what: str, lo: int, hi: int) -> list:
        """:func:`_wm_seen_intervals` of the ``what`` movers (:func:`_wm_movers`), computed once."""
        return self.cached(
            ("wm-seen-intervals", s.name, cam, what, lo, hi),
            lambda: _wm_seen_intervals(s, _wm_movers(s, what), cam, lo, hi),
        )

    def can_host(self, slot: Slot, variant: str) -> bool:
        """Whether the slot's video can carry ``variant``: a Waymo object subject (Displacement
        ``object``, Speed ``accel``/``accel_mismatch``) needs a mover seen by the video's camera."""
        if slot.source != "Waymo":
            return True
        s = self.world.waymo[slot.sequence]
        if slot.task == "Displacement & Path Length" and variant == "object":
            return bool(self.seen_intervals(s, slot.camera, "path", *_INTERVAL["path"]))
        if slot.task == "Speed & Acceleration" and variant in ("accel", "accel_mismatch"):
            return bool(self.seen_intervals(s, slot.camera, "accel", *_INTERVAL["accel"]))
        return True

    def seq(self, slot: Slot):
        """The source sequence of a slot."""
        if slot.source == "ScanNet":
            return self.world.scannet[slot.sequence]
        if slot.source == "Waymo":
            return self.world.waymo[slot.sequence]
        return self.world.omni[slot.sequence]

    def build(self, slot: Slot) -> Draft:
        """The draft of one slot; a variant the sequence cannot host falls back to a normal row."""
        fn: Callable = {
            "3D Video Grounding": self.grounding,
            "Ego-Centric Orientation": self.orientation,
            "Pose Estimation": self.pose,
            "Displacement & Path Length": self.displacement,
            "Speed & Acceleration": self.speed,
            "Trajectory Description": self.trajectory,
            "Dimensional Measurement": self.dimensional,
            "Spatial Relation": self.relation,
        }[slot.task]
        for attempt in range(6):
            rng = rng_for(self.seed, f"row|{slot.key}|{attempt}")
            try:
                return fn(slot, rng)
            except NoCandidate:
                if attempt >= 2 and slot.variant != "normal":
                    slot.variant = "normal"  # the sequence cannot host this variant
        raise RuntimeError(f"cannot build row {slot.key} on {slot.sequence}")

    # ---------------------------------------------------------------------- grounding
    def grounding(self, slot: Slot, rng: np.random.Generator) -> Draft:
        """3D Video Grounding: legacy box (ScanNet centre without alignment) and the true oriented box."""
        s = self.seq(slot)
        scen = SCENE_OF_SOURCE[slot.source]
        defects: list[str] = []
        reasons: list[str] = []
        evidence: dict = {}
        if slot.source == "ScanNet":
            if slot.variant == "ambiguous":
                label, f, visible = _sn_multi_visible(s, rng)
                inst = _choose(rng, visible)
                defects.append("multiple_instances")
                reasons.append("ambiguous_instance")
                evidence = {
                    "label": label,
                    "n_visible_instances": len(visible),
                    "visible_object_ids": [i.object_id for i in visible],
                }
            else:
                inst = _choose(rng, _sn_unique(s))
                f = _sn_visible_frame(s, inst, rng)
            t = f / s.fps
            desc = inst.description
            legacy_c = s.legacy_box_center(inst, f)
            legacy = {
                "C_central_point": legacy_c.tolist(),
                "C_lwh": inst.size.tolist(),
                "C_heading": s.legacy_heading(f),
            }
            true_box = s.box_in_camera(inst, f)
            entity = {"kind": "object", "id": inst.object_id, "label": inst.label}
            defects.append("grounding_alignment_omitted")
            verdict = "excluded" if reasons else "corrected"
        elif slot.source == "Waymo":
            cands = self.cached(
                ("wm-unique-visible", s.name, slot.camera), lambda: _wm_unique_visible(s, slot.camera)
            )
            if not cands:  # no object is the only visible one of its type: any visible object
                vis = s.visible(slot.camera)
                cands = [(i, int(k)) for i in range(len(s.objects)) for k in np.flatnonzero(vis[i])]
            if not cands:
                raise NoCandidate("no visible object")
            i, k = _choose(rng, cands)
            o = s.objects[i]
            t = float(s.t[k])
            desc = o.description
            true_box = s.box_in_camera(o, k, slot.camera)
            legacy = {
                "C_central_point": true_box["C_central_point"],
                "C_lwh": o.size.tolist(),
                "C_heading": math.degrees(float(o.heading_v[k])),
            }
            entity = {"kind": "object", "id": o.oid, "label": o.kind, "type": o.type}
            verdict = "re-contracted"
        else:
            objs = [o for o in s.objects if "group" not in OMNI_CLASSES[o.class_name]]
            o = _choose(rng, objs)
            idx = s.objects.index(o)
            fr = np.arange(0, s.n_frames, 3)
            ok = fr[s.visible()[idx, fr]]
            k = int(_choose(rng, list(ok)))
            t = k / s.fps
            desc = o.description
            true_box = s.box_in_camera(o, k)
            legacy = {
                "C_central_point": true_box["C_central_point"],
                "C_lwh": o.side.tolist(),
                "C_heading": s.legacy_heading(o, k),
            }
            entity = {"kind": "object", "id": o.oid, "label": o.class_name}
            verdict = "re-contracted"
        if slot.named:
            q = f"Locate the 3D bounding box of the {_strip_article(desc)} at {_t(t)}s."
        else:
            q = f"Locate the 3D bounding box of the {_strip_article(desc)}."
            defects.insert(0, "unnamed_frame")
        tv, ta = _box_true(true_box)
        detail = format_legacy_box(legacy["C_central_point"], legacy["C_lwh"], legacy["C_heading"])
        if verdict == "excluded":
            tv, ta = None, None
        return Draft(
            question=q,
            prompt=f"Object description: {desc}.",
            time_start=t,
            time_end=t,
            detail=detail,
            cand_kind="box",
            cand_args={"legacy": legacy, "scenario": scen},
            contract={
                "entity": entity,
                "times": [t],
                "operator": "box_in_camera",
                "unit": "m",
                "frame": "opencv_camera",
            },
            true_value=tv,
            true_answer=ta,
            legacy_value=legacy,
            defects=defects,
            verdict=verdict,
            reasons=reasons,
            evidence=evidence,
        )

    # ---------------------------------------------------------------------- orientation
    def orientation(self, slot: Slot, rng: np.random.Generator) -> Draft:
        """Ego-Centric Orientation: legacy X-Z endpoint angle vs gravity-horizontal heading change."""
        s = self.seq(slot)
        if slot.source == "ScanNet":
            f1 = s.last_valid
            legacy = s.legacy_xz_angle(0, f1)
            truth = s.heading_change(0, f1)
            t_end, t_true = s.video_end, f1 / s.fps
            defects = ["orientation_xz_plane", "orientation_symmetric_grid"]
            kind = "angle_grid"
            frame = "raw_world_gravity_horizontal"
        else:
            k1 = s.n_frames - 1
            legacy = s.legacy_xz_angle(0, k1, slot.camera)
            truth = s.heading_change(0, k1, slot.camera)
            t_end = t_true = s.video_end
            defects = ["orientation_xz_plane", "orientation_smallest_correct"]
            kind = "angle_smallest"
            frame = "waymo_world_gravity_horizontal"
        contract = {
            "entity": {"kind": "camera"},
            "times": [0.0, t_true],
            "operator": "heading_change",
            "unit": "deg",
            "frame": frame,
        }
        if t_true < t_end:
            contract["shortened_to"] = t_true
        return Draft(
            question="How many degrees does the camera's horizontal orientation shift from the start "
            "of the video to its end?",
            prompt="",
            time_start=0.0,
            time_end=t_end,
            detail=format_angle(legacy),
            cand_kind=kind,
            cand_args={"value": legacy},
            contract=contract,
            true_value=truth,
            true_answer=format_angle(truth),
            legacy_value=legacy,
            defects=defects,
            verdict="re-contracted",
        )

    # ---------------------------------------------------------------------- pose
    def pose(self, slot: Slot, rng: np.random.Generator) -> Draft:
        """Pose Estimation: ScanNet premise/target poses, Waymo wrong timestamps, ROPE relative pose."""
        s = self.seq(slot)
        defects: list[str] = []
        reasons: list[str] = []
        if slot.source == "ScanNet":
            end = int(s.last_valid // 30)
            t0 = 0 if rng.random() < 0.5 else int(rng.integers(0, max(end - 3, 1)))
            t1 = t0 if slot.variant == "premise" else int(rng.integers(min(t0 + 2, end), end + 1))
            if not (s.valid[30 * t0] and s.valid[30 * t1]):
                raise NoCandidate("invalid pose at a pose time")
            P0, P1 = s.poses[30 * t0], s.poses[30 * t1]
            q = f"Given the initial pose of the camera: {format_pose(P0)}, what is the camera's pose?"
            legacy_T = P1
            truth_T = P1
            defects += ["pose_time_omitted", "pose_identical_rotations"]
            compact = False
            frame = "scannet_raw_opencv"
            t_start, t_end = float(t0), float(t1)
        elif slot.source == "Waymo":
            # the legacy benchmark asks its Waymo poses in converse pairs (the pose at b given the one at
            # a, then at a given b): occurrences 2k and 2k+1 of a video share two times, swapped
            pair = rng_for(self.seed, f"pose-pair|{slot.video}|{slot.occurrence // 2}")
            a = int(pair.integers(0, 19))
            b = int(_choose(pair, [x for x in range(20) if x != a]))
            t0, t1 = (a, b) if slot.occurrence % 2 == 0 else (b, a)
            if slot.variant == "premise":
                t1 = t0
            k0, k1 = s.frame_of(t0), s.frame_of(t1)
            P0, truth_T = s.cam_pose_cv(k0, slot.camera), s.cam_pose_cv(k1, slot.camera)
            legacy_T = truth_T
            if slot.variant == "wrong_timestamp":
                for _ in range(50):
                    u = rng.random()
                    off = 1 if u < 0.6 else int(rng.integers(2, 6)) if u < 0.9 else int(rng.integers(10, 31))
                    off *= int(rng.choice([-1, 1]))
                    kw = min(max(k1 + off, 0), s.n_frames - 1)
                    cand = s.cam_pose_cv(kw, slot.camera)
                    if np.linalg.norm(cand[:3, 3] - truth_T[:3, 3]) > 0.05:
                        legacy_T = cand
                        break
                else:
                    raise NoCandidate("ego too slow for a wrong-timestamp pose")
                defects.append("waymo_pose_wrong_timestamp")
            q = (
                f"Given the camera pose at t={t0} s in the Waymo world coordinate frame: "
                f"{format_pose(P0, compact=True)}, what is the camera pose in the same coordinate frame "
                f"at t={t1} s?"
            )
            compact = True
            frame = "waymo_world_opencv"
            t_start, t_end = float(t1), float(t1)
        else:
            t1 = int(rng.integers(1, int(s.video_end) + 1))
            truth_T = legacy_T = s.pose_rel(s.frame_of(t1))
            q = f"Taking the camera pose at t=0 s as the identity, what is the camera pose at t={t1} s?"
            compact = False
            frame = "opencv_camera_at_t0"
            t0, t_start, t_end = 0, 0.0, float(t1)
        if slot.variant == "premise":
            defects.append("premise_equals_answer")
            reasons.append("premise_equals_target")
        if reasons:
            verdict = "excluded"
        elif "waymo_pose_wrong_timestamp" in defects:
            verdict = "corrected"
        else:
            verdict = "retained"
        contract = {
            "entity": {"kind": "camera"},
            "times": [float(t1)],
            "operator": "pose",
            "unit": "m",
            "frame": frame,
            "premise_time": float(t0),
        }
        return Draft(
            question=q,
            prompt="",
            time_start=t_start,
            time_end=t_end,
            detail=format_pose(legacy_T, compact=compact),
            cand_kind="pose",
            cand_args={
                "T": legacy_T,
                "compact": compact,
                "source": slot.source,
                "same_rotation": slot.source == "ScanNet",
            },
            contract=contract,
            true_value=None if reasons else _pose_dict(truth_T),
            true_answer=None if reasons else format_pose(truth_T, compact=compact),
            legacy_value=_pose_dict(legacy_T),
            defects=defects,
            verdict=verdict,
            reasons=reasons,
            premise=None if slot.source == "Omni6DPose" else format_pose(P0, compact=compact),
        )

    # ---------------------------------------------------------------------- motion helpers
    def _interval(
        self, slot: Slot, s, rng: np.random.Generator, lo: int = 2, hi: int = 12
    ) -> tuple[int, int]:
        """Integer-second interval on the sequence timeline (valid poses for ScanNet)."""
        if slot.source == "ScanNet":
            return _sn_interval(s, rng, lo, hi)
        end = int(math.floor(s.video_end))
        t0 = int(rng.integers(0, end - lo + 1))
        t1 = min(t0 + int(rng.integers(lo, hi + 1)), end)
        return t0, t1

    def _frames(self, slot: Slot, s, t0: float, t1: float) -> tuple[int, int]:
        """Source frames of two timeline times (nearest frame)."""
        return s.frame_of(t0), s.frame_of(t1)

    def _camera_motion(self, slot: Slot, s, k0: int, k1: int) -> tuple[float, float]:
        """(displacement, path length) of the camera between frames."""
        if slot.source == "Waymo":
            return s.cam_displacement(k0, k1, slot.camera), s.cam_path(k0, k1, slot.camera)
        return s.displacement(k0, k1), s.path_length(k0, k1)

    # ---------------------------------------------------------------------- displacement
    def displacement(self, slot: Slot, rng: np.random.Generator) -> Draft:
        """Displacement & Path Length: camera or object subject, zero-length and ambiguous subjects."""
        s = self.seq(slot)
        scen = SCENE_OF_SOURCE[slot.source]
        defects = ["unit_tag_missing"]
        reasons: list[str] = []
        evidence: dict = {}
        t0, t1 = self._interval(slot, s, rng)
        op = "displacement" if rng.random() < 0.5 else "path_length"
        entity: dict = {"kind": "camera"}
        if slot.variant == "object":
            o, t0, t1 = _wm_object_interval(
                s,
                _wm_movers(s, "path"),
                slot.camera,
                rng,
                *_INTERVAL["path"],
                seen_intervals=self.seen_intervals(s, slot.camera, "path", *_INTERVAL["path"]),
            )
        elif slot.variant == "ambiguous":  # "the car": any moving sedan, in view or not
            o, t0, t1 = _wm_object_interval(
                s, _wm_movers(s, "sedan"), slot.camera, rng, *_INTERVAL["path"], need_visible=False
            )
        if slot.variant == "zero":
            t1 = t0
        k0, k1 = self._frames(slot, s, t0, t1)
        if slot.variant in ("object", "ambiguous"):
            op = "path_length"
            value = s.obj_path(o, k0, k1)
            if slot.variant == "object":
                q = f"How far has the {_strip_article(o.description)} traveled from {_t(t0)}s to {_t(t1)}s?"
                entity = {"kind": "object", "id": o.oid, "label": o.kind, "type": o.type}
            else:
                q = f"How far has the car traveled from {_t(t0)}s to {_t(t1)}s?"
                entity = {
                    "kind": "ambiguous",
                    "candidates": [{"kind": "camera"}, {"kind": "object", "id": o.oid}],
                }
                defects.insert(0, "ambiguous_subject")
                reasons.append("ambiguous_subject")
                cam_path = self._camera_motion(slot, s, k0, k1)[1]
                evidence = {"camera_path_m": round(cam_path, 6), "object_path_m": round(value, 6)}
        else:
            disp, path = self._camera_motion(slot, s, k0, k1)
            value = disp if op == "displacement" else path
            if op == "displacement" and slot.source == "ScanNet" and slot.variant != "zero":
                # the ScanNet construction asked "how far has the camera traveled" and printed the
                # endpoint displacement: the audit must find this reading per source, not assume a path
                q = f"How far has the camera traveled from {_t(t0)}s to {_t(t1)}s?"
                defects += ["statistic_unnamed", "distance_traveled_is_displacement"]
                evidence = {"reading": "displacement (how far has the camera traveled, built as |p(t1) - p(t0)|)",
                            "path_length_m": round(path, 6)}
            elif op == "displacement":
                q = f"What is the displacement of the camera from {_t(t0)}s to {_t(t1)}s?"
            else:
                q = f"What is the total distance traveled by the camera from {_t(t0)}s to {_t(t1)}s?"
        legacy = value
        if slot.variant == "zero":
            defects.insert(0, "zero_length_interval")
            reasons.append("zero_length_interval")
        if slot.variant == "mismatch":
            legacy = _perturb(rng, value, _FLOOR[(scen, "m")])
            defects.append("value_mismatch")
        verdict = "excluded" if reasons else ("corrected" if slot.variant == "mismatch" else "retained")
        contract = {
            "entity": entity,
            "times": [float(t0), float(t1)],
            "operator": op,
            "unit": "m",
            "frame": "world",
        }
        return Draft(
            question=q,
            prompt="",
            time_start=float(t0),
            time_end=float(t1),
            detail=format_scalar(legacy, "m"),
            cand_kind="scalar",
            cand_args={"value": legacy, "unit": "m", "scenario": scen},
            contract=contract,
            true_value=None if reasons else value,
            true_answer=None if reasons else format_scalar(value, "m"),
            legacy_value=legacy,
            defects=defects,
            verdict=verdict,
            reasons=reasons,
            evidence=evidence,
        )

    # ---------------------------------------------------------------------- speed
    def speed(self, slot: Slot, rng: np.random.Generator) -> Draft:
        """Speed & Acceleration: 'average speed' = displacement / time; object acceleration (Waymo)."""
        s = self.seq(slot)
        scen = SCENE_OF_SOURCE[slot.source]
        defects = ["unit_tag_missing"]
        if slot.variant in ("accel", "accel_mismatch"):
            o, t0, t1 = _wm_object_interval(
                s,
                _wm_movers(s, "accel"),
                slot.camera,
                rng,
                *_INTERVAL["accel"],
                seen_intervals=self.seen_intervals(s, slot.camera, "accel", *_INTERVAL["accel"]),
            )
            k0, k1 = self._frames(slot, s, t0, t1)
            value = s.obj_acceleration(o, k0, k1)
            legacy = value
            unit = "m/s²"
            if slot.variant == "accel_mismatch":
                legacy = _perturb(rng, value, _FLOOR[(scen, unit)])
                defects.append("value_mismatch")
            q = (
                f"How quickly is the {_strip_article(o.description)} accelerating "
                f"from {_t(t0)}s to {_t(t1)}s?"
            )
            contract = {
                "entity": {"kind": "object", "id": o.oid, "label": o.kind, "type": o.type},
                "times": [float(t0), float(t1)],
                "operator": "acceleration",
                "unit": "m/s^2",
                "frame": "world",
                "estimator": "(v(t1) - v(t0)) / (t1 - t0) from the track's world velocities",
            }
        else:
            t0, t1 = self._interval(slot, s, rng, 2, 12)
            k0, k1 = self._frames(slot, s, t0, t1)
            disp, path = self._camera_motion(slot, s, k0, k1)
            value = disp / (t1 - t0)
            legacy = value
            unit = "m/s"
            defects = ["statistic_unnamed", "speed_is_displacement_over_time", "unit_tag_missing"]
            if slot.variant == "mismatch":
                legacy = _perturb(rng, value, _FLOOR[(scen, unit)])
                defects.append("value_mismatch")
            q = f"What is the average speed of the camera from {_t(t0)}s to {_t(t1)}s?"
            contract = {
                "entity": {"kind": "camera"},
                "times": [float(t0), float(t1)],
                "operator": "average_velocity",
                "unit": "m/s",
                "frame": "world",
                "statistic": "magnitude of average velocity (endpoint displacement / elapsed time)",
                "average_speed_path_over_time": path / (t1 - t0),
            }
        verdict = "corrected" if "value_mismatch" in defects else "retained"
        return Draft(
            question=q,
            prompt="",
            time_start=float(t0),
            time_end=float(t1),
            detail=format_scalar(legacy, unit),
            cand_kind="scalar",
            cand_args={"value": legacy, "unit": unit, "scenario": scen},
            contract=contract,
            true_value=value,
            true_answer=format_scalar(value, unit),
            legacy_value=legacy,
            defects=defects,
            verdict=verdict,
        )

    # ---------------------------------------------------------------------- trajectory
    def trajectory(self, slot: Slot, rng: np.random.Generator) -> Draft:
        """Trajectory Description (Waymo): legacy distances on a 10 m grid."""
        s = self.seq(slot)
        segs = s.trajectory_segments(slot.camera)
        legacy = []
        for kind, v in segs:
            legacy.append((kind, max(10.0, 10.0 * round(v / 10.0)) if kind == "move" else float(round(v))))
        moves = [(i, v) for i, (k, v) in enumerate(segs) if k == "move"]
        if all(abs(legacy[i][1] - v) < 1.0 for i, v in moves):  # keep the grid visibly coarser
            i, v = max(moves, key=lambda m: m[1])
            legacy[i] = (
                "move",
                10.0 * math.floor(v / 10.0) if v % 10 >= 1.0 else 10.0 * math.floor(v / 10.0) - 10,
            )
        legacy_text = format_trajectory(legacy, move_decimals=0)
        truth_text = format_trajectory(segs)
        return Draft(
            question="Summarize the camera trajectory, including distances moved and turns made.",
            prompt="",
            time_start=0.0,
            time_end=s.video_end,
            detail=legacy_text,
            cand_kind="trajectory",
            cand_args={"segments": legacy},
            contract={
                "entity": {"kind": "camera"},
                "times": [0.0, s.video_end],
                "operator": "trajectory_description",
                "unit": "m",
                "frame": "waymo_world",
                "segmentation": "turns = heading change of the camera over each constructed turn window; "
                "distances = camera path length between turn midpoints",
            },
            true_value=truth_text,
            true_answer=truth_text,
            legacy_value=legacy_text,
            defects=["trajectory_10m_grid"],
            verdict="corrected",
        )

    # ---------------------------------------------------------------------- dimensional
    def dimensional(self, slot: Slot, rng: np.random.Generator) -> Draft:
        """Dimensional Measurement: dimensions, camera distance, box distance and referent exclusions."""
        src = slot.source
        s = self.seq(slot)
        scen = SCENE_OF_SOURCE[src]
        unit = "cm" if src == "Omni6DPose" else "m"
        scale = 100.0 if unit == "cm" else 1.0
        defects = ["unit_tag_missing"]
        reasons: list[str] = []
        evidence: dict = {}
        comps = ("length", "width", "height")
        comp = _choose(rng, ["height", "height", "height", "length", "width"])
        u = rng.random()
        kind = "dimension" if u < 0.55 else ("distance" if u < 0.85 or src != "ScanNet" else "min_distance")
        v = slot.variant
        t = 0.0
        t_end = None
        entity: dict
        value: float | None
        legacy: float
        if v in ("ambiguous", "grouped"):
            kind = "dimension"
            if src == "ScanNet":
                label, f, visible = _sn_multi_visible(s, rng)
                insts = s.labels()[label]
                inst = _choose(rng, visible)
                t = f / s.fps
                legacy = float(inst.size[comps.index(comp)])
                evidence = {"label": label, "n_instances": len(insts), "n_visible_instances": len(visible)}
                ids = [i.object_id for i in insts]
                desc = inst.description if v == "ambiguous" else _choose(rng, SCANNET_LABELS[label]["group"])
            else:
                groups: dict[str, list] = {}
                for o in s.objects:
                    groups.setdefault(o.class_name, []).append(o)
                cls = next(c for c, g in groups.items() if len(g) >= 2)
                inst = _choose(rng, groups[cls])
                t = 0.0
                legacy = float(inst.side[comps.index(comp)])
                evidence = {"label": cls, "n_instances": len(groups[cls])}
                ids = [o.oid for o in groups[cls]]
                desc = inst.description if v == "ambiguous" else _choose(rng, OMNI_CLASSES[cls]["group"])
            if v == "ambiguous":
                defects.insert(0, "multiple_instances")
                reasons.append("ambiguous_instance")
            else:
                defects.insert(0, "grouped_referent")
                reasons.append("grouped_referent")
            entity = {"kind": "object", "id": None, "label": evidence["label"], "candidates": ids}
            value = None
        elif v == "no_source":
            kind = "dimension"
            if src == "ScanNet":
                label = _choose(rng, sorted(ABSENT_LABELS))
                desc = ABSENT_LABELS[label]
                t = float(_choose(rng, list(_sn_frames(s)))) / s.fps
            else:
                desc = _choose(rng, ABSENT_DESCRIPTIONS)
                label = desc
                k = int(rng.integers(0, s.n_frames))
                t = float(s.t[k])
            legacy = float(rng.uniform(0.6, 2.5) if src == "ScanNet" else rng.uniform(2.0, 12.0))
            entity = {"kind": "object", "id": None, "label": label}
            value = None
            defects.insert(0, "no_source_instance")
            reasons.append("no_source_instance")
        elif v == "not_visible":
            kind = "distance"
            beh = s.behind()
            fr = _sn_frames(s)
            opts = [(inst, int(f)) for inst in _sn_unique(s) for f in fr[beh[s.instances.index(inst), fr]]]
            if not opts:
                raise NoCandidate("no frame with an instance behind the camera")
            inst, f = _choose(rng, opts)
            t = f / s.fps
            desc = inst.description
            legacy = s.legacy_distance_to_camera(inst, f)
            entity = {"kind": "object", "id": inst.object_id, "label": inst.label}
            value = None
            defects.insert(0, "not_visible")
            reasons.append("not_visible_at_frame")
            evidence = {"all_corners_behind_camera": True, "frame": f}
        else:
            value, legacy0, desc, entity, t, t_end, kind, comp = self._dim_normal(slot, s, rng, kind, comp)
            legacy = legacy0
            if abs(legacy0 - value) > 1e-6:  # the axis-aligned box (legacy) and the tight box differ
                evidence = {"legacy_box": "axis-aligned box in the annotation frame",
                            "axis_aligned_value_m": legacy0, "tight_value_m": value}
            if v == "mismatch":
                for _ in range(50):  # clearly different from both conventions' values
                    legacy = _perturb(rng, legacy0 * scale, _FLOOR[(scen, unit)]) / scale
                    if abs(legacy - value) * scale >= 3 * _FLOOR[(scen, unit)]:
                        break
                defects.append("value_mismatch")
        d = _strip_article(desc)
        if kind == "dimension":
            q = f"What is the {comp} of the {d}?"
            op = {
                "operator": "dimension",
                "component": comp,
                "box_axis": {"length": "x", "width": "y", "height": "z"}[comp],
            }
        elif kind == "distance":
            q = f"How close is the camera to the {d} at {_t(t)}s?"
            op = {"operator": "distance_to_camera"}
        else:
            q = f"What is the minimum distance between the {d}?"
            op = {"operator": "box_distance"}
        if reasons:
            verdict = "excluded"
        elif v == "mismatch":
            verdict = "corrected"
        else:  # legacy value right under its own box convention only: the contract changes
            verdict = "re-contracted" if evidence.get("legacy_box") else "retained"
        times = [t] if t_end is None else [t, t_end]
        contract = {"entity": entity, "times": times, "unit": unit, "frame": "object_box", **op}
        prompt = f"Object description: {desc}." if kind != "min_distance" else f"Objects: {desc}."
        return Draft(
            question=q,
            prompt=prompt,
            time_start=t,
            time_end=t if t_end is None else t_end,
            detail=format_scalar(legacy * scale, unit),
            cand_kind="scalar",
            cand_args={"value": legacy * scale, "unit": unit, "scenario": scen},
            contract=contract,
            true_value=value,
            true_answer=None if value is None else format_scalar(value * scale, unit),
            legacy_value=legacy,
            defects=defects,
            verdict=verdict,
            reasons=reasons,
            evidence=evidence,
        )

    def _dim_normal(self, slot: Slot, s, rng: np.random.Generator, kind: str, comp: str):
        """A normal Dimensional row: (value, legacy value, description, entity, t, t_end, kind, component).

        Length and width are asked only of objects whose box-local x edge is clearly the longer
        horizontal edge, so "length = box x" and "length = longer side" give the same answer.
        ScanNet: the value is the tight upright box's, the legacy value the annotation-frame
        axis-aligned box's (length / width = extents along ann x / y); they are equal (to float
        noise) for objects along the room axes and at least 3 cm apart otherwise (a turned object
        whose two values come closer is asked its height, or at another frame); box distances are
        asked between objects along the room axes only.
        """

        def fits(size) -> bool:
            return kind != "dimension" or comp == "height" or size[0] >= 1.05 * size[1]

        if slot.source == "ScanNet":
            if kind == "min_distance":
                uniq = [i for i in _sn_unique(s) if not i.turned]
                a, b = (uniq[i] for i in rng.choice(len(uniq), size=2, replace=False))
                f = _sn_visible_frame(s, a, rng)
                desc = f"{_strip_article(a.description)} and the {_strip_article(b.description)}"
                ent = {"kind": "object_pair", "ids": [a.object_id, b.object_id], "labels": [a.label, b.label]}
                d = s.box_distance(a, b)
                return d, d, desc, ent, f / s.fps, None, kind, comp
            pool = [i for i in _sn_unique(s) if fits(i.size)]
            if not pool:
                comp, pool = "height", _sn_unique(s)
            inst = _choose(rng, pool)
            ci = ("length", "width", "height").index(comp)
            if kind == "dimension":
                f = _sn_visible_frame(s, inst, rng)
                value, legacy = float(inst.box_lwh[ci]), float(inst.size[ci])
                if 1e-6 < abs(value - legacy) < 0.03:
                    comp, value, legacy = "height", float(inst.box_lwh[2]), float(inst.size[2])
            else:
                idx = s.instances.index(inst)
                fr = _sn_frames(s)
                ok = [int(k) for k in fr[s.visible()[idx, fr]]
                      if not (1e-6 < abs(s.distance_to_camera(inst, k) - s.legacy_distance_to_camera(inst, k)) < 0.03)]
                if not ok:
                    raise NoCandidate("no frame separates the two box conventions")
                f = int(_choose(rng, ok))
                value, legacy = s.distance_to_camera(inst, f), s.legacy_distance_to_camera(inst, f)
            ent = {"kind": "object", "id": inst.object_id, "label": inst.label}
            return value, legacy, inst.description, ent, f / s.fps, None, kind, comp
        if slot.source == "Waymo":
            # the referent is the only object of its type in view at the asked frame: a dimension
            # row asks at t rounded to 0.1 s, which must fall on the same frame
            vis = s.visible(slot.camera)
            opts = self.cached(
                ("wm-unique-loose", s.name, slot.camera),
                lambda: _wm_unique_visible(s, slot.camera, loose=True),
            )
            if kind == "dimension":
                opts = [(i, k) for i, k in opts if s.frame_of(round(float(s.t[k]), 1)) == k]
            if not opts:
                raise NoCandidate("no object is the only one of its type in this camera's view")
            i, k = _choose(rng, opts)
            o = s.objects[i]
            if not fits(o.size):
                comp = "height"
            ci = ("length", "width", "height").index(comp)
            ent = {"kind": "object", "id": o.oid, "label": o.kind, "type": o.type}
            if kind == "dimension":
                ks = np.flatnonzero(vis[i])
                run = ks[(ks >= k) & (ks <= k + 40)]
                t0, t1 = round(float(s.t[k]), 1), round(float(s.t[run[-1]]), 1)
                return float(o.size[ci]), float(o.size[ci]), o.description, ent, t0, t1, kind, comp
            d = s.distance_to_camera(o, k, slot.camera)
            return (
                d,
                d,
                o.description,
                ent,
                float(s.t[k]),
                None,
                kind,
                comp,
            )
        objs = [o for o in s.objects if "group" not in OMNI_CLASSES[o.class_name]]
        pool = [o for o in objs if fits(o.side)]
        if not pool:
            comp, pool = "height", objs
        o = _choose(rng, pool)
        idx = s.objects.index(o)
        fr = np.arange(0, s.n_frames, 3)
        k = int(_choose(rng, list(fr[s.visible()[idx, fr]])))
        ci = ("length", "width", "height").index(comp)
        ent = {"kind": "object", "id": o.oid, "label": o.class_name}
        if kind == "dimension":
            return float(o.side[ci]), float(o.side[ci]), o.description, ent, 0.0, None, kind, comp
        d = s.distance_to_camera(o, k)
        return d, d, o.description, ent, k / s.fps, None, kind, comp

    # ---------------------------------------------------------------------- spatial relation
    def relation(self, slot: Slot, rng: np.random.Generator) -> Draft:
        """Spatial Relation: Waymo camera mount; ROPE object pairs at t = 0 (or a tied pair)."""
        s = self.seq(slot)
        reasons: list[str] = []
        defects: list[str] = []
        evidence: dict = {}
        if slot.source == "Waymo":
            label = CAMERA_RELATION[slot.camera]
            return Draft(
                question="What is the orientation of the camera mounted on the moving car relative to the "
                "car's forward direction?",
                prompt="",
                time_start=0.0,
                time_end=s.video_end,
                detail=label,
                cand_kind="label",
                cand_args={"value": label, "labels": ["Front", "Front-Left", "Front-Right", "Left", "Right"]},
                contract={
                    "entity": {"kind": "camera", "camera": slot.camera},
                    "times": [0.0, s.video_end],
                    "operator": "camera_mount_relation",
                    "unit": None,
                    "frame": "vehicle",
                },
                true_value=label,
                true_answer=label,
                legacy_value=label,
                defects=[],
                verdict="retained",
            )
        ids = [o.mask_id for o in s.objects if "group" not in OMNI_CLASSES[o.class_name]]
        vis0 = {o.mask_id: bool(s.visible()[i, 0]) for i, o in enumerate(s.objects)}
        if slot.variant == "no_dominant":
            a, b = s.tied_pair
            truth, ev = s.relation(a, b)
            if truth is not None:
                raise NoCandidate("tied pair resolves")
            legacy = (
                ("Right" if ev["dx"] > 0 else "Left")
                if rng.random() < 0.5
                else ("Farther" if ev["dz"] > 0 else "Closer")
            )
            reasons.append("no_dominant_relation")
            evidence = ev
        else:
            clear = []
            for a in ids:
                for b in ids:
                    if a == b or not (vis0[a] and vis0[b]):
                        continue
                    rel, ev = s.relation(a, b)
                    if rel is None:
                        continue
                    lat, dep = abs(ev["dx"]), abs(ev["dz"])
                    if rel == "Directly above" or max(lat, dep) >= 2.5 * min(lat, dep):
                        clear.append((a, b, rel))
            if not clear:
                a, b = s.clear_pair
                clear = [(a, b, s.relation(a, b)[0])]
            above = [c for c in clear if c[2] == "Directly above"]
            a, b, truth = _choose(rng, above) if above and rng.random() < 0.3 else _choose(rng, clear)
            legacy = truth
        A, B = s.obj(a), s.obj(b)
        q = (
            f"What is the position of the {_strip_article(A.description)} relative to the "
            f"{_strip_article(B.description)} at t=0 s?"
        )
        return Draft(
            question=q,
            prompt="",
            time_start=0.0,
            time_end=0.0,
            detail=legacy,
            cand_kind="label",
            cand_args={"value": legacy, "labels": ["Left", "Right", "Closer", "Farther", "Directly above"]},
            contract={
                "entity": {
                    "kind": "object_pair",
                    "ids": [A.oid, B.oid],
                    "labels": [A.class_name, B.class_name],
                },
                "times": [0.0],
                "operator": "spatial_relation",
                "unit": None,
                "frame": "opencv_camera",
                "rule": "Directly above if A stands on B; else the larger of |x| (Left/Right) and |z| "
                "(Closer/Farther) camera-frame offsets when it is >= 1.5x the other",
            },
            true_value=None if reasons else truth,
            true_answer=None if reasons else truth,
            legacy_value=legacy,
            defects=defects,
            verdict="excluded" if reasons else "retained",
            reasons=reasons,
            evidence=evidence,
        )


# ================================================================================ candidates


def _scalar_text(v: float, unit: str) -> str:
    return format_scalar(v, unit)


def _scalar_candidates(rng: np.random.Generator, v: float, unit: str, scen: str) -> tuple[list[str], str]:
    """The legacy answer plus four distractors at log-sampled gaps scaled by scenario and value, and
    how their sides were chosen: ``balanced`` (two below and two above the answer where the value
    leaves room, :data:`BALANCED_SHARE` of the rows) or ``random`` (a side at random per distractor)."""
    floor = max(_FLOOR.get((scen, unit), 0.05), 0.01)
    balanced = bool(rng.random() < BALANCED_SHARE)
    out = [_scalar_text(v, unit)]
    vals = [float(out[0][: -len(unit)])]
    tries = 0
    while len(out) < 5:
        boost = 1.5 ** (tries // 40)
        g = boost * max(
            floor * math.exp(rng.uniform(0, math.log(6))),
            abs(v) * math.exp(rng.uniform(math.log(0.06), math.log(0.5))),
        )
        below = len(out) % 2 == 1 if balanced else rng.random() < 0.5  # balanced: below, above, below, above
        d = v - g if (below and v - g >= 0) else v + g
        txt = _scalar_text(d, unit)
        x = float(txt[: -len(unit)])
        if all(abs(x - y) >= 0.01 - 1e-9 for y in vals):
            out.append(txt)
            vals.append(x)
        tries += 1
    return out, "balanced" if balanced else "random"


def _angle_candidates(rng: np.random.Generator, v: float, kind: str) -> list[str]:
    if kind == "angle_grid":
        return [format_angle(v)] + [format_angle(v + d) for d in (-15.0, -7.5, 7.5, 15.0)]
    gaps = np.cumsum(rng.uniform(2.0, 12.0, size=4))
    return [format_angle(v)] + [format_angle(v + g) for g in gaps]


def _perturb_rotation(rng: np.random.Generator, R: np.ndarray, lo: float, hi: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    ang = math.radians(rng.uniform(lo, hi)) * rng.choice([-1, 1])
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    dR = np.eye(3) + math.sin(ang) * K + (1 - math.cos(ang)) * K @ K
    return dR @ R


def _pose_candidates(
    rng: np.random.Generator, T: np.ndarray, compact: bool, source: str, same_rotation: bool
) -> list[str]:
    lo, hi = _POSE_GAP[source]
    out = [format_pose(T, compact=compact)]
    while len(out) < 5:
        D = T.copy()
        D[:3, 3] = T[:3, 3] + rng.normal(size=3) / math.sqrt(3) * math.exp(
            rng.uniform(math.log(lo), math.log(hi))
        )
        if source == "Waymo":
            D[2, 3] = T[2, 3] + rng.uniform(-0.3, 0.3)
        if not same_rotation:
            if source == "Waymo":
                D[:3, :3] = rot_z(math.radians(rng.uniform(3, 25) * rng.choice([-1, 1]))) @ T[:3, :3]
            else:
                D[:3, :3] = _perturb_rotation(rng, T[:3, :3], 8.0, 30.0)
        txt = format_pose(D, compact=compact)
        if txt not in out:
            out.append(txt)
    return out


def _box_candidates(rng: np.random.Generator, legacy: dict, scen: str) -> list[str]:
    lo, hi = _CENTER_GAP[scen]
    c = np.array(legacy["C_central_point"], float)
    lwh = np.array(legacy["C_lwh"], float)
    h = float(legacy["C_heading"])
    out = [format_legacy_box(c, lwh, h)]
    while len(out) < 5:
        dc = rng.normal(size=3) / math.sqrt(3) * math.exp(rng.uniform(math.log(lo), math.log(hi)))
        txt = format_legacy_box(
            c + dc, lwh * rng.uniform(0.8, 1.25, size=3), wrap_deg(h + rng.uniform(-40, 40))
        )
        if txt not in out:
            out.append(txt)
    return out


def _label_candidates(rng: np.random.Generator, value: str, labels: list[str]) -> list[str]:
    others = [x for x in labels if x != value]
    rng.shuffle(others)
    return [value] + others[:4]


def _trajectory_candidates(rng: np.random.Generator, segments: list) -> list[str]:
    legacy = format_trajectory(segments, move_decimals=0)
    total = sum(v for k, v in segments if k == "move")
    pool = []
    for f in (rng.uniform(0.45, 0.75), rng.uniform(1.25, 1.7)):
        pool.append([(k, max(10.0, 10 * round(v * f / 10)) if k == "move" else v) for k, v in segments])
    if any(k == "turn" for k, _ in segments):
        pool.append([(k, -v if k == "turn" else v) for k, v in segments])
        pool.append([("move", 10 * round(total / 10))])
    else:
        half = 10 * round(total / 20)
        pool.append(
            [("move", half), ("turn", float(rng.choice([-90, -45, 45, 90]))), ("move", max(10.0, half))]
        )
        pool.append([("move", 10 * round(total * rng.uniform(0.3, 0.6) / 10) or 10.0)])
    pool.append([])
    out = [legacy]
    for segs in pool:
        txt = format_trajectory(segs, move_decimals=0)
        if txt not in out:
            out.append(txt)
    k = 2
    while len(out) < 5:
        txt = format_trajectory([("move", 10.0 * (round(total / 10) + 3 * k))], move_decimals=0)
        if txt not in out:
            out.append(txt)
        k += 1
    return out[:1] + list(rng.permutation(out[1:]))[:4]


#: How the legacy distractors of each kind were placed (the manifest's ``legacy_options.construction``).
CONSTRUCTIONS = {
    "balanced": "scalar: two distractors below and two above the answer (the median candidate is the answer)",
    "random": "scalar: each distractor below or above the answer at random",
    "angle_grid": "angle: distractors at -15, -7.5, +7.5 and +15 degrees around the answer (the median is the answer)",
    "angle_smallest": "angle: distractors at cumulative gaps above the answer (the smallest candidate is the answer)",
    "pose": "pose: translations perturbed, rotations perturbed or the answer's",
    "box": "box: centre, edges and heading perturbed",
    "label": "label: four other labels of the task",
    "trajectory": "trajectory: distances scaled, turns flipped or dropped",
}


def make_candidates(rng: np.random.Generator, d: Draft) -> tuple[list[str], str]:
    """Five candidate strings, the legacy answer first (letters are assigned later), and how the
    distractors were placed (a key of :data:`CONSTRUCTIONS`)."""
    a = d.cand_args
    if d.cand_kind == "scalar":
        return _scalar_candidates(rng, a["value"], a["unit"], a["scenario"])
    if d.cand_kind in ("angle_grid", "angle_smallest"):
        return _angle_candidates(rng, a["value"], d.cand_kind), d.cand_kind
    if d.cand_kind == "pose":
        return _pose_candidates(rng, a["T"], a["compact"], a["source"], a["same_rotation"]), "pose"
    if d.cand_kind == "box":
        return _box_candidates(rng, a["legacy"], a["scenario"]), "box"
    if d.cand_kind == "label":
        return _label_candidates(rng, a["value"], a["labels"]), "label"
    return _trajectory_candidates(rng, a["segments"]), "trajectory"


def _answer_rank(texts: list[str], ans_pos: int, unit: str | None) -> int | None:
    """Rank (1 = smallest value) of the legacy answer among the five candidates as written (SI values, so
    ``45cm`` and ``0.45m`` compare); None for candidates that are not scalars."""
    if unit is None:
        return None
    from ..values import Scalar, parse

    vals = [parse(t) for t in texts]
    if not all(isinstance(x, Scalar) for x in vals):
        return None
    si = [x.si for x in vals]
    return 1 + sum(x < si[ans_pos] - 1e-12 for x in si)


def _numeric_alt(text: str, unit: str) -> str:
    """Another spelling of the same scalar value: ``0.45m`` -> ``45cm``, ``0.10m`` -> ``0.1m``,
    ``1.23m/s`` -> ``1.230m/s``."""
    num = text[: len(text) - len(unit)]
    if unit == "m" and abs(float(num)) < 10 and not num.endswith("0") and len(num.split(".")[1]) == 2:
        return f"{round(float(num) * 100):d}cm"
    if num.endswith("0"):
        return f"{float(num):.1f}{unit}"
    return f"{float(num):.3f}{unit}"


def _coarse(text: str, unit: str) -> str:
    """A coarser rounding of a scalar answer (``8.03°`` -> ``8°``)."""
    num = float(text[: len(text) - len(unit)])
    return f"{num:.0f}{unit}" if abs(num) >= 5 else f"{num:.1f}{unit}"


# ============================================================================= row assembly


def assign_variants(
    slots: list[Slot], seed: int, can_host: Callable[[Slot, str], bool] | None = None
) -> None:
    """Exact-count variant assignment per (task, source) group by a seeded permutation.

    Each variant takes the next slots of the permutation that can host it (``can_host``, e.g. a
    Waymo object subject needs a mover in the video's camera); slots passed over stay for the
    following variants. A group with fewer hosts than the count carries fewer rows of the variant.
    """
    groups: dict[tuple[str, str], list[Slot]] = {}
    for sl in slots:
        groups.setdefault((sl.task, sl.source), []).append(sl)
    for (task, source), group in sorted(groups.items()):
        rng = rng_for(seed, f"variants|{task}|{source}")
        free = [int(i) for i in rng.permutation(len(group))]
        for variant, frac, at_least_one in VARIANTS.get((task, source), []):
            n = int(round(frac * len(group)))
            if at_least_one and len(group) >= 4:
                n = max(n, 1)
            hosts = [i for i in free if can_host is None or can_host(group[i], variant)][:n]
            for i in hosts:
                group[i].variant = variant
            taken = set(hosts)
            free = [i for i in free if i not in taken]
        if task == "3D Video Grounding":
            order2 = rng.permutation(len(group))
            for i in order2[: int(round(GROUNDING_NAMED * len(group)))]:
                group[i].named = True


def _answer_flags(slots: list[Slot], seed: int) -> tuple[set[int], set[int], set[int]]:
    n = len(slots)
    rng = rng_for(seed, "answer-layer")
    mismatch = {int(i) for i in rng.permutation(n)[: int(round(KEY_MISMATCH_RATE * n))]}
    exact_ok = [i for i, s in enumerate(slots) if s.task in _DUP_EXACT_TASKS]
    num_ok = [i for i, s in enumerate(slots) if s.task in _SCALAR_TASKS]
    n_exact = max(int(round(DUP_EXACT_RATE * n)), 2 if n >= 100 else 1)
    n_num = max(int(round(DUP_NUMERIC_RATE * n)), 2 if n >= 100 else 1)
    exact = {int(exact_ok[i]) for i in rng.permutation(len(exact_ok))[:n_exact]}
    num_pool = [i for i in num_ok if i not in exact]
    numeric = {int(num_pool[i]) for i in rng.permutation(len(num_pool))[:n_num]}
    return mismatch, exact, numeric


def _values_differ(a: str, b: str, unit: str | None, tol: float = 0.015) -> bool:
    """True when two answer strings differ: scalars by at least ``tol``, others as text."""
    if unit is None:
        return a != b
    return abs(float(a[: len(a) - len(unit)]) - float(b[: len(b) - len(unit)])) >= tol


_DEFECT_ORDER = {code: i for i, code in enumerate(DEFECTS)}


def build_rows(world: World, slots: list[Slot], seed: int) -> tuple[list[dict], list[dict]]:
    """Legacy rows (qa.parquet columns) and manifest records, in the same order."""
    builder = Builder(world, seed)
    assign_variants(slots, seed, builder.can_host)
    mismatch, dup_exact, dup_numeric = _answer_flags(slots, seed)
    rows, manifest = [], []
    premised: list[tuple[int, Slot, Draft]] = []
    for i, sl in enumerate(slots):
        d = builder.build(sl)
        rng = rng_for(seed, f"answer|{sl.key}")
        cands, construction = make_candidates(rng, d)
        unit = (
            d.cand_args.get("unit")
            if d.cand_kind == "scalar"
            else ("°" if d.cand_kind.startswith("angle") else None)
        )
        defects = list(d.defects)
        positions = list(rng.permutation(5))  # positions[j] = letter index of candidate j
        texts = [""] * 5
        for j, p in enumerate(positions):
            texts[p] = cands[j]
        ans_pos = positions[0]
        key_pos = ans_pos
        distractor_pos = [p for p in positions[1:]]
        if i in mismatch:
            opts = [p for p in distractor_pos if _values_differ(texts[p], d.detail, unit)]
            if opts:
                key_pos = int(opts[int(rng.integers(0, len(opts)))])
                defects.append("key_detail_mismatch")
                if unit is not None and d.cand_kind == "scalar" and rng.random() < 0.3:
                    coarse = _coarse(texts[ans_pos], unit)
                    half = 0.5 if "." not in coarse else 0.05
                    if all(_values_differ(coarse, texts[p], unit, 2 * half) for p in distractor_pos):
                        texts[ans_pos] = coarse
        free = [p for p in distractor_pos if p != key_pos]
        if i in dup_exact and len(free) >= 2:
            a, b = (int(x) for x in rng.choice(free, size=2, replace=False))
            texts[b] = texts[a]
            defects.append("duplicate_options_exact")
        elif i in dup_numeric and len(free) >= 2 and unit is not None:
            a, b = (int(x) for x in rng.choice(free, size=2, replace=False))
            texts[b] = _numeric_alt(texts[a], unit)
            defects.append("duplicate_options_numeric")
        defects = sorted(set(defects), key=lambda c: _DEFECT_ORDER[c])
        for c in defects:
            assert c in DEFECTS, c
        for r in d.reasons:
            assert r in REASONS, r
        cand = {LETTERS[p]: texts[p] for p in range(5)}
        rows.append(
            {
                "Video": sl.video,
                "Source": sl.source,
                "Task": sl.task,
                "QType": "Single Choice",
                "Question": d.question,
                "Prompt": d.prompt,
                "time_start": float(d.time_start),
                "time_end": float(d.time_end),
                "Candidates": json.dumps(cand, ensure_ascii=False),
                "Answer": LETTERS[key_pos],
                "Answer Detail": d.detail,
                "ID": int(sl.id),
                "scene": SCENE_OF_SOURCE[sl.source],
            }
        )
        rec = {
            "row": i,
            "video": sl.video,
            "id": int(sl.id),
            "task": sl.task,
            "source": sl.source,
            "sequence": sl.sequence,
            "camera": sl.camera,
            "contract": _r(d.contract),
            "true_value": _r(d.true_value),
            "true_answer": d.true_answer,
            "legacy_value": _r(d.legacy_value),
            "defects": defects,
            "expected_verdict": d.verdict,
            "expected_reasons": list(d.reasons),
        }
        if d.evidence:
            rec["evidence"] = _r(d.evidence)
        rec["legacy_options"] = {"construction": construction, "answer_rank": _answer_rank(texts, int(ans_pos), unit)}
        manifest.append(rec)
        if d.premise is not None and not d.reasons:
            premised.append((i, sl, d))
    for i in _premise_reveals(premised):
        manifest[i]["defects"] = sorted({*manifest[i]["defects"], "premise_reveals_answer"},
                                        key=lambda c: _DEFECT_ORDER[c])
    return rows, manifest


def _premise_reveals(premised: list[tuple[int, Slot, Draft]]) -> list[int]:
    """Rows (of released Pose rows with a printed premise) whose premise is printed at a time another
    of them asks as its target in the same recording (the segment a reader sees in the video name: a
    converse pair, or another camera of the segment), or prints as the answer of another of them in
    the same video."""
    from ..options.observables import sequence_of

    recordings: dict[str, list] = {}
    for item in premised:
        recordings.setdefault(sequence_of(item[1].video, item[1].source)[0], []).append(item)
    out = []
    for rec in recordings.values():
        for i, sl, d in rec:
            t0 = d.contract["premise_time"]
            if any(j != i and (dj.contract["times"][0] == t0 or (sj.video == sl.video and dj.true_answer == d.premise))
                   for j, sj, dj in rec):
                out.append(i)
    return sorted(out)


__all__ = ["TASK_ORDER", "TASK_SOURCES", "Draft", "Slot", "World", "assign_variants", "build_rows"]
