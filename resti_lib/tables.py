"""Write a table in the three forms the report uses: markdown, CSV and LaTeX (one stem, one writer)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from .io.benchmark import atomic_write_bytes


def _fmt(df: pd.DataFrame, floatfmt: str) -> pd.DataFrame:
    out = df.copy()
    for c in out.columns:
        if pd.api.types.is_float_dtype(out[c]):
            out[c] = out[c].map(lambda x: "" if pd.isna(x) else format(x, floatfmt))
    return out


def write_table(df: pd.DataFrame, stem: str | Path, *, floatfmt: str = ".4g", caption: str | None = None
                ) -> list[Path]:
    """Write ``<stem>.md``, ``<stem>.csv`` and ``<stem>.tex``; returns the three paths."""
    stem = Path(stem)
    shown = _fmt(df, floatfmt)
    md = shown.to_markdown(index=False)
    if caption:
        md = f"{caption}\n\n{md}"
    csv = df.to_csv(index=False, lineterminator="\n")
    tex = shown.to_latex(index=False, escape=True, caption=caption)
    paths = []
    for ext, text in (("md", md + "\n"), ("csv", csv), ("tex", tex)):
        p = stem.with_suffix(f".{ext}")
        atomic_write_bytes(p, text.encode("utf-8"))
        paths.append(p)
    return paths
