"""The HTML audit report index: links every rendered notebook, table and figure under ``outputs/``.

The index uses relative links only, so it opens from disk in a browser.
"""

from __future__ import annotations

import html
import os
from pathlib import Path

from . import paths
from .io.benchmark import atomic_write_bytes

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1100px;margin:2em auto;
padding:0 1em;color:#222}
h1{font-size:1.6em}h2{font-size:1.2em;margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:.85em}td,th{border:1px solid #ccc;padding:.2em .5em}
.figs{display:flex;flex-wrap:wrap;gap:1em}.figs figure{margin:0;max-width:520px}
.figs img{max-width:100%;border:1px solid #eee}figcaption{font-size:.8em;color:#555}
"""


def _rel(target: Path, base: Path) -> str:
    return Path(os.path.relpath(target, base)).as_posix()


def _section(title: str, items: list[str]) -> str:
    if not items:
        return ""
    return f"<h2>{html.escape(title)}</h2>\n" + "\n".join(items)


def summary_section(out_root: Path) -> str:
    """Headline numbers and the key tables of the release, when the run produced them."""
    import json

    import pandas as pd

    parts = []
    meta_p = out_root / "release" / "release.json"
    if meta_p.exists():
        meta = json.loads(meta_p.read_text(encoding="utf-8"))
        c = meta.get("counts", {})
        letters = " ".join(f"{k} {v}" for k, v in meta.get("answer_letters", {}).items())
        parts.append(f"<p><b>{c.get('original', 0):,}</b> legacy questions &rarr; <b>{c.get('accepted', 0):,}</b> "
                     f"accepted and <b>{c.get('excluded', 0):,}</b> excluded with reasons. "
                     f"Answer letters: {html.escape(letters)}.</p>")
    for stem, caption in (("coverage_by_task", "Accepted and excluded by task"),
                          ("verdicts", "Verdicts"), ("attacks_before_after", "Option-only attacks, before and after"),
                          ("selftest_defect_recall", "Self-test: defects found against defects injected")):
        csv = out_root / "tables" / f"{stem}.csv"
        if csv.exists():
            df = pd.read_csv(csv)
            parts.append(f"<h3>{html.escape(caption)}</h3>" + df.to_html(index=False, border=0, na_rep="",
                                                                           float_format=lambda x: f"{x:.3g}"))
    return _section("Summary", parts) if parts else ""


def write_index(out_root: Path | None = None, *, title: str = "resti audit report",
                summary_html: str | None = None) -> Path:
    """Write ``outputs/report/index.html`` for whatever the run produced."""
    out_root = Path(out_root or paths.OUTPUTS)
    if summary_html is None:
        summary_html = summary_section(out_root)
    report_dir = out_root / "report"
    index = report_dir / "index.html"
    nb_items = []
    for p in sorted((report_dir / "notebooks").glob("*.html")):
        nb_items.append(f'<li><a href="{_rel(p, report_dir)}">{html.escape(p.stem)}</a></li>')
    table_items = []
    for p in sorted(out_root.glob("**/*.md")):
        if "report" in p.relative_to(out_root).parts[:1] or "miniworld" in p.parts:
            continue
        csv, tex = p.with_suffix(".csv"), p.with_suffix(".tex")
        extra = "".join(f' · <a href="{_rel(q, report_dir)}">{q.suffix[1:]}</a>' for q in (csv, tex)
                        if q.exists())
        table_items.append(f'<li><a href="{_rel(p, report_dir)}">{html.escape(str(p.relative_to(out_root)))}'
                           f"</a>{extra}</li>")
    fig_items = []
    for p in sorted((out_root / "figures").glob("*.png")):
        src = _rel(p, report_dir)
        fig_items.append(f'<figure><a href="{src}"><img src="{src}" alt="{html.escape(p.stem)}"></a>'
                         f"<figcaption>{html.escape(p.name)}</figcaption></figure>")
    release_items = []
    rel_dir = out_root / "release"
    if rel_dir.exists():
        for p in sorted(rel_dir.iterdir()):
            if p.is_file():
                release_items.append(f'<li><a href="{_rel(p, report_dir)}">{html.escape(p.name)}</a> '
                                     f"({p.stat().st_size:,} bytes)</li>")
    body = [f"<h1>{html.escape(title)}</h1>", summary_html,
            _section("Rendered notebooks", ["<ul>", *nb_items, "</ul>"] if nb_items else []),
            _section("Release files", ["<ul>", *release_items, "</ul>"] if release_items else []),
            _section("Tables (markdown · csv · tex)", ["<ul>", *table_items, "</ul>"] if table_items else []),
            _section("Figures", ['<div class="figs">', *fig_items, "</div>"] if fig_items else [])]
    doc = (f"<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
           f"<style>{CSS}</style></head><body>\n" + "\n".join(b for b in body if b) + "\n</body></html>\n")
    atomic_write_bytes(index, doc.encode("utf-8"))
    return index
