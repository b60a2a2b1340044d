"""Speed & Acceleration: named statistic, legacy construction diagnosis, acceleration estimator; mini-world."""

from __future__ import annotations

import math

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from resti_lib.geometry.frames import make_T
from resti_lib.sources import waymo as W
from resti_lib.tasks import speed as S
from resti_lib.tasks.run import run_task
from tests import scalar_helpers as H
from tests.helpers import row, write_legacy
from tests.test_sources_scannet import P0, write_scene, write_sens
from tests.test_sources_scannet import SCENE as SN_SCENE
from tests.test_sources_waymo import SEG, T0, write_segment

TASK = "Speed & Acceleration"


def _cands(v: float, unit: str) -> dict:
    return {k: f"{v * f:.2f}{unit}" for k, f in zip("ABCDE", (1.0, 1.5, 2.0, 2.5, 3.0))}


def _accelerating_box(root):
    """obj-a accelerates at 2 m/s^2 along vehicle +X: centre x = 5 + 10 t + t^2, annotated speed 10 + 2 t."""
    n = 5
    t = np.arange(n) * 0.1
    micros = T0 + np.arange(n) * 100_000
    box = {W.KEY_SEGMENT: [SEG] * n, W.KEY_MICROS: micros, W.KEY_OBJECT: ["obj-a"] * n,
           W.BOX_COLUMNS["cx"]: 5.0 + 10.0 * t + t * t, W.BOX_COLUMNS["cy"]: [0.0] * n,
           W.BOX_COLUMNS["cz"]: [1.0] * n, W.BOX_COLUMNS["length"]: [4.5] * n, W.BOX_COLUMNS["width"]: [2.0] * n,
           W.BOX_COLUMNS["height"]: [1.6] * n, W.BOX_COLUMNS["heading"]: [0.0] * n,
           W.BOX_COLUMNS["type"]: pa.array([1] * n, pa.int8()),
           W.BOX_OPTIONAL["speed_x"]: 10.0 + 2.0 * t, W.BOX_OPTIONAL["speed_y"]: [0.0] * n,
           W.BOX_OPTIONAL["speed_z"]: [0.0] * n}
    pq.write_table(pa.table(box), root / "lidar_box" / f"{SEG}.parquet")


@pytest.fixture(scope="module")
def hand(tmp_path_factory):
    """ScanNet camera on a right angle: (0,0) -> (1,0) -> (1,1) m at 30 Hz, so over two frames the
    displacement is sqrt(2) m and the path 2 m: displacement / dt = 21.21 m/s, path / dt = 30 m/s."""
    base = tmp_path_factory.mktemp("speed")
    write_scene(base / "scans")
    poses = [make_T(P0[:3, :3], [x, y, 0.5]) for x, y in ((0, 0), (1, 0), (1, 1))]
    write_sens(base / "scans" / SN_SCENE / f"{SN_SCENE}.sens", poses)
    write_segment(base / "waymo")
    _accelerating_box(base / "waymo")
    q = "What is the average speed of the camera from 0s to 0.066667s?"
    v, s = math.sqrt(2) * 15, 30.0
    sn = f"{SN_SCENE}.mp4"
    rows = [row(TASK, "ScanNet", sn, i, _cands(val, "m/s"), "A", question=q, t0=0.0, t1=0.066667)
            for i, val in enumerate((v, v, s, 50.0))]
    rows.append(row(TASK, "ScanNet", sn, 4, _cands(v, "m/s"), "A", t0=0.0, t1=0.066667,
                    question="What is the magnitude of the average velocity of the camera from 0s to 0.066667s?"))
    rows.append(row(TASK, "Waymo", f"{SEG}_camera_1.mp4", 0, _cands(2.0, "m/s²"), "A", t0=0.0, t1=0.4,
                    question="How quickly is the grey sedan accelerating from 0s to 0.4s?"))
    write_legacy(rows, base / "qa.parquet")
    params = {"legacy_benchmark": str(base / "qa.parquet"), "scannet_root": str(base / "scans"),
              "waymo_root": str(base / "waymo"), "omni6d_root": "", "scannet_fps": 30, "omni6d_fps": 30,
              "video_map": "", "seed": 0, "output_dir": str(base / "out"), "rule": {"abs_tol": 0.002, "rel_tol": 0.0}}
    run = run_task(TASK, params)
    return run, {(o.source, o.legacy_id): o for o in run.outcomes}


def test_statistic_hypotheses_by_hand(hand):
    _, o = hand
    h = o[("ScanNet", 0)].evidence["hypotheses"]
    assert h["displacement_over_time"] == pytest.approx(math.sqrt(2) / 0.066667)  # dt is the asked interval
    assert h["path_over_time"] == pytest.approx(2 / 0.066667)
    g = o[("ScanNet", 0)].evidence["construction_statistic"]
    assert (g["n_velocity_only"], g["n_speed_only"], g["n_neither"], g["statistic"]) == (2, 1, 1, "average_velocity")


def test_displacement_over_time_rows_are_retained_and_flagged(hand):
    _, o = hand
    for i in (0, 1):
        x = o[("ScanNet", i)]
        assert x.verdict == "retained" and x.contract["operator"] == "average_velocity"
        assert {"statistic_unnamed", "speed_is_displacement_over_time"} <= set(x.defects)
        assert x.question.startswith("What is the magnitude of the average velocity of the camera between t=0 s")
        assert "endpoint displacement divided by elapsed time? (unit: m/s)" in x.question


def test_true_average_speed_row_keeps_its_statistic(hand):
    _, o = hand
    x = o[("ScanNet", 2)]
    assert x.verdict == "retained" and x.contract["operator"] == "average_speed"
    assert "speed_is_displacement_over_time" not in x.defects and x.answer.value == pytest.approx(2 / 0.066667)
    assert "total distance traveled along its path divided by elapsed time" in x.question


def test_wrong_row_is_corrected_under_the_construction_statistic(hand):
    _, o = hand
    x = o[("ScanNet", 3)]
    assert x.verdict == "corrected" and x.answer.value == pytest.approx(math.sqrt(2) / 0.066667)
    assert {"value_mismatch", "speed_is_displacement_over_time", "statistic_unnamed"} <= set(x.defects)


def test_named_statistic_has_no_statistic_defect(hand):
    _, o = hand
    x = o[("ScanNet", 4)]
    assert x.verdict == "retained" and "statistic_unnamed" not in x.defects
    assert "construction_statistic" not in x.evidence


def test_split_table(hand):
    run, _ = hand
    t = S.statistic_split(run).set_index("source")
    assert t.loc["ScanNet", "average_speed_rows"] == 4
    assert (t.loc["ScanNet", "valid_under_clarified"], t.loc["ScanNet", "changed"]) == (3, 1)


def test_acceleration_from_annotated_velocities(hand):
    _, o = hand
    x = o[("Waymo", 0)]
    assert x.verdict == "retained" and x.answer.value == pytest.approx(2.0) and x.answer.unit == "m/s²"
    ev = x.evidence["acceleration"]
    assert ev["estimator"] == S.EST_STORED
    # central differences are one-sided at the track ends: (10.7 - 10.1) / 0.4 = 1.5 m/s^2
    assert ev["central_difference_check"] == pytest.approx(1.5)
    assert "annotated 3D-box velocities" in x.question and x.question.endswith("(unit: m/s²)")


def test_acceleration_interval_ending_in_invalid_poses_is_shortened_in_the_question(tmp_path):
    # ScanNet camera: frames 0 and 1 valid (1 m apart along raw +Y), frame 2 invalid. The asked end
    # t=2/30 s lies in the trailing invalid pose: the interval becomes [0, 1/30] s, where the
    # forward and backward differences both give 30 m/s, so the mean acceleration is 0 m/s^2.
    write_scene(tmp_path / "scans")
    rows = [row(TASK, "ScanNet", f"{SN_SCENE}.mp4", 0, _cands(0.5, "m/s²"), "A", t0=0.0, t1=0.066667,
                question="How quickly is the camera accelerating from 0s to 0.066667s?")]
    write_legacy(rows, tmp_path / "qa.parquet")
    params = {"legacy_benchmark": str(tmp_path / "qa.parquet"), "scannet_root": str(tmp_path / "scans"),
              "waymo_root": "", "omni6d_root": "", "scannet_fps": 30, "omni6d_fps": 30, "video_map": "", "seed": 0,
              "output_dir": str(tmp_path / "out"), "rule": {"abs_tol": 0.002, "rel_tol": 0.0}}
    (o,) = run_task(TASK, params).outcomes
    assert o.contract["operator"] == "acceleration" and o.answer.value == pytest.approx(0.0, abs=1e-9)
    assert o.evidence["acceleration"]["shortened_to"] == pytest.approx(1 / 30)
    assert o.time_end == pytest.approx(1 / 30) and o.contract["times"][1] == pytest.approx(1 / 30)
    assert "between t=0 s and t=0.033333 s" in o.question


# ----------------------------------------------------------------------------- the mini-world


@pytest.fixture(scope="module")
def speed_run(miniworld, tmp_path_factory):
    return H.run_with_yaml(TASK, "speed", miniworld, tmp_path_factory.mktemp("speed_out"))


@pytest.fixture(scope="module")
def man(miniworld):
    return H.manifest(miniworld)


def test_miniworld_defects_verdicts_values(speed_run, man, miniworld):
    unseen = H.unseen_subject_rows(speed_run, man, miniworld) | H.source_ambiguous_rows(speed_run, man, miniworld)
    assert unseen == set()  # the generator takes only subjects seen in the interval
    assert [m for m in H.defect_mismatches(speed_run, man) if m[0] not in unseen] == []
    assert [m for m in H.verdict_mismatches(speed_run, man) if m[0] not in unseen] == []
    assert H.value_mismatches(speed_run, man) == []


def test_miniworld_statistic_split(speed_run, man):
    t = S.statistic_split(speed_run)
    assert set(t["construction_statistic"]) == {"average_velocity"}
    for _, r in t.iterrows():
        rows = [m for m in man if m["task"] == TASK and m["source"] == r["source"]
                and "speed_is_displacement_over_time" in m["defects"]]
        assert r["average_speed_rows"] == len(rows)
        assert r["changed"] == sum(m["expected_verdict"] == "corrected" for m in rows)


def test_miniworld_exclusions_and_questions(speed_run):
    assert H.exclusion_problems(speed_run) == []
    for r in speed_run.result.accepted:
        q = r["Question"]
        assert "(unit: m/s" in q and ("divided by elapsed time" in q)


def test_miniworld_no_significant_attack_and_valid_options(speed_run):
    assert H.significant_attacks(speed_run) == []
    assert H.structural_failures(speed_run) == []
