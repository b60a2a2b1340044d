"""Candidate synthesis: four distractors per answer, built so that the answer is exchangeable.

The construction (the same for every answer kind):

1. Draw five points *independently from one distribution* around a latent anchor (log-space for
   positive quantities, degrees for angles, centre / log-dimensions / rotation for boxes,
   translation / rotation for poses, magnitudes and turn directions for trajectory phrases).
2. Designate one of the five as the answer: for scalars the one whose signed-value rank equals a
   balanced target rank; otherwise uniformly at random.
3. Move the whole set rigidly (translation in the drawing space, a group action for rotations) so
   that the designated point equals the true answer.
4. Reject and redraw the whole set when a separation constraint fails (symmetric in the five
   points, so the answer stays exchangeable).

Because the five draws are exchangeable and the designation does not look at them, every
option-only rule that does not know the answer (median, rank, centroid, medoid, field majority,
string length, ...) picks the answer with probability exactly 1/5 in expectation. Letters are
assigned afterwards, independently of the values (:func:`assign_letters`).

All parameters (spreads, separations) are keyword arguments with defaults; the task params YAML
files override them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from .. import LETTERS
from .. import values as V
from ..errors import OptionError  # noqa: F401  (raised here; the class lives with every resti error)

MAX_TRIES = 400


@dataclass
class Options:
    """Five candidate strings; ``answer_index`` points at the answer (before lettering)."""

    strings: list[str]
    answer_index: int
    evidence: dict = field(default_factory=dict)


def _distinct(strings: list[str]) -> bool:
    if len(set(strings)) != len(strings):
        return False
    keys = [V.parse(s).key() for s in strings]
    return len(set(keys)) == len(keys)


def _designate_by_rank(z: np.ndarray, target_rank: int | None, rng) -> int:
    if target_rank is None:
        return int(rng.integers(len(z)))
    return int(np.argsort(z, kind="stable")[target_rank - 1])


# ---------------------------------------------------------------------------------------- scalars

def scalar_decimals(value: float, decimals: int = 2, *, min_ulps: float = 20.0, max_decimals: int = 6) -> int:
    """Decimals needed so a positive ``value`` spans at least ``min_ulps`` printed units (0.063 m -> 3)."""
    if value <= 0 or not math.isfinite(value):
        return decimals
    need = math.ceil(math.log10(min_ulps * 10.0 ** -decimals / value)) if value < min_ulps * 10.0 ** -decimals else 0
    return min(max_decimals, decimals + max(0, need))


def scalar_options(value: float, unit: str, *, rng: np.random.Generator, decimals: int = 2,
                   target_rank: int | None = None, log_spread: tuple = (0.10, 0.35),
                   min_log_gap: float = 0.04, positive: bool = True) -> Options:
    """Positive scalars (distances, speeds, lengths): five log-normal draws, answer at ``target_rank``.

    ``log_spread`` bounds the per-row spread s (log-uniform); draws are ``z_i ~ N(0, 1)`` and
    ``value_i = value * exp(s * (z_i - z_r))``; log is monotone, so the answer's signed-value rank is
    the rank of ``z_r``. Adjacent values differ by at least ``min_log_gap`` in log space and by at
    least two printed units. Values of at most 20 printed units (or zero/negative values) use
    additive offsets; there a target rank can be infeasible (0.06 m cannot have four smaller
    distinct 2-decimal values), and after half the tries the rank is left free (the evidence says
    which rank was used). Callers that may choose the format use :func:`scalar_decimals` first.
    """
    ulp = 10.0 ** -decimals
    if not math.isfinite(value):
        raise OptionError(f"answer value is {value}")
    additive = (not positive) or value < 20 * ulp
    for attempt in range(MAX_TRIES):
        if attempt == MAX_TRIES // 2:
            target_rank = None
        s = math.exp(rng.uniform(math.log(log_spread[0]), math.log(log_spread[1])))
        z = rng.standard_normal(5)
        r = _designate_by_rank(z, target_rank, rng)
        if additive:
            step = max(abs(value) * s, 4 * ulp) if abs(value) > 0 else 8 * ulp
            vals = value + step * (z - z[r])
            if positive and (vals < 0).any():
                continue
        else:
            vals = value * np.exp(s * (z - z[r]))
            gaps = np.diff(np.sort(np.log(vals)))
            if gaps.min() < min_log_gap:
                continue
        vs = np.sort(vals)
        if np.diff(vs).min() < 2 * ulp:
            continue
        strings = [V.format_scalar(v, unit, decimals) for v in vals]
        strings[r] = V.format_scalar(value, unit, decimals)
        if _distinct(strings):
            return Options(strings, r, {"spread": round(s, 4), "rank": int(np.argsort(np.argsort(z))[r]) + 1,
                                        "additive": additive})
    raise OptionError(f"no distinct scalar options for {value} {unit}")


def angle_options(deg: float, *, rng: np.random.Generator, decimals: int = 2, target_rank: int | None = None,
                  spread: tuple = (4.0, 30.0), min_sep: float = 1.0) -> Options:
    """Signed angles in [-180, 180): jittered offsets, wrapped, >= ``min_sep`` circular separation.

    The answer's signed-value rank (after wrapping) equals ``target_rank`` when given.
    """
    ans = float(V.wrap_degrees(deg))
    for attempt in range(MAX_TRIES):
        if attempt == MAX_TRIES // 2:
            # near the wrap (e.g. 179.4° asked to be the smallest) a rank can be infeasible:
            # give up the target rank rather than the row; the evidence records the rank used
            target_rank = None
        s = math.exp(rng.uniform(math.log(spread[0]), math.log(spread[1])))
        z = rng.standard_normal(5)
        choices = list(range(5))
        rng.shuffle(choices)
        for r in choices:
            vals = V.wrap_degrees(ans + s * (z - z[r]))
            vals[r] = ans
            rank = int(np.argsort(np.argsort(vals, kind="stable"))[r]) + 1
            if target_rank is not None and rank != target_rank:
                continue
            d = np.abs(V.wrap_degrees(vals[:, None] - vals[None, :]))
            np.fill_diagonal(d, 360.0)
            if d.min() < min_sep:
                break
            strings = [V.format_angle(v, decimals) for v in vals]
            if _distinct(strings):
                return Options(strings, r, {"spread_deg": round(s, 3), "rank": rank})
            break
    raise OptionError(f"no angle options for {deg}")


# ------------------------------------------------------------------------------------ structured

def _yaw(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _axis_rot(axis: np.ndarray, theta: float) -> np.ndarray:
    return Rotation.from_rotvec(np.asarray(axis, float) / np.linalg.norm(axis) * theta).as_matrix()


def _min_pairwise(X: np.ndarray) -> float:
    d = np.sqrt(((X[:, None, :] - X[None, :, :]) ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    return float(d.min())


def _min_rot_angle(Rs: list[np.ndarray]) -> float:
    best = np.inf
    for i in range(len(Rs)):
        for j in range(i + 1, len(Rs)):
            c = (np.trace(Rs[i].T @ Rs[j]) - 1) / 2
            best = min(best, math.degrees(math.acos(max(-1.0, min(1.0, c)))))
    return best


def box_options(center, lwh, R, *, rng: np.random.Generator, center_sigma: float, dims_sigma: float = 0.12,
                yaw_sigma_deg: float = 25.0, tilt_sigma_deg: float = 0.0, up_axis: int | None = 2,
                min_center_sep: float | None = None, min_log_dims_sep: float = 0.05,
                min_rot_sep_deg: float = 3.0) -> Options:
    """Grounding boxes: joint exchangeable draws in centre, log-dimensions and rotation.

    ``center_sigma`` (metres) is source-scaled by the caller (e.g. a fraction of the box size
    plus a floor per source). Rotations: ``R_i = R_ans · Q_r^T · Q_i`` with ``Q_i`` rotations about
    the box-local ``up_axis`` (yaw, ``yaw_sigma_deg``) composed with an optional tilt; with
    ``up_axis=None`` the perturbation is a full 3D rotation of ``tilt_sigma_deg``. Every candidate
    keeps the answer's up direction when ``tilt_sigma_deg == 0``, so "most upright box" reveals nothing.
    """
    c0, d0, R0 = np.asarray(center, float), np.asarray(lwh, float), np.asarray(R, float)
    if np.any(d0 <= 0):
        raise OptionError(f"non-positive box size {d0}")
    sep = min_center_sep if min_center_sep is not None else 0.5 * center_sigma
    for _ in range(MAX_TRIES):
        dc = rng.normal(0.0, center_sigma, (5, 3))
        dd = rng.normal(0.0, dims_sigma, (5, 3))
        Q = []
        for _i in range(5):
            q = np.eye(3)
            if up_axis is not None:
                axis = np.zeros(3)
                axis[up_axis] = 1.0
                q = _axis_rot(axis, math.radians(rng.normal(0.0, yaw_sigma_deg)))
            if tilt_sigma_deg > 0:
                q = q @ Rotation.from_rotvec(rng.normal(0.0, math.radians(tilt_sigma_deg), 3)).as_matrix()
            Q.append(q)
        r = int(rng.integers(5))
        centers = c0 + (dc - dc[r])
        dims = d0 * np.exp(dd - dd[r])
        rots = [R0 @ Q[r].T @ Q[i] for i in range(5)]
        if _min_pairwise(centers) < sep or _min_pairwise(np.log(dims)) < min_log_dims_sep:
            continue
        if _min_rot_angle(rots) < min_rot_sep_deg:
            continue
        strings = [V.format_box(centers[i], dims[i], rots[i]) for i in range(5)]
        strings[r] = V.format_box(c0, d0, R0)
        if _distinct(strings):
            return Options(strings, r, {"center_sigma": round(center_sigma, 4)})
    raise OptionError("no box options under the separation constraints")


def pose_options(T, *, rng: np.random.Generator, trans_sigma: float, up=(0.0, 0.0, 1.0),
                 yaw_sigma_deg: float = 20.0, z_scale: float = 0.3, min_trans_sep: float | None = None,
                 min_rot_sep_deg: float = 3.0, decimals: int = 2, compact: bool = False) -> Options:
    """Pose matrices: exchangeable draws of translation and of rotation about the world ``up``.

    ``R_i = Q_i Q_r^T R_ans`` (left-multiplied world-frame rotations about ``up``) keeps every
    candidate's tilt equal to the answer's, so gravity-aligned entries reveal nothing; the
    translation offsets are ``trans_sigma`` horizontally and ``z_scale * trans_sigma`` along ``up``.
    Rotations are exact before rounding, so every printed matrix is valid to the rounding.
    """
    T = np.asarray(T, float)
    R0, t0 = T[:3, :3], T[:3, 3]
    up = np.asarray(up, float) / np.linalg.norm(up)
    sep = min_trans_sep if min_trans_sep is not None else 0.4 * trans_sigma
    P = np.eye(3) - np.outer(up, up)
    for _ in range(MAX_TRIES):
        d = rng.normal(0.0, trans_sigma, (5, 3))
        d = d @ P + np.outer(d @ up, up) * z_scale
        Q = [_axis_rot(up, math.radians(rng.normal(0.0, yaw_sigma_deg))) for _ in range(5)]
        r = int(rng.integers(5))
        ts = t0 + (d - d[r])
        rots = [Q[i] @ Q[r].T @ R0 for i in range(5)]
        if _min_pairwise(ts) < sep or _min_rot_angle(rots) < min_rot_sep_deg:
            continue
        mats = []
        for i in range(5):
            M = np.eye(4)
            M[:3, :3], M[:3, 3] = rots[i], ts[i]
            mats.append(M)
        strings = [V.format_pose(M, decimals, compact=compact) for M in mats]
        strings[r] = V.format_pose(T, decimals, compact=compact)
        if _distinct(strings):
            return Options(strings, r, {"trans_sigma": round(trans_sigma, 4)})
    raise OptionError("no pose options under the separation constraints")


def trajectory_options(segments, *, rng: np.random.Generator, move_log_sigma: float = 0.25,
                       turn_sigma_deg: float = 20.0, flip_prob: float = 0.3, min_rel_diff: float = 0.08
                       ) -> Options:
    """Trajectory phrases of the answer's structure: exchangeable draws of move lengths (log space),
    turn magnitudes and turn directions. ``no significant movement`` answers get moving distractors
    drawn from a single short move (their structure cannot be kept)."""
    segs = list(segments)
    if not segs:
        # the answer is "no significant movement": the four others are single short moves; this
        # cannot be made exchangeable (a label), and the row's evidence says so
        for _ in range(MAX_TRIES):
            lengths = np.exp(rng.normal(math.log(8.0), 0.6, 4))
            strings = [V.format_trajectory([("move", float(x))]) for x in lengths]
            r = int(rng.integers(5))
            strings.insert(r, V.NO_MOVEMENT)
            if _distinct(strings):
                return Options(strings, r, {"structure": "none", "exchangeable": False})
        raise OptionError("no options for a no-movement answer")
    kinds = [k for k, _ in segs]
    moves = [j for j, k in enumerate(kinds) if k == "move"]
    turns = [j for j, k in enumerate(kinds) if k == "turn"]
    mags = np.array([abs(v) for _, v in segs], float)
    signs = np.array([math.copysign(1, v) if k == "turn" else 1.0 for k, v in segs])
    total0 = float(mags[moves].sum())
    logit0 = np.log(mags[moves] / total0)
    for _ in range(MAX_TRIES):
        # 1-D exchangeable draw of the total distance (so rank/mean/medoid attacks on it see chance),
        # exchangeable draws of the split between moves (log-ratio space) and of the turns
        z = rng.standard_normal(5)
        split = rng.normal(0, move_log_sigma, (5, len(moves)))
        tnoise = rng.normal(0, turn_sigma_deg, (5, len(turns)))
        flips = np.where(rng.random((5, len(turns))) < flip_prob, -1.0, 1.0)
        r = int(rng.integers(5))
        totals = total0 * np.exp(move_log_sigma * (z - z[r]))
        cands = []
        for i in range(5):
            w = np.exp(logit0 + split[i] - split[r])
            lengths = totals[i] * w / w.sum()
            tm = mags[turns] + tnoise[i] - tnoise[r]
            seg_i, mi, ti = [], 0, 0
            for j, k in enumerate(kinds):
                if k == "move":
                    seg_i.append(("move", float(lengths[mi])))
                    mi += 1
                else:
                    seg_i.append(("turn", float(signs[j] * flips[i, ti] * flips[r, ti] * tm[ti])))
                    ti += 1
            cands.append(seg_i)
        # turn magnitudes stay in (0, 180): reflect instead of rejecting, so no rank is favoured
        for c in cands:
            for j, (k, v) in enumerate(c):
                if k == "turn":
                    m = abs(v) % 360.0
                    m = 360.0 - m if m > 180.0 else m
                    c[j] = ("turn", math.copysign(max(m, 1.0), v))
        ts = np.sort(totals)
        if (np.diff(ts) / ts[1:]).min() < min_rel_diff:
            continue
        strings = [V.format_trajectory(c) for c in cands]
        strings[r] = V.format_trajectory(segs)
        if _distinct(strings):
            return Options(strings, r, {"structure": "same", "exchangeable": True})
    raise OptionError("no trajectory options")


def label_options(answer: str, labels: list[str]) -> Options:
    """Categorical answers: the fixed label set of the task/source (the answer among them)."""
    if answer not in labels:
        raise OptionError(f"label {answer!r} not in {labels}")
    if len(labels) != 5:
        raise OptionError(f"need five labels, got {labels}")
    return Options(list(labels), labels.index(answer), {"labels": list(labels)})


# ---------------------------------------------------------------------------------------- letters

def assign_letters(opts: Options, answer_letter: str, rng: np.random.Generator) -> tuple[dict, str]:
    """Place the answer at ``answer_letter`` (a balanced schedule decides it) and the four others
    in a random order on the remaining letters."""
    others = [s for i, s in enumerate(opts.strings) if i != opts.answer_index]
    order = rng.permutation(4)
    rest = [L for L in LETTERS if L != answer_letter]
    cands = {answer_letter: opts.strings[opts.answer_index]}
    for L, k in zip(rest, order):
        cands[L] = others[int(k)]
    return {L: cands[L] for L in LETTERS}, answer_letter
