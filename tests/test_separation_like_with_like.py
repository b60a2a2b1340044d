"""The separation check compares trajectory descriptions like with like: the totals of two
descriptions of one shape, never a straight path against a turning one."""

from __future__ import annotations

from resti_lib.options.checks import ROW_CHECKS, parse_row
from resti_lib.tasks import interface
from tests.helpers import row

TRAJ = "Trajectory Description"
Q = "Summarize the camera trajectory, including distances moved and turns made."


def _check(cands: list[str]):
    r = row(task=TRAJ, source="Waymo", video="1_camera_1.mp4", t0=0.0, t1=20.0, question=Q,
            cands=dict(zip("ABCDE", cands)), answer="A")
    return ROW_CHECKS["separation"](parse_row(r, "x", interface()))


def test_straight_and_turning_paths_of_close_totals_are_distinct():
    # 72.1 m straight against 41.2 + 28.4 = 69.6 m with a turn: different shapes, both fine (v5's case)
    assert _check(["move forward 72.1m", "move forward 41.9m", "no significant movement",
                   "move forward 41.2m, then turn left 58°, then move forward 28.4m", "move forward 103.7m"]) is None


def test_two_straight_paths_of_close_totals_still_fail():
    # 72.1 and 70.0 m, both straight: 2.1 m apart, under the 4% relative floor (2.9 m)
    msg = _check(["move forward 72.1m", "move forward 70.0m", "no significant movement",
                  "move forward 41.2m, then turn left 58°, then move forward 28.4m", "move forward 103.7m"])
    assert msg == "70 and 72.1 closer than the floor"
    # turning paths of one shape are compared too: 41.2 + 28.4 = 69.6 against 40 + 30.5 = 70.5
    msg = _check(["move forward 72.1m", "move forward 30.0m", "no significant movement",
                  "move forward 41.2m, then turn left 58°, then move forward 28.4m",
                  "move forward 40.0m, then turn left 30°, then move forward 30.5m"])
    assert msg == "69.6 and 70.5 closer than the floor"
