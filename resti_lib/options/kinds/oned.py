"""What the one-dimensional kinds share: the first valid set of a batch, the check of a set."""

from __future__ import annotations

import numpy as np

from ... import values as V
from ..plan import Reject


# -- one-dimensional kinds (drawn in batches, checked vectorised, the first valid set kept)
def first_valid_1d(pv: np.ndarray, ok: np.ndarray, gap_of, rel: float = 0.0, circular: bool = False
                    ) -> list:
    """Indices of batch rows whose five printed values ``pv`` (K, 5) are distinct and separated."""
    srt = np.sort(pv, axis=1)
    d = np.diff(srt, axis=1)
    need = gap_of(srt[:, 1:])
    good = ok & (d >= need - 1e-9).all(axis=1)
    if rel > 0:
        good &= (d >= rel * np.abs(srt[:, 1:]) - 1e-12).all(axis=1)
    if circular:
        good &= (srt[:, 0] + 360.0 - srt[:, -1]) >= gap_of(srt[:, :1])[:, 0] - 1e-9
    return list(np.flatnonzero(good))


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
