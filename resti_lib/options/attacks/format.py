"""Family ``format``: how the candidates are printed.

A candidate printed from exact source values and one printed from arithmetic on them can differ in how
they are written, not in what they say: fewer decimals (a trailing zero dropped by a JSON writer), more
last digits 0, a negative zero, other significant digits, another key order or spacing, or last digits
that differ from the other candidates' at the same field. Each tell is a per-candidate count (or the
size of the candidate's layout class); the attack picks the candidates at the extreme. Whether the
answer sits at the high or the low end is not known in advance, so every direction is scored
(:func:`resti_lib.options.attacks.common.directional`).

Tie sets: a rule such as "the candidate with the fewest significant digits" or "the shortest string"
usually ties several candidates; the tied set is the pick and is scored by its expected accuracy
(1/|set| when the answer is in it). ``fmt_last_digit`` tries every last digit as a constant pick (the
candidates whose printed numbers end in that digit), the best digit kept with a Bonferroni factor.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from ... import LETTERS
from .batch import Batch
from .common import ENDS, Directional, directional
from .features import (
    NUMERIC,
    decimals,
    digits,
    is_negative_zero,
    last_digit,
    numeric_row,
    significant,
    significant_stripped,
    skeleton,
    tokens,
)
from .registry import attack


def _per_candidate(batch: Batch, feature) -> list:
    """``letter -> feature(candidate string)`` for numeric rows, None for the others."""
    out = []
    for p in batch.rows:
        out.append({k: float(feature(p.candidates[k])) for k in LETTERS} if numeric_row(p) else None)
    return out


def _class_sizes(batch: Batch, key) -> list:
    """``letter -> size of the candidate's class`` under ``key(candidate string)``: a small class is an
    odd one out, a large one the common form."""
    out = []
    for p in batch.rows:
        if not numeric_row(p):
            out.append(None)
            continue
        keys = {k: key(p.candidates[k]) for k in LETTERS}
        c = Counter(keys.values())
        out.append({k: float(c[keys[k]]) for k in LETTERS})
    return out


@attack("fmt_negative_zero", NUMERIC, "candidates whose count of printed negative zeros (-0, -0.0) is the odd "
        "one out or the common one (in every direction)", family="format", scope="batch")
def _neg_zero(batch: Batch):
    return directional(batch, _class_sizes(batch, lambda s: sum(is_negative_zero(t) for t in tokens(s))))


@attack("fmt_layout", NUMERIC, "candidates whose layout (key order, spacing, signs, separators) is the odd one out "
        "or the common one (in every direction)", family="format", scope="batch")
def _layout(batch: Batch):
    return directional(batch, _class_sizes(batch, skeleton))


@attack("fmt_zero_last_digits", NUMERIC, "most or fewest printed numbers ending in 0 (in every direction)",
        family="format", scope="batch")
def _zero_last(batch: Batch):
    return directional(batch, _per_candidate(batch, lambda s: sum(digits(t)[-1:] == "0" for t in tokens(s))))


@attack("fmt_decimals", NUMERIC, "most or fewest printed decimals in total (in every direction)",
        family="format", scope="batch")
def _decimals_attack(batch: Batch):
    return directional(batch, _per_candidate(batch, lambda s: sum(decimals(t) for t in tokens(s))))


@attack("fmt_significant_digits", NUMERIC, "most or fewest significant digits in total (in every direction)",
        family="format", scope="batch")
def _sig(batch: Batch):
    return directional(batch, _per_candidate(batch, lambda s: sum(significant(t) for t in tokens(s))))


def _last_digit_odd(p) -> dict | None:
    """Per candidate: at how many printed fields its last digit differs from every other candidate's last
    digit at the same field (rows whose candidates print different numbers of fields: None)."""
    toks = {k: tokens(p.candidates[k]) for k in LETTERS}
    n = {len(t) for t in toks.values()}
    if len(n) != 1 or n == {0}:
        return None
    last = np.array([[(digits(t)[-1:] or "x") for t in toks[k]] for k in LETTERS])
    same = (last[:, None, :] == last[None, :, :]).sum(1) - 1  # other candidates sharing the digit
    return {k: float((same[i] == 0).sum()) for i, k in enumerate(LETTERS)}


@attack("fmt_last_digit_odd", NUMERIC, "most or fewest fields whose last printed digit differs from every other "
        "candidate's at that field (in every direction)", family="format", scope="batch")
def _last_odd(batch: Batch):
    return directional(batch, [(_last_digit_odd(p) if numeric_row(p) else None) for p in batch.rows])


# ------------------------------------------------------------------------------------ tie sets

@attack("fmt_fewest_significant", NUMERIC, "tie set of the candidates with the fewest (or most) significant "
        "digits of the numbers themselves (trailing zeros after the point dropped: a round value), scored by "
        "its expected accuracy", family="format", scope="batch")
def _fewest_significant(batch: Batch):
    return directional(batch, _per_candidate(batch, lambda s: -sum(significant_stripped(t) for t in tokens(s))),
                       directions=ENDS)


@attack("fmt_shortest", ["any"], "tie set of the shortest (or longest) printed candidates, whitespace aside, "
        "scored by its expected accuracy", family="format", scope="batch")
def _shortest_tie(batch: Batch):
    scores = [{k: -float(len("".join(str(p.candidates[k]).split()))) for k in LETTERS} for p in batch.rows]
    return directional(batch, scores, directions=ENDS)


@attack("fmt_last_digit", NUMERIC, "tie set of the candidates whose last printed digit (of their last number) is "
        "d, every digit d tried as a constant pick, the best kept with a Bonferroni factor over the digits",
        family="format", scope="batch")
def _last_digit(batch: Batch):
    lasts = [({k: last_digit(tokens(p.candidates[k])[-1]) if tokens(p.candidates[k]) else "x" for k in LETTERS}
              if numeric_row(p) else None) for p in batch.rows]
    out = Directional()
    for d in "0123456789":
        picks = []
        for last in lasts:
            hit = frozenset(k for k, x in last.items() if x == d) if last is not None else frozenset()
            picks.append(hit or None)
        if any(pk is not None for pk in picks):
            out[f"digit {d}"] = picks
    return out
