"""One conformance suite over every registered task (and a toy ninth task defined in tests/toy_task.py).

Each task is its own single descriptor: its params file, notebook, stage, figures, answer kind, rule
and question reader are read from the registry by everything else. The toy task goes through the
shared path, the release, ``resti verify`` and the report's tables and figure registry, touching no
module of the package. The option path carries the run's params from the task run into
``release.json`` and back into ``verify`` and ``reoption`` (two bugs of that path have a test here).
"""

from __future__ import annotations

import json
import re

import nbformat
import pandas as pd
import pytest
import yaml

from resti_lib import SOURCES, paths
from resti_lib import values as V
from resti_lib.adjudicate import Rule
from resti_lib.io.benchmark import legacy_row_keys, load_release
from resti_lib.options.spec import Interface, TaskInterface, load_option_params, spec_of
from resti_lib.release.assemble import assemble
from resti_lib.release.verify import verify_path
from resti_lib.report import statistics as S
from resti_lib.report.figures import figure_specs
from resti_lib.run.plan import main_config
from resti_lib.tasks import all_tasks, interface, names, register_task, task_for
from resti_lib.tasks.base import Task
from resti_lib.tasks.run import run_rows
from tests.helpers import row, write_legacy
from tests.test_sources_scannet import SCENE, write_scene
from tests.toy_task import TOY, ToyRange, toy_registered

BUILTIN = [t.name for t in all_tasks()]


def test_eight_builtin_tasks_in_benchmark_order():
    assert len(BUILTIN) == 8 and len(set(BUILTIN)) == 8
    assert [task_for(n).order for n in BUILTIN] == sorted(task_for(n).order for n in BUILTIN)


@pytest.mark.parametrize("name", BUILTIN)
def test_builtin_descriptor(name):
    t = task_for(name)
    assert t.descriptor_problems() == []
    # its params file and notebook exist; every key of the params file is a notebook parameter
    params = yaml.safe_load((paths.PARAMS / f"{t.params_name}.yaml").read_text())
    nb = nbformat.read(paths.NOTEBOOKS / f"{t.notebook}.ipynb", as_version=4)
    cell = next(c for c in nb.cells if "parameters" in c.metadata.get("tags", []))
    declared = {line.split(":", 1)[0].strip() for line in cell.source.splitlines() if ":" in line}
    assert set(params) <= declared
    # the notebook audits this task (its name is read from the task's module, not written there)
    code = "".join(c.source for c in nb.cells)
    alias = re.search(rf"resti_lib\.tasks import {t.notebook.split('_', 1)[1]} as (\w+)", code).group(1)
    assert f"run_task({alias}.TASK" in code
    # the main job runs it in the first wave, or the wave after the tasks it follows, with its params file
    stages = {s["notebook"]: s for s in main_config()["stages"]}
    stage = stages[t.notebook]
    followed = [task_for(x).notebook for x in t.follows]
    assert stage["wave"] == 1 + max((stages[n]["wave"] for n in followed), default=0)
    assert stage["needs"] == followed and stage["params"].endswith(f"{t.params_name}.yaml")
    # the report shows its figures under "Tasks"
    specs = {s.pattern: s for s in figure_specs()}
    for suffix in t.figures:
        assert specs[f"{t.notebook}_{suffix}"].section == "Tasks"
    # the answer interface knows its kind and a rule per source
    ti = interface().task(name)
    assert ti.kind == t.answer_kind and set(ti.rules) == set(SOURCES)


def test_registration_validates_and_refuses_a_duplicate():
    class Nameless(Task):
        pass

    with pytest.raises(ValueError, match="no task name"):
        register_task(Nameless)

    class Again(ToyRange):
        name = BUILTIN[0]

    with pytest.raises(ValueError, match="already registered"):
        register_task(Again)

    class SameNotebook(ToyRange):
        name = "Another toy"
        notebook = task_for(BUILTIN[0]).notebook
        params_name = task_for(BUILTIN[0]).params_name

    with pytest.raises(ValueError, match="already used"):
        register_task(SameNotebook)
    assert names() == tuple(BUILTIN)


def _toy_legacy(tmp):
    q = "How far is the camera from the scan origin at t={} s?"
    rows = [row(task=TOY, video=f"{SCENE}.mp4", rid=i, question=q.format(t), detail=d, t0=0.0, t1=0.0,
                cands={"A": d, "B": "1.00m", "C": "2.00m", "D": "4.00m", "E": "5.00m"}, answer="A")
            for i, (t, d) in enumerate([("0", "3.20m"), ("0.0333", "3.20m"), ("0.0667", "3.20m")])]
    path = write_legacy(rows, tmp / "qa.parquet")
    df = pd.DataFrame(rows)
    df["row"] = range(len(df))
    df["Legacy Row Key"] = legacy_row_keys(rows)
    return path, df


@pytest.fixture(scope="module")
def toy_release(tmp_path_factory):
    """The toy task audited, assembled into a release (with its verify) while it is registered."""
    base = tmp_path_factory.mktemp("toy_release")
    write_scene(base / "scans")
    legacy_path, df = _toy_legacy(base)
    params = {"scannet_root": str(base / "scans"), "seed": 0, "output_dir": str(base / "out")}
    with toy_registered():
        run = run_rows(TOY, df, params)
        validation = assemble(legacy_path, base / "out" / "tasks", base / "out" / "release")
        rel = load_release(base / "out" / "release", known_tasks=names())
        prov = pd.read_parquet(base / "out" / "release" / "provenance.parquet")
        tables = {"coverage": S.coverage_table(prov), "verdicts": S.verdict_table(prov),
                  "reference": S.reference_comparison(validation, validation)}
        specs = {s.pattern: s for s in figure_specs()}
        stages = [s["notebook"] for s in main_config()["stages"]]
        reverify = verify_path(base / "out" / "release")
    return run, validation, rel, tables, specs, stages, reverify


def test_toy_task_goes_through_release_verify_and_report(toy_release):
    run, validation, rel, tables, specs, stages, reverify = toy_release
    # the release holds the toy's two accepted rows and its exclusion: every legacy row once
    assert validation["passed"] and reverify["passed"]
    assert validation["by_task"] == {TOY: 2} and validation["excluded_by_task"] == {TOY: 1}
    assert sorted(rel.accepted["Task"]) == [TOY, TOY]
    # release.json records the interface the options were built with, and verify read it back
    meta = json.loads((rel.root / "release.json").read_text())
    assert set(meta["answer_interface"]["rules"]) == {TOY}
    assert reverify["answer_interface"] == "release.json answer_interface"
    # the report's tables name it, and its declared figure and its stage are registered
    cov = tables["coverage"].set_index("task")
    assert cov.loc[TOY, "accepted"] == 2 and cov.loc[TOY, "excluded"] == 1
    assert TOY in set(tables["reference"]["task"])
    assert specs["09_toy_range_ranges"].section == "Tasks"
    assert "09_toy_range" in stages
    # the registry is back to the eight built-in tasks once the toy is unregistered
    assert TOY not in names()


# ------------------------------------------------------------------------ one option path (bugs)

def _dimension_row(task_name: str) -> dict:
    return row(task=task_name, question="What is the length of the table? (unit: m)", detail="0.54m",
               cands={"A": "0.54m", "B": "0.20m", "C": "0.90m", "D": "1.30m", "E": "2.10m"}, answer="A")


def test_spec_uses_the_run_rule_not_the_default_params():
    """Before: ``task_rule`` read params/<task>.yaml behind the run's back, so a rule given to the run
    came back as the default Rule(0.002, 0.002)."""
    name = "Dimensional Measurement"
    given = Rule(0.5, 0.1)
    iface = Interface(load_option_params(), {name: TaskInterface("scalar", {s: given for s in SOURCES},
                                                                 task_for(name).quantity_of)})
    spec = spec_of(_dimension_row(name), "r0", iface=iface)
    assert spec.rule == given and spec.obs.quantity == "length"
    # the task's own rule under a run's params (here: what papermill -y "rule: {...}" passes)
    ti = task_for(name).interface(task_for(name).settings({"rule": {"abs_tol": 0.3, "rel_tol": 0.002}}))
    assert ti.rule("ScanNet") == Rule(0.3, 0.002)


def test_run_rule_reaches_the_options_and_verify(miniworld, tmp_path):
    """A Dimensional run with a 0.3 m tolerance: every pair of its candidates is farther apart than the
    rule (so no two agree under the user's own rule), the task records the rule, and the release
    verifies against it."""
    from tests.task_checks import miniworld_params

    name = "Dimensional Measurement"
    params = miniworld_params(miniworld, tmp_path / "out", rule={"abs_tol": 0.3, "rel_tol": 0.002})
    run = run_rows(name, _task_rows(miniworld, name), params)
    rec = json.loads((run.out_dir / "interface.json").read_text())
    assert rec["rules"][name]["ScanNet"] == {"abs_tol": 0.3, "rel_tol": 0.002}
    assert run.result.accepted
    for r in run.result.accepted:
        vals = sorted(V.parse(s).si for s in r["Candidates"].values())
        ulp = 10.0 ** -V.parse(r["Answer Detail"]).decimals * V.parse(r["Answer Detail"]).si_per_unit
        for a, b in zip(vals, vals[1:]):  # by hand: adjacent candidates differ by more than the rule allows
            assert b - a > 0.5 * ulp + 0.3 + 0.002 * b - 1e-9, (r["ReSTI ID"], vals)


def _task_rows(world, name):
    from resti_lib.io.benchmark import load_legacy

    df, _ = load_legacy(world / "legacy" / "qa.parquet", strict=False, tasks=[name], known_tasks=names())
    return df[df["Task"] == name]


def test_reoption_with_option_overrides_verifies(tmp_path):
    """Before: reoption built with the override but verify checked against params/options.yaml and
    refused its own output (``fails verification: separation``)."""
    from resti_lib.release.reoption import reoption_release

    src = _tiny_release(tmp_path)
    over = {"separation": {"scalar": {"min_rel_gap": 0.0}}, "adversarial": {"rounds": 0}}
    res = reoption_release(src, tmp_path / "out", seed=0, options=over)
    assert res.validation["passed"]
    meta = json.loads((tmp_path / "out" / "release.json").read_text())
    assert meta["answer_interface"]["options"]["separation"]["scalar"]["min_rel_gap"] == 0.0
    again = verify_path(tmp_path / "out")
    assert again["passed"] and again["answer_interface"] == "release.json answer_interface"
    # a rebuild of the rebuilt release keeps the recorded params (the override is not lost)
    res2 = reoption_release(tmp_path / "out", tmp_path / "out2", seed=1)
    assert res2.meta["answer_interface"]["options"]["separation"]["scalar"]["min_rel_gap"] == 0.0


def _tiny_release(tmp_path):
    from tests.helpers import seal_release, write_release
    from tests.test_reoption import _tiny_rows

    key = "ScanNet|Spatial Relation|v.mp4|0|uid=00000000000000aa"
    return seal_release(write_release(_tiny_rows(), [{"key": key, "legacy_id": 0, "legacy_video": "v.mp4",
                                                      "source": "ScanNet", "task": "Spatial Relation",
                                                      "reason_codes": ["unsupported_question"]}],
                                      tmp_path / "in"))


# ------------------------------------------------------------------- a rebuild never aborts (issue 19)

def test_reoption_excludes_a_row_it_cannot_option_instead_of_aborting(tmp_path):
    """Options that no set can meet (candidates five times their value apart) exclude the scalar rows
    by name (no_valid_options) instead of stopping the rebuild; every input row is still accounted
    for, and the other rows ship their options."""
    from resti_lib.io.files import read_jsonl
    from resti_lib.release.reoption import reoption_release

    src = _tiny_release(tmp_path)
    n_in = len(read_jsonl(src / "resti.jsonl"))
    n_exc_in = len(read_jsonl(src / "excluded.jsonl"))
    res = reoption_release(src, tmp_path / "out", seed=0, options={"separation": {"scalar": {"min_rel_gap": 5.0}},
                                                                  "adversarial": {"rounds": 0}})
    exc = read_jsonl(tmp_path / "out" / "excluded.jsonl")
    new = [r for r in exc if r["reason_codes"] == ["no_valid_options"]]
    scalar_rows = [r for r in read_jsonl(src / "resti.jsonl")
                   if isinstance(V.parse(r["Answer Detail"]), V.Scalar) and not V.parse(r["Answer Detail"]).is_angle]
    assert len(new) == len(scalar_rows) > 0
    assert all(r["verification_evidence"]["option_error"] for r in new)
    assert len(res.rows) + len(exc) == n_in + n_exc_in  # nothing lost
    assert res.validation["passed"]


def test_offsets_leave_out_the_rows_own_value_and_its_copies():
    """Class offsets: a row's copies (same class, same value) never enter its own offset."""
    import numpy as np

    from resti_lib.options.population import hierarchical_offsets

    keys = [("q", "cup"), ("q", "cup"), ("q", "cup"), ("q", "bowl")]
    b0 = np.array([1.0, 1.0, 3.0, 5.0])
    off = hierarchical_offsets(keys, b0, kappa=1.0)
    # distinct entries: (cup,1), (cup,3), (bowl,5). For a cup row of value 1: the other distinct
    # entries are 3 and 5; quantity level: mean of (3, 5) over 2 = 4, shrunk to the all-mean 4
    # -> (8 + 1*4) / (2 + 1) = 4; class level: cup entries other than itself: (3), so (3 + 1*4) / (1 + 1) = 3.5
    assert off[0] == off[1] == 3.5
    # the cup of value 3: others (1, 5): all-mean 3; quantity (6 + 3) / 3 = 3; class (1 + 3) / 2 = 2
    assert off[2] == 2.0


def test_offsets_take_other_recordings_box_edges_of_the_class():
    """Class offsets with extra evidence (the box edges of the same classes in another task): an entry
    of the row's own recording never enters its offset, nor one equal to a row's own (key, value)."""
    import numpy as np

    from resti_lib.options.population import hierarchical_offsets

    keys = [("q", "sedan"), ("q", "bus")]
    b0 = np.array([1.0, 3.0])
    extra = ([("q", "sedan"), ("q", "sedan"), ("q", "bus"), ("q", "sedan")], [2.0, 6.0, 5.0, 1.0],
             ["g1", "g2", "g3", "g2"])
    off = hierarchical_offsets(keys, b0, 1.0, groups=["g1", "g3"], extra=extra)
    # the sedan row (recording g1): its own box (2.0, g1) and the copy of its value (1.0) stay out.
    # Entries left: bus 3, sedan 6, bus 5 -> all-mean 14/3; quantity (14 + 14/3) / (3 + 1) = 14/3;
    # class: sedan 6 alone -> (6 + 14/3) / (1 + 1) = 16/3
    assert abs(off[0] - 16 / 3) < 1e-12
    # the bus row (g3): its own box (5.0) stays out. Entries: sedan 1, 2, 6 -> all-mean 3; quantity 3;
    # class: no other bus -> (0 + 3) / (0 + 1) = 3
    assert abs(off[1] - 3.0) < 1e-12
    # without the extra evidence: the sedan's class has no other entry, so it takes the mean of the bus (3)
    assert hierarchical_offsets(keys, b0, 1.0)[0] == 3.0
