"""Notebooks 03, 05, 06: parameters cells match params/*.yaml; notebook 06 runs on the mini-world."""

from __future__ import annotations

import ast

import nbformat
import pytest
import yaml

from resti_lib import paths
from resti_lib.run.notebooks import notebook_parameters, run_notebook
from resti_lib.tasks.base import COMMON_KEYS

NOTEBOOKS = {"03_dimensional": "dimensional", "05_displacement": "displacement", "06_speed": "speed"}


@pytest.mark.parametrize("nb, name", sorted(NOTEBOOKS.items()))
def test_parameters_cell_declares_every_yaml_key(nb, name):
    declared = notebook_parameters(paths.NOTEBOOKS / f"{nb}.ipynb")
    own = yaml.safe_load((paths.PARAMS / f"{name}.yaml").read_text())
    assert set(COMMON_KEYS) | set(own) == set(declared)
    for k, v in own.items():
        assert ast.literal_eval(declared[k]["default"]) == v, k
    assert ast.literal_eval(declared["legacy_benchmark"]["default"]) == "outputs/miniworld/legacy/qa.parquet"
    nbk = nbformat.read(paths.NOTEBOOKS / f"{nb}.ipynb", as_version=4)
    assert nbk.metadata["kernelspec"]["name"] == "python3"
    assert all(not c.get("outputs") and not c.get("execution_count") for c in nbk.cells if c.cell_type == "code")


@pytest.mark.notebook
def test_speed_notebook_runs_on_the_miniworld(miniworld, tmp_path):
    w = miniworld
    params = {"legacy_benchmark": str(w / "legacy" / "qa.parquet"), "scannet_root": str(w / "scannet" / "scans"),
              "waymo_root": str(w / "waymo"), "omni6d_root": str(w / "omni6d"), "output_dir": str(tmp_path / "out")}
    run = run_notebook(paths.NOTEBOOKS / "06_speed.ipynb", params, out_dir=tmp_path / "nb", html_dir=tmp_path / "html")
    assert run.html.exists()
    figs = sorted(p.name for p in (tmp_path / "out" / "figures").glob("*.png"))
    assert figs == ["06_speed_legacy_vs_source.png", "06_speed_statistics.png"]
    split = (tmp_path / "out" / "tables" / "06_speed_statistic_split.csv").read_text().splitlines()
    assert split[0].startswith("source,average_speed_rows,valid_under_clarified,changed")
    assert (tmp_path / "out" / "tasks" / "speed-acceleration" / "accepted.jsonl").exists()
