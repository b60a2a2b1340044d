"""The question observables the attack suite reads (the option stage's observables), from hand-written rows;
and the attack side's readings of them (question kind, implied rate, premise). Values checked by hand."""

import json

import numpy as np
import pytest

from resti_lib import values as V
from resti_lib.options.attacks.features import implied_rate, noun_of, premise_parts, question_kind, repeats_premise
from resti_lib.options.observables import observables_of
from resti_lib.tasks import interface as _interface
from tests.helpers import row

IFACE = _interface()


def _obs(r: dict):
    """The observables of a row, its quantity read by its task."""
    return observables_of(r, IFACE.quantity_of(r["Task"], r["Question"]))



def test_window_and_implied_speed():
    r = row(question="What is the displacement (straight-line distance) of the camera between t=2.5 s and "
                     "t=12.5 s? (unit: m)", t0=2.5, t1=12.5)
    o = _obs(r)
    assert o.quantity == "displacement" and o.window_s == 10.0 and o.subject_class == "camera"
    assert noun_of(o) is None and question_kind(o) == "displacement"
    assert implied_rate(V.parse("30.00m"), o) == ("speed", pytest.approx(3.0))  # 30 m over 10 s
    o2 = _obs(row(task="Trajectory Description", question="Which option best describes the camera's "
                            "movement trajectory between t=0 s and t=20 s?", t0=0.0, t1=20.0))
    assert implied_rate(V.parse("move forward 60.0m, then turn left 90°"), o2) == ("speed", pytest.approx(3.0))


def test_instant_rates():
    r = row(task="Speed & Acceleration", source="Waymo", video="seg_1_000_21_000_camera_3.mp4",
            question="What is the magnitude of the acceleration of the silver sedan with tinted windows at t=14 s, "
                     "from velocities over 1-second central windows? (unit: m/s²)", t0=14.0, t1=14.0)
    o = _obs(r)
    assert question_kind(o) == "acceleration@instant" and o.window_s == 1.0
    assert noun_of(o) == "sedan" and (o.sequence, o.camera) == ("seg_1_000_21_000", "3")
    assert implied_rate(V.parse("2.50m/s²"), o) == ("acceleration", 2.5)


def test_premise_pose_printed_and_identity():
    pose = {"tx": 8396.06, "ty": 6063.86, "tz": -877.36, "r11": 1.0, "r12": 0.0, "r13": 0.0, "r21": 0.0,
            "r22": 1.0, "r23": 0.0, "r31": 0.0, "r32": 0.0, "r33": 1.0}
    text = json.dumps(pose, separators=(",", ":"))
    q = (f"Given the camera pose at t=14 s in the Waymo world coordinate frame: {text}, what is the camera pose "
         "in the same coordinate frame at t=3 s?")
    o = _obs(row(task="Pose Estimation", source="Waymo", video="seg_camera_1.mp4", question=q,
                           t0=3.0, t1=3.0))
    t, R = premise_parts(o)
    assert np.allclose(t, [8396.06, 6063.86, -877.36]) and np.allclose(R, np.eye(3))
    assert o.premise_time == 14.0 and o.window_s == 11.0
    assert repeats_premise(V.parse(text.replace(",", ", ")), o)  # the same numbers, spaced
    assert not repeats_premise(V.parse(text.replace("8396.06", "8396.07")), o)
    ident = _obs(row(task="Pose Estimation", source="Omni6DPose", video="000001.mp4", t0=0.0, t1=22.0,
                               question="Taking the camera pose at t=0 s as the identity and expressing the result "
                                        "in the OpenCV camera frame of that instant, what is the camera pose at "
                                        "t=22 s?"))
    assert np.allclose(ident.premise, np.eye(4)) and ident.window_s == 22.0
    assert repeats_premise(V.parse(V.format_pose(np.eye(4), 2)), ident)


def test_dimension_question_kind_and_noun():
    o = _obs(row(task="Dimensional Measurement", question="What is the height of the white refrigerator "
                           "beside the white trash can? (unit: m)"))
    assert question_kind(o) == "height" and noun_of(o) == "refrigerator"
