"""The answer-interface audit of one release: structural checks + option-only attacks, written out.

Used by ``notebooks/00_answer_interface.ipynb`` and ``resti attack``/``resti verify``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from .io.benchmark import atomic_write_bytes, load_release
from .options.attacks import ATTACKS, attack_table, strongest
from .tables import write_table
from .verify import verify_release

# Reference figures of the report for the rebuilt v5 options (section "Repair: regenerated
# Orientation choices" and the Grounding repair): value, hits, rows.
PAPER_REFERENCE = {
    ("Ego-Centric Orientation", "median"): (37, 185),
    ("Ego-Centric Orientation", "best fixed signed-value rank"): (38, 185),
    ("3D Video Grounding", "strongest full-coverage attack"): (71, 314),
}
RANK_ATTACKS = ("min", "rank_2", "median", "rank_4", "max")


@dataclass
class AuditResult:
    label: str
    validation: dict
    attacks: pd.DataFrame
    files: list[Path]


def select_attacks(spec) -> list[str]:
    """``"all"`` or a list of attack names (unknown names raise)."""
    if spec in (None, "all"):
        return list(ATTACKS)
    names = [spec] if isinstance(spec, str) else list(spec)
    unknown = [n for n in names if n not in ATTACKS]
    if unknown:
        raise ValueError(f"unknown attack(s) {unknown}; known: {sorted(ATTACKS)}")
    return names


def audit_release(release: str | Path, *, label: str, out_dir: str | Path, alpha: float = 0.05,
                  attacks="all") -> AuditResult:
    """Verify and attack one release; write ``validation_<label>.json`` and ``attacks_<label>.*``."""
    out_dir = Path(out_dir)
    rel = load_release(release, strict=False)
    validation = verify_release(rel)
    table = attack_table(rel.accepted.to_dict("records"), alpha=alpha, attacks=select_attacks(attacks))
    files = [out_dir / f"validation_{label}.json"]
    atomic_write_bytes(files[0], (json.dumps(validation, indent=2, ensure_ascii=False) + "\n").encode())
    files += write_table(table, out_dir / f"attacks_{label}",
                         caption=f"Option-only attacks on {label} (Holm alpha={alpha})")
    return AuditResult(label, validation, table, files)


def paper_comparison(table: pd.DataFrame) -> pd.DataFrame:
    """Our figures beside the report's for the rebuilt ReSTI v5 options."""
    rows = []
    o = table[(table["task"] == "Ego-Centric Orientation") & (table["source"] == "ALL")]
    if not o.empty:
        med = o[o["attack"] == "median"].iloc[0]
        ranks = o[o["attack"].isin(RANK_ATTACKS)].sort_values("hits", ascending=False, kind="stable").iloc[0]
        rows.append(("Ego-Centric Orientation", "median", int(med["hits"]), int(med["picked"])))
        rows.append(("Ego-Centric Orientation", "best fixed signed-value rank",
                     int(ranks["hits"]), int(ranks["picked"]), ranks["attack"]))
    g = strongest(table, "3D Video Grounding")
    if g is not None:
        rows.append(("3D Video Grounding", "strongest full-coverage attack", int(g["hits"]), int(g["picked"]),
                     g["attack"]))
    out = []
    for r in rows:
        task, what, hits, n = r[:4]
        ph, pn = PAPER_REFERENCE[(task, what)]
        out.append({"task": task, "figure": what, "attack": r[4] if len(r) > 4 else what,
                    "ours": f"{hits}/{n} = {hits / n:.2%}", "report": f"{ph}/{pn} = {ph / pn:.2%}",
                    "same": (hits, n) == (ph, pn)})
    return pd.DataFrame(out)


def audit_legacy(legacy: str | Path, *, out_dir: str | Path, alpha: float = 0.05, attacks="all",
                 learned=False, groups: dict | None = None) -> pd.DataFrame:
    """Attacks on a legacy ``qa.parquet`` ("before repair"): a hit is a pick of the keyed letter.
    ``learned=True`` (or a ``LearnedConfig``) adds the learned blind attacker to the family,
    cross-validated by ``groups``
    (Legacy Row Key -> group, e.g. the source sequence; default the video)."""
    from .io.benchmark import load_legacy
    from .options.learned import attack_table_with_learned

    df, _ = load_legacy(legacy, strict=False)
    table = attack_table_with_learned(df.to_dict("records"), alpha=alpha, attacks=select_attacks(attacks),
                                      learned=None if learned is True else learned, groups=groups)
    write_table(table, Path(out_dir) / "attacks_legacy", caption=f"Option-only attacks on the legacy "
                f"benchmark (Holm alpha={alpha})")
    return table
