"""The option stage: the five candidates of every accepted row, built once.

Used where the release is assembled (:func:`resti_lib.release.assemble.write_release`) and by ``resti
reoption`` — the same code, so what the report audits is what ships. Input: accepted rows in the
ReSTI schema (their ``Answer Detail`` is the answer; any existing candidates are ignored except the
label set of a categorical task) and, optionally, what each task knows beyond the row
(:class:`~resti_lib.options.spec.OptionSpec` extras). Output: the same rows with ``Candidates``
and ``Answer`` set, and one evidence record per row.

How a row's candidates are drawn (see :mod:`resti_lib.options.population`): the answers of its
group (task, source, quantity, unit) define a distribution *conditioned on what the question
states* — a distance is modelled as a rate over the question's window, a size relative to the
sizes of its subject's class, a pose as a motion from the premise pose over the window, a box's
centre, edge lengths and heading jointly (their correlation kept) — and the five candidates are
exchangeable draws from it, one of which is the answer (its own answer left out of the model).
Every candidate is printed from its own exact value by :mod:`resti_lib.values`, the way the answer
was printed; rotations start from an exact rotation that prints as the answer's matrix, so nothing
invariant under the perturbation can differ in its last digit.

Constraints, symmetric in the five candidates (a set that breaks one is redrawn whole, so the
answer stays exchangeable): pairwise separation (no two candidates within the task's adjudication
rule of each other, orientation options at least 1 degree apart, boxes and poses separated in
centre or translation, rotation and size) and physical possibility given the question (the implied
speed of a distance over its window, acceleration, sizes, depths). When the draws cannot meet the
constraints the spread widens in steps (recorded in the evidence).

Letters are balanced per task by a schedule. The answer's signed-value rank among the five is not
scheduled: it follows from the exchangeable draw (an extreme answer is more often the extreme
candidate, as any of five exchangeable values would be), so it is uniform over the rows without
tying an answer to a rank its value makes unlikely.

Exact zeros (a stationary object) and ``no significant movement`` are fixed slots: that string is
placed in every row whose answer it is and in ``zero_slot_ratio`` times as many other rows of the
group, so it is the answer in about one row in five where it appears.
Rows of one video that ask for the same answer share one candidate set, so another question of the
same video cannot reveal it; a Pose answer that another question of the same video prints as its
premise gets, where it can, other premise poses of that video as distractors.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from .. import LETTERS
from .. import values as V
from ..errors import InputError, OptionError
from ..geometry.frames import nearest_rotation
from ..rng import row_rng, stable_seed
from .population import Copula, Marginal, circular_cut, from_cut_line, on_cut_line
from .spec import (
    Interface,
    OptionSpec,
    angle_gap,
    box_floors,
    box_separation,
    per_source,
    pose_floors,
    pose_separation,
    scalar_bounds,
    scalar_gap,
    spec_of,
    speed_bound,
)

WINDOWED = ("displacement", "path_length", "trajectory")
#: Quantities of an object that recur when one object is asked about in several recordings.
OBJECT_SIZES = ("length", "width", "height", "distance", "distance_to_camera", "surface_distance")

ONE_D = ("scalar", "angle", "trajectory")


# ------------------------------------------------------------------------------ schedules

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


def _slot_rows(carriers: list[str], others: list[str], ratio: float, *, seed: int, group: str) -> set:
    """Rows carrying a fixed slot: every carrier plus ``ratio`` times as many others (seeded)."""
    want = min(len(others), round(ratio * len(carriers)))
    if not carriers or want == 0:
        return set(carriers)
    rng = np.random.default_rng(stable_seed(seed, "slot", group))
    pool = sorted(others)
    return set(carriers) | {pool[int(i)] for i in rng.permutation(len(pool))[:want]}


# ------------------------------------------------------------------------------ geometry helpers

def rot(axis, deg: float) -> np.ndarray:
    a = np.asarray(axis, float)
    return Rotation.from_rotvec(a / np.linalg.norm(a) * np.radians(deg)).as_matrix()


def rotation_preimage(printed, decimals: int, rng: np.random.Generator, *, accept=None, tries: int = 3000
                      ) -> np.ndarray:
    """An exact rotation whose entries print as ``printed`` at ``decimals`` (and that ``accept``
    takes, e.g. its printed heading): every field a perturbation leaves alone then prints exactly
    as in the answer."""
    P = np.asarray(printed, float)
    R = nearest_rotation(P)

    def ok(Q):
        return np.array_equal(np.round(Q, decimals), np.round(P, decimals)) and (accept is None or accept(Q))

    if ok(R):
        return R
    sigma = 0.6 * 10.0 ** -decimals
    for _ in range(tries):
        Q = Rotation.from_rotvec(rng.normal(0.0, sigma, 3)).as_matrix() @ R
        if ok(Q):
            return Q
    return R


def heading_deg(R, up, col: int) -> float:
    """Heading of column ``col`` of a rotation about the world ``up`` axis (degrees)."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    e1 = np.array([1.0, 0.0, 0.0]) - up[0] * up
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.array([0.0, 1.0, 0.0]) - up[1] * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    v = np.asarray(R, float)[:, col]
    return float(np.degrees(np.arctan2(v @ e2, v @ e1)))


def horizontal_frame(R, up, col: int = 2) -> np.ndarray:
    """Columns: horizontal forward (column ``col`` projected), left, up — a premise's heading frame."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    f = np.asarray(R, float)[:, col] - (np.asarray(R, float)[:, col] @ up) * up
    if np.linalg.norm(f) < 1e-6:
        f = np.array([1.0, 0.0, 0.0]) - up[0] * up
    f /= np.linalg.norm(f)
    return np.column_stack([f, np.cross(up, f), up])


def box_yaw(R, up_axis: int) -> float:
    """Heading of a box about its local ``up_axis`` (``box_yaw(R @ rot(e_up, d)) == box_yaw(R) + d``)."""
    R = np.asarray(R, float)
    up = R[:, up_axis]
    f = np.array([0.0, 0.0, 1.0]) - up[2] * up
    if np.linalg.norm(f) < 1e-6:
        f = np.array([1.0, 0.0, 0.0]) - up[0] * up
    f /= np.linalg.norm(f)
    g = np.cross(up, f)
    a = R[:, (up_axis + 1) % 3]
    return float(np.degrees(np.arctan2(a @ g, a @ f)))


_DOWN = np.array([0.0, 1.0, 0.0])  # +Y down in the reference camera's OpenCV axes


def gaze_depth(R, t) -> float:
    """Depth along the reference optical axis (+Z) of its closest approach to this camera's optical
    axis; NaN when the two are parallel or the point is not in front."""
    a = np.array([0.0, 0.0, 1.0])
    b = np.asarray(R, float)[:, 2]
    t = np.asarray(t, float)
    c = a @ b
    den = 1.0 - c * c
    if den < 1e-4:
        return float("nan")
    s = (t @ a - c * (t @ b)) / den
    return float(s) if 0.05 < s < 50.0 else float("nan")


def _gaze_basis(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e1 = np.cross(_DOWN, u)
    if np.linalg.norm(e1) < 1e-9:
        e1 = np.cross(np.array([1.0, 0.0, 0.0]), u)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(u, e1)


def gaze_fields(R, t, G) -> np.ndarray:
    """A camera relative to a gaze point ``G`` (reference frame): its centre (3), the two angles of its
    optical axis away from the line towards ``G`` and its roll about the optical axis (degrees).
    Cameras around a desk look at it: every candidate drawn this way does too."""
    R, C = np.asarray(R, float), np.asarray(t, float)
    a = R[:, 2]
    u = np.asarray(G, float) - C
    u /= np.linalg.norm(u)
    e1, e2 = _gaze_basis(u)
    au = max(float(a @ u), 1e-6)
    alpha, beta = np.degrees(np.arctan2(a @ e1, au)), np.degrees(np.arctan2(a @ e2, au))
    xr = np.cross(_DOWN, a)
    xr /= np.linalg.norm(xr)
    yr = np.cross(a, xr)
    roll = np.degrees(np.arctan2(R[:, 0] @ yr, R[:, 0] @ xr))
    return np.array([*C, alpha, beta, roll])


def from_gaze_fields(f, G) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`gaze_fields`: (R, t)."""
    f = np.asarray(f, float)
    C = f[:3]
    u = np.asarray(G, float) - C
    u /= np.linalg.norm(u)
    e1, e2 = _gaze_basis(u)
    a = u + np.tan(np.radians(f[3])) * e1 + np.tan(np.radians(f[4])) * e2
    a /= np.linalg.norm(a)
    xr = np.cross(_DOWN, a)
    xr /= np.linalg.norm(xr)
    yr = np.cross(a, xr)
    x = np.cos(np.radians(f[5])) * xr + np.sin(np.radians(f[5])) * yr
    return np.column_stack([x, np.cross(a, x), a]), C


def centre_fields(c, mode: str) -> np.ndarray:
    """A box centre as drawn: projective (x/z, y/z, log z), height (x/z, y, log z) or cartesian."""
    c = np.asarray(c, float)
    if mode == "projective":
        return np.array([c[0] / c[2], c[1] / c[2], math.log(c[2])])
    if mode == "height":
        return np.array([c[0] / c[2], c[1], math.log(c[2])])
    return c.copy()


def centre_from_fields(f, mode: str) -> np.ndarray:
    f = np.asarray(f, float)
    if mode == "projective":
        z = math.exp(f[2])
        return np.array([f[0] * z, f[1] * z, z])
    if mode == "height":
        z = math.exp(f[2])
        return np.array([f[0] * z, f[1], z])
    return f.copy()


def centre_half_cells(c, mode: str, ulp: float) -> np.ndarray:
    """Half width of the printed rounding cell of each centre field (first-order)."""
    z = abs(float(c[2])) or 1.0
    h = 0.5 * ulp
    if mode == "projective":
        return np.array([h / z, h / z, h / z])
    if mode == "height":
        return np.array([h / z, h, h / z])
    return np.array([h, h, h])


# ------------------------------------------------------------------------------ field models

@dataclass
class FieldModel:
    """Marginals of ``d`` fields and ``k`` covariates of one group's rows, and their copula."""

    fields: list
    covariates: list
    copula: Copula
    cov_scores: np.ndarray  # (n, k) covariate scores of every member row
    index: dict  # rid -> member position

    @classmethod
    def fit(cls, rids: list, B: np.ndarray, H: np.ndarray, W: np.ndarray | None, *, knn: int, shrink: float,
            min_rows: int = 8, prior_sd=0.5, prior_center=None) -> "FieldModel":
        """Fit on the base values ``B`` (n, d) of the group's rows ``rids`` with half rounding cells
        ``H`` and covariates ``W`` (n, k).

        A group with fewer than ``min_rows`` answers cannot define a distribution alone: each field's
        marginal then also holds pseudo-answers at the normal quantiles of a weak prior (the rows'
        mean, or ``prior_center`` without rows, and the larger of their spread and ``prior_sd``),
        as many as the rows are short of ``min_rows``."""
        n = len(rids)
        B = np.asarray(B, float).reshape(n, -1) if n else np.zeros((0, np.size(prior_center)))
        H = np.asarray(H, float).reshape(B.shape) if n else np.zeros(B.shape)
        d = B.shape[1]
        m = max(0, min_rows - n)
        fields = []
        for j in range(d):
            bj, hj = B[:, j], H[:, j]
            if m:
                centre = float(bj.mean()) if n else float(np.atleast_1d(prior_center)[j])
                sd = max(float(bj.std()) if n > 1 else 0.0, float(np.atleast_1d(prior_sd)[j % np.size(prior_sd)]))
                pseudo = centre + sd * norm_quantiles(m)
                bj = np.concatenate([bj, pseudo])
                hj = np.concatenate([hj, np.full(m, hj.mean() if n else 0.1 * sd)])
            fields.append(Marginal.fit(bj, hj, k=knn))
        covs, cs = [], np.zeros((n, 0))
        if W is not None and W.size and n >= min_rows:
            W = np.asarray(W, float).reshape(n, -1)
            keep = [j for j in range(W.shape[1]) if np.nanstd(W[:, j]) > 1e-9]
            for j in keep:
                covs.append(Marginal.fit(W[:, j], 1e-6, k=knn))
            if covs:
                cs = np.column_stack([c.row_map(None).score(W[:, j]) for c, j in zip(covs, keep)])
        if n:
            us = np.column_stack([f.row_map(None).score(B[:, j]) for j, f in enumerate(fields)])
            cop = Copula.fit(np.column_stack([us, cs]), d, shrink=shrink)
        else:
            cop = Copula(np.eye(d), d)
        return cls(fields, covs, cop, cs, {r: i for i, r in enumerate(rids)})

    def prepare(self, rid: str | None, bounds: list | None = None) -> "RowDraw":
        """The maps (without the row's own answer, within the row's ``bounds`` [(lower, upper) per
        field, base space]) and conditional model of one row, computed once; a row outside the model
        (``None`` or not a member) draws from the whole group."""
        i = self.index.get(rid) if rid is not None else None
        u_w = self.cov_scores[i] if (i is not None and self.cov_scores.shape[1]) else None
        if i is None and self.cov_scores.shape[1]:
            u_w = np.zeros(self.cov_scores.shape[1])
        mu, L = self.copula.conditional(u_w)
        bounds = bounds or [(None, None)] * len(self.fields)
        return RowDraw([f.row_map(i, lo, hi) for f, (lo, hi) in zip(self.fields, bounds)], mu, L)


def norm_quantiles(m: int) -> np.ndarray:
    """``m`` evenly spaced standard normal quantiles (deterministic pseudo-answers)."""
    from scipy.stats import norm

    return norm.ppf((np.arange(m) + 0.5) / m)


@dataclass
class RowDraw:
    """Draws of one row's distractors in base space (see :class:`FieldModel`).

    ``gamma`` scales the exchangeable model in standardised score space: the stage calibrates it per
    group so that the distractors that survive the separation and plausibility constraints are
    distributed like the answers (the constraints push candidates apart, which would otherwise make
    the distractors less typical than the answer).
    """

    maps: list
    mu: np.ndarray
    L: np.ndarray
    last_z: np.ndarray | None = None
    last_za: np.ndarray | None = None
    drawn: list = field(default_factory=list)  # every standardised draw of the row, kept or not

    def draw(self, cells: list, s: float, rng: np.random.Generator, *, n: int = 4, prior: bool = False,
             batch: int | None = None) -> np.ndarray:
        """Base values (n, d) — or (batch, n, d) — given the answer's base rounding ``cells``
        [(lo, hi), ...]; ``prior``: no designated answer (fixed-slot rows)."""
        d = len(self.maps)
        K = batch or 1
        if prior:
            c = math.sqrt(max(1.0 - s * s, 1e-6)) * rng.standard_normal((K, 1, d))
            z = c + s * rng.standard_normal((K, n, d))
            self.last_za = None
        else:
            u_a = np.column_stack([m.cell_score(lo, hi, rng, K) for m, (lo, hi) in zip(self.maps, cells)])
            z_a = np.linalg.solve(self.L, (u_a - self.mu[None, :]).T).T  # (K, d)
            c = (1.0 - s * s) * z_a + s * math.sqrt(1.0 - s * s) * rng.standard_normal((K, d))
            z = c[:, None, :] + s * rng.standard_normal((K, n, d))
            self.last_za = z_a
        self.last_z = z
        self.drawn.append(z.reshape(-1, d))
        u = self.mu[None, None, :] + z @ self.L.T
        out = np.stack([self.maps[j].values(u[:, :, j].ravel()).reshape(K, n) for j in range(d)], axis=-1)
        return out if batch else out[0]

    def keep(self, i: int) -> None:
        """Record batch member ``i`` as the accepted draw (for calibration)."""
        if self.last_z is not None and self.last_z.ndim == 3:
            self.last_z = self.last_z[i]
            self.last_za = None if self.last_za is None else self.last_za[i]


def hierarchical_offsets(keys: list[tuple], b0: np.ndarray, kappa: float) -> np.ndarray:
    """Leave-one-out means of ``b0`` per nested key, each level shrunk towards its parent.

    ``keys[i]`` is a tuple of levels for row i, e.g. ``(quantity, subject_class)``: the offset of a
    row is the mean of the other rows of its (quantity, class), shrunk by ``kappa`` pseudo-rows
    towards the mean of its quantity, itself shrunk towards the group mean. A row never enters
    its own offset, so an attacker who knows the typical value of a class learns nothing the
    distractors do not share.
    """
    b0 = np.asarray(b0, float)
    one = b0.ndim == 1
    b0 = b0[:, None] if one else b0
    n = len(keys)
    tot = b0.sum(axis=0)
    out = np.zeros_like(b0)
    depth = max((len(k) for k in keys), default=0)
    sums: list[dict] = []
    for lv in range(1, depth + 1):
        acc: dict = defaultdict(lambda: [np.zeros(b0.shape[1]), 0])
        for i, k in enumerate(keys):
            a = acc[k[:lv]]
            a[0] = a[0] + b0[i]
            a[1] += 1
        sums.append(acc)
    for i, k in enumerate(keys):
        m = (tot - b0[i]) / max(n - 1, 1)
        for lv in range(1, len(k) + 1):
            s_, c_ = sums[lv - 1][k[:lv]]
            m = ((s_ - b0[i]) + kappa * m) / (c_ - 1 + kappa)
        out[i] = m
    return out[:, 0] if one else out


# ------------------------------------------------------------------------------ plans

@dataclass
class RowPlan:
    spec: OptionSpec
    group: str = ""
    letter: str = "A"
    fixed: tuple = ()
    answer_is_fixed: bool = False
    donor: str | None = None
    share_with: str | None = None  # another row whose candidate set this row reuses
    evidence: dict = field(default_factory=dict)

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
    quantity of the same subject (camera, or the same noun phrase) over the same window (to the
    millisecond), and the same answer string."""
    o = spec.obs
    window = None if o.window_s is None else round(float(o.window_s), 3)
    subject = " ".join(str(o.subject or "").lower().split())
    return (spec.task, spec.source, o.quantity, subject, window, o.premise_text, spec.detail)


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
    return (o.quantity, o.subject_class == "camera", o.window_s is None)


def recorded_decimals(values, max_decimals: int) -> int:
    """The decimals a field of a group's answers is recorded with: the fewest that represent at
    least half of the values exactly (Waymo box heights are recorded to the centimetre where
    lengths have millimetres). Distractors printed finer than the answers would mark the answer."""
    v = np.asarray(values, dtype=float)
    for d in range(max_decimals + 1):
        if np.mean(np.abs(np.round(v, d) - v) > 1e-9) < 0.5:
            return d
    return max_decimals


def _group_key(spec: OptionSpec) -> str:
    o = spec.obs
    if spec.kind == "scalar":  # questions at an instant and over an interval are told apart
        form = "instant" if spec.obs.time_start is not None and spec.obs.time_start == spec.obs.time_end else "interval"
        return f"{spec.task}|{spec.source}|{spec.unit}|{form}"
    if spec.kind == "angle":
        return f"{spec.task}|{spec.source}|{o.quantity}"
    if spec.kind == "pose":
        return f"{spec.task}|{spec.source}|pose"
    return f"{spec.task}|{spec.source}|{spec.kind}"


def _mid_time(spec: OptionSpec) -> float:
    """When in the video the question asks (the middle of its window): a covariate, since what a
    camera does depends on the moment of the recording."""
    o = spec.obs
    if o.time_start is None or o.time_end is None:
        return float("nan")
    return 0.5 * (o.time_start + o.time_end)


def _log_window(spec: OptionSpec) -> float:
    w = spec.obs.window_s
    return math.log(w) if w and w > 0 else float("nan")


class Stage:
    """Plans and builds the options of a set of accepted rows (see the module docstring)."""

    def __init__(self, records: list[dict], *, iface: Interface, seed: int = 0, extras: dict | None = None):
        self.records = records
        self.seed = int(seed)
        self.iface = iface
        self.params = iface.options
        self.model = self.params["model"]
        extras = extras or {}
        self.plans: list[RowPlan] = []
        for i, r in enumerate(records):
            rid = str(r.get("ReSTI ID") or r.get("Legacy Row Key") or i)
            self.plans.append(RowPlan(spec_of(r, rid, extras.get(rid), iface=iface)))
        if len({p.rid for p in self.plans}) != len(self.plans):
            dup = [k for k, n in Counter(p.rid for p in self.plans).items() if n > 1]
            raise InputError(f"row ids are not unique, e.g. {dup[:3]}", field="ReSTI ID")
        self.by_id = {p.rid: p for p in self.plans}
        self.groups: dict[str, GroupModel] = {}
        self._cur = None
        self._last = None
        self.s_factors: dict = {}
        self._plan()

    # -------------------------------------------------------------------- planning
    def _plan(self) -> None:
        by_group: dict[str, list[RowPlan]] = defaultdict(list)
        for p in self.plans:
            p.group = _group_key(p.spec)
            by_group[p.group].append(p)
        # a group too small to model pools with the other sources of its task (offsets per source)
        small = int(self.model.get("min_group", 8))
        for g in sorted(by_group):
            ps = by_group[g]
            if ps[0].spec.kind in ("scalar", "angle") and len(ps) < small:
                pooled = f"{ps[0].spec.task}|*|{ps[0].spec.unit}|{g.rsplit('|', 1)[-1]}"
                for p in ps:
                    p.group = pooled
                by_group[pooled].extend(ps)
                del by_group[g]
        for g, ps in sorted(by_group.items()):
            kind = ps[0].spec.kind
            fit = getattr(self, f"_fit_{kind}", None)
            self.groups[g] = fit(g, ps) if fit else GroupModel(kind)
        self._share_sets()
        for task in sorted({p.spec.task for p in self.plans}):
            ids = {p.rid: set(LETTERS) for p in self.plans if p.spec.task == task}
            sched = constrained_schedule(ids, list(LETTERS), seed=self.seed, group=f"letters|{task}")
            for rid, L in sched.items():
                self.by_id[rid].letter = L

    def _share_sets(self) -> None:
        """Rows that ask the same thing and have the same answer share one candidate set: the
        camera videos of one recording (their ego answers are equal), the same object asked in two
        scenes. Otherwise the answer, repeated with fresh distractors, is the one value two rows'
        options have in common."""
        first: dict[tuple, str] = {}
        for p in self.plans:
            key = share_key(p.spec)
            if key in first and p.spec.kind != "label":
                p.share_with = first[key]
            else:
                first.setdefault(key, p.rid)

    # -------------------------------------------------------------------- group fits
    def _fit_scalar(self, g: str, ps: list[RowPlan]) -> GroupModel:
        vals = np.array([p.spec.value.value for p in ps], float)
        eps = min(p.spec.ulp for p in ps)
        moving = [p for p, v in zip(ps, vals) if v > 0]
        info: dict = {"eps": eps, "offset": {}}
        if moving:
            x = np.array([p.spec.value.value for p in moving], float)
            b0 = np.log(x + eps)
            ow = np.array([_log_window(p.spec) if p.spec.obs.quantity in WINDOWED else 0.0 for p in moving])
            ow = np.where(np.isfinite(ow), ow, 0.0)
            keys = [(p.spec.source, p.spec.obs.quantity, p.spec.obs.subject_class) for p in moving]
            oc = hierarchical_offsets(keys, b0 - ow, self.model["class_shrink"])
            off = ow + oc
            for p, o in zip(moving, off):
                info["offset"][p.rid] = float(o)
            # smallest bandwidth: half the separation floor (a population concentrated below the floor
            # is modelled at the floor's resolution, where five separated candidates can be typical)
            H = np.array([0.5 * max(scalar_gap(p.spec, self.params, p.spec.value.value),
                                    self.params["separation"]["scalar"]["min_rel_gap"] * p.spec.value.value)
                          / (p.spec.value.value + eps) for p in moving])
            W = np.array([[_log_window(p.spec), _mid_time(p.spec)] for p in moving])
            W = W[:, np.isfinite(W).all(axis=0)] if len(W) else None
            fm = FieldModel.fit([p.rid for p in moving], b0 - off, H, W, knn=self.model["knn"],
                                shrink=self.model["copula_shrink"], min_rows=int(self.model["min_group"]))
        else:  # only exact zeros: distractors from a weak prior about twenty printed units
            fm = FieldModel.fit([], None, None, None, knn=self.model["knn"], shrink=self.model["copula_shrink"],
                                min_rows=int(self.model["min_group"]), prior_sd=1.0,
                                prior_center=[math.log(20 * eps + eps)])
        gm_reuse = GroupModel("scalar", None, {})
        self._fit_reuse(gm_reuse, ps)
        info.update(gm_reuse.info)
        carriers: set = set()
        for sub in sorted({slot_subgroup(p.spec) for p in ps}, key=str):
            zs = [p.rid for p in ps if p.spec.value.value <= 0 and slot_subgroup(p.spec) == sub]
            ms = [p.rid for p in moving if slot_subgroup(p.spec) == sub]
            carriers |= _slot_rows(zs, ms, self.model["zero_slot_ratio"], seed=self.seed, group=f"{g}|{sub}")
        for p in ps:
            if p.rid in carriers:  # the zero printed like the row's own answer
                zero = V.format_scalar(0.0, p.spec.unit, p.spec.decimals)
                p.fixed = (zero if p.spec.value.value > 0 else p.spec.detail,)
                p.answer_is_fixed = p.spec.value.value <= 0
        return GroupModel("scalar", fm, info)

    def _fit_angle(self, g: str, ps: list[RowPlan]) -> GroupModel:
        th = np.array([p.spec.value.value for p in ps], float)
        b = np.arctanh(np.clip(th / 180.0, -1 + 1e-12, 1 - 1e-12))
        H = np.array([0.5 * angle_gap(p.spec, self.params) / 180.0 / max(1e-9, 1 - (t / 180.0) ** 2)
                      for p, t in zip(ps, th)])
        W = np.array([[_log_window(p.spec)] for p in ps])
        W = W if np.isfinite(W).all() else None
        fm = FieldModel.fit([p.rid for p in ps], b, H, W, knn=self.model["knn"], shrink=self.model["copula_shrink"],
                            min_rows=int(self.model["min_group"]), prior_sd=0.3)
        gm = GroupModel("angle", fm)
        self._window_slot(g, gm, ps, th, angle_gap(ps[0].spec, self.params))
        return gm

    def _window_slot(self, g: str, gm: GroupModel, ps: list[RowPlan], values: np.ndarray, gap: float) -> None:
        """A dense window of answers (:func:`dense_window`) is a slot: every row whose answer lies in
        it and ``zero_slot_ratio`` times as many others carry one candidate from it (in the others,
        a value drawn among the window's answers); no other candidate falls in it. Where the window
        holds more than a fifth of the answers, the slot candidate is the answer in more than one
        carrier in five: a leak no option set can remove, named by :mod:`resti_lib.options.structural`."""
        win = dense_window(values, gap)
        if win is None:
            return
        lo, hi, _ = win
        inside = [p.rid for p, x in zip(ps, values) if lo - 1e-9 <= x <= hi + 1e-9]
        others = [p.rid for p in ps if p.rid not in set(inside)]
        carriers = _slot_rows(inside, others, self.model["zero_slot_ratio"], seed=self.seed, group=f"{g}|window")
        gm.info["window"] = (lo, hi)
        gm.info["window_values"] = {p.rid: float(x) for p, x in zip(ps, values) if p.rid in set(inside)}
        for p in ps:
            if p.rid in set(inside):
                p.evidence["window_slot"] = "answer"
            elif p.rid in carriers:
                p.evidence["window_slot"] = "drawn"

    def _fit_trajectory(self, g: str, ps: list[RowPlan]) -> GroupModel:
        moving = [p for p in ps if p.spec.value.segments and p.spec.value.total_distance > 0]
        none = [p.rid for p in ps if not p.spec.value.segments]
        info: dict = {"offset": {}}
        fm = None
        if moving:
            x = np.array([p.spec.value.total_distance for p in moving])
            ow = np.array([_log_window(p.spec) for p in moving])
            ow = np.where(np.isfinite(ow), ow, 0.0)
            for p, o in zip(moving, ow):
                info["offset"][p.rid] = float(o)
            H = 0.5 * self.params["separation"]["trajectory"]["min_rel_gap"] * x / (x + 0.1)
            W = np.array([[_log_window(p.spec)] for p in moving])
            W = W if np.isfinite(W).all() else None
            fm = FieldModel.fit([p.rid for p in moving], np.log(x + 0.1) - ow, H, W, knn=self.model["knn"],
                                shrink=self.model["copula_shrink"], min_rows=int(self.model["min_group"]))
        else:  # only "no significant movement": single moves of a few metres per second of window
            fm = FieldModel.fit([], None, None, None, knn=self.model["knn"], shrink=self.model["copula_shrink"],
                                min_rows=int(self.model["min_group"]), prior_sd=1.0, prior_center=[math.log(3.0)])
        carriers = _slot_rows(none, [p.rid for p in moving], self.model["zero_slot_ratio"], seed=self.seed, group=g)
        donors = sorted(p.rid for p in moving)
        for p in ps:
            if p.rid in carriers:
                p.fixed = (V.NO_MOVEMENT,)
                p.answer_is_fixed = not p.spec.value.segments
                if p.answer_is_fixed and donors:
                    p.donor = donors[int(row_rng(self.seed, p.rid, "donor").integers(len(donors)))]
        return GroupModel("trajectory", fm, info)

    def _fit_box(self, g: str, ps: list[RowPlan]) -> GroupModel:
        kp = self.params["kinds"]["box"]
        src = ps[0].spec.source
        mode = per_source(kp["centre"], src, "projective")
        up_axis = per_source(kp["up_axis"], src, None)
        info: dict = {"mode": {}, "R0": {}, "yaw0": {}, "class_off": {}, "up_axis": up_axis}
        cs = np.array([p.spec.value.center for p in ps], float)
        ds = np.array([p.spec.value.lwh for p in ps], float)
        info["decimals"] = {**{f"c{j}": recorded_decimals(cs[:, j], 3) for j in range(3)},
                            **{f"d{j}": recorded_decimals(ds[:, j], 3) for j in range(3)}}
        rows_f, rows_h = [], []
        lds = []
        for p in ps:
            v: V.Box = p.spec.value
            if v.R is None:
                raise InputError("a grounding answer without a rotation has no option builder", row=p.rid,
                                 field="Answer Detail")
            c = np.array(v.center, float)
            m = mode if c[2] > 0 else "cartesian"
            info["mode"][p.rid] = m
            rng = row_rng(self.seed, p.rid, "preimage")
            R0 = rotation_preimage(v.R, 6, rng, accept=lambda Q, h=v.heading: h is None or
                                   round(V.box_heading(Q), 2) == round(h, 2))
            info["R0"][p.rid] = R0
            lds.append(np.log(np.maximum(np.array(v.lwh, float), 1e-4)))
        lds = np.array(lds)
        coff = hierarchical_offsets([(p.spec.obs.subject_class,) for p in ps], lds, self.model["class_shrink"])
        cut = None
        if up_axis is not None:
            yaws = np.array([box_yaw(info["R0"][p.rid], up_axis) for p in ps])
            cut = circular_cut(yaws)
            info["cut"] = cut
        # centre fields use one mode per group (rows behind the camera: cartesian in their own model)
        for i, p in enumerate(ps):
            v = p.spec.value
            c = np.array(v.center, float)
            m = info["mode"][p.rid]
            f = centre_fields(c, mode) if m == mode else np.full(3, np.nan)
            hc = centre_half_cells(c, mode, 10.0 ** -3)
            dd = np.maximum(np.array(v.lwh, float), 1e-4)
            hd = 0.5e-3 / dd
            info["class_off"][p.rid] = coff[i]
            row_f = [*f, *(lds[i] - coff[i])]
            row_h = [*hc, *hd]
            if up_axis is not None:
                y = box_yaw(info["R0"][p.rid], up_axis)
                info["yaw0"][p.rid] = y
                row_f.append(float(on_cut_line(y, cut)))
                row_h.append(0.005)
            rows_f.append(row_f)
            rows_h.append(row_h)
        F, Hh = np.array(rows_f, float), np.array(rows_h, float)
        ok = np.isfinite(F).all(axis=1)
        members = [p.rid for p, k in zip(ps, ok) if k]
        if not members:
            raise InputError(f"{g}: no box in front of the camera", field="Answer Detail")
        fm = FieldModel.fit(members, F[ok], Hh[ok], None, knn=self.model["knn"], shrink=self.model["copula_shrink"],
                            min_rows=int(self.model["min_group"]), prior_sd=[0.1, 0.1, 0.3, 0.3, 0.3, 0.3, 30.0])
        info["group_mode"] = mode
        # rows behind the camera: draw like the nearest member in the field model (rare; recorded)
        info["proxy"] = {p.rid: members[0] for p, k in zip(ps, ok) if not k}
        return GroupModel("box", fm, info)

    def _fit_pose(self, g: str, ps: list[RowPlan]) -> GroupModel:
        """Poses as a motion from the premise: the translation in the premise's horizontal heading
        frame (forward, left, up; a rate over the window for vehicles) and the rotation vector of the
        relative rotation ``R R_p^T``, jointly. A question without a printed premise (the reference
        camera as the identity) has the identity as premise."""
        kp = self.params["kinds"]["pose"]
        src = ps[0].spec.source
        up = np.asarray(kp["world_up"], float)
        rate = bool(per_source(kp["rate"], src, False))
        info: dict = {"rate": rate, "R0": {}, "frame": {}, "win": {}}
        relative = all(p.spec.obs.premise_text is None for p in ps)
        info["relative"] = relative
        ts = np.array([p.spec.value.t for p in ps], float)
        info["t_decimals"] = [recorded_decimals(ts[:, j], ps[0].spec.decimals) for j in range(3)]
        F, Hh, W = [], [], []
        for p in ps:
            v: V.Pose = p.spec.value
            o = p.spec.obs
            R0 = rotation_preimage(v.R, v.decimals, row_rng(self.seed, p.rid, "preimage"))
            info["R0"][p.rid] = R0
            win = o.window_s if (o.window_s and o.window_s > 0) else 1.0
            info["win"][p.rid] = win
            scale = win if rate else 1.0
            if o.premise is not None and o.premise_text is not None:
                Rp, tp = nearest_rotation(o.premise[:3, :3]), np.array(o.premise[:3, 3], float)
                Hf = horizontal_frame(Rp, up, 2)
            else:  # relative poses: the reference camera is the identity
                Rp, tp, Hf = np.eye(3), np.zeros(3), np.eye(3)
            info["frame"][p.rid] = (Rp, tp, Hf)
            h_t = 0.5 * 10.0 ** -v.decimals
            if not relative:
                d = Hf.T @ (np.array(v.t, float) - tp) / scale
                r = Rotation.from_matrix(R0 @ Rp.T).as_rotvec()
                F.append([*d, *r])
                Hh.append([h_t / scale] * 3 + [h_t] * 3)
            W.append([_log_window(p.spec)])
        if relative:  # cameras looking at a desk: drawn around the gaze point they share
            depths = np.array([gaze_depth(info["R0"][p.rid], p.spec.value.t) for p in ps])
            G = np.array([0.0, 0.0, float(np.nanmedian(depths)) if np.isfinite(depths).any() else 0.5])
            info["gaze"] = G
            yaws = []
            for p in ps:
                f = gaze_fields(info["R0"][p.rid], p.spec.value.t, G)
                F.append(list(f))
                Hh.append([0.5 * 10.0 ** -p.spec.value.decimals] * 3 + [0.3, 0.3, 0.3])
                yaws.append(f[5])
            cut = circular_cut(yaws)
            info["cut"] = cut
            for row in F:
                row[5] = float(on_cut_line(row[5], cut))
        F, Hh, W = np.array(F, float), np.array(Hh, float), np.array(W, float)
        fm = FieldModel.fit([p.rid for p in ps], F, Hh, W if np.isfinite(W).all() else None,
                            knn=self.model["knn"], shrink=self.model["copula_shrink"],
                            min_rows=int(self.model["min_group"]),
                            prior_sd=([0.2, 0.2, 0.2, 5.0, 5.0, 10.0] if relative else
                                      [0.5, 0.5, 0.2, 0.1, 0.1, 0.3] if not rate else [3.0, 1.0, 0.2, 0.1, 0.1, 0.3]))
        return GroupModel("pose", fm, info)

    # -------------------------------------------------------------------- building
    def _draw(self, gm: GroupModel, rid: str, cells: list, s: float, rng, bounds: list | None = None,
              **kw) -> np.ndarray:
        """Draw through the row's prepared model (kept for the row being built only: O(G) memory)."""
        key = (id(gm), rid, None if bounds is None else tuple(map(tuple, bounds)))
        if self._cur is None or self._cur[0] != key:
            self._cur = (key, gm.fields.prepare(rid, bounds))
        rd = self._cur[1]
        out = rd.draw(cells, s, rng, **kw)
        self._last = rd
        return out

    def calibrate(self, *, sample: int = 60, rounds: int = 2) -> dict:
        """Per group, the within-set spread under which the kept candidate sets are as spread around
        their answer as the model's unconstrained sets are.

        Separation and plausibility constraints reject sets whose candidates crowd each other, so the
        sets kept are wider than the model's; their distractors would then be less typical than
        the answer. Each round builds a seeded sample of the group's rows and scales the spread ``s``
        by the root mean square distance from the answer (standardised scores) of everything drawn
        for those rows over that of the distractors kept — paired over the same answers, so their
        own spread cancels. Returns group -> spread factor.
        """
        out = {}
        by_group: dict[str, list[RowPlan]] = defaultdict(list)
        for p in self.plans:
            if p.spec.kind != "label" and not p.answer_is_fixed and p.share_with is None:
                by_group[p.group].append(p)
        for g, ps in sorted(by_group.items()):
            gm = self.groups[g]
            if gm.fields is None or len(ps) < 20:
                continue
            rng = np.random.default_rng(stable_seed(self.seed, "calibrate", g))
            pick = [ps[int(i)] for i in sorted(rng.permutation(len(ps))[:sample])]
            factor = 1.0
            for _ in range(rounds):
                gm.info["s_factor"] = factor
                drawn, kept = [], []
                for p in pick:
                    saved = dict(p.evidence)
                    try:
                        self._build_row(p, None, {}, calibrating=True)
                    except OptionError:
                        continue
                    finally:
                        p.evidence = saved
                    rd = self._last
                    if rd is not None and rd.last_za is not None and rd.drawn:
                        za = np.asarray(rd.last_za).reshape(1, -1)
                        drawn.append(((np.concatenate(rd.drawn) - za) ** 2).ravel())
                        kept.append(((np.asarray(rd.last_z).reshape(-1, za.shape[1]) - za) ** 2).ravel())
                if len(kept) < 10:
                    break
                ratio = math.sqrt(float(np.mean(np.concatenate(drawn))) / max(float(np.mean(np.concatenate(kept))),
                                                                              1e-12))
                factor = float(np.clip(factor * ratio, 0.5, 1.0))
            gm.info["s_factor"] = factor
            out[g] = factor
        return out

    def build(self, progress: bool = False, on_failure: str = "raise") -> tuple[list[dict], pd.DataFrame, dict]:
        """Build every row; returns (rows, evidence, failed). ``on_failure``: ``raise`` stops at a
        row whose options cannot meet the constraints; ``skip`` leaves its candidates empty and
        names it in ``failed`` (rid -> problem), for the caller to exclude."""
        built: dict[str, list[str]] = {}
        out, ev = [], []
        failed: dict[str, str] = {}
        self.s_factors = self.calibrate()
        it = self.plans
        if progress:
            from tqdm.auto import tqdm

            it = tqdm(self.plans, desc="options", unit="row", leave=False)
        reveals = self._reveals()
        for p, r in zip(it, self.records):
            if p.share_with is not None and p.share_with in built:
                strings = list(built[p.share_with])
                p.evidence.update({"shared_with": p.share_with})
            else:
                try:
                    strings = self._build_row(p, r, reveals)
                except OptionError as e:
                    if on_failure != "skip":
                        raise
                    failed[p.rid] = str(e)
                    out.append(dict(r))
                    continue
                built[p.rid] = strings
            cands, letter = self._letter(p, strings)
            new = dict(r)
            new["Candidates"] = cands
            new["Answer"] = letter
            out.append(new)
            ev.append({"rid": p.rid, "task": p.spec.task, "source": p.spec.source, "kind": p.spec.kind,
                       "group": p.group, "letter": letter, "rank": _signed_rank(p, strings),
                       "fixed": ",".join(p.fixed), "answer_is_fixed": p.answer_is_fixed,
                       "s_factor": self.groups[p.group].info.get("s_factor", 1.0) if p.group in self.groups else None,
                       **p.evidence})
        return out, pd.DataFrame(ev), failed

    def _letter(self, p: RowPlan, strings: list[str]) -> tuple[dict, str]:
        """The answer at its scheduled letter; the others in a seeded random order."""
        ans = p.spec.detail
        others = [s for s in strings if s != ans]
        rng = row_rng(self.seed, p.rid, "letters")
        others = [others[int(i)] for i in rng.permutation(len(others))]
        cands = {}
        for L in LETTERS:
            cands[L] = ans if L == p.letter else others.pop(0)
        return cands, p.letter

    def _build_row(self, p: RowPlan, record: dict | None, reveals: dict, *, calibrating: bool = False) -> list[str]:
        kind = p.spec.kind
        if kind == "label":
            return self._build_label(p, record)
        gm = self.groups[p.group]
        builder = getattr(self, f"_build_{kind}")
        s0 = float(self.model["s"]) * gm.info.get("s_factor", 1.0)
        tries = int(self.model["max_tries"]) // (4 if calibrating else 1)
        if kind in ("scalar", "angle"):
            tries = max(2, tries // 16)  # each try is a batch of 32 sets
        rng = row_rng(self.seed, p.rid, "calibrate" if calibrating else "options")
        last = "no candidates drawn"
        # widening steps: a wider spread, then (relaxed) same-video premises no longer imposed
        tiers = ((s0, True), (min(0.8, 1.5 * s0), True), (min(0.8, 1.5 * s0), False), (0.9, False))
        for tier, (s, strict) in enumerate(tiers):
            for attempt in range(tries):
                try:
                    strings = builder(p, gm, s, rng, strict, reveals)
                except _Reject as e:
                    last = str(e)
                    continue
                p.evidence.update({"s": s, "tries": tier * tries + attempt + 1, "strict": strict,
                                   "widened": tier > 0})
                return strings
        raise OptionError(f"{p.rid} ({p.spec.task}, {p.spec.source}): no options under the constraints ({last})")

    # -- one-dimensional kinds (drawn in batches, checked vectorised, the first valid set kept)
    def _first_valid_1d(self, pv: np.ndarray, ok: np.ndarray, gap_of, rel: float = 0.0, circular: bool = False
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

    def _build_scalar(self, p, gm, s, rng, strict, reveals):
        spec = p.spec
        v: V.Scalar = spec.value
        eps = gm.info["eps"]
        _, hi_b = scalar_bounds(spec, self.params)
        fixed = list(p.fixed)
        n_cont = 5 - len(fixed)
        n_draw = n_cont if p.answer_is_fixed else n_cont - 1
        K = 32
        if p.answer_is_fixed:
            rid = p.rid if p.rid in gm.fields.index else None
            off = gm.info["offset"][rid] if rid is not None else self._mean_offset(gm, spec)
        else:
            off = gm.info["offset"][p.rid]
        # what the row can print: above zero (half a printed unit), below the physical bound
        bounds = [(math.log(0.5 * spec.ulp + eps) - off, math.log(hi_b + eps) - off if math.isfinite(hi_b) else None)]
        if p.answer_is_fixed:
            b = self._draw(gm, rid, [], s, rng, n=n_draw, prior=True, batch=K, bounds=bounds)[:, :, 0]
        else:
            x = v.value
            cell = (math.log(max(x - 0.5 * spec.ulp, 0.0) + eps) - off, math.log(x + 0.5 * spec.ulp + eps) - off)
            b = self._draw(gm, p.rid, [cell], s, rng, n=n_draw, batch=K, bounds=bounds)[:, :, 0]
        dec = spec.decimals
        xs = self._reuse(gm, p, np.exp(b + off) - eps, rng)
        pv = np.round(xs, dec)
        extra = [float(V.parse(t).value) for t in fixed] + ([] if p.answer_is_fixed else [v.value])
        allv = np.column_stack([pv, np.tile(extra, (K, 1))]) if extra else pv
        ok = (pv > 0).all(axis=1) & (pv <= hi_b + 1e-12).all(axis=1)
        sep = self.params["separation"]["scalar"]
        per_unit = v.si_per_unit
        ulp = spec.ulp

        def gap_of(upper):
            tol = 0.5 * ulp + (spec.rule.abs_tol + spec.rule.rel_tol * upper * per_unit) / per_unit
            return np.maximum(sep["min_gap_ulps"] * ulp, tol)

        for i in self._first_valid_1d(allv, ok, gap_of, rel=sep["min_rel_gap"]):
            strings = [V.format_scalar(float(t), v.unit, dec) for t in xs[i]]
            alls = strings + fixed + ([] if p.answer_is_fixed else [spec.detail])
            try:
                self._check_1d(spec, [float(V.parse(t).value) for t in alls], alls,
                               gap=lambda t: scalar_gap(spec, self.params, t), rel=sep["min_rel_gap"])
            except _Reject:
                continue
            if self._last is not None:
                self._last.keep(i)
            return alls
        raise _Reject("no drawn set met the separation and plausibility constraints")

    def _fit_reuse(self, gm: GroupModel, ps: list) -> None:
        """Answers that recur in other recordings (the same object asked in two scenes): the share of
        rows whose answer is the answer of a row of another source sequence, and those values. A
        distractor then takes such a value as often (:meth:`_reuse`), or the recurring answer would
        be the one candidate another row's answer vouches for."""
        seqs: dict[float, set] = defaultdict(set)
        if not all(p.spec.obs.quantity in OBJECT_SIZES for p in ps):
            return  # rates of a camera coincide only through coarse printing, which the draws share
        for p in ps:
            if p.spec.value.value > 0:
                seqs[round(float(p.spec.value.value), 9)].add(p.spec.obs.sequence)
        moving = [p for p in ps if p.spec.value.value > 0]
        if not moving:
            return
        reused = sum(1 for p in moving if len(seqs[round(float(p.spec.value.value), 9)] - {p.spec.obs.sequence}) > 0)
        rate = reused / len(moving)
        if rate < 0.05:
            return
        gm.info["reuse_rate"] = rate
        gm.info["reuse_values"] = np.array(sorted(seqs))
        gm.info["reuse_seqs"] = seqs

    def _reuse(self, gm: GroupModel, p: RowPlan, xs: np.ndarray, rng) -> np.ndarray:
        """Distractors take the answers of other recordings as often as the answers do
        (:meth:`_fit_reuse`): drawn values that already print as such an answer count; of the rest,
        enough become the nearest such answer to make up the group's reuse rate."""
        rate = gm.info.get("reuse_rate")
        if not rate or xs.size == 0:
            return xs
        pool = gm.info["reuse_values"]
        seqs = gm.info["reuse_seqs"]
        own = p.spec.obs.sequence
        if len(pool) < 2:
            return xs
        j = np.clip(np.searchsorted(pool, xs), 1, len(pool) - 1)
        near = np.where(np.abs(pool[j - 1] - xs) <= np.abs(pool[j] - xs), pool[j - 1], pool[j])
        # a value is usable when another recording has it (one lookup per distinct value)
        vals, at = np.unique(near, return_inverse=True)
        other = np.array([len(q) > (own in q) for q in (seqs[round(float(x), 9)] for x in vals)], dtype=bool)
        usable = other[at].reshape(near.shape)
        already = usable & (np.abs(np.round(xs, p.spec.decimals) - near) < 1e-9)
        natural = float(already.mean())
        if natural >= rate:
            return xs
        extra = (rate - natural) / max(1e-9, 1.0 - natural)
        snap = ~already & usable & (rng.random(xs.shape) < extra)
        return np.where(snap, near, xs)

    def _mean_offset(self, gm, spec) -> float:
        q = spec.obs.quantity
        if q in WINDOWED:
            lw = _log_window(spec)
            return lw if math.isfinite(lw) else 0.0
        return float(np.mean(list(gm.info["offset"].values()))) if gm.info["offset"] else 0.0

    def _check_1d(self, spec, values, strings, *, gap, rel: float = 0.0, circular: bool = False):
        if len(set(strings)) != 5 or len({V.parse(t).key() for t in strings}) != 5:
            raise _Reject("two candidates print the same value")
        xs = sorted(values)
        for a, b in zip(xs, xs[1:]):
            if b - a < gap(b) - 1e-12:
                raise _Reject("two candidates closer than the separation floor")
            if rel > 0 and (b - a) < rel * max(abs(b), 1e-12):
                raise _Reject("two candidates closer than the relative gap")
        if circular and (xs[0] + 360.0 - xs[-1]) < gap(xs[0]) - 1e-12:
            raise _Reject("two candidates closer than the separation floor across ±180")

    def _build_angle(self, p, gm, s, rng, strict, reveals):
        spec = p.spec
        v: V.Scalar = spec.value
        x = v.value
        h = 0.5 * spec.ulp

        def b(t):
            return float(np.arctanh(np.clip(t / 180.0, -1 + 1e-12, 1 - 1e-12)))

        cell = (b(max(x - h, -180.0)), b(min(x + h, 180.0 - 1e-9)))
        K = 32
        slot = p.evidence.get("window_slot")
        n_model = 3 if slot == "drawn" else 4
        z = self._draw(gm, p.rid, [cell], s, rng, n=n_model, batch=K)[:, :, 0]
        th = 180.0 * np.tanh(z)
        if slot == "drawn":  # one candidate from the window, drawn among the other rows' answers there
            lo, hi = gm.info["window"]
            pool = np.array([v for r, v in gm.info["window_values"].items() if r != p.rid])
            w = pool[rng.integers(len(pool), size=K)] + rng.uniform(-0.5, 0.5, K) * max(hi - lo, spec.ulp)
            th = np.column_stack([th, np.clip(w, lo, hi)])
        pv = np.round(V.wrap_degrees(th), spec.decimals)
        pv = np.where(pv >= 180.0, -180.0, pv)
        allv = np.column_stack([pv, np.full(K, x)])
        g = angle_gap(spec, self.params)
        ok = np.ones(K, bool)
        if "window" in gm.info:  # only the slot candidate (the answer, or the drawn one) in the window
            lo, hi = gm.info["window"]
            cols = pv if slot != "drawn" else pv[:, :n_model]
            ok &= ~((cols >= lo - 1e-9) & (cols <= hi + 1e-9)).any(axis=1)
        for i in self._first_valid_1d(allv, ok, lambda u: np.full(u.shape, g), circular=True):
            strings = [V.format_angle(float(t), spec.decimals) for t in th[i]] + [spec.detail]
            try:
                self._check_1d(spec, [float(V.parse(t).value) for t in strings], strings, gap=lambda _: g,
                               circular=True)
            except _Reject:
                continue
            if self._last is not None:
                self._last.keep(i)
            return strings
        raise _Reject("no drawn set met the separation constraints")

    def _build_trajectory(self, p, gm, s, rng, strict, reveals):
        spec = p.spec
        v: V.Trajectory = spec.value
        fixed = list(p.fixed)
        n_cont = 5 - len(fixed)
        pars = {"split_sigma": 0.25, "turn_sigma_deg": 15.0}
        lo_b, hi_b = scalar_bounds(spec, self.params)
        if p.answer_is_fixed:
            template = self.by_id[p.donor].spec.value if p.donor else V.Trajectory((("move", 1.0),), "")
            fmt = _traj_formatter(template, pars, rng, centred=False)
            off = _log_window(spec)
            off = off if math.isfinite(off) else 0.0
            b = self._draw(gm, p.donor if p.donor in gm.fields.index else None, [], s, rng, n=n_cont, prior=True)[:, 0]
            totals = np.exp(b + off) - 0.1
            strings = [fmt(float(t)) for t in totals]
            alls = strings + fixed
            values = [V.parse(t).total_distance for t in strings]
        else:
            if not v.segments or v.total_distance <= 0:
                raise OptionError(f"trajectory {spec.detail!r} has no movement to vary")
            fmt = _traj_formatter(v, pars, rng, centred=True)
            off = gm.info["offset"][p.rid]
            x = v.total_distance
            cell = (math.log(max(x - 0.05, 0.0) + 0.1) - off, math.log(x + 0.05 + 0.1) - off)
            b = self._draw(gm, p.rid, [cell], s, rng, n=n_cont - 1)[:, 0]
            totals = np.exp(b + off) - 0.1
            strings = [fmt(float(t)) for t in totals]
            structures = {V.parse(t).structure for t in strings}
            if structures != {v.structure}:
                raise _Reject("a distractor lost the answer's structure")
            alls = strings + fixed + [spec.detail]
            values = [V.parse(t).total_distance for t in strings] + [x]
        if any(t <= 0 for t in values) or any(t > hi_b for t in values):
            raise _Reject("a distractor distance is not physically possible")
        if len(set(alls)) != 5:
            raise _Reject("two candidates print the same phrase")
        rel = self.params["separation"]["trajectory"]["min_rel_gap"]
        xs = sorted(values)
        if any((b2 - a) < rel * b2 for a, b2 in zip(xs, xs[1:])):
            raise _Reject("two totals closer than the relative gap")
        return alls

    # -- structured kinds
    def _build_box(self, p, gm, s, rng, strict, reveals):
        spec = p.spec
        v: V.Box = spec.value
        info = gm.info
        R0 = info["R0"][p.rid]
        c0, d0 = np.array(v.center, float), np.array(v.lwh, float)
        rid = p.rid if p.rid in gm.fields.index else info["proxy"][p.rid]
        mode = info["group_mode"] if rid == p.rid else "cartesian"
        up_axis = info["up_axis"]
        coff = info["class_off"][p.rid]
        if rid == p.rid:
            f0 = centre_fields(c0, mode)
            hc = centre_half_cells(c0, mode, 1e-3)
            cells = [(f0[j] - hc[j], f0[j] + hc[j]) for j in range(3)]
            ld = np.log(np.maximum(d0, 1e-4)) - coff
            hd = 0.5e-3 / np.maximum(d0, 1e-4)
            cells += [(ld[j] - hd[j], ld[j] + hd[j]) for j in range(3)]
            if up_axis is not None:
                y = float(on_cut_line(info["yaw0"][p.rid], info["cut"]))
                cells.append((y - 0.005, y + 0.005))
            B = self._draw(gm, p.rid, cells, s, rng, n=4)
            centres = np.array([centre_from_fields(b[:3], mode) for b in B])
        else:  # a centre behind the camera: exchangeable cartesian shifts
            B = self._draw(gm, rid, [], s, rng, n=4, prior=True)
            centres = c0 + rng.normal(0.0, 0.1 * max(1.0, np.linalg.norm(c0)), (4, 3))
        dims = np.exp(B[:, 3:6] + coff)
        if up_axis is not None:
            yaws = from_cut_line(B[:, 6], info["cut"])
            e = np.zeros(3)
            e[up_axis] = 1.0
            rots = [R0 @ rot(e, float(V.wrap_degrees(y - info["yaw0"][p.rid]))) for y in yaws]
        else:
            sig = np.radians(self.params["kinds"]["box"]["iso_sigma_deg"])
            Q = [Rotation.from_rotvec(rng.normal(0.0, sig, 3)).as_matrix() for _ in range(5)]
            rots = [R0 @ Q[4].T @ Q[i] for i in range(4)]
        dec = info["decimals"]
        centres = np.column_stack([np.round(centres[:, j], dec[f"c{j}"]) for j in range(3)])
        dims = np.column_stack([np.round(dims[:, j], dec[f"d{j}"]) for j in range(3)])
        strings = [V.format_box(centres[i], dims[i], rots[i]) for i in range(4)]
        parsed = [V.parse(t) for t in strings]
        self._check_boxes(spec, [*parsed, v])
        return strings + [spec.detail]

    def _check_boxes(self, spec, boxes):
        fl = box_floors(spec, self.params)
        pl = self.params["plausibility"]
        max_size = float(per_source(pl["max_size_m"], spec.source, math.inf))
        dmin = float(per_source(pl["min_depth_m"], spec.source, 0.0))
        dmax = float(per_source(pl["max_depth_m"], spec.source, math.inf))
        strings = [b.text for b in boxes]
        if len(set(strings)) != 5:
            raise _Reject("two boxes print the same")
        for b in boxes[:-1]:
            d = np.array(b.lwh)
            if (d <= 0).any() or (d > max_size).any():
                raise _Reject("a box size is not physically possible")
            depth = float(np.linalg.norm(b.center))
            if b.center[2] > 0 and not dmin <= b.center[2] <= dmax:
                raise _Reject("a box depth is not physically possible")
            if not np.isfinite(depth):
                raise _Reject("a box centre is not finite")
        for i in range(5):
            for j in range(i + 1, 5):
                if box_separation(boxes[i], boxes[j], fl) < 1.0:
                    raise _Reject("two boxes within the separation floors of each other")

    def _build_pose(self, p, gm, s, rng, strict, reveals):
        spec = p.spec
        v: V.Pose = spec.value
        info = gm.info
        R0, t0 = info["R0"][p.rid], np.array(v.t, float)
        win = info["win"][p.rid]
        scale = win if info["rate"] else 1.0
        h_t = 0.5 * 10.0 ** -v.decimals
        strings: list[str] = []
        fixed_reveals = list(reveals.get(p.rid, [])) if strict else []  # relaxed tiers draw them all
        n_draw = 4
        if fixed_reveals:
            pick = [fixed_reveals[int(i)] for i in rng.permutation(len(fixed_reveals))[:4]]
            strings += pick
            n_draw = 4 - len(pick)
        if n_draw and info["relative"]:
            G = info["gaze"]
            f0 = gaze_fields(R0, t0, G)
            f0[5] = float(on_cut_line(f0[5], info["cut"]))
            hh = [h_t] * 3 + [0.3, 0.3, 0.3]
            B = self._draw(gm, p.rid, [(f0[j] - hh[j], f0[j] + hh[j]) for j in range(6)], s, rng, n=n_draw)
            for b in B:
                b = np.array(b, float)
                b[5] = float(from_cut_line(b[5], info["cut"]))
                R, t = from_gaze_fields(b, G)
                T = np.eye(4)
                T[:3, :3] = R
                T[:3, 3] = [round(float(t[j]), info["t_decimals"][j]) for j in range(3)]
                strings.append(V.format_pose(T, v.decimals, compact=v.compact))
        elif n_draw:
            Rp, tp, Hf = info["frame"][p.rid]
            f0 = np.concatenate([Hf.T @ (t0 - tp) / scale, Rotation.from_matrix(R0 @ Rp.T).as_rotvec()])
            hh = [h_t / scale] * 3 + [h_t] * 3
            B = self._draw(gm, p.rid, [(f0[j] - hh[j], f0[j] + hh[j]) for j in range(6)], s, rng, n=n_draw)
            for b in B:
                T = np.eye(4)
                T[:3, :3] = Rotation.from_rotvec(b[3:6]).as_matrix() @ Rp
                t = tp + Hf @ (b[:3] * scale)
                T[:3, 3] = [round(float(t[j]), info["t_decimals"][j]) for j in range(3)]
                strings.append(V.format_pose(T, v.decimals, compact=v.compact))
        self._check_poses(p, [V.parse(t) for t in strings] + [v])
        return strings + [spec.detail]

    def _check_poses(self, p, poses):
        spec = p.spec
        fl = pose_floors(spec, self.params)
        if len({q.text for q in poses}) != 5:
            raise _Reject("two poses print the same")
        rots = [tuple(np.round(np.array(q.R), 6).ravel()) for q in poses]
        if len(set(rots)) != 5:
            raise _Reject("two poses print the same rotation")
        for i in range(5):
            for j in range(i + 1, 5):
                if pose_separation(poses[i], poses[j], fl) < 1.0:
                    raise _Reject("two poses within the separation floors of each other")
        o = spec.obs
        if o.premise is not None and o.window_s and o.window_s > 0:
            vmax = speed_bound(self.params, spec.source, o.subject_class)
            tp = o.premise[:3, 3]
            for q in poses[:-1]:
                if np.linalg.norm(np.array(q.t) - tp) / o.window_s > vmax:
                    raise _Reject("a pose implies an impossible speed from the premise")

    def _build_label(self, p: RowPlan, record: dict) -> list[str]:
        labels = list(p.spec.labels) or list(p.spec.extra.get("labels") or [])
        if p.spec.detail not in labels or len(set(labels)) != 5:
            raise OptionError(f"{p.rid}: the row's candidates are not five distinct labels containing "
                              f"{p.spec.detail!r}")
        return sorted(labels)

    # -------------------------------------------------------------------- same-video reveals
    def _reveals(self) -> dict:
        """Pose answers that another question of the same video prints as its premise: the other
        premise poses of the video that can serve as distractors (rid -> strings)."""
        premises: dict[str, dict] = defaultdict(dict)
        for p in self.plans:
            o = p.spec.obs
            if p.spec.kind == "pose" and o.premise_text:
                try:
                    premises[o.video][V.parse(o.premise_text).key()] = (p.rid, o.premise_text)
                except InputError:
                    continue
        out: dict[str, list[str]] = {}
        for p in self.plans:
            if p.spec.kind != "pose":
                continue
            prem = premises.get(p.spec.obs.video, {})
            key = p.spec.value.key()
            if key in prem and prem[key][0] != p.rid:
                own = p.spec.obs.premise_text
                others = sorted({txt for k, (r, txt) in prem.items() if k != key and txt != own})
                v: V.Pose = p.spec.value
                usable = [_reprint(t, v) for t in others]
                out[p.rid] = [t for t in usable if t != p.spec.detail]
                p.evidence["same_video_reveal"] = {"revealed_by": prem[key][0], "other_premises": len(out[p.rid])}
        return out


def _signed_rank(p: RowPlan, strings: list[str]) -> int | None:
    """The answer's signed-value rank among the five (1 = smallest) for one-dimensional answers."""
    if p.spec.kind not in ONE_D:
        return None

    def key(t):
        v = V.parse(t)
        return v.total_distance if isinstance(v, V.Trajectory) else v.value

    vals = sorted(key(t) for t in strings)
    return vals.index(key(p.spec.detail)) + 1


def _reprint(text: str, like: V.Pose) -> str:
    q = V.parse(text)
    return V.format_pose(q.matrix, like.decimals, compact=like.compact)


class _Reject(Exception):
    """A drawn candidate set breaks a constraint; it is redrawn whole."""


def _traj_formatter(template: V.Trajectory, pars: dict, rng, *, centred: bool):
    """A function total -> phrase with the template's structure and exchangeable splits and turns.

    ``centred``: the template is the answer, so its own split and turn draws are subtracted (the
    answer is one of the exchangeable draws); otherwise the template only lends its structure.
    """
    segs = list(template.segments)
    kinds = [k for k, _ in segs]
    moves = [j for j, k in enumerate(kinds) if k == "move"]
    turns = [j for j, k in enumerate(kinds) if k == "turn"]
    mags = np.array([abs(x) for _, x in segs], float)
    signs = np.array([np.sign(x) if k == "turn" else 1.0 for k, x in segs])
    logit0 = np.log(mags[moves] / mags[moves].sum())
    e_r = rng.normal(0, pars["split_sigma"], len(moves)) if centred else np.zeros(len(moves))
    t_r = rng.normal(0, pars["turn_sigma_deg"], len(turns)) if centred else np.zeros(len(turns))

    def fmt(total: float) -> str:
        e = rng.normal(0, pars["split_sigma"], len(moves))
        w = np.exp(logit0 + e - e_r)
        lengths = float(total) * w / w.sum()
        tn = rng.normal(0, pars["turn_sigma_deg"], len(turns))
        out, mi, ti = [], 0, 0
        for j, k in enumerate(kinds):
            if k == "move":
                out.append(("move", float(lengths[mi])))
                mi += 1
            else:
                m = abs(mags[j] + tn[ti] - t_r[ti]) % 360.0
                m = 360.0 - m if m > 180.0 else m
                out.append(("turn", float(signs[j] * max(m, 1.0))))
                ti += 1
        return V.format_trajectory(out)

    return fmt


def build_options(records: list[dict], *, iface: Interface, seed: int = 0, extras: dict | None = None,
                  progress: bool = False, on_failure: str = "raise") -> tuple[list[dict], pd.DataFrame, dict]:
    """Candidates and letters for every row under the answer interface ``iface`` (the option params
    and each task's rule and question reader; see the module docstring); returns (rows, evidence,
    failed) — see :meth:`Stage.build`."""
    if not records:
        return [], pd.DataFrame(), {}
    return Stage(records, iface=iface, seed=seed, extras=extras).build(progress=progress, on_failure=on_failure)


__all__ = ["OptionError", "Stage", "box_yaw", "build_options", "centre_fields", "centre_from_fields",
           "constrained_schedule", "heading_deg", "recorded_decimals", "rotation_preimage", "share_key"]
