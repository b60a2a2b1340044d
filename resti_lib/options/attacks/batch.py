"""The rows of a release as the attacks see them: a :class:`Batch` of usable rows (complete, with an
answer letter), their release records and their question observables."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ... import LETTERS
from ... import values as V
from ..checks import ParsedRow, parse_row
from .features import decimals, scalar_or_distance


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

    def coupled(self) -> tuple[list, list]:
        """Rows whose candidate sets are one draw, read from the release alone: per row, the id of its
        cluster (None for a row alone) and its letters in slot order (the order that maps the candidates
        of every row of the cluster onto each other).

        Two rows of one cell (task, source) and one recording are one draw when their candidates are the
        same strings (labels aside: every row of a task offers one set of labels), or, for numbers, the same
        set up to a common factor or a common shift within the printed resolution (:func:`_one_draw`;
        two independent sets of one recording pass that by chance almost never). An option stage gives such sets to the camera
        videos of one drive that ask one quantity (one set, letters shuffled) and to rows whose answer follows
        a sibling's by physics (a path length, the trajectory's total distance: the sibling's set scaled).
        Their answers then sit at one place of one set, so a rule that reads the values hits all of them or
        none, and the count of hits is not binomial over rows (:func:`.scoring.tie_aware_p_counts` takes
        each cluster as one draw). Rows of such a set whose answers sit at different places are a template of
        options reused across questions, not one draw: a cluster keeps the rows that answer at one place (on
        independent sets this only makes the test more cautious). Slots: letters by value (numbers), else
        by string."""
        return self.memo("coupled", self._coupled)

    def _coupled(self) -> tuple[list, list]:
        n = len(self.rows)
        nums = [scalar_or_distance(p) for p in self.rows]
        slots = [_slot_order(p, v) for p, v in zip(self.rows, nums)]
        cluster: list = [None] * n
        try:
            seqs = self.sequences()
        except ValueError:  # no answer interface: recordings unknown, every row alone
            return cluster, slots
        parent = list(range(n))

        def find(i):
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        cells = {i: c for c, idx in self.cells().items() for i in idx}
        for idx in seqs.values():
            by_cell: dict = defaultdict(list)
            for i in idx:
                by_cell[cells[i]].append(i)
            for members in by_cell.values():
                sig = {i: _set_of(self.rows[i], slots[i], nums[i]) for i in members}
                for a, i in enumerate(members):
                    for j in members[a + 1:]:
                        if _one_draw(sig[i], sig[j]):
                            parent[find(i)] = find(j)
        roots: dict = defaultdict(list)
        for i in range(n):  # a set whose rows answer at different places is a template reused, not one draw
            p = self.rows[i]
            roots[(find(i), slots[i].index(p.answer) if p.answer in slots[i] else None)].append(i)
        for r, idx in roots.items():
            if len(idx) > 1:
                for i in idx:
                    cluster[i] = f"c{r[0]}.{r[1]}"
        return cluster, slots


def _slot_order(p: ParsedRow, nums: dict | None) -> str:
    """The row's letters in slot order: by value for numbers (``nums``, :func:`.features.scalar_or_distance`:
    a scalar's value, a trajectory's total distance), else by printed string."""
    if nums is not None:
        return "".join(sorted(nums, key=lambda k: (nums[k], k)))
    return "".join(sorted(p.candidates, key=lambda k: (str(p.candidates[k]), k)))


def _set_of(p: ParsedRow, order: str, nums: dict | None) -> tuple | None:
    """(the set of printed strings, the values in slot order, each value's printed resolution: half its
    last digit, summed over the moves of a trajectory, the dimensions: a speed and an acceleration asked
    at one instant are two quantities); None for a label row (rows of one task offer one
    set of labels, which makes no draw)."""
    if all(isinstance(v, V.Label) for v in p.values.values()):
        return None
    strings = frozenset(str(p.candidates[k]) for k in order)
    if nums is None:
        return strings, None, None, None
    x = np.array([float(nums[k]) for k in order])
    res = np.array([_resolution(p.values[k]) for k in order])
    dims = {v.dimension if isinstance(v, V.Scalar) else "trajectory" for v in p.values.values()}
    return strings, x, res, tuple(sorted(dims))


def _resolution(v) -> float:
    if isinstance(v, V.Scalar):
        return 0.5 * 10.0 ** -v.decimals * v.si_per_unit
    # a phrase prints one number per segment, in order: the total's resolution is its moves' rounding summed
    toks = V.number_tokens(v.text)
    return sum(0.5 * 10.0 ** -decimals(t) for (k, _), t in zip(v.segments, toks) if k == "move")


def _one_draw(a: tuple | None, b: tuple | None) -> bool:
    """Two rows' sets are one draw: the same strings, or values that one common factor or one common shift
    maps onto each other, place by place, within their printed resolution."""
    if a is None or b is None:
        return False
    if a[0] == b[0]:
        return True
    if a[1] is None or b[1] is None or a[3] != b[3]:
        return False
    (_, x, rx, _), (_, y, ry, _) = a, b
    d = y - x  # a shift b: every place's interval [d - rx - ry, d + rx + ry] holds it
    if (d - rx - ry).max() <= (d + rx + ry).min() + 1e-12:
        return True
    if (x - rx > 0).all() and (y - ry > 0).all():  # a factor: every place's interval of y / x holds it
        return float(((y - ry) / (x + rx)).max()) <= float(((y + ry) / (x - rx)).min()) + 1e-12
    return False


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
