"""Family ``relation``: physical relations across the rows of one recording.

Rows of one source sequence (the camera videos of a Waymo segment, a ScanNet scene, an Omni6DPose
scene) measure one world, so a row's answer often follows from the answers of its siblings by physics,
not by a repeated string (family ``cross_row``). Every attack here reads the sibling rows' answers (as
a reader holding the released file does; never the row's own), and what each question prints
(window, premise pose, subject noun) through :mod:`resti_lib.options.observables`; it predicts the
row's value and picks the candidate nearest to a prediction (None where no sibling relates):

- ``rel_rate_window``: a mean speed over a window times the window is the displacement (or path
  length) over the same window, and the other way round;
- ``rel_path_length``: the path length over a window is the total distance of a trajectory
  description over the same window, and the other way round;
- ``rel_distance_bound``: a displacement is never longer than the path length (or trajectory
  description's total distance) over the same window: the largest displacement within a sibling's path
  length, and the shortest path within a sibling's displacement;
- ``rel_box_edge``: a length, width or height is an edge of a sibling's oriented box of the same
  subject noun (any sibling box when none shares it), and a box carries a sibling's dimension;
- ``rel_pose_track``: a camera pose at a time is interpolated between the sibling poses of the same
  camera and frame (answers and printed premises) around it, or extrapolated from the two nearest
  (dead reckoning, constant velocity);
- ``rel_turn_sum``: a heading change over a window is the signed turn sum of a trajectory description
  over the same window, and the other way round;
- ``rel_converse``: a spatial relation of B to A is the mirror of the relation of A to B asked in
  another row of the same recording at the same time (the same words in another order).
"""

from __future__ import annotations

import re
from collections import Counter, defaultdict

import numpy as np

from ... import values as V
from ..follow import DIMENSIONS, DISTANCES, circular, distance_of, same_window, turn_sum, window
from .batch import Batch
from .common import top
from .features import premise_parts, rot_angle
from .registry import attack

MIRROR = {"left": "right", "right": "left", "closer": "farther", "farther": "closer", "front": "back",
          "back": "front"}


def _answer(batch: Batch, i: int):
    p = batch.rows[i]
    return p.values[p.answer]


def _facts(batch: Batch, j: int, keyed: bool) -> list:
    """What a reader knows of sibling ``j``'s value: its answer (a keyed reader) or its five candidates
    (a blind reader, who sees the sibling's question and options). Options coupled across the relation
    make every candidate match one of the sibling's, so the blind version singles out nothing."""
    p = batch.rows[j]
    return [p.values[p.answer]] if keyed else list(p.values.values())


def _siblings(batch: Batch, i: int, want) -> list[int]:
    """The other rows of row ``i``'s recording for which ``want(j)`` holds."""
    return [j for j in batch.sequences()[batch.obs[i].sequence] if j != i and want(j)]


def _nearest_log(p, predictions: list) -> frozenset | None:
    """The candidates (scalar SI values or trajectory distances) nearest, in log ratio, to any prediction."""
    preds = [x for x in predictions if x is not None and np.isfinite(x) and x > 0]
    if not preds:
        return None
    lp = np.log(preds)
    scores = {}
    for k, v in p.values.items():
        x = distance_of(v)
        scores[k] = -float(np.min(np.abs(np.log(x) - lp))) if x and x > 0 else -np.inf
    return top(scores)


def _scalar_row(p) -> bool:
    return all(isinstance(v, V.Scalar) for v in p.values.values())


def _trajectory_row(p) -> bool:
    return all(isinstance(v, V.Trajectory) for v in p.values.values())


# ------------------------------------------------------------------------------------ windows

def _window_facts(batch: Batch, i: int, quantities: tuple, value_of) -> list:
    """``value_of(j)`` of the sibling rows measuring one of ``quantities`` over the same window as row i."""
    w = window(batch.obs[i])
    if w is None:
        return []
    sib = _siblings(batch, i, lambda j: batch.obs[j].quantity in quantities and window(batch.obs[j]) is not None
                    and same_window(w, window(batch.obs[j])))
    return [value_of(j) for j in sib]


def _si_all(batch: Batch, j: int, keyed: bool) -> list:
    return [abs(a.si) for a in _facts(batch, j, keyed) if isinstance(a, V.Scalar)]


def _flat(lists) -> list:
    return [x for xs in lists for x in xs]


def _rate_window(batch: Batch, keyed: bool):
    out: list = [None] * len(batch)
    for i, (p, o) in enumerate(zip(batch.rows, batch.obs)):
        w = window(o)
        if w is None or not _scalar_row(p):
            continue
        span = w[1] - w[0]
        if o.quantity == "speed":
            preds = _flat(_window_facts(batch, i, DISTANCES, lambda j, s=span: [x / s for x in _si_all(batch, j, keyed)]))
        elif o.quantity in DISTANCES:
            preds = _flat(_window_facts(batch, i, ("speed",), lambda j, s=span: [x * s for x in _si_all(batch, j, keyed)]))
        else:
            continue
        out[i] = _nearest_log(p, preds)
    return out


def _path_length(batch: Batch, keyed: bool):
    out: list = [None] * len(batch)
    for i, (p, o) in enumerate(zip(batch.rows, batch.obs)):
        if o.quantity == "path_length" and _scalar_row(p):
            preds = _flat(_window_facts(batch, i, ("trajectory",), lambda j: [
                a.total_distance for a in _facts(batch, j, keyed) if isinstance(a, V.Trajectory)]))
        elif o.quantity == "trajectory" and _trajectory_row(p):
            preds = _flat(_window_facts(batch, i, ("path_length",), lambda j: _si_all(batch, j, keyed)))
        else:
            continue
        out[i] = _nearest_log(p, preds)
    return out


#: Printing slack of a bound between two printed distances: relative, and absolute in metres (two
#: decimals of a metre each side).
BOUND_REL, BOUND_ABS = 1e-3, 0.011


def _distance_bound(batch: Batch, keyed: bool):
    out: list = [None] * len(batch)
    for i, (p, o) in enumerate(zip(batch.rows, batch.obs)):
        dist = {k: distance_of(v) for k, v in p.values.items()}
        if any(x is None for x in dist.values()):
            continue
        if o.quantity == "displacement":  # at most the path over the window: the largest within it
            bounds = _flat(_window_facts(batch, i, ("path_length", "trajectory"), lambda j: [
                distance_of(a) for a in _facts(batch, j, keyed)]))
            fits = lambda x, b: x <= b * (1 + BOUND_REL) + BOUND_ABS  # noqa: E731
            best = max
        elif o.quantity in ("path_length", "trajectory"):  # at least the displacement: the shortest beyond it
            bounds = _flat(_window_facts(batch, i, ("displacement",), lambda j: [
                distance_of(a) for a in _facts(batch, j, keyed)]))
            fits = lambda x, b: x >= b * (1 - BOUND_REL) - BOUND_ABS  # noqa: E731
            best = min
        else:
            continue
        picks: set = set()
        for b in (x for x in bounds if x is not None and np.isfinite(x)):
            ok = {k: x for k, x in dist.items() if fits(x, b)}
            if ok:
                target = best(ok.values())
                picks |= {k for k, x in ok.items() if x == target}
        out[i] = frozenset(picks) or None
    return out


def _turn_sum(batch: Batch, keyed: bool):
    out: list = [None] * len(batch)
    for i, (p, o) in enumerate(zip(batch.rows, batch.obs)):
        if o.quantity == "heading_change" and all(isinstance(v, V.Scalar) and v.is_angle for v in p.values.values()):
            preds = _flat(_window_facts(batch, i, ("trajectory",), lambda j: [
                turn_sum(a) for a in _facts(batch, j, keyed) if isinstance(a, V.Trajectory)]))
            value = {k: float(v.value) for k, v in p.values.items()}
        elif o.quantity == "trajectory" and _trajectory_row(p):
            preds = _flat(_window_facts(batch, i, ("heading_change",), lambda j: [
                float(a.value) for a in _facts(batch, j, keyed) if isinstance(a, V.Scalar)]))
            value = {k: turn_sum(v) for k, v in p.values.items()}
        else:
            continue
        preds = [x for x in preds if x is not None]
        if preds:
            out[i] = top({k: -min(circular(x, y) for y in preds) for k, x in value.items()})
    return out


# ------------------------------------------------------------------------------------ boxes and dimensions

def _same_noun(batch: Batch, i: int, sib: list) -> list:
    """The siblings that name the same subject noun as row ``i`` (all of them when none does)."""
    noun = batch.obs[i].subject_class
    same = [j for j in sib if batch.obs[j].subject_class == noun]
    return same or sib


def _box_edge(batch: Batch, keyed: bool):
    out: list = [None] * len(batch)
    for i, (p, o) in enumerate(zip(batch.rows, batch.obs)):
        if o.quantity in DIMENSIONS and _scalar_row(p):
            sib = _same_noun(batch, i, _siblings(batch, i, lambda j: isinstance(_answer(batch, j), V.Box)))
            out[i] = _nearest_log(p, [float(e) for j in sib for a in _facts(batch, j, keyed) if isinstance(a, V.Box)
                                      for e in a.lwh])
        elif all(isinstance(v, V.Box) for v in p.values.values()):
            sib = _same_noun(batch, i, _siblings(batch, i, lambda j: batch.obs[j].quantity in DIMENSIONS
                                                 and isinstance(_answer(batch, j), V.Scalar)))
            dims = np.log([x for j in sib for x in _si_all(batch, j, keyed) if x > 0])
            if len(dims):
                out[i] = top({k: -float(np.min(np.abs(np.log(np.maximum(np.array(v.lwh, float), 1e-9))[:, None]
                                                      - dims[None, :])))
                              for k, v in p.values.items()})
    return out


# ------------------------------------------------------------------------------------ poses

def _pose_frame(o):
    """The frame a Pose question's poses live in: a printed premise is in the recording's world frame;
    an identity premise makes the camera at the premise time the frame. Keyed with the camera (the
    camera videos of one segment are different cameras)."""
    if o.premise is None:
        return None
    return ("world" if o.premise_text else ("camera", o.premise_time), o.camera)


def _pose_facts(batch: Batch, i: int, keyed: bool) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """(time, translation, rotation) of every pose of row ``i``'s camera and frame known without row i's
    answer: the premises printed in its own and its siblings' questions, and (a keyed reader) the
    siblings' answers."""
    o = batch.obs[i]
    frame = _pose_frame(o)
    facts = []
    if o.premise_time is not None:
        t, R = premise_parts(o)
        facts.append((float(o.premise_time), t, R))
    for j in _siblings(batch, i, lambda j: _pose_frame(batch.obs[j]) == frame):
        oj = batch.obs[j]
        if oj.premise_time is not None:
            t, R = premise_parts(oj)
            facts.append((float(oj.premise_time), t, R))
        a = _answer(batch, j) if keyed else None
        if isinstance(a, V.Pose) and oj.time_end is not None:
            facts.append((float(oj.time_end), np.array(a.t, float), np.array(a.R, float)))
    return facts


def predict_pose(facts: list, t: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The pose at time ``t`` from known poses ``(time, translation, rotation)``: a pose at ``t`` itself;
    else the translation interpolated between the nearest known poses before and after ``t`` (the
    rotation of the nearer); else extrapolated from the two nearest on one side at their constant
    velocity (dead reckoning); else the one known pose. None without facts."""
    if not facts:
        return None
    by_time: dict = {}
    for ft, tr, R in facts:
        by_time.setdefault(round(ft, 6), (ft, tr, R))
    known = sorted(by_time.values(), key=lambda f: f[0])
    times = np.array([f[0] for f in known])
    at = np.flatnonzero(np.abs(times - t) <= 1e-6)
    if len(at):
        return known[at[0]][1], known[at[0]][2]
    before = [f for f in known if f[0] < t]
    after = [f for f in known if f[0] > t]
    if before and after:
        a, b = before[-1], after[0]
        u = (t - a[0]) / (b[0] - a[0])
        return a[1] + u * (b[1] - a[1]), (a[2] if u <= 0.5 else b[2])
    side = before[-2:] if before else after[:2]
    if len(side) == 2:
        a, b = side
        v = (b[1] - a[1]) / (b[0] - a[0])
        near = b if before else a
        return near[1] + v * (t - near[0]), near[2]
    return side[0][1], side[0][2]


def _pose_track(batch: Batch, keyed: bool):
    out: list = [None] * len(batch)
    for i, (p, o) in enumerate(zip(batch.rows, batch.obs)):
        if o.premise is None or o.time_end is None or not all(isinstance(v, V.Pose) for v in p.values.values()):
            continue
        facts = _pose_facts(batch, i, keyed)
        if len(facts) < 2:  # the premise alone is the question family's (premise_distance)
            continue
        pred = predict_pose(facts, float(o.time_end))
        if pred is None:
            continue
        tp, Rp = pred
        dt = {k: float(np.linalg.norm(np.array(v.t, float) - tp)) for k, v in p.values.items()}
        dr = {k: rot_angle(np.array(v.R, float), Rp) for k, v in p.values.items()}
        st = float(np.median(list(dt.values()))) or 1.0
        sr = float(np.median(list(dr.values()))) or 1.0
        out[i] = top({k: -(dt[k] / st + 0.25 * dr[k] / sr) for k in p.values})
    return out


# ------------------------------------------------------------------------------------ converse relations

_WORDS = re.compile(r"[a-z0-9]+")


def _word_bag(question) -> tuple:
    return tuple(sorted(Counter(_WORDS.findall(str(question or "").lower())).items()))


def mirror_label(text: str) -> str | None:
    """The converse of a relation label (``Left`` <-> ``Right``, ``Closer`` <-> ``Farther``, ``Front`` <->
    ``Back``); None for a label without one among these."""
    t = " ".join(str(text).lower().split())
    return MIRROR.get(t)


@attack("keyed_converse", ["label"], "relation label mirroring the answer of the converse question (the same words "
        "in another order, same recording and time: B relative to A against A relative to B); reads the sibling "
        "rows' answers (a blind reader sees the same five labels in both)", family="keyed", scope="batch")
def _converse(batch: Batch):
    out: list = [None] * len(batch)
    bags = [_word_bag(r.get("Question")) for r in batch.records]
    key = defaultdict(list)
    for i, (p, o) in enumerate(zip(batch.rows, batch.obs)):
        if all(isinstance(v, V.Label) for v in p.values.values()):
            key[(o.sequence, o.time_start, o.time_end, bags[i])].append(i)
    for idx in key.values():
        for i in idx:
            q = str(batch.records[i].get("Question") or "")
            converse = [j for j in idx if j != i and str(batch.records[j].get("Question") or "") != q]
            want = {mirror_label(_answer(batch, j).text) for j in converse} - {None}
            hit = frozenset(k for k, v in batch.rows[i].values.items() if " ".join(v.text.lower().split()) in want)
            out[i] = hit or None
    return out


# ------------------------------------------------------------------------------------ registration

_RELATIONS = (
    ("rate_window", ["scalar"], _rate_window,
     "candidate nearest to a sibling's displacement or path length over the same window divided by the window "
     "(a mean speed), or to a sibling's mean speed times the window (a distance)"),
    ("path_length", ["scalar", "trajectory"], _path_length,
     "path length nearest to the total distance of a sibling trajectory description over the same window, or "
     "trajectory whose total distance is nearest to a sibling path length"),
    ("distance_bound", ["scalar", "trajectory"], _distance_bound,
     "largest displacement not longer than a sibling's path length (or trajectory description's total distance) "
     "over the same window, or shortest path length or trajectory not shorter than a sibling's displacement"),
    ("turn_sum", ["angle", "trajectory"], _turn_sum,
     "heading change nearest to the signed turn sum of a sibling trajectory description over the same window, or "
     "trajectory whose turn sum is nearest to a sibling heading change"),
    ("box_edge", ["scalar", "box"], _box_edge,
     "length, width or height nearest to an edge of a sibling's oriented box (same subject noun first), or box "
     "with an edge nearest to a sibling's length, width or height"),
    ("pose_track", ["pose"], _pose_track,
     "pose nearest (translation, then rotation) to the camera pose interpolated between the known poses of the "
     "same camera and frame or extrapolated from the two nearest (dead reckoning)"),
)


def _register(name: str, kinds: list, fn, what: str) -> None:
    attack(f"rel_{name}", kinds, what + "; reads the sibling rows' questions and candidates (a sibling's "
           "every candidate, or for poses the printed premises)", family="relation", scope="batch")(
        lambda batch, fn=fn: fn(batch, False))
    attack(f"keyed_{name}", kinds, what + "; reads the sibling rows' answers", family="keyed", scope="batch")(
        lambda batch, fn=fn: fn(batch, True))


for _name, _kinds, _fn, _what in _RELATIONS:
    _register(_name, _kinds, _fn, _what)
