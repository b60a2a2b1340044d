"""Blind attacks on the answer interface: pick a letter without the video.

*Blind* is everything but the video: the five candidate strings, the question text, the other rows of
the same video and the row's metadata (video name, source, times). Every channel is a **family** of
registered attacks with one output contract:

==================== ==========================================================================
family               what an attack of the family reads
==================== ==========================================================================
``option``           the candidate values (ranks, centroids, field votes) and, for the label
                     prior, the other rows' answers of the task and source (leave-one-out)
``format``           how each candidate is printed (decimals, last digits, ``-0``, significant
                     digits, key order and spacing, length)
``typicality``       how typical a candidate's field combination is of the other rows' answers
``question``         the question's observables (:mod:`resti_lib.options.observables`): implied
                     rate over the window, premise pose, question type and subject noun
``cross_row``        the other rows of the same video / source sequence (their questions,
                     candidates and answers)
``metadata``         non-video fields (the Waymo camera in the video name)
``learned_option``   a classifier on candidate features (:mod:`resti_lib.options.learned`)
``learned_question`` a classifier on candidate and question features
==================== ==========================================================================

An attack returns, per row, the **set** of letters it picks (or None where it does not apply, e.g.
no premise pose). A tied set is scored by its expected accuracy: the row scores ``1/|set|`` when the
answer is in the set (a five-way tie scores exactly chance). Nothing is skipped or abstained.

The table has one row per (attack, task, source) and per (attack, task) with ``source == "ALL"``:
``n_rows`` (usable rows of the cell), ``coverage`` (fraction the attack applies to), ``picked``,
``hits`` (expected hits), ``accuracy`` (hits / picked), ``chance`` (1/5), ``p_value`` (exact
one-sided test of the expected hits under the null that the answer is any of the five options with
equal probability, see :func:`tie_aware_p`; times the attack's own number of comparisons),
``p_holm`` and ``significant`` (Holm's step-down correction over every row of the table at
``alpha``), ``min_detectable`` (the smallest blind accuracy the test detects with 80% power at the
cell's ``n_rows`` and Holm's first-step level ``alpha / rows``) and ``underpowered`` (cannot detect
35%), ``tied_rows`` (rows scored as a tie).

Rules that read other rows' answers (label prior, typical value, ...) always leave the row itself
out (the new families leave its whole source sequence out). A rule whose direction is not known in
advance (fewest or most decimals, nearest or farthest, or a middle rank) is scored in every direction;
the table keeps the best direction of each cell (column ``direction``) with its p-value multiplied by
the number of directions (:class:`Directional`).

New attacks plug in with :func:`attack`. The learned families train classifiers and are skipped by
``fast=True`` (``resti attack --fast``).
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.stats import binom

from .. import LETTERS, SOURCES
from .. import values as V
from ..geometry.frames import nearest_rotation
from .checks import ParsedRow, parse_row

CHANCE = 1.0 / 5.0
COLUMNS = ["attack", "family", "task", "source", "n_rows", "coverage", "picked", "hits", "accuracy", "chance",
           "p_value", "p_holm", "significant", "min_detectable", "underpowered", "tied_rows", "direction"]
PICK_COLUMNS = ["attack", "family", "direction", "rid", "task", "source", "pick", "answer", "tied", "hit"]

FAMILIES = {
    "option": "option-only rules on the candidate values",
    "format": "formatting tells of the printed candidates",
    "typicality": "field typicality against the other rows' answers",
    "question": "question-aware rules (window, premise pose, question type and noun)",
    "cross_row": "same-video / same-sequence cross-row reveals",
    "metadata": "metadata (video name and other non-video fields)",
    "learned_option": "learned attacker on candidate features",
    "learned_question": "learned attacker on candidate and question features",
}
LEARNED_FAMILIES = ("learned_option", "learned_question")


@dataclass
class Attack:
    """A registered attack. ``scope``: ``row`` (``fn(p)``), ``question`` (``fn(p, obs)``) or ``batch``
    (``fn(batch)`` -> one pick per usable row). ``tests``: comparisons made inside the attack
    (Bonferroni factor of its p-value)."""

    name: str
    kinds: tuple
    fn: Callable
    description: str
    family: str = "option"
    scope: str = "row"
    tests: int = 1

    @property
    def learned(self) -> bool:
        return self.family in LEARNED_FAMILIES


ATTACKS: dict[str, Attack] = {}


def load_families() -> dict[str, Attack]:
    """The registry with every family loaded: the other families live in their own modules
    (:mod:`.tells`, :mod:`.readers`, :mod:`.learned`), which import this one and register on import;
    they are imported here, on first use, so no module-level import cycle arises."""
    from . import learned, readers, tells  # noqa: F401

    return ATTACKS


def attack(name: str, kinds: Iterable[str], description: str, *, family: str = "option", scope: str = "row",
           tests: int = 1):
    """Register an attack (decorator). ``kinds``: value kinds it reads (``scalar``, ``angle``, ``box``,
    ``pose``, ``trajectory``, ``label``, ``any``); row and question attacks run only on rows of those
    kinds."""
    if family not in FAMILIES:
        raise ValueError(f"unknown attack family {family!r}; known: {sorted(FAMILIES)}")
    if scope not in ("row", "question", "batch"):
        raise ValueError(f"unknown attack scope {scope!r}")

    def deco(fn):
        ATTACKS[name] = Attack(name, tuple(kinds), fn, description, family, scope, tests)
        return fn
    return deco


# ------------------------------------------------------------------------------------ the batch

@dataclass
class Batch:
    """The usable rows of a release (complete, with an answer letter) as attacks see them.

    ``rows`` parsed rows, ``records`` the release rows (question text, video, fields), ``obs`` the
    question observables (computed on first use), ``settings`` attack settings (learned attacker
    configuration, cross-validation groups)."""

    rows: list
    records: list
    settings: dict = field(default_factory=dict)
    _obs: list | None = None
    _index: dict = field(default_factory=dict)

    @property
    def obs(self) -> list:
        if self._obs is None:
            from .observables import observables_of

            iface = self.settings.get("iface")
            if iface is None:
                raise ValueError("attacks that read the question need the answer interface (attack_table iface=)")
            self._obs = [observables_of(r, iface.quantity_of(str(r.get("Task")), r.get("Question"))) for r in self.records]
        return self._obs

    @property
    def task_order(self) -> tuple:
        """Task names in the interface's (benchmark) order, then any other task of the rows by name."""
        iface = self.settings.get("iface")
        known = tuple(iface.tasks) if iface is not None else ()
        return known + tuple(sorted({str(p.task) for p in self.rows} - set(known)))

    def __len__(self) -> int:
        return len(self.rows)

    def groups(self, key: Callable[[int], object], name: str | None = None) -> dict:
        """Row indices grouped by ``key(i)`` (a None key is left out); memoised under ``name``."""
        if name is not None and name in self._index:
            return self._index[name]
        out: dict = defaultdict(list)
        for i in range(len(self.rows)):
            k = key(i)
            if k is not None:
                out[k].append(i)
        out = dict(out)
        if name is not None:
            self._index[name] = out
        return out

    def cells(self) -> dict:
        """(task, source) -> row indices."""
        return self.groups(lambda i: (self.rows[i].task, self.rows[i].source), "cells")


def _record_of(p: ParsedRow) -> dict:
    return {"Task": p.task, "Source": p.source, "Candidates": p.candidates, "Answer": p.answer,
            "Answer Detail": p.detail, "time_start": p.time_start, "time_end": p.time_end}


def make_batch(rows: list[ParsedRow], records: list[dict] | None = None, **settings) -> tuple[Batch, list[int]]:
    """The batch of usable rows and their indices in ``rows``."""
    used = [i for i, p in enumerate(rows) if p.complete and p.answer in LETTERS]
    recs = [records[i] for i in used] if records is not None else [_record_of(rows[i]) for i in used]
    return Batch([rows[i] for i in used], recs, dict(settings)), used


# ------------------------------------------------------------------------------------ helpers

TIE = 1e-12  # values closer than this are ties (printed values are far coarser)
ALL5 = frozenset(LETTERS)


def top(scores: dict, *, tol: float = TIE) -> frozenset | None:
    """The letters of highest score (a tie is a set); None for no scores. Non-finite scores never win
    over finite ones."""
    fin = {k: s for k, s in scores.items() if np.isfinite(s)}
    if not fin:
        return ALL5 if scores else None
    best = max(fin.values())
    return frozenset(k for k, s in fin.items() if s >= best - tol * max(1.0, abs(best)))


def as_pick(x) -> frozenset | None:
    """Normalise an attack's answer: None, a letter, a set of letters or a ``letter -> score`` dict."""
    if x is None:
        return None
    if isinstance(x, str):
        return frozenset([x])
    if isinstance(x, dict):
        return top(x)
    s = frozenset(x)
    return s if s else None


def _scalar(p: ParsedRow) -> dict | None:
    if not all(isinstance(v, V.Scalar) for v in p.values.values()):
        return None
    return {k: v.si for k, v in p.values.items()}


def scalar_or_distance(p: ParsedRow) -> dict | None:
    """Signed SI values of scalar candidates, or total distances of trajectory candidates."""
    vals = _scalar(p)
    if vals is None and all(isinstance(v, V.Trajectory) for v in p.values.values()):
        vals = {k: v.total_distance for k, v in p.values.items()}
    return vals


def _rank_pick(vals: dict, rank: int) -> frozenset:
    """Letters at 1-based ascending ``rank`` of the signed values (every letter tied with it)."""
    order = sorted(vals.items(), key=lambda kv: (kv[1], kv[0]))
    v = order[rank - 1][1]
    return frozenset(k for k, w in vals.items() if abs(w - v) <= TIE)


def _nearest(vecs: dict, target: np.ndarray) -> frozenset:
    return top({k: -float(np.linalg.norm(np.asarray(v) - target)) for k, v in vecs.items()})


def _medoid(vecs: dict, dist=None) -> frozenset:
    keys = sorted(vecs)
    if dist is None:
        X = np.array([np.asarray(vecs[k], dtype=float).ravel() for k in keys])
        D = np.sqrt(((X[:, None, :] - X[None, :, :]) ** 2).sum(-1))
        return top({k: -float(D[i].sum()) for i, k in enumerate(keys)})
    return top({k: -sum(dist(vecs[k], vecs[j]) for j in keys if j != k) for k in keys})


def _rot_angle(A, B) -> float:
    """Angle (radians) between two matrices as printed, from the trace alone. An attacker reads the
    printed entries, so no projection onto SO(3) here; the audit's own angle, on projected rotations,
    is :func:`resti_lib.geometry.frames.rotation_angle_deg`."""
    c = (np.trace(np.asarray(A).T @ np.asarray(B)) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def _fields(p: ParsedRow) -> dict | None:
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


def _flat_fields(p: ParsedRow) -> dict | None:
    """Every scalar field of a structured answer, as letter -> 1-D vector (printed values)."""
    vals = p.values
    if all(isinstance(v, (V.Box, V.Pose)) for v in vals.values()):
        lens = {len(v.vector()) for v in vals.values()}
        if len(lens) == 1:
            return {k: v.vector() for k, v in vals.items()}
    return None


def extreme(values: dict, direction) -> frozenset:
    """Letters of the largest (``direction="max"``, or rank 1) or smallest (``"min"``) value, or of the
    value at descending rank ``direction`` (an int 1-5; ties share a rank). Non-finite values take no
    rank; a five-way tie when nothing is finite or all values are equal."""
    if direction == "max":
        direction = 1
    fin = sorted((float(v) for v in values.values() if np.isfinite(v)), reverse=True)
    if not fin:
        return ALL5
    pos = len(fin) - 1 if direction == "min" else min(int(direction), len(fin)) - 1
    target = fin[pos]
    return frozenset(k for k, v in values.items() if np.isfinite(v)
                     and abs(float(v) - target) <= TIE * max(1.0, abs(target)))


def expected_hit(pick: frozenset | None, answer: str) -> float:
    return (1.0 / len(pick)) if pick and answer in pick else 0.0


DIRECTIONS = ("max", "min", 2, 4, 3)


def direction_name(d) -> str:
    return d if isinstance(d, str) else f"rank {d}"


class Directional(dict):
    """An attack's picks in every direction of its score: ``{direction: [pick per row]}``.

    A rule whose direction is not known in advance (fewest or most decimals, nearest or farthest, or a
    middle rank: an answer kept away from both ends is a tell too) is scored in each direction; the
    table keeps, per cell and for the pooled task, the direction with the most expected hits and
    multiplies its p-value by the number of directions (Bonferroni), as for the best constant letter.
    Choosing on the rows themselves and correcting keeps the test exact; choosing on other rows
    (leave-one-out or cross-fitting) does not, because rows that choose for each other share their luck.
    """


def directional(batch: Batch, scores: list, *, directions=DIRECTIONS) -> Directional:
    """The picks of every direction of a per-row score: the largest score, the smallest, or the score at
    descending rank 2, 4 or 3 (:func:`extreme`). ``scores[i]`` is a ``letter -> value`` dict or None (the
    rule does not apply)."""
    return Directional({d: [None if sc is None else extreme(sc, d) for sc in scores] for d in directions})


# ------------------------------------------------------------------------------- option-only rules

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
        return None if vals is None else _rank_pick(vals, rank)
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
    return _medoid({k: np.array([v]) for k, v in vals.items()})


@attack("nearest_circular_mean", ["angle"], "angle nearest (circularly) to the circular mean")
def _circ(p: ParsedRow):
    if not all(isinstance(v, V.Scalar) and v.is_angle for v in p.values.values()):
        return None
    rad = {k: np.radians(v.value) for k, v in p.values.items()}
    m = np.arctan2(np.mean(np.sin(list(rad.values()))), np.mean(np.cos(list(rad.values()))))
    return top({k: -abs(np.angle(np.exp(1j * (a - m)))) for k, a in rad.items()})


def _field_matrix(p: ParsedRow) -> tuple[list, np.ndarray | None]:
    """Letters (sorted) and the 5 x n matrix of every printed field of a structured answer."""
    flat = _flat_fields(p)
    if flat is None:
        return [], None
    keys = sorted(flat)
    return keys, np.array([flat[k] for k in keys])


@attack("field_median", ["box", "pose"], "per-field median vote over every printed field")
def _field_median(p: ParsedRow):
    keys, X = _field_matrix(p)
    if X is None:
        return None
    votes = Counter({k: 0 for k in keys})
    for j in range(X.shape[1]):
        col = X[:, j]
        hit = np.flatnonzero(np.abs(col - np.median(col)) <= TIE)
        if len(hit) == 1:
            votes[keys[hit[0]]] += 1
    return top(dict(votes))


@attack("field_majority", ["box", "pose"], "per-field modal value vote (values shared by >= 2 candidates)")
def _field_majority(p: ParsedRow):
    keys, X = _field_matrix(p)
    if X is None:
        return None
    votes = Counter({k: 0 for k in keys})
    for j in range(X.shape[1]):
        c = Counter(np.round(X[:, j], 9))
        val, n = c.most_common(1)[0]
        if n >= 2 and list(c.values()).count(n) == 1:
            for i in range(len(keys)):
                if round(X[i, j], 9) == val:
                    votes[keys[i]] += 1
    return top(dict(votes))


def _group_attack(group: str, how: str):
    def fn(p: ParsedRow):
        f = _fields(p)
        if f is None or group not in f:
            return None
        vecs = f[group]
        if group == "rotation":
            if how == "centroid":
                M = nearest_rotation(np.mean([vecs[k] for k in sorted(vecs)], axis=0))
                return top({k: -_rot_angle(R, M) for k, R in vecs.items()})
            return _medoid(vecs, dist=_rot_angle)
        if how == "centroid":
            return _nearest(dict(vecs), np.mean(list(vecs.values()), axis=0))
        return _medoid(vecs)
    return fn


for _g, _kinds in [("center", ["box"]), ("logdims", ["box"]), ("translation", ["pose"]),
                   ("rotation", ["box", "pose"])]:
    for _how in ("centroid", "medoid"):
        attack(f"{_how}_{_g}", _kinds, f"{_how} pick on the {_g} field group")(_group_attack(_g, _how))


def _standardized(p: ParsedRow) -> dict | None:
    keys, X = _field_matrix(p)
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
    return None if z is None else _nearest(z, np.zeros_like(next(iter(z.values()))))


@attack("medoid_all", ["box", "pose"], "medoid of all standardized fields")
def _medoid_all(p: ParsedRow):
    z = _standardized(p)
    return None if z is None else _medoid(z)


def answer_key(v):
    """What the label prior counts: the label, or a trajectory's segment structure."""
    return v.structure if isinstance(v, V.Trajectory) else v.key()


def _labelled(p: ParsedRow) -> bool:
    return all(isinstance(v, (V.Label, V.Trajectory)) for v in p.values.values())


def label_name(v) -> str:
    """A readable name of a candidate's :func:`answer_key`: the label text, or the trajectory structure."""
    if isinstance(v, V.Label):
        return " ".join(v.text.split())
    return "-".join(v.structure) if v.structure else "no movement"


def constant_label(batch: Batch, rows: list | None = None) -> Directional:
    """One direction per label (trajectory: structure) seen among the candidates: pick, in every row
    whose candidates carry it, the candidates with that label (None in the other rows). The table keeps
    the best label of each cell with a Bonferroni factor over the labels; each label's test is exact
    (the answer is one of five exchangeable candidates). ``rows``: restrict to these row indices."""
    rows = range(len(batch)) if rows is None else rows
    keys: dict = {}
    for i in rows:
        if _labelled(batch.rows[i]):
            for v in batch.rows[i].values.values():
                keys.setdefault(answer_key(v), label_name(v))
    out = Directional()
    for key, name in keys.items():
        picks: list = [None] * len(batch)
        for i in rows:
            p = batch.rows[i]
            if _labelled(p):
                hit = frozenset(k for k, v in p.values.items() if answer_key(v) == key)
                picks[i] = hit or None
        out[name] = picks
    return out


def split_halves(batch: Batch, learn: Callable[[list, list], dict]) -> Directional:
    """A rule learned on one half of the source sequences and tested on the other, both ways: direction
    ``"half 1 from half 0"`` picks in the rows of half 1 with what ``learn(train, test)`` (row indices)
    returns for them (``{row: pick}``), and vice versa. A row's pick never depends on the answers of its
    own half, so each direction's test is exact; the table keeps the better one (Bonferroni over two)."""
    import zlib

    half = [zlib.crc32(str(o.sequence).encode("utf-8")) % 2 for o in batch.obs]
    out = Directional()
    for test_half in (1, 0):
        train = [i for i, h in enumerate(half) if h != test_half]
        test = [i for i, h in enumerate(half) if h == test_half]
        picks: list = [None] * len(batch)
        for i, pk in learn(train, test).items():
            picks[i] = pk
        out[f"half {test_half} from half {1 - test_half}"] = picks
    return out


def majority_label(batch: Batch, train: list, test: list, key_of_row: Callable[[int], object]) -> dict:
    """For each test row: the candidates whose label (trajectory: structure) is the most frequent answer
    among the training rows with the same ``key_of_row`` (ties: every tied label); rows whose key has
    no training row are left out."""
    counts: dict = defaultdict(Counter)
    for i in train:
        k = key_of_row(i)
        if k is not None and _labelled(batch.rows[i]):
            p = batch.rows[i]
            counts[k][answer_key(p.values[p.answer])] += 1
    out = {}
    for i in test:
        k = key_of_row(i)
        p = batch.rows[i]
        if k is None or k not in counts or not _labelled(p):
            continue
        out[i] = top({c: float(counts[k].get(answer_key(v), 0)) for c, v in p.values.items()})
    return out


@attack("label_prior", ["label", "trajectory"],
        "the most frequent answer label (trajectory: segment structure) of the task and source: every label "
        "tried as a constant pick, the best kept with a Bonferroni factor over the labels", scope="batch")
def _label_prior(batch: Batch):
    return constant_label(batch)


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
            if not all(v.kind in ("scalar", "box", "pose", "trajectory") for v in p.values.values()):
                continue
            own = by_seq[batch.obs[i].sequence]  # leave the row's source sequence out
            scores[i] = {k: float(answers.get(v.key(), 0) - own.get(v.key(), 0)) for k, v in p.values.items()}
    return directional(batch, scores)


def candidate_vectors(p: ParsedRow) -> dict | None:
    """``letter -> vector`` of a row's candidates, standardised per field across the five (scalars: the
    SI value; trajectories: total distance; boxes and poses: every printed field); None for labels."""
    vals = scalar_or_distance(p)
    if vals is not None:
        X = np.array([[vals[k]] for k in LETTERS])
    else:
        flat = _flat_fields(p)
        if flat is None:
            return None
        X = np.array([flat[k] for k in LETTERS], dtype=float)
    sd = X.std(axis=0)
    sd[sd <= 1e-12] = 1.0
    Z = (X - X.mean(axis=0)) / sd
    return {k: Z[i] for i, k in enumerate(LETTERS)}


def _order_concordance(p: ParsedRow) -> dict | None:
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


@attack("letter_order", ["scalar", "trajectory", "box", "pose"], "candidate from which the other four, in letter "
        "order, get steadily farther (or nearer): distractors listed in the order they were generated around "
        "the answer (in every direction)", scope="batch")
def _letter_order(batch: Batch):
    return directional(batch, [_order_concordance(p) for p in batch.rows])


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


# ------------------------------------------------------------------------------------ statistics

def _kind_of(p: ParsedRow) -> set:
    kinds = {v.kind for v in p.values.values()}
    if kinds == {"scalar"} and all(v.is_angle for v in p.values.values()):
        kinds = {"scalar", "angle"}
    return kinds | {"any"}


def holm(pvalues: Iterable[float], alpha: float) -> list[bool]:
    """Holm's step-down procedure: which hypotheses are rejected at family-wise level ``alpha``."""
    return [bool(q <= alpha) for q in holm_adjusted(pvalues)]


def holm_adjusted(pvalues: Iterable[float]) -> list[float]:
    """Holm-adjusted p-values: ``max_{j <= i} min(1, (m - j + 1) p_(j))`` in sorted order; a hypothesis
    is rejected at level ``alpha`` iff its adjusted p-value is at most ``alpha``."""
    p = np.asarray(list(pvalues), dtype=float)
    m = len(p)
    order = np.argsort(p, kind="stable")
    adj = np.empty(m)
    running = 0.0
    for i, idx in enumerate(order):
        running = max(running, min(1.0, (m - i) * p[idx]))
        adj[idx] = running
    return adj.tolist()


def binom_p(hits: int, n: int, chance: float = CHANCE) -> float:
    """Exact one-sided binomial P[X >= hits], X ~ Binomial(n, chance)."""
    if n == 0:
        return 1.0
    return float(binom.sf(hits - 1, n, chance))


_GRID = 12  # expected hits are multiples of 1/60 = 1/(5 * 12); grid unit 1/60


def tie_aware_p(hits: float, ties: Iterable[int]) -> float:
    """Exact one-sided p-value of tie-aware expected hits.

    Row ``i`` picks a set of ``k_i`` letters and scores ``1/k_i`` when the answer is in it. Under the
    null (the answer is each of the five candidates with probability 1/5, independently across rows)
    the row scores ``1/k_i`` with probability ``k_i/5``. The score sum ``S`` is, in units of 1/60,
    ``sum_k (60/k) H_k`` with ``H_k ~ Binomial(n_k, k/5)`` (``n_k`` rows with a ``k``-way tie); this
    returns ``P[S >= hits]`` by exact convolution (the ``k = 1`` part in closed form). With no ties it
    is :func:`binom_p`.
    """
    n = Counter(int(k) for k in ties)
    if not n:
        return 1.0
    w_obs = round(hits * 60)
    if set(n) <= {1}:
        return binom_p(round(hits), n[1])
    offset = 12 * n.get(5, 0)                       # five-way ties always score 1/5
    pmf = np.array([1.0])                            # distribution of the k = 2..4 part, in units of 1/60
    for k in (2, 3, 4):
        nk = n.get(k, 0)
        if not nk:
            continue
        step = 60 // k
        part = np.zeros(step * nk + 1)
        part[::step] = binom.pmf(np.arange(nk + 1), nk, k / 5.0)
        pmf = np.convolve(pmf, part) if len(pmf) * len(part) < 4e7 else _fft_convolve(pmf, part)
    support = np.flatnonzero(pmf > 0)
    n1 = n.get(1, 0)
    need = w_obs - offset - support                  # what the k = 1 part must reach, units of 1/60
    h1 = np.ceil(need / 60.0 - 1e-9)                 # hits of single picks needed
    tail = np.where(h1 <= 0, 1.0, binom.sf(h1 - 1, n1, CHANCE)) if n1 else (need <= 0).astype(float)
    return float(min(1.0, max(0.0, np.sum(pmf[support] * tail))))


def _fft_convolve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    from scipy.signal import fftconvolve

    return np.clip(fftconvolve(a, b), 0.0, None)


# ------------------------------------------------------------------------------------ running

def parse_rows(records: list[dict]) -> list[ParsedRow]:
    out = []
    for i, r in enumerate(records):
        rid = r.get("ReSTI ID") or r.get("Legacy Row Key") or i
        out.append(parse_row(r, rid))
    return out


def _pick_text(pick: frozenset | None) -> str | None:
    return None if pick is None else "".join(sorted(pick))


def _run_one(a: Attack, batch: Batch) -> list | Directional:
    if a.scope == "batch":
        res = a.fn(batch)
        parts = res.items() if isinstance(res, Directional) else [(None, res)]
        out = {}
        for d, picks in parts:
            picks = [as_pick(x) for x in picks]
            if len(picks) != len(batch):
                raise RuntimeError(f"attack {a.name!r} returned {len(picks)} picks for {len(batch)} rows")
            out[d] = picks
        return Directional(out) if isinstance(res, Directional) else out[None]
    kinds = set(a.kinds)
    out = []
    for i, p in enumerate(batch.rows):
        if not kinds & _kind_of(p):
            out.append(None)
        elif a.scope == "row":
            out.append(as_pick(a.fn(p)))
        else:
            out.append(as_pick(a.fn(p, batch.obs[i])))
    return out


def picks_frame(batch: Batch, name: str, picks, family: str | None = None) -> pd.DataFrame:
    """Per-row picks of one attack in the columns of :func:`run_picks` (a :class:`Directional` attack has
    one row per row and direction). Tasks where it never applies are left out; the other rows of a task
    where it applies somewhere have ``pick`` None, so each cell keeps its full row count."""
    family = family or (ATTACKS[name].family if name in ATTACKS else "option")
    parts = [(direction_name(d), pk) for d, pk in picks.items()] if isinstance(picks, Directional) else [("", picks)]
    applies = {batch.rows[i].task for _, pk in parts for i, x in enumerate(pk) if x is not None}
    recs = []
    for d, pk in parts:
        for p, x in zip(batch.rows, pk):
            if p.task not in applies:
                continue
            recs.append((name, family, d, p.rid, p.task, p.source, _pick_text(x), p.answer, len(x) if x else 0,
                         expected_hit(x, p.answer) if x else float("nan")))
    return pd.DataFrame.from_records(recs, columns=PICK_COLUMNS)


def select(families=None, attacks=None, *, fast: bool = False) -> list[str]:
    """Attack names of the chosen ``families`` (None or ``"all"``: every family) and/or ``attacks``
    (names; None: every attack of the families); ``fast`` leaves the learned families out. Unknown
    names raise ``ValueError``."""
    load_families()
    if families in (None, "all"):
        fams = list(FAMILIES)
    else:
        fams = [families] if isinstance(families, str) else list(families)
        bad = [f for f in fams if f not in FAMILIES]
        if bad:
            raise ValueError(f"unknown attack family(ies) {bad}; known: {list(FAMILIES)}")
    if attacks in (None, "all"):
        names = [n for n, a in ATTACKS.items() if a.family in fams]
    else:
        names = [attacks] if isinstance(attacks, str) else list(attacks)
        bad = [n for n in names if n not in ATTACKS]
        if bad:
            raise ValueError(f"unknown attack(s) {bad}; known: {sorted(ATTACKS)}")
        names = [n for n in names if ATTACKS[n].family in fams]
    if fast:
        names = [n for n in names if not ATTACKS[n].learned]
    return names


def run_picks(rows: list[ParsedRow], names: Iterable[str] | None = None, *, records: list[dict] | None = None,
              batch: Batch | None = None, **settings) -> pd.DataFrame:
    """Per-row picks of the named attacks (default: every non-learned attack): columns ``attack, family,
    direction`` (empty, or one row per direction of a :class:`Directional` attack), ``rid, task,
    source, pick`` (the picked letters, e.g. ``"A"`` or ``"AC"`` for a tie; None where the attack does
    not apply), ``answer, tied`` (size of the picked set), ``hit`` (expected hit)."""
    if batch is None:
        batch, _ = make_batch(rows, records, **settings)
    names = list(names) if names is not None else select(fast=True)
    frames = [picks_frame(batch, n, _run_one(ATTACKS[n], batch)) for n in names]
    frames = [f for f in frames if len(f)]
    if not frames:
        return pd.DataFrame(columns=PICK_COLUMNS)
    return pd.concat(frames, ignore_index=True)


def summarize_picks(picks: pd.DataFrame, *, alpha: float = 0.05, tests: dict | None = None, task_order: tuple = ()
                    ) -> pd.DataFrame:
    """Aggregate per-row picks into the attack table (see the module docstring for the columns).

    ``tests`` maps attack name -> comparisons inside it (Bonferroni factor; default from the registry).
    ``task_order``: the order of the tasks in the table (others follow by name).
    An attack with several directions keeps, per cell, the direction with the most expected hits and
    its p-value is multiplied by the number of directions too.
    """
    from .power import UNDERPOWERED_AT, attack_power

    load_families()
    tests = {**{n: a.tests for n, a in ATTACKS.items()}, **(tests or {})}
    if len(picks) == 0:
        return pd.DataFrame(columns=COLUMNS)
    if "family" not in picks.columns:
        picks = picks.assign(family=picks["attack"].map(lambda n: ATTACKS[n].family if n in ATTACKS else "option"))
    if "tied" not in picks.columns:
        picks = picks.assign(tied=picks["pick"].map(lambda s: 0 if pd.isna(s) else len(s)))
    picks = picks.assign(hit=picks["hit"].astype(float))
    if "direction" not in picks.columns:
        picks = picks.assign(direction="")
    out = []
    for (name, task), g in picks.groupby(["attack", "task"], sort=False):
        family = g["family"].iloc[0]
        for source, gs in [(s, gs) for s, gs in g.groupby("source", sort=False)] + [("ALL", g)]:
            options = []
            for direction, gd in gs.groupby("direction", sort=False):
                n_rows = len(gd)
                made = gd[gd["pick"].notna()]
                picked = len(made)
                hits = float(made["hit"].sum())
                ties = made["tied"].astype(int).tolist()
                if name == "constant_letter" and source == "ALL":
                    # best constant letter over the whole task, not the union of per-source choices
                    counts = Counter(gd["answer"])
                    hits = float(max(counts.values())) if counts else 0.0
                    picked, ties = n_rows, [1] * n_rows
                options.append((direction, n_rows, picked, hits, ties))
            options = [o for o in options if o[2] > 0] or options[:1]  # directions that apply to the cell
            # the direction with the most expected hits (the first on a tie), Bonferroni over directions
            direction, n_rows, picked, hits, ties = max(options, key=lambda o: (o[3], -options.index(o)))
            factor = tests.get(name, 1) * len(options)
            p = min(1.0, tie_aware_p(hits, ties) * factor) if picked else 1.0
            out.append({"attack": name, "family": family, "task": task, "source": source, "n_rows": n_rows,
                        "coverage": picked / n_rows if n_rows else 0.0, "picked": picked, "hits": hits,
                        "accuracy": hits / picked if picked else float("nan"), "chance": CHANCE, "p_value": p,
                        "tied_rows": int(sum(1 for k in ties if k > 1)), "direction": direction})
    df = pd.DataFrame(out)
    df = df[df["picked"] > 0]
    fam = {f: i for i, f in enumerate(FAMILIES)}
    order = {n: (fam.get(a.family, len(fam)), i) for i, (n, a) in enumerate(ATTACKS.items())}
    rank = {t: i for i, t in enumerate(task_order)}
    rank.update({t: len(rank) + i for i, t in enumerate(sorted(set(df["task"]) - set(rank)))})
    src_order = {s: i for i, s in enumerate(SOURCES)}
    df = df.assign(_a=df["attack"].map(lambda n: order.get(n, (len(fam), len(order)))), _t=df["task"].map(rank),
                   _s=df["source"].map(lambda s: src_order.get(s, 99)))
    df = df.sort_values(["_t", "_a", "_s"], kind="stable").drop(columns=["_a", "_t", "_s"]).reset_index(drop=True)
    df["p_holm"] = holm_adjusted(df["p_value"])
    df["significant"] = df["p_holm"] <= alpha
    power = attack_power(df["n_rows"], len(df), alpha=alpha, underpowered_at=UNDERPOWERED_AT)
    df = df.merge(power[["n_rows", "min_detectable", "underpowered"]], on="n_rows", how="left")
    return df[COLUMNS]


OPTION_ONLY = ("option",)


def attack_table(records: list[dict], *, iface=None, families=None, alpha: float = 0.05, fast: bool = False,
                 attacks=None, learned=None, groups: dict | None = None, progress: bool = False) -> pd.DataFrame:
    """The attack table of a list of release rows (dicts with Candidates as dicts).

    Parameters
    ----------
    records:
        Release (or legacy) rows.
    iface:
        The answer interface (:class:`resti_lib.options.spec.Interface`, from
        :func:`resti_lib.tasks.interface`): what each task's questions measure, for the attacks that
        read the question, and the order of the tasks in the table.
    families:
        Attack families to run (see :data:`FAMILIES`); ``"all"``: every family, the full blind suite of
        ``resti attack``. None (the default) keeps the historical scope of this function, the
        option-only rules (:data:`OPTION_ONLY`), unless ``attacks`` names attacks of other families.
    alpha:
        Holm family-wise error rate over every row of the table.
    fast:
        Leave the learned families out.
    attacks:
        Restrict to these attack names (within ``families``).
    learned:
        Learned-attacker settings (:class:`resti_lib.options.learned.LearnedConfig` or a dict of its
        fields); ``False`` leaves the learned families out (as ``fast``).
    groups:
        ``Legacy Row Key -> cross-validation group`` for the learned attackers (default: the source
        sequence read from the video name).
    progress:
        Show a progress bar over the attacks.
    """
    if families is None:
        families = OPTION_ONLY if attacks in (None, "all") else "all"
    names = select(families, attacks, fast=fast or learned is False)
    rows = parse_rows(records)
    batch, _ = make_batch(rows, records, learned=None if learned is False else learned, groups=groups or {},
                          iface=iface)
    it = names
    if progress:
        from tqdm.auto import tqdm

        it = tqdm(names, desc="attacks", unit="attack", disable=None)  # silent when not a terminal
    frames = []
    for n in it:
        f = picks_frame(batch, n, _run_one(ATTACKS[n], batch))
        if len(f):
            frames.append(f)
    picks = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=PICK_COLUMNS)
    return summarize_picks(picks, alpha=alpha, task_order=batch.task_order)


def strongest(table: pd.DataFrame, task: str, *, source: str = "ALL", full_coverage: bool = True
              ) -> pd.Series | None:
    """The attack with the highest accuracy for a task (optionally restricted to full coverage)."""
    t = table[(table["task"] == task) & (table["source"] == source)]
    if full_coverage:
        t = t[t["coverage"] >= 1.0 - 1e-12]
    if t.empty:
        return None
    return t.sort_values(["accuracy", "hits"], ascending=False, kind="stable").iloc[0]


def headline(table: pd.DataFrame) -> pd.DataFrame:
    """One row per task/source cell: significant cells first (strongest attack by p-value), then the
    others with their power. Columns ``task, source, n_rows, significant, attack, family, accuracy,
    p_value, p_holm, significant_attacks, families, min_detectable, underpowered``."""
    if table.empty:
        return pd.DataFrame(columns=["task", "source", "n_rows", "significant", "attack", "family", "accuracy",
                                     "p_value", "p_holm", "significant_attacks", "families", "min_detectable",
                                     "underpowered"])
    out = []
    for (task, source), g in table.groupby(["task", "source"], sort=False):
        best = g.sort_values(["p_value", "accuracy"], ascending=[True, False], kind="stable").iloc[0]
        sig = g[g["significant"]]
        out.append({"task": task, "source": source, "n_rows": int(best["n_rows"]),
                    "significant": bool(len(sig)), "attack": best["attack"], "family": best["family"],
                    "accuracy": float(best["accuracy"]), "p_value": float(best["p_value"]),
                    "p_holm": float(best["p_holm"]), "significant_attacks": len(sig),
                    "families": ",".join(f for f in FAMILIES if f in set(sig["family"])),
                    "min_detectable": float(best["min_detectable"]), "underpowered": bool(best["underpowered"])})
    df = pd.DataFrame(out)
    task_order = {t: i for i, t in enumerate(dict.fromkeys(table["task"]))}  # the table's own order
    src_order = {s: i for i, s in enumerate(SOURCES)}
    df = df.assign(_g=~df["significant"], _t=df["task"].map(task_order),
                   _s=df["source"].map(lambda s: src_order.get(s, 99)))
    return df.sort_values(["_g", "_t", "_s"], kind="stable").drop(columns=["_g", "_t", "_s"]).reset_index(drop=True)
