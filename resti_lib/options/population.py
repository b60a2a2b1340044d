"""Population-calibrated options for one-dimensional answers (scalars, angles, trajectory totals).

The exchangeable builders of :mod:`resti_lib.options.builders` draw five points around a latent
anchor and shift the set so that the designated point equals the answer. That makes every rule
that looks at one row alone (rank, median, medoid, string length) pick the answer with
probability 1/5. A rule that has seen *other rows* can do better: under that construction the
probability that candidate ``j`` is the answer is proportional to the density of answers at
``x_j`` over the whole task (the population), so "pick the candidate where answers usually are"
wins whenever the population is narrower than, or not much wider than, the distractor spread
(Waymo heading changes cluster within a degree of zero; Omni6DPose speeds within a factor of
two). A learned attacker finds it.

This module removes that leak by matching the candidates' marginal to the population:

1. The answers of one group (task, source, unit) define a monotone map ``Q`` from a standard
   normal score ``u`` to a value: the quantile function, after the normal score, of an adaptive
   kernel density estimate of the answers in a base space (``log(x + ulp)`` for magnitudes,
   ``atanh(θ/180)`` for signed angles, the angle itself for headings, the value for
   coordinates), extended linearly beyond its grid. Under ``Q`` a standard normal ``u`` is
   distributed like the group's answers. Each row uses the map of the *other* answers of its
   group (leave one out), so its own answer is a fresh draw for the model, as it is for an
   attacker who learned the population from other rows.
2. Model: an anchor ``c ~ N(0, 1 - s²)``; five scores ``u_i ~ N(c, s²)`` independently, so every
   ``u_i`` is standard normal and the five are exchangeable; the answer is the one of signed-value
   rank ``k`` (a balanced schedule decides ``k``, so the designation is uniform over the five).
3. Given a row's answer, its score ``u_a`` is drawn uniformly in probability over the scores that
   print as the answer (ties and rounding cells have width), the anchor from its exact posterior
   given that the rank-``k`` score equals ``u_a`` (computed on a grid), and the other four from
   ``N(c, s²)`` truncated below or above ``u_a`` (``k - 1`` below, ``5 - k`` above).
4. The five values are printed with the answer's format (the answer keeps its original string);
   the whole set is redrawn when two print the same or a value leaves the domain.

So the five candidates are five exchangeable draws whose single-candidate marginal is the
population itself: neither a rule on one row nor a model of where answers usually are can tell
the answer. ``s`` (the kernel width in normal-score units, below 1) trades option spread for
nothing else. ``fixed`` slots carry a value that cannot be drawn continuously (the exact zero of
a stationary object): see :func:`population_options`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.special import log_ndtr, ndtr, ndtri

from .builders import MAX_TRIES, OptionError, Options

ANGLE_SCALE = 180.0


@dataclass(frozen=True)
class Population:
    """The value map ``Q`` of one group (see the module docstring)."""

    kind: str  # "positive" (magnitudes >= 0), "angle" (degrees in [-180, 180)), "real" or "circular"
    ulp: float  # printed unit in the last place
    knots_u: np.ndarray
    knots_b: np.ndarray
    slope_lo: float
    slope_hi: float
    n: int
    offset: float = 0.0  # circular: the cut of the circle is at offset +- 180
    floor: float | None = None  # positive: the smallest printable value; lower scores print as it

    # base space
    def b_of(self, x):
        x = np.asarray(x, dtype=float)
        if self.kind == "positive":
            return np.log(np.maximum(x + self.ulp, 1e-300))
        if self.kind == "real":
            return x
        if self.kind == "circular":
            return (x - self.offset + 180.0) % 360.0 - 180.0
        return np.arctanh(np.clip(x / ANGLE_SCALE, -1 + 1e-12, 1 - 1e-12))

    def x_of(self, b):
        b = np.asarray(b, dtype=float)
        if self.kind == "positive":
            return np.exp(b) - self.ulp
        if self.kind == "real":
            return b
        if self.kind == "circular":
            return (b + self.offset + 180.0) % 360.0 - 180.0
        return ANGLE_SCALE * np.tanh(b)

    # the map and its inverse
    def b_at(self, u):
        u = np.asarray(u, dtype=float)
        ku, kb = self.knots_u, self.knots_b
        out = np.interp(u, ku, kb)
        out = np.where(u < ku[0], kb[0] + self.slope_lo * (u - ku[0]), out)
        return np.where(u > ku[-1], kb[-1] + self.slope_hi * (u - ku[-1]), out)

    def value(self, u):
        x = self.x_of(self.b_at(u))
        return np.maximum(x, self.floor) if self.floor is not None else x

    def u_at(self, b):
        b = np.asarray(b, dtype=float)
        ku, kb = self.knots_u, self.knots_b
        out = np.interp(b, kb, ku)
        out = np.where(b < kb[0], ku[0] + (b - kb[0]) / self.slope_lo, out)
        return np.where(b > kb[-1], ku[-1] + (b - kb[-1]) / self.slope_hi, out)

    def cell(self, x: float) -> tuple[float, float]:
        """Scores ``(u_lo, u_hi)`` whose values print as ``x`` (its rounding cell)."""
        lo, hi = x - 0.5 * self.ulp, x + 0.5 * self.ulp
        if self.kind == "positive":
            if self.floor is not None and x <= self.floor + 1e-12:
                return -math.inf, float(self.u_at(self.b_of(hi)))
            lo = max(lo, -0.5 * self.ulp)
        return float(self.u_at(self.b_of(lo))), float(self.u_at(self.b_of(hi)))


@dataclass
class PopulationModel:
    """An adaptive kernel density estimate of one group's answers, with leave-one-out maps.

    ``cdf_terms[g, i]`` is answer ``i``'s kernel mass below grid point ``g`` (base space), so
    the map of the whole group and the map without any one answer are cheap to tabulate.
    """

    kind: str
    ulp: float
    grid: np.ndarray
    cdf_terms: np.ndarray
    offset: float
    floor: float | None
    bandwidths: np.ndarray

    @property
    def n(self) -> int:
        return int(self.cdf_terms.shape[1])

    def population(self, leave_out: int | None = None) -> Population:
        """The map ``Q`` of the group, or of the group without answer ``leave_out``."""
        total = self.cdf_terms.sum(axis=1)
        m = self.n
        if leave_out is not None and m > 1:
            total = total - self.cdf_terms[:, leave_out]
            m -= 1
        u = ndtri(np.clip(total / m, 1e-15, 1 - 1e-15))
        g = self.grid
        keep = np.concatenate([[True], np.diff(u) > 1e-12])
        u, g = u[keep], g[keep]
        if len(u) < 2:
            h = float(self.bandwidths.mean())
            return Population(self.kind, self.ulp, u, g, h, h, m, self.offset, self.floor)
        slope_lo = (g[1] - g[0]) / (u[1] - u[0])
        slope_hi = (g[-1] - g[-2]) / (u[-1] - u[-2])
        return Population(self.kind, self.ulp, u, g, float(slope_lo), float(slope_hi), m, self.offset, self.floor)


def fit_model(values, *, kind: str, ulp: float, k: int = 4, bw: float = 1.0, floor: float | None = None,
              grid: int = 1024) -> PopulationModel:
    """An adaptive Gaussian kernel density estimate of a group's answers in base space.

    Each answer's bandwidth is ``bw`` times the distance to its ``k``-th nearest other answer,
    so dense stretches (a cluster of near-zero heading changes, road-aligned headings) stay as
    sharp as the data and sparse stretches smooth; no bandwidth is below half a printed unit, so
    tied answers keep the width of their rounding cell. ``floor`` (magnitudes): the smallest value
    a candidate may print; lower values print as the floor.
    """
    if kind not in ("positive", "angle", "real", "circular"):
        raise ValueError(f"unknown population kind {kind!r}")
    if floor is not None and kind != "positive":
        raise ValueError("a floor applies to magnitudes only")
    vals = np.asarray(values, dtype=float)
    if vals.size == 0 or not np.all(np.isfinite(vals)):
        raise ValueError("a population needs finite values")
    offset = circular_cut(vals) + 180.0 if kind == "circular" else 0.0
    base = Population(kind, ulp, np.zeros(1), np.zeros(1), 1.0, 1.0, 0, offset)
    b = np.asarray(base.b_of(vals), dtype=float)
    n = int(b.size)
    half = np.abs(np.asarray(base.b_of(vals + 0.5 * ulp)) - b)
    if kind == "circular":
        half = np.minimum(half, 360.0 - half)
    half = np.maximum(half, 1e-9)
    if n > 1:
        d = np.abs(b[:, None] - b[None, :])
        if kind == "circular":
            d = np.minimum(d, 360.0 - d)
        d = np.sort(d, axis=1)[:, 1:]
        dk = d[:, min(k, n - 1) - 1]
    else:
        dk = 4 * half
    h = np.maximum(bw * dk, half)
    g = np.linspace(float((b - 6 * h).min()), float((b + 6 * h).max()), grid)
    terms = ndtr((g[:, None] - b[None, :]) / h[None, :])
    return PopulationModel(kind, ulp, g, terms, offset, floor, h)


def fit_population(values, *, kind: str, ulp: float, floor: float | None = None, **kw) -> Population:
    """The map ``Q`` of a group from all its answers (see :func:`fit_model`)."""
    return fit_model(values, kind=kind, ulp=ulp, floor=floor, **kw).population()


def circular_cut(deg) -> float:
    """The middle of the widest empty arc of a set of angles (where a circle is best cut open)."""
    a = np.sort((np.asarray(deg, dtype=float) + 180.0) % 360.0 - 180.0)
    if a.size == 0:
        return 180.0
    gaps = np.diff(np.concatenate([a, [a[0] + 360.0]]))
    i = int(np.argmax(gaps))
    return float((a[i] + gaps[i] / 2.0 + 180.0) % 360.0 - 180.0)


# ------------------------------------------------------------------------------ sampling pieces

def _anchor(u_a: float, k: int, n_cont: int, s: float, rng: np.random.Generator, grid: int = 1601) -> float:
    """Anchor ``c`` from its posterior given that the rank-``k`` of ``n_cont`` scores equals ``u_a``."""
    prior_sd = math.sqrt(max(1.0 - s * s, 1e-6))
    lo, hi = min(u_a, 0.0) - 8.0 * s - 4 * prior_sd, max(u_a, 0.0) + 8.0 * s + 4 * prior_sd
    c = np.linspace(lo, hi, grid)
    z = (u_a - c) / s
    logw = -0.5 * (c / prior_sd) ** 2 - 0.5 * z * z
    if k > 1:
        logw += (k - 1) * log_ndtr(z)
    if n_cont - k > 0:
        logw += (n_cont - k) * log_ndtr(-z)
    w = np.exp(logw - logw.max())
    cdf = np.cumsum(w)
    i = int(np.searchsorted(cdf, rng.random() * cdf[-1]))
    i = min(i, grid - 1)
    step = (hi - lo) / (grid - 1)
    return float(c[i] + (rng.random() - 0.5) * step)


def _truncated(c: float, s: float, bound: float, n: int, below: bool, rng: np.random.Generator) -> np.ndarray:
    """``n`` draws of ``N(c, s²)`` truncated to ``< bound`` (below) or ``> bound``."""
    if n == 0:
        return np.zeros(0)
    zb = (bound - c) / s
    if below:
        p = float(ndtr(zb))
        q = rng.random(n) * p
        z = ndtri(np.clip(q, 1e-300, 1 - 1e-16))
        z = np.minimum(z, zb)
    else:
        p = float(ndtr(-zb))
        q = rng.random(n) * p
        z = -ndtri(np.clip(q, 1e-300, 1 - 1e-16))
        z = np.maximum(z, zb)
    return c + s * z


def answer_score(pop: Population, x: float, rng: np.random.Generator) -> float:
    """A score that prints as ``x``: uniform in probability over its rounding cell."""
    u_lo, u_hi = pop.cell(x)
    p_lo, p_hi = float(ndtr(u_lo)), float(ndtr(u_hi))
    if not p_hi > p_lo:
        return float(pop.u_at(pop.b_of(x)))
    return float(ndtri(p_lo + rng.random() * (p_hi - p_lo)))


def field_draws(pop: Population, value: float, *, s: float, rng: np.random.Generator, n: int = 5,
                rank: int | None = None) -> np.ndarray:
    """Values of the ``n - 1`` other candidates of one field of a structured answer, in random order.

    The answer's rank in the field is uniform (or ``rank``), independently per field, as when the
    ``n`` candidates are exchangeable draws and one of them is designated at random.
    """
    k = int(rank) if rank is not None else int(rng.integers(1, n + 1))
    u_a = answer_score(pop, value, rng)
    c = _anchor(u_a, k, n, s, rng)
    u = np.concatenate([_truncated(c, s, u_a, k - 1, True, rng), _truncated(c, s, u_a, n - k, False, rng)])
    return np.asarray(pop.value(rng.permutation(u)), dtype=float)


def population_options(value: float, answer_text: str, pop: Population, *, rng: np.random.Generator,
                       fmt: Callable[[float], str], key: Callable[[str], object], s: float = 0.35,
                       target_rank: int | None = None, fixed: tuple = (), answer_is_fixed: bool = False,
                       floor: float | None = None, min_gap: float = 0.0, min_rel_gap: float = 0.0,
                       max_tries: int = MAX_TRIES) -> Options:
    """Five candidates: ``fixed`` strings plus continuous draws from the population model.

    ``value``/``answer_text``: the answer and its exact string (kept as is). ``fmt`` prints a
    value like the answer; ``key`` maps a string to a comparable value (for duplicates).
    ``target_rank``: the answer's signed-value rank among the continuous candidates (1 = smallest).
    ``fixed``: strings placed in every set (at most one per value; e.g. ``"0.00m/s"``); when
    ``answer_is_fixed`` the answer is ``fixed[0]`` and the continuous candidates are drawn with the
    anchor from its prior (none of them is designated). ``floor``: continuous values printing
    below it are rejected. ``min_gap`` (printed units) and ``min_rel_gap`` (relative) separate
    adjacent values; like every constraint here they are symmetric in the five candidates.
    """
    if not 0.0 < s < 1.0:
        raise ValueError(f"kernel width s={s} must be in (0, 1)")
    fixed = tuple(fixed)
    n_cont = 5 - len(fixed)
    if n_cont < 1 or (answer_is_fixed and not fixed):
        raise ValueError("need at least one continuous candidate, and a fixed answer when answer_is_fixed")
    k = target_rank
    ev: dict = {"s": s, "fixed": list(fixed)}
    for attempt in range(max_tries):
        if attempt == max_tries // 2 and not answer_is_fixed:
            k = None  # an infeasible rank: give up the rank rather than the row (evidence says so)
        if answer_is_fixed:
            c = float(rng.normal(0.0, math.sqrt(max(1.0 - s * s, 1e-6))))
            us = c + s * rng.standard_normal(n_cont)
            vals = list(pop.value(us))
            strings = [fmt(v) for v in vals]
            r = None
        else:
            kk = k if k is not None else int(rng.integers(1, n_cont + 1))
            u_a = answer_score(pop, value, rng)
            c = _anchor(u_a, kk, n_cont, s, rng)
            below = _truncated(c, s, u_a, kk - 1, True, rng)
            above = _truncated(c, s, u_a, n_cont - kk, False, rng)
            vals = [*pop.value(below), *pop.value(above)]
            strings = [fmt(v) for v in vals]
            vals.append(value)
            strings.append(answer_text)
            r = len(strings) - 1
        cont_keys = [key(x) for x in strings]
        if floor is not None and any(kv < floor - 1e-12 for kv in cont_keys):
            continue
        all_strings = strings + list(fixed)
        keys = [key(x) for x in all_strings]
        if len(set(all_strings)) != 5 or len(set(keys)) != 5:
            continue
        srt = sorted(keys)
        gaps = np.diff(srt)
        if min_gap > 0 and gaps.min() < min_gap - 1e-12:
            continue
        if min_rel_gap > 0:
            rel = gaps / np.maximum(np.abs(srt[1:]), 1e-12)
            if rel.min() < min_rel_gap:
                continue
        if answer_is_fixed:
            ans_index = len(strings)
        else:
            ans_index = r
        ev.update({"rank": int(sorted(keys).index(keys[ans_index]) + 1), "tries": attempt + 1,
                   "rank_kept": k is not None or answer_is_fixed})
        return Options(all_strings, ans_index, ev)
    raise OptionError(f"no population options for {answer_text!r} under the constraints")
