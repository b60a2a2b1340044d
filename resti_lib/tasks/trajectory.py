"""Trajectory Description (Waymo): the camera's motion as "move forward" / "turn" segments.

Contract
--------
Subject: the video's camera (``world_from_vehicle @ extrinsic``, OpenCV axes, forward +Z); world:
the segment's world frame, up = world +Z; interval: the row's ``[time_start, time_end]`` (the whole
video). Statistic: distances are path lengths along the source trajectory, turns are net heading
changes of the optical axis in the horizontal plane (left = counter-clockwise seen from above).

Operator: the measure operator ``trajectory`` (:mod:`resti_lib.measure.trajectory`): turn windows,
widened over the steps still turning, split at the half-done sample; moves are path lengths between
splits, short moves dropped. No grid: distances come from the timestamped source positions
(``move_decimals`` in the answer). The legacy distances sat on a 10 m grid
(``trajectory_10m_grid``, detected by :func:`on_grid`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .. import values as V
from ..adjudicate import Diagnosis, Rule
from ..contract import Contract, base_contract, interval
from ..errors import ContractError
from ..geometry.trajectory import PoseTrack
from ..io.figures import save_figure
from ..measure.trajectory import describe_motion, track_interval
from . import register_task
from .base import AnswerSpec, Case, Exclude, Outcome, Task

TASK = "Trajectory Description"


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


def question_text(t0: float, t1: float) -> str:
    """The rewritten question (v5 wording): interval, path-length distances, net-heading turns."""
    return (f"Which option best describes the camera's movement trajectory between t={V.format_seconds(t0)} s and "
            f"t={V.format_seconds(t1)} s? Distances are path lengths along the trajectory and turns are net heading changes.")


@register_task
class Trajectory(Task):
    name = TASK
    params_name = "trajectory"
    notebook = "07_trajectory"
    order = 7
    answer_kind = "trajectory"
    rule_key = "compare_abs_tol_m"
    quantity = "trajectory"
    figures = {
        "paths": ("Trajectory Description: top-down camera paths of distinct Waymo segments with the turn windows "
                  "and the samples that split the moves."),
    }
    legacy_kind = V.Trajectory
    operators = ("trajectory",)


    def rule(self, settings: dict, source: str) -> Rule:
        """Each move's distance within half a printed unit + ``compare_abs_tol_m`` +
        ``compare_rel_tol``·d (turns are compared on their own, ``compare_turn_tol_deg``)."""
        return Rule(abs_tol=float(settings["compare_abs_tol_m"]), rel_tol=float(settings["compare_rel_tol"]))

    def read_contract(self, row: dict, video_map: dict | None = None) -> Contract:
        c, _ = base_contract(row, "trajectory", video_map=video_map)
        c.entity = {"kind": "camera"}
        c.times = interval(c, row)
        return c

    def reconstruct(self, case: Case) -> None:
        c, r = case.contract, case.row
        if c.source != "Waymo" or c.camera is None:
            raise Exclude("unsupported_question", detail="trajectory rows need a Waymo camera video", source=c.source)
        seg = case.ctx.waymo(c.sequence)
        track = seg.camera_track(c.camera)
        t0, t1 = (c.times + [c.times[-1]])[:2] if c.times else (float(r["time_start"]), float(r["time_end"]))
        case.provenance(files=[str(seg.path("vehicle_pose")), str(seg.path("camera_calibration"))],
                        chain="world_from_vehicle(t) @ extrinsic(camera) @ T_waymo_cam<-cv_cam")
        try:
            m = case.measure("trajectory", {"kind": "camera"}, [t0, t1])
        except ContractError as e:
            t0c, t1c, _ = track_interval(track, t0, t1)
            raise Exclude("invalid_pose_at_time", error=str(e), interval=[t0c, t1c]) from None
        ev = m.evidence
        segs = [tuple(x) for x in ev.get("segments", [])]
        t0, t1u = float(ev["t0"]), float(ev.get("t1_used", t1))
        case.outcome.frames = {"camera": int(c.camera), "interval_s": [t0, t1u], "n_samples": ev["n_samples"],
                               "frame_timestamp_micros": [int(track.meta["micros"][0]), int(track.meta["micros"][-1])]}
        c.entity = {"kind": "camera", "camera": int(c.camera)}
        c.times = [t0, t1u]
        c.frame = "Waymo segment world frame, up +Z; camera forward = OpenCV +Z"
        c.unit = "m"
        c.params.update({"distances": "path length between turn split samples",
                         "turns": "net horizontal heading change (left positive)"})
        case.outcome.evidence["operator"] = ev
        case.outcome.evidence["path"] = path_evidence(track, t0, t1u)
        case.outcome.prompt = ""
        case.outcome.time_start, case.outcome.time_end = t0, t1u
        case.value = segs
        case.observables.update(subject="the camera", subject_class="camera",
                                path_length_m=ev.get("path_length_m"))
        case.answer = AnswerSpec(kind="trajectory", value=segs)

    def diagnose(self, case: Case) -> None:
        p, segs, legacy = case.params, case.value, case.legacy
        grid = float(p["grid_m"])
        rule = Rule(abs_tol=float(p["compare_abs_tol_m"]), rel_tol=float(p["compare_rel_tol"]))
        case.rule = {**rule.to_dict(), "turn_tol_deg": float(p["compare_turn_tol_deg"])}
        if legacy is None:
            case.diagnosis = Diagnosis(False)
            return
        cmp = compare(legacy, segs, rule, float(p["compare_turn_tol_deg"]))
        d = Diagnosis(True, cmp["agrees"], evidence={"comparison": cmp})
        if on_grid(legacy, grid):
            d.defects.append("trajectory_10m_grid")
            d.evidence["grid"] = {"grid_m": grid, "legacy_moves_m": [v for k, v in legacy.segments if k == "move"],
                                  "source_moves_m": [v for k, v in segs if k == "move"]}
        if not cmp["agrees"] and (not cmp["same_structure"] or not on_grid(legacy, grid)):
            d.defects.append("value_mismatch")  # not explained by the grid
        case.diagnosis = d

    def rewrite(self, case: Case) -> str:
        return question_text(*case.contract.times)


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


def path_evidence(track: PoseTrack, t0: float, t1: float) -> dict:
    """The camera path of a row for its figure: sample times and world x-y positions relative to the
    first sample in ``[t0, t1]`` (valid samples only, centimetre precision)."""
    sel = (track.times >= t0 - 1e-6) & (track.times <= t1 + 1e-6) & track.valid
    p = track.positions[sel]
    xy = np.round(p[:, :2] - p[0, :2], 2) if len(p) else np.zeros((0, 2))
    return {"t": [round(float(t), 6) for t in track.times[sel]], "xy": xy.tolist()}


def _draw_path(ax, evidence: dict, title: str) -> None:
    """Top-down camera path (world x-y) with the turn windows and the split samples of one row, on
    ``ax``, from the row's evidence (``operator`` and ``path``: no source is reopened)."""
    op = evidence["operator"]
    tt = np.asarray(evidence["path"]["t"], float)
    p = np.asarray(evidence["path"]["xy"], float).reshape(-1, 2)
    ax.plot(p[:, 0], p[:, 1], color="#2c7fb8", lw=1.5, label="move")
    for w in op.get("turn_windows", []):
        m = (tt >= w["window"][0] - 1e-6) & (tt <= w["window"][1] + 1e-6)
        ax.plot(p[m, 0], p[m, 1], color="#d95f0e", lw=3.0)
        k = int(np.argmin(np.abs(tt - w["split_time"])))
        ax.scatter([p[k, 0]], [p[k, 1]], color="k", s=14, zorder=3)
        d = w["heading_change_deg"]
        ax.annotate(f"{'left' if d > 0 else 'right'} {abs(d):.0f}°", (p[k, 0], p[k, 1]),
                    textcoords="offset points", xytext=(6, 6), fontsize=8)
    ax.scatter([0.0], [0.0], marker="o", color="#2c7fb8", s=20, zorder=3)
    ax.plot([], [], color="#d95f0e", lw=3.0, label="turn window")
    ax.scatter([], [], color="k", s=14, label="split sample")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("world x − x(t0) [m]")
    ax.set_ylabel("world y − y(t0) [m]")
    ax.set_title(title, fontsize=8, loc="left")


def plot_path(evidence: dict, path: str | Path, *, title: str = "") -> Path:
    """Top-down camera path (world x-y) with the turn windows and the split samples of one row, from
    the row's evidence (``operator`` and ``path``: no source is reopened)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.0, 4.2), layout="constrained")
    segs = [tuple(s) for s in evidence["operator"].get("segments", [])]
    _draw_path(ax, evidence, title or V.format_trajectory(segs))
    ax.legend(frameon=False, fontsize=7, loc="best")
    return save_figure(fig, path)


def plot_paths(outcomes: list[Outcome], fig_dir: str | Path, *, prefix: str = "07_trajectory_path",
               max_plots: int = 4) -> list[Path]:
    """One figure ``<fig_dir>/<prefix>s.png`` with the top-down paths of up to ``max_plots`` rows on
    distinct source sequences (the cameras of one Waymo segment share its path), those with the most
    turns first, one legend for all panels. Returns ``[path]`` (``[]`` without a drawable row)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seen, chosen = set(), []
    ranked = sorted((o for o in outcomes if o.verdict != "excluded" and "path" in o.evidence),
                    key=lambda o: (-len(o.evidence["operator"].get("turn_windows", [])), o.row))
    for o in ranked:
        sequence = (o.contract or {}).get("sequence") or o.video
        if sequence not in seen:
            seen.add(sequence)
            chosen.append(o)
        if len(chosen) == max_plots:
            break
    if not chosen:
        return []
    ncol = 2 if len(chosen) > 1 else 1
    nrow = -(-len(chosen) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(11.0, 4.6 * nrow), squeeze=False, layout="constrained")
    for ax in axes.flat[len(chosen):]:
        ax.set_visible(False)
    for ax, o in zip(axes.flat, chosen):
        segs = [tuple(s) for s in o.evidence["operator"].get("segments", [])]
        _draw_path(ax, o.evidence, f"{o.video}\n{V.format_trajectory(segs)}")
    h, lab = axes.flat[0].get_legend_handles_labels()
    fig.legend(h, lab, loc="outside lower center", ncol=3, frameon=False)
    return [save_figure(fig, Path(fig_dir) / f"{prefix}s.png")]


__all__ = [
    "TASK",
    "Trajectory",
    "compare",
    "describe_motion",
    "diagnosis_table",
    "on_grid",
    "path_evidence",
    "plot_path",
    "plot_paths",
    "question_text",
]
