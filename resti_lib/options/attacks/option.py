"""Family ``option``: rules on the five candidate values alone (ranks, centres, medoids, per-field votes,
the letter order and string length) and, for the label prior, the other rows' answers of the task and
source."""

from __future__ import annotations

from collections import Counter

import numpy as np

from ... import LETTERS
from ... import values as V
from ...geometry.frames import nearest_rotation
from ..checks import ParsedRow
from .batch import Batch
from .common import TIE, Directional, directional, top
from .features import (
    answer_key,
    field_matrix,
    fields,
    label_name,
    labelled,
    medoid_pick,
    nearest_pick,
    order_concordance,
    rank_pick,
    rot_angle,
    scalar_or_distance,
)
from .registry import attack


@attack("constant_letter", ["any"], "best constant letter in the task/source cell (Bonferroni over 5 letters)",
        scope="batch", tests=5)
def _constant_letter(batch: Batch):
    out: list = [None] * len(batch)
    for idx in batch.cells().values():
        counts = Counter(batch.rows[i].answer for i in idx)
        best = max(LETTERS, key=lambda L: (counts.get(L, 0), -LETTERS.index(L)))
        for i in idx:
            out[i] = frozenset([best])
    return out


def _rank_attack(rank: int):
    def fn(p: ParsedRow):
        vals = scalar_or_distance(p)
        return None if vals is None else rank_pick(vals, rank)
    return fn


for _rank, _name in [(1, "min"), (2, "rank_2"), (3, "median"), (4, "rank_4"), (5, "max")]:
    attack(_name, ["scalar", "trajectory"], f"candidate of signed-value rank {_rank} of 5")(_rank_attack(_rank))


@attack("nearest_mean", ["scalar", "trajectory"], "candidate nearest to the mean of the five values")
def _nearest_mean(p: ParsedRow):
    vals = scalar_or_distance(p)
    if vals is None:
        return None
    m = np.mean(list(vals.values()))
    return top({k: -abs(v - m) for k, v in vals.items()})


@attack("medoid", ["scalar", "trajectory"], "candidate with the least total distance to the others")
def _medoid_scalar(p: ParsedRow):
    vals = scalar_or_distance(p)
    if vals is None:
        return None
    return medoid_pick({k: np.array([v]) for k, v in vals.items()})


@attack("nearest_circular_mean", ["angle"], "angle nearest (circularly) to the circular mean")
def _circ(p: ParsedRow):
    if not all(isinstance(v, V.Scalar) and v.is_angle for v in p.values.values()):
        return None
    rad = {k: np.radians(v.value) for k, v in p.values.items()}
    m = np.arctan2(np.mean(np.sin(list(rad.values()))), np.mean(np.cos(list(rad.values()))))
    return top({k: -abs(np.angle(np.exp(1j * (a - m)))) for k, a in rad.items()})


def _field_votes(p: ParsedRow, winners) -> frozenset | None:
    """One vote per printed field for the candidates ``winners(column)`` names (indices)."""
    keys, X = field_matrix(p)
    if X is None:
        return None
    votes = Counter({k: 0 for k in keys})
    for j in range(X.shape[1]):
        for i in winners(X[:, j]):
            votes[keys[i]] += 1
    return top(dict(votes))


def _median_winner(col: np.ndarray) -> list[int]:
    hit = np.flatnonzero(np.abs(col - np.median(col)) <= TIE)
    return [int(hit[0])] if len(hit) == 1 else []


def _modal_winners(col: np.ndarray) -> list[int]:
    c = Counter(np.round(col, 9))
    val, n = c.most_common(1)[0]
    if n < 2 or list(c.values()).count(n) != 1:
        return []
    return [i for i in range(len(col)) if round(col[i], 9) == val]


@attack("field_median", ["box", "pose"], "per-field median vote over every printed field")
def _field_median(p: ParsedRow):
    return _field_votes(p, _median_winner)


@attack("field_majority", ["box", "pose"], "per-field modal value vote (values shared by >= 2 candidates)")
def _field_majority(p: ParsedRow):
    return _field_votes(p, _modal_winners)


def _group_attack(group: str, how: str):
    def fn(p: ParsedRow):
        f = fields(p)
        if f is None or group not in f:
            return None
        vecs = f[group]
        if group == "rotation":
            if how == "centroid":
                M = nearest_rotation(np.mean([vecs[k] for k in sorted(vecs)], axis=0))
                return top({k: -rot_angle(R, M) for k, R in vecs.items()})
            return medoid_pick(vecs, dist=rot_angle)
        if how == "centroid":
            return nearest_pick(dict(vecs), np.mean(list(vecs.values()), axis=0))
        return medoid_pick(vecs)
    return fn


for _g, _kinds in [("center", ["box"]), ("logdims", ["box"]), ("translation", ["pose"]),
                   ("rotation", ["box", "pose"])]:
    for _how in ("centroid", "medoid"):
        attack(f"{_how}_{_g}", _kinds, f"{_how} pick on the {_g} field group")(_group_attack(_g, _how))


def _standardized(p: ParsedRow) -> dict | None:
    keys, X = field_matrix(p)
    if X is None:
        return None
    sd = X.std(axis=0)
    keep = sd > 1e-12
    if not keep.any():
        return {k: np.zeros(1) for k in keys}
    Z = (X[:, keep] - X[:, keep].mean(axis=0)) / sd[keep]
    return {k: Z[i] for i, k in enumerate(keys)}


@attack("centroid_all", ["box", "pose"], "nearest to the centroid of all standardized fields")
def _centroid_all(p: ParsedRow):
    z = _standardized(p)
    return None if z is None else nearest_pick(z, np.zeros_like(next(iter(z.values()))))


@attack("medoid_all", ["box", "pose"], "medoid of all standardized fields")
def _medoid_all(p: ParsedRow):
    z = _standardized(p)
    return None if z is None else medoid_pick(z)


def constant_label(batch: Batch, rows: list | None = None) -> Directional:
    """One direction per label (trajectory: structure) seen among the candidates: pick, in every row
    whose candidates carry it, the candidates with that label (None in the other rows). The table keeps
    the best label of each cell with a Bonferroni factor over the labels; each label's test is exact
    (the answer is one of five exchangeable candidates). ``rows``: restrict to these row indices."""
    rows = range(len(batch)) if rows is None else rows
    keys: dict = {}
    for i in rows:
        if labelled(batch.rows[i]):
            for v in batch.rows[i].values.values():
                keys.setdefault(answer_key(v), label_name(v))
    out = Directional()
    for key, name in keys.items():
        picks: list = [None] * len(batch)
        for i in rows:
            p = batch.rows[i]
            if labelled(p):
                hit = frozenset(k for k, v in p.values.items() if answer_key(v) == key)
                picks[i] = hit or None
        out[name] = picks
    return out


@attack("label_prior", ["label", "trajectory"],
        "the most frequent answer label (trajectory: segment structure) of the task and source: every label "
        "tried as a constant pick, the best kept with a Bonferroni factor over the labels", scope="batch")
def _label_prior(batch: Batch):
    return constant_label(batch)


@attack("letter_order", ["scalar", "trajectory", "box", "pose"], "candidate from which the other four, in letter "
        "order, get steadily farther (or nearer): distractors listed in the order they were generated around "
        "the answer (in every direction)", scope="batch")
def _letter_order(batch: Batch):
    return directional(batch, [order_concordance(p) for p in batch.rows])


@attack("label_order", ["label"], "label whose removal leaves the other four in the usual order of the labels "
        "(pairwise precedence among the candidate lists of the other rows of the cell, leave-one-out)",
        scope="batch")
def _label_order(batch: Batch):
    out: list = [None] * len(batch)
    for idx in batch.cells().values():
        lists = {i: [batch.rows[i].values[k].key() for k in LETTERS] for i in idx
                 if all(isinstance(v, V.Label) for v in batch.rows[i].values.values())}
        prec: Counter = Counter()
        for seq in lists.values():
            for a in range(5):
                for b in range(a + 1, 5):
                    prec[(seq[a], seq[b])] += 1
        for i, seq in lists.items():
            loo = prec.copy()
            for a in range(5):
                for b in range(a + 1, 5):
                    loo[(seq[a], seq[b])] -= 1
            scores = {}
            for c in range(5):
                rest = [x for j, x in enumerate(seq) if j != c]
                scores[LETTERS[c]] = float(sum(np.sign(loo[(rest[a], rest[b])] - loo[(rest[b], rest[a])])
                                               for a in range(4) for b in range(a + 1, 4)))
            out[i] = top(scores)
    return out


@attack("shortest_string", ["any"], "shortest candidate string")
def _shortest(p: ParsedRow):
    return top({k: -float(len(s)) for k, s in p.candidates.items()})


@attack("longest_string", ["any"], "longest candidate string")
def _longest(p: ParsedRow):
    return top({k: float(len(s)) for k, s in p.candidates.items()})
