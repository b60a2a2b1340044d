"""The other rows' answers as a reference population, the row's own recording always left out.

Rules that read other rows' answers (a typical value, a majority label, a rate) compare a row's
candidates with the answers of *other source sequences*: the camera videos of one Waymo segment
share answers, so a row never learns from its own recording. A rule learned on one half of the
recordings and tested on the other (:func:`split_halves`) keeps its test exact.
"""

from __future__ import annotations

import zlib
from collections import Counter, defaultdict
from collections.abc import Callable

import numpy as np

from ... import LETTERS
from .batch import Batch
from .common import Directional, top
from .features import answer_key, labelled

MIN_NOUN_ROWS = 4  # condition on the subject noun when at least this many other rows share it


def bandwidth(x: np.ndarray) -> float:
    """The normal-reference bandwidth of a kernel density on the candidate values of a group (blind:
    no answer is used)."""
    x = x[np.isfinite(x)]
    if len(x) < 2:
        return 1.0
    sd = float(np.std(x))
    iqr = float(np.subtract(*np.percentile(x, [75, 25]))) / 1.34
    s = min(sd, iqr) if iqr > 0 else sd
    return max(0.9 * s * len(x) ** -0.2, 1e-6)


def loo_density(batch: Batch, values: list, pop_key, *, noun_key=None) -> list:
    """Per row: ``letter -> log density`` of each candidate's value among the answers' values of the rows
    with the same ``pop_key(i)`` from *other source sequences* (Gaussian kernel; bandwidth from all
    candidate values of the population, no answer used). With ``noun_key``, rows whose noun is shared
    by at least :data:`MIN_NOUN_ROWS` such rows use only those. ``values[i]``: ``letter -> float`` or
    None."""
    out: list = [None] * len(batch)
    groups = batch.groups(lambda i: pop_key(i) if values[i] is not None else None)
    for idx in groups.values():
        ans = np.array([values[i][batch.rows[i].answer] for i in idx])
        cands = np.array([[values[i][k] for k in LETTERS] for i in idx])
        seqs = np.array([batch.obs[i].sequence for i in idx], dtype=object)
        h = bandwidth(cands.ravel())
        nouns = np.array([noun_key(i) if noun_key else None for i in idx], dtype=object)
        for j, i in enumerate(idx):
            mask = seqs != seqs[j]  # leave the row's whole source sequence out
            if noun_key and nouns[j] is not None and int((mask & (nouns == nouns[j])).sum()) >= MIN_NOUN_ROWS:
                mask &= nouns == nouns[j]
            pop = ans[mask]
            if len(pop) == 0:
                continue
            z = (cands[j][:, None] - pop[None, :]) / h
            dens = np.exp(-0.5 * z * z).sum(1)
            out[i] = {k: float(np.log(d + 1e-300)) for k, d in zip(LETTERS, dens)}
    return out


def halves(batch: Batch) -> list[tuple[str, list, list]]:
    """The two halves of the source sequences (by a hash of the sequence name), as ``(direction name,
    training rows, test rows)``: ``"half 1 from half 0"`` tests the rows of half 1, then the reverse."""
    half = [zlib.crc32(str(o.sequence).encode("utf-8")) % 2 for o in batch.obs]
    out = []
    for test_half in (1, 0):
        train = [i for i, h in enumerate(half) if h != test_half]
        test = [i for i, h in enumerate(half) if h == test_half]
        out.append((f"half {test_half} from half {1 - test_half}", train, test))
    return out


def split_halves(batch: Batch, learn: Callable[[list, list], dict]) -> Directional:
    """A rule learned on one half of the source sequences and tested on the other, both ways: direction
    ``"half 1 from half 0"`` picks in the rows of half 1 with what ``learn(train, test)`` (row indices)
    returns for them (``{row: pick}``), and vice versa. A row's pick never depends on the answers of its
    own half, so each direction's test is exact; the table keeps the better one (Bonferroni over two)."""
    out = Directional()
    for name, train, test in halves(batch):
        picks: list = [None] * len(batch)
        for i, pk in learn(train, test).items():
            picks[i] = pk
        out[name] = picks
    return out


def majority_label(batch: Batch, train: list, test: list, key_of_row: Callable[[int], object]) -> dict:
    """For each test row: the candidates whose label (trajectory: structure) is the most frequent answer
    among the training rows with the same ``key_of_row`` (ties: every tied label); rows whose key has
    no training row are left out."""
    counts: dict = defaultdict(Counter)
    for i in train:
        k = key_of_row(i)
        if k is not None and labelled(batch.rows[i]):
            p = batch.rows[i]
            counts[k][answer_key(p.values[p.answer])] += 1
    out = {}
    for i in test:
        k = key_of_row(i)
        p = batch.rows[i]
        if k is None or k not in counts or not labelled(p):
            continue
        out[i] = top({c: float(counts[k].get(answer_key(v), 0)) for c, v in p.values.items()})
    return out


# ------------------------------------------------------------------------------------ population features

POPULATION_BLOCK = 256  # rows whose (rows, reference) matrices are held at once (memory, not results)
POPULATION_FEATURES = ("answer_quantile", "candidate_quantile", "answer_density", "candidate_density",
                       "density_ratio", "answer_z")


def population_features(batch: Batch, values: list, group_of: list, reference: np.ndarray) -> np.ndarray:
    """Where each candidate stands in its population, against the answers of the ``reference`` rows
    only (a boolean mask over the batch: a learned attacker's training fold) and never against its own
    recording: (n_rows * 5, :data:`POPULATION_FEATURES`) in letter order, NaN where ``values[i]``
    (``letter -> float``) or ``group_of[i]`` is None or the group has no reference answer.

    Per candidate value x, among the reference rows of the same group from other recordings: the
    quantile of x among their answers and among their candidates (mid-ranks), the log kernel density
    of their answers and of their candidates at x (bandwidth from the group's candidates), the log ratio
    of the two (where answers are denser than distractors), and x standardised by their answers'
    mean and standard deviation (at least the bandwidth).
    """
    out = np.full((len(batch) * 5, len(POPULATION_FEATURES)), np.nan)
    groups = batch.groups(lambda i: group_of[i] if values[i] is not None else None)
    for idx in groups.values():
        X = np.array([[values[i][k] for k in LETTERS] for i in idx], dtype=float)
        seq = np.array([batch.obs[i].sequence for i in idx], dtype=object)
        ref = np.array([bool(reference[i]) for i in idx])
        if not ref.any():
            continue
        ans = np.array([values[i][batch.rows[i].answer] for i in idx], dtype=float)[ref]
        cands = X[ref].ravel()
        seq_a, seq_c = seq[ref], np.repeat(seq[ref], 5)
        h = bandwidth(X.ravel())
        # the reference answers' mean and spread without the row's recording, from per-recording sums
        codes, inv = np.unique(np.concatenate([seq_a, seq]).astype(str), return_inverse=True)
        own = inv[len(ans):]
        n_own = np.bincount(inv[:len(ans)], minlength=len(codes))[own]
        s1 = ans.sum() - np.bincount(inv[:len(ans)], weights=ans, minlength=len(codes))[own]
        s2 = (ans ** 2).sum() - np.bincount(inv[:len(ans)], weights=ans ** 2, minlength=len(codes))[own]
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = s1 / (len(ans) - n_own)
            sd = np.sqrt(np.maximum(s2 / (len(ans) - n_own) - mean ** 2, 0.0))
        rows = np.array(idx)
        # rows in blocks: the (rows, reference) matrices of a block, never of the whole group at once
        for lo in range(0, len(idx), POPULATION_BLOCK):
            b = slice(lo, lo + POPULATION_BLOCK)
            Ma = (seq[b, None] != seq_a[None, :]).astype(float)            # (B, Ra): other recordings only
            Mc = (seq[b, None] != seq_c[None, :]).astype(float)            # (B, Rc)
            na, nc = Ma.sum(1), Mc.sum(1)
            with np.errstate(invalid="ignore", divide="ignore"):
                for k in range(5):
                    x = X[b, k]
                    da = x[:, None] - ans[None, :]
                    dc = x[:, None] - cands[None, :]
                    qa = (((da > 0) + 0.5 * (da == 0)) * Ma).sum(1) / na
                    qc = (((dc > 0) + 0.5 * (dc == 0)) * Mc).sum(1) / nc
                    fa = np.log((np.exp(-0.5 * (da / h) ** 2) * Ma).sum(1) / na + 1e-12)
                    fc = np.log((np.exp(-0.5 * (dc / h) ** 2) * Mc).sum(1) / nc + 1e-12)
                    feats = np.column_stack([qa, qc, fa, fc, fa - fc, (x - mean[b]) / np.maximum(sd[b], h)])
                    feats[na == 0] = np.nan
                    out[rows[b] * 5 + k] = feats
    return out
