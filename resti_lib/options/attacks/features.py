"""What a row says to a blind reader, shared by the families: its candidate values on comparable
scales, the field groups of structured answers, how each candidate is printed, and what the question
states (read through :mod:`resti_lib.options.observables`, never parsed a second way)."""

from __future__ import annotations

import functools
import re

import numpy as np

from ... import LETTERS
from ... import values as V
from ...errors import InputError
from ..checks import ParsedRow
from .common import TIE, top

NUMERIC = ("scalar", "box", "pose", "trajectory")


# ------------------------------------------------------------------------------------ candidate values

def scalar_values(p: ParsedRow) -> dict | None:
    """Signed SI values of scalar candidates, or None."""
    if not all(isinstance(v, V.Scalar) for v in p.values.values()):
        return None
    return {k: v.si for k, v in p.values.items()}


def scalar_or_distance(p: ParsedRow) -> dict | None:
    """Signed SI values of scalar candidates, or total distances of trajectory candidates."""
    vals = scalar_values(p)
    if vals is None and all(isinstance(v, V.Trajectory) for v in p.values.values()):
        vals = {k: v.total_distance for k, v in p.values.items()}
    return vals


def reader_log(x):
    """A magnitude (SI) on the scale readers compare it on: ``log(|x| + 1 mm)`` (arrays too)."""
    return np.log(np.abs(x) + 1e-3)


def value_scale(p: ParsedRow) -> dict | None:
    """Candidate values on the scale of their variation: log |x| for lengths, speeds and trajectories,
    signed degrees for angles; None for other kinds."""
    vals = p.values
    if all(isinstance(v, V.Scalar) for v in vals.values()):
        if all(v.is_angle for v in vals.values()):
            return {k: float(v.value) for k, v in vals.items()}
        return {k: float(reader_log(v.si)) for k, v in vals.items()}
    if all(isinstance(v, V.Trajectory) for v in vals.values()):
        return {k: float(reader_log(v.total_distance)) for k, v in vals.items()}
    return None


def numeric_row(p: ParsedRow) -> bool:
    return all(v.kind in NUMERIC for v in p.values.values())


def rank_pick(vals: dict, rank: int) -> frozenset:
    """Letters at 1-based ascending ``rank`` of the signed values (every letter tied with it)."""
    order = sorted(vals.items(), key=lambda kv: (kv[1], kv[0]))
    v = order[rank - 1][1]
    return frozenset(k for k, w in vals.items() if abs(w - v) <= TIE)


def nearest_pick(vecs: dict, target: np.ndarray) -> frozenset:
    """The letters whose vector is nearest to ``target``."""
    return top({k: -float(np.linalg.norm(np.asarray(v) - target)) for k, v in vecs.items()})


def medoid_pick(vecs: dict, dist=None) -> frozenset:
    """The letters of least total distance to the others (Euclidean, or ``dist``)."""
    keys = sorted(vecs)
    if dist is None:
        X = np.array([np.asarray(vecs[k], dtype=float).ravel() for k in keys])
        D = np.sqrt(((X[:, None, :] - X[None, :, :]) ** 2).sum(-1))
        return top({k: -float(D[i].sum()) for i, k in enumerate(keys)})
    return top({k: -sum(dist(vecs[k], vecs[j]) for j in keys if j != k) for k in keys})


def rot_angle(A, B) -> float:
    """Angle (radians) between two matrices as printed, from the trace alone. An attacker reads the
    printed entries, so no projection onto SO(3) here; the audit's own angle, on projected rotations,
    is :func:`resti_lib.geometry.frames.rotation_angle_deg`."""
    c = (np.trace(np.asarray(A).T @ np.asarray(B)) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def fields(p: ParsedRow) -> dict | None:
    """Named field groups of structured answers (grounding box / pose)."""
    vals = p.values
    if all(isinstance(v, V.Box) for v in vals.values()):
        out = {
            "center": {k: np.array(v.center) for k, v in vals.items()},
            "logdims": {k: np.log(np.maximum(np.array(v.lwh), 1e-9)) for k, v in vals.items()},
        }
        if all(v.R is not None for v in vals.values()):
            out["rotation"] = {k: np.array(v.R) for k, v in vals.items()}
        return out
    if all(isinstance(v, V.Pose) for v in vals.values()):
        return {"translation": {k: np.array(v.t) for k, v in vals.items()},
                "rotation": {k: np.array(v.R) for k, v in vals.items()}}
    return None


def flat_fields(p: ParsedRow) -> dict | None:
    """Every scalar field of a structured answer, as letter -> 1-D vector (printed values)."""
    vals = p.values
    if all(isinstance(v, (V.Box, V.Pose)) for v in vals.values()):
        lens = {len(v.vector()) for v in vals.values()}
        if len(lens) == 1:
            return {k: v.vector() for k, v in vals.items()}
    return None


def field_matrix(p: ParsedRow) -> tuple[list, np.ndarray | None]:
    """Letters (sorted) and the 5 x n matrix of every printed field of a structured answer."""
    flat = flat_fields(p)
    if flat is None:
        return [], None
    keys = sorted(flat)
    return keys, np.array([flat[k] for k in keys])


def candidate_vectors(p: ParsedRow) -> dict | None:
    """``letter -> vector`` of a row's candidates, standardised per field across the five (scalars: the
    SI value; trajectories: total distance; boxes and poses: every printed field); None for labels."""
    vals = scalar_or_distance(p)
    if vals is not None:
        X = np.array([[vals[k]] for k in LETTERS])
    else:
        flat = flat_fields(p)
        if flat is None:
            return None
        X = np.array([flat[k] for k in LETTERS], dtype=float)
    sd = X.std(axis=0)
    sd[sd <= 1e-12] = 1.0
    Z = (X - X.mean(axis=0)) / sd
    return {k: Z[i] for i, k in enumerate(LETTERS)}


def order_concordance(p: ParsedRow) -> dict | None:
    """Per candidate ``c``: Kendall concordance between the letter order of the other four candidates and
    their distance to ``c`` (+6: they get steadily farther from ``c`` in letter order; -6: nearer)."""
    z = candidate_vectors(p)
    if z is None:
        return None
    out = {}
    for c in LETTERS:
        d = [float(np.linalg.norm(z[k] - z[c])) for k in LETTERS if k != c]
        out[c] = float(sum(np.sign(d[b] - d[a]) if abs(d[b] - d[a]) > 1e-9 else 0.0
                           for a in range(4) for b in range(a + 1, 4)))
    return out


# ------------------------------------------------------------------------------------ labels

def answer_key(v):
    """What the label prior counts: the label, or a trajectory's segment structure."""
    return v.structure if isinstance(v, V.Trajectory) else v.key()


def labelled(p: ParsedRow) -> bool:
    return all(isinstance(v, (V.Label, V.Trajectory)) for v in p.values.values())


def label_name(v) -> str:
    """A readable name of a candidate's :func:`answer_key`: the label text, or the trajectory structure."""
    if isinstance(v, V.Label):
        return " ".join(v.text.split())
    return "-".join(v.structure) if v.structure else "no movement"


# ------------------------------------------------------------------------------------ printing

@functools.lru_cache(maxsize=1 << 16)
def tokens(s: str) -> tuple[str, ...]:
    """The printed numbers of a candidate string (remembered: every formatting attack reads them)."""
    return tuple(V.number_tokens(s))


def decimals(tok: str) -> int:
    t = tok.lower().split("e")[0]
    return len(t.split(".", 1)[1]) if "." in t else 0


def digits(tok: str) -> str:
    return re.sub(r"[^0-9]", "", tok.lower().split("e")[0])


def is_negative_zero(tok: str) -> bool:
    return tok.startswith("-") and not digits(tok).strip("0")


def significant(tok: str) -> int:
    """Significant digits as printed (trailing zeros count: ``0.10`` has two)."""
    return len(digits(tok).lstrip("0"))


def significant_stripped(tok: str) -> int:
    """Significant digits of the number itself (trailing zeros after the point dropped: ``0.10`` has one,
    ``12.50`` three, ``120`` three)."""
    t = tok.lower().split("e")[0].lstrip("+-")
    if "." in t:
        t = t.rstrip("0").rstrip(".")
    return len(digits(t).lstrip("0"))


def last_digit(tok: str) -> str:
    return digits(tok)[-1:] or "x"


def skeleton(s: str) -> str:
    """The layout of a printed value: every digit run replaced by ``9`` (key order, spacing, signs and
    separators remain)."""
    return re.sub(r"\d+", "9", str(s))


def flat_text(s: str) -> str:
    """A printed value or question with its whitespace removed."""
    return "".join(str(s).split())


def printed_in(s: str, text: str) -> bool:
    """``s`` occurs in ``text`` as a whole number: no digit or point before it, no digit after it."""
    at = text.find(s)
    while at >= 0:
        end = at + len(s)
        if (at == 0 or not (text[at - 1].isdecimal() or text[at - 1] == ".")) and not (
                end < len(text) and text[end].isdecimal()):
            return True
        at = text.find(s, at + 1)
    return False


# ------------------------------------------------------------------------------------ the question
# What the rules read of :class:`resti_lib.options.observables.Observables`.

PER_WINDOW = {"displacement": "speed", "path_length": "speed", "trajectory": "speed", "heading_change": "turn rate"}
RATES = {"speed": "speed", "acceleration": "acceleration"}


def question_kind(o) -> str:
    """The question type: the measured quantity, with ``@instant`` for a speed or acceleration at one
    instant (averaged over a stated window) rather than over an interval."""
    if o.quantity in RATES and o.time_start is not None and o.time_start == o.time_end:
        return f"{o.quantity}@instant"
    return o.quantity


def noun_of(o) -> str | None:
    """The head noun of the measured thing; None for the camera or when the question names none."""
    return None if o.is_camera or not o.subject_class else o.subject_class


def implied_rate(value, o) -> tuple[str, float] | None:
    """The rate a value implies over the question's window: ``(kind, rate)``.

    Displacements, path lengths and trajectories imply a speed (distance / window, m/s), a heading
    change a turn rate (|degrees| / window); speeds and accelerations are rates themselves (SI
    magnitude). None when the value has no rate (another quantity, no window, an unparsed value).
    """
    if isinstance(value, V.Trajectory):
        x = value.total_distance
    elif isinstance(value, V.Scalar):
        x = abs(value.si)
    else:
        return None
    if o.quantity in RATES:
        return RATES[o.quantity], x
    kind = PER_WINDOW.get(o.quantity)
    w = o.window_s
    if kind is None or w is None or w <= 0:
        return None
    return kind, x / w


def premise_parts(o) -> tuple[np.ndarray, np.ndarray] | None:
    """Translation (3,) and rotation (3, 3) of the premise pose of a Pose question, or None."""
    if o.premise is None:
        return None
    P = np.asarray(o.premise, float)
    return P[:3, 3], P[:3, :3]


def premise_key(o):
    """The value key of the premise pose printed in a question (None when it prints none)."""
    if not o.premise_text:
        return None
    try:
        return V.parse(o.premise_text).key()
    except InputError:
        return None


def repeats_premise(v, o) -> bool:
    """Whether a pose candidate prints the premise pose itself (the same printed numbers)."""
    if o.premise is None or not isinstance(v, V.Pose):
        return False
    if o.premise_text:
        k = premise_key(o)
        return k is not None and k == v.key()
    return bool(np.allclose(v.matrix, np.asarray(o.premise, float), atol=0.5 * 10.0 ** -v.decimals + 1e-9))
