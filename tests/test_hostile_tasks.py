"""Real-data faults in the legacy benchmark and the sources: exclusions with reasons, or one clear
stop when the whole input is unusable. Every damaged world is a copy made in tmp_path."""

from __future__ import annotations

import json
import shutil
import struct

import pandas as pd
import pytest

from resti_lib.defects import DEFECTS, REASONS
from resti_lib.errors import InputError
from resti_lib.release.assemble import assemble
from resti_lib.sources.scannet import read_sens_header
from resti_lib.tasks.run import run_task


def _params(w, out, legacy=None):
    return {"legacy_benchmark": str(legacy or w / "legacy" / "qa.parquet"), "scannet_root": str(w / "scannet" / "scans"),
            "waymo_root": str(w / "waymo"), "omni6d_root": str(w / "omni6d"), "scannet_fps": 30, "omni6d_fps": 30,
            "video_map": "", "seed": 0, "output_dir": str(out)}


@pytest.fixture
def legacy_copy(miniworld, tmp_path):
    """A copy of the mini-world's legacy benchmark (the sources are read in place)."""
    qa = tmp_path / "qa.parquet"
    shutil.copy(miniworld / "legacy" / "qa.parquet", qa)
    return qa


def _outcomes(run) -> dict[int, object]:
    return {o.row: o for o in run.outcomes}


def test_new_codes_are_in_the_vocabulary():
    for code in ("duplicate_row", "time_past_video_end"):
        assert code in DEFECTS and code in REASONS and DEFECTS[code].layer == "question"


@pytest.mark.slow  # over 3 s: make test runs it, make test-fast leaves it out
def test_scannet_pose_invalid_at_t0_is_an_exclusion(miniworld, world_with, tmp_path):
    """Real ScanNet often has failed tracking (-inf poses) on the first frames. Pose rows asking the
    pose at t = 0 are excluded like in the other tasks; the other rows keep their verdict."""
    task = "Pose Estimation"
    clean = _outcomes(run_task(task, _params(miniworld, tmp_path / "clean")))
    world = world_with(*(p.relative_to(miniworld) for p in (miniworld / "scannet" / "scans").glob("*/*.sens")))
    for sens in sorted((world / "scannet" / "scans").glob("*/*.sens")):
        with open(sens, "r+b") as f:
            h = read_sens_header(f, sens)
            f.seek(h.frames_offset)  # the camera_to_world matrix of frame 0
            f.write(struct.pack("<16f", *([float("-inf")] * 16)))
    damaged = _outcomes(run_task(task, _params(world, tmp_path / "damaged")))
    legacy = pd.read_parquet(world / "legacy" / "qa.parquet")
    rows = legacy[(legacy["Task"] == task)]
    at_zero = {int(i) for i in rows.index[(rows["Source"] == "ScanNet") & (rows["time_start"] == 0.0)]}
    assert at_zero  # the world asks poses at t = 0
    for i in rows.index:
        o = damaged[int(i)]
        if int(i) in at_zero:
            assert o.verdict == "excluded" and o.reasons == ["invalid_pose_at_time"], (i, o.reasons)
            assert "non-finite" in o.evidence["error"] and o.evidence["premise_time"] == 0.0
        else:
            assert (o.verdict, o.reasons) == (clean[int(i)].verdict, clean[int(i)].reasons), i


@pytest.mark.parametrize("how", ["zero rows", "zero bytes", "jsonl without lines"])
def test_empty_legacy_file_is_a_clear_stop(miniworld, legacy_copy, tmp_path, how):
    qa = legacy_copy
    if how == "zero rows":
        pd.read_parquet(qa).iloc[:0].to_parquet(qa)
    elif how == "zero bytes":
        qa.write_bytes(b"")
    else:
        qa = tmp_path / "qa.jsonl"
        qa.write_text("\n", encoding="utf-8")
    params = _params(miniworld, tmp_path / "out", legacy=qa)
    with pytest.raises(InputError) as e:
        run_task("Displacement & Path Length", params)
    assert e.value.file == str(qa) and "\n" not in str(e.value)
    assert ("no rows" in str(e.value)) if how != "zero bytes" else ("cannot read parquet" in str(e.value))


def _run_all(world, qa, tmp_path, tasks):
    out = tmp_path / "out"
    params = _params(world, out, legacy=qa)
    runs = {task: run_task(task, params) for task in tasks}
    v = assemble(qa, out / "tasks", out / "release")
    prov = pd.read_parquet(out / "release" / "provenance.parquet").set_index("row")
    exc = {e["key"]: e for e in map(json.loads, (out / "release" / "excluded.jsonl").read_text().splitlines())}
    acc = (out / "release" / "resti.jsonl").read_text().splitlines()
    return runs, v, prov, exc, acc


def test_bad_ids_duplicates_and_late_times(miniworld, legacy_copy, tmp_path):
    world, qa = miniworld, legacy_copy
    tasks = ["Speed & Acceleration", "Displacement & Path Length"]
    df = pd.read_parquet(qa)
    df = df[df["Task"].isin(tasks)].reset_index(drop=True)  # two tasks are enough here
    df["ID"] = df["ID"].astype(str)  # an ID column of text, as a re-exported benchmark may have
    n = len(df)
    # an ID that is not a number
    bad_id = int(df.index[df["Task"] == "Speed & Acceleration"][2])
    df.loc[bad_id, "ID"] = "x3"
    # two exact copies of one row, appended at the end of the file
    dup = int(df.index[df["Task"] == "Displacement & Path Length"][4])
    df = pd.concat([df, df.loc[[dup, dup]]], ignore_index=True)
    # a time past the end of the video, and one exactly at its last frame (kept)
    world_info = json.loads((world / "world.json").read_text())
    frames = {s["scene"]: (s["n_frames"], s["fps"]) for s in world_info["sequences"]["scannet"]}
    disp = df[(df["Task"] == "Displacement & Path Length") & (df["Source"] == "ScanNet")].index
    late, last = int(disp[1]), int(disp[2])
    scene = df.loc[late, "Video"].removesuffix(".mp4")
    nf, fps = frames[scene]
    df.loc[late, "time_end"] = nf / fps + 2.0  # two seconds after the last frame's interval
    scene2 = df.loc[last, "Video"].removesuffix(".mp4")
    df.loc[last, "time_end"] = (frames[scene2][0] - 1) / frames[scene2][1]
    df.to_parquet(qa)
    _, v, prov, exc, acc = _run_all(world, qa, tmp_path, tasks)
    assert v["passed"] and len(acc) + len(exc) == n + 2
    # the ID: a malformed row, excluded with the field named
    assert prov.loc[bad_id, "verdict"] == "excluded"
    assert json.loads(prov.loc[bad_id, "reasons"]) == ["malformed_row"]
    assert exc[prov.loc[bad_id, "key"]]["verification_evidence"]["field"] == "ID"
    # duplicates: the first kept and audited, each copy excluded and pointing at it
    first_key = prov.loc[dup, "key"]
    assert prov.loc[dup, "verdict"] != "excluded" or "duplicate_row" not in prov.loc[dup, "reasons"]
    for copy in (n, n + 1):
        assert json.loads(prov.loc[copy, "reasons"]) == ["duplicate_row"]
        assert exc[prov.loc[copy, "key"]]["verification_evidence"]["duplicate_of"] == first_key
    for r in (dup, n, n + 1):
        assert "duplicate_row" in json.loads(prov.loc[r, "defects"])
    assert sum("duplicate_row" in json.loads(d) for d in prov["defects"]) == 3
    # the late time: excluded with the video's end in the evidence; the last frame is a valid time
    assert json.loads(prov.loc[late, "reasons"]) == ["time_past_video_end"]
    ev = exc[prov.loc[late, "key"]]["verification_evidence"]
    assert ev["video_end_s"] == pytest.approx(nf / fps) and ev["late_times"] == {"time_end": nf / fps + 2.0}
    assert "time_past_video_end" not in json.loads(prov.loc[last, "reasons"])
    assert sum("time_past_video_end" in json.loads(d) for d in prov["defects"]) == 1
