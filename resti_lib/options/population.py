"""Population models of answers: one-dimensional marginals and a Gaussian copula over fields.

The option stage (:mod:`resti_lib.options.stage`) draws the five candidates of a row as
*exchangeable* draws from the distribution of answers of its group, conditioned on what the question
states (its observables). One of the five is the answer. A blind reader then has nothing to tell the
answer from the others: under the model every candidate is a draw from the same conditional
distribution, and the answer is one of them chosen at random.

Two pieces make that distribution:

* :class:`Marginal` — the distribution of one field of a group's answers in a *base space* (log of a
  magnitude minus a per-row offset such as the log of the question's window, an angle on a cut
  circle, a coordinate). It is an adaptive Gaussian kernel density estimate (each answer's bandwidth
  is the distance to its ``k``-th nearest *distinct* other answer, never below half its printed
  unit), mapped to a standard normal *score* by its CDF. The map of a row leaves the row's own answer
  out. Cost: O(m·G) to fit (m distinct values, G grid points) and O(G) per row, so a group of n rows
  costs O(n log n + n·G), never n².
* :class:`Copula` — the correlation of the scores of several fields (a box's centre and its three
  edge lengths) and of covariates (the log of the question's time window), shrunk towards
  independence for small groups. Conditioning on a row's covariates gives the distribution of its
  fields given what the question states.

Drawing (standardised conditional scores ``z``, see :class:`resti_lib.options.stage.RowDraw`): an
anchor ``c ~ N(0, (1 - s²) I)`` and five candidates ``z_j = c + s·e_j`` are exchangeable and each is
``N(0, I)``. Given the answer's ``z_a``, the anchor is ``N((1 - s²) z_a, s²(1 - s²) I)`` and the
other four follow.

Every row's distractors are drawn from the other recordings' answers, so each answer leaves an *echo*:
the other rows' distractors crowd where it is while no other answer need be there, and a reader holding the
release finds the answer where the other recordings' candidates outnumber their answers. The kernels'
width decides it: :func:`echo_balanced` simulates the candidate sets of a group and widens the bandwidth
where the likelihood's leaves the answer's echo off its chance rank.

Coarsely printed magnitudes (a group whose median answer is under ``model.lattice.below_units``
printed units, such as speeds of a hand-held camera at 0.01 m/s) and narrow populations (the middle
half of the answers spans under ``model.lattice.below_floors`` separation floors) are drawn on a
*quantile lattice* instead (:func:`lattice_scores`): five candidates a printed unit apart cannot crowd an answer of a few
units the way the anchor model's would, and the widened sets that survive separation made the answer
the most typical candidate. On the lattice each candidate takes one of five strata of equal
probability (random offset), so the set is exchangeable under the model whatever the separation
floor.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtr, ndtri

from ..rng import stable_seed
from .attacks.prior import kernel_sums

_P_MIN = 1e-12


def circular_cut(deg) -> float:
    """The middle of the widest empty arc of a set of angles (where a circle is best cut open)."""
    a = np.sort((np.asarray(deg, dtype=float) + 180.0) % 360.0 - 180.0)
    if a.size == 0:
        return 180.0
    gaps = np.diff(np.concatenate([a, [a[0] + 360.0]]))
    i = int(np.argmax(gaps))
    return float((a[i] + gaps[i] / 2.0 + 180.0) % 360.0 - 180.0)


def on_cut_line(deg, cut: float) -> np.ndarray:
    """Angles (degrees) as positions on the circle cut open at ``cut``: values in (-180, 180] from
    the point opposite the cut."""
    return (np.asarray(deg, dtype=float) - cut) % 360.0 - 180.0


def from_cut_line(x, cut: float) -> np.ndarray:
    return (np.asarray(x, dtype=float) + 180.0 + cut + 180.0) % 360.0 - 180.0


def _kth_distinct_gap(u: np.ndarray, k: int) -> np.ndarray:
    """For sorted distinct values ``u``: distance from each to its ``k``-th nearest other value."""
    m = u.size
    if m == 1:
        return np.array([np.inf])
    k = min(k, m - 1)
    cand = []
    for j in range(1, k + 1):
        left = np.full(m, np.inf)
        left[j:] = u[j:] - u[:-j]
        right = np.full(m, np.inf)
        right[:-j] = u[j:] - u[:-j]
        cand += [left, right]
    return np.sort(np.vstack(cand), axis=0)[k - 1]


def _bandwidths(b: np.ndarray, half: np.ndarray, k: int, bw: float, max_distinct: int) -> np.ndarray:
    """Each value's kernel bandwidth: ``bw`` times the distance to its ``k``-th nearest distinct other value,
    never below its half rounding cell ``half``. Values that differ by less than 1/max_distinct of the span
    are one distinct value (keeps the fit O(n log n) when a group holds 100k rows)."""
    span = float(b.max() - b.min())
    res = span / max_distinct if span > 0 else 1.0
    q = np.round((b - b.min()) / res) if span > 0 else np.zeros_like(b)
    uq, inv = np.unique(q, return_inverse=True)
    ub = b.min() + uq * res if span > 0 else np.array([b[0]])
    gap = _kth_distinct_gap(ub, k)
    if not np.isfinite(gap).any():
        gap = np.full_like(gap, 8.0 * float(half.max()))
    gap = np.where(np.isfinite(gap), gap, np.nanmax(np.where(np.isfinite(gap), gap, np.nan)))
    return np.maximum(bw * gap[inv], half)


KNN_STEP = 1.5        # the neighbour counts tried by select_knn: k, 1.5 k, 2.25 k, ... up to k_max
KNN_EVAL_ROWS = 512   # held-out answers scored per count (evenly spaced in value order beyond that)


def knn_ladder(k: int, k_max: int) -> list[int]:
    """The neighbour counts tried: ``k``, ``k * KNN_STEP``, ... (rounded, distinct) up to ``k_max``, and ``k_max``."""
    ladder: list[int] = []
    kk = float(k)
    while int(round(kk)) <= k_max:
        if int(round(kk)) not in ladder:
            ladder.append(int(round(kk)))
        kk *= KNN_STEP
    if k_max not in ladder:
        ladder.append(int(k_max))
    return ladder


def recording_labels(groups, n: int) -> list[str]:
    """Each row's recording label (``groups``; a row without one, or no ``groups``, is its own)."""
    return [f"rec:{x}" if x is not None else f"row:{i}" for i, x in enumerate(groups)] if groups is not None \
        else [f"row:{i}" for i in range(n)]


def select_knn(b, half, groups, k: int, k_max: int, *, bw: float = 1.0, max_distinct: int = 8192) -> int:
    """The neighbour count of the adaptive bandwidth, among ``k``, ``k * KNN_STEP``, ... ``k_max``, whose
    density of the other recordings' answers gives each recording's answers (``groups``: one label per
    value; None: each value its own) the highest mean log density. Several answers of one recording (the
    same car asked twice) count as one piece of evidence. The likelihood does not see the echo of each
    answer in the other rows' distractors; :func:`echo_balanced` widens against it. Cost:
    O(n * min(n, KNN_EVAL_ROWS)) per count."""
    b = np.asarray(b, float)
    n = b.size
    g = np.arange(n) if groups is None else np.asarray([str(x) for x in groups], dtype=object)
    ladder = knn_ladder(k, max(int(k), min(int(k_max), n)))  # a count beyond the values is the widest there is
    ev = np.arange(n) if n <= KNN_EVAL_ROWS else np.argsort(b, kind="stable")[
        np.linspace(0, n - 1, KNN_EVAL_ROWS).round().astype(int)]
    other = g[ev][:, None] != g[None, :]                   # (E, n): kernels of other recordings only
    n_other = other.sum(axis=1)
    keep = n_other > 0
    if keep.sum() < 2:
        return int(k)
    ev, other, n_other = ev[keep], other[keep], n_other[keep]
    span = float(b.max() - b.min()) or 1.0
    floor = 1e-3 / span                                    # a lone answer costs a bounded penalty
    best, best_score = int(k), -np.inf
    for kk in ladder:
        h = _bandwidths(b, np.broadcast_to(half, b.shape), kk, bw, max_distinct)
        dens = ((np.exp(-0.5 * ((b[ev][:, None] - b[None, :]) / h[None, :]) ** 2) / h[None, :]) * other).sum(axis=1)
        score = float(np.mean(np.log(dens / (n_other * math.sqrt(2.0 * math.pi)) + floor)))
        if score > best_score + 1e-9:
            best, best_score = kk, score
    return best


@dataclass
class Marginal:
    """Adaptive KDE of one field's base values, as a map between values and standard normal scores.

    ``b``: the base value of each row (in row order); ``h``: each row's kernel bandwidth;
    ``grid``/``total``: the summed kernel CDF of all rows on a grid; ``k``: the neighbour count of the
    bandwidths.
    """

    b: np.ndarray
    h: np.ndarray
    grid: np.ndarray
    total: np.ndarray
    k: int = 4  # the neighbour count of the bandwidth
    _own: dict = field(default_factory=dict, repr=False, compare=False)  # summed CDF of the rows left out, per set

    @property
    def n(self) -> int:
        return int(self.b.size)

    @classmethod
    def fit(cls, b, half_cell, *, k: int = 4, bw: float = 1.0, grid: int = 2048, max_distinct: int = 8192,
            k_max: int = 0, groups=None) -> "Marginal":
        """Fit on base values ``b`` (one per row) with ``half_cell`` (scalar or per row) the half
        width of each value's printed rounding cell in base space (the smallest bandwidth).

        ``k_max`` above ``k``: the neighbour count of the bandwidth is chosen among ``k`` .. ``k_max``
        (:func:`select_knn`) as the one whose density best predicts the answers of each recording
        (``groups``, one label per value) from the other recordings."""
        b = np.asarray(b, dtype=float)
        if b.size == 0 or not np.all(np.isfinite(b)):
            raise ValueError("a marginal needs finite values")
        half = np.broadcast_to(np.asarray(half_cell, dtype=float), b.shape)
        half = np.maximum(half, 1e-9)
        if k_max > k:
            k = select_knn(b, half, groups, k, k_max, bw=bw, max_distinct=max_distinct)
        h = _bandwidths(b, half, k, bw, max_distinct)
        lo, hi = float((b - 6.0 * h).min()), float((b + 6.0 * h).max())
        g = np.linspace(lo, hi, grid)
        # the CDF of all rows on the grid, summed over distinct (value, bandwidth) pairs in chunks
        pairs, counts = np.unique(np.column_stack([b, h]), axis=0, return_counts=True)
        total = np.zeros(grid)
        for s in range(0, len(pairs), 512):
            p, c = pairs[s:s + 512], counts[s:s + 512]
            total += (ndtr((g[:, None] - p[None, :, 0]) / p[None, :, 1]) * c[None, :]).sum(axis=1)
        return cls(b, h, g, total, int(k))

    # -------------------------------------------------------------------- maps
    def row_map(self, leave_out=None, lower: float | None = None, upper: float | None = None
                ) -> "Map1D":
        """The value <-> score map of the group, without the rows ``leave_out`` (an index or indices:
        the row's own answer, and those of its recording; all of them: the whole group), and
        conditioned on ``lower <= b <= upper`` (what the row can print: a magnitude above zero, a
        speed a vehicle can reach) so that no draw falls where no answer of the row can be."""
        n = self.n
        out = np.atleast_1d(np.asarray([] if leave_out is None else leave_out, dtype=int))
        if out.size == 0 or out.size >= n:
            p = self.total / n
        else:  # the row's own answer (and its recording's), out of the group's summed CDF
            key = out.tobytes()
            own = self._own.get(key)
            if own is None:  # kept per set left out: the rows of one recording leave out the same rows
                own = self._own[key] = ndtr((self.grid[:, None] - self.b[out][None, :]) / self.h[out][None, :]).sum(axis=1)
            p = (self.total - own) / (n - out.size)
        if lower is not None or upper is not None:
            p_lo = float(np.interp(lower, self.grid, p)) if lower is not None else 0.0
            p_hi = float(np.interp(upper, self.grid, p)) if upper is not None else 1.0
            if p_hi - p_lo > 1e-6:
                p = np.clip((p - p_lo) / (p_hi - p_lo), 0.0, 1.0)
        u = ndtri(np.clip(p, _P_MIN, 1.0 - _P_MIN))
        keep = np.concatenate([[True], np.diff(u) > 1e-12])
        u, g = u[keep], self.grid[keep]
        if len(u) < 2:
            h = float(np.mean(self.h))
            u, g = np.array([-1.0, 1.0]), np.array([self.b.mean() - h, self.b.mean() + h])
        return Map1D(u, g)


@dataclass
class Map1D:
    """A monotone map between base values and standard normal scores (knots, linear tails)."""

    u: np.ndarray
    g: np.ndarray

    def score(self, x) -> np.ndarray:
        x = np.atleast_1d(np.asarray(x, dtype=float))
        u, g = self.u, self.g
        out = np.interp(x, g, u)
        lo = (u[1] - u[0]) / (g[1] - g[0])
        hi = (u[-1] - u[-2]) / (g[-1] - g[-2])
        out = np.where(x < g[0], u[0] + (x - g[0]) * lo, out)
        return np.where(x > g[-1], u[-1] + (x - g[-1]) * hi, out)

    def values(self, z) -> np.ndarray:
        z = np.atleast_1d(np.asarray(z, dtype=float))
        u, g = self.u, self.g
        out = np.interp(z, u, g)
        lo = (g[1] - g[0]) / (u[1] - u[0])
        hi = (g[-1] - g[-2]) / (u[-1] - u[-2])
        out = np.where(z < u[0], g[0] + (z - u[0]) * lo, out)
        return np.where(z > u[-1], g[-1] + (z - u[-1]) * hi, out)

    def cell_score(self, lo: float, hi: float, rng: np.random.Generator, k: int | None = None):
        """Score(s) uniform in probability over the base interval ``[lo, hi]`` (a rounding cell);
        ``k``: that many (an array), else one float."""
        u_lo, u_hi = self.score([lo, hi])
        p_lo, p_hi = float(ndtr(u_lo)), float(ndtr(u_hi))
        r = rng.random(1 if k is None else k)
        if not p_hi > p_lo:
            out = np.full(r.shape, 0.5 * (u_lo + u_hi))
        else:
            out = ndtri(p_lo + r * (p_hi - p_lo))
        return float(out[0]) if k is None else out


@dataclass
class Copula:
    """Correlation of normal scores of ``d`` fields followed by ``k`` covariates, shrunk to the identity.

    ``conditional(u_w)`` gives the mean and Cholesky factor of the fields' scores given the
    covariates' scores of one row.
    """

    corr: np.ndarray
    d: int

    @classmethod
    def fit(cls, scores: np.ndarray, d: int, *, shrink: float = 10.0) -> "Copula":
        """``scores``: (n, d + k) normal scores; ``shrink``: pseudo-rows of independence."""
        s = np.asarray(scores, dtype=float)
        n, m = s.shape
        if n < 3 or m == 1:
            return cls(np.eye(m), d)
        s = np.clip(s, -6, 6)
        with np.errstate(invalid="ignore", divide="ignore"):  # a constant field correlates with nothing
            c = np.corrcoef(s, rowvar=False)
        c = np.where(np.isfinite(c), c, 0.0)
        np.fill_diagonal(c, 1.0)
        w = n / (n + shrink)
        c = w * c + (1.0 - w) * np.eye(m)
        return cls(c, d)

    def conditional(self, u_w: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        d = self.d
        S = self.corr
        Sff = S[:d, :d]
        if u_w is None or S.shape[0] == d:
            return np.zeros(d), np.linalg.cholesky(Sff + 1e-9 * np.eye(d))
        Sfw, Sww = S[:d, d:], S[d:, d:]
        B = np.linalg.solve(Sww + 1e-9 * np.eye(Sww.shape[0]), Sfw.T).T
        mu = B @ np.asarray(u_w, dtype=float)
        C = Sff - B @ Sfw.T
        C = 0.5 * (C + C.T) + 1e-9 * np.eye(d)
        return mu, np.linalg.cholesky(C)


__all__ = ["Marginal", "Map1D", "Copula", "circular_cut", "on_cut_line", "from_cut_line"]


@dataclass
class FieldModel:
    """Marginals of ``d`` fields and ``k`` covariates of one group's rows, and their copula."""

    fields: list
    covariates: list
    copula: Copula
    cov_scores: np.ndarray  # (n, k) covariate scores of every member row
    index: dict  # rid -> member position
    recording: dict = field(default_factory=dict)  # member position -> positions of its recording's rows
    echo: dict = field(default_factory=dict)  # the echo balance of the bandwidth (:func:`echo_balanced`), if run

    @classmethod
    def fit(cls, rids: list, B: np.ndarray, H: np.ndarray, W: np.ndarray | None, *, knn: int, shrink: float,
            min_rows: int = 8, prior_sd=0.5, prior_center=None, max_knn: int = 0,
            groups: list | None = None, echo: dict | None = None, field_knn: dict | None = None) -> "FieldModel":
        """Fit on the base values ``B`` (n, d) of the group's rows ``rids`` with half rounding cells
        ``H`` and covariates ``W`` (n, k).

        A group with fewer than ``min_rows`` answers cannot define a distribution alone: each field's
        marginal then also holds pseudo-answers at the normal quantiles of a weak prior (the rows'
        mean, or ``prior_center`` without rows, and the larger of their spread and ``prior_sd``),
        as many as the rows are short of ``min_rows``.

        ``groups``: each row's recording. A row's distractors are then drawn without its recording's
        answers (:meth:`prepare`), and ``max_knn`` above ``knn`` chooses each field's bandwidth by how
        well the other recordings predict a recording's answers (:func:`select_knn`). ``echo`` (a group of
        at least :data:`ECHO_MIN_ROWS` rows): each field's count is widened while it balances the echo
        better (:func:`echo_balanced`). ``field_knn``: {field: count} fixed counts (no choice)."""
        n = len(rids)
        if echo and n >= ECHO_MIN_ROWS and groups is not None:
            return echo_balanced(cls, rids, B, H, W, knn=knn, shrink=shrink, min_rows=min_rows, prior_sd=prior_sd,
                                 prior_center=prior_center, groups=groups, echo=echo, max_knn=max_knn)
        B = np.asarray(B, float).reshape(n, -1) if n else np.zeros((0, np.size(prior_center)))
        H = np.asarray(H, float).reshape(B.shape) if n else np.zeros(B.shape)
        d = B.shape[1]
        m = max(0, min_rows - n)
        # each row's recording (a row without one is its own)
        labels = recording_labels(groups, n)
        fields = []
        for j in range(d):
            bj, hj = B[:, j], H[:, j]
            if m:
                centre = float(bj.mean()) if n else float(np.atleast_1d(prior_center)[j])
                sd = max(float(bj.std()) if n > 1 else 0.0, float(np.atleast_1d(prior_sd)[j % np.size(prior_sd)]))
                pseudo = centre + sd * norm_quantiles(m)
                bj = np.concatenate([bj, pseudo])
                hj = np.concatenate([hj, np.full(m, hj.mean() if n else 0.1 * sd)])
            kj = (field_knn or {}).get(j)
            fields.append(Marginal.fit(bj, hj, k=knn if kj is None else int(kj), k_max=max_knn if kj is None else 0,
                                       groups=labels + [f"pseudo:{i}" for i in range(m)]))
        covs, cs = [], np.zeros((n, 0))
        if W is not None and W.size and n >= min_rows:
            W = np.asarray(W, float).reshape(n, -1)
            keep = [j for j in range(W.shape[1]) if np.nanstd(W[:, j]) > 1e-9]
            kw = max([knn, *(field_knn or {}).values()])  # covariates as wide as the widest field
            for j in keep:
                covs.append(Marginal.fit(W[:, j], 1e-6, k=kw))
            if covs:
                cs = np.column_stack([c.row_map(None).score(W[:, j]) for c, j in zip(covs, keep)])
        if n:
            us = np.column_stack([f.row_map(None).score(B[:, j]) for j, f in enumerate(fields)])
            cop = Copula.fit(np.column_stack([us, cs]), d, shrink=shrink)
        else:
            cop = Copula(np.eye(d), d)
        members: dict = defaultdict(list)
        for i, lab in enumerate(labels):
            members[lab].append(i)
        arrays = {lab: np.array(idx) for lab, idx in members.items()}  # one array per recording, shared by its rows
        return cls(fields, covs, cop, cs, {r: i for i, r in enumerate(rids)}, {i: arrays[lab] for i, lab in enumerate(labels)})

    def prepare(self, rid: str | None, bounds: list | None = None, only: int | None = None,
                memo: dict | None = None) -> "RowDraw":
        """The maps (without the answers of the row's recording, its own included, within the row's
        ``bounds`` [(lower, upper) per field, base space]) and conditional model of one row, computed
        once; a row outside the model (``None`` or not a member) draws from the whole group. ``only``: the draw
        of that field alone (its marginal in the joint draw: the anchor's pull and the spread act per
        standardised score, so one field's draws depend on the row's answer in that field alone); ``memo``:
        a dict that keeps that field's map per recording left out (rows of one recording share it)."""
        i = self.index.get(rid) if rid is not None else None
        u_w = self.cov_scores[i] if (i is not None and self.cov_scores.shape[1]) else None
        if i is None and self.cov_scores.shape[1]:
            u_w = np.zeros(self.cov_scores.shape[1])
        mu, L = self.copula.conditional(u_w)
        bounds = bounds or [(None, None)] * len(self.fields)
        out = self.recording.get(i, i) if i is not None else None
        if out is not None and np.size(out) >= self.fields[0].n:  # one recording holds the group: its row alone
            out = i
        if only is not None:
            lo, hi = bounds[only]
            sd = math.sqrt(float((L @ L.T)[only, only]))
            key = (only, lo, hi, None if out is None else np.asarray(out).tobytes())
            memo = {} if memo is None else memo
            if key not in memo:
                memo[key] = self.fields[only].row_map(out, lo, hi)
            return RowDraw([memo[key]], mu[only:only + 1], np.array([[sd]]))
        return RowDraw([f.row_map(out, lo, hi) for f, (lo, hi) in zip(self.fields, bounds)], mu, L)


ECHO_MIN_ROWS = 20        # a smaller group keeps the likelihood's bandwidth
ECHO_SIM_ROWS = 300       # rows of a group simulated per count (evenly spaced in value order beyond that)
ECHO_SIM_REPS = 4         # simulated candidate sets per row and count
ECHO_SIM_WIDTHS = (0.02, 0.05, 0.2)   # reader kernels, as shares of the spread of the simulated candidates
ECHO_Z = 2.0              # the likelihood's count is kept unless its simulated echo is this many standard errors off


def echo_balanced(cls, rids, B, H, W, *, knn, shrink, min_rows, prior_sd, prior_center, groups, echo,
                  max_knn=0) -> "FieldModel":
    """The model of a group with the likelihood's bandwidth counts (:func:`select_knn`); where the candidate
    sets simulated from it leave the answer's echo score in one field more than :data:`ECHO_Z` standard
    errors from its chance rank (:func:`echo_imbalance`), that field's count is widened to the one of
    ``echo["ladder"]`` that leaves it nearest (the narrower count on a tie), field by field in order, the
    others held. Never narrower than the likelihood's count (a narrower kernel prints other rows' answers as
    distractors more often), and not moved by differences within the simulation's noise. The counts tried
    and their imbalance are in the model's ``echo`` (one entry per field)."""
    kw = dict(shrink=shrink, min_rows=min_rows, prior_sd=prior_sd, prior_center=prior_center, groups=groups)
    best = cls.fit(rids, B, H, W, knn=knn, max_knn=max_knn, **kw)
    k0 = [f.k for f in best.fields]
    n = len(rids)
    b = np.asarray(B, float).reshape(n, -1)
    z = echo_imbalance(best, rids, b, groups, echo)
    counts = dict(enumerate(k0))
    tried = []
    for j in range(len(k0)):
        # a field's echo is read from its draws alone (:meth:`FieldModel.prepare`), which another field's
        # count does not move: the first reading stands while earlier fields are widened
        best_z = float(z[j])
        tried.append({k0[j]: round(best_z, 3)})
        for k in (k for k in echo["ladder"] if k > k0[j] and tried[j][k0[j]] > ECHO_Z):
            fm = cls.fit(rids, B, H, W, knn=knn, field_knn={**counts, j: int(k)}, **kw)
            zk = echo_imbalance(fm, rids, b, groups, echo, only=j)
            tried[j][int(k)] = round(float(zk[j]), 3)
            if zk[j] < best_z - 1e-9:
                best, best_z = fm, float(zk[j])
                counts = {**counts, j: int(k)}
    best.echo = {"k": [int(f.k) for f in best.fields], "likelihood_k": [int(k) for k in k0], "imbalance": tried}
    return best


def echo_imbalance(fm: "FieldModel", rids, b, groups, echo: dict, only: int | None = None) -> np.ndarray:
    """How far the answer's echo score sits from its chance rank in candidate sets simulated from ``fm``
    (the stage's draw without the constraints: spread ``echo["s"]``, quantile lattice ``echo["lattice"]``),
    in standard errors of one release, the largest over the reader kernels :data:`ECHO_SIM_WIDTHS` (and over
    the readouts, where ``echo["printed"]`` gives several); one
    value per field, each field read on its own (``b``: (n, d) base values; ``only``: that field alone is read,
    the others are left at 0, as are the fields ``echo["fields"]`` does not name).

    The echo score of a candidate is the density of the other recordings' answers at it over the density of
    their candidates (:func:`resti_lib.options.attacks.prior._answer_echo` reads it the same way, on
    the printed values). Too narrow a kernel leaves a bump at each answer, the other rows' distractors crowd
    there and the answer scores low; too wide a kernel spreads the distractors where no answer is and the
    answer scores high."""
    n = len(rids)
    b = np.asarray(b, float).reshape(n, -1)
    d = b.shape[1]
    off = np.zeros((n, d)) if echo.get("offset") is None else \
        np.broadcast_to(np.asarray(echo["offset"], float).reshape(n, -1), (n, d))
    sel = np.arange(n) if n <= ECHO_SIM_ROWS else np.argsort(b[:, 0], kind="stable")[
        np.linspace(0, n - 1, ECHO_SIM_ROWS).round().astype(int)]
    m = sel.size
    g = np.asarray(recording_labels(groups, n), dtype=object)[sel]
    other = g[:, None] != g[None, :]
    ok = other.any(axis=1)
    z = np.zeros(d)
    read = range(d) if echo.get("fields") is None else [j for j in echo["fields"] if j < d]
    for j in read if only is None else [only]:
        # the candidate sets are simulated from the data alone (the rows, not the option seed): the model
        # of a group does not change with the seed the options are drawn with
        # (a one-field group's seed names no field: its simulation is the one it has always been)
        rng = np.random.default_rng(stable_seed("echo balance", ECHO_SIM_REPS, *([] if d == 1 else [j]), *rids))
        C = np.empty((ECHO_SIM_REPS, m, 5))
        memo: dict = {}
        for r, i in enumerate(sel):
            rd = fm.prepare(rids[i], only=j, memo=memo)
            x = float(b[i, j])
            C[:, r, 0] = x
            C[:, r, 1:] = rd.draw([(x, x)], float(echo["s"]), rng, n=4, batch=ECHO_SIM_REPS,
                                  lattice=echo.get("lattice"))[:, :, 0]
        C = C + off[sel, j][None, :, None]
        # the values a reader sees (printed, on the reader's scale): one readout, or a list of them (each is read)
        reads = echo["printed"](C, sel, j) if echo.get("printed") is not None else C
        for Cr in reads if isinstance(reads, list) else [reads]:
            for w in ECHO_SIM_WIDTHS:
                ranks = []
                for c in Cr:  # read as the suite's answer_echo reads it (one kernel sum)
                    h = w * (float(np.std(c)) or 1.0)
                    fc, fa = kernel_sums(c, c, other, h, first=True)   # the answers are the first column
                    sc = np.log(fa + 1e-12) - np.log(fc + 1e-12)
                    # the answer's rank among the five (0: it scores lowest, the echo's pick; 2 by chance)
                    below = (sc[:, 1:] < sc[:, :1] - 1e-9).sum(1) + 0.5 * (np.abs(sc[:, 1:] - sc[:, :1]) <= 1e-9).sum(1)
                    ranks.append(below[ok])
                r = np.concatenate(ranks)
                if r.size:
                    z[j] = max(z[j], abs(float(r.mean()) - 2.0) / (math.sqrt(2.0) / math.sqrt(r.size / ECHO_SIM_REPS)))
    return z


def norm_quantiles(m: int) -> np.ndarray:
    """``m`` evenly spaced standard normal quantiles (deterministic pseudo-answers)."""
    from scipy.stats import norm

    return norm.ppf((np.arange(m) + 0.5) / m)


@dataclass
class RowDraw:
    """Draws of one row's distractors in base space (see :class:`FieldModel`).

    ``gamma`` scales the exchangeable model in standardised score space: the stage calibrates it per
    group so that the distractors that survive the separation and plausibility constraints are
    distributed like the answers (the constraints push candidates apart, which would otherwise make
    the distractors less typical than the answer).
    """

    maps: list
    mu: np.ndarray
    L: np.ndarray
    last_z: np.ndarray | None = None
    last_za: np.ndarray | None = None
    drawn: list = field(default_factory=list)  # every standardised draw of the row, kept or not

    def draw(self, cells: list, s: float, rng: np.random.Generator, *, n: int = 4, prior: bool = False,
             batch: int | None = None, lattice: float | None = None) -> np.ndarray:
        """Base values (n, d) — or (batch, n, d) — given the answer's base rounding ``cells``
        [(lo, hi), ...]; ``prior``: no designated answer (fixed-slot rows)."""
        d = len(self.maps)
        K = batch or 1
        if prior and lattice is not None and d == 1:
            # a set of the lattice from a random start: the n values are distributed as an answer and the
            # other candidates of a row that has one (a row whose answer is a fixed slot draws like the others)
            z_v = rng.standard_normal((K, 1))
            z = np.concatenate([z_v[:, None, :], lattice_scores(z_v, n - 1, lattice, rng)], axis=1) if n > 1 \
                else z_v[:, None, :]
            self.last_za = None
        elif prior:
            c = math.sqrt(max(1.0 - s * s, 1e-6)) * rng.standard_normal((K, 1, d))
            z = c + s * rng.standard_normal((K, n, d))
            self.last_za = None
        else:
            u_a = np.column_stack([m.cell_score(lo, hi, rng, K) for m, (lo, hi) in zip(self.maps, cells)])
            z_a = np.linalg.solve(self.L, (u_a - self.mu[None, :]).T).T  # (K, d)
            if lattice is not None and d == 1:
                z = lattice_scores(z_a, n, lattice, rng)
            else:
                c = (1.0 - s * s) * z_a + s * math.sqrt(1.0 - s * s) * rng.standard_normal((K, d))
                z = c[:, None, :] + s * rng.standard_normal((K, n, d))
            self.last_za = z_a
        self.last_z = z
        self.drawn.append(z.reshape(-1, d))
        u = self.mu[None, None, :] + z @ self.L.T
        out = np.stack([self.maps[j].values(u[:, :, j].ravel()).reshape(K, n) for j in range(d)], axis=-1)
        return out if batch else out[0]

    def keep(self, i: int) -> None:
        """Record batch member ``i`` as the accepted draw (for calibration)."""
        if self.last_z is not None and self.last_z.ndim == 3:
            self.last_z = self.last_z[i]
            self.last_za = None if self.last_za is None else self.last_za[i]


def lattice_scores(z_a: np.ndarray, n: int, width: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` other candidates (K, n, 1) beside the answer's standardised score ``z_a`` (K, 1) on a jittered
    quantile lattice: the circle of quantiles [0, 1) is cut into ``n + 1`` strata of equal probability at
    a random offset, every candidate sits in its own stratum at a uniform position within the stratum's
    central ``width`` fraction. Given the set, each of the ``n + 1`` is the answer with probability
    1/(n + 1) (the offset is uniform, so the answer's quantile is uniform whatever its stratum), and
    neighbours are at least ``(1 - width)/(n + 1)`` apart in probability."""
    K = z_a.shape[0]
    m = n + 1
    q_a = ndtr(z_a[:, 0])
    lo = 0.5 * (1.0 - width)
    t_a = lo + width * rng.random(K)
    r = q_a - t_a / m                                     # the answer's stratum starts at r
    t = lo + width * rng.random((K, n))
    q = (r[:, None] + (np.arange(1, m)[None, :] + t) / m) % 1.0
    return ndtri(np.clip(q, _P_MIN, 1.0 - _P_MIN))[:, :, None]


def empirical_kappa(keys: list[tuple], values: np.ndarray, floor: float) -> list[float]:
    """Pseudo-rows of shrinkage per level of nested ``keys`` (``values``: (n, d), one entry per distinct
    key and value), estimated from the data: the within-class variance over the variance of the class
    means beyond their sampling noise (method of moments, classes compared within their parent), never
    below ``floor``. Classes whose means differ by no more than their noise get an infinite count
    (the parent's mean): an offset fitted on noise would shift each class's draws by its noise, and a
    population of classes that share one distribution (speeds of parked and driving cars of every
    class) would be drawn wider than any class's answers."""
    values = np.asarray(values, float).reshape(len(keys), -1)
    d = values.shape[1]
    depth = max((len(k) for k in keys), default=0)
    out = []
    for lv in range(1, depth + 1):
        cls: dict = defaultdict(list)
        for k, v in zip(keys, values):
            if len(k) >= lv:
                cls[tuple(k[:lv])].append(v)
        means = {c: np.mean(vs, axis=0) for c, vs in cls.items()}
        ss_w = sum(float(((np.asarray(vs) - means[c]) ** 2).sum()) for c, vs in cls.items())
        df_w = sum(len(vs) - 1 for vs in cls.values())
        parents: dict = defaultdict(list)
        for c in cls:
            parents[c[:lv - 1]].append(c)
        dev, df_b, noise, n_cls = 0.0, 0, 0.0, 0
        for cs in parents.values():
            if len(cs) < 2:
                continue
            M = np.array([means[c] for c in cs])
            dev += float(((M - M.mean(axis=0)) ** 2).sum()) / d
            df_b += len(cs) - 1
            noise += sum(1.0 / len(cls[c]) for c in cs)
            n_cls += len(cs)
        if df_w <= 0 or df_b <= 0:
            out.append(float(floor))
            continue
        s2w = ss_w / df_w / d
        tau2 = dev / df_b - s2w * noise / n_cls
        if tau2 > 0:
            out.append(max(float(floor), s2w / tau2))
        else:  # the means differ by no more than their noise (identical values: nothing to shrink)
            out.append(math.inf if s2w > 0 else float(floor))
    return out


def hierarchical_offsets(keys: list[tuple], b0: np.ndarray, kappa: float, *, groups: list | None = None,
                         extra: tuple | None = None, empirical: bool = False) -> np.ndarray:
    """Leave-one-out means of ``b0`` per nested key, each level shrunk towards its parent.

    ``keys[i]`` is a tuple of levels for row i, e.g. ``(quantity, subject_class)``: the offset of a
    row is the mean of the other rows of its (quantity, class), shrunk by ``kappa`` pseudo-rows
    towards the mean of its quantity, itself shrunk towards the group mean. A row never enters
    its own offset, and neither do the rows of its key with the same value (the same object asked
    again, in another recording or a copy of the release): each distinct (key, value) counts once,
    so an attacker who knows the typical value of a class learns nothing the distractors do not
    share, and repeated answers do not pull their class's offset onto themselves.

    ``kappa``: pseudo-rows at every level; ``empirical``: ``kappa`` is the floor of counts estimated
    per level from the entries (:func:`empirical_kappa`).

    ``extra``: ``(keys, values, groups)`` of further evidence that enters the means but gets no
    offset (the box edges of the same classes asked in another task); an entry of the row's own
    group (``groups[i]``, its recording) never enters the row's offset, nor does one equal to a row's
    own (key, value).
    """
    b0 = np.asarray(b0, float)
    one = b0.ndim == 1
    b0 = b0[:, None] if one else b0
    # one entry per distinct (key, value)
    ids: dict = {}
    row_of = np.empty(len(keys), int)
    for i, k in enumerate(keys):
        row_of[i] = ids.setdefault((tuple(k), tuple(np.round(b0[i], 9))), len(ids))
    ukeys = [k for k, _ in ids]
    first = {u: i for i, u in reversed(list(enumerate(row_of)))}
    ub = np.array([b0[first[u]] for u in range(len(ids))]) if ids else b0[:0]
    n = len(ukeys)
    # extra evidence: distinct (key, value) not already a row's, with the groups that hold it
    xs: dict = {}
    if extra is not None:
        for k, v, grp in zip(*extra):
            v = np.atleast_1d(np.asarray(v, float))
            ident = (tuple(k), tuple(np.round(v, 9)))
            if ident in ids:
                continue
            xs.setdefault(ident, (v, set()))[1].add(grp)
    xkeys = [k for k, _ in xs]
    xb = np.array([v for v, _ in xs.values()]).reshape(len(xs), ub.shape[1]) if xs else np.zeros((0, ub.shape[1]))
    tot = ub.sum(axis=0) + xb.sum(axis=0)
    n_all = n + len(xkeys)
    out_u = np.zeros_like(ub)
    depth = max((len(k) for k in ukeys + xkeys), default=0)
    if empirical:
        kappas = empirical_kappa(ukeys + xkeys, np.concatenate([ub, xb]) if len(xb) else ub, float(kappa))
    else:
        kappas = [float(kappa)] * depth
    sums: list[dict] = []
    for lv in range(1, depth + 1):
        acc: dict = defaultdict(lambda: [np.zeros(ub.shape[1]), 0])
        for k, v in [*zip(ukeys, ub), *zip(xkeys, xb)]:
            a = acc[k[:lv]]
            a[0] = a[0] + v
            a[1] += 1
        sums.append(acc)
    # the extra evidence each group holds (left out of its own rows' offsets)
    own_x: dict = defaultdict(list)
    for j, (_, grps) in enumerate(xs.values()):
        for grp in grps:
            own_x[grp].append(j)
    row_groups: dict = defaultdict(set)
    if groups is not None:
        for i, grp in enumerate(groups):
            row_groups[row_of[i]].add(grp)
    for i, k in enumerate(ukeys):
        # a distinct entry held by rows of several groups: its offset leaves out the extra
        # evidence of each of them (one offset per distinct entry)
        drop = sorted({j for grp in row_groups.get(i, ()) for j in own_x.get(grp, ())})
        dsum = xb[drop].sum(axis=0) if drop else np.zeros(ub.shape[1])
        m = (tot - ub[i] - dsum) / max(n_all - 1 - len(drop), 1)
        for lv in range(1, len(k) + 1):
            s_, c_ = sums[lv - 1][k[:lv]]
            dl = [j for j in drop if xkeys[j][:lv] == k[:lv]]
            s_ = s_ - ub[i] - (xb[dl].sum(axis=0) if dl else 0.0)
            kp = kappas[lv - 1]
            if math.isfinite(kp):  # an infinite count keeps the parent's mean
                m = (s_ + kp * m) / (c_ - 1 - len(dl) + kp)
        out_u[i] = m
    out = out_u[row_of] if len(keys) else np.zeros_like(b0)
    return out[:, 0] if one else out
