"""What every attack returns and how a pick is read: sets of letters, ties, and directions.

An attack returns, per row, the **set** of letters it picks (or None where it does not apply). A rule
whose direction is not known in advance (fewest or most decimals, nearest or farthest, or a middle
rank) returns its picks in every direction (:class:`Directional`); the table keeps the best direction
of each cell with a Bonferroni factor over the directions.
"""

from __future__ import annotations

import numpy as np

from ... import LETTERS

TIE = 1e-12  # values closer than this are ties (printed values are far coarser)
ALL5 = frozenset(LETTERS)
CHANCE = 1.0 / len(LETTERS)


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


def expected_hit(pick: frozenset | None, answer: str) -> float:
    """The row's score: ``1/|pick|`` when the answer is in the picked set (a tie), else 0."""
    return (1.0 / len(pick)) if pick and answer in pick else 0.0


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


DIRECTIONS = ("max", "min", 2, 4, 3)
ENDS = ("max", "min")


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


def directional(batch, scores: list, *, directions=DIRECTIONS) -> Directional:
    """The picks of every direction of a per-row score: the largest score, the smallest, or the score at
    descending rank 2, 4 or 3 (:func:`extreme`). ``scores[i]`` is a ``letter -> value`` dict or None (the
    rule does not apply)."""
    return Directional({d: [None if sc is None else extreme(sc, d) for sc in scores] for d in directions})
