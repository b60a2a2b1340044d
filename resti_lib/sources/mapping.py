"""Video name -> source sequence, by rule or by a user table.

Rules (STI-Bench video names):

==============================  ===========  =====================  ============
video                           source       sequence               camera
==============================  ===========  =====================  ============
``scene0012_00.mp4``            ScanNet      ``scene0012_00``       None
``<segment>_camera_<N>.mp4``    Waymo        ``<segment>``          ``N`` (1-5)
``000123.mp4``                  Omni6DPose   ``000123`` (ROPE)      None
==============================  ===========  =====================  ============

A user CSV with columns ``video, source, sequence, camera`` overrides the rule for the videos it
lists (``camera`` may be empty). The extension is optional in names and in the table.
"""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path
from typing import NamedTuple

from resti_lib.errors import InputError
from resti_lib.sources.waymo import CAMERA_NAMES

__all__ = ["SOURCES", "VideoSource", "load_mapping_table", "map_video"]

SOURCES = ("ScanNet", "Waymo", "Omni6DPose")
_SCANNET = re.compile(r"^(scene\d{4}_\d{2})$")
_WAYMO = re.compile(r"^(.+)_camera_(\d+|[A-Za-z_]+)$")
_ROPE = re.compile(r"^(\d+)$")
_CAMERA_NAMES = {name: n for n, name in CAMERA_NAMES.items()}   # FRONT -> 1, ...


class VideoSource(NamedTuple):
    """Where a video comes from. ``rule`` says how it was decided (``"rule:scannet"``, ``"table"``)."""

    source: str
    sequence: str
    camera: int | None
    rule: str


def _stem(video: str) -> str:
    name = Path(str(video).strip()).name
    return name[:-4] if name.lower().endswith(".mp4") else name


def _camera(value: str | int | None, *, file: str | Path | None = None, row: object = None) -> int | None:
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    s = str(value).strip().upper()
    n = int(s) if s.isdigit() else _CAMERA_NAMES.get(s)
    if n is None or not 1 <= n <= 5:
        raise InputError(f"unknown Waymo camera {value!r} (1-5 or FRONT ...)", file=file, row=row, field="camera")
    return n


def load_mapping_table(path: str | Path) -> dict[str, VideoSource]:
    """Read a user table ``video, source, sequence, camera`` (CSV with a header line).

    Raises
    ------
    InputError
        Missing columns, an unknown source, an empty sequence, a bad camera, or a video twice.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise InputError(f"cannot read mapping table: {e}", file=path) from None
    out: dict[str, VideoSource] = {}
    reader = csv.DictReader(io.StringIO(text, newline=""))
    cols = set(reader.fieldnames or [])
    for c in ("video", "source", "sequence"):
        if c not in cols:
            raise InputError("missing column", file=path, field=c)
    for i, r in enumerate(reader, start=2):  # line numbers, header = 1
        key = _stem(r["video"])
        if not key:
            raise InputError("empty video name", file=path, row=i, field="video")
        src = (r["source"] or "").strip()
        if src not in SOURCES:
            raise InputError(f"unknown source {src!r} (one of {', '.join(SOURCES)})", file=path, row=i,
                             field="source")
        seq = (r["sequence"] or "").strip()
        if not seq:
            raise InputError("empty sequence", file=path, row=i, field="sequence")
        cam = _camera(r.get("camera"), file=path, row=i)
        if key in out:
            raise InputError(f"video {key!r} listed twice", file=path, row=i, field="video")
        out[key] = VideoSource(src, seq, cam, "table")
    return out


def map_video(video: str, table: dict[str, VideoSource] | str | Path | None = None) -> VideoSource:
    """Source, sequence and (Waymo) camera of a video name.

    Parameters
    ----------
    video : str
        File name or path (``.mp4`` optional).
    table : dict or path, optional
        A user table (see :func:`load_mapping_table`) that overrides the rule.

    Raises
    ------
    InputError
        The name matches no rule and is not in the table.
    """
    if table is not None and not isinstance(table, dict):
        table = load_mapping_table(table)
    key = _stem(video)
    if table and key in table:
        return table[key]
    if m := _SCANNET.match(key):
        return VideoSource("ScanNet", m.group(1), None, "rule:scannet")
    if m := _WAYMO.match(key):
        return VideoSource("Waymo", m.group(1), _camera(m.group(2), row=video), "rule:waymo")
    if m := _ROPE.match(key):
        return VideoSource("Omni6DPose", m.group(1), None, "rule:rope")
    raise InputError(f"video name {video!r} matches no source rule (sceneXXXX_YY, <segment>_camera_<N>, "
                     "<digits>) and is not in the mapping table", row=video, field="video")
