"""Load + verify + attack the 1,782 rows of ReSTI v5: wall time and rows/s (target < 2 s total)."""

from __future__ import annotations

import time


def main() -> None:
    t_import = time.perf_counter()
    from resti_lib import paths
    from resti_lib.io.benchmark import load_release
    from resti_lib.options.attacks import attack_table
    from resti_lib.verify import verify_release

    t0 = time.perf_counter()
    src = paths.resti_v5_dir()
    if not src.exists():
        print(f"bench_answer_interface: {src} absent; skipped")
        return
    rel = load_release(src, strict=False)
    t1 = time.perf_counter()
    v = verify_release(rel)
    t2 = time.perf_counter()
    table = attack_table(rel.accepted.to_dict("records"))
    t3 = time.perf_counter()
    n = v["accepted_rows"]
    total = t3 - t0
    print(f"answer interface on ReSTI v5 ({n} rows, {len(table)} attack-table rows):")
    print(f"  import  {t0 - t_import:6.3f} s (numpy/pandas/scipy; paid once per process)")
    print(f"  load    {t1 - t0:6.3f} s   {n / (t1 - t0):9.0f} rows/s")
    print(f"  verify  {t2 - t1:6.3f} s   {n / (t2 - t1):9.0f} rows/s")
    print(f"  attack  {t3 - t2:6.3f} s   {n / (t3 - t2):9.0f} rows/s")
    print(f"  total   {total:6.3f} s   {n / total:9.0f} rows/s   target 2 s: ratio {total / 2.0:.2f}")


if __name__ == "__main__":
    main()
