"""Source roots from params, opened lazily and cached per sequence.

The keys are those of ``../shared/formats/contract.md``: ``scannet_root`` (ScanNet's ``scans/``),
``waymo_root`` (``<component>/<segment>.parquet``), ``omni6d_root`` (``ROPE/`` + ``Meta/``),
``scannet_fps``, ``omni6d_fps``, and optionally ``video_map`` (CSV video, source, sequence, camera).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .. import paths
from ..defaults import load
from ..errors import InputError
from .mapping import VideoSource, load_mapping_table, map_video

ROOT_KEYS = {"ScanNet": "scannet_root", "Waymo": "waymo_root", "Omni6DPose": "omni6d_root"}

# Opened sequences shared by every context of the process (several task audits in one process
# read each sequence once). Keyed by source, root, sequence and frame rate; inputs are read-only.
_OPENED: dict[tuple, object] = {}
# Data derived from an opened sequence (tracks, instance lists, frame views), kept beside it here
# rather than on the reader object: id(sequence) -> (sequence, {key: value}).
_DERIVED: dict[int, tuple[object, dict]] = {}


def derived(seq, key, make):
    """``make()`` computed once per opened sequence ``seq`` and ``key``: tracks, instance lists and
    frame views derived from a sequence are kept here, shared by every question and every context of
    the process like the sequences themselves, never attached to the reader object."""
    entry = _DERIVED.get(id(seq))
    if entry is None or entry[0] is not seq:
        entry = _DERIVED[id(seq)] = (seq, {})
    memo = entry[1]
    if key not in memo:
        memo[key] = make()
    return memo[key]


@dataclass
class SourceContext:
    scannet_root: Path | None = None
    waymo_root: Path | None = None
    omni6d_root: Path | None = None
    scannet_fps: float = 30.0
    omni6d_fps: float = 30.0
    video_map: dict | None = None

    @classmethod
    def from_params(cls, params: dict) -> "SourceContext":
        def p(key):
            v = params.get(key)
            return paths.resolve(v) if v else None

        vm = params.get("video_map")
        table = load_mapping_table(paths.resolve(vm)) if vm else None
        def fps(key):  # the run's value, else params/default.yaml's; never a silent substitute for 0
            v = params.get(key)
            v = load("default")[key] if v is None else v
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
                raise InputError(f"{v!r} is not a frame rate above 0", field=key)
            return float(v)

        return cls(scannet_root=p("scannet_root"), waymo_root=p("waymo_root"), omni6d_root=p("omni6d_root"),
                   scannet_fps=fps("scannet_fps"), omni6d_fps=fps("omni6d_fps"), video_map=table)

    def locate(self, video: str) -> VideoSource:
        return map_video(video, self.video_map)

    def _root(self, source: str) -> Path:
        root = getattr(self, ROOT_KEYS[source])
        if root is None:
            raise InputError(f"no {ROOT_KEYS[source]} given in the params", field=ROOT_KEYS[source])
        if not Path(root).exists():
            raise InputError(f"{ROOT_KEYS[source]} does not exist", file=root, field=ROOT_KEYS[source])
        return Path(root)

    def scannet(self, scene: str):
        from .scannet import ScanNetScene

        root = self._root("ScanNet")
        k = ("ScanNet", str(root), scene, self.scannet_fps)
        if k not in _OPENED:
            _OPENED[k] = ScanNetScene(root, scene, fps=self.scannet_fps)
        return _OPENED[k]

    def waymo(self, segment: str):
        from .waymo import WaymoSegment

        root = self._root("Waymo")
        k = ("Waymo", str(root), segment)
        if k not in _OPENED:
            _OPENED[k] = WaymoSegment(root, segment)
        return _OPENED[k]

    def rope(self, scene: str):
        from .omni6d import RopeScene

        root = self._root("Omni6DPose")
        k = ("Omni6DPose", str(root), scene, self.omni6d_fps)
        if k not in _OPENED:
            _OPENED[k] = RopeScene(root, scene, fps=self.omni6d_fps)
        return _OPENED[k]

    def derived(self, seq, key, make):
        """:func:`derived` (data computed once per opened sequence)."""
        return derived(seq, key, make)

    def sequence(self, video: str):
        """The opened source sequence of a video (ScanNetScene, WaymoSegment or RopeScene)."""
        vs = self.locate(video)
        return {"ScanNet": self.scannet, "Waymo": self.waymo, "Omni6DPose": self.rope}[vs.source](vs.sequence)


def check_real_params(params: dict) -> list[str]:
    """Everything missing or wrong in a real-data params file, as one list of messages.

    Source roots are required for the sources the legacy benchmark uses (all three when the
    benchmark itself cannot be read).
    """
    problems = []
    leg = params.get("legacy_benchmark")
    needed = set(ROOT_KEYS)
    if not leg:
        problems.append("legacy_benchmark: not given (the STI-Bench qa.parquet)")
    elif not paths.resolve(leg).is_file():
        problems.append(f"legacy_benchmark: {paths.resolve(leg)} is not a file")
    else:
        try:
            import pandas as pd

            needed = set(pd.read_parquet(paths.resolve(leg), columns=["Source"])["Source"]) & set(ROOT_KEYS)
        except Exception as e:  # a damaged file is reported by the loader with file/row/field
            problems.append(f"legacy_benchmark: {paths.resolve(leg)} cannot be read ({e})")
    checks = {"scannet_root": "a folder holding <scene>/ folders (ScanNet scans/)",
              "waymo_root": "a folder holding <component>/<segment>.parquet",
              "omni6d_root": "a folder holding ROPE/ and Meta/"}
    wanted = {ROOT_KEYS[s] for s in needed}
    for key, what in checks.items():
        if key not in wanted:
            continue
        v = params.get(key)
        if not v:
            problems.append(f"{key}: not given ({what})")
            continue
        p = paths.resolve(v)
        if not p.is_dir():
            problems.append(f"{key}: {p} is not a folder ({what})")
        elif key == "waymo_root":
            for comp in ("vehicle_pose", "camera_calibration", "camera_image", "lidar_box"):
                if not (p / comp).is_dir():
                    problems.append(f"{key}: {p / comp} missing (Waymo v2 component {comp})")
        elif key == "omni6d_root":
            for sub in ("ROPE", "Meta/real_obj_meta.json"):
                if not (p / sub).exists():
                    problems.append(f"{key}: {p / sub} missing")
    vm = params.get("video_map")
    if vm and not paths.resolve(vm).is_file():
        problems.append(f"video_map: {paths.resolve(vm)} is not a file")
    return problems
