"""Figures: no two texts of a figure overlap (labels, values, titles), checked on the drawn artists."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest


def text_overlaps(fig) -> list[tuple[str, str]]:
    """Pairs of visible, non-empty texts of ``fig`` whose drawn boxes intersect."""
    from matplotlib.text import Text

    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    ticks, drawn = set(), []
    for ax in fig.axes:  # tick labels are drawn only for ticks inside the view
        for labs, i in ((ax.get_xticklabels(), 0), (ax.get_yticklabels(), 1)):
            for t in labs:
                ticks.add(id(t))
                bb = t.get_window_extent(r)
                c = (bb.x0 + bb.x1) / 2 if i == 0 else (bb.y0 + bb.y1) / 2
                lo, hi = (ax.bbox.x0, ax.bbox.x1) if i == 0 else (ax.bbox.y0, ax.bbox.y1)
                if lo - 1 <= c <= hi + 1:
                    drawn.append(t)
    boxes = []
    for t in [t for t in fig.findobj(Text) if id(t) not in ticks] + drawn:
        if t.get_visible() and t.get_text().strip():
            bb = t.get_window_extent(r)
            if bb.width > 0 and bb.height > 0:
                boxes.append((t.get_text(), bb))
    out = []
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            a, b = boxes[i][1], boxes[j][1]
            if a.x0 < b.x1 - 0.5 and b.x0 < a.x1 - 0.5 and a.y0 < b.y1 - 0.5 and b.y0 < a.y1 - 0.5:
                out.append((boxes[i][0], boxes[j][0]))
    return out


@pytest.fixture
def captured(monkeypatch):
    """Figures handed to the savers, checked for overlapping texts instead of written."""
    import matplotlib

    matplotlib.use("Agg")
    figs = []

    def keep(fig, path, **_):
        figs.append(fig)
        return path

    import resti_lib.report.plots as plots
    import resti_lib.tasks.orientation as ori

    monkeypatch.setattr(ori, "save_figure", keep)
    monkeypatch.setattr(plots, "_save", lambda fig, path: keep(fig, path))
    return figs


def _unit(deg: float) -> list[float]:
    return [math.cos(math.radians(deg)), math.sin(math.radians(deg)), 0.0]


@pytest.mark.parametrize("start, change", [(160.0, 5.07), (160.0, -3.0), (-100.0, 40.7), (10.0, 175.0)])
def test_orientation_endpoint_labels_do_not_overlap(captured, start, change):
    from resti_lib.tasks.orientation import figure_endpoints

    # the start and end directions `change` degrees apart on both planes (the case of the default run:
    # +5.07 degrees, where the labels and the angle used to overlap)
    col0, col1 = _unit(start), _unit(start + change)
    ev = {"diagnosis": {"legacy_deg": 40.7, "conventions_deg": {"xz_plane_column2": -change, "gravity_heading": change}},
          "legacy_operator_axes": {"column2_t0": [col0[0], 0.0, col0[1]], "column2_t1": [col1[0], 0.0, col1[1]]},
          "heading": {"up": [0.0, 0.0, 1.0], "forward_t0": _unit(start), "forward_t1": _unit(start + change)}}
    o = SimpleNamespace(verdict="re-contracted", row=0, source="ScanNet", video="scene0900_00.mp4", time_start=0.0,
                        time_end=48.633, evidence=ev)
    figure_endpoints(SimpleNamespace(outcomes=[o]), "unused.png")
    assert len(captured) == 1
    assert text_overlaps(captured[0]) == []
    texts = [t.get_text() for t in captured[0].findobj(lambda a: hasattr(a, "get_text"))]
    assert f"heading change {change:+.2f}°" in texts


def test_report_figures_have_no_overlapping_texts(captured):
    from resti_lib.report.plots import attack_accuracy, audit_overview

    cov = pd.DataFrame({"task": ["3D Video Grounding", "Dimensional Measurement", "Total"], "accepted": [45, 29, 74],
                        "excluded": [1, 12, 13], "total": [46, 41, 87]})
    cats = pd.DataFrame({"category": ["unit tag", "key-detail mismatch", "unnamed frame"], "reports": [141, 140, 28],
                         "share": [0.46, 0.45, 0.09]})
    audit_overview(cov, cats, "unused.png", title="Audit overview")
    rng = np.random.default_rng(0)
    rows = [{"attack": a, "family": "option", "task": t, "source": "ALL", "n_rows": 40, "coverage": c,
             "picked": int(40 * c), "hits": float(rng.integers(5, 20)), "significant": a == "median"}
            for t in ("3D Video Grounding", "Dimensional Measurement", "Speed & Acceleration")
            for a, c in (("median", 1.0), ("min", 1.0), ("nearest_mean", 0.5))]
    t = pd.DataFrame(rows)
    t["accuracy"] = t["hits"] / t["picked"]
    attack_accuracy(t, "unused.png", title="Blind attacks", alpha_label="alpha=0.05")
    assert len(captured) == 2
    for fig in captured:
        assert text_overlaps(fig) == []
