"""Scoring the blind attacks: tie-aware exact p-values, Holm's correction, power, large effects, and
the table, its headline and the strongest attack of a task.

The table (:func:`attack_table`) has one row per (attack, task, source) and per (attack, task) with
``source == "ALL"``: ``n_rows`` (usable rows of the cell), ``coverage`` (fraction the attack applies
to), ``picked``, ``draws`` (the picked rows as independent draws: a cluster of coupled rows is one, see
:meth:`.batch.Batch.coupled`), ``hits`` (expected hits), ``accuracy`` (hits / picked), ``chance`` (1/5), ``p_value``
(exact one-sided test of the expected hits under the null that the answer is any of the five options
with equal probability, independently across draws, see :func:`tie_aware_p`: rows whose candidate sets are
one draw, read from the strings, count as one, :meth:`.batch.Batch.coupled`; times the attack's own number
of comparisons; exact
when a row's pick reads no answer of a row whose hit is counted with it, approximate for the learned
attackers, which are fitted out of fold so that rows of one fold read the answers of the others: on a
re-optioned v5, over 40 redrawn sets of answer letters, the count spread 1.02-1.03 times the binomial
for the blind and question attackers and 1.12 times for the population attacker, whose features read
the training folds' answers, so its p-values are somewhat small),
``p_holm`` and ``significant`` (Holm's step-down correction over every row of the table at ``alpha``),
``min_detectable`` (the smallest blind accuracy the test detects with 80% power at the cell's
``n_rows`` and Holm's first-step level ``alpha / rows``) and ``underpowered`` (cannot detect 35%),
``tied_rows`` (rows scored as a tie), ``direction`` (the best direction of a :class:`Directional`
attack) and ``large_effect``.

``large_effect`` flags a blind accuracy too large to pass unnoticed where the table's correction cannot
reach it: at least :data:`LARGE_EFFECT_AT` (35%) on at least :data:`LARGE_EFFECT_MIN_ROWS` picked rows,
with the lower end of the two-sided 99% exact (Clopper-Pearson) interval of the cell's accuracy above
chance (the interval widened for the attack's own comparisons, as its p-value is). A significant row
can be a large effect too; the flag matters where the cell is small and the table large.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable

import numpy as np
import pandas as pd
from scipy.stats import binom

from ... import SOURCES
from ..power import UNDERPOWERED_AT, attack_power, clopper_pearson
from .batch import Batch, kind_of, make_batch, parse_rows
from .common import CHANCE, Directional, as_pick, direction_name, expected_hit
from .registry import ATTACKS, FAMILIES, Attack, family_of, select

COLUMNS = ["attack", "family", "task", "source", "n_rows", "coverage", "picked", "draws", "hits", "accuracy", "chance",
           "p_value", "p_holm", "significant", "min_detectable", "underpowered", "tied_rows", "direction",
           "large_effect"]
PICK_COLUMNS = ["attack", "family", "direction", "rid", "task", "source", "pick", "answer", "tied", "hit", "cluster",
                "slots"]
HEADLINE_COLUMNS = ["task", "source", "n_rows", "significant", "attack", "family", "accuracy", "p_value", "p_holm",
                    "significant_attacks", "families", "min_detectable", "underpowered", "large_effect",
                    "large_effects", "large_effect_attacks"]
OPTION_ONLY = ("option",)
LARGE_EFFECT_AT = 0.35        # a blind accuracy this large is flagged ...
LARGE_EFFECT_MIN_ROWS = 20    # ... on at least this many picked rows ...
LARGE_EFFECT_LEVEL = 0.99     # ... when the exact interval at this level lies above chance
LARGE_EFFECT_SHOWN = 3        # large-effect attacks named per headline cell


# ------------------------------------------------------------------------------------ statistics

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


def tie_aware_p(hits: float, ties: Iterable[int]) -> float:
    """Exact one-sided p-value of tie-aware expected hits.

    Row ``i`` picks a set of ``k_i`` letters and scores ``1/k_i`` when the answer is in it. Under the
    null (the answer is each of the five candidates with probability 1/5, independently across rows)
    the row scores ``1/k_i`` with probability ``k_i/5``. The score sum ``S`` is, in units of 1/60,
    ``sum_k (60/k) H_k`` with ``H_k ~ Binomial(n_k, k/5)`` (``n_k`` rows with a ``k``-way tie); this
    returns ``P[S >= hits]`` by exact convolution (the ``k = 1`` part in closed form). With no ties it
    is :func:`binom_p`.
    """
    return tie_aware_p_counts(hits, Counter(int(k) for k in ties))


def tie_aware_p_counts(hits: float, n: dict, clusters: Iterable = ()) -> float:
    """:func:`tie_aware_p` from the number of rows of each tie size (``{k: rows picking k letters}``), and
    ``clusters``: groups of rows whose answers sit at one place of one candidate set (:meth:`.batch.Batch.coupled`),
    each given as its score in units of 1/60 when the answer is at each of the five places (a length-5
    sequence); a cluster is one draw (each place with probability 1/5), its rows are not in ``n``."""
    n = {int(k): int(v) for k, v in n.items() if v}
    clusters = [np.asarray(c, int) for c in clusters]
    if not n and not clusters:
        return 1.0
    w_obs = round(hits * 60)
    if set(n) <= {1} and not clusters:
        return binom_p(round(hits), n[1])
    offset = 12 * n.get(5, 0)                       # five-way ties always score 1/5
    pmf = np.array([1.0])                            # distribution of the k = 2..4 part and the clusters, 1/60 units
    for c in clusters:
        part = np.zeros(int(c.max()) + 1)
        np.add.at(part, c, 0.2)
        pmf = np.convolve(pmf, part) if len(pmf) * len(part) < 4e7 else _fft_convolve(pmf, part)
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


def large_effects(hits, picked, factor, *, at: float = LARGE_EFFECT_AT, min_rows: int = LARGE_EFFECT_MIN_ROWS,
                  level: float = LARGE_EFFECT_LEVEL, p_values=None) -> np.ndarray:
    """Which cells show a large blind effect: accuracy ``hits / picked`` at least ``at`` on at least
    ``min_rows`` picked rows, with the lower end of the exact two-sided interval at ``level`` (widened to
    ``1 - (1 - level) / factor`` for an attack of ``factor`` comparisons) above chance.

    ``p_values``: the cells' exact one-sided p-values, already times ``factor`` (the table's): the interval's
    lower end lies above chance exactly when that test rejects at ``(1 - level) / 2`` (the exact interval
    inverts the exact test), and the table's test also counts ties and coupled rows (one draw per cluster)."""
    hits, picked, factor = (np.asarray(x, float) for x in (hits, picked, factor))
    with np.errstate(invalid="ignore", divide="ignore"):
        acc = np.where(picked > 0, hits / np.maximum(picked, 1), 0.0)
    if p_values is not None:
        return (picked >= min_rows) & (acc >= at) & (np.asarray(p_values, float) < (1.0 - level) / 2.0)
    lo = np.zeros(len(hits))
    ok = picked > 0
    if ok.any():
        lvl = 1.0 - (1.0 - level) / np.maximum(factor[ok], 1.0)
        lo[ok] = [float(clopper_pearson(h, n, level=lv)[0]) for h, n, lv in zip(hits[ok], picked[ok], lvl)]
    return (picked >= min_rows) & (acc >= at) & (lo > CHANCE)


# ------------------------------------------------------------------------------------ running

def _pick_text(pick: frozenset | None) -> str | None:
    return None if pick is None else "".join(sorted(pick))


def run_one(a: Attack, batch: Batch) -> list | Directional:
    """The picks of one attack on a batch: a list (one pick per row, None where it does not apply) or a
    :class:`Directional`."""
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
        if not kinds & kind_of(p):
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
    family = family or family_of(name)
    parts = [(direction_name(d), pk) for d, pk in picks.items()] if isinstance(picks, Directional) else [("", picks)]
    applies = {batch.rows[i].task for _, pk in parts for i, x in enumerate(pk) if x is not None}
    cluster, slots = batch.coupled()
    recs = []
    for d, pk in parts:
        for i, (p, x) in enumerate(zip(batch.rows, pk)):
            if p.task not in applies:
                continue
            recs.append((name, family, d, p.rid, p.task, p.source, _pick_text(x), p.answer, len(x) if x else 0,
                         expected_hit(x, p.answer) if x else float("nan"), cluster[i], slots[i]))
    return pd.DataFrame.from_records(recs, columns=PICK_COLUMNS)


def run_picks(rows: list, names: Iterable[str] | None = None, *, records: list[dict] | None = None,
              batch: Batch | None = None, **settings) -> pd.DataFrame:
    """Per-row picks of the named attacks (default: every non-learned attack): columns ``attack, family,
    direction`` (empty, or one row per direction of a :class:`Directional` attack), ``rid, task,
    source, pick`` (the picked letters, e.g. ``"A"`` or ``"AC"`` for a tie; None where the attack does
    not apply), ``answer, tied`` (size of the picked set), ``hit`` (expected hit)."""
    if batch is None:
        batch, _ = make_batch(rows, records, **settings)
    names = list(names) if names is not None else select(fast=True)
    frames = [picks_frame(batch, n, run_one(ATTACKS[n], batch)) for n in names]
    frames = [f for f in frames if len(f)]
    if not frames:
        return pd.DataFrame(columns=PICK_COLUMNS)
    return pd.concat(frames, ignore_index=True)


# ------------------------------------------------------------------------------------ the table

_TIES = range(1, 6)


def _aggregate(picks: pd.DataFrame, keys: list) -> pd.DataFrame:
    """Per ``keys`` group (and direction, in order of appearance): rows, picked rows, expected hits and
    picked rows by size of the picked set (``t1`` .. ``t5``)."""
    return picks.groupby(keys + ["direction"], sort=False).agg(
        n_rows=("hit", "size"), picked=("_picked", "sum"), hits=("hit", "sum"),
        **{f"t{k}": (f"_t{k}", "sum") for k in _TIES}).reset_index()


def summarize_picks(picks: pd.DataFrame, *, alpha: float = 0.05, tests: dict | None = None, task_order: tuple = ()
                    ) -> pd.DataFrame:
    """Aggregate per-row picks into the attack table (see the module docstring for the columns).

    ``tests`` maps attack name -> comparisons inside it (Bonferroni factor; default from the registry).
    ``task_order``: the order of the tasks in the table (others follow by name).
    An attack with several directions keeps, per cell, the direction with the most expected hits and
    its p-value is multiplied by the number of directions too.
    """
    tests = {**{n: a.tests for n, a in ATTACKS.items()}, **(tests or {})}
    if len(picks) == 0:
        return pd.DataFrame(columns=COLUMNS)
    if "family" not in picks.columns:
        picks = picks.assign(family=picks["attack"].map(family_of))
    if "tied" not in picks.columns:
        picks = picks.assign(tied=picks["pick"].map(lambda s: 0 if pd.isna(s) else len(s)))
    if "direction" not in picks.columns:
        picks = picks.assign(direction="")
    made = picks["pick"].notna()
    tied = picks["tied"].astype(int)
    picks = picks.assign(hit=picks["hit"].astype(float).where(made, 0.0), _picked=made,
                         **{f"_t{k}": made & (tied == k) for k in _TIES})
    by_source = _aggregate(picks, ["attack", "task", "source"])
    pooled = _aggregate(picks, ["attack", "task"]).assign(source="ALL")
    const = pooled["attack"] == "constant_letter"
    if const.any():  # the best constant letter over the whole task, not the union of per-source choices
        best = picks[picks["attack"] == "constant_letter"].groupby(["task", "direction"], sort=False)["answer"].agg(
            lambda a: float(a.value_counts().max()))
        rows = pooled.loc[const]
        pooled.loc[const, "hits"] = [best[(t, d)] for t, d in zip(rows["task"], rows["direction"])]
        pooled.loc[const, "picked"] = rows["n_rows"]
        pooled.loc[const, [f"t{k}" for k in _TIES]] = 0
        pooled.loc[const, "t1"] = rows["n_rows"]
    agg = pd.concat([by_source, pooled], ignore_index=True)
    # per cell: the direction with the most expected hits among those that apply (the first on a tie)
    agg["_order"] = np.arange(len(agg))
    agg["_applies"] = agg["picked"] > 0
    cell = ["attack", "task", "source"]
    n_applies = agg.groupby(cell, sort=False)["_applies"].transform("sum")
    agg["_options"] = np.where(n_applies > 0, n_applies, 1)
    agg = agg[agg["_applies"] | (n_applies == 0)]
    agg = agg.sort_values(["hits", "_order"], ascending=[False, True], kind="stable").drop_duplicates(cell)
    agg = agg[agg["picked"] > 0].sort_values("_order", kind="stable")
    agg["_factor"] = agg["attack"].map(lambda n: tests.get(n, 1)) * agg["_options"]
    ties = agg[[f"t{k}" for k in _TIES]].to_numpy(int)
    # coupled rows are one draw (per source and pooled; not the pooled constant letter, whose count is
    # the best letter's over the task)
    coupled = picks[picks["cluster"].notna()] if "cluster" in picks.columns else picks.iloc[:0]
    clusters = cluster_scores(pd.concat([coupled, coupled.assign(source="ALL")], ignore_index=True),
                              ["attack", "task", "source", "direction"])
    p, draws = [], []
    for a, tk, src, d, h, t in zip(agg["attack"], agg["task"], agg["source"], agg["direction"], agg["hits"], ties):
        pv, nd = _cell_p(h, t, None if (a, src) == ("constant_letter", "ALL") else clusters.get((a, tk, src, d)))
        p.append(pv)
        draws.append(nd)
    family = picks.drop_duplicates("attack").set_index("attack")["family"]
    df = pd.DataFrame({"attack": agg["attack"].to_numpy(), "family": agg["attack"].map(family).to_numpy(),
                       "task": agg["task"].to_numpy(), "source": agg["source"].to_numpy(),
                       "n_rows": agg["n_rows"].to_numpy(int), "picked": agg["picked"].to_numpy(int), "draws": draws,
                       "hits": agg["hits"].to_numpy(float), "chance": CHANCE,
                       "p_value": np.minimum(1.0, np.array(p) * agg["_factor"].to_numpy()),
                       "tied_rows": ties[:, 1:].sum(1), "direction": agg["direction"].to_numpy(),
                       "_factor": agg["_factor"].to_numpy()})
    df["coverage"] = df["picked"] / df["n_rows"]
    df["accuracy"] = df["hits"] / df["picked"]
    fam = {f: i for i, f in enumerate(FAMILIES)}
    order = {n: (fam.get(a.family, len(fam)), i) for i, (n, a) in enumerate(ATTACKS.items())}
    rank = {t: i for i, t in enumerate(task_order)}
    rank.update({t: len(rank) + i for i, t in enumerate(sorted(set(df["task"]) - set(rank)))})
    src_order = {s: i for i, s in enumerate(SOURCES)}
    src_order["ALL"] = len(SOURCES) + 1
    df = df.assign(_a=df["attack"].map(lambda n: order.get(n, (len(fam), len(order)))), _t=df["task"].map(rank),
                   _s=df["source"].map(lambda s: src_order.get(s, len(SOURCES))))
    df = df.sort_values(["_t", "_a", "_s"], kind="stable").drop(columns=["_a", "_t", "_s"]).reset_index(drop=True)
    df["p_holm"] = holm_adjusted(df["p_value"])
    df["significant"] = df["p_holm"] <= alpha
    df["large_effect"] = large_effects(df["hits"], df["picked"], df["_factor"], p_values=df["p_value"])
    power = attack_power(df["n_rows"], len(df), alpha=alpha, underpowered_at=UNDERPOWERED_AT)
    df = df.merge(power[["n_rows", "min_detectable", "underpowered"]], on="n_rows", how="left")
    return df[COLUMNS]


def cluster_scores(picks: pd.DataFrame, keys: list) -> dict:
    """Per cell (a tuple of ``keys``): the clusters of coupled rows it holds (two or more picked rows of one
    cluster, :meth:`.batch.Batch.coupled`), each as its score in units of 1/60 at each of the five places of
    the set, and how many of the cell's picked rows of each tie size they take, for
    :func:`tie_aware_p_counts`. A picks table without clusters (rows given without their batch) has none."""
    if len(picks) == 0 or "cluster" not in picks.columns or "slots" not in picks.columns:
        return {}
    c = picks[picks["pick"].notna() & picks["cluster"].notna() & picks["slots"].notna()]
    if not len(c):
        return {}
    gid = c.groupby(keys + ["cluster"], sort=False).ngroup().to_numpy()
    size = np.bincount(gid)
    contrib = np.zeros((len(c), 5), int)   # each row's score (1/60 units) at each place of its set
    tied = np.zeros(len(c), int)
    for r, (pick, slots) in enumerate(zip(c["pick"].to_numpy(), c["slots"].to_numpy())):
        tied[r] = len(pick)
        for letter in pick:
            contrib[r, slots.index(letter)] += 60 // len(pick)
    score = np.zeros((size.size, 5), int)
    np.add.at(score, gid, contrib)
    ties = np.zeros((size.size, 6), int)
    np.add.at(ties, (gid, tied), 1)
    first = np.unique(gid, return_index=True)[1]
    cells = c[keys].to_numpy(object)[first]
    out: dict = {}
    for g in np.flatnonzero(size >= 2):
        scores, taken = out.setdefault(tuple(cells[g]), ([], Counter()))
        scores.append(score[g])
        taken.update({k: int(ties[g, k]) for k in range(1, 6) if ties[g, k]})
    return out


def cell_tests(picks: pd.DataFrame, keys: list) -> pd.DataFrame:
    """Per cell of ``keys`` over picked rows: ``n`` rows, expected ``hits`` and ``p``, the exact one-sided
    p-value of :func:`tie_aware_p_counts` (ties scored by expected hit, coupled rows one draw), with no
    correction for comparisons. The test the option stage's adversarial filter runs."""
    picks = picks[picks["pick"].notna()]
    tied = picks["pick"].map(len)
    cells = picks.assign(**{f"_t{k}": tied == k for k in _TIES}).groupby(keys, sort=True).agg(
        n=("hit", "size"), hits=("hit", "sum"), **{f"t{k}": (f"_t{k}", "sum") for k in _TIES})
    clusters = cluster_scores(picks, keys)
    p = [_cell_p(h, t, clusters.get(key if isinstance(key, tuple) else (key,)))[0]
         for key, h, t in zip(cells.index, cells["hits"], cells[[f"t{k}" for k in _TIES]].to_numpy(int))]
    return cells[["n", "hits"]].assign(p=p)


def _cell_p(hits: float, ties, coupled: tuple | None) -> tuple[float, int]:
    """The exact p-value of a cell (its picked rows by tie size ``ties``, ``t1`` .. ``t5``; ``coupled``: its
    entry of :func:`cluster_scores`, None without clusters) and its number of independent draws."""
    scores, taken = coupled if coupled is not None else ([], {})
    rest = {k: int(v) - taken.get(k, 0) for k, v in zip(_TIES, ties)}
    return tie_aware_p_counts(hits, rest, scores), sum(rest.values()) + len(scores)


def attack_table(records: list[dict], *, iface=None, families=None, alpha: float = 0.05, fast: bool = False,
                 attacks=None, learned=None, groups: dict | None = None, progress: bool = False,
                 evaluate: Iterable | None = None) -> pd.DataFrame:
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
        Learned-attacker settings (:class:`resti_lib.options.attacks.learned.LearnedConfig` or a dict of
        its fields); ``False`` leaves the learned families out (as ``fast``).
    groups:
        ``Legacy Row Key -> cross-validation group`` for the learned attackers (default: the source
        sequence read from the video name).
    progress:
        Show a progress bar over the attacks.
    evaluate:
        Score only these rows (ids as :func:`parse_rows` gives them: ``ReSTI ID``, else ``Legacy Row
        Key``); every row stays readable (siblings, populations, training folds). With the ids outside
        the named structural leaks (:func:`resti_lib.options.structural.residual_ids`), the table
        says whether the options leak anything beyond what no option design can hide.
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
        f = picks_frame(batch, n, run_one(ATTACKS[n], batch))
        if len(f):
            frames.append(f)
    picks = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=PICK_COLUMNS)
    if evaluate is not None:
        keep = {str(x) for x in evaluate}
        picks = picks[picks["rid"].astype(str).isin(keep)]
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
    cells with a large effect (:func:`large_effects`) that the table's correction does not reach, then
    the others with their power. Columns :data:`HEADLINE_COLUMNS`: ``large_effect`` (the cell has a
    large effect), ``large_effects`` (how many attacks show one) and ``large_effect_attacks`` (the
    strongest of them by accuracy, ``name (accuracy, hits/picked)``)."""
    if table.empty:
        return pd.DataFrame(columns=HEADLINE_COLUMNS)
    if "large_effect" not in table.columns:
        table = table.assign(large_effect=False)
    out = []
    for (task, source), g in table.groupby(["task", "source"], sort=False):
        best = g.sort_values(["p_value", "accuracy"], ascending=[True, False], kind="stable").iloc[0]
        sig = g[g["significant"]]
        large = g[g["large_effect"].astype(bool)].sort_values(["accuracy", "hits"], ascending=False, kind="stable")
        named = ", ".join(f"{r.attack} ({r.accuracy:.2f}, {r.hits:g}/{r.picked})"
                          for r in large.head(LARGE_EFFECT_SHOWN).itertuples())
        out.append({"task": task, "source": source, "n_rows": int(best["n_rows"]),
                    "significant": bool(len(sig)), "attack": best["attack"], "family": best["family"],
                    "accuracy": float(best["accuracy"]), "p_value": float(best["p_value"]),
                    "p_holm": float(best["p_holm"]), "significant_attacks": len(sig),
                    "families": ",".join(f for f in FAMILIES if f in set(sig["family"])),
                    "min_detectable": float(best["min_detectable"]), "underpowered": bool(best["underpowered"]),
                    "large_effect": bool(len(large)), "large_effects": len(large), "large_effect_attacks": named})
    df = pd.DataFrame(out)
    task_order = {t: i for i, t in enumerate(dict.fromkeys(table["task"]))}  # the table's own order
    src_order = {s: i for i, s in enumerate(SOURCES)}
    df = df.assign(_g=np.where(df["significant"], 0, np.where(df["large_effect"], 1, 2)), _t=df["task"].map(task_order),
                   _s=df["source"].map(lambda s: src_order.get(s, 99)))
    return df.sort_values(["_g", "_t", "_s"], kind="stable").drop(columns=["_g", "_t", "_s"]).reset_index(drop=True)
