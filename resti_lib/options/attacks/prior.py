"""Family ``prior``: what the other recordings of the release say about a printed candidate.

- ``string_rate``: how often a candidate's printed string (direction ``string``, anywhere in the
  release) or value (direction ``value``, among questions of the same quantity) is the answer when it
  is offered, counted over the rows of *other recordings* (the row's own recording left out) and shrunk
  towards chance; the candidate of highest (or lowest) rate;
- ``field_rate``: the same rate per printed field (the j-th number of the candidate, e.g. a pose's
  ``r31``) within the task/source cell, summed in log over the fields (a field prior);
- ``nearest_set``: nearest neighbours over candidate sets: the five rows of other recordings of the
  same cell and question type whose sorted candidate values lie nearest to the row's; the candidate
  at the rank their answers took most often (direction ``rank``) or nearest to their answers' median
  relative to their sets (direction ``value``).
"""

from __future__ import annotations

from collections import Counter, defaultdict

import numpy as np

from ... import LETTERS
from .batch import Batch
from .common import CHANCE, ENDS, Directional, directional, top
from .features import flat_text, question_kind, tokens, value_scale
from .registry import attack

SHRINK = 2.0       # pseudo-offers at chance added to every rate (a string offered once says little)
NEIGHBOURS = 5


def _rates(batch: Batch, key_of, rows=None) -> list:
    """Per row (of ``rows``, default every row, in that order): ``letter -> rate`` at which the candidate's
    key (``key_of(i, letter)``; None: the row has no rate) is the answer when offered in rows of other
    recordings: (answers + SHRINK/5) / (offers + SHRINK)."""
    rows = range(len(batch)) if rows is None else rows
    offered: Counter = Counter()
    answered: Counter = Counter()
    own_off: dict = defaultdict(Counter)
    own_ans: dict = defaultdict(Counter)
    keys = []
    for i in rows:
        p = batch.rows[i]
        ks = {k: key_of(i, k) for k in LETTERS}
        keys.append((i, ks))
        seq = batch.obs[i].sequence
        for k, x in ks.items():
            if x is None:
                continue
            offered[x] += 1
            own_off[seq][x] += 1
            if k == p.answer:
                answered[x] += 1
                own_ans[seq][x] += 1
    out: list = []
    for i, ks in keys:
        if any(x is None for x in ks.values()):
            out.append(None)
            continue
        seq = batch.obs[i].sequence
        r = {}
        for k, x in ks.items():
            n = offered[x] - own_off[seq][x]
            a = answered[x] - own_ans[seq][x]
            r[k] = (a + SHRINK * CHANCE) / (n + SHRINK)
        out.append(r)
    return out


@attack("string_rate", ["any"], "candidate whose printed string (anywhere in the release) or value (same quantity) "
        "is most (or least) often the answer where it is offered in other recordings (in every direction)",
        family="prior", scope="batch")
def _string_rate(batch: Batch):
    by_string = _rates(batch, lambda i, k: flat_text(batch.rows[i].candidates[k]))
    by_value = _rates(batch, lambda i, k: (batch.obs[i].quantity, batch.rows[i].values[k].key()))
    out = Directional()
    for name, rates in (("string", by_string), ("value", by_value)):
        for d, picks in directional(batch, rates, directions=ENDS).items():
            out[f"{name} {d}"] = picks
    return out


@attack("field_rate", ["scalar", "box", "pose", "trajectory"], "candidate whose printed fields (the j-th number of "
        "each candidate) are most (or least) often the answer's where offered in other recordings of the "
        "task/source cell, summed in log over the fields (in every direction)", family="prior", scope="batch")
def _field_rate(batch: Batch):
    toks = [{k: tokens(p.candidates[k]) for k in LETTERS} for p in batch.rows]
    width = [({len(t) for t in tk.values()} or {0}) for tk in toks]
    scores: list = [None] * len(batch)
    for idx in batch.cells().values():
        for nf in sorted({len(toks[i]["A"]) for i in idx if len(width[i]) == 1} - {0}):
            rows = [i for i in idx if width[i] == {nf}]
            total = np.zeros((len(rows), len(LETTERS)))
            for f in range(nf):
                rates = _rates(batch, lambda i, k, f=f: toks[i][k][f], rows)
                total += np.log([[r[k] for k in LETTERS] for r in rates])
            for r, i in enumerate(rows):
                scores[i] = {k: float(total[r, q]) for q, k in enumerate(LETTERS)}
    return directional(batch, scores, directions=ENDS)


@attack("nearest_set", ["scalar", "trajectory"], "nearest neighbours over candidate sets: the candidate at the rank "
        "(or nearest to the relative value) the answers took in the five most similar candidate sets of other "
        "recordings of the same cell and question type", family="prior", scope="batch")
def _nearest_set(batch: Batch):
    vals = [value_scale(p) for p in batch.rows]
    by_rank: list = [None] * len(batch)
    by_value: list = [None] * len(batch)
    groups = batch.groups(lambda i: (batch.rows[i].task, batch.rows[i].source, question_kind(batch.obs[i]))
                          if vals[i] is not None else None)
    for idx in groups.values():
        X = np.array([[vals[i][k] for k in LETTERS] for i in idx], dtype=float)
        if not np.all(np.isfinite(X)):
            continue
        S = np.sort(X, axis=1)
        centre = S.mean(1, keepdims=True)
        spread = np.maximum(S.std(1, keepdims=True), 1e-9)
        ans = np.array([vals[i][batch.rows[i].answer] for i in idx])
        ans_rank = np.array([int((X[r] < ans[r] - 1e-12).sum()) for r in range(len(idx))])
        ans_rel = (ans - centre[:, 0]) / spread[:, 0]
        seqs = np.array([batch.obs[i].sequence for i in idx], dtype=object)
        D = np.sqrt(((S[:, None, :] - S[None, :, :]) ** 2).sum(-1))
        for r, i in enumerate(idx):
            d = D[r].copy()
            d[seqs == seqs[r]] = np.inf  # the row's own recording left out
            ok = np.flatnonzero(np.isfinite(d))
            if not len(ok):
                continue
            near = ok[np.lexsort((ok, d[ok]))][:NEIGHBOURS]
            votes = Counter(ans_rank[near].tolist())
            rank = {k: int((X[r] < X[r, q] - 1e-12).sum()) for q, k in enumerate(LETTERS)}
            by_rank[i] = top({k: float(votes.get(rank[k], 0)) for k in LETTERS})
            m = float(np.median(ans_rel[near]))
            rel = (X[r] - centre[r, 0]) / spread[r, 0]
            by_value[i] = top({k: -abs(float(rel[q]) - m) for q, k in enumerate(LETTERS)})
    return Directional({"rank": by_rank, "value": by_value})
