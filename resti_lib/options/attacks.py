"""Option-only attacks: pick a letter from the five candidate strings alone.

An attack sees only the candidates of a row plus the row's task and source (and, for the label
prior, the *other* rows' answers, leave-one-out). It never sees video, question text or the key.
Each attack returns, per row, a letter or ``None`` (abstain: the rule does not apply or ties).

The report has one row per (attack, task, source) and per (attack, task) with ``source == "ALL"``:
``coverage`` (fraction of the group's rows where the attack picked), ``picked``, ``hits``,
``accuracy`` (hits / picked), ``chance`` (1/5), ``p_value`` (exact one-sided binomial,
P[X >= hits | Binomial(picked, 1/5)]), and ``significant`` by Holm's step-down correction over
all rows of the report at level ``alpha``.

New attacks plug in with ``@attack("name", kinds=...)``.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np
import pandas as pd
from scipy.stats import binom

from .. import LETTERS, SOURCES, TASKS
from .. import values as V
from .checks import ParsedRow, parse_row

CHANCE = 1.0 / 5.0
COLUMNS = ["attack", "task", "source", "n_rows", "coverage", "picked", "hits", "accuracy", "chance",
           "p_value", "significant"]


@dataclass
class Attack:
    name: str
    kinds: tuple
    fn: Callable
    description: str
    needs_group: bool = False


ATTACKS: dict[str, Attack] = {}


def attack(name: str, kinds: Iterable[str], description: str, *, needs_group: bool = False):
    def deco(fn):
        ATTACKS[name] = Attack(name, tuple(kinds), fn, description, needs_group)
        return fn
    return deco


# ------------------------------------------------------------------------------------ helpers

TIE = 1e-12  # values closer than this are ties (printed values are far coarser)


def _close(a: float, b: float) -> bool:
    return abs(a - b) <= TIE


def _pick_unique(scores: dict) -> str | None:
    """The letter with the highest score; None when the highest is tied."""
    if not scores:
        return None
    target = max(scores.values())
    winners = [k for k, s in scores.items() if _close(s, target)]
    return winners[0] if len(winners) == 1 else None


def _scalar(p: ParsedRow) -> dict | None:
    if not all(isinstance(v, V.Scalar) for v in p.values.values()):
        return None
    return {k: v.si for k, v in p.values.items()}


def _rank_pick(vals: dict, rank: int) -> str | None:
    """Letter at 1-based ascending ``rank`` of the signed values; None on a tie at that position."""
    order = sorted(vals.items(), key=lambda kv: (kv[1], kv[0]))
    k, v = order[rank - 1]
    if sum(1 for _, w in order if _close(w, v)) > 1:
        return None
    return k


def _nearest(vecs: dict, target: np.ndarray) -> str | None:
    return _pick_unique({k: -float(np.linalg.norm(np.asarray(v) - target)) for k, v in vecs.items()})


def _medoid(vecs: dict, dist=None) -> str | None:
    keys = sorted(vecs)
    if dist is None:
        X = np.array([np.asarray(vecs[k], dtype=float).ravel() for k in keys])
        D = np.sqrt(((X[:, None, :] - X[None, :, :]) ** 2).sum(-1))
        return _pick_unique({k: -float(D[i].sum()) for i, k in enumerate(keys)})
    return _pick_unique({k: -sum(dist(vecs[k], vecs[j]) for j in keys if j != k) for k in keys})


def _rot_angle(A, B) -> float:
    c = (np.trace(np.asarray(A).T @ np.asarray(B)) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def _project_so3(M: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


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


# ------------------------------------------------------------------------------- the attacks

@attack("constant_letter", ["any"], "best constant letter in the group (Bonferroni over 5 letters)",
        needs_group=True)
def _constant_letter(rows: list[ParsedRow]):
    counts = Counter(p.answer for p in rows)
    best = max(LETTERS, key=lambda L: (counts.get(L, 0), -LETTERS.index(L)))
    return [best for _ in rows], 5


def _rank_attack(rank: int):
    def fn(p: ParsedRow):
        vals = _scalar(p)
        if vals is None and all(isinstance(v, V.Trajectory) for v in p.values.values()):
            vals = {k: v.total_distance for k, v in p.values.items()}
        return None if vals is None else _rank_pick(vals, rank)
    return fn


for _rank, _name in [(1, "min"), (2, "rank_2"), (3, "median"), (4, "rank_4"), (5, "max")]:
    attack(_name, ["scalar", "trajectory"], f"candidate of signed-value rank {_rank} of 5")(_rank_attack(_rank))


@attack("nearest_mean", ["scalar", "trajectory"], "candidate nearest to the mean of the five values")
def _nearest_mean(p: ParsedRow):
    vals = _scalar(p)
    if vals is None and all(isinstance(v, V.Trajectory) for v in p.values.values()):
        vals = {k: v.total_distance for k, v in p.values.items()}
    if vals is None:
        return None
    m = np.mean(list(vals.values()))
    return _pick_unique({k: -abs(v - m) for k, v in vals.items()})


@attack("medoid", ["scalar", "trajectory"], "candidate with the least total distance to the others")
def _medoid_scalar(p: ParsedRow):
    vals = _scalar(p)
    if vals is None and all(isinstance(v, V.Trajectory) for v in p.values.values()):
        vals = {k: v.total_distance for k, v in p.values.items()}
    if vals is None:
        return None
    return _medoid({k: np.array([v]) for k, v in vals.items()})


@attack("nearest_circular_mean", ["angle"], "angle nearest (circularly) to the circular mean")
def _circ(p: ParsedRow):
    if not all(isinstance(v, V.Scalar) and v.is_angle for v in p.values.values()):
        return None
    rad = {k: np.radians(v.value) for k, v in p.values.items()}
    m = np.arctan2(np.mean(np.sin(list(rad.values()))), np.mean(np.cos(list(rad.values()))))
    return _pick_unique({k: -abs(np.angle(np.exp(1j * (a - m)))) for k, a in rad.items()})


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
    votes = Counter()
    for j in range(X.shape[1]):
        col = X[:, j]
        hit = np.flatnonzero(np.abs(col - np.median(col)) <= TIE)
        hit = [keys[i] for i in hit]
        if len(hit) == 1:
            votes[hit[0]] += 1
    return _pick_unique(dict(votes)) if votes else None


@attack("field_majority", ["box", "pose"], "per-field modal value vote (values shared by >= 2 candidates)")
def _field_majority(p: ParsedRow):
    keys, X = _field_matrix(p)
    if X is None:
        return None
    votes = Counter()
    for j in range(X.shape[1]):
        c = Counter(np.round(X[:, j], 9))
        val, n = c.most_common(1)[0]
        if n >= 2 and list(c.values()).count(n) == 1:
            for i in range(len(keys)):
                if round(X[i, j], 9) == val:
                    votes[keys[i]] += 1
    return _pick_unique(dict(votes)) if votes else None


def _group_attack(group: str, how: str):
    def fn(p: ParsedRow):
        f = _fields(p)
        if f is None or group not in f:
            return None
        vecs = f[group]
        if group == "rotation":
            if how == "centroid":
                M = _project_so3(np.mean([vecs[k] for k in sorted(vecs)], axis=0))
                return _pick_unique({k: -_rot_angle(R, M) for k, R in vecs.items()})
            return _medoid(vecs, dist=_rot_angle)
        if how == "centroid":
            return _nearest({k: v for k, v in vecs.items()}, np.mean(list(vecs.values()), axis=0))
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
        return None
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


@attack("label_prior", ["label", "trajectory"],
        "most frequent correct label (trajectory: segment structure) among the other rows "
        "of the same task and source, leave-one-out", needs_group=True)
def _label_prior(rows: list[ParsedRow]):
    def key(v):
        return v.structure if isinstance(v, V.Trajectory) else v.key()

    correct = [key(p.values[p.answer]) if p.answer in p.values else None for p in rows]
    total = Counter(c for c in correct if c is not None)
    picks = []
    for p, c in zip(rows, correct):
        loo = total.copy()
        if c is not None:
            loo[c] -= 1
        scores = {k: loo.get(key(v), 0) for k, v in p.values.items()}
        picks.append(_pick_unique(scores) if max(scores.values(), default=0) > 0 else None)
    return picks, 1


@attack("shortest_string", ["any"], "shortest candidate string")
def _shortest(p: ParsedRow):
    return _pick_unique({k: -len(s) for k, s in p.candidates.items()})


@attack("longest_string", ["any"], "longest candidate string")
def _longest(p: ParsedRow):
    return _pick_unique({k: len(s) for k, s in p.candidates.items()})


# ------------------------------------------------------------------------------------ running

def _kind_of(p: ParsedRow) -> set:
    kinds = {v.kind for v in p.values.values()}
    if kinds == {"scalar"} and all(v.is_angle for v in p.values.values()):
        kinds = {"scalar", "angle"}
    return kinds | {"any"}


def holm(pvalues: Iterable[float], alpha: float) -> list[bool]:
    """Holm's step-down procedure: which hypotheses are rejected at family-wise level ``alpha``."""
    p = np.asarray(list(pvalues), dtype=float)
    m = len(p)
    order = np.argsort(p, kind="stable")
    reject = np.zeros(m, dtype=bool)
    for i, idx in enumerate(order):
        if p[idx] <= alpha / (m - i):
            reject[idx] = True
        else:
            break
    return reject.tolist()


def binom_p(hits: int, n: int, chance: float = CHANCE) -> float:
    """Exact one-sided binomial P[X >= hits], X ~ Binomial(n, chance)."""
    if n == 0:
        return 1.0
    return float(binom.sf(hits - 1, n, chance))


def parse_rows(records: list[dict]) -> list[ParsedRow]:
    out = []
    for i, r in enumerate(records):
        rid = r.get("ReSTI ID") or r.get("Legacy Row Key") or i
        out.append(parse_row(r, rid))
    return out


def run_picks(rows: list[ParsedRow], names: Iterable[str] | None = None) -> pd.DataFrame:
    """Per-row picks of every attack: columns ``attack, rid, task, source, pick, answer, hit``."""
    names = list(names) if names is not None else list(ATTACKS)
    usable = [p for p in rows if p.complete and p.answer in LETTERS]
    by_group: dict[tuple, list[ParsedRow]] = defaultdict(list)
    for p in usable:
        by_group[(p.task, p.source)].append(p)
    recs = []
    for name in names:
        a = ATTACKS[name]
        for (task, source), grp in sorted(by_group.items()):
            if a.needs_group:
                if "any" not in a.kinds and not any(set(a.kinds) & _kind_of(p) for p in grp):
                    continue
                picks, _ = a.fn(grp)
            else:
                picks = [a.fn(p) if (set(a.kinds) & _kind_of(p)) else "n/a" for p in grp]
            for p, pick in zip(grp, picks):
                if pick == "n/a":
                    continue
                recs.append((name, p.rid, task, source, pick, p.answer, pick == p.answer))
    return pd.DataFrame.from_records(recs, columns=["attack", "rid", "task", "source", "pick", "answer",
                                                    "hit"])


def summarize_picks(picks: pd.DataFrame, *, alpha: float = 0.05, tests: dict | None = None) -> pd.DataFrame:
    """Aggregate per-row picks into the attack table with binomial p-values and Holm flags.

    ``tests`` maps attack name -> number of implicit comparisons inside it (Bonferroni factor,
    e.g. 5 for the best constant letter).
    """
    tests = tests or {n: 5 if n == "constant_letter" else 1 for n in ATTACKS}
    out = []
    task_order = {t: i for i, t in enumerate(TASKS)}
    src_order = {s: i for i, s in enumerate(SOURCES)}
    if len(picks) == 0:
        return pd.DataFrame(columns=COLUMNS)
    for (name, task), g in picks.groupby(["attack", "task"], sort=False):
        groups = [(s, gs) for s, gs in g.groupby("source", sort=False)] + [("ALL", g)]
        for source, gs in groups:
            n_rows = len(gs)
            made = gs[gs["pick"].notna()]
            picked = len(made)
            hits = int(made["hit"].sum())
            if name == "constant_letter" and source == "ALL":
                # best constant letter over the whole task, not the union of per-source choices
                counts = Counter(gs["answer"])
                hits = max(counts.values()) if counts else 0
                picked = n_rows
            p = min(1.0, binom_p(hits, picked) * tests.get(name, 1))
            out.append({"attack": name, "task": task, "source": source, "n_rows": n_rows,
                        "coverage": picked / n_rows if n_rows else 0.0, "picked": picked, "hits": hits,
                        "accuracy": hits / picked if picked else float("nan"), "chance": CHANCE,
                        "p_value": p})
    df = pd.DataFrame(out)
    order = {n: i for i, n in enumerate(ATTACKS)}
    df["_a"] = df["attack"].map(order)
    df["_t"] = df["task"].map(task_order)
    df["_s"] = df["source"].map(lambda s: src_order.get(s, 99))
    df = df.sort_values(["_t", "_a", "_s"], kind="stable").drop(columns=["_a", "_t", "_s"])
    df["significant"] = holm(df["p_value"], alpha) if len(df) else []
    return df.reset_index(drop=True)[COLUMNS]


def attack_table(records: list[dict], *, alpha: float = 0.05, attacks: Iterable[str] | None = None,
                 ) -> pd.DataFrame:
    """The full attack report for a list of release rows (dicts with Candidates as dicts)."""
    rows = parse_rows(records)
    return summarize_picks(run_picks(rows, attacks), alpha=alpha)


def strongest(table: pd.DataFrame, task: str, *, source: str = "ALL", full_coverage: bool = True
              ) -> pd.Series | None:
    """The attack with the highest accuracy for a task (optionally restricted to full coverage)."""
    t = table[(table["task"] == task) & (table["source"] == source)]
    if full_coverage:
        t = t[t["coverage"] >= 1.0 - 1e-12]
    if t.empty:
        return None
    return t.sort_values(["accuracy", "hits"], ascending=False, kind="stable").iloc[0]
