"""One params schema, checked before anything runs (issue 20, item 2).

The defaults are the schema: a key no default names is refused with the closest known key, a value of
another type than its default's or out of its key's range is refused, and every error names the
params file and the key. The same check serves ``resti run`` (main params and every stage's params),
``resti measure --params``, ``resti reoption --params`` and a task notebook's parameters.
"""

from __future__ import annotations

import time

import pytest
import yaml

from resti_lib import defaults as D
from resti_lib import paths
from resti_lib.errors import InputError
from resti_lib.io.params import MAX_PARAMS_BYTES, read_params
from resti_lib.run.plan import main_config


def _main(tmp_path, **changes):
    cfg = yaml.safe_load((paths.PARAMS / "default.yaml").read_text())
    cfg.update(changes)
    p = tmp_path / "main.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


def test_a_misspelled_key_is_refused_with_the_closest_known_one(tmp_path):
    cfg = yaml.safe_load((paths.PARAMS / "default.yaml").read_text())
    cfg["legacy_benchmak"] = cfg.pop("legacy_benchmark")
    p = tmp_path / "main.yaml"
    p.write_text(yaml.safe_dump(cfg))
    with pytest.raises(InputError) as e:
        main_config(p)
    assert e.value.file == str(p) and e.value.field == "legacy_benchmak"
    assert "did you mean 'legacy_benchmark'?" in str(e.value)


@pytest.mark.parametrize("key,value,needle", [
    ("jobs", "two", "not an integer"), ("seed", "zero", "not an integer"), ("scannet_fps", 0, "above 0"),
    ("scannet_fps", "thirty", "not a number"), ("world_seed", -1, "at least 0"), ("jobs", 0, "at least 1"),
])
def test_main_params_of_the_wrong_type_or_range_are_refused_by_name(tmp_path, key, value, needle):
    p = _main(tmp_path, **{key: value})
    with pytest.raises(InputError) as e:
        main_config(p)
    assert e.value.file == str(p) and e.value.field == key and needle in str(e.value)


def test_a_stage_params_file_is_checked_against_its_notebook(tmp_path):
    traj = yaml.safe_load((paths.PARAMS / "trajectory.yaml").read_text())
    traj["compare_abs_tol_m"] = -5.0
    tp = tmp_path / "trajectory.yaml"
    tp.write_text(yaml.safe_dump(traj))
    cfg = yaml.safe_load((paths.PARAMS / "default.yaml").read_text())
    cfg["stages"] = [{"notebook": "07_trajectory", "params": str(tp), "wave": 1}, *cfg["stages"]]
    p = tmp_path / "main.yaml"
    p.write_text(yaml.safe_dump(cfg))
    with pytest.raises(InputError) as e:
        main_config(p)
    assert e.value.file == str(tp) and e.value.field == "compare_abs_tol_m" and "at least 0" in str(e.value)
    # a stage field of the wrong type, and an unknown one
    cfg["stages"][0] = {"notebook": "07_trajectory", "params": "params/trajectory.yaml", "wave": "first"}
    p.write_text(yaml.safe_dump(cfg))
    with pytest.raises(InputError) as e:
        main_config(p)
    assert e.value.field == "wave" and e.value.file == str(p)
    cfg["stages"][0] = {"notebook": "07_trajectory", "params": "params/trajectory.yaml", "speed": "fast"}
    p.write_text(yaml.safe_dump(cfg))
    with pytest.raises(InputError) as e:
        main_config(p)
    assert e.value.field == "speed"


def test_an_empty_or_oversized_params_file_is_refused_at_once(tmp_path):
    empty = tmp_path / "empty.yaml"
    empty.write_text("# nothing\n")
    with pytest.raises(InputError) as e:
        read_params(empty)
    assert e.value.file == str(empty) and "empty" in str(e.value)
    big = tmp_path / "big.yaml"
    with big.open("w") as f:  # 12 MB of valid YAML
        for i in range(12 * 1024 * 1024 // 24):
            f.write(f"key_{i:012d}: 1234567\n")
    assert big.stat().st_size > MAX_PARAMS_BYTES
    t0 = time.perf_counter()
    with pytest.raises(InputError) as e:
        read_params(big)
    assert time.perf_counter() - t0 < 1.0 and "bytes" in str(e.value) and e.value.file == str(big)


def test_resti_measure_params_are_checked(tmp_path, capsys):
    from resti_lib.measure.cli import measure_main

    c = tmp_path / "c.json"
    c.write_text('{"source": "ScanNet", "sequence": "scene0000_00", "entity": {"kind": "camera"}, '
                 '"times": [0, 1], "operator": "displacement"}')
    for text, field in (("scannet_fps: thirty\n", "scannet_fps"), ("scannet_fps: 2001-01-01\n", "scannet_fps"),
                        ("pose_rul: nearest\n", "pose_rul")):
        p = tmp_path / "p.yaml"
        p.write_text(text)
        assert measure_main([str(c), "--params", str(p)]) == 2
        err = capsys.readouterr().err
        assert str(p) in err and field in err and "Traceback" not in err


def test_notebook_parameters_are_checked_by_the_task_run(tmp_path):
    from resti_lib.tasks.run import run_task

    with pytest.raises(InputError) as e:
        run_task("Trajectory Description", {"seed": "zero", "legacy_benchmark": "x"})
    assert e.value.field == "seed" and e.value.file == "notebook parameters"


def test_every_default_params_file_meets_its_own_schema():
    for f in sorted(paths.PARAMS.glob("*.yaml")):
        d = yaml.safe_load(f.read_text())
        D.check_params(d, d, file=f)  # by construction; a RANGES rule that refuses a default fails here


def test_a_lattice_width_outside_zero_to_one_is_refused_by_name():
    opts = yaml.safe_load((paths.PARAMS / "options.yaml").read_text())
    for bad in (1.5, -0.1):
        v = {"model": {**opts["model"], "lattice": {**opts["model"]["lattice"], "width": bad}}}
        with pytest.raises(InputError) as e:
            D.check_params(v, opts, file="options.yaml")
        assert e.value.field == "model" and "width" in str(e.value) and "out of range" in str(e.value)
    D.check_params({"model": {**opts["model"], "lattice": {"below_units": 20, "width": 1.0}}}, opts)


def test_a_frame_rate_of_zero_is_refused_not_replaced():
    from resti_lib.sources.context import SourceContext

    with pytest.raises(InputError) as e:
        SourceContext.from_params({"scannet_fps": 0})
    assert e.value.field == "scannet_fps"
    assert SourceContext.from_params({}).scannet_fps == yaml.safe_load(
        (paths.PARAMS / "default.yaml").read_text())["scannet_fps"]


@pytest.mark.parametrize("where", ["legacy_folder", "inside_source_root"])
def test_an_output_folder_on_an_input_is_refused_before_any_stage_runs(tmp_path, miniworld, where, capsys):
    """output_dir set to the folder holding qa.parquet (or inside a source root): exit 2 naming it,
    and nothing is written beside the input."""
    import shutil

    from resti_lib.run.cli import main as cli_main

    inp = tmp_path / "in"
    inp.mkdir()
    shutil.copy(miniworld / "legacy" / "qa.parquet", inp / "qa.parquet")
    out = inp if where == "legacy_folder" else miniworld / "waymo" / "out"
    p = _main(tmp_path, world_dir="", legacy_benchmark=str(inp / "qa.parquet"),
              scannet_root=str(miniworld / "scannet" / "scans"), waymo_root=str(miniworld / "waymo"),
              omni6d_root=str(miniworld / "omni6d"), output_dir=str(out))
    before = sorted(x.name for x in inp.iterdir())
    assert cli_main(["run", "--params", str(p)]) == 2
    err = capsys.readouterr().err
    assert "refused before any stage ran" in err and str(out) in err
    assert sorted(x.name for x in inp.iterdir()) == before and not (miniworld / "waymo" / "out").exists()


@pytest.mark.slow
@pytest.mark.notebook
def test_an_input_error_inside_a_notebook_exits_2_with_its_one_line(tmp_path, miniworld, capsys):
    """The release a notebook audits is a folder without row files: the error is found inside notebook
    00, and resti run exits 2 (bad input) with the line the reader gives outside a notebook, not 1 with
    a notebook failure."""
    from resti_lib.io.benchmark import load_release
    from resti_lib.run.cli import main as cli_main

    empty = tmp_path / "not_a_release"
    empty.mkdir()
    with pytest.raises(InputError) as outside:
        load_release(empty)
    own = yaml.safe_load((paths.PARAMS / "answer_interface.yaml").read_text())
    own["release_path"] = str(empty)
    ai = tmp_path / "answer_interface.yaml"
    ai.write_text(yaml.safe_dump(own))
    cfg = yaml.safe_load((paths.PARAMS / "default.yaml").read_text())
    cfg["stages"] = [{**s, "params": str(ai)} if s["notebook"] == "00_answer_interface" else s for s in cfg["stages"]]
    p = _main(tmp_path, world_dir="", legacy_benchmark=str(miniworld / "legacy" / "qa.parquet"),
              scannet_root=str(miniworld / "scannet" / "scans"), waymo_root=str(miniworld / "waymo"),
              omni6d_root=str(miniworld / "omni6d"), output_dir=str(tmp_path / "out"), stages=cfg["stages"])
    assert cli_main(["run", "--params", str(p), "--only", "answer_interface"]) == 2
    err = capsys.readouterr().err
    assert f"resti run: input error: {outside.value}" in err
    assert (tmp_path / "out" / "notebooks" / "00_answer_interface.ipynb").is_file()  # found inside the notebook


def test_a_full_disk_names_the_file_being_written(tmp_path, monkeypatch):
    import errno
    import os

    from resti_lib.io.files import atomic_write_bytes

    real = os.fdopen

    class Full:
        def __init__(self, *a, **k):
            self.f = real(*a, **k)

        def __enter__(self):
            return self

        def __exit__(self, *a):
            self.f.close()

        def write(self, data):
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fdopen", Full)
    target = tmp_path / "release" / "resti.jsonl"
    with pytest.raises(OSError) as e:
        atomic_write_bytes(target, b"{}\n")
    assert e.value.errno == errno.ENOSPC and e.value.filename == str(target)
    assert list(target.parent.iterdir()) == []  # nothing half-written left behind
