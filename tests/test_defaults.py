"""Defaults written once: params/*.yaml is the single source of every task and operator default.

The task notebooks' parameters cells must carry the same values as the YAML files the main job
passes them; an operator setting repeated in a task's YAML must equal its default in
params/measure.yaml unless the task declares it a deliberate override; no module of the task or
measure layers keeps its own table of defaults.
"""

from __future__ import annotations

import ast

import pytest
import yaml

from resti_lib import paths
from resti_lib.run.notebooks import notebook_parameters
from resti_lib.tasks import names as _task_names
from resti_lib.tasks import task_for
from resti_lib.tasks.base import COMMON_KEYS

TASK_NAMES = _task_names()


def _yaml(name: str) -> dict:
    return yaml.safe_load((paths.PARAMS / f"{name}.yaml").read_text()) or {}


def _notebook(task) -> str:
    hits = sorted(paths.NOTEBOOKS.glob(f"[0-9][0-9]_{task.params_name}.ipynb"))
    assert len(hits) == 1, (task.name, hits)
    return hits[0]


@pytest.mark.parametrize("task_name", TASK_NAMES)
def test_notebook_parameters_equal_the_yaml(task_name):
    task = task_for(task_name)
    want = {**{k: _yaml("default")[k] for k in COMMON_KEYS}, **_yaml(task.params_name)}
    got = {k: ast.literal_eval(v["default"]) for k, v in notebook_parameters(_notebook(task)).items()}
    assert set(got) == set(want), sorted(set(got) ^ set(want))
    diff = {k: (got[k], want[k]) for k in want if got[k] != want[k]}
    assert diff == {}


@pytest.mark.parametrize("task_name", TASK_NAMES)
def test_operator_settings_of_a_task_equal_the_operator_defaults(task_name):
    task = task_for(task_name)
    measure = _yaml("measure")
    own = _yaml(task.params_name)
    differ = sorted(k for k in set(own) & set(measure) if own[k] != measure[k])
    assert differ == sorted(task.setting_overrides)


def test_task_settings_are_the_yaml():
    # a task reads its defaults from its params file: nothing given, nothing else
    for name in TASK_NAMES:
        t = task_for(name)
        common = {k: _yaml("default")[k] for k in COMMON_KEYS}
        assert t.settings({}) == {**common, **_yaml(t.params_name)}
        assert t.settings({"seed": 3})["seed"] == 3


def test_no_module_keeps_a_second_table_of_defaults():
    files = sorted((paths.ROOT / "resti_lib" / "tasks").glob("*.py")) + \
        sorted((paths.ROOT / "resti_lib" / "measure").glob("*.py")) + [paths.ROOT / "resti_lib" / "sources" / "referents.py"]
    found = []
    for f in files:
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.Assign):
                for tgt in node.targets:
                    if isinstance(tgt, ast.Name) and "DEFAULT" in tgt.id:
                        found.append(f"{f.name}:{tgt.id}")
    assert found == []
