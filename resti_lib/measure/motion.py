"""Motion operators: pose, displacement, path length, rates, acceleration, heading change.

Every operator reads the contract entity's track (:meth:`MeasureContext.entity_track`) and calls
one function of :mod:`resti_lib.geometry.trajectory` with the context's ``pose_rule`` and
``time_tol``; the evidence names the world, the subject and the files.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import ContractError
from ..geometry import trajectory as G
from ..geometry.trajectory import PoseTrack
from .registry import EntityTrack, MeasureContext, register_operator

EST_STORED = ("mean acceleration |v(t1) - v(t0)| / (t1 - t0); v = the LiDAR box's annotated velocity (vehicle "
              "frame) rotated into the world frame by the frame's vehicle pose, linear between frames")


def _describe(ctx: MeasureContext, et: EntityTrack) -> None:
    ctx.evidence.update({"world": et.world, "subject": et.subject, "files": et.track.source,
                         "pose_rule": ctx.rule})
    if et.notes:
        ctx.evidence["notes"] = list(et.notes)


def _gaps(ctx: MeasureContext) -> str:
    return str(ctx.setting("path_gaps"))


@register_operator("pose", unit=None, n_times=(1, 2))
def _op_pose(ctx: MeasureContext) -> tuple[Any, dict]:
    """4x4 ``T_world<-entity`` (cameras: OpenCV axes) at ``times[0]``.

    ``pose_rule: nearest`` takes the nearest sample within half the median sampling interval;
    ``linear`` interpolates (a time within ``time_tol`` of a sample is that sample).
    """
    et = ctx.entity_track()
    _describe(ctx, et)
    track = et.track
    tol = sample_window(track) if ctx.rule == "nearest" else ctx.tol
    T, ev = G.pose_at(track, ctx.t0, ctx.rule, tol)
    ev["tol_s"] = tol
    ev["matrix"] = f"T_world<-entity (entity-to-world, row-major); entity: {et.subject}"
    if "frames" in track.meta:
        ev["frames"] = [int(track.meta["frames"][i]) for i in ev["indices"]]
    if "micros" in track.meta:
        ev["frame_timestamp_micros"] = [int(track.meta["micros"][i]) for i in ev["indices"]]
    return T, ev


def sample_window(track: PoseTrack) -> float:
    """Half the median sampling interval of a track (seconds): the nearest-sample window."""
    return 0.5 * float(np.median(np.diff(track.times))) if len(track) > 1 else G.DEFAULT_TOL


@register_operator("displacement", unit="m")
def _op_displacement(ctx: MeasureContext) -> tuple[Any, dict]:
    """|p(t1) - p(t0)| of the entity (m)."""
    et = ctx.entity_track()
    _describe(ctx, et)
    return G.endpoint_displacement(et.track, ctx.t0, ctx.t1, rule=ctx.rule, tol=ctx.tol)


@register_operator("path_length", unit="m")
def _op_path_length(ctx: MeasureContext) -> tuple[Any, dict]:
    """Integrated |Δp| over the source samples in [t0, t1] (m)."""
    et = ctx.entity_track()
    _describe(ctx, et)
    return G.path_length(et.track, ctx.t0, ctx.t1, rule=ctx.rule, tol=ctx.tol, gaps=_gaps(ctx))


@register_operator("average_velocity", unit="m/s")
def _op_average_velocity(ctx: MeasureContext) -> tuple[Any, dict]:
    """Magnitude of average velocity: displacement / (t1 - t0) (m/s)."""
    et = ctx.entity_track()
    _describe(ctx, et)
    return G.average_velocity(et.track, ctx.t0, ctx.t1, rule=ctx.rule, tol=ctx.tol)


@register_operator("average_speed", unit="m/s")
def _op_average_speed(ctx: MeasureContext) -> tuple[Any, dict]:
    """Path length / (t1 - t0) (m/s)."""
    et = ctx.entity_track()
    _describe(ctx, et)
    return G.average_speed(et.track, ctx.t0, ctx.t1, rule=ctx.rule, tol=ctx.tol, gaps=_gaps(ctx))


def stored_velocity_acceleration(seg, track: PoseTrack, t0: float, t1: float) -> tuple[float, dict]:
    """Mean acceleration from a Waymo track's annotated box velocities (vehicle frame, rotated into
    the world by the frame's vehicle pose, linear between frames).

    Raises ContractError when a needed velocity is missing (NaN) or a time lies outside the track.
    """
    spd = np.asarray(track.meta.get("speed"), float)
    if spd.ndim != 2 or spd.shape[0] != len(track):
        raise ContractError(f"{track.name}: no annotated velocities")
    ego = seg.ego_track()
    k = np.searchsorted(ego.meta["micros"], track.meta["micros"])
    R = ego.T[np.clip(k, 0, len(ego) - 1), :3, :3]
    v_world = np.einsum("nij,nj->ni", R, spd)
    times = track.times

    def v_at(t):
        if t < times[0] - 1e-3 or t > times[-1] + 1e-3:
            raise ContractError(f"{track.name}: t={t} s outside the track [{times[0]:.3f}, {times[-1]:.3f}] s")
        j = int(np.clip(np.searchsorted(times, t), 1, len(times) - 1))
        a = float(np.clip((t - times[j - 1]) / (times[j] - times[j - 1]), 0.0, 1.0))
        v = (1 - a) * v_world[j - 1] + a * v_world[j]
        if not np.isfinite(v).all():
            raise ContractError(f"{track.name}: annotated velocity missing near t={t} s")
        return v, [j - 1, j]

    v0, i0 = v_at(t0)
    v1, i1 = v_at(t1)
    acc = (v1 - v0) / (t1 - t0)
    return float(np.linalg.norm(acc)), {"estimator": EST_STORED, "v_t0": v0.tolist(), "v_t1": v1.tolist(),
                                        "samples_t0": i0, "samples_t1": i1, "vector": acc.tolist(),
                                        "dt_s": t1 - t0}


@register_operator("acceleration", unit="m/s^2")
def _op_acceleration(ctx: MeasureContext) -> tuple[Any, dict]:
    """Magnitude of the mean acceleration over [t0, t1] (m/s^2); estimator in the evidence.

    Waymo objects with ``acceleration_estimator: annotated_velocity``: the LiDAR boxes' annotated
    velocities (central differences of the positions when they are unusable, noted); otherwise
    central differences of the positions.
    """
    et = ctx.entity_track()
    _describe(ctx, et)
    track = et.track
    if (ctx.source == "Waymo" and ctx.entity["kind"] == "object"
            and ctx.setting("acceleration_estimator") == "annotated_velocity"):
        try:
            a, ev = stored_velocity_acceleration(ctx.scene, track, ctx.t0, ctx.t1)
            try:
                ev["central_difference_check"] = G.acceleration(track, ctx.t0, ctx.t1, tol=ctx.tol)[0]
            except ContractError as e:
                ev["central_difference_check"] = str(e)
            return a, ev
        except ContractError as e:
            fallback = str(e)
        a, ev = G.acceleration(track, ctx.t0, ctx.t1, tol=ctx.tol)
        ev["note"] = f"annotated velocities unusable ({fallback}); central differences"
        return a, ev
    return G.acceleration(track, ctx.t0, ctx.t1, tol=ctx.tol)


@register_operator("heading_change", unit="deg")
def _op_heading_change(ctx: MeasureContext) -> tuple[Any, dict]:
    """Signed gravity-horizontal heading change of the entity's forward axis (deg, [-180, 180))."""
    et = ctx.entity_track()
    _describe(ctx, et)
    return G.heading_change(et.track, ctx.t0, ctx.t1, et.forward_axis, et.up, rule=ctx.rule, tol=ctx.tol)
