"""Omni6DPose ROPE readers on meta files written here with every field cutoop's dataclasses require."""

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


OBJ_WORLD = T_of(rz(30.0), [1.0, 0.0, 0.0])  # the mug, static, 1 m ahead of camera 0


def object_entry(T_cam_obj, T_world_obj, *, quat=None):
    return {"meta": {"oid": OID, "class_name": "mug", "class_label": 7, "instance_path": "real/mug_001.obj",
                     "scale": [1.0, 1.0, 2.0], "is_background": False, "bbox_side_len": [0.1, 0.2, 0.6]},
            "quaternion_wxyz": quat if quat is not None else wxyz(T_cam_obj[:3, :3]),
            "translation": T_cam_obj[:3, 3].tolist(), "is_valid": True, "id": 1, "material": ["plastic"],
            "world_quaternion_wxyz": wxyz(T_world_obj[:3, :3]), "world_translation": T_world_obj[:3, 3].tolist()}


def frame_meta(k, *, store="world_from_cam", quat=None, obj_world=OBJ_WORLD):
    P = camera_pose(k)
    stored = P if store == "world_from_cam" else np.linalg.inv(P)
    T_cam_obj = np.linalg.inv(P) @ obj_world
    return {"objects": {f"1_{OID}": object_entry(T_cam_obj, obj_world, quat=quat)},
            "camera": {"quaternion": wxyz(stored[:3, :3]), "translation": stored[:3, 3].tolist(),
                       "intrinsics": INTR, "scene_obj_path": "", "background_image_path": "",
                       "background_depth_path": "", "distances": [], "kind": "real"},
            "scene_dataset": "ROPE", "env_param": {}, "face_up": True, "concentrated": False, "comments": "",
            "runtime_seed": 0, "baseline_dis": 0, "emitter_dist_l": 0}


def obj_meta():
    return {"class_list": [{"name": "mug", "label": 7, "instance_ids": [OID], "stat": {}}],
            "instance_dict": {OID: {"object_id": OID, "source": "real", "name": "mug_001",
                                    "obj_path": "real/mug_001.obj",
                                    "tag": {"datatype": "test", "sceneChanger": False,
                                            "symmetry": {"any": False, "x": "none", "y": "any", "z": "none"},
                                            "materialOptions": ["plastic"], "upAxis": ["y"]},
                                    "class_label": 7, "class_name": "mug", "dimensions": [0.1, 0.2, 0.3]}}}


def write_rope(root, n=3, **kw):
    d = root / "ROPE" / SCENE
    d.mkdir(parents=True)
    for k in range(n):
        (d / f"{k:06d}_meta.json").write_text(json.dumps(frame_meta(k, **kw)))
    (root / "Meta").mkdir()
    (root / "Meta" / "real_obj_meta.json").write_text(json.dumps(obj_meta()))
    return root


def test_cutoop_is_used():
    assert O.HAVE_CUTOOP


def test_verify_convention_world_from_cam(tmp_path):
    sc = O.RopeScene(write_rope(tmp_path), SCENE)
    conv, ev = sc.verify_camera_convention()
    assert conv == {"direction": "world_from_cam", "axes": "opencv", "object_axes": "opencv"}
    holds = {(c["direction"], c["axes"]): c["holds"] for c in ev["candidates"]}
    assert holds == {("world_from_cam", "opencv"): True, ("cam_from_world", "opencv"): False,
                     ("world_from_cam", "opengl"): False, ("cam_from_world", "opengl"): False}
    best = next(c for c in ev["candidates"] if c["holds"])
    assert best["median_residual_m"] < 1e-9


def test_verify_convention_cam_from_world(tmp_path):
    sc = O.RopeScene(write_rope(tmp_path, store="cam_from_world"), SCENE)
    conv, _ = sc.verify_camera_convention()
    assert conv["direction"] == "cam_from_world"
    # the camera track is the same physical trajectory either way
    tr = sc.camera_track(rebase=False)
    np.testing.assert_allclose(tr.T[2], camera_pose(2), atol=1e-12)


def test_no_convention_holds(tmp_path):
    # an object 5 m straight above camera 0 (at the origin, looking along +X) has depth 0 under
    # every reading of the stored pose: nothing can be verified
    above = T_of(np.eye(3), [0.0, 0.0, 5.0])
    sc = O.RopeScene(write_rope(tmp_path, n=1, obj_world=above), SCENE)
    with pytest.raises(InputError) as e:
        sc.verify_camera_convention()
    assert e.value.field == "camera"


def test_camera_track_rebased_by_hand(tmp_path):
    sc = O.RopeScene(write_rope(tmp_path), SCENE)
    tr = sc.camera_track()
    np.testing.assert_allclose(tr.times, [0.0, 1 / 30, 2 / 30])
    np.testing.assert_allclose(tr.T[0], np.eye(4), atol=1e-12)
    # camera 2 sits at world (0, 0.1, 0); in camera 0's OpenCV frame world +Y is -x: (-0.1, 0, 0)
    np.testing.assert_allclose(tr.T[2, :3, 3], [-0.1, 0.0, 0.0], atol=1e-12)
    up = sc.world_up_in_track_frame([0, 0, 1])
    np.testing.assert_allclose(up, [0.0, -1.0, 0.0], atol=1e-12)  # world up = camera -Y (level camera)
    th, _ = G.heading_change(tr, 0.0, 2 / 30, (0, 0, 1), up)
    assert th == pytest.approx(10.0)  # yaw 5 deg per frame, left


def test_object_boxes_by_hand(tmp_path):
    sc = O.RopeScene(write_rope(tmp_path), SCENE)
    (b,) = sc.object_boxes(0)
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
