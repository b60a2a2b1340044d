"""The task interface: a ninth task registered from this module alone runs the shared path.

The toy task asks how far the camera is from the scan origin at a time. It supplies only its
contract reader, a measure operator and its diagnosis (the default scalar comparison); the shared
runner makes the outcomes, parses the legacy values, adjudicates, excludes, builds the options and
writes release-style rows with provenance and the option spec.
"""

from __future__ import annotations

import json
import math

import pandas as pd
import pytest

from resti_lib import values as V
from resti_lib.io.benchmark import legacy_row_keys
from resti_lib.measure import evaluate_contract
from resti_lib.tasks import interface, task_for
from resti_lib.tasks.run import run_rows
from tests.helpers import row
from tests.test_sources_scannet import SCENE, write_scene
from tests.toy_task import TOY, ToyRange, toy_registered


def _rows() -> pd.DataFrame:
    q = "How far is the camera from the scan origin at t={} s?"
    rows = [row(task=TOY, video=f"{SCENE}.mp4", rid=i, question=q.format(t), detail=d, t0=0.0, t1=0.0,
                cands={"A": d, "B": "1.00m", "C": "2.00m", "D": "4.00m", "E": "5.00m"}, answer="A")
            for i, (t, d) in enumerate([("0", "3.20m"), ("0.0333", "3.20m"), ("0.0667", "3.20m")])]
    df = pd.DataFrame(rows)
    df["row"] = range(len(df))
    df["Legacy Row Key"] = legacy_row_keys(rows)
    return df


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    with toy_registered():
        yield _toy_run(tmp_path_factory)


def _toy_run(tmp_path_factory):
    base = tmp_path_factory.mktemp("toy")
    write_scene(base / "scans")
    params = {"scannet_root": str(base / "scans"), "seed": 0, "output_dir": str(base / "out")}
    return run_rows(TOY, _rows(), params), params


def test_the_toy_task_is_registered(toy):
    assert isinstance(task_for(TOY), ToyRange)


def test_toy_task_runs_the_shared_path(toy):
    run, _ = toy
    o0, o1, o2 = run.outcomes
    # by hand: P0 = [1, -3, 0.5] -> sqrt(10.25) = 3.2016 m (printed 3.20: retained); P1 = [1, -2, 0.5] at
    # 1/30 s -> sqrt(5.25) = 2.2913 m (the legacy 3.20 is frame 0's value: corrected); frame 2 is invalid
    assert o0.verdict == "retained" and o0.answer.value == pytest.approx(math.sqrt(10.25))
    assert o1.verdict == "corrected" and o1.answer.value == pytest.approx(math.sqrt(5.25))
    assert "value_mismatch" in o1.defects and "unit_tag_missing" in o1.defects
    assert o2.verdict == "excluded" and o2.reasons == ["invalid_pose_at_time"]
    # release-style rows: five candidates, the key is the detail, the ReSTI id names the task
    acc = run.result.accepted
    assert len(acc) == 2 and [r["ID"] for r in acc] == [0, 1]
    for r in acc:
        assert sorted(r["Candidates"]) == list("ABCDE") and r["Candidates"][r["Answer"]] == r["Answer Detail"]
        assert r["ReSTI ID"].startswith("resti-toy-camera-range-") and "unit: m" in r["Question"]
    assert V.parse(acc[1]["Answer Detail"]).value == pytest.approx(2.29, abs=0.005)
    (exc,) = run.result.excluded
    assert exc["reason_codes"] == ["invalid_pose_at_time"] and exc["verification_evidence"]["error"]


def test_toy_provenance_and_option_spec(toy):
    run, _ = toy
    prov = run.result.provenance
    assert list(prov["verdict"]) == ["retained", "corrected", "excluded"]
    spec = json.loads(prov["option_spec"].iloc[1])
    assert spec["kind"] == "scalar" and spec["unit"] == "m" and spec["decimals"] == 2
    assert spec["rule"]["abs_tol"] == 0.0
    assert spec["observables"]["subject"] == "the camera" and spec["observables"]["sequence"] == SCENE
    assert spec["observables"]["time_start"] == pytest.approx(0.0333)
    assert pd.isna(prov["option_spec"].iloc[2])  # excluded rows get none
    c = json.loads(prov["contract"].iloc[1])
    assert c["format"] == {"kind": "scalar", "unit": "m", "decimals": 2}  # the repaired answer's σ
    assert c["legacy"]["format"] == {"kind": "scalar", "unit": "m", "decimals": 2}  # the legacy row's σ
    assert c["legacy"]["missing"] == ["unit"] and c["missing"] == []
    assert c["legacy"]["distractors"]["n_candidates"] == 5 and "params/options.yaml" in c["distractors"]["policy"]
    # the options that ship meet the answer-interface requirements
    from resti_lib.options.checks import ROW_CHECKS, parse_row
    for r in run.result.accepted:
        for name in ("separation", "plausible_given_question", "format_consistency"):
            assert ROW_CHECKS[name](parse_row(r, r["ReSTI ID"], interface())) is None, name
    assert json.loads(prov["source_files"].iloc[0])[0].endswith(".sens")


def test_resti_measure_gives_the_task_value(toy):
    run, params = toy
    r = evaluate_contract({"source": "ScanNet", "sequence": SCENE, "entity": {"kind": "camera"}, "times": [0.0333],
                           "operator": "toy_camera_range"}, params)
    assert r["value"] == pytest.approx(run.outcomes[1].answer.value, abs=0.0)


def test_contract_states_format_and_distractor_policy_of_the_legacy_row():
    from resti_lib.tasks import read_contract

    grid = {"A": "-5.00°", "B": "2.50°", "C": "10.00°", "D": "17.50°", "E": "25.00°"}
    r = row(task="Ego-Centric Orientation", video="scene0900_00.mp4", cands=grid, answer="C",
            question="How much did the camera turn from 1s to 4s?")
    c = read_contract(r)
    assert c.format == {"kind": "angle", "unit": "°", "decimals": 2}  # σ: read from "10.00°"
    assert c.distractors["offsets_from_detail"] == [-15.0, -7.5, 0.0, 7.5, 15.0]  # D: the symmetric grid
    assert c.distractors["findings"] == ["orientation_symmetric_grid"] and c.distractors["key_is_detail"]
    assert {"format", "distractors"} <= set(c.to_dict())
    box = V.format_legacy_box((1.25, 2.35, 3.45), (1.15, 0.85, 0.95), 10.25)
    c = read_contract(row(task="3D Video Grounding", cands={k: box for k in "ABCDE"}, answer="A",
                          question="What is the 3D bounding box of the chair at 3 s?"))
    assert c.format == {"kind": "box", "decimals": 2, "rotation": "heading"}
    assert c.distractors["findings"] == ["duplicate_options_exact"]
