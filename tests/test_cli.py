"""The command line: one-line errors for bad params, paths from the current directory, help for every
command (with the stage and attack names), an empty --only refused, no traceback on a closed pipe."""

import os
import subprocess
import sys

import pytest

from resti_lib import paths
from tests.helpers import row, write_release

COMMANDS = ("verify", "attack", "reoption", "measure", "synth", "run")


class Result:
    def __init__(self, returncode, stdout, stderr):
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


@pytest.fixture
def resti(capsys, monkeypatch):
    """``resti ARGS`` in this process (from ``cwd``): exit code, stdout and stderr."""
    from resti_lib.run.cli import main

    def call(*args, cwd=None):
        monkeypatch.chdir(cwd or paths.ROOT)
        capsys.readouterr()
        try:
            rc = main(list(args))
        except SystemExit as e:  # argparse: --help and usage errors
            rc = e.code
        out = capsys.readouterr()
        return Result(rc, out.out, out.err)
    return call


def one_line_error(r) -> str:
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    return lines[0]


def test_missing_params_file_is_one_line(resti, tmp_path):
    line = one_line_error(resti("run", "--params", "nope.yaml", cwd=tmp_path))
    assert "params file not found" in line and str(tmp_path / "nope.yaml") in line


@pytest.mark.parametrize("text, what", [("a: [1, 2\nb: 3\n", "not valid YAML at line"),
                                        ("key: value\n  - broken: [\n", "not valid YAML at line"),
                                        ("- just\n- a list\n", "params must be a mapping")])
def test_malformed_params_file_is_one_line(resti, tmp_path, text, what):
    (tmp_path / "bad.yaml").write_text(text)
    line = one_line_error(resti("run", "--params", "bad.yaml", cwd=tmp_path))
    assert what in line and "bad.yaml" in line


def test_params_path_is_taken_from_the_current_directory(resti, tmp_path):
    # no mine.yaml in the repository root: the one in the current directory is read (its check names it)
    (tmp_path / "mine.yaml").write_text("world_dir: ''\noutput_dirr: out\n")
    r = resti("run", "--params", "mine.yaml", cwd=tmp_path)
    line = one_line_error(r)
    assert r.returncode == 2 and str(tmp_path / "mine.yaml") in line and "did you mean 'output_dir'?" in line


def test_empty_only_is_an_error(resti):
    r = resti("run", "--only")
    assert r.returncode == 2 and "expected at least one argument" in r.stderr and "Traceback" not in r.stderr


def test_unknown_stage_lists_the_stages(resti):
    line = one_line_error(resti("run", "--only", "dimensionl"))
    assert "unknown stage(s) ['dimensionl']" in line and "03_dimensional (dimensional)" in line


@pytest.mark.parametrize("cmd", COMMANDS)
def test_every_command_has_help(resti, cmd):
    r = resti(cmd, "--help")
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith(f"usage: resti {cmd}")


def test_help_lists_stages_and_attacks(resti):
    from resti_lib.options.attacks import ATTACKS

    run_help = " ".join(resti("run", "--help").stdout.split())
    for stage in ("01_grounding (grounding)", "99_release_report", "90_reoption_release (reoption_release, on demand)"):
        assert stage in run_help
    attack_help = " ".join(resti("attack", "--help").stdout.split())
    assert all(name in attack_help for name in ATTACKS)


def test_closed_pipe_ends_quietly(tmp_path):
    rows = [row(rid=i, answer="ABCDE"[i % 5], cands={k: f"{(j + 1) * (i + 1) / 10:.2f}m" for j, k in enumerate("ABCDE")})
            for i in range(20)]
    for r in rows:
        r["Answer Detail"] = r["Candidates"][r["Answer"]]
    rel = write_release(rows, [], tmp_path / "rel")
    rd, wr = os.pipe()
    os.close(rd)  # the reader is gone before the first line is written (`resti attack ... | head`)
    try:
        r = subprocess.run([sys.executable, "-m", "resti_lib.run.cli", "attack", str(rel)], stdout=wr,
                           stderr=subprocess.PIPE, text=True, timeout=300, check=False)
    finally:
        os.close(wr)
    assert "Traceback" not in r.stderr and "BrokenPipe" not in r.stderr, r.stderr
    assert r.returncode == 141
