"""What a blind reader knows about a row besides its options: the question's observables.

Read from one ReSTI-schema row (question text, times, video name, task, source), never from the
video or the sources. The option stage conditions the distractors on these (a displacement over
0.1 s is drawn from the answers' implied rates, a pose near the premise like the answers are, a box
of a truck like the boxes of trucks); the attack suite reads the same things.

``Observables`` fields:

* ``quantity`` — what is measured, as the row's task reads its question: ``displacement``,
  ``path_length``, ``speed``, ``acceleration``, ``length``, ``width``, ``height``,
  ``distance_to_camera``, ``surface_distance``, ``distance``,
  ``heading_change``, ``box``, ``pose``, ``trajectory``, ``relation``;
* ``window_s`` — the question's time window (end minus start, or target minus premise time), or None;
* ``subject`` / ``subject_class`` — the noun phrase of the measured thing and its head noun
  (``camera`` for the camera);
* ``premise`` — the 4x4 premise pose of a Pose question (identity when the question takes the
  reference camera as the identity), ``premise_text`` its printed JSON, ``premise_time``;
* ``sequence`` / ``camera`` — from the video name (the source recording; Waymo camera number).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from .. import values as V
from ..errors import InputError

_TIME = r"t\s*=\s*(-?\d+(?:\.\d+)?)\s*s"
_CUT_WORDS = ("with", "near", "beside", "besides", "next", "by", "on", "in", "under", "underneath",
              "against", "along", "behind", "between", "from", "at", "above", "below", "over", "inside",
              "outside", "across", "around", "wearing", "carrying", "holding", "pulling", "pushing",
              "filled", "covered", "parked", "sitting", "standing", "placed", "leaning", "full", "facing",
              "mounted", "hanging", "located", "that", "which", "where", "whose", "of", "to")
_CUT_RE = re.compile(r"\b(" + "|".join(_CUT_WORDS) + r")\b|[,;(]", re.IGNORECASE)
_WAYMO_VIDEO = re.compile(r"^(?P<seq>.+)_camera_(?P<cam>\d+|[A-Za-z_]+)$")


@dataclass(frozen=True)
class Observables:
    task: str
    source: str
    video: str
    sequence: str
    camera: str | None
    quantity: str
    time_start: float | None
    time_end: float | None
    window_s: float | None
    subject: str
    subject_class: str
    premise: np.ndarray | None = field(default=None, compare=False)
    premise_text: str | None = None
    premise_time: float | None = None
    reference: str | None = None  # what a relation is relative to ("relative to the X, is the Y")

    @property
    def is_camera(self) -> bool:
        """The question asks about the camera (not an object it sees)."""
        return self.subject_class == "camera"

    def to_dict(self) -> dict:
        return {"quantity": self.quantity, "window_s": self.window_s, "subject": self.subject,
                "subject_class": self.subject_class, "sequence": self.sequence, "camera": self.camera,
                "premise_time": self.premise_time, "premise": self.premise_text}


def _num(x) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def sequence_of(video: str, source: str) -> tuple[str, str | None]:
    """Source sequence and camera from a video name (``<segment>_camera_<n>.mp4``, ``sceneXXXX_YY``, ``000123``)."""
    stem = re.sub(r"\.[A-Za-z0-9]+$", "", str(video or ""))
    m = _WAYMO_VIDEO.match(stem)
    if m and source == "Waymo":
        return m["seq"], m["cam"]
    return stem, None


def head_noun(phrase: str) -> str:
    """The head noun of a description: the last word before the first relational word or comma
    (``"white utility truck with a bucket lift"`` -> ``truck``)."""
    t = " ".join(str(phrase or "").lower().split())
    t = re.sub(r"^(the|a|an)\s+", "", t)
    m = _CUT_RE.search(t)
    head = t[:m.start()] if m and m.start() > 0 else t
    words = re.findall(r"[a-z][a-z\-]*", head)
    return words[-1] if words else ""


_ART = r"(?:the |a |an )?"
_SUBJECT_PATTERNS = (
    re.compile(r"bounding box of " + _ART + r"(?P<s>.+?) in (?:the |an |a )?(?:\w+ )*?(?:OpenCV|camera) ", re.I),
    re.compile(r"nearest point of the bounding box of " + _ART + r"(?P<s>.+?)\?", re.I),
    re.compile(r"\b(?:length|width|height)\b(?: \([^)]*\))? of " + _ART + r"(?P<s>.+?)\?", re.I),
    re.compile(r"\bbetween (?:the bounding boxes of )?" + _ART + r"(?!t\s*=)(?P<s>.+?) and ", re.I),
    re.compile(r"\bof " + _ART + r"(?P<s>.+?) \(its 3D box", re.I),
    re.compile(r"\bof " + _ART + r"(?P<s>.+?) (?:between|at) t\s*=", re.I),
)


_QUANTITY_PREFIX = re.compile(r"^(?:.*?\b(?:acceleration|velocity|speed|displacement|distance|length)\b"
                              r"(?: \([^)]*\))? of " + _ART + r")+", re.I)


def subject_of(question: str) -> str:
    q = " ".join(str(question or "").split())
    if re.search(r"\bcamera'?s?\b.{0,40}\b(between|at t|trajectory|movement|velocity|displacement|"
                 r"acceleration|heading|pose)", q, re.I) and not re.search(r"bounding box of", q, re.I):
        if not re.search(r"\(its 3D box", q, re.I):
            return "camera"
    for pat in _SUBJECT_PATTERNS:
        m = pat.search(q)
        if m:
            s = _QUANTITY_PREFIX.sub("", m["s"].strip()).strip()
            if s.lower() in ("camera", "the camera"):
                return "camera"
            return s
    return "camera" if "camera" in q.lower() else ""


def premise_of(question: str) -> tuple[np.ndarray | None, str | None, float | None]:
    """The premise pose printed in a Pose question, its text and its time (identity for a question
    that takes the reference camera as the identity)."""
    q = str(question or "")
    m = re.search(r"\{[^{}]*\"tx\"[^{}]*\}", q)
    if m:
        text = m.group(0)
        try:
            p = V.parse(text)
        except InputError:
            return None, None, None
        if not isinstance(p, V.Pose):
            return None, None, None
        before = q[:m.start()]
        times = re.findall(_TIME, before)
        t = float(times[-1]) if times else (0.0 if re.search(r"initial pose", before, re.I) else None)
        return p.matrix, text, t
    m = re.search(r"camera pose at " + _TIME + r" as the identity", q, re.I)
    if m:
        return np.eye(4), None, float(m.group(1))
    return None, None, None


_RELATIVE = re.compile(r"relative to " + _ART + r"(?P<ref>.+?), is " + _ART + r"(?P<s>.+?) to the ", re.I)


def relation_parts(question: str) -> tuple[str, str] | None:
    """``(reference, target)`` of a relation question ("relative to the X, is the Y to the ..."),
    lower case, or None."""
    m = _RELATIVE.search(" ".join(str(question or "").split()))
    return (m["ref"].strip().lower(), m["s"].strip().lower()) if m else None


def observables_of(row: dict, quantity: str) -> Observables:
    """The observables of one ReSTI-schema row (see the module docstring); ``quantity``: what its
    question measures, read by its task (:meth:`resti_lib.options.spec.Interface.quantity_of`)."""
    task = str(row.get("Task") or "")
    source = str(row.get("Source") or "")
    video = str(row.get("Video") or "")
    q = str(row.get("Question") or "")
    t0, t1 = _num(row.get("time_start")), _num(row.get("time_end"))
    seq, cam = sequence_of(video, source)
    premise, premise_text, premise_time = (premise_of(q) if quantity == "pose" else (None, None, None))
    window = None
    if quantity == "pose":
        target = t1
        if premise_time is not None and target is not None:
            window = abs(target - premise_time)
        elif t0 is not None and t1 is not None:
            window = t1 - t0
    elif quantity in ("displacement", "path_length", "speed", "acceleration", "heading_change", "trajectory"):
        if t0 is not None and t1 is not None and t1 > t0:
            window = t1 - t0
        else:  # an instant: the stated averaging window, if any ("over a 1-second window")
            m = re.search(r"(\d+(?:\.\d+)?)-second (?:central )?window", q)
            window = float(m.group(1)) if m else None
    subject = "camera" if quantity in ("heading_change", "pose", "trajectory") else subject_of(q)
    parts = relation_parts(q) if quantity == "relation" else None
    reference = parts[0] if parts else None
    cls = "camera" if subject == "camera" else head_noun(subject)
    return Observables(task=task, source=source, video=video, sequence=seq, camera=cam, quantity=quantity,
                       time_start=t0, time_end=t1, window_s=window, subject=subject, subject_class=cls,
                       premise=premise, premise_text=premise_text, premise_time=premise_time, reference=reference)


__all__ = ["Observables", "observables_of", "head_noun", "subject_of", "premise_of", "relation_parts", "sequence_of"]
