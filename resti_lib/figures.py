"""Saving figures: one helper, atomic, with no import-time side effects on matplotlib's settings."""

from __future__ import annotations

import io
from pathlib import Path

from .io.benchmark import atomic_write_bytes


def save_figure(fig, path: str | Path, *, dpi: float | None = None) -> Path:
    """Write ``fig`` as PNG to ``path`` (temporary file, then rename), close it, return the path.

    No software tag is written, so the same figure gives the same bytes.
    """
    import matplotlib.pyplot as plt

    path = Path(path)
    buf = io.BytesIO()
    kw = {"dpi": dpi} if dpi is not None else {}
    fig.savefig(buf, format="png", bbox_inches="tight", metadata={"Software": None}, **kw)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
    return path
