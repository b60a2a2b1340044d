"""Rebuild the answer options of a ReSTI-schema release (``resti reoption``).

Input: a release folder (``resti.jsonl`` or ``resti.parquet``, ``excluded.jsonl``). Every accepted
row gets new candidates and a new answer letter from the option stage
(:mod:`resti_lib.options.stage`, the same code that builds the options of our own release).
Everything else of the row is kept as it is: row order, ``ReSTI ID``, ``Legacy Row Key``,
question, prompt, times, video, task, source and the ``Answer Detail`` string, which is also the
keyed candidate, character for character.

The input is checked first (:func:`check_input`: counts, digests, exclusions); a damaged input is
refused, never re-issued with fresh checksums. The output is written by the one release writer
(:func:`resti_lib.release.assemble.release_stage`): a staging folder swapped in when complete, never over the
input nor over a folder resti did not write. It holds the three artifacts, ``evaluation_subset.json``
(a documented subset under which the leaks options cannot remove are at chance,
:mod:`resti_lib.options.structural`), ``release.json`` (counts, letters, bytes and sha256 of each
artifact, and the structural leaks with their size), ``SHA256SUMS`` and ``validation.json``
(:func:`resti_lib.release.verify.verify_release`). A release that fails verification is not published.
This module also holds the before/after audit helpers of notebook 90.
"""

from __future__ import annotations

import json
import os
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .. import SOURCES, __version__, paths
from ..errors import InputError, ReoptionError
from ..io.benchmark import jsonl_text, load_release, rows_to_parquet_bytes
from ..io.figures import save_figure
from ..io.files import read_bytes, read_jsonl, sha256_bytes
from ..options.learned import LearnedConfig, attack_table_with_learned
from ..options.stage import build_options
from ..options.structural import evaluation_subset, structural_leaks
from ..tasks import interface, names

DEFAULT_RELEASE = "${SHARED}/data/resti_v5"
ARTIFACTS = ("resti.jsonl", "resti.parquet", "excluded.jsonl", "evaluation_subset.json")


def reoption_records(records: list[dict], *, iface, seed: int = 0, extras: dict | None = None,
                     progress: bool = False) -> tuple[list[dict], pd.DataFrame, list[dict]]:
    """New candidates and letters for every row through the option stage
    (:func:`resti_lib.options.stage.build_options`) under the answer interface ``iface``; returns
    (rows, evidence, exclusions). The rebuild never aborts on a row: a row whose options cannot meet
    the constraints leaves the accepted rows as an exclusion record with reason
    ``no_valid_options`` and the stage's message in its evidence (the other rows are unchanged).
    """
    built, ev, failed = build_options(records, iface=iface, seed=seed, extras=extras, progress=progress,
                                      on_failure="skip")
    rows, excluded = [], []
    for r in built:
        rid = str(r.get("ReSTI ID") or r.get("Legacy Row Key"))
        if rid not in failed:
            rows.append(r)
            continue
        key = r.get("Legacy Row Key")
        parts = str(key).split("|")
        excluded.append({"key": key, "legacy_id": r.get("ID"),
                         "legacy_video": parts[2] if len(parts) > 2 else r.get("Video"),
                         "source": r.get("Source"), "task": r.get("Task"), "reason_codes": ["no_valid_options"],
                         "verification_verdict": "excluded_no_valid_options",
                         "verification_evidence": {"resti_id": rid, "option_error": failed[rid]}})
    return rows, ev, excluded


# ------------------------------------------------------------------------------------ writing

def release_meta(rows: list[dict], excluded: list[dict], artifacts: dict, *, source_meta: dict | None,
                 source_digests: dict, seed: int, options: dict) -> dict:
    """The ``release.json`` object (no dates or paths, so the same input gives the same bytes); the
    row counts come from :func:`resti_lib.release.assemble.count_fields`, as in an assembled release."""
    from .assemble import count_fields

    c = count_fields(rows, excluded, excluded_order="name")
    by_task_letter = {t: {L: int(n) for L, n in sorted(Counter(r["Answer"] for r in rows if r["Task"] == t).items())}
                      for t in c["accepted_by_task"]}
    sm = source_meta or {}
    return {
        "name": sm.get("name", "ReSTI"),
        "version": f"{sm.get('version', 'unknown')}+reoption",
        "derived_from": {"name": sm.get("name"), "version": sm.get("version"), "artifacts": source_digests},
        "reoption": {"seed": int(seed), "generator": "resti_lib.release.reoption", "resti_version": __version__,
                     "options": options,
                     "preserved": "row order and every field except Candidates and Answer; the keyed "
                                  "candidate is the Answer Detail string"},
        "artifacts": artifacts,
        "counts": c["counts"],
        "accepted_by_source": c["accepted_by_source"],
        "accepted_by_task": c["accepted_by_task"],
        "accepted_by_task_source": {f"{t}|{s}": int(n) for (t, s), n in
                                    sorted(Counter((r["Task"], r["Source"]) for r in rows).items())},
        "excluded_by_task": c["excluded_by_task"],
        "answer_letters": c["answer_letters"],
        "answer_letters_by_task": by_task_letter,
    }


@dataclass
class ReoptionResult:
    out_dir: Path
    rows: list[dict]
    before: list[dict]
    evidence: pd.DataFrame
    meta: dict
    validation: dict
    seconds: float
    leaks: pd.DataFrame | None = None
    subset: dict | None = None
    dropped: list = field(default_factory=list)  # rows excluded for no_valid_options


def check_input(rel) -> None:
    """Refuse a damaged input release, naming the failing check (:class:`InputError` whose
    ``field`` is the check).

    The input must carry its integrity records and match them: ``release.json`` with row counts
    (accepted, excluded, original) equal to the rows and exclusions present, digests
    (``SHA256SUMS`` or the ``release.json`` artifacts) covering the files read and matching them,
    at least one accepted row, unique ids. A release with a cut row, an emptied ``excluded.jsonl``
    or an empty ``resti.jsonl`` is refused instead of being re-issued with fresh checksums.
    """
    from .verify import integrity_checks

    where = rel.root
    if rel.meta is None:
        raise InputError("the input release has no release.json: its row counts cannot be checked, so "
                         "damage (cut rows, lost exclusions) would go unnoticed; nothing was written",
                         file=where, field="release_json")
    checks = integrity_checks(rel)
    if checks["sha256"]["status"] == "skipped":
        raise InputError("the input release has no digests (SHA256SUMS or release.json artifacts): "
                         "damage would go unnoticed; nothing was written", file=where, field="sha256")
    failing = {k: c for k, c in checks.items() if c["status"] == "fail"}
    if failing:
        name, c = next(iter(failing.items()))
        msgs = "; ".join(f"{k}: {v}" for k, v in list((c.get("messages") or {}).items())[:3]) \
            or ", ".join(c["failing"][:3])
        others = f" (also failing: {', '.join(list(failing)[1:])})" if len(failing) > 1 else ""
        raise InputError(f"the input release is damaged; check {name!r} fails: {msgs}{others}; "
                         "nothing was written", file=where, field=name)


def reoption_release(release: str | os.PathLike = DEFAULT_RELEASE, out_dir: str | os.PathLike = "outputs/reoption",
                     *, seed: int = 0, options: dict | None = None) -> ReoptionResult:
    """Read and check a release, rebuild its options, write and verify the new release, publish it
    atomically (:func:`resti_lib.release.assemble.release_stage`: never over the input, nor over a folder
    that resti did not write). ``options``: overrides of the option params, on top of those the input
    records (``answer_interface`` in its ``release.json``; else ``params/options.yaml``). The params
    the rebuild used are written under ``answer_interface`` in the new ``release.json``, which
    ``resti verify`` reads back."""
    from .assemble import failing_checks, release_stage
    from .verify import release_interface

    t0 = time.perf_counter()
    src = paths.resolve(release)
    out = paths.resolve(out_dir)
    with release_stage(out, inputs=[src]) as st:
        rel = load_release(src, strict=True, known_tasks=names())
        check_input(rel)
        iface, _ = release_interface(rel, options=options)
        if rel.accepted_file is not None and rel.accepted_file.suffix == ".jsonl":
            # the rows exactly as written (field order and value types), not through a data frame
            records = read_jsonl(rel.accepted_file)
        else:
            records = rel.accepted.to_dict("records")
        rows, ev, dropped = reoption_records(records, iface=iface, seed=seed)
        leaks = structural_leaks(rows, iface)
        subset = evaluation_subset(rows, iface, leaks, seed=seed)
        st.write("resti.jsonl", jsonl_text(rows).encode("utf-8"))
        st.write("resti.parquet", rows_to_parquet_bytes(rows))
        excluded_bytes = read_bytes(rel.excluded_file) if rel.excluded_file is not None else b""
        if dropped:  # appended after the input's own records, which are copied byte for byte
            excluded_bytes += jsonl_text(dropped, sort_keys=True).encode("utf-8")
        st.write("excluded.jsonl", excluded_bytes)
        st.write("evaluation_subset.json", (json.dumps(subset, indent=1, ensure_ascii=False) + "\n").encode("utf-8"))
        src_digests = {}
        for f in (rel.accepted_file, rel.excluded_file):
            if f is not None:
                b = read_bytes(f)
                src_digests[f.name] = {"bytes": len(b), "sha256": sha256_bytes(b)}
        meta = release_meta(rows, [*rel.excluded, *dropped], st.artifacts(ARTIFACTS), source_meta=rel.meta,
                            source_digests=src_digests, seed=seed, options=iface.options)
        meta["answer_interface"] = iface.to_dict()
        meta["reoption"]["adversarial_filter"] = ev.attrs.get("adversarial", [])
        meta["structural_leaks"] = json.loads(leaks.to_json(orient="records"))
        st.seal(meta, ARTIFACTS)
        validation = st.verify()
        if not validation["passed"]:
            raise ReoptionError(f"the rebuilt release fails verification: {failing_checks(validation)}")
    return ReoptionResult(out, rows, records, ev, meta, validation, time.perf_counter() - t0, leaks, subset, dropped)


def filter_table(by_task: dict) -> pd.DataFrame:
    """The adversarial filter of each task's option stage (``adversarial_filter`` in an assembled
    release's ``release.json``: task -> checks), one row per task: checks, rows scored, rows drawn
    again, why it stopped, and the cells where the redrawn rows still leak."""
    out = []
    for task, log in sorted(by_task.items()):
        last = log[-1] if log else {}
        out.append({"task": task, "checks": len(log), "rows scored": last.get("rows_checked"),
                    "rows drawn again": sum(int(r.get("redrawn", 0)) for r in log),
                    "stopped": last.get("stopped", "nothing to check" if not log else "?"),
                    "draw leaks": "; ".join(f"{c['source']} {c['attack']} {c['hits']:g}/{c['n']}"
                                            for c in last.get("draw_leaks") or [])})
    return pd.DataFrame(out, columns=["task", "checks", "rows scored", "rows drawn again", "stopped", "draw leaks"])


def filter_summary(log: list[dict]) -> str:
    """One line on the adversarial filter's rounds (``reoption.adversarial_filter`` in ``release.json``):
    checks, rows drawn again, why it stopped, and the cells where the redrawn rows still leak."""
    if not log:
        return "adversarial filter: off"
    redrawn = sum(int(r.get("redrawn", 0)) for r in log)
    last = log[-1]
    line = f"adversarial filter: {len(log)} checks, {redrawn} rows drawn again, stopped: {last.get('stopped', '?')}"
    leaks = last.get("draw_leaks") or []
    if leaks:
        line += " (the draw itself leaks; redrawn rows alone: " + "; ".join(
            f"{c['task']}/{c['source']} {c['attack']}{' ' + c['direction'] if c['direction'] else ''} "
            f"{c['hits']:g}/{c['n']}" for c in leaks) + ")"
    return line


# ------------------------------------------------------------------------------------ audit

def attack_tables(before: list[dict], after: list[dict], *, alpha: float = 0.05,
                  learned: LearnedConfig | bool | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The attack table (rule attacks + ``learned_blind``, Holm within each) of input and output."""
    iface = interface()
    return (attack_table_with_learned(before, iface=iface, alpha=alpha, learned=learned),
            attack_table_with_learned(after, iface=iface, alpha=alpha, learned=learned))


def side_by_side(before: pd.DataFrame, after: pd.DataFrame) -> pd.DataFrame:
    """One row per (attack, task, source): input and output accuracy, hits, p-value, significance."""
    cols = ["picked", "hits", "accuracy", "p_value", "significant"]
    key = ["attack", "task", "source"]
    m = before[key + ["n_rows"] + cols].merge(after[key + cols], on=key, how="outer", suffixes=("_in", "_out"))
    order = {t: i for i, t in enumerate(names())}
    src = {s: i for i, s in enumerate(SOURCES)}
    m["_t"] = m["task"].map(order)
    m["_s"] = m["source"].map(lambda s: src.get(s, 99))
    return m.sort_values(["_t", "_s", "attack"], kind="stable").drop(columns=["_t", "_s"]).reset_index(drop=True)


def strongest_by_task(table: pd.DataFrame, *, source: str | None = None) -> pd.DataFrame:
    """Per task (and source): the attack with the smallest p-value, and the learned attacker's row."""
    out = []
    t = table if source is None else table[table["source"] == source]
    for (task, src), g in t.groupby(["task", "source"], sort=False):
        best = g.sort_values(["p_value", "accuracy"], ascending=[True, False], kind="stable").iloc[0]
        lb = g[g["attack"] == "learned_blind"]
        out.append({"task": task, "source": src, "n_rows": int(best["n_rows"]), "strongest": best["attack"],
                    "accuracy": best["accuracy"], "hits": int(best["hits"]), "picked": int(best["picked"]),
                    "p_value": best["p_value"], "significant": bool(best["significant"]),
                    "learned_accuracy": float(lb["accuracy"].iloc[0]) if len(lb) else float("nan"),
                    "learned_p": float(lb["p_value"].iloc[0]) if len(lb) else float("nan")})
    df = pd.DataFrame(out)
    order = {t: i for i, t in enumerate(names())}
    srcs = {s: i for i, s in enumerate(SOURCES)}
    df["_t"] = df["task"].map(order)
    df["_s"] = df["source"].map(lambda s: srcs.get(s, 99))
    return df.sort_values(["_t", "_s"]).drop(columns=["_t", "_s"]).reset_index(drop=True)


def value_reuse(records: list[dict], *, min_answers: int = 3) -> pd.DataFrame:
    """Candidate strings that are the answer in at least ``min_answers`` rows of a (task, source):
    how often they are the answer where they appear (1/5 is what the options can reach at best;
    a value that is the answer in more than a fifth of its group cannot get there)."""
    ans: Counter = Counter()
    app: Counter = Counter()
    n_group: Counter = Counter()
    for r in records:
        g = (r["Task"], r["Source"])
        n_group[g] += 1
        for L, s in r["Candidates"].items():
            app[(g, s)] += 1
            if L == r["Answer"]:
                ans[(g, s)] += 1
    from ..options.attacks import binom_p

    out = []
    for (g, s), n in ans.items():
        if n < min_answers:
            continue
        out.append({"task": g[0], "source": g[1], "value": s, "answer_rows": n, "appears_in": app[(g, s)],
                    "answer_share": n / app[(g, s)], "share_of_group": n / n_group[g],
                    "p_value": binom_p(n, app[(g, s)])})
    df = pd.DataFrame(out, columns=["task", "source", "value", "answer_rows", "appears_in", "answer_share",
                                    "share_of_group", "p_value"])
    return df.sort_values(["answer_share", "answer_rows"], ascending=False).reset_index(drop=True)


def label_balance(records: list[dict], task: str = "Spatial Relation") -> pd.DataFrame:
    """Answer label counts per source of a categorical task (what a label prior exploits)."""
    c = Counter((r["Source"], r["Answer Detail"]) for r in records if r["Task"] == task)
    df = pd.DataFrame([{"source": s, "label": lab, "rows": n} for (s, lab), n in sorted(c.items())])
    if len(df):
        df["share"] = df["rows"] / df.groupby("source")["rows"].transform("sum")
    return df


def write_audit(before: pd.DataFrame, after: pd.DataFrame, out_dir: str | os.PathLike, *, alpha: float
                ) -> dict:
    """Write the attack tables of input and output, the side-by-side table and the strongest
    attack per task and source (markdown, CSV and LaTeX each); returns the tables."""
    from ..io.tables import write_table

    out = paths.resolve(out_dir)
    sb, sa = strongest_by_task(before), strongest_by_task(after)
    both = sb.merge(sa, on=["task", "source", "n_rows"], suffixes=("_in", "_out"))
    tables = {"attacks_input": before, "attacks_output": after, "attacks_side_by_side": side_by_side(before, after),
              "strongest_by_task": both}
    captions = {"attacks_input": f"Option-only attacks on the input release (Holm alpha={alpha})",
                "attacks_output": f"Option-only attacks on the rebuilt release (Holm alpha={alpha})",
                "attacks_side_by_side": "Every attack, input beside output",
                "strongest_by_task": "Strongest attack per task and source (smallest p-value), input and output"}
    for name, t in tables.items():
        write_table(t, out / name, caption=captions[name])
    return tables


def before_after_figure(strongest: pd.DataFrame, path: str | os.PathLike) -> Path:
    """Accuracy of the strongest attack and of the learned attacker per task and source, input
    beside output, with 95% intervals of the strongest attack's accuracy (chance dashed)."""
    import matplotlib.pyplot as plt

    from ..options.power import clopper_pearson

    t = strongest.reset_index(drop=True)
    labels = [f"{a} | {b}" for a, b in zip(t["task"], t["source"])]
    y = np.arange(len(t))
    fig, ax = plt.subplots(figsize=(7.5, 0.9 + 0.22 * len(t)))
    for col, off, color, name in (("in", -0.18, "#c0392b", "input"), ("out", 0.18, "#2c7fb8", "output")):
        acc, hits, n = t[f"accuracy_{col}"], t[f"hits_{col}"], t[f"picked_{col}"]
        lo, hi = clopper_pearson(hits, n)
        ax.errorbar(acc, y + off, xerr=[acc - lo, hi - acc], fmt="o", ms=3, color=color, elinewidth=0.7,
                    label=f"strongest attack, {name}")
        ax.scatter(t[f"learned_accuracy_{col}"], y + off, marker="x", s=14, color=color,
                   label=f"learned attacker, {name}")
    ax.axvline(0.2, color="k", lw=0.8, ls="--")
    ax.set_yticks(y, labels, fontsize=6)
    ax.invert_yaxis()
    ax.set_xlim(0, 1)
    ax.set_xlabel("accuracy without video; dashed: chance 1/5")
    ax.legend(fontsize=6, loc="lower right")
    return save_figure(fig, path)


def preserved_fields_check(before: list[dict], after: list[dict]) -> list[str]:
    """Differences other than the rebuilt Candidates/Answer (empty when everything is preserved)."""
    problems = []
    if len(before) != len(after):
        return [f"row count {len(before)} != {len(after)}"]
    for i, (a, b) in enumerate(zip(before, after)):
        if list(a) != list(b):
            problems.append(f"row {i}: field order/names differ")
        for k in a:
            if k in ("Candidates", "Answer"):
                continue
            if json.dumps(a[k], ensure_ascii=False) != json.dumps(b.get(k), ensure_ascii=False):
                problems.append(f"row {i}: {k} changed")
        if b["Candidates"].get(b["Answer"]) != a["Answer Detail"]:
            problems.append(f"row {i}: keyed candidate is not the Answer Detail string")
    return problems


__all__ = ["DEFAULT_RELEASE", "ReoptionError", "ReoptionResult", "attack_tables", "before_after_figure",
           "check_input", "filter_summary", "filter_table", "label_balance",
           "preserved_fields_check", "reoption_records", "reoption_release", "side_by_side",
           "strongest_by_task", "value_reuse", "write_audit"]
