"""The report's figures. Each function takes computed tables and writes one PNG (non-interactive
backend).

Figures are drawn for the report's full width (about 11 inches at 110 dpi, the width of the index
page), with constrained layout so titles, labels and legends never overlap; legends sit outside
the data. Captions and order on the report page: :func:`resti_lib.report.figures.figure_specs`.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd

from ..io.figures import FULL_WIDTH_IN, pyplot, save_figure, styled
from ..options.power import clopper_pearson


def _save(fig, path: Path) -> Path:
    return save_figure(fig, path)


@styled
def attack_accuracy(table: pd.DataFrame, path: Path, *, title: str = "", alpha_label: str = "") -> Path:
    """Accuracy of every option-only attack per task (source ALL) with 95% CIs (over the independent draws:
    coupled rows count once), against chance.

    One panel per task, two panels a row; red points are Holm-significant; the label of an attack
    that picks on part of the rows carries its coverage.
    """
    plt = pyplot()
    t = table[(table["source"] == "ALL") & (table["picked"] > 0)].copy()
    tasks = list(dict.fromkeys(t["task"]))  # the table's own (task registry) order
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
        # coupled rows are one draw (the table's ``draws``): the interval is that of the draws' accuracy
        n = g["draws"].astype(float) if "draws" in g else g["picked"].astype(float)
        lo, hi = clopper_pearson(g["accuracy"] * n, n)
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


