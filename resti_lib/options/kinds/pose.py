"""Poses: a motion from the premise pose (translation in the premise's heading frame, for a vehicle
as a speed and a direction; a turn and two tilts), cameras relative to a reference around their gaze
point."""

from __future__ import annotations

import numpy as np

from ... import values as V
from ...geometry.fields import (
    from_gaze_fields,
    from_yaw_tilt,
    gaze_depth,
    gaze_fields,
    horizontal_frame,
    level_rotation,
    rotation_preimage,
    shell_half_cells,
    yaw_tilt,
)
from ...geometry.frames import nearest_rotation
from ...rng import row_rng
from ..plan import GroupModel, Reject, RowPlan, log_window, recorded_decimals
from ..population import circular_cut, from_cut_line, on_cut_line
from ..spec import (
    per_source,
    pose_floors,
    pose_separation,
    speed_bound,
)
from . import KindBuilder, register_kind

TILT_FIELDS = (4, 5)   # a non-relative pose's fields: motion (3), turn, the two tilts

# ANCHOR: a distractor draw is anchored at the answer's score, drawn uniformly over the answer's printed cell in
# each field. A field read from the rotation's preimage (:func:`~resti_lib.geometry.fields.rotation_preimage`) is
# already a point drawn in that cell, so it anchors at that point (a cell of zero width): a cell around it would
# spread the anchor over two printed cells. On v5 Waymo (seed 1) that wider anchor left the answers' tilt entries
# where the other recordings' candidates crowd more than their answers (echo z -3.6 to -5.2, pooled; -0.5 to -2.4
# at the point).


def time_sign(o) -> float:
    """-1 for a target time before the premise's (the motion from the premise runs backwards), else 1:
    translations are modelled along the direction of time, so a car's forward motion is one direction
    of the model whether the question asks after or before its premise."""
    if o.premise_time is not None and o.time_end is not None and o.time_end < o.premise_time:
        return -1.0
    return 1.0


def heading_axis(premises: list, up) -> int:
    """The premise camera axis whose horizontal projection carries a group's heading frame: the axis
    most nearly horizontal over the group's printed premises (median of ``|axis . up|``). Releases
    print cameras in different axes (OpenCV +Z forward and +Y down; the Waymo camera frame +X forward
    and +Z up): a fixed axis would be the vertical one for some, whose horizontal projection is only
    its small tilt, an arbitrary heading per row. Any horizontal axis is rigid with the heading, so
    the frame turns with the camera either way."""
    if not premises:
        return 2
    up = np.asarray(up, float) / np.linalg.norm(up)
    tilt = np.median([np.abs(np.asarray(P, float)[:3, :3].T @ up) for P in premises], axis=0)
    return int(np.argmin(tilt))


@register_kind("pose")
class PoseKind(KindBuilder):
    """Poses: a motion from the premise pose (translation in the premise's heading frame, a turn about
    the vertical and the camera's tilts from level), cameras relative to a reference around their
    gaze point."""

    def fit(self, st, g: str, ps: list[RowPlan]) -> GroupModel:
        """Poses as a motion from the premise: the translation in the premise's horizontal heading
        frame (forward, left, up; for vehicles a speed over the window and a direction,
        :meth:`translation_fields`; signed by the direction of time, :func:`time_sign`), the turn
        about the vertical from the premise's heading (signed likewise) and the camera's two tilts
        from level (:func:`~resti_lib.geometry.fields.yaw_tilt`: gravity-referenced, not relative to
        the premise, so a distractor leans as the group's answers lean and a level camera among tilted
        ones is no tell), jointly. A question without a printed premise
        (the reference camera as the identity) has the identity as premise."""
        kp = st.params["kinds"]["pose"]
        src = ps[0].spec.source
        up = np.asarray(kp["world_up"], float)
        rate = bool(per_source(kp["rate"], src, False))
        info: dict = {"rate": rate, "R0": {}, "frame": {}, "win": {}}
        relative = all(p.spec.obs.premise_text is None for p in ps)
        info["relative"] = relative
        col = heading_axis([p.spec.obs.premise for p in ps if p.spec.obs.premise_text is not None], up)
        info["heading_axis"] = col
        # the second tilt is centred on the group's circular mean (an OpenCV camera's is near -90 deg)
        tilts = np.array([yaw_tilt(p.spec.value.R, up)[2] for p in ps])
        info["tilt_ref"] = float(np.arctan2(np.sin(tilts).mean(), np.cos(tilts).mean())) if len(tilts) else 0.0
        # zeros keep their sign in print only where the group's answers (or premises) ever show a -0.0
        info["signed_zero"] = V.prints_negative_zero(
            [p.spec.value.vector() for p in ps] +
            [np.asarray(p.spec.obs.premise, float)[:3].ravel() for p in ps if p.spec.obs.premise_text is not None])
        ts = np.array([p.spec.value.t for p in ps], float)
        info["t_decimals"] = [recorded_decimals(ts[:, j], ps[0].spec.decimals) for j in range(3)]
        F, Hh, W = [], [], []
        for p in ps:
            v: V.Pose = p.spec.value
            o = p.spec.obs
            R0 = rotation_preimage(v.R, v.decimals, row_rng(st.seed, p.rid, "preimage"), signed_zero=info["signed_zero"])
            info["R0"][p.rid] = R0
            win = o.window_s if (o.window_s and o.window_s > 0) else 1.0
            info["win"][p.rid] = win
            sign = time_sign(o)
            scale = sign * (win if rate else 1.0)
            if o.premise is not None and o.premise_text is not None:
                Rp, tp = nearest_rotation(o.premise[:3, :3]), np.array(o.premise[:3, 3], float)
                Hf = horizontal_frame(Rp, up, col)
            else:  # relative poses: the reference camera is the identity
                Rp, tp, Hf = np.eye(3), np.zeros(3), np.eye(3)
            info["frame"][p.rid] = (Rp, tp, Hf, float(yaw_tilt(Rp, up)[0]))
            h_t = 0.5 * 10.0 ** -v.decimals
            if not relative:
                d = Hf.T @ (np.array(v.t, float) - tp) / scale
                f_t, h_f = self.translation_fields(d, h_t / abs(scale), rate)
                F.append([*f_t, *self.rotation_fields(R0, info["frame"][p.rid][3], sign, up, info["tilt_ref"])])
                Hh.append([*h_f] + [h_t] * 3)
            W.append([log_window(p.spec)])
        if relative:  # cameras looking at a desk: drawn around the gaze point they share, in a levelled frame
            depths = np.array([gaze_depth(info["R0"][p.rid], p.spec.value.t) for p in ps])
            G = np.array([0.0, 0.0, float(np.nanmedian(depths)) if np.isfinite(depths).any() else 0.5])
            A = level_rotation([info["R0"][p.rid][:, 0] for p in ps] + [[1.0, 0.0, 0.0]])
            info["gaze"], info["level"] = A @ G, A
            for p in ps:
                f = self.desk_fields(info, info["R0"][p.rid], p.spec.value.t)
                F.append(list(f))
                Hh.append(shell_half_cells(f, 0.5 * 10.0 ** -p.spec.value.decimals) + [0.3, 0.3, 0.3])
            # the azimuth about the gaze point and the roll are circular: each on the line cut where the
            # group's answers are sparsest
            info["cut_az"] = circular_cut([row[1] for row in F])
            info["cut"] = circular_cut([row[5] for row in F])
            for row in F:
                row[1] = float(on_cut_line(row[1], info["cut_az"]))
                row[5] = float(on_cut_line(row[5], info["cut"]))
        F, Hh, W = np.array(F, float), np.array(Hh, float), np.array(W, float)
        # the tilts are read where a reader sees them: the printed entries they move alone
        echo = None if relative else st.echo_spec(None, None, self.tilt_readout(F, info["tilt_ref"], [
            p.spec.value.decimals for p in ps]), fields=TILT_FIELDS)
        fm = st.fit_fields(ps, F, Hh, W if np.isfinite(W).all() else None, echo=echo,
                           prior_sd=([0.2, 20.0, 20.0, 5.0, 5.0, 10.0] if relative else
                                     [0.5, 0.5, 0.2, 0.3, 0.1, 0.1] if not rate else [1.0, 0.3, 0.1, 0.3, 0.1, 0.1]))
        return GroupModel("pose", fm, info)

    @staticmethod
    def desk_fields(info, R, t) -> np.ndarray:
        """A desk camera's gaze fields (:func:`~resti_lib.geometry.fields.gaze_fields`) in the group's levelled
        frame (``info["level"]``, about the levelled gaze point ``info["gaze"]``)."""
        A = info["level"]
        return gaze_fields(A @ np.asarray(R, float), A @ np.asarray(t, float), info["gaze"])

    @staticmethod
    def desk_pose(info, f) -> tuple[np.ndarray, np.ndarray]:
        """The rotation and centre, in the reference frame, of the desk fields ``f`` (:meth:`desk_fields`)."""
        R, t = from_gaze_fields(f, info["gaze"])
        return info["level"].T @ R, info["level"].T @ t

    @staticmethod
    def tilt_readout(F, tilt_ref: float, decimals):
        """The echo readout of the two tilt fields (:data:`TILT_FIELDS`, drawn alone, the other fields at the
        row's answer): the up components of the camera's axes that each moves, rounded as the row prints
        them. With ``R = A^T Rz(yaw) Ry(b) Rx(c)`` those are ``(-sin b, cos b sin c, cos b cos c)``, free of the
        heading, and they are printed entries (the third row) when the world's up is a world axis: the first
        tilt is read as ``-sin b``, the second as whichever of the other two it moves more at ``tilt_ref``."""
        b_rows = np.asarray(F, float)[:, TILT_FIELDS[0]]
        scale = 10.0 ** np.asarray(decimals, float)
        second = np.sin if abs(np.cos(tilt_ref)) >= abs(np.sin(tilt_ref)) else np.cos

        def printed(c, sel, j):
            if j == TILT_FIELDS[0]:
                u = -np.sin(c)
            else:
                u = np.cos(b_rows[sel])[None, :, None] * second(c + tilt_ref)
            k = scale[sel][None, :, None]
            return np.round(u * k) / k

        return printed

    @staticmethod
    def translation_fields(d, half: float, rate: bool) -> tuple[list[float], list[float]]:
        """The fields of a motion ``d`` (forward, left, up in the premise's heading frame) and the half
        width of its printed cell in each. A vehicle's (``rate``): the log of its speed and the
        direction of its motion (the angle from forward, and the climb), since a car moves along its
        heading and its sideways motion grows with its speed (drawn as three independent-looking
        components, a slow car's distractors veered where its answer goes straight). Others: the
        three components."""
        d = np.asarray(d, float)
        if not rate:
            return [float(x) for x in d], [half] * 3
        r = float(np.linalg.norm(d))
        ang = min(half / max(r, half), np.pi)
        return ([float(np.log(r + half)), float(np.arctan2(d[1], d[0])), float(np.arctan2(d[2], np.hypot(d[0], d[1])))],
                [half / (r + half), ang, ang])

    @staticmethod
    def translation_of(f, half: float, rate: bool) -> np.ndarray:
        """The motion of :meth:`translation_fields` (its inverse)."""
        if not rate:
            return np.asarray(f[:3], float)
        r = max(float(np.exp(f[0])) - half, 0.0)
        az, el = float(f[1]), float(f[2])
        return r * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])

    @staticmethod
    def rotation_fields(R, premise_yaw: float, sign: float, up, tilt_ref: float) -> list[float]:
        """A rotation's fields: its turn about the vertical from the premise's heading ``premise_yaw``
        (signed by the direction of time) and its two tilts from level (the second about
        ``tilt_ref``), radians."""
        a, b, c = yaw_tilt(R, up)
        turn, lean = np.radians(V.wrap_degrees(np.degrees([a - premise_yaw, c - tilt_ref])))
        return [float(sign * turn), float(b), float(lean)]

    @staticmethod
    def rotation_of(fields, premise_yaw: float, sign: float, up, tilt_ref: float) -> np.ndarray:
        """The rotation of :meth:`rotation_fields` (its inverse)."""
        return from_yaw_tilt([premise_yaw + sign * fields[0], fields[1], fields[2] + tilt_ref], up)

    def build(self, st, p, gm, s, rng, strict, reveals):
        spec = p.spec
        v: V.Pose = spec.value
        info = gm.info
        R0, t0 = info["R0"][p.rid], np.array(v.t, float)
        win = info["win"][p.rid]
        sign = time_sign(spec.obs)
        scale = sign * (win if info["rate"] else 1.0)
        h_t = 0.5 * 10.0 ** -v.decimals
        strings: list[str] = []
        fixed_reveals = list(reveals.get(p.rid, [])) if strict else []  # relaxed tiers draw them all
        n_draw = 4
        if fixed_reveals:
            pick = [fixed_reveals[int(i)] for i in rng.permutation(len(fixed_reveals))[:4]]
            strings += pick
            n_draw = 4 - len(pick)
        if n_draw and info["relative"]:
            f0 = self.desk_fields(info, R0, t0)
            hh = shell_half_cells(f0, h_t) + [0.0] * 3  # the rotation's fields: the preimage's point (ANCHOR)
            f0[1] = float(on_cut_line(f0[1], info["cut_az"]))
            f0[5] = float(on_cut_line(f0[5], info["cut"]))
            B = st.draw(gm, p.rid, [(f0[j] - hh[j], f0[j] + hh[j]) for j in range(6)], s, rng, n=n_draw)
            for b in B:
                b = np.array(b, float)
                b[1] = float(from_cut_line(b[1], info["cut_az"]))
                b[5] = float(from_cut_line(b[5], info["cut"]))
                R, t = self.desk_pose(info, b)
                T = np.eye(4)
                T[:3, :3] = R
                T[:3, 3] = [round(float(t[j]), info["t_decimals"][j]) for j in range(3)]
                strings.append(V.format_pose(T, v.decimals, compact=v.compact, signed_zero=info["signed_zero"]))
        elif n_draw:
            _, tp, Hf, yaw_p = info["frame"][p.rid]
            up = np.asarray(st.params["kinds"]["pose"]["world_up"], float)
            f_t, h_f = self.translation_fields(Hf.T @ (t0 - tp) / scale, h_t / abs(scale), info["rate"])
            f0 = np.concatenate([f_t, self.rotation_fields(R0, yaw_p, sign, up, info["tilt_ref"])])
            hh = [*h_f] + [0.0] * 3  # the rotation's fields: the preimage's point (see ANCHOR)
            B = st.draw(gm, p.rid, [(f0[j] - hh[j], f0[j] + hh[j]) for j in range(6)], s, rng, n=n_draw)
            for b in B:
                T = np.eye(4)
                T[:3, :3] = self.rotation_of(b[3:6], yaw_p, sign, up, info["tilt_ref"])
                t = tp + Hf @ (self.translation_of(b[:3], h_t / abs(scale), info["rate"]) * scale)
                T[:3, 3] = [round(float(t[j]), info["t_decimals"][j]) for j in range(3)]
                strings.append(V.format_pose(T, v.decimals, compact=v.compact, signed_zero=info["signed_zero"]))
        self.check(st, p, [V.parse(t) for t in strings] + [v])
        return strings + [spec.detail]

    def check(self, st, p, poses):
        spec = p.spec
        fl = pose_floors(spec, st.params)
        if len({q.text for q in poses}) != 5:
            raise Reject("two poses print the same")
        rots = [tuple(np.round(np.array(q.R), 6).ravel()) for q in poses]
        if len(set(rots)) != 5:
            raise Reject("two poses print the same rotation")
        for i in range(5):
            for j in range(i + 1, 5):
                if pose_separation(poses[i], poses[j], fl) < 1.0:
                    raise Reject("two poses within the separation floors of each other")
        o = spec.obs
        if o.premise is not None and o.window_s and o.window_s > 0:
            vmax = speed_bound(st.params, spec.source, o.subject_class)
            tp = o.premise[:3, 3]
            for q in poses[:-1]:
                if np.linalg.norm(np.array(q.t) - tp) / o.window_s > vmax:
                    raise Reject("a pose implies an impossible speed from the premise")
