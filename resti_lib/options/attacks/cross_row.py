"""Family ``cross_row``: reveals among the rows of one video or source sequence.

A candidate printed in another row's question (``xrow_question``), among another row's candidates
(``xrow_options``) or equal to another row's answer (``xrow_answer``; this one reads other rows' keys,
as a reader who knows the answer to the other question does). Relations that take arithmetic (a speed
times its window, a pose between two others) are the family ``relation``.
"""

from __future__ import annotations

from ... import LETTERS
from .batch import Batch
from .common import directional
from .features import flat_text, numeric_row, premise_key, printed_in
from .registry import attack


def _xrow_scores(batch: Batch, count) -> list:
    """Per numeric row: ``letter -> count(i, letter, others)`` over the other rows of its sequence."""
    out: list = [None] * len(batch)
    for idx in batch.sequences().values():
        for i in idx:
            if not numeric_row(batch.rows[i]):
                continue
            others = [j for j in idx if j != i]
            out[i] = {k: float(count(i, k, others)) for k in LETTERS}
    return out


@attack("xrow_question", ["scalar", "box", "pose", "trajectory"], "candidate printed verbatim (spacing aside) in "
        "another question of the same video or source sequence (in every direction)", family="cross_row",
        scope="batch")
def _xrow_question(batch: Batch):
    flat_q = [flat_text(r.get("Question") or "") for r in batch.records]
    premise_keys = [premise_key(o) for o in batch.obs]

    def count(i, k, others):
        p = batch.rows[i]
        s = flat_text(p.candidates[k])
        key = p.values[k].key()
        return sum(1 for j in others if printed_in(s, flat_q[j]) or (premise_keys[j] is not None
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
        family="keyed", scope="batch")
def _xrow_answer(batch: Batch):
    ans = [p.values[p.answer].key() for p in batch.rows]

    def count(i, k, others):
        key = batch.rows[i].values[k].key()
        return sum(1 for j in others if ans[j] == key)
    return directional(batch, _xrow_scores(batch, count))
