"""Shared fixtures. Real-data tests skip without ../shared (or $RESTI_SHARED), unless CI=true."""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path

import pytest

from resti_lib import paths


def _require(path: Path, what: str) -> Path:
    if path.exists():
        return path
    msg = f"{what} not found at {path} (set RESTI_SHARED to the folder holding data/)"
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(f"CI=true requires the shared data: {msg}")
    pytest.skip(msg)


@pytest.fixture(scope="session")
def resti_v5_dir() -> Path:
    """The public ReSTI v5 release (real data)."""
    return _require(paths.resti_v5_dir(), "ReSTI v5 release")


@pytest.fixture(scope="session")
def real_vehicle_pose() -> Path:
    """The real Waymo v2 vehicle_pose parquet (199 frames)."""
    return _require(paths.real_waymo_vehicle_pose(), "real Waymo v2 vehicle_pose file")


@pytest.fixture(scope="session")
def real_samples() -> Path:
    """Small real source files (ScanNet scene0000_00, a ROPE frame, Waymo camera_hkp), byte-exact."""
    return _require(paths.shared_dir() / "data" / "real_samples", "real source samples")


@pytest.fixture(scope="session")
def miniworld_generated(tmp_path_factory) -> tuple[Path, dict]:
    """The default mini-world (seed 0), generated once per session into a temporary folder, with the
    summary the generator returned. Under several workers the first one generates it, under a lock, and
    the others read it. Read-only: tests that change a world use :func:`world_with`."""
    import json

    from resti_lib.synth import generate

    with _once_per_session(tmp_path_factory, "miniworld") as (out, make):
        summary = out.parent / f"{out.name}.summary.json"
        if make:
            summary.write_text(json.dumps(generate(out, seed=0)))
        return out, json.loads(summary.read_text())


@pytest.fixture(scope="session")
def miniworld(miniworld_generated) -> Path:
    """The default mini-world's folder (:func:`miniworld_generated`)."""
    return miniworld_generated[0]


def _tree_stat(root: Path) -> dict:
    out = {}
    for p in sorted(root.rglob("*")):
        st = p.lstat()
        if not p.is_dir() and p.name != ".generator_stamp":
            out[str(p.relative_to(root))] = (st.st_size, st.st_mtime_ns)
    return out


def _link_world(src: Path, dst: Path, owned: list[tuple[str, ...]]) -> None:
    """``dst`` mirrors ``src``: entries on the way to an owned path are real folders, owned paths are
    copies, everything else is one link (a whole folder or a file)."""
    import shutil

    dst.mkdir(parents=True, exist_ok=True)
    for child in sorted(src.iterdir()):
        inner = [o[1:] for o in owned if o[0] == child.name]
        if not inner:
            (dst / child.name).symlink_to(child, target_is_directory=child.is_dir())
        elif any(not o for o in inner):  # owned whole
            (shutil.copytree if child.is_dir() else shutil.copy2)(child, dst / child.name)
        else:
            _link_world(child, dst / child.name, inner)


@pytest.fixture
def world_with(miniworld, tmp_path):
    """``world_with(*own)``: a mini-world to damage without copying it (its 7,000 files cost seconds to
    copy). ``own`` names the paths (files or folders, relative to the world) the test will change: they
    are real copies; the rest are links to the session world. The readers under test never walk a tree
    recursively, so linked folders read as real ones. After the test the session world must be unchanged:
    a test that wrote through a link (a path it did not own) fails here."""
    before = _tree_stat(miniworld)

    def make(*own) -> Path:
        owned = [Path(o).parts for o in own]
        missing = [str(o) for o in own if not (miniworld / o).exists()]
        assert not missing, f"not in the mini-world: {missing}"
        _link_world(miniworld, tmp_path / "w", owned)
        return tmp_path / "w"

    yield make
    assert _tree_stat(miniworld) == before, "a test changed the session mini-world through a link"


# ------------------------------------------------------------------ the main job, run once per session

SOURCE_DATE_EPOCH = "1700000000"  # 2023-11-14T22:13:20Z: reruns with it set are byte-identical
MAIN_RUN_UMASK = 0o002  # not the usual 022: outputs must follow the umask, not a fixed mode


def main_params(miniworld: Path, out: Path, *, stage_params: dict | None = None) -> dict:
    """params/default.yaml pointed at a generated mini-world and an output folder, its stage list in
    full (the task stages included); ``stage_params`` replaces the params file of named stages."""
    from resti_lib.run.plan import main_config

    cfg = main_config()
    cfg.update(world_dir=str(miniworld), legacy_benchmark=str(miniworld / "legacy" / "qa.parquet"),
               scannet_root=str(miniworld / "scannet" / "scans"), waymo_root=str(miniworld / "waymo"),
               omni6d_root=str(miniworld / "omni6d"), output_dir=str(out))
    for s in cfg["stages"]:
        if stage_params and s["notebook"] in stage_params:
            s["params"] = str(stage_params[s["notebook"]])
    return cfg


def run_cli(args: list[str], *, umask: int | None = None, cwd=None, env: dict | None = None):
    """``resti ARGS`` in a subprocess (optionally under ``umask``), with SOURCE_DATE_EPOCH set."""
    import subprocess
    import sys

    e = {**os.environ, "SOURCE_DATE_EPOCH": SOURCE_DATE_EPOCH, **(env or {})}
    pre = (lambda: os.umask(umask)) if umask is not None else None
    return subprocess.run([sys.executable, "-m", "resti_lib.run.cli", *args], capture_output=True, text=True,
                          cwd=cwd or paths.ROOT, env=e, preexec_fn=pre, timeout=1800, check=False)


class MainRun:
    def __init__(self, out: Path, params: Path, cfg: dict, returncode: int, stdout: str, stderr: str):
        self.out, self.params, self.cfg = out, params, cfg
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


@contextmanager
def _once_per_session(tmp_path_factory, name: str):
    """Yields the folder for ``name`` and whether this process must make it: the first process of the
    session (one worker, under a lock) makes it, the others wait for it and read it."""
    import fcntl

    if not os.environ.get("PYTEST_XDIST_WORKER"):
        yield tmp_path_factory.mktemp(name), True
        return
    root = tmp_path_factory.getbasetemp().parent  # shared by the session's workers
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        made = root / f"{name}.done"
        yield root / name, not made.exists()
        made.touch()


@pytest.fixture(scope="session")
def main_run(miniworld, tmp_path_factory) -> MainRun:
    """``resti run`` on the default mini-world, once per session (a subprocess under umask 002, with
    SOURCE_DATE_EPOCH set): the tests of the main job, the report and the browser share it. Its tests
    are one xdist group (one worker); should grouping fail, the other workers wait for the one run."""
    import json

    import yaml

    from resti_lib.run.pipeline import _generator_stamp

    with _once_per_session(tmp_path_factory, "main_run") as (base, make):
        out, params, record = base / "outputs", base / "params.yaml", base / "run.json"
        cfg = main_params(miniworld, out)
        if make:
            (miniworld / ".generator_stamp").write_text(_generator_stamp(0))  # the fixture made it
            base.mkdir(parents=True, exist_ok=True)
            params.write_text(yaml.safe_dump(cfg))
            proc = run_cli(["run", "--params", str(params)], umask=MAIN_RUN_UMASK)
            record.write_text(json.dumps({"returncode": proc.returncode, "stdout": proc.stdout,
                                          "stderr": proc.stderr}))
        run = json.loads(record.read_text())
    assert run["returncode"] == 0, run["stderr"][-3000:]
    return MainRun(out, params, cfg, run["returncode"], run["stdout"], run["stderr"])


#: expensive fixtures of a module or session that are made once per worker (not shared on disk)
SHARED_FIXTURES = ("rebuilt", "v5_table")


@pytest.hookimpl(tryfirst=True)  # before the workers read xdist_group to group node ids
def pytest_collection_modifyitems(config, items):
    """Tests that read the shared main-job run (``main_run``) are slow: ``make test-fast`` leaves them
    out. With parallel workers they stay on one worker (one group), so the main job runs once."""
    for item in items:
        names = getattr(item, "fixturenames", ())
        if "main_run" in names:
            item.add_marker(pytest.mark.slow)
            item.add_marker(pytest.mark.xdist_group("main_run"))
            continue
        for fixture in SHARED_FIXTURES:  # made once per worker: their readers stay on one worker
            if fixture in names:
                item.add_marker(pytest.mark.xdist_group(fixture))
                break


class EditedRun:
    """:func:`dimensional_edit`: ``edited`` the outputs right after the edited run (a copy), ``inc`` the
    same folder after the edit was undone; the two runs' stdout."""

    def __init__(self, base: Path, record: dict):
        self.base, self.edited, self.inc = base, base / "edited", base / "incremental"
        self.edit_params = base / "dimensional.yaml"
        self.edit_stdout, self.undo_stdout = record["edit_stdout"], record["undo_stdout"]


#: the one params edit the main-job tests make: Dimensional answers print one more decimal, and the
#: task's tolerance (also its option separation floor) widens until some rows have no valid options
DIMENSIONAL_EDIT = ((r"^decimals: 2 ", "decimals: 3 "), (r"^rule: \{abs_tol: 0\.002,", "rule: {abs_tol: 0.3,"))


@pytest.fixture(scope="session")
def dimensional_edit(main_run, miniworld, tmp_path_factory) -> EditedRun:
    """One task's params edited on a copy of the session's main run, rerun, then the edit undone and rerun
    (once per session; the pipeline, what-changed and browser tests read it): every params-edit
    check reads the same two runs instead of each making its own."""
    import json
    import re
    import shutil

    import yaml

    with _once_per_session(tmp_path_factory, "dimensional_edit") as (base, make):
        record = base / "runs.json"
        if make:
            base.mkdir(parents=True, exist_ok=True)
            text = (paths.PARAMS / "dimensional.yaml").read_text()
            for pattern, new in DIMENSIONAL_EDIT:
                assert re.search(pattern, text, re.MULTILINE), pattern
                text = re.sub(pattern, new, text, flags=re.MULTILINE)
            (base / "dimensional.yaml").write_text(text)
            inc = base / "incremental"
            shutil.copytree(main_run.out, inc, symlinks=True)
            (base / "edited.yaml").write_text(yaml.safe_dump(
                main_params(miniworld, inc, stage_params={"03_dimensional": base / "dimensional.yaml"})))
            edit = run_cli(["run", "--params", str(base / "edited.yaml")])
            assert edit.returncode == 0, edit.stderr[-3000:]
            shutil.copytree(inc, base / "edited", symlinks=True)
            (base / "undone.yaml").write_text(yaml.safe_dump(main_params(miniworld, inc)))
            undo = run_cli(["run", "--params", str(base / "undone.yaml")])
            assert undo.returncode == 0, undo.stderr[-3000:]
            record.write_text(json.dumps({"edit_stdout": edit.stdout, "undo_stdout": undo.stdout}))
        data = json.loads(record.read_text())
    return EditedRun(base, data)
