"""``resti reoption`` at scale: ReSTI v5 (1,782 accepted rows) and v5 repeated K times under new names.

A repeated copy renames every video (``r<k>_<video>``), ReSTI ID and Legacy Row Key, so each copy is a
new recording of its own, and carries a ``release.json`` and ``SHA256SUMS`` that match its bytes (a
legitimate input). Each run is one ``resti reoption`` process (adversarial filter included); prints
wall seconds, the peak memory of the process, rows/s and the cost per row relative to 1x.
Targets: 1x under 30 s on 2 cores; Kx per-row cost at most 2x the 1x cost, under 4 GB, no abort.

Usage: python -m bench.bench_reoption [K ...]   (default: 1 20)
"""

from __future__ import annotations

import hashlib
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_1X_S = 30.0
MAX_ROW_RATIO = 2.0
MAX_GB = 4.0


def repeated_release(src: Path, k: int, out: Path) -> int:
    """Write v5 repeated ``k`` times under new names into ``out``; the number of accepted rows."""
    out.mkdir(parents=True, exist_ok=True)
    meta = json.loads((src / "release.json").read_text(encoding="utf-8"))
    acc = [json.loads(x) for x in (src / "resti.jsonl").read_text(encoding="utf-8").splitlines() if x.strip()]
    exc = [json.loads(x) for x in (src / "excluded.jsonl").read_text(encoding="utf-8").splitlines() if x.strip()]
    rows, excluded = [], []
    for c in range(k):
        tag = f"r{c}_" if c else ""  # the first copy keeps v5's names

        def key(old: str, tag: str = tag) -> str:  # Source|Task|Video|ID|uid=<16 hex>, renamed
            if not tag:
                return old
            src_, task, video, rid, uid = old.split("|")
            uid = "uid=" + hashlib.sha256((tag + uid).encode()).hexdigest()[:16]
            return "|".join([src_, task, tag + video, rid, uid])

        for r in acc:
            rows.append({**r, "Video": tag + r["Video"], "ReSTI ID": f"{r['ReSTI ID']}{':' + tag if tag else ''}",
                         "Legacy Row Key": key(r["Legacy Row Key"])})
        for e in exc:
            excluded.append({**e, "key": key(e["key"]), "legacy_video": tag + str(e.get("legacy_video"))})
    files = {"resti.jsonl": rows, "excluded.jsonl": excluded}
    sums = {}
    for name, recs in files.items():
        data = "".join(json.dumps(r, ensure_ascii=False) + "\n" for r in recs).encode("utf-8")
        (out / name).write_bytes(data)
        sums[name] = (hashlib.sha256(data).hexdigest(), len(data))
    arts = {}
    for path, art in meta.get("artifacts", {}).items():
        name = Path(path).name
        if name in sums:
            arts[path] = {**art, "sha256": sums[name][0], "bytes": sums[name][1]}
    meta["artifacts"] = arts
    meta["counts"] = {key: int(v) * k for key, v in meta["counts"].items()}
    for key in ("accepted_by_source", "accepted_by_task", "excluded_by_task", "answer_letters"):
        if isinstance(meta.get(key), dict):
            meta[key] = {a: int(v) * k for a, v in meta[key].items()}
    (out / "release.json").write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    (out / "SHA256SUMS").write_text("".join(f"{h}  {n}\n" for n, (h, _) in sums.items()), encoding="utf-8")
    return len(rows)


def run(release: Path, out: Path) -> tuple[float, float, int]:
    """Wall seconds, peak memory (GB) and exit status of one ``resti reoption`` process."""
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "resti_lib.run.cli", "reoption", "--release", str(release),
                        "--out", str(out), "--seed", "0"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                       text=True)
    wall = time.perf_counter() - t0
    if p.returncode:
        print(p.stderr.strip().splitlines()[-1] if p.stderr.strip() else f"exit {p.returncode}")
    peak_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss  # the largest child so far
    return wall, peak_kb / 2**20, p.returncode


def main() -> None:
    from resti_lib import paths

    src = paths.resti_v5_dir()
    if not src.exists():
        print(f"bench_reoption: {src} absent; skipped")
        return
    scales = [int(x) for x in sys.argv[1:]] or [1, 20]
    per_row: dict[int, float] = {}
    with tempfile.TemporaryDirectory(prefix="resti-bench-reoption-") as tmp:
        for k in scales:
            folder = Path(tmp) / f"v5x{k}"
            n = repeated_release(src, k, folder)
            wall, gb, rc = run(folder, Path(tmp) / f"out{k}")
            per_row[k] = wall / n
            ratio = per_row[k] / per_row[scales[0]]
            status = "aborted" if rc else "ok"
            line = (f"{k:>3}x  {n:>6} rows  {wall:7.1f} s  {n / wall:7.1f} rows/s  peak {gb:4.2f} GB  "
                    f"per-row cost {ratio:4.2f}x of {scales[0]}x  {status}")
            if k == 1:
                line += f"  target {TARGET_1X_S:g} s: {'met' if wall < TARGET_1X_S else 'NOT met'}"
            elif scales[0] == 1:
                ok = rc == 0 and ratio <= MAX_ROW_RATIO and gb < MAX_GB
                line += f"  target <= {MAX_ROW_RATIO:g}x, < {MAX_GB:g} GB: {'met' if ok else 'NOT met'}"
            print(line, flush=True)


if __name__ == "__main__":
    main()
