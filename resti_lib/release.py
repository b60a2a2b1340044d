"""Assemble the task outputs into one release, check the invariants, write it atomically.

Files (``outputs/release/``): ``resti.jsonl`` and ``resti.parquet`` (identical rows, ReSTI v5 fields),
``excluded.jsonl``, ``provenance.parquet`` (every legacy row: contract, source files, frames,
transform chain, verdict, evidence), ``validation.json`` (``resti verify``), ``release.json``
(counts, exclusions by task, answer letters, bytes and sha256 of every artifact) and ``SHA256SUMS``.

Invariants, checked on every run (an :class:`InvariantError` stops the run, nothing is written):
accepted + excluded == legacy rows; every legacy key exactly once; ids unique; verify passes.
The files are written to a temporary folder next to the target, then swapped in, so a crash
leaves the previous release intact. No timestamps are written: reruns are byte-identical.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import tempfile
from collections import Counter
from pathlib import Path

import pandas as pd

from . import LETTERS, TASKS, __version__, paths
from .io.benchmark import jsonl_text, load_legacy, load_release, rows_to_parquet_bytes
from .tasks.base import slug
from .verify import sha256_file, verify_release


class InvariantError(RuntimeError):
    """A release invariant failed (rows lost or duplicated, ids not unique, verify failing)."""


def _read_jsonl(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


def collect(tasks_dir: Path, legacy: pd.DataFrame) -> tuple[list[dict], list[dict], pd.DataFrame]:
    """Read every task's outputs; legacy rows of a task that is not in TASKS become exclusions."""
    accepted, excluded, prov = [], [], []
    present = set(legacy["Task"])
    for task in TASKS:
        if task not in present:
            continue
        d = tasks_dir / slug(task)
        if not (d / "accepted.jsonl").exists():
            raise InvariantError(f"no outputs for task {task!r} in {d}: run its notebook first")
        accepted += _read_jsonl(d / "accepted.jsonl")
        excluded += _read_jsonl(d / "excluded.jsonl")
        prov.append(pd.read_parquet(d / "provenance.parquet"))
    for r in legacy[~legacy["Task"].isin(TASKS)].to_dict("records"):
        excluded.append({"key": r["Legacy Row Key"], "legacy_id": r.get("ID"), "legacy_video": r.get("Video"),
                         "source": r.get("Source"), "task": r.get("Task"), "reason_codes": ["malformed_row"],
                         "verification_verdict": "excluded_malformed_row",
                         "verification_evidence": {"field": "Task", "problem": f"unknown task {r.get('Task')!r}"}})
        prov.append(pd.DataFrame([{"row": int(r["row"]), "key": r["Legacy Row Key"], "resti_id": None,
                                   "task": str(r.get("Task")), "source": str(r.get("Source")),
                                   "video": str(r.get("Video")), "verdict": "excluded",
                                   "reasons": '["malformed_row"]', "defects": "[]"}]))
    provenance = pd.concat(prov, ignore_index=True) if prov else pd.DataFrame()
    return accepted, excluded, provenance


def check_invariants(legacy: pd.DataFrame, accepted: list[dict], excluded: list[dict]) -> dict:
    """accepted + excluded == legacy, each key once, ids unique. Returns the counts."""
    keys = list(legacy["Legacy Row Key"])
    acc = [r["Legacy Row Key"] for r in accepted]
    exc = [r["key"] for r in excluded]
    problems = []
    if len(acc) + len(exc) != len(keys):
        problems.append(f"accepted {len(acc)} + excluded {len(exc)} != legacy {len(keys)}")
    dup = [k for k, n in Counter(acc + exc).items() if n > 1]
    if dup:
        problems.append(f"{len(dup)} legacy keys appear twice, e.g. {dup[:3]}")
    lost = sorted(set(keys) - set(acc) - set(exc))
    if lost:
        problems.append(f"{len(lost)} legacy rows lost, e.g. {lost[:3]}")
    extra = sorted(set(acc + exc) - set(keys))
    if extra:
        problems.append(f"{len(extra)} keys not in the legacy benchmark, e.g. {extra[:3]}")
    ids = [r["ReSTI ID"] for r in accepted]
    if len(set(ids)) != len(ids):
        problems.append("ReSTI IDs are not unique")
    if problems:
        raise InvariantError("; ".join(problems))
    return {"legacy": len(keys), "accepted": len(acc), "excluded": len(exc)}


def _parquet_bytes(df: pd.DataFrame) -> bytes:
    buf = io.BytesIO()
    df.to_parquet(buf, index=False, compression="zstd")
    return buf.getvalue()


def release_meta(accepted: list[dict], excluded: list[dict], artifacts: dict, *, context: dict | None = None
                 ) -> dict:
    """``release.json``: counts, answer letters, artifacts and (``context``) the run that made it
    (:func:`resti_lib.runinfo.run_context`: input, params digest, code and package versions)."""
    by_task = Counter(r["Task"] for r in accepted)
    by_source = Counter(r["Source"] for r in accepted)
    ex_task = Counter(r["task"] for r in excluded)
    letters = Counter(r["Answer"] for r in accepted)
    order = {t: i for i, t in enumerate(TASKS)}
    meta = {
        "name": "ReSTI", "format": "ReSTI v5 schema", "generator": f"resti {__version__}",
        "counts": {"accepted": len(accepted), "excluded": len(excluded), "original": len(accepted) + len(excluded)},
        "accepted_by_source": dict(sorted(by_source.items())),
        "accepted_by_task": dict(sorted(by_task.items())),
        "excluded_by_task": dict(sorted(ex_task.items(), key=lambda kv: order.get(kv[0], 99))),
        "answer_letters": {k: letters.get(k, 0) for k in LETTERS},
        "artifacts": artifacts,
    }
    if context:
        meta["run"] = context
    return meta


def _swap_in(tmp: Path, target: Path) -> None:
    prev = target.with_name(f".{target.name}.prev")
    if prev.exists():
        shutil.rmtree(prev)
    if target.exists():
        os.rename(target, prev)
    os.rename(tmp, target)
    if prev.exists():
        shutil.rmtree(prev)


def recover(target: Path) -> None:
    """Undo an interrupted swap: a ``.prev`` folder without its target becomes the target again."""
    prev = target.with_name(f".{target.name}.prev")
    if prev.exists() and not target.exists():
        os.rename(prev, target)


OPTION_MODES = ("population", "task")


def rebuild_options(accepted: list[dict], *, seed: int = 0, options: dict | None = None) -> list[dict]:
    """Release-level options: every row's four distractors and letter rebuilt from exchangeable draws
    calibrated on the answers of its (task, source) population (:mod:`resti_lib.reoption`).

    The task notebooks build each row's options alone; an attacker that learns where answers of a
    task usually fall can still prefer the most typical candidate. Here the whole population is
    known, so the draws follow it. Questions, times and Answer Detail strings are unchanged; a row
    whose options cannot be built under the constraints keeps the task's options.
    """
    from .reoption import reoption_records

    rows, _ = reoption_records(accepted, seed=seed, options=options, keep_on_failure=True)
    return rows


def write_release(accepted: list[dict], excluded: list[dict], provenance: pd.DataFrame, legacy: pd.DataFrame,
                  out_dir: str | Path, *, options: str = "population", seed: int = 0,
                  context: dict | None = None) -> dict:
    """Write the release atomically; returns the validation object.

    ``options``: ``population`` rebuilds the options at release level (:func:`rebuild_options`);
    ``task`` keeps the options the task notebooks built.
    """
    if options not in OPTION_MODES:
        raise ValueError(f"options must be one of {OPTION_MODES}, got {options!r}")
    out_dir = Path(out_dir)
    recover(out_dir)
    check_invariants(legacy, accepted, excluded)
    order = {k: i for i, k in enumerate(legacy["Legacy Row Key"])}
    accepted = sorted(accepted, key=lambda r: order[r["Legacy Row Key"]])
    if options == "population" and accepted:
        accepted = rebuild_options(accepted, seed=seed)
    excluded = sorted(excluded, key=lambda r: order[r["key"]])
    provenance = provenance.assign(_o=provenance["key"].map(order)).sort_values("_o").drop(columns="_o")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out_dir.parent, prefix=f".{out_dir.name}.tmp-"))
    os.chmod(tmp, paths.dir_mode())  # mkdtemp creates 0700; the release honours the umask
    try:
        (tmp / "resti.jsonl").write_bytes(jsonl_text(accepted).encode("utf-8"))
        (tmp / "resti.parquet").write_bytes(rows_to_parquet_bytes(accepted))
        (tmp / "excluded.jsonl").write_bytes(jsonl_text(excluded, sort_keys=True).encode("utf-8"))
        (tmp / "provenance.parquet").write_bytes(_parquet_bytes(provenance.reset_index(drop=True)))
        rel = load_release(tmp, strict=False)
        rel.meta = release_meta(accepted, excluded, {}, context=context)  # the counts release.json states
        validation = verify_release(rel, legacy_keys=list(legacy["Legacy Row Key"]))
        (tmp / "validation.json").write_bytes((json.dumps(validation, indent=2, ensure_ascii=False) + "\n")
                                              .encode("utf-8"))
        if not validation["passed"]:
            failed = {k: c["failing"][:3] for k, c in validation["checks"].items() if c["status"] == "fail"}
            raise InvariantError(f"the assembled release fails verify: {failed}")
        names = ["resti.jsonl", "resti.parquet", "excluded.jsonl", "provenance.parquet", "validation.json"]
        artifacts = {n: {"bytes": (tmp / n).stat().st_size, "sha256": sha256_file(tmp / n)} for n in names}
        meta = release_meta(accepted, excluded, artifacts, context=context)
        (tmp / "release.json").write_bytes((json.dumps(meta, indent=2, ensure_ascii=False) + "\n").encode("utf-8"))
        sums = "".join(f"{sha256_file(tmp / n)}  {n}\n" for n in names + ["release.json"])
        (tmp / "SHA256SUMS").write_bytes(sums.encode("utf-8"))
        _swap_in(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return validation


def assemble(legacy_path: str | Path, tasks_dir: str | Path, out_dir: str | Path, *, options: str = "population",
             seed: int = 0, context: dict | None = None) -> dict:
    """Read the legacy benchmark and every task's outputs, then :func:`write_release`."""
    legacy, _ = load_legacy(legacy_path, strict=False)
    accepted, excluded, provenance = collect(Path(tasks_dir), legacy)
    return write_release(accepted, excluded, provenance, legacy, out_dir, options=options, seed=seed,
                         context=context)


def sequence_groups(provenance: pd.DataFrame) -> dict:
    """Legacy Row Key -> source sequence (from each row's contract), for grouped cross-validation."""
    out = {}
    for key, contract in zip(provenance["key"], provenance.get("contract", pd.Series([None] * len(provenance)))):
        try:
            seq = json.loads(contract).get("sequence") if isinstance(contract, str) else None
        except json.JSONDecodeError:
            seq = None
        if seq:
            out[key] = seq
    return out
