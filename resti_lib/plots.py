"""Figures. Each function takes computed tables and writes one PNG (non-interactive backend).

Figures are drawn for the report's full width (about 11 inches at 110 dpi, the width of the index
page), with constrained layout so titles, labels and legends never overlap; legends sit outside
the data. Captions and order on the report page: :data:`resti_lib.figures.FIGURES`.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd

from . import TASKS
from .figures import save_figure

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


def clopper_pearson(hits, n, level: float = 0.95):
    """Exact binomial confidence interval for hits/n (arrays allowed)."""
    from scipy.stats import beta  # imported here: most figures do not need scipy

    hits, n = np.asarray(hits, float), np.asarray(n, float)
    a = (1 - level) / 2
    lo = np.where(hits > 0, beta.ppf(a, np.maximum(hits, 1e-12), n - hits + 1), 0.0)
    hi = np.where(hits < n, beta.ppf(1 - a, hits + 1, np.maximum(n - hits, 1e-12)), 1.0)
    return lo, hi


def _save(fig, path: Path) -> Path:
    return save_figure(fig, path)


@styled
def attack_accuracy(table: pd.DataFrame, path: Path, *, title: str = "", alpha_label: str = "") -> Path:
    """Accuracy of every option-only attack per task (source ALL) with 95% CIs, against chance.

    One panel per task, two panels a row; red points are Holm-significant; the label of an attack
    that picks on part of the rows carries its coverage.
    """
    plt = pyplot()
    t = table[(table["source"] == "ALL") & (table["picked"] > 0)].copy()
    tasks = [x for x in TASKS if x in set(t["task"])] + sorted(set(t["task"]) - set(TASKS))
    ncol = 2 if len(tasks) > 1 else 1
    nrow = max(1, -(-len(tasks) // ncol))
    per_row = [max((t["task"] == x).sum() for x in tasks[r * ncol:(r + 1) * ncol]) for r in range(nrow)] \
        if tasks else [1]
    heights = [0.6 + 0.19 * max(1, n) for n in per_row]
    fig, axes = plt.subplots(nrow, ncol, figsize=(FULL_WIDTH_IN, 0.9 + sum(heights)), squeeze=False,
                             sharex=True, layout="constrained", gridspec_kw={"height_ratios": heights})
    for ax in axes.flat[len(tasks):]:
        ax.set_visible(False)
    for ax, task in zip(axes.flat, tasks):
        g = t[t["task"] == task].reset_index(drop=True)
        lo, hi = clopper_pearson(g["hits"], g["picked"])
        y = np.arange(len(g))[::-1]
        colors = ["#c0392b" if s else "#2c7fb8" for s in g["significant"]]
        ax.errorbar(g["accuracy"], y, xerr=[g["accuracy"] - lo, hi - g["accuracy"]], fmt="none",
                    ecolor="#999999", elinewidth=0.8)
        ax.scatter(g["accuracy"], y, c=colors, s=16, zorder=3)
        ax.axvline(0.2, color="k", lw=0.8, ls="--")
        ax.set_yticks(y, [f"{a} ({c:.0%} of rows)" if c < 0.999 else a for a, c in zip(g["attack"], g["coverage"])],
                      fontsize=8)
        ax.set_ylim(-0.7, len(g) - 0.3)
        n = int(g["n_rows"].max()) if "n_rows" in g and len(g) else 0
        ax.set_title(f"{task} ({n} rows)", loc="left")
        ax.set_xlim(0, 1)
        ax.xaxis.set_major_formatter(matplotlib.ticker.PercentFormatter(1.0))
    for ax in axes[-1]:
        if ax.get_visible():
            ax.set_xlabel("accuracy of the blind pick (95% CI)")
    note = "dashed: chance 1/5; red: Holm-significant" + (f" ({alpha_label})" if alpha_label else "")
    fig.suptitle((title + "\n" if title else "") + note, fontsize=9)
    return _save(fig, path)


@styled
def audit_overview(coverage: pd.DataFrame, categories: pd.DataFrame, path: Path, *, title: str = "") -> Path:
    """(a) accepted and excluded questions per task, with counts; (b) defect reports per category."""
    plt = pyplot()
    cov = coverage[coverage["task"] != "Total"]
    fig, (a, b) = plt.subplots(1, 2, figsize=(FULL_WIDTH_IN, 4.0), layout="constrained",
                               gridspec_kw={"width_ratios": [1.35, 1]})
    y = np.arange(len(cov))[::-1]
    a.barh(y, cov["accepted"], color="#2c7fb8", label="accepted")
    a.barh(y, cov["excluded"], left=cov["accepted"], color="#d95f0e", label="excluded")
    top = max(cov["total"]) if len(cov) else 1
    for yi, acc, exc in zip(y, cov["accepted"], cov["excluded"]):
        a.text(acc + exc + top * 0.01, yi, f"{acc} / {exc}", va="center", fontsize=8)
    a.set_yticks(y, cov["task"])
    a.set_xlabel("questions (accepted / excluded)")
    a.set_xlim(0, top * 1.22)
    # the legend sits above the bars, never on a count
    a.legend(frameon=False, loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2, borderaxespad=0.2)
    a.set_title("(a) accepted and excluded per task", loc="left", pad=18)
    if len(categories):
        yb = np.arange(len(categories))[::-1]
        b.barh(yb, categories["reports"], color="#756bb1")
        for yi, n, s in zip(yb, categories["reports"], categories["share"]):
            b.text(n, yi, f" {n} ({s:.0%})", va="center", fontsize=8)
        b.set_yticks(yb, categories["category"])
        b.set_xlim(0, max(1, categories["reports"].max()) * 1.3)
    b.set_xlabel("defect reports (one row can report several)")
    b.set_title(f"(b) {int(categories['reports'].sum()) if len(categories) else 0} defect reports by category",
                loc="left", pad=18)
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path)


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
    return _save(fig, path)
