"""Rebuild the answer options of a ReSTI-schema release (``resti reoption``).

Input: a release folder (``resti.jsonl`` or ``resti.parquet``, ``excluded.jsonl``). For every
accepted row the ``Answer Detail`` is parsed (:mod:`resti_lib.values`), four new distractors are
built for it, and the answer letter is reassigned. Everything else of the row is kept as it is:
row order, ``ReSTI ID``, ``Legacy Row Key``, question, prompt, times, video, task, source and the
``Answer Detail`` string, which is also the keyed candidate, character for character.

Every candidate is one of five exchangeable draws whose single-candidate distribution is the
distribution of the group's answers (:mod:`resti_lib.options.population`): neither a rule on one
row (rank, median, centroid, medoid, string length) nor a model of where answers usually lie can
tell the answer. Builders by answer kind (all parameters in :data:`DEFAULT_OPTIONS`, overridable
per kind and per source, e.g. ``{"box": {"Waymo": {"s": 0.2}}}``):

- scalars (distances, speeds, accelerations, sizes) and angles: one calibrated draw per
  (task, source, unit), printed with the detail's unit and decimals. Exact zeros of magnitudes
  (stationary objects) cannot be drawn continuously: the zero string is a *fixed slot*, placed in
  every zero-answer row and in four times as many other rows of the group (chosen by a seeded
  schedule), so that it is the answer in one row out of five where it appears, as far as the
  group allows;
- grounding boxes: calibrated draws per field (image-plane direction and depth of the centre, or
  the height below a vehicle camera; each edge length at the precision the source records it;
  the heading about the box-local up axis), rotations exact before printing; Omni6DPose boxes
  (no known up axis) take exchangeable isotropic rotation perturbations;
- poses: the heading about the world up axis drawn calibrated (tilt kept), the translation per
  axis calibrated (ScanNet), an exchangeable shift (Waymo, whose world frames differ between
  sequences) or, for poses relative to a reference camera (Omni6DPose), the answer's own motion
  carried on by a calibrated amount about a gaze centre, so every candidate looks where the
  reference camera looks; the JSON layout of the detail (compact or spaced) is kept;
- trajectory phrases: the answer's segment structure, a calibrated total distance and
  exchangeable splits and turn magnitudes; ``no significant movement`` is a fixed slot like the
  zeros, its rows drawing the other four phrases from a donor row's structure;
- relation labels: the row's own five labels (the answer among them) in a new letter order.

Letters are balanced per task and signed-value ranks per (task, source) (:func:`constrained_schedule`,
which respects ranks a row cannot take, e.g. an exact zero is always the smallest).

The input is checked first (:func:`check_input`: counts, digests, exclusions); a damaged input is
refused, never re-issued with fresh checksums. The output is written by the one release writer
(:func:`resti_lib.release.release_stage`): a staging folder swapped in when complete, never over the
input nor over a folder resti did not write. It holds the three artifacts, ``release.json`` (counts,
letters, bytes and sha256 of each artifact), ``SHA256SUMS`` and ``validation.json``
(:func:`resti_lib.verify.verify_release`). A release that fails verification is not published.
"""

from __future__ import annotations

import copy
import json
import os
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from . import LETTERS, SOURCES, TASKS, __version__, paths
from . import values as V
from .errors import InputError, ReoptionError
from .figures import save_figure
from .io.benchmark import jsonl_text, load_release, rows_to_parquet_bytes
from .io.files import read_bytes, read_jsonl, sha256_bytes
from .options import builders as B
from .options.learned import LearnedConfig, attack_table_with_learned
from .options.population import Population, field_draws, fit_model, population_options
from .rng import row_rng, stable_seed

DEFAULT_RELEASE = "${SHARED}/data/resti_v5"
ARTIFACTS = ("resti.jsonl", "resti.parquet", "excluded.jsonl")

# Builder parameters per kind; a source name as key overrides for that source.
DEFAULT_OPTIONS: dict = {
    "scalar": {"s": 0.45, "min_gap_ulps": 1, "min_rel_gap": 0.03, "zero_slot_ratio": 4.0},
    "angle": {"s": 0.45, "min_gap_deg": 0.02},
    "box": {
        "s": 0.25, "up_axis": 2, "iso_sigma_deg": 8.0, "min_rot_sep_deg": 0.0, "center": "projective",
        "Waymo": {"center": "height"},
        "Omni6DPose": {"up_axis": None},
    },
    "pose": {
        "s": 0.3, "min_rot_sep_deg": 0.0, "translation": "population", "trans_sigma": 0.0, "z_scale": 1.0,
        "min_orbit_deg": 3.0,
        "ScanNet": {"up": [0.0, 0.0, 1.0]},
        "Waymo": {"up": [0.0, 0.0, 1.0], "translation": "shift", "trans_sigma": 12.0, "z_scale": 0.02},
        "Omni6DPose": {"up": [0.0, -1.0, 0.0], "translation": "orbit"},
    },
    "trajectory": {"s": 0.45, "split_sigma": 0.25, "turn_sigma_deg": 15.0, "min_rel_gap": 0.04,
                   "none_slot_ratio": 4.0},
}


def merge_options(overrides: dict | None) -> dict:
    """:data:`DEFAULT_OPTIONS` updated by ``overrides`` (two levels: kind, then key or source)."""
    out = copy.deepcopy(DEFAULT_OPTIONS)
    for kind, kv in (overrides or {}).items():
        if kind not in out:
            raise ValueError(f"unknown option kind {kind!r}; known: {sorted(out)}")
        for k, v in (kv or {}).items():
            if k in SOURCES and isinstance(v, dict):
                out[kind].setdefault(k, {}).update(v)
            else:
                out[kind][k] = v
    return out


def kind_params(options: dict, kind: str, source: str) -> dict:
    """Parameters of one kind for one source (source overrides flattened in)."""
    base = {k: v for k, v in options[kind].items() if k not in SOURCES}
    base.update(options[kind].get(source, {}))
    return base


# ------------------------------------------------------------------------------------ schedules

def constrained_schedule(allowed: dict, levels, *, seed: int, group: str) -> dict:
    """Balanced levels (counts differ by at most one where the constraints allow) with constraints.

    ``allowed``: key -> allowed levels. Rows with fewer allowed levels are placed first; each row
    takes its allowed level with the largest remaining quota; ties are broken by a seeded order,
    so the result depends only on the keys, their constraints, the seed and the group name.
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


def _slot_rows(carriers: list[str], candidates: list[str], ratio: float, *, seed: int, group: str) -> set:
    """The rows that carry a fixed slot: every carrier plus ``ratio`` times as many others (seeded)."""
    want = min(len(candidates), round(ratio * len(carriers)))
    if not carriers or want == 0:
        return set(carriers)
    rng = np.random.default_rng(stable_seed(seed, "slot", group))
    others = sorted(candidates)
    pick = rng.permutation(len(others))[:want]
    return set(carriers) | {others[int(i)] for i in pick}


# ------------------------------------------------------------------------------------ planning

@dataclass
class GroupModels:
    """The population models of one group: one per field, and which answer each row contributed."""

    fields: dict
    index: dict
    ulp: float = 0.01
    col: int = 0
    decimals: dict = field(default_factory=dict)  # recorded decimals of each structured field
    field_index: dict = field(default_factory=dict)  # per field: rid -> answer index, when not ``index``

    def get(self, name: str, rid: str) -> Population:
        """The map of field ``name`` without the row's own answer (leave one out)."""
        return self.fields[name].population(self.field_index.get(name, self.index).get(rid))


@dataclass
class RowPlan:
    """What the builder needs for one row, decided before any row is built."""

    rid: str
    task: str
    source: str
    kind: str
    value: object
    detail: str
    group: str = ""
    rank: int | None = None
    letter: str = "A"
    fixed: tuple = ()
    answer_is_fixed: bool = False
    donor: str | None = None
    evidence: dict = field(default_factory=dict)


def _kind(v) -> str:
    if isinstance(v, V.Scalar):
        return "angle" if v.is_angle else "scalar"
    return v.kind


def plan_rows(records: list[dict], *, seed: int, options: dict) -> tuple[list[RowPlan], dict]:
    """Parse every detail; decide groups, fixed slots, target ranks and letters."""
    plans: list[RowPlan] = []
    for i, r in enumerate(records):
        rid = r.get("ReSTI ID") or r.get("Legacy Row Key") or str(i)
        detail = r.get("Answer Detail")
        v = V.parse(detail, row=rid, field="Answer Detail")
        kind = _kind(v)
        if not v.finite():
            raise InputError("Answer Detail is not finite", row=rid, field="Answer Detail")
        if kind == "scalar" and v.value < 0:
            raise InputError("a negative magnitude has no option builder", row=rid, field="Answer Detail")
        p = RowPlan(str(rid), r.get("Task"), r.get("Source"), kind, v, detail)
        if kind == "scalar":
            p.group = f"{p.task}|{p.source}|{v.unit}|{v.decimals}"
        elif kind == "angle":
            p.group = f"{p.task}|{p.source}|deg|{v.decimals}"
        else:
            p.group = f"{p.task}|{p.source}|{kind}"
        plans.append(p)
    if len({p.rid for p in plans}) != len(plans):
        raise InputError("row ids (ReSTI ID) are not unique")
    by_group: dict[str, list[RowPlan]] = defaultdict(list)
    for p in plans:
        by_group[p.group].append(p)
    populations: dict[str, GroupModels] = {}
    for g, ps in sorted(by_group.items()):
        kind = ps[0].kind
        if kind == "scalar":
            ulp = 10.0 ** -ps[0].value.decimals
            zero_text = V.format_scalar(0.0, ps[0].value.unit, ps[0].value.decimals)
            zeros = [p.rid for p in ps if p.value.value == 0.0]
            rest = [p.value.value for p in ps if p.value.value != 0.0]
            pars = kind_params(options, "scalar", ps[0].source)
            idx = {p.rid: i for i, p in enumerate(x for x in ps if x.value.value != 0.0)}
            populations[g] = GroupModels({"value": fit_model(rest or [ulp], kind="positive", ulp=ulp, floor=ulp)},
                                         idx, ulp)
            carriers = _slot_rows(zeros, [p.rid for p in ps if p.value.value != 0.0],
                                  pars["zero_slot_ratio"], seed=seed, group=g)
            for p in ps:
                if p.rid in carriers:
                    p.fixed = (zero_text,)
                    p.answer_is_fixed = p.value.value == 0.0
        elif kind == "angle":
            ulp = 10.0 ** -ps[0].value.decimals
            populations[g] = GroupModels({"value": fit_model([p.value.value for p in ps], kind="angle", ulp=ulp)},
                                         {p.rid: i for i, p in enumerate(ps)}, ulp)
        elif kind in ("box", "pose"):
            populations[g] = _fit_structured(ps, kind, options)
        elif kind == "trajectory":
            moving = [p for p in ps if p.value.segments and p.value.total_distance > 0]
            none = [p.rid for p in ps if not p.value.segments]
            pars = kind_params(options, "trajectory", ps[0].source)
            model = fit_model([p.value.total_distance for p in moving] or [1.0], kind="positive", ulp=0.1,
                              floor=0.1)
            populations[g] = GroupModels({"value": model}, {p.rid: i for i, p in enumerate(moving)}, 0.1)
            carriers = _slot_rows(none, [p.rid for p in moving], pars["none_slot_ratio"], seed=seed, group=g)
            donors = sorted(p.rid for p in moving)
            for p in ps:
                if p.rid in carriers:
                    p.fixed = (V.NO_MOVEMENT,)
                    p.answer_is_fixed = not p.value.segments
                    if p.answer_is_fixed:
                        if not donors:
                            raise ReoptionError(f"{g}: no moving trajectory to draw distractors from")
                        rng = row_rng(seed, p.rid, "donor")
                        p.donor = donors[int(rng.integers(len(donors)))]
    # ranks per (task, source) over scalar, angle and trajectory rows
    ranked: dict[tuple, dict] = defaultdict(dict)
    for p in plans:
        if p.kind not in ("scalar", "angle", "trajectory"):
            continue
        ranked[(p.task, p.source)][p.rid] = _allowed_ranks(p, populations.get(p.group))
    for (task, source), allowed in sorted(ranked.items()):
        sched = constrained_schedule(allowed, [1, 2, 3, 4, 5], seed=seed, group=f"ranks|{task}|{source}")
        for p in plans:
            if p.rid in sched:
                p.rank = sched[p.rid]
    # letters per task
    for task in sorted({p.task for p in plans}):
        ids = [p.rid for p in plans if p.task == task]
        sched = constrained_schedule({k: set(LETTERS) for k in ids}, list(LETTERS), seed=seed,
                                     group=f"letters|{task}")
        for p in plans:
            if p.task == task:
                p.letter = sched[p.rid]
    return plans, populations


def _allowed_ranks(p: RowPlan, pop: GroupModels | None) -> set:
    """Overall signed-value ranks the answer can take (fixed slots are the smallest values)."""
    if p.answer_is_fixed:
        return {1}
    lo = 1 + len(p.fixed)
    if p.kind == "scalar" and pop is not None:
        # printable continuous values strictly between the floor (one unit) and the answer
        below = round(p.value.value / pop.ulp) - 1
        hi = min(5, lo + max(0, below))
        return set(range(lo, hi + 1))
    return set(range(lo, 6))


# ------------------------------------------------------------------------------------ building

def _scalar_key(s: str) -> float:
    return float(V.parse(s).value)


def _build_scalar(p: RowPlan, models: GroupModels, pars: dict, rng) -> B.Options:
    v: V.Scalar = p.value
    pop = models.get("value", p.rid)
    ulp = 10.0 ** -v.decimals

    def fmt(x):
        return V.format_scalar(float(x), v.unit, v.decimals)

    k = None if p.rank is None else p.rank - len(p.fixed)
    return population_options(v.value, p.detail, pop, rng=rng, fmt=fmt, key=_scalar_key, s=pars["s"],
                              target_rank=k, fixed=p.fixed, answer_is_fixed=p.answer_is_fixed,
                              floor=ulp, min_gap=pars["min_gap_ulps"] * ulp, min_rel_gap=pars["min_rel_gap"])


def _build_angle(p: RowPlan, models: GroupModels, pars: dict, rng) -> B.Options:
    v: V.Scalar = p.value
    pop = models.get("value", p.rid)

    def fmt(x):
        return V.format_angle(float(x), v.decimals)

    return population_options(v.value, p.detail, pop, rng=rng, fmt=fmt, key=_scalar_key, s=pars["s"],
                              target_rank=p.rank, min_gap=pars["min_gap_deg"])


def _traj_formatter(template: V.Trajectory, pars: dict, rng, *, centred: bool):
    """A function total -> phrase with the template's structure (turn directions included) and
    exchangeable splits and turn magnitudes.

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


def _traj_key(s: str) -> float:
    v = V.parse(s)
    return float(v.total_distance) if isinstance(v, V.Trajectory) else float("nan")


def _build_trajectory(p: RowPlan, models: GroupModels, pars: dict, rng, by_id: dict) -> B.Options:
    v: V.Trajectory = p.value
    pop = models.get("value", p.rid)
    if p.answer_is_fixed:
        template = by_id[p.donor].value
        fmt = _traj_formatter(template, pars, rng, centred=False)
        return population_options(0.0, p.detail, pop, rng=rng, fmt=fmt, key=_traj_key, s=pars["s"],
                                  fixed=(p.detail,), answer_is_fixed=True, floor=0.1,
                                  min_rel_gap=pars["min_rel_gap"])
    if not v.segments or v.total_distance <= 0:
        raise B.OptionError(f"trajectory {p.detail!r} has no movement to vary")
    fmt = _traj_formatter(v, pars, rng, centred=True)
    k = None if p.rank is None else p.rank - len(p.fixed)
    opts = population_options(v.total_distance, p.detail, pop, rng=rng, fmt=fmt, key=_traj_key, s=pars["s"],
                              target_rank=k, fixed=p.fixed, floor=0.1, min_rel_gap=pars["min_rel_gap"])
    structures = {V.parse(s).structure for s in opts.strings if s != V.NO_MOVEMENT}
    if structures != {v.structure}:
        raise B.OptionError("a distractor lost the answer's structure")
    return opts


def _so3(R) -> np.ndarray:
    U, _, Vt = np.linalg.svd(np.asarray(R, float))
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt


def _rot(axis, deg: float) -> np.ndarray:
    return Rotation.from_rotvec(np.asarray(axis, float) / np.linalg.norm(axis) * np.radians(deg)).as_matrix()


def box_yaw(R, up_axis: int = 2) -> float:
    """Heading of a box about its local ``up_axis``: the angle of the next local axis in the plane
    perpendicular to the box's up direction, from the projected camera forward (degrees).
    ``box_yaw(R @ rot(e_up, d)) == box_yaw(R) + d``."""
    R = np.asarray(R, float)
    up = R[:, up_axis]
    f = np.array([0.0, 0.0, 1.0]) - up[2] * up
    if np.linalg.norm(f) < 1e-6:
        f = np.array([1.0, 0.0, 0.0]) - up[0] * up
    f /= np.linalg.norm(f)
    g = np.cross(up, f)
    a = R[:, (up_axis + 1) % 3]
    return float(np.degrees(np.arctan2(a @ g, a @ f)))


def pose_yaw(R, up, col: int) -> float:
    """Heading of column ``col`` of a rotation about the world ``up`` axis (degrees).
    ``pose_yaw(rot(up, d) @ R) == pose_yaw(R) + d``."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    e1 = np.array([1.0, 0.0, 0.0]) - up[0] * up
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.array([0.0, 1.0, 0.0]) - up[1] * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    v = np.asarray(R, float)[:, col]
    return float(np.degrees(np.arctan2(v @ e2, v @ e1)))


def _min_rot_sep(rots) -> float:
    best = np.inf
    for i in range(len(rots)):
        for j in range(i + 1, len(rots)):
            c = (np.trace(rots[i].T @ rots[j]) - 1.0) / 2.0
            best = min(best, float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))))
    return best


def _distinct_set(strings: list[str]) -> bool:
    if len(set(strings)) != 5:
        return False
    return len({V.parse(x).key() for x in strings}) == 5


def center_fields(c, mode: str) -> np.ndarray:
    """A box centre as drawn: ``projective`` (x/z, y/z, z), ``height`` (x/z, y, z) or ``cartesian``.

    Drawing the image-plane direction and the depth keeps every candidate in front of the camera
    and in its field of view like the answers; ``height`` keeps the height below a vehicle camera
    (ground objects) instead of the vertical direction."""
    c = np.asarray(c, float)
    if mode == "projective":
        return np.array([c[0] / c[2], c[1] / c[2], c[2]])
    if mode == "height":
        return np.array([c[0] / c[2], c[1], c[2]])
    if mode == "cartesian":
        return c.copy()
    raise ValueError(f"unknown centre mode {mode!r}")


def center_from_fields(f, mode: str) -> np.ndarray:
    f = np.asarray(f, float)
    if mode == "projective":
        return np.array([f[0] * f[2], f[1] * f[2], f[2]])
    if mode == "height":
        return np.array([f[0] * f[2], f[1], f[2]])
    return f.copy()


def field_decimals(values, max_decimals: int) -> int:
    """The decimals a field of a group's answers is recorded with: the fewest that represent at
    least half of the values exactly (Waymo box heights have two where lengths have three)."""
    v = np.asarray(values, dtype=float)
    for d in range(max_decimals + 1):
        if np.mean(np.abs(np.round(v, d) - v) > 1e-9) < 0.5:
            return d
    return max_decimals


def orbit_axis(R, up, min_deg: float) -> tuple[np.ndarray, float]:
    """Rotation axis (oriented along ``up``) and signed angle of a relative camera rotation; below
    ``min_deg`` the axis is not defined by the data and ``up`` is used."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    rv = Rotation.from_matrix(np.asarray(R, float)).as_rotvec()
    theta = float(np.degrees(np.linalg.norm(rv)))
    if theta < min_deg:
        return up, float(np.degrees(rv @ up))
    axis = rv / np.linalg.norm(rv)
    if axis @ up < 0:
        axis, theta = -axis, -theta
    return axis, theta


def gaze_depth(R, t) -> float:
    """Depth along the reference optical axis (the identity camera's +Z) of its closest approach
    to this camera's optical axis; NaN when the two are parallel or the point is not in front."""
    a = np.array([0.0, 0.0, 1.0])
    b = np.asarray(R, float)[:, 2]
    t = np.asarray(t, float)
    c = a @ b
    den = 1.0 - c * c
    if den < 1e-4:
        return float("nan")
    s = (t @ a - c * (t @ b)) / den  # point s*a on the reference axis closest to the line t + u*b
    return float(s) if 0.05 < s < 50.0 else float("nan")


def _fit_structured(ps: list, kind: str, options: dict) -> GroupModels:
    """Field populations of one box or pose group (see :func:`_build_box`, :func:`_build_pose`)."""
    pars = kind_params(options, kind, ps[0].source)
    pops: dict = {}
    decimals: dict = {}
    field_index: dict = {}
    col = 0
    if kind == "box":
        cs = np.array([p.value.center for p in ps], float)
        ds = np.array([p.value.lwh for p in ps], float)
        mode = pars["center"]
        front = [i for i, c in enumerate(cs) if c[2] > 0]  # a centre behind the camera is drawn cartesian
        fs = np.array([center_fields(cs[i], mode) for i in front]) if front else np.zeros((0, 3))
        for j in range(3):
            dc, dd = field_decimals(cs[:, j], 3), field_decimals(ds[:, j], 3)
            decimals[f"c{j}"], decimals[f"d{j}"] = dc, dd
            pops[f"k{j}"] = fit_model(cs[:, j], kind="real", ulp=10.0 ** -dc)
            if mode != "cartesian" and front:
                kind_j = "positive" if j == 2 else "real"
                ratio = j == 0 or (j == 1 and mode == "projective")
                ulp_j = 1e-4 if ratio else 10.0 ** -dc  # image-plane ratios are not printed
                pops[f"c{j}"] = fit_model(fs[:, j], kind=kind_j, ulp=ulp_j)
                field_index[f"c{j}"] = {ps[i].rid: n for n, i in enumerate(front)}
            pops[f"d{j}"] = fit_model(ds[:, j], kind="positive", ulp=10.0 ** -dd)
        decimals["center_mode"] = mode
        if pars["up_axis"] is not None:
            yaws = [box_yaw(_so3(p.value.R), pars["up_axis"]) for p in ps]
            pops["yaw"] = fit_model(yaws, kind="circular", ulp=0.01)
    elif pars["translation"] == "orbit":
        up = np.asarray(pars["up"], float) / np.linalg.norm(pars["up"])
        axes, thetas, depths = {}, [], []
        for p in ps:
            R, t = _so3(p.value.R), np.array(p.value.t, float)
            axis, theta = orbit_axis(R, up, pars["min_orbit_deg"])
            axes[p.rid] = (axis, theta)
            thetas.append(theta)
            depths.append(gaze_depth(R, t))
        pops["theta"] = fit_model(thetas, kind="circular", ulp=0.01)
        ts = np.array([p.value.t for p in ps], float)
        for j in range(3):
            decimals[f"t{j}"] = field_decimals(ts[:, j], ps[0].value.decimals)
        idx = {p.rid: i for i, p in enumerate(ps)}
        d = np.array(depths, float)
        ok = np.isfinite(d)
        for p in ps:  # the orbit centre of a row: the median gaze depth of the other rows
            others = ok.copy()
            others[idx[p.rid]] = False
            dm = float(np.median(d[others])) if others.any() else 1.0
            axes[p.rid] = (*axes[p.rid], dm)
        decimals["orbit"] = axes
    else:
        up = np.asarray(pars["up"], float)
        Rs = [_so3(p.value.R) for p in ps]
        horiz = [np.mean([np.linalg.norm(R[:, c] - (R[:, c] @ up) * up / (up @ up)) for R in Rs]) for c in range(3)]
        col = int(np.argmax(horiz))
        pops["yaw"] = fit_model([pose_yaw(R, up, col) for R in Rs], kind="circular", ulp=0.01)
        if pars["translation"] == "population":
            ts = np.array([p.value.t for p in ps], float)
            for j in range(3):
                decimals[f"t{j}"] = field_decimals(ts[:, j], ps[0].value.decimals)
                pops[f"t{j}"] = fit_model(ts[:, j], kind="real", ulp=10.0 ** -decimals[f"t{j}"])
    return GroupModels(pops, {p.rid: i for i, p in enumerate(ps)}, col=col, decimals=decimals,
                       field_index=field_index)


def _build_box(p: RowPlan, models: GroupModels, pars: dict, rng) -> B.Options:
    """Grounding boxes: every field an exchangeable population-calibrated draw (centre per axis,
    edge lengths per axis, heading about the box-local up axis); without an up axis, rotations are
    exchangeable draws of an isotropic perturbation."""
    v: V.Box = p.value
    if v.R is None:
        raise B.OptionError("grounding answer without a rotation")
    R0 = _so3(v.R)
    c0, d0 = np.array(v.center, float), np.array(v.lwh, float)
    s = pars["s"]
    up_axis = pars["up_axis"]
    pops = {name: models.get(name, p.rid) for name in models.fields}
    for _ in range(B.MAX_TRIES):
        mode = models.decimals["center_mode"] if (c0[2] > 0 and "c0" in pops) else "cartesian"
        f0 = center_fields(c0, mode)
        key = "k" if mode == "cartesian" else "c"
        fs = np.column_stack([field_draws(pops[f"{key}{j}"], f0[j], s=s, rng=rng) for j in range(3)])
        cs = np.array([center_from_fields(f, mode) for f in fs])
        cs = np.column_stack([np.round(cs[:, j], models.decimals[f"c{j}"]) for j in range(3)])
        ds = np.column_stack([np.round(field_draws(pops[f"d{j}"], d0[j], s=s, rng=rng), models.decimals[f"d{j}"])
                              for j in range(3)])
        if (ds <= 0).any():
            continue
        if up_axis is not None:
            yaw0 = box_yaw(R0, up_axis)
            yaws = field_draws(pops["yaw"], yaw0, s=s, rng=rng)
            e = np.zeros(3)
            e[up_axis] = 1.0
            rots = [R0 @ _rot(e, float(V.wrap_degrees(y - yaw0))) for y in yaws]
        else:
            Q = [Rotation.from_rotvec(rng.normal(0.0, np.radians(pars["iso_sigma_deg"]), 3)).as_matrix()
                 for _ in range(5)]
            rots = [R0 @ Q[4].T @ Q[i] for i in range(4)]
        if _min_rot_sep([R0, *rots]) < pars["min_rot_sep_deg"]:
            continue
        strings = [V.format_box(cs[i], ds[i], rots[i]) for i in range(4)]
        r = int(rng.integers(5))
        strings.insert(r, p.detail)
        if _distinct_set(strings):
            return B.Options(strings, r, {"kind": "box", "s": s})
    raise B.OptionError("no box options under the constraints")


def _build_pose(p: RowPlan, models: GroupModels, pars: dict, rng) -> B.Options:
    """Poses: the heading about the world up axis a population-calibrated draw (tilt kept), the
    translation per axis a population-calibrated draw or, for world frames that differ between
    sequences, an exchangeable shift (``translation: shift``, ``trans_sigma``, ``z_scale``).
    ``translation: orbit`` (poses relative to a reference camera, Omni6DPose): the answer's own
    relative motion carried on by a population-calibrated amount, about its rotation axis through
    a gaze centre on the reference optical axis, so every candidate looks where the reference
    camera looks (see :func:`orbit_axis`, :func:`gaze_depth`)."""
    v: V.Pose = p.value
    R0, t0 = _so3(v.R), np.array(v.t, float)
    up = np.asarray(pars["up"], float) / np.linalg.norm(pars["up"])
    s = pars["s"]
    pops = {name: models.get(name, p.rid) for name in models.fields}
    orbit = pars["translation"] == "orbit"
    if orbit:
        axis, theta0, depth = models.decimals["orbit"][p.rid]
        centre = np.array([0.0, 0.0, depth])
    else:
        yaw0 = pose_yaw(R0, up, models.col)
    for _ in range(B.MAX_TRIES):
        if orbit:
            # the same motion carried on by a different amount: a rotation about the answer's own
            # rotation axis through a gaze centre on the reference optical axis
            deltas = [float(V.wrap_degrees(th - theta0)) for th in field_draws(pops["theta"], theta0, s=s, rng=rng)]
            rots = [_rot(axis, dl) @ R0 for dl in deltas]
            ts = np.array([_rot(axis, dl) @ (t0 - centre) + centre for dl in deltas])
            ts = np.column_stack([np.round(ts[:, j], models.decimals[f"t{j}"]) for j in range(3)])
        else:
            yaws = field_draws(pops["yaw"], yaw0, s=s, rng=rng)
            rots = [_rot(up, float(V.wrap_degrees(y - yaw0))) @ R0 for y in yaws]
            if pars["translation"] == "population":
                ts = np.column_stack([np.round(field_draws(pops[f"t{j}"], t0[j], s=s, rng=rng),
                                               models.decimals[f"t{j}"]) for j in range(3)])
            else:
                d = rng.normal(0.0, pars["trans_sigma"], (5, 3))
                d = d - np.outer(d @ up, up) + np.outer(d @ up, up) * pars["z_scale"]
                ts = t0 + d[:4] - d[4]
        if _min_rot_sep([R0, *rots]) < pars["min_rot_sep_deg"]:
            continue
        strings = []
        for i in range(4):
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = rots[i], ts[i]
            strings.append(V.format_pose(T, v.decimals, compact=v.compact))
        r = int(rng.integers(5))
        strings.insert(r, p.detail)
        if _distinct_set(strings):
            return B.Options(strings, r, {"kind": "pose", "s": s})
    raise B.OptionError("no pose options under the constraints")


def _build_label(p: RowPlan, record: dict) -> B.Options:
    labels = sorted(str(s) for s in (record.get("Candidates") or {}).values())
    if p.detail not in labels or len(set(labels)) != 5:
        raise B.OptionError(f"the row's candidates are not five distinct labels containing {p.detail!r}")
    return B.label_options(p.detail, labels)


def build_row(p: RowPlan, record: dict, *, seed: int, options: dict, populations: dict, by_id: dict
              ) -> tuple[dict, str, dict]:
    """Five candidates for one row: (Candidates A-E, answer letter, evidence)."""
    rng = row_rng(seed, p.rid, "reoption")
    if p.kind == "scalar":
        opts = _build_scalar(p, populations[p.group], kind_params(options, "scalar", p.source), rng)
    elif p.kind == "angle":
        opts = _build_angle(p, populations[p.group], kind_params(options, "angle", p.source), rng)
    elif p.kind == "trajectory":
        opts = _build_trajectory(p, populations[p.group], kind_params(options, "trajectory", p.source), rng,
                                 by_id)
    elif p.kind == "box":
        opts = _build_box(p, populations[p.group], kind_params(options, "box", p.source), rng)
    elif p.kind == "pose":
        opts = _build_pose(p, populations[p.group], kind_params(options, "pose", p.source), rng)
    elif p.kind == "label":
        opts = _build_label(p, record)
    else:  # pragma: no cover - parse() returns one of the kinds above
        raise B.OptionError(f"no builder for kind {p.kind!r}")
    if opts.strings[opts.answer_index] != p.detail:
        raise ReoptionError(f"{p.rid}: the keyed candidate is not the Answer Detail string")
    cands, letter = B.assign_letters(opts, p.letter, rng)
    return cands, letter, dict(opts.evidence)


def reoption_records(records: list[dict], *, seed: int = 0, options: dict | None = None,
                     keep_on_failure: bool = False) -> tuple[list[dict], pd.DataFrame]:
    """New rows (same order, same fields; Candidates and Answer rebuilt) and per-row evidence.

    ``keep_on_failure``: a row whose options cannot be built under the constraints keeps its
    Candidates and Answer (evidence ``kept``) instead of stopping the whole rebuild.
    """
    options = merge_options(options)
    plans, pops = plan_rows(records, seed=seed, options=options)
    by_id = {p.rid: p for p in plans}
    out, ev = [], []
    for p, r in zip(plans, records):
        try:
            cands, letter, e = build_row(p, r, seed=seed, options=options, populations=pops, by_id=by_id)
        except B.OptionError as err:
            if not keep_on_failure:
                raise ReoptionError(f"{p.rid} ({p.task}, {p.source}): {err}") from None
            out.append(dict(r))
            ev.append({"rid": p.rid, "task": p.task, "source": p.source, "kind": p.kind, "group": p.group,
                       "kept": True, "problem": str(err)})
            continue
        new = dict(r)
        new["Candidates"] = cands
        new["Answer"] = letter
        out.append(new)
        ev.append({"rid": p.rid, "task": p.task, "source": p.source, "kind": p.kind, "group": p.group,
                   "target_rank": p.rank, "letter": letter, "fixed": ",".join(p.fixed),
                   "answer_is_fixed": p.answer_is_fixed, "rank": e.get("rank"), "rank_kept": e.get("rank_kept", True),
                   "tries": e.get("tries")})
    return out, pd.DataFrame(ev)


# ------------------------------------------------------------------------------------ writing

def release_meta(rows: list[dict], excluded: list[dict], artifacts: dict, *, source_meta: dict | None,
                 source_digests: dict, seed: int, options: dict) -> dict:
    """The ``release.json`` object (no dates or paths, so the same input gives the same bytes); the
    row counts come from :func:`resti_lib.release.count_fields`, as in an assembled release."""
    from .release import count_fields

    c = count_fields(rows, excluded, excluded_order="name")
    by_task_letter = {t: {L: int(n) for L, n in sorted(Counter(r["Answer"] for r in rows if r["Task"] == t).items())}
                      for t in c["accepted_by_task"]}
    sm = source_meta or {}
    return {
        "name": sm.get("name", "ReSTI"),
        "version": f"{sm.get('version', 'unknown')}+reoption",
        "derived_from": {"name": sm.get("name"), "version": sm.get("version"), "artifacts": source_digests},
        "reoption": {"seed": int(seed), "generator": "resti_lib.reoption", "resti_version": __version__,
                     "options": options,
                     "preserved": "row order and every field except Candidates and Answer; the keyed "
                                  "candidate is the Answer Detail string"},
        "artifacts": artifacts,
        "counts": c["counts"],
        "accepted_by_source": c["accepted_by_source"],
        "accepted_by_task": c["accepted_by_task"],
        "accepted_by_task_source": {f"{t}|{s}": int(n) for (t, s), n in
                                    sorted(Counter((r["Task"], r["Source"]) for r in rows).items())},
        "excluded_by_task": c["excluded_by_task"],
        "answer_letters": c["answer_letters"],
        "answer_letters_by_task": by_task_letter,
    }


@dataclass
class ReoptionResult:
    out_dir: Path
    rows: list[dict]
    before: list[dict]
    evidence: pd.DataFrame
    meta: dict
    validation: dict
    seconds: float


def check_input(rel) -> None:
    """Refuse a damaged input release, naming the failing check (:class:`InputError` whose
    ``field`` is the check).

    The input must carry its integrity records and match them: ``release.json`` with row counts
    (accepted, excluded, original) equal to the rows and exclusions present, digests
    (``SHA256SUMS`` or the ``release.json`` artifacts) covering the files read and matching them,
    at least one accepted row, unique ids. A release with a cut row, an emptied ``excluded.jsonl``
    or an empty ``resti.jsonl`` is refused instead of being re-issued with fresh checksums.
    """
    from .verify import integrity_checks

    where = rel.root
    if rel.meta is None:
        raise InputError("the input release has no release.json: its row counts cannot be checked, so "
                         "damage (cut rows, lost exclusions) would go unnoticed; nothing was written",
                         file=where, field="release_json")
    checks = integrity_checks(rel)
    if checks["sha256"]["status"] == "skipped":
        raise InputError("the input release has no digests (SHA256SUMS or release.json artifacts): "
                         "damage would go unnoticed; nothing was written", file=where, field="sha256")
    failing = {k: c for k, c in checks.items() if c["status"] == "fail"}
    if failing:
        name, c = next(iter(failing.items()))
        msgs = "; ".join(f"{k}: {v}" for k, v in list((c.get("messages") or {}).items())[:3]) \
            or ", ".join(c["failing"][:3])
        others = f" (also failing: {', '.join(list(failing)[1:])})" if len(failing) > 1 else ""
        raise InputError(f"the input release is damaged; check {name!r} fails: {msgs}{others}; "
                         "nothing was written", file=where, field=name)


def reoption_release(release: str | os.PathLike = DEFAULT_RELEASE, out_dir: str | os.PathLike = "outputs/reoption",
                     *, seed: int = 0, options: dict | None = None) -> ReoptionResult:
    """Read and check a release, rebuild its options, write and verify the new release, publish it
    atomically (:func:`resti_lib.release.release_stage`: never over the input, nor over a folder
    that resti did not write)."""
    from .release import failing_checks, release_stage

    t0 = time.perf_counter()
    src = paths.resolve(release)
    out = paths.resolve(out_dir)
    with release_stage(out, inputs=[src]) as st:
        rel = load_release(src, strict=True)
        check_input(rel)
        if rel.accepted_file is not None and rel.accepted_file.suffix == ".jsonl":
            # the rows exactly as written (field order and value types), not through a data frame
            records = read_jsonl(rel.accepted_file)
        else:
            records = rel.accepted.to_dict("records")
        opts = merge_options(options)
        rows, ev = reoption_records(records, seed=seed, options=opts)
        st.write("resti.jsonl", jsonl_text(rows).encode("utf-8"))
        st.write("resti.parquet", rows_to_parquet_bytes(rows))
        st.write("excluded.jsonl", read_bytes(rel.excluded_file) if rel.excluded_file is not None else b"")
        src_digests = {}
        for f in (rel.accepted_file, rel.excluded_file):
            if f is not None:
                b = read_bytes(f)
                src_digests[f.name] = {"bytes": len(b), "sha256": sha256_bytes(b)}
        meta = release_meta(rows, rel.excluded, st.artifacts(ARTIFACTS), source_meta=rel.meta,
                            source_digests=src_digests, seed=seed, options=opts)
        st.seal(meta, ARTIFACTS)
        validation = st.verify()
        if not validation["passed"]:
            raise ReoptionError(f"the rebuilt release fails verification: {failing_checks(validation)}")
    return ReoptionResult(out, rows, records, ev, meta, validation, time.perf_counter() - t0)


# ------------------------------------------------------------------------------------ audit

def attack_tables(before: list[dict], after: list[dict], *, alpha: float = 0.05,
                  learned: LearnedConfig | bool | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The attack table (rule attacks + ``learned_blind``, Holm within each) of input and output."""
    return (attack_table_with_learned(before, alpha=alpha, learned=learned),
            attack_table_with_learned(after, alpha=alpha, learned=learned))


def side_by_side(before: pd.DataFrame, after: pd.DataFrame) -> pd.DataFrame:
    """One row per (attack, task, source): input and output accuracy, hits, p-value, significance."""
    cols = ["picked", "hits", "accuracy", "p_value", "significant"]
    key = ["attack", "task", "source"]
    m = before[key + ["n_rows"] + cols].merge(after[key + cols], on=key, how="outer", suffixes=("_in", "_out"))
    order = {t: i for i, t in enumerate(TASKS)}
    src = {s: i for i, s in enumerate(SOURCES)}
    m["_t"] = m["task"].map(order)
    m["_s"] = m["source"].map(lambda s: src.get(s, 99))
    return m.sort_values(["_t", "_s", "attack"], kind="stable").drop(columns=["_t", "_s"]).reset_index(drop=True)


def strongest_by_task(table: pd.DataFrame, *, source: str | None = None) -> pd.DataFrame:
    """Per task (and source): the attack with the smallest p-value, and the learned attacker's row."""
    out = []
    t = table if source is None else table[table["source"] == source]
    for (task, src), g in t.groupby(["task", "source"], sort=False):
        best = g.sort_values(["p_value", "accuracy"], ascending=[True, False], kind="stable").iloc[0]
        lb = g[g["attack"] == "learned_blind"]
        out.append({"task": task, "source": src, "n_rows": int(best["n_rows"]), "strongest": best["attack"],
                    "accuracy": best["accuracy"], "hits": int(best["hits"]), "picked": int(best["picked"]),
                    "p_value": best["p_value"], "significant": bool(best["significant"]),
                    "learned_accuracy": float(lb["accuracy"].iloc[0]) if len(lb) else float("nan"),
                    "learned_p": float(lb["p_value"].iloc[0]) if len(lb) else float("nan")})
    df = pd.DataFrame(out)
    order = {t: i for i, t in enumerate(TASKS)}
    srcs = {s: i for i, s in enumerate(SOURCES)}
    df["_t"] = df["task"].map(order)
    df["_s"] = df["source"].map(lambda s: srcs.get(s, 99))
    return df.sort_values(["_t", "_s"]).drop(columns=["_t", "_s"]).reset_index(drop=True)


def value_reuse(records: list[dict], *, min_answers: int = 3) -> pd.DataFrame:
    """Candidate strings that are the answer in at least ``min_answers`` rows of a (task, source):
    how often they are the answer where they appear (1/5 is what the options can reach at best;
    a value that is the answer in more than a fifth of its group cannot get there)."""
    ans: Counter = Counter()
    app: Counter = Counter()
    n_group: Counter = Counter()
    for r in records:
        g = (r["Task"], r["Source"])
        n_group[g] += 1
        for L, s in r["Candidates"].items():
            app[(g, s)] += 1
            if L == r["Answer"]:
                ans[(g, s)] += 1
    from .options.attacks import binom_p

    out = []
    for (g, s), n in ans.items():
        if n < min_answers:
            continue
        out.append({"task": g[0], "source": g[1], "value": s, "answer_rows": n, "appears_in": app[(g, s)],
                    "answer_share": n / app[(g, s)], "share_of_group": n / n_group[g],
                    "p_value": binom_p(n, app[(g, s)])})
    df = pd.DataFrame(out, columns=["task", "source", "value", "answer_rows", "appears_in", "answer_share",
                                    "share_of_group", "p_value"])
    return df.sort_values(["answer_share", "answer_rows"], ascending=False).reset_index(drop=True)


def label_balance(records: list[dict], task: str = "Spatial Relation") -> pd.DataFrame:
    """Answer label counts per source of a categorical task (what a label prior exploits)."""
    c = Counter((r["Source"], r["Answer Detail"]) for r in records if r["Task"] == task)
    df = pd.DataFrame([{"source": s, "label": lab, "rows": n} for (s, lab), n in sorted(c.items())])
    if len(df):
        df["share"] = df["rows"] / df.groupby("source")["rows"].transform("sum")
    return df


def write_audit(before: pd.DataFrame, after: pd.DataFrame, out_dir: str | os.PathLike, *, alpha: float
                ) -> dict:
    """Write the attack tables of input and output, the side-by-side table and the strongest
    attack per task and source (markdown, CSV and LaTeX each); returns the tables."""
    from .tables import write_table

    out = paths.resolve(out_dir)
    sb, sa = strongest_by_task(before), strongest_by_task(after)
    both = sb.merge(sa, on=["task", "source", "n_rows"], suffixes=("_in", "_out"))
    tables = {"attacks_input": before, "attacks_output": after, "attacks_side_by_side": side_by_side(before, after),
              "strongest_by_task": both}
    captions = {"attacks_input": f"Option-only attacks on the input release (Holm alpha={alpha})",
                "attacks_output": f"Option-only attacks on the rebuilt release (Holm alpha={alpha})",
                "attacks_side_by_side": "Every attack, input beside output",
                "strongest_by_task": "Strongest attack per task and source (smallest p-value), input and output"}
    for name, t in tables.items():
        write_table(t, out / name, caption=captions[name])
    return tables


def before_after_figure(strongest: pd.DataFrame, path: str | os.PathLike) -> Path:
    """Accuracy of the strongest attack and of the learned attacker per task and source, input
    beside output, with 95% intervals of the strongest attack's accuracy (chance dashed)."""
    import matplotlib.pyplot as plt

    from .plots import clopper_pearson

    t = strongest.reset_index(drop=True)
    labels = [f"{a} | {b}" for a, b in zip(t["task"], t["source"])]
    y = np.arange(len(t))
    fig, ax = plt.subplots(figsize=(7.5, 0.9 + 0.22 * len(t)))
    for col, off, color, name in (("in", -0.18, "#c0392b", "input"), ("out", 0.18, "#2c7fb8", "output")):
        acc, hits, n = t[f"accuracy_{col}"], t[f"hits_{col}"], t[f"picked_{col}"]
        lo, hi = clopper_pearson(hits, n)
        ax.errorbar(acc, y + off, xerr=[acc - lo, hi - acc], fmt="o", ms=3, color=color, elinewidth=0.7,
                    label=f"strongest attack, {name}")
        ax.scatter(t[f"learned_accuracy_{col}"], y + off, marker="x", s=14, color=color,
                   label=f"learned attacker, {name}")
    ax.axvline(0.2, color="k", lw=0.8, ls="--")
    ax.set_yticks(y, labels, fontsize=6)
    ax.invert_yaxis()
    ax.set_xlim(0, 1)
    ax.set_xlabel("accuracy without video; dashed: chance 1/5")
    ax.legend(fontsize=6, loc="lower right")
    return save_figure(fig, path)


def preserved_fields_check(before: list[dict], after: list[dict]) -> list[str]:
    """Differences other than the rebuilt Candidates/Answer (empty when everything is preserved)."""
    problems = []
    if len(before) != len(after):
        return [f"row count {len(before)} != {len(after)}"]
    for i, (a, b) in enumerate(zip(before, after)):
        if list(a) != list(b):
            problems.append(f"row {i}: field order/names differ")
        for k in a:
            if k in ("Candidates", "Answer"):
                continue
            if json.dumps(a[k], ensure_ascii=False) != json.dumps(b.get(k), ensure_ascii=False):
                problems.append(f"row {i}: {k} changed")
        if b["Candidates"].get(b["Answer"]) != a["Answer Detail"]:
            problems.append(f"row {i}: keyed candidate is not the Answer Detail string")
    return problems


__all__ = ["DEFAULT_OPTIONS", "DEFAULT_RELEASE", "ReoptionError", "ReoptionResult", "attack_tables",
           "before_after_figure", "constrained_schedule", "label_balance", "merge_options",
           "preserved_fields_check", "reoption_records", "reoption_release", "side_by_side",
           "strongest_by_task", "value_reuse", "write_audit"]
