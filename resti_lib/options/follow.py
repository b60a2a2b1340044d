"""Candidate sets that follow a related row's across tasks: a relation singles out nothing.

Rows of one recording measure one world, so one row's answer often follows from another's by physics
(the attacks of family ``relation`` in :mod:`resti_lib.options.attacks.relation` read those links): a
box's edge is the length, width or height of its subject asked in another row, a heading change the
turn sum of a trajectory description over the same window, a path length its total distance (and a
displacement at most that), a mean speed a distance over the window divided by the window. A reader
who sees the driver row's five candidates then picks the follower's candidate that matches one of
them. Here the follower's distractors are the images of the driver's distractors under the relation,
anchored at the follower's own answer: candidate ``j`` is the answer moved by the driver's candidate
``j`` relative to the driver's answer (a ratio for magnitudes, a difference for angles). Every
follower candidate then matches exactly one driver candidate, as the answer matches the driver's
answer, and the relation picks each of the five alike.

A link exists only where the relation holds for the answers (within ``params/options.yaml``
``follow``): a sibling that measures something else is left alone. The follower's set must still meet
its own requirements (separation, plausibility, format); where it does not, the row draws its own.

Which task's rows drive which: the task order of :data:`FOLLOWS` (a driver is built before its
followers; a follower may drive another, e.g. trajectory -> path length -> speed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import values as V
from .spec import OptionSpec

DIMENSIONS = ("length", "width", "height")
DISTANCES = ("displacement", "path_length")
WINDOW_TOL_S = 0.1      # two windows are the same when both ends agree within this many seconds ...
WINDOW_TOL_REL = 0.01   # ... or this fraction of the window, whichever is larger

#: follower quantity -> (driver quantities, what a driver candidate measures, additive?). A box
#: follows the dimensions of its subject asked in other rows (its distractors' edges are their
#: distractors' images; the rest of the box is its own draw): a box's distractors' edges may lie closer
#: together than a dimension's separation floor allows, a dimension's never do. A displacement is at
#: most the path over its window (``path_bound``, one-sided: :data:`AT_MOST`): its candidates are the
#: path lengths (or a trajectory's total distances) asked beside it times the answer's own ratio, so
#: every displacement candidate lies within exactly one path candidate, as the answer within the answer.
FOLLOWS: dict[str, tuple[tuple[str, ...], str, bool]] = {
    "box": (DIMENSIONS, "box_edge", False),
    "displacement": (("path_length", "trajectory"), "path_bound", False),
    "heading_change": (("trajectory",), "turn_sum", True),
    "path_length": (("trajectory",), "total_distance", False),
    "speed": (DISTANCES, "per_window", False),
}
#: Relations that bound the follower from above (any ratio up to ``relative_tol`` past the driver's
#: value links), not an equality within ``relative_tol``.
AT_MOST = frozenset({"path_bound"})


def window(o) -> tuple[float, float] | None:
    """The interval a question asks about (None for an instant or no times)."""
    if o.time_start is None or o.time_end is None or not o.time_end > o.time_start:
        return None
    return float(o.time_start), float(o.time_end)


def same_window(a, b) -> bool:
    tol = max(WINDOW_TOL_S, WINDOW_TOL_REL * (a[1] - a[0]))
    return abs(a[0] - b[0]) <= tol and abs(a[1] - b[1]) <= tol


def turn_sum(v: V.Trajectory) -> float:
    """The signed heading change of a trajectory description (left turns positive), in degrees."""
    return float(sum(x for k, x in v.segments if k == "turn"))


def distance_of(v) -> float | None:
    """The distance a value states: a scalar's magnitude (SI) or a trajectory's total distance."""
    if isinstance(v, V.Trajectory):
        return v.total_distance
    return abs(float(v.si)) if isinstance(v, V.Scalar) else None


def circular(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


@dataclass(frozen=True)
class Link:
    """Row ``follower`` follows row ``driver``: ``measure(value)`` is what a driver candidate predicts
    of the follower (in the follower's SI units for magnitudes, degrees for angles)."""

    follower: str
    driver: str
    relation: str
    edge: int | None
    additive: bool

    def measure(self, v) -> float | None:
        if self.relation == "box_edge":
            return abs(float(v.si)) if isinstance(v, V.Scalar) else None
        if self.relation == "turn_sum":
            return turn_sum(v) if isinstance(v, V.Trajectory) else None
        if self.relation == "total_distance":
            return v.total_distance if isinstance(v, V.Trajectory) else None
        if self.relation == "path_bound":  # a path length's magnitude or a trajectory's total distance
            return distance_of(v)
        if self.relation == "per_window":
            return abs(float(v.si)) if isinstance(v, V.Scalar) else None
        return None

    def residual(self, follower: OptionSpec, driver_answer) -> float | None:
        """How far the follower's answer is from what the driver's answer gives: degrees (angles) or
        a log ratio (magnitudes); None where it cannot be formed."""
        g = self.measure(driver_answer)
        if g is None or not math.isfinite(g):
            return None
        if self.additive:
            return float(V.wrap_degrees(float(follower.value.value) - g))
        if self.relation == "box_edge":
            e = float(follower.value.lwh[self.edge])
            return math.log(e / g) if e > 0 and g > 0 else None
        w = window(follower.obs)
        pred = g / (w[1] - w[0]) if self.relation == "per_window" and w is not None else g
        fx = abs(float(follower.value.si))
        return math.log(fx / pred) if pred > 0 and fx > 0 else None

    def image(self, follower: OptionSpec, driver_answer, driver_candidate, offset: float = 0.0) -> float | None:
        """The follower's value that relates to ``driver_candidate`` as its answer relates to the
        driver's answer, moved by ``offset`` (degrees or log ratio); None where it cannot be formed."""
        a, c = self.measure(driver_answer), self.measure(driver_candidate)
        if a is None or c is None or not (math.isfinite(a) and math.isfinite(c)):
            return None
        x = float(follower.value.lwh[self.edge]) if self.relation == "box_edge" else float(follower.value.value)
        if self.additive:
            return float(V.wrap_degrees(x + (c - a) + offset))
        if a <= 0 or c <= 0:
            return None
        return x * c / a * math.exp(offset)


def find_link(f: OptionSpec, drivers: list[OptionSpec], params: dict) -> Link | None:
    """The driver row ``f`` follows among ``drivers`` (rows of other tasks), or None: a sibling of the
    same recording whose answer relates to ``f``'s by the relation of ``f``'s quantity (same window;
    for an edge, the same subject noun), the closest match first."""
    o = f.obs
    if o.quantity not in FOLLOWS or f.kind not in ("scalar", "angle"):
        return None
    quantities, relation, additive = FOLLOWS[o.quantity]
    rel_tol = float(params.get("relative_tol", 0.05))
    deg_tol = float(params.get("angle_tol_deg", 3.0))
    w = window(o)
    best: tuple[float, Link] | None = None
    for d in drivers:
        od = d.obs
        # a row of its own task drives only through a bound (a displacement and the path length asked
        # beside it); an equality within one task is the same quantity asked twice (shared sets)
        if od.sequence != o.sequence or od.quantity not in quantities or (d.task == f.task and relation not in AT_MOST):
            continue
        wd = window(od)
        if w is None or wd is None or not same_window(w, wd):
            continue
        edges = [None]
        for k in edges:
            link = Link(f.rid, d.rid, relation, k, additive)
            r = link.residual(f, d.value)
            if r is None:
                continue
            score = abs(r) / max(deg_tol if additive else rel_tol, 1e-9)
            related = r <= rel_tol if relation in AT_MOST else score <= 1.0
            if related and (best is None or score < best[0]):
                best = (score, link)
    return None if best is None else best[1]


def find_box_links(f: OptionSpec, drivers: list[OptionSpec], params: dict) -> list[Link]:
    """The dimension rows a box row follows: rows of other tasks of the same recording asking a
    length, width or height of the same subject noun whose answer is an edge of the box (within
    ``relative_tol``), one per edge, the closest match first."""
    if f.kind != "box" or not isinstance(f.value, V.Box):
        return []
    rel_tol = float(params.get("relative_tol", 0.05))
    found: dict[int, tuple[float, Link]] = {}
    for d in drivers:
        if d.obs.sequence != f.obs.sequence or d.task == f.task or d.obs.quantity not in DIMENSIONS \
                or d.obs.subject_class != f.obs.subject_class or not isinstance(d.value, V.Scalar):
            continue
        for k in range(3):
            link = Link(f.rid, d.rid, "box_edge", k, False)
            r = link.residual(f, d.value)
            if r is not None and abs(r) <= rel_tol and (k not in found or abs(r) < found[k][0]):
                found[k] = (abs(r), link)
    used: set = set()
    out = []
    for _, link in sorted(found.values(), key=lambda t: (t[0], t[1].edge)):
        if link.driver not in used:  # one edge per dimension row
            used.add(link.driver)
            out.append(link)
    return sorted(out, key=lambda lk: lk.edge)


def box_edge_map(links, specs: dict, *, min_links: int = 3, min_share: float = 0.8) -> dict:
    """Which edge of a box a dimension question asks, per (source, quantity): the edge its answers
    match in the boxes of the same subject in their recordings (``links``: each box row's
    :func:`find_box_links`; ``specs``: rid -> spec of their drivers), where at least ``min_links``
    links agree on one edge in at least ``min_share`` of them (Waymo: a length is the box's first edge;
    ScanNet: a height its third). A source whose links disagree (its boxes' axes follow no fixed
    convention) gets none."""
    counts: dict[tuple, dict[int, int]] = {}
    for box in links:
        for link in box:
            d = specs[link.driver]
            c = counts.setdefault((d.source, d.obs.quantity), {})
            c[link.edge] = c.get(link.edge, 0) + 1
    out = {}
    for key, c in sorted(counts.items()):
        edge, n = max(sorted(c.items()), key=lambda t: t[1])
        if n >= min_links and n >= min_share * sum(c.values()):
            out[key] = edge
    return out


def follow_box(links: list[Link], f: OptionSpec, drivers: dict, own: list[str], decimals: dict) -> list[str] | None:
    """A box row's candidates with the edges its dimension rows ask replaced: edge ``k`` of its
    distractor ``j`` is the image of distractor ``j`` of the dimension row (``drivers``: rid -> (spec,
    strings)), printed with the group's decimals of that edge (``decimals["d<k>"]``); the rest of each
    box is its own draw ``own``. None when a driver is missing or a box cannot be printed."""
    others = [s for s in own if s != f.detail]
    if len(others) != 4:
        return None
    boxes = [V.parse(s) for s in others]
    if any(b.R is None for b in boxes):
        return None
    dims = [list(b.lwh) for b in boxes]
    for link in links:
        if link.driver not in drivers:
            return None
        dspec, dstrings = drivers[link.driver]
        dothers = [s for s in dstrings if s != dspec.detail]
        if len(dothers) != 4:
            return None
        for j, s in enumerate(dothers):
            x = link.image(f, dspec.value, V.parse(s))
            if x is None or not x > 0:
                return None
            dims[j][link.edge] = round(x, int(decimals.get(f"d{link.edge}", 3)))
    out = [V.format_box(b.center, d, b.R) for b, d in zip(boxes, dims)] + [f.detail]
    return out if len(set(out)) == 5 else None


def follow_strings(link: Link, f: OptionSpec, driver: OptionSpec, driver_strings: list[str],
                   offsets=None) -> list[str] | None:
    """The follower's five candidate strings from the driver's five (its own answer in place of the
    image of the driver's answer), distractor ``j`` moved by ``offsets[j]`` (default none), or None
    when two coincide once printed or one is impossible."""
    others = [s for s in driver_strings if s != driver.detail]
    if len(others) != 4:
        return None
    offsets = [0.0] * 4 if offsets is None else list(offsets)
    out = []
    for s, off in zip(others, offsets):
        x = link.image(f, driver.value, V.parse(s), float(off))
        if x is None or not np.isfinite(x):
            return None
        if f.kind == "angle":
            out.append(V.format_angle(-180.0 if round(x, f.decimals) >= 180.0 else x, f.decimals))
        else:
            if x <= 0:
                return None
            out.append(V.format_scalar(x, f.unit, f.decimals))
    out.append(f.detail)
    return out if len(set(out)) == 5 else None


def grid_offsets(step: float, rng, tries: int) -> list[np.ndarray]:
    """Offsets for the four distractors on a grid of ``step`` (a little over the separation floor):
    the five candidates take the five slots of the grid in a random order, each distractor moved by
    its slot less the answer's slot. Where two driver candidates give one image, the candidates
    around it are then evenly spaced with the answer in a uniformly random slot, so the candidate
    nearest the image is the answer in one set in five (unless the answer is within half a step of
    its image: no separated set can hide that)."""
    out = []
    for _ in range(tries):
        slots = rng.permutation(5).astype(float)
        out.append((slots[:4] - slots[4]) * step)
    return out


def residual_offsets(own: float, pool: list[float], rng, tries: int) -> list[np.ndarray]:
    """Offsets for the four distractors when their exact images cannot all be used (two driver
    candidates give one image): each distractor's distance from its image drawn from ``pool`` (the
    residuals of the linked rows of other recordings), relative to the answer's own residual ``own``,
    so the answer's distance from its image is one of five draws from one distribution."""
    if len(pool) < 5:
        return []
    p = np.asarray(pool, float)
    return [p[rng.integers(0, len(p), 4)] - own for _ in range(tries)]


__all__ = ["AT_MOST", "FOLLOWS", "Link", "circular", "distance_of", "find_box_links", "find_link", "follow_box", "follow_strings",
           "grid_offsets", "residual_offsets", "same_window", "turn_sum", "window"]
