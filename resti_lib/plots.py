"""Figures. Each function takes computed tables and writes one PNG (non-interactive backend)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from scipy.stats import beta  # noqa: E402

from . import TASKS  # noqa: E402
from .figures import save_figure  # noqa: E402

plt.rcParams.update({"figure.dpi": 110, "savefig.dpi": 110, "font.size": 8, "svg.hashsalt": "resti",
                     "axes.spines.top": False, "axes.spines.right": False})


def clopper_pearson(hits, n, level: float = 0.95):
    """Exact binomial confidence interval for hits/n (arrays allowed)."""
    hits, n = np.asarray(hits, float), np.asarray(n, float)
    a = (1 - level) / 2
    lo = np.where(hits > 0, beta.ppf(a, hits, n - hits + 1), 0.0)
    hi = np.where(hits < n, beta.ppf(1 - a, hits + 1, n - hits), 1.0)
    return lo, hi


def _save(fig, path: Path) -> Path:
    return save_figure(fig, path)


def attack_accuracy(table: pd.DataFrame, path: Path, *, title: str = "", alpha_label: str = "") -> Path:
    """Accuracy of every option-only attack per task (source ALL) with 95% CIs, against chance."""
    t = table[(table["source"] == "ALL") & (table["picked"] > 0)].copy()
    tasks = [x for x in TASKS if x in set(t["task"])]
    fig, axes = plt.subplots(len(tasks), 1, figsize=(7.5, 1.0 + 1.25 * max(1, len(tasks))), squeeze=False,
                             sharex=True)
    for ax, task in zip(axes[:, 0], tasks):
        g = t[t["task"] == task].reset_index(drop=True)
        lo, hi = clopper_pearson(g["hits"], g["picked"])
        y = np.arange(len(g))
        colors = ["#c0392b" if s else "#2c7fb8" for s in g["significant"]]
        ax.errorbar(g["accuracy"], y, xerr=[g["accuracy"] - lo, hi - g["accuracy"]], fmt="none",
                    ecolor="#999999", elinewidth=0.8)
        ax.scatter(g["accuracy"], y, c=colors, s=12, zorder=3)
        ax.axvline(0.2, color="k", lw=0.8, ls="--")
        ax.set_yticks(y, [f"{a} ({c:.0%})" if c < 1 else a for a, c in zip(g["attack"], g["coverage"])],
                      fontsize=6)
        ax.set_title(task, fontsize=8, loc="left")
        ax.set_xlim(0, 1)
    axes[-1, 0].set_xlabel("accuracy of the option-only pick (95% CI); dashed: chance 1/5; "
                           "red: Holm-significant" + (f" ({alpha_label})" if alpha_label else ""))
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return _save(fig, path)


def audit_overview(coverage: pd.DataFrame, categories: pd.DataFrame, path: Path, *, title: str = "") -> Path:
    """(a) accepted and excluded questions per task, with counts; (b) defect reports per category."""
    cov = coverage[coverage["task"] != "Total"]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10.5, 3.6), gridspec_kw={"width_ratios": [1.35, 1]})
    y = np.arange(len(cov))[::-1]
    a.barh(y, cov["accepted"], color="#2c7fb8", label="accepted")
    a.barh(y, cov["excluded"], left=cov["accepted"], color="#d95f0e", label="excluded")
    for yi, acc, exc in zip(y, cov["accepted"], cov["excluded"]):
        a.text(acc + exc + max(cov["total"]) * 0.01, yi, f"{acc} / {exc}", va="center", fontsize=7)
    a.set_yticks(y, cov["task"])
    a.set_xlabel("questions (accepted / excluded)")
    a.set_xlim(0, max(cov["total"]) * 1.25 if len(cov) else 1)
    a.legend(frameon=False, loc="lower right")
    a.set_title("(a) accepted and excluded per task", loc="left", fontsize=8)
    if len(categories):
        yb = np.arange(len(categories))[::-1]
        b.barh(yb, categories["reports"], color="#756bb1")
        for yi, n, s in zip(yb, categories["reports"], categories["share"]):
            b.text(n, yi, f" {n} ({s:.0%})", va="center", fontsize=7)
        b.set_yticks(yb, categories["category"])
        b.set_xlim(0, categories["reports"].max() * 1.3)
    b.set_xlabel("defect reports (one row can report several)")
    b.set_title(f"(b) {int(categories['reports'].sum()) if len(categories) else 0} defect reports by category",
                loc="left", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return _save(fig, path)
