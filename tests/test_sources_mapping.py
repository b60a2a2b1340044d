"""Video name -> (source, sequence, camera): rules and the user table."""

from __future__ import annotations

import pytest

from resti_lib.errors import InputError
from resti_lib.sources.mapping import VideoSource, load_mapping_table, map_video

SEG = "10023947602400723454_1120_000_1140_000"


@pytest.mark.parametrize("video, expect", [
    ("scene0012_00.mp4", ("ScanNet", "scene0012_00", None)),
    ("videos/scene0041_00", ("ScanNet", "scene0041_00", None)),
    (f"{SEG}_camera_1.mp4", ("Waymo", SEG, 1)),
    (f"{SEG}_camera_FRONT_LEFT.mp4", ("Waymo", SEG, 2)),
    ("000123.mp4", ("Omni6DPose", "000123", None)),
])
def test_rules(video, expect):
    assert tuple(map_video(video))[:3] == expect


def test_unknown_name():
    with pytest.raises(InputError) as e:
        map_video("holiday.mp4")
    assert e.value.field == "video"
    with pytest.raises(InputError):
        map_video(f"{SEG}_camera_9.mp4")


def test_table_overrides_rule(tmp_path):
    p = tmp_path / "map.csv"
    p.write_text("video,source,sequence,camera\n"
                 "scene0012_00.mp4,ScanNet,scene0012_01,\n"
                 f"clip7.mp4,Waymo,{SEG},3\n")
    table = load_mapping_table(p)
    assert map_video("scene0012_00.mp4", table) == VideoSource("ScanNet", "scene0012_01", None, "table")
    assert map_video("clip7", p) == VideoSource("Waymo", SEG, 3, "table")
    assert map_video("scene0001_00.mp4", table).rule == "rule:scannet"


@pytest.mark.parametrize("body, field, row", [
    ("video,source\nx,ScanNet\n", "sequence", None),
    ("video,source,sequence,camera\nx,Kitti,s,\n", "source", 2),
    ("video,source,sequence,camera\nx,Waymo,s,12\n", "camera", 2),
    ("video,source,sequence,camera\nx,ScanNet,s,\nx.mp4,ScanNet,t,\n", "video", 3),
])
def test_bad_table(tmp_path, body, field, row):
    p = tmp_path / "m.csv"
    p.write_text(body)
    with pytest.raises(InputError) as e:
        load_mapping_table(p)
    assert e.value.field == field and e.value.row == row and e.value.file == str(p)
