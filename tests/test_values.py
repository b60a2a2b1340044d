"""values.py: every answer encoding, by hand."""

import json
import math

import numpy as np
import pytest

from resti_lib import values as V
from resti_lib.errors import InputError


@pytest.mark.parametrize("text,value,unit,si,dec", [
    ("0.45m", 0.45, "m", 0.45, 2),
    ("104.89cm", 104.89, "cm", 1.0489, 2),
    ("15.97m/s", 15.97, "m/s", 15.97, 2),
    ("0.10m/s²", 0.10, "m/s²", 0.10, 2),
    ("-162.97°", -162.97, "°", -162.97, 2),
    ("8°", 8.0, "°", 8.0, 0),
    ("0.10 m", 0.10, "m", 0.10, 2),
    ("3", 3.0, "", 3.0, 0),
])
def test_scalars(text, value, unit, si, dec):
    v = V.parse(text)
    assert isinstance(v, V.Scalar)
    assert v.value == pytest.approx(value) and v.unit == unit and v.decimals == dec
    assert v.si == pytest.approx(si)


def test_numeric_duplicates_after_unit_normalisation():
    a, b, c, d = V.parse("0.1m"), V.parse("0.10 m"), V.parse("10cm"), V.parse("0.11m")
    assert V.same_value(a, b) and V.same_value(a, c) and not V.same_value(a, d)
    assert not V.same_value(V.parse("1m"), V.parse("1m/s"))  # different dimension


def test_key_detail_agreement_rule():
    # the report's example: detail 8.03°, option B 8°, key C 0°
    assert V.agree(V.parse("8.03°"), V.parse("8°"))
    assert not V.agree(V.parse("8.03°"), V.parse("0°"))
    assert V.agree(V.parse("104.89cm"), V.parse("1.05m"))  # 1.0489 m vs 1.05 m (+-0.005)
    assert not V.agree(V.parse("1.0489m"), V.parse("1.06m"))


def test_pose_both_spacings():
    spaced = '{"tx": 4.61, "ty": 3.82, "tz": 1.38, "r11": 1.0, "r12": 0.0, "r13": 0.0, ' \
             '"r21": 0.0, "r22": 1.0, "r23": 0.0, "r31": 0.0, "r32": 0.0, "r33": 1.0}'
    v = V.parse(spaced)
    assert isinstance(v, V.Pose) and not v.compact
    assert v.t == (4.61, 3.82, 1.38) and np.allclose(v.R, np.eye(3))
    T = np.eye(4)
    T[:3, 3] = [4.61, 3.82, 1.38]
    assert V.format_pose(T) == spaced
    compact = V.format_pose(T, compact=True)
    assert compact.startswith('{"tx":4.61,"ty":3.82') and V.parse(compact).compact


def test_box_roundtrip_and_heading():
    c = math.cos(math.radians(30))
    s = math.sin(math.radians(30))
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    text = V.format_box([1.0, -0.5, 2.25], [0.5, 0.25, 1.0], R)
    obj = json.loads(text)
    assert list(obj) == ["C_central_point", "C_heading", "C_lwh", "C_rotation_camera_from_box"]
    assert obj["C_heading"] == 30.0  # degrees(atan2(R10, R00)) by hand
    v = V.parse(text)
    assert isinstance(v, V.Box) and v.center == (1.0, -0.5, 2.25) and v.lwh == (0.5, 0.25, 1.0)
    assert np.allclose(v.R, np.round(R, 6))


def test_legacy_box_without_rotation():
    v = V.parse('{"C_central_point":[1.2,0.3,2.5],"C_lwh":[0.5,0.4,1.1],"C_heading":12.5}')
    assert isinstance(v, V.Box) and v.R is None and v.heading == 12.5


def test_trajectory_phrases():
    v = V.parse("move forward 212.5m, then turn right 50°, then move forward 156.5m")
    assert v.segments == (("move", 212.5), ("turn", -50.0), ("move", 156.5))
    assert v.total_distance == pytest.approx(369.0)
    assert v.structure == ("move", "turn-", "move")
    assert V.parse("no significant movement").segments == ()
    assert V.format_trajectory(v.segments) == v.text
    assert V.format_trajectory([("turn", 77), ("move", 48.94)]) == "turn left 77°, then move forward 48.9m"


def test_labels_and_angles():
    assert V.parse("Front-Left").kind == "label"
    assert V.format_angle(179.999) == "-180.00°"  # never 180.00°
    assert V.format_angle(-0.001) == "0.00°"
    assert V.format_angle(190.0) == "-170.00°"


@pytest.mark.parametrize("bad", ["", "{not json", '{"tx": 1}', "move forward abc", "12 parsecs", "[1,2]"])
def test_unreadable_values_name_row_and_field(bad):
    with pytest.raises(InputError) as e:
        V.parse(bad, row="row-7", field="Candidates.C")
    assert "row-7" in str(e.value) and "Candidates.C" in str(e.value)


def test_nan_parses_but_is_not_finite():
    v = V.parse("nanm")
    assert isinstance(v, V.Scalar) and not v.finite()


def test_format_seconds():
    assert [V.format_seconds(t) for t in (0.0, -0.0000001, 16.0, 19.7, 19.8000184, 143.3)] == \
        ["0", "0", "16", "19.7", "19.800018", "143.3"]


def test_comparison_rule_half_unit_of_a_zero_in_centimetres():
    from resti_lib.adjudicate import Rule, same_quantity_agrees

    # "0.00cm" is printed to 0.01 cm: half a unit is 0.00005 m, whatever the value
    zero_cm, new = V.parse("0.00cm"), V.parse("0.004000000m")
    assert zero_cm.si_per_unit == 0.01
    assert not same_quantity_agrees(zero_cm, new, Rule())  # 0.004 m > 0.00005 m
    assert same_quantity_agrees(zero_cm, V.parse("0.000040000m"), Rule())  # 0.00004 m <= 0.00005 m
    assert same_quantity_agrees(zero_cm, new, Rule(abs_tol=0.004))


def test_trajectory_segment_decimals():
    t = V.parse("move forward 340m, then turn right 30.5°, then move  forward 12.10m")
    assert t.segment_decimals == (0, 1, 2)
    assert V.parse("no significant movement").segment_decimals == ()
    assert V.Trajectory(segments=(("move", 1.0),), text="").segment_decimals == (0,)


def test_adaptive_decimals_for_small_values():
    # at least 20 printed units: 2.5 m has 250 units of 0.01; 0.063 m needs 0.001 (63 units); 0.0012 m 0.00001
    assert V.adaptive_decimals(2.5) == 2
    assert V.adaptive_decimals(0.063) == 3
    assert V.adaptive_decimals(0.0012) == 5
    assert V.adaptive_decimals(0.0) == 2


def test_negative_zero_printed_only_where_the_printer_keeps_it():
    """A rotation entry of -0.001 rounds to -0.0: printed with its sign by default (as v5 Waymo and ScanNet
    print it), as 0.0 when the release never shows a negative zero (as v5 Omni6DPose answers)."""
    T = np.eye(4)
    T[:3, :3] = [[1.0, -0.001, 0.0], [0.001, 1.0, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = [-0.004, 2.0, 0.0]
    signed = json.loads(V.format_pose(T, 2, compact=True))
    plain = V.format_pose(T, 2, compact=True, signed_zero=False)
    assert '"r12":-0.0' in V.format_pose(T, 2, compact=True) and '"tx":-0.0' in V.format_pose(T, 2, compact=True)
    assert "-0.0" not in plain and '"r12":0.0' in plain and '"tx":0.0' in plain
    assert math.copysign(1.0, signed["r12"]) == -1.0 and signed["r21"] == 0.0
    assert V.prints_negative_zero(list(signed.values()))
    assert not V.prints_negative_zero(list(json.loads(plain).values()))
    assert not V.prints_negative_zero([0.0, 1.0, -2.0])  # a negative value is not a negative zero
