"""The full blind suite on the public ReSTI v5 release: the leaks an independent review found in every task are
flagged, each by the family that reads its channel. The leaks themselves are counted here by direct
inspection of the rows (a second method), not read back from the attack table."""

import json
import re
from collections import Counter, defaultdict

import pytest

from resti_lib import values as V
from resti_lib.options.attacks import attack_table, headline
from resti_lib.tasks import interface as _interface

IFACE = _interface()


def _obs(r: dict):
    """The observables of a row, its quantity read by its task."""
    from resti_lib.options.observables import observables_of

    return observables_of(r, IFACE.quantity_of(r["Task"], r["Question"]))

pytestmark = [pytest.mark.shared, pytest.mark.slow]


@pytest.fixture(scope="module")
def v5_rows(resti_v5_dir):
    text = (resti_v5_dir / "resti.jsonl").read_text(encoding="utf-8")
    return [json.loads(line) for line in text.splitlines()]


@pytest.fixture(scope="module")
def v5_table(v5_rows):
    return attack_table(iface=IFACE, records=v5_rows, families="all")


def _sig(table, attack, task, source):
    r = table[(table["attack"] == attack) & (table["task"] == task) & (table["source"] == source)]
    return bool(len(r)) and bool(r["significant"].iloc[0])


def test_flags_every_task(v5_table):
    h = headline(v5_table)
    flagged = set(zip(h.loc[h["significant"], "task"], h.loc[h["significant"], "source"]))
    assert len(flagged) >= 27, sorted(set(zip(h["task"], h["source"])) - flagged)
    assert {t for t, _ in flagged} == set(v5_table["task"])  # every task
    assert h["significant"].iloc[:len(flagged)].all()  # significant cells first


def test_metadata_camera_decides_the_waymo_relation(v5_rows, v5_table):
    by_cam = defaultdict(Counter)
    for r in v5_rows:
        if r["Task"] == "Spatial Relation" and r["Source"] == "Waymo":
            by_cam[re.search(r"_camera_(\d)", r["Video"]).group(1)][r["Answer Detail"]] += 1
    assert all(len(c) == 1 and sum(c.values()) > 1 for c in by_cam.values())  # one label per camera
    row = v5_table[(v5_table["attack"] == "metadata_label") & (v5_table["source"] == "Waymo")].iloc[0]
    assert row["significant"] and row["accuracy"] == 1.0


def test_same_video_verbatim_answers_in_waymo_pose(v5_rows, v5_table):
    pose = [r for r in v5_rows if r["Task"] == "Pose Estimation" and r["Source"] == "Waymo"]
    flat = lambda s: "".join(s.split())
    revealed = sum(any(flat(r["Answer Detail"]) in flat(o["Question"]) for o in pose
                       if o["Video"] == r["Video"] and o is not r) for r in pose)
    assert revealed >= 90  # of 121
    row = v5_table[(v5_table["attack"] == "xrow_question") & (v5_table["task"] == "Pose Estimation")
                   & (v5_table["source"] == "Waymo")].iloc[0]
    assert row["significant"] and row["accuracy"] >= revealed / len(pose)


def test_negative_zero_rounding_tell_in_waymo_pose(v5_rows, v5_table):
    pose = [r for r in v5_rows if r["Task"] == "Pose Estimation" and r["Source"] == "Waymo"]
    only = [r for r in pose if sum("-0.0," in c or "-0.0}" in c for c in r["Candidates"].values()) == 1]
    told = sum("-0.0" in r["Answer Detail"] for r in only)
    assert told == len(only) >= 30  # where one candidate prints -0.0, it is the answer
    assert _sig(v5_table, "fmt_negative_zero", "Pose Estimation", "Waymo")


def test_distractors_listed_around_the_answer_in_scalar_tasks(v5_table):
    for task, sources in [("Displacement & Path Length", ["ScanNet", "Waymo", "Omni6DPose"]),
                          ("Speed & Acceleration", ["ScanNet", "Waymo", "Omni6DPose"]),
                          ("Ego-Centric Orientation", ["ScanNet", "Waymo"]),
                          ("Dimensional Measurement", ["ScanNet", "Omni6DPose"])]:
        for s in sources:
            assert _sig(v5_table, "letter_order", task, s), (task, s)


def test_box_rotation_typicality_and_relation_label_order(v5_table):
    assert _sig(v5_table, "typical_box_rotation", "3D Video Grounding", "ScanNet")
    assert _sig(v5_table, "typical_box_rotation", "3D Video Grounding", "Waymo")
    assert _sig(v5_table, "label_order", "Spatial Relation", "Omni6DPose")


def test_learned_question_attacker_reaches_the_small_cells(v5_rows, v5_table):
    # Dimensional Waymo has 26 rows: only the learned attacker reaches Holm significance there
    assert _sig(v5_table, "learned_question", "Dimensional Measurement", "Waymo")
    n = sum(r["Task"] == "Dimensional Measurement" and r["Source"] == "Waymo" for r in v5_rows)
    row = v5_table[(v5_table["attack"] == "learned_question") & (v5_table["task"] == "Dimensional Measurement")
                   & (v5_table["source"] == "Waymo")].iloc[0]
    assert row["n_rows"] == n == 26 and row["underpowered"]


def test_implied_rate_is_a_speed_over_the_window(v5_rows):
    """A Displacement distractor implies a speed over the question's window; on v5 the window is stated in
    every Displacement question and the implied speeds of answers stay physical."""
    from resti_lib.options.attacks.features import implied_rate

    speeds = []
    for r in v5_rows:
        if r["Task"] == "Displacement & Path Length" and r["Source"] == "Waymo":
            o = _obs(r)
            assert o.window_s and o.window_s > 0
            kind, v = implied_rate(V.parse(r["Answer Detail"]), o)
            assert kind == "speed"
            speeds.append(v)
    assert max(speeds) < 45.0
