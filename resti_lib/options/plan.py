"""What the option stage knows of each row and group before drawing: the row plan (its spec,
group, letter, fixed slots, shared set), the group model, the group and share keys, dense windows
and slots, the letter schedule, and the reject signal of a candidate set."""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass, field

import numpy as np

from .. import values as V
from ..rng import stable_seed
from .population import FieldModel
from .spec import (
    OptionSpec,
)

WINDOWED = ("displacement", "path_length", "trajectory")


#: Quantities of an object that recur when one object is asked about in several recordings.
OBJECT_SIZES = ("length", "width", "height", "distance", "distance_to_camera", "surface_distance")


ONE_D = ("scalar", "angle", "trajectory")


def constrained_schedule(allowed: dict, levels, *, seed: int, group: str) -> dict:
    """Balanced levels (counts differ by at most one where the constraints allow).

    ``allowed``: key -> allowed levels. Rows with fewer allowed levels are placed first; each takes
    its allowed level with the largest remaining quota; ties broken by a seeded order.
    """
    levels = list(levels)
    keys = sorted(allowed)
    n, m = len(keys), len(levels)
    if n == 0:
        return {}
    rng = np.random.default_rng(stable_seed(seed, "constrained_schedule", group))
    base, extra = divmod(n, m)
    quota = {lv: base for lv in levels}
    for j in rng.permutation(m)[:extra]:
        quota[levels[int(j)]] += 1
    tiebreak = {k: float(x) for k, x in zip(keys, rng.random(n))}
    level_order = {lv: float(x) for lv, x in zip(levels, rng.random(m))}
    out = {}
    for k in sorted(keys, key=lambda k: (len(allowed[k]), tiebreak[k])):
        opts = [lv for lv in levels if lv in allowed[k]]
        if not opts:
            raise ValueError(f"no allowed level for {k!r}")
        best = max(opts, key=lambda lv: (quota[lv], level_order[lv]))
        out[k] = best
        quota[best] -= 1
    return out


def slot_rows(carriers: list[str], others: list[str], ratio: float, *, seed: int, group: str) -> set:
    """Rows carrying a fixed slot: every carrier plus ``ratio`` times as many others (seeded)."""
    want = min(len(others), round(ratio * len(carriers)))
    if not carriers or want == 0:
        return set(carriers)
    rng = np.random.default_rng(stable_seed(seed, "slot", group))
    pool = sorted(others)
    return set(carriers) | {pool[int(i)] for i in rng.permutation(len(pool))[:want]}


@dataclass
class RowPlan:
    spec: OptionSpec
    group: str = ""
    letter: str = "A"
    fixed: tuple = ()
    answer_is_fixed: bool = False
    donor: str | None = None
    share_with: str | None = None  # another row whose candidate set this row reuses
    couple_with: str | None = None  # another row whose candidate set this row's is a translate of
    link: object | None = None  # a related row of another task whose candidate set this row's follows (.follow.Link)
    box_links: list = field(default_factory=list)  # a box's dimension rows whose distractors its edges follow
    evidence: dict = field(default_factory=dict)
    scratch: dict = field(default_factory=dict, repr=False)  # state of one build of the row, across its tries

    @property
    def rid(self) -> str:
        return self.spec.rid


@dataclass
class GroupModel:
    kind: str
    fields: FieldModel | None = None
    info: dict = field(default_factory=dict)  # per-row derived values (offsets, preimages, ...)


def share_key(spec: OptionSpec) -> tuple:
    """What two rows must have in common to share a candidate set: task, source, the measured
    quantity of the same subject (the camera of one recording, or the same noun phrase) over the same
    window (to the millisecond), and the same answer string. Cameras of two recordings are not one
    subject: their answers coincide only through coarse printing, and one set shared by both would
    carry the answer from a row of one recording to the other's (a learned reader trained on one
    recognises the set in the other)."""
    o = spec.obs
    window = None if o.window_s is None else round(float(o.window_s), 3)
    subject = " ".join(str(o.subject or "").lower().split())
    recording = o.sequence if o.is_camera else None
    return (spec.task, spec.source, o.quantity, subject, recording, window, o.premise_text, spec.detail)


def couple_key(spec: OptionSpec) -> tuple:
    """What two rows of one recording must have in common for their candidate sets to be coupled
    (one a translate of the other by the difference of their answers): task, source, the source
    sequence, the measured quantity of the same subject over the same window, the premise, the
    unit and printed decimals. The camera videos of one segment ask the ego heading change over one
    window and get answers a hundredth of a degree apart (the mounts differ)."""
    o = spec.obs
    window = None if o.window_s is None else round(float(o.window_s), 3)
    start = None if o.time_start is None else round(float(o.time_start), 3)
    subject = " ".join(str(o.subject or "").lower().split())
    return (spec.task, spec.source, o.sequence, o.quantity, subject, start, window, o.premise_text, spec.unit,
            spec.decimals)


def dense_window(values, gap: float, *, min_rows: int = 5) -> tuple[float, float, int] | None:
    """The window narrower than the separation floor ``gap`` (it holds at most one candidate) that
    holds the most answers, when it holds more than a fifth of them: ``(lo, hi, count)``.

    Five exchangeable candidates would put more than one candidate there on average, which
    separated candidates cannot: the stage then treats the window like a fixed slot (see
    :meth:`Stage._window_slot`)."""
    x = np.sort(np.asarray(values, float))
    n = len(x)
    best = None
    j = 0
    for i in range(n):
        j = max(j, i)
        while j + 1 < n and x[j + 1] - x[i] < gap:
            j += 1
        if best is None or j - i + 1 > best[2]:
            best = (float(x[i]), float(x[j]), j - i + 1)
    if best is None or best[2] < min_rows or best[2] / n <= 0.2:
        return None
    return best


def slot_subgroup(spec: OptionSpec) -> tuple:
    """Rows among which a fixed slot's carriers are chosen: the same quantity, of the camera or of
    an object, over a window or at an instant — so the slot string is not the answer more often in
    one kind of question than another."""
    o = spec.obs
    return (o.quantity, o.is_camera, o.window_s is None)


def slot_subgroup_text(sub: tuple) -> str:
    """A :func:`slot_subgroup` in words (``"object, at an instant"``)."""
    _, camera, instant = sub
    return f"{'camera' if camera else 'object'}, {'at an instant' if instant else 'over a window'}"


def slot_subgroup_sizes(specs: list) -> Counter:
    """Rows per :func:`slot_subgroup` (scalars): what a slot answer's share is counted over."""
    return Counter(slot_subgroup(s) for s in specs if s.kind == "scalar")


def slot_answers(specs: list) -> dict[tuple, list[int]]:
    """Answers printed where no candidate can print below them, per (:func:`slot_subgroup`, value)
    (indices into ``specs``): exact zeros (stationary objects) and answers at the smallest printable
    value (one printed unit: objects that touch, 0.01 m; a parked car's 0.01 m/s just above the zeros).
    Each is one string that, drawn like the other answers, would always be the smallest candidate (or
    the smallest above the zero): the option stage makes it a fixed slot that other rows carry as a
    distractor (``model.zero_slot_ratio`` per such answer), and the evaluation subset keeps such answers
    at one row in five. Ordered by subgroup, the zero before the floor."""
    subs: dict[tuple, list[int]] = defaultdict(list)
    for i, s in enumerate(specs):
        if s.kind == "scalar":
            subs[slot_subgroup(s)].append(i)
    out = {}
    for sub, ids in sorted(subs.items(), key=lambda t: str(t[0])):
        zs = [i for i in ids if specs[i].value.value <= 0]
        if zs:
            out[(sub, 0.0)] = zs
        fl = [i for i in ids if abs(specs[i].value.value - specs[i].ulp) < 1e-9 * specs[i].ulp]
        if fl:
            out[(sub, float(specs[fl[0]].value.value))] = fl
    return out


def recorded_decimals(values, max_decimals: int) -> int:
    """The decimals a field of a group's answers is recorded with: the fewest that represent at
    least half of the values exactly (Waymo box heights are recorded to the centimetre where
    lengths have millimetres). Distractors printed finer than the answers would mark the answer."""
    v = np.asarray(values, dtype=float)
    for d in range(max_decimals + 1):
        if np.mean(np.abs(np.round(v, d) - v) > 1e-9) < 0.5:
            return d
    return max_decimals


def group_key(spec: OptionSpec) -> str:
    o = spec.obs
    if spec.kind == "scalar":  # questions at an instant and over an interval, of the camera and of an
        # object are told apart (a parked car's speed is not a slow camera's)
        form = "instant" if spec.obs.time_start is not None and spec.obs.time_start == spec.obs.time_end else "interval"
        role = "camera" if o.is_camera else "object"
        return f"{spec.task}|{spec.source}|{spec.unit}|{form}|{role}"
    if spec.kind == "angle":
        return f"{spec.task}|{spec.source}|{o.quantity}"
    if spec.kind == "pose":  # a camera's mount fixes where the car's travel lies in its frame
        return f"{spec.task}|{spec.source}|pose" + (f"|camera {o.camera}" if o.camera else "")
    return f"{spec.task}|{spec.source}|{spec.kind}"


def mid_time(spec: OptionSpec) -> float:
    """When in the video the question asks (the middle of its window): a covariate, since what a
    camera does depends on the moment of the recording."""
    o = spec.obs
    if o.time_start is None or o.time_end is None:
        return float("nan")
    return 0.5 * (o.time_start + o.time_end)


def log_window(spec: OptionSpec) -> float:
    w = spec.obs.window_s
    return math.log(w) if w and w > 0 else float("nan")


class Reject(Exception):
    """A drawn candidate set breaks a constraint; it is redrawn whole."""


def signed_rank(p: RowPlan, strings: list[str]) -> int | None:
    """The answer's signed-value rank among the five (1 = smallest) for one-dimensional answers."""
    if p.spec.kind not in ONE_D:
        return None

    def key(t):
        v = V.parse(t)
        return v.total_distance if isinstance(v, V.Trajectory) else v.value

    vals = sorted(key(t) for t in strings)
    return vals.index(key(p.spec.detail)) + 1

def reprint(text: str, like: V.Pose) -> str:
    q = V.parse(text)
    return V.format_pose(q.matrix, like.decimals, compact=like.compact)
