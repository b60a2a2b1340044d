"""Shared acceptance checks of task modules on the mini-world (manifest = truth per legacy row)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from resti_lib import values as V
from resti_lib.defects import DEFECTS, REASONS
from resti_lib.options.attacks import attack_table
from resti_lib.tasks import interface as _interface
from resti_lib.tasks.run import TaskRun, run_task

IFACE = _interface()

IFACE = _interface()

ANSWER_LAYER = {c for c, d in DEFECTS.items() if d.layer == "answer"}


@dataclass
class MiniRun:
    run: TaskRun
    manifest: list  # manifest records of the task's rows
    by_row: dict  # row -> manifest record


def miniworld_params(world: Path, out: Path, **extra) -> dict:
    return {"legacy_benchmark": str(world / "legacy" / "qa.parquet"), "scannet_root": str(world / "scannet" / "scans"),
            "waymo_root": str(world / "waymo"), "omni6d_root": str(world / "omni6d"), "scannet_fps": 30,
            "omni6d_fps": 30, "video_map": "", "seed": 0, "output_dir": str(out), **extra}


def run_on_miniworld(task: str, world: Path, out: Path, **extra) -> MiniRun:
    run = run_task(task, miniworld_params(world, out, **extra))
    man = [json.loads(line) for line in (world / "manifest.jsonl").read_text().splitlines() if line.strip()]
    mine = [m for m in man if m["task"] == task]
    assert len(mine) == len(run.outcomes) > 0
    return MiniRun(run, mine, {m["row"]: m for m in mine})


def check_defects(mr: MiniRun) -> None:
    """Question- and source-layer defects: recall 100 % and no false positive, row by row; verdicts
    and exclusion reasons as expected. Answer-layer defects (detected by ``run_task`` from the legacy
    row alone): recall 100 %; an extra ``pose_identical_rotations`` is tolerated only on rows whose
    key points at a distractor (the detector compares the keyed candidate, which there is a
    distractor that may share another distractor's rounded rotation by chance)."""
    problems = []
    for o in mr.run.outcomes:
        m = mr.by_row[o.row]
        got, want = set(o.defects), set(m["defects"])
        own_got, own_want = got - ANSWER_LAYER, want - ANSWER_LAYER
        if own_got != own_want:
            problems.append((o.row, "defects", sorted(own_got ^ own_want)))
        missed = (want & ANSWER_LAYER) - got
        extra = (got & ANSWER_LAYER) - want
        if "key_detail_mismatch" in want:
            extra -= {"pose_identical_rotations"}
        if missed or extra:
            problems.append((o.row, "answer layer", sorted(missed), sorted(extra)))
        if o.verdict != m["expected_verdict"]:
            problems.append((o.row, "verdict", o.verdict, m["expected_verdict"]))
        if sorted(o.reasons) != sorted(m["expected_reasons"]):
            problems.append((o.row, "reasons", o.reasons, m["expected_reasons"]))
    assert not problems, problems


def check_values(mr: MiniRun) -> None:
    """Accepted rows: the keyed candidate is the Answer Detail and equals the manifest truth within
    the serialization rounding (excluded rows have no truth)."""
    acc = {r["Legacy Row Key"]: r for r in mr.run.result.accepted}
    bad = []
    for o in mr.run.outcomes:
        m = mr.by_row[o.row]
        if o.verdict == "excluded":
            assert m["true_answer"] is None, o.row
            continue
        r = acc[o.key]
        assert r["Candidates"][r["Answer"]] == r["Answer Detail"]
        assert len(set(r["Candidates"].values())) == 5
        if not V.agree(V.parse(r["Answer Detail"]), V.parse(m["true_answer"])):
            bad.append((o.row, r["Answer Detail"], m["true_answer"]))
    assert not bad, bad


def check_exclusions(mr: MiniRun) -> None:
    """Every exclusion record has known reason codes and non-empty evidence."""
    for e in mr.run.result.excluded:
        assert e["reason_codes"] and all(c in REASONS for c in e["reason_codes"]), e
        assert isinstance(e["verification_evidence"], dict) and e["verification_evidence"], e


def check_attacks(mr: MiniRun, allowed: tuple = ()) -> None:
    """No Holm-significant option-only attack on the rebuilt options, per source and pooled."""
    tab = attack_table(iface=IFACE, records=mr.run.result.accepted)
    sig = tab[tab["significant"] & ~tab["attack"].isin(allowed)]
    assert sig.empty, sig.to_string()


def check_notebook(stem: str, params_yaml: str) -> None:
    """The task notebook declares every shared key and every key of its params YAML, and is
    committed without outputs under the generic ``python3`` kernelspec."""
    import nbformat
    import yaml

    from resti_lib import paths
    from resti_lib.run.notebooks import check_parameters, notebook_parameters
    from resti_lib.tasks.base import COMMON_KEYS

    nb_path = paths.NOTEBOOKS / f"{stem}.ipynb"
    task_keys = yaml.safe_load((paths.PARAMS / params_yaml).read_text())
    declared = set(notebook_parameters(nb_path))
    assert set(COMMON_KEYS) | set(task_keys) <= declared, sorted(set(COMMON_KEYS) | set(task_keys) - declared)
    check_parameters(nb_path, {**{k: None for k in COMMON_KEYS}, **task_keys})
    nb = nbformat.read(nb_path, as_version=4)
    assert nb.metadata["kernelspec"]["name"] == "python3"
    assert all(not c.get("outputs") and c.get("execution_count") is None for c in nb.cells if c.cell_type == "code")
