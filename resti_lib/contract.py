"""Question contracts: legacy question text -> ``C = (s, e, t, F, q, u, σ, D)`` plus missing parts.

The parser reads what a question states (target, time, frame, statistic, unit) and records what it
leaves out in ``missing``: ``time`` (no time named although the value depends on one), ``subject``
(two possible subjects), ``frame`` (no coordinate frame / axes / matrix direction), ``statistic``
("average speed" without saying path or displacement), ``unit`` (no unit tag). The task modules
then resolve what the source can resolve and state it in the rewritten question, or exclude.

Times in the text win over the row's ``time_start``/``time_end`` when both exist; the row fields
are the fallback (the legacy evaluator prints them before the question).
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass, field

from .errors import InputError
from .sources.mapping import map_video

NUM = r"[-+]?\d+(?:\.\d+)?"
_T_RANGE = [
    re.compile(rf"from\s+(?:t\s*=\s*)?({NUM})\s*s(?:econds?)?\s+to\s+(?:t\s*=\s*)?({NUM})\s*s", re.I),
    re.compile(rf"between\s+(?:t\s*=\s*|source pose timestamps\s+)?({NUM})\s*(?:s\b|seconds?\b)?\s*and\s+"
               rf"(?:t\s*=\s*)?({NUM})\s*s", re.I),
]
_T_POINT = [
    re.compile(rf"\bat\s+t\s*=\s*({NUM})\s*s\b", re.I),
    re.compile(rf"\bat\s+({NUM})\s*s(?:econds?)?\b", re.I),
    re.compile(r"\bsource frame\s+(\d+)\s*\((\d+(?:\.\d+)?)\s*FPS", re.I),
]
_UNIT_TAG = re.compile(r"\(unit:\s*([^)]+)\)", re.I)
_JSON_OBJ = re.compile(r"\{[^{}]*\}")

CAMERA_WORDS = ("camera", "ego", "our car", "the vehicle we", "recording vehicle")
AMBIGUOUS_SUBJECTS = ("the car", "the vehicle")  # on Waymo: the ego car or another tracked car


@dataclass
class Contract:
    """The measurement contract of one question (see module docstring)."""

    task: str
    source: str
    video: str
    sequence: str | None
    camera: int | None
    operator: str
    entity: dict = field(default_factory=dict)
    times: list = field(default_factory=list)
    time_stated: bool = False
    frame: str | None = None
    unit: str | None = None
    unit_stated: bool = False
    params: dict = field(default_factory=dict)
    missing: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True, default=float)


def find_times(text: str) -> tuple[list[float], bool]:
    """Times named in the text (seconds) and whether any were found."""
    for rx in _T_RANGE:
        m = rx.search(text)
        if m:
            return [float(m.group(1)), float(m.group(2))], True
    for rx in _T_POINT:
        m = rx.search(text)
        if m:
            if rx.pattern.startswith(r"\bsource frame"):
                return [int(m.group(1)) / float(m.group(2))], True
            return [float(m.group(1))], True
    return [], False


def find_unit(text: str) -> str | None:
    m = _UNIT_TAG.search(text)
    return m.group(1).strip() if m else None


def find_pose_json(text: str) -> dict | None:
    """The first pose JSON (``{"tx": ...}``) printed in a question (the premise), if any."""
    for m in _JSON_OBJ.finditer(text):
        try:
            obj = json.loads(m.group(0))
        except json.JSONDecodeError:
            continue
        if isinstance(obj, dict) and "tx" in obj:
            return obj
    return None


def _description(row: dict, question: str) -> str | None:
    """The object description: from the prompt when present, else the noun phrase of the question."""
    prompt = (row.get("Prompt") or "").strip()
    m = re.match(r"^(?:Target object description|Object description|Object|Objects):\s*(.+?)\.?(?:;|$)",
                 prompt, re.I)
    if m:
        return m.group(1).strip().rstrip(".")
    for rx in (r"bounding box of (?:the |a |an )?(.+?)[.?]?$", r"(?:length|width|height) of (?:the |a |an )?(.+?)\?",
               r"close is the camera to (?:the |a |an )?(.+?)(?: at |\?)", r"How far has (?:the |a |an )?(.+?) traveled",
               r"How quickly is (?:the |a |an )?(.+?) accelerating"):
        m = re.search(rx, question, re.I)
        if m:
            return m.group(1).strip()
    return None


def _pair(question: str) -> tuple[str, str] | None:
    for rx in (r"distance between (?:the |a |an )?(.+?) and (?:the |a |an )?(.+?)\?",
               r"position of (?:the |a |an )?(.+?) relative to (?:the |a |an )?(.+?)(?: at |\?)",
               r"relative to (?:the |a |an )?(.+?), is (?:the |a |an )?(.+?) to the"):
        m = re.search(rx, question, re.I)
        if m:
            return m.group(1).strip(), m.group(2).strip()
    return None


def parse_question(row: dict, *, video_map: dict | None = None) -> Contract:
    """Parse one legacy (or ReSTI) row into its contract. Never raises on odd text: what cannot be
    read is reported in ``operator == "unknown"`` or ``missing``."""
    task, source, video = row["Task"], row["Source"], row["Video"]
    q = " ".join(str(row.get("Question") or "").split())
    ql = q.lower()
    try:
        seq = map_video(video, video_map)
        sequence, camera = seq.sequence, seq.camera
    except InputError:
        sequence, camera = None, None
    times, stated = find_times(q)
    t0, t1 = float(row.get("time_start") or 0.0), float(row.get("time_end") or 0.0)
    unit = find_unit(q)
    c = Contract(task=task, source=source, video=video, sequence=sequence, camera=camera,
                 operator="unknown", times=times or [t0, t1], time_stated=stated, unit=unit,
                 unit_stated=unit is not None)

    def miss(part: str):
        if part not in c.missing:
            c.missing.append(part)

    if task == "3D Video Grounding":
        c.operator = "box_in_camera"
        c.entity = {"kind": "object", "description": _description(row, q)}
        c.times = times[:1] if stated else [t0]
        c.frame = "OpenCV camera" if "opencv" in ql else None
        if not stated:
            miss("time")
        if c.frame is None:
            miss("frame")
    elif task == "Ego-Centric Orientation":
        c.operator = "heading_change"
        c.entity = {"kind": "camera"}
        c.times = times if stated and len(times) == 2 else [t0, t1]
        if not ("gravity" in ql or "horizontal plane" in ql or "perpendicular to gravity" in ql):
            miss("frame")
        if not stated:
            miss("time")
    elif task == "Pose Estimation":
        c.operator = "pose"
        c.entity = {"kind": "camera"}
        premise = find_pose_json(q)
        all_t = [float(x) for x in re.findall(rf"t\s*=\s*({NUM})\s*s", q)]
        if len(all_t) >= 2:
            c.params["premise_time"], c.times, c.time_stated = all_t[0], [all_t[-1]], True
        elif len(all_t) == 1:
            c.params["premise_time"] = 0.0 if "initial" in ql else t0
            c.times, c.time_stated = [all_t[0]], True
        else:
            c.params["premise_time"], c.times = (0.0 if "initial" in ql else t0), [t1]
            miss("time")
        if premise is not None:
            c.params["premise_pose"] = premise
        if not any(w in ql for w in ("world coordinate", "coordinate frame", "same coordinate", "opencv")):
            miss("frame")
    elif task in ("Displacement & Path Length", "Speed & Acceleration"):
        if "accelerat" in ql:
            c.operator = "acceleration"
        elif task == "Speed & Acceleration":
            c.operator = "average_speed" if "speed" in ql else "average_velocity"
            if "average speed" in ql and not any(w in ql for w in ("path", "displacement", "endpoint")):
                miss("statistic")
        elif any(w in ql for w in ("total distance", "trajectory length", "path length", "distance traveled")) \
                and "displacement" not in ql:
            c.operator = "path_length"
        elif "how far" in ql:
            c.operator = "displacement"
            miss("statistic")
        else:
            c.operator = "displacement"
        desc = _description(row, q)
        if any(w in ql for w in CAMERA_WORDS):
            c.entity = {"kind": "camera"}
        elif source == "Waymo" and any(ql.startswith(f"how far has {w[4:]}") or f"has {w}" in ql
                                       for w in AMBIGUOUS_SUBJECTS) and desc in ("car", "vehicle"):
            c.entity = {"kind": "ambiguous", "candidates": ["camera", "object"], "description": desc}
            miss("subject")
        else:
            c.entity = {"kind": "object", "description": desc}
        c.times = times if stated and len(times) == 2 else [t0, t1]
        if not stated:
            miss("time")
    elif task == "Trajectory Description":
        c.operator = "trajectory"
        c.entity = {"kind": "camera"}
        c.times = times if stated and len(times) == 2 else [t0, t1]
    elif task == "Dimensional Measurement":
        m = re.search(r"\b(length|width|height)\b", ql)
        pair = _pair(q)
        if pair and "distance" in ql:
            c.operator = "object_distance"
            c.entity = {"kind": "object_pair", "descriptions": list(pair)}
        elif "close is the camera" in ql or "from the camera" in ql or "camera to" in ql:
            c.operator = "distance_to_camera"
            c.entity = {"kind": "object", "description": _description(row, q)}
        elif m:
            c.operator = "dimension"
            c.params["dimension"] = m.group(1)
            c.entity = {"kind": "object", "description": _description(row, q)}
        c.times = times[:1] if stated else [t0]
    elif task == "Spatial Relation":
        pair = _pair(q)
        if "mounted" in ql:
            c.operator = "mounted_relation"
            c.entity = {"kind": "camera"}
        elif pair:
            c.operator = "relative_position"
            c.entity = {"kind": "object_pair", "descriptions": list(pair)}
            c.times = times[:1] if stated else [t0]
    if c.operator in ("displacement", "path_length", "average_velocity", "average_speed", "acceleration",
                      "dimension", "distance_to_camera", "object_distance") and not c.unit_stated:
        miss("unit")
    return c
