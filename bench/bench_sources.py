"""Source readers and trajectory operators: throughput.

- pose operators on a 10^6-pose track (evaluations/s): ``pose_at`` (linear: lerp + slerp),
  the vectorised heading operator, ``path_length`` and ``segment_turns`` over every sample;
- ``.sens`` pose extraction (MB/s of file scanned) on a generated file in a temp dir
  (real bytes for the image payloads, which the reader seeks over).

Sizes: ``RESTI_BENCH_POSES`` (default 1_000_000), ``RESTI_BENCH_SENS_FRAMES`` (default 1500 frames
of ~300 kB each, about 450 MB). Not run by the tests.
"""

from __future__ import annotations

import os
import struct
import tempfile
import time
from pathlib import Path

import numpy as np


def _track(n: int):
    from resti_lib.geometry.frames import make_T, yaw_matrix
    from resti_lib.geometry.trajectory import PoseTrack

    rng = np.random.default_rng(0)
    t = np.arange(n) * 0.01
    yaw = 0.8 * np.sin(2 * np.pi * t / 60.0) + rng.normal(0, 1e-4, n)  # turns of ~90 deg every 30 s
    pitch = 0.1 * np.sin(t / 7.0)
    c, s = np.cos(pitch), np.sin(pitch)
    Rx = np.zeros((n, 3, 3))
    Rx[:, 0, 0] = 1
    Rx[:, 1, 1], Rx[:, 1, 2], Rx[:, 2, 1], Rx[:, 2, 2] = c, -s, s, c
    R = yaw_matrix(yaw) @ Rx
    p = np.cumsum(np.stack([np.cos(yaw), np.sin(yaw), 0 * yaw], 1) * 0.1, axis=0)
    return PoseTrack(t, make_T(R, p), name="bench")


def _timed(fn, repeat: int = 3) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def bench_pose_operators(n: int) -> None:
    from resti_lib.geometry import trajectory as G

    t0 = time.perf_counter()
    tr = _track(n)
    t_build = time.perf_counter() - t0
    t_q, _ = _timed(lambda: (setattr(tr, "_quat", None), tr.quat_xyzw), repeat=1)
    rng = np.random.default_rng(1)
    q = rng.uniform(tr.times[0], tr.times[-1], n)
    t_pose, _ = _timed(lambda: G.pose_at(tr, q))
    R0 = tr.rotations[:-1]
    R1 = tr.rotations[1:]
    t_head, _ = _timed(lambda: G.horizontal_heading_deg(R0, R1, (1, 0, 0), (0, 0, 1)))
    t_path, (L, _) = _timed(lambda: G.path_length(tr, 0.0, float(tr.times[-1])))
    t_seg, (segs, _) = _timed(lambda: G.segment_turns(tr, 0.0, float(tr.times[-1]), forward_axis=(1, 0, 0)),
                              repeat=1)
    t_one, _ = _timed(lambda: G.heading_change(tr, 1.0, float(tr.times[-1]) - 1.0, (1, 0, 0)), repeat=5)
    print(f"pose operators on {n:,} poses (track build {t_build:.2f} s, quaternion cache {t_q:.2f} s):")
    print(f"  pose_at linear (lerp+slerp)   {t_pose:7.3f} s  {n / t_pose:12,.0f} evaluations/s")
    print(f"  heading (Eq. heading), pairs  {t_head:7.3f} s  {(n - 1) / t_head:12,.0f} evaluations/s")
    print(f"  path_length, all samples      {t_path:7.3f} s  {n / t_path:12,.0f} samples/s  (L = {L:,.1f} m)")
    print(f"  segment_turns, all samples    {t_seg:7.3f} s  {n / t_seg:12,.0f} samples/s  ({len(segs)} segments)")
    print(f"  heading_change, one call      {t_one * 1e3:7.3f} ms")


def _write_sens(path: Path, n: int, color: int, depth: int) -> None:
    blob_c = np.random.default_rng(2).integers(0, 256, color, dtype=np.uint8).tobytes()
    blob_d = np.random.default_rng(3).integers(0, 256, depth, dtype=np.uint8).tobytes()
    K = np.eye(4).reshape(-1)
    with open(path, "wb") as f:
        f.write(struct.pack("<IQ", 4, 6) + b"bench!")
        f.writelines(struct.pack("<16f", *K) for _ in range(4))
        f.write(struct.pack("<ii4IfQ", 2, 1, 1296, 968, 640, 480, 1000.0, n))
        for i in range(n):
            T = np.eye(4)
            T[0, 3] = 0.01 * i
            f.write(struct.pack("<16f", *T.reshape(-1)))
            f.write(struct.pack("<QQQQ", i, i, color, depth))
            f.write(blob_c)
            f.write(blob_d)


def bench_sens(n_frames: int) -> None:
    from resti_lib.sources.scannet import read_sens_poses

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "bench.sens"
        t0 = time.perf_counter()
        _write_sens(p, n_frames, 200_000, 100_000)
        t_write = time.perf_counter() - t0
        mb = p.stat().st_size / 1e6
        t_read, sp = _timed(lambda: read_sens_poses(p))
        assert sp.T.shape == (n_frames, 4, 4)

        def read_all() -> int:
            with open(p, "rb") as f:
                return sum(len(b) for b in iter(lambda: f.read(1 << 22), b""))

        t_full, _ = _timed(read_all)
        print(f".sens pose extraction: {n_frames} frames, {mb:,.0f} MB (written in {t_write:.1f} s; "
              f"file in the page cache)")
        print(f"  read_sens_poses      {t_read:7.3f} s  {mb / t_read:12,.0f} MB/s scanned  "
              f"{n_frames / t_read:10,.0f} frames/s")
        print(f"  reading every byte   {t_full:7.3f} s  {mb / t_full:12,.0f} MB/s (what a full reader "
              f"would pay at best)  ratio {t_full / t_read:,.0f}x")


def main() -> None:
    n = int(os.environ.get("RESTI_BENCH_POSES", "1000000"))
    frames = int(os.environ.get("RESTI_BENCH_SENS_FRAMES", "1500"))
    bench_pose_operators(n)
    bench_sens(frames)


if __name__ == "__main__":
    main()
