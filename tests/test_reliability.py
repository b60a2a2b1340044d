"""Corrupted inputs: rows excluded for a stated reason, or one clear error naming file and field;
never a partial release."""

import json
import os

import pandas as pd
import pyarrow.parquet as pq
import pytest

from resti_lib.errors import InputError
from resti_lib.release.assemble import assemble
from resti_lib.tasks import names as _task_names
from resti_lib.tasks.run import run_task

TASK_NAMES = _task_names()


def _params(w, out):
    return {"legacy_benchmark": str(w / "legacy" / "qa.parquet"), "scannet_root": str(w / "scannet" / "scans"),
            "waymo_root": str(w / "waymo"), "omni6d_root": str(w / "omni6d"), "scannet_fps": 30, "omni6d_fps": 30,
            "video_map": "", "seed": 0, "output_dir": str(out)}


def test_malformed_legacy_rows_are_excluded_with_a_reason(world_with, tmp_path):
    world = world_with("legacy")
    qa = world / "legacy" / "qa.parquet"
    df = pd.read_parquet(qa)
    df = df[df.groupby("Task").cumcount() < 25].reset_index(drop=True)  # 25 rows of each task: a short run
    n = len(df)
    bad = {}
    i = df.index[df["Task"] == "Displacement & Path Length"][0]
    df.loc[i, "Candidates"] = '{"A": "1.00m", "B": '          # truncated Candidates JSON
    bad[i] = "Candidates"
    j = df.index[df["Task"] == "Speed & Acceleration"][0]
    c = json.loads(df.loc[j, "Candidates"])
    c.pop("E")
    df.loc[j, "Candidates"] = json.dumps(c)                    # four candidates
    bad[j] = "Candidates"
    k = df.index[df["Task"] == "Pose Estimation"][0]
    df.loc[k, "time_end"] = float("nan")                       # non-finite time
    bad[k] = "time_end"
    u = df.index[df["Task"] == "Dimensional Measurement"][0]
    df.loc[u, "Task"] = "Depth Guessing"                       # unknown task
    bad[u] = "Task"
    w = df.index[df["Task"] == "Trajectory Description"][0]
    df.loc[w, "Video"] = "seg|0_camera_1.mp4"                  # a '|' in the video name
    bad[w] = "Video"
    df.to_parquet(qa)
    out = tmp_path / "out"
    params = _params(world, out)
    for task in TASK_NAMES:
        run_task(task, params)
    v = assemble(qa, out / "tasks", out / "release")
    exc = [json.loads(line) for line in (out / "release" / "excluded.jsonl").read_text().splitlines()]
    acc = (out / "release" / "resti.jsonl").read_text().splitlines()
    assert len(acc) + len(exc) == n and v["passed"]
    prov = pd.read_parquet(out / "release" / "provenance.parquet").set_index("row")
    for row, field in bad.items():
        assert prov.loc[row, "verdict"] == "excluded"
        assert json.loads(prov.loc[row, "reasons"]) == ["malformed_row"]
        rec = next(e for e in exc if e["key"] == prov.loc[row, "key"])
        assert rec["verification_evidence"]["field"] == field


def test_truncated_sens_excludes_its_rows_by_name(miniworld, world_with, tmp_path):
    """A truncated .sens is damage: every row of that scene that needs it is excluded
    (source_damaged) with the file and field in its evidence; the other scenes' rows are audited."""
    rel = sorted((miniworld / "scannet" / "scans").glob("*/*.sens"))[0].relative_to(miniworld)
    scene = rel.parent.name
    world = world_with(rel)
    sens = world / rel
    os.truncate(sens, sens.stat().st_size // 2)
    params = _params(world, tmp_path / "out")
    for task in ("3D Video Grounding", "Ego-Centric Orientation", "Pose Estimation"):
        run = run_task(task, params)
        mine = [o for o in run.outcomes if o.video.startswith(scene)]
        assert mine and all(o.verdict == "excluded" and o.reasons == ["source_damaged"] for o in mine), task
        assert all(o.evidence["source_file"] == str(sens) and o.evidence["source_field"] == "num_frames"
                   for o in mine)
        assert any(o.verdict != "excluded" for o in run.outcomes if not o.video.startswith(scene))
    assert not (tmp_path / "out" / "release").exists()


def test_waymo_parquet_missing_a_column_excludes_its_segment(miniworld, world_with, tmp_path):
    rel = sorted((miniworld / "waymo" / "vehicle_pose").glob("*.parquet"))[0].relative_to(miniworld)
    world = world_with(rel)
    p = world / rel
    t = pq.read_table(p)
    pq.write_table(t.drop(["[VehiclePoseComponent].world_from_vehicle.transform"]), p)
    run = run_task("Trajectory Description", _params(world, tmp_path / "out"))
    mine = [o for o in run.outcomes if o.video.startswith(rel.stem)]
    assert mine and all(o.reasons == ["source_damaged"] and o.evidence["source_file"] == str(p)
                        and "world_from_vehicle" in o.evidence["source_field"] for o in mine)


def test_rope_zero_norm_quaternion(miniworld, world_with, tmp_path):
    scene = sorted((miniworld / "omni6d" / "ROPE").iterdir())[0]
    rel = sorted(scene.glob("*_meta.json"))[0].relative_to(miniworld)
    world = world_with(rel)
    meta = world / rel
    m = json.loads(meta.read_text())
    m["camera"]["quaternion"] = [0.0, 0.0, 0.0, 0.0]
    meta.write_text(json.dumps(m))
    with pytest.raises(InputError) as e:
        run_task("Pose Estimation", _params(world, tmp_path / "out"))
    assert e.value.file == str(meta) and "quaternion" in e.value.field
