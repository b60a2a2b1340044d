"""Geometry: transforms, rotation checks, quaternions, axis conventions and trajectory operators.

Expected values are computed by hand (stated in comments) or by a second, loop-based method.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from resti_lib.errors import ContractError, InputError
from resti_lib.geometry import frames as F
from resti_lib.geometry import trajectory as G

RZ90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def rz(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rx(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


# a level OpenCV camera looking along world +X (z_cam -> +X, x_cam -> -Y, y_cam -> -Z)
LEVEL_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


# ---------------------------------------------------------------------------------------------
# frames

def test_make_invert_apply_by_hand():
    T = F.make_T(RZ90, [1.0, 2.0, 3.0])
    # Rz90 (1,0,0) = (0,1,0), plus t -> (1,3,3)
    np.testing.assert_allclose(F.apply_T(T, [1.0, 0.0, 0.0]), [1.0, 3.0, 3.0])
    Ti = F.invert_T(T)
    np.testing.assert_allclose(F.apply_T(Ti, [1.0, 3.0, 3.0]), [1.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(Ti @ T, np.eye(4), atol=1e-15)
    # batch of transforms against a batch of points
    Tb = np.stack([T, np.eye(4)])
    np.testing.assert_allclose(F.apply_T(Tb, [[1, 0, 0], [5, 6, 7]]), [[1, 3, 3], [5, 6, 7]])


@pytest.mark.parametrize("R, what", [
    (np.diag([1.0, 1.0, np.inf]), "non-finite"),
    (np.diag([1.1, 1.0, 1.0]), "orthonormal"),
    (np.diag([1.0, 1.0, -1.0]), "det"),
])
def test_check_rotation_rejects(R, what):
    with pytest.raises(InputError) as e:
        F.check_rotation(R, tol=1e-6, file="poses.txt", row=7, field="camera_to_world")
    assert what in str(e.value)
    assert e.value.file == "poses.txt" and e.value.field == "camera_to_world" and e.value.row == 7


def test_check_rotation_batch_reports_index():
    Rs = np.stack([np.eye(3), np.eye(3), np.diag([1.0, -1.0, 1.0])])
    with pytest.raises(InputError) as e:
        F.check_rotation(Rs, file="x", field="R")
    assert e.value.row == 2


def test_quaternion_scalar_first_by_hand():
    s = math.sqrt(0.5)
    np.testing.assert_allclose(F.quat_wxyz_to_matrix([s, 0, 0, s]), RZ90, atol=1e-15)
    # (1,0,0,0) is the identity in wxyz; read as xyzw it would be a 180 deg turn about X
    np.testing.assert_allclose(F.quat_wxyz_to_matrix([1, 0, 0, 0]), np.eye(3))
    # unnormalised input is normalised; q and -q are the same rotation
    np.testing.assert_allclose(F.quat_wxyz_to_matrix([-2 * s, 0, 0, -2 * s]), RZ90, atol=1e-15)
    q = F.matrix_to_quat_wxyz(RZ90)
    np.testing.assert_allclose(q, [s, 0, 0, s], atol=1e-15)


def test_quaternion_zero_norm_is_input_error():
    with pytest.raises(InputError) as e:
        F.quat_wxyz_to_matrix([0, 0, 0, 0], file="000000_meta.json", row="1_obj", field="quaternion_wxyz")
    assert "zero norm" in str(e.value) and e.value.field == "quaternion_wxyz"
    assert "000000_meta.json" in str(e.value)
    with pytest.raises(InputError):
        F.quat_wxyz_to_matrix([[1, 0, 0, 0], [np.nan, 0, 0, 1]])


def test_waymo_opencv_axes():
    # Waymo forward (+X) is OpenCV +Z, Waymo left (+Y) is OpenCV -X, Waymo up (+Z) is OpenCV -Y
    np.testing.assert_allclose(F.waymo_to_opencv_points([1, 0, 0]), [0, 0, 1])
    np.testing.assert_allclose(F.waymo_to_opencv_points([0, 1, 0]), [-1, 0, 0])
    np.testing.assert_allclose(F.waymo_to_opencv_points([0, 0, 1]), [0, -1, 0])
    np.testing.assert_allclose(F.opencv_to_waymo_points([0, 0, 1]), [1, 0, 0])
    # a Waymo camera aligned with a level vehicle facing world +X: OpenCV pose = LEVEL_CAM
    T = F.waymo_cam_pose_to_opencv(np.eye(4))
    np.testing.assert_allclose(T[:3, :3], LEVEL_CAM)
    np.testing.assert_allclose(F.opencv_cam_pose_to_waymo(T), np.eye(4))
    assert np.linalg.det(F.R_CV_FROM_WAYMO) == pytest.approx(1.0)


def test_yaw_matrix():
    np.testing.assert_allclose(F.yaw_matrix(math.pi / 2), RZ90, atol=1e-15)
    assert F.yaw_matrix(np.zeros(5)).shape == (5, 3, 3)


# ---------------------------------------------------------------------------------------------
# PoseTrack and pose_at

def line_track(n=11, dt=0.1, invalid=()):
    t = np.arange(n) * dt
    T = F.make_T(np.broadcast_to(np.eye(3), (n, 3, 3)), np.stack([t * 2.0, 0 * t, 0 * t], axis=1))
    for i in invalid:
        T[i] = -np.inf
    return G.PoseTrack(t, T, name="line", source="mem")


def test_posetrack_validation():
    with pytest.raises(InputError) as e:
        G.PoseTrack([0.0, 0.2, 0.2], np.broadcast_to(np.eye(4), (3, 4, 4)), source="f.sens")
    assert e.value.row == 2 and e.value.field == "times"
    tr = line_track(invalid=(3,))
    assert tr.valid.tolist() == [True] * 3 + [False] + [True] * 7


def test_pose_at_rules():
    tr = line_track()
    T, ev = G.pose_at(tr, 0.3, rule="exact")
    assert T[0, 3] == pytest.approx(0.6) and ev["indices"] == [3]
    with pytest.raises(ContractError):
        G.pose_at(tr, 0.33, rule="exact")
    T, ev = G.pose_at(tr, 0.33, rule="nearest", tol=0.05)
    assert ev["indices"] == [3]
    T, ev = G.pose_at(tr, 0.35, rule="linear")
    assert T[0, 3] == pytest.approx(0.7) and ev["indices"] == [3, 4] and ev["alpha"] == pytest.approx(0.5)
    with pytest.raises(ContractError, match="outside"):
        G.pose_at(tr, 1.5)


def test_pose_at_slerp_by_hand():
    T = np.stack([F.make_T(np.eye(3), [0, 0, 0]), F.make_T(RZ90, [2, 0, 0])])
    tr = G.PoseTrack([0.0, 1.0], T)
    Tm, _ = G.pose_at(tr, 0.5)
    c = math.sqrt(0.5)  # halfway between 0 and 90 deg about Z is 45 deg
    np.testing.assert_allclose(Tm[:3, :3], [[c, -c, 0], [c, c, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(Tm[:3, 3], [1, 0, 0])


def test_pose_at_never_interpolates_over_invalid():
    tr = line_track(invalid=(4,))
    with pytest.raises(ContractError, match="invalid"):
        G.pose_at(tr, 0.35)  # between samples 3 and 4
    T, _ = G.pose_at(tr, 0.3)  # sample 3 itself is fine
    assert T[0, 3] == pytest.approx(0.6)
    Ts, ev = G.pose_at(tr, np.array([0.1, 0.35, 0.45]), errors="nan")
    assert np.isnan(Ts[1]).all() and np.isnan(Ts[2]).all() and ev["n_failed"] == 2


def test_pose_at_vectorised_matches_scalar_loop():
    rng = np.random.default_rng(0)
    n = 30
    angles = np.cumsum(rng.uniform(-20, 20, n))
    T = F.make_T(np.stack([rz(a) @ rx(b) for a, b in zip(angles, rng.uniform(-10, 10, n))]),
                 rng.normal(size=(n, 3)))
    times = np.cumsum(rng.uniform(0.05, 0.2, n))
    tr = G.PoseTrack(times, T)
    q = rng.uniform(times[0], times[-1], 50)
    Tv, _ = G.pose_at(tr, q)
    for k, tk in enumerate(q):
        # second method: scipy Slerp on the bracketing pair, plain loop
        from scipy.spatial.transform import Rotation, Slerp
        i = int(np.searchsorted(times, tk)) - 1
        a = (tk - times[i]) / (times[i + 1] - times[i])
        R = Slerp([0, 1], Rotation.from_matrix(T[i:i + 2, :3, :3]))([a]).as_matrix()[0]
        np.testing.assert_allclose(Tv[k, :3, :3], R, atol=1e-10)
        np.testing.assert_allclose(Tv[k, :3, 3], (1 - a) * T[i, :3, 3] + a * T[i + 1, :3, 3], atol=1e-12)


# ---------------------------------------------------------------------------------------------
# intervals, distances, rates

def test_interval_shortened_at_trailing_invalid():
    tr = line_track(invalid=(8, 9, 10))
    (_, t1), ev = G.interval_valid(tr, 0.0, 1.0)
    assert t1 == pytest.approx(0.7) and ev["shortened_to"] == pytest.approx(0.7)
    d, ev = G.endpoint_displacement(tr, 0.0, 1.0)
    assert d == pytest.approx(1.4) and ev["shortened_to"] == pytest.approx(0.7)
    with pytest.raises(ContractError, match="trailing invalid"):
        G.endpoint_displacement(tr, 0.8, 1.0)


def test_path_refuses_interior_invalid():
    tr = line_track(invalid=(5,))
    with pytest.raises(ContractError, match="bridge"):
        G.path_length(tr, 0.0, 1.0)
    L, ev = G.path_length(tr, 0.0, 1.0, gaps="skip")
    assert L == pytest.approx(2.0) and ev["bridged_invalid_samples"] == [5]
    d, _ = G.endpoint_displacement(tr, 0.0, 1.0)  # endpoints only: fine
    assert d == pytest.approx(2.0)


def test_path_length_and_rates_out_and_back():
    # x(t): 0 -> 3 m over 0..3 s, back to 1 m at 5 s; samples every 1 s
    t = np.arange(6.0)
    x = np.array([0.0, 1.0, 2.0, 3.0, 2.0, 1.0])
    tr = G.PoseTrack(t, F.make_T(np.broadcast_to(np.eye(3), (6, 3, 3)), np.stack([x, 0 * x, 0 * x], 1)))
    L, ev = G.path_length(tr, 0.5, 4.5)
    # p(0.5)=0.5, samples 1,2,3,4 (x=1,2,3,2), p(4.5)=1.5 -> 0.5+1+1+1+0.5 = 4.0
    assert L == pytest.approx(4.0) and ev["interior_index_range"] == [1, 4]
    d, _ = G.endpoint_displacement(tr, 0.5, 4.5)
    assert d == pytest.approx(1.0)
    v, ev = G.average_velocity(tr, 0.5, 4.5)
    assert v == pytest.approx(0.25) and "average velocity" in ev["statistic"]
    s, _ = G.average_speed(tr, 0.5, 4.5)
    assert s == pytest.approx(1.0)
    with pytest.raises(ContractError, match="zero-length"):
        G.average_velocity(tr, 2.0, 2.0)


def test_acceleration_constant_by_hand():
    # x = 0.5 * a * t^2 with a = 2 m/s^2: central differences are exact for quadratics,
    # v(t) = 2t, so the mean acceleration over [1, 3] is (6 - 2) / 2 = 2.
    t = np.arange(0, 5.01, 0.5)
    x = t ** 2
    tr = G.PoseTrack(t, F.make_T(np.broadcast_to(np.eye(3), (t.size, 3, 3)), np.stack([x, 0 * x, x * 0], 1)))
    a, ev = G.acceleration(tr, 1.0, 3.0)
    assert a == pytest.approx(2.0)
    assert "central difference" in ev["estimator"] and ev["velocity_t0"]["schemes"] == ["central"]
    np.testing.assert_allclose(ev["v_t0"], [2.0, 0, 0])


# ---------------------------------------------------------------------------------------------
# headings

def cam_track(yaws, pitches=None, times=None):
    yaws = np.asarray(yaws, float)
    pitches = np.zeros_like(yaws) if pitches is None else np.asarray(pitches, float)
    # yaw about world Z, then the camera pitched about its own x axis (tilt up/down)
    R = np.stack([rz(y) @ LEVEL_CAM @ rx(p) for y, p in zip(yaws, pitches)])
    times = np.arange(len(yaws), dtype=float) if times is None else times
    return G.PoseTrack(times, F.make_T(R, np.zeros((len(yaws), 3))), name="cam")


def test_heading_change_by_hand():
    tr = cam_track([10.0, 40.0], pitches=[-20.0, 15.0])
    th, ev = G.heading_change(tr, 0.0, 1.0, (0, 0, 1), (0, 0, 1))
    assert th == pytest.approx(30.0)  # tilt does not enter the horizontal heading
    np.testing.assert_allclose(ev["forward_t0"][2], -math.sin(math.radians(20.0)), atol=1e-12)
    th, _ = G.heading_change(cam_track([170.0, -170.0]), 0.0, 1.0)
    assert th == pytest.approx(20.0)  # through +180, a left turn of 20 deg
    th, _ = G.heading_change(cam_track([0.0, 180.0]), 0.0, 1.0)
    assert th == pytest.approx(-180.0)  # wrapped into [-180, 180)
    th, _ = G.heading_change(cam_track([0.0, -90.0]), 0.0, 1.0)
    assert th == pytest.approx(-90.0)  # right turn


def test_heading_invariant_under_common_rotation():
    tr = cam_track([5.0, 77.0], pitches=[10.0, -30.0])
    th, _ = G.heading_change(tr, 0.0, 1.0)
    Q = rx(33.0) @ rz(-71.0) @ rx(12.0)  # rotate trajectory and world basis together
    T2 = F.make_T(Q) @ tr.T
    th2, _ = G.heading_change(G.PoseTrack(tr.times, T2), 0.0, 1.0, (0, 0, 1), Q @ [0, 0, 1])
    assert abs(th - th2) < 1e-10


def test_heading_vertical_forward_is_error():
    R = np.stack([np.eye(3), np.eye(3)])  # OpenCV forward (0,0,1) is world up
    tr = G.PoseTrack([0.0, 1.0], F.make_T(R))
    with pytest.raises(ContractError, match="vertical"):
        G.heading_change(tr, 0.0, 1.0)


def test_legacy_plane_angle_sign_and_difference_from_heading():
    # column 2 (optical axis): start along +X, end along +Z -> +90 deg in the X-Z plane (X toward Z)
    R0 = LEVEL_CAM
    R1 = np.column_stack([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # optical axis up
    tr = G.PoseTrack([0.0, 1.0], F.make_T(np.stack([R0, R1])))
    ang, _ = G.legacy_plane_angle(tr, 0.0, 1.0, column=2, plane=("x", "z"))
    assert ang == pytest.approx(90.0)
    # a pure pitch-down of 30 deg: heading unchanged, X-Z angle = -30 (from +X toward -Z)
    tr = cam_track([0.0, 0.0], pitches=[0.0, -30.0])
    ang, _ = G.legacy_plane_angle(tr, 0.0, 1.0)
    th, _ = G.heading_change(tr, 0.0, 1.0)
    assert ang == pytest.approx(-30.0) and th == pytest.approx(0.0, abs=1e-12)


# ---------------------------------------------------------------------------------------------
# trajectory description

def test_segment_turns_straight_left_straight():
    # 20 m straight along +X at 10 m/s, a 90 deg left arc of radius 10 m, then 30 m along +Y
    dt = 0.05
    v = 10.0
    pts, yaws = [], []
    for s in np.arange(0, 20.0, v * dt):
        pts.append([s, 0.0, 0.0])
        yaws.append(0.0)
    arc = math.pi / 2 * 10.0
    for s in np.arange(0, arc, v * dt):
        a = s / 10.0
        pts.append([20.0 + 10 * math.sin(a), 10 - 10 * math.cos(a), 0.0])
        yaws.append(math.degrees(a))
    for s in np.arange(0, 30.0 + 1e-9, v * dt):
        pts.append([30.0, 10.0 + s, 0.0])
        yaws.append(90.0)
    pts = np.array(pts)
    R = np.stack([rz(y) for y in yaws])  # vehicle frame: forward +X
    tr = G.PoseTrack(np.arange(len(pts)) * dt, F.make_T(R, pts), name="car")
    segs, _ = G.segment_turns(tr, 0.0, tr.times[-1], turn_threshold_deg=20, min_move_m=1.0,
                               forward_axis=(1, 0, 0))
    assert [k for k, _ in segs] == ["move forward", "turn left", "move forward"]
    assert segs[1][1] == pytest.approx(90.0, abs=1.0)
    assert segs[0][1] == pytest.approx(20.0, abs=1.0)
    assert segs[2][1] == pytest.approx(30.0, abs=1.0)
    # mirrored: right turn
    M = np.diag([1.0, -1.0, 1.0])
    R2 = np.stack([rz(-y) for y in yaws])
    tr2 = G.PoseTrack(tr.times, F.make_T(R2, pts @ M))
    segs2, _ = G.segment_turns(tr2, 0.0, tr.times[-1], forward_axis=(1, 0, 0))
    assert [k for k, _ in segs2] == ["move forward", "turn right", "move forward"]


def test_segment_turns_stationary():
    tr = cam_track([0.0] * 10)
    segs, ev = G.segment_turns(tr, 0.0, 9.0)
    assert segs == [] and ev["summary"] == "no significant movement"


def drive(profile, dt=0.1):
    """Integrate (duration s, speed m/s, yaw rate deg/s) pieces into a vehicle track (forward +X)."""
    x = y = yaw = 0.0
    pts, yaws = [[0.0, 0.0, 0.0]], [0.0]
    for dur, v, rate in profile:
        for _ in range(round(dur / dt)):
            yaw += rate * dt
            x += v * dt * math.cos(math.radians(yaw))
            y += v * dt * math.sin(math.radians(yaw))
            pts.append([x, y, 0.0])
            yaws.append(yaw)
    R = np.stack([rz(a) for a in yaws])
    return G.PoseTrack(np.arange(len(pts)) * dt, F.make_T(R, np.array(pts)), name="drive")


def test_segment_turns_pause_inside_turn_and_small_wiggles():
    # 10 s straight at 5 m/s; left 45 deg; 0.1 s pause at 2 m/s (0.2 m < min_move); left 45 deg;
    # 10 s straight with a 5 deg wiggle (below the 15 deg threshold) in the middle
    tr = drive([(10, 5, 0), (3, 5, 15), (0.1, 2, 0), (3, 5, 15), (5, 5, 0), (1, 5, 5), (1, 5, -5), (3, 5, 0)])
    segs, ev = G.segment_turns(tr, 0.0, float(tr.times[-1]), forward_axis=(1, 0, 0), turn_threshold_deg=15,
                               min_move_m=1.0, turn_rate_deg_s=3.0)
    assert [k for k, _ in segs] == ["move forward", "turn left", "move forward"]
    assert segs[1][1] == pytest.approx(90.0, abs=1e-9)  # both halves and the pause: one 90 deg turn
    assert segs[0][1] == pytest.approx(50.0, abs=1e-9)  # 10 s at 5 m/s
    assert segs[2][1] == pytest.approx(50.0, abs=1e-9)  # 5 + 1 + 1 + 3 s at 5 m/s (wiggle included)
    assert ev["distance_while_turning_m"] == pytest.approx(30.2, abs=1e-9)  # 6 s at 5 m/s + 0.2 m


def test_box_centre_fields_with_depth_exponents_by_hand():
    """(x, y, z) = (6, 1.5, 16) with exponents (0.5, 1): projective fields x/sqrt(z) = 1.5, y/z = 0.09375,
    log 16; height fields 1.5, y itself, log 16; both map back to the centre."""
    from resti_lib.geometry.fields import centre_fields, centre_from_fields

    c = np.array([6.0, 1.5, 16.0])
    f = centre_fields(c, "projective", (0.5, 1.0))
    assert np.allclose(f, [1.5, 0.09375, math.log(16.0)])
    assert np.allclose(centre_fields(c, "height", (0.5, 1.0)), [1.5, 1.5, math.log(16.0)])
    for mode in ("projective", "height"):
        assert np.allclose(centre_from_fields(centre_fields(c, mode, (0.5, 1.0)), mode, (0.5, 1.0)), c)


def test_the_depth_exponent_is_the_one_that_frees_the_offset_from_depth():
    """Lateral offsets drawn in metres independent of depth (lanes): exponent near 0; directions drawn
    independent of depth (offset = z tan(angle)): exponent near 1; offsets spread as sqrt(z): near 0.5."""
    from resti_lib.options.kinds.box import depth_exponent

    rng = np.random.default_rng(0)
    n = 4000  # the rank correlation moves slowly with the exponent: many answers pin it to a twentieth
    z = np.exp(rng.uniform(math.log(4.0), math.log(60.0), n))
    assert depth_exponent(rng.normal(0.0, 3.0, n), z) <= 0.1
    assert depth_exponent(z * np.tan(rng.normal(0.0, 0.3, n)), z) >= 0.9
    assert 0.4 <= depth_exponent(np.sqrt(z) * rng.normal(0.0, 1.0, n), z) <= 0.6


def test_shell_fields_by_hand_and_the_gaze_fields_round_trip():
    """An offset (0, 0, -2) from the gaze point (the reference camera's side) is (log 2, 0, 0); (3, 0, 0)
    is azimuth 90; (0, -1, -1) is elevation -45 at distance sqrt 2. A camera near the desk looking at
    the gaze point, through the gaze fields and back, is itself."""
    from resti_lib.geometry.fields import from_gaze_fields, from_shell_fields, gaze_fields, shell_fields

    assert np.allclose(shell_fields([0.0, 0.0, -2.0]), [math.log(2.0), 0.0, 0.0])
    assert np.allclose(shell_fields([3.0, 0.0, 0.0]), [math.log(3.0), 90.0, 0.0])
    assert np.allclose(shell_fields([0.0, -1.0, -1.0]), [0.5 * math.log(2.0), 0.0, -45.0])
    for v in ([0.0, 0.0, -2.0], [3.0, 0.0, 0.0], [0.2, -0.4, 0.3]):
        assert np.allclose(from_shell_fields(shell_fields(v)), v)
    G = np.array([0.0, 0.0, 0.8])
    C = np.array([0.3, -0.2, 0.1])
    a = (G - C) / np.linalg.norm(G - C)
    x = np.cross([0.0, 1.0, 0.0], a)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(a, x), a])
    R2, C2 = from_gaze_fields(gaze_fields(R, C, G), G)
    assert np.allclose(C2, C) and np.allclose(R2, R)


def test_concentrated_axis_by_hand():
    """Rotations whose column 1 is +-(0, -0.6, -0.8) (the sign flips: an axial direction) and whose other two
    columns turn freely about it: column 1 is the concentrated axis (its mean outer product has eigenvalue 1),
    the others share the plane (eigenvalues 1/2 each, by symmetry)."""
    from scipy.spatial.transform import Rotation

    from resti_lib.geometry.fields import concentrated_axis

    u = np.array([0.0, -0.6, -0.8])
    v = np.cross(u, [1.0, 0.0, 0.0])
    v /= np.linalg.norm(v)
    w = np.cross(u, v)
    Rs = []
    for k, a in enumerate(np.linspace(0, 2 * np.pi, 40, endpoint=False)):
        s = 1.0 if k % 2 else -1.0
        x = np.cos(a) * v + np.sin(a) * w
        Rs.append(np.column_stack([x, s * u, np.cross(x, s * u)]))
    assert all(abs(np.linalg.det(R) - 1) < 1e-9 for R in Rs)
    assert concentrated_axis(Rs) == 1
    # the same set with its axes renamed (column 1 moved to column 2): the answer follows the column
    assert concentrated_axis([R[:, [0, 2, 1]] @ np.diag([1, 1, -1]) for R in Rs]) == 2
    # isotropic rotations: no axis stands out, but one is returned
    assert concentrated_axis(Rotation.random(50, random_state=1).as_matrix()) in (0, 1, 2)


def test_level_rotation_finds_the_down_of_level_cameras():
    """Cameras held level (x axis horizontal, any heading, any pitch) seen from a reference camera pitched 40
    degrees down: in the reference frame the true down is (0, cos 40, -sin 40) (OpenCV: +Y down, +Z forward; a
    camera pitched down sees the down direction tilted away from it). The levelling rotation takes that
    direction to +Y, and then every camera's x axis has no +Y component; cameras with their x axes in every
    direction give the identity."""
    from scipy.spatial.transform import Rotation

    from resti_lib.geometry.fields import level_rotation

    rng = np.random.default_rng(3)
    pitch = math.radians(40.0)
    down = np.array([0.0, math.cos(pitch), -math.sin(pitch)])
    # level x axes: unit vectors perpendicular to the down direction
    e1 = np.array([1.0, 0.0, 0.0])
    e2 = np.cross(down, e1)
    xs = [math.cos(a) * e1 + math.sin(a) * e2 for a in rng.uniform(0, 2 * np.pi, 40)]
    A = level_rotation(xs)
    assert np.allclose(A @ A.T, np.eye(3)) and np.linalg.det(A) > 0
    assert np.allclose(A @ down, [0.0, 1.0, 0.0], atol=1e-9)
    assert max(abs(float((A @ x)[1])) for x in xs) < 1e-9
    # a reference camera already level: the identity (its +Y is the down)
    flat = [np.array([math.cos(a), 0.0, math.sin(a)]) for a in rng.uniform(0, 2 * np.pi, 40)]
    assert np.allclose(level_rotation(flat), np.eye(3), atol=1e-9)
    # x axes in every direction: no down stands out
    assert np.array_equal(level_rotation(Rotation.random(60, random_state=2).as_matrix()[:, :, 0]), np.eye(3))
