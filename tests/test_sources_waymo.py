"""Waymo v2 parquet readers: files written here in the exact v2 layout, plus the real vehicle_pose."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from resti_lib.errors import InputError
from resti_lib.geometry import trajectory as G
from resti_lib.sources import waymo as W

SEG = "1234567890_1000_000_1020_000"
T0 = 1_552_440_195_362_591  # micros of the first frame


def transform_col(mats):
    flat = np.asarray(mats, dtype=np.float64).reshape(-1)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat, type=pa.float64()), 16)


def rz4(deg, t):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0, t[0]], [s, c, 0, t[1]], [0, 0, 1, t[2]], [0, 0, 0, 1.0]])


def camera_col(numbers, as_text=False):
    """``key.camera_name``: the CameraName enum as int8, or its names as text (the official camera_hkp)."""
    if as_text:
        return pa.array([W.CAMERA_NAMES[c] for c in numbers], pa.string())
    return pa.array(numbers, pa.int8())


def write_segment(root, n=5, drop=None, camera_names_as_text=False):
    """Vehicle parked at world (10, 20, 0) facing world +Y (yaw 90 deg); a FRONT camera 1.5 m ahead
    and 2 m up; one object (id "obj-a") 5 m ahead moving forward at 10 m/s; frames every 0.1 s."""
    micros = T0 + np.arange(n) * 100_000
    Wv = np.stack([rz4(90, (10, 20, 0))] * n)
    vp = {W.KEY_SEGMENT: [SEG] * n, W.KEY_MICROS: micros, W.VEHICLE_POSE: transform_col(Wv)}
    if drop:
        vp.pop(drop)
    (root / "vehicle_pose").mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.table(vp), root / "vehicle_pose" / f"{SEG}.parquet")

    E = np.eye(4)
    E[:3, 3] = [1.5, 0.0, 2.0]
    cal = {W.KEY_SEGMENT: [SEG, SEG], W.KEY_CAMERA: camera_col([1, 2], camera_names_as_text),
           W.CAL_EXTRINSIC: transform_col([E, rz4(45, (1.0, 0.5, 2.0))]),
           W.CAL_WIDTH: pa.array([1920, 1920], pa.int32()), W.CAL_HEIGHT: pa.array([1280, 1280], pa.int32())}
    for k, c in W.CAL_INTRINSIC.items():
        cal[c] = [2000.0 if k.startswith("f") else (960.0 if k == "c_u" else 640.0 if k == "c_v" else 0.0)] * 2
    (root / "camera_calibration").mkdir(exist_ok=True)
    pq.write_table(pa.table(cal), root / "camera_calibration" / f"{SEG}.parquet")

    img = {W.KEY_SEGMENT: [SEG] * n, W.KEY_MICROS: micros, W.KEY_CAMERA: camera_col([1] * n, camera_names_as_text),
           "[CameraImageComponent].image": pa.array([b"\xff\xd8jpeg"] * n, pa.binary()),
           W.IMG_POSE: transform_col(Wv), W.IMG_POSE_TIMESTAMP: (micros + 20_000) / 1e6}
    (root / "camera_image").mkdir(exist_ok=True)
    pq.write_table(pa.table(img), root / "camera_image" / f"{SEG}.parquet")

    k = np.arange(n)
    box = {W.KEY_SEGMENT: [SEG] * n, W.KEY_MICROS: micros, W.KEY_OBJECT: ["obj-a"] * n,
           W.BOX_COLUMNS["cx"]: 5.0 + 1.0 * k, W.BOX_COLUMNS["cy"]: [0.0] * n, W.BOX_COLUMNS["cz"]: [1.0] * n,
           W.BOX_COLUMNS["length"]: [4.5] * n, W.BOX_COLUMNS["width"]: [2.0] * n,
           W.BOX_COLUMNS["height"]: [1.6] * n, W.BOX_COLUMNS["heading"]: [0.0] * n,
           W.BOX_COLUMNS["type"]: pa.array([1] * n, pa.int8()),
           W.BOX_OPTIONAL["speed_x"]: [10.0] * n, W.BOX_OPTIONAL["speed_y"]: [0.0] * n,
           W.BOX_OPTIONAL["speed_z"]: [0.0] * n}
    (root / "lidar_box").mkdir(exist_ok=True)
    pq.write_table(pa.table(box), root / "lidar_box" / f"{SEG}.parquet")
    return root


@pytest.fixture()
def seg_root(tmp_path):
    return write_segment(tmp_path / "waymo")


def test_camera_names():
    assert W.camera_number(1) == 1
    assert W.camera_number("FRONT") == 1
    assert W.camera_number("front_left") == 2
    assert W.camera_number("3") == 3
    with pytest.raises(InputError) as e:
        W.camera_number("REAR")
    assert e.value.field == "camera"
    with pytest.raises(InputError):
        W.camera_number(7)


def test_camera_names_as_text_in_every_component(tmp_path):
    as_int = W.WaymoSegment(write_segment(tmp_path / "int"), SEG)
    as_text = W.WaymoSegment(write_segment(tmp_path / "text", camera_names_as_text=True), SEG)
    assert pq.read_schema(as_text.path("camera_calibration")).field(W.KEY_CAMERA).type == pa.string()
    assert sorted(as_text.calibration) == [1, 2]
    np.testing.assert_allclose(as_text.camera_calibration("FRONT_LEFT")["extrinsic"], rz4(45, (1.0, 0.5, 2.0)))
    for poses in ("vehicle_pose", "camera_image"):
        a, b = as_int.camera_track("FRONT", poses=poses), as_text.camera_track(1, poses=poses)
        assert len(b) == 5
        np.testing.assert_allclose(b.T, a.T)
        np.testing.assert_allclose(b.times, a.times)
    np.testing.assert_array_equal(W.read_camera_numbers(as_text.path("camera_image")), [1] * 5)


@pytest.mark.parametrize("component, values, problem", [
    ("camera_calibration", pa.array(["FRONT", "REAR"]), "'REAR' is not a camera"),
    ("camera_calibration", pa.array([1, 7], pa.int8()), "7 is not a camera"),
    ("camera_image", pa.array(["FRONT", None, "FRONT", "FRONT", "FRONT"]), "missing"),
    ("camera_image", pa.array([1.0] * 5), "type double"),
])
def test_bad_camera_name_names_file_row_and_column(tmp_path, component, values, problem):
    root = write_segment(tmp_path / "waymo")
    path = root / component / f"{SEG}.parquet"
    t = pq.read_table(path)
    pq.write_table(t.set_column(t.schema.get_field_index(W.KEY_CAMERA), W.KEY_CAMERA, values), path)
    seg = W.WaymoSegment(root, SEG)
    with pytest.raises(InputError) as e:
        seg.camera_track(1, poses="camera_image" if component == "camera_image" else "vehicle_pose")
    assert e.value.file == str(path) and e.value.field == W.KEY_CAMERA and problem in e.value.message
    if problem != "type double":
        assert e.value.row == 1


def test_real_camera_hkp_camera_names(real_samples):
    """The official camera_hkp test file stores key.camera_name as text: read as CameraName numbers."""
    path = real_samples / "waymo" / "camera_hkp" / "10023947602400723454_1120_000_1140_000.parquet"
    stored = pq.read_table(path, columns=[W.KEY_CAMERA]).column(0)
    assert pa.types.is_string(stored.type)
    nums = W.read_camera_numbers(path, "10023947602400723454_1120_000_1140_000")
    by_hand = {"FRONT": 1, "FRONT_LEFT": 2, "FRONT_RIGHT": 3, "SIDE_LEFT": 4, "SIDE_RIGHT": 5}
    assert len(nums) == 15_844
    np.testing.assert_array_equal(nums, [by_hand[x] for x in stored.to_pylist()])
    assert {W.CAMERA_NAMES[int(c)] for c in nums} == set(by_hand)


def test_vehicle_pose_and_time(seg_root):
    seg = W.WaymoSegment(seg_root, SEG)
    tr = seg.ego_track()
    np.testing.assert_allclose(tr.times, [0.0, 0.1, 0.2, 0.3, 0.4])
    assert seg.first_micros == T0
    np.testing.assert_allclose(tr.T[0], rz4(90, (10, 20, 0)))


def test_camera_track_opencv_by_hand(seg_root):
    seg = W.WaymoSegment(seg_root, SEG)
    tr = seg.camera_track("FRONT")
    T = tr.T[0]
    # centre: Rz90 (1.5, 0, 2) + (10, 20, 0) = (10, 21.5, 2)
    np.testing.assert_allclose(T[:3, 3], [10.0, 21.5, 2.0], atol=1e-12)
    # optical axis = vehicle forward = world +Y; image right = -(vehicle left) = world +X; down = -Z
    np.testing.assert_allclose(T[:3, 2], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(T[:3, 0], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(T[:3, 1], [0, 0, -1], atol=1e-12)
    cal = seg.camera_calibration(1)
    assert cal["width"] == 1920 and cal["intrinsics"]["c_u"] == 960.0
    # per-image poses at pose_timestamp = frame + 20 ms
    ti = seg.camera_track(1, poses="camera_image")
    np.testing.assert_allclose(ti.times, np.arange(5) * 0.1 + 0.02, atol=1e-6)
    np.testing.assert_allclose(ti.T[0], T, atol=1e-12)


def test_lidar_box_world_by_hand(seg_root):
    seg = W.WaymoSegment(seg_root, SEG)
    boxes = seg.boxes_at(0.0)
    assert len(boxes) == 1
    b = boxes[0]
    # vehicle-frame (5, 0, 1) -> world Rz90 (5, 0, 1) + (10, 20, 0) = (10, 25, 1); heading 0 + 90 deg
    np.testing.assert_allclose(b["center_world"], [10.0, 25.0, 1.0], atol=1e-12)
    assert math.degrees(b["heading_world"]) == pytest.approx(90.0)
    np.testing.assert_allclose(b["size"], [4.5, 2.0, 1.6])
    assert b["type"] == "TYPE_VEHICLE" and np.isnan(b["accel"]).all()  # acceleration columns absent
    tr = seg.object_track("obj-a")
    d, _ = G.endpoint_displacement(tr, 0.0, 0.4)
    assert d == pytest.approx(4.0)  # 1 m per 0.1 s for 0.4 s
    np.testing.assert_allclose(tr.positions[-1], [10.0, 29.0, 1.0], atol=1e-12)
    with pytest.raises(InputError) as e:
        seg.object_track("nope")
    assert e.value.field == W.KEY_OBJECT


def test_missing_column_names_file_and_column(tmp_path):
    root = write_segment(tmp_path / "w", drop=W.VEHICLE_POSE)
    with pytest.raises(InputError) as e:
        W.WaymoSegment(root, SEG).ego_track()
    assert e.value.field == W.VEHICLE_POSE
    assert e.value.file.endswith(f"vehicle_pose/{SEG}.parquet")


def test_image_bytes_not_read(seg_root, monkeypatch):
    seen = []
    real = pq.read_table

    def spy(path, columns=None, **kw):
        seen.append(list(columns or []))
        return real(path, columns=columns, **kw)

    monkeypatch.setattr(W.pq, "read_table", spy)
    W.read_camera_image_poses(seg_root / "camera_image" / f"{SEG}.parquet", "FRONT")
    assert seen and all("[CameraImageComponent].image" not in c for c in seen)


def test_duplicate_timestamp(tmp_path):
    p = tmp_path / "vp.parquet"
    pq.write_table(pa.table({W.KEY_SEGMENT: [SEG] * 2, W.KEY_MICROS: [T0, T0],
                             W.VEHICLE_POSE: transform_col([np.eye(4)] * 2)}), p)
    with pytest.raises(InputError) as e:
        W.read_vehicle_pose(p)
    assert e.value.field == W.KEY_MICROS


def test_vehicle_pose_errors_name_the_file_row_among_other_segments(tmp_path):
    # file rows 0-2: another segment; rows 3-5: SEG, written out of time order (row 4 goes back in time; a
    # pose table runs forward, so that is damage named at its row, not something to sort away)
    other = "9999999999_0000_000_0020_000"
    bad = np.eye(4)
    bad[0, 0] = 2.0  # not a rotation
    micros = [T0, T0 + 1, T0 + 2, T0 + 200_000, T0 + 100_000, T0 + 200_000]
    p = tmp_path / "vp.parquet"
    pq.write_table(pa.table({W.KEY_SEGMENT: [other] * 3 + [SEG] * 3, W.KEY_MICROS: micros,
                             W.VEHICLE_POSE: transform_col([np.eye(4)] * 6)}), p)
    with pytest.raises(InputError) as e:
        W.read_vehicle_pose(p, SEG)
    assert e.value.field == W.KEY_MICROS and e.value.row == 4
    # in time order, row 5 repeating row 4's time: named at row 5
    pq.write_table(pa.table({W.KEY_SEGMENT: [other] * 3 + [SEG] * 3,
                             W.KEY_MICROS: micros[:3] + [T0 + 100_000, T0 + 200_000, T0 + 200_000],
                             W.VEHICLE_POSE: transform_col([np.eye(4)] * 6)}), p)
    with pytest.raises(InputError) as e:
        W.read_vehicle_pose(p, SEG)
    assert e.value.field == W.KEY_MICROS and e.value.row == 5
    pq.write_table(pa.table({W.KEY_SEGMENT: [other] * 3 + [SEG] * 3,
                             W.KEY_MICROS: micros[:3] + [T0 + 100_000, T0 + 200_000, T0 + 300_000],
                             W.VEHICLE_POSE: transform_col([np.eye(4)] * 4 + [bad, np.eye(4)])}), p)
    with pytest.raises(InputError) as e:
        W.read_vehicle_pose(p, SEG)
    assert e.value.field == W.VEHICLE_POSE and e.value.row == 4


def test_snapshot_far_from_box_frames_excludes_but_damaged_boxes_stop(tmp_path):
    from resti_lib.errors import ContractError
    from resti_lib.sources.referents import SceneView

    root = write_segment(tmp_path / "w")  # box frames at 0.0 .. 0.4 s
    view = SceneView("Waymo", W.WaymoSegment(root, SEG), 1)
    assert [i.id for i in view.snapshot(0.2).instances] == ["obj-a"]
    with pytest.raises(ContractError):  # 0.1 s from the nearest box frame: one question, not the run
        view.snapshot(0.5)
    # the box frame at 0.2 s moved 1 us off its vehicle_pose frame: a damaged file, one clear error
    p = root / "lidar_box" / f"{SEG}.parquet"
    t = pq.read_table(p).to_pydict()
    t[W.KEY_MICROS] = [m + (1 if m == T0 + 200_000 else 0) for m in t[W.KEY_MICROS]]
    pq.write_table(pa.table(t), p)
    view = SceneView("Waymo", W.WaymoSegment(root, SEG), 1)
    with pytest.raises(InputError) as e:
        view.snapshot(0.2)
    assert e.value.file == str(p) and e.value.field == W.KEY_MICROS


# ---------------------------------------------------------------------------------------------
# the real file


def test_real_vehicle_pose(real_vehicle_pose):
    root = real_vehicle_pose.parent.parent
    seg_name = real_vehicle_pose.stem
    seg = W.WaymoSegment(root, seg_name)
    tr = seg.ego_track()
    assert len(tr) == 199
    assert seg.duration == pytest.approx(19.8, abs=0.01)
    assert tr.valid.all()

    # independent read: pandas, python lists, plain loops
    df = pd.read_parquet(real_vehicle_pose).sort_values("key.frame_timestamp_micros")
    mats = [np.array(list(m), dtype=float).reshape(4, 4)
            for m in df["[VehiclePoseComponent].world_from_vehicle.transform"]]
    micros = df["key.frame_timestamp_micros"].tolist()
    for i in range(len(mats)):
        R = mats[i][:3, :3]
        assert np.abs(R @ R.T - np.eye(3)).max() < 1e-5 and abs(np.linalg.det(R) - 1) < 1e-5
        assert tr.times[i] == pytest.approx((micros[i] - micros[0]) / 1e6, abs=1e-9)

    t_end = (micros[-1] - micros[0]) / 1e6
    path = 0.0
    for i in range(1, len(mats)):
        dx = [mats[i][k][3] - mats[i - 1][k][3] for k in range(3)]
        path += math.sqrt(sum(v * v for v in dx))
    L, _ = G.path_length(tr, 0.0, t_end)
    assert L == pytest.approx(path, rel=1e-12)
    disp = math.dist([mats[-1][k][3] for k in range(3)], [mats[0][k][3] for k in range(3)])
    d, _ = G.endpoint_displacement(tr, 0.0, t_end)
    assert d == pytest.approx(disp, rel=1e-12)
    s, _ = G.average_speed(tr, 0.0, t_end)
    assert s == pytest.approx(path / t_end, rel=1e-12)

    # heading, second method: yaw of the vehicle's +X axis in the world XY plane (up = +Z)
    def yaw(m):
        return math.degrees(math.atan2(m[1][0], m[0][0]))

    for i0, i1 in [(0, 198), (20, 150), (100, 101)]:
        expect = (yaw(mats[i1]) - yaw(mats[i0]) + 180.0) % 360.0 - 180.0
        th, _ = G.heading_change(tr, tr.times[i0], tr.times[i1], (1, 0, 0), (0, 0, 1))
        assert th == pytest.approx(expect, abs=1e-6)

    # mid-interval linear pose vs a hand lerp of the translation
    tm = 0.5 * (tr.times[10] + tr.times[11])
    T, _ = G.pose_at(tr, tm)
    np.testing.assert_allclose(T[:3, 3], 0.5 * (mats[10][:3, 3] + mats[11][:3, 3]), atol=1e-9)
