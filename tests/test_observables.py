"""Question observables read from hand-written rows (values stated in the text, checked by hand)."""

import json

import numpy as np
import pytest

from resti_lib import values as V
from resti_lib.options.observables import head_noun, implied_rate, observe, premise_pose, sequence_of
from tests.helpers import row


def test_window_and_implied_speed():
    r = row(question="What is the displacement (straight-line distance) of the camera between t=2.5 s and "
                     "t=12.5 s? (unit: m)", t0=0.0, t1=99.0)
    o = observe(r)
    assert (o.t0, o.t1, o.duration) == (2.5, 12.5, 10.0)  # the text wins over the time fields
    assert o.operator == "displacement" and o.subject == "camera" and o.noun == "camera"
    kind, rate = implied_rate(V.parse("30.00m"), o)
    assert kind == "speed" and rate == pytest.approx(3.0)  # 30 m over 10 s
    assert implied_rate(V.parse("30.00m"), observe(row(question="How long is it?", t0=4.0, t1=4.0))) is None


def test_instant_rates_and_their_window():
    r = row(task="Speed & Acceleration", source="Waymo", video="seg_1_000_21_000_camera_3.mp4",
            question="What is the magnitude of the acceleration of the silver sedan with tinted windows at t=14 s, "
                     "from velocities over 1-second central windows? (unit: m/s²)", t0=14.0, t1=14.0)
    o = observe(r)
    assert o.qtype == "acceleration@instant" and o.rate_window == 1.0 and o.duration == 0.0
    assert o.subject == "object" and o.noun == "sedan"
    assert (o.sequence, o.camera) == ("seg_1_000_21_000", 3)
    assert implied_rate(V.parse("2.50m/s²"), o) == ("acceleration", 2.5)


def test_premise_pose_printed_and_identity():
    pose = {"tx": 8396.06, "ty": 6063.86, "tz": -877.36, "r11": 1.0, "r12": 0.0, "r13": 0.0, "r21": 0.0,
            "r22": 1.0, "r23": 0.0, "r31": 0.0, "r32": 0.0, "r33": 1.0}
    q = (f"Given the camera pose at t=14 s in the Waymo world coordinate frame: {json.dumps(pose)}, what is the "
         "camera pose in the same coordinate frame at t=3 s?")
    o = observe(row(task="Pose Estimation", source="Waymo", video="seg_camera_1.mp4", question=q, t0=3.0, t1=3.0))
    assert o.premise is not None and o.premise.t == (8396.06, 6063.86, -877.36)
    assert o.premise_time == 14.0 and o.t1 == 3.0
    ident = premise_pose("Taking the camera pose at t=0 s as the identity and expressing the result in the "
                         "OpenCV camera frame of that instant, what is the camera pose at t=22 s?")
    assert np.allclose(ident.matrix, np.eye(4))
    assert premise_pose("What is the camera pose at t=3 s?") is None


@pytest.mark.parametrize("text,noun", [
    ("A small brown teddy bear wearing a blue shirt", "bear"),
    ("Office chairs in front of a bookshelf with files and folders", "chair"),
    ("Object description: Black Ford pickup truck", "truck"),
    ("Two black bookshelves against a light-colored wall", "bookshelf"),
    ("White door with two black handles, wooden frame", "door"),
    ("bounding boxes of a long green chili pepper with a curved shape", "pepper"),
    ("Books on shelves in a dimly lit library aisle", "book"),
    ("A long, white, slightly curved stick", "long"),  # a comma ends the phrase: documented limit
    ("", None),
])
def test_head_noun(text, noun):
    assert head_noun(text) == noun


def test_sequence_from_video_names():
    assert sequence_of("scene0012_00.mp4") == ("scene0012_00", None)
    assert sequence_of("10203656353524179475_7625_000_7645_000_camera_1.mp4") == (
        "10203656353524179475_7625_000_7645_000", 1)
    assert sequence_of("000123.mp4") == ("000123", None)
    assert sequence_of("my clip.mp4") == ("my clip", None)  # no rule: its own sequence


def test_dimension_question_type():
    o = observe(row(task="Dimensional Measurement", question="What is the height of the white refrigerator beside "
                    "the white trash can? (unit: m)"))
    assert o.qtype == "dimension:height" and o.noun == "refrigerator"


def test_odd_rows_do_not_raise():
    o = observe({"Task": "Pose Estimation", "Source": "Waymo", "Video": None, "Question": "{not json} {\"tx\": 1}",
                 "time_start": "soon", "time_end": None})
    assert o.premise is None and o.t0 is None and o.duration is None
