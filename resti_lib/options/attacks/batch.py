"""The rows of a release as the attacks see them: a :class:`Batch` of usable rows (complete, with an
answer letter), their release records and their question observables."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field

from ... import LETTERS
from ..checks import ParsedRow, parse_row


@dataclass
class Batch:
    """The usable rows of a release (complete, with an answer letter) as attacks see them.

    ``rows`` parsed rows, ``records`` the release rows (question text, video, fields), ``obs`` the
    question observables (computed on first use), ``settings`` attack settings (learned attacker
    configuration, cross-validation groups, the answer interface ``iface``)."""

    rows: list
    records: list
    settings: dict = field(default_factory=dict)
    _obs: list | None = None
    _index: dict = field(default_factory=dict)

    @property
    def obs(self) -> list:
        if self._obs is None:
            from ..observables import observables_of

            iface = self.settings.get("iface")
            if iface is None:
                raise ValueError("attacks that read the question need the answer interface (attack_table iface=)")
            self._obs = [observables_of(r, iface.quantity_of(str(r.get("Task")), r.get("Question"))) for r in self.records]
        return self._obs

    @property
    def tasks(self) -> tuple:
        """The tasks of the rows, sorted by name (the columns of a task one-hot)."""
        return tuple(sorted({str(p.task) for p in self.rows}))

    @property
    def task_order(self) -> tuple:
        """The order of the tasks in a table: the interface's tasks (the task registry's order) present
        in the rows, then any other task of the rows by name."""
        iface = self.settings.get("iface")
        present = set(self.tasks)
        known = tuple(t for t in (iface.tasks if iface is not None else ()) if t in present)
        return known + tuple(t for t in self.tasks if t not in known)

    def __len__(self) -> int:
        return len(self.rows)

    def memo(self, name: str, make: Callable[[], object]):
        """``make()`` computed once per batch under ``name`` (features several attacks read)."""
        if name not in self._index:
            self._index[name] = make()
        return self._index[name]

    def groups(self, key: Callable[[int], object], name: str | None = None) -> dict:
        """Row indices grouped by ``key(i)`` (a None key is left out); memoised under ``name``."""
        if name is not None and name in self._index:
            return self._index[name]
        out: dict = defaultdict(list)
        for i in range(len(self.rows)):
            k = key(i)
            if k is not None:
                out[k].append(i)
        out = dict(out)
        if name is not None:
            self._index[name] = out
        return out

    def cells(self) -> dict:
        """(task, source) -> row indices."""
        return self.groups(lambda i: (self.rows[i].task, self.rows[i].source), "cells")

    def sequences(self) -> dict:
        """Source sequence (the recording, read from the video name) -> row indices."""
        return self.groups(lambda i: self.obs[i].sequence, "sequence")


def record_of(p: ParsedRow) -> dict:
    """The release fields of a parsed row (for rows given without their records)."""
    return {"Task": p.task, "Source": p.source, "Candidates": p.candidates, "Answer": p.answer,
            "Answer Detail": p.detail, "time_start": p.time_start, "time_end": p.time_end}


def make_batch(rows: list[ParsedRow], records: list[dict] | None = None, **settings) -> tuple[Batch, list[int]]:
    """The batch of usable rows and their indices in ``rows``."""
    used = [i for i, p in enumerate(rows) if p.complete and p.answer in LETTERS]
    recs = [records[i] for i in used] if records is not None else [record_of(rows[i]) for i in used]
    return Batch([rows[i] for i in used], recs, dict(settings)), used


def parse_rows(records: list[dict]) -> list[ParsedRow]:
    """Every release row parsed once (its id: ``ReSTI ID``, else ``Legacy Row Key``, else its index)."""
    out = []
    for i, r in enumerate(records):
        rid = r.get("ReSTI ID") or r.get("Legacy Row Key") or i
        out.append(parse_row(r, rid))
    return out


def kind_of(p: ParsedRow) -> set:
    """The value kinds of a row's candidates (``angle`` besides ``scalar`` for angles), and ``any``."""
    kinds = {v.kind for v in p.values.values()}
    if kinds == {"scalar"} and all(v.is_angle for v in p.values.values()):
        kinds = {"scalar", "angle"}
    return kinds | {"any"}
