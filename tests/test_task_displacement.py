"""Displacement & Path Length: hand-made rows on hand-made sources, and acceptance on the mini-world."""

from __future__ import annotations

import json

import pytest

from resti_lib import values as V
from resti_lib.adjudicate import Rule
from resti_lib.tasks import displacement as D
from resti_lib.tasks.run import run_task
from resti_lib.tasks.scalar_audit import tie_break_by_legacy
from tests import scalar_helpers as H
from tests.helpers import row, write_legacy
from tests.test_sources_scannet import SCENE as SN_SCENE
from tests.test_sources_scannet import write_scene
from tests.test_sources_waymo import SEG, write_segment

TASK = "Displacement & Path Length"
SN_VIDEO = f"{SN_SCENE}.mp4"
WY_VIDEO = f"{SEG}_camera_1.mp4"


def _cands(v: float, unit: str = "m") -> dict:
    return {k: f"{v * f:.2f}{unit}" for k, f in zip("ABCDE", (1.0, 1.5, 2.0, 2.5, 3.0))}


@pytest.fixture(scope="module")
def hand(tmp_path_factory):
    """Camera 1 m along raw +Y per ScanNet frame (frame 2 invalid); Waymo car parked, box obj-a
    (4.5 x 2 x 1.6 m, a sedan's size) 5 m ahead of it moving 10 m/s forward."""
    base = tmp_path_factory.mktemp("disp")
    write_scene(base / "scans")
    write_segment(base / "waymo")
    rows = [
        row(TASK, "ScanNet", SN_VIDEO, 0, _cands(1.0), "A", question="What is the displacement of the camera "
            "from 0s to 0.033333s?", t0=0.0, t1=0.033333),
        row(TASK, "ScanNet", SN_VIDEO, 1, _cands(1.0), "A", question="What is the total distance traveled by the "
            "camera from 0s to 0.066667s?", t0=0.0, t1=0.066667),
        row(TASK, "ScanNet", SN_VIDEO, 2, _cands(1.0), "A", question="What is the displacement of the camera from "
            "0s to 0s?", t0=0.0, t1=0.0),
        row(TASK, "ScanNet", SN_VIDEO, 3, _cands(1.6), "A", question="What is the displacement of the camera from "
            "0s to 0.033333s?", t0=0.0, t1=0.033333),
        row(TASK, "Waymo", WY_VIDEO, 0, _cands(4.0), "A", question="How far has the grey sedan traveled from 0s "
            "to 0.4s?", t0=0.0, t1=0.4),
        row(TASK, "Waymo", WY_VIDEO, 1, _cands(4.0), "A", question="How far has the car traveled from 0s to 0.4s?",
            t0=0.0, t1=0.4),
        row(TASK, "Waymo", WY_VIDEO, 2, _cands(4.0), "A", question="How far has the white bus traveled from 0s to "
            "0.4s?", t0=0.0, t1=0.4),
    ]
    write_legacy(rows, base / "qa.parquet")
    params = {"legacy_benchmark": str(base / "qa.parquet"), "scannet_root": str(base / "scans"),
              "waymo_root": str(base / "waymo"), "omni6d_root": "", "scannet_fps": 30, "omni6d_fps": 30,
              "video_map": "", "seed": 0, "output_dir": str(base / "out"), "rule": {"abs_tol": 0.002, "rel_tol": 0.0}}
    run = run_task(TASK, params)
    return {o.legacy_id if o.source == "ScanNet" else 10 + o.legacy_id: o for o in run.outcomes}


def test_camera_displacement_by_hand(hand):
    o = hand[0]
    assert o.verdict == "retained" and o.answer.value == pytest.approx(1.0)
    assert o.question == ("What is the displacement (straight-line distance between its start and end positions) "
                          "of the camera between t=0 s and t=0.033333 s? (unit: m)")
    assert "unit_tag_missing" in o.defects and o.evidence["other_operator"]["path_length"] == pytest.approx(1.0)


def test_trailing_invalid_pose_shortens_the_interval(hand):
    o = hand[1]
    assert o.answer.value == pytest.approx(1.0) and o.evidence["geometry"]["shortened_to"] == pytest.approx(1 / 30)
    assert o.time_end == pytest.approx(1 / 30) and "t=0.033333 s" in o.question
    assert o.frames["frames"] == [0, 1] and o.frames["shortened_to"] == pytest.approx(1 / 30)


def test_zero_length_and_value_mismatch(hand):
    assert hand[2].reasons == ["zero_length_interval"] and "zero_length_interval" in hand[2].defects
    assert hand[3].verdict == "corrected" and "value_mismatch" in hand[3].defects


def test_waymo_object_track_by_description(hand):
    o = hand[10]
    assert o.verdict == "retained" and o.answer.value == pytest.approx(4.0)  # 10 m/s for 0.4 s
    assert o.contract["entity"]["id"] == "obj-a" and o.contract["operator"] == "path_length"
    assert o.evidence["visible_samples"] >= 1 and "box centre" in o.question
    assert o.frames["frame_timestamp_micros"] == [1_552_440_195_362_591, 1_552_440_195_762_591]


def test_ambiguous_subject_and_no_source(hand):
    o = hand[11]
    assert o.reasons == ["ambiguous_subject"] and "ambiguous_subject" in o.defects
    assert o.evidence["camera_value_si"] == pytest.approx(0.0)  # the recording car is parked
    assert o.evidence["object_candidates"][0]["value_si"] == pytest.approx(4.0)
    assert hand[12].reasons == ["no_source_instance"]  # a 4.5 m box is no bus


def test_tie_break_by_legacy_value():
    rule = Rule(abs_tol=0.0, rel_tol=0.0)
    legacy = V.parse("4.00m")
    k, ev = tie_break_by_legacy(["a", "b"], [3.0, 4.0], legacy, "m", rule, enabled=True)
    assert k == 1 and ev["n_agreeing"] == 1
    assert tie_break_by_legacy(["a", "b"], [3.996, 4.004], legacy, "m", rule, enabled=True)[0] == 0  # both print 4.00
    assert tie_break_by_legacy(["a", "b"], [3.996, 4.004], legacy, "m", rule, enabled=True, decimals=3)[0] is None
    assert tie_break_by_legacy(["a", "b"], [3.0, 4.0], legacy, "m", rule, enabled=False)[0] is None


def test_operator_of_how_far():
    # "how far ... traveled" reads literally as the path, with the statistic left open
    assert D.operator_of("How far has the cyclist traveled from 1s to 4s?") == ("path_length", True)
    assert D.operator_of("What is the displacement of the camera from 1s to 4s?") == ("displacement", False)
    assert D.operator_of("What is the total distance traveled by the camera?") == ("path_length", False)


# ----------------------------------------------------------------------------- the mini-world


@pytest.fixture(scope="module")
def disp_run(miniworld, tmp_path_factory):
    return H.run_with_yaml(TASK, "displacement", miniworld, tmp_path_factory.mktemp("disp_out"))


@pytest.fixture(scope="module")
def man(miniworld):
    return H.manifest(miniworld)


def test_miniworld_defects_verdicts_values(disp_run, man, miniworld):
    unseen = H.unseen_subject_rows(disp_run, man, miniworld) | H.source_ambiguous_rows(disp_run, man, miniworld)
    assert unseen == set()  # the generator takes only subjects seen in the interval
    assert [m for m in H.defect_mismatches(disp_run, man) if m[0] not in unseen] == []
    assert [m for m in H.verdict_mismatches(disp_run, man) if m[0] not in unseen] == []
    assert H.value_mismatches(disp_run, man) == []
    assert {o.source for o in disp_run.outcomes} == {"ScanNet", "Waymo", "Omni6DPose"}


def test_how_far_is_read_per_source(disp_run, man):
    """'How far has X traveled' is read as the legacy construction of each source built it: the
    ScanNet rows as the displacement (the generator built them so), the Waymo rows as the path."""
    how_far = [o for o in disp_run.outcomes if o.verdict != "excluded" and "construction_statistic" in o.evidence]
    by_source = {o.source: o.evidence["construction_statistic"]["statistic"] for o in how_far}
    assert by_source == {"ScanNet": "displacement", "Waymo": "path_length"}
    for o in how_far:
        m = {x["row"]: x for x in man}[o.row]
        assert o.contract["operator"] == m["contract"]["operator"], o.row
        if o.source == "ScanNet":
            assert {"statistic_unnamed", "distance_traveled_is_displacement"} <= set(o.defects)
            assert "displacement (straight-line" in o.question
            hyp = o.evidence["hypotheses"]  # the legacy value is the displacement
            assert hyp["matches"]["displacement"] == (o.verdict == "retained"), o.row
        else:
            assert "distance_traveled_is_displacement" not in o.defects
    scannet = [o for o in how_far if o.source == "ScanNet"]
    assert sum(o.verdict == "retained" for o in scannet) >= 5
    # at least five ScanNet rows discriminate: the legacy value matches the displacement only
    assert sum(o.evidence["hypotheses"]["matches"] == {"displacement": True, "path_length": False}
               for o in scannet) >= 5


def test_reading_per_source_by_hand():
    from resti_lib.tasks.motion import reading_per_source, row_reading

    names = {"displacement": "displacement", "path_length": "path"}
    rows = [("ScanNet", {"displacement": True, "path_length": False})] * 3 + \
        [("ScanNet", {"displacement": False, "path_length": False})] + \
        [("Waymo", {"displacement": True, "path_length": True})] * 2 + \
        [("Omni6DPose", {"displacement": True, "path_length": False})] * 2 + \
        [("Omni6DPose", {"displacement": False, "path_length": True})]
    g = reading_per_source(rows, names, "path_length", 0.25)
    assert g["ScanNet"]["statistic"] == "displacement" and g["ScanNet"]["n_displacement_only"] == 3
    assert g["ScanNet"]["n_neither"] == 1 and not g["ScanNet"]["mixed"]
    assert g["Waymo"]["statistic"] == "path_length" and g["Waymo"]["decided_by"].startswith("undetermined")
    assert g["Omni6DPose"]["mixed"]  # 1 of 3 deciding rows reads the other way: each row keeps its own
    assert row_reading({"displacement": False, "path_length": True}, g["Omni6DPose"])[0] == "path_length"
    assert row_reading({"displacement": False, "path_length": False}, g["ScanNet"])[:2] == ("displacement", True)
    assert row_reading({"displacement": True, "path_length": True}, g["Waymo"])[:2] == ("path_length", False)


def test_miniworld_exclusions_and_questions(disp_run):
    assert disp_run.result.excluded and H.exclusion_problems(disp_run) == []
    for e in disp_run.result.excluded:
        if e["reason_codes"] == ["ambiguous_subject"]:
            ev = e["verification_evidence"]
            assert ev["n_object_candidates"] >= 1 and "camera_value_si" in ev
    for r in disp_run.result.accepted:
        assert r["Question"].endswith("(unit: m)") and " between t=" in r["Question"]
    assert json.loads(disp_run.result.provenance["contract"].iloc[0])["operator"] in D.WORDING


def test_miniworld_no_significant_attack_and_valid_options(disp_run):
    assert H.significant_attacks(disp_run) == []
    assert H.structural_failures(disp_run) == []


def test_subject_phrases_of_the_scalar_questions():
    from types import SimpleNamespace

    from resti_lib.sources.referents import noun_phrase
    from resti_lib.tasks.scalar_audit import subject_phrase

    assert noun_phrase("A white utility truck.") == "the white utility truck"
    assert noun_phrase("The  Office chair") == "the office chair"
    assert noun_phrase("TV stand") == "the TV stand"
    assert noun_phrase("A U-turn sign") == "the U-turn sign"
    assert noun_phrase(None) == "the object"
    assert subject_phrase(SimpleNamespace(kind="camera"), "a red car") == "the camera"
    assert subject_phrase(SimpleNamespace(kind="object"), "a red car") == "the red car (its 3D box centre)"
