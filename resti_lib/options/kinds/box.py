"""Boxes: centre (image-plane direction and depth, or height), log edges relative to the class and heading drawn jointly."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import spearmanr

from ... import values as V
from ...errors import InputError
from ...geometry.fields import (
    box_yaw,
    centre_fields,
    centre_from_fields,
    centre_half_cells,
    concentrated_axis,
    rot,
    rotation_preimage,
)
from ...measure.relations import name_mount_yaw
from ...rng import row_rng
from ..plan import GroupModel, Reject, RowPlan, recorded_decimals
from ..population import circular_cut, from_cut_line, hierarchical_offsets, on_cut_line
from ..spec import (
    OPTION_PARAMS,
    box_floors,
    box_separation,
    per_source,
)
from . import KindBuilder, register_kind

EXPONENTS = np.linspace(0.0, 1.0, 21)   # the depth exponents tried for an image-plane coordinate


def depth_exponent(x, z) -> float:
    """The exponent ``p`` of :data:`EXPONENTS` for which the magnitude of ``x / z**p`` is least rank-correlated
    with the depth ``z`` among a group's answers (1.0, the direction x/z, below 8 answers).

    A box's lateral offset is spread in metres at every depth (a lane is a lane near and far), so its
    direction x/z narrows with depth: a dependence of spread, which a normal copula of x/z and log z cannot
    hold. Drawn as x/z with the depth drawn near the answer's, the distractors would then pair wide
    directions with far depths and print lateral offsets no answer has. Drawn as the coordinate whose
    magnitude does not depend on depth, they print them as the answers do."""
    x, z = np.asarray(x, float), np.asarray(z, float)
    ax, lz = np.abs(x), np.log(z)
    if x.size < 8 or np.ptp(lz) == 0 or np.ptp(ax) == 0:  # no depth dependence can be read
        return 1.0
    best, best_r = 1.0, math.inf
    for p in EXPONENTS:
        r = abs(float(spearmanr(ax / z ** p, lz)[0]))
        if np.isfinite(r) and r < best_r - 1e-9:
            best, best_r = float(p), r
    return best


@register_kind("box")
class BoxKind(KindBuilder):
    """Boxes: centre (image-plane direction and depth, or height), log edges relative to the class
    and heading drawn jointly."""

    def fit(self, st, g: str, ps: list[RowPlan]) -> GroupModel:
        kp = st.params["kinds"]["box"]
        src = ps[0].spec.source
        mode = per_source(kp["centre"], src, "projective")
        up_axis = per_source(kp["up_axis"], src, None)
        if up_axis not in (None, 0, 1, 2, "auto") or isinstance(up_axis, bool):
            raise InputError(f"kinds.box.up_axis for {src} is {up_axis!r}: a box axis 0, 1 or 2, 'auto' (the axis "
                             "most concentrated over the group's answers) or null (isotropic rotations)",
                             file=OPTION_PARAMS, field=f"kinds.box.up_axis.{src}")
        # the heading is drawn in the vehicle frame where the source names the camera's mount: the camera-frame
        # heading plus the mount yaw of the camera the video names (what a blind reader knows), so the
        # headings of cars along the road gather at one place whichever camera sees them
        in_vehicle = per_source(kp["mount_frame"], src, False)
        if not isinstance(in_vehicle, bool):
            raise InputError(f"kinds.box.mount_frame for {src} is {in_vehicle!r}: true (headings drawn in the vehicle "
                             "frame of the camera the video names) or false", file=OPTION_PARAMS,
                             field=f"kinds.box.mount_frame.{src}")
        mount = {p.rid: (name_mount_yaw(p.spec.obs.camera) if in_vehicle else None) or 0.0 for p in ps}
        info: dict = {"mode": {}, "R0": {}, "yaw0": {}, "class_off": {}}
        cs = np.array([p.spec.value.center for p in ps], float)
        ds = np.array([p.spec.value.lwh for p in ps], float)
        front = cs[:, 2] > 0
        info["power"] = (depth_exponent(cs[front, 0], cs[front, 2]),
                         depth_exponent(cs[front, 1], cs[front, 2]) if mode == "projective" else 1.0)
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
            rng = row_rng(st.seed, p.rid, "preimage")
            R0 = rotation_preimage(v.R, 6, rng, accept=lambda Q, h=v.heading: h is None or
                                   round(V.box_heading(Q), 2) == round(h, 2))
            info["R0"][p.rid] = R0
            lds.append(np.log(np.maximum(np.array(v.lwh, float), 1e-4)))
        lds = np.array(lds)
        if up_axis == "auto":
            up_axis = concentrated_axis([info["R0"][p.rid] for p in ps])
        info["up_axis"] = up_axis
        coff = hierarchical_offsets([(p.spec.obs.subject_class,) for p in ps], lds, st.model["class_shrink"])
        cut = None
        if up_axis is not None:  # each answer's heading, in the vehicle frame where mounted
            info["yaw0"] = {p.rid: box_yaw(info["R0"][p.rid], up_axis) + mount[p.rid] for p in ps}
            cut = circular_cut(list(info["yaw0"].values()))
            info["cut"] = cut
        # centre fields use one mode per group (rows behind the camera: cartesian in their own model)
        for i, p in enumerate(ps):
            v = p.spec.value
            c = np.array(v.center, float)
            m = info["mode"][p.rid]
            f = centre_fields(c, mode, info["power"]) if m == mode else np.full(3, np.nan)
            hc = centre_half_cells(c, mode, 10.0 ** -3, info["power"])
            dd = np.maximum(np.array(v.lwh, float), 1e-4)
            hd = 0.5e-3 / dd
            info["class_off"][p.rid] = coff[i]
            row_f = [*f, *(lds[i] - coff[i])]
            row_h = [*hc, *hd]
            if up_axis is not None:
                row_f.append(float(on_cut_line(info["yaw0"][p.rid], cut)))
                row_h.append(0.005)
            rows_f.append(row_f)
            rows_h.append(row_h)
        F, Hh = np.array(rows_f, float), np.array(rows_h, float)
        ok = np.isfinite(F).all(axis=1)
        members = [p.rid for p, k in zip(ps, ok) if k]
        if not members:
            raise InputError(f"{g}: no box in front of the camera", field="Answer Detail")
        # the echo is read per field on the fields' scale, the edges as log metres (class offset back)
        off = np.zeros_like(F)
        off[:, 3:6] = np.asarray(coff, float)
        if up_axis is not None:  # the heading back in the camera frame, as printed
            off[:, 6] = [-mount[p.rid] for p in ps]
        off6 = off[ok][:, 6] if up_axis is not None else None   # the echo's rows are the members

        def printed(c, sel, j):
            """The heading read two ways: as the rotation prints it (its cosine, camera frame) and as a reader who
            knows the camera turns it (the vehicle-frame angle, on the cut line; near 0 and 180 degrees, where
            cars along the road are, the cosine is flat and shows no echo). The other fields as drawn."""
            if j != 6:
                return c
            return [np.cos(np.radians(from_cut_line(c, cut))), c - off6[sel][None, :, None]]

        fm = st.fit_fields([p for p, k in zip(ps, ok) if k], F[ok], Hh[ok], None,
                           prior_sd=[0.1, 0.1, 0.3, 0.3, 0.3, 0.3, 30.0], echo=st.echo_spec(None, off[ok], printed))
        info["group_mode"] = mode
        # rows behind the camera: draw like the nearest member in the field model (rare; recorded)
        info["proxy"] = {p.rid: members[0] for p, k in zip(ps, ok) if not k}
        return GroupModel("box", fm, info)

    # -- structured kinds
    def build(self, st, p, gm, s, rng, strict, reveals):
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
            f0 = centre_fields(c0, mode, info["power"])
            hc = centre_half_cells(c0, mode, 1e-3, info["power"])
            cells = [(f0[j] - hc[j], f0[j] + hc[j]) for j in range(3)]
            ld = np.log(np.maximum(d0, 1e-4)) - coff
            hd = 0.5e-3 / np.maximum(d0, 1e-4)
            cells += [(ld[j] - hd[j], ld[j] + hd[j]) for j in range(3)]
            if up_axis is not None:
                y = float(on_cut_line(info["yaw0"][p.rid], info["cut"]))
                cells.append((y, y))  # the preimage's heading: a point of its printed cell (pose.ANCHOR)
            B = st.draw(gm, p.rid, cells, s, rng, n=4)
            centres = np.array([centre_from_fields(b[:3], mode, info["power"]) for b in B])
        else:  # a centre behind the camera: exchangeable cartesian shifts
            B = st.draw(gm, rid, [], s, rng, n=4, prior=True)
            centres = c0 + rng.normal(0.0, 0.1 * max(1.0, np.linalg.norm(c0)), (4, 3))
        dims = np.exp(B[:, 3:6] + coff)
        if up_axis is not None:
            yaws = from_cut_line(B[:, 6], info["cut"])
            e = np.zeros(3)
            e[up_axis] = 1.0
            rots = [R0 @ rot(e, float(V.wrap_degrees(y - info["yaw0"][p.rid]))) for y in yaws]
        else:
            sig = np.radians(st.params["kinds"]["box"]["iso_sigma_deg"])
            Q = [Rotation.from_rotvec(rng.normal(0.0, sig, 3)).as_matrix() for _ in range(5)]
            rots = [R0 @ Q[4].T @ Q[i] for i in range(4)]
        dec = info["decimals"]
        centres = np.column_stack([np.round(centres[:, j], dec[f"c{j}"]) for j in range(3)])
        dims = np.column_stack([np.round(dims[:, j], dec[f"d{j}"]) for j in range(3)])
        strings = [V.format_box(centres[i], dims[i], rots[i]) for i in range(4)]
        parsed = [V.parse(t) for t in strings]
        self.check(st, spec, [*parsed, v])
        return strings + [spec.detail]

    def check(self, st, spec, boxes):
        fl = box_floors(spec, st.params)
        pl = st.params["plausibility"]
        max_size = float(per_source(pl["max_size_m"], spec.source, math.inf))
        dmin = float(per_source(pl["min_depth_m"], spec.source, 0.0))
        dmax = float(per_source(pl["max_depth_m"], spec.source, math.inf))
        strings = [b.text for b in boxes]
        if len(set(strings)) != 5:
            raise Reject("two boxes print the same")
        for b in boxes[:-1]:
            d = np.array(b.lwh)
            if (d <= 0).any() or (d > max_size).any():
                raise Reject("a box size is not physically possible")
            depth = float(np.linalg.norm(b.center))
            if b.center[2] > 0 and not dmin <= b.center[2] <= dmax:
                raise Reject("a box depth is not physically possible")
            if not np.isfinite(depth):
                raise Reject("a box centre is not finite")
        for i in range(5):
            for j in range(i + 1, 5):
                if box_separation(boxes[i], boxes[j], fl) < 1.0:
                    raise Reject("two boxes within the separation floors of each other")
