"""Hostile and damaged inputs: params never become code, every damaged file is one clear message
(file, row, field) and a non-zero exit, never a traceback. Every damaged copy is made here, in
``tmp_path``; the shared data are only read."""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import io
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from resti_lib import errors
from resti_lib.errors import InputError, RestiError
from resti_lib.run.cli import main as cli_main
from resti_lib.run.notebooks import load_params
from tests.helpers import row, seal_release, write_release

# ---------------------------------------------------------------------------------------- helpers


def run_cli(*args) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli_main([str(a) for a in args])
    return rc, out.getvalue(), err.getvalue()


def one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def _rows(n=12):
    return [row(rid=i, video=f"scene09{i % 3:02d}_00.mp4",
                cands={"A": f"{1 + i}.00m", "B": f"{2 + i}.50m", "C": f"{3 + i}.25m", "D": f"{4 + i}.75m",
                       "E": f"{6 + i}.10m"}, answer="ABCDE"[i % 5]) for i in range(n)]


@pytest.fixture
def release(tmp_path) -> Path:
    """A small sealed release (release.json with counts, SHA256SUMS), built here."""
    excluded = [{"key": "ScanNet|Spatial Relation|v.mp4|0|uid=00000000000000aa", "legacy_id": 0,
                 "legacy_video": "v.mp4", "source": "ScanNet", "task": "Spatial Relation",
                 "reason_codes": ["unsupported_question"]}]
    return seal_release(write_release(_rows(), excluded, tmp_path / "rel"))


def read_rows(folder: Path) -> list[dict]:
    return [json.loads(line) for line in (folder / "resti.jsonl").read_text(encoding="utf-8").splitlines()]


def put_rows(folder: Path, rows: list[dict]) -> None:
    (folder / "resti.jsonl").write_text("".join(json.dumps(r, ensure_ascii=False) + "\n" for r in rows),
                                        encoding="utf-8")


# ----------------------------------------------------------------------------------- params (1)

PLANTED = {
    "binary": "x: !!binary aGVsbG8=\n",
    "explicit timestamp": "x: !!timestamp 2024-01-01\n",
    "plain date": "x: 2024-01-01\n",
    "plain datetime": "x: 2001-12-14t21:59:43.10-05:00\n",
    "set": "x: !!set {a, b}\n",
    "omap": "x: !!omap [{a: 1}, {b: 2}]\n",
    "pairs": "x: !!pairs [{a: 1}]\n",
    "python object": "x: !!python/object/apply:os.system ['echo planted']\n",
    "python name": "x: !!python/name:os.system\n",
    "local tag": "x: !custom 3\n",
    "nested in a list": "opts: [1, 2, !!binary aGk=]\n",
    "nested in a mapping": "opts: {inner: {when: 1999-01-01}}\n",
    "binary key": "? !!binary aGk=\n: 1\n",
}
# the key (as the error names it) of each planted value
PLANTED_KEY = {"nested in a list": "opts[2]", "nested in a mapping": "opts.inner.when", "binary key": "(top level)"}


@pytest.mark.parametrize("name", sorted(PLANTED))
def test_params_refuse_every_non_plain_yaml_type(tmp_path, name):
    p = tmp_path / "p.yaml"
    p.write_text("seed: 0\n" + PLANTED[name], encoding="utf-8")
    with pytest.raises(InputError) as e:
        load_params(p)
    msg = str(e.value)
    assert "\n" not in msg and e.value.file == str(p)
    assert e.value.field == PLANTED_KEY.get(name, "x")
    assert "not allowed" in msg


def test_params_plain_types_load_as_written(tmp_path):
    p = tmp_path / "p.yaml"
    p.write_text("a: text\nb: 3\nc: 2.5\nd: true\ne: null\nf: [1, two]\ng: {h: 1}\n"
                 "base: &b {x: 1}\nderived: {<<: *b, y: 2}\n", encoding="utf-8")
    assert load_params(p) == {"a": "text", "b": 3, "c": 2.5, "d": True, "e": None, "f": [1, "two"],
                              "g": {"h": 1}, "base": {"x": 1}, "derived": {"x": 1, "y": 2}}


def test_params_alias_bomb_is_refused(tmp_path):
    lines = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    for i in range(1, 7):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]")
    p = tmp_path / "bomb.yaml"
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(InputError, match="aliases are expanded"):
        load_params(p)


def test_planted_stage_params_never_reach_a_notebook(tmp_path):
    """`resti run` refuses the params before any notebook (or the mini-world) is touched."""
    stage = tmp_path / "displacement.yaml"
    stage.write_text("compare_abs_tol: !!python/object/apply:os.system ['touch planted']\n", encoding="utf-8")
    cfg = {"world_dir": str(tmp_path / "world"), "output_dir": str(tmp_path / "out"),
           "stages": [{"notebook": "05_displacement", "params": str(stage), "wave": 1}]}
    main = tmp_path / "default.yaml"
    main.write_text(yaml.safe_dump(cfg), encoding="utf-8")
    rc, _, err = run_cli("run", "--params", main)
    line = one_line(err)
    assert rc == 2 and str(stage) in line and "compare_abs_tol" in line
    assert not (tmp_path / "out").exists() and not (tmp_path / "world").exists()


# ----------------------------------------------------------------------------- hierarchy (11)

def test_one_exception_hierarchy():
    from resti_lib.options import stage
    from resti_lib.release import assemble as release
    from resti_lib.release import reoption
    from resti_lib.run import notebooks as runner

    for name in errors.__all__:
        assert issubclass(getattr(errors, name), RestiError), name
    assert release.InvariantError is errors.InvariantError
    assert reoption.ReoptionError is errors.ReoptionError
    assert runner.NotebookError is errors.NotebookError
    assert stage.OptionError is errors.OptionError
    # every exception class defined in the package (control-flow classes aside) is a RestiError
    import pkgutil

    import resti_lib

    control_flow = {"Excluded", "Exclude", "NoCandidate", "Reject"}  # a row excluded; a drawn option set redrawn
    for mod in pkgutil.walk_packages(resti_lib.__path__, "resti_lib."):
        m = importlib.import_module(mod.name)
        for obj in vars(m).values():
            if isinstance(obj, type) and issubclass(obj, BaseException) and obj.__module__ == mod.name \
                    and obj.__name__ not in control_flow:
                assert issubclass(obj, RestiError), f"{mod.name}.{obj.__name__}"
    e = InputError("bad value\nsecond line", file="f.jsonl", row="r1", field="Answer")
    assert str(e) == "file f.jsonl, row r1, field 'Answer': bad value second line"


def test_cli_prints_one_line_for_any_resti_error(monkeypatch):
    import resti_lib.release.verify as V

    for exc, code in ((errors.InvariantError("rows lost"), 1), (errors.OutputError("not ours", file="x"), 2),
                      (errors.BusyError("held", file="y"), 3), (InputError("bad", file="z", row=3, field="ID"), 2)):
        def boom(*a, _e=exc, **k):
            raise _e

        monkeypatch.setattr(V, "verify_path", boom)
        rc, _, err = run_cli("verify", "whatever")
        assert rc == code and str(exc) in one_line(err)


# ------------------------------------------------------------------ damaged files: point 5 (5)

def _latin1(d):
    rows = read_rows(d)
    rows[0]["Question"] = "Quelle est la d\u00e9placement ?"
    (d / "resti.jsonl").write_bytes("".join(json.dumps(r, ensure_ascii=False) + "\n" for r in rows)
                                    .encode("latin-1"))
    return "not UTF-8"


def _utf16(d):
    (d / "resti.jsonl").write_bytes((d / "resti.jsonl").read_text(encoding="utf-8").encode("utf-16"))
    return "UTF-16"


def _jsonl_is_folder(d):
    (d / "resti.jsonl").unlink()
    (d / "resti.jsonl").mkdir()
    return "is a folder"


def _deep(d):
    lines = (d / "resti.jsonl").read_text(encoding="utf-8").splitlines()
    lines[3] = lines[3][:-1] + ', "x": ' + "[" * 200_000 + "]" * 200_000 + "}"
    (d / "resti.jsonl").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return "nested too deeply"


def _not_object(d):
    lines = (d / "resti.jsonl").read_text(encoding="utf-8").splitlines()
    lines[2] = "[1, 2, 3]"
    (d / "resti.jsonl").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return "not an object"


FILE_FAULTS = {"latin-1 text": _latin1, "UTF-16 text": _utf16, "resti.jsonl is a folder": _jsonl_is_folder,
               "deep nesting": _deep, "a line that is a list": _not_object}


@pytest.mark.parametrize("fault", sorted(FILE_FAULTS))
@pytest.mark.parametrize("cmd", ["verify", "attack", "reoption"])
def test_unreadable_files_are_one_message(release, tmp_path, fault, cmd):
    expect = FILE_FAULTS[fault](release)
    args = {"verify": ["verify", release], "attack": ["attack", release],
            "reoption": ["reoption", "--release", release, "--out", tmp_path / "out"]}[cmd]
    rc, _, err = run_cli(*args)
    line = one_line(err)
    assert rc == 2 and str(release / "resti.jsonl") in line and expect in line
    assert not (tmp_path / "out").exists()


def _release_json(text: bytes):
    def mutate(d):
        (d / "release.json").write_bytes(text)
    return mutate


META_FAULTS = {
    "invalid JSON": (_release_json(b'{"counts": {"accepted": 12,'), "not valid JSON"),
    "empty": (_release_json(b""), "not valid JSON"),
    "a list": (_release_json(b"[1, 2]"), "not an object"),
    "counts not an object": (_release_json(b'{"counts": [12, 1]}'), "not an object"),
    "no counts": (_release_json(b'{"name": "x"}'), "no counts"),
}


@pytest.mark.parametrize("fault", sorted(META_FAULTS))
def test_damaged_release_json(release, tmp_path, fault):
    mutate, expect = META_FAULTS[fault]
    mutate(release)
    rc, out, err = run_cli("verify", release, "--json")
    assert rc == 1 and err == ""
    v = json.loads(out)
    c = v["checks"]["release_json"]
    assert c["status"] == "fail" and not v["passed"]
    assert any(expect in m for m in c["messages"].values())
    rc, _, err = run_cli("reoption", "--release", release, "--out", tmp_path / "out")
    line = one_line(err)
    assert rc == 2 and ("release.json" in line or "release_json" in line)
    assert not (tmp_path / "out").exists()
    if fault in ("invalid JSON", "empty", "a list"):  # attack reads the rows, and says the file is damaged
        rc, out, err = run_cli("attack", release, "--format", "json")
        assert rc == 2 and str(release / "release.json") in one_line(err) and json.loads(out)


def test_empty_folder_and_missing_release(tmp_path):
    (tmp_path / "empty").mkdir()
    for cmd in ("verify", "attack"):
        rc, _, err = run_cli(cmd, tmp_path / "empty")
        assert rc == 2 and "no resti.jsonl or resti.parquet" in one_line(err)
        rc, _, err = run_cli(cmd, tmp_path / "absent")
        assert rc == 2 and "release not found" in one_line(err)


def test_sha256sums_line_without_a_file_name(release, tmp_path):
    digest = hashlib.sha256((release / "resti.jsonl").read_bytes()).hexdigest()
    (release / "SHA256SUMS").write_text(f"{digest}\n", encoding="utf-8")
    rc, out, err = run_cli("verify", release, "--json")
    c = json.loads(out)["checks"]["sha256"]
    assert rc == 1 and err == "" and c["status"] == "fail"
    assert "SHA256SUMS line 1" in c["failing"]
    rc, _, err = run_cli("reoption", "--release", release, "--out", tmp_path / "out")
    assert rc == 2 and "sha256" in one_line(err)


def test_row_missing_task(release, tmp_path):
    rows = read_rows(release)
    del rows[4]["Task"]
    put_rows(release, rows)
    rid = rows[4]["ReSTI ID"]
    rc, out, err = run_cli("verify", release, "--json")
    v = json.loads(out)
    assert rc == 1 and err == "" and v["checks"]["known_task"]["failing"] == [rid]
    assert v["checks"]["columns"]["failing"] == [rid]
    rc, out, err = run_cli("attack", release, "--format", "json")
    line = one_line(err)
    assert rc == 2 and "1 of 12 rows" in line and rid in line and "Task" in line
    assert json.loads(out)  # the other eleven rows are still attacked
    rc, _, err = run_cli("reoption", "--release", release, "--out", tmp_path / "out")
    line = one_line(err)
    assert rc == 2 and rid in line and "'Task'" in line


def test_numeric_candidate_in_attack(release):
    rows = read_rows(release)
    rows[0]["Candidates"]["B"] = 2.5
    rows[7]["Candidates"]["D"] = "1e308°"
    put_rows(release, rows)
    rc, out, err = run_cli("attack", release, "--format", "csv")
    line = one_line(err)
    assert rc == 2 and "2 of 12 rows" in line
    assert rows[0]["ReSTI ID"] in line and "Candidates.B" in line and rows[7]["ReSTI ID"] in line
    assert out.startswith("attack,")  # the other ten rows are still attacked


def test_run_missing_params_bad_yaml_unknown_notebook(tmp_path):
    rc, _, err = run_cli("run", "--params", tmp_path / "absent.yaml")
    assert rc == 2 and "params file not found" in one_line(err)
    bad = tmp_path / "bad.yaml"
    bad.write_text("stages: [1,\n", encoding="utf-8")
    rc, _, err = run_cli("run", "--params", bad)
    line = one_line(err)
    assert rc == 2 and str(bad) in line and "not valid YAML at line 2" in line
    unk = tmp_path / "unk.yaml"
    unk.write_text(yaml.safe_dump({"output_dir": str(tmp_path / "out"),
                                   "stages": [{"notebook": "05_displacement"}, {"notebook": "42_nothing"}]}))
    rc, _, err = run_cli("run", "--params", unk)
    line = one_line(err)
    assert rc == 2 and "row stage 1" in line and "field 'notebook'" in line and "42_nothing" in line
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("scale", ["0", "-1", "1001"])
def test_synth_scale_out_of_bounds(tmp_path, scale):
    rc, _, err = run_cli("synth", tmp_path / "w", "--scale", scale)
    line = one_line(err)
    assert rc == 2 and "field 'scale'" in line and "1 to 1000" in line
    assert not (tmp_path / "w").exists()


def test_no_traceback_from_a_real_process(release):
    """The same messages from the installed entry point (a separate process)."""
    _utf16(release)
    r = subprocess.run([sys.executable, "-m", "resti_lib.run.cli", "verify", str(release)], check=False, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr and "UTF-16" in one_line(r.stderr)


# ---------------------------------------------------------------------------------- reoption (3)

def _cut_last_row(d):
    lines = (d / "resti.jsonl").read_text(encoding="utf-8").splitlines(keepends=True)
    (d / "resti.jsonl").write_text("".join(lines[:-1]), encoding="utf-8")


def _empty_excluded(d):
    (d / "excluded.jsonl").write_text("", encoding="utf-8")


def _empty_accepted(d):
    (d / "resti.jsonl").write_text("", encoding="utf-8")


def _reseal_sums(d):
    """An edited release whose SHA256SUMS were recomputed: only the counts can tell."""
    sums = "".join(f"{hashlib.sha256((d / n).read_bytes()).hexdigest()}  {n}\n"
                   for n in ("resti.jsonl", "excluded.jsonl"))
    (d / "SHA256SUMS").write_text(sums, encoding="utf-8")


DAMAGE = {
    "last row cut": ([_cut_last_row], "release_json", "counts.accepted"),
    "excluded.jsonl emptied": ([_empty_excluded], "release_json", "counts.excluded"),
    "resti.jsonl emptied": ([_empty_accepted], "release_json", "counts.accepted"),
    "last row cut, SHA256SUMS recomputed": ([_cut_last_row, _reseal_sums], "release_json", "counts.accepted"),
    "row edited, counts intact": ([lambda d: put_rows(d, [dict(r, Question=r["Question"] + "!")
                                                          for r in read_rows(d)])], "sha256", "resti.jsonl"),
    "release.json removed": ([lambda d: (d / "release.json").unlink()], "release_json", "no release.json"),
    "digests removed": ([lambda d: (d / "SHA256SUMS").unlink()], "sha256", "no digests"),
}


@pytest.mark.parametrize("damage", sorted(DAMAGE))
def test_reoption_refuses_damaged_input(release, tmp_path, damage):
    steps, check, words = DAMAGE[damage]
    for step in steps:
        step(release)
    out = tmp_path / "out"
    rc, stdout, err = run_cli("reoption", "--release", release, "--out", out)
    line = one_line(err)
    assert rc == 2 and f"field {check!r}" in line and words in line and str(release) in line
    assert not out.exists() and stdout == ""


def test_reoption_of_an_intact_copy_still_works(release, tmp_path):
    rc, stdout, err = run_cli("reoption", "--release", release, "--out", tmp_path / "out")
    assert rc == 0 and "verify: PASSED" in stdout and err == ""


@pytest.mark.parametrize("damage", ["last row cut", "excluded.jsonl emptied", "resti.jsonl emptied"])
def test_reoption_refuses_damaged_copies_of_v5(resti_v5_dir, tmp_path, damage):
    v5 = tmp_path / "v5"
    shutil.copytree(resti_v5_dir, v5)
    v5.chmod(0o755)
    for p in v5.iterdir():
        p.chmod(0o644)
    steps, check, words = DAMAGE[damage]
    for step in steps:
        step(v5)
    rc, _, err = run_cli("reoption", "--release", v5, "--out", tmp_path / "out")
    line = one_line(err)
    assert rc == 2 and f"field {check!r}" in line and words in line
    assert not (tmp_path / "out").exists()
