"""`make report` three ways, as ratios to the cold run, beside the floor of kernel start-ups.

- cold: no outputs at all (mini-world generation + every stage);
- warm: nothing changed (every stage up to date; target under 5 s);
- one task changed: ``decimals`` of params/dimensional.yaml edited, so that task, the task whose
  candidate sets follow it (Grounding: ``Task.follows``), the release and the report rerun (target
  under 25 s on 2 cores).

The floor is the sum of the kernel start-ups of the stages that ran (one empty notebook through
papermill, median of three, times the number of stages). Everything happens in a temporary copy of
params/ and a temporary output folder: the user's params/ and outputs/ are not touched.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import yaml

from resti_lib import paths

WARM_TARGET_S, ONE_TASK_TARGET_S = 5.0, 25.0


def _params(tmp: Path) -> Path:
    """A copy of params/ whose main file writes everything under ``tmp/outputs``."""
    pdir = tmp / "params"
    shutil.copytree(paths.PARAMS, pdir)
    cfg = yaml.safe_load((pdir / "default.yaml").read_text())
    out = tmp / "outputs"
    world = out / "miniworld"
    cfg.update(world_dir=str(world), legacy_benchmark=str(world / "legacy" / "qa.parquet"),
               scannet_root=str(world / "scannet" / "scans"), waymo_root=str(world / "waymo"),
               omni6d_root=str(world / "omni6d"), output_dir=str(out))
    for s in cfg["stages"]:
        s["params"] = str(pdir / Path(s["params"]).name)
    (pdir / "default.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    return pdir / "default.yaml"


def _make_report(params: Path) -> tuple[float, float, list[str]]:
    """Wall seconds, CPU seconds (user + system of every process it started) and the stages run."""
    import resource

    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(["make", "-s", "-C", str(paths.ROOT), "report", f"PARAMS={params}"], capture_output=True,
                       text=True, check=False)
    dt = time.perf_counter() - t0
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    if r.returncode != 0:
        raise SystemExit(f"bench_pipeline: make report failed:\n{r.stderr[-3000:]}")
    m = re.search(r"resti run: \d+ stage\(s\) run, \d+ up to date, [\d.]+ s(?: \(([^)]*)\))?", r.stdout)
    ran = [x.strip() for x in (m.group(1) or "").split(",") if x.strip()] if m else []
    return dt, cpu, ran


def kernel_startup_s(repeat: int = 3) -> float:
    """Median wall time of one empty notebook through papermill with the main job's kernel settings."""
    import nbformat
    import papermill

    from resti_lib.run.notebooks import KERNEL, KERNEL_ARGUMENTS

    with tempfile.TemporaryDirectory() as d:
        nb = nbformat.v4.new_notebook()
        cell = nbformat.v4.new_code_cell("x = 0")
        cell.metadata["tags"] = ["parameters"]
        nb.cells = [cell, nbformat.v4.new_code_cell("x")]
        nb.metadata["kernelspec"] = {"name": KERNEL, "display_name": "Python 3", "language": "python"}
        src = Path(d) / "empty.ipynb"
        nbformat.write(nb, src)
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            papermill.execute_notebook(str(src), str(Path(d) / "out.ipynb"), parameters={"x": 1}, kernel_name=KERNEL,
                                       progress_bar=False, log_output=False, cwd=str(paths.ROOT),
                                       extra_arguments=list(KERNEL_ARGUMENTS))
            times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    cores = os.cpu_count() or 1
    with tempfile.TemporaryDirectory(prefix="resti-bench-") as d:
        tmp = Path(d)
        params = _params(tmp)
        load = os.getloadavg()[0]
        cold, cpu_cold, ran_cold = _make_report(params)
        warm, cpu_warm, ran_warm = _make_report(params)
        dim = params.parent / "dimensional.yaml"
        text = dim.read_text()
        dim.write_text(re.sub(r"^decimals: 2 ", "decimals: 3 ", text, count=1, flags=re.MULTILINE))
        one, cpu_one, ran_one = _make_report(params)
        load = max(load, os.getloadavg()[0])
        state = json.loads((tmp / "outputs" / ".resti" / "stages.json").read_text())
        rel = tmp / "outputs" / "release"
        rows = sum(len((rel / n).read_text().splitlines()) for n in ("resti.jsonl", "excluded.jsonl"))
    k = kernel_startup_s()
    print(f"make report on the default mini-world ({rows} legacy rows, {cores} cores, load average up to "
          f"{load:.1f}); kernel start-up {k:.2f} s")
    print(f"  {'run':<18}{'wall s':>8}{'/ cold':>8}{'cpu s':>8}{'stages':>8}{'start-ups s':>13}{'/ cold':>8}   target")
    for name, t, cpu, ran, target in (("cold", cold, cpu_cold, ran_cold, None),
                                      ("warm, unchanged", warm, cpu_warm, ran_warm, WARM_TARGET_S),
                                      ("one task changed", one, cpu_one, ran_one, ONE_TASK_TARGET_S)):
        floor = k * len(ran)
        tgt = f"< {target:.0f} s: {'met' if t < target else 'MISSED'}" if target else ""
        print(f"  {name:<18}{t:8.1f}{t / cold:8.2f}{cpu:8.1f}{len(ran):8d}{floor:13.1f}{floor / cold:8.2f}   {tgt}")
    print("  cpu: user + system seconds of every process of the run (on a machine shared with other work, the")
    print("  wall time of a run whose stages run one after another approaches this)")
    print("  start-ups: the sum of the kernel start-ups of the stages that ran (the floor of a run that")
    print("  starts them one after another; stages of one wave start side by side on the cores)")
    print(f"  one task changed reran: {', '.join(ran_one)}")
    print("  seconds per stage (last run of each): " + ", ".join(
        f"{n} {s['seconds']:.1f}" for n, s in sorted(state["stages"].items()) if s.get("seconds")))


if __name__ == "__main__":
    main()
