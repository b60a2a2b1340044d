"""The mini-world: source files in the exact real formats plus a legacy STI-Bench benchmark.

:func:`generate` writes, under ``out_dir``::

    scannet/scans/<scene>/...             ScanNet v2 layout (.txt, .sens, pose/, .ply, segs, aggregation)
    waymo/<component>/<segment>.parquet   Waymo v2 vehicle_pose, camera_calibration, camera_image, lidar_box
    omni6d/ROPE/<scene>/<frame>_meta.json, omni6d/Meta/real_obj_meta.json
    legacy/qa.parquet                     legacy rows with the documented defects injected
    legacy/video_map.csv                  video -> (source, sequence, camera)
    manifest.jsonl                        the truth per legacy row (tests and the self-test table only)
    world.json                            seed, scale, counts, conventions, per-sequence ground truth

The default world is small (a few sequences per source, ~290 rows). ``scale=N`` mirrors the full
2,064-row task/source/video structure of the legacy benchmark N times, with every benchmark video
mapped to a bounded pool of generated sequences (``legacy/video_map.csv``).

Nothing on the audit path may import this package (``docs/design.md``).
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import time
from collections import Counter
from pathlib import Path

import pyarrow as pa

from .. import paths
from ..defects import DEFECTS
from ..errors import InputError
from ..release.publish import publishing
from . import legacy as _legacy
from . import omni6d as _omni6d
from . import scannet as _scannet
from . import waymo as _waymo
from .common import dumps, stable_seed, write_json, write_parquet

GENERATOR_VERSION = "1.1.0"

LEGACY_COLUMNS = (
    "Video",
    "Source",
    "Task",
    "QType",
    "Question",
    "Prompt",
    "time_start",
    "time_end",
    "Candidates",
    "Answer",
    "Answer Detail",
    "ID",
    "scene",
)

#: Rows per (task, source) of the default world; ``None`` = one per video of that source.
DEFAULT_COUNTS: dict[tuple[str, str], int | None] = {
    ("3D Video Grounding", "ScanNet"): 26,
    ("3D Video Grounding", "Waymo"): 12,
    ("3D Video Grounding", "Omni6DPose"): 8,
    ("Dimensional Measurement", "ScanNet"): 18,
    ("Dimensional Measurement", "Waymo"): 10,
    ("Dimensional Measurement", "Omni6DPose"): 13,
    ("Displacement & Path Length", "ScanNet"): 27,
    ("Displacement & Path Length", "Waymo"): 15,
    ("Displacement & Path Length", "Omni6DPose"): 10,
    ("Ego-Centric Orientation", "ScanNet"): None,
    ("Ego-Centric Orientation", "Waymo"): None,
    ("Pose Estimation", "ScanNet"): 22,
    ("Pose Estimation", "Waymo"): 18,
    ("Pose Estimation", "Omni6DPose"): 12,
    ("Spatial Relation", "Waymo"): None,
    ("Spatial Relation", "Omni6DPose"): 6,
    ("Speed & Acceleration", "ScanNet"): 17,
    ("Speed & Acceleration", "Waymo"): 20,
    ("Speed & Acceleration", "Omni6DPose"): 11,
    ("Trajectory Description", "Waymo"): None,
}
#: Cameras filmed per default Waymo segment (several videos per segment).
DEFAULT_WAYMO_CAMERAS = [[1, 2, 4], [1, 3, 5], [1, 2, 3], [1, 4, 5]]
#: Per-task legacy row counts (``formats/sti_bench_and_resti.md``): the scale fallback.
LEGACY_TASK_COUNTS = {
    "3D Video Grounding": 317,
    "Dimensional Measurement": 289,
    "Displacement & Path Length": 358,
    "Ego-Centric Orientation": 185,
    "Pose Estimation": 360,
    "Spatial Relation": 146,
    "Speed & Acceleration": 331,
    "Trajectory Description": 78,
}
_SOURCE_ORDER = ("ScanNet", "Waymo", "Omni6DPose")
#: Largest ``scale``: 1,000 copies are about 2.1 million legacy rows (the 100x benchmark takes ~10 min).
MAX_SCALE = 1000


# ================================================================================ the pool


def _build_pool(seed: int) -> tuple[_legacy.World, list, list]:
    scenes = _scannet.build_default(seed)
    segs = _waymo.build_default(seed)
    ropes = _omni6d.build_default(seed)
    world = _legacy.World(
        scannet={s.name: s for s in scenes},
        waymo={s.name: s for s, _ in segs},
        omni={s.name: s for s in ropes},
    )
    return world, segs, ropes


def _write_sources(
    out: Path, world: _legacy.World, segs: list, ropes: list, seed: int, omni6d_camera_convention: str
) -> None:
    for s in world.scannet.values():
        _scannet.write_scene(s, out / "scannet" / "scans", stable_seed(seed, f"scannet-files|{s.name}"))
    for seg, ego in segs:
        _waymo.write_segment(seg, ego, out / "waymo")
    for r in ropes:
        _omni6d.write_scene(r, out / "omni6d", omni6d_camera_convention)
    _omni6d.write_object_meta(ropes, out / "omni6d")


# =============================================================================== row slots


def _distribute(n: int, videos: list, offset: int) -> list[int]:
    """Round-robin counts of ``n`` rows over ``videos`` starting at ``offset``."""
    counts = [0] * len(videos)
    for i in range(n):
        counts[(offset + i) % len(videos)] += 1
    return counts


def _default_slots(world: _legacy.World) -> list[_legacy.Slot]:
    videos: dict[str, list[tuple[str, str, int | None]]] = {
        "ScanNet": [(f"{n}.mp4", n, None) for n in world.scannet],
        "Waymo": [
            (f"{seg}_camera_{c}.mp4", seg, c)
            for seg, cams in zip(world.waymo, DEFAULT_WAYMO_CAMERAS)
            for c in cams
        ],
        "Omni6DPose": [(f"{n}.mp4", n, None) for n in world.omni],
    }
    per_video: dict[str, list[str]] = {v: [] for src in _SOURCE_ORDER for v, _, _ in videos[src]}
    for t_i, task in enumerate(_legacy.TASK_ORDER):
        for source in _legacy.TASK_SOURCES[task]:
            vids = videos[source]
            n = DEFAULT_COUNTS[(task, source)]
            counts = [1] * len(vids) if n is None else _distribute(n, vids, t_i)
            for (v, _, _), c in zip(vids, counts):
                per_video[v] += [task] * c
    slots: list[_legacy.Slot] = []
    for source in _SOURCE_ORDER:
        for v, seq, cam in videos[source]:
            occ: Counter = Counter()
            for i, task in enumerate(per_video[v]):
                slots.append(
                    _legacy.Slot(
                        video=v,
                        source=source,
                        task=task,
                        id=i,
                        sequence=seq,
                        camera=cam,
                        occurrence=occ[task],
                    )
                )
                occ[task] += 1
    # the legacy (video, ID) key collides in a few places: reproduce one collision
    last = [s for s in slots if s.video == videos["Omni6DPose"][-1][0]]
    if len(last) > 3:
        last[3].id = last[2].id
    return slots


def _legacy_keys(resti_v5_dir: Path | None) -> list[tuple[str, str, str, int]] | None:
    """(source, task, video, id) of every legacy row from a ReSTI v5 release, or None."""
    d = Path(resti_v5_dir) if resti_v5_dir else paths.resti_v5_dir()
    acc, exc = d / "resti.jsonl", d / "excluded.jsonl"
    if not acc.exists():
        return None
    keys = []
    for f, field in ((acc, "Legacy Row Key"), (exc, "key")):
        if not f.exists():
            continue
        for line in f.read_text(encoding="utf-8").splitlines():
            if line.strip():
                parts = json.loads(line)[field].split("|")
                keys.append((parts[0], parts[1], parts[2], int(parts[3])))
    order = {s: i for i, s in enumerate(_SOURCE_ORDER)}
    return sorted(keys, key=lambda k: (order[k[0]], k[2], k[3], _legacy.TASK_ORDER.index(k[1])))


def _fallback_keys() -> list[tuple[str, str, str, int]]:
    """A 2,064-row structure from the per-task counts alone (even split over the task's sources)."""
    rows: dict[str, list[str]] = {s: [] for s in _SOURCE_ORDER}
    for task in _legacy.TASK_ORDER:
        srcs = _legacy.TASK_SOURCES[task]
        n = LEGACY_TASK_COUNTS[task]
        for j, src in enumerate(srcs):
            rows[src] += [task] * (n // len(srcs) + (1 if j < n % len(srcs) else 0))
    keys = []
    for src in _SOURCE_ORDER:
        tasks = rows[src]
        once = Counter(t for t in tasks if t in ("Ego-Centric Orientation", "Trajectory Description"))
        n_videos = max(math.ceil(len(tasks) / 5.6), max(once.values(), default=0))
        per_video: list[list[str]] = [[] for _ in range(n_videos)]
        cursor = 0
        for task in _legacy.TASK_ORDER:
            for _ in range(tasks.count(task)):
                per_video[cursor % n_videos].append(task)
                cursor += 1
        for vi, vt in enumerate(per_video):
            for i, task in enumerate(vt):
                keys.append((src, task, f"fallback-{src}-{vi:04d}", i))
    return keys


def _scaled_video(source: str, original: str, j: int, seed: int) -> tuple[str, int | None]:
    """A generated benchmark video name (never a real one) for the j-th video of a source."""
    if source == "ScanNet":
        return f"scene{1000 + j // 2:04d}_{j % 2:02d}.mp4", None
    if source == "Omni6DPose":
        return f"{1000 + j:06d}.mp4", None
    h = hashlib.sha256(f"{seed}|waymo-video|{j}".encode()).hexdigest()
    num = "9" + str(int(h[:16], 16))[:19].rjust(19, "0")
    start = int(h[16:20], 16) % 9000 + 100
    ms = int(h[20:24], 16) % 1000
    cam = int(original.rsplit("_camera_", 1)[1].split(".")[0]) if "_camera_" in original else 1 + j % 5
    return f"{num}_{start}_{ms:03d}_{start + 20}_{ms:03d}_camera_{cam}.mp4", cam


def _scaled_slots(
    world: _legacy.World, scale: int, seed: int, resti_v5_dir: Path | None
) -> tuple[list[_legacy.Slot], str]:
    keys = _legacy_keys(resti_v5_dir)
    origin = "resti_v5 Legacy Row Keys"
    if keys is None:
        keys, origin = _fallback_keys(), "per-task counts (fallback)"
    pools = {"ScanNet": list(world.scannet), "Waymo": list(world.waymo), "Omni6DPose": list(world.omni)}
    videos_by_source: dict[str, list[str]] = {s: [] for s in _SOURCE_ORDER}
    for src, _, video, _ in keys:
        if video not in videos_by_source[src]:
            videos_by_source[src].append(video)
    slots: list[_legacy.Slot] = []
    for c in range(scale):
        names: dict[str, tuple[str, str, int | None]] = {}
        for src in _SOURCE_ORDER:
            vids = videos_by_source[src]
            for i, v in enumerate(vids):
                j = c * len(vids) + i
                name, cam = _scaled_video(src, v, j, seed)
                pool = pools[src]
                seq = pool[stable_seed(seed, f"pool|{name}") % len(pool)]
                names[(src, v)] = (name, seq, cam)
        occ: Counter = Counter()
        for src, task, video, vid_id in keys:
            name, seq, cam = names[(src, video)]
            slots.append(
                _legacy.Slot(
                    video=name,
                    source=src,
                    task=task,
                    id=vid_id,
                    sequence=seq,
                    camera=cam,
                    occurrence=occ[(name, task)],
                )
            )
            occ[(name, task)] += 1
    return slots, origin


# ================================================================================ writing


def _write_legacy(out: Path, rows: list[dict], slots: list[_legacy.Slot]) -> None:
    cols = {c: [r[c] for r in rows] for c in LEGACY_COLUMNS}
    types = {"time_start": pa.float64(), "time_end": pa.float64(), "ID": pa.int64()}
    table = pa.table({c: pa.array(v, types.get(c, pa.string())) for c, v in cols.items()})
    write_parquet(out / "legacy" / "qa.parquet", table)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["video", "source", "sequence", "camera"])
    seen = set()
    for s in slots:
        if s.video not in seen:
            seen.add(s.video)
            w.writerow([s.video, s.source, s.sequence, "" if s.camera is None else s.camera])
    (out / "legacy" / "video_map.csv").write_text(buf.getvalue(), encoding="utf-8")


def _counts(manifest: list[dict]) -> dict:
    by_ts = Counter(f"{m['task']}|{m['source']}" for m in manifest)
    defects = Counter(c for m in manifest for c in m["defects"])
    return {
        "rows": len(manifest),
        "rows_by_task_source": dict(sorted(by_ts.items())),
        "rows_by_source": dict(sorted(Counter(m["source"] for m in manifest).items())),
        "videos": len({m["video"] for m in manifest}),
        "defects": {c: defects[c] for c in DEFECTS if defects[c]},
        "verdicts": dict(sorted(Counter(m["expected_verdict"] for m in manifest).items())),
        "reasons": dict(sorted(Counter(r for m in manifest for r in m["expected_reasons"]).items())),
    }


def _dir_size(path: Path) -> tuple[int, int]:
    files = [p for p in path.rglob("*") if p.is_file()]
    return len(files), sum(p.stat().st_size for p in files)


def generate(
    out_dir: str | Path,
    *,
    seed: int = 0,
    scale: int | None = None,
    omni6d_camera_convention: str = "identity",
    resti_v5_dir: str | Path | None = None,
) -> dict:
    """Generate the mini-world and its legacy benchmark.

    Parameters
    ----------
    out_dir : path
        Output folder: absent, empty, or a mini-world written before. The new world is built in a
        staging folder beside it and swapped in whole when complete (:mod:`resti_lib.release.publish`), so an
        interrupted generation leaves the previous world (or nothing), never half a world, and a
        folder holding anything else is refused (:class:`~resti_lib.errors.OutputError`).
    seed : int
        World seed; equal seeds give byte-identical files.
    scale : int, optional
        ``None``: the small default world. ``1 <= N <= MAX_SCALE``: N copies of the full legacy structure
        (2,064 rows each) taken from the ReSTI v5 Legacy Row Keys (fallback: per-task counts), over
        the same bounded pool of sequences.
    omni6d_camera_convention : {"identity", "world_from_camera", "camera_from_world"}
        How ROPE meta files store the camera pose (recorded in world.json). ``identity`` (default):
        the real ROPE way, identity camera pose and zero world translations (the motion is in the
        objects' camera-frame poses only); the others: a SOPE-style stored pose carrying the motion.
    resti_v5_dir : path, optional
        Where to find ``resti.jsonl``/``excluded.jsonl`` for ``scale`` (default: shared data).

    Returns
    -------
    dict
        Summary: paths, counts (rows per task/source, defects, verdicts), files, bytes, seconds.
    """
    if omni6d_camera_convention not in _omni6d.CONVENTIONS:
        raise InputError(f"must be one of {_omni6d.CONVENTIONS}, got {omni6d_camera_convention!r}",
                         field="omni6d_camera_convention")
    check_scale(scale)
    t_start = time.perf_counter()
    out = Path(out_dir)
    with publishing(out, kind="world", inputs=[resti_v5_dir], what="mini-world folder", wait=True) as stage:
        counts, world = _generate_into(stage, seed=seed, scale=scale,
                                       omni6d_camera_convention=omni6d_camera_convention,
                                       resti_v5_dir=resti_v5_dir)
    n_files, n_bytes = _dir_size(out)
    return {
        "out_dir": str(out),
        "seed": seed,
        "scale": scale,
        "row_structure": world["row_structure"],
        "qa_parquet": str(out / "legacy" / "qa.parquet"),
        "manifest": str(out / "manifest.jsonl"),
        "world_json": str(out / "world.json"),
        "counts": counts,
        "files": n_files,
        "bytes": n_bytes,
        "seconds": round(time.perf_counter() - t_start, 3),
        "sequences": world["n_sequences"],
    }


def check_scale(scale) -> None:
    """``scale`` is ``None`` or an integer in ``1 .. MAX_SCALE`` (:class:`InputError` otherwise)."""
    if scale is None:
        return
    if isinstance(scale, bool) or not isinstance(scale, int) or not 1 <= scale <= MAX_SCALE:
        raise InputError(f"scale must be a whole number from 1 to {MAX_SCALE} (copies of the 2,064-row "
                         f"structure), got {scale!r}", field="scale")


def _generate_into(out: Path, *, seed: int, scale: int | None, omni6d_camera_convention: str,
                   resti_v5_dir) -> tuple[dict, dict]:
    """Write the whole world into ``out`` (a staging folder); ``world.json`` is written last."""
    world, segs, ropes = _build_pool(seed)
    _write_sources(out, world, segs, ropes, seed, omni6d_camera_convention)
    if scale is None:
        slots, origin = _default_slots(world), "default world"
    else:
        slots, origin = _scaled_slots(world, int(scale), seed, resti_v5_dir)
    rows, manifest = _legacy.build_rows(world, slots, seed)
    _write_legacy(out, rows, slots)
    with open(out / "manifest.jsonl", "w", encoding="utf-8") as f:
        f.writelines(dumps(m) + "\n" for m in manifest)
    counts = _counts(manifest)
    world_info = {
        "generator": "resti_lib.synth",
        "generator_version": GENERATOR_VERSION,
        "seed": seed,
        "scale": scale,
        "row_structure": origin,
        "counts": counts,
        "conventions": {
            "camera_axes": "OpenCV (+X right, +Y down, +Z forward) for every written camera pose, "
            "except Waymo extrinsics, which use Waymo camera axes (+X forward, +Y left, +Z up)",
            "scannet_fps": _scannet.FPS,
            "omni6d_fps": _omni6d.FPS,
            "scannet_pose": "T_raw<-cam (camera-to-world), float32 in .sens; invalid frames all -inf",
            "scannet_axis_alignment": "T_ann<-raw, rotation about +Z plus translation",
            "omni6d_camera_pose": omni6d_camera_convention,
            "omni6d_frames": "written the real ROPE way: camera pose identity, world_translation zero, "
            "object poses T_cam<-object in OpenCV axes; the camera motion is only in the static objects' poses"
            if omni6d_camera_convention == "identity" else "SOPE-style: the stored camera pose and the objects' "
            "world poses carry the motion",
            "omni6d_moving_object": f"scene {_omni6d.MOVING_SCENE}: its last object is re-placed during the video "
            "(world.json sequences.omni6d[].moving_object)",
            "scannet_boxes": "instances are upright boxes (some turned about +Z in the annotation frame); the "
            "truth box is the tight upright box of the written vertices (footprint = minimum-area rectangle, "
            "length >= width, yaw in (-90, 90]); legacy ScanNet dimensions, distances and grounding sizes use "
            "the axis-aligned box in the annotation frame (extents along ann x, y, z)",
            "omni6d_object_pose": "T_cam<-object in OpenCV axes; box centred at the object origin, "
            "sides = scale * dimensions along object x, y, z",
            "waymo_time": "t = (micros - first vehicle_pose micros) / 1e6; questions use the nearest frame",
            "waymo_lidar_box_speed": "object world velocity / acceleration expressed in the vehicle frame",
            "waymo_camera_image_pose": "world_from_vehicle at pose_timestamp (frame time + camera offset)",
            "legacy_time_formats": "ScanNet t = frame / 30, Waymo t = (micros - first) / 1e6, "
            "ROPE t = frame / 30",
        },
        "sequences": {
            "scannet": [s.describe() for s in world.scannet.values()],
            "waymo": [s.describe() for s in world.waymo.values()],
            "omni6d": [s.describe(omni6d_camera_convention) for s in world.omni.values()],
        },
    }
    write_json(out / "world.json", world_info, indent=1)
    return counts, {"row_structure": origin, "n_sequences": {"ScanNet": len(world.scannet),
                                                             "Waymo": len(world.waymo),
                                                             "Omni6DPose": len(world.omni)}}


__all__ = ["DEFAULT_COUNTS", "GENERATOR_VERSION", "LEGACY_COLUMNS", "MAX_SCALE", "check_scale", "generate"]
