"""Trajectory Description: the motion operator on hand-computed paths, and acceptance on the mini-world."""

from __future__ import annotations

import math

import numpy as np
import pytest

from resti_lib import values as V
from resti_lib.adjudicate import Rule
from resti_lib.geometry.frames import R_WAYMO_FROM_CV, make_T, yaw_matrix
from resti_lib.geometry.trajectory import PoseTrack
from resti_lib.tasks import trajectory as TR
from tests.task_checks import (
    check_attacks,
    check_defects,
    check_exclusions,
    check_notebook,
    check_values,
    run_on_miniworld,
)

TASK = TR.TASK


def _drive(turn_deg: float, *, speed: float = 10.0, straight_s: float = 5.0, turn_s: float = 4.0,
           hz: float = 10.0) -> PoseTrack:
    """A camera (OpenCV axes, optical axis = driving direction) driving ``straight_s``, turning by
    ``turn_deg`` with a smoothstep yaw over ``turn_s``, then ``straight_s`` again, at ``speed``."""
    dt = 1e-3
    tau = np.arange(0.0, 2 * straight_s + turn_s + dt / 2, dt)
    x = np.clip((tau - straight_s) / turn_s, 0.0, 1.0)
    yaw = math.radians(turn_deg) * x * x * (3 - 2 * x)
    px = np.concatenate([[0.0], np.cumsum(speed * np.cos(yaw[1:]) * dt)])
    py = np.concatenate([[0.0], np.cumsum(speed * np.sin(yaw[1:]) * dt)])
    k = np.round(np.arange(0.0, tau[-1] + 1e-9, 1.0 / hz) / dt).astype(int)
    R = yaw_matrix(yaw[k]) @ R_WAYMO_FROM_CV  # optical axis (cv +Z) -> vehicle forward (+X)
    T = make_T(R, np.stack([px[k], py[k], np.zeros(k.size)], axis=1))
    return PoseTrack(tau[k], T, name="test camera")


def test_left_turn_split_at_half_turn():
    tr = _drive(90.0)
    segs, ev = TR.describe_motion(tr, 0.0, float(tr.times[-1]), tol=0.05)
    assert [k for k, _ in segs] == ["move", "turn", "move"]
    # 50 m straight + half of the 40 m arc on each side; the turn is the whole 90 degrees
    assert segs[0][1] == pytest.approx(70.0, abs=0.05)
    assert segs[2][1] == pytest.approx(70.0, abs=0.05)
    assert segs[1][1] == pytest.approx(90.0, abs=0.05)
    assert ev["turn_windows"][0]["t_half"] == pytest.approx(7.0, abs=0.01)
    assert ev["path_length_m"] == pytest.approx(140.0, abs=0.05)
    assert V.format_trajectory(segs) == "move forward 70.0m, then turn left 90°, then move forward 70.0m"


def test_right_turn_and_small_turn():
    segs, _ = TR.describe_motion(_drive(-50.0), 0.0, 14.0, tol=0.05)
    assert segs[1][0] == "turn" and segs[1][1] == pytest.approx(-50.0, abs=0.05)
    straight, _ = TR.describe_motion(_drive(8.0), 0.0, 14.0, tol=0.05)  # below the 15 deg threshold
    assert [k for k, _ in straight] == ["move"] and straight[0][1] == pytest.approx(140.0, abs=0.05)


def test_no_significant_movement():
    t = np.arange(0, 5.0, 0.1)
    T = make_T(np.repeat(np.eye(3)[None], t.size, 0), np.tile([0.001, 0.0, 0.0], (t.size, 1)) * t[:, None])
    segs, ev = TR.describe_motion(PoseTrack(t, T), 0.0, 4.9, tol=0.05, no_movement_m=2.0)
    assert segs == [] and ev["summary"] == V.NO_MOVEMENT
    assert V.format_trajectory(segs) == "no significant movement"


def test_grid_and_comparison():
    grid = V.parse("move forward 340m, then turn right 30°, then move forward 10m")
    assert TR.on_grid(grid) and not TR.on_grid(V.parse("move forward 346.8m"))
    assert not TR.on_grid(V.parse("no significant movement"))
    rule = Rule(abs_tol=0.25)
    src = [("move", 346.8), ("turn", -30.4), ("move", 12.1)]
    cmp = TR.compare(grid, src, rule, 2.0)
    assert cmp["same_structure"] and not cmp["agrees"] and cmp["errors"][0] == pytest.approx(6.8)
    near = V.parse("move forward 346.8m, then turn right 30°, then move forward 12.1m")
    assert TR.compare(near, src, rule, 2.0)["agrees"]
    # each move agrees within half a unit of its own printed place: 12m (+-0.5) but not 12.0m (+-0.05)
    src2 = [("move", 346.8), ("turn", -30.4), ("move", 12.4)]
    assert TR.compare(V.parse("move forward 346.8m, then turn right 30°, then move forward 12m"), src2,
                      Rule(), 2.0)["agrees"]
    assert not TR.compare(V.parse("move forward 346.8m, then turn right 30°, then move forward 12.0m"), src2,
                          Rule(), 2.0)["agrees"]
    flipped = V.parse("move forward 346.8m, then turn left 30°, then move forward 12.1m")
    assert not TR.compare(flipped, src, rule, 2.0)["same_structure"]


def test_question_wording():
    q = TR.question_text(0.0, 19.7)
    assert q == ("Which option best describes the camera's movement trajectory between t=0 s and t=19.7 s? "
                 "Distances are path lengths along the trajectory and turns are net heading changes.")


# ------------------------------------------------------------------------------- mini-world


@pytest.fixture(scope="module")
def traj_run(miniworld, tmp_path_factory):
    return run_on_miniworld(TASK, miniworld, tmp_path_factory.mktemp("trajectory_out"))


def test_defects_match_manifest(traj_run):
    check_defects(traj_run)
    assert all("trajectory_10m_grid" in o.defects for o in traj_run.run.outcomes)


def test_values_equal_truth(traj_run):
    check_values(traj_run)


def test_exclusions_have_reasons_and_evidence(traj_run):
    check_exclusions(traj_run)


def test_no_significant_attack(traj_run):
    check_attacks(traj_run)


def test_options_keep_structure(traj_run):
    for r in traj_run.run.result.accepted:
        structs = {V.parse(s).structure[::2] for s in r["Candidates"].values()}
        assert len(structs) == 1  # same move/turn pattern (turn directions may flip)
        lens = [len(s) for s in r["Candidates"].values()]
        assert max(lens) - min(lens) <= 3


def test_path_figure(traj_run, miniworld, tmp_path):
    from resti_lib.sources.waymo import WaymoSegment

    o = next(o for o in traj_run.run.outcomes if o.evidence.get("operator", {}).get("turn_windows"))
    seq, cam = o.video[:-4].rsplit("_camera_", 1)
    track = WaymoSegment(miniworld / "waymo", seq).camera_track(int(cam))
    # the figure reads the row's evidence: the path there is the source track to the centimetre
    ev = o.evidence["path"]
    sel = (track.times >= o.time_start - 1e-6) & (track.times <= o.time_end + 1e-6) & track.valid
    np.testing.assert_allclose(ev["xy"], track.positions[sel, :2] - track.positions[sel][0, :2], atol=0.005)
    p = TR.plot_path(o.evidence, tmp_path / "07_trajectory_path.png")
    assert p.exists() and p.stat().st_size > 1000


def test_notebook_parameters():
    check_notebook("07_trajectory", "trajectory.yaml")


def test_measure_operator_matches_the_task(traj_run, miniworld):
    from resti_lib.measure import evaluate_contract

    acc = {r["Legacy Row Key"]: r for r in traj_run.run.result.accepted}
    o = next(o for o in traj_run.run.outcomes if o.verdict != "excluded")
    seq, cam = o.video[:-4].rsplit("_camera_", 1)
    res = evaluate_contract({"source": "Waymo", "sequence": seq, "camera": int(cam), "entity": {"kind": "camera"},
                             "times": o.contract["times"], "operator": "trajectory"},
                            {"waymo_root": str(miniworld / "waymo")})
    assert res.get("value") == acc[o.key]["Answer Detail"], res.get("error")
