"""What the one-dimensional kinds share: the first valid set of a batch, the check of a set."""

from __future__ import annotations

import numpy as np

from ... import values as V
from ..plan import Reject, RowPlan


# -- one-dimensional kinds (drawn in batches, checked vectorised, the first valid set kept)
def first_valid_1d(pv: np.ndarray, ok: np.ndarray, gap_of, rel: float = 0.0, circular: bool = False,
                   at_rank: tuple[int, int, int] | None = None) -> list:
    """Indices of batch rows whose five printed values ``pv`` (K, 5) are distinct and separated;
    ``at_rank=(column, r, tol)``: only those where the value in ``column`` (the answer) has a rank
    (:func:`answer_ranks`) within ``tol`` of ``r``, nearest first."""
    srt = np.sort(pv, axis=1)
    d = np.diff(srt, axis=1)
    need = gap_of(srt[:, 1:])
    good = ok & (d >= need - 1e-9).all(axis=1)
    if rel > 0:
        good &= (d >= rel * np.abs(srt[:, 1:]) - 1e-12).all(axis=1)
    if circular:
        good &= (srt[:, 0] + 360.0 - srt[:, -1]) >= gap_of(srt[:, :1])[:, 0] - 1e-9
    if at_rank is not None:
        off = np.abs(answer_ranks(pv, at_rank[0]) - at_rank[1])
        good &= off <= at_rank[2]
        return [int(i) for i in np.flatnonzero(good)[np.argsort(off[good], kind="stable")]]
    return list(np.flatnonzero(good))


def answer_ranks(pv: np.ndarray, column: int) -> np.ndarray:
    """Per batch row of ``pv`` (K, m), how many values lie below the one in ``column``."""
    return (pv < pv[:, column:column + 1]).sum(axis=1)


def check_1d(spec, values, strings, *, gap, rel: float = 0.0, circular: bool = False):
    if len(set(strings)) != 5 or len({V.parse(t).key() for t in strings}) != 5:
        raise Reject("two candidates print the same value")
    xs = sorted(values)
    for a, b in zip(xs, xs[1:]):
        if b - a < gap(b) - 1e-12:
            raise Reject("two candidates closer than the separation floor")
        if rel > 0 and (b - a) < rel * max(abs(b), 1e-12):
            raise Reject("two candidates closer than the relative gap")
    if circular and (xs[0] + 360.0 - xs[-1]) < gap(xs[0]) - 1e-12:
        raise Reject("two candidates closer than the separation floor across ±180")


def drawn_rank(p: RowPlan, allv: np.ndarray, column: int) -> tuple[int, int, int]:
    """The rank the answer (``column`` of the batch ``allv``) keeps, for :func:`first_valid_1d`:
    the one it has in the first set the row's build draws, before any constraint.

    Constraints reject sets unevenly: where answers crowd below a sharp edge (vehicles' cruising
    speeds), sets that crowd are rejected, the sets kept put their distractors on the sparse side,
    and the answer's rank leans (the largest). Keeping an unconstrained draw's rank keeps the model's
    rank distribution, uniform when the model is calibrated. A row that cannot meet it in all but the
    last tier of tries (``p.scratch``, reset per build) takes the nearest rank it can, and its
    evidence says so (``drawn_rank_missed``)."""
    sc = p.scratch
    if "rank" not in sc:
        sc["rank"] = int(answer_ranks(allv[:1], column)[0])
        sc["left"] = int(sc.get("tries_before_last_tier", 1))
        p.evidence["drawn_rank"] = sc["rank"]
        p.evidence.pop("drawn_rank_missed", None)
    sc["left"] -= 1
    if sc["left"] < 0:
        p.evidence["drawn_rank_missed"] = True
        return (column, sc["rank"], allv.shape[1])
    return (column, sc["rank"], 0)
