"""Question contracts ``C = (s, e, t, F, q, u, σ, D)`` and the readers every task builds on.

A contract says what a question measures: source sequence ``s``, entity ``e``, times ``t``, frame
``F``, operator ``q``, unit ``u``, answer format ``σ`` (:attr:`Contract.format`) and distractor
policy ``D`` (:attr:`Contract.distractors`). Each task reads its own contract from a legacy row
(``Task.read_contract`` in :mod:`resti_lib.tasks`) with the readers here: times named in the text
(:func:`find_times`), the unit tag (:func:`find_unit`), a printed pose (:func:`find_pose_json`), the
object description (:func:`description`), an object pair (:func:`object_pair`), and σ and D of the
legacy row (:func:`legacy_format`, :func:`legacy_distractors`). What the question leaves out is
listed in ``missing``: ``time`` (no time named although the value depends on one), ``subject``
(two possible subjects), ``frame`` (no coordinate frame / axes / matrix direction), ``statistic``
(a rate or distance without saying path or displacement), ``unit`` (no unit tag). The task then
resolves what the source can resolve and states it in the rewritten question, or excludes.

Times in the text win over the row's ``time_start``/``time_end`` when both exist; the row fields
are the fallback (the legacy evaluator prints them before the question).
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field

from . import values as V
from .adjudicate import answer_layer_defects
from .errors import InputError
from .sources.mapping import map_video

NUM = r"[-+]?\d+(?:\.\d+)?"
_T_RANGE = [
    re.compile(rf"from\s+(?:t\s*=\s*)?({NUM})\s*s(?:econds?)?\s+to\s+(?:t\s*=\s*)?({NUM})\s*s", re.IGNORECASE),
    re.compile(rf"between\s+(?:t\s*=\s*|source pose timestamps\s+)?({NUM})\s*(?:s\b|seconds?\b)?\s*and\s+"
               rf"(?:t\s*=\s*)?({NUM})\s*s", re.IGNORECASE),
]
_T_POINT = [
    re.compile(rf"\bat\s+t\s*=\s*({NUM})\s*s\b", re.IGNORECASE),
    re.compile(rf"\bat\s+({NUM})\s*s(?:econds?)?\b", re.IGNORECASE),
    re.compile(r"\bsource frame\s+(\d+)\s*\((\d+(?:\.\d+)?)\s*FPS", re.IGNORECASE),
]
_UNIT_TAG = re.compile(r"\(unit:\s*([^)]+)\)", re.IGNORECASE)
_JSON_OBJ = re.compile(r"\{[^{}]*\}")
_PROMPT_OBJECT = re.compile(r"^(?:Target object description|Object description|Object|Objects):\s*(.+?)\.?(?:;|$)",
                            re.IGNORECASE)
_PAIR = (r"distance between (?:the |a |an )?(.+?) and (?:the |a |an )?(.+?)\?",
         r"position of (?:the |a |an )?(.+?) relative to (?:the |a |an )?(.+?)(?: at |\?)",
         r"relative to (?:the |a |an )?(.+?), is (?:the |a |an )?(.+?) to the")

#: Question-layer defect code of each missing contract part (the parts a task reports).
MISSING_DEFECTS = {"time": None, "subject": "ambiguous_subject", "frame": None, "statistic": None,
                   "unit": "unit_tag_missing"}


@dataclass
class Contract:
    """The measurement contract of one question (see module docstring).

    ``format`` (σ): how the answer is printed -- ``{"kind", "unit", "decimals", ...}``.
    ``distractors`` (D): how the four wrong options are made -- ``{"policy", ...}``; for a legacy
    row what its candidates show, for a repaired row the option stage's policy and rule.
    ``legacy``: on a repaired contract, what the legacy row stated (its ``missing`` parts, σ and D).
    """

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
    format: dict = field(default_factory=dict)
    distractors: dict = field(default_factory=dict)
    legacy: dict = field(default_factory=dict)

    def miss(self, part: str) -> None:
        """Record a part the question leaves out (once)."""
        if part not in self.missing:
            self.missing.append(part)

    def to_dict(self) -> dict:
        return asdict(self)


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


def question_text(row: dict) -> str:
    """The row's question with whitespace runs collapsed."""
    return " ".join(str(row.get("Question") or "").split())


def description(row: dict, question: str, patterns: Iterable[str] = ()) -> str | None:
    """The object description: from the prompt when present, else the first group of the first
    task pattern (regular expressions) that matches the question."""
    m = _PROMPT_OBJECT.match((row.get("Prompt") or "").strip())
    if m:
        return m.group(1).strip().rstrip(".")
    for rx in patterns:
        m = re.search(rx, question, re.IGNORECASE)
        if m:
            return m.group(1).strip()
    return None


def object_pair(question: str) -> tuple[str, str] | None:
    """The two descriptions of a pair question ("distance between A and B", "A relative to B")."""
    for rx in _PAIR:
        m = re.search(rx, question, re.IGNORECASE)
        if m:
            return m.group(1).strip(), m.group(2).strip()
    return None


def legacy_format(row: dict) -> dict:
    """σ of a legacy row, read from its Answer Detail: the value kind, unit and printed decimals."""
    try:
        v = V.parse(row.get("Answer Detail"))
    except InputError as e:
        return {"kind": None, "readable": False, "problem": e.message}
    out: dict = {"kind": v.kind}
    if isinstance(v, V.Scalar):
        out.update({"kind": "angle" if v.is_angle else "scalar", "unit": v.unit, "decimals": v.decimals})
    elif isinstance(v, (V.Pose, V.Box)):
        out["decimals"] = v.decimals
        if isinstance(v, V.Box):
            out["rotation"] = "matrix" if v.R is not None else ("heading" if v.heading is not None else "none")
    elif isinstance(v, V.Trajectory):
        out["move_decimals"] = max((d for (k, _), d in zip(v.segments, v.segment_decimals) if k == "move"),
                                   default=None)
    return out


def legacy_distractors(row: dict) -> dict:
    """D of a legacy row, read from its candidates: how many, whether the key points at the
    detail, the offsets of scalar and angle candidates from the detail, and the row's answer-layer
    findings (the checks of :mod:`resti_lib.adjudicate`, codes of :mod:`resti_lib.defects`)."""
    cands = row.get("Candidates") if isinstance(row.get("Candidates"), dict) else {}
    out: dict = {"policy": "as printed in the legacy row", "n_candidates": len(cands),
                 "key_is_detail": cands.get(row.get("Answer")) == row.get("Answer Detail"),
                 "findings": sorted(answer_layer_defects(row)[0])}
    try:
        d = V.parse(row.get("Answer Detail"))
        vals = {k: V.parse(v) for k, v in cands.items()}
    except InputError:
        return out
    if isinstance(d, V.Scalar) and all(isinstance(v, V.Scalar) and v.dimension == d.dimension for v in vals.values()):
        off = [v.si - d.si for v in vals.values()]
        if d.is_angle:
            off = [float(V.wrap_degrees(x)) for x in off]
        out["offsets_from_detail"] = sorted(round(float(x), 6) for x in off)
    return out


def base_contract(row: dict, operator: str = "unknown", *, video_map: dict | None = None) -> tuple[Contract, str]:
    """The parts every task reads the same way: source, sequence, camera, the times named in the
    text (else the row's ``time_start``/``time_end``), the unit tag, σ and D. Returns the contract
    and the whitespace-normalised question."""
    q = question_text(row)
    try:
        seq = map_video(row["Video"], video_map)
        sequence, camera = seq.sequence, seq.camera
    except InputError:
        sequence, camera = None, None
    times, stated = find_times(q)
    t0, t1 = float(row.get("time_start") or 0.0), float(row.get("time_end") or 0.0)
    unit = find_unit(q)
    c = Contract(task=row["Task"], source=row["Source"], video=row["Video"], sequence=sequence, camera=camera,
                 operator=operator, times=times or [t0, t1], time_stated=stated, unit=unit,
                 unit_stated=unit is not None, format=legacy_format(row),
                 distractors=legacy_distractors(row))
    return c, q


def interval(c: Contract, row: dict) -> list[float]:
    """``[t0, t1]``: the two times of the text, else the row's ``time_start``/``time_end``."""
    if c.time_stated and len(c.times) == 2:
        return list(c.times)
    return [float(row.get("time_start") or 0.0), float(row.get("time_end") or 0.0)]


def instant(c: Contract, row: dict) -> list[float]:
    """``[t]``: the first time of the text, else the row's ``time_start``."""
    return list(c.times[:1]) if c.time_stated else [float(row.get("time_start") or 0.0)]
