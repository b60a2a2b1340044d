"""Family ``typicality``: how typical a candidate is of the other rows' answers.

Real answers have correlated fields (a box's length, width and height; a camera's translation and
rotation over one interval). Distractors drawn field by field are atypical combinations. Each attack
fits a Gaussian to the answers of the cell's rows from other source sequences (in log units where sizes
are multiplicative) and scores each candidate by its Mahalanobis distance, in every direction (most or
least typical, or a middle rank). ``answer_reuse`` counts how often a candidate's value is the answer of
another recording of the cell.
"""

from __future__ import annotations

from collections import Counter, defaultdict

import numpy as np

from ... import LETTERS
from ... import values as V
from .batch import Batch
from .common import directional
from .features import numeric_row, premise_parts
from .registry import attack


@attack("answer_reuse", ["scalar", "box", "pose", "trajectory"], "candidates whose value is (or is not) the answer "
        "of a row of another source sequence in the task/source cell: distractors drawn from the other rows' "
        "answers leave the answer the one fresh value (in every direction)", family="typicality", scope="batch")
def _answer_reuse(batch: Batch):
    scores: list = [None] * len(batch)
    for idx in batch.cells().values():
        answers = Counter(batch.rows[i].values[batch.rows[i].answer].key() for i in idx)
        by_seq: dict = defaultdict(Counter)
        for i in idx:
            by_seq[batch.obs[i].sequence][batch.rows[i].values[batch.rows[i].answer].key()] += 1
        for i in idx:
            p = batch.rows[i]
            if not numeric_row(p):
                continue
            own = by_seq[batch.obs[i].sequence]  # leave the row's source sequence out
            scores[i] = {k: float(answers.get(v.key(), 0) - own.get(v.key(), 0)) for k, v in p.values.items()}
    return directional(batch, scores)


def loo_gaussian_scores(batch: Batch, feats: list, *, group=None, shrink: float = 0.1) -> list:
    """Per row: ``letter -> -(Mahalanobis distance)²`` of each candidate's feature vector under a Gaussian
    fitted to the answers' vectors of the rows of its group (default: task/source cell) from *other
    source sequences*.

    ``feats[i]`` is ``letter -> vector`` (all of one length) or None. The covariance is shrunk towards
    its diagonal by ``shrink`` and floored, so small groups stay well-conditioned; a group with fewer
    than ``dim + 3`` such rows gives None.
    """
    groups = batch.cells() if group is None else group
    out: list = [None] * len(batch)
    for idx in groups.values():
        idx = [i for i in idx if feats[i] is not None]
        if not idx:
            continue
        A = np.array([feats[i][batch.rows[i].answer] for i in idx], dtype=float)
        ok = np.all(np.isfinite(A), axis=1)
        idx = [i for i, o in zip(idx, ok) if o]
        A = A[ok]
        m, d = A.shape if len(A) else (0, 0)
        if m - 1 < d + 3:
            continue
        s1, s2 = A.sum(0), A.T @ A
        seqs = np.array([batch.obs[i].sequence for i in idx], dtype=object)
        for j, i in enumerate(idx):
            same = seqs == seqs[j]  # leave the row's whole source sequence out
            n = m - int(same.sum())
            if n < d + 3:
                continue
            a1, a2 = A[same].sum(0), A[same].T @ A[same]
            mu = (s1 - a1) / n
            cov = (s2 - a2) / n - np.outer(mu, mu)
            cov = (1 - shrink) * cov + shrink * np.diag(np.diag(cov))
            cov += np.eye(d) * max(1e-9, 1e-6 * float(np.trace(cov)) / d)
            inv = np.linalg.inv(cov)
            X = np.array([feats[i][k] for k in LETTERS], dtype=float)
            if not np.all(np.isfinite(X)):
                continue
            D = X - mu
            out[i] = {k: -float(D[q] @ inv @ D[q]) for q, k in enumerate(LETTERS)}
    return out


def _boxes(p) -> bool:
    return all(isinstance(v, V.Box) for v in p.values.values())


@attack("typical_box_size", ["box"], "box whose (log length, log width, log height) is most or least typical of "
        "the answers of other source sequences (Gaussian; in every direction)", family="typicality",
        scope="batch")
def _typical_box_size(batch: Batch):
    feats = [({k: np.log(np.maximum(np.array(p.values[k].lwh, float), 1e-6)) for k in LETTERS} if _boxes(p) else None)
             for p in batch.rows]
    return directional(batch, loo_gaussian_scores(batch, feats))


@attack("typical_box_rotation", ["box"], "box whose rotation (the nine entries of the box-to-camera matrix) is most "
        "or least typical of the other rows' answers: real boxes stand on the ground, so their up axis follows "
        "gravity in the camera frame (in every direction)", family="typicality", scope="batch")
def _typical_box_rotation(batch: Batch):
    feats = [({k: np.array(p.values[k].R, float).ravel() for k in LETTERS}
              if _boxes(p) and all(v.R is not None for v in p.values.values()) else None) for p in batch.rows]
    return directional(batch, loo_gaussian_scores(batch, feats))


def _placement(v) -> np.ndarray:
    c = np.array(v.center, float)
    if c[2] <= 1e-6:
        return np.full(3, np.nan)
    return np.array([c[0] / c[2], c[1] / c[2], np.log(c[2])])


@attack("typical_box_placement", ["box"], "box whose image direction and log depth (x/z, y/z, log z) is most or "
        "least typical of the other rows' answers (in every direction)", family="typicality", scope="batch")
def _typical_box_placement(batch: Batch):
    feats = [({k: _placement(p.values[k]) for k in LETTERS} if _boxes(p) else None) for p in batch.rows]
    return directional(batch, loo_gaussian_scores(batch, feats))


def _rel_motion(v: V.Pose, o) -> np.ndarray:
    """(log translation length, rotation angle in degrees) of a pose relative to the question's premise
    pose (or to the identity when it prints none)."""
    t, R = np.array(v.t, float), np.array(v.R, float)
    prem = premise_parts(o)
    if prem is not None:
        t = t - prem[0]
        R = prem[1].T @ R
    ang = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)))
    return np.array([np.log(np.linalg.norm(t) + 1e-3), ang])


@attack("typical_pose_motion", ["pose"], "pose whose (log translation, rotation angle) from the premise pose is "
        "most or least typical of the other rows' answers (in every direction)", family="typicality",
        scope="batch")
def _typical_pose_motion(batch: Batch):
    feats = []
    for p, o in zip(batch.rows, batch.obs):
        if all(isinstance(v, V.Pose) for v in p.values.values()):
            feats.append({k: _rel_motion(p.values[k], o) for k in LETTERS})
        else:
            feats.append(None)
    return directional(batch, loo_gaussian_scores(batch, feats))
