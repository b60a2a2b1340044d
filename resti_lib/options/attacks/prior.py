"""Family ``prior``: what the other recordings of the release say about a printed candidate.

Every rule here is learned on one half of the recordings (source sequences) and tested on the other,
both ways (:func:`resti_lib.options.attacks.reference.split_halves`): a rate or a neighbour learned
leaving only the row's own recording out would make the rows choose for each other, and rows that
share their luck make a binomial test far too confident (two labels near a tie at the bottom of a
leave-one-out count hand every row its own answer).

- ``string_rate``: how often a candidate's printed string (``string``, anywhere in the release) or
  value (``value``, among questions of the same quantity) is the answer when it is offered, shrunk
  towards chance; the candidate of highest (or lowest) rate;
- ``field_rate``: the same rate per printed field (the j-th number of the candidate, e.g. a pose's
  ``r31``) within the task/source cell, summed in log over the fields (a field prior);
- ``field_density``: a field prior on values: per printed field of a box or a pose, the kernel
  density of the candidate's value among the answers of the other half (or its ratio to the density
  among their candidates), summed in log over the fields;
- ``nearest_set``: nearest neighbours over candidate sets: the five rows of the other half of the
  cell (same question type) whose sorted candidate values lie nearest to the row's; the candidate at
  the rank their answers took most often (``rank``) or nearest to their answers' median relative to
  their sets (``value``);
- ``answer_echo``: the echo of each answer in the other recordings' distractors: the candidate where
  the answers of the recordings before the row's (in a fixed order, so the test stays exact) are least
  dense relative to the candidates of every other recording, at a narrow and a wide kernel.
"""

from __future__ import annotations

import zlib
from collections import Counter

import numpy as np

from ... import LETTERS
from ... import values as V
from .batch import Batch
from .common import CHANCE, ENDS, Directional, extreme
from .features import flat_text, question_kind, tokens, value_scale
from .reference import bandwidth, halves
from .registry import attack

SHRINK = 2.0       # pseudo-offers at chance added to every rate (a string offered once says little)
NEIGHBOURS = 5


def _rates(batch: Batch, key_of, train: list, test: list) -> dict:
    """Per test row: ``letter -> rate`` at which the candidate's key (``key_of(i, letter)``; None: the row
    has no rate) is the answer when offered in the training rows: (answers + SHRINK/5) / (offers + SHRINK)."""
    offered: Counter = Counter()
    answered: Counter = Counter()
    for i in train:
        p = batch.rows[i]
        for k in LETTERS:
            x = key_of(i, k)
            if x is not None:
                offered[x] += 1
                answered[x] += k == p.answer
    out = {}
    for i in test:
        ks = {k: key_of(i, k) for k in LETTERS}
        if any(x is None for x in ks.values()):
            continue
        out[i] = {k: (answered[x] + SHRINK * CHANCE) / (offered[x] + SHRINK) for k, x in ks.items()}
    return out


def _halves(batch: Batch, variants: tuple, scores_of, ends=ENDS) -> Directional:
    """Rules learned on one half and tested on the other (:func:`reference.halves`): ``scores_of(train,
    test)`` returns ``{variant: {row: letter -> score}}``, once per half; one direction per (half,
    variant, end)."""
    out = Directional()
    for half, train, test in halves(batch):
        scores = scores_of(train, test)
        for variant in variants:
            for end in ends:
                picks: list = [None] * len(batch)
                for i, sc in scores[variant].items():
                    picks[i] = extreme(sc, end)
                out[" ".join(x for x in (variant, end, half) if x)] = picks
    return out


@attack("string_rate", ["any"], "candidate whose printed string (anywhere in the release) or value (same quantity) "
        "is most (or least) often the answer where it is offered in the other half of the recordings (in every "
        "direction)", family="prior", scope="batch")
def _string_rate(batch: Batch):
    string = lambda i, k: flat_text(batch.rows[i].candidates[k])
    value = lambda i, k: (batch.obs[i].quantity, batch.rows[i].values[k].key())
    return _halves(batch, ("string", "value"), lambda train, test: {
        "string": _rates(batch, string, train, test), "value": _rates(batch, value, train, test)})


def _field_scores(batch: Batch, train: list, test: list) -> dict:
    """Per test row of a cell whose candidates print the same number of fields: the sum over the fields of
    the log rate of the candidate's printed field among the training rows of the cell."""
    toks = batch.memo("prior_tokens", lambda: [{k: tokens(p.candidates[k]) for k in LETTERS} for p in batch.rows])
    width = [({len(t) for t in tk.values()} or {0}) for tk in toks]
    cell = lambda i: (batch.rows[i].task, batch.rows[i].source, next(iter(width[i])) if len(width[i]) == 1 else None)
    key = lambda i, k, f: (cell(i), f, toks[i][k][f]) if cell(i)[2] and f < cell(i)[2] else None
    n_fields = max((c[2] or 0) for c in map(cell, test)) if test else 0
    out: dict = {}
    for f in range(n_fields):
        for i, r in _rates(batch, lambda i, k, f=f: key(i, k, f), train,
                           [i for i in test if (cell(i)[2] or 0) > f]).items():
            acc = out.setdefault(i, dict.fromkeys(LETTERS, 0.0))
            for k in LETTERS:
                acc[k] += float(np.log(r[k]))
    return out


@attack("field_rate", ["scalar", "box", "pose", "trajectory"], "candidate whose printed fields (the j-th number of "
        "each candidate) are most (or least) often the answer's where offered in the other half of the recordings "
        "of the task/source cell, summed in log over the fields (in every direction)", family="prior",
        scope="batch")
def _field_rate(batch: Batch):
    return _halves(batch, ("",), lambda train, test: {"": _field_scores(batch, train, test)})


JOINT_NEIGHBOURS = 10  # training candidates nearest a candidate, all its printed fields at once


def _field_densities(batch: Batch, train: list, test: list) -> tuple[dict, dict, dict]:
    """Per test row of a cell of structured answers (boxes, poses: every candidate prints the same fields):
    the sum over the fields of the log kernel density of the candidate's field value among the training
    rows' answers (``density``), and of its ratio to the density among their candidates (``ratio``); and,
    every field at once, the share of answers among the :data:`JOINT_NEIGHBOURS` training candidates nearest
    it (``joint``: each field in units of its spread over the training candidates). Fields that match the
    answers' one by one can still combine where no answer is (a camera's turn and its roll about a desk):
    the joint share reads that."""
    vecs = batch.memo("prior_vectors", lambda: [
        np.array([p.values[k].vector() for k in LETTERS], float)
        if all(isinstance(v, (V.Box, V.Pose)) for v in p.values.values())
        and len({len(v.vector()) for v in p.values.values()}) == 1 else None for p in batch.rows])
    cell = lambda i: (batch.rows[i].task, batch.rows[i].source, vecs[i].shape[1]) if vecs[i] is not None else None
    density, ratio, joint = {}, {}, {}
    pool: dict = {}
    for i in train:
        if cell(i) is not None:
            pool.setdefault(cell(i), []).append(i)
    for g, idx in pool.items():
        rows = [i for i in test if cell(i) == g]
        if not rows:
            continue
        C = np.stack([vecs[i] for i in idx])                                  # (m, 5, F)
        A = np.stack([vecs[i][LETTERS.index(batch.rows[i].answer)] for i in idx])  # (m, F)
        T = np.stack([vecs[i] for i in rows])                                 # (t, 5, F)
        logd, logr = np.zeros(T.shape[:2]), np.zeros(T.shape[:2])
        for f in range(T.shape[2]):
            h = bandwidth(C[:, :, f].ravel())
            fa = np.exp(-0.5 * ((T[:, :, f, None] - A[None, None, :, f]) / h) ** 2).mean(-1)
            fc = np.exp(-0.5 * ((T[:, :, f, None] - C[:, :, f].ravel()[None, None, :]) / h) ** 2).mean(-1)
            logd += np.log(fa + 1e-12)
            logr += np.log(fa + 1e-12) - np.log(fc + 1e-12)
        flat = C.reshape(-1, C.shape[2])
        is_answer = np.zeros(C.shape[:2], bool)
        is_answer[np.arange(len(idx)), [LETTERS.index(batch.rows[i].answer) for i in idx]] = True
        is_answer = is_answer.ravel()                                           # in the order of ``flat``
        sd = np.maximum(flat.std(axis=0), 1e-9)
        k_near = min(JOINT_NEIGHBOURS, len(flat))
        for r, i in enumerate(rows):
            density[i] = {k: float(logd[r, q]) for q, k in enumerate(LETTERS)}
            ratio[i] = {k: float(logr[r, q]) for q, k in enumerate(LETTERS)}
            d = (((T[r][:, None, :] - flat[None, :, :]) / sd) ** 2).sum(-1)       # (5, m*5)
            near = np.argsort(d, axis=1, kind="stable")[:, :k_near]
            joint[i] = {k: float(is_answer[near[q]].mean()) for q, k in enumerate(LETTERS)}
    return density, ratio, joint


@attack("field_density", ["box", "pose"], "box or pose whose printed fields are most (or least) typical, field by "
        "field, of the answers of the other half of the recordings of the task/source cell (log kernel density "
        "summed over the fields, or its ratio to the density of their candidates), or all fields at once (the "
        "share of answers among its nearest candidates there; in every direction)",
        family="prior", scope="batch")
def _field_density(batch: Batch):
    return _halves(batch, ("density", "ratio", "joint"),
                   lambda train, test: dict(zip(("density", "ratio", "joint"), _field_densities(batch, train, test))))


def _scaled(batch: Batch) -> tuple[list, object]:
    """Each row's candidate values on their scale (:func:`value_scale`; None for other kinds), and the
    key of the rows one rule compares: task, source and question type, for rows whose values are all
    finite (None otherwise)."""
    vals = batch.memo("prior_values", lambda: [value_scale(p) for p in batch.rows])
    key = lambda i: (batch.rows[i].task, batch.rows[i].source, question_kind(batch.obs[i])) \
        if vals[i] is not None and all(np.isfinite(list(vals[i].values()))) else None
    return vals, key


def _nearest_sets(batch: Batch, train: list, test: list) -> tuple[dict, dict]:
    """Per test row: rank votes and relative-value closeness of its candidates from the answers of its five
    nearest training rows (sorted candidate values; same cell and question type)."""
    vals, key = _scaled(batch)
    by_rank, by_value = {}, {}
    pool: dict = {}
    for i in train:
        if key(i) is not None:
            pool.setdefault(key(i), []).append(i)
    for g, idx in pool.items():
        X = np.array([[vals[i][k] for k in LETTERS] for i in idx])
        S = np.sort(X, axis=1)
        centre, spread = S.mean(1), np.maximum(S.std(1), 1e-9)
        ans = np.array([vals[i][batch.rows[i].answer] for i in idx])
        ans_rank = (X < ans[:, None] - 1e-12).sum(1)
        ans_rel = (ans - centre) / spread
        for i in (j for j in test if key(j) == g):
            x = np.array([vals[i][k] for k in LETTERS])
            d = np.sqrt(((S - np.sort(x)) ** 2).sum(1))
            near = np.lexsort((np.arange(len(d)), d))[:NEIGHBOURS]
            votes = Counter(ans_rank[near].tolist())
            rank = (x[None, :] < x[:, None] - 1e-12).sum(1)
            by_rank[i] = {k: float(votes.get(int(rank[q]), 0)) for q, k in enumerate(LETTERS)}
            rel = (x - x.mean()) / max(float(x.std()), 1e-9)
            by_value[i] = {k: -abs(float(rel[q]) - float(np.median(ans_rel[near]))) for q, k in enumerate(LETTERS)}
    return by_rank, by_value


@attack("nearest_set", ["scalar", "trajectory"], "nearest neighbours over candidate sets: the candidate at the rank "
        "(or nearest to the relative value) the answers took in the five most similar candidate sets of the other "
        "half of the recordings (same cell and question type)", family="prior", scope="batch")
def _nearest_set(batch: Batch):
    return _halves(batch, ("rank", "value"),
                   lambda train, test: dict(zip(("rank", "value"), _nearest_sets(batch, train, test))), ends=("max",))



ECHO_WIDTHS = (0.02, 0.2)  # kernel widths of the echo rule, as shares of the group's spread of candidate values
ECHO_BLOCK = 16            # rows whose (candidates x reference values) kernels are held at once (within cache)


def kernel_sums(x: np.ndarray, ref: np.ndarray, keep: np.ndarray, h: float, *, first: bool = False):
    """``out[i, q] = sum_j keep[i, j] * sum_r K((x[i, q] - ref[j, r]) / h)``: Gaussian kernels of the values
    ``x`` (n, 5) over the reference rows ``ref`` (m, R) that ``keep`` (n, m) allows, in blocks of
    :data:`ECHO_BLOCK` rows (each row's sums are the same in any block). ``first``: also the sums over the first
    reference column alone (``ref[:, :1]``), from the same kernels (a pair ``(out, out_first)``)."""
    out = np.zeros(x.shape)
    out1 = np.zeros(x.shape) if first else None
    for s in range(0, len(x), ECHO_BLOCK):
        e = np.subtract(x[s:s + ECHO_BLOCK, :, None, None], ref[None, None, :, :])   # (b, 5, m, R), in place:
        e /= h
        np.multiply(e, e, out=e)
        e *= -0.5                                                                  # -z*z/2 (exact halving)
        np.exp(e, out=e)
        k = keep[s:s + ECHO_BLOCK, None, :]
        out[s:s + ECHO_BLOCK] = (e.sum(-1) * k).sum(-1)
        if first:
            out1[s:s + ECHO_BLOCK] = (e[..., 0] * k).sum(-1)
    return (out, out1) if first else out


def _echo_scores(batch: Batch) -> Directional:
    """Per width of :data:`ECHO_WIDTHS`: in each group of rows of one cell and question type, the candidate
    where the answers of the earlier recordings are least dense relative to the candidates of every other
    recording (:func:`_answer_echo`)."""
    vals, key = _scaled(batch)
    out = Directional({f"width {w:g}": [None] * len(batch) for w in ECHO_WIDTHS})
    for idx in batch.groups(key).values():
        X = np.array([[vals[i][k] for k in LETTERS] for i in idx])
        A = np.array([vals[i][batch.rows[i].answer] for i in idx])[:, None]
        seq = [str(batch.obs[i].sequence) for i in idx]
        # recordings in a fixed order (a hash of the name, then the name): a row reads the answers before its own
        rank = {r: n for n, r in enumerate(sorted(set(seq), key=lambda r: (zlib.crc32(r.encode("utf-8")), r)))}
        pos = np.array([rank[r] for r in seq])
        other = pos[:, None] != pos[None, :]
        earlier = pos[:, None] > pos[None, :]
        spread = float(np.std(X))
        for w in ECHO_WIDTHS:
            h = max(w * spread, 1e-9)
            fc = kernel_sums(X, X, other, h)
            fa = kernel_sums(X, A, earlier, h)
            score = np.log(fa + 1e-12) - np.log(fc + 1e-12)
            for r, i in enumerate(idx):
                if earlier[r].any():
                    out[f"width {w:g}"][i] = extreme({k: float(score[r, q]) for q, k in enumerate(LETTERS)}, "min")
    return out


@attack("answer_echo", ["scalar", "trajectory"], "the echo of each answer in the other recordings' distractors: the "
        "candidate where the answers of the recordings before the row's (a fixed order) are least dense relative to "
        "the candidates of every other recording (narrow and wide kernels)", family="prior", scope="batch")
def _answer_echo(batch: Batch):
    """A generator that draws a row's distractors from a kernel density of the other rows' answers leaves a
    bump at every answer: the other rows' distractors crowd where this row's answer is, while no other
    answer need be there. Where a distractor sits, the answer it was drawn around is near. So the answer is
    the candidate where other recordings' candidates outnumber their answers most.

    The test is exact though every row reads other rows' answers: a row reads the candidate sets of every
    other recording (no answer key) and the answers of the recordings *before* its own in a fixed order.
    Under the null (each row's answer is any of its five candidates with probability 1/5, whatever the
    candidate sets), a row's hit has probability 1/5 given every earlier row's hit, so the hits are
    independent and their count binomial. Reading every other recording's answers (leave-one-recording-out)
    would make rows choose for each other: on v5's Waymo speeds the count's spread over permuted answer
    letters was 3.9-4.6 hits against the binomial's 3.2."""
    return _echo_scores(batch)
