"""The package, tests and benchmarks pass the pinned linter with the project's rule set
(``[tool.ruff.lint]`` in pyproject.toml), as ``make lint`` runs it."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def test_lint_is_clean():
    ruff = Path(sys.executable).with_name("ruff")
    exe = str(ruff) if ruff.exists() else shutil.which("ruff")
    if exe is None:
        pytest.skip("ruff is not installed (make venv installs the pinned version)")
    r = subprocess.run([exe, "check", "resti_lib", "tests", "bench"], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-3000:]
