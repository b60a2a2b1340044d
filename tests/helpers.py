"""Small hand-built rows for tests (no shared data needed)."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from resti_lib.io.benchmark import legacy_row_keys


def row(task="Displacement & Path Length", source="ScanNet", video="scene0900_00.mp4", rid=0,
        cands=None, answer="B", detail=None, t0=0.0, t1=5.0, question="What is the displacement?"):
    cands = cands or {"A": "1.00m", "B": "2.00m", "C": "3.00m", "D": "4.00m", "E": "5.00m"}
    return {"Video": video, "Source": source, "Task": task, "QType": "Single Choice",
            "Question": question, "Prompt": "", "time_start": t0, "time_end": t1,
            "Candidates": cands, "Answer": answer,
            "Answer Detail": detail if detail is not None else cands.get(answer, "2.00m"),
            "ID": rid, "scene": {"ScanNet": "indoor", "Waymo": "outdoor", "Omni6DPose": "desktop"}[source]}


def write_legacy(rows, path: Path, *, candidates_as="json") -> Path:
    recs = []
    for r in rows:
        r = dict(r)
        if candidates_as == "json":
            r["Candidates"] = json.dumps(r["Candidates"])
        recs.append(r)
    pd.DataFrame.from_records(recs).to_parquet(path)
    return path


def write_release(rows, excluded, folder: Path) -> Path:
    """A tiny ReSTI-schema release folder (no release.json)."""
    folder.mkdir(parents=True, exist_ok=True)
    keys = legacy_row_keys(rows)
    out = []
    for i, (r, k) in enumerate(zip(rows, keys)):
        out.append({**r, "ReSTI ID": f"resti-test-{i}", "Legacy Row Key": k})
    (folder / "resti.jsonl").write_text("".join(json.dumps(r, ensure_ascii=False) + "\n" for r in out),
                                        encoding="utf-8")
    (folder / "excluded.jsonl").write_text("".join(json.dumps(e) + "\n" for e in excluded), encoding="utf-8")
    return folder


def seal_release(folder: Path) -> Path:
    """Add the integrity records a published release carries: ``release.json`` with the row counts
    (counted here from the files) and ``SHA256SUMS`` of the two row files."""
    import hashlib

    def n_rows(name):
        p = folder / name
        return sum(1 for line in p.read_text(encoding="utf-8").splitlines() if line.strip()) if p.exists() else 0

    acc, exc = n_rows("resti.jsonl"), n_rows("excluded.jsonl")
    (folder / "release.json").write_text(json.dumps({"name": "test release", "version": "t1", "counts": {
        "accepted": acc, "excluded": exc, "original": acc + exc}}, indent=2) + "\n", encoding="utf-8")
    sums = "".join(f"{hashlib.sha256((folder / n).read_bytes()).hexdigest()}  {n}\n"
                   for n in ("resti.jsonl", "excluded.jsonl") if (folder / n).exists())
    (folder / "SHA256SUMS").write_text(sums, encoding="utf-8")
    return folder
