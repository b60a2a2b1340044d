"""The answer-interface audit of one release: structural checks + the blind attack suite, written out.

Used by ``notebooks/00_answer_interface.ipynb`` and ``resti attack``/``resti verify``. The attack table
(:func:`resti_lib.options.attacks.attack_table`) has one row per (attack, task, source); its headline
(:func:`resti_lib.options.attacks.headline`) one row per task/source cell, significant cells first, with
the power of the test where nothing is significant.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from ..io.benchmark import load_release
from ..io.files import atomic_write_bytes
from ..io.tables import write_table
from ..options.attacks import attack_table, headline, select, strongest
from ..tasks import interface
from ..tasks import names as task_names
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

    @property
    def headline(self) -> pd.DataFrame:
        """One row per task/source cell, significant cells first (see :func:`attacks.headline`)."""
        return headline(self.attacks)


def select_attacks(spec, families="all", *, fast: bool = False) -> list[str]:
    """``"all"`` or a list of attack names, within ``families`` (unknown names raise ``ValueError``)."""
    return select(families, None if spec in (None, "all") else spec, fast=fast)


def format_headline(head: pd.DataFrame, *, alpha: float, tests: int) -> str:
    """The headline as markdown: a sentence with the count of significant cells, then one table row per
    task/source cell (significant cells first) with the strongest attack, its accuracy and p-values,
    and the smallest blind accuracy the test detects there (80% power)."""
    n_sig = int(head["significant"].sum()) if len(head) else 0
    lines = [(f"**{n_sig} of {len(head)} task/source cells have a Holm-significant blind attack** "
              f"(alpha {alpha}, {tests} tests; `min_detectable`: smallest blind accuracy detected with 80% "
              "power at the cell's n; underpowered: cannot detect 35%).")]
    if len(head):
        shown = head[["task", "source", "n_rows", "significant", "attack", "family", "accuracy", "p_value", "p_holm",
                      "significant_attacks", "families", "min_detectable", "underpowered"]].copy()
        shown["accuracy"] = shown["accuracy"].map(lambda x: f"{x:.3f}")
        shown["min_detectable"] = shown["min_detectable"].map(lambda x: f"{x:.3f}")
        for c in ("p_value", "p_holm"):
            shown[c] = shown[c].map(lambda x: f"{x:.3g}")
        lines += ["", shown.to_markdown(index=False)]
    return "\n".join(lines)


def audit_release(release: str | Path, *, label: str, out_dir: str | Path, alpha: float = 0.05,
                  attacks="all", families="all", fast: bool = False, learned=None,
                  groups: dict | None = None) -> AuditResult:
    """Verify and attack one release with the blind suite (``families``, ``fast``: see
    :func:`attacks.attack_table`); write ``validation_<label>.json``, ``attacks_<label>.*`` and
    ``attacks_<label>_headline.*``."""
    out_dir = Path(out_dir)
    rel = load_release(release, strict=False, known_tasks=task_names())
    validation = verify_release(rel)
    names = select_attacks(attacks, families, fast=fast or learned is False)
    table = attack_table(rel.accepted.to_dict("records"), iface=interface(), families="all", attacks=names, alpha=alpha,
                         learned=learned, groups=groups, progress=True)
    files = [out_dir / f"validation_{label}.json"]
    atomic_write_bytes(files[0], (json.dumps(validation, indent=2, ensure_ascii=False) + "\n").encode())
    files += write_table(table, out_dir / f"attacks_{label}",
                         caption=f"Blind attacks on {label} (Holm alpha={alpha} over {len(table)} rows)")
    files += write_table(headline(table), out_dir / f"attacks_{label}_headline",
                         caption=f"Blind attacks on {label}: strongest attack per task/source cell, significant "
                         "cells first, with the smallest blind accuracy detectable at 80% power")
    return AuditResult(label, validation, table, files)


def paper_comparison(table: pd.DataFrame) -> pd.DataFrame:
    """Our figures beside the report's for the rebuilt ReSTI v5 options."""
    rows = []
    if "family" in table.columns:  # the report's figures are option-only attacks
        table = table[table["family"] == "option"]
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
                 learned=False, groups: dict | None = None, families=None) -> pd.DataFrame:
    """Attacks on a legacy ``qa.parquet`` ("before repair"): a hit is a pick of the keyed letter.
    ``learned=True`` (or a ``LearnedConfig``) adds the learned blind attacker to the family,
    cross-validated by ``groups`` (Legacy Row Key -> group; default the source sequence of the video).
    ``families`` None: the option-only rules (and the learned option-only attacker); ``"all"``: the
    full blind suite."""
    from ..io.benchmark import load_legacy
    from ..options.learned import attack_table_with_learned

    df, _ = load_legacy(legacy, strict=False, known_tasks=task_names())
    table = attack_table_with_learned(df.to_dict("records"), iface=interface(), alpha=alpha,
                                      attacks=None if attacks in (None, "all") else select_attacks(attacks),
                                      learned=None if learned is True else learned, groups=groups,
                                      families=families)
    write_table(table, Path(out_dir) / "attacks_legacy", caption=f"Blind attacks on the legacy "
                f"benchmark (Holm alpha={alpha})")
    return table
