"""The answer-interface audit of one release: structural checks + the blind attack suite, written out.

:func:`attack_release` is the one attack of a release folder: ``resti attack``, notebook 00 (its
headline and figure), notebook 99 (the table of our release) and the closing summary of ``resti run``
all run it, so they count the same tests on the same rows under one Holm family
(:data:`SUITE`: every family, the learned attackers with their default settings). The attack table
(:func:`resti_lib.options.attacks.attack_table`) has one row per (attack, task, source); its headline
(:func:`resti_lib.options.attacks.headline`) one row per task/source cell, significant cells first, with
the power of the test where nothing is significant. :func:`attack_counts` gives the numbers every
place prints, in one sentence.
"""

from __future__ import annotations

import json
import os
import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from .. import LETTERS, paths
from ..io.benchmark import Release, load_release
from ..io.files import atomic_write_bytes
from ..io.tables import write_table
from ..options.attacks import COLUMNS, FAMILIES, attack_table, headline, select
from ..options.structural import residual_ids
from ..tasks import interface
from ..tasks import names as task_names
from .verify import release_interface, verify_release

#: The suite every place runs on a release (``resti attack`` without options): every family, the
#: learned attackers with their default settings, Holm's correction at ``alpha`` over the whole table.
SUITE = {"families": "all", "fast": False, "attacks": "all", "alpha": 0.05, "rows": "all"}

#: Which rows ``resti attack`` scores: ``all``; ``subset``: the rows of the release's evaluation subset,
#: read on their own (what an evaluation on the subset shows a reader); ``residual``: the rows no named
#: structural leak touches, read with the whole file beside them
#: (:func:`resti_lib.options.structural.residual_ids`).
ROW_SCOPES = ("all", "subset", "residual")


@dataclass(frozen=True)
class AttackCounts:
    """What every place prints about one attack table."""

    tests: int               # rows of the table (attack x task x source, ALL included): the Holm family
    significant: int         # Holm-significant rows
    cells: int               # task/source cells (ALL pools a task's sources)
    significant_cells: int   # cells with at least one Holm-significant row

    def sentence(self, *, bold: bool = False) -> str:
        """``S of C task/source cells have a Holm-significant blind attack (s of T tests)``: the words
        ``resti attack``, the report and the run's summary print (``bold``: markdown bold on the cells)."""
        b = "**" if bold else ""
        return (f"{b}{self.significant_cells} of {self.cells} task/source cells have a Holm-significant blind "
                f"attack{b} ({self.significant} of {self.tests} tests)")


def _significant_mask(table: pd.DataFrame) -> pd.Series:
    """The ``significant`` column as booleans, from a table in memory or read back from its CSV."""
    return table["significant"].astype(str).str.lower() == "true"


def attack_counts(table: pd.DataFrame | None) -> AttackCounts:
    """Counts of an attack table (in memory or read from its CSV)."""
    if table is None or len(table) == 0:
        return AttackCounts(0, 0, 0, 0)
    sig = _significant_mask(table)
    cells = table[["task", "source"]].drop_duplicates()
    sig_cells = table.loc[sig, ["task", "source"]].drop_duplicates()
    return AttackCounts(len(table), int(sig.sum()), len(cells), len(sig_cells))


def attack_rows(rel: Release) -> tuple[list[dict], dict]:
    """The accepted rows an attack can read, and ``{row id: why}`` for the others (structurally bad:
    a schema problem, a candidate that does not parse, an answer that is not a letter, a value that
    is not finite or not physically possible)."""
    from ..options.checks import ROW_CHECKS, parse_row

    bad: dict = {}
    for p in rel.problems:
        if p.file is not None and rel.accepted_file is not None and p.file == str(rel.accepted_file):
            bad.setdefault(p.row, f"{p.field}: {p.message}")
    usable = []
    for i, r in enumerate(rel.accepted.to_dict("records")):
        rid = next((r[c] for c in ("ReSTI ID", "Legacy Row Key") if isinstance(r.get(c), str) and r[c].strip()), i)
        if rid in bad:
            continue
        pr = parse_row(r, rid)
        if pr.errors:
            bad[rid] = "; ".join(f"Candidates.{k}: {m}" for k, m in sorted(pr.errors.items()))
        elif not pr.complete:
            bad[rid] = f"Candidates: letters {sorted(pr.candidates)}, expected A-E"
        elif pr.answer not in LETTERS:
            bad[rid] = f"Answer: {pr.answer!r} is not a letter A-E"
        elif msg := ROW_CHECKS["finite_values"](pr) or ROW_CHECKS["value_ranges"](pr):
            bad[rid] = msg
        else:
            usable.append(r)
    return usable, bad


@dataclass
class AttackRun:
    """The blind attack suite on one release: the table, the rows left out and the suite that ran."""

    release: Release
    table: pd.DataFrame
    skipped: dict = field(default_factory=dict)   # row id -> why it could not be attacked
    suite: dict = field(default_factory=dict)     # families, fast, attacks, alpha

    @property
    def headline(self) -> pd.DataFrame:
        return headline(self.table)

    @property
    def counts(self) -> AttackCounts:
        return attack_counts(self.table)

    def command(self, path: str) -> str:
        """The ``resti attack`` command line that prints these counts for ``path``."""
        return suite_command(path, self.suite)


def suite_command(path: str, suite: dict) -> str:
    """``resti attack PATH`` with the options that differ from :data:`SUITE`."""
    args = ["resti", "attack", path]
    fams = suite.get("families", "all")
    if fams not in (None, "all"):
        args += ["--families", *([fams] if isinstance(fams, str) else list(fams))]
    atts = suite.get("attacks", "all")
    if atts not in (None, "all"):
        args += ["--attacks", *([atts] if isinstance(atts, str) else list(atts))]
    if suite.get("fast"):
        args.append("--fast")
    if float(suite.get("alpha", SUITE["alpha"])) != SUITE["alpha"]:
        args += ["--alpha", f"{suite['alpha']:g}"]
    if suite.get("rows", "all") != "all":
        args += ["--rows", suite["rows"]]
    return " ".join(shlex.quote(a) for a in args)


def attack_release(release: str | Path | Release, *, families="all", attacks="all", fast: bool = False,
                   alpha: float = SUITE["alpha"], progress: bool = False, rows: str = "all") -> AttackRun:
    """The blind attack suite on a release folder (or accepted-rows file, or a loaded release): the
    rows an attack can read (:func:`attack_rows`; the others are listed in ``skipped``), the answer
    interface the release records (:func:`resti_lib.release.verify.release_interface`), the
    ``families`` (or ``attacks``) of the suite with the learned attackers at their default settings
    unless ``fast``, and Holm's correction at ``alpha`` over every row of the table; ``rows`` (one of
    :data:`ROW_SCOPES`) names the rows scored. Unknown family or attack names, and a subset or
    residual scope without a readable ``evaluation_subset.json`` beside the rows, raise ``ValueError``."""
    if rows not in ROW_SCOPES:
        raise ValueError(f"rows {rows!r}: expected one of {', '.join(ROW_SCOPES)}")
    names = select(None if families in (None, "all") else families,
                   None if attacks in (None, "all", ["all"]) else attacks, fast=fast)
    rel = release if isinstance(release, Release) else load_release(release, strict=False, known_tasks=task_names())
    records, skipped = attack_rows(rel)
    iface = release_interface(rel)[0]
    evaluate = None
    if rows != "all":
        subset = _evaluation_subset(rel, rows)
        if rows == "subset":
            keep = {str(x) for x in subset["ids"]}
            records = [r for i, r in enumerate(records) if str(r.get("ReSTI ID") or i) in keep]
        else:
            evaluate = residual_ids(records, iface, subset)
    # ``names`` is already the choice (keyed families included when named), so every family is allowed here
    table = attack_table(records, iface=iface, families=list(FAMILIES), attacks=names, alpha=alpha, progress=progress,
                         evaluate=evaluate) \
        if records else pd.DataFrame(columns=COLUMNS)
    suite = {"families": families if families not in (None, ["all"]) else "all", "fast": bool(fast),
             "attacks": attacks if attacks not in (None, ["all"]) else "all", "alpha": alpha, "rows": rows}
    return AttackRun(rel, table, skipped, suite)


def _evaluation_subset(rel: Release, rows: str) -> dict:
    """The ``evaluation_subset.json`` beside a release's rows (``resti reoption`` writes it)."""
    path = Path(rel.accepted_file).parent / "evaluation_subset.json" if rel.accepted_file else None
    if path is None or not path.is_file():
        raise ValueError(f"rows {rows!r} needs the release's evaluation_subset.json ({path or 'no release folder'} "
                         "not found; resti reoption writes it)")
    try:
        subset = json.loads(path.read_text(encoding="utf-8"))
        ids, dropped = subset["ids"], subset["dropped"]
        if not isinstance(ids, list) or not all(isinstance(d, dict) and "id" in d and "reason" in d for d in dropped):
            raise TypeError("ids must be a list and dropped a list of {id, reason}")
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ValueError(f"file {path}: not an evaluation subset ({type(e).__name__}: {e})") from None
    return subset


@dataclass
class AuditResult:
    label: str
    validation: dict
    attacks: pd.DataFrame
    files: list[Path]
    run: AttackRun | None = None

    @property
    def headline(self) -> pd.DataFrame:
        """One row per task/source cell, significant cells first (see :func:`attacks.headline`)."""
        return headline(self.attacks)


def select_attacks(spec, families="all", *, fast: bool = False) -> list[str]:
    """``"all"`` or a list of attack names, within ``families`` (unknown names raise ``ValueError``)."""
    return select(families, None if spec in (None, "all") else spec, fast=fast)


HEADLINE_SHOWN = ("task", "source", "n_rows", "significant", "attack", "family", "accuracy", "p_value", "p_holm",
                  "significant_attacks", "families", "min_detectable", "underpowered", "large_effect")


def format_headline(head: pd.DataFrame, *, alpha: float, counts: AttackCounts) -> str:
    """The headline as markdown: the counts (:meth:`AttackCounts.sentence`), then one table row per
    task/source cell (significant cells first) with the strongest attack, its accuracy and p-values,
    and the smallest blind accuracy the test detects there (80% power)."""
    lines = [(f"{counts.sentence(bold=True)}; Holm alpha {alpha} over the {counts.tests} tests; "
              "`min_detectable`: smallest blind accuracy detected with 80% power at the cell's n; "
              "underpowered: cannot detect 35%.")]
    if len(head):
        shown = head[[c for c in HEADLINE_SHOWN if c in head.columns]].copy()
        shown["accuracy"] = shown["accuracy"].map(lambda x: f"{x:.3f}")
        shown["min_detectable"] = shown["min_detectable"].map(lambda x: f"{x:.3f}")
        for c in ("p_value", "p_holm"):
            shown[c] = shown[c].map(lambda x: f"{x:.3g}")
        lines += ["", shown.to_markdown(index=False)]
    return "\n".join(lines)


def verify_failures(validation: dict, rel: Release) -> pd.DataFrame:
    """One row per (failing check, row) of a validation object, with the row's task, source, video,
    question, candidates and answer beside the check's message: the rows behind a FAILED verify."""
    rows = rel.accepted.to_dict("records")
    by_id: dict = {}
    for i, r in enumerate(rows):
        for c in ("ReSTI ID", "Legacy Row Key"):
            if isinstance(r.get(c), str):
                by_id.setdefault(r[c], r)
        by_id.setdefault(i, r)
    out = []
    for name, check in (validation.get("checks") or {}).items():
        if check.get("status") != "fail":
            continue
        messages = check.get("messages") or {}
        for rid in check.get("failing") or []:
            r = by_id.get(rid, {})
            cands = r.get("Candidates")
            out.append({"check": name, "row": rid, "task": r.get("Task"), "source": r.get("Source"),
                        "video": r.get("Video"), "message": messages.get(rid, ""),
                        "question": r.get("Question"),
                        "candidates": json.dumps(cands, ensure_ascii=False) if isinstance(cands, dict) else cands,
                        "answer": r.get("Answer")})
    return pd.DataFrame(out, columns=["check", "row", "task", "source", "video", "message", "question", "candidates",
                                      "answer"])


def release_label(rel: Release) -> str:
    """A file-name label for a release: ``<name>_<version>`` from its ``release.json`` (the public
    ReSTI v5: ``resti_v5``), else ``release``."""
    meta = rel.meta if isinstance(rel.meta, dict) else {}
    name, version = meta.get("name"), meta.get("version")
    if isinstance(name, str) and isinstance(version, str) and name.strip() and version.strip():
        return re.sub(r"[^a-z0-9]+", "_", f"{name}_{version}".lower()).strip("_")
    return "release"


def command_path(path: str | Path) -> str:
    """How a command run from the repository root names ``path`` (relative when that is shorter)."""
    p = Path(path).resolve()
    try:
        rel = os.path.relpath(p, paths.ROOT)
    except ValueError:
        return str(p)
    return rel if len(rel) < len(str(p)) else str(p)


def audit_summary(run: AttackRun, validation: dict, *, label: str, path: str | Path, shown: str | None = None) -> dict:
    """What the report's headline and the run's summary read about an audited release: its path, the
    ``resti verify`` result (failing checks with their row counts) and the attack counts, with the
    command lines that print the same. ``shown``: how the commands name the release (default: its
    path from the repository root; an output folder's own release is named relative to the folder, so
    the same run written elsewhere gives the same bytes)."""
    where = shown or command_path(path)
    failing = {k: int(c.get("n_failing", 0)) for k, c in (validation.get("checks") or {}).items()
               if c.get("status") == "fail"}
    c = run.counts
    return {"label": label, "release": where, "verify": {"passed": bool(validation.get("passed")),
                                                         "failing": failing,
                                                         "command": f"resti verify {shlex.quote(where)}"},
            "attacks": {"tests": c.tests, "significant": c.significant, "cells": c.cells,
                        "significant_cells": c.significant_cells, "sentence": c.sentence(),
                        "skipped_rows": len(run.skipped), "suite": run.suite, "command": run.command(where)}}


def write_audit_summary(path: str | Path, summary: dict) -> Path:
    """Write an :func:`audit_summary` as JSON (sorted as built, UTF-8, trailing newline)."""
    atomic_write_bytes(Path(path), (json.dumps(summary, indent=2, ensure_ascii=False) + "\n").encode())
    return Path(path)


def audit_release(release: str | Path, *, out_dir: str | Path, label: str | None = None,
                  alpha: float = SUITE["alpha"], attacks="all", families="all", fast: bool = False) -> AuditResult:
    """Verify and attack one release with the blind suite (:func:`attack_release`); write
    ``validation_<label>.json``, ``verify_failures_<label>.*`` (the rows of every failing check),
    ``attacks_<label>.*``, ``attacks_<label>_headline.*`` and ``audit_<label>.json``
    (:func:`audit_summary`). ``label`` defaults to :func:`release_label`."""
    out_dir = Path(out_dir)
    rel = load_release(release, strict=False, known_tasks=task_names())
    label = label or release_label(rel)
    validation = verify_release(rel)
    run = attack_release(rel, families=families, attacks=attacks, fast=fast, alpha=alpha, progress=True)
    table = run.table
    files = [out_dir / f"validation_{label}.json"]
    atomic_write_bytes(files[0], (json.dumps(validation, indent=2, ensure_ascii=False) + "\n").encode())
    files += write_table(verify_failures(validation, rel), out_dir / f"verify_failures_{label}",
                         caption=f"resti verify on {label}: the rows of every failing check")
    files += write_table(table, out_dir / f"attacks_{label}",
                         caption=f"Blind attacks on {label} (Holm alpha={alpha} over {len(table)} rows)")
    files += write_table(headline(table), out_dir / f"attacks_{label}_headline",
                         caption=f"Blind attacks on {label}: strongest attack per task/source cell, significant "
                         "cells first, with the smallest blind accuracy detectable at 80% power")
    files.append(write_audit_summary(out_dir / f"audit_{label}.json",
                                     audit_summary(run, validation, label=label, path=release)))
    return AuditResult(label, validation, table, files, run)


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
