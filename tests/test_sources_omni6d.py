"""Omni6DPose ROPE readers on meta files written here with every field cutoop's dataclasses require.

Frames are written the real way by default (camera pose identity, ``world_translation`` zero, object
poses in the OpenCV camera of the frame): the camera motion must come from the static objects.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from resti_lib.errors import InputError
from resti_lib.geometry import trajectory as G
from resti_lib.sources import omni6d as O

SCENE = "000123"
OID = "real-mug_001"
# a level OpenCV camera looking along world +X (z_cam -> +X, x_cam -> -Y, y_cam -> -Z)
LEVEL_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
INTR = {"fx": 600.0, "fy": 600.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480}


def rz(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def wxyz(R):
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return [float(w), float(x), float(y), float(z)]


def T_of(R, t):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def camera_pose(k):
    """World<-camera at frame k: yaw 5k deg, position (0, 0.05k, 0)."""
    return T_of(rz(5.0 * k) @ LEVEL_CAM, [0.0, 0.05 * k, 0.0])


# static objects standing upright (object +Z = world up) about 1 m ahead of camera 0
STATIC = {OID: T_of(rz(30.0), [1.0, 0.0, 0.0]),
          "real-bowl_002": T_of(rz(-50.0), [1.2, 0.25, -0.1]),
          "real-box_003": T_of(rz(10.0), [0.9, 0.05, 0.05])}
MOVER = "real-can_004"


def mover_pose(k):
    """A can that is slid 30 cm and turned 40 deg from frame 2 on (re-placed)."""
    return T_of(rz(0.0), [1.1, 0.1, 0.0]) if k < 2 else T_of(rz(40.0), [1.1, -0.2, 0.0])


def object_entry(oid, mask, T_cam_obj, T_world_obj, *, quat=None):
    return {"meta": {"oid": oid, "class_name": oid.split("-")[1].split("_")[0], "class_label": 7,
                     "instance_path": f"real/{oid}.obj", "scale": [1.0, 1.0, 2.0], "is_background": False,
                     "bbox_side_len": [0.1, 0.2, 0.6]},
            "quaternion_wxyz": quat if quat is not None else wxyz(T_cam_obj[:3, :3]),
            "translation": T_cam_obj[:3, 3].tolist(), "is_valid": True, "id": mask, "material": ["plastic"],
            "world_quaternion_wxyz": wxyz(T_world_obj[:3, :3]), "world_translation": T_world_obj[:3, 3].tolist()}


def frame_meta(k, *, store="identity", quat=None, objects=None, mover=False, gl=False, cam=camera_pose):
    """One frame. ``store``: ``identity`` (real ROPE: no camera motion, zero world poses),
    ``world_from_cam`` / ``cam_from_world`` (a stored pose carrying the motion, SOPE-style);
    ``gl``: object poses in OpenGL camera axes."""
    P = cam(k)
    objs = dict(STATIC if objects is None else objects)
    if mover:
        objs[MOVER] = mover_pose(k)
    entries = {}
    for i, (oid, Tw) in enumerate(objs.items(), start=1):
        Tc = np.linalg.inv(P) @ Tw
        if gl:
            Tc = np.diag([1.0, -1.0, -1.0, 1.0]) @ Tc
        world = np.eye(4) if store == "identity" else Tw
        entries[f"{i}_{oid}"] = object_entry(oid, i, Tc, world, quat=quat if oid == OID else None)
    if store == "identity":
        stored = np.eye(4)
    else:
        stored = P if store == "world_from_cam" else np.linalg.inv(P)
    return {"objects": entries,
            "camera": {"quaternion": wxyz(stored[:3, :3]), "translation": stored[:3, 3].tolist(),
                       "intrinsics": INTR, "scene_obj_path": "", "background_image_path": "",
                       "background_depth_path": "", "distances": [], "kind": ""},
            "scene_dataset": "real", "env_param": {}, "face_up": True, "concentrated": False,
            "comments": "real scan video data", "runtime_seed": -1, "baseline_dis": 0, "emitter_dist_l": 0}


def obj_meta(oids=(OID, *STATIC, MOVER), up="z"):
    inst = {oid: {"object_id": oid, "source": "real", "name": oid, "obj_path": f"real/{oid}.obj",
                  "tag": {"datatype": "test", "sceneChanger": False,
                          "symmetry": {"any": False, "x": "none", "y": "any", "z": "none"},
                          "materialOptions": ["plastic"], "upAxis": [up]},
                  "class_label": 7, "class_name": oid.split("-")[1].split("_")[0], "dimensions": [0.1, 0.2, 0.3]}
            for oid in dict.fromkeys(oids)}
    return {"class_list": [{"name": "mug", "label": 7, "instance_ids": sorted(inst), "stat": {}}],
            "instance_dict": inst}


def write_rope(root, n=3, *, up="z", **kw):
    d = root / "ROPE" / SCENE
    d.mkdir(parents=True)
    for k in range(n):
        (d / f"{k:06d}_meta.json").write_text(json.dumps(frame_meta(k, **kw)))
    (root / "Meta").mkdir()
    (root / "Meta" / "real_obj_meta.json").write_text(json.dumps(obj_meta(up=up)))
    return root


def rel(k):
    """The true camera pose relative to frame 0: T_c0<-ck."""
    return np.linalg.inv(camera_pose(0)) @ camera_pose(k)


def test_cutoop_is_used():
    assert O.HAVE_CUTOOP


def test_camera_track_from_static_objects_by_hand(tmp_path):
    sc = O.RopeScene(write_rope(tmp_path), SCENE)
    conv, ev = sc.verify_camera_convention()
    assert conv == {"camera": "objects", "direction": None, "axes": None, "object_axes": "opencv"}
    assert "no motion" in ev["stored_camera"]
    tr = sc.camera_track()
    np.testing.assert_allclose(tr.times, [0.0, 1 / 30, 2 / 30])
    for k in range(3):
        np.testing.assert_allclose(tr.T[k], rel(k), atol=1e-12)
    # camera 2 sits at world (0, 0.1, 0); in camera 0's OpenCV frame world +Y is -x: (-0.1, 0, 0)
    np.testing.assert_allclose(tr.T[2, :3, 3], [-0.1, 0.0, 0.0], atol=1e-12)
    cev = tr.meta["evidence"]
    assert sorted(cev["static_objects"]) == sorted(STATIC) and cev["left_out"] == []
    assert cev["frames_without_static_object"] == 0 and cev["max_consensus_spread_m"] < 1e-12
    # world up from the objects' up axes (object +Z, upAxis "z") = camera -Y of the level camera
    np.testing.assert_allclose(sc.world_up_in_track_frame([0, 0, 1]), [0.0, -1.0, 0.0], atol=1e-12)
    assert sc.gravity[1]["n_agreeing"] == 3
    th, _ = G.heading_change(tr, 0.0, 2 / 30, (0, 0, 1), sc.world_up_in_track_frame([0, 0, 1]))
    assert th == pytest.approx(10.0)  # yaw 5 deg per frame, left


def test_moving_object_is_left_out_and_named(tmp_path):
    sc = O.RopeScene(write_rope(tmp_path, n=4, mover=True), SCENE)
    static, ev = sc.static_objects
    assert sorted(static) == sorted(STATIC)
    (out,) = ev["left_out"]
    assert out["oid"] == MOVER and "moved or re-placed" in out["reason"]
    assert sorted(out["inconsistent_with"]) == sorted(STATIC)
    assert out["max_deviation_m"] > 0.25 and out["max_deviation_deg"] > 30
    tr = sc.camera_track()
    for k in range(4):
        np.testing.assert_allclose(tr.T[k], rel(k), atol=1e-12)
    # the mover's own track follows it: 0.3 m along world -Y after frame 2 (camera-0 frame +x)
    mt = sc.object_track(MOVER)
    np.testing.assert_allclose(mt.positions[3] - mt.positions[0], [0.3, 0.0, 0.0], atol=1e-12)
    assert not mt.meta["static"]


def test_frames_without_a_static_object_have_no_camera_pose(tmp_path):
    write_rope(tmp_path, n=3)
    # frame 1 shows only the re-placed can: its camera pose is unknown (invalid sample)
    (tmp_path / "ROPE" / SCENE / "000001_meta.json").write_text(json.dumps(
        frame_meta(1, objects={}, mover=True)))
    sc = O.RopeScene(tmp_path, SCENE)
    tr = sc.camera_track()
    assert tr.valid.tolist() == [True, False, True]
    np.testing.assert_allclose(tr.T[2], rel(2), atol=1e-12)
    assert tr.meta["evidence"]["frames_without_static_object"] == 1


def test_object_seen_later_is_placed_through_a_shared_frame(tmp_path):
    write_rope(tmp_path, n=3)
    late = {"real-bowl_002": STATIC["real-bowl_002"]}
    (tmp_path / "ROPE" / SCENE / "000002_meta.json").write_text(json.dumps(frame_meta(2, objects=late)))
    sc = O.RopeScene(tmp_path, SCENE)
    np.testing.assert_allclose(sc.camera_track().T[2], rel(2), atol=1e-12)


@pytest.mark.parametrize("store", ["world_from_cam", "cam_from_world"])
def test_stored_camera_pose_used_after_it_agrees(tmp_path, store):
    sc = O.RopeScene(write_rope(tmp_path, store=store), SCENE)
    conv, ev = sc.verify_camera_convention()
    assert conv == {"camera": "stored", "direction": store, "axes": "opencv", "object_axes": "opencv"}
    holds = {(c["direction"], c["axes"]): c["holds"] for c in ev["stored_camera"]["candidates"]}
    assert sum(holds.values()) == 1 and holds[(store, "opencv")]
    np.testing.assert_allclose(sc.camera_track(rebase=False).T[2], camera_pose(2), atol=1e-12)
    np.testing.assert_allclose(sc.camera_track().T[2], rel(2), atol=1e-12)
    # a scene frame exists: world up is the given scene direction moved into the first camera
    np.testing.assert_allclose(sc.world_up_in_track_frame([0, 0, 1]), [0.0, -1.0, 0.0], atol=1e-12)


def test_stored_camera_pose_that_disagrees_is_not_used(tmp_path):
    def wrong(k):  # the stored camera moves twice as far as the objects say
        return T_of(rz(5.0 * k) @ LEVEL_CAM, [0.0, 0.1 * k, 0.0])

    write_rope(tmp_path, n=3)
    for k in range(3):
        m = frame_meta(k)
        m["camera"]["quaternion"] = wxyz(wrong(k)[:3, :3])
        m["camera"]["translation"] = wrong(k)[:3, 3].tolist()
        (tmp_path / "ROPE" / SCENE / f"{k:06d}_meta.json").write_text(json.dumps(m))
    sc = O.RopeScene(tmp_path, SCENE)
    conv, ev = sc.verify_camera_convention()
    assert conv["camera"] == "objects" and ev["stored_camera"]["used"] is False
    assert "not used" in sc.camera_evidence()["stored_camera"]["note"]
    np.testing.assert_allclose(sc.camera_track().T[2], rel(2), atol=1e-12)


def test_object_poses_in_opengl_axes_are_recognised(tmp_path):
    sc = O.RopeScene(write_rope(tmp_path, gl=True), SCENE)
    assert sc.object_axes[0] == "opengl"
    np.testing.assert_allclose(sc.camera_track().T[2], rel(2), atol=1e-12)
    b = next(b for b in sc.object_boxes(0) if b["oid"] == OID)
    np.testing.assert_allclose(b["center"], [0.0, 0.0, 1.0], atol=1e-12)


def test_objects_nowhere_in_view(tmp_path):
    # an object 5 m straight above camera 0 (at the origin, looking along +X) has depth 0 under
    # either axis reading: the object poses cannot be verified
    above = {OID: T_of(np.eye(3), [0.0, 0.0, 5.0])}
    sc = O.RopeScene(write_rope(tmp_path, n=1, objects=above), SCENE)
    with pytest.raises(InputError) as e:
        sc.camera_track()
    assert e.value.field == "objects" and "in front of the camera" in str(e.value)


def test_object_boxes_by_hand(tmp_path):
    sc = O.RopeScene(write_rope(tmp_path), SCENE)
    b = next(b for b in sc.object_boxes(0) if b["oid"] == OID)
    # camera 0 at the origin looking along +X; the mug at world (1, 0, 0) is 1 m straight ahead
    np.testing.assert_allclose(b["center"], [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(b["lwh"], [0.1, 0.2, 0.6])  # scale (1, 1, 2) * dimensions (0.1, 0.2, 0.3)
    np.testing.assert_allclose(b["R"], LEVEL_CAM.T @ rz(30.0), atol=1e-12)
    assert b["oid"] == OID and b["class_name"] == "mug"
    # the static mug seen from the moving camera stays put in the first-camera frame
    tr = sc.object_track(OID)
    np.testing.assert_allclose(tr.positions, np.tile([0.0, 0.0, 1.0], (3, 1)), atol=1e-12)


def test_zero_norm_quaternion(tmp_path):
    sc = O.RopeScene(write_rope(tmp_path, quat=[0.0, 0.0, 0.0, 0.0]), SCENE)
    with pytest.raises(InputError) as e:
        sc.object_boxes(1)
    assert e.value.field == "quaternion_wxyz" and e.value.file.endswith("000001_meta.json")
    assert "zero norm" in str(e.value)


def test_missing_field_named(tmp_path):
    write_rope(tmp_path, n=1)
    p = tmp_path / "ROPE" / SCENE / "000000_meta.json"
    m = json.loads(p.read_text())
    del m["camera"]
    p.write_text(json.dumps(m))
    with pytest.raises(InputError) as e:
        O.RopeScene(tmp_path, SCENE).meta(0)
    assert e.value.field == "camera" and e.value.file == str(p)


# ------------------------------------------------------------------------------ real bytes


def test_real_rope_frame(real_samples):
    """The real ROPE frame (000157/000800): identity camera pose, zero world translations, object poses
    in the OpenCV camera in front of it and inside the image; the camera track reads it as is."""
    root = real_samples / "omni6dpose"
    raw = json.loads((root / "ROPE" / "000157" / "000800_meta.json").read_text())
    assert raw["camera"]["quaternion"] == [1, 0, 0, 0] and raw["camera"]["translation"] == [0, 0, 0]
    k = raw["camera"]["intrinsics"]
    by_hand = {}
    for o in raw["objects"].values():
        assert o["world_translation"] == [0, 0, 0]
        x, y, z = o["translation"]
        u, v = k["fx"] * x / z + k["cx"], k["fy"] * y / z + k["cy"]
        assert 0.67 <= z <= 0.79 and 0 <= u < k["width"] and 0 <= v < k["height"]
        by_hand[o["meta"]["oid"]] = (x, y, z)
    sc = O.RopeScene(root, "000157")
    assert sc.frames == [800] and sc.object_axes[0] == "opencv"
    conv, ev = sc.verify_camera_convention()
    assert conv["camera"] == "objects" and "no motion" in ev["stored_camera"]
    tr = sc.camera_track()
    np.testing.assert_allclose(tr.T[0], np.eye(4), atol=1e-12)
    assert sorted(tr.meta["evidence"]["static_objects"]) == sorted(by_hand)
    # the observations are the file's poses, OpenCV axes, as stored
    obs = sc._observations
    for oid, c in by_hand.items():
        np.testing.assert_allclose(obs[oid]["T"][0, :3, 3], c, atol=1e-15)
    # the camera looks down on a table: world up (the objects' shared +y) points up in the image
    # (-Y) and towards the camera (-Z); three of the four objects agree (the mango lies on its side)
    up, gev = sc.gravity
    assert up[1] < -0.3 and up[2] < -0.5 and gev["n_agreeing"] == 3
