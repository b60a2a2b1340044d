"""Learned blind attackers: classifiers that score each candidate without the video.

Families ``learned_option`` and ``learned_question``. Where the rule attacks test one shortcut each, these attackers
combine them and learn regularities across rows. Two attacks are registered:

``learned_blind`` (family ``learned_option``)
    sees, per candidate, only features computed from the row's five candidate strings and the row's
    task, source and letter layout:

    - the parsed value summaries of the candidate (scalar value and its logarithm, angle, trajectory
      totals, box centre / log-dimensions / heading, pose translation / rotation angle), and for each
      summary the candidate's rank in the row, the gaps to its neighbours, its distance to the row
      mean (standardised) and to the row medoid;
    - for boxes and poses: distances to the centroid of each field group and the medoid scores, the
      per-field median and modal votes (the rule attacks' statistics), the printed rotation entries,
      and camera geometry (is a box centre in view; does a camera look where the reference camera
      looks);
    - string length and digit count (absolute and relative to the row), the letter, the task and
      source (one-hot), the relation label (one-hot), the trajectory phrase structure, and the
      letter-order concordance of the ``letter_order`` attack.

``learned_question`` (family ``learned_question``)
    sees the same candidate features plus the question's: the measured quantity, instant or interval,
    camera or another subject, the window, whether it prints a premise pose, hashed words of the
    question text and the hashed subject noun (:mod:`resti_lib.options.observables`), and per
    candidate the rate it implies over the window and its distance to the premise pose.

A gradient-boosting classifier (scikit-learn, fixed ``random_state``, one thread) is trained on
candidate rows with label "is the keyed candidate" and evaluated out of fold with
:class:`~sklearn.model_selection.GroupKFold` on the rows' **source sequence** (read from the video
name, or given as ``groups``): no sequence is in a training and a test fold at once, so the camera
videos of one Waymo segment, which share answers, cannot leak into each other. The pick of a row is
the set of candidates with the highest out-of-fold score (a tie is scored by its expected accuracy).
"""

from __future__ import annotations

import math
import re
import warnings
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ... import LETTERS, SOURCES
from ... import values as V
from ...geometry.frames import nearest_rotation
from ..checks import ParsedRow
from .batch import Batch, make_batch
from .common import top
from .features import (
    decimals,
    implied_rate,
    last_digit,
    noun_of,
    order_concordance,
    premise_parts,
    question_kind,
    repeats_premise,
    rot_angle,
    significant_stripped,
    tokens,
    value_scale,
)
from .reference import population_features
from .registry import ATTACKS, attack, select
from .scoring import attack_table, picks_frame

NAME = "learned_blind"
QUESTION_NAME = "learned_question"
SUMMARY_SLOTS = 9  # numeric summaries per candidate (kind-specific; NaN where absent)
FIT_THREADS = 2    # threads that grow the population attacker's trees (a tree does not depend on them)
FOLD_THREADS = 2   # cross-validation folds fitted side by side (a fold's scores do not depend on them)
LABELS = tuple(V.RELATION_LABELS)


@dataclass(frozen=True)
class LearnedConfig:
    """Classifier and cross-validation settings (all literal, so runs are reproducible)."""

    model: str = "gradient_boosting"  # or "random_forest"
    n_splits: int = 5
    random_state: int = 0
    max_iter: int = 60
    learning_rate: float = 0.15
    max_leaf_nodes: int = 15
    min_samples_leaf: int = 8
    n_estimators: int = 300
    population_model: str = "random_forest"  # the population attacker's classifier (or "gradient_boosting")
    population_trees: int = 60
    population_min_leaf: int = 8


# ------------------------------------------------------------------------------------ features

def _summaries(p: ParsedRow) -> np.ndarray:
    """(5, SUMMARY_SLOTS) kind-specific numeric summaries of the candidates in letter order."""
    out = np.full((5, SUMMARY_SLOTS), np.nan)
    vals = [p.values[k] for k in LETTERS]
    for i, v in enumerate(vals):
        if isinstance(v, V.Scalar):
            if v.is_angle:
                out[i, :3] = [v.value, abs(v.value), math.cos(math.radians(v.value))]
            else:
                out[i, :2] = [v.si, math.log10(abs(v.si) + 1e-3)]
        elif isinstance(v, V.Trajectory):
            turns = [abs(x) for k, x in v.segments if k == "turn"]
            moves = [x for k, x in v.segments if k == "move"]
            out[i, :5] = [v.total_distance, math.log10(v.total_distance + 1e-3), len(v.segments),
                          sum(turns), max(moves) if moves else 0.0]
        elif isinstance(v, V.Box):
            c, d = np.array(v.center), np.log(np.maximum(np.array(v.lwh), 1e-6))
            out[i, :9] = [*c, *d, v.heading if v.heading is not None else np.nan,
                          float(d.sum()), float(np.linalg.norm(c))]
        elif isinstance(v, V.Pose):
            t, R = np.array(v.t), np.array(v.R)
            ang = math.degrees(rot_angle(np.eye(3), nearest_rotation(R)))
            out[i, :9] = [*t, float(np.linalg.norm(t)), ang, *R[2], float(np.trace(R))]
    return out


def _geometry(p: ParsedRow) -> tuple[np.ndarray, np.ndarray]:
    """Camera geometry of boxes and poses: (5, 3) summaries with within-row statistics, and the
    (5, 9) printed rotation entries.

    Boxes: the image-plane direction of the centre (x/z, y/z) and its largest magnitude (is it
    in view). Poses: the distance between the candidate's optical axis and the reference camera's
    (+Z through the origin), the depth of their closest approach, and the translation length
    (does the camera look where the reference camera looks).
    """
    geo = np.full((5, 3), np.nan)
    rot = np.full((5, 9), np.nan)
    for i, k in enumerate(LETTERS):
        v = p.values[k]
        if isinstance(v, V.Box):
            c = np.array(v.center, float)
            if c[2] > 1e-6:
                geo[i] = [c[0] / c[2], c[1] / c[2], max(abs(c[0]), abs(c[1])) / c[2]]
            if v.R is not None:
                rot[i] = np.array(v.R, float).ravel()
        elif isinstance(v, V.Pose):
            R, t = np.array(v.R, float), np.array(v.t, float)
            a, b = np.array([0.0, 0.0, 1.0]), R[:, 2]
            n = np.cross(a, b)
            if np.linalg.norm(n) > 1e-6:
                dist = abs(t @ n) / np.linalg.norm(n)
                cab = a @ b
                depth = (t @ a - cab * (t @ b)) / max(1.0 - cab * cab, 1e-9)
            else:
                dist, depth = float(np.linalg.norm(np.cross(t, a))), np.nan
            geo[i] = [dist, depth, float(np.linalg.norm(t))]
            rot[i] = R.ravel()
    return geo, rot


def _column_stats(x: np.ndarray) -> np.ndarray:
    """Within-row statistics of one summary column x (5,): rank, gaps, z, |z|, medoid, is-min/max."""
    return _block_stats(np.asarray(x, float)[:, None])


def _block_stats(M: np.ndarray) -> np.ndarray:
    """:func:`_column_stats` of every column of ``M`` (5, m) at once: (5, 8 m), the eight statistics of
    column 0, then of column 1, ... (a column with a NaN gives NaN)."""
    m = M.shape[1]
    out = np.full((5, m, 8), np.nan)
    ok = ~np.isnan(M).any(axis=0)
    if ok.any():
        X = M[:, ok]
        order = np.argsort(X, axis=0, kind="stable")
        ranks = np.empty_like(X)
        np.put_along_axis(ranks, order, np.repeat(np.arange(1.0, 6.0)[:, None], X.shape[1], axis=1), axis=0)
        xs = np.take_along_axis(X, order, axis=0)
        span = xs[-1] - xs[0]
        scale = np.where(span > 0, span, 1.0)
        d = np.diff(xs, axis=0)
        nan_row = np.full((1, X.shape[1]), np.nan)
        gaps_lo, gaps_hi = np.empty_like(X), np.empty_like(X)
        np.put_along_axis(gaps_lo, order, np.vstack([nan_row, d]) / scale, axis=0)
        np.put_along_axis(gaps_hi, order, np.vstack([d, nan_row]) / scale, axis=0)
        sd = X.std(axis=0)
        z = np.where(sd > 0, (X - X.mean(axis=0)) / np.where(sd > 0, sd, 1.0), 0.0)
        med = np.abs(X[:, None, :] - X[None, :, :]).sum(1) / (scale * 4)
        near = np.minimum(np.nan_to_num(gaps_lo, nan=np.inf), np.nan_to_num(gaps_hi, nan=np.inf))
        out[:, ok] = np.stack([ranks, gaps_lo, gaps_hi, z, np.abs(z), med, near,
                               np.abs(X - np.median(X, axis=0)) / scale], axis=2)
    return out.reshape(5, m * 8)


def _group_stats(p: ParsedRow) -> np.ndarray:
    """Box/pose field-group statistics: centroid distance and medoid score per group, field votes."""
    out = np.full((5, 11), np.nan)
    vals = [p.values[k] for k in LETTERS]
    groups: list[list[np.ndarray]] = []
    rot: list[np.ndarray] | None = None
    if all(isinstance(v, V.Box) for v in vals):
        groups = [[np.array(v.center) for v in vals], [np.log(np.maximum(np.array(v.lwh), 1e-6)) for v in vals]]
        if all(v.R is not None for v in vals):
            rot = [np.array(v.R) for v in vals]
    elif all(isinstance(v, V.Pose) for v in vals):
        groups = [[np.array(v.t) for v in vals]]
        rot = [np.array(v.R) for v in vals]
    else:
        return out
    col = 0
    for g in groups:
        X = np.array(g)
        D = np.sqrt(((X[:, None] - X[None]) ** 2).sum(-1))
        s = D.sum() / 20 or 1.0
        out[:, col] = np.linalg.norm(X - X.mean(0), axis=1) / s
        out[:, col + 1] = D.sum(1) / (4 * s)
        col += 2
    col = 4
    if rot is not None:
        M = nearest_rotation(np.mean(rot, axis=0))
        D = np.array([[rot_angle(a, b) for b in rot] for a in rot])
        s = D.sum() / 20 or 1.0
        out[:, col] = np.array([rot_angle(R, M) for R in rot]) / s
        out[:, col + 1] = D.sum(1) / (4 * s)
    flat = np.array([v.vector() for v in vals]) if len({len(v.vector()) for v in vals}) == 1 else None
    if flat is not None:
        med_votes = np.zeros(5)
        maj_votes = np.zeros(5)
        for j in range(flat.shape[1]):
            colv = flat[:, j]
            hit = np.flatnonzero(np.abs(colv - np.median(colv)) <= 1e-12)
            if len(hit) == 1:
                med_votes[hit[0]] += 1
            c = Counter(np.round(colv, 9))
            val, n = c.most_common(1)[0]
            if n >= 2:
                maj_votes[np.round(colv, 9) == val] += 1
        out[:, 6] = med_votes / flat.shape[1]
        out[:, 7] = maj_votes / flat.shape[1]
        sd = flat.std(0)
        keep = sd > 1e-12
        if keep.any():
            Z = (flat[:, keep] - flat[:, keep].mean(0)) / sd[keep]
            out[:, 8] = np.linalg.norm(Z, axis=1)
            DZ = np.sqrt(((Z[:, None] - Z[None]) ** 2).sum(-1))
            out[:, 9] = DZ.sum(1) / max(DZ.sum() / 5, 1e-12)
        out[:, 10] = np.abs(flat - np.median(flat, axis=0)).sum(1) / (np.abs(flat - np.median(flat, axis=0)).sum() / 5
                                                                     or 1.0)
    return out


def row_features(p: ParsedRow, tasks: tuple = ()) -> np.ndarray:
    """(5, F) features of the five candidates of one complete row, in letter order (``tasks``: the
    task names of the one-hot task columns)."""
    strings = [str(p.candidates[k]) for k in LETTERS]
    n = 5
    task = np.zeros((n, len(tasks)))
    if p.task in tasks:
        task[:, tasks.index(p.task)] = 1
    src = np.zeros((n, len(SOURCES)))
    if p.source in SOURCES:
        src[:, SOURCES.index(p.source)] = 1
    letter = np.eye(5)
    lens = np.array([len(s) for s in strings], float)
    digits = np.array([sum(ch.isdigit() for ch in s) for s in strings], float)
    minus = np.array([s.count("-") for s in strings], float)
    strf = np.column_stack([lens, digits, minus, lens - lens.mean(), digits - digits.mean(), minus - minus.mean(),
                            _column_stats(lens)[:, 0], _column_stats(digits)[:, 0],
                            (lens == lens.min()) & ((lens == lens.min()).sum() == 1),
                            (lens == lens.max()) & ((lens == lens.max()).sum() == 1)])
    summ = _summaries(p)
    stats = _block_stats(summ)
    angle = np.full((n, 2), np.nan)
    vals = [p.values[k] for k in LETTERS]
    if all(isinstance(v, V.Scalar) and v.is_angle for v in vals):
        rad = np.radians([v.value for v in vals])
        m = math.atan2(np.sin(rad).mean(), np.cos(rad).mean())
        d = np.abs(np.angle(np.exp(1j * (rad - m))))
        angle[:, 0] = d
        angle[:, 1] = _column_stats(d)[:, 0]
    lab = np.zeros((n, len(LABELS) + 1))
    traj = np.full((n, 3), np.nan)
    for i, v in enumerate(vals):
        if isinstance(v, V.Label):
            j = LABELS.index(v.text) if v.text in LABELS else len(LABELS)
            lab[i, j] = 1
        if isinstance(v, V.Trajectory):
            st = v.structure
            traj[i] = [len(st), sum(1 for s in st if s == "turn+"), sum(1 for s in st if s == "turn-")]
    order = order_concordance(p)
    order = np.array([[order[k]] for k in LETTERS]) if order is not None else np.full((n, 1), np.nan)
    geo, rot = _geometry(p)
    geo_stats = _block_stats(geo)
    return np.concatenate([task, src, letter, strf, summ, stats, _group_stats(p), angle, lab, traj, geo, geo_stats,
                           rot, order], axis=1)


def feature_matrix(rows: list[ParsedRow], tasks: tuple | None = None) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Stacked candidate features ``X`` (5 per usable row), labels ``y`` and the usable row indices
    (``tasks``: the task names of the one-hot task columns; default: the rows' tasks, sorted)."""
    tasks = tuple(tasks) if tasks is not None else tuple(sorted({str(p.task) for p in rows}))
    X, y, used = [], [], []
    for i, p in enumerate(rows):
        if not (p.complete and p.answer in LETTERS):
            continue
        X.append(row_features(p, tasks))
        y.append([k == p.answer for k in LETTERS])
        used.append(i)
    if not X:
        return np.zeros((0, 0)), np.zeros(0, bool), []
    return np.concatenate(X).astype(float), np.concatenate(y).astype(bool), used


# ------------------------------------------------------------------------------------ the attack

def _model(cfg: LearnedConfig, model: str | None = None):
    """The classifier named by ``model`` (default ``cfg.model``)."""
    model = model or cfg.model
    if model == "gradient_boosting":
        from sklearn.ensemble import HistGradientBoostingClassifier

        return HistGradientBoostingClassifier(max_iter=cfg.max_iter, learning_rate=cfg.learning_rate,
                                              max_leaf_nodes=cfg.max_leaf_nodes,
                                              min_samples_leaf=cfg.min_samples_leaf, early_stopping=False,
                                              random_state=cfg.random_state)
    if model == "random_forest":
        from sklearn.ensemble import RandomForestClassifier

        return RandomForestClassifier(n_estimators=cfg.n_estimators, min_samples_leaf=cfg.min_samples_leaf // 4 or 1,
                                      random_state=cfg.random_state, n_jobs=1)
    raise ValueError(f"unknown model {model!r} (gradient_boosting or random_forest)")


def _population_model(cfg: LearnedConfig):
    """The population attacker's classifier: a random forest (trees grown on two threads; a tree does not
    depend on the thread that grows it) or the gradient boosting of :func:`_model`."""
    if cfg.population_model == "random_forest":
        from sklearn.ensemble import RandomForestClassifier

        return RandomForestClassifier(n_estimators=cfg.population_trees, min_samples_leaf=cfg.population_min_leaf,
                                      random_state=cfg.random_state, n_jobs=FIT_THREADS)
    return _model(cfg, cfg.population_model)


def out_of_fold_scores(rows: list[ParsedRow], videos: list, cfg: LearnedConfig | None = None
                       ) -> tuple[np.ndarray, list[int]]:
    """Out-of-fold candidate scores of the option-only attacker, shape (n_used, 5), and the indices of the
    used rows.

    Folds: :class:`sklearn.model_selection.GroupKFold` on ``videos`` (one group label per row; pass the
    source sequence to keep a sequence's videos together).
    """
    X, y, used = feature_matrix(rows)
    if not used:
        return np.zeros((0, 5)), []
    return grouped_scores(X, y, [videos[i] for i in used], cfg), used


def grouped_scores(X: np.ndarray, y: np.ndarray, groups: list, cfg: LearnedConfig | None = None, *,
                   fold_features=None, make_model=None) -> np.ndarray:
    """Out-of-fold scores (n_rows, 5) of a classifier on candidate features ``X`` (5 consecutive candidate
    rows per question, in letter order) with labels ``y``; folds by ``groups`` (one label per question),
    so no group is in a training and a test fold at once. ``fold_features(train)`` (optional): more
    candidate features made from the training rows of a fold alone (``train``: a boolean mask over the
    questions), e.g. where a candidate stands among the training answers. ``make_model(cfg)``: the
    classifier (default :func:`_model`); it predicts on one thread, so its sums are reproducible."""
    from sklearn.model_selection import GroupKFold
    from threadpoolctl import threadpool_limits

    cfg = cfg or LearnedConfig()
    if fold_features is None:
        X = X[:, ~np.all(np.isnan(X), axis=0)]  # features of kinds absent from these rows
    groups_row = np.array([str(g) for g in groups])
    n_groups = len(set(groups_row))
    if n_groups < 2:
        raise ValueError("the learned attacker needs at least two groups (videos or sequences) for grouped "
                         "cross-validation")
    n_splits = min(cfg.n_splits, n_groups)
    row_idx = np.arange(len(groups_row))
    scores = np.full((len(groups_row), 5), np.nan)

    def fold(train: np.ndarray, test: np.ndarray) -> np.ndarray:
        """The test rows' scores of a model fitted on the training rows (a fold depends on nothing
        but its rows, so the folds run side by side and give the same scores in any order)."""
        tr = (train[:, None] * 5 + np.arange(5)).ravel()
        te = (test[:, None] * 5 + np.arange(5)).ravel()
        if y[tr].all() or not y[tr].any():
            return np.zeros((len(test), 5))
        Xf = X
        if fold_features is not None:
            mask = np.zeros(len(groups_row), bool)
            mask[train] = True
            Xf = np.concatenate([X, fold_features(mask)], axis=1)
            Xf = Xf[:, ~np.all(np.isnan(Xf[tr]), axis=0)]
        model = (make_model or _model)(cfg)
        model.fit(Xf[tr], y[tr])
        if hasattr(model, "n_jobs"):
            model.n_jobs = 1  # trees' votes summed in one order
        return model.predict_proba(Xf[te])[:, list(model.classes_).index(True)].reshape(-1, 5)

    folds = list(GroupKFold(n_splits=n_splits).split(row_idx, groups=groups_row))
    # one OpenMP thread per gradient boosting (its threads spin while they wait, and a busy machine
    # stalls them), the folds on FOLD_THREADS threads instead; the population attacker's forest grows
    # its trees on FIT_THREADS joblib threads, which do not change a tree
    with threadpool_limits(1), warnings.catch_warnings():
        # a forest hands its trees to joblib with the caller's warning filters, and warns on every
        # tree when that list is empty (a host that cleared it); the trees do not read it
        warnings.filterwarnings("ignore", message=".*sklearn.utils.parallel.delayed", category=UserWarning)
        with ThreadPoolExecutor(max_workers=FOLD_THREADS) as ex:
            for (_, test), s in zip(folds, ex.map(lambda f: fold(*f), folds)):
                scores[test] = s
    return scores


# ------------------------------------------------------------------------------------ question features

QUANTITIES = ("box", "heading_change", "pose", "displacement", "path_length", "speed", "acceleration", "trajectory",
              "length", "width", "height", "distance_to_camera", "surface_distance", "distance", "relation")
WORD_BUCKETS = 32
NOUN_BUCKETS = 16


def _bucket(text: str, n: int) -> int:
    import zlib

    return zlib.crc32(text.encode("utf-8")) % n


def question_row_features(record: dict, obs) -> np.ndarray:
    """Features of one question (the same for its five candidates): the measured quantity, an instant
    or an interval, a camera or another subject, the window, whether a premise pose is printed, hashed
    words of the question text and the hashed subject noun."""
    q = np.zeros(len(QUANTITIES) + 1)
    q[QUANTITIES.index(obs.quantity) if obs.quantity in QUANTITIES else len(QUANTITIES)] = 1
    w = obs.window_s
    instant = obs.time_start is not None and obs.time_start == obs.time_end
    window = [np.log(w + 0.1) if w is not None else np.nan, w if w is not None else np.nan, float(instant),
              float(obs.is_camera), float(obs.premise is not None)]
    words = np.zeros(WORD_BUCKETS)
    toks = re.findall(r"[a-z]+", str(record.get("Question") or "").lower())
    for t in toks:
        words[_bucket(t, WORD_BUCKETS)] += 1
    words /= max(1, len(toks))
    noun = np.zeros(NOUN_BUCKETS + 1)
    n = noun_of(obs)
    noun[_bucket(n, NOUN_BUCKETS) if n else NOUN_BUCKETS] = 1
    return np.concatenate([q, window, words, noun])


def question_candidate_features(p: ParsedRow, obs) -> np.ndarray:
    """(5, F) candidate features that need the question: the implied rate over the window (log), the
    translation and rotation distance to the premise pose (and whether the candidate repeats it), each
    with its within-row statistics."""
    rate = np.full(5, np.nan)
    prem = np.full((5, 3), np.nan)
    parts = premise_parts(obs)
    for i, k in enumerate(LETTERS):
        v = p.values[k]
        r = implied_rate(v, obs)
        if r is not None:
            rate[i] = math.log(r[1] + 1e-4)
        if parts is not None and isinstance(v, V.Pose):
            t0, R0 = parts
            dt = float(np.linalg.norm(np.array(v.t, float) - t0))
            prem[i] = [math.log(dt + 1e-3), math.degrees(rot_angle(R0, np.array(v.R, float))),
                       float(repeats_premise(v, obs))]
    cols = [rate[:, None], _column_stats(rate), prem, _column_stats(prem[:, 0]), _column_stats(prem[:, 1])]
    return np.concatenate(cols, axis=1)


def _option_matrix(batch: Batch) -> tuple[np.ndarray, np.ndarray]:
    """Option-only candidate features and labels of every row of the batch (computed once per batch)."""
    def make():
        X, y, _ = feature_matrix(batch.rows, batch.tasks)
        return X, y
    return batch.memo("learned_option_features", make)


def question_matrix(batch: Batch) -> np.ndarray:
    """Question and question-aware candidate features of every row (5 candidate rows per question)."""
    out = []
    for p, r, o in zip(batch.rows, batch.records, batch.obs):
        q = np.repeat(question_row_features(r, o)[None, :], 5, axis=0)
        out.append(np.concatenate([q, question_candidate_features(p, o)], axis=1))
    return np.concatenate(out).astype(float) if out else np.zeros((0, 0))


def _picks_of_scores(scores: np.ndarray) -> list:
    """The top-scoring letters of each row (a tie is a set)."""
    return [top({k: float(x) for k, x in zip(LETTERS, s)}) for s in scores]


def learned_picks(rows: list[ParsedRow], videos: list, cfg: LearnedConfig | None = None) -> pd.DataFrame:
    """Per-row picks of the learned attacker, in the columns of :func:`scoring.run_picks`."""
    batch, used = make_batch(rows)
    scores, _ = out_of_fold_scores(batch.rows, [videos[i] for i in used], cfg)
    return picks_frame(batch, NAME, _picks_of_scores(scores), family="learned_option")


def config_of(spec) -> LearnedConfig:
    """A :class:`LearnedConfig` from None (defaults), a config, ``True`` or a dict of its fields."""
    if isinstance(spec, LearnedConfig):
        return spec
    if spec is None or spec is True:
        return LearnedConfig()
    return config_from(spec)


def cv_groups(batch: Batch) -> list:
    """Cross-validation group of every row: ``settings["groups"][Legacy Row Key]`` where given, else the
    source sequence read from the video name (the camera videos of one Waymo segment, which share ego
    answers, never straddle train and test)."""
    given = batch.settings.get("groups") or {}
    return [given.get(r.get("Legacy Row Key"), o.sequence) for r, o in zip(batch.records, batch.obs)]


@attack(NAME, ["any"], "gradient-boosting classifier on candidate features, out of fold by source sequence",
        family="learned_option", scope="batch")
def _learned_blind(batch: Batch):
    groups = cv_groups(batch)
    if len(set(groups)) < 2:
        return [None] * len(batch)
    X, y = _option_matrix(batch)
    return _picks_of_scores(grouped_scores(X, y, groups, config_of(batch.settings.get("learned"))))


@attack(QUESTION_NAME, ["any"], "gradient-boosting classifier on candidate features and the question's features "
        "(type, subject, window, premise, hashed words and noun; implied rate, distance to the premise), out of "
        "fold by source sequence", family="learned_question", scope="batch")
def _learned_question(batch: Batch):
    groups = cv_groups(batch)
    if len(set(groups)) < 2:
        return [None] * len(batch)
    X, y = _option_matrix(batch)
    Xq = np.concatenate([X, question_matrix(batch)], axis=1)
    return _picks_of_scores(grouped_scores(Xq, y, groups, config_of(batch.settings.get("learned"))))


# ------------------------------------------------------------------------------------ population-relative features

POPULATION_NAME = "learned_population"


def _onehot(labels: list, names: tuple) -> np.ndarray:
    out = np.zeros((len(labels), len(names)))
    for r, x in enumerate(labels):
        if x in names:
            out[r, names.index(x)] = 1.0
    return out


def _printed(s: str) -> list[float]:
    """How a candidate is printed: decimals and significant digits (trailing zeros dropped) of its numbers,
    its last digit, whether that is 0, and its length."""
    toks = tokens(s)
    last = last_digit(toks[-1]) if toks else "x"
    return [float(sum(decimals(t) for t in toks)), float(sum(significant_stripped(t) for t in toks)),
            float(last) if last.isdigit() else np.nan, float(last == "0"), float(len("".join(str(s).split())))]


def _log_rates(p, o) -> dict | None:
    """``letter -> log rate`` each candidate implies over the question's window (None without one)."""
    r = {k: implied_rate(v, o) for k, v in p.values.items()}
    if any(x is None for x in r.values()):
        return None
    return {k: math.log(x[1] + 1e-4) for k, x in r.items()}


def population_static(batch: Batch) -> np.ndarray:
    """The fold-independent part of the population attacker's features, (n_rows * 5, F): the candidate on
    its value scale and its implied rate, with their rank, gaps to the neighbours (relative to the set's
    range) and standardised position within the set; how it is printed (relative to the set too); the
    question's window; the task, source and quantity (one-hot over the batch's own, sorted)."""
    def make():
        vals = [value_scale(p) for p in batch.rows]
        rates = [_log_rates(p, o) for p, o in zip(batch.rows, batch.obs)]
        cols = []
        for v in (vals, rates):
            x = np.array([[d[k] for k in LETTERS] if d is not None else [np.nan] * 5 for d in v], float)
            cols.append(x.reshape(-1, 1))
            cols.append(np.concatenate([_column_stats(row)[:, :4] for row in x]))
        printed = np.array([[_printed(p.candidates[k]) for k in LETTERS] for p in batch.rows], float)
        flat = printed.reshape(-1, printed.shape[2])
        rel = (printed - printed.mean(axis=1, keepdims=True)).reshape(-1, printed.shape[2])
        window = np.repeat([math.log(o.window_s + 0.1) if o.window_s else np.nan for o in batch.obs], 5)[:, None]
        quantities = tuple(sorted({o.quantity for o in batch.obs}))
        sources = tuple(sorted({str(p.source) for p in batch.rows}))
        hot = [_onehot([str(p.task) for p in batch.rows], batch.tasks),
               _onehot([str(p.source) for p in batch.rows], sources),
               _onehot([o.quantity for o in batch.obs], quantities)]
        hot = np.repeat(np.concatenate(hot, axis=1), 5, axis=0)
        return np.concatenate(cols + [flat, rel, window, hot], axis=1)
    return batch.memo("learned_population_static", make)


def population_fold(batch: Batch, train: np.ndarray) -> np.ndarray:
    """The fold-dependent part: where each candidate value and implied rate stands among the answers (and
    the candidates) of the training rows of its task, source and question type (rates: source, rate kind
    and subject), never of its own recording (:func:`reference.population_features`), and each of those
    relative to the candidate set's mean."""
    vals, rates, gv, gr = batch.memo("learned_population_values", lambda: _population_values(batch))
    parts = []
    for v, g in ((vals, gv), (rates, gr)):
        f = population_features(batch, v, g, train)
        parts += [f, f - np.repeat(f.reshape(len(batch), 5, -1).mean(axis=1), 5, axis=0)]
    return np.concatenate(parts, axis=1)


def _population_values(batch: Batch):
    vals = [value_scale(p) for p in batch.rows]
    rates = [_log_rates(p, o) for p, o in zip(batch.rows, batch.obs)]
    gv = [(str(p.task), str(p.source), question_kind(o)) for p, o in zip(batch.rows, batch.obs)]
    gr = [(str(p.source), implied_rate(p.values["A"], o)[0] if r is not None else None,
           "camera" if o.is_camera else "object") for p, o, r in zip(batch.rows, batch.obs, rates)]
    return vals, rates, gv, gr


@attack(POPULATION_NAME, ["scalar", "trajectory"], "gradient-boosting classifier on population-relative features: "
        "each candidate's quantile and density among the answers (and the candidates) of its task, source and "
        "question type, fitted out of fold on other recordings; its implied rate likewise; its rank, gaps and "
        "position within the set; its printed digits; the window (out of fold by source sequence)",
        family="learned_question", scope="batch")
def _learned_population(batch: Batch):
    groups = cv_groups(batch)
    used = [i for i, p in enumerate(batch.rows) if value_scale(p) is not None]
    if len({groups[i] for i in used}) < 2:
        return [None] * len(batch)
    X = population_static(batch)
    y = np.array([[k == p.answer for k in LETTERS] for p in batch.rows]).ravel()
    sel = (np.array(used)[:, None] * 5 + np.arange(5)).ravel()

    def fold(train_mask):
        full = np.zeros(len(batch), bool)
        full[np.array(used)[train_mask]] = True
        return population_fold(batch, full)[sel]

    scores = grouped_scores(X[sel], y[sel], [groups[i] for i in used], config_of(batch.settings.get("learned")),
                            fold_features=fold, make_model=_population_model)
    out: list = [None] * len(batch)
    for i, pk in zip(used, _picks_of_scores(scores)):
        out[i] = pk
    return out


def attack_table_with_learned(records: list[dict], *, iface=None, alpha: float = 0.05, attacks=None,
                              learned: LearnedConfig | None | bool = None, groups: dict | None = None,
                              families=None) -> pd.DataFrame:
    """The attack table with the learned attackers (:func:`scoring.attack_table` with ``fast=False``).

    ``families`` None keeps this function's historical scope: the option-only rules and the learned
    option-only attacker (``learned_blind``); pass ``"all"`` for every family.
    ``learned=False`` leaves the learned attackers out. ``groups`` maps a row's Legacy Row Key to its
    cross-validation group (default: the source sequence of its video).
    """
    fams = ("option", "learned_option") if families is None else families
    if attacks not in (None, "all"):
        names = [attacks] if isinstance(attacks, str) else list(attacks)
        attacks = names + [n for n in select(fams) if ATTACKS[n].learned and n not in names]
    return attack_table(records, iface=iface, families=fams, alpha=alpha, attacks=attacks, learned=learned,
                        groups=groups)


def config_from(params: dict | None) -> LearnedConfig:
    """A :class:`LearnedConfig` from a params mapping (unknown keys raise)."""
    params = dict(params or {})
    known = set(LearnedConfig.__dataclass_fields__)
    unknown = sorted(set(params) - known)
    if unknown:
        raise ValueError(f"unknown learned-attacker setting(s) {unknown}; known: {sorted(known)}")
    return LearnedConfig(**params)
