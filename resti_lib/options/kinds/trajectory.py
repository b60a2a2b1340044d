"""Trajectory descriptions: total distances drawn as rates over the window (in batches; the answer
keeps the rank an unconstrained draw gives it), split and turned like the answer's structure; 'no
significant movement' as a slot."""

from __future__ import annotations

import math

import numpy as np

from ... import values as V
from ...errors import OptionError
from ...rng import row_rng
from ..attacks.features import reader_log
from ..follow import turn_sum
from ..plan import GroupModel, Reject, RowPlan, log_window, slot_rows
from ..spec import (
    scalar_bounds,
)
from . import KindBuilder, register_kind
from .oned import drawn_rank, first_valid_1d


@register_kind("trajectory")
class TrajectoryKind(KindBuilder):
    """Trajectory descriptions: total distances drawn as rates over the window (in batches; the
    answer keeps the rank an unconstrained draw gives it), split and turned like the answer's
    structure; 'no significant movement' as a slot."""

    def fit(self, st, g: str, ps: list[RowPlan]) -> GroupModel:
        moving = [p for p in ps if p.spec.value.segments and p.spec.value.total_distance > 0]
        none = [p.rid for p in ps if not p.spec.value.segments]
        info: dict = {"offset": {}}
        fm = None
        if moving:
            x = np.array([p.spec.value.total_distance for p in moving])
            ow = np.array([log_window(p.spec) for p in moving])
            ow = np.where(np.isfinite(ow), ow, 0.0)
            for p, o in zip(moving, ow):
                info["offset"][p.rid] = float(o)
            H = 0.5 * st.params["separation"]["trajectory"]["min_rel_gap"] * x / (x + 0.1)
            W = np.array([[log_window(p.spec)] for p in moving])
            W = W if np.isfinite(W).all() else None
            fm = st.fit_fields(moving, np.log(x + 0.1) - ow, H, W, echo=st.echo_spec(None, ow, _reader_scale))
        else:  # only "no significant movement": single moves of a few metres per second of window
            fm = st.fit_fields([], None, None, None, prior_sd=1.0, prior_center=[math.log(3.0)])
        carriers = slot_rows(none, [p.rid for p in moving], st.model["zero_slot_ratio"], seed=st.seed, group=g)
        donors = sorted(p.rid for p in moving)
        for p in ps:
            if p.rid in carriers:
                p.fixed = (V.NO_MOVEMENT,)
                p.answer_is_fixed = not p.spec.value.segments
                if p.answer_is_fixed and donors:
                    p.donor = donors[int(row_rng(st.seed, p.rid, "donor").integers(len(donors)))]
        return GroupModel("trajectory", fm, info)

    def build(self, st, p, gm, s, rng, strict, reveals):
        spec = p.spec
        v: V.Trajectory = spec.value
        fixed = list(p.fixed)
        n_cont = 5 - len(fixed)
        pars = {"split_sigma": 0.25, "turn_sigma_deg": 15.0}
        lo_b, hi_b = scalar_bounds(spec, st.params)
        rel = st.params["separation"]["trajectory"]["min_rel_gap"]
        turn_gap = float(st.params["separation"]["angle"]["min_sep_deg"])
        if p.answer_is_fixed:
            template = st.by_id[p.donor].spec.value if p.donor else V.Trajectory((("move", 1.0),), "")
            fmt = traj_formatter(template, pars, rng, centred=False)
            off = log_window(spec)
            off = off if math.isfinite(off) else 0.0
            b = st.draw(gm, p.donor if p.donor in gm.fields.index else None, [], s, rng, n=n_cont, prior=True)[:, 0]
            totals = np.exp(b + off) - 0.1
            strings = [fmt(float(t)) for t in totals]
            alls = strings + fixed
            values = [V.parse(t).total_distance for t in strings]
        else:
            if not v.segments or v.total_distance <= 0:
                raise OptionError(f"trajectory {spec.detail!r} has no movement to vary")
            fmt = traj_formatter(v, pars, rng, centred=True)
            off = gm.info["offset"][p.rid]
            x = v.total_distance
            cell = (math.log(max(x - 0.05, 0.0) + 0.1) - off, math.log(x + 0.05 + 0.1) - off)
            K = 32
            totals = np.exp(st.draw(gm, p.rid, [cell], s, rng, n=n_cont - 1, batch=K)[:, :, 0] + off) - 0.1
            allv = np.column_stack([totals, np.full(K, x)])
            ok = (totals > 0).all(axis=1) & (totals <= hi_b).all(axis=1)
            at_rank = drawn_rank(p, allv, n_cont - 1)
            for i in first_valid_1d(allv, ok, np.zeros_like, rel=rel, at_rank=at_rank):
                strings = [fmt(float(t)) for t in totals[i]]
                parsed = [V.parse(t) for t in strings]
                if {t.structure for t in parsed} != {v.structure}:
                    continue  # a distractor lost the answer's structure
                if not _turns_apart([*parsed, v], turn_gap):
                    continue  # two candidates turn alike: a heading change asked beside could not match both
                alls = strings + fixed + [spec.detail]
                values = [t.total_distance for t in parsed] + [x]
                if _valid(alls, values, hi_b, rel):
                    if st.last_draw is not None:
                        st.last_draw.keep(i)
                    return alls
            raise Reject("no drawn set met the separation constraints" + ("" if at_rank[2] else " at the drawn rank"))
        if not _valid(alls, values, hi_b, rel):
            raise Reject("a distractor set broke the separation or plausibility constraints")
        return alls

    def near(self, st, a, b) -> bool:
        """Two moving answers of one structure, turns that print alike and totals closer than the
        separation floor: the camera videos of one Waymo segment describe one drive, each from its
        mount (path lengths a few centimetres apart), and their heading changes are one."""
        va, vb = a.spec.value, b.spec.value
        if not va.segments or not vb.segments or va.structure != vb.structure:
            return False
        if any(k == "turn" and round(x) != round(y) for (k, x), (_, y) in zip(va.segments, vb.segments)):
            return False
        x, y = va.total_distance, vb.total_distance
        rel = st.params["separation"]["trajectory"]["min_rel_gap"]
        return x > 0 and y > 0 and abs(x - y) < rel * max(x, y)

    def translate(self, st, base, p, strings):
        """Each of ``base``'s distractors moved segment by segment by the difference of the two
        answers (the slot phrase kept): the turns a sibling heading change or another camera's
        description names then match every candidate, or none."""
        bv = base.spec.value
        d = [x - y for (_, x), (_, y) in zip(p.spec.value.segments, bv.segments)]
        out = []
        for text in (x for x in strings if x != base.spec.detail):
            t = V.parse(text)
            if not t.segments:
                out.append(text)
                continue
            if t.structure != bv.structure:
                return None
            segs = [(k, x + dd) for (k, x), dd in zip(t.segments, d)]
            if any(k == "move" and x <= 0 for k, x in segs):
                return None
            out.append(V.format_trajectory(segs))
        out.append(p.spec.detail)
        return out if len(set(out)) == 5 else None


def _turns_apart(candidates: list[V.Trajectory], gap: float) -> bool:
    """Candidates that turn have printed turn sums ``gap`` degrees apart (the heading-change
    separation): the heading-change rows of the recording follow the set (turn sum = heading change),
    and two candidates turning alike would leave one of their images unmatched, or matched by the
    answer alone."""
    sums = sorted(round(turn_sum(t)) for t in candidates if any(k == "turn" for k, _ in t.segments))
    return all(b - a >= gap for a, b in zip(sums, sums[1:]))


def _valid(alls: list[str], values: list[float], hi_b: float, rel: float) -> bool:
    """Five distinct phrases whose totals are positive, physically possible and a relative gap apart."""
    if any(t <= 0 or t > hi_b for t in values) or len(set(alls)) != 5:
        return False
    xs = sorted(values)
    return all((b2 - a) >= rel * b2 for a, b2 in zip(xs, xs[1:]))


def traj_formatter(template: V.Trajectory, pars: dict, rng, *, centred: bool):
    """A function total -> phrase with the template's structure and exchangeable splits and turns.

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


def _reader_scale(c: np.ndarray, sel, j=0) -> np.ndarray:
    """Log totals over the window plus the window (``log(x + 0.1)``) as readers compare them: the log of
    the total distance (:func:`resti_lib.options.attacks.features.value_scale`)."""
    return reader_log(np.maximum(np.exp(c) - 0.1, 0.0))
