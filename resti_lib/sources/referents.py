"""The one referent module: description phrases, source labels, visibility, instances and boxes.

Every task reads an object description the same way (grounding, the scalar tasks, relations).

Phrase reading (:func:`read_phrase`)
    Normalised (lower case, ``_`` and ``-`` read as spaces), the leading article dropped. A
    quantifier of ``group_words`` at the start ("pair of", "set of", "both", ...) makes the phrase
    a *grouped referent* and is dropped. The *head* is the text up to the first cut word (a
    preposition or participle, :data:`CUT_WORDS`, "of" included) or punctuation
    ("White door with two black handles" -> "white door"; "black trash can of the kitchen" ->
    "black trash can"). Motion cues ("parked", "moving") are kept for track matching.

Label matching (:func:`resolve`)
    A source label (or a synonym, :data:`SYNONYMS`) must occur as a word in the head, optionally
    with a plural ``s``/``es``; the head noun is the match that ends last (the longer one on a
    tie: "tv stand" over "stand"). A plural head noun makes the referent a group. ScanNet:
    segGroup labels; Omni6DPose: class names with ``_`` read as a space. Waymo: the box ``type`` is
    all the source knows, so a noun lexicon (:data:`WAYMO_NOUNS`) maps the head noun to a type plus
    a broad size range of that vehicle class (real-world dimensions, metres), and only boxes of that
    type whose size lies in the range match ("A red double-decker bus" needs a box at least 3.8 m
    tall); such a noun is *finer than the label* when it names more than the type.

Question text (:func:`noun_phrase`)
    ``"the <description>"``: the article dropped, the first letter lower-cased unless the
    description opens with an acronym ("A TV stand" -> "the TV stand", "A U-turn sign" -> "the
    U-turn sign").

Visibility (:func:`box_visibility`, parameters :func:`visibility_rule`)
    A frustum test with the camera intrinsics (pinhole, distortion ignored, no occlusion): a
    3x3x3 grid of points spanning the solid box (corners, edge and face midpoints, centre) is
    moved into the OpenCV camera frame; a point is in view when its depth lies in
    ``[near, far]`` and it projects inside the image. The box is visible when its centre is in view
    or at least ``min_fraction`` of the points are (a large object close to the camera overflows the
    image yet is plainly visible); ``min_fraction: 1.0`` is the centre-only test. One parameter
    shape everywhere: ``{near, far, min_fraction}``, each a number or a per-source mapping.

Box geometry
    :func:`point_box_distance` (nearest point of a solid oriented box) and
    :func:`box_box_distance` (minimum Euclidean distance between two solid oriented boxes,
    0 when they touch or overlap, solved exactly as a bounded least-squares problem in the six
    box-local coordinates).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import lsq_linear

from ..defaults import setting
from ..errors import ContractError, InputError
from ..geometry import trajectory as G
from ..geometry.boxes import OrientedBox, upright_oriented_box
from ..geometry.frames import apply_T, invert_T, make_T
from .context import derived

__all__ = [
    "CUT_WORDS",
    "GROUP_WORDS",
    "SYNONYMS",
    "WAYMO_NOUNS",
    "Instance",
    "Phrase",
    "Referent",
    "SceneView",
    "box_box_distance",
    "box_points",
    "box_visibility",
    "match_labels",
    "noun_phrase",
    "omni_boxes_at",
    "omni_instances",
    "point_box_distance",
    "read_phrase",
    "resolve",
    "scannet_camera_at",
    "scannet_instances",
    "visibility_rule",
    "waymo_boxes_at",
    "waymo_camera_at",
    "waymo_noun",
]

# ------------------------------------------------------------------------------------- phrases

#: Words that end the head noun phrase of a description.
CUT_WORDS = ("with", "near", "beside", "besides", "next", "by", "on", "in", "under", "underneath",
             "against", "along", "behind", "between", "from", "at", "above", "below", "over",
             "inside", "outside", "across", "around", "wearing", "carrying", "holding", "pulling",
             "pushing", "filled", "covered", "parked", "sitting", "standing", "placed", "leaning",
             "mounted", "riding", "driving", "walking", "that", "which", "who", "whose", "to", "for", "where",
             "while", "containing", "showing", "featuring", "topped", "stacked", "lying", "hanging", "of",
             "full", "facing", "located")
_CUT_RE = re.compile(r"\b(" + "|".join(CUT_WORDS) + r")\b|[,;(]", re.IGNORECASE)
#: Quantifiers that make a description a group when it opens with one. Number words are not in the
#: default list ("three-seat sofa"); "two chairs" is a group through its plural head noun.
GROUP_WORDS = ("pair of", "set of", "group of", "couple of", "row of", "stack of", "pile of", "both")
_STATIC_RE = re.compile(r"\b(parked|stationary|stopped|standing still|idle)\b", re.IGNORECASE)
_MOVING_RE = re.compile(r"\b(moving|driving|walking|running|riding|turning|crossing|passing|approaching)\b",
                        re.IGNORECASE)
_ARTICLE_RE = re.compile(r"^(?:the|a|an)\s+", re.IGNORECASE)

#: Synonyms mapping description words to ScanNet / Omni6DPose labels (extend with params ``synonyms``).
SYNONYMS = {"couch": "sofa", "fridge": "refrigerator", "television": "tv", "trash bin": "trash can",
            "garbage can": "trash can", "waste bin": "trash can", "bookcase": "bookshelf",
            "night stand": "nightstand", "cupboard": "cabinet", "teddy": "teddy bear",
            "remote": "remote control", "cup": "mug", "sneaker": "shoe", "notebook computer": "laptop"}


def _norm(text: str) -> str:
    return " ".join(str(text).replace("_", " ").replace("-", " ").lower().split())


def noun_phrase(desc: str | None) -> str:
    """``"the <description>"`` for question text: the leading article dropped, the first letter
    lower-cased unless the description opens with an acronym (``"A TV stand"`` -> ``"the TV stand"``,
    ``"A U-turn sign"`` -> ``"the U-turn sign"``)."""
    d = _ARTICLE_RE.sub("", " ".join(str(desc or "object").split()).rstrip("."))
    return "the " + (d[0].lower() + d[1:] if d and not d[:2].isupper() else d)


@dataclass
class Phrase:
    """A description read for matching.

    Attributes
    ----------
    text : the description as given. head : lower-case head noun phrase.
    grouped : the group marker (``"pair of"``, ``"both"``) or None. motion : ``"static"``,
        ``"moving"`` or None (cue words anywhere in the text).
    """

    text: str
    head: str
    grouped: str | None = None
    motion: str | None = None


def read_phrase(text: str | None, group_words=GROUP_WORDS) -> Phrase:
    """Head noun phrase, group marker and motion cue of a description (see module docstring)."""
    t = _ARTICLE_RE.sub("", _norm(text or ""))
    grouped = None
    for g in sorted((_norm(w) for w in group_words), key=len, reverse=True):
        m = re.match(rf"^(?:the\s+)?{re.escape(g)}\b\s*(?:the\s+)?", t)
        if m:
            grouped, t = g, t[m.end():]
            break
    m = _CUT_RE.search(t, 1) if t else None
    head = t[: m.start()].strip() if m else t
    motion = "static" if _STATIC_RE.search(t) else ("moving" if _MOVING_RE.search(t) else None)
    return Phrase(text=str(text or ""), head=head, grouped=grouped, motion=motion)


def match_labels(phrase: Phrase, labels: list[str], synonyms: dict | None = None) -> tuple[str | None, bool, dict]:
    """The source label named by the head noun of ``phrase``.

    Returns ``(label or None, plural, evidence)``. A label matches when it (or a synonym mapping
    to it) occurs as a whole word in the head, optionally with a plural ``s``/``es``; the head noun
    is the match that ends last (the longer one on a tie). ``plural`` is true when the match carries
    the plural ending.
    """
    syn = {**SYNONYMS, **(synonyms or {})}
    known = {_norm(lab): lab for lab in labels}
    words = dict(known)
    for w, target in syn.items():
        if _norm(target) in known:
            words.setdefault(_norm(w), known[_norm(target)])
    best = None
    for w, lab in words.items():
        for m in re.finditer(r"\b" + re.escape(w) + r"(es|s)?\b", phrase.head):
            key = (m.end(), len(w))
            if best is None or key > best[0]:
                plural = m.group(1) is not None and not (w.endswith("s") and m.group(1) == "s")
                best = (key, lab, plural, m.group(0))
    if best is None:
        return None, False, {"head": phrase.head, "matched": None}
    return best[1], best[2], {"head": phrase.head, "matched": best[3]}


# Waymo: head noun -> (box type, {dimension: (lo, hi)} metres); broad real-world class ranges.
_CAR_W = (1.4, 2.3)
WAYMO_NOUNS: dict[str, tuple[str, dict]] = {
    "double decker": ("TYPE_VEHICLE", {"length": (8.0, 16.0), "height": (3.8, 5.0)}),
    "double decker bus": ("TYPE_VEHICLE", {"length": (8.0, 16.0), "height": (3.8, 5.0)}),
    "pickup truck": ("TYPE_VEHICLE", {"length": (4.6, 7.0), "width": (1.7, 2.5), "height": (1.55, 2.3)}),
    "bus": ("TYPE_VEHICLE", {"length": (7.5, 19.0), "width": (2.2, 2.9), "height": (2.5, 4.8)}),
    "pickup": ("TYPE_VEHICLE", {"length": (4.6, 7.0), "width": (1.7, 2.5), "height": (1.55, 2.3)}),
    "truck": ("TYPE_VEHICLE", {"length": (6.0, 18.0), "width": (1.9, 3.0), "height": (2.2, 4.6)}),
    "trailer": ("TYPE_VEHICLE", {"length": (1.5, 18.0)}),
    "minivan": ("TYPE_VEHICLE", {"length": (4.3, 5.6), "width": _CAR_W, "height": (1.55, 2.1)}),
    "van": ("TYPE_VEHICLE", {"length": (4.0, 7.5), "width": (1.6, 2.5), "height": (1.55, 3.0)}),
    "suv": ("TYPE_VEHICLE", {"length": (3.9, 5.8), "width": (1.6, 2.3), "height": (1.45, 2.1)}),
    "sedan": ("TYPE_VEHICLE", {"length": (4.35, 5.5), "width": _CAR_W, "height": (1.15, 1.7)}),
    "coupe": ("TYPE_VEHICLE", {"length": (3.6, 5.2), "width": _CAR_W, "height": (1.05, 1.6)}),
    "hatchback": ("TYPE_VEHICLE", {"length": (3.3, 4.45), "width": (1.5, 2.1), "height": (1.25, 1.85)}),
    "convertible": ("TYPE_VEHICLE", {"length": (3.6, 5.2), "width": _CAR_W, "height": (1.0, 1.6)}),
    "taxi": ("TYPE_VEHICLE", {"length": (3.8, 5.6), "width": _CAR_W}),
    "car": ("TYPE_VEHICLE", {"length": (3.0, 6.0), "width": _CAR_W}),
    "vehicle": ("TYPE_VEHICLE", {}),
    "motorcycle": ("TYPE_VEHICLE", {"length": (1.3, 2.7), "width": (0.4, 1.2)}),
    "scooter": ("TYPE_VEHICLE", {"length": (1.0, 2.3), "width": (0.3, 1.0)}),
    "pedestrian": ("TYPE_PEDESTRIAN", {}), "person": ("TYPE_PEDESTRIAN", {}), "man": ("TYPE_PEDESTRIAN", {}),
    "woman": ("TYPE_PEDESTRIAN", {}), "boy": ("TYPE_PEDESTRIAN", {}), "girl": ("TYPE_PEDESTRIAN", {}),
    "child": ("TYPE_PEDESTRIAN", {}), "kid": ("TYPE_PEDESTRIAN", {}), "worker": ("TYPE_PEDESTRIAN", {}),
    "jogger": ("TYPE_PEDESTRIAN", {}), "people": ("TYPE_PEDESTRIAN", {}),
    "cyclist": ("TYPE_CYCLIST", {}), "bicyclist": ("TYPE_CYCLIST", {}), "bicycle": ("TYPE_CYCLIST", {}),
    "bike": ("TYPE_CYCLIST", {}),
    "sign": ("TYPE_SIGN", {}),
    "jeep": ("TYPE_VEHICLE", {"length": (3.4, 5.2), "width": (1.5, 2.1)}),
    "wagon": ("TYPE_VEHICLE", {"length": (4.0, 5.4), "width": _CAR_W}),
    "limousine": ("TYPE_VEHICLE", {"length": (5.0, 10.0), "width": (1.7, 2.3)}),
    "ambulance": ("TYPE_VEHICLE", {"length": (5.0, 8.5), "width": (1.9, 2.6), "height": (2.2, 3.4)}),
    "walker": ("TYPE_PEDESTRIAN", {}), "biker": ("TYPE_CYCLIST", {}), "rider": ("TYPE_CYCLIST", {}),
    "signpost": ("TYPE_SIGN", {}),
}


GENERIC_NOUNS = ("car", "vehicle")


def waymo_noun(phrase: Phrase) -> tuple[str | None, str | None, dict]:
    """(noun, Waymo box type, size ranges) of a description's head noun, or (None, None, {})."""
    lab, _plural, ev = match_labels(phrase, list(WAYMO_NOUNS))
    if lab is None:
        return None, None, {}
    if lab in GENERIC_NOUNS:
        # "small green hatchback car": a class noun right before the generic one is the class
        words = phrase.head.split()
        n = len(ev["matched"].split())
        for k in (2, 1):
            prev = " ".join(words[-n - k:-n]) if len(words) > n else ""
            if prev in WAYMO_NOUNS and prev not in GENERIC_NOUNS and words[-n:] == ev["matched"].split():
                lab = prev
                break
    typ, rng = WAYMO_NOUNS[lab]
    return lab, typ, dict(rng)


def size_fits(lwh, ranges: dict) -> bool:
    """True when the box's (length, width, height) lies in every given (lo, hi) range."""
    idx = {"length": 0, "width": 1, "height": 2}
    return all(lo <= float(lwh[idx[k]]) <= hi for k, (lo, hi) in ranges.items())


@dataclass
class Referent:
    """What a description names in one source.

    ``label``: the source label (ScanNet / Omni6DPose) or the Waymo noun; ``box_type`` and
    ``size_ranges``: what a Waymo box must be to match; ``grouped``: the group marker (a quantifier
    or ``"plural: <word>"``) or None; ``evidence``: head, matched word, and for Waymo the noun class.
    """

    description: str | None
    phrase: Phrase
    label: str | None
    plural: bool
    evidence: dict
    box_type: str | None = None
    size_ranges: dict = field(default_factory=dict)

    @property
    def head(self) -> str:
        return self.phrase.head

    @property
    def grouped(self) -> str | None:
        """The group marker, or None when the description names one object."""
        if self.phrase.grouped:
            return self.phrase.grouped
        return f"plural: {self.evidence.get('matched')}" if self.plural else None

    def admits(self, label: str, lwh=None) -> bool:
        """Does a source instance (its label; Waymo: type and box size) match the description?"""
        if self.label is None:
            return False
        if self.box_type is not None:
            return label == self.box_type and (lwh is None or size_fits(lwh, self.size_ranges))
        return label == self.label


def resolve(description: str | None, source: str, labels: list[str] | None = None, *, synonyms: dict | None = None,
            group_words=GROUP_WORDS) -> Referent:
    """Read a description against a source's vocabulary (module docstring).

    ``labels``: the sequence's labels (ScanNet, Omni6DPose); Waymo uses :data:`WAYMO_NOUNS`.
    """
    ph = read_phrase(description, group_words)
    if source == "Waymo":
        noun, typ, ranges = waymo_noun(ph)
        _, plural, ev = match_labels(ph, list(WAYMO_NOUNS))
        ev.update({"noun": noun, "box_type": typ, "size_ranges_m": ranges})
        return Referent(description, ph, noun, plural if noun else False, ev, typ, ranges)
    label, plural, ev = match_labels(ph, list(labels or []), synonyms)
    return Referent(description, ph, label, plural, ev)


# ------------------------------------------------------------------------------------ geometry


def point_box_distance(p, center, R, lwh) -> tuple[float, np.ndarray]:
    """Distance from point ``p`` to the solid box (centre, ``R = R_frame_from_box``, edge lengths).

    Returns ``(distance, nearest point of the box)``; the distance is 0 inside the box.
    """
    p, c, R, h = (np.asarray(x, dtype=np.float64) for x in (p, center, R, lwh))
    q = R.T @ (p - c)
    qc = np.clip(q, -h / 2, h / 2)
    nearest = c + R @ qc
    return float(np.linalg.norm(p - nearest)), nearest


def box_box_distance(a: OrientedBox, b: OrientedBox) -> tuple[float, np.ndarray, np.ndarray]:
    """Minimum Euclidean distance between two solid oriented boxes (0 when they touch/overlap).

    A point of box ``a`` is ``c_a + R_a diag(l_a / 2) u`` with ``u`` in ``[-1, 1]^3``; the distance is
    the minimum of ``|c_a + M_a u - c_b - M_b v|`` over ``u, v``: a bounded linear least-squares
    problem, solved with the bounded-variable least-squares method (exact up to round-off).
    Returns ``(distance, nearest point on a, nearest point on b)``.
    """
    Ma = np.asarray(a.R, float) * (np.asarray(a.lwh, float) / 2)[None, :]
    Mb = np.asarray(b.R, float) * (np.asarray(b.lwh, float) / 2)[None, :]
    A = np.hstack([Ma, -Mb])
    rhs = np.asarray(b.center, float) - np.asarray(a.center, float)
    res = lsq_linear(A, rhs, bounds=(-1.0, 1.0), method="bvls", tol=1e-12)
    u, v = res.x[:3], res.x[3:]
    pa = np.asarray(a.center, float) + Ma @ u
    pb = np.asarray(b.center, float) + Mb @ v
    d = float(np.linalg.norm(pa - pb))
    return (0.0 if d < 1e-9 else d), pa, pb


def box_points(box: OrientedBox, n: int = 3) -> np.ndarray:
    """``n^3`` points spanning the solid box (corners included; the centre when ``n`` is odd)."""
    s = np.linspace(-0.5, 0.5, n)
    g = np.array([[x, y, z] for x in s for y in s for z in s]) * np.asarray(box.lwh, float)
    return apply_T(box.T, g)


def box_visibility(box_cam: OrientedBox, intr: dict, *, near: float = 0.1, far: float = np.inf,
                   min_fraction: float = 0.5, n: int = 3) -> dict:
    """Frustum test of a box given in the OpenCV camera frame (see module docstring): visible when the
    centre is in view or at least ``min_fraction`` of the grid points are.

    Returns ``{"visible", "fraction", "n_points", "n_in_view", "centre_in_view", "all_behind",
    "centre_depth_m"}``.
    """
    P = box_points(box_cam, n)
    z = P[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = intr["fx"] * P[:, 0] / z + intr["cx"]
        v = intr["fy"] * P[:, 1] / z + intr["cy"]
    ok = (z >= near) & (z <= far) & (u >= 0) & (u < intr["width"]) & (v >= 0) & (v < intr["height"])
    c = np.asarray(box_cam.center, float)
    cz = c[2]
    cu = intr["fx"] * c[0] / cz + intr["cx"] if cz > 0 else np.nan
    cv = intr["fy"] * c[1] / cz + intr["cy"] if cz > 0 else np.nan
    centre_ok = bool(near <= cz <= far and 0 <= cu < intr["width"] and 0 <= cv < intr["height"])
    frac = float(ok.mean())
    return {"visible": bool(centre_ok or (frac >= min_fraction and ok.any())), "fraction": round(frac, 4),
            "n_points": int(P.shape[0]), "n_in_view": int(ok.sum()), "centre_in_view": centre_ok,
            "all_behind": bool((z < 0).all()), "centre_depth_m": float(cz)}


# ----------------------------------------------------------------------------------- instances


@dataclass
class Instance:
    """A source object as the scalar tasks see it.

    ``box`` is an :class:`OrientedBox` in ``frame`` (ScanNet: raw scan frame; Waymo: segment world
    at the box's frame; Omni6DPose: the OpenCV camera of the asked frame). ``dims`` = (length,
    width, height) under the source's convention (``dims_rule`` states it).
    """

    id: str
    label: str
    box: OrientedBox
    frame: str
    dims: np.ndarray
    dims_rule: str
    extra: dict = field(default_factory=dict)


SCANNET_DIMS = ("extents of the gravity-upright oriented box of the instance's mesh vertices in the "
                "annotation frame: height vertical, length and width the larger and smaller horizontal "
                "extents")
WAYMO_DIMS = "LiDAR box size: length = size.x along the heading, width = size.y across it, height = size.z"
OMNI_DIMS = ("scale x dimensions of the object meta: length, width, height along the object's own "
             "x, y, z box axes")


def scannet_instances(scene) -> list[Instance]:
    """Every annotated instance of a ScanNet scene with its upright box in the raw scan frame."""
    out = []
    for oid, inst in sorted(scene.instances.items()):
        if inst.axis_alignment is not None:
            box = inst.obb_raw
            note = "upright box in the annotation frame, expressed in the raw frame"
        else:
            box = upright_oriented_box(inst.vertices_raw)
            note = "no axisAlignment: upright box of the raw vertices (raw +Z up)"
        extra = {"note": note, "n_vertices": len(inst.vertices_raw), "files": inst.source}
        if inst.axis_alignment is not None:
            extra["aabb_ann_m"] = [float(x) for x in inst.aabb_ann["size"]]
        out.append(Instance(str(oid), inst.label, box, "ScanNet raw scan frame", np.asarray(box.lwh, float),
                            SCANNET_DIMS, extra))
    return out


def scannet_camera_at(scene, t: float, tol: float | None = None) -> tuple[np.ndarray, int, dict]:
    """``T_raw_from_cam`` of the sensor frame at time ``t`` (nearest frame within half a frame).

    Raises ContractError when the frame is absent or its pose is invalid.
    """
    track = scene.camera_track()
    tol = 0.5 / scene.fps if tol is None else tol
    T, ev = G.pose_at(track, float(t), "nearest", tol)
    frame = int(track.meta["frames"][ev["indices"][0]])
    return T, frame, {"frame": frame, "t_frame": float(track.times[ev["indices"][0]]), "fps": scene.fps,
                      "pose_file": track.source}


def waymo_boxes_at(seg, t: float, *, tol: float) -> list[Instance]:
    """LiDAR boxes of the frame nearest ``t`` within ``tol`` seconds (world frame)."""
    out = []
    for b in seg.boxes_at(float(t), tol=tol):
        T = b["T_world_from_box"]
        box = OrientedBox(T[:3, 3].copy(), T[:3, :3].copy(), np.asarray(b["size"], float))
        out.append(Instance(str(b["id"]), b["type"], box, "Waymo segment world frame", box.lwh.copy(),
                            WAYMO_DIMS, {"t": b["t"], "micros": b["micros"]}))
    return out


def waymo_camera_at(seg, camera: int, t: float, *, tol: float) -> tuple[np.ndarray, dict]:
    """``T_world_from_cam`` (OpenCV axes) of a Waymo camera at ``t`` and its pinhole intrinsics."""
    track = seg.camera_track(camera)
    T, ev = G.pose_at(track, float(t), "linear", tol)
    cal = seg.camera_calibration(camera)
    k = cal["intrinsics"]
    intr = {"fx": k["f_u"], "fy": k["f_v"], "cx": k["c_u"], "cy": k["c_v"], "width": cal["width"],
            "height": cal["height"]}
    return T, {"intrinsics": intr, "pose": ev, "track": track.name}


def omni_boxes_at(rope, frame: int) -> list[Instance]:
    """Objects annotated in one ROPE frame, boxes in that frame's OpenCV camera."""
    out = []
    for b in rope.object_boxes(int(frame)):
        box = OrientedBox(np.asarray(b["center"], float), np.asarray(b["R"], float), np.asarray(b["lwh"], float))
        out.append(Instance(str(b["oid"]), str(b["class_name"]), box, f"ROPE camera at frame {int(frame)}",
                            box.lwh.copy(), OMNI_DIMS, {"mask_id": b["mask_id"], "is_valid": b["is_valid"]}))
    return out


def omni_instances(rope) -> dict[str, dict]:
    """Every object annotated anywhere in a ROPE scene: oid -> class, dims, frames listing it (computed
    once per opened scene)."""
    return derived(rope, "omni_instances", lambda: _omni_instances(rope))


def _omni_instances(rope) -> dict[str, dict]:
    inst_meta = rope.object_meta.instance_dict
    out: dict[str, dict] = {}
    for f in rope.frames:
        for o in rope.meta(f).objects:
            oid = o.meta.oid
            d = out.setdefault(oid, {"oid": oid, "class_name": o.meta.class_name, "frames": []})
            d["frames"].append(int(f))
            if "lwh" not in d:
                dims = np.asarray(inst_meta[oid].dimensions, float) if oid in inst_meta else np.full(3, np.nan)
                d["lwh"] = np.asarray(o.meta.scale, float) * dims
    return out


def frame_of_time(t: float, fps: float, frames: list[int], *, tol_frames: float = 0.5) -> int:
    """The annotated frame at time ``t`` (``round(t * fps)``); ContractError when none is near."""
    k = round(float(t) * fps)
    arr = np.asarray(frames)
    j = int(np.argmin(np.abs(arr - k)))
    if abs(arr[j] - t * fps) > tol_frames:
        raise ContractError(f"no annotated frame at t={t} s (nearest frame {int(arr[j])} at {arr[j] / fps:.3f} s)")
    return int(arr[j])


def in_camera(box_world: OrientedBox, T_world_from_cam: np.ndarray) -> OrientedBox:
    """A world box expressed in the camera frame."""
    return box_world.transformed(invert_T(np.asarray(T_world_from_cam, float)))


def box_from(center, R, lwh) -> OrientedBox:
    """An :class:`OrientedBox` from arrays."""
    return OrientedBox(np.asarray(center, float), np.asarray(R, float), np.asarray(lwh, float))


def identity_pose() -> np.ndarray:
    return make_T(np.eye(3))


# ---------------------------------------------------------------------------------- scene view


def visibility_rule(vis: dict | None, source: str) -> tuple[float, float, float]:
    """``(near, far, min_fraction)`` of a source from a ``{near, far, min_fraction}`` mapping whose
    entries are numbers or per-source mappings; missing entries take the operator default
    (``params/measure.yaml``)."""
    base = setting(None, "visibility")
    vis = {**base, **(vis or {})}

    def pick(key):
        v = vis.get(key, base[key])
        return float(v.get(source, base[key][source] if isinstance(base[key], dict) else base[key])
                     if isinstance(v, dict) else v)

    return pick("near"), pick("far"), pick("min_fraction")


@dataclass
class Snapshot:
    """The instances at one time, in one frame, with the camera pose in that frame."""

    t: float
    instances: list
    T_frame_from_cam: np.ndarray
    intrinsics: dict
    frame: str
    evidence: dict


class SceneView:
    """Uniform access to a source sequence for referent resolution.

    Parameters
    ----------
    source : ``ScanNet`` | ``Waymo`` | ``Omni6DPose``
    seq : the opened sequence (``ScanNetScene``, ``WaymoSegment``, ``RopeScene``)
    camera : Waymo camera number (the video's camera)
    vis : ``{"near", "far", "min_fraction"}`` (:func:`visibility_rule`)
    params : the operator settings ``waymo_frame_tol_s`` (a time this close to a Waymo box frame
        reads that frame) and ``time_tol`` (defaults: ``params/measure.yaml``)
    """

    def __init__(self, source: str, seq, camera: int | None = None, *, vis: dict | None = None,
                 synonyms: dict | None = None, params: dict | None = None):
        self.source = source
        self.seq = seq
        self.camera = camera
        self.near, self.far, self.min_fraction = visibility_rule(vis, source)
        self.synonyms = synonyms or {}
        self.frame_tol = float(setting(params, "waymo_frame_tol_s"))
        self.time_tol = float(setting(params, "time_tol"))

    @classmethod
    def open(cls, ctx, video: str, params: dict) -> SceneView:
        vs = ctx.locate(video)
        cam = vs.camera if vs.source == "Waymo" else None
        return cls(vs.source, ctx.sequence(video), cam, vis=params.get("visibility"),
                   synonyms=params.get("synonyms"), params=params)

    @property
    def name(self) -> str:
        return str(getattr(self.seq, "scene", None) or getattr(self.seq, "segment", ""))

    # -- sequence-level instances
    def all_instances(self) -> list[Instance]:
        """Every instance of the sequence (ScanNet instances, Waymo tracks, ROPE objects), computed
        once per opened sequence (:func:`resti_lib.sources.context.derived`), not once per question."""
        return derived(self.seq, "all_instances", self._build_instances)

    def _build_instances(self) -> list[Instance]:
        if self.source == "ScanNet":
            return scannet_instances(self.seq)
        if self.source == "Waymo":
            df = self.seq.lidar_boxes
            out = []
            for oid, g in df.groupby("id", sort=True):
                size = g[["length", "width", "height"]].median().to_numpy(float)
                out.append(Instance(str(oid), str(g["type_name"].iloc[0]), box_from(np.zeros(3), np.eye(3), size),
                                    "Waymo track (median box size)", size, WAYMO_DIMS,
                                    {"t_first": float(g["t"].min()), "t_last": float(g["t"].max()),
                                     "n_frames": len(g)}))
            return out
        out = []
        for oid, d in sorted(omni_instances(self.seq).items()):
            out.append(Instance(str(oid), str(d["class_name"]), box_from(np.zeros(3), np.eye(3), d["lwh"]),
                                "ROPE object (dimensions only)", np.asarray(d["lwh"], float), OMNI_DIMS,
                                {"frames": [d["frames"][0], d["frames"][-1]], "n_frames": len(d["frames"])}))
        return out

    def labels(self) -> list[str]:
        return sorted({i.label for i in self.all_instances()})

    def resolve(self, description: str | None) -> Referent:
        """What a description names in this sequence (:func:`resolve`)."""
        return resolve(description, self.source, None if self.source == "Waymo" else self.labels(),
                       synonyms=self.synonyms)

    def matches(self, ref: Referent, inst: Instance) -> bool:
        return ref.admits(inst.label, inst.dims)

    # -- one time
    def snapshot(self, t: float) -> Snapshot:
        """Instances and camera at time ``t`` (ContractError: no frame / invalid pose there)."""
        if self.source == "ScanNet":
            T, frame, ev = scannet_camera_at(self.seq, t)
            return Snapshot(float(t), self.all_instances(), T, self.seq.intrinsics, "ScanNet raw scan frame",
                            {**ev, "files": [ev["pose_file"], str(self.seq.meta_path)]})
        if self.source == "Waymo":
            # reading lidar_box here lets a damaged file stop the run (InputError), never one question
            near = self.seq.nearest_box_frame(float(t))
            if near is not None and abs(near - float(t)) > self.frame_tol:
                far = InputError(f"no box frame within {self.frame_tol} s of t={float(t)} "
                                 f"(nearest {near:.6f} s)", file=self.seq.path("lidar_box"),
                                 field="key.frame_timestamp_micros")
                raise ContractError(str(far))
            boxes = waymo_boxes_at(self.seq, t, tol=self.frame_tol)
            t_frame = boxes[0].extra["t"] if boxes else float(t)
            T, ev = waymo_camera_at(self.seq, self.camera, t_frame, tol=self.time_tol)
            return Snapshot(float(t), boxes, T, ev["intrinsics"], "Waymo segment world frame",
                            {"t_frame": t_frame, "camera": self.camera, "frame_timestamp_micros":
                             boxes[0].extra["micros"] if boxes else None,
                             "files": [str(self.seq.path("lidar_box")), str(self.seq.path("vehicle_pose")),
                                       str(self.seq.path("camera_calibration"))]})
        frame = frame_of_time(t, self.seq.fps, self.seq.frames)
        return Snapshot(float(t), omni_boxes_at(self.seq, frame), identity_pose(), self.seq.intrinsics(frame),
                        f"ROPE camera at frame {frame}",
                        {"frame": frame, "fps": self.seq.fps, "files": [str(self.seq.meta_path(frame)),
                                                                         str(self.seq.obj_meta_path)]})

    def visibility(self, snap: Snapshot, inst: Instance) -> dict:
        """Frustum test of an instance of the snapshot in the snapshot's camera."""
        return box_visibility(in_camera(inst.box, snap.T_frame_from_cam), snap.intrinsics, near=self.near,
                              far=self.far, min_fraction=self.min_fraction)

    def camera_distance(self, snap: Snapshot, inst: Instance) -> tuple[float, dict]:
        """Distance from the camera centre to the nearest point of the instance's box."""
        c = np.asarray(snap.T_frame_from_cam, float)[:3, 3]
        d, nearest = point_box_distance(c, inst.box.center, inst.box.R, inst.box.lwh)
        return d, {"camera_centre": c.tolist(), "nearest_box_point": nearest.tolist(), "frame": snap.frame}

    def world_box(self, inst_id: str, t: float | None = None) -> Instance:
        """An instance's box in one common frame for pair distances (ScanNet raw, Waymo world at ``t``,
        ROPE first-camera frame via the object's track)."""
        def find(instances):
            hit = next((i for i in instances if i.id == str(inst_id)), None)
            if hit is None:
                raise ContractError(f"{self.source} {self.name}: no object {inst_id!r}"
                                    + (f" at t={t} s" if self.source == "Waymo" else ""))
            return hit

        if self.source == "ScanNet":
            return find(self.all_instances())
        if self.source == "Waymo":
            return find(self.snapshot(t).instances)
        base = find(self.all_instances())
        tr = self.seq.object_track(str(inst_id))
        T = tr.T[0]
        return Instance(base.id, base.label, box_from(T[:3, 3], T[:3, :3], base.dims),
                        "ROPE camera frame at the first frame", base.dims, OMNI_DIMS, {"track": tr.name})
