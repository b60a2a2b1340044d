"""Output folders: never delete what is not ours, never write over an input, always a complete
folder at the path (or one the next start restores), one writer at a time, permissions from the
umask. Every folder here is made in tmp_path."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from resti_lib.errors import BusyError, OutputError
from resti_lib.io.lock import folder_lock, lock_file_for, run_lock
from resti_lib.release import publish
from resti_lib.release.publish import MARKER, publishing, recover
from resti_lib.release.reoption import reoption_release
from resti_lib.run.cli import main as cli_main
from tests.helpers import row, seal_release, write_release


def _tree(root: Path) -> dict:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
            for p in sorted(root.rglob("*"))}


@pytest.fixture
def release(tmp_path) -> Path:
    rows = [row(rid=i, video=f"scene09{i % 3:02d}_00.mp4",
                cands={"A": f"{1 + i}.00m", "B": f"{2 + i}.50m", "C": f"{3 + i}.25m", "D": f"{4 + i}.75m",
                       "E": f"{6 + i}.10m"}, answer="ABCDE"[i % 5]) for i in range(10)]
    return seal_release(write_release(rows, [], tmp_path / "in"))


def _holder(lock_path: Path, seconds: float = 60.0) -> subprocess.Popen:
    """Another process holding a lock file (it prints 'held' once it has it)."""
    code = ("import sys, time\nfrom resti_lib.io.lock import hold\n"
            f"with hold({str(lock_path)!r}, what='test'):\n    print('held', flush=True)\n    time.sleep({seconds})\n")
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"
    return p


# ------------------------------------------------------------------------- not ours, not inputs

def test_reoption_refuses_a_folder_of_other_files(release, tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("years of work")
    (out / "data").mkdir()
    (out / "data" / "x.csv").write_text("1,2\n")
    before = _tree(out)
    assert cli_main(["reoption", "--release", str(release), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "not written by resti" in err and "thesis.tex" in err and len(err.strip().splitlines()) == 1
    assert _tree(out) == before


@pytest.mark.parametrize("where", ["the input", "the input's parent", "inside the input"])
def test_reoption_never_writes_over_its_input(release, tmp_path, where, capsys):
    out = {"the input": release, "the input's parent": release.parent, "inside the input": release / "new"}[where]
    before = _tree(tmp_path)
    assert cli_main(["reoption", "--release", str(release), "--out", str(out)]) == 2
    assert "input of this run" in capsys.readouterr().err
    assert _tree(tmp_path) == before


def test_release_writer_refuses_foreign_folder_and_other_kinds(tmp_path):
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="not written by resti"), publishing(foreign, kind="release"):
        pass
    world = tmp_path / "world"
    with publishing(world, kind="world") as st:
        (st / "world.json").write_text("{}")
    with pytest.raises(OutputError, match="resti world folder, not a release folder"), \
            publishing(world, kind="release"):
        pass
    afile = tmp_path / "a_file"
    afile.write_text("x")
    with pytest.raises(OutputError, match="not a folder"), publishing(afile, kind="release"):
        pass
    assert (foreign / "notes.txt").read_text() == "mine" and afile.read_text() == "x"


def test_outputs_of_earlier_versions_are_recognised(release, tmp_path):
    """A release folder written before the marker existed holds only release files and a
    release.json naming resti: it may be replaced; one extra file makes it foreign."""
    old = tmp_path / "old"
    old.mkdir()
    for n in ("resti.jsonl", "excluded.jsonl", "SHA256SUMS", "validation.json"):
        (old / n).write_text("")
    (old / "release.json").write_text(json.dumps({"generator": "resti 0.9.0", "counts": {}}))
    assert publish.owner_problem(old, "release") is None
    (old / "my_notes.md").write_text("x")
    assert "my_notes.md" in publish.owner_problem(old, "release")
    (old / "my_notes.md").unlink()
    (old / "release.json").write_text(json.dumps({"generator": "someone else"}))
    assert publish.owner_problem(old, "release") is not None


def test_rewrite_replaces_our_folder_and_marks_it(release, tmp_path):
    out = tmp_path / "out"
    reoption_release(release, out, seed=1, options={"adversarial": {"rounds": 0}})
    first = _tree(out)
    assert json.loads((out / MARKER).read_text()) == {"kind": "release", "written_by": "resti"}
    reoption_release(release, out, seed=2, options={"adversarial": {"rounds": 0}})
    assert _tree(out) != first and (out / MARKER).exists()
    reoption_release(release, out, seed=1, options={"adversarial": {"rounds": 0}})
    assert _tree(out) == first  # same input and seed: the same bytes, marker included
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


# ------------------------------------------------------------------------------ swap and recovery

def _kill_between_renames(monkeypatch):
    """The portable swap (no atomic exchange) interrupted after the old folder was moved aside."""
    monkeypatch.setattr(publish, "exchange", lambda a, b: False)
    real = os.rename
    calls = []

    def rename(a, b):
        calls.append((a, b))
        if len(calls) == 2:
            raise KeyboardInterrupt("killed between the two renames")
        return real(a, b)

    monkeypatch.setattr(publish.os, "rename", rename)


def test_interrupted_swap_is_restored_at_the_next_start(release, tmp_path, monkeypatch):
    out = tmp_path / "out"
    reoption_release(release, out, seed=1, options={"adversarial": {"rounds": 0}})
    first = _tree(out)
    with monkeypatch.context() as m:
        _kill_between_renames(m)
        with pytest.raises(KeyboardInterrupt):
            reoption_release(release, out, seed=2, options={"adversarial": {"rounds": 0}})
    assert not out.exists()  # the crash window: the old release is aside, under .out.old-*
    aside = [p for p in tmp_path.iterdir() if p.name.startswith(".out.old-")]
    assert len(aside) == 1 and _tree(aside[0]) == first
    # the next start puts it back before doing anything else, then publishes the new release
    reoption_release(release, out, seed=3, options={"adversarial": {"rounds": 0}})
    assert (out / MARKER).exists() and _tree(out) != first
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    # and recover() alone restores the old release
    with monkeypatch.context() as m:
        _kill_between_renames(m)
        with pytest.raises(KeyboardInterrupt):
            reoption_release(release, out, seed=1, options={"adversarial": {"rounds": 0}})
    third = _tree(next(p for p in tmp_path.iterdir() if p.name.startswith(".out.old-")))
    assert recover(out) and _tree(out) == third


def test_stale_temporaries_are_removed_at_start(release, tmp_path):
    out = tmp_path / "out"
    for name in (".out.tmp-deadbeef0001", ".out.tmp-deadbeef0002"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "resti.jsonl").write_text("half written")
    reoption_release(release, out, seed=1, options={"adversarial": {"rounds": 0}})
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    (tmp_path / ".other.tmp-1").mkdir()  # temporaries of another folder are not ours to remove
    reoption_release(release, out, seed=1, options={"adversarial": {"rounds": 0}})
    assert (tmp_path / ".other.tmp-1").is_dir()


@pytest.mark.skipif(publish._renameat2 is None, reason="no atomic exchange on this system")
def test_atomic_exchange(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    (a / "x").write_text("a")
    (b / "x").write_text("b")
    assert publish.exchange(a, b)
    assert (a / "x").read_text() == "b" and (b / "x").read_text() == "a"


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o002])
def test_permissions_follow_the_umask(release, tmp_path, mask):
    old = os.umask(mask)
    try:
        out = tmp_path / f"out{mask:o}"
        reoption_release(release, out, seed=0, options={"adversarial": {"rounds": 0}})
    finally:
        os.umask(old)
    assert out.stat().st_mode & 0o777 == 0o777 & ~mask
    for p in out.iterdir():
        assert p.stat().st_mode & 0o777 == 0o666 & ~mask, p.name


# ------------------------------------------------------------------------------------- the lock

def test_second_writer_of_a_folder_exits_with_a_message(release, tmp_path, capsys):
    out = tmp_path / "out"
    holder = _holder(lock_file_for(out))
    try:
        rc = cli_main(["reoption", "--release", str(release), "--out", str(out)])
        err = capsys.readouterr().err
        assert rc == 3 and f"pid {holder.pid}" in err and len(err.strip().splitlines()) == 1
        assert not out.exists()
        with pytest.raises(BusyError, match="still being written"), folder_lock(out, wait=True, timeout=0.5):
            pass
    finally:
        holder.kill()
        holder.wait()
    # free again once the holder is gone
    assert reoption_release(release, out, seed=0, options={"adversarial": {"rounds": 0}}).validation["passed"]
    assert not lock_file_for(out).exists()  # the lock file leaves with its holder


def test_second_run_on_one_output_folder_stops(tmp_path, capsys):
    import yaml

    out = tmp_path / "outputs"
    out.mkdir()
    params = tmp_path / "p.yaml"
    params.write_text(yaml.safe_dump({"output_dir": str(out), "stages": []}))
    holder = _holder(out / ".resti.lock")
    try:
        rc = cli_main(["run", "--params", str(params)])
        err = capsys.readouterr().err
        assert rc == 3 and "another resti run" in err and f"pid {holder.pid}" in err
        assert sorted(p.name for p in out.iterdir()) == [".resti.lock"]
    finally:
        holder.kill()
        holder.wait()
    with run_lock(out):  # free once the holder is gone (also when it was killed)
        pass


def test_lock_is_reentrant_within_a_process(tmp_path):
    target = tmp_path / "w"
    with folder_lock(target):
        with folder_lock(target):
            assert lock_file_for(target).exists()
        assert lock_file_for(target).exists()
    assert not lock_file_for(target).exists()


# ------------------------------------------------------------------------------- the mini-world

def _old_world(w: Path) -> Path:
    """A previous world (its files stand for a full one: only their survival is checked)."""
    (w / "legacy").mkdir(parents=True)
    (w / "legacy" / "qa.parquet").write_bytes(b"the previous legacy benchmark")
    (w / "world.json").write_text(json.dumps({"generator": "resti_lib.synth", "seed": 0}))
    (w / MARKER).write_bytes(publish.marker_bytes("world"))
    return w


@pytest.mark.slow  # over 3 s: make test runs it, make test-fast leaves it out
def test_generate_never_leaves_half_a_world(tmp_path, monkeypatch):
    from resti_lib import synth

    w = _old_world(tmp_path / "w")
    before = _tree(w)

    def boom(*a, **k):
        raise RuntimeError("generator failed halfway")

    monkeypatch.setattr(synth, "_write_legacy", boom)
    with pytest.raises(RuntimeError):
        synth.generate(w, seed=1)
    assert _tree(w) == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_generate_refuses_a_folder_that_is_not_a_world(tmp_path):
    from resti_lib.synth import generate

    d = tmp_path / "d"
    d.mkdir()
    (d / "keep.txt").write_text("precious")
    with pytest.raises(OutputError):
        generate(d, seed=0)
    assert [p.name for p in d.iterdir()] == ["keep.txt"]


def test_killed_generation_keeps_the_previous_world(tmp_path):
    """A real kill (SIGKILL) while the new world is being written: the old one is untouched, and
    the next start removes the half-written staging folder."""
    w = _old_world(tmp_path / "w")
    before = _tree(w)
    code = f"from resti_lib.synth import generate\ngenerate({str(w)!r}, seed=5)\n"
    p = subprocess.Popen([sys.executable, "-c", code])
    try:
        t0 = time.monotonic()
        while not [q for q in tmp_path.glob(".w.tmp-*") if (q / "scannet").exists()]:
            assert p.poll() is None and time.monotonic() - t0 < 120, "the generator never started writing"
            time.sleep(0.05)
        os.kill(p.pid, signal.SIGKILL)
    finally:
        p.wait()
    assert _tree(w) == before
    assert list(tmp_path.glob(".w.tmp-*"))  # the killed run's staging folder is still there ...
    with folder_lock(w):
        recover(w)
    assert not list(tmp_path.glob(".w.tmp-*"))  # ... until the next start
    assert _tree(w) == before


def test_a_run_waits_for_the_world_being_generated(tmp_path):
    """The second run needing the mini-world waits while another process holds it, then uses the
    world that process made (it does not generate a second one)."""
    from resti_lib.run.pipeline import _generator_stamp, ensure_world

    w = tmp_path / "world"
    (w / "legacy").mkdir(parents=True)
    (w / "legacy" / "qa.parquet").write_bytes(b"made by the other run")
    (w / "world.json").write_text(json.dumps({"generator": "resti_lib.synth"}))
    (w / ".generator_stamp").write_text(_generator_stamp(0))
    before = _tree(w)
    holder = _holder(lock_file_for(w), seconds=1.5)
    try:
        t0 = time.monotonic()
        assert ensure_world({"world_dir": str(w), "world_seed": 0}) == w
        waited = time.monotonic() - t0
    finally:
        holder.kill()
        holder.wait()
    assert waited > 0.5 and _tree(w) == before
