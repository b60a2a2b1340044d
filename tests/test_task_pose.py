"""Pose Estimation: operators on hand-computed tracks, and acceptance on the mini-world."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from resti_lib import values as V
from resti_lib.geometry.frames import make_T, rotation_angle_deg, yaw_matrix
from resti_lib.geometry.trajectory import PoseTrack
from resti_lib.measure.motion import sample_window
from resti_lib.tasks import pose as P
from resti_lib.tasks.run import audit_row
from tests.task_checks import (
    check_attacks,
    check_defects,
    check_exclusions,
    check_notebook,
    check_values,
    run_on_miniworld,
)

TASK = P.TASK


def _track(n: int = 101, dt: float = 0.1) -> PoseTrack:
    """Moves +1 m/s along world x and yaws 3 deg/s: P(t) = [R_z(3t deg) | (t, 2, 1)]."""
    t = np.arange(n) * dt
    T = make_T(yaw_matrix(np.radians(3.0 * t)), np.stack([t, np.full(n, 2.0), np.ones(n)], axis=1))
    return PoseTrack(t, T, name="test camera", meta={"frames": np.arange(n)})


def _printed(T: np.ndarray) -> np.ndarray:
    return V.parse(V.format_pose(T)).matrix


def test_pose_at_time_nearest_sample():
    tr = _track()
    T, ev = P.pose_at_time(tr, 5.02)
    assert ev["indices"] == [50] and ev["frame"] == [50]
    assert np.allclose(T[:3, 3], [5.0, 2.0, 1.0])
    assert sample_window(tr) == pytest.approx(0.05)


def test_rotation_angle_of_a_rounded_matrix_is_its_rounding_not_three_degrees():
    from scipy.spatial.transform import Rotation

    R = Rotation.from_euler("z", 35.0, degrees=True).as_matrix()
    printed = np.round(R, 2)  # [[0.82, -0.57], [0.57, 0.82]] in the x-y block: agrees with R to 0.005
    # by hand: the nearest rotation of [[a, -b], [b, a]] turns by atan2(b, a); arccos((trace - 1) / 2)
    # of the unprojected product would say 2.99 degrees
    want = 35.0 - math.degrees(math.atan2(0.57, 0.82))
    assert rotation_angle_deg(R, printed) == pytest.approx(want, abs=1e-9) and want < 0.2
    assert rotation_angle_deg(np.eye(3), printed) == pytest.approx(math.degrees(math.atan2(0.57, 0.82)), abs=1e-9)
    Rx = Rotation.from_euler("xyz", [20.0, -50.0, 110.0], degrees=True).as_matrix()
    assert rotation_angle_deg(Rx, np.round(Rx, 2)) < 0.5
    assert rotation_angle_deg(np.eye(3), Rx) == pytest.approx(np.degrees(Rotation.from_matrix(Rx).magnitude()))


def test_timestamp_search_finds_the_wrong_sample():
    tr = _track()
    legacy = _printed(tr.T[53])  # the matrix of t = 5.3 s, asked at t = 5.0 s
    s = P.timestamp_search(tr, legacy, 5.0)
    assert s["best_t"] == pytest.approx(5.3)
    assert s["wrong_timestamp"] and not s["reproduced_at_asked"]
    assert s["time_offset_s"] == pytest.approx(0.3)
    assert s["translation_change_m"] == pytest.approx(0.3, abs=0.01)  # printed to 2 decimals
    assert s["best_residual"] <= 0.005 + 1e-12
    ok = P.timestamp_search(tr, _printed(tr.T[50]), 5.0)
    assert ok["reproduced_at_asked"] and not ok["wrong_timestamp"]
    far = _printed(tr.T[50]).copy()
    far[0, 3] += 100.0  # no sample reproduces it: a value mismatch, not a wrong timestamp
    s2 = P.timestamp_search(tr, far, 5.0)
    assert not s2["wrong_timestamp"] and s2["best_residual"] > 1.0


def test_resolve_premise_from_time_start_or_search():
    tr = _track()
    premise = json.loads(V.format_pose(tr.T[20]))
    r = P.resolve_premise(tr, premise, [0.0, 2.0])
    assert r["time"] == 2.0 and r["how"] == "time_start" and r["reproduced"]
    r2 = P.resolve_premise(tr, premise, [7.0])
    assert r2["time"] == pytest.approx(2.0) and r2["how"] == "search"
    assert P.resolve_premise(tr, None, [0.0])["time"] == 0.0


def test_question_wording():
    q = P.question_text("Waymo", 3.0, 12.0, "{...}")
    for part in ("t=3 s", "t=12 s", "Waymo world coordinate frame", "camera-to-world", "OpenCV", "meters"):
        assert part in q
    q2 = P.question_text("Omni6DPose", 0.0, 7.5, None)
    assert "t=0 s as the identity" in q2 and "t=7.5 s" in q2
    assert rotation_angle_deg(np.eye(3), yaw_matrix(np.radians(30.0))) == pytest.approx(30.0)


# ------------------------------------------------------------------------------- mini-world


@pytest.fixture(scope="module")
def pose_run(miniworld, tmp_path_factory):
    return run_on_miniworld(TASK, miniworld, tmp_path_factory.mktemp("pose_out"))


def test_defects_match_manifest(pose_run):
    check_defects(pose_run)


def test_values_equal_truth(pose_run):
    check_values(pose_run)


def test_exclusions_have_reasons_and_evidence(pose_run):
    check_exclusions(pose_run)
    ex = [o for o in pose_run.run.outcomes if o.verdict == "excluded"]
    assert ex and all(o.reasons == ["premise_equals_target"] for o in ex)


def test_no_significant_attack(pose_run):
    check_attacks(pose_run)


def test_wrong_timestamp_diagnosis(pose_run):
    tab = P.diagnosis_table(pose_run.run.outcomes)
    summ = P.wrong_timestamp_summary(tab)
    truth = sum("waymo_pose_wrong_timestamp" in m["defects"] for m in pose_run.manifest)
    assert summ["n_wrong"] == truth > 0
    assert summ["median_translation_change_m"] > 0.05
    wrong = tab[tab["wrong_timestamp"]]
    assert (wrong["best_residual"] <= 0.006).all() and (wrong["asked_residual"] > 0.006).all()


def test_rebuilt_options_have_distinct_valid_rotations(pose_run):
    for r in pose_run.run.result.accepted:
        vals = [V.parse(s) for s in r["Candidates"].values()]
        Rs = [np.array(v.R) for v in vals]
        for i in range(5):
            assert np.abs(Rs[i] @ Rs[i].T - np.eye(3)).max() < 0.03
            for j in range(i + 1, 5):
                assert not np.allclose(Rs[i], Rs[j]), r["ReSTI ID"]
        q = r["Question"]
        assert "t=" in q and ("camera-to-world" in q or "camera-to-reference" in q)


def test_notebook_parameters():
    check_notebook("08_pose", "pose.yaml")


# ------------------------------------------------------------------------- stubbed sources


class _Rope:
    def __init__(self, track):
        self.track, self.dir, self.obj_meta_path = track, "ROPE/000001", "Meta/real_obj_meta.json"

    def camera_track(self, rebase=True):
        return self.track

    def world_up_in_track_frame(self, up):
        return np.asarray(up, float)

    def camera_notes(self, up):
        return []


class _Ctx:
    """Stubbed sources: one ROPE scene (``000001``) or one ScanNet scene (``scene0000_00``)."""

    video_map = None
    omni6d_root = scannet_root = "stub"

    def __init__(self, rope=None, scene=None):
        self._rope, self._scene = rope, scene

    def locate(self, video):
        from resti_lib.sources.mapping import VideoSource

        if self._scene is not None:
            return VideoSource("ScanNet", "scene0000_00", None, "stub")
        return VideoSource("Omni6DPose", "000001", None, "stub")

    def rope(self, seq):
        return self._rope

    def scannet(self, seq):
        return self._scene


def _row(question, detail, t0, t1):
    return {"row": 0, "Legacy Row Key": "Omni6DPose|Pose Estimation|000001.mp4|0|uid=0", "Source": "Omni6DPose",
            "Task": TASK, "Video": "000001.mp4", "ID": 0, "Question": question, "Prompt": "",
            "time_start": t0, "time_end": t1, "Answer Detail": detail, "Candidates": {}}


def test_omni_pose_relative_to_the_premise_camera():
    from resti_lib.geometry.frames import invert_T

    tr = _track(n=301)
    truth = invert_T(tr.T[20]) @ tr.T[50]  # camera at 5 s seen from the camera at 2 s
    r = _row("Taking the camera pose at t=2 s as the identity, what is the camera pose at t=5 s?",
             V.format_pose(truth), 2.0, 5.0)
    o = audit_row(TASK, r, _Ctx(_Rope(tr)), {})
    assert o.verdict == "retained" and not o.defects
    assert np.allclose(o.answer.value, truth)
    assert "t=2 s as the identity" in o.question and "t=5 s" in o.question
    wrong = _row(r["Question"], V.format_pose(tr.T[50]), 2.0, 5.0)  # legacy forgot to re-base
    o2 = audit_row(TASK, wrong, _Ctx(_Rope(tr)), {})
    assert o2.verdict == "corrected" and o2.defects == ["value_mismatch"]
    same = _row("Taking the camera pose at t=2 s as the identity, what is the camera pose at t=2 s?",
                V.format_pose(np.eye(4)), 2.0, 2.0)
    o3 = audit_row(TASK, same, _Ctx(_Rope(tr)), {})
    assert o3.verdict == "excluded" and o3.reasons == ["premise_equals_target"]
    assert o3.defects == ["premise_equals_answer"] and o3.evidence["same_time"]


# ------------------------------------------------------------ premises that are another row's answer


class _Scene:
    meta_path = "scene0000_00.txt"

    def __init__(self, track):
        self.track = track

    def camera_track(self):
        return self.track


def _scan_rows(tr, pairs):
    """Legacy ScanNet rows asking the pose at t1 given the printed pose at t0 (whole seconds)."""
    out = []
    for i, (t0, t1) in enumerate(pairs):
        q = (f"Given the camera pose at t={t0} s in the ScanNet raw scan coordinate frame: {V.format_pose(tr.T[10 * t0])}, "
             f"what is the camera pose in the same coordinate frame at t={t1} s?")
        out.append({"row": i, "Legacy Row Key": f"ScanNet|{TASK}|scene0000_00.mp4|{i}|uid={i}", "Source": "ScanNet",
                    "Task": TASK, "Video": "scene0000_00.mp4", "ID": i, "Question": q, "Prompt": "",
                    "time_start": float(t1), "time_end": float(t1), "Answer Detail": V.format_pose(tr.T[10 * t1]),
                    "Candidates": {}})
    return out


def test_a_premise_that_is_another_rows_answer_moves_to_the_first_second_no_row_asks():
    import pandas as pd

    from resti_lib.tasks import task_for
    from resti_lib.tasks.run import audit_rows

    tr = _track(n=101)  # 0 .. 10 s; the pose at t is [R_z(3t deg) | (t, 2, 1)]
    # a converse pair (2 -> 5, 5 -> 2) and a row asking t=0 from an unasked premise (7 -> 0)
    rows = _scan_rows(tr, [(2, 5), (5, 2), (7, 0)])
    out = audit_rows(task_for(TASK), pd.DataFrame(rows), _Ctx(scene=_Scene(tr)), {})
    moved, kept = out[:2], out[2]
    # by hand: seconds 0, 2 and 5 are asked, so the first free one is 1 s, where the pose is [R_z(3 deg) | (1, 2, 1)]
    want = V.format_pose(make_T(yaw_matrix(np.radians(3.0)), np.array([1.0, 2.0, 1.0])))
    for o, other in zip(moved, (1, 0)):
        assert o.verdict == "retained" and o.defects == ["premise_reveals_answer"]
        assert o.evidence["premise_moved"] == {"legacy_premise_time": [2.0, 5.0][o.row], "premise_time": 1.0,
                                               "answer_of_rows": [other]}
        assert o.question.startswith(f"Given the camera pose at t=1 s in the ScanNet raw scan coordinate frame: {want},")
        assert o.contract["params"]["premise_time"] == 1.0
    assert kept.verdict == "retained" and not kept.defects and "t=7 s" in kept.question
    # every whole second asked by some row: nothing can replace the premise, the rows are excluded
    tr4 = _track(n=31)  # 0 .. 3 s
    out4 = audit_rows(task_for(TASK), pd.DataFrame(_scan_rows(tr4, [(1, 0), (0, 1), (3, 2), (2, 3)])),
                      _Ctx(scene=_Scene(tr4)), {})
    assert [o.verdict for o in out4] == ["excluded"] * 4
    assert all(o.reasons == ["no_unrevealing_premise"] and o.defects == ["premise_reveals_answer"] for o in out4)
    assert [o.evidence["answer_of_rows"] for o in out4] == [[1], [0], [3], [2]]


def test_no_released_premise_prints_an_answer_of_its_recording(pose_run):
    """The mini-world asks Waymo poses in converse pairs, as the legacy benchmark does; in the release
    no premise is at a time another row of the recording asks, nor prints as one of its answers."""
    import re

    man = pose_run.by_row
    acc = {r["Legacy Row Key"]: r for r in pose_run.run.result.accepted}
    released = [o for o in pose_run.run.outcomes if o.verdict != "excluded" and o.source != "Omni6DPose"]
    assert sum("premise_reveals_answer" in man[o.row]["defects"] for o in released) >= 4
    for o in released:
        t0 = float(re.search(r"at t=([0-9.]+) s", acc[o.key]["Question"]).group(1))
        seq = [p for p in released if man[p.row]["sequence"] == man[o.row]["sequence"]]
        assert all(abs(man[p.row]["contract"]["times"][0] - t0) > 1e-6 for p in seq), o.row
        premise = acc[o.key]["Question"].split(": ", 1)[1].split(", what is", 1)[0]
        assert all(acc[p.key]["Answer Detail"] != premise for p in seq if p.video == o.video), o.row
        if "premise_reveals_answer" in man[o.row]["defects"]:
            # moved to the first whole second that no row of the sequence asks
            asked = {man[p.row]["contract"]["times"][0] for p in seq}
            assert t0 == min(t for t in range(0, 30) if t not in asked), o.row
