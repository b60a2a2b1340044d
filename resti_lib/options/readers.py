"""Attack families that read beyond the five candidates: the question (family ``question``), the other
rows of the same video or source sequence (``cross_row``) and non-video metadata (``metadata``).

Question-aware rules use the observables of :mod:`resti_lib.options.observables` (the ones the option
stage conditions its distractors on):

- ``implied_rate_typical``: the rate a candidate implies over the question's window (a displacement
  or path over the window is a speed, a heading change a turn rate; speeds and accelerations are
  rates) scored by its density among the other rows' answer rates of the same source, rate kind and
  subject (the row's source sequence left out, log scale);
- ``implied_rate_possible``: the candidates whose implied rate is physically possible (at most the
  limit of :data:`PHYSICAL_LIMITS` and at most twice the largest rate among the other rows' answers);
- ``premise_distance``: the pose candidate nearest to (or farthest from) the premise pose printed in
  the question, candidates that repeat the premise left out;
- ``typical_value``: the candidate most (or least) typical of the answers to the other questions of
  the same type and subject noun (the row's source sequence left out);
- ``nearest_question``: nearest neighbours: the answers of the five most similar questions of other
  source sequences (word overlap) of the same type, and the candidate nearest to their median (scalars) or
  most frequent among them (labels, trajectory structures).

Cross-row reveals look at the other rows of the same video or source sequence: a candidate printed in
another row's question (``xrow_question``), among another row's candidates (``xrow_options``) or equal
to another row's answer (``xrow_answer``; this one reads other rows' keys, as a reader who knows the
answer to the other question does).

Metadata: the Waymo camera in the video name: ``metadata_label`` (labels and trajectory structures)
learns the most frequent answer per camera on one half of the source sequences and tests it on the
other (both ways; a majority vote that leaves one row out is not an exact test, its rows share their
luck), ``metadata_value`` (numbers) scores candidates by their density among the answers of other
sequences with the same camera.

Where the direction of a rule is not known in advance, it is chosen per row from the other rows of its
task/source cell (:func:`resti_lib.options.attacks.directional`).
"""

from __future__ import annotations

import re
from collections import Counter

import numpy as np

from .. import LETTERS
from .. import values as V
from ..errors import InputError
from .attacks import ALL5, Batch, answer_key, attack, directional, majority_label, split_halves, top

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
MIN_NOUN_ROWS = 4      # condition on the subject noun when at least this many other rows share it
NEIGHBOURS = 5


# ------------------------------------------------------------------------------------ observables
# What the rules read of :class:`resti_lib.options.observables.Observables`.

_PER_WINDOW = {"displacement": "speed", "path_length": "speed", "trajectory": "speed", "heading_change": "turn rate"}
_RATES = {"speed": "speed", "acceleration": "acceleration"}


def question_kind(o) -> str:
    """The question type: the measured quantity, with ``@instant`` for a speed or acceleration at one
    instant (averaged over a stated window) rather than over an interval."""
    if o.quantity in _RATES and o.time_start is not None and o.time_start == o.time_end:
        return f"{o.quantity}@instant"
    return o.quantity


def is_camera(o) -> bool:
    return o.subject_class == "camera"


def noun_of(o) -> str | None:
    """The head noun of the measured thing; None for the camera or when the question names none."""
    return None if is_camera(o) or not o.subject_class else o.subject_class


def implied_rate(value, o) -> tuple[str, float] | None:
    """The rate a value implies over the question's window: ``(kind, rate)``.

    Displacements, path lengths and trajectories imply a speed (distance / window, m/s), a heading
    change a turn rate (|degrees| / window); speeds and accelerations are rates themselves (SI
    magnitude). None when the value has no rate (another quantity, no window, an unparsed value).
    """
    if isinstance(value, V.Trajectory):
        x = value.total_distance
    elif isinstance(value, V.Scalar):
        x = abs(value.si)
    else:
        return None
    if o.quantity in _RATES:
        return _RATES[o.quantity], x
    kind = _PER_WINDOW.get(o.quantity)
    w = o.window_s
    if kind is None or w is None or w <= 0:
        return None
    return kind, x / w


def premise_parts(o) -> tuple[np.ndarray, np.ndarray] | None:
    """Translation (3,) and rotation (3, 3) of the premise pose of a Pose question, or None."""
    if o.premise is None:
        return None
    P = np.asarray(o.premise, float)
    return P[:3, 3], P[:3, :3]


def repeats_premise(v, o) -> bool:
    """Whether a pose candidate prints the premise pose itself (the same printed numbers)."""
    if o.premise is None or not isinstance(v, V.Pose):
        return False
    if o.premise_text:
        try:
            return V.parse(o.premise_text).key() == v.key()
        except InputError:
            return False
    return bool(np.allclose(v.matrix, np.asarray(o.premise, float), atol=0.5 * 10.0 ** -v.decimals + 1e-9))


# ------------------------------------------------------------------------------------ helpers

def _value_scale(p) -> dict | None:
    """Candidate values on the scale of their variation: log |x| for lengths, speeds and trajectories,
    signed degrees for angles; None for other kinds."""
    vals = p.values
    if all(isinstance(v, V.Scalar) for v in vals.values()):
        if all(v.is_angle for v in vals.values()):
            return {k: float(v.value) for k, v in vals.items()}
        return {k: float(np.log(abs(v.si) + 1e-3)) for k, v in vals.items()}
    if all(isinstance(v, V.Trajectory) for v in vals.values()):
        return {k: float(np.log(v.total_distance + 1e-3)) for k, v in vals.items()}
    return None


def _bandwidth(x: np.ndarray) -> float:
    """Silverman's rule on the candidate values of a group (blind: no answer is used)."""
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
        h = _bandwidth(cands.ravel())
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


def _cell_qtype(batch: Batch, i: int) -> tuple:
    return (batch.rows[i].task, batch.rows[i].source, question_kind(batch.obs[i]))


def _noun(batch: Batch, i: int):
    return noun_of(batch.obs[i])


# ------------------------------------------------------------------------------------ question-aware rules

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
    return (o.source, rates[i][0], "camera" if is_camera(o) else "object")


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


@attack("premise_distance", ["pose"], "pose candidate nearest to (or farthest from) the premise pose printed in "
        "the question, in translation and rotation (each scaled by the row's median), candidates repeating the "
        "premise left out (in every direction)", family="question", scope="batch")
def _premise_distance(batch: Batch):
    scores: list = []
    for p, o in zip(batch.rows, batch.obs):
        if o.premise is None or not all(isinstance(v, V.Pose) for v in p.values.values()):
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


@attack("typical_value", ["scalar", "trajectory"], "candidate most or least typical of the answers to the other "
        "questions of the same type (and subject noun when shared by enough rows) in other source sequences "
        "(in every direction)", family="question", scope="batch")
def _typical_value(batch: Batch):
    vals = [_value_scale(p) for p in batch.rows]
    dens = loo_density(batch, vals, lambda i: _cell_qtype(batch, i), noun_key=lambda i: _noun(batch, i))
    return directional(batch, dens)


_WORD = re.compile(r"[a-z]+")


def _words(q: str) -> frozenset:
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
    words = [_words(r.get("Question")) for r in batch.records]
    vals = [_value_scale(p) for p in batch.rows]
    groups = batch.groups(lambda i: _cell_qtype(batch, i))
    for idx in groups.values():
        neighbours = nearest_questions([words[i] for i in idx], exclude=[batch.obs[i].sequence for i in idx])
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


# ------------------------------------------------------------------------------------ cross-row reveals

def _numeric_row(p) -> bool:
    return all(v.kind in ("scalar", "box", "pose", "trajectory") for v in p.values.values())


def _flat(s: str) -> str:
    return "".join(str(s).split())


def _printed_in(s: str, text: str) -> bool:
    """``s`` occurs in ``text`` as a whole number: no digit or point before it, no digit after it."""
    at = text.find(s)
    while at >= 0:
        end = at + len(s)
        if (at == 0 or not (text[at - 1].isdecimal() or text[at - 1] == ".")) and not (
                end < len(text) and text[end].isdecimal()):
            return True
        at = text.find(s, at + 1)
    return False


def _sequence_groups(batch: Batch) -> dict:
    return batch.groups(lambda i: batch.obs[i].sequence, "sequence")


def _xrow_scores(batch: Batch, count) -> list:
    """Per numeric row: ``letter -> count(i, letter, others)`` over the other rows of its sequence."""
    out: list = [None] * len(batch)
    for idx in _sequence_groups(batch).values():
        for i in idx:
            if not _numeric_row(batch.rows[i]):
                continue
            others = [j for j in idx if j != i]
            out[i] = {k: float(count(i, k, others)) for k in LETTERS}
    return out


@attack("xrow_question", ["scalar", "box", "pose", "trajectory"], "candidate printed verbatim (spacing aside) in "
        "another question of the same video or source sequence (in every direction)", family="cross_row",
        scope="batch")
def _xrow_question(batch: Batch):
    flat_q = [_flat(r.get("Question") or "") for r in batch.records]
    premise_keys = []
    for o in batch.obs:
        try:
            premise_keys.append(V.parse(o.premise_text).key() if o.premise_text else None)
        except InputError:
            premise_keys.append(None)
    def count(i, k, others):
        p = batch.rows[i]
        s = _flat(p.candidates[k])
        key = p.values[k].key()
        return sum(1 for j in others if _printed_in(s, flat_q[j]) or (premise_keys[j] is not None
                                                                     and premise_keys[j] == key))
    return directional(batch, _xrow_scores(batch, count))


@attack("xrow_options", ["scalar", "box", "pose", "trajectory"], "candidate whose value recurs (or never recurs) "
        "among the candidates of the other rows of the same video or source sequence (in every direction)",
        family="cross_row", scope="batch")
def _xrow_options(batch: Batch):
    keys = [{v.key() for v in p.values.values()} for p in batch.rows]

    def count(i, k, others):
        key = batch.rows[i].values[k].key()
        return sum(1 for j in others if key in keys[j])
    return directional(batch, _xrow_scores(batch, count))


@attack("xrow_answer", ["scalar", "box", "pose", "trajectory"], "candidate equal to the answer of another row of "
        "the same video or source sequence (reads the other rows' keys; in every direction)",
        family="cross_row", scope="batch")
def _xrow_answer(batch: Batch):
    ans = [p.values[p.answer].key() for p in batch.rows]

    def count(i, k, others):
        key = batch.rows[i].values[k].key()
        return sum(1 for j in others if ans[j] == key)
    return directional(batch, _xrow_scores(batch, count))


# ------------------------------------------------------------------------------------ metadata

def _camera_key(batch: Batch, i: int):
    o = batch.obs[i]
    return None if o.camera is None else (batch.rows[i].task, batch.rows[i].source, question_kind(o), o.camera)


@attack("metadata_label", ["label", "trajectory"], "most frequent answer label (trajectory: structure) per camera in "
        "the video name, learned on one half of the source sequences and tested on the other (both ways)",
        family="metadata", scope="batch")
def _metadata_label(batch: Batch):
    return split_halves(batch, lambda train, test: majority_label(batch, train, test,
                                                                   lambda i: _camera_key(batch, i)))


@attack("metadata_value", ["scalar", "trajectory"], "candidate most or least typical of the answers of the other "
        "rows of other source sequences with the same camera in the video name and question type (in every "
        "direction)",
        family="metadata", scope="batch")
def _metadata_value(batch: Batch):
    vals = [_value_scale(p) for p in batch.rows]
    dens = loo_density(batch, vals, lambda i: _camera_key(batch, i))
    return directional(batch, dens)
