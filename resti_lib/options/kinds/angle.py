"""Angles (heading changes): drawn on a bounded scale, at least the separation floor apart
circularly; a dense window of answers is a slot."""

from __future__ import annotations

import numpy as np

from ... import values as V
from ..plan import GroupModel, Reject, RowPlan, dense_window, log_window, slot_rows
from ..spec import (
    angle_gap,
)
from . import KindBuilder, register_kind
from .oned import check_1d, first_valid_1d


@register_kind("angle")
class AngleKind(KindBuilder):
    """Angles (heading changes): drawn on a bounded scale, at least the separation floor apart
    circularly; a dense window of answers is a slot."""

    def fit(self, st, g: str, ps: list[RowPlan]) -> GroupModel:
        th = np.array([p.spec.value.value for p in ps], float)
        b = np.arctanh(np.clip(th / 180.0, -1 + 1e-12, 1 - 1e-12))
        H = np.array([0.5 * angle_gap(p.spec, st.params) / 180.0 / max(1e-9, 1 - (t / 180.0) ** 2)
                      for p, t in zip(ps, th)])
        W = np.array([[log_window(p.spec)] for p in ps])
        W = W if np.isfinite(W).all() else None
        fm = st.fit_fields(ps, b, H, W, prior_sd=0.3)
        gm = GroupModel("angle", fm)
        window_slot(st, g, gm, ps, th, angle_gap(ps[0].spec, st.params))
        return gm

    def build(self, st, p, gm, s, rng, strict, reveals):
        spec = p.spec
        v: V.Scalar = spec.value
        x = v.value
        h = 0.5 * spec.ulp

        def b(t):
            return float(np.arctanh(np.clip(t / 180.0, -1 + 1e-12, 1 - 1e-12)))

        cell = (b(max(x - h, -180.0)), b(min(x + h, 180.0 - 1e-9)))
        K = 32
        slot = p.evidence.get("window_slot")
        n_model = 3 if slot == "drawn" else 4
        z = st.draw(gm, p.rid, [cell], s, rng, n=n_model, batch=K)[:, :, 0]
        th = 180.0 * np.tanh(z)
        if slot == "drawn":  # one candidate from the window, drawn among the other rows' answers there
            lo, hi = gm.info["window"]
            pool = np.array([v for r, v in gm.info["window_values"].items() if r != p.rid])
            w = pool[rng.integers(len(pool), size=K)] + rng.uniform(-0.5, 0.5, K) * max(hi - lo, spec.ulp)
            th = np.column_stack([th, np.clip(w, lo, hi)])
        pv = np.round(V.wrap_degrees(th), spec.decimals)
        pv = np.where(pv >= 180.0, -180.0, pv)
        allv = np.column_stack([pv, np.full(K, x)])
        g = angle_gap(spec, st.params)
        ok = np.ones(K, bool)
        if "window" in gm.info:  # only the slot candidate (the answer, or the drawn one) in the window
            lo, hi = gm.info["window"]
            cols = pv if slot != "drawn" else pv[:, :n_model]
            ok &= ~((cols >= lo - 1e-9) & (cols <= hi + 1e-9)).any(axis=1)
        for i in first_valid_1d(allv, ok, lambda u: np.full(u.shape, g), circular=True):
            strings = [V.format_angle(float(t), spec.decimals) for t in th[i]] + [spec.detail]
            try:
                check_1d(spec, [float(V.parse(t).value) for t in strings], strings, gap=lambda _: g,
                               circular=True)
            except Reject:
                continue
            if st.last_draw is not None:
                st.last_draw.keep(i)
            return strings
        raise Reject("no drawn set met the separation constraints")

    def near(self, st, a, b) -> bool:
        return abs(float(V.wrap_degrees(a.spec.value.value - b.spec.value.value))) < angle_gap(a.spec, st.params)

    def translate(self, st, base, p, strings):
        d = p.spec.value.value - base.spec.value.value
        vals = [float(V.wrap_degrees(float(V.parse(s).value) + d)) for s in strings if s != base.spec.detail]
        out = [V.format_angle(-180.0 if round(x, p.spec.decimals) >= 180.0 else x, p.spec.decimals) for x in vals]
        out.append(p.spec.detail)
        return out if len(set(out)) == 5 else None


def window_slot(st, g: str, gm: GroupModel, ps: list[RowPlan], values: np.ndarray, gap: float) -> None:
    """A dense window of answers (:func:`dense_window`) is a slot: every row whose answer lies in
    it and ``zero_slot_ratio`` times as many others carry one candidate from it (in the others,
    a value drawn among the window's answers); no other candidate falls in it. Where the window
    holds more than a fifth of the answers, the slot candidate is the answer in more than one
    carrier in five: a leak no option set can remove, named by :mod:`resti_lib.options.structural`."""
    win = dense_window(values, gap)
    if win is None:
        return
    lo, hi, _ = win
    inside = [p.rid for p, x in zip(ps, values) if lo - 1e-9 <= x <= hi + 1e-9]
    others = [p.rid for p in ps if p.rid not in set(inside)]
    carriers = slot_rows(inside, others, st.model["zero_slot_ratio"], seed=st.seed, group=f"{g}|window")
    gm.info["window"] = (lo, hi)
    gm.info["window_values"] = {p.rid: float(x) for p, x in zip(ps, values) if p.rid in set(inside)}
    for p in ps:
        if p.rid in set(inside):
            p.evidence["window_slot"] = "answer"
        elif p.rid in carriers:
            p.evidence["window_slot"] = "drawn"
