"""Ego-Centric Orientation: hand-computed headings, the legacy X-Z operator, invariance, shortening,
and the mini-world acceptance."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from resti_lib.geometry import trajectory as GT
from resti_lib.geometry.frames import opencv_cam_pose_to_waymo
from resti_lib.geometry.trajectory import PoseTrack
from resti_lib.options.attacks import attack_table
from resti_lib.tasks import interface as _interface
from resti_lib.tasks import orientation as O
from resti_lib.tasks import read_contract
from tests.task_checks import check_defects, check_values, run_on_miniworld

IFACE = _interface()

IFACE = _interface()

TASK = "Ego-Centric Orientation"


def look(forward, up=(0.0, 0.0, 1.0)):
    """R_world<-cam of an OpenCV camera looking along ``forward`` with image up = world ``up``."""
    z = np.asarray(forward, float) / np.linalg.norm(forward)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


def track_of(Rs, times=None, t=None):
    n = len(Rs)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rs
    if t is not None:
        T[:, :3, 3] = t
    return PoseTrack(np.arange(n, dtype=float) if times is None else times, T, name="hand")


def tracks_for(tr):
    return O.Tracks(tr, tr, (0.0, 0.0, 1.0), "hand world (+Z up)", "OpenCV", [])


def test_heading_and_legacy_by_hand():
    # start: level, looking along +X. end: looking toward azimuth 60 deg, pitched 20 deg down.
    a20, a60 = math.radians(20), math.radians(60)
    f1 = (math.cos(a20) * math.cos(a60), math.cos(a20) * math.sin(a60), -math.sin(a20))
    tr = track_of([look((1, 0, 0)), look(f1)])
    conv = O.conventions(tracks_for(tr), 0.0, 1.0, O.Orientation().settings({}))
    assert conv["gravity_heading"] == pytest.approx(60.0, abs=1e-9)
    # legacy: column 2 on the X-Z plane, from (x, z) = (1, 0) to (cos20 cos60, -sin20), positive from +Z to +X:
    # atan2(a_z b_x - a_x b_z, a_x b_x + a_z b_z) = atan2(sin20, cos20 cos60)
    want = math.degrees(math.atan2(math.sin(a20), math.cos(a20) * math.cos(a60)))
    assert want == pytest.approx(36.0524, abs=1e-3)  # atan(tan 20 / cos 60)
    assert conv["xz_plane_column2"] == pytest.approx(want, abs=1e-9)
    assert conv["xz_plane_column2_reversed"] == pytest.approx(-want, abs=1e-9)
    assert conv["geodesic_angle"] > 60.0


def test_heading_sign_and_wrap():
    # turning right (clockwise seen from above) is negative; 190 deg to the left wraps to -170
    tr = track_of([look((1, 0, 0)), look((0, -1, 0)), look((math.cos(math.radians(190)), math.sin(math.radians(190)), 0))])
    p = O.Orientation().settings({})
    assert O.conventions(tracks_for(tr), 0.0, 1.0, p)["gravity_heading"] == pytest.approx(-90.0, abs=1e-9)
    assert O.conventions(tracks_for(tr), 0.0, 2.0, p)["gravity_heading"] == pytest.approx(-170.0, abs=1e-9)


def test_invariance_under_rigid_rotation_of_trajectory_and_world():
    rng = np.random.default_rng(7)
    Rs = Rotation.random(40, random_state=3).as_matrix()
    tr = track_of(Rs, t=rng.normal(size=(40, 3)))
    worst = 0.0
    for k in range(20):
        Q = Rotation.random(random_state=100 + k).as_matrix()
        up = np.array([0.0, 0.0, 1.0])
        for i, j in [(0, 39), (3, 17), (5, 6)]:
            a = GT.horizontal_heading_deg(Rs[i], Rs[j], (0, 0, 1), up)
            b = GT.horizontal_heading_deg(Q @ Rs[i], Q @ Rs[j], (0, 0, 1), Q @ up)
            worst = max(worst, abs((b - a + 180) % 360 - 180))
    assert worst <= 1e-9
    assert O.invariance_error(tracks_for(tr), 0.0, 39.0, O.Orientation().settings({}), rng) <= 1e-9


def test_waymo_source_axes_column2_is_up_and_forward_is_cv_z():
    R = look((0.3, 0.9, -0.1))
    T = np.eye(4)
    T[:3, :3] = R
    Tw = opencv_cam_pose_to_waymo(T)
    np.testing.assert_allclose(Tw[:3, 0], R[:, 2], atol=1e-12)  # Waymo +X forward = OpenCV +Z
    np.testing.assert_allclose(Tw[:3, 2], -R[:, 1], atol=1e-12)  # Waymo +Z up = OpenCV -Y


def test_shortened_interval_says_so():
    Rs = [look((1, 0, 0)), look((0, 1, 0)), look((-1, 0, 0))]
    tr = track_of(Rs)
    tr.T[2] = -np.inf
    tr.valid[2] = False
    th, ev = GT.heading_change(tr, 0.0, 2.0)
    assert th == pytest.approx(90.0) and ev["shortened_to"] == 1.0
    q = O.rewrite_question(0.0, 1.0, 2.0)
    assert "last valid source camera pose" in q and "2.000000" in q
    c = read_contract({"Task": TASK, "Source": "ScanNet", "Video": "scene0001_00.mp4", "Question": q,
                        "time_start": 9.0, "time_end": 9.0})
    assert c.times == [0.0, 1.0] and c.time_stated and not c.missing


def test_end_within_one_frame_past_the_track_is_clamped_and_recorded():
    tr = track_of([look((1, 0, 0)), look((0, 1, 0))], times=np.array([0.0, 1.0]))
    assert O.clamp_to_track(tr, 0.0, 1.05, 0.1) == (0.0, 1.0, {"t1": {"asked": 1.05, "used": 1.0}})
    assert O.clamp_to_track(tr, 0.0, 1.5, 0.1) == (0.0, 1.5, {})
    assert O.clamp_to_track(tr, 0.0, 0.5, 0.1) == (0.0, 0.5, {})


# --------------------------------------------------------------------------------- mini-world acceptance

@pytest.fixture(scope="module")
def mini(miniworld, tmp_path_factory):
    import yaml

    from resti_lib import paths

    p = yaml.safe_load((paths.PARAMS / "orientation.yaml").read_text())
    p.pop("alpha")
    return run_on_miniworld(TASK, miniworld, tmp_path_factory.mktemp("orientation_out"), **p)


def test_defects_verdicts(mini):
    check_defects(mini)
    assert all("orientation_xz_plane" in o.defects for o in mini.run.outcomes)
    assert all(o.verdict == "re-contracted" for o in mini.run.outcomes)


def test_values_equal_manifest_truth(mini):
    check_values(mini)
    for o in mini.run.outcomes:
        m = mini.by_row[o.row]
        assert abs((o.answer.value - m["true_value"] + 180) % 360 - 180) <= 1e-6, o.row
        assert o.time_end == pytest.approx(m["contract"]["times"][1], abs=1e-6)
        d = o.evidence["diagnosis"]
        assert abs(d["legacy_deg"] - m["legacy_value"]) <= 0.005 + 1e-9
        assert d["invariance_error_deg"] <= 1e-9


def test_shortened_rows(mini):
    short = [o for o in mini.run.outcomes if "shortened_to" in mini.by_row[o.row]["contract"]]
    assert short, "the mini-world has sequences ending in invalid poses"
    for o in mini.run.outcomes:
        m = mini.by_row[o.row]
        if o in short:
            assert "last valid source camera pose" in o.question
            assert o.evidence["shortened_to"] == pytest.approx(m["contract"]["shortened_to"], abs=1e-6)
            assert o.time_end < float(mini.run.legacy.set_index("row").loc[o.row, "time_end"])
        else:
            assert "shortened_to" not in o.evidence and "last valid" not in o.question


def test_convention_counts(mini):
    t = O.convention_counts(mini.run.outcomes).set_index("convention")
    n = int(t.loc["rows", "ALL"])
    assert n == len(mini.run.outcomes)
    assert int(t.loc["xz_plane_column2", "ALL"]) == n
    assert int(t.loc["gravity_heading", "ALL"]) < n


def test_attacks_at_chance(mini):
    table = attack_table(iface=IFACE, records=mini.run.result.accepted)
    assert not table["significant"].any(), table[table["significant"]]
    sub = table[table["attack"].isin(["median", "nearest_circular_mean", "min", "max", "rank_2", "rank_4"])
                & (table["source"] == "ALL")]
    assert len(sub) == 6 and (sub["coverage"] == 1.0).all()
    # the answer's signed-value rank follows the exchangeable draw: every fixed-rank pick hits no more
    # often than a binomial(n, 1/5) count does 999 times in 1000
    from scipy.stats import binom

    n = len(mini.run.result.accepted)
    assert (sub[sub["attack"] != "nearest_circular_mean"]["hits"] <= binom.ppf(0.999, n, 0.2)).all()


def test_figures(mini, miniworld, tmp_path):
    p = O.figure_endpoints(mini.run, tmp_path / "ends.png")
    q = O.figure_scatter(mini.run.outcomes, tmp_path / "scatter.png")
    assert p.stat().st_size > 5000 and q.stat().st_size > 5000
