"""The answer-interface audit of the 1,782 rows of ReSTI v5: ``resti attack`` with every family (target
30 s on 2 cores), its learned part separately, and the in-process breakdown by stage and family.

Prints wall and CPU seconds (CPU time is what the machine's other load does not inflate), rows/s and
the ratio to the target. Not run by the tests.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

TARGET_S = 30.0


def _cli(args: list[str]) -> tuple[float, float]:
    """Wall and CPU (children) seconds of one ``resti attack`` run, output discarded."""
    c0 = os.times()
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "resti_lib.run.cli", "attack", *args], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    c1 = os.times()
    return time.perf_counter() - t0, (c1.children_user + c1.children_system) - (c0.children_user + c0.children_system)


def _timed(fn):
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - t0, time.process_time() - c0


def main() -> None:
    from resti_lib import paths

    src = paths.resti_v5_dir()
    if not src.exists():
        print(f"bench_answer_interface: {src} absent; skipped")
        return
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores (wall times stretch with it)")
    full_w, full_c = _cli([str(src), "--format", "csv"])
    fast_w, fast_c = _cli([str(src), "--format", "csv", "--fast"])
    n = 1782
    print("resti attack on ReSTI v5 (1,782 rows), end to end (import, load, attack, print):")
    print(f"  all families  wall {full_w:6.1f} s  cpu {full_c:6.1f} s  {n / full_w:7.0f} rows/s   "
          f"ratio to the {TARGET_S:.0f} s target {full_w / TARGET_S:.2f}")
    print(f"  --fast        wall {fast_w:6.1f} s  cpu {fast_c:6.1f} s  {n / fast_w:7.0f} rows/s   "
          f"ratio {fast_w / TARGET_S:.2f}")
    print(f"  learned part  wall {full_w - fast_w:6.1f} s  cpu {full_c - fast_c:6.1f} s  "
          f"({(full_w - fast_w) / full_w:.0%} of the run)")

    from resti_lib.io.benchmark import load_release
    from resti_lib.options.attacks import ATTACKS, FAMILIES, make_batch, parse_rows, run_one, select
    from resti_lib.release.verify import verify_release
    from resti_lib.tasks import interface

    rel, w_load, c_load = _timed(lambda: load_release(src, strict=False))
    records = rel.accepted.to_dict("records")
    _, w_ver, c_ver = _timed(lambda: verify_release(rel))
    batch, w_parse, c_parse = _timed(lambda: make_batch(parse_rows(records), records, iface=interface())[0])
    _, w_obs, c_obs = _timed(lambda: batch.obs)
    (cluster, _), w_cpl, c_cpl = _timed(batch.coupled)
    print("in process, by stage and family:")
    for name, w, c in (("load", w_load, c_load), ("verify", w_ver, c_ver), ("parse", w_parse, c_parse),
                       ("observables", w_obs, c_obs), ("coupled rows", w_cpl, c_cpl)):
        print(f"  {name:18s} wall {w:6.2f} s  cpu {c:6.2f} s  {n / w:8.0f} rows/s")
    clustered = [c for c in cluster if c is not None]
    print(f"  ({len(set(clustered))} clusters of coupled rows hold {len(clustered)} of {n} rows: one draw each)")
    for fam in FAMILIES:
        names = select(fam)
        _, w, c = _timed(lambda names=names: [run_one(ATTACKS[a], batch) for a in names])
        print(f"  {fam:18s} wall {w:6.2f} s  cpu {c:6.2f} s  {n / w:8.0f} rows/s  ({len(names)} attacks)")


if __name__ == "__main__":
    main()
