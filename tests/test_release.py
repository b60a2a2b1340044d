"""Release assembly: nothing lost, ids unique, verify passes, byte-identical reruns, atomic swap."""

import json
import shutil

import pandas as pd
import pytest

from resti_lib.io.benchmark import load_legacy
from resti_lib.release.assemble import InvariantError, assemble, collect, write_release
from resti_lib.tasks import interface as _interface
from resti_lib.tasks.base import AnswerSpec, Outcome, finalize, slug, write_task_outputs
from tests.helpers import row, write_legacy

IFACE = _interface()

IFACE = _interface()

TASK = "Displacement & Path Length"


def _world(tmp_path, n=12):
    rows = [row(rid=i, video=f"scene09{i % 3:02d}_00.mp4", t0=0.0, t1=2.0 + i) for i in range(n)]
    rows.append(row(task="Unknown Task", rid=99))
    legacy_path = write_legacy(rows, tmp_path / "qa.parquet")
    legacy, _ = load_legacy(legacy_path, strict=False)
    mine = legacy[legacy["Task"] == TASK]
    outcomes = []
    for r in mine.to_dict("records"):
        o = Outcome(row=int(r["row"]), key=r["Legacy Row Key"], task=TASK, source="ScanNet", video=r["Video"],
                    legacy_id=r["ID"], verdict="retained", question="What is the displacement? (unit: m)",
                    time_start=r["time_start"], time_end=r["time_end"],
                    answer=AnswerSpec("scalar", 1.0 + r["row"] * 0.37, unit="m"))
        if r["row"] % 4 == 3:
            o.exclude("zero_length_interval", t0=0.0, t1=0.0)
        outcomes.append(o)
    res = finalize(outcomes, mine, seed=0, iface=IFACE)
    write_task_outputs(res, tmp_path / "out" / "tasks" / slug(TASK))
    return legacy_path, legacy


def test_assemble_accounts_for_every_row(tmp_path):
    legacy_path, legacy = _world(tmp_path)
    v = assemble(legacy_path, tmp_path / "out" / "tasks", tmp_path / "out" / "release")
    rel = tmp_path / "out" / "release"
    acc = [json.loads(line) for line in (rel / "resti.jsonl").read_text().splitlines()]
    exc = [json.loads(line) for line in (rel / "excluded.jsonl").read_text().splitlines()]
    assert len(acc) + len(exc) == len(legacy) == 13
    assert {r["Legacy Row Key"] for r in acc} | {r["key"] for r in exc} == set(legacy["Legacy Row Key"])
    # the unknown task row is excluded as malformed, with its reason
    unk = [r for r in exc if r["task"] == "Unknown Task"]
    assert len(unk) == 1 and unk[0]["reason_codes"] == ["malformed_row"]
    assert v["passed"] and v["checks"]["legacy_coverage"]["status"] == "pass"
    meta = json.loads((rel / "release.json").read_text())
    assert meta["counts"] == {"accepted": len(acc), "excluded": len(exc), "original": 13}
    # SHA256SUMS lists every artifact with its digest (checked by an independent hashlib call)
    import hashlib
    for line in (rel / "SHA256SUMS").read_text().splitlines():
        digest, name = line.split("  ")
        assert hashlib.sha256((rel / name).read_bytes()).hexdigest() == digest
    prov = pd.read_parquet(rel / "provenance.parquet")
    assert len(prov) == 13 and set(prov["verdict"]) == {"retained", "excluded"}
    par = pd.read_parquet(rel / "resti.parquet")
    assert list(par["ReSTI ID"]) == [r["ReSTI ID"] for r in acc]


def test_rerun_is_byte_identical(tmp_path):
    legacy_path, _ = _world(tmp_path)
    rel = tmp_path / "out" / "release"
    assemble(legacy_path, tmp_path / "out" / "tasks", rel)
    first = {p.name: p.read_bytes() for p in rel.iterdir()}
    shutil.rmtree(tmp_path / "out" / "tasks")
    _world(tmp_path)  # rebuild the task outputs from scratch
    assemble(legacy_path, tmp_path / "out" / "tasks", rel)
    second = {p.name: p.read_bytes() for p in rel.iterdir()}
    assert first == second


def test_lost_row_is_an_error_and_previous_release_survives(tmp_path):
    legacy_path, legacy = _world(tmp_path)
    rel = tmp_path / "out" / "release"
    assemble(legacy_path, tmp_path / "out" / "tasks", rel)
    before = {p.name: p.read_bytes() for p in rel.iterdir()}
    acc, exc, prov, _ = collect(tmp_path / "out" / "tasks", legacy)
    with pytest.raises(InvariantError, match="lost"):
        write_release(acc[1:], exc, prov, legacy, rel)
    with pytest.raises(InvariantError, match="twice"):
        write_release(acc, exc + exc[:1], prov, legacy, rel)
    assert {p.name: p.read_bytes() for p in rel.iterdir()} == before
    assert not list(rel.parent.glob(".release.tmp-*"))


def test_crash_mid_write_keeps_previous_release(tmp_path, monkeypatch):
    legacy_path, legacy = _world(tmp_path)
    rel = tmp_path / "out" / "release"
    assemble(legacy_path, tmp_path / "out" / "tasks", rel)
    before = {p.name: p.read_bytes() for p in rel.iterdir()}
    import resti_lib.release.assemble as R

    def boom(*a, **k):
        raise KeyboardInterrupt("simulated crash")

    monkeypatch.setattr(R, "release_meta", boom)
    with pytest.raises(KeyboardInterrupt):
        assemble(legacy_path, tmp_path / "out" / "tasks", rel)
    assert {p.name: p.read_bytes() for p in rel.iterdir()} == before


def test_missing_task_outputs_is_an_error(tmp_path):
    legacy_path, _ = _world(tmp_path)
    shutil.rmtree(tmp_path / "out" / "tasks" / slug(TASK))
    with pytest.raises(InvariantError, match="no outputs for task"):
        assemble(legacy_path, tmp_path / "out" / "tasks", tmp_path / "out" / "release")
