"""Scale: the full 2,064-row legacy structure (scale 1) and 100x (about 206k rows).

For each scale: generate the legacy benchmark over a bounded pool of source sequences, then run
every task's audit in-process (the same `run_task` the notebooks call) and assemble the release.
Prints wall time, peak memory and rows/s, and the cost ratio per row between scales (linear
growth means a ratio near 1). Target: the 100x run under 10 minutes within 4 GB.

Usage: python -m bench.bench_scale [SCALE ...]   (default: 1 100)
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = r"""
import json, resource, sys, time
from pathlib import Path
from resti_lib import TASKS
from resti_lib.release import assemble
from resti_lib.tasks.run import run_task
from resti_lib.io.benchmark import load_legacy
w = Path(sys.argv[1])
params = {"legacy_benchmark": str(w / "legacy/qa.parquet"), "scannet_root": str(w / "scannet/scans"),
          "waymo_root": str(w / "waymo"), "omni6d_root": str(w / "omni6d"), "scannet_fps": 30, "omni6d_fps": 30,
          "video_map": str(w / "legacy/video_map.csv"), "seed": 0, "output_dir": str(w / "out")}
t0 = time.perf_counter()
legacy, _ = load_legacy(params["legacy_benchmark"], strict=False)
for task in TASKS:
    if (legacy["Task"] == task).any():
        run_task(task, params)
v = assemble(params["legacy_benchmark"], w / "out" / "tasks", w / "out" / "release")
dt = time.perf_counter() - t0
print(json.dumps({"rows": len(legacy), "audit_s": dt, "accepted": v["accepted_rows"], "excluded": v["excluded_rows"],
                  "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run_scale(scale: int) -> dict:
    import json

    from resti_lib.synth import generate

    with tempfile.TemporaryDirectory(prefix=f"resti-scale{scale}-") as d:
        w = Path(d)
        t0 = time.perf_counter()
        generate(w, seed=0, scale=scale)
        gen = time.perf_counter() - t0
        r = subprocess.run([sys.executable, "-c", CHILD, str(w)], capture_output=True, text=True)
        if r.returncode != 0:
            raise SystemExit(f"bench_scale: audit failed at scale {scale}:\n{r.stderr[-3000:]}")
        out = json.loads(r.stdout.strip().splitlines()[-1])
        out.update(scale=scale, generate_s=gen)
        return out


def main(argv: list[str] | None = None) -> None:
    scales = [int(x) for x in (argv or [])] or [1, 100]
    res = [run_scale(s) for s in scales]
    print("scale    rows   generate   audit+release   rows/s   peak MB   accepted/excluded")
    for r in res:
        print(f"{r['scale']:5d} {r['rows']:7d} {r['generate_s']:9.1f}s {r['audit_s']:14.1f}s "
              f"{r['rows'] / r['audit_s']:8.0f} {r['maxrss_mb']:9.0f}   {r['accepted']}/{r['excluded']}")
    if len(res) > 1:
        a, b = res[0], res[-1]
        per_a, per_b = a["audit_s"] / a["rows"], b["audit_s"] / b["rows"]
        print(f"cost per row, scale {b['scale']} / scale {a['scale']}: {per_b / per_a:.2f} (1.0 = linear)")
        print(f"target: scale 100 under 600 s and 4096 MB -> {b['audit_s'] + b['generate_s']:.0f} s, "
              f"{b['maxrss_mb']:.0f} MB")


if __name__ == "__main__":
    main(sys.argv[1:])
