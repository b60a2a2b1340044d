"""ScanNet readers on files written here in the exact ScanNet layout (formats/scannet.md)."""

from __future__ import annotations

import json
import math
import struct

import numpy as np
import pytest
import trimesh

from resti_lib.errors import ContractError, InputError
from resti_lib.geometry import frames as F
from resti_lib.geometry import trajectory as G
from resti_lib.sources import scannet as S

SCENE = "scene0007_00"
RZ90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
# A = T_ann_from_raw: rotate 90 deg about Z, then shift by (1, 2, 0)
A = F.make_T(RZ90, [1.0, 2.0, 0.0])
# a level camera at raw (1, -3, 0.5) looking along raw +Y: x_cam = +X, y_cam = -Z, z_cam = +Y
P0 = F.make_T(np.column_stack([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]), [1.0, -3.0, 0.5])
P1 = F.make_T(P0[:3, :3], [1.0, -2.0, 0.5])


def write_sens(path, poses, color_sizes=None, depth_sizes=None, version=4):
    n = len(poses)
    color_sizes = color_sizes or [100] * n
    depth_sizes = depth_sizes or [50] * n
    K = np.array([[1170.0, 0, 647.0, 0], [0, 1170.0, 483.0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    with open(path, "wb") as f:
        f.write(struct.pack("<I", version))
        name = b"StructureSensor"
        f.write(struct.pack("<Q", len(name)) + name)
        f.writelines(struct.pack("<16f", *np.asarray(M, float).reshape(-1)) for M in (K, np.eye(4), K, np.eye(4)))
        f.write(struct.pack("<ii", 2, 1))  # jpeg, zlib_ushort
        f.write(struct.pack("<4I", 1296, 968, 640, 480))
        f.write(struct.pack("<f", 1000.0))
        f.write(struct.pack("<Q", n))
        for i, T in enumerate(poses):
            f.write(struct.pack("<16f", *np.asarray(T, float).reshape(-1)))
            f.write(struct.pack("<QQQQ", 1000 * i, 1000 * i + 1, color_sizes[i], depth_sizes[i]))
            f.write(b"\xab" * color_sizes[i])
            f.write(b"\xcd" * depth_sizes[i])


def write_scene(root, *, with_alignment=True, vertices=None, n_segs_extra=0):
    d = root / SCENE
    d.mkdir(parents=True)
    lines = []
    if with_alignment:
        lines.append("axisAlignment = " + " ".join(f"{x:g}" for x in A.reshape(-1)))
    lines += ["colorHeight = 968", "colorWidth = 1296", "fx_color = 1170.19", "fy_color = 1170.19",
              "mx_color = 647.75", "my_color = 483.75", "numColorFrames = 3", "numDepthFrames = 3",
              "sceneType = Office"]
    (d / f"{SCENE}.txt").write_text("\n".join(lines) + "\n")
    bad = np.full((4, 4), -np.inf)
    write_sens(d / f"{SCENE}.sens", [P0, P1, bad])
    # mesh: instance 1 = the 8 corners of raw box [0,2]x[0,1]x[0,1]; instance 2 = 4 far points
    if vertices is None:
        box = np.array([[x, y, z] for x in (0.0, 2.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
        far = np.array([[5.0, 5.0, 0.0], [6.0, 5.0, 0.0], [5.0, 6.0, 0.0], [5.0, 5.0, 1.0]])
        vertices = np.vstack([box, far])
        seg = [10] * 4 + [11] * 4 + [20] * 4
    else:
        seg = [10] * len(vertices)
    faces = np.array([[0, 1, 2]])
    trimesh.Trimesh(vertices, faces, process=False).export(d / f"{SCENE}_vh_clean_2.ply")
    (d / f"{SCENE}_vh_clean_2.0.010000.segs.json").write_text(json.dumps(
        {"sceneId": SCENE, "params": {}, "segIndices": seg + [99] * n_segs_extra}))
    (d / f"{SCENE}.aggregation.json").write_text(json.dumps({
        "sceneId": f"scannet.{SCENE}", "segmentsFile": f"scannet.{SCENE}_vh_clean_2.0.010000.segs.json",
        "segGroups": [{"id": 0, "objectId": 0, "label": "table", "segments": [10, 11]},
                      {"id": 1, "objectId": 1, "label": "chair", "segments": [20]}]}))
    return root


@pytest.fixture()
def scans(tmp_path):
    return write_scene(tmp_path / "scans")


def test_scene_meta(scans):
    m = S.read_scene_meta(scans / SCENE / f"{SCENE}.txt")
    np.testing.assert_allclose(m.require_axis_alignment(), A)
    assert m.color_intrinsics == {"fx": 1170.19, "fy": 1170.19, "cx": 647.75, "cy": 483.75,
                                  "width": 1296, "height": 968}
    assert m.num_color_frames == 3 and m.values["sceneType"] == "Office"


def test_sens_poses(scans):
    sp = S.read_sens_poses(scans / SCENE / f"{SCENE}.sens")
    assert sp.header.num_frames == 3 and sp.header.color_width == 1296
    assert sp.header.sensor_name == "StructureSensor"
    np.testing.assert_allclose(sp.T[0], P0)
    np.testing.assert_allclose(sp.T[1], P1)
    assert sp.valid.tolist() == [True, True, False]
    assert sp.timestamp_color.tolist() == [0, 1000, 2000]


def test_sens_reader_skips_payloads(tmp_path, monkeypatch):
    p = tmp_path / "big.sens"
    n = 4
    write_sens(p, [P0] * n, color_sizes=[200_000] * n, depth_sizes=[100_000] * n)
    read_bytes = []
    real_open = open

    class Spy:
        def __init__(self, f):
            self.f = f

        def read(self, k=-1):
            b = self.f.read(k)
            read_bytes.append(len(b))
            return b

        def __getattr__(self, name):
            return getattr(self.f, name)

        def __enter__(self):
            return self

        def __exit__(self, *a):
            self.f.close()

    monkeypatch.setattr(S, "open", lambda *a, **k: Spy(real_open(*a, **k)), raising=False)
    sp = S.read_sens_poses(p)
    assert sp.T.shape == (n, 4, 4)
    header_bytes = 4 + 8 + 15 + 4 * 64 + 8 + 16 + 4 + 8
    assert sum(read_bytes) == header_bytes + 96 * n  # not one image byte


FRAME = 96 + 100 + 50  # frame header + colour + depth bytes as written by write_sens


@pytest.mark.parametrize("cut, row, field", [
    (-2 * FRAME + 40, 1, "camera_to_world"),  # 40 of frame 1's 96 header bytes: inside the pose
    (-2 * FRAME + 75, 1, "timestamp_depth"),  # bytes 72..80 of the header
    (-100, 2, "color_data"),                  # frame 2's colour bytes cut short
    (-20, 2, "depth_data"),
])
def test_truncated_sens(tmp_path, cut, row, field):
    p = tmp_path / "t.sens"
    write_sens(p, [P0, P1, P1])
    data = p.read_bytes()
    p.write_bytes(data[:cut])
    with pytest.raises(InputError) as e:
        S.read_sens_poses(p)
    assert e.value.row == row and e.value.field == field and e.value.file == str(p)


def test_truncated_header_and_version(tmp_path):
    p = tmp_path / "h.sens"
    write_sens(p, [P0])
    p.write_bytes(p.read_bytes()[:60])  # 27 bytes of version + name, then 33 of intrinsic_color
    with pytest.raises(InputError) as e:
        S.read_sens_poses(p)
    assert e.value.field == "intrinsic_color"
    write_sens(p, [P0], version=3)
    with pytest.raises(InputError) as e:
        S.read_sens_poses(p)
    assert e.value.field == "version"


def test_camera_track_and_invalid(scans):
    sc = S.ScanNetScene(scans, SCENE)
    tr = sc.camera_track()
    np.testing.assert_allclose(tr.times, [0.0, 1 / 30, 2 / 30])
    assert tr.valid.tolist() == [True, True, False]
    d, ev = G.endpoint_displacement(tr, 0.0, 2 / 30)
    assert d == pytest.approx(1.0) and ev["shortened_to"] == pytest.approx(1 / 30)
    assert sc.intrinsics["fx"] == 1170.19


def test_pose_dir_and_inf_pose(scans):
    d = scans / SCENE
    (d / f"{SCENE}.sens").unlink()
    (d / "pose").mkdir()
    for k, T in enumerate([P0, P1]):
        (d / "pose" / f"{k}.txt").write_text("\n".join(" ".join(f"{x:.6f}" for x in r) for r in T) + "\n")
    (d / "pose" / "2.txt").write_text("\n".join(["-inf -inf -inf -inf"] * 4) + "\n")
    sc = S.ScanNetScene(scans, SCENE)
    tr = sc.camera_track()
    assert tr.valid.tolist() == [True, True, False]
    np.testing.assert_allclose(sc.camera_pose(1), P1)
    # an invalid pose at an asked frame is a per-question outcome (ContractError), naming file and field
    with pytest.raises(ContractError) as e:
        sc.camera_pose(2)
    assert "pose/2.txt" in str(e.value) and "field 'pose'" in str(e.value) and "row 2" in str(e.value)
    (d / "pose" / "3.txt").write_text("1 0 0\n0 1 0\n")
    with pytest.raises(InputError) as e:
        S.read_pose_dir(d / "pose")
    assert e.value.file.endswith("3.txt") and e.value.field == "pose"


def test_instances_and_camera_frame_centre_by_hand(scans):
    sc = S.ScanNetScene(scans, SCENE)
    inst = sc.instances
    assert sorted(inst) == [0, 1] and inst[0].label == "table"
    assert inst[0].vertices_raw.shape == (8, 3)
    # A @ v for the raw box [0,2]x[0,1]x[0,1]: x_ann = 1 - y in [0,1], y_ann = x + 2 in [2,4]
    aabb = inst[0].aabb_ann
    np.testing.assert_allclose(aabb["center"], [0.5, 3.0, 0.5])
    np.testing.assert_allclose(aabb["size"], [1.0, 2.0, 1.0])
    # camera-frame centre at frame 0: c_cam = P^-1 A^-1 c_ann. Raw centre (1, 0.5, 0.5), camera at
    # (1, -3, 0.5) looking along +Y -> the centre is 3.5 m straight ahead: (0, 0, 3.5)
    c_cam = F.apply_T(F.invert_T(sc.camera_pose(0)) @ F.invert_T(sc.axis_alignment), aabb["center"])
    np.testing.assert_allclose(c_cam, [0.0, 0.0, 3.5], atol=1e-12)
    # the legacy chain P^-1 c_ann (alignment omitted): R^T ((0.5, 3, 0.5) - (1, -3, 0.5)) = (-0.5, 0, 6)
    np.testing.assert_allclose(F.apply_T(F.invert_T(sc.camera_pose(0)), aabb["center"]), [-0.5, 0.0, 6.0],
                               atol=1e-12)
    # oriented box: length 2 along ann +Y (yaw 90 deg), width 1, height 1
    obb = inst[0].obb_ann
    np.testing.assert_allclose(obb.lwh, [2.0, 1.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(obb.center, [0.5, 3.0, 0.5], atol=1e-9)
    np.testing.assert_allclose(np.abs(obb.R[:, 0]), [0.0, 1.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(inst[0].obb_raw.center, [1.0, 0.5, 0.5], atol=1e-9)


def test_upright_box_rotated_rectangle_by_hand():
    yaw = math.radians(30.0)
    c, s = math.cos(yaw), math.sin(yaw)
    corners = []
    for u in (-2.0, 2.0):
        for v in (-1.0, 1.0):
            for z in (0.0, 1.0):
                corners.append([1.0 + c * u - s * v, 1.0 + s * u + c * v, z])
    b = S.upright_oriented_box(np.array(corners))
    np.testing.assert_allclose(b.lwh, [4.0, 2.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(b.center, [1.0, 1.0, 0.5], atol=1e-12)
    assert math.degrees(math.atan2(b.R[1, 0], b.R[0, 0])) == pytest.approx(30.0)


def test_upright_box_is_tight_whatever_the_point_density():
    """A 4 x 2 m footprint at yaw 0 with a dense streak of points along its diagonal: the density's
    principal axis is tilted, the minimum-area rectangle is not."""
    corners = [[x, y, z] for x in (0.0, 4.0) for y in (0.0, 2.0) for z in (0.0, 0.5)]
    s = np.linspace(0.05, 0.95, 2000)[:, None]
    streak = np.hstack([4.0 * s, 2.0 * s, np.full_like(s, 0.25)])
    b = S.upright_oriented_box(np.vstack([corners, streak]))
    np.testing.assert_allclose(b.lwh, [4.0, 2.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(b.center, [2.0, 1.0, 0.25], atol=1e-12)
    assert b.yaw_deg == pytest.approx(0.0, abs=1e-9) and b.footprint_area == pytest.approx(8.0)


def test_upright_box_of_degenerate_points():
    line = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [2.0, 2.0, 1.0]])
    b = S.upright_oriented_box(line)
    np.testing.assert_allclose(b.lwh, [2.0 * math.sqrt(2.0), 0.0, 1.0], atol=1e-12)
    assert b.yaw_deg == pytest.approx(45.0)
    b = S.upright_oriented_box(np.array([[1.0, 2.0, 3.0]]))
    np.testing.assert_allclose(b.lwh, [0.0, 0.0, 0.0])
    np.testing.assert_allclose(b.center, [1.0, 2.0, 3.0])


def _ply_vertices(path) -> np.ndarray:
    """x, y, z of a binary little-endian PLY, parsed by hand from its header."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode().splitlines()
    i = next(k for k, h in enumerate(header) if h.startswith("element vertex"))
    n = int(header[i].split()[2])
    props = []
    for h in header[i + 1:]:
        if not h.startswith("property"):
            break
        props.append((h.split()[2], {"float": "<f4", "uchar": "u1", "double": "<f8"}[h.split()[1]]))
    v = np.frombuffer(data, dtype=np.dtype(props), count=n, offset=end)
    return np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)


def test_real_scene0000_00_tight_boxes(real_samples):
    """The 55 instances of ScanNet scene0000_00 with their labels and tight upright boxes, checked
    against a by-hand reading (PLY, segments, aggregation, axisAlignment) and a fine yaw search."""
    from scipy.spatial import ConvexHull

    d = real_samples / "scannet" / "scene0000_00"
    meta = S.read_scene_meta(d / "scene0000_00.txt")
    inst = S.read_instances(d, "scene0000_00", meta.axis_alignment_or_none, d / "scene0000_00.txt")
    agg = json.loads((d / "scene0000_00.aggregation.json").read_text())
    seg = np.asarray(json.loads((d / "scene0000_00_vh_clean_2.0.010000.segs.json").read_text())["segIndices"])
    A = np.array([float(x) for x in (d / "scene0000_00.txt").read_text().split("axisAlignment = ")[1]
                  .split()[:16]]).reshape(4, 4)
    ann = _ply_vertices(d / "scene0000_00_vh_clean_2.ply") @ A[:3, :3].T + A[:3, 3]
    assert len(agg["segGroups"]) == len(inst) == 55
    yaws = np.radians(np.arange(0.0, 90.0, 0.05))
    axes = np.stack([np.cos(yaws), np.sin(yaws)], axis=1)
    shrunk = []
    for g in agg["segGroups"]:
        i = inst[g["objectId"]]
        assert i.label == g["label"]
        v = ann[np.isin(seg, g["segments"])]
        np.testing.assert_allclose(i.vertices_ann, v, atol=1e-9)
        b = i.obb_ann
        # height = vertical extent; the box is upright and holds every vertex
        assert b.lwh[2] == pytest.approx(np.ptp(v[:, 2]), abs=1e-9) and abs(b.R[2, 2] - 1.0) < 1e-12
        local = (v - b.center) @ b.R
        assert (np.abs(local) <= b.lwh / 2 + 1e-9).all() and b.lwh[0] >= b.lwh[1]
        # footprint never larger than the axis-aligned one; as small as a 0.05-degree yaw search
        aabb = np.ptp(v[:, 0]) * np.ptp(v[:, 1])
        assert b.footprint_area <= aabb + 1e-12
        h = v[ConvexHull(v[:, :2]).vertices, :2]
        u, w = h @ axes.T, h @ np.stack([-axes[:, 1], axes[:, 0]], axis=1).T
        grid = (np.ptp(u, axis=0) * np.ptp(w, axis=0)).min()
        assert grid * (1 - 5e-3) <= b.footprint_area <= grid + 1e-12  # the grid misses by <= 0.025 deg
        shrunk.append(1 - b.footprint_area / aabb)
        if g["label"] == "couch":  # the example: PCA put it at 30.1 deg, 8.79 m^2
            assert abs(b.yaw_deg) < 2.0 and b.footprint_area < 7.15
    assert sum(x > 0.01 for x in shrunk) >= 30


def test_missing_axis_alignment_only_when_needed(tmp_path):
    root = write_scene(tmp_path / "scans", with_alignment=False)
    sc = S.ScanNetScene(root, SCENE)
    assert len(sc.camera_track()) == 3  # poses do not need the annotation frame
    inst = sc.instances  # raw vertices load fine
    with pytest.raises(InputError) as e:
        _ = sc.axis_alignment
    assert e.value.field == "axisAlignment" and e.value.file.endswith(f"{SCENE}.txt")
    with pytest.raises(InputError) as e:
        _ = inst[0].aabb_ann
    assert e.value.field == "axisAlignment" and e.value.file.endswith(f"{SCENE}.txt")


def test_segs_vertex_mismatch(tmp_path):
    root = write_scene(tmp_path / "scans", n_segs_extra=3)
    with pytest.raises(InputError) as e:
        _ = S.ScanNetScene(root, SCENE).instances
    assert e.value.field == "segIndices"


def test_bad_axis_alignment(tmp_path):
    p = tmp_path / "s.txt"
    p.write_text("axisAlignment = 1 0 0\n")
    with pytest.raises(InputError) as e:
        S.read_scene_meta(p)
    assert e.value.field == "axisAlignment" and e.value.row == 1
