"""Before/after examples: legacy rows beside their repaired form, per task and verdict, with the evidence.

:func:`select_examples` picks, for every task (registry order) and verdict (retained, corrected,
re-contracted, excluded), a few rows of the release's provenance (the rows with the most defects
first, then by legacy row), and puts beside each other what a reader compares: the legacy question,
candidates, key and Answer Detail; the repaired question, candidates, answer and Answer Detail (or the
exclusion reasons); the source evidence (frames and times, the transform chain, the recomputed value
and its comparison with the legacy value, the source files) and the defects with their layer and
category. Notebook 99 writes the table (``tables/examples.*``); the index renders it as cards
(:func:`cards_html`). On real data the rows are the real rows.
"""

from __future__ import annotations

import html
import json
from pathlib import Path

import pandas as pd

from ..defects import DEFECTS, REASONS
from ..tasks import names as task_names

VERDICTS = ("retained", "corrected", "re-contracted", "excluded")
COLUMNS = ["task", "verdict", "source", "row", "key", "video", "legacy_question", "legacy_candidates", "legacy_answer",
           "legacy_detail", "question", "candidates", "answer", "detail", "reasons", "defects", "frames",
           "transform_chain", "comparison", "evidence", "source_files"]
EVIDENCE_CHARS = 700  # evidence shown per example (the full record is in provenance.parquet)


def _json(x) -> object:
    if isinstance(x, str):
        try:
            return json.loads(x)
        except ValueError:
            return x
    return x


def _text(x) -> str:
    if x is None or (isinstance(x, float) and pd.isna(x)):
        return ""
    return x if isinstance(x, str) else json.dumps(x, ensure_ascii=False, sort_keys=True)


def _comparison(ev: dict, legacy_detail: str, new_detail: str) -> str:
    """The recomputed value against the legacy one, as the diagnosis compared them."""
    cmp = ev.get("comparison") if isinstance(ev, dict) else None
    if isinstance(cmp, dict):
        parts = [f"legacy {cmp.get('legacy_text', legacy_detail)}", f"recomputed {new_detail}"]
        if cmp.get("residual_si") is not None:
            parts.append(f"residual {cmp['residual_si']:+.4g} (SI)")
        if "agrees" in cmp:
            parts.append("agree" if cmp["agrees"] else "disagree")
        if cmp.get("rule"):
            parts.append(f"rule: {cmp['rule']}")
        return "; ".join(parts)
    if new_detail:
        return f"legacy {legacy_detail or '(none)'}; recomputed {new_detail}"
    return ""


def _evidence(ev) -> str:
    """The row's evidence without the option stage's record (long, and not about the value)."""
    if not isinstance(ev, dict):
        return _text(ev)[:EVIDENCE_CHARS]
    shown = {k: v for k, v in ev.items() if k not in ("options", "comparison")}
    text = json.dumps(shown, ensure_ascii=False, sort_keys=True)
    return text if len(text) <= EVIDENCE_CHARS else text[:EVIDENCE_CHARS] + " …"


def select_examples(prov: pd.DataFrame, legacy: pd.DataFrame, accepted: pd.DataFrame, *,
                    per_verdict: int = 2) -> pd.DataFrame:
    """Up to ``per_verdict`` examples per task and verdict (columns :data:`COLUMNS`). ``prov``: the
    release's provenance (``row`` is the legacy row's index in ``legacy``); ``accepted``: the release's
    accepted rows (by ``Legacy Row Key``)."""
    repaired = {r["Legacy Row Key"]: r for r in accepted.to_dict("records")} if len(accepted) else {}
    order = {t: i for i, t in enumerate(task_names())}
    p = prov.assign(_n=prov["defects"].map(lambda d: len(_json(d) or [])),
                    _t=prov["task"].map(lambda t: order.get(t, len(order))),
                    _v=prov["verdict"].map(lambda v: VERDICTS.index(v) if v in VERDICTS else len(VERDICTS)))
    p = p.sort_values(["_t", "task", "_v", "_n", "row"], ascending=[True, True, True, False, True], kind="stable")
    out = []
    for _, g in p.groupby(["_t", "task", "_v"], sort=False):
        for r in g.head(per_verdict).itertuples(index=False):
            leg = legacy.iloc[int(r.row)].to_dict() if 0 <= int(r.row) < len(legacy) else {}
            new = repaired.get(r.key, {})
            ev = _json(r.evidence) or {}
            files = [Path(f).name for f in (_json(r.source_files) or [])]
            new_detail = _text(r.new_detail)
            out.append({"task": r.task, "verdict": r.verdict, "source": r.source, "row": int(r.row), "key": r.key,
                        "video": r.video, "legacy_question": _text(leg.get("Question")),
                        "legacy_candidates": _text(leg.get("Candidates")), "legacy_answer": _text(leg.get("Answer")),
                        "legacy_detail": _text(leg.get("Answer Detail")), "question": _text(new.get("Question")),
                        "candidates": _text(new.get("Candidates")), "answer": _text(new.get("Answer")),
                        "detail": _text(new.get("Answer Detail")), "reasons": _text(_json(r.reasons) or []),
                        "defects": _text(_json(r.defects) or []), "frames": _text(_json(r.frames) or {}),
                        "transform_chain": _text(r.transform_chain),
                        "comparison": _comparison(ev, _text(r.legacy_detail), new_detail),
                        "evidence": _evidence(ev), "source_files": ", ".join(files)})
    return pd.DataFrame(out, columns=COLUMNS)


# ------------------------------------------------------------------------------------ rendering

def _e(x) -> str:
    return html.escape(str(x))


def _options(cands: str, mark: str, detail: str) -> str:
    c = _json(cands)
    if not isinstance(c, dict):
        return f"<p>{_e(cands)}</p>" if cands else ""
    key = ' class="key"'
    items = "".join(f"<li{key if k == mark else ''}><b>{_e(k)}</b> <code>{_e(v)}</code>"
                    + (" &larr; key" if k == mark else "") + "</li>" for k, v in c.items())
    return f"<ol class=\"options\">{items}</ol><p class=\"detail\">Answer Detail <code>{_e(detail)}</code></p>"


def _defects(codes: str) -> str:
    items = []
    for c in _json(codes) or []:
        d = DEFECTS.get(c)
        items.append(f"<li><code>{_e(c)}</code> ({_e(d.layer)} layer, {_e(d.category)}): {_e(d.description)}</li>"
                     if d else f"<li><code>{_e(c)}</code></li>")
    return f"<ul class=\"defects\">{''.join(items)}</ul>" if items else "<p>none</p>"


def card_html(ex: dict) -> str:
    """One example: legacy beside repaired, then the source evidence and the defects."""
    after = (f"<p class=\"q\">{_e(ex['question'])}</p>" + _options(ex["candidates"], ex["answer"], ex["detail"])
             if ex["verdict"] != "excluded" else
             "<p><b>Excluded</b>: " + "; ".join(f"<code>{_e(c)}</code> ({_e(REASONS.get(c, ''))})"
                                                for c in (_json(ex["reasons"]) or [])) + "</p>")
    evidence = [("frames and times", ex["frames"]), ("transform chain", ex["transform_chain"]),
                ("recomputed value", ex["comparison"]), ("evidence", ex["evidence"]),
                ("source files", ex["source_files"])]
    dl = "".join(f"<dt>{_e(k)}</dt><dd><code>{_e(v)}</code></dd>" for k, v in evidence if v and v not in ("{}", "[]"))
    return (f"<article class=\"example {_e(ex['verdict'])}\"><h4><span class=\"verdict {_e(ex['verdict'])}\">"
            f"{_e(ex['verdict'])}</span> {_e(ex['task'])} · {_e(ex['source'])} · legacy row {_e(ex['row'])} "
            f"<span class=\"where\">{_e(ex['video'])}</span></h4>"
            "<div class=\"pair\"><div><h5>Legacy (STI-Bench)</h5>"
            f"<p class=\"q\">{_e(ex['legacy_question'])}</p>"
            + _options(ex["legacy_candidates"], ex["legacy_answer"], ex["legacy_detail"])
            + f"</div><div><h5>Repaired (ours)</h5>{after}</div></div>"
            f"<h5>Source evidence</h5><dl class=\"evidence\">{dl or '<dt>none</dt><dd></dd>'}</dl>"
            f"<h5>Defects</h5>{_defects(ex['defects'])}</article>")


def cards_html(examples: pd.DataFrame, *, tasks: list[str] | None = None) -> str:
    """Every example, grouped by task (``tasks``: only these)."""
    parts = []
    for task, g in examples.groupby("task", sort=False):
        if tasks is not None and task not in tasks:
            continue
        counts = ", ".join(f"{v} {n}" for v, n in g["verdict"].value_counts(sort=False).items())
        parts.append(f"<section class=\"task\" id=\"ex-{_e(task.lower().replace(' ', '-').replace('&', 'and'))}\">"
                     f"<h3>{_e(task)}</h3><p class=\"more\">{_e(counts)} shown</p>"
                     + "".join(card_html(r) for r in g.to_dict("records")) + "</section>")
    return "".join(parts)


def one_per_verdict(examples: pd.DataFrame) -> pd.DataFrame:
    """The first example of each verdict (in verdict order), each from another task where possible."""
    out, used = [], set()
    for v in VERDICTS:
        g = examples[examples["verdict"] == v]
        if g.empty:
            continue
        fresh = g[~g["task"].isin(used)]
        r = (fresh if len(fresh) else g).iloc[0]
        used.add(r["task"])
        out.append(r)
    return pd.DataFrame(out, columns=examples.columns)


CSS = """
article.example{border:1px solid #ddd;border-radius:4px;padding:.4em .9em .7em;margin:1em 0;background:#fff}
article.example h4{margin:.3em 0 .5em;font-size:1em}article.example h5{margin:.6em 0 .2em;font-size:.9em;color:#444}
article.example .where{font-weight:normal;color:#888;font-size:.85em;margin-left:.5em}
.pair{display:grid;grid-template-columns:1fr 1fr;gap:1em}.pair>div{min-width:0}
p.q{font-size:.9em;margin:.2em 0}ol.options{list-style:none;padding-left:0;margin:.2em 0;font-size:.85em}
ol.options li.key{background:#eef6ee}ol.options code,p.detail code,dl.evidence code{overflow-wrap:anywhere}
p.detail{font-size:.85em;margin:.2em 0}dl.evidence{display:grid;grid-template-columns:max-content 1fr;gap:.1em .8em;
font-size:.82em;margin:.2em 0}dl.evidence dd{margin:0;min-width:0}ul.defects{font-size:.85em;margin:.2em 0}
.verdict{display:inline-block;font-size:.8em;font-weight:600;padding:0 .45em;border-radius:3px;margin-right:.3em}
.verdict.retained{background:#d8eedd}.verdict.corrected{background:#dbe8f7}.verdict[class~="re-contracted"]{background:#efe0f7}
.verdict.excluded{background:#f8d7d3}
"""
