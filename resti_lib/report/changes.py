"""What changed: a run with other params set against the baseline run of the same output folder.

The first run of an output folder (or one run with ``resti run --baseline``) is the *baseline*: its
params and the files a reader compares (the release's rows, exclusions and provenance, the attack
table of our release) are kept in ``<output_dir>/.resti/baseline/``. A later run whose params differ
gets a *What changed* section: the params that changed (and the stages that read them), the rows whose
verdict, value, question or options changed, the attack table of the changed tasks before and after,
and warnings when the change made the answer interface infeasible (rows excluded for
``no_valid_options``) or leaky (a new Holm-significant cell, or an underpowered cell with a large
blind effect, which Holm's correction cannot flag). A run with the baseline's params has no section
(and refreshes the baseline's files), so reverting an edit gives the baseline's report back, byte for
byte.

:func:`update` is called by the main job after its stages, with the params every stage last ran with;
it writes ``report/what_changed.json`` and its tables (``report/what_changed_*.csv``), which
:func:`changes_html` renders on the index.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from ..io.files import atomic_write_bytes

BASELINE = Path(".resti") / "baseline"
FILES = ("release/resti.jsonl", "release/excluded.jsonl", "release/provenance.parquet", "tables/attacks_release.csv")
SUMMARY = Path("report") / "what_changed.json"
TABLES = {"params": "what_changed_params", "rows": "what_changed_rows", "attacks": "what_changed_attacks"}
# a blind accuracy this large on at least this many picked rows, its exact 99% interval above chance, is a
# large effect (when the attack table does not flag large effects itself)
LARGE_EFFECT_AT, LARGE_EFFECT_MIN_ROWS, LARGE_EFFECT_LEVEL, CHANCE = 0.35, 20, 0.99, 0.2
ROWS_SHOWN = 40


def _canonical(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False, default=str)


def _write_json(path: Path, obj) -> None:
    atomic_write_bytes(path, (json.dumps(obj, indent=1, ensure_ascii=False, sort_keys=True, default=str) + "\n").encode())


def _read_json(path: Path):
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def clear(out_root: Path) -> None:
    """Remove the What changed files (a run with the baseline's params has none)."""
    (out_root / SUMMARY).unlink(missing_ok=True)
    for stem in TABLES.values():
        (out_root / "report" / f"{stem}.csv").unlink(missing_ok=True)


def snapshot(out_root: Path, params: dict) -> None:
    """Keep ``params`` and the compared files of this run as the baseline."""
    base = out_root / BASELINE
    base.mkdir(parents=True, exist_ok=True)
    for rel in FILES:
        src, dst = out_root / rel, base / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.exists():
            shutil.copyfile(src, dst)
        else:
            dst.unlink(missing_ok=True)
    _write_json(base / "params.json", params)


def update(out_root: str | Path, params: dict, *, rebaseline: bool = False) -> dict | None:
    """Compare this run with the baseline (see the module docstring); returns the summary written, or
    None when there is nothing to say (no baseline yet, ``rebaseline``, or the baseline's params)."""
    out_root = Path(out_root)
    base = out_root / BASELINE
    old = _read_json(base / "params.json")
    if rebaseline or old is None or _canonical(old) == _canonical(params):
        snapshot(out_root, params)
        clear(out_root)
        return None
    summary, tables = compare(base, out_root, old, params)
    (out_root / "report").mkdir(parents=True, exist_ok=True)
    for key, df in tables.items():
        atomic_write_bytes(out_root / "report" / f"{TABLES[key]}.csv",
                           df.to_csv(index=False, lineterminator="\n").encode("utf-8"))
    _write_json(out_root / SUMMARY, summary)
    return summary


# ------------------------------------------------------------------------------------ params

def _flat(obj, prefix: str = "") -> dict:
    if isinstance(obj, dict) and obj:
        out = {}
        for k, v in obj.items():
            out.update(_flat(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: obj}


def params_diff(old: dict, new: dict) -> pd.DataFrame:
    """One row per changed value: ``param`` (dotted), ``before``, ``after`` and the stages (or library
    params files) that read it."""
    rows: dict[tuple, list[str]] = {}
    for group in ("stages", "library"):
        o, n = old.get(group) or {}, new.get(group) or {}
        for name in sorted(set(o) | set(n)):
            fo, fn = _flat(o.get(name) or {}), _flat(n.get(name) or {})
            for k in sorted(set(fo) | set(fn)):
                a, b = fo.get(k, "(absent)"), fn.get(k, "(absent)")
                if _canonical(a) != _canonical(b):
                    rows.setdefault((k, _canonical(a), _canonical(b)), []).append(name)
    out = [{"param": k, "before": a, "after": b, "read by": ", ".join(names)} for (k, a, b), names in rows.items()]
    return pd.DataFrame(out, columns=["param", "before", "after", "read by"])


# -------------------------------------------------------------------------------------- rows

def _rows_of(folder: Path) -> dict[str, dict]:
    """Per legacy row key: verdict, task, source, question, value, options and reasons."""
    out: dict[str, dict] = {}
    prov = folder / "release" / "provenance.parquet"
    if prov.exists():
        for r in pd.read_parquet(prov, columns=["key", "task", "source", "verdict"]).to_dict("records"):
            out[r["key"]] = {"task": r["task"], "source": r["source"], "verdict": r["verdict"]}
    acc = folder / "release" / "resti.jsonl"
    for line in (acc.read_text(encoding="utf-8").splitlines() if acc.exists() else []):
        if line.strip():
            r = json.loads(line)
            d = out.setdefault(r["Legacy Row Key"], {"task": r["Task"], "source": r["Source"], "verdict": "accepted"})
            d.update(question=r.get("Question"), value=r.get("Answer Detail"),
                     options=_canonical({"candidates": r.get("Candidates"), "answer": r.get("Answer")}))
    exc = folder / "release" / "excluded.jsonl"
    for line in (exc.read_text(encoding="utf-8").splitlines() if exc.exists() else []):
        if line.strip():
            r = json.loads(line)
            d = out.setdefault(r["key"], {"task": r.get("task"), "source": r.get("source"), "verdict": "excluded"})
            d["reasons"] = ", ".join(r.get("reason_codes") or [])
    return out


def rows_diff(old_dir: Path, new_dir: Path) -> pd.DataFrame:
    """Rows whose verdict, value, question or options changed, in legacy-row order of the new release."""
    old, new = _rows_of(old_dir), _rows_of(new_dir)
    out = []
    for key in list(new) + [k for k in old if k not in new]:
        a, b = old.get(key, {}), new.get(key, {})
        what = [name for name, field in (("verdict", "verdict"), ("value", "value"), ("question", "question"),
                                         ("options", "options")) if a.get(field) != b.get(field)]
        if not what:
            continue
        out.append({"key": key, "task": b.get("task", a.get("task")), "source": b.get("source", a.get("source")),
                    "changed": ", ".join(what), "verdict before": a.get("verdict", ""),
                    "verdict after": b.get("verdict", ""), "value before": a.get("value") or "",
                    "value after": b.get("value") or "", "reasons after": b.get("reasons", ""),
                    "options before": a.get("options") or "", "options after": b.get("options") or ""})
    return pd.DataFrame(out, columns=["key", "task", "source", "changed", "verdict before", "verdict after",
                                      "value before", "value after", "reasons after", "options before",
                                      "options after"])


# ----------------------------------------------------------------------------------- attacks

def _bool(s: pd.Series) -> pd.Series:
    return s.astype(str).str.lower() == "true"


def large_effects(table: pd.DataFrame) -> pd.Series:
    """Rows of an attack table with a large blind effect: the table's own ``large_effect`` column when
    it has one, else accuracy at least 35% on at least 20 picked rows with the exact two-sided 99%
    interval above chance."""
    if "large_effect" in table.columns:
        return _bool(table["large_effect"])
    from ..options.power import clopper_pearson

    hits, picked = table["hits"].astype(float).to_numpy(), table["picked"].astype(float).to_numpy()
    acc = np.where(picked > 0, hits / np.maximum(picked, 1), 0.0)
    big = (picked >= LARGE_EFFECT_MIN_ROWS) & (acc >= LARGE_EFFECT_AT)
    lo = np.zeros(len(table))
    if big.any():
        lo[big] = [float(clopper_pearson(h, n, level=LARGE_EFFECT_LEVEL)[0]) for h, n in zip(hits[big], picked[big])]
    return pd.Series(big & (lo > CHANCE), index=table.index)


def cells(table: pd.DataFrame | None) -> pd.DataFrame:
    """Per task/source cell: the strongest attack (smallest p-value, as in the headline of ``resti
    attack``), whether any attack is Holm-significant, whether the cell is underpowered, and its
    strongest large-effect attack."""
    cols = ["task", "source", "rows", "strongest", "hits / picked", "accuracy", "significant", "underpowered",
            "large effect"]
    if table is None or len(table) == 0:
        return pd.DataFrame(columns=cols)
    t = table[table["picked"].astype(float) > 0].assign(_sig=lambda d: _bool(d["significant"]),
                                                         _big=lambda d: large_effects(d))
    out = []
    for (task, source), g in t.groupby(["task", "source"], sort=False):
        b = g.sort_values(["p_value", "accuracy"], ascending=[True, False], kind="stable").iloc[0]
        big = g[g["_big"]].sort_values(["accuracy", "hits"], ascending=False, kind="stable")
        out.append({"task": task, "source": source, "rows": int(g["n_rows"].max()), "strongest": b["attack"],
                    "hits / picked": f"{float(b['hits']):g}/{int(b['picked'])}", "accuracy": float(b["accuracy"]),
                    "significant": bool(g["_sig"].any()),
                    "underpowered": bool(_bool(g["underpowered"]).any()) if "underpowered" in g else False,
                    "large effect": (f"{big.iloc[0]['attack']} {float(big.iloc[0]['hits']):g}/"
                                     f"{int(big.iloc[0]['picked'])}" if len(big) else "")})
    return pd.DataFrame(out, columns=cols)


def attacks_diff(old: pd.DataFrame | None, new: pd.DataFrame | None, tasks: list[str]) -> pd.DataFrame:
    """The cells of ``tasks`` before and after, side by side."""
    a, b = cells(old), cells(new)
    a, b = a[a["task"].isin(tasks)], b[b["task"].isin(tasks)]
    m = a.merge(b, on=["task", "source"], how="outer", suffixes=(" before", " after"), sort=False)
    order = [c for c in ("task", "source", "rows before", "rows after", "strongest before", "hits / picked before",
                         "accuracy before", "significant before", "strongest after", "hits / picked after",
                         "accuracy after", "significant after", "underpowered after", "large effect before",
                         "large effect after") if c in m.columns]
    return m[order].reset_index(drop=True)


# ------------------------------------------------------------------------------------ compare

def _read_csv(p: Path) -> pd.DataFrame | None:
    try:
        return pd.read_csv(p) if p.exists() else None
    except (OSError, ValueError, pd.errors.EmptyDataError):
        return None


def compare(base: Path, out_root: Path, old_params: dict, new_params: dict) -> tuple[dict, dict[str, pd.DataFrame]]:
    """The summary (params, counts, warnings) and the tables of a run against its baseline."""
    params = params_diff(old_params, new_params)
    rows = rows_diff(base, out_root)
    tasks = list(dict.fromkeys(rows["task"])) if len(rows) else []
    att = attacks_diff(_read_csv(base / "tables" / "attacks_release.csv"),
                       _read_csv(out_root / "tables" / "attacks_release.csv"), tasks)
    warnings = []
    newly = rows[(rows["verdict after"] == "excluded") & rows["reasons after"].str.contains("no_valid_options")
                 & (rows["verdict before"] != "excluded")]
    if len(newly):
        warnings.append({"kind": "infeasible", "rows": list(newly["key"]),
                         "text": f"{len(newly)} row(s) newly excluded for no_valid_options: no five candidates meet "
                                 "the separation floors and bounds under the new params (the adjudication tolerance "
                                 "of a scalar task is also its separation floor): " + "; ".join(newly["key"])})
    if len(att):
        sig_after = att.get("significant after", pd.Series(False, index=att.index)).fillna(False).astype(bool)
        sig_before = att.get("significant before", pd.Series(False, index=att.index)).fillna(False).astype(bool)
        for i in att.index[sig_after & ~sig_before]:
            r = att.loc[i]
            warnings.append({"kind": "leaky", "cell": f"{r['task']}/{r['source']}",
                             "text": f"{r['task']}/{r['source']}: a Holm-significant blind attack appeared "
                                     f"(strongest {r.get('strongest after', '')} {r.get('hits / picked after', '')})"})
        big_after = att.get("large effect after", pd.Series("", index=att.index)).fillna("").astype(str)
        big_before = att.get("large effect before", pd.Series("", index=att.index)).fillna("").astype(str)
        under = att.get("underpowered after", pd.Series(False, index=att.index)).fillna(False).astype(bool)
        for i in att.index[(big_after != "") & (big_before == "") & ~sig_after]:
            r = att.loc[i]
            warnings.append({"kind": "large effect", "cell": f"{r['task']}/{r['source']}",
                             "text": f"{r['task']}/{r['source']}: large blind effect {big_after[i]} that Holm's "
                                     "correction does not flag" + (" (the cell is underpowered: too few rows for the "
                                                                   "test to detect 35%)" if under[i] else "")})
    summary = {"baseline": str(BASELINE / "params.json"), "params": params.to_dict("records"),
               "rows_changed": len(rows), "by_change": rows["changed"].str.split(", ").explode().value_counts()
               .sort_index().to_dict() if len(rows) else {}, "tasks": tasks, "warnings": warnings}
    return summary, {"params": params, "rows": rows, "attacks": att}


# ------------------------------------------------------------------------------------ render

def _short_key(key: str) -> str:
    """``video #id`` of a legacy row key (``source|task|video|id|uid=...``); the full key is in the CSV."""
    parts = str(key).split("|")
    return f"{parts[2]} #{parts[3]}" if len(parts) >= 4 else str(key)


def changes_html(out_root: Path, *, to_html, e) -> str:
    """The What changed section (empty when this run has the baseline's params)."""
    out_root = Path(out_root)
    s = _read_json(out_root / SUMMARY)
    if not s:
        return ""
    rep = out_root / "report"
    params = _read_csv(rep / f"{TABLES['params']}.csv")
    rows = pd.read_csv(rep / f"{TABLES['rows']}.csv", dtype=str, keep_default_na=False) \
        if (rep / f"{TABLES['rows']}.csv").exists() else pd.DataFrame()
    att = _read_csv(rep / f"{TABLES['attacks']}.csv")
    warn = "".join(f"<li class=\"{e(w['kind'].replace(' ', '-'))}\"><b>{e(w['kind'])}</b>: {e(w['text'])}</li>"
                   for w in s.get("warnings") or [])
    by = ", ".join(f"{k} {v}" for k, v in (s.get("by_change") or {}).items())
    parts = ["<section id=\"changes\"><h2>What changed</h2>",
             "<p>This run's params differ from the baseline run of this output folder (its first run, or the last "
             "<code>resti run --baseline</code>); reverting the params gives the baseline's report back.</p>"]
    if warn:
        parts.append(f"<ul class=\"warnings\">{warn}</ul>")
    if params is not None and len(params):
        parts.append(to_html(params, caption="Params that changed (and the stages that read them)."))
    parts.append(f"<p><b>{s.get('rows_changed', 0)}</b> rows changed ({e(by) or 'none'}).</p>")
    if len(rows):
        shown = rows[["task", "source", "changed", "verdict before", "verdict after", "value before", "value after",
                      "reasons after"]].copy()
        shown.insert(0, "row", rows["key"].map(_short_key))
        parts.append(to_html(shown, caption="Rows whose verdict, value, question or options changed (their options "
                                            "before and after: the linked CSV).", max_rows=ROWS_SHOWN)
                     + f"<p class=\"more\"><a href=\"{TABLES['rows']}.csv\">{TABLES['rows']}.csv</a></p>")
    if att is not None and len(att):
        parts.append(to_html(att, caption="Blind attacks of the changed tasks, per task/source cell, before (baseline) "
                                          "and after (this run): the strongest attack, Holm significance, power and "
                                          "large effects."))
    return "".join(parts) + "</section>"
