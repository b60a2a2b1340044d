"""The HTML audit report: ``<output_dir>/report/index.html``.

The page opens with what the run was made from (input, params digest, code and package versions:
:mod:`resti_lib.run.runinfo`), then the headline (our release's counts, verdict shares and defect
categories; the answer-interface audit of the reference release, its significant leaks first; the
self-test, labelled synthetic), the figures in registry order (:func:`resti_lib.report.figures.figure_specs`)
at full width, the tables of the report's text on the page and every other table linked by
section, the rendered notebooks and the release files. Links are relative: it opens from disk,
offline (no script, no remote resource).
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path

import pandas as pd

from .. import paths
from ..io.files import atomic_write_bytes
from ..io.tables import percent, to_html
from .changes import changes_html
from .examples import CSS as EX_CSS
from .examples import card_html, cards_html, one_per_verdict
from .figures import ordered_figures

CSS = """
*{box-sizing:border-box}
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1180px;margin:0 auto;
padding:1em 1.2em 3em;color:#222;line-height:1.45;overflow-wrap:break-word}
h1{font-size:1.7em;margin:.3em 0}h2{font-size:1.3em;margin-top:2em;border-bottom:1px solid #ddd}
h3{font-size:1.05em;margin:1.4em 0 .4em}
a{color:#1a5e9a}code{font-size:.9em}
dl.context{display:grid;grid-template-columns:max-content 1fr;gap:.15em 1em;margin:.6em 0;font-size:.9em}
dl.context dt{font-weight:600;color:#444}dl.context dd{margin:0}
.banner{padding:.6em .9em;border-radius:4px;margin:.8em 0;font-size:.95em}
.banner.synthetic{background:#fff4e0;border:1px solid #f0b45a}
.banner.real{background:#e8f3ea;border:1px solid #7fbf8e}
.selftest{background:#fafafa;border:1px dashed #bbb;padding:.2em 1em 1em;margin-top:1.5em}
.label{display:inline-block;font-size:.75em;font-weight:600;padding:.05em .5em;border-radius:3px;
vertical-align:middle;margin-left:.4em}
.label.synthetic{background:#f0b45a;color:#3a2500}.label.real{background:#7fbf8e;color:#0e2e16}
nav.toc{font-size:.9em;margin:.8em 0}nav.toc a{margin-right:1em}
.table-wrap{max-width:100%;overflow-x:auto}
table.resti-table{border-collapse:collapse;font-size:.82em;margin:.3em 0 .2em;max-width:100%}
table.resti-table td,table.resti-table th{border:1px solid #d0d0d0;padding:.2em .45em;vertical-align:top;
text-align:left}
table.resti-table th{background:#f3f3f3}
p.caption{font-size:.88em;color:#444;margin:.8em 0 .2em}p.more{font-size:.8em;color:#666;margin:0}
figure{margin:1.2em 0 2em;max-width:100%}figure img{display:block;max-width:100%;height:auto;border:1px solid #eee}
figcaption{font-size:.88em;color:#444;margin-top:.3em}figcaption .file{color:#888;font-size:.9em}
ul.files{columns:2;font-size:.88em}ul.files li{break-inside:avoid}
.status{display:inline-block;font-size:.85em;font-weight:600;padding:0 .4em;border-radius:3px;white-space:nowrap}
.status.ok{background:#d8eedd;color:#14532d}.status.bad{background:#f8d7d3;color:#7a1a10}
.status.na{background:#eee;color:#444}.status.leak{background:#fde7c4;color:#6b3e00}
table.claims td.how{font-size:.92em;color:#444}table.claims .where{font-size:.85em;color:#777}
p.verify-fail{background:#fdf0ee;border-left:3px solid #c0392b;padding:.3em .6em}
#changes{background:#f6f9fd;border:1px solid #b9cde6;padding:.2em 1em 1em;margin-top:1.5em}
ul.warnings li{background:#fff4e0;border-left:3px solid #e67e22;padding:.2em .5em;margin:.3em 0;list-style:none}
"""

# Tables shown on the page, by section: (file stem under tables/, caption). Every other table is
# linked under the section of its notebook.
SHOWN_TABLES: tuple[tuple[str, tuple[tuple[str, str], ...]], ...] = (
    ("Coverage and verdicts", (
        ("coverage_by_task", "Accepted and excluded questions by task and source."),
        ("verdicts", "Verdicts by task: retained, corrected, re-contracted, excluded."),
    )),
    ("Legacy diagnosis", (
        ("key_detail_breakdown", ("Keyed candidate against Answer Detail: why they differ (structured records, "
                                  "scalars beyond rounding, incompatible formats, coarser rounding).")),
        ("question_layer_defects", "Question-layer defects by task (rows)."),
        ("source_layer_defects", "Source-layer defects by task (rows)."),
        ("answer_layer_defects", "Answer-layer defects by task (rows)."),
    )),
    ("Exclusions", (
        ("exclusion_reasons", "Exclusion reasons by task (a row can carry several)."),
    )),
    ("Answer interface", (
        ("scalar_attacks_before_after", ("Option-only attacks pooled over every row with five scalar candidates "
                                         "(all tasks together; e.g. the median pick, 46.9% on STI-Bench in the ReSTI "
                                         "report): the legacy options (before) and the release's (after).")),
        ("attacks_before_after", ("Strongest blind attack per task, legacy options (before) and our release "
                                  "(after).")),
    )),
    ("Reference release (ReSTI v5, real data)", (
        ("reference_comparison", "Accepted and excluded per task: our release beside the reference."),
        ("reference_by_source", "Reference release: accepted and excluded per task and source."),
        ("reference_exclusion_reasons", "Reference release: exclusion reasons by task."),
    )),
    ("Self-test on the mini-world (synthetic)", (
        ("selftest_verdicts", "Expected verdict (generator manifest) against the audit's verdict."),
        ("selftest_values", "Accepted rows whose answer equals the generator's true value."),
    )),
)
HEADLINE_TABLES = ("defect_categories", "selftest_defect_recall", "exclusion_classes", "paper_claims_legacy")


def _rel(target: Path, base: Path) -> str:
    return Path(os.path.relpath(target, base)).as_posix()


def _e(x) -> str:
    return html.escape(str(x))


def _read_csv(p: Path) -> pd.DataFrame | None:
    if not p.exists():
        return None
    try:
        return pd.read_csv(p)
    except (OSError, ValueError, pd.errors.EmptyDataError):
        return None


def _read_json(p: Path):
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


# ------------------------------------------------------------------------------------ header

def header_html(context: dict | None) -> str:
    """What the run was made from, and a banner that says whether the numbers are on real data."""
    if not context:
        return ("<div class=\"banner\">No run context recorded (release.json has no <code>run</code> block): "
                "rerun <code>resti run</code>.</div>")
    inp = context.get("input") or {}
    rows = []
    if inp.get("synthetic"):
        banner = ("<div class=\"banner synthetic\"><b>Input: the synthetic mini-world</b> (seed "
                  f"{_e(inp.get('seed'))}), generated by resti with known injected defects. The counts, verdicts "
                  "and self-test below describe this generated data, not STI-Bench. The answer-interface audit "
                  "of the reference release is the one result on real data.</div>")
        where = f"{_e(inp.get('seed'))}, <code>{_e(inp.get('world_dir'))}</code>"
        rows.append(("Input", f"mini-world <span class=\"label synthetic\">synthetic</span> seed {where}"))
    else:
        banner = "<div class=\"banner real\"><b>Input: real data</b> (paths below).</div>"
        listed = "<br>".join(f"{_e(k)}: <code>{_e(v)}</code>" for k, v in inp.items()
                             if k not in ("kind", "synthetic"))
        rows.append(("Input", "real data <span class=\"label real\">real</span><br>" + listed))
    if context.get("reference_release"):
        rows.append(("Reference release", f"<code>{_e(context['reference_release'])}</code>"))
    rows.append(("Params digest", f"<code>sha256:{_e(context.get('params_digest', ''))}</code>"))
    code = context.get("code") or {}
    code_txt = " · ".join(x for x in (
        f"git <code>{_e(code['git'])}</code>" if code.get("git") else "",
        f"commit <code>{_e(code['commit'][:12])}</code>" if code.get("commit") else "",
        _e(code.get("package", ""))) if x)
    rows.append(("Code version", code_txt))
    pk = context.get("packages") or {}
    rows.append(("Packages", " · ".join(f"{_e(k)} {_e(v)}" for k, v in pk.items())))
    if context.get("date"):
        rows.append(("Date", f"{_e(context['date'])} (SOURCE_DATE_EPOCH)"))
    dl = "".join(f"<dt>{k}</dt><dd>{v}</dd>" for k, v in rows)
    return banner + f"<dl class=\"context\">{dl}</dl>"


# ---------------------------------------------------------------------------------- headline

def _verdict_shares(tables: Path) -> str:
    v = _read_csv(tables / "verdicts.csv")
    if v is None or "task" not in v:
        return ""
    total = v[v["task"] == "Total"]
    if total.empty:
        return ""
    t = total.iloc[0]
    cols = [c for c in ("retained", "corrected", "re-contracted", "excluded") if c in v.columns]
    n = sum(int(t[c]) for c in cols)
    df = pd.DataFrame([{"verdict": c, "rows": int(t[c]), "share": int(t[c]) / n if n else 0.0} for c in cols])
    return to_html(df, caption="Verdict shares (every legacy row ends in exactly one verdict).")


def release_attack_counts(out_root: Path):
    """The attack counts of our release (:func:`resti_lib.release.audit.attack_counts` of
    ``tables/attacks_release.csv``), or None before notebook 99 wrote it."""
    from ..release.audit import attack_counts

    table = _read_csv(Path(out_root) / "tables" / "attacks_release.csv")
    return None if table is None or "significant" not in table else attack_counts(table)


def reference_audit(out_root: Path) -> dict | None:
    """The audit summary notebook 00 wrote for the reference release (``answer_interface/audit_<label>.json``,
    :func:`resti_lib.release.audit.audit_summary`), or None (no reference audited: notebook 00 audits our
    own release, label ``release``, when the reference is absent)."""
    for p in sorted((Path(out_root) / "answer_interface").glob("audit_*.json")):
        s = _read_json(p)
        if isinstance(s, dict) and s.get("label") not in (None, "release") and "attacks" in s:
            return s
    return None


def _leaks(table: pd.DataFrame | None, what: str, counts=None) -> str:
    """The attack counts (the sentence ``resti attack`` prints) and the significant rows, strongest first."""
    from ..release.audit import attack_counts

    if table is None or "significant" not in table:
        return f"<p>No attack table for {what}.</p>"
    counts = counts or attack_counts(table)
    sig = table[table["significant"].astype(str) == "True"].copy()
    head = f"<p class=\"counts\">{_e(counts.sentence())}.</p>"
    if sig.empty:
        return head
    sig = sig.sort_values(["accuracy", "hits"], ascending=False, kind="stable")
    shown = pd.DataFrame({"task": sig["task"], "source": sig["source"], "attack": sig["attack"],
                          "family": sig["family"],
                          "hits / picked": [f"{h:g}/{int(p)}" for h, p in zip(sig["hits"], sig["picked"])],
                          "accuracy": sig["accuracy"].astype(float), "p_value": sig["p_value"].astype(float)})
    return head + to_html(shown, caption=f"Significant leaks of {what}, strongest first (chance 20%; the whole "
                          "table is linked under Tables).", max_rows=10)


def _verify_line(verify: dict, failures: Path | None, report_dir: Path) -> str:
    """``resti verify``: PASSED, or FAILED with the failing checks and their rows one click away."""
    if verify.get("passed"):
        return f"<p><code>{_e(verify.get('command', 'resti verify'))}</code>: <b>PASSED</b>.</p>"
    checks = ", ".join(f"<code>{_e(k)}</code> {n} rows" for k, n in (verify.get("failing") or {}).items())
    link = ""
    if failures is not None and failures.with_suffix(".csv").exists():
        link = (f" The failing rows, with their question, candidates and the check's message: "
                f"{_table_links(failures.with_suffix('.md'), report_dir)}.")
    return (f"<p class=\"verify-fail\"><code>{_e(verify.get('command', 'resti verify'))}</code>: <b>FAILED</b> "
            f"({checks}).{link}</p>")


def headline_html(out_root: Path) -> str:
    tables = out_root / "tables"
    rel = out_root / "release"
    report_dir = out_root / "report"
    parts = ["<h3>Our release</h3>"]
    meta = _read_json(rel / "release.json")
    val = _read_json(rel / "validation.json")
    synthetic = bool(((meta or {}).get("run") or {}).get("input", {}).get("synthetic"))
    tag = "<span class=\"label synthetic\">synthetic input</span>" if synthetic else ""
    if meta:
        c = meta.get("counts", {})
        verify = "PASSED" if val and val.get("passed") else "FAILED" if val else "not run"
        acc, tot = c.get("accepted", 0), c.get("original", 0)
        parts[0] = f"<h3>Our release {tag}</h3>"
        parts.append(f"<p><b>{tot:,}</b> legacy questions &rarr; <b>{acc:,}</b> accepted ({percent(acc / tot if tot else 0)}) "
                     f"and <b>{c.get('excluded', 0):,}</b> excluded with reasons; <code>resti verify</code>: "
                     f"<b>{verify}</b>.</p>")
    else:
        parts.append("<p>No release in this output folder yet.</p>")
    parts.append(_verdict_shares(tables))
    cats = _read_csv(tables / "defect_categories.csv")
    if cats is not None:
        total = int(cats["reports"].sum()) if "reports" in cats else 0
        parts.append(to_html(cats, caption=f"Defect categories: {total} defect reports (one row can report several;"
                                           " shares of the reports)."))
    ours = _read_csv(tables / "attacks_release.csv")
    if ours is not None:
        summary = _read_json(tables / "audit_release.json") or {}
        cmd = (summary.get("attacks") or {}).get("command")
        where = " (OUTPUT_DIR: this report's output folder)" if cmd and "OUTPUT_DIR" in cmd else ""
        parts.append(f"<h3>Blind attacks on our release {tag}</h3>" + _leaks(ours, "our release")
                     + (f"<p class=\"more\">The same counts: <code>{_e(cmd)}</code>{where}.</p>" if cmd else ""))
    if meta and meta.get("adversarial_filter"):
        from ..release.reoption import filter_table

        parts.append(to_html(filter_table(meta["adversarial_filter"]), caption=(
            "Adversarial filter of the option stage, per task (release.json adversarial_filter): the strongest "
            "blind discriminators checked the drawn options on the rows no structural leak touches and redrew "
            "the rows a significant one identified; 'draw leaks' names the cells where the redrawn rows, on "
            "their own, were still significant.")))
    parts.append("<h3>Answer-interface audit of the reference release <span class=\"label real\">real data</span></h3>")
    ref = reference_audit(out_root)
    if ref is None:
        parts.append("<p>No reference release was audited (<code>release_path</code> in "
                     "params/answer_interface.yaml).</p>")
    else:
        ai = out_root / "answer_interface"
        label = ref["label"]
        parts.append(f"<p>Release <code>{_e(ref['release'])}</code>.</p>")
        parts.append(_verify_line(ref["verify"], ai / f"verify_failures_{label}", report_dir))
        parts.append(_leaks(_read_csv(ai / f"attacks_{label}.csv"), "the reference release")
                     + f"<p class=\"more\">The same counts: <code>{_e(ref['attacks']['command'])}</code>.</p>")
    recall = _read_csv(tables / "selftest_defect_recall.csv")
    if recall is not None:
        parts.append(selftest_html(recall))
    return "<section id=\"headline\"><h2>Headline</h2>" + "".join(p for p in parts if p) + "</section>"


SELFTEST_TEXT = (
    "What the audit found against what the generator injected (its manifest). <b>What it shows:</b> on "
    "data with known defects, the audit finds the defects it was built to find, gives the verdicts the "
    "generator expected and recomputes the true values, so a change that breaks a detector shows here. "
    "<b>What it does not show:</b> the generator and the audit are written by the same project from the same "
    "reading of the ReSTI report, so 100% here means the two agree with each other, not that either is right "
    "about STI-Bench; defects nobody thought of are neither injected nor found; the mini-world is small and "
    "clean beside real sources. It is not a result on STI-Bench: the reference release above is.")


def selftest_html(recall: pd.DataFrame) -> str:
    return ("<div class=\"selftest\"><h3>Self-test on the mini-world <span class=\"label synthetic\">synthetic"
            f"</span></h3><p>{SELFTEST_TEXT}</p>"
            + to_html(recall, caption="Defect recall and precision against the generator's manifest.") + "</div>")


# ------------------------------------------------------------------- the ReSTI report, measured

STATUS_CLASS = {"reproduced": "ok", "not reproduced": "bad", "not checkable here": "na", "leak not in the report": "leak"}


def _claims(out_root: Path) -> pd.DataFrame | None:
    from .paper import panel

    frames = [_read_csv(out_root / "answer_interface" / "paper_claims_v5.csv"),
              _read_csv(out_root / "tables" / "paper_claims_legacy.csv")]
    if all(f is None for f in frames):
        return None
    return panel(*[f.fillna("") if f is not None else None for f in frames])


def paper_html(out_root: Path, report_dir: Path) -> str:
    """The panel: every quantitative claim of the ReSTI report we can check, the figure we measure and
    its status, then the leaks of v5 the report does not mention."""
    from .paper import STATUSES, status_counts

    df = _claims(out_root)
    if df is None:
        return ""
    n = status_counts(df)
    summary = ", ".join(f"<span class=\"status {STATUS_CLASS[s]}\">{n[s]} {_e(s)}</span>" for s in STATUSES if n[s])
    rows = []
    for r in df.itertuples(index=False):
        cls = STATUS_CLASS.get(r.status, "na")
        rows.append(f"<tr class=\"{cls}\"><td>{_e(r.claim)}<br><span class=\"where\">{_e(r.section)}</span></td>"
                    f"<td>{_e(r[3])}</td><td>{_e(r.measured)}</td>"
                    f"<td><span class=\"status {cls}\">{_e(r.status)}</span></td><td class=\"how\">{_e(r.how)}</td></tr>")
    links = " · ".join(_table_links(p.with_suffix(".md"), report_dir) for p in
                       (out_root / "answer_interface" / "paper_claims_v5.csv",
                        out_root / "tables" / "paper_claims_legacy.csv") if p.exists())
    return ("<section id=\"paper\"><h2>The ReSTI report against what we measure</h2>"
            "<p>Each quantitative claim of the ReSTI report that can be checked here, the figure we measure, and "
            "whether it is <b>reproduced</b>; claims on ReSTI v5 are measured on the public release (notebook 00), "
            "claims on the legacy benchmark on this run's legacy input (notebook 99, only when it is real), and a "
            f"claim that needs what is not here says why. {summary}.</p>"
            "<div class=\"table-wrap\"><table class=\"resti-table claims\"><thead><tr><th>claim</th>"
            "<th>ReSTI report</th><th>measured</th><th>status</th><th>how / why</th></tr></thead><tbody>"
            + "".join(rows) + "</tbody></table></div>"
            + (f"<p class=\"more\">{links}</p>" if links else "") + "</section>")


def exclusions_html(out_root: Path, report_dir: Path) -> str:
    """ReSTI v5's exclusions explained (its codes, what they mean, the split by the stated rule) and
    ours by the same rule."""
    ref = reference_audit(out_root)
    parts = []
    if ref is not None:
        ai = out_root / "answer_interface"
        label = ref["label"]
        split, glossary = _read_csv(ai / f"exclusion_split_{label}.csv"), _read_csv(ai / f"exclusion_glossary_{label}.csv")
        if split is not None and glossary is not None:
            from .exclusions import glossary_spec

            parts.append(f"<h3>The reference release ({_e(label)}) <span class=\"label real\">real data</span></h3>"
                         f"<p><b>Rule:</b> {_e(glossary_spec()['rule'])}.</p>"
                         + to_html(split, caption="Exclusions by class (ReSTI report: its figures beside ours).")
                         + to_html(glossary, caption="Every exclusion code of the reference release: verification "
                                   "verdicts (what a check of the source found) first, then reason codes (engineering "
                                   "statuses of its pipeline), with our nearest reason code.")
                         + f"<p class=\"more\">{_table_links(ai / f'exclusion_glossary_{label}.md', report_dir)}</p>")
    ours = _read_csv(out_root / "tables" / "exclusion_classes.csv")
    if ours is not None:
        from .statistics import EXCLUSION_RULE

        parts.append(f"<h3>Our release</h3><p><b>The same rule on our reason codes:</b> {_e(EXCLUSION_RULE)}.</p>"
                     + to_html(ours, caption="Our exclusions by class.")
                     + f"<p class=\"more\">{_table_links(out_root / 'tables' / 'exclusion_classes.md', report_dir)}</p>")
    if not parts:
        return ""
    return "<section id=\"exclusions\"><h2>Exclusions explained</h2>" + "".join(parts) + "</section>"


# ------------------------------------------------------------------------------------ examples

EXAMPLES_PAGE = "examples.html"


def _examples(out_root: Path, products: set | None) -> pd.DataFrame | None:
    p = out_root / "tables" / "examples.csv"
    if not p.exists() or not _current(p, out_root, products):
        return None
    try:
        return pd.read_csv(p, dtype=str, keep_default_na=False)
    except (OSError, ValueError, pd.errors.EmptyDataError):
        return None


def examples_html(out_root: Path, report_dir: Path, products: set | None = None) -> str:
    """One example of each verdict on the page, every task's examples on ``examples.html``."""
    ex = _examples(out_root, products)
    if ex is None or ex.empty:
        return ""
    tasks = list(dict.fromkeys(ex["task"]))
    links = " · ".join(f'<a href="{EXAMPLES_PAGE}#ex-{_e(t.lower().replace(" ", "-").replace("&", "and"))}">'
                       f"{_e(t)}</a>" for t in tasks)
    first = one_per_verdict(ex)
    return ("<section id=\"examples\"><h2>Before and after: examples</h2>"
            f"<p>One legacy row of each verdict beside its repaired form, with the source evidence and the defects. "
            f"Every task, up to two rows per verdict: <a href=\"{EXAMPLES_PAGE}\">all examples</a> ({links}).</p>"
            + "".join(card_html(r) for r in first.to_dict("records")) + "</section>")


def write_examples_page(out_root: Path, report_dir: Path, title: str, products: set | None = None) -> Path | None:
    """``report/examples.html``: every example, by task, with a link back to the index."""
    page = report_dir / EXAMPLES_PAGE
    ex = _examples(out_root, products)
    if ex is None or ex.empty:
        page.unlink(missing_ok=True)
        return None
    doc = ("<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\">"
           "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
           f"<title>{_e(title)}: examples</title><style>{CSS}{EX_CSS}</style></head><body>\n"
           f"<p><a href=\"index.html\">&larr; back to the report</a></p><h1>Before and after: examples</h1>"
           "<p>Per task and verdict, up to two legacy rows (the rows with the most defects first) beside their "
           "repaired form, with the source evidence and the defects (table <code>tables/examples.csv</code>; every "
           "row's full record is in <code>release/provenance.parquet</code>).</p>\n"
           + cards_html(ex) + "\n</body></html>\n")
    atomic_write_bytes(page, doc.encode("utf-8"))
    return page


# --------------------------------------------------------------------------- figures, tables

def _current(p: Path, out_root: Path, products: set | None) -> bool:
    """Is ``p`` a file of this run (a recorded stage product), or is every file listed?"""
    return products is None or p.relative_to(out_root).as_posix() in products


def figures_html(out_root: Path, report_dir: Path, products: set | None = None) -> str:
    items, section = [], None
    for p, spec in ordered_figures(out_root / "figures"):
        if not _current(p, out_root, products):
            continue
        sec = spec.section if spec else "Other figures"
        if sec != section:
            items.append(f"<h3>{_e(sec)}</h3>")
            section = sec
        src = _rel(p, report_dir)
        cap = spec.caption if spec else p.stem
        items.append(f"<figure id=\"fig-{_e(p.stem)}\"><a href=\"{src}\" title=\"open full size\">"
                     f"<img src=\"{src}\" alt=\"{_e(cap)}\" loading=\"lazy\"></a><figcaption>{_e(cap)} "
                     f"<span class=\"file\">({_e(p.name)}; click to open full size)</span></figcaption></figure>")
    if not items:
        return ""
    return "<section id=\"figures\"><h2>Figures</h2>" + "".join(items) + "</section>"


def _table_links(p: Path, report_dir: Path) -> str:
    links = [f'<a href="{_rel(p, report_dir)}">{_e(p.stem)}</a>']
    links += [f'<a href="{_rel(q, report_dir)}">{q.suffix[1:]}</a>' for q in (p.with_suffix(".csv"),
                                                                               p.with_suffix(".tex")) if q.exists()]
    return " · ".join(links)


def _link_section(p: Path, out_root: Path) -> str:
    rel = p.relative_to(out_root)
    top = rel.parts[0]
    if top == "answer_interface":
        return "Answer interface (notebook 00)"
    if top == "reoption":
        return "Re-optioned reference release (notebook 90)"
    stem = p.stem
    if stem[:2].isdigit() and "_" in stem:
        nb = stem.split("_", 2)
        return f"Notebook {nb[0]} · {nb[1]}"
    if stem.startswith("selftest_"):
        return "Self-test (synthetic)"
    if stem.startswith("reference_"):
        return "Reference release"
    if stem.startswith("attacks_"):
        return "Answer interface"
    return "Release and diagnosis"


def tables_html(out_root: Path, report_dir: Path, products: set | None = None) -> str:
    tables = out_root / "tables"
    shown, parts = set(HEADLINE_TABLES), []
    for section, entries in SHOWN_TABLES:
        sec = []
        for stem, caption in entries:
            df = _read_csv(tables / f"{stem}.csv")
            if df is None or not _current(tables / f"{stem}.csv", out_root, products):
                continue
            shown.add(stem)
            md = tables / f"{stem}.md"
            sec.append(to_html(df, caption=caption, max_rows=60)
                       + f"<p class=\"more\">{_table_links(md, report_dir)}</p>")
        if sec:
            parts.append(f"<h3>{_e(section)}</h3>" + "".join(sec))
    groups: dict[str, list[str]] = {}
    for p in sorted(out_root.glob("**/*.md")):
        top = p.relative_to(out_root).parts[0]
        if top in ("report", "miniworld", "notebooks", ".resti") or (p.parent == tables and p.stem in shown):
            continue
        if not _current(p, out_root, products):
            continue
        groups.setdefault(_link_section(p, out_root), []).append(f"<li>{_table_links(p, report_dir)}</li>")
    if groups:
        parts.append("<h3>Every other table (markdown · csv · tex), by section</h3>")
        for sec in sorted(groups, key=lambda s: (not s.startswith("Release"), s)):
            parts.append(f"<h4>{_e(sec)}</h4><ul class=\"files\">" + "".join(groups[sec]) + "</ul>")
    if not parts:
        return ""
    return "<section id=\"tables\"><h2>Tables</h2>" + "".join(parts) + "</section>"


def notebooks_html(report_dir: Path, products: set | None = None) -> str:
    out_root = report_dir.parent
    items = [f'<li><a href="{_rel(p, report_dir)}">{_e(p.stem)}</a></li>'
             for p in sorted((report_dir / "notebooks").glob("*.html")) if _current(p, out_root, products)]
    if not items:
        return ""
    return ("<section id=\"notebooks\"><h2>Rendered notebooks</h2><ul class=\"files\">" + "".join(items)
            + "</ul></section>")


def release_html(out_root: Path, report_dir: Path) -> str:
    rel_dir = out_root / "release"
    if not rel_dir.exists():
        return ""
    items = [f'<li><a href="{_rel(p, report_dir)}">{_e(p.name)}</a> ({p.stat().st_size:,} bytes)</li>'
             for p in sorted(rel_dir.iterdir()) if p.is_file() and not p.name.startswith(".")]
    return "<section id=\"release\"><h2>Release files</h2><ul class=\"files\">" + "".join(items) + "</ul></section>"


def write_index(out_root: Path | None = None, *, title: str = "resti audit report",
                context: dict | None = None, products: set | None = None) -> Path:
    """Write ``<out_root>/report/index.html`` for whatever the run produced. ``context``: the run
    block (:func:`resti_lib.run.runinfo.run_context`); default: the one in ``release/release.json``.
    ``products``: paths (relative to ``out_root``) the stages of this output folder wrote; figures,
    tables and notebooks not among them (left by older runs) are not listed. Default: all."""
    out_root = Path(out_root or paths.OUTPUTS)
    report_dir = out_root / "report"
    index = report_dir / "index.html"
    if context is None:
        context = ((_read_json(out_root / "release" / "release.json") or {}).get("run"))
    write_examples_page(out_root, report_dir, title, products)
    sections = [changes_html(out_root, to_html=to_html, e=_e), headline_html(out_root),
                paper_html(out_root, report_dir), exclusions_html(out_root, report_dir),
                examples_html(out_root, report_dir, products), figures_html(out_root, report_dir, products),
                tables_html(out_root, report_dir, products), notebooks_html(report_dir, products),
                release_html(out_root, report_dir)]
    ids = [("changes", "What changed"), ("headline", "Headline"), ("paper", "ReSTI report vs measured"),
           ("exclusions", "Exclusions"),
           ("examples", "Examples"), ("figures", "Figures"), ("tables", "Tables"), ("notebooks", "Notebooks"),
           ("release", "Release files")]
    toc = " ".join(f'<a href="#{i}">{t}</a>' for (i, t), s in zip(ids, sections) if s)
    body = [f"<header id=\"run\"><h1>{_e(title)}</h1>{header_html(context)}</header>",
            f"<nav class=\"toc\">{toc}</nav>", *sections]
    doc = ("<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\">"
           "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
           f"<title>{_e(title)}</title><style>{CSS}{EX_CSS}</style></head><body>\n"
           + "\n".join(b for b in body if b) + "\n</body></html>\n")
    atomic_write_bytes(index, doc.encode("utf-8"))
    return index
