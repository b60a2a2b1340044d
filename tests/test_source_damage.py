"""Damaged sources are named or excluded, never measured (issue 20, item 1).

Each test plants one kind of damage in a copy of the mini-world (``world_with``) and shows that the
rows needing the damaged file are excluded with the reason and the file, row and field in their
evidence (``source_damaged``, ``source_gap``), that ``resti measure`` exits 2 naming them, and that
rows of other recordings keep their answers.
"""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from resti_lib.errors import SourceError, SourceGapError
from resti_lib.measure.cli import measure_main
from resti_lib.sources import waymo as W
from resti_lib.tasks.run import run_task

MICROS = W.KEY_MICROS


def _params(w, out):
    return {"legacy_benchmark": str(w / "legacy" / "qa.parquet"), "scannet_root": str(w / "scannet" / "scans"),
            "waymo_root": str(w / "waymo"), "omni6d_root": str(w / "omni6d"), "scannet_fps": 30, "omni6d_fps": 30,
            "video_map": "", "seed": 0, "output_dir": str(out)}


def _segment(miniworld):
    return sorted((miniworld / "waymo" / "vehicle_pose").glob("*.parquet"))[0].stem


def _measure(tmp_path, world, contract: dict, capsys) -> tuple[int, str]:
    (tmp_path / "c.json").write_text(json.dumps(contract))
    (tmp_path / "p.yaml").write_text(f"waymo_root: {world / 'waymo'}\nscannet_root: {world / 'scannet' / 'scans'}\n")
    rc = measure_main([str(tmp_path / "c.json"), "--params", str(tmp_path / "p.yaml")])
    return rc, capsys.readouterr().err


def _path_contract(seg, t1=19.0):
    return {"source": "Waymo", "sequence": seg, "camera": 1, "entity": {"kind": "camera"}, "times": [0.0, t1],
            "operator": "path_length"}


@pytest.mark.slow
def test_reversed_vehicle_pose_timestamp_is_refused_not_measured(miniworld, world_with, tmp_path, capsys):
    seg = _segment(miniworld)
    rel = f"waymo/vehicle_pose/{seg}.parquet"
    world = world_with(rel)
    t = pq.read_table(world / rel)
    micros = t[MICROS].to_numpy().copy()
    micros[50] = -micros[50]  # one timestamp negated: out of order
    pq.write_table(t.set_column(t.column_names.index(MICROS), MICROS, pa.array(micros)), world / rel)
    with pytest.raises(SourceError) as e:
        W.read_vehicle_pose(world / rel)
    assert (e.value.row, e.value.field) == (50, MICROS)
    rc, err = _measure(tmp_path, world, _path_contract(seg), capsys)
    assert rc == 2 and f"{seg}.parquet" in err and "row 50" in err and MICROS in err
    run = run_task("Trajectory Description", _params(world, tmp_path / "out"))
    mine = [o for o in run.outcomes if o.video.startswith(seg)]
    others = [o for o in run.outcomes if not o.video.startswith(seg)]
    assert mine and all(o.reasons == ["source_damaged"] and o.evidence["source_row"] == 50 for o in mine)
    # the other segments' answers are those of the undamaged world
    clean = {o.key: o.answer for o in run_task("Trajectory Description", _params(miniworld, tmp_path / "o2")).outcomes}
    assert others and all(str(o.answer) == str(clean[o.key]) for o in others)


@pytest.mark.slow
def test_a_gap_inside_the_window_excludes_instead_of_interpolating(miniworld, world_with, tmp_path, capsys):
    seg = _segment(miniworld)
    rel = f"waymo/vehicle_pose/{seg}.parquet"
    world = world_with(rel)
    t = pq.read_table(world / rel)
    keep = np.ones(t.num_rows, bool)
    keep[60:120] = False  # 60 consecutive frames (6 s at 10 Hz) missing
    pq.write_table(t.filter(pa.array(keep)), world / rel)
    rc, err = _measure(tmp_path, world, _path_contract(seg), capsys)
    assert rc == 2 and "max_gap_factor" in err and "times" in err
    # a window before the gap is measured as before (by hand: same samples, same value)
    ok_clean = _measure_value(tmp_path, miniworld, _path_contract(seg, 5.0), capsys)
    ok_gap = _measure_value(tmp_path, world, _path_contract(seg, 5.0), capsys)
    assert ok_gap == pytest.approx(ok_clean, abs=1e-12)
    run = run_task("Trajectory Description", _params(world, tmp_path / "out"))
    mine = [o for o in run.outcomes if o.video.startswith(seg)]
    assert mine and all(o.reasons == ["source_gap"] and "max_gap_factor" in o.evidence["problem"] for o in mine)


def _measure_value(tmp_path, world, contract, capsys) -> float:
    (tmp_path / "c.json").write_text(json.dumps(contract))
    (tmp_path / "p.yaml").write_text(f"waymo_root: {world / 'waymo'}\n")
    assert measure_main([str(tmp_path / "c.json"), "--params", str(tmp_path / "p.yaml"), "--json"]) == 0
    return float(json.loads(capsys.readouterr().out)["value"])


def test_the_gap_check_is_relative_to_the_tracks_own_sampling():
    from resti_lib.geometry.trajectory import PoseTrack

    T = np.repeat(np.eye(4)[None], 6, axis=0)
    tr = PoseTrack(np.array([0.0, 0.1, 0.2, 0.3, 0.6, 0.7]), T, max_gap_factor=2.5)  # one 0.3 s step, median 0.1
    tr.check_gap(0.0, 0.25)  # before the gap
    with pytest.raises(SourceGapError) as e:
        tr.check_gap(0.25, 0.65)
    assert e.value.row == 4  # the sample after the gap
    PoseTrack(tr.times, T, max_gap_factor=3.5).check_gap(0.0, 0.7)  # 3 intervals is within 3.5


@pytest.mark.parametrize("field,value", [("objectId", "1"), ("segments", "12"), ("segments", None),
                                         ("segments", [1.5])])
def test_aggregation_field_types_are_checked_by_the_reader(miniworld, world_with, field, value):
    from resti_lib.sources.scannet import read_instances

    scene = "scene0900_00"
    rel = f"scannet/scans/{scene}/{scene}.aggregation.json"
    world = world_with(rel)
    agg = json.loads((world / rel).read_text())
    agg["segGroups"][1][field] = value
    (world / rel).write_text(json.dumps(agg))
    with pytest.raises(SourceError) as e:
        read_instances(world / "scannet" / "scans" / scene, scene, None)
    assert (e.value.file, e.value.row, e.value.field) == (str(world / rel), 1, field)


@pytest.mark.slow
@pytest.mark.parametrize("field,value", [("objectId", "1"), ("segments", "12")])
def test_aggregation_fields_of_the_wrong_type_are_named(miniworld, world_with, tmp_path, field, value):
    scene = "scene0900_00"
    rel = f"scannet/scans/{scene}/{scene}.aggregation.json"
    world = world_with(rel)
    agg = json.loads((world / rel).read_text())
    agg["segGroups"][1][field] = value
    (world / rel).write_text(json.dumps(agg))
    run = run_task("Dimensional Measurement", _params(world, tmp_path / "out"))
    mine = [o for o in run.outcomes if o.video.startswith(scene) and o.source == "ScanNet"]
    assert mine and all(o.reasons == ["source_damaged"] and o.evidence["source_field"] == field
                        and o.evidence["source_row"] == 1 for o in mine)


@pytest.mark.slow
def test_a_rope_quaternion_given_as_text_is_named(miniworld, world_with, tmp_path):
    rel = "omni6d/ROPE/000900/000000_meta.json"
    world = world_with(rel)
    meta = json.loads((world / rel).read_text())
    first = sorted(meta["objects"])[0]
    meta["objects"][first]["quaternion_wxyz"] = "1,0,0,0"
    (world / rel).write_text(json.dumps(meta))
    run = run_task("Displacement & Path Length", _params(world, tmp_path / "out"))
    mine = [o for o in run.outcomes if o.video.startswith("000900")]
    assert mine and all(o.reasons == ["source_damaged"] and o.evidence["source_field"] == "quaternion_wxyz"
                        and o.evidence["source_file"].endswith("000000_meta.json") for o in mine)


@pytest.mark.slow
def test_mesh_vertices_that_are_not_finite_are_refused_by_name(miniworld, world_with, tmp_path):
    import trimesh

    scene = "scene0900_00"
    rel = f"scannet/scans/{scene}/{scene}_vh_clean_2.ply"
    world = world_with(rel)
    mesh = trimesh.load(world / rel, process=False)
    v = np.array(mesh.vertices)
    v[7] = np.nan
    mesh.vertices = v
    (world / rel).write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary"))
    run = run_task("Dimensional Measurement", _params(world, tmp_path / "out"))
    mine = [o for o in run.outcomes if o.video.startswith(scene) and o.source == "ScanNet"]
    assert mine and all(o.reasons == ["source_damaged"] and o.evidence["source_field"] == "vertex"
                        and o.evidence["source_row"] == 7 for o in mine)
