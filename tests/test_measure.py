"""`resti measure`: contracts as data on all three sources (files written by the source tests' writers)."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
import yaml

from resti_lib import measure as M
from tests.test_sources_omni6d import SCENE as ROPE_SCENE
from tests.test_sources_omni6d import write_rope
from tests.test_sources_scannet import P1, write_scene
from tests.test_sources_scannet import SCENE as SN_SCENE
from tests.test_sources_waymo import SEG, write_segment


@pytest.fixture(scope="module")
def roots(tmp_path_factory):
    base = tmp_path_factory.mktemp("sources")
    write_scene(base / "scans")
    write_segment(base / "waymo")
    write_rope(base / "omni6d")
    return {"scannet_root": str(base / "scans"), "waymo_root": str(base / "waymo"),
            "omni6d_root": str(base / "omni6d")}


def sn(op, times, **kw):
    return {"source": "ScanNet", "sequence": SN_SCENE, "entity": {"kind": "camera"}, "times": times,
            "operator": op, **kw}


def wy(op, times, entity=None, **kw):
    return {"source": "Waymo", "sequence": SEG, "entity": entity or {"kind": "object", "id": "obj-a"},
            "times": times, "operator": op, **kw}


def rp(op, times, entity=None, **kw):
    return {"source": "Omni6DPose", "sequence": ROPE_SCENE, "entity": entity or {"kind": "camera"},
            "times": times, "operator": op, **kw}


def test_scannet_pose_and_displacement(roots):
    r = M.evaluate_contract(sn("pose", [1 / 30]), roots)
    np.testing.assert_allclose(r["value"], P1)
    assert r["evidence"]["frames"] == [1] and r["evidence"]["files"].endswith(".sens")
    assert r["evidence"]["world"] == "ScanNet raw scan frame"
    r = M.evaluate_contract(sn("displacement", [0.0, 1 / 30], unit="cm"), roots)
    assert r["value"] == pytest.approx(100.0) and r["unit"] == "cm"  # the camera moved 1 m along +Y
    r = M.evaluate_contract(sn("average_velocity", [0.0, 1 / 30]), roots)
    assert r["value"] == pytest.approx(30.0) and r["unit"] == "m/s"  # 1 m in 1/30 s


def test_scannet_invalid_pose_error_and_shortening(roots):
    r = M.evaluate_contract(sn("pose", [2 / 30]), roots)
    assert "invalid" in r["error"] and "value" not in r
    r = M.evaluate_contract(sn("displacement", [0.0, 2 / 30]), roots)
    assert r["value"] == pytest.approx(1.0)
    assert r["evidence"]["shortened_to"] == pytest.approx(1 / 30)


def test_scannet_object_motion_is_refused(roots):
    r = M.evaluate_contract(sn("displacement", [0.0, 1 / 30], entity={"kind": "object", "id": 0}), roots)
    assert "static" in r["error"]


def test_waymo_object_operators_by_hand(roots):
    # the object moves 1 m per 0.1 s along its +X at constant velocity for 0.4 s
    r = M.evaluate_contract(wy("displacement", [0.0, 0.4]), roots)
    assert r["value"] == pytest.approx(4.0)
    r = M.evaluate_contract(wy("path_length", [0.05, 0.4]), roots)
    assert r["value"] == pytest.approx(3.5)
    r = M.evaluate_contract(wy("average_speed", [0.0, 0.4]), roots)
    assert r["value"] == pytest.approx(10.0)
    r = M.evaluate_contract(wy("acceleration", [0.0, 0.4]), {**roots, "acceleration_estimator": "central_difference"})
    assert r["value"] == pytest.approx(0.0, abs=1e-9) and "central difference" in r["evidence"]["estimator"]
    # the default for Waymo objects (as in the Speed notebook): the boxes' annotated velocities
    r = M.evaluate_contract(wy("acceleration", [0.0, 0.4]), roots)
    assert r["value"] == pytest.approx(0.0, abs=1e-9) and "annotated velocity" in r["evidence"]["estimator"]
    r = M.evaluate_contract(wy("heading_change", [0.0, 0.4]), roots)
    assert r["value"] == pytest.approx(0.0, abs=1e-9)


def test_waymo_camera_pose(roots):
    r = M.evaluate_contract(wy("pose", [0.2], entity={"kind": "camera"}, camera="FRONT"), roots)
    T = np.array(r["value"])
    np.testing.assert_allclose(T[:3, 3], [10.0, 21.5, 2.0], atol=1e-12)  # see test_sources_waymo
    np.testing.assert_allclose(T[:3, 2], [0.0, 1.0, 0.0], atol=1e-12)
    assert r["evidence"]["frame_timestamp_micros"] == [1_552_440_195_562_591]


def test_omni6d_by_hand(roots):
    r = M.evaluate_contract(rp("pose", [0.0]), roots)
    np.testing.assert_allclose(r["value"], np.eye(4), atol=1e-12)
    r = M.evaluate_contract(rp("heading_change", [0.0, 2 / 30]), roots)
    assert r["value"] == pytest.approx(10.0)  # the camera yaws 5 deg per frame to the left
    r = M.evaluate_contract(rp("displacement", [0.0, 2 / 30]), roots)
    assert r["value"] == pytest.approx(0.1)  # 0.05 m per frame
    r = M.evaluate_contract(rp("displacement", [0.0, 2 / 30], entity={"kind": "object", "id": "real-mug_001"}),
                            roots)
    assert r["value"] == pytest.approx(0.0, abs=1e-12)  # the mug is static


@pytest.mark.parametrize("contract, needle", [
    (sn("teleport", [0.0, 1.0]), "unknown operator"),
    (sn("displacement", [0.0]), "takes 2"),
    (sn("displacement", [0.0, 9.0]), "outside"),
    (sn("average_speed", [1 / 30, 1 / 30]), "zero-length"),
    (sn("displacement", [0.0, 1 / 30], unit="deg"), "cannot express"),
    (wy("displacement", [0.0, 0.4], entity={"kind": "object", "id": "ghost"}), "ghost"),
    (wy("pose", [0.0], entity={"kind": "camera"}, camera="SIDE_LEFT"), "not calibrated"),
    ({"source": "Kitti", "sequence": "x", "entity": {"kind": "camera"}, "times": [0], "operator": "pose"},
     "unknown source"),
])
def test_errors_not_values(roots, contract, needle):
    r = M.evaluate_contract(contract, roots)
    assert needle in r["error"] and "value" not in r


def test_missing_root_param(roots):
    r = M.evaluate_contract(sn("pose", [0.0]), {"waymo_root": roots["waymo_root"]})
    assert "scannet_root" in r["error"]


def test_registry_is_open(roots):
    @M.register_operator("frame_count_test", unit=None, n_times=(1,))
    def _count(ctx):
        return len(ctx.entity_track().track), {"counted": "samples"}

    try:
        r = M.evaluate_contract(sn("frame_count_test", [0.0]), roots)
        assert r["value"] == 3 and r["evidence"]["counted"] == "samples"
    finally:
        M.OPERATORS.pop("frame_count_test")


def test_measure_main(roots, tmp_path, capsys):
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump(roots))
    ok = tmp_path / "ok.json"
    ok.write_text(json.dumps([sn("displacement", [0.0, 1 / 30]), wy("displacement", [0.0, 0.4])]))
    assert M.measure_main([str(ok), "--params", str(params), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [o["value"] for o in out] == pytest.approx([1.0, 4.0])
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(sn("pose", [2 / 30])))
    assert M.measure_main([str(bad), "--params", str(params)]) == 1
    assert "ERROR" in capsys.readouterr().out
    (tmp_path / "broken.json").write_text("{nope")
    assert M.measure_main([str(tmp_path / "broken.json"), "--params", str(params)]) == 2


def test_real_waymo_vehicle_heading_and_path(real_vehicle_pose):
    params = {"waymo_root": str(real_vehicle_pose.parent.parent)}
    seg = real_vehicle_pose.stem
    df = pd.read_parquet(real_vehicle_pose).sort_values("key.frame_timestamp_micros")
    mats = [np.array(list(m), dtype=float).reshape(4, 4)
            for m in df["[VehiclePoseComponent].world_from_vehicle.transform"]]
    micros = df["key.frame_timestamp_micros"].tolist()
    i0, i1 = 30, 180
    t0, t1 = (micros[i0] - micros[0]) / 1e6, (micros[i1] - micros[0]) / 1e6
    base = {"source": "Waymo", "sequence": seg, "entity": {"kind": "camera"}, "times": [t0, t1]}
    r = M.evaluate_contract({**base, "operator": "heading_change"}, params)
    yaw0 = math.atan2(mats[i0][1, 0], mats[i0][0, 0])
    yaw1 = math.atan2(mats[i1][1, 0], mats[i1][0, 0])
    expect = (math.degrees(yaw1 - yaw0) + 180.0) % 360.0 - 180.0
    assert r["value"] == pytest.approx(expect, abs=1e-6)
    assert "vehicle frame is the subject" in r["evidence"]["notes"][0]
    r = M.evaluate_contract({**base, "operator": "path_length"}, params)
    expect = sum(float(np.linalg.norm(mats[k][:3, 3] - mats[k - 1][:3, 3])) for k in range(i0 + 1, i1 + 1))
    assert r["value"] == pytest.approx(expect, rel=1e-12)


def _rope_T(meta: dict, oid: str) -> np.ndarray:
    """T_cam<-obj of one object of a ROPE frame meta, by hand (unit wxyz quaternion)."""
    o = next(o for o in meta["objects"].values() if o["meta"]["oid"] == oid)
    w, x, y, z = o["quaternion_wxyz"]
    T = np.eye(4)
    T[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    T[:3, 3] = o["translation"]
    return T


def test_measure_rope_camera_written_the_real_way(miniworld, tmp_path, capsys):
    """`resti measure` on the mini-world's ROPE scene with a re-placed object (frames written the real
    way: identity camera pose): camera displacement, path length and pose equal an independent
    computation from one static object's poses, T_c0<-ck = T_c0<-obj T_ck<-obj^-1, within 1 mm."""
    info = json.loads((miniworld / "world.json").read_text())
    scene = next(s for s in info["sequences"]["omni6d"] if s["moving_object"])
    d = miniworld / "omni6d" / "ROPE" / scene["scene"]
    metas = [json.loads((d / f"{k:06d}_meta.json").read_text()) for k in range(scene["n_frames"])]
    assert all(m["camera"]["translation"] == [0.0, 0.0, 0.0] for m in metas)
    seen = [{o["meta"]["oid"] for o in m["objects"].values()} for m in metas]
    mover = scene["moving_object"]
    k0 = 30 * math.ceil(mover["frames"][0] / 30)  # an interval over the re-placement
    k1 = k0 + 90
    oid = next(o["oid"] for o in scene["objects"] if o["oid"] != mover["oid"]
               and all(o["oid"] in seen[k] for k in [0, *range(k0, k1 + 1)]))
    T0 = _rope_T(metas[0], oid)
    cam = {k: T0 @ np.linalg.inv(_rope_T(metas[k], oid)) for k in range(k0, k1 + 1)}
    want_disp = float(np.linalg.norm(cam[k1][:3, 3] - cam[k0][:3, 3]))
    want_path = sum(float(np.linalg.norm(cam[k][:3, 3] - cam[k - 1][:3, 3])) for k in range(k0 + 1, k1 + 1))
    t0, t1 = k0 / 30, k1 / 30
    contracts = [{"source": "Omni6DPose", "sequence": scene["scene"], "entity": {"kind": "camera"},
                  "times": times, "operator": op}
                 for op, times in (("displacement", [t0, t1]), ("path_length", [t0, t1]), ("pose", [t1]))]
    (tmp_path / "c.json").write_text(json.dumps(contracts))
    (tmp_path / "p.yaml").write_text(yaml.safe_dump({"omni6d_root": str(miniworld / "omni6d")}))
    assert M.measure_main([str(tmp_path / "c.json"), "--params", str(tmp_path / "p.yaml"), "--json"]) == 0
    disp, path, pose = json.loads(capsys.readouterr().out)
    assert want_disp > 0.05 and disp["value"] == pytest.approx(want_disp, abs=1e-3)
    assert path["value"] == pytest.approx(want_path, abs=1e-3)
    np.testing.assert_allclose(np.array(pose["value"])[:3, 3], cam[k1][:3, 3], atol=1e-3)
    np.testing.assert_allclose(np.array(pose["value"])[:3, :3], cam[k1][:3, :3], atol=1e-6)
