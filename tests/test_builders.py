"""Option builders: constraints hold, and option-only attacks stay at chance on many built rows."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from resti_lib import values as V
from resti_lib.options import builders as B
from resti_lib.options.attacks import attack_table
from resti_lib.options.checks import rotation_tolerance
from resti_lib.rng import balanced_schedule, row_rng


def test_scalar_answer_rank_and_distinct():
    for rank in range(1, 6):
        o = B.scalar_options(2.345, "m", rng=np.random.default_rng(rank), target_rank=rank)
        vals = [V.parse(s).si for s in o.strings]
        assert o.strings[o.answer_index] == format(2.345, ".2f") + "m"  # the answer itself, formatted
        assert sorted(vals).index(vals[o.answer_index]) + 1 == rank
        assert len({V.parse(s).key() for s in o.strings}) == 5


def test_scalar_decimals_for_small_values():
    assert B.scalar_decimals(2.5) == 2
    assert B.scalar_decimals(0.063) == 3   # 0.063 m spans 63 units of 0.001 (>= 20)
    assert B.scalar_decimals(0.0012) == 5


def test_scalar_format_of_answer_is_round_half_even_free():
    # 2.345 is stored as 2.34499999...; the formatter prints what Python's format gives
    assert V.format_scalar(2.345, "m") == format(2.345, ".2f") + "m"


def test_angle_separation_and_wrap():
    o = B.angle_options(178.0, rng=np.random.default_rng(3), target_rank=5)
    vals = np.array([V.parse(s).value for s in o.strings])
    assert o.strings[o.answer_index] == "178.00°"
    assert ((vals >= -180) & (vals < 180)).all()
    d = np.abs((vals[:, None] - vals[None, :] + 180) % 360 - 180)
    np.fill_diagonal(d, 999)
    assert d.min() >= 1.0


def test_box_keeps_up_axis_and_valid_rotations():
    R = Rotation.from_euler("xyz", [80, 5, 30], degrees=True).as_matrix()
    o = B.box_options([1, 0.5, 3], [0.8, 0.6, 1.2], R, rng=np.random.default_rng(0), center_sigma=0.3)
    ans = V.parse(o.strings[o.answer_index])
    assert np.allclose(ans.center, [1, 0.5, 3]) and np.allclose(ans.R, np.round(R, 6))
    for s in o.strings:
        b = V.parse(s)
        Rb = np.array(b.R)
        assert np.abs(Rb @ Rb.T - np.eye(3)).max() < 1e-5
        # box-local axis 2 (up) is the same direction for every candidate
        assert abs(Rb[:, 2] @ R[:, 2]) > 1 - 1e-5


def test_pose_rotations_distinct_and_valid_after_rounding():
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("zyx", [40, 3, -2], degrees=True).as_matrix()
    T[:3, 3] = [10.0, -4.0, 1.5]
    o = B.pose_options(T, rng=np.random.default_rng(1), trans_sigma=1.0)
    Rs = [np.array(V.parse(s).R) for s in o.strings]
    for Rp in Rs:
        assert np.abs(Rp @ Rp.T - np.eye(3)).max() <= 2 * math.sqrt(3) * 0.005 + 1e-4 < rotation_tolerance(2)
    keys = {tuple(np.round(Rp, 2).ravel()) for Rp in Rs}
    assert len(keys) == 5  # no reused rotation
    # third row (tilt w.r.t. world up) identical to the answer's, to the rounding
    for Rp in Rs:
        assert np.allclose(Rp[2], np.round(T[2, :3], 2), atol=0.011)


def test_trajectory_same_structure():
    segs = [("move", 120.0), ("turn", -45.0), ("move", 60.0)]
    o = B.trajectory_options(segs, rng=np.random.default_rng(2))
    assert o.strings[o.answer_index] == "move forward 120.0m, then turn right 45°, then move forward 60.0m"
    for s in o.strings:
        assert [k for k, _ in V.parse(s).segments] == ["move", "turn", "move"]


def test_letters_balanced_and_answer_placed():
    keys = [f"row{i}" for i in range(103)]
    sched = balanced_schedule(keys, list("ABCDE"), seed=0, group="t")
    counts = {L: list(sched.values()).count(L) for L in "ABCDE"}
    assert max(counts.values()) - min(counts.values()) <= 1
    o = B.scalar_options(1.0, "m", rng=np.random.default_rng(0), target_rank=2)
    cands, L = B.assign_letters(o, "D", np.random.default_rng(0))
    assert L == "D" and cands["D"] == "1.00m" and sorted(cands) == list("ABCDE")


@pytest.mark.parametrize("kind", ["scalar", "angle", "box", "pose", "trajectory"])
def test_attacks_at_chance_on_built_rows(kind):
    """500 rows per kind with random answers: no Holm-significant attack (alpha 0.05)."""
    g = np.random.default_rng(11)
    keys = [f"{kind}-{i}" for i in range(500)]
    ranks = balanced_schedule(keys, [1, 2, 3, 4, 5], seed=1, group=kind)
    letters = balanced_schedule(keys, list("ABCDE"), seed=1, group=kind + "L")
    task = {"scalar": "Displacement & Path Length", "angle": "Ego-Centric Orientation",
            "box": "3D Video Grounding", "pose": "Pose Estimation", "trajectory": "Trajectory Description"}[kind]
    rows = []
    for k in keys:
        rng = row_rng(1, k)
        if kind == "scalar":
            v = float(np.exp(g.normal(0, 1.5)))
            o = B.scalar_options(v, "m", rng=rng, target_rank=ranks[k], decimals=B.scalar_decimals(v))
        elif kind == "angle":
            o = B.angle_options(float(g.uniform(-180, 180)), rng=rng, target_rank=ranks[k])
        elif kind == "box":
            R = Rotation.from_euler("zx", [g.uniform(0, 360), 90], degrees=True).as_matrix()
            o = B.box_options(g.normal(0, 3, 3), np.exp(g.normal(0, 0.7, 3)), R, rng=rng, center_sigma=0.4)
        elif kind == "pose":
            T = np.eye(4)
            T[:3, :3] = Rotation.from_euler("z", g.uniform(0, 360), degrees=True).as_matrix()
            T[:3, 3] = g.normal(0, 20, 3)
            o = B.pose_options(T, rng=rng, trans_sigma=2.0)
        else:
            segs = [("move", float(g.uniform(5, 300)))]
            if g.random() < 0.6:
                segs += [("turn", float(g.choice([-1, 1]) * g.uniform(15, 120))), ("move", float(g.uniform(5, 300)))]
            o = B.trajectory_options(segs, rng=rng)
        cands, L = B.assign_letters(o, letters[k], rng)
        rows.append({"Task": task, "Source": "Waymo", "Candidates": cands, "Answer": L,
                     "Answer Detail": cands[L], "ReSTI ID": k, "time_start": 0.0, "time_end": 1.0})
    t = attack_table(rows, alpha=0.05)
    assert not t["significant"].any(), t[t["significant"]].to_string()
