"""Ego-Centric Orientation: gravity-relative heading change, and the legacy vertical-plane angle.

Repair (report, "Repair: gravity-relative optical heading")
-----------------------------------------------------------
``f(t) = R(t) a`` (``a`` the optical-forward axis: OpenCV camera ``+Z``; for Waymo that is the
Waymo camera's ``+X``, which the OpenCV-converted track carries as ``+Z``), projected on the plane
orthogonal to world up ``u`` (ScanNet raw ``+Z``, Waymo world ``+Z``), and
``theta = atan2(u . (h0 x h1), h0 . h1)`` wrapped to [-180, 180)
(the measure operator ``heading_change``). A sequence ending in invalid poses has
its interval shortened to the last valid timestamp, and the question says so; an invalid pose is
never replaced.

Diagnosis (report, "Diagnosis: a source-axis component is not heading")
-----------------------------------------------------------------------
The legacy operator projects one column of the camera-to-world rotation *in the source's camera
axes* (ScanNet OpenCV, Waymo's +X forward/+Z up camera axes) on the raw-world X-Z plane and takes
the signed endpoint angle (:func:`resti_lib.geometry.trajectory.legacy_plane_angle`). Every row
is evaluated under that operator (both sign conventions) and a few standard heading conventions;
the evidence lists which reproduce the printed legacy value.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from .. import values as V
from ..adjudicate import Diagnosis
from ..contract import Contract, base_contract, interval
from ..errors import ContractError
from ..geometry import trajectory as G
from ..geometry.frames import opencv_cam_pose_to_waymo
from ..geometry.trajectory import PoseTrack
from ..io.figures import save_figure
from ..rng import row_rng
from ..sources.context import SourceContext
from . import register_task
from .base import AnswerSpec, Case, Exclude, Outcome, Task

TASK = "Ego-Centric Orientation"

#: Conventions evaluated against every legacy value (name -> description).
CONVENTIONS = {
    "gravity_heading": "optical forward projected on the plane orthogonal to world up (the repair)",
    "xz_plane_column2": "source-axes camera column 2 on raw-world X-Z, positive from +Z toward +X "
                        "(right-handed about +Y)",
    "xz_plane_column2_reversed": "source-axes camera column 2 on raw-world X-Z, positive from +X toward +Z",
    "euler_zyx_yaw": "difference of the ZYX Euler yaw of the camera-to-world rotation",
    "right_axis_heading": "camera +X (right) projected on the horizontal plane",
    "relative_rotation_about_up": "component about world up of the rotation vector of R1 R0^T",
    "geodesic_angle": "total rotation angle between the endpoint rotations (unsigned)",
}
LEGACY_OPERATORS = ("xz_plane_column2", "xz_plane_column2_reversed")
VERDICT_REASON = ("the legacy question names no plane or convention; the value is derived as the gravity-horizontal "
                  "heading change of the optical axis")


# ==================================================================================== tracks


class Tracks:
    """A camera's tracks for the heading operators.

    Attributes
    ----------
    cv : PoseTrack  ``T_world<-cam`` in OpenCV axes (optical forward ``+Z``).
    src : PoseTrack  the same poses in the source's own camera axes (ScanNet OpenCV; Waymo +X
        forward, +Z up), which the legacy operator used.
    up : world-up unit vector in the track's world.
    forward : optical-forward axis in the OpenCV camera frame (``(0, 0, 1)``).
    world, axes_note : words for the evidence.
    """

    def __init__(self, cv: PoseTrack, src: PoseTrack, up, world: str, axes_note: str, files: list):
        self.cv, self.src = cv, src
        self.up = tuple(float(x) for x in up)
        self.forward = (0.0, 0.0, 1.0)
        self.world, self.axes_note, self.files = world, axes_note, files


def camera_tracks(ctx: SourceContext, source: str, sequence: str, camera: int | None, p: dict) -> Tracks:
    """The camera tracks of a sequence (see :class:`Tracks`)."""
    if source == "ScanNet":
        sc = ctx.scannet(sequence)
        tr = sc.camera_track()
        return Tracks(tr, tr, (0.0, 0.0, 1.0), "ScanNet raw scan frame (+Z up)",
                      "ScanNet camera axes are OpenCV: optical forward = column 2", [tr.source])
    if source == "Waymo":
        if camera is None:
            raise ContractError("Waymo video without a camera number")
        seg = ctx.waymo(sequence)
        tr = seg.camera_track(camera)
        src = PoseTrack(tr.times, opencv_cam_pose_to_waymo(tr.T), name=tr.name + " (Waymo camera axes)",
                        source=tr.source, meta=tr.meta)
        return Tracks(tr, src, (0.0, 0.0, 1.0), "Waymo segment world frame (+Z up)",
                      "Waymo camera axes: +X forward, +Y left, +Z up; optical forward = Waymo +X = OpenCV +Z",
                      [str(seg.path("vehicle_pose")), str(seg.path("camera_calibration"))])
    rope = ctx.rope(sequence)
    tr = rope.camera_track(rebase=True)
    up = rope.world_up_in_track_frame(np.asarray(p["omni6d_up"], float))
    return Tracks(tr, tr, up, "ROPE camera frame at the first frame", "OpenCV axes (verified convention)",
                  [str(rope.dir)])


# ================================================================================ conventions


def _yaw_zyx(R: np.ndarray) -> float:
    return float(Rotation.from_matrix(R).as_euler("ZYX", degrees=True)[0])


def conventions(tracks: Tracks, t0: float, t1: float, p: dict) -> dict[str, float]:
    """Every convention of :data:`CONVENTIONS` on the interval ``[t0, t1]`` (degrees)."""
    rule, tol = str(p["pose_rule"]), float(p["time_tol"])
    out = {}
    out["gravity_heading"], _ = G.heading_change(tracks.cv, t0, t1, tracks.forward, tracks.up, rule=rule, tol=tol)
    out["xz_plane_column2"], _ = G.legacy_plane_angle(tracks.src, t0, t1, 2, ("z", "x"), rule=rule, tol=tol)
    out["xz_plane_column2_reversed"], _ = G.legacy_plane_angle(tracks.src, t0, t1, 2, ("x", "z"), rule=rule,
                                                               tol=tol)
    (a, b), _ = G.interval_valid(tracks.cv, t0, t1, tol=tol)
    T0, _ = G.pose_at(tracks.cv, a, rule, tol)
    T1, _ = G.pose_at(tracks.cv, b, rule, tol)
    R0, R1 = T0[:3, :3], T1[:3, :3]
    out["euler_zyx_yaw"] = float(V.wrap_degrees(_yaw_zyx(R1) - _yaw_zyx(R0)))
    out["right_axis_heading"] = float(G.horizontal_heading_deg(R0, R1, (1.0, 0.0, 0.0), tracks.up))
    rv = Rotation.from_matrix(R1 @ R0.T).as_rotvec()
    out["relative_rotation_about_up"] = float(V.wrap_degrees(math.degrees(float(rv @ np.asarray(tracks.up)))))
    out["geodesic_angle"] = float(math.degrees(np.linalg.norm(rv)))
    return out


def invariance_error(tracks: Tracks, t0: float, t1: float, p: dict, rng: np.random.Generator) -> float:
    """|theta(Q R, Q u) - theta(R, u)| in degrees for a random rigid rotation Q of trajectory and world."""
    rule, tol = str(p["pose_rule"]), float(p["time_tol"])
    (a, b), _ = G.interval_valid(tracks.cv, t0, t1, tol=tol)
    T0, _ = G.pose_at(tracks.cv, a, rule, tol)
    T1, _ = G.pose_at(tracks.cv, b, rule, tol)
    Q = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()
    th = G.horizontal_heading_deg(T0[:3, :3], T1[:3, :3], tracks.forward, tracks.up)
    thq = G.horizontal_heading_deg(Q @ T0[:3, :3], Q @ T1[:3, :3], tracks.forward, Q @ np.asarray(tracks.up))
    return float(abs(V.wrap_degrees(thq - th)))


# ===================================================================================== rows


def clamp_to_track(track: PoseTrack, t0: float, t1: float, slack: float) -> tuple[float, float, dict]:
    """Move interval ends that lie outside the track by at most ``slack`` seconds onto its first/last
    sample (a video end printed as ``N / fps`` against a last sample at ``(N - 1) / fps``).

    Farther ends are left alone (the operator then refuses them). Returns ``(t0, t1, changes)``.
    """
    changes = {}
    first, last = float(track.times[0]), float(track.times[-1])
    if first - slack <= t0 < first:
        changes["t0"] = {"asked": t0, "used": first}
        t0 = first
    if last < t1 <= last + slack:
        changes["t1"] = {"asked": t1, "used": last}
        t1 = last
    return t0, t1, changes


def rewrite_question(t0: float, t1: float, shortened_from: float | None) -> str:
    """v5 wording; a shortened interval names its last valid pose and the invalid remainder."""
    note = ""
    if shortened_from is not None:
        note = (f" (the last valid source camera pose; the source poses after it, up to {shortened_from:.6f} "
                f"seconds, are invalid)")
    return (f"Between source pose timestamps {t0:.6f} and {t1:.6f} seconds{note}, what is the signed horizontal "
            "heading change of the camera? Project the camera's optical-forward direction onto the plane "
            "perpendicular to gravity. Positive angles are counterclockwise about +up when viewed from above; "
            "report the wrapped angle in [-180°, 180°).")


@register_task
class Orientation(Task):
    name = TASK
    params_name = "orientation"
    notebook = "02_orientation"
    order = 6
    answer_kind = "scalar"
    follows = ("Trajectory Description",)
    rule_key = "angle_abs_tol_deg"
    quantity = "heading_change"
    figures = {
        "endpoints": ("Ego-Centric Orientation, one row: (a) the camera column the legacy operator uses, on the "
                      "vertical X–Z plane; (b) optical forward on the gravity-horizontal plane, the repaired heading "
                      "change. Blue: start; gold: end."),
        "legacy_vs_operators": ("Ego-Centric Orientation: the legacy value against the X–Z operator (left) and against the "
                                "repaired gravity-horizontal heading (right)."),
    }
    legacy_kind = V.Scalar
    operators = ("heading_change",)
    missing_defects: ClassVar[dict] = {}

    def read_contract(self, row: dict, video_map: dict | None = None) -> Contract:
        c, q = base_contract(row, "heading_change", video_map=video_map)
        ql = q.lower()
        c.entity = {"kind": "camera"}
        c.times = interval(c, row)
        if not ("gravity" in ql or "horizontal plane" in ql or "perpendicular to gravity" in ql):
            c.miss("frame")
        if not c.time_stated:
            c.miss("time")
        return c

    def reconstruct(self, case: Case) -> None:
        c, row, p, o = case.contract, case.row, case.params, case.outcome
        if c.sequence is None:
            raise Exclude("unsupported_question", problem="video maps to no source sequence")
        t0, t1 = (float(x) for x in (c.times if len(c.times) == 2 else [row["time_start"], row["time_end"]]))
        try:
            tracks = camera_tracks(case.ctx, c.source, c.sequence, c.camera, p)
            t0, t1, clamped = clamp_to_track(tracks.cv, t0, t1, float(p["end_slack_s"]))
            m = case.measure("heading_change", {"kind": "camera"}, [t0, t1])
            conv = conventions(tracks, t0, t1, p)
        except ContractError as e:
            msg = str(e)
            reason = "invalid_pose_at_time" if "invalid" in msg.lower() else "unsupported_question"
            raise Exclude(reason, error=msg, t0=t0, t1=t1) from None
        theta, ev = float(m.value), m.evidence
        t1_used = float(ev["t1_used"])
        shortened = ev.get("shortened_to") is not None
        frames = {"t0": t0, "t1": t1_used, "indices_t0": ev["indices_t0"], "indices_t1": ev["indices_t1"]}
        if "frames" in tracks.cv.meta:
            fr = tracks.cv.meta["frames"]
            frames["source_frames"] = [int(fr[ev["indices_t0"][0]]), int(fr[ev["indices_t1"][-1]])]
        if "micros" in tracks.cv.meta:
            mi = tracks.cv.meta["micros"]
            frames["frame_timestamp_micros"] = [int(mi[ev["indices_t0"][0]]), int(mi[ev["indices_t1"][-1]])]
        case.provenance(files=tracks.files, frames=frames,
                        chain="theta = atan2(u.(h0 x h1), h0.h1), h = horizontal projection of R(t) a; "
                              + tracks.axes_note)
        case.state.update(conv=conv, tracks=tracks, t0=t0, t1=t1, t1_used=t1_used, shortened=shortened)
        o.evidence["heading"] = {"value_deg": theta, "forward_t0": ev["forward_t0"],
                                 "forward_t1": ev["forward_t1"], "up": list(tracks.up), "world": tracks.world}
        o.evidence["legacy_operator_axes"] = legacy_operator_axes(tracks, t0, t1_used, p)
        if clamped:
            o.evidence["clamped_to_track"] = clamped
        if shortened:
            o.evidence["shortened_to"] = float(ev["shortened_to"])
            o.evidence["shortened_from"] = float(ev["shortened_from"])
            o.evidence["shortening_reason"] = ev.get("reason")
        c.times, c.time_stated, c.unit = [t0, t1_used], True, "deg"
        c.frame = f"{tracks.world}; gravity-horizontal plane"
        c.entity = {"kind": "camera", "camera": c.camera}
        if shortened:
            c.params = {**c.params, "shortened_to": t1_used, "shortened_from": t1}
        o.time_start, o.time_end = t0, t1_used
        case.value = theta
        case.observables.update(subject="the camera", subject_class="camera", up=list(tracks.up))
        case.answer = AnswerSpec(kind="angle", value=theta, unit="°", decimals=2)

    def diagnose(self, case: Case) -> None:
        p, conv, legacy = case.params, case.state["conv"], case.legacy
        angle = legacy is not None and (legacy.is_angle or legacy.unit == "")
        dec = legacy.decimals if angle else 2
        tol = 0.5 * 10.0 ** -dec + float(p["angle_abs_tol_deg"])
        case.rule = {"abs_tol": float(p["angle_abs_tol_deg"]), "rel_tol": 0.0,
                     "text": f"a convention reproduces the legacy value within half a printed unit + "
                             f"{float(p['angle_abs_tol_deg']):g} deg"}
        diag: dict[str, Any] = {"conventions_deg": conv, "tolerance_deg": tol}
        d = Diagnosis(False, evidence={"diagnosis": diag, "verdict_reason": VERDICT_REASON})
        if angle:
            res = {k: float(abs(V.wrap_degrees(float(legacy.value) - v))) for k, v in conv.items()}
            repro = sorted((k for k, r in res.items() if r <= tol), key=lambda k: res[k])
            diag.update({"legacy_deg": float(legacy.value), "residuals_deg": res, "reproduced_by": repro})
            if any(k in repro for k in LEGACY_OPERATORS):
                d.defects.append("orientation_xz_plane")
        else:
            diag["legacy_detail_error"] = case.legacy_problem or f"Answer Detail is not an angle: {case.detail!r}"
        if p["invariance_check"]:
            s = case.state
            diag["invariance_error_deg"] = invariance_error(s["tracks"], s["t0"], s["t1"], p,
                                                            row_rng(int(p["seed"]), case.outcome.key,
                                                                    "invariance"))
        case.diagnosis = d

    def rewrite(self, case: Case) -> str:
        s = case.state
        return rewrite_question(s["t0"], s["t1_used"], s["t1"] if s["shortened"] else None)


def legacy_operator_axes(tracks: Tracks, t0: float, t1: float, p: dict) -> dict:
    """The source-axes camera column 2 at both ends (what the legacy X-Z operator projects), for the
    endpoint figure."""
    rule, tol = str(p["pose_rule"]), float(p["time_tol"])
    T0, _ = G.pose_at(tracks.src, t0, rule, tol)
    T1, _ = G.pose_at(tracks.src, t1, rule, tol)
    return {"column2_t0": T0[:3, 2].tolist(), "column2_t1": T1[:3, 2].tolist()}


# ===================================================================================== tables


def convention_counts(outcomes: list[Outcome]) -> pd.DataFrame:
    """How many legacy values each convention reproduces, per source (and in total)."""
    recs = []
    for o in outcomes:
        d = o.evidence.get("diagnosis", {})
        if "reproduced_by" not in d:
            continue
        recs.append({"source": o.source, **{k: (k in d["reproduced_by"]) for k in CONVENTIONS}})
    if not recs:
        return pd.DataFrame(columns=["convention", "description"])
    df = pd.DataFrame(recs)
    out = df.groupby("source")[list(CONVENTIONS)].sum().T
    out["ALL"] = out.sum(axis=1)
    out.insert(0, "description", [CONVENTIONS[k] for k in out.index])
    n = df.groupby("source").size()
    out.loc["rows"] = ["rows with a readable legacy value", *[int(n.get(s, 0)) for s in out.columns[1:-1]],
                       int(n.sum())]
    return out.rename_axis("convention").reset_index()


def diagnosis_table(outcomes: list[Outcome]) -> pd.DataFrame:
    """One row per legacy row: legacy value, repaired value, the legacy operator, shortening."""
    recs = []
    for o in outcomes:
        d = o.evidence.get("diagnosis", {})
        conv = d.get("conventions_deg", {})
        recs.append({"row": o.row, "source": o.source, "video": o.video, "verdict": o.verdict,
                     "legacy_deg": d.get("legacy_deg"), "repaired_deg": conv.get("gravity_heading"),
                     "xz_plane_deg": conv.get("xz_plane_column2"),
                     "reproduced_by": ",".join(d.get("reproduced_by", [])),
                     "t_end": o.time_end, "shortened_from": o.evidence.get("shortened_from"),
                     "invariance_error_deg": d.get("invariance_error_deg"),
                     "defects": ",".join(sorted(set(o.defects)))})
    return pd.DataFrame(recs)


def _arc(ax, a0: float, a1: float, r: float, color: str) -> None:
    """Signed arc from angle a0 to a1 (radians, a1 - a0 already the signed change), unlabelled: the
    value is written in the panel's corner (:func:`_angle_box`), where nothing can cover it."""
    ts = np.linspace(a0, a1, 80)
    ax.plot(r * np.cos(ts), r * np.sin(ts), color=color, lw=1.4)
    ax.annotate("", (r * np.cos(ts[-1]), r * np.sin(ts[-1])), (r * np.cos(ts[-3]), r * np.sin(ts[-3])),
                arrowprops={"arrowstyle": "->", "color": color, "lw": 1.4})


def _angle_box(ax, text: str, color: str) -> None:
    ax.text(0.98, 0.03, text, transform=ax.transAxes, color=color, fontsize=8, ha="right", va="bottom",
            bbox={"boxstyle": "round,pad=0.25", "fc": "white", "ec": color, "lw": 0.8})


MIN_LABEL_GAP = math.radians(28.0)  # start and end labels at least this far apart around the circle


def _end_labels(ax, w0: np.ndarray, w1: np.ndarray, colors=("#2c7fb8", "#d4a017")) -> None:
    """``start`` and ``end`` beyond the arrow tips, pushed apart around the circle when the two
    directions are close, aligned away from the centre so the text never covers an arrow."""
    t0, t1 = math.atan2(w0[1], w0[0]), math.atan2(w1[1], w1[0])
    d = (t1 - t0 + math.pi) % (2 * math.pi) - math.pi
    if abs(d) < MIN_LABEL_GAP:
        push = 0.5 * (MIN_LABEL_GAP - abs(d)) * (1.0 if d >= 0 else -1.0)
        t0, t1 = t0 - push, t1 + push
    for t, color, lab in ((t0, colors[0], "start"), (t1, colors[1], "end")):
        x, y = 1.12 * math.cos(t), 1.12 * math.sin(t)
        ax.text(x, y, lab, color=color, fontsize=8, ha="left" if x >= 0 else "right",
                va="bottom" if y >= 0 else "top")


def figure_endpoints(run, path: str | Path, *, row: int | None = None) -> Path | None:
    """Endpoint forward vectors of one row on the vertical X-Z plane and on the horizontal plane.

    (a) the source-axes camera column the legacy operator uses, projected on raw-world X-Z, with
    the signed X-Z angle; (b) the optical-forward vectors projected on the gravity-horizontal
    plane, with the repaired heading change. Blue: start; gold: end.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    outs = [o for o in run.outcomes if o.verdict != "excluded"]
    if row is not None:
        outs = [o for o in outs if o.row == row]
    elif outs:
        def gap(o):
            d = o.evidence["diagnosis"]
            return abs(float(V.wrap_degrees(d.get("legacy_deg", 0.0) - d["conventions_deg"]["gravity_heading"])))
        sc = [o for o in outs if o.source == "ScanNet"] or outs
        outs = [max(sc, key=gap)]
    if not outs:
        return None
    o = outs[0]
    d = o.evidence["diagnosis"]
    conv = d["conventions_deg"]
    fig, axes = plt.subplots(1, 2, figsize=(8.4, 4.0))
    # (a) vertical plane: components (x, z) of source column 2; angle positive from +Z toward +X
    axes_ev = o.evidence["legacy_operator_axes"]
    a, b = np.array(axes_ev["column2_t0"]), np.array(axes_ev["column2_t1"])
    ax = axes[0]
    ws = []
    for v, color in ((a, "#2c7fb8"), (b, "#d4a017")):
        w = np.array([v[0], v[2]])
        ws.append(w / (np.linalg.norm(w) or 1.0))
        ax.annotate("", (ws[-1][0], ws[-1][1]), (0, 0), arrowprops={"arrowstyle": "->", "color": color, "lw": 2})
    _end_labels(ax, *ws)
    a0 = math.atan2(a[2], a[0])
    _arc(ax, a0, a0 - math.radians(conv["xz_plane_column2"]), 0.6, "#d7301f")
    _angle_box(ax, f"X-Z angle {conv['xz_plane_column2']:+.2f}°", "#d7301f")
    ax.set_xlabel("world X")
    ax.set_ylabel("world Z (vertical)")
    ax.set_title("(a) legacy: source camera column 2 on raw-world X-Z", fontsize=8, loc="left")
    # (b) horizontal plane: optical forward projected orthogonal to up (world X-Y when up = +Z)
    up = np.asarray(o.evidence["heading"]["up"])
    e1 = np.cross(up, [0.0, 1.0, 0.0]) if abs(up[1]) < 0.9 else np.cross(up, [1.0, 0.0, 0.0])
    e1 = np.array([1.0, 0.0, 0.0]) if np.allclose(up, [0, 0, 1]) else e1 / np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    f0, f1 = np.array(o.evidence["heading"]["forward_t0"]), np.array(o.evidence["heading"]["forward_t1"])
    ax = axes[1]
    ws = []
    for v, color in ((f0, "#2c7fb8"), (f1, "#d4a017")):
        w = np.array([v @ e1, v @ e2])
        ws.append(w / (np.linalg.norm(w) or 1.0))
        ax.annotate("", (ws[-1][0], ws[-1][1]), (0, 0), arrowprops={"arrowstyle": "->", "color": color, "lw": 2})
    _end_labels(ax, *ws)
    h0 = math.atan2(f0 @ e2, f0 @ e1)
    _arc(ax, h0, h0 + math.radians(conv["gravity_heading"]), 0.6, "#08519c")
    _angle_box(ax, f"heading change {conv['gravity_heading']:+.2f}°", "#08519c")
    ax.set_xlabel("horizontal axis 1 (world X)")
    ax.set_ylabel("horizontal axis 2 (world Y)")
    ax.set_title("(b) repair: optical forward on the gravity-horizontal plane", fontsize=8, loc="left")
    for ax in axes:
        ax.set_xlim(-1.6, 1.6)
        ax.set_ylim(-1.6, 1.6)
        ax.set_aspect("equal")
        ax.axhline(0, color="#dddddd", lw=0.6, zorder=0)
        ax.axvline(0, color="#dddddd", lw=0.6, zorder=0)
    leg = d.get("legacy_deg")
    fig.suptitle(f"{o.video}: {o.time_start:.3f} s to {o.time_end:.3f} s; legacy detail "
                 f"{leg if leg is None else f'{leg:+.2f}°'}", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def figure_scatter(outcomes: list[Outcome], path: str | Path) -> Path | None:
    """Legacy value against the repaired heading and against the X-Z operator, per source."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = diagnosis_table(outcomes).dropna(subset=["legacy_deg"])
    if t.empty:
        return None
    fig, axes = plt.subplots(1, 2, figsize=(8.0, 3.8), sharey=True)
    colors = {"ScanNet": "#2c7fb8", "Waymo": "#d95f0e", "Omni6DPose": "#31a354"}
    for ax, col, title in ((axes[0], "xz_plane_deg", "legacy operator (X-Z plane)"),
                           (axes[1], "repaired_deg", "gravity-horizontal heading (repair)")):
        for src, g in t.groupby("source"):
            ax.scatter(g[col], g["legacy_deg"], s=12, color=colors.get(src, "k"), label=src, alpha=0.8)
        ax.plot([-180, 180], [-180, 180], color="#999999", lw=0.8, ls="--")
        ax.set_xlim(-180, 180)
        ax.set_ylim(-180, 180)
        ax.set_xlabel(f"{title} (°)")
        ax.set_title(title, fontsize=8, loc="left")
    axes[0].set_ylabel("legacy Answer Detail (°)")
    axes[0].legend(fontsize=7, frameon=False)
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)
