"""The self-test on the mini-world: what the audit found against what the generator injected.

This is the only module outside ``synth`` and the tests that reads the generator's manifest, and
only to score the audit after the fact; nothing on the audit path imports it.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from .. import values as V
from ..errors import InputError


def load_manifest(path: str | Path) -> pd.DataFrame:
    path = Path(path)
    rows = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    return pd.DataFrame(rows)


def defect_recall(prov: pd.DataFrame, manifest: pd.DataFrame) -> pd.DataFrame:
    """Per defect class: injected, detected, true positives, recall and precision (rows joined by
    legacy row index)."""
    found = {int(r.row): set(json.loads(r.defects or "[]")) for r in prov.itertuples()}
    truth = {int(r["row"]): set(r.get("defects") or []) for r in manifest.to_dict("records")}
    codes = sorted(set().union(*truth.values(), *found.values()))
    out = []
    for c in codes:
        t = {i for i, s in truth.items() if c in s}
        f = {i for i, s in found.items() if c in s}
        tp = len(t & f)
        out.append({"defect": c, "injected": len(t), "detected": len(f), "true positives": tp,
                    "recall": tp / len(t) if t else float("nan"),
                    "precision": tp / len(f) if f else float("nan")})
    return pd.DataFrame(out)


def verdict_agreement(prov: pd.DataFrame, manifest: pd.DataFrame) -> pd.DataFrame:
    """Confusion of the expected verdict (manifest) against the audit's verdict."""
    m = manifest.set_index("row")["expected_verdict"]
    p = prov.set_index("row")["verdict"]
    df = pd.DataFrame({"expected": m, "audit": p.reindex(m.index)})
    return df.pivot_table(index="expected", columns="audit", aggfunc="size", fill_value=0).reset_index()


def value_agreement(release_rows: list[dict], prov: pd.DataFrame, manifest: pd.DataFrame) -> pd.DataFrame:
    """Per task: accepted rows whose Answer Detail equals the manifest's true answer within rounding."""
    truth = manifest.set_index("row")
    key_row = dict(zip(prov["key"], prov["row"]))
    out = {}
    for r in release_rows:
        row = key_row.get(r["Legacy Row Key"])
        t = truth.loc[row, "true_answer"] if row in truth.index else None
        o = out.setdefault(r["Task"], {"task": r["Task"], "accepted": 0, "with truth": 0, "equal": 0})
        o["accepted"] += 1
        if t is None or (isinstance(t, float) and pd.isna(t)):
            continue
        o["with truth"] += 1
        try:
            if V.agree(V.parse(r["Answer Detail"]), V.parse(t)):
                o["equal"] += 1
        except InputError:
            pass
    return pd.DataFrame(list(out.values()))
