"""Tables as the report shows them: one writer for markdown, CSV and LaTeX (one stem, three files),
and one display form for notebooks and the HTML index.

Shown forms (markdown, LaTeX, HTML) print shares as percentages (``41.5%``), p-values with three
significant digits and no index column; the CSV keeps the raw numbers for reuse.
"""

from __future__ import annotations

import html
import math
from pathlib import Path

import pandas as pd

from .files import atomic_write_bytes

# Columns holding a fraction of 1, printed as percentages (when every value lies in [0, 1]).
PERCENT_COLUMNS = frozenset({"share", "recall", "precision", "accuracy", "coverage", "chance", "fraction"})
PERCENT_SUFFIXES = (" share", "_share", " accuracy", "_accuracy", " fraction", "_fraction", " recall",
                    " precision")
P_VALUE_COLUMNS = frozenset({"p_value", "p value", "p"})


def is_percent_column(name: object, values: pd.Series) -> bool:
    name = str(name)
    if name not in PERCENT_COLUMNS and not name.endswith(PERCENT_SUFFIXES):
        return False
    if not (pd.api.types.is_float_dtype(values) or pd.api.types.is_integer_dtype(values)):
        return False
    v = values.dropna()
    return bool(((v >= 0) & (v <= 1)).all())


def percent(x: float, digits: int = 1) -> str:
    """``0.415 -> '41.5%'``; NaN -> ''."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return ""
    return f"{100.0 * float(x):.{digits}f}%"


def _float_text(x, floatfmt: str) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return ""
    return format(x, floatfmt)


def with_index_as_column(df: pd.DataFrame) -> pd.DataFrame:
    """A meaningful index (named, or of labels) becomes a column; an unnamed integer index (row
    positions, e.g. after filtering or sorting) is dropped."""
    unnamed = all(n is None for n in df.index.names)
    if unnamed and df.index.nlevels == 1 and pd.api.types.is_integer_dtype(df.index.dtype):
        return df.reset_index(drop=True) if not isinstance(df.index, pd.RangeIndex) else df
    names = [n if n is not None else ("" if df.index.nlevels == 1 else f"level {i}")
             for i, n in enumerate(df.index.names)]
    out = df.copy()
    out.index = out.index.set_names(names)
    return out.reset_index()


def formatted(df: pd.DataFrame, *, floatfmt: str = ".4g") -> pd.DataFrame:
    """The shown form of a table: every cell a string, percentages and p-values formatted."""
    out = with_index_as_column(df).copy()
    out.columns = [str(c) for c in out.columns]
    for c in out.columns:
        col = out[c]
        if is_percent_column(c, col):
            out[c] = col.map(percent)
        elif c in P_VALUE_COLUMNS and pd.api.types.is_float_dtype(col):
            out[c] = col.map(lambda x: _float_text(x, ".3g"))
        elif pd.api.types.is_float_dtype(col):
            out[c] = col.map(lambda x: _float_text(x, floatfmt))
        else:
            out[c] = col.map(lambda x: "" if x is None or (isinstance(x, float) and math.isnan(x)) else str(x))
    return out


def to_html(df: pd.DataFrame, *, floatfmt: str = ".4g", caption: str | None = None, max_rows: int | None = None
            ) -> str:
    """A table as HTML without index column (``<table class="resti-table">``)."""
    shown = formatted(df, floatfmt=floatfmt)
    more = ""
    if max_rows is not None and len(shown) > max_rows:
        more = f"<p class=\"more\">first {max_rows} of {len(shown):,} rows</p>"
        shown = shown.head(max_rows)
    # long column names may wrap after an underscore (zero-width space), so tables fit the page
    shown.columns = [c.replace("_", "_\u200b") for c in shown.columns]
    body = shown.to_html(index=False, border=0, escape=True, classes="resti-table")
    cap = f"<p class=\"caption\">{html.escape(caption)}</p>" if caption else ""
    return f"{cap}<div class=\"table-wrap\">{body}</div>{more}"


def _display_html(obj) -> str:
    if isinstance(obj, pd.Series):
        obj = obj.to_frame(name=obj.name if obj.name is not None else "value")
    return to_html(obj)


def install_display() -> None:
    """In an IPython kernel: show DataFrames and Series as :func:`to_html` does (no index column,
    percentages). The main job starts its notebook kernels with this (runner.KERNEL_ARGUMENTS)."""
    try:
        from IPython import get_ipython
    except ImportError:
        return
    ip = get_ipython()
    if ip is None:
        return
    fmt = ip.display_formatter.formatters["text/html"]
    fmt.for_type(pd.DataFrame, _display_html)
    fmt.for_type(pd.Series, _display_html)


def write_table(df: pd.DataFrame, stem: str | Path, *, floatfmt: str = ".4g", caption: str | None = None
                ) -> list[Path]:
    """Write ``<stem>.md``, ``<stem>.csv`` and ``<stem>.tex``; returns the three paths."""
    stem = Path(stem)
    shown = formatted(df, floatfmt=floatfmt)
    md = shown.to_markdown(index=False)
    if caption:
        md = f"{caption}\n\n{md}"
    csv = with_index_as_column(df).to_csv(index=False, lineterminator="\n")
    tex = shown.to_latex(index=False, escape=True, caption=caption)
    paths = []
    for ext, text in (("md", md + "\n"), ("csv", csv), ("tex", tex)):
        p = stem.with_suffix(f".{ext}")
        atomic_write_bytes(p, text.encode("utf-8"))
        paths.append(p)
    return paths
