"""Spatial Relation: mounted-camera and object-pair operators on hand-computed cases, and
acceptance on the mini-world (the label prior is reported, not required to be at chance)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from resti_lib.geometry.frames import make_T, yaw_matrix
from resti_lib.options.stage import build_options
from resti_lib.tasks import interface as _interface
from resti_lib.tasks import relation as RE
from resti_lib.tasks.run import audit_row
from tests.task_checks import (
    check_attacks,
    check_defects,
    check_exclusions,
    check_notebook,
    check_values,
    run_on_miniworld,
)

IFACE = _interface()

TASK = RE.TASK


@pytest.mark.parametrize("yaw,label", [(0.0, "Front"), (44.0, "Front-Left"), (-47.0, "Front-Right"),
                                        (91.0, "Left"), (-89.5, "Right"), (180.0, "Back"), (22.0, None),
                                        (-66.0, None)])
def test_mount_relation_from_extrinsic_yaw(yaw, label):
    E = make_T(yaw_matrix(math.radians(yaw)), [1.5, 0.0, 2.0])
    got, ev = RE.mount_relation(E, margin_deg=5.0)
    assert got == label
    assert abs((ev["yaw_deg"] - yaw + 180.0) % 360.0 - 180.0) < 1e-9
    assert ev["edge_margin_deg"] == pytest.approx(22.5 - min(abs(yaw - c) for c in (0, 45, -45, 90, -90, 180)),
                                                  abs=1e-9)


@pytest.mark.parametrize("camera,yaw", [(1, 0.0), ("2", 45.0), ("FRONT_RIGHT", -45.0), (4, 90.0), ("side_right", -90.0),
                                         (9, None), ("rear", None)])
def test_name_mount_yaw_reads_the_camera_enum(camera, yaw):
    """Waymo's CameraName enum (1 FRONT, 2 FRONT_LEFT, 3 FRONT_RIGHT, 4 SIDE_LEFT, 5 SIDE_RIGHT) and the rig's
    nominal mounts (vehicle +Y left), written out by hand; a camera the enum does not name has none."""
    from resti_lib.measure.relations import name_mount_yaw

    assert name_mount_yaw(camera) == yaw


def test_relative_position_cases():
    up = np.array([0.0, -1.0, 0.0])  # camera looking horizontally: scene up = -Y in OpenCV axes
    eye, lwh = np.eye(3), np.array([0.2, 0.2, 0.1])  # B's box: local z = its height
    Rb = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # box z -> camera -Y (up)
    b = np.array([0.0, 0.0, 1.0])
    assert RE.relative_position(b + [0.30, 0, 0.1], b, eye, lwh, up)[0] == "Right"
    assert RE.relative_position(b + [-0.30, 0, 0.1], b, eye, lwh, up)[0] == "Left"
    assert RE.relative_position(b + [0.05, 0, 0.4], b, eye, lwh, up)[0] == "Farther"
    assert RE.relative_position(b + [0.05, 0, -0.4], b, eye, lwh, up)[0] == "Closer"
    lab, ev = RE.relative_position(b + [0.2, 0, 0.2], b, eye, lwh, up)
    assert lab is None and ev["dominance"] == pytest.approx(1.0) and ev["margin_m"] == pytest.approx(-0.1)
    lab, ev = RE.relative_position(b + [0.01, -0.09, 0.0], b, Rb, lwh, up)  # 0.09 above centre, top at 0.05
    assert lab == "Directly above" and ev["height_above_top_m"] == pytest.approx(0.04)
    beside = RE.relative_position(b + [0.3, -0.09, 0.0], b, Rb, lwh, up)[0]
    assert beside == "Right"  # higher but not over the footprint


def test_referents():
    inst = {"a": {"class_name": "teddy_bear"}, "b": {"class_name": "mug"}, "c": {"class_name": "mug"},
            "d": {"class_name": "remote_control"}}
    assert RE.match_referent("small brown teddy bear wearing a blue shirt", inst)["oids"] == ["a"]
    assert RE.match_referent("black remote control with red buttons", inst)["status"] == "ok"
    assert RE.match_referent("white ceramic mug with a red logo", inst)["status"] == "ambiguous_instance"
    assert RE.match_referent("the two mugs", inst)["status"] == "grouped_referent"
    assert RE.match_referent("wooden toy train", inst)["status"] == "no_source_instance"


def test_label_options_are_the_fixed_five():
    for src, labels in RE.LABELS.items():
        row = {"Video": "v.mp4", "Source": src, "Task": "Spatial Relation", "Question": "q", "time_start": 0.0,
               "time_end": 0.0, "Candidates": {}, "Answer": None, "Answer Detail": labels[2], "ReSTI ID": "r0"}
        out, _, _ = build_options(iface=IFACE, records=[row], seed=0, extras={"r0": {"labels": list(labels)}})
        assert sorted(out[0]["Candidates"].values()) == sorted(labels)
        assert out[0]["Candidates"][out[0]["Answer"]] == labels[2]


def test_question_wording():
    q = RE.question_text("Omni6DPose", a="red suitcase", b="teddy bear", t=0.0)
    assert q.startswith("Viewed from the camera at t=0 s: relative to the teddy bear, is the red suitcase to the "
                        "left, to the right, closer to the camera, farther from the camera, or directly above?")
    assert "mounted on the moving car" in RE.question_text("Waymo")


# ------------------------------------------------------------------------------- mini-world


@pytest.fixture(scope="module")
def rel_run(miniworld, tmp_path_factory):
    return run_on_miniworld(TASK, miniworld, tmp_path_factory.mktemp("relation_out"))


def test_defects_match_manifest(rel_run):
    check_defects(rel_run)


def test_values_equal_truth(rel_run):
    check_values(rel_run)


def test_exclusions_have_reasons_and_evidence(rel_run):
    check_exclusions(rel_run)
    for e in rel_run.run.result.excluded:
        if "no_dominant_relation" in e["reason_codes"]:
            ev = e["verification_evidence"]
            assert {"dx", "dz", "dominance", "required_ratio"} <= set(ev) and ev["dominance"] < 1.5


def test_no_significant_attack_except_label_prior(rel_run):
    check_attacks(rel_run, allowed=("label_prior",))


def test_mount_labels_verified_by_calibration(rel_run):
    tab = RE.diagnosis_table(rel_run.run.outcomes)
    w = tab[tab["source"] == "Waymo"]
    assert len(w) and w["name_agrees"].all() and (w["edge_margin_deg"] > 15).all()


def test_notebook_parameters():
    check_notebook("04_relation", "relation.yaml")


class _Seg:
    def __init__(self, E):
        self.E = E

    def camera_calibration(self, cam):
        return {"extrinsic": self.E, "row": 0}

    def path(self, component):
        return f"{component}/seg.parquet"


class _Ctx:
    video_map = None
    waymo_root = "stub"

    def __init__(self, E):
        self.seg = _Seg(E)

    def locate(self, video):
        from resti_lib.sources.mapping import VideoSource

        return VideoSource("Waymo", "seg", 2, "stub")

    def waymo(self, seq):
        return self.seg


def test_mount_label_follows_the_calibration_not_the_name():
    row = {"row": 3, "Legacy Row Key": "Waymo|Spatial Relation|seg_camera_2.mp4|0|uid=0", "Source": "Waymo",
           "Task": TASK, "Video": "seg_camera_2.mp4", "ID": 0, "Prompt": "", "time_start": 0.0, "time_end": 19.8,
           "Question": "What is the orientation of the camera mounted on the moving car relative to the car's "
                       "forward direction?", "Answer Detail": "Front-Left", "Candidates": {}}
    E = make_T(yaw_matrix(math.radians(-45.0)), [1.5, -0.1, 2.1])  # FRONT_LEFT by name, faces front-right
    o = audit_row(TASK, row, _Ctx(E), {})
    assert o.answer.value == "Front-Right" and o.verdict == "corrected" and o.defects == ["value_mismatch"]
    assert o.evidence["mount"]["name_label"] == "Front-Left" and not o.evidence["mount"]["name_agrees_with_calibration"]
    ok = audit_row(TASK, row, _Ctx(make_T(yaw_matrix(math.radians(44.0)), [1.5, 0.1, 2.1])), {})
    assert ok.verdict == "retained" and ok.answer.value == "Front-Left"
    edge = audit_row(TASK, row, _Ctx(make_T(yaw_matrix(math.radians(21.0)), [1.5, 0.1, 2.1])), {})
    assert edge.reasons == ["no_dominant_relation"] and edge.evidence["edge_margin_deg"] == pytest.approx(1.5)


def test_measure_operators_match_the_task(rel_run, miniworld):
    from resti_lib.measure import evaluate_contract

    params = {"waymo_root": str(miniworld / "waymo"), "omni6d_root": str(miniworld / "omni6d")}
    for o in rel_run.run.outcomes:
        if o.verdict == "excluded":
            continue
        if o.source == "Waymo":
            seq, cam = o.video[:-4].rsplit("_camera_", 1)
            c = {"source": "Waymo", "sequence": seq, "camera": int(cam), "entity": {"kind": "camera"},
                 "times": [0.0], "operator": "mounted_relation"}
        else:
            a, b = o.contract["entity"]["ids"]
            c = {"source": "Omni6DPose", "sequence": o.video[:-4], "entity": {"kind": "object", "id": a, "reference": b},
                 "times": o.contract["times"], "operator": "relative_position"}
        res = evaluate_contract(c, params)
        assert res.get("value") == o.answer.value, (o.row, res.get("error"))
