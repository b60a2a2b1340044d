"""Scale: the full 2,064-row legacy structure (scale 1) and 100x (about 206k rows).

For each scale: generate the legacy benchmark over a bounded pool of source sequences, then run
every task's audit (the same `run_task` the notebooks call), one process per task with as many at
once as there are cores (as the main job runs its notebooks), and assemble the release. Prints wall
time, the peak memory of the largest process, rows/s, and the cost ratio per row between scales
(linear growth means a ratio near 1). Target: the 100x run under 10 minutes within 4 GB.

Usage: python -m bench.bench_scale [SCALE ...]   (default: 1 100)
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

from resti_lib.tasks import names as _task_names

TASK_NAMES = _task_names()

CHILD = r"""
import json, os, resource, sys, time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from resti_lib.release.assemble import assemble
from resti_lib.tasks.run import run_task
import pandas as pd

def one(task, params):
    t = time.perf_counter()
    run = run_task(task, params)
    return (task, time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            run.result.option_seconds)

if __name__ == "__main__":
    w = Path(sys.argv[1])
    params = {"legacy_benchmark": str(w / "legacy/qa.parquet"), "scannet_root": str(w / "scannet/scans"),
              "waymo_root": str(w / "waymo"), "omni6d_root": str(w / "omni6d"), "scannet_fps": 30,
              "omni6d_fps": 30, "video_map": str(w / "legacy/video_map.csv"), "seed": 0,
              "output_dir": str(w / "out")}
    t0 = time.perf_counter()
    present = set(pd.read_parquet(params["legacy_benchmark"], columns=["Task"])["Task"])
    tasks = [t for t in TASK_NAMES if t in present]
    # like the main job: one process per task, as many at once as there are cores, the tasks that
    # took longest before first (the main job orders a wave by its last run's stage seconds)
    last = json.loads(sys.argv[2]) if len(sys.argv) > 2 else {}
    tasks.sort(key=lambda t: -last.get(t, 0.0))
    with ProcessPoolExecutor(max_workers=os.cpu_count() or 1, max_tasks_per_child=1) as ex:
        per_task = list(ex.map(one, tasks, [params] * len(tasks)))
    t1 = time.perf_counter()
    v = assemble(params["legacy_benchmark"], w / "out" / "tasks", w / "out" / "release")
    dt = time.perf_counter() - t0
    print(json.dumps({"rows": v["total_rows"], "audit_s": dt, "tasks_s": t1 - t0, "release_s": dt - (t1 - t0),
                      "accepted": v["accepted_rows"], "excluded": v["excluded_rows"],
                      "maxrss_mb": max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                                       max(m for _, _, m, _ in per_task)),
                      "options_s": sum(o for _, _, _, o in per_task),
                      "per_task": {t: [round(s, 1), round(m), round(o, 1)] for t, s, m, o in per_task}}))
"""


def run_scale(scale: int, last: dict | None = None) -> dict:
    """One scale; ``last``: seconds per task of an earlier run, the longest started first."""
    import json

    from resti_lib.synth import generate

    with tempfile.TemporaryDirectory(prefix=f"resti-scale{scale}-") as d:
        w = Path(d)
        t0 = time.perf_counter()
        generate(w, seed=0, scale=scale)
        gen = time.perf_counter() - t0
        script = w / "_bench_child.py"
        script.write_text(CHILD)
        r = subprocess.run([sys.executable, str(script), str(w), json.dumps(last or {})], capture_output=True,
                           text=True)
        if r.returncode != 0:
            raise SystemExit(f"bench_scale: audit failed at scale {scale}:\n{r.stderr[-3000:]}")
        out = json.loads(r.stdout.strip().splitlines()[-1])
        out.update(scale=scale, generate_s=gen)
        return out


def main(argv: list[str] | None = None) -> None:
    scales = [int(x) for x in (argv or [])] or [1, 100]
    res = []
    for s in scales:  # each scale's tasks ordered by the previous scale's seconds
        res.append(run_scale(s, {t: v[0] for t, v in res[-1]["per_task"].items()} if res else None))
    print("scale    rows   generate   tasks   release   rows/s   peak MB   accepted/excluded")
    for r in res:
        print(f"{r['scale']:5d} {r['rows']:7d} {r['generate_s']:9.1f}s {r['tasks_s']:6.1f}s {r['release_s']:7.1f}s "
              f"{r['rows'] / r['audit_s']:8.0f} {r['maxrss_mb']:9.0f}   {r['accepted']}/{r['excluded']}")
        print("        per task (s, peak MB, option stage s): " + ", ".join(
            f"{t.split()[0]} {v[0]}/{v[1]}/{v[2]}" for t, v in r["per_task"].items()))
        print(f"        option stage: {r['options_s']:.1f} s of {sum(v[0] for v in r['per_task'].values()):.1f} s "
              f"of task processing ({r['options_s'] / max(1e-9, sum(v[0] for v in r['per_task'].values())):.0%})")
    if len(res) > 1:
        a, b = res[0], res[-1]
        per_a, per_b = a["audit_s"] / a["rows"], b["audit_s"] / b["rows"]
        print(f"cost per row, scale {b['scale']} / scale {a['scale']}: {per_b / per_a:.2f} (1.0 = linear)")
        print(f"target: scale 100 under 600 s and 4096 MB -> {b['audit_s'] + b['generate_s']:.0f} s, "
              f"{b['maxrss_mb']:.0f} MB")


if __name__ == "__main__":
    main(sys.argv[1:])
