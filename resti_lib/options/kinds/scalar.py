"""Scalars: magnitudes drawn as log rates over the question's window, relative to their subject's
class; exact zeros and floor answers as slots; sizes that recur elsewhere reused as often as the answers."""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np

from ... import values as V
from ..attacks.features import reader_log
from ..follow import DIMENSIONS
from ..plan import (
    OBJECT_SIZES,
    WINDOWED,
    GroupModel,
    Reject,
    RowPlan,
    log_window,
    mid_time,
    slot_answers,
    slot_rows,
    slot_subgroup,
)
from ..population import hierarchical_offsets
from ..spec import (
    scalar_bounds,
    scalar_gap,
)
from . import KindBuilder, register_kind
from .oned import check_1d, first_valid_1d


@register_kind("scalar")
class ScalarKind(KindBuilder):
    """Scalars: magnitudes drawn as log rates over the question's window, relative to their
    subject's class; exact zeros as slots; sizes that recur elsewhere reused as often as the
    answers."""

    # -------------------------------------------------------------------- group fits
    def fit(self, st, g: str, ps: list[RowPlan]) -> GroupModel:
        vals = np.array([p.spec.value.value for p in ps], float)
        eps = min(p.spec.ulp for p in ps)
        moving = [p for p, v in zip(ps, vals) if v > 0]
        info: dict = {"eps": eps, "offset": {}}
        if moving:
            x = np.array([p.spec.value.value for p in moving], float)
            b0 = np.log(x + eps)
            ow = np.array([log_window(p.spec) if p.spec.obs.quantity in WINDOWED else 0.0 for p in moving])
            ow = np.where(np.isfinite(ow), ow, 0.0)
            keys = [(p.spec.source, p.spec.obs.quantity, p.spec.obs.subject_class) for p in moving]
            oc = hierarchical_offsets(keys, b0 - ow, st.model["class_shrink"],
                                      groups=[p.spec.obs.sequence for p in moving],
                                      extra=size_evidence(st, moving, eps), empirical=True)
            off = ow + oc
            for p, o in zip(moving, off):
                info["offset"][p.rid] = float(o)
            # smallest bandwidth: half the separation floor (a population concentrated below the floor
            # is modelled at the floor's resolution, where five separated candidates can be typical)
            H = np.array([0.5 * max(scalar_gap(p.spec, st.params, p.spec.value.value),
                                    st.params["separation"]["scalar"]["min_rel_gap"] * p.spec.value.value)
                          / (p.spec.value.value + eps) for p in moving])
            W = np.array([[log_window(p.spec), mid_time(p.spec)] for p in moving])
            W = W[:, np.isfinite(W).all(axis=0)] if len(W) else None
            # coarse printing: five candidates at least a printed unit apart cannot crowd an answer of a
            # few units as the anchor model would, so they take one stratum of the distribution each
            units = float(np.median([p.spec.value.value / p.spec.ulp for p in moving]))
            lat = st.model["lattice"]
            # narrow populations too: where the middle half of the class-relative answers spans few
            # separation floors (vehicle lengths: 7 floors of 3%), five separated candidates cannot
            # stay inside it, and the sets kept lean to its wider side (the answer the smallest)
            q1, q3 = np.percentile(b0 - off, [25, 75])
            floors = float((q3 - q1) / max(2.0 * float(np.median(H)), 1e-12))
            narrow = len(moving) >= int(st.model["min_group"]) and floors < float(lat.get("below_floors", 0))
            if units < float(lat["below_units"]) or narrow:
                info["lattice"] = float(lat["width"])
            ulp = np.array([p.spec.ulp for p in moving])
            si = np.array([p.spec.value.si_per_unit for p in moving])

            def printed(c, sel, j=0):  # log rate + offset -> the printed value, on the readers' scale (SI, log)
                x = np.maximum(np.round((np.exp(c) - eps) / ulp[sel][None, :, None]), 1.0) * ulp[sel][None, :, None]
                return reader_log(x * si[sel][None, :, None])

            fm = st.fit_fields(moving, b0 - off, H, W, echo=st.echo_spec(info.get("lattice"), off, printed))
        else:  # only exact zeros: distractors from a weak prior about twenty printed units
            fm = st.fit_fields([], None, None, None, prior_sd=1.0, prior_center=[math.log(20 * eps + eps)])
        gm_reuse = GroupModel("scalar", None, {})
        fit_reuse(gm_reuse, ps)
        info.update(gm_reuse.info)
        # slot answers (exact zeros, answers at the printing floor: plan.slot_answers) are fixed strings
        # that other rows carry as distractors, as often as zero_slot_ratio says
        slots = slot_answers([p.spec for p in ps])
        carried: dict[str, list] = defaultdict(list)
        first: set = set()
        # a floor value is offered as its slot only: no row of the subgroup draws a candidate printed there
        info["floor_slot"] = sorted({sub for (sub, value) in slots if value > 0}, key=str)
        for (sub, value), idx in slots.items():
            answers = {ps[i].rid for i in idx}
            # a zero is carried by moving rows; the floor by any other row of its subgroup (the zeros too)
            others = [p.rid for p in ps if slot_subgroup(p.spec) == sub and p.rid not in answers
                      and (value > 0 or p.spec.value.value > 0)]
            tag = f"{g}|{sub}" if sub not in first else f"{g}|{sub}|{value:g}"
            first.add(sub)
            for rid in sorted(slot_rows(sorted(answers), others, st.model["zero_slot_ratio"], seed=st.seed,
                                        group=tag)):
                carried[rid].append(None if rid in answers else value)
        for p in ps:
            if p.rid in carried:  # the row's own answer first, then the slot values it carries
                own = None in carried[p.rid]
                p.answer_is_fixed = own
                p.fixed = tuple(([p.spec.detail] if own else []) +
                                [V.format_scalar(x, p.spec.unit, p.spec.decimals) for x in carried[p.rid] if x is not None])
        return GroupModel("scalar", fm, info)

    def build(self, st, p, gm, s, rng, strict, reveals):
        spec = p.spec
        v: V.Scalar = spec.value
        eps = gm.info["eps"]
        _, hi_b = scalar_bounds(spec, st.params)
        fixed = list(p.fixed)
        n_cont = 5 - len(fixed)
        n_draw = n_cont if p.answer_is_fixed else n_cont - 1
        K = 32
        if p.answer_is_fixed:
            rid = p.rid if p.rid in gm.fields.index else None
            off = gm.info["offset"][rid] if rid is not None else mean_offset(gm, spec)
        else:
            off = gm.info["offset"][p.rid]
        # what the row can print: above zero (half a printed unit; above the floor, one and a half, where the
        # floor is a slot), below the physical bound
        low = 1.5 if slot_subgroup(spec) in gm.info.get("floor_slot", ()) else 0.5
        bounds = [(math.log(low * spec.ulp + eps) - off, math.log(hi_b + eps) - off if math.isfinite(hi_b) else None)]
        if p.answer_is_fixed:
            b = st.draw(gm, rid, [], s, rng, n=n_draw, prior=True, batch=K, bounds=bounds,
                        lattice=gm.info.get("lattice"))[:, :, 0]
        elif st.free_draw:
            b = st.draw(gm, p.rid, [], s, rng, n=n_draw, prior=True, batch=K, bounds=bounds)[:, :, 0]
        else:
            x = v.value
            cell = (math.log(max(x - 0.5 * spec.ulp, 0.0) + eps) - off, math.log(x + 0.5 * spec.ulp + eps) - off)
            lattice = gm.info.get("lattice")
            b = st.draw(gm, p.rid, [cell], s, rng, n=n_draw, batch=K, bounds=bounds, lattice=lattice)[:, :, 0]
            if lattice is not None:
                p.evidence["draw"] = "lattice"
        dec = spec.decimals
        xs = np.exp(b + off) - eps
        if strict:  # the widened tiers leave the reuse rate aside rather than fail the row
            xs = reuse(gm, p, xs, rng)
        pv = np.round(xs, dec)
        extra = [float(V.parse(t).value) for t in fixed] + ([] if p.answer_is_fixed else [v.value])
        allv = np.column_stack([pv, np.tile(extra, (K, 1))]) if extra else pv
        ok = (pv > 0).all(axis=1) & (pv <= hi_b + 1e-12).all(axis=1)
        sep = st.params["separation"]["scalar"]
        per_unit = v.si_per_unit
        ulp = spec.ulp

        def gap_of(upper):
            tol = 0.5 * ulp + (spec.rule.abs_tol + spec.rule.rel_tol * upper * per_unit) / per_unit
            return np.maximum(sep["min_gap_ulps"] * ulp, tol)

        for i in first_valid_1d(allv, ok, gap_of, rel=sep["min_rel_gap"]):
            strings = [V.format_scalar(float(t), v.unit, dec) for t in xs[i]]
            alls = strings + fixed + ([] if p.answer_is_fixed else [spec.detail])
            try:
                check_1d(spec, [float(V.parse(t).value) for t in alls], alls,
                               gap=lambda t: scalar_gap(spec, st.params, t), rel=sep["min_rel_gap"])
            except Reject:
                continue
            if st.last_draw is not None:
                st.last_draw.keep(i)
            return alls
        raise Reject("no drawn set met the separation and plausibility constraints")

    def near(self, st, a, b) -> bool:
        x, y = a.spec.value.value, b.spec.value.value
        return x > 0 and y > 0 and abs(x - y) < scalar_gap(a.spec, st.params, max(x, y))

    def translate(self, st, base, p, strings):
        d = p.spec.value.value - base.spec.value.value
        vals = [float(V.parse(s).value) + d for s in strings if s != base.spec.detail]
        if any(x <= 0 for x in vals):
            return None
        out = [V.format_scalar(x, p.spec.unit, p.spec.decimals) for x in vals] + [p.spec.detail]
        return out if len(set(out)) == 5 else None


def size_evidence(st, ps: list, eps: float) -> tuple[list, list, list] | None:
    """The sizes of the classes of a group's rows that the boxes of another task state: for each box
    of the stage of the rows' sources, its edge that a dimension question of that
    source asks (:func:`resti_lib.options.follow.box_edge_map`), in the rows' unit and printing, as
    (keys, base values, recordings) for :func:`hierarchical_offsets`. A class asked once or twice as a
    dimension (a sedan's length) is then placed by every sedan box of the other recordings, not by the
    group's mean, which its buses and trucks pull up."""
    want = {(p.spec.source, p.spec.obs.quantity): p.spec for p in ps if p.spec.obs.quantity in DIMENSIONS}
    edge = {k: st.edge_map[k] for k in want if k in st.edge_map}
    if not edge:
        return None
    keys, vals, grps = [], [], []
    for b in (st.by_id[rid].spec for rid in st.box_links):
        for (src, q), j in edge.items():
            if b.source != src or not isinstance(b.value, V.Box):
                continue
            like = want[(src, q)]
            x = round(float(b.value.lwh[j]) / like.value.si_per_unit, like.decimals)
            if x > 0:
                keys.append((src, q, b.obs.subject_class))
                vals.append(math.log(x + eps))
                grps.append(b.obs.sequence)
    return (keys, vals, grps) if keys else None


def fit_reuse(gm: GroupModel, ps: list) -> None:
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
    # only the values that recur: a value answered in one recording and taken as a distractor in others
    # is seen elsewhere only as a distractor, which is how a reader of the other recordings would
    # tell the row where it is the answer
    gm.info["reuse_values"] = np.array(sorted(x for x, q in seqs.items() if len(q) >= 2))
    gm.info["reuse_seqs"] = seqs


def reuse(gm: GroupModel, p: RowPlan, xs: np.ndarray, rng) -> np.ndarray:
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
    # a set never snaps two values onto one answer, nor onto the row's own answer: that would print
    # one value twice, and the set would be redrawn forever where every value recurs
    taken = np.round(np.where(already, near, np.nan), p.spec.decimals)
    own_value = round(float(p.spec.value.value), p.spec.decimals)
    for k, j in zip(*np.nonzero(snap)):
        target = round(float(near[k, j]), p.spec.decimals)
        if target == own_value or target in set(taken[k][np.isfinite(taken[k])]):
            snap[k, j] = False
        else:
            taken[k, j] = target
    return np.where(snap, near, xs)


def mean_offset(gm, spec) -> float:
    q = spec.obs.quantity
    if q in WINDOWED:
        lw = log_window(spec)
        return lw if math.isfinite(lw) else 0.0
    return float(np.mean(list(gm.info["offset"].values()))) if gm.info["offset"] else 0.0
