"""Trajectory Description (Waymo): the camera's motion as "move forward" / "turn" segments.

Contract
--------
Subject: the video's camera (``world_from_vehicle @ extrinsic``, OpenCV axes, forward +Z); world:
the segment's world frame, up = world +Z; interval: the row's ``[time_start, time_end]`` (the whole
video). Statistic: distances are path lengths along the source trajectory, turns are net heading
changes of the optical axis in the horizontal plane (left = counter-clockwise seen from above).

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

No grid: distances come from the timestamped source positions (``move_decimals`` in the answer).
The legacy distances sat on a 10 m grid (``trajectory_10m_grid``, detected by :func:`on_grid`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from .. import values as V
from ..adjudicate import Rule, verdict_for
from ..contract import parse_question
from ..errors import ContractError, InputError
from ..figures import save_figure
from ..geometry import trajectory as G
from ..geometry.trajectory import PoseTrack
from ..measure import MeasureContext, register_operator
from .base import AnswerSpec, Outcome

TASK = "Trajectory Description"
FORWARD = (0.0, 0.0, 1.0)  # OpenCV optical axis
UP = (0.0, 0.0, 1.0)  # Waymo world up

#: Defaults of the task parameters (``params/trajectory.yaml`` overrides them).
DEFAULTS = {
    "turn_rate_deg_s": 3.0,
    "turn_threshold_deg": 15.0,
    "settle_rate_deg_s": 0.5,
    "min_move_m": 1.0,
    "no_movement_m": 2.0,
    "grid_m": 10.0,
    "compare_abs_tol_m": 0.25,
    "compare_rel_tol": 0.0,
    "compare_turn_tol_deg": 2.0,
    "pose_rule": "linear",
}


def _p(params: dict, key: str):
    v = params.get(key)
    return DEFAULTS[key] if v is None else v


# ------------------------------------------------------------------------------------ operator


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


def on_grid(traj: V.Trajectory, grid_m: float = 10.0) -> bool:
    """True when every move distance of a phrase is a positive multiple of ``grid_m`` metres."""
    moves = [v for k, v in traj.segments if k == "move"]
    return bool(moves) and all(v > 0 and abs(v / grid_m - round(v / grid_m)) < 1e-9 for v in moves)


def compare(legacy: V.Trajectory, segs: list[tuple[str, float]], rule: Rule, turn_tol_deg: float) -> dict:
    """Field-by-field comparison of a legacy phrase with the source segments.

    Same structure (move/turn pattern and turn directions) is required; each move agrees within
    half a unit of its printed place + ``rule.abs_tol`` + ``rule.rel_tol``·d, each turn within half a
    degree + ``turn_tol_deg``.
    """
    new = V.Trajectory(segments=tuple(segs), text="")
    out = {"legacy_structure": list(legacy.structure), "source_structure": list(new.structure),
           "same_structure": legacy.structure == new.structure}
    if not out["same_structure"]:
        out["agrees"] = False
        return out
    errs, ok = [], True
    for (k, lv), (_, nv), dec in zip(legacy.segments, segs, legacy.segment_decimals):
        err = abs(lv - nv)
        errs.append(err)
        if k == "move":
            ok &= err <= 0.5 * 10.0 ** -dec + rule.abs_tol + rule.rel_tol * abs(nv) + 1e-9
        else:
            ok &= err <= 0.5 + turn_tol_deg + 1e-9
    out.update({"errors": errs, "agrees": bool(ok), "rule": rule.describe() + f"; turns within 0.5 + "
                f"{turn_tol_deg:g} deg"})
    return out


# ------------------------------------------------------------------------------------- the task


def _new(r: dict) -> Outcome:
    return Outcome(row=int(r["row"]), key=r["Legacy Row Key"], task=TASK, source=str(r["Source"]),
                   video=str(r["Video"]), legacy_id=r.get("ID"), verdict="retained",
                   legacy_detail=str(r.get("Answer Detail")))


def question_text(t0: float, t1: float) -> str:
    """The rewritten question (v5 wording): interval, path-length distances, net-heading turns."""
    return (f"Which option best describes the camera's movement trajectory between t={V.format_seconds(t0)} s and "
            f"t={V.format_seconds(t1)} s? Distances are path lengths along the trajectory and turns are net heading changes.")


def _kw(params: dict) -> dict:
    return {k: float(_p(params, k)) for k in ("turn_rate_deg_s", "turn_threshold_deg", "settle_rate_deg_s",
                                              "min_move_m", "no_movement_m")}


def audit_row(r: dict, ctx, params: dict) -> Outcome:
    """One legacy row -> Outcome (see :func:`audit`)."""
    o = _new(r)
    c = parse_question(r, video_map=ctx.video_map)
    vs = ctx.locate(r["Video"])
    if vs.source != "Waymo" or vs.camera is None:
        return o.exclude("unsupported_question", detail="trajectory rows need a Waymo camera video",
                         source=vs.source)
    seg = ctx.waymo(vs.sequence)
    track = seg.camera_track(vs.camera)
    t0, t1 = (c.times + [c.times[-1]])[:2] if c.times else (float(r["time_start"]), float(r["time_end"]))
    tol = 0.5 * float(np.median(np.diff(track.times)))
    t0 = max(float(t0), float(track.times[0])) if t0 >= track.times[0] - tol else t0
    t1 = min(float(t1), float(track.times[-1])) if t1 <= track.times[-1] + tol else t1
    o.source_files = [str(seg.path("vehicle_pose")), str(seg.path("camera_calibration"))]
    o.transform_chain = "world_from_vehicle(t) @ extrinsic(camera) @ T_waymo_cam<-cv_cam"
    rule = str(_p(params, "pose_rule"))
    try:
        segs, ev = describe_motion(track, t0, t1, rule=rule, tol=tol, **_kw(params))
    except ContractError as e:
        return o.exclude("invalid_pose_at_time", error=str(e), interval=[t0, t1])
    t1u = float(ev.get("t1_used", t1))
    o.frames = {"camera": int(vs.camera), "interval_s": [t0, t1u], "n_samples": ev["n_samples"],
                "frame_timestamp_micros": [int(track.meta["micros"][0]), int(track.meta["micros"][-1])]}
    c.entity = {"kind": "camera", "camera": int(vs.camera)}
    c.times = [t0, t1u]
    c.frame = "Waymo segment world frame, up +Z; camera forward = OpenCV +Z"
    c.unit = "m"
    c.params.update({"distances": "path length between turn split samples",
                     "turns": "net horizontal heading change (left positive)"})
    o.contract = c.to_dict()
    o.evidence["operator"] = ev
    grid = float(_p(params, "grid_m"))
    comparable = True
    try:
        legacy = V.parse(r.get("Answer Detail"), row=o.row, field="Answer Detail")
        if not isinstance(legacy, V.Trajectory):
            raise InputError("not a trajectory phrase")
    except InputError as e:
        legacy, comparable = None, False
        o.evidence["legacy_unreadable"] = str(e)
    agrees = None
    if legacy is not None:
        rule_c = Rule(abs_tol=float(_p(params, "compare_abs_tol_m")), rel_tol=float(_p(params, "compare_rel_tol")))
        cmp = compare(legacy, segs, rule_c, float(_p(params, "compare_turn_tol_deg")))
        agrees = cmp["agrees"]
        o.evidence["comparison"] = cmp
        if on_grid(legacy, grid):
            o.defects.append("trajectory_10m_grid")
            o.evidence["grid"] = {"grid_m": grid, "legacy_moves_m": [v for k, v in legacy.segments if k == "move"],
                                  "source_moves_m": [v for k, v in segs if k == "move"]}
        if not agrees and (not cmp["same_structure"] or not on_grid(legacy, grid)):
            o.defects.append("value_mismatch")  # not explained by the grid
    o.verdict = verdict_for(comparable, agrees)
    o.question = question_text(t0, t1u)
    o.prompt = ""
    o.time_start, o.time_end = t0, t1u
    o.answer = AnswerSpec(kind="trajectory", value=segs)
    return o


def audit(rows: pd.DataFrame, ctx, params: dict) -> list[Outcome]:
    """Task-module entry point: one :class:`Outcome` per legacy Trajectory Description row."""
    return [audit_row(r, ctx, params) for r in rows.to_dict("records")]


# ---------------------------------------------------------------------------------- reporting


def diagnosis_table(outcomes: list[Outcome]) -> pd.DataFrame:
    """Per row: legacy phrase, source phrase, grid flag, largest move error and the path length."""
    recs = []
    for o in outcomes:
        op = o.evidence.get("operator", {})
        cmp = o.evidence.get("comparison", {})
        segs = [tuple(s) for s in op.get("segments", [])]
        errs = cmp.get("errors") or []
        recs.append({"row": o.row, "video": o.video, "verdict": o.verdict,
                     "legacy": o.legacy_detail, "source": V.format_trajectory(segs) if o.verdict != "excluded" else None,
                     "on_10m_grid": "trajectory_10m_grid" in o.defects,
                     "same_structure": cmp.get("same_structure"),
                     "max_abs_error": max(errs) if errs else None,
                     "path_length_m": op.get("path_length_m")})
    return pd.DataFrame(recs)


def _draw_path(ax, track: PoseTrack, evidence: dict, title: str) -> None:
    """Top-down camera path (world x-y) with the turn windows and the split samples, on ``ax``."""
    t0 = float(evidence.get("t0", track.times[0]))
    t1 = float(evidence.get("t1_used", track.times[-1]))
    sel = (track.times >= t0 - 1e-6) & (track.times <= t1 + 1e-6) & track.valid
    p = track.positions[sel]
    tt = track.times[sel]
    ax.plot(p[:, 0] - p[0, 0], p[:, 1] - p[0, 1], color="#2c7fb8", lw=1.5, label="move")
    for w in evidence.get("turn_windows", []):
        m = (tt >= w["window"][0] - 1e-9) & (tt <= w["window"][1] + 1e-9)
        ax.plot(p[m, 0] - p[0, 0], p[m, 1] - p[0, 1], color="#d95f0e", lw=3.0)
        k = int(np.argmin(np.abs(tt - w["split_time"])))
        ax.scatter([p[k, 0] - p[0, 0]], [p[k, 1] - p[0, 1]], color="k", s=14, zorder=3)
        d = w["heading_change_deg"]
        ax.annotate(f"{'left' if d > 0 else 'right'} {abs(d):.0f}°", (p[k, 0] - p[0, 0], p[k, 1] - p[0, 1]),
                    textcoords="offset points", xytext=(6, 6), fontsize=8)
    ax.scatter([0.0], [0.0], marker="o", color="#2c7fb8", s=20, zorder=3)
    ax.plot([], [], color="#d95f0e", lw=3.0, label="turn window")
    ax.scatter([], [], color="k", s=14, label="split sample")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("world x − x(t0) [m]")
    ax.set_ylabel("world y − y(t0) [m]")
    ax.set_title(title, fontsize=8, loc="left", wrap=True)


def plot_path(track: PoseTrack, evidence: dict, path: str | Path, *, title: str = "") -> Path:
    """Top-down camera path (world x-y) with the turn windows and the split samples of one row."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.0, 4.2), layout="constrained")
    segs = [tuple(s) for s in evidence.get("segments", [])]
    _draw_path(ax, track, evidence, title or V.format_trajectory(segs))
    ax.legend(frameon=False, fontsize=7, loc="best")
    return save_figure(fig, path)


def plot_paths(outcomes: list[Outcome], params: dict, fig_dir: str | Path, *, prefix: str = "07_trajectory_path",
               max_plots: int = 4) -> list[Path]:
    """One figure ``<fig_dir>/<prefix>s.png`` with the top-down paths of up to ``max_plots`` rows
    on distinct source segments (the cameras of one segment share its path), those with the most
    turns first; one legend for all panels. Returns ``[path]`` (``[]`` without an accepted row)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..sources.context import SourceContext

    ctx = SourceContext.from_params(params)
    seen, chosen = set(), []
    ranked = sorted((o for o in outcomes if o.verdict != "excluded" and "operator" in o.evidence),
                    key=lambda o: (-len(o.evidence["operator"].get("turn_windows", [])), o.row))
    for o in ranked:
        vs = ctx.locate(o.video)
        if vs.sequence not in seen:
            seen.add(vs.sequence)
            chosen.append((o, vs))
        if len(chosen) == max_plots:
            break
    if not chosen:
        return []
    ncol = 2 if len(chosen) > 1 else 1
    nrow = -(-len(chosen) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(11.0, 4.6 * nrow), squeeze=False, layout="constrained")
    for ax in axes.flat[len(chosen):]:
        ax.set_visible(False)
    for ax, (o, vs) in zip(axes.flat, chosen):
        track = ctx.waymo(vs.sequence).camera_track(vs.camera)
        segs = [tuple(s) for s in o.evidence["operator"].get("segments", [])]
        _draw_path(ax, track, o.evidence["operator"], f"{o.video}\n{V.format_trajectory(segs)}")
    h, lab = axes.flat[0].get_legend_handles_labels()
    fig.legend(h, lab, loc="outside lower center", ncol=3, frameon=False)
    return [save_figure(fig, Path(fig_dir) / f"{prefix}s.png")]


# ------------------------------------------------------------------------------ measure operator


@register_operator("trajectory", unit=None, n_times=(2,))
def _op_trajectory(mctx: MeasureContext) -> tuple[str, dict]:
    """Trajectory phrase of the entity over [t0, t1] (moves = path length between turn splits)."""
    et = mctx.entity_track()
    kw = {k: float(mctx.params.get(f"trajectory_{k}", DEFAULTS[k])) for k in
          ("turn_rate_deg_s", "turn_threshold_deg", "settle_rate_deg_s", "min_move_m", "no_movement_m")}
    segs, ev = describe_motion(et.track, mctx.t0, mctx.t1, forward_axis=et.forward_axis, up=et.up,
                               rule=mctx.rule, tol=mctx.tol, **kw)
    mctx.evidence.update({"world": et.world, "subject": et.subject})
    return V.format_trajectory(segs), ev


__all__ = [
    "DEFAULTS",
    "TASK",
    "audit",
    "audit_row",
    "compare",
    "describe_motion",
    "diagnosis_table",
    "on_grid",
    "plot_path",
    "plot_paths",
    "question_text",
]
