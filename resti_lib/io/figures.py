"""Figures: one atomic writer (no import-time side effects on matplotlib's settings), the drawing
style every figure shares, a figure's registry entry (:class:`FigureSpec`) and the generic panel
scatter the task figures use.

Every PNG under ``<output_dir>/figures`` is named after the notebook that writes it. The report
page shows them in the order of :func:`resti_lib.report.figures.figure_specs`: the report's own
figures, then each registered task's (declared by the task, :attr:`resti_lib.tasks.base.Task.figures`).
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd

from .files import atomic_write_bytes

STYLE = {"figure.dpi": 110, "savefig.dpi": 110, "font.size": 9, "svg.hashsalt": "resti",
         "axes.spines.top": False, "axes.spines.right": False, "axes.titlesize": 9, "legend.fontsize": 8}
FULL_WIDTH_IN = 11.0


def pyplot():
    """``matplotlib.pyplot`` on the non-interactive backend (figures are written, never shown)."""
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def styled(fn):
    """Draw under :data:`STYLE` (a context: importing this module changes no matplotlib setting)."""
    import functools

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with matplotlib.rc_context(STYLE):
            return fn(*args, **kwargs)
    return wrapper


def save_figure(fig, path: str | Path, *, dpi: float | None = None) -> Path:
    """Write ``fig`` as PNG to ``path`` (temporary file, then rename), close it, return the path.

    No software tag is written, so the same figure gives the same bytes. A figure laid out by the
    constrained layout engine already fits its page: it is saved as laid out (a tight bounding box
    would draw it a second time only to find the same box).
    """
    import matplotlib.pyplot as plt
    from matplotlib.layout_engine import ConstrainedLayoutEngine

    path = Path(path)
    buf = io.BytesIO()
    kw = {"dpi": dpi} if dpi is not None else {}
    if not isinstance(fig.get_layout_engine(), ConstrainedLayoutEngine):
        kw["bbox_inches"] = "tight"
    fig.savefig(buf, format="png", metadata={"Software": None}, **kw)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
    return path


@dataclass(frozen=True)
class FigureSpec:
    """``pattern``: file stem, or a glob of stems; ``section``: heading on the report page."""

    pattern: str
    section: str
    caption: str



@styled
def scatter_panels(df: pd.DataFrame, path: str | Path, *, x: str, y: str, xlabel: str, ylabel: str,
                   title: str = "", series: list[tuple[str, str]] | None = None,
                   colors: dict | None = None, group: str = "verdict") -> Path:
    """Legacy against reconstructed values, one panel per source, coloured by ``group`` (y = x
    dashed). ``series``: extra ``(x column, label)`` pairs drawn against ``y`` with other markers.
    One legend for the figure, below the panels."""
    plt = pyplot()
    sources = [s for s in ("ScanNet", "Waymo", "Omni6DPose") if s in set(df["source"])] or ["(none)"]
    fig, axes = plt.subplots(1, len(sources), figsize=(min(FULL_WIDTH_IN, 3.7 * len(sources) + 0.5), 3.9),
                             squeeze=False, layout="constrained")
    colors = colors or {"retained": "tab:green", "corrected": "tab:red", "re-contracted": "tab:orange",
                        "excluded": "grey"}
    markers = ["o", "^", "s", "x"]
    pairs = series or [(x, xlabel)]
    handles: dict[str, object] = {}
    for ax, src in zip(axes[0], sources):
        d = df[df["source"] == src]
        lim = [np.inf, -np.inf]
        for j, (xc, lab) in enumerate(pairs):
            for key, g in d.groupby(group):
                ok = g[[xc, y]].notna().all(axis=1)
                if not ok.any():
                    continue
                gx, gy = g.loc[ok, xc].astype(float), g.loc[ok, y].astype(float)
                label = f"{key}" + (f" · {lab}" if series else "")
                h = ax.scatter(gx, gy, s=16, marker=markers[j % len(markers)], color=colors.get(key, "k"),
                               alpha=0.75, label=label)
                handles.setdefault(label, h)
                lim = [min(lim[0], gx.min(), gy.min()), max(lim[1], gx.max(), gy.max())]
        if np.isfinite(lim).all():
            pad = 0.05 * (lim[1] - lim[0] + 1e-9)
            ax.plot([lim[0] - pad, lim[1] + pad], [lim[0] - pad, lim[1] + pad], "k--", lw=0.7)
        ax.set_title(f"{src} (n={len(d)})")
        ax.set_xlabel(xlabel if not series else "source value (SI)")
        ax.set_ylabel(ylabel)
    if handles:
        fig.legend(list(handles.values()), list(handles), loc="outside lower center",
                   ncol=min(4, len(handles)), frameon=False)
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)
