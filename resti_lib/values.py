"""The one place that parses and formats answer strings.

Every answer encoding of the legacy benchmark and of ReSTI v5 parses into one typed value:

========== ============================================ ==========================================
kind       example text                                 parsed
========== ============================================ ==========================================
scalar     ``0.45m``, ``104.89cm``, ``15.97m/s``,       :class:`Scalar` (value in the stated unit,
           ``0.10m/s²``                                 ``si`` in m, m/s, m/s²)
angle      ``9.53°``, ``-162.97°``                      :class:`Scalar` with unit ``°``
pose       ``{"tx": .., "ty": .., "tz": .., "r11": ..}`` :class:`Pose` (translation + 3x3 rotation)
box        ``{"C_central_point": [..], "C_lwh": [..],   :class:`Box` (centre, lwh, rotation or
           "C_heading": .., "C_rotation_camera_from_box"}``  None, heading)
trajectory ``move forward 212.5m, then turn right 50°``  :class:`Trajectory` (segments)
label      ``Front-Left``, ``Closer``                   :class:`Label`
========== ============================================ ==========================================

Formatting functions (``format_*``) write the ReSTI v5 encodings; ``parse(format_x(v))`` round-trips.
Parsing never guesses: an unreadable string raises :class:`~resti_lib.errors.InputError` naming the
row and field when the caller passes them.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from functools import lru_cache
from typing import Union

import numpy as np

from .errors import InputError

# unit text -> (canonical unit, factor to SI, dimension)
_UNITS: dict[str, tuple[str, float, str]] = {
    "m": ("m", 1.0, "length"),
    "meter": ("m", 1.0, "length"),
    "meters": ("m", 1.0, "length"),
    "metre": ("m", 1.0, "length"),
    "metres": ("m", 1.0, "length"),
    "cm": ("cm", 0.01, "length"),
    "mm": ("mm", 0.001, "length"),
    "km": ("km", 1000.0, "length"),
    "m/s": ("m/s", 1.0, "speed"),
    "km/h": ("km/h", 1 / 3.6, "speed"),
    "m/s²": ("m/s²", 1.0, "acceleration"),
    "m/s^2": ("m/s²", 1.0, "acceleration"),
    "m/s2": ("m/s²", 1.0, "acceleration"),
    "°": ("°", 1.0, "angle"),
    "deg": ("°", 1.0, "angle"),
    "degree": ("°", 1.0, "angle"),
    "degrees": ("°", 1.0, "angle"),
    "s": ("s", 1.0, "time"),
    "": ("", 1.0, "number"),
}



def canonical_unit(unit: str) -> str | None:
    """The canonical spelling of a unit text (``"deg"`` -> ``"°"``, ``"m/s^2"`` -> ``"m/s²"``), or None."""
    u = str(unit).strip()
    hit = _UNITS.get(u, _UNITS.get(u.lower()))
    return hit[0] if hit else None


def si_factor(unit: str) -> float:
    """SI value of one ``unit`` (``cm`` -> 0.01); the one unit table of the package."""
    u = canonical_unit(unit)
    if u is None:
        raise InputError(f"unknown unit {unit!r}", field="unit")
    return _UNITS[u][1]


def unit_dimension(unit: str) -> str:
    """``length``, ``speed``, ``acceleration``, ``angle``, ``time`` or ``number``."""
    u = canonical_unit(unit)
    if u is None:
        raise InputError(f"unknown unit {unit!r}", field="unit")
    return _UNITS[u][2]


_NUM = r"[-+]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+]?\d+)?|[-+]?(?:nan|inf|infinity)"
_SCALAR_RE = re.compile(
    rf"^\s*(?P<num>{_NUM})\s*(?P<unit>m/s²|m/s\^2|m/s2|m/s|km/h|cm|mm|km|m|meters?|metres?|°|"
    r"degrees?|deg|s)?\s*$",
    re.IGNORECASE,
)
_MOVE_RE = re.compile(rf"^move forward\s+(?P<num>{_NUM})\s*m$", re.IGNORECASE)
_TURN_RE = re.compile(rf"^turn (?P<dir>left|right)\s+(?P<num>{_NUM})\s*°$", re.IGNORECASE)
NO_MOVEMENT = "no significant movement"

RELATION_LABELS = ("Front", "Front-Left", "Front-Right", "Left", "Right", "Back",
                   "Closer", "Farther", "Directly above")

POSE_KEYS = ("tx", "ty", "tz", "r11", "r12", "r13", "r21", "r22", "r23", "r31", "r32", "r33")


def _decimals(num_text: str) -> int:
    t = num_text.lower().split("e")[0]
    return len(t.split(".", 1)[1]) if "." in t else 0


@dataclass(frozen=True)
class Scalar:
    """A number with a unit. ``value`` is in ``unit``; ``si`` in the SI unit of its dimension."""

    value: float
    unit: str
    text: str
    decimals: int
    kind: str = "scalar"

    @property
    def dimension(self) -> str:
        return _UNITS[self.unit][2]

    @property
    def si(self) -> float:
        return self.value * _UNITS[self.unit][1]

    @property
    def si_per_unit(self) -> float:
        """SI value of one ``unit`` (``0.01`` for cm), also when ``value`` is zero."""
        return _UNITS[self.unit][1]

    @property
    def is_angle(self) -> bool:
        return self.unit == "°"

    def vector(self) -> np.ndarray:
        return np.array([self.si], dtype=float)

    def finite(self) -> bool:
        return math.isfinite(self.value)

    def key(self) -> tuple:
        return ("scalar", self.dimension, round(self.si, 9))


@dataclass(frozen=True)
class Pose:
    """A rigid pose: translation ``t`` (3,) and rotation ``R`` (3, 3); ``compact`` JSON or spaced."""

    t: tuple
    R: tuple
    text: str
    decimals: int
    compact: bool = False
    kind: str = "pose"

    @property
    def matrix(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = np.array(self.R, dtype=float)
        T[:3, 3] = np.array(self.t, dtype=float)
        return T

    def vector(self) -> np.ndarray:
        return np.concatenate([np.array(self.t, float), np.array(self.R, float).ravel()])

    def finite(self) -> bool:
        return bool(np.all(np.isfinite(self.vector())))

    def key(self) -> tuple:
        return ("pose",) + tuple(round(float(x), 9) for x in self.vector())


@dataclass(frozen=True)
class Box:
    """An oriented box: centre (3,), box-local edge lengths ``lwh`` (3,), rotation (3, 3) or None."""

    center: tuple
    lwh: tuple
    R: tuple | None
    heading: float | None
    text: str
    decimals: int
    kind: str = "box"

    def vector(self) -> np.ndarray:
        parts = [np.array(self.center, float), np.array(self.lwh, float)]
        if self.R is not None:
            parts.append(np.array(self.R, float).ravel())
        if self.heading is not None:
            parts.append(np.array([self.heading], float))
        return np.concatenate(parts)

    def finite(self) -> bool:
        return bool(np.all(np.isfinite(self.vector())))

    def key(self) -> tuple:
        return ("box",) + tuple(round(float(x), 9) for x in self.vector())


@dataclass(frozen=True)
class Trajectory:
    """A trajectory phrase: segments ``("move", metres)`` or ``("turn", signed degrees, left > 0)``."""

    segments: tuple
    text: str
    kind: str = "trajectory"

    def vector(self) -> np.ndarray:
        return np.array([v for _, v in self.segments], dtype=float)

    def finite(self) -> bool:
        return bool(np.all(np.isfinite(self.vector()))) if self.segments else True

    @property
    def total_distance(self) -> float:
        return float(sum(v for k, v in self.segments if k == "move"))

    @property
    def structure(self) -> tuple:
        """The segment pattern without magnitudes, e.g. ``("move", "turn-", "move")``."""
        out = []
        for k, v in self.segments:
            out.append(k if k == "move" else ("turn+" if v > 0 else "turn-"))
        return tuple(out)

    @property
    def segment_decimals(self) -> tuple:
        """Printed decimals of each segment's magnitude in ``text`` (0 where the text does not print it)."""
        parts = [p.strip() for p in re.split(r",\s*then\s+", " ".join(self.text.strip().split()))]
        if len(parts) != len(self.segments):
            return (0,) * len(self.segments)
        out = []
        for p in parts:
            m = _MOVE_RE.match(p) or _TURN_RE.match(p)
            out.append(_decimals(m["num"]) if m else 0)
        return tuple(out)

    def key(self) -> tuple:
        return ("trajectory",) + tuple((k, round(v, 9)) for k, v in self.segments)


@dataclass(frozen=True)
class Label:
    """A categorical answer (relation labels and any other non-numeric text)."""

    text: str
    kind: str = "label"

    def vector(self) -> np.ndarray:
        return np.zeros(0)

    def finite(self) -> bool:
        return True

    def key(self) -> tuple:
        return ("label", " ".join(self.text.lower().split()))


Value = Union[Scalar, Pose, Box, Trajectory, Label]


def _err(msg: str, where: dict) -> InputError:
    return InputError(msg, file=where.get("file"), row=where.get("row"), field=where.get("field"))


def _parse_json(text: str, where: dict) -> Value:
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as e:
        raise _err(f"malformed JSON value ({e.msg} at char {e.pos}): {text[:80]!r}", where) from None
    except RecursionError:
        raise _err(f"JSON value nested too deeply: {text[:40]!r}...", where) from None
    except ValueError as e:  # e.g. an integer literal longer than Python converts
        raise _err(f"malformed JSON value ({e}): {text[:40]!r}", where) from None
    if not isinstance(obj, dict):
        raise _err(f"JSON value is not an object: {text[:80]!r}", where)
    dec = max((_decimals(m) for m in re.findall(r"-?\d+\.\d+", text)), default=0)
    if "tx" in obj or "r11" in obj:
        missing = [k for k in POSE_KEYS if k not in obj]
        if missing:
            raise _err(f"pose JSON lacks keys {missing}", where)
        try:
            vals = [float(obj[k]) for k in POSE_KEYS]
        except (TypeError, ValueError, OverflowError):
            raise _err("pose JSON has a non-numeric entry", where) from None
        R = (tuple(vals[3:6]), tuple(vals[6:9]), tuple(vals[9:12]))
        return Pose(t=tuple(vals[:3]), R=R, text=text, decimals=dec, compact='", "' not in text
                    and '": ' not in text)
    if "C_central_point" in obj:
        try:
            c = tuple(float(x) for x in obj["C_central_point"])
            lwh = tuple(float(x) for x in obj["C_lwh"])
            R = obj.get("C_rotation_camera_from_box")
            R = tuple(tuple(float(x) for x in r) for r in R) if R is not None else None
            h = obj.get("C_heading")
            h = float(h) if h is not None else None
        except (KeyError, TypeError, ValueError, OverflowError) as e:
            raise _err(f"grounding JSON malformed ({e!r})", where) from None
        if len(c) != 3 or len(lwh) != 3 or (R is not None and (len(R) != 3 or any(len(r) != 3 for r in R))):
            raise _err("grounding JSON has wrong shapes (centre 3, lwh 3, rotation 3x3)", where)
        return Box(center=c, lwh=lwh, R=R, heading=h, text=text, decimals=dec)
    raise _err(f"JSON value is neither a pose nor a box: keys {sorted(obj)[:6]}", where)


def _parse_trajectory(text: str) -> Trajectory | None:
    s = " ".join(text.strip().split())
    if s.lower() == NO_MOVEMENT:
        return Trajectory(segments=(), text=text)
    parts = [p.strip() for p in re.split(r",\s*then\s+", s)]
    segs = []
    for p in parts:
        m = _MOVE_RE.match(p)
        if m:
            segs.append(("move", float(m["num"])))
            continue
        m = _TURN_RE.match(p)
        if m:
            v = float(m["num"])
            segs.append(("turn", v if m["dir"].lower() == "left" else -v))
            continue
        return None
    return Trajectory(segments=tuple(segs), text=text)


def parse(text: object, *, file=None, row=None, field=None) -> Value:
    """Parse one answer string into a typed value.

    Parameters
    ----------
    text:
        The candidate or Answer Detail string.
    file, row, field:
        Where the string came from; named in the error if it cannot be parsed.
    """
    if isinstance(text, str):  # values are immutable: a string read before is not parsed again
        try:
            return _parse_text(text)
        except InputError:
            pass  # parsed again below, for an error that names where the string came from
    return _parse(text, {"file": file, "row": row, "field": field})


@lru_cache(maxsize=1 << 16)
def _parse_text(text: str) -> Value:
    return _parse(text, {"file": None, "row": None, "field": None})


def _parse(text: object, where: dict) -> Value:
    if text is None or (isinstance(text, float) and math.isnan(text)):
        raise _err("value is missing (null)", where)
    if not isinstance(text, str):
        if isinstance(text, (int, float)) and not isinstance(text, bool):
            try:
                return Scalar(value=float(text), unit="", text=str(text), decimals=_decimals(str(text)))
            except (OverflowError, ValueError):
                raise _err(f"number {str(text)[:40]} is out of range", where) from None
        raise _err(f"value is a {type(text).__name__}, expected a string", where)
    s = text.strip()
    if not s:
        raise _err("value is an empty string", where)
    if s.startswith("{"):
        return _parse_json(s, where)
    m = _SCALAR_RE.match(s)
    if m:
        unit_txt = (m["unit"] or "")
        unit = _UNITS[unit_txt if unit_txt in _UNITS else unit_txt.lower()][0]
        return Scalar(value=float(m["num"]), unit=unit, text=text, decimals=_decimals(m["num"]))
    if s.lower().startswith(("move", "turn", "no significant")):
        traj = _parse_trajectory(s)
        if traj is not None:
            return traj
        raise _err(f"unreadable trajectory phrase: {s[:80]!r}", where)
    if re.search(r"\d", s):
        raise _err(f"unreadable value: {s[:80]!r}", where)
    return Label(text=s)


def same_value(a: Value, b: Value) -> bool:
    """True when two parsed values encode the same value (after unit normalisation)."""
    return a.key() == b.key()


def agree(a: Value, b: Value, *, rel: float = 0.0, abs_tol: float | None = None) -> bool:
    """Key–detail agreement: same kind and equal within the coarser of the two roundings.

    Two numeric values agree when they differ by at most half a unit in the last place of the
    coarser text (plus ``abs_tol``), so ``8.03°`` and ``8°`` agree but ``8.03°`` and ``0°`` do not.
    Structured values agree field by field under the same rule; labels and trajectory phrases by
    normalised text (trajectory magnitudes under the rounding rule).
    """
    if a.kind != b.kind:
        return False
    if isinstance(a, Label):
        return a.key() == b.key()
    if isinstance(a, Scalar):
        if a.dimension != b.dimension:
            return False
        ulp = 0.5 * max(10.0 ** -a.decimals * _UNITS[a.unit][1], 10.0 ** -b.decimals * _UNITS[b.unit][1])
        tol = ulp + (abs_tol or 0.0) + rel * max(abs(a.si), abs(b.si))
        return abs(a.si - b.si) <= tol + 1e-12
    if isinstance(a, Trajectory):
        if a.structure != b.structure:
            return False
        return bool(np.all(np.abs(a.vector() - b.vector()) <= 0.5 + (abs_tol or 0.0)))
    va, vb = a.vector(), b.vector()
    if va.shape != vb.shape:
        return False
    ulp = 0.5 * 10.0 ** -min(a.decimals, b.decimals)
    return bool(np.all(np.abs(va - vb) <= ulp + (abs_tol or 0.0) + 1e-12))


# ---------------------------------------------------------------- formatting (ReSTI v5 encodings)

def _r(x: float, d: int, signed_zero: bool = True) -> float:
    v = round(float(x), d)
    return v if signed_zero else v + 0.0  # ``-0.0 + 0.0`` is ``0.0``: a zero printed without its sign


def prints_negative_zero(values) -> bool:
    """Whether any of the printed ``values`` is a negative zero (``-0.0``): a printer that keeps the sign of
    a value that rounds to zero. A release whose answers never show one prints its zeros unsigned, and a
    distractor that printed ``-0.0`` there would be told from the answers by that sign alone."""
    x = np.asarray(values, dtype=float).ravel()
    return bool(np.any((x == 0) & np.signbit(x)))


def format_seconds(t: float) -> str:
    """A time in question text: the shortest exact decimal of ``t`` rounded to 1 µs (``0``, ``16``,
    ``19.7``, ``19.800018``); never ``-0``."""
    s = f"{round(float(t), 6):.6f}".rstrip("0").rstrip(".")
    return "0" if s in ("", "-0") else s


def adaptive_decimals(value: float, decimals: int = 2, *, min_ulps: float = 20.0, max_decimals: int = 6) -> int:
    """Decimals needed so a positive ``value`` spans at least ``min_ulps`` printed units
    (``adaptive_decimals(0.063) == 3``: 0.063 m is 63 units of 0.001)."""
    if value <= 0 or not math.isfinite(value):
        return decimals
    need = math.ceil(math.log10(min_ulps * 10.0 ** -decimals / value)) if value < min_ulps * 10.0 ** -decimals else 0
    return min(max_decimals, decimals + max(0, need))


def format_scalar(value: float, unit: str, decimals: int = 2) -> str:
    """``format_scalar(0.4512, "m") == "0.45m"``; units glued on as in the benchmark."""
    if unit not in _UNITS:
        raise ValueError(f"unknown unit {unit!r}")
    return f"{value:.{decimals}f}{_UNITS[unit][0]}"


def wrap_degrees(deg: float | np.ndarray) -> float | np.ndarray:
    """Wrap to [-180, 180)."""
    return (np.asarray(deg) + 180.0) % 360.0 - 180.0


def format_angle(deg: float, decimals: int = 2) -> str:
    """Signed angle wrapped to [-180, 180), e.g. ``"9.53°"``. Rounding never yields ``180.00°``."""
    w = float(wrap_degrees(deg))
    txt = f"{w:.{decimals}f}"
    if float(txt) >= 180.0:
        txt = f"{-180.0:.{decimals}f}"
    if float(txt) == 0.0:
        txt = txt.lstrip("-")
    return txt + "°"


def format_pose(T: np.ndarray, decimals: int = 2, *, compact: bool = False, signed_zero: bool = True) -> str:
    """Pose JSON ``{"tx","ty","tz","r11".."r33"}``; ``compact`` as v5 Waymo rows, spaced as ScanNet;
    ``signed_zero`` False: an entry that rounds to zero prints ``0.0`` whatever its sign."""
    T = np.asarray(T, dtype=float)
    vals = [T[0, 3], T[1, 3], T[2, 3]] + [T[i, j] for i in range(3) for j in range(3)]
    obj = {k: _r(v, decimals, signed_zero) for k, v in zip(POSE_KEYS, vals)}
    return json.dumps(obj, separators=(",", ":") if compact else (", ", ": "))


def box_heading(R: np.ndarray) -> float:
    """The redundant summary ``degrees(atan2(R[1,0], R[0,0]))`` wrapped to [-180, 180)."""
    R = np.asarray(R, dtype=float)
    return float(wrap_degrees(math.degrees(math.atan2(R[1, 0], R[0, 0]))))


def format_box(center, lwh, R, *, decimals: int = 3, rot_decimals: int = 6) -> str:
    """ReSTI v5 grounding JSON (keys sorted, compact), OpenCV camera axes.

    ``C_central_point`` and ``C_lwh`` in metres (3 decimals), ``C_rotation_camera_from_box`` the complete
    3x3 (6 decimals), ``C_heading`` = :func:`box_heading` (2 decimals).
    """
    R = np.asarray(R, dtype=float)
    obj = {
        "C_central_point": [_r(x, decimals) for x in center],
        "C_heading": _r(box_heading(R), 2),
        "C_lwh": [_r(x, decimals) for x in lwh],
        "C_rotation_camera_from_box": [[_r(x, rot_decimals) for x in r] for r in R],
    }
    return json.dumps(obj, separators=(",", ":"), sort_keys=True)


def format_legacy_box(center, lwh, heading_deg: float, decimals: int = 2) -> str:
    """The legacy grounding encoding (no rotation): centre, lwh and a scalar heading."""
    obj = {"C_central_point": [_r(x, decimals) for x in center], "C_lwh": [_r(x, decimals) for x in lwh],
           "C_heading": _r(heading_deg, decimals)}
    return json.dumps(obj, separators=(",", ":"))


def format_trajectory(segments, *, move_decimals: int = 1) -> str:
    """``[("move", 212.5), ("turn", -50), ("move", 156.5)]`` -> v5 phrase; empty -> no movement."""
    if not segments:
        return NO_MOVEMENT
    parts = []
    for kind, v in segments:
        if kind == "move":
            parts.append(f"move forward {v:.{move_decimals}f}m")
        elif kind == "turn":
            parts.append(f"turn {'left' if v > 0 else 'right'} {abs(v):.0f}°")
        else:
            raise ValueError(f"unknown segment kind {kind!r}")
    return ", then ".join(parts)


_TOKEN_RE = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def number_tokens(text: str) -> list[str]:
    """The numbers of a printed value exactly as printed, in order (``'{"tx": -0.0, "ty": 1.5}'`` ->
    ``["-0.0", "1.5"]``; ``"12.30m"`` -> ``["12.30"]``): what formatting checks and formatting attacks
    read (decimals, last digits, negative zeros), never the values themselves (use :func:`parse`)."""
    return _TOKEN_RE.findall(str(text))


__all__ = [
    "Scalar", "Pose", "Box", "Trajectory", "Label", "Value", "parse", "same_value", "agree",
    "format_scalar", "format_angle", "format_pose", "format_box", "format_legacy_box", "prints_negative_zero",
    "format_trajectory", "format_seconds", "box_heading", "wrap_degrees", "adaptive_decimals", "NO_MOVEMENT",
    "RELATION_LABELS", "canonical_unit", "si_factor", "unit_dimension", "number_tokens",
]
