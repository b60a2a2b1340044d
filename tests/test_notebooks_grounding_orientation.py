"""Notebooks 01 and 02: parameters cells match params/*.yaml; both run on the mini-world."""

from __future__ import annotations

import ast

import nbformat
import pytest
import yaml

from resti_lib import paths
from resti_lib.run.notebooks import notebook_parameters, run_notebook
from resti_lib.tasks.base import COMMON_KEYS

NOTEBOOKS = {"01_grounding": "grounding", "02_orientation": "orientation"}


@pytest.mark.parametrize("nb, name", sorted(NOTEBOOKS.items()))
def test_parameters_cell_declares_every_yaml_key(nb, name):
    declared = notebook_parameters(paths.NOTEBOOKS / f"{nb}.ipynb")
    own = yaml.safe_load((paths.PARAMS / f"{name}.yaml").read_text())
    assert set(COMMON_KEYS) | set(own) == set(declared)
    for k, v in own.items():
        assert ast.literal_eval(declared[k]["default"]) == v, k
    defaults = {k: ast.literal_eval(declared[k]["default"]) for k in COMMON_KEYS}
    assert defaults["legacy_benchmark"] == "outputs/miniworld/legacy/qa.parquet"
    assert defaults["scannet_root"] == "outputs/miniworld/scannet/scans"
    assert defaults["waymo_root"] == "outputs/miniworld/waymo"
    assert defaults["omni6d_root"] == "outputs/miniworld/omni6d"
    nbk = nbformat.read(paths.NOTEBOOKS / f"{nb}.ipynb", as_version=4)
    assert nbk.metadata["kernelspec"]["name"] == "python3"
    assert all(not c.get("outputs") and not c.get("execution_count") for c in nbk.cells if c.cell_type == "code")
    params_cell = next(c for c in nbk.cells if "parameters" in c.metadata.get("tags", []))
    comments = [line.split("#", 1)[1] for line in params_cell.source.splitlines() if "#" in line]
    assert not any(ch in c for c in comments for ch in "'\"()")


@pytest.mark.notebook
def test_notebooks_run_on_the_miniworld(miniworld, tmp_path):
    w = miniworld
    params = {"legacy_benchmark": str(w / "legacy" / "qa.parquet"), "scannet_root": str(w / "scannet" / "scans"),
              "waymo_root": str(w / "waymo"), "omni6d_root": str(w / "omni6d"), "output_dir": str(tmp_path / "out")}
    for nb in NOTEBOOKS:
        run = run_notebook(paths.NOTEBOOKS / f"{nb}.ipynb", params, out_dir=tmp_path / "nb", html_dir=tmp_path / "html")
        assert run.html.exists()
    figs = sorted(p.name for p in (tmp_path / "out" / "figures").glob("*.png"))
    assert figs == ["01_grounding_distances.png", "01_grounding_topdown.png", "02_orientation_endpoints.png",
                    "02_orientation_legacy_vs_operators.png"]
    hyp = (tmp_path / "out" / "tables" / "01_grounding_hypotheses.csv").read_text().splitlines()
    assert hyp[0] == "source,hypothesis,rows" and any(line.startswith("ScanNet,alignment_omitted,") for line in hyp)
    conv = (tmp_path / "out" / "tables" / "02_orientation_conventions.csv").read_text().splitlines()
    assert conv[0].startswith("convention,description,ScanNet,Waymo,ALL")
    for slug in ("3d-video-grounding", "ego-centric-orientation"):
        assert (tmp_path / "out" / "tasks" / slug / "accepted.jsonl").exists()
