"""Exclusions explained: the glossary of a release's exclusion codes and its recoverable / structural split.

A ReSTI v5 exclusion carries ``reason_codes`` (engineering statuses of its pipeline) and, for most rows,
a ``verification_verdict`` (what a check of the source found). ``v5_exclusions.yaml`` (beside this
module) says what every code means, our nearest reason code and, for verdicts, the class under one
rule: *recoverable* when the referent is ambiguous or unmatched, *structural* when the statement is
defective. Our own exclusions are classed by the same rule through their reason codes
(:func:`resti_lib.report.statistics.exclusion_class`).
"""

from __future__ import annotations

from collections import Counter
from functools import lru_cache
from pathlib import Path

import pandas as pd
import yaml

from ..defects import REASONS

GLOSSARY_FILE = Path(__file__).with_name("v5_exclusions.yaml")
CLASSES = ("recoverable", "structural")


@lru_cache(maxsize=1)
def glossary_spec() -> dict:
    """The parsed ``v5_exclusions.yaml``: ``rule``, ``unverified_class``, ``verdicts``, ``reason_codes``."""
    return yaml.safe_load(GLOSSARY_FILE.read_text(encoding="utf-8"))


def verdict_class(verdict: str | None) -> str:
    """The class of one v5 exclusion from its verification verdict (the rule of ``v5_exclusions.yaml``);
    a verdict the glossary does not know is ``unknown``."""
    spec = glossary_spec()
    if verdict is None:
        return spec["unverified_class"]
    entry = spec["verdicts"].get(verdict)
    return entry["class"] if entry else "unknown"


def exclusion_glossary(excluded: list[dict]) -> pd.DataFrame:
    """Every exclusion code of a release (verification verdicts first, then reason codes): rows
    carrying it, what it means, our nearest reason code (and its wording), and the class of a verdict.
    A code the glossary does not know is listed with ``meaning`` "(not in the glossary)"."""
    spec = glossary_spec()
    verdicts = Counter(r.get("verification_verdict") for r in excluded if r.get("verification_verdict"))
    reasons = Counter(c for r in excluded for c in (r.get("reason_codes") or []))
    out = []
    for kind, counts, table in (("verification verdict", verdicts, spec["verdicts"]),
                                ("reason code", reasons, spec["reason_codes"])):
        for code, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])):
            entry = table.get(code) or {}
            ours = entry.get("ours", "")
            out.append({"code": code, "kind": kind, "rows": n,
                        "meaning": entry.get("meaning", "(not in the glossary)"),
                        "ours": f"{ours}: {REASONS[ours]}" if ours in REASONS else ours,
                        "class": entry.get("class", "") if kind == "verification verdict" else ""})
    unverified = sum(1 for r in excluded if not r.get("verification_verdict"))
    if unverified:
        out.append({"code": "(no verification verdict)", "kind": "verification verdict", "rows": unverified,
                    "meaning": "first-round exclusions never verified against the source; their reason codes say why",
                    "ours": "", "class": spec["unverified_class"]})
    return pd.DataFrame(out, columns=["code", "kind", "rows", "meaning", "ours", "class"])


def exclusion_split(excluded: list[dict], *, paper: dict | None = None) -> pd.DataFrame:
    """The recoverable / structural split of a release's exclusions by its verification verdicts
    (:func:`verdict_class`), with the verdicts of each class, the rule, and (``paper``:
    ``{class: rows}``) the figure the ReSTI report gives."""
    per: dict[str, Counter] = {}
    for r in excluded:
        v = r.get("verification_verdict")
        per.setdefault(verdict_class(v), Counter())[v or "(no verification verdict)"] += 1
    total = sum(sum(c.values()) for c in per.values())
    rows = []
    for cls in [*CLASSES, *sorted(set(per) - set(CLASSES))]:
        c = per.get(cls, Counter())
        n = sum(c.values())
        row = {"class": cls, "rows": n, "share": n / total if total else 0.0}
        if paper is not None:
            row["ReSTI report"] = paper.get(cls)
        row["verdicts"] = ", ".join(f"{k} {v}" for k, v in sorted(c.items(), key=lambda kv: (-kv[1], kv[0])))
        rows.append(row)
    return pd.DataFrame(rows)
