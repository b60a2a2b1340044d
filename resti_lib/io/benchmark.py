"""Readers and writers for the legacy STI-Bench ``qa.parquet`` and ReSTI-schema releases.

Strict by default: the first problem raises :class:`~resti_lib.errors.InputError` naming the file,
the row (ReSTI ID, Legacy Row Key, or 0-based index) and the field. With ``strict=False`` every
row is kept and its problems are returned as :class:`Problem` records, so an audit can record a
defect for that row instead of dropping it.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np
import pandas as pd

from .. import LETTERS, SOURCES, TASKS, paths
from ..errors import InputError

LEGACY_COLUMNS = ("Video", "Source", "Task", "QType", "Question", "Prompt", "time_start", "time_end",
                  "Candidates", "Answer", "Answer Detail", "ID", "scene")
RELEASE_COLUMNS = LEGACY_COLUMNS + ("ReSTI ID", "Legacy Row Key")
EXCLUDED_REQUIRED = ("key", "legacy_id", "legacy_video", "source", "task", "reason_codes")


@dataclass
class Problem:
    """One validation problem of one row (the per-row record used when not strict)."""

    check: str
    row: Any
    field: str | None
    message: str
    file: str | None = None

    def error(self) -> InputError:
        return InputError(self.message, file=self.file, row=self.row, field=self.field)


@dataclass
class Release:
    """A ReSTI-schema release: accepted rows, exclusion records and (optional) metadata."""

    accepted: pd.DataFrame
    excluded: list[dict]
    meta: dict | None = None
    root: Path | None = None
    accepted_file: Path | None = None
    excluded_file: Path | None = None
    problems: list[Problem] = field(default_factory=list)


# ------------------------------------------------------------------------------------------ keys

def canonical_row_text(row: dict) -> str:
    """Canonical JSON of the legacy content of a row (what the uid hashes)."""
    cand = row.get("Candidates")
    obj = {k: row.get(k) for k in LEGACY_COLUMNS if k != "Candidates"}
    obj["Candidates"] = cand if isinstance(cand, dict) else str(cand)
    for k in ("time_start", "time_end"):
        v = obj.get(k)
        if isinstance(v, float) and not math.isfinite(v):
            obj[k] = str(v)
    if obj.get("ID") is not None:
        try:
            obj["ID"] = int(obj["ID"])
        except (TypeError, ValueError):
            obj["ID"] = str(obj["ID"])
    return json.dumps(obj, sort_keys=True, ensure_ascii=False, default=str)


def legacy_row_keys(rows: Iterable[dict]) -> list[str]:
    """``Source|Task|Video|ID|uid=<16 hex>`` for each row, uid = sha256 of its canonical content.

    Identical rows get distinct uids through an occurrence counter, so keys are always unique.
    """
    seen: Counter = Counter()
    keys = []
    for r in rows:
        text = canonical_row_text(r)
        n = seen[text]
        seen[text] += 1
        uid = hashlib.sha256((text + (f"#{n}" if n else "")).encode()).hexdigest()[:16]
        keys.append(f"{r.get('Source')}|{r.get('Task')}|{r.get('Video')}|{r.get('ID')}|uid={uid}")
    return keys


def parse_key(key: str) -> dict:
    """Split a Legacy Row Key into its parts."""
    parts = key.split("|")
    if len(parts) != 5 or not parts[4].startswith("uid="):
        raise ValueError(f"not a Legacy Row Key: {key!r}")
    return {"source": parts[0], "task": parts[1], "video": parts[2], "id": parts[3], "uid": parts[4][4:]}


# ------------------------------------------------------------------------------------ validation

def _candidates(value: Any, *, file, row) -> dict:
    if isinstance(value, dict):
        return value
    if isinstance(value, str):
        try:
            obj = json.loads(value)
        except json.JSONDecodeError as e:
            raise InputError(f"Candidates is not valid JSON ({e.msg} at char {e.pos})",
                             file=file, row=row, field="Candidates") from None
        if not isinstance(obj, dict):
            raise InputError("Candidates JSON is not an object", file=file, row=row, field="Candidates")
        return obj
    if value is None or (isinstance(value, float) and math.isnan(value)):
        raise InputError("Candidates is null", file=file, row=row, field="Candidates")
    raise InputError(f"Candidates is a {type(value).__name__}", file=file, row=row, field="Candidates")


def validate_row(r: dict, *, file, row) -> list[Problem]:
    """Structural problems of one legacy/release row (schema level; values are parsed elsewhere)."""
    out: list[Problem] = []

    def bad(check, fld, msg):
        out.append(Problem(check, row, fld, msg, str(file) if file else None))

    if r.get("Task") not in TASKS:
        bad("known_task", "Task", f"unknown task {r.get('Task')!r}")
    if r.get("Source") not in SOURCES:
        bad("known_source", "Source", f"unknown source {r.get('Source')!r}")
    cand = r.get("Candidates")
    if not isinstance(cand, dict):
        bad("candidates_json", "Candidates", "Candidates is not a dict")
    else:
        keys = sorted(cand)
        if keys != list(LETTERS):
            bad("five_candidates", "Candidates", f"Candidates keys are {keys}, expected exactly A-E")
        for k, v in cand.items():
            if not isinstance(v, str) or not v.strip():
                bad("candidate_strings", f"Candidates.{k}", f"candidate {k} is {v!r}, not a non-empty string")
        if r.get("Answer") not in cand:
            bad("answer_in_candidates", "Answer", f"answer letter {r.get('Answer')!r} is not a candidate")
    if r.get("Answer") not in LETTERS:
        bad("answer_letter", "Answer", f"answer {r.get('Answer')!r} is not a letter A-E")
    ts, te = r.get("time_start"), r.get("time_end")
    try:
        ts_f, te_f = float(ts), float(te)
    except (TypeError, ValueError):
        bad("finite_times", "time_start", f"times are not numbers: {ts!r}, {te!r}")
    else:
        if not math.isfinite(ts_f):
            bad("finite_times", "time_start", f"time_start is {ts_f}")
        if not math.isfinite(te_f):
            bad("finite_times", "time_end", f"time_end is {te_f}")
        if math.isfinite(ts_f) and math.isfinite(te_f):
            if ts_f < 0:
                bad("time_order", "time_start", f"time_start {ts_f} is negative")
            if te_f < ts_f:
                bad("time_order", "time_end", f"time_end {te_f} < time_start {ts_f}")
    detail = r.get("Answer Detail")
    if not isinstance(detail, str) or not detail.strip():
        bad("answer_detail", "Answer Detail", f"Answer Detail is {detail!r}")
    return out


def _raise_first(problems: list[Problem], strict: bool) -> None:
    if strict and problems:
        raise problems[0].error()


# ----------------------------------------------------------------------------------------- legacy

def load_legacy(path: str | os.PathLike, *, strict: bool = True, tasks: Iterable[str] | None = None
                ) -> tuple[pd.DataFrame, list[Problem]]:
    """Read a legacy STI-Bench ``qa.parquet`` (or ``.jsonl``).

    Returns the rows in file order with ``Candidates`` as dicts, plus ``row`` (0-based index in the
    file) and ``Legacy Row Key``; and the list of problems (empty when strict, since strict raises).
    ``tasks``: keep only rows of these tasks (their ``row`` and keys are those of the whole file:
    identical rows always share a task, so the uid occurrence counter is unaffected).
    """
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", file=path)
    if path.suffix == ".parquet":
        try:
            df = pd.read_parquet(path)
        except Exception as e:  # pyarrow raises several types for a damaged file
            raise InputError(f"cannot read parquet ({e})", file=path) from None
        cols = list(df.columns)
        index = np.arange(len(df))
        if tasks is not None and "Task" in df.columns:
            keep = df["Task"].isin(list(tasks)).to_numpy()
            df, index = df[keep], index[keep]
        records = df.to_dict("records")
    else:
        records = _read_jsonl(path)
        cols = sorted({k for r in records for k in r}) if records else []
        index = np.arange(len(records))
        if tasks is not None:
            wanted = set(tasks)
            pairs = [(i, r) for i, r in zip(index, records) if r.get("Task") in wanted]
            index = np.array([i for i, _ in pairs], dtype=int)
            records = [r for _, r in pairs]
    missing = [c for c in LEGACY_COLUMNS if c not in cols]
    if missing:
        raise InputError(f"missing column(s) {missing}", file=path, field=missing[0])
    problems: list[Problem] = []
    for i, r in zip(index.tolist(), records):
        try:
            r["Candidates"] = _candidates(r.get("Candidates"), file=path, row=i)
        except InputError as e:
            if strict:
                raise
            problems.append(Problem("candidates_json", i, "Candidates", e.message, str(path)))
        for k in ("time_start", "time_end"):
            try:
                r[k] = float(r[k])
            except (TypeError, ValueError):
                pass
        if isinstance(r.get("ID"), float) and r["ID"].is_integer():
            r["ID"] = int(r["ID"])
        problems += validate_row(r, file=path, row=i)
        _raise_first(problems, strict)
    keys = legacy_row_keys(records)
    out = pd.DataFrame.from_records(records, columns=list(cols))
    out["row"] = index
    out["Legacy Row Key"] = keys
    return out, problems


# ---------------------------------------------------------------------------------------- release

def _read_jsonl(path: Path) -> list[dict]:
    rows = []
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, start=1):
            if not line.strip():
                continue
            try:
                obj = json.loads(line)
            except json.JSONDecodeError as e:
                raise InputError(f"line {n} is not valid JSON ({e.msg} at char {e.pos}); "
                                 "truncated or damaged file?", file=path, row=f"line {n}") from None
            if not isinstance(obj, dict):
                raise InputError(f"line {n} is not a JSON object", file=path, row=f"line {n}")
            rows.append(obj)
    return rows


def _row_id(r: dict, i: int) -> Any:
    return r.get("ReSTI ID") or r.get("Legacy Row Key") or i


def validate_release_rows(records: list[dict], file: Path | None) -> list[Problem]:
    """Schema problems of accepted release rows (per row) and duplicate ids (across rows)."""
    problems: list[Problem] = []
    for i, r in enumerate(records):
        rid = _row_id(r, i)
        missing = [c for c in RELEASE_COLUMNS if c not in r]
        if missing:
            problems.append(Problem("columns", rid, missing[0], f"missing field(s) {missing}",
                                    str(file) if file else None))
        problems += validate_row(r, file=file, row=rid)
    for col in ("ReSTI ID", "Legacy Row Key"):
        counts = Counter(r.get(col) for r in records if r.get(col) is not None)
        for v, n in counts.items():
            if n > 1:
                problems.append(Problem("unique_ids", v, col, f"{col} {v!r} appears {n} times",
                                        str(file) if file else None))
    return problems


def validate_excluded(records: list[dict], file: Path | None) -> list[Problem]:
    problems: list[Problem] = []
    for i, r in enumerate(records):
        rid = r.get("key", i)
        missing = [c for c in EXCLUDED_REQUIRED if c not in r]
        if missing:
            problems.append(Problem("columns", rid, missing[0], f"exclusion record lacks {missing}",
                                    str(file) if file else None))
            continue
        if not isinstance(r["reason_codes"], list) or not r["reason_codes"]:
            problems.append(Problem("exclusion_reasons", rid, "reason_codes", "reason_codes is empty",
                                    str(file) if file else None))
        malformed = "malformed_row" in (r.get("reason_codes") or [])  # an unknown task/source is its reason
        if r.get("task") not in TASKS and not malformed:
            problems.append(Problem("known_task", rid, "task", f"unknown task {r.get('task')!r}",
                                    str(file) if file else None))
        if r.get("source") not in SOURCES and not malformed:
            problems.append(Problem("known_source", rid, "source", f"unknown source {r.get('source')!r}",
                                    str(file) if file else None))
    counts = Counter(r.get("key") for r in records)
    for v, n in counts.items():
        if n > 1:
            problems.append(Problem("unique_ids", v, "key", f"exclusion key {v!r} appears {n} times",
                                    str(file) if file else None))
    return problems


def _find(root: Path, names: Iterable[str]) -> Path | None:
    for n in names:
        for cand in (root / n, root / "annotations" / n):
            if cand.exists():
                return cand
    return None


def load_release(path: str | os.PathLike, *, strict: bool = True) -> Release:
    """Read a ReSTI-schema release: a folder (``resti.jsonl`` or ``resti.parquet``, ``excluded.jsonl``,
    optional ``release.json``) or a single accepted-rows file (``.jsonl`` / ``.parquet``)."""
    path = Path(path)
    if not path.exists():
        raise InputError("release not found", file=path)
    root = path if path.is_dir() else path.parent
    if path.is_dir():
        acc = _find(path, ("resti.jsonl", "resti.parquet"))
        if acc is None:
            raise InputError("no resti.jsonl or resti.parquet in the release folder", file=path)
    else:
        acc = path
    if acc.suffix == ".parquet":
        try:
            records = pd.read_parquet(acc).to_dict("records")
        except Exception as e:
            raise InputError(f"cannot read parquet ({e})", file=acc) from None
        for i, r in enumerate(records):
            r["Candidates"] = _candidates(r.get("Candidates"), file=acc, row=_row_id(r, i)) \
                if not isinstance(r.get("Candidates"), dict) else r["Candidates"]
            if isinstance(r["Candidates"], dict):  # parquet structs may carry None for absent letters
                r["Candidates"] = {k: v for k, v in r["Candidates"].items() if v is not None}
    else:
        records = _read_jsonl(acc)
        for i, r in enumerate(records):
            if not isinstance(r.get("Candidates"), dict):
                try:
                    r["Candidates"] = _candidates(r.get("Candidates"), file=acc, row=_row_id(r, i))
                except InputError:
                    if strict:
                        raise
    problems = validate_release_rows(records, acc)
    exc_file = _find(root, ("excluded.jsonl",)) if path.is_dir() else None
    excluded = _read_jsonl(exc_file) if exc_file else []
    problems += validate_excluded(excluded, exc_file)
    _raise_first(problems, strict)
    meta_file = _find(root, ("release.json",)) if path.is_dir() else None
    meta = json.loads(meta_file.read_text(encoding="utf-8")) if meta_file else None
    df = pd.DataFrame.from_records(records)
    return Release(accepted=df, excluded=excluded, meta=meta, root=root, accepted_file=acc,
                   excluded_file=exc_file, problems=problems)


# ---------------------------------------------------------------------------------------- writers

def jsonl_text(rows: Iterable[dict], *, sort_keys: bool = False) -> str:
    """One JSON object per line, UTF-8 text kept as is (the v5 encoding), trailing newline."""
    return "".join(json.dumps(r, ensure_ascii=False, sort_keys=sort_keys) + "\n" for r in rows)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write to a temporary file in the same folder, then rename over ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, paths.file_mode())  # mkstemp creates 0600; an output honours the umask
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_jsonl(rows: Iterable[dict], path: Path, *, sort_keys: bool = False) -> None:
    atomic_write_bytes(Path(path), jsonl_text(rows, sort_keys=sort_keys).encode("utf-8"))


def rows_to_parquet_bytes(rows: list[dict]) -> bytes:
    """Deterministic parquet of release rows (Candidates as a JSON string column, like the legacy)."""
    import io

    import pyarrow as pa
    import pyarrow.parquet as pq

    recs = [{**r, "Candidates": json.dumps(r["Candidates"], ensure_ascii=False)} for r in rows]
    cols = list(RELEASE_COLUMNS) + [c for c in (recs[0] if recs else {}) if c not in RELEASE_COLUMNS]
    table = pa.Table.from_pylist(recs, schema=None) if recs else pa.table({c: [] for c in cols})
    table = table.select([c for c in cols if c in table.column_names]).replace_schema_metadata(None)
    buf = io.BytesIO()
    pq.write_table(table, buf, compression="zstd", write_statistics=False, store_schema=False)
    return buf.getvalue()
