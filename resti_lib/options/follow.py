"""Candidate sets that follow a related row's across tasks: a relation singles out nothing.

Rows of one recording measure one world, so one row's answer often follows from another's by physics
(the attacks of family ``relation`` in :mod:`resti_lib.options.attacks.relation` read those links): a
length is an edge of the subject's box, a heading change the turn sum of a trajectory description over
the same window, a path length its total distance, a mean speed a distance over the window divided
by the window. A reader who sees the driver row's five candidates then picks the follower's candidate
that matches one of them. Here the follower's distractors are the images of the driver's distractors
under the relation, anchored at the follower's own answer: candidate ``j`` is the answer moved by the
driver's candidate ``j`` relative to the driver's answer (a ratio for magnitudes, a difference for
angles). Every follower candidate then matches exactly one driver candidate, as the answer matches
the driver's answer, and the relation picks each of the five alike.

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

#: follower quantity -> (driver quantities, what a driver candidate measures, additive?)
FOLLOWS: dict[str, tuple[tuple[str, ...], str, bool]] = {
    "length": (("box",), "edge", False),
    "width": (("box",), "edge", False),
    "height": (("box",), "edge", False),
    "heading_change": (("trajectory",), "turn_sum", True),
    "path_length": (("trajectory",), "total_distance", False),
    "speed": (DISTANCES, "per_window", False),
}


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
        if self.relation == "edge":
            return float(v.lwh[self.edge]) if isinstance(v, V.Box) else None
        if self.relation == "turn_sum":
            return turn_sum(v) if isinstance(v, V.Trajectory) else None
        if self.relation == "total_distance":
            return v.total_distance if isinstance(v, V.Trajectory) else None
        if self.relation == "per_window":
            return abs(float(v.si)) if isinstance(v, V.Scalar) else None
        return None

    def image(self, follower: OptionSpec, driver_answer, driver_candidate) -> float | None:
        """The follower's value that relates to ``driver_candidate`` as its answer relates to the
        driver's answer (None where it cannot be formed)."""
        a, c = self.measure(driver_answer), self.measure(driver_candidate)
        if a is None or c is None or not (math.isfinite(a) and math.isfinite(c)):
            return None
        x = float(follower.value.value)
        if self.additive:
            return float(V.wrap_degrees(x + (c - a)))
        if a <= 0 or c <= 0:
            return None
        return x * c / a


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
        if od.sequence != o.sequence or od.quantity not in quantities or d.task == f.task:
            continue
        if relation == "edge":
            if od.subject_class != o.subject_class or not isinstance(d.value, V.Box):
                continue
            edges = [0, 1, 2]
        else:
            wd = window(od)
            if w is None or wd is None or not same_window(w, wd):
                continue
            edges = [None]
        for k in edges:
            link = Link(f.rid, d.rid, relation, k, additive)
            g = link.measure(d.value)
            if g is None or not math.isfinite(g):
                continue
            if additive:
                err = circular(float(f.value.value), g)
                ok = err <= deg_tol
                score = err / max(deg_tol, 1e-9)
            else:
                span = (w[1] - w[0]) if relation == "per_window" else 1.0
                pred = g / span
                fx = abs(float(f.value.si))
                if pred <= 0 or fx <= 0:
                    continue
                err = abs(math.log(fx / pred))
                ok = err <= rel_tol
                score = err / max(rel_tol, 1e-9)
            if ok and (best is None or score < best[0]):
                best = (score, link)
    return None if best is None else best[1]


def follow_strings(link: Link, f: OptionSpec, driver: OptionSpec, driver_strings: list[str]) -> list[str] | None:
    """The follower's five candidate strings from the driver's five (its own answer in place of the
    image of the driver's answer), or None when two coincide once printed or one is impossible."""
    others = [s for s in driver_strings if s != driver.detail]
    if len(others) != 4:
        return None
    out = []
    for s in others:
        x = link.image(f, driver.value, V.parse(s))
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


__all__ = ["FOLLOWS", "Link", "circular", "find_link", "follow_strings", "same_window", "turn_sum", "window"]
