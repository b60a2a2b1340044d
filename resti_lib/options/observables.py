"""Question observables: what a blind reader learns about a row from everything but the video.

The answer interface is judged against readers that see the question text, the other rows of the same
video and the row's metadata. This module reads, once per row, the observables such a reader has and
that options must be conditioned on (and that attacks exploit):

============== ============================================================================================
field          meaning
============== ============================================================================================
``operator``   question type (:func:`question_type`: ``displacement``,
               ``path_length``, ``average_velocity``, ``acceleration``, ``dimension``, ``pose`` ...)
``qtype``      ``operator`` refined where the operator has variants (``dimension:height``,
               ``average_speed@instant``)
``subject``    ``camera``, ``object``, ``object_pair`` or ``ambiguous``
``noun``       head noun of the subject description, lower case and singular (``sedan``, ``chair``);
               ``camera`` for camera questions; None when the question names no subject
``t0, t1``     the question's time window in seconds (equal for an instant)
``duration``   ``t1 - t0`` (0 for an instant)
``rate_window`` the averaging window stated for an instantaneous rate ("over a 1-second window"), seconds
``premise``    the premise pose printed in a Pose Estimation question (a :class:`resti_lib.values.Pose`;
               the identity when the question declares the premise pose the identity), else None
``sequence``   source sequence of the video (ScanNet scan, Waymo segment, ROPE sequence): the unit of
               grouped cross-validation; the video stem when the name follows no rule
``camera``     Waymo camera number from the video name (1-5), else None
============== ============================================================================================

Times, the object description and object pairs are read with the readers of :mod:`resti_lib.contract`;
the question type with the words the task contracts use (:func:`question_type`), since a release row
carries no contract; the head noun with :func:`resti_lib.referents.read_phrase`; value strings (the
premise pose) are parsed by :mod:`resti_lib.values` only. Nothing here reads the
answer or the candidates, so observables are safe to use when building options.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import values as V
from .. import contract as C
from ..errors import InputError
from ..sources.mapping import map_video

__all__ = [
    "RATE_OPERATORS",
    "Observables",
    "head_noun",
    "implied_rate",
    "observe",
    "observe_all",
    "premise_pose",
    "sequence_of",
]

# Operators whose answer divided by the window is a speed (m/s), and operators whose answer is a rate.
_PER_WINDOW = {"displacement": "speed", "path_length": "speed", "trajectory": "speed", "heading_change": "turn rate"}
RATE_OPERATORS = {"average_velocity": "speed", "average_speed": "speed", "acceleration": "acceleration"}

_PREFIX = re.compile(r"^(?:(?:target\s+)?object\s+description|objects?|target)\s*:\s*", re.IGNORECASE)
_LEAD = re.compile(r"^(?:bounding\s+box(?:es)?\s+of\s+)?(?:the|a|an|two|three|some|several)\s+", re.IGNORECASE)
_RATE_WINDOW = re.compile(r"(\d+(?:\.\d+)?)\s*-?\s*second\s+(?:central\s+)?windows?", re.IGNORECASE)
_JSON_OBJ = re.compile(r"\{[^{}]*\}")
_IDENTITY = re.compile(r"\bas the identity\b", re.IGNORECASE)
# "... of the <subject> between t=..", "... of the <subject> at t=..", "... of the <subject>?"
_OF_SUBJECT = re.compile(r"\b(?:velocity|speed|acceleration|displacement|distance traveled|trajectory|length|width|"
                         r"height|position|box) of (?:the |a |an )?(.+?)(?:\s+between\b|\s+at\b|\s+from\b|\?|,|$)",
                         re.IGNORECASE)


@dataclass(frozen=True)
class Observables:
    """What a blind reader knows about one row (see the module docstring)."""

    task: str
    source: str
    video: str
    sequence: str
    camera: int | None
    operator: str
    qtype: str
    subject: str | None
    noun: str | None
    description: str | None
    t0: float | None
    t1: float | None
    rate_window: float | None
    premise: V.Pose | None
    premise_time: float | None

    @property
    def duration(self) -> float | None:
        """Length of the question's time window in seconds (0 for an instant; None when unknown)."""
        if self.t0 is None or self.t1 is None:
            return None
        return self.t1 - self.t0


def _singular(word: str) -> str:
    w = word.lower()
    if len(w) > 4 and w.endswith("ves") and not w.endswith(("eves", "oves")):
        return w[:-3] + "f"          # shelves -> shelf
    if len(w) > 4 and w.endswith("ies"):
        return w[:-3] + "y"          # batteries -> battery
    if len(w) > 4 and w.endswith(("ches", "shes", "sses", "xes")):
        return w[:-2]                # benches -> bench, boxes -> box
    if len(w) > 3 and w.endswith("s") and not w.endswith(("ss", "us", "is")):
        return w[:-1]                # chairs -> chair
    return w


def head_noun(description: str | None) -> str | None:
    """The head noun of a subject description, lower case and singular.

    ``"A small brown teddy bear wearing a blue shirt"`` -> ``"bear"``; ``"Office chairs in front of a
    bookshelf"`` -> ``"chair"``; ``"Object description: Black Ford pickup truck"`` -> ``"truck"``.
    The head noun phrase is read by :func:`resti_lib.referents.read_phrase` (the one phrase reader:
    it ends at the first cut word or punctuation); its last word is the head.
    """
    from ..referents import read_phrase

    if not description:
        return None
    s = _PREFIX.sub("", " ".join(str(description).split()))
    s = _LEAD.sub("", s)
    words = re.findall(r"[a-z][a-z]*", read_phrase(s).head)
    while len(words) > 1 and words[-1].endswith(("ing", "ed")):  # "trash can overflowing" -> "can"
        words.pop()
    return _singular(words[-1]) if words else None


def premise_pose(question: str, *, row: object = None) -> V.Pose | None:
    """The premise pose printed in a question (the first pose JSON object), parsed by :mod:`values`.

    A question that declares the premise pose the identity ("taking the camera pose at t=0 s as the
    identity") has the identity premise. Returns None when the question states no pose.
    """
    q = str(question or "")
    for m in _JSON_OBJ.finditer(q):
        text = m.group(0)
        if '"tx"' not in text:
            continue
        try:
            v = V.parse(text, row=row, field="Question")
        except InputError:
            continue
        if isinstance(v, V.Pose):
            return v
    if _IDENTITY.search(q):
        return V.parse(V.format_pose(np.eye(4), 2), row=row, field="Question")
    return None


def sequence_of(video: str) -> tuple[str, int | None]:
    """Source sequence and Waymo camera of a video name (rule of :func:`sources.mapping.map_video`);
    a name that follows no rule is its own sequence."""
    try:
        m = map_video(video)
        return m.sequence, m.camera
    except InputError:
        name = Path(str(video)).name
        return (name[:-4] if name.lower().endswith(".mp4") else name), None


def _float(x) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


_CAMERA_WORDS = ("camera", "ego", "our car", "the vehicle we", "recording vehicle")
_PATH_WORDS = ("total distance", "trajectory length", "path length", "distance traveled")
_DESCRIPTION_PATTERNS = (r"bounding box of (?:the |a |an )?(.+?)(?: in (?:the |an )?(?:\w+ )?OpenCV|[.?]?$)",
                         r"(?:length|width|height) of (?:the |a |an )?(.+?)\?",
                         r"close is the camera to (?:the |a |an )?(.+?)(?: at |\?)",
                         r"How far has (?:the |a |an )?(.+?) traveled",
                         r"How quickly is (?:the |a |an )?(.+?) accelerating")


def question_type(row: dict, q: str) -> tuple[str, dict]:
    """``(operator, entity)`` of a question read from its text, the way the task contracts read them
    (:mod:`resti_lib.tasks`): the operator of the task and, for the motion and dimension tasks, the
    variant the words name; the entity ``{"kind": camera | object | object_pair, "description(s)"}``.
    A release row carries no contract, so a blind reader (and the attack suite) reads it from here."""
    task, ql = row.get("Task"), q.lower()
    camera = {"kind": "camera"}

    def obj():
        d = C.description(row, q, _DESCRIPTION_PATTERNS)
        if d is None:
            m = _OF_SUBJECT.search(q)
            d = m.group(1).strip() if m else None
        return {"kind": "object", "description": d}

    if task == "3D Video Grounding":
        return "box_in_camera", obj()
    if task == "Ego-Centric Orientation":
        return "heading_change", camera
    if task == "Pose Estimation":
        return "pose", camera
    if task == "Trajectory Description":
        return "trajectory", camera
    if task in ("Displacement & Path Length", "Speed & Acceleration"):
        if "accelerat" in ql:
            op = "acceleration"
        elif task == "Speed & Acceleration":
            op = "average_speed" if "speed" in ql else "average_velocity"
        else:
            op = "path_length" if any(w in ql for w in _PATH_WORDS) and "displacement" not in ql else "displacement"
        return op, (camera if any(w in ql for w in _CAMERA_WORDS) else obj())
    if task == "Dimensional Measurement":
        pair = C.object_pair(q)
        if pair and "distance" in ql:
            return "object_distance", {"kind": "object_pair", "descriptions": list(pair)}
        if "close is the camera" in ql or "from the camera" in ql or "camera to" in ql:
            return "distance_to_camera", obj()
        m = re.search(r"\b(length|width|height)\b", ql)
        return (f"dimension:{m.group(1)}", obj()) if m else ("unknown", obj())
    if task == "Spatial Relation":
        if "mounted" in ql:
            return "mounted_relation", camera
        pair = C.object_pair(q)
        if pair:
            return "relative_position", {"kind": "object_pair", "descriptions": list(pair)}
    return "unknown", {}


def observe(row: dict) -> Observables:
    """The observables of one ReSTI (or legacy) row. Never raises on odd question text: what cannot be
    read is None."""
    q = C.question_text(row)
    video = str(row.get("Video") or "")
    sequence, camera = sequence_of(video)
    task, source = row.get("Task"), row.get("Source")
    operator, entity = question_type(row, q)
    qtype = operator
    operator = operator.split(":", 1)[0]
    times = [t for t in (_float(t) for t in C.find_times(q)[0]) if t is not None]
    if not times:
        times = [t for t in (_float(row.get("time_start")), _float(row.get("time_end"))) if t is not None]
    premise = premise_pose(q, row=row.get("ReSTI ID")) if task == "Pose Estimation" else None
    premise_time = None
    if task == "Pose Estimation":
        stamps = [float(x) for x in re.findall(rf"t\s*=\s*({C.NUM})\s*s", q)]
        if len(stamps) >= 2 or (len(stamps) == 1 and premise is not None and "initial" not in q.lower()
                                and "identity" not in q.lower()):
            premise_time, times = stamps[0], stamps[-1:]
        elif len(stamps) == 1:
            premise_time, times = 0.0, stamps
    elif task in ("3D Video Grounding", "Dimensional Measurement", "Spatial Relation") and len(times) > 1 \
            and C.find_times(q)[1]:
        times = times[:1]
    t0, t1 = (times[0], times[-1]) if times else (None, None)
    m = _RATE_WINDOW.search(q)
    rate_window = float(m.group(1)) if m else None
    if operator in RATE_OPERATORS and t0 is not None and t0 == t1:
        qtype = f"{operator}@instant"
    subject = entity.get("kind")
    descriptions = [entity["description"]] if entity.get("description") else list(entity.get("descriptions") or [])
    if subject == "camera":
        noun, description = "camera", None
    else:
        description = descriptions[-1] if descriptions else None
        noun = head_noun(description)
    return Observables(task=task, source=source, video=video, sequence=sequence, camera=camera, operator=operator,
                       qtype=qtype, subject=subject, noun=noun, description=description, t0=t0, t1=t1,
                       rate_window=rate_window, premise=premise,
                       premise_time=premise_time if premise is not None else None)


def observe_all(records: list[dict]) -> list[Observables]:
    """:func:`observe` for every row, in order."""
    return [observe(r) for r in records]


def implied_rate(value, obs: Observables) -> tuple[str, float] | None:
    """The rate a value implies over the question's window: ``(kind, rate)``.

    Displacements, path lengths and trajectories imply a speed (distance / duration, m/s), a heading
    change a turn rate (|degrees| / duration); speeds and accelerations are rates themselves (SI
    magnitude). None when the value has no rate (another operator, an instant window for a distance,
    an unparsed value).
    """
    if isinstance(value, V.Trajectory):
        x = value.total_distance
    elif isinstance(value, V.Scalar):
        x = abs(value.si)
    else:
        return None
    if obs.operator in RATE_OPERATORS:
        return RATE_OPERATORS[obs.operator], x
    kind = _PER_WINDOW.get(obs.operator)
    d = obs.duration
    if kind is None or d is None or d <= 0:
        return None
    return kind, x / d
