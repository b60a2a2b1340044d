"""The report's statistics tables, computed from a release's provenance (and the legacy benchmark).

Every function returns a DataFrame; ``notebooks/99_release_report.ipynb`` writes them with
:func:`resti_lib.io.tables.write_table` (markdown, CSV, LaTeX).
"""

from __future__ import annotations

import json
from collections import Counter

import pandas as pd

from .. import SOURCES
from ..defects import DEFECTS, REPORT_CATEGORIES

# the power of the attack tests lives beside the attack table (the options layer cannot import this one)
from ..options.power import (  # noqa: F401
    POWER,
    UNDERPOWERED_AT,
    attack_power,
    critical_hits,
    min_detectable_accuracy,
)
from ..tasks import interface, names

VERDICT_ORDER = ("retained", "corrected", "re-contracted", "excluded")
#: the defect tables' columns: the registry's codes of each layer, in its order (one list, in defects.py)
QUESTION_DEFECTS, ANSWER_DEFECTS, SOURCE_DEFECTS = (tuple(c for c, d in DEFECTS.items() if d.layer == layer)
                                                    for layer in ("question", "answer", "source"))


def _task_index(tasks) -> list[str]:
    order = names()
    return [t for t in order if t in set(tasks)] + sorted(set(tasks) - set(order))


def _defects(prov: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for r in prov.itertuples():
        for d in json.loads(r.defects or "[]"):
            rows.append({"task": r.task, "source": r.source, "defect": d})
    return pd.DataFrame(rows, columns=["task", "source", "defect"])


def coverage_table(prov: pd.DataFrame) -> pd.DataFrame:
    """Accepted and excluded by task, with the per-source split (the report's coverage table)."""
    out = []
    for task in _task_index(prov["task"]):
        g = prov[prov["task"] == task]
        row = {"task": task}
        for s in SOURCES:
            gs = g[g["source"] == s]
            if len(gs):
                row[f"{s} accepted"] = int((gs["verdict"] != "excluded").sum())
                row[f"{s} excluded"] = int((gs["verdict"] == "excluded").sum())
        row["accepted"] = int((g["verdict"] != "excluded").sum())
        row["excluded"] = int((g["verdict"] == "excluded").sum())
        row["total"] = len(g)
        out.append(row)
    df = pd.DataFrame(out).fillna(0)
    total = {"task": "Total", **{c: int(df[c].sum()) for c in df.columns if c != "task"}}
    df = pd.concat([df, pd.DataFrame([total])], ignore_index=True)
    num = [c for c in df.columns if c != "task"]
    df[num] = df[num].astype(int)
    return df


def source_table(prov: pd.DataFrame) -> pd.DataFrame:
    out = []
    for s in [x for x in SOURCES if x in set(prov["source"])]:
        g = prov[prov["source"] == s]
        out.append({"source": s, "accepted": int((g["verdict"] != "excluded").sum()),
                    "excluded": int((g["verdict"] == "excluded").sum()), "total": len(g)})
    return pd.DataFrame(out)


def verdict_table(prov: pd.DataFrame) -> pd.DataFrame:
    t = prov.pivot_table(index="task", columns="verdict", aggfunc="size", fill_value=0)
    t = t.reindex(columns=[v for v in VERDICT_ORDER], fill_value=0)
    t = t.reindex(_task_index(prov["task"]))
    t.loc["Total"] = t.sum()
    return t.reset_index().rename(columns={"index": "task"})


def _defect_counts(prov: pd.DataFrame, codes) -> pd.DataFrame:
    d = _defects(prov)
    d = d[d["defect"].isin(codes)]
    t = d.pivot_table(index="task", columns="defect", aggfunc="size", fill_value=0) if len(d) else \
        pd.DataFrame(index=pd.Index([], name="task"))
    t = t.reindex(columns=[c for c in codes if c in set(d["defect"])], fill_value=0)
    t = t.reindex([x for x in _task_index(prov["task"])], fill_value=0)
    t.loc["Total"] = t.sum()
    return t.reset_index().rename(columns={"index": "task"})


def question_defect_table(prov: pd.DataFrame) -> pd.DataFrame:
    """Rows per task with each question-layer defect (no pose time, ambiguous subject, unnamed frame...)."""
    return _defect_counts(prov, QUESTION_DEFECTS)


def answer_defect_table(prov: pd.DataFrame) -> pd.DataFrame:
    """Rows per task with each answer-layer defect (key–detail mismatch, exact/numeric duplicates...)."""
    return _defect_counts(prov, ANSWER_DEFECTS)


def source_defect_table(prov: pd.DataFrame) -> pd.DataFrame:
    return _defect_counts(prov, SOURCE_DEFECTS)


def defect_category_table(prov: pd.DataFrame, categories=REPORT_CATEGORIES) -> pd.DataFrame:
    """Defect reports in the report's six construction-defect categories (one row can report
    several); share of the sum of these reports, not of the questions."""
    d = _defects(prov)
    c = Counter(DEFECTS[x].category for x in d["defect"] if x in DEFECTS)
    c = Counter({k: c.get(k, 0) for k in categories})
    total = sum(c.values())
    rows = [{"category": k, "reports": n, "share": n / total if total else 0.0} for k, n in c.most_common()]
    return pd.DataFrame(rows, columns=["category", "reports", "share"])


def exclusion_reason_table(excluded: list[dict]) -> pd.DataFrame:
    c = Counter((r["task"], code) for r in excluded for code in r["reason_codes"])
    rows = [{"task": t, "reason": code, "rows": n} for (t, code), n in c.items()]
    df = pd.DataFrame(rows, columns=["task", "reason", "rows"])
    order = {t: i for i, t in enumerate(names())}
    return df.sort_values(["task", "rows"], key=lambda s: s.map(order) if s.name == "task" else -s,
                          kind="stable").reset_index(drop=True)


def strongest_attacks(table: pd.DataFrame, label: str) -> pd.DataFrame:
    """Per task: the strongest attack (pooled over sources) and the number of Holm-significant rows."""
    out = []
    for task in _task_index(table["task"]):
        t = table[(table["task"] == task) & (table["source"] == "ALL") & (table["picked"] > 0)]
        full = t[t["coverage"] >= 0.999]
        best = (full if len(full) else t).sort_values(["accuracy", "hits"], ascending=False, kind="stable")
        if best.empty:
            continue
        b = best.iloc[0]
        out.append({"task": task, f"{label} strongest": b["attack"],
                    f"{label} accuracy": f"{b['hits']:g}/{b['picked']} = {b['accuracy']:.1%}",
                    f"{label} significant rows": int(table[(table["task"] == task)]["significant"].sum())})
    return pd.DataFrame(out)


def attacks_before_after(before: pd.DataFrame, after: pd.DataFrame) -> pd.DataFrame:
    a, b = strongest_attacks(before, "before"), strongest_attacks(after, "after")
    return a.merge(b, on="task", how="outer")


def reference_comparison(ours: dict, reference: dict) -> pd.DataFrame:
    """Our release's counts beside a reference release's (validation objects of ``resti verify``)."""
    rows = []
    for task in names():
        rows.append({"task": task,
                     "ours accepted": ours["by_task"].get(task, 0),
                     "ours excluded": ours["excluded_by_task"].get(task, 0),
                     "reference accepted": reference["by_task"].get(task, 0),
                     "reference excluded": reference["excluded_by_task"].get(task, 0)})
    rows.append({"task": "Total", "ours accepted": ours["accepted_rows"], "ours excluded": ours["excluded_rows"],
                 "reference accepted": reference["accepted_rows"],
                 "reference excluded": reference["excluded_rows"]})
    return pd.DataFrame(rows)


# ------------------------------------------------------------------ tables of the report's text
# (key–detail mismatch breakdown, exclusions by class, the pooled legacy attack, a release's
# per-source counts)

KEY_DETAIL_CLASSES = (
    ("structured", "structured record (Grounding box or Pose matrix) disagreeing"),
    ("scalar", "scalar disagreeing beyond rounding"),
    ("other", "label or trajectory disagreeing"),
    ("format", "incompatible format (unreadable, other kind or unit dimension)"),
    ("rounding", "same value, coarser rounding or other spelling (a mismatch for the ReSTI report, not for us)"),
)


def key_detail_class(keyed: str, detail: str) -> str:
    """Why a keyed candidate differs from the Answer Detail (see :data:`KEY_DETAIL_CLASSES`)."""
    from .. import values as V
    from ..errors import InputError

    try:
        k, d = V.parse(keyed), V.parse(detail)
    except InputError:
        return "format"
    if k.kind != d.kind or (isinstance(k, V.Scalar) and k.dimension != d.dimension):
        return "format"
    if V.agree(k, d):
        return "rounding"
    if k.kind in ("box", "pose"):
        return "structured"
    return "scalar" if k.kind == "scalar" else "other"


KEY_DETAIL_PAPER = "mismatches, the ReSTI report's definition: the keyed candidate's text is not the Answer Detail's"
KEY_DETAIL_OURS = ("mismatches, our definition (the key_detail_mismatch defect): the values disagree beyond "
                   "rounding or cannot be compared")


def key_detail_breakdown(legacy: pd.DataFrame) -> pd.DataFrame:
    """Key–detail mismatches of the legacy rows under both definitions, the ReSTI report's first.

    The report counts every row whose keyed candidate's text differs from the Answer Detail's (its
    1,014 on STI-Bench include coarser rounding); we count a ``key_detail_mismatch`` defect only when
    the values disagree beyond rounding or cannot be compared. Rows: the report's total, its causes
    (structured records, scalars beyond rounding, other kinds, incompatible formats, the same value
    printed coarser or otherwise) with the definitions that count each, then our total. ``share``: of
    the report's total."""
    counts: dict[str, Counter] = {c: Counter() for c, _ in KEY_DETAIL_CLASSES}
    for r in legacy.to_dict("records"):
        cands = r.get("Candidates") if isinstance(r.get("Candidates"), dict) else {}
        keyed, detail = cands.get(r.get("Answer")), r.get("Answer Detail")
        if keyed is None or detail is None or keyed == detail:
            continue
        counts[key_detail_class(str(keyed), str(detail))][str(r.get("Task"))] += 1

    def by_task(c: Counter) -> str:
        return ", ".join(f"{t} {k}" for t, k in sorted(c.items(), key=lambda kv: (-kv[1], kv[0])))

    total = sum(sum(c.values()) for c in counts.values())
    ours = Counter()
    for code, _ in KEY_DETAIL_CLASSES:
        if code != "rounding":
            ours.update(counts[code])
    rows = [{"cause": KEY_DETAIL_PAPER, "rows": total, "share": 1.0 if total else 0.0,
             "ReSTI report's definition": True, "ours": None, "by task": by_task(sum(counts.values(), Counter()))}]
    for code, label in KEY_DETAIL_CLASSES:
        n = sum(counts[code].values())
        rows.append({"cause": label, "rows": n, "share": n / total if total else 0.0,
                     "ReSTI report's definition": True, "ours": code != "rounding", "by task": by_task(counts[code])})
    n_ours = sum(ours.values())
    rows.append({"cause": KEY_DETAIL_OURS, "rows": n_ours, "share": n_ours / total if total else 0.0,
                 "ReSTI report's definition": None, "ours": True, "by task": by_task(ours)})
    return pd.DataFrame(rows, columns=["cause", "rows", "share", "ReSTI report's definition", "ours", "by task"])


# Exclusion reasons by class (the report: of the exclusions, some "concern ambiguous or unmatched
# referents" -- a better description could recover the row -- and the others "defective task
# statements"). One rule for our exclusions and for ReSTI v5's verdicts (report/v5_exclusions.yaml maps
# each v5 verdict to one of these codes and the same class; a test checks that they agree):
# recoverable when the referent is ambiguous or unmatched, structural when the statement is defective
# (a group named as one object, a referent not visible at the asked time, a degenerate interval or
# premise, no dominant relation, an undefined dimension, a pose the source does not have, a row that
# cannot be read as a question of its task). A copy of another row and a row without valid options are
# neither (class "other").
RECOVERABLE_REASONS = frozenset({"ambiguous_instance", "no_source_instance", "ambiguous_subject"})
STRUCTURAL_REASONS = frozenset({"grouped_referent", "not_visible_at_frame", "zero_length_interval",
                                "premise_equals_target", "no_dominant_relation", "undefined_dimension",
                                "invalid_pose_at_time", "time_past_video_end", "malformed_row",
                                "unsupported_question"})
EXCLUSION_RULE = ("recoverable: any reason is an ambiguous or unmatched referent (" +
                  ", ".join(sorted(RECOVERABLE_REASONS)) + "); structural: every reason is a defective "
                  "statement (" + ", ".join(sorted(STRUCTURAL_REASONS)) + "); other: the rest")


def exclusion_class(codes) -> str:
    """``recoverable`` when any reason is an ambiguous or unmatched referent, ``structural`` when
    every reason is a defective statement, ``other`` for codes outside both lists."""
    codes = set(codes)
    if codes & RECOVERABLE_REASONS:
        return "recoverable"
    if codes and codes <= STRUCTURAL_REASONS:
        return "structural"
    return "other"


def exclusion_class_table(excluded: list[dict]) -> pd.DataFrame:
    """Excluded rows by class and task: recoverable (ambiguous or unmatched referents) against
    structural (defective task statements), with the reason codes of each class."""
    classes = ("recoverable", "structural", "other")
    per: dict[str, Counter] = {c: Counter() for c in classes}
    reasons: dict[str, Counter] = {c: Counter() for c in classes}
    for r in excluded:
        codes = list(r.get("reason_codes") or [])
        c = exclusion_class(codes)
        per[c][str(r.get("task"))] += 1
        reasons[c].update(codes)
    total = sum(sum(c.values()) for c in per.values())
    rows = []
    for c in classes:
        n = sum(per[c].values())
        if c == "other" and n == 0:
            continue
        rows.append({"class": c, "rows": n, "share": n / total if total else 0.0,
                     "reasons": ", ".join(f"{k} {v}" for k, v in sorted(reasons[c].items(),
                                                                          key=lambda kv: (-kv[1], kv[0]))),
                     "by task": ", ".join(f"{t} {k}" for t, k in sorted(per[c].items(),
                                                                          key=lambda kv: (-kv[1], kv[0])))})
    return pd.DataFrame(rows, columns=["class", "rows", "share", "reasons", "by task"])


SCALAR_POOL = "all scalar rows"


def legacy_attack_table(legacy, *, out_dir, figure, alpha: float = 0.05) -> pd.DataFrame:
    """The full blind suite on the legacy benchmark (:func:`resti_lib.release.audit.audit_legacy`, tables
    in ``out_dir``) and its accuracy figure at ``figure``, made together so that a cache of the table
    (:func:`resti_lib.run.stages.memo_frame`, with ``figure`` among its products) keeps the figure too."""
    from ..release.audit import audit_legacy
    from .plots import attack_accuracy

    table = audit_legacy(legacy, out_dir=out_dir, alpha=alpha, families="all", learned=True)
    attack_accuracy(table, figure, title="Blind attacks on the legacy options", alpha_label=f"alpha={alpha}")
    return table


def pooled_scalar_attacks(legacy: pd.DataFrame, *, alpha: float = 0.05) -> pd.DataFrame:
    """Option-only attacks pooled over every legacy row whose five candidates are scalars (all tasks
    together, as the report's "median pick on the legacy scalar rows"), best first."""
    from .. import values as V
    from ..errors import InputError
    from ..options.attacks import attack_table

    rows = []
    for r in legacy.to_dict("records"):
        cands = r.get("Candidates")
        if not isinstance(cands, dict) or len(cands) != 5:
            continue
        try:
            if not all(isinstance(V.parse(s), V.Scalar) for s in cands.values()):
                continue
        except InputError:
            continue
        rows.append({**r, "Task": SCALAR_POOL})
    if not rows:
        return pd.DataFrame(columns=["attack", "rows", "picked", "hits", "accuracy", "p_value", "significant"])
    t = attack_table(rows, iface=interface(), alpha=alpha)
    t = t[(t["source"] == "ALL") & (t["picked"] > 0)]
    t = t.sort_values(["accuracy", "hits"], ascending=False, kind="stable")
    return (t.rename(columns={"n_rows": "rows"})[["attack", "rows", "picked", "hits", "accuracy", "p_value",
                                                   "significant"]].reset_index(drop=True))


def pooled_before_after(before: pd.DataFrame, after: pd.DataFrame) -> pd.DataFrame:
    """The pooled scalar attacks (:func:`pooled_scalar_attacks`) of the legacy rows (before) beside the
    same attacks on the release's rows (after), in the order of the legacy table."""
    cols = ["rows", "picked", "hits", "accuracy", "significant"]
    b = before.set_index("attack")[cols] if len(before) else pd.DataFrame(columns=cols)
    a = after.set_index("attack")[cols] if len(after) else pd.DataFrame(columns=cols)
    m = b.add_suffix(" before").join(a.add_suffix(" after"), how="outer")
    order = list(b.index) + [x for x in a.index if x not in b.index]
    return m.reindex(order).reset_index().rename(columns={"index": "attack"})


def release_coverage(accepted: pd.DataFrame, excluded: list[dict]) -> pd.DataFrame:
    """:func:`coverage_table` of any release (e.g. the reference one): accepted and excluded rows
    per task and source."""
    recs = [{"task": t, "source": s, "verdict": "accepted"}
            for t, s in zip(accepted.get("Task", []), accepted.get("Source", []))]
    recs += [{"task": r.get("task"), "source": r.get("source"), "verdict": "excluded"} for r in excluded]
    return coverage_table(pd.DataFrame(recs, columns=["task", "source", "verdict"]))


def significant_leaks(table: pd.DataFrame) -> pd.DataFrame:
    """Holm-significant rows of an attack table, strongest first: task, source, attack, hits/picked,
    accuracy, p-value."""
    if table is None or len(table) == 0 or "significant" not in table:
        return pd.DataFrame(columns=["task", "source", "attack", "hits", "picked", "accuracy", "p_value"])
    sig = table[table["significant"].astype(bool)]
    sig = sig.sort_values(["accuracy", "hits"], ascending=False, kind="stable")
    return sig[["task", "source", "attack", "hits", "picked", "accuracy", "p_value"]].reset_index(drop=True)
