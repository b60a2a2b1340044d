"""Attack families that read the candidates against each other and against the release's answers:
formatting tells (family ``format``) and field typicality (family ``typicality``).

Formatting tells
    A candidate printed from exact source values and one printed from arithmetic on them can differ
    in how they are written, not in what they say: fewer decimals (a trailing zero dropped by a JSON
    writer), more last digits 0, a negative zero, other significant digits, another key order or
    spacing, or last digits that differ from the other candidates' at the same field. Each tell is a
    per-candidate count (or the size of the candidate's layout class); the attack picks the
    candidates at the extreme. Whether the answer sits at the high or the low end is not known in
    advance, so the direction is chosen per row from the other rows of its task/source cell
    (:func:`resti_lib.options.attacks.directional`).

Field typicality
    Real answers have correlated fields (a box's length, width and height; a camera's translation
    and rotation over one interval). Distractors drawn field by field are atypical combinations.
    Each attack fits a Gaussian to the answers of the cell's rows from other source sequences (in
    log units where sizes are multiplicative) and scores each candidate by its Mahalanobis
    distance, in every direction (most or least typical, or a middle rank) as above.
"""

from __future__ import annotations

import re
from collections import Counter

import numpy as np

from .. import LETTERS
from .. import values as V
from .attacks import Batch, attack, directional

NUMERIC = ("scalar", "box", "pose", "trajectory")


def _tokens(s: str) -> list[str]:
    return V.number_tokens(s)


def _decimals(tok: str) -> int:
    t = tok.lower().split("e")[0]
    return len(t.split(".", 1)[1]) if "." in t else 0


def _digits(tok: str) -> str:
    return re.sub(r"[^0-9]", "", tok.lower().split("e")[0])


def _is_negative_zero(tok: str) -> bool:
    return tok.startswith("-") and not _digits(tok).strip("0")


def _significant(tok: str) -> int:
    return len(_digits(tok).lstrip("0"))


def skeleton(s: str) -> str:
    """The layout of a printed value: every digit run replaced by ``9`` (key order, spacing, signs and
    separators remain)."""
    return re.sub(r"\d+", "9", str(s))


def _numeric(p) -> bool:
    return all(v.kind in NUMERIC for v in p.values.values())


def _per_candidate(batch: Batch, feature) -> list:
    """``letter -> feature(candidate string)`` for numeric rows, None for the others."""
    out = []
    for p in batch.rows:
        out.append({k: float(feature(p.candidates[k])) for k in LETTERS} if _numeric(p) else None)
    return out


def _class_sizes(batch: Batch, key) -> list:
    """``letter -> size of the candidate's class`` under ``key(candidate string)``: a small class is an
    odd one out, a large one the common form."""
    out = []
    for p in batch.rows:
        if not _numeric(p):
            out.append(None)
            continue
        keys = {k: key(p.candidates[k]) for k in LETTERS}
        c = Counter(keys.values())
        out.append({k: float(c[keys[k]]) for k in LETTERS})
    return out


@attack("fmt_negative_zero", NUMERIC, "candidates whose count of printed negative zeros (-0, -0.0) is the odd "
        "one out or the common one (in every direction)", family="format", scope="batch")
def _neg_zero(batch: Batch):
    return directional(batch, _class_sizes(batch, lambda s: sum(_is_negative_zero(t) for t in _tokens(s))))


@attack("fmt_layout", NUMERIC, "candidates whose layout (key order, spacing, signs, separators) is the odd one out "
        "or the common one (in every direction)", family="format", scope="batch")
def _layout(batch: Batch):
    return directional(batch, _class_sizes(batch, skeleton))


@attack("fmt_zero_last_digits", NUMERIC, "most or fewest printed numbers ending in 0 (in every direction)",
        family="format", scope="batch")
def _zero_last(batch: Batch):
    return directional(batch, _per_candidate(batch, lambda s: sum(_digits(t)[-1:] == "0" for t in _tokens(s))))


@attack("fmt_decimals", NUMERIC, "most or fewest printed decimals in total (in every direction)",
        family="format", scope="batch")
def _decimals_attack(batch: Batch):
    return directional(batch, _per_candidate(batch, lambda s: sum(_decimals(t) for t in _tokens(s))))


@attack("fmt_significant_digits", NUMERIC, "most or fewest significant digits in total (in every direction)",
        family="format", scope="batch")
def _sig(batch: Batch):
    return directional(batch, _per_candidate(batch, lambda s: sum(_significant(t) for t in _tokens(s))))


def _last_digit_odd(p) -> dict | None:
    """Per candidate: at how many printed fields its last digit differs from every other candidate's last
    digit at the same field (rows whose candidates print different numbers of fields: None)."""
    toks = {k: _tokens(p.candidates[k]) for k in LETTERS}
    n = {len(t) for t in toks.values()}
    if len(n) != 1 or n == {0}:
        return None
    last = np.array([[(_digits(t)[-1:] or "x") for t in toks[k]] for k in LETTERS])
    same = (last[:, None, :] == last[None, :, :]).sum(1) - 1  # other candidates sharing the digit
    return {k: float((same[i] == 0).sum()) for i, k in enumerate(LETTERS)}


@attack("fmt_last_digit_odd", NUMERIC, "most or fewest fields whose last printed digit differs from every other "
        "candidate's at that field (in every direction)", family="format", scope="batch")
def _last_odd(batch: Batch):
    return directional(batch, [(_last_digit_odd(p) if _numeric(p) else None) for p in batch.rows])


# ------------------------------------------------------------------------------------ field typicality

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
    from .readers import premise_parts

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
