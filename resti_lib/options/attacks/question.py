"""Family ``question``: rules that read the question's observables
(:mod:`resti_lib.options.observables`, the ones the option stage conditions its distractors on).

- ``implied_rate_typical``: the rate a candidate implies over the question's window (a displacement
  or path over the window is a speed, a heading change a turn rate; speeds and accelerations are
  rates) scored by its density among the other rows' answer rates of the same source, rate kind and
  subject (the row's source sequence left out, log scale);
- ``implied_rate_possible``: the candidates whose implied rate is physically possible (at most the
  limit of :data:`PHYSICAL_LIMITS` and at most twice the largest rate among the other rows' answers);
- ``premise_distance``: the pose candidate nearest to (or farthest from) the premise pose printed in
  the question, candidates that repeat the premise left out;
- ``travel_direction``: the pose candidate displaced from the premise pose along the direction the
  answers of other recordings travel in the premise camera's own frame (a vehicle's camera moves
  along its heading, forwards for a later target, backwards for an earlier one);
- ``typical_value``: the candidate most (or least) typical of the answers to the other questions of
  the same type and subject noun (the row's source sequence left out);
- ``nearest_question``: nearest neighbours: the answers of the five most similar questions of other
  source sequences (word overlap) of the same type, and the candidate nearest to their median (scalars) or
  most frequent among them (labels, trajectory structures).
"""

from __future__ import annotations

import re
from collections import Counter

import numpy as np

from ... import LETTERS
from ... import values as V
from .batch import Batch
from .common import ALL5, directional, top
from .features import answer_key, implied_rate, noun_of, premise_parts, question_kind, repeats_premise, value_scale
from .reference import loo_density
from .registry import attack

# Largest physically possible rates by rate kind (and source for camera speeds): handheld indoor and
# desktop cameras, road vehicles; accelerations and turn rates of any of them.
PHYSICAL_LIMITS = {
    ("speed", "ScanNet"): 3.0,        # m/s, a walking person's camera
    ("speed", "Omni6DPose"): 3.0,
    ("speed", "Waymo"): 45.0,         # m/s, a road vehicle
    ("acceleration", None): 10.0,     # m/s², about 1 g
    ("turn rate", None): 180.0,       # °/s
}
POSSIBLE_MARGIN = 2.0  # a rate above twice the largest answer rate of the other rows is impossible
NEIGHBOURS = 5
MIN_TRAVEL = 1e-6      # a candidate closer than this (m) to the premise has no direction of travel


def _cell_qtype(batch: Batch, i: int) -> tuple:
    return (batch.rows[i].task, batch.rows[i].source, question_kind(batch.obs[i]))


def _noun(batch: Batch, i: int):
    return noun_of(batch.obs[i])


def _rates(batch: Batch) -> list:
    """Per row: (rate kind, ``letter -> rate``) or None."""
    out = []
    for p, o in zip(batch.rows, batch.obs):
        r = {k: implied_rate(v, o) for k, v in p.values.items()}
        if any(x is None for x in r.values()):
            out.append(None)
            continue
        kinds = {x[0] for x in r.values()}
        out.append((kinds.pop(), {k: x[1] for k, x in r.items()}) if len(kinds) == 1 else None)
    return out


def _rate_group(batch: Batch, i: int, rates: list):
    o = batch.obs[i]
    return (o.source, rates[i][0], "camera" if o.is_camera else "object")


@attack("implied_rate_typical", ["scalar", "trajectory"], "candidate whose implied rate over the question's window "
        "is most or least typical of the other rows' answer rates (same source, rate kind and subject; "
        "in every direction)", family="question", scope="batch")
def _implied_rate_typical(batch: Batch):
    rates = _rates(batch)
    logs = [None if r is None else {k: float(np.log(x + 1e-4)) for k, x in r[1].items()} for r in rates]
    dens = loo_density(batch, logs, lambda i: _rate_group(batch, i, rates), noun_key=lambda i: _noun(batch, i))
    return directional(batch, dens)


def _limit(kind: str, source: str) -> float:
    return PHYSICAL_LIMITS.get((kind, source), PHYSICAL_LIMITS.get((kind, None), np.inf))


@attack("implied_rate_possible", ["scalar", "trajectory"], "candidates whose implied rate over the question's "
        "window is physically possible (within the physical limit and twice the largest answer rate of the "
        "other rows)", family="question", scope="batch")
def _implied_rate_possible(batch: Batch):
    rates = _rates(batch)
    out: list = [None] * len(batch)
    groups = batch.groups(lambda i: _rate_group(batch, i, rates) if rates[i] is not None else None)
    for (source, kind, _), idx in groups.items():
        ans = np.array([rates[i][1][batch.rows[i].answer] for i in idx])
        seqs = np.array([batch.obs[i].sequence for i in idx], dtype=object)
        for j, i in enumerate(idx):
            others = ans[seqs != seqs[j]]
            bound = min(_limit(kind, source), POSSIBLE_MARGIN * float(others.max()) if len(others) else np.inf)
            ok = frozenset(k for k, x in rates[i][1].items() if x <= bound + 1e-12)
            out[i] = ok if ok and len(ok) < 5 else ALL5
    return out


def _pose_distances(p, o) -> dict | None:
    """``letter -> (translation distance, rotation angle in degrees)`` to the premise; None for a
    candidate that repeats the premise."""
    out = {}
    tp, Rp = premise_parts(o)
    for k, v in p.values.items():
        if repeats_premise(v, o):
            out[k] = None
            continue
        R = np.array(v.R, float)
        ang = np.degrees(np.arccos(np.clip((np.trace(Rp.T @ R) - 1) / 2, -1.0, 1.0)))
        out[k] = (float(np.linalg.norm(np.array(v.t, float) - tp)), float(ang))
    return out


def _pose_row(p, o) -> bool:
    return o.premise is not None and all(isinstance(v, V.Pose) for v in p.values.values())


@attack("premise_distance", ["pose"], "pose candidate nearest to (or farthest from) the premise pose printed in "
        "the question, in translation and rotation (each scaled by the row's median), candidates repeating the "
        "premise left out (in every direction)", family="question", scope="batch")
def _premise_distance(batch: Batch):
    scores: list = []
    for p, o in zip(batch.rows, batch.obs):
        if not _pose_row(p, o):
            scores.append(None)
            continue
        d = _pose_distances(p, o)
        real = [x for x in d.values() if x is not None]
        if not real:
            scores.append({k: np.nan for k in LETTERS})
            continue
        st = np.median([x[0] for x in real]) or 1.0
        sr = np.median([x[1] for x in real]) or 1.0
        scores.append({k: (-(x[0] / st + x[1] / sr) if x is not None else np.nan) for k, x in d.items()})
    return directional(batch, scores)


def travel_directions(p, o) -> dict | None:
    """``letter -> unit vector`` of each pose candidate's displacement from the premise pose, in the
    premise camera's own axes and signed by time (backwards for a target before the premise time);
    NaN for a candidate at the premise. None for rows without a premise pose or a target time."""
    if not _pose_row(p, o) or o.time_end is None or o.premise_time is None or o.time_end == o.premise_time:
        return None
    tp, Rp = premise_parts(o)
    sign = 1.0 if o.time_end > o.premise_time else -1.0
    out = {}
    for k, v in p.values.items():
        d = Rp.T @ (np.array(v.t, float) - tp) * sign
        n = float(np.linalg.norm(d))
        out[k] = d / n if n > MIN_TRAVEL else np.full(3, np.nan)
    return out


@attack("travel_direction", ["pose"], "pose candidate displaced from the premise pose along the direction of travel "
        "(the mean direction, in the premise camera's axes and signed by time, of the answers of other "
        "recordings with the same quantity, source and camera; in every direction)", family="question", scope="batch")
def _travel_direction(batch: Batch):
    dirs = [travel_directions(p, o) for p, o in zip(batch.rows, batch.obs)]
    scores: list = [None] * len(batch)
    groups = batch.groups(lambda i: (batch.obs[i].quantity, batch.obs[i].source, batch.obs[i].camera)
                          if dirs[i] is not None else None)
    for idx in groups.values():
        ans = np.array([dirs[i][batch.rows[i].answer] for i in idx])
        ok = np.all(np.isfinite(ans), axis=1)
        seqs = np.array([batch.obs[i].sequence for i in idx], dtype=object)
        total = ans[ok].sum(0)
        by_seq: dict = {}
        for j, s in enumerate(seqs):
            if ok[j]:
                by_seq[s] = by_seq.get(s, 0) + ans[j]
        for j, i in enumerate(idx):
            mean = total - by_seq.get(seqs[j], 0)  # the row's own recording left out
            if not np.any(mean):
                continue
            mean = mean / np.linalg.norm(mean)
            scores[i] = {k: float(d @ mean) if np.all(np.isfinite(d)) else np.nan for k, d in dirs[i].items()}
    return directional(batch, scores)


@attack("typical_value", ["scalar", "trajectory"], "candidate most or least typical of the answers to the other "
        "questions of the same type (and subject noun when shared by enough rows) in other source sequences "
        "(in every direction)", family="question", scope="batch")
def _typical_value(batch: Batch):
    vals = [value_scale(p) for p in batch.rows]
    dens = loo_density(batch, vals, lambda i: _cell_qtype(batch, i), noun_key=lambda i: _noun(batch, i))
    return directional(batch, dens)


_WORD = re.compile(r"[a-z]+")


def words(q: str) -> frozenset:
    """The words of a question (three letters or more, lower case)."""
    return frozenset(w for w in _WORD.findall(str(q).lower()) if len(w) > 2)


def nearest_questions(word_sets: list, k: int = NEIGHBOURS, block: int = 512, exclude: list | None = None) -> list:
    """For each question, the indices of the ``k`` most similar *other* questions (Jaccard similarity of
    their word sets; ties to the lower index), never one with the same ``exclude`` label (e.g. its
    source sequence); computed in blocks on a sparse word matrix, so a group of n questions costs
    O(n²) arithmetic but only O(block × n) memory."""
    from scipy.sparse import csr_matrix

    n = len(word_sets)
    if n < 2:
        return [[] for _ in range(n)]
    vocab: dict = {}
    rows, cols = [], []
    for i, ws in enumerate(word_sets):
        for w in ws:
            rows.append(i)
            cols.append(vocab.setdefault(w, len(vocab)))
    X = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, max(1, len(vocab))))
    size = np.asarray(X.sum(axis=1)).ravel()
    labels = np.array(exclude, dtype=object) if exclude is not None else None
    out = []
    kk = min(k, n - 1)
    for b0 in range(0, n, block):
        inter = (X[b0:b0 + block] @ X.T).toarray()
        union = size[b0:b0 + block, None] + size[None, :] - inter
        sim = inter / np.maximum(union, 1.0)
        for r in range(sim.shape[0]):
            row = sim[r]
            row[b0 + r] = -np.inf  # never itself
            if labels is not None:
                row[labels == labels[b0 + r]] = -np.inf
            kth = np.partition(row, n - kk)[n - kk]  # the k-th largest similarity
            cand = np.flatnonzero((row >= kth) & np.isfinite(row))
            order = cand[np.lexsort((cand, -row[cand]))][:kk]  # similarity descending, then index
            out.append(order.tolist())
    return out


@attack("nearest_question", ["scalar", "trajectory", "label"], "nearest neighbours: the candidate nearest to the "
        "median answer (labels: the most frequent answer) of the five most similar questions of the same type "
        "in other source sequences", family="question", scope="batch")
def _nearest_question(batch: Batch):
    out: list = [None] * len(batch)
    ws = [words(r.get("Question")) for r in batch.records]
    vals = [value_scale(p) for p in batch.rows]
    groups = batch.groups(lambda i: _cell_qtype(batch, i))
    for idx in groups.values():
        neighbours = nearest_questions([ws[i] for i in idx], exclude=[batch.obs[i].sequence for i in idx])
        for i, nb in zip(idx, neighbours):
            p = batch.rows[i]
            near = [idx[j] for j in nb]
            if not near:
                continue
            if vals[i] is not None:
                m = float(np.median([vals[j][batch.rows[j].answer] for j in near]))
                out[i] = top({k: -abs(x - m) for k, x in vals[i].items()})
            elif all(isinstance(v, (V.Label, V.Trajectory)) for v in p.values.values()):
                c = Counter(answer_key(batch.rows[j].values[batch.rows[j].answer]) for j in near)
                out[i] = top({k: float(c.get(answer_key(v), 0)) for k, v in p.values.items()})
    return out
