"""The ``trajectory`` operator: the entity's motion as "move forward" / "turn" segments.

Statistic: distances are path lengths along the source trajectory, turns are net heading changes
of the forward axis in the horizontal plane (left = counter-clockwise seen from above).

Operator (:func:`describe_motion`)
----------------------------------
1. The total path length below ``no_movement_m`` -> ``no significant movement``.
2. Turn windows from :func:`resti_lib.geometry.trajectory.segment_turns` (steps turning faster
   than ``turn_rate_deg_s``, turns below ``turn_threshold_deg`` dropped).
3. Each window is widened over the adjacent steps that still turn the same way at
   ``settle_rate_deg_s`` or faster, so the net heading change covers the whole turn (a turn eases
   in and out below the detection rate).
4. A turn splits the path at the source sample nearest to the time the turn is half done
   (heading half-way between its start and end); a move is the path length between consecutive
   splits (the interval ends are splits). Moves shorter than ``min_move_m`` are dropped and the
   turns around them merge when they turn the same way.

Interval (:func:`track_interval`): an end within half a sampling interval outside the track is
moved onto its first / last sample, and half the median sampling interval is the time tolerance.
"""

from __future__ import annotations

import math

import numpy as np

from .. import values as V
from ..defaults import setting
from ..errors import ContractError
from ..geometry import trajectory as G
from ..geometry.trajectory import PoseTrack
from .registry import MeasureContext, register_operator

__all__ = ["FORWARD", "UP", "describe_motion", "motion_settings", "track_interval"]

FORWARD = (0.0, 0.0, 1.0)  # OpenCV optical axis
UP = (0.0, 0.0, 1.0)  # Waymo world up
KNOBS = ("turn_rate_deg_s", "turn_threshold_deg", "settle_rate_deg_s", "min_move_m", "no_movement_m")


def _samples(track: PoseTrack, t0: float, t1: float, rule: str, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Times and poses of ``[pose(t0), source samples strictly inside, pose(t1)]``."""
    T_end, _ = G.pose_at(track, np.array([t0, t1]), rule, tol)
    inside = np.flatnonzero((track.times > t0 + tol) & (track.times < t1 - tol))
    if not track.valid[inside].all():
        raise ContractError(f"{track.name}: invalid pose(s) inside [{t0:.6f}, {t1:.6f}] s")
    ts = np.concatenate([[t0], track.times[inside], [t1]])
    T = np.concatenate([T_end[:1], track.T[inside], T_end[1:]], axis=0)
    return ts, T


def describe_motion(track: PoseTrack, t0: float, t1: float, *, turn_rate_deg_s: float = 3.0,
                    turn_threshold_deg: float = 15.0, settle_rate_deg_s: float = 0.5, min_move_m: float = 1.0,
                    no_movement_m: float = 2.0, forward_axis=FORWARD, up=UP, rule: str = "linear",
                    tol: float = G.DEFAULT_TOL) -> tuple[list[tuple[str, float]], dict]:
    """Segment the motion in ``[t0, t1]`` into moves and turns (algorithm in the module docstring).

    Parameters
    ----------
    track : PoseTrack
        ``T_world_from_entity`` samples; ``forward_axis`` in the entity frame, ``up`` in the world.
    t0, t1 : float
        Interval (seconds on the track's timeline); shortened when the track ends in invalid poses.
    turn_rate_deg_s, turn_threshold_deg, min_move_m :
        Detection parameters passed to :func:`resti_lib.geometry.trajectory.segment_turns`.
    settle_rate_deg_s : float
        Adjacent steps turning the same way at least this fast belong to the turn.
    no_movement_m : float
        A total path length below this is "no significant movement".

    Returns
    -------
    segments : list of ``("move", metres)`` and ``("turn", signed degrees, left > 0)`` (the
        :func:`resti_lib.values.format_trajectory` input); empty for no significant movement.
    evidence : dict
        Path length, per-turn windows (detected and widened), split times and sample indices,
        per-move distances, the parameters.
    """
    (t0, t1), ev = G.interval_valid(track, t0, t1, tol=tol)
    ts, T = _samples(track, t0, t1, rule, tol)
    ds = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1)
    cs = np.concatenate([[0.0], np.cumsum(ds)])
    total = float(cs[-1])
    params = {"turn_rate_deg_s": turn_rate_deg_s, "turn_threshold_deg": turn_threshold_deg,
              "settle_rate_deg_s": settle_rate_deg_s, "min_move_m": min_move_m, "no_movement_m": no_movement_m,
              "forward_axis": list(map(float, forward_axis)), "up": list(map(float, up)), "rule": rule}
    ev.update(track.describe())
    ev.update({"path_length_m": total, "n_samples": int(ts.size), "params": params,
               "distances": "path length between turn split samples",
               "turns": "net horizontal heading change of the forward axis over the widened turn window"})
    if total < no_movement_m:
        ev["summary"] = V.NO_MOVEMENT
        return [], ev
    _, sev = G.segment_turns(track, t0, t1, turn_threshold_deg=turn_threshold_deg, min_move_m=min_move_m,
                             turn_rate_deg_s=turn_rate_deg_s, forward_axis=forward_axis, up=up, rule=rule,
                             tol=tol)
    psi_rel = G.horizontal_heading_deg(T[:1, :3, :3], T[:, :3, :3], forward_axis, up)
    if not np.isfinite(psi_rel).all():
        raise ContractError(f"{track.name}: forward axis vertical at some sample; headings undefined")
    psi = np.degrees(np.unwrap(np.radians(psi_rel)))
    dt = np.diff(ts)
    rate = np.diff(psi) / np.where(dt > 0, dt, np.inf)

    def idx(t: float) -> int:
        return int(np.argmin(np.abs(ts - t)))

    windows = [(idx(s["t_start"]), idx(s["t_end"])) for s in sev["segments"] if s["kind"].startswith("turn")]
    turns = []
    for j, (a, b) in enumerate(windows):
        a0, b0 = a, b
        sign = 1.0 if psi[b] >= psi[a] else -1.0
        lo = turns[-1]["b"] if turns else 0
        hi = windows[j + 1][0] if j + 1 < len(windows) else ts.size - 1
        while a > lo and sign * rate[a - 1] >= settle_rate_deg_s:
            a -= 1
        while b < hi and sign * rate[b] >= settle_rate_deg_s:
            b += 1
        dpsi = float(psi[b] - psi[a])
        target = psi[a] + 0.5 * dpsi
        k = a + int(np.flatnonzero(sign * (psi[a + 1:b + 1] - target) >= 0)[0])  # first sample past half
        f = (target - psi[k - 1]) / (psi[k] - psi[k - 1]) if psi[k] != psi[k - 1] else 1.0
        t_half = float(ts[k - 1] + f * (ts[k] - ts[k - 1]))
        turns.append({"a": a, "b": b, "detected": [float(ts[a0]), float(ts[b0])],
                      "window": [float(ts[a]), float(ts[b])], "heading_change_deg": dpsi, "t_half": t_half,
                      "split": idx(t_half)})
    splits = [0] + [tr["split"] for tr in turns] + [ts.size - 1]
    moves = [float(cs[splits[i + 1]] - cs[splits[i]]) for i in range(len(splits) - 1)]
    segs: list[tuple[str, float]] = []
    dropped = 0.0
    for i, m in enumerate(moves):
        if m >= min_move_m:
            segs.append(("move", m))
        else:
            dropped += m
        if i < len(turns):
            d = turns[i]["heading_change_deg"]
            if segs and segs[-1][0] == "turn" and math.copysign(1, segs[-1][1]) == math.copysign(1, d):
                segs[-1] = ("turn", segs[-1][1] + d)
            else:
                segs.append(("turn", d))
    ev.update({"turn_windows": [{k: v for k, v in tr.items() if k not in ("a", "b")}
                                | {"split_time": float(ts[tr["split"]])} for tr in turns],
               "split_times": [float(ts[s]) for s in splits], "moves_m": moves,
               "unreported_short_moves_m": dropped, "segments": [list(s) for s in segs]})
    return segs, ev


def motion_settings(params: dict | None) -> dict:
    """The detection knobs of :func:`describe_motion` (settings ``turn_rate_deg_s`` ... ``no_movement_m``)."""
    return {k: float(setting(params, k)) for k in KNOBS}


def track_interval(track: PoseTrack, t0: float, t1: float) -> tuple[float, float, float]:
    """``(t0, t1, tol)``: ends within half a sampling interval outside the track moved onto its
    first / last sample; ``tol`` = half the median sampling interval."""
    tol = 0.5 * float(np.median(np.diff(track.times)))
    t0 = max(float(t0), float(track.times[0])) if t0 >= track.times[0] - tol else t0
    t1 = min(float(t1), float(track.times[-1])) if t1 <= track.times[-1] + tol else t1
    return t0, t1, tol


@register_operator("trajectory", unit=None, n_times=(2,))
def _op_trajectory(ctx: MeasureContext) -> tuple[str, dict]:
    """Trajectory phrase of the entity over [t0, t1] (moves = path length between turn splits);
    the evidence holds the segments (``segments``) and the interval used (``t0``, ``t1_used``)."""
    et = ctx.entity_track()
    t0, t1, tol = track_interval(et.track, ctx.t0, ctx.t1)
    segs, ev = describe_motion(et.track, t0, t1, forward_axis=et.forward_axis, up=et.up, rule=ctx.rule, tol=tol,
                               **motion_settings(ctx.params))
    ctx.evidence.update({"world": et.world, "subject": et.subject})
    return V.format_trajectory(segs), ev
