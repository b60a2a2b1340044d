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
import numbers
import os
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Collection, Iterable

import numpy as np
import pandas as pd

from .. import LETTERS, SOURCES
from ..errors import InputError
from .files import open_regular, parse_json, read_json_object, read_jsonl

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
    meta_file: Path | None = None
    meta_error: str | None = None


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


def key_part(value) -> str:
    """A field as it stands in a Legacy Row Key: ``|`` written ``%7C`` (a malformed video name that
    holds one still gives a key of five parts, and its row is excluded by name)."""
    return str(value).replace("|", "%7C")


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
        keys.append(f"{r.get('Source')}|{r.get('Task')}|{key_part(r.get('Video'))}|{r.get('ID')}|uid={uid}")
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
        obj = parse_json(value, file=file, row=row, field="Candidates", what="Candidates")
        if not isinstance(obj, dict):
            raise InputError("Candidates JSON is not an object", file=file, row=row, field="Candidates")
        return obj
    if value is None or (isinstance(value, float) and math.isnan(value)):
        raise InputError("Candidates is null", file=file, row=row, field="Candidates")
    raise InputError(f"Candidates is a {type(value).__name__}", file=file, row=row, field="Candidates")


def validate_row(r: dict, *, file, row, known_tasks: Collection[str] | None = None) -> list[Problem]:
    """Structural problems of one legacy/release row (schema level; values are parsed elsewhere).
    ``known_tasks``: the tasks a row may name (the task registry, :func:`resti_lib.tasks.names`;
    None: not checked here)."""
    out: list[Problem] = []

    def bad(check, fld, msg):
        out.append(Problem(check, row, fld, msg, str(file) if file else None))

    if known_tasks is not None and r.get("Task") not in known_tasks:
        bad("known_task", "Task", f"unknown task {r.get('Task')!r}")
    if r.get("Source") not in SOURCES:
        bad("known_source", "Source", f"unknown source {r.get('Source')!r}")
    video = r.get("Video")
    if not isinstance(video, str) or not video.strip() or "|" in video or any(ord(c) < 32 for c in video):
        bad("video_name", "Video", f"Video {video!r} is not a file name (text without '|' or control characters)")
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
        if not isinstance(r.get("Answer"), str) or r.get("Answer") not in cand:
            bad("answer_in_candidates", "Answer", f"answer letter {r.get('Answer')!r} is not a candidate")
    if not isinstance(r.get("Answer"), str) or r.get("Answer") not in LETTERS:
        bad("answer_letter", "Answer", f"answer {r.get('Answer')!r} is not a letter A-E")
    ts, te = r.get("time_start"), r.get("time_end")
    try:
        if isinstance(ts, (bool, str)) or isinstance(te, (bool, str)):
            raise TypeError("times must be numbers")
        ts_f, te_f = float(ts), float(te)
    except (TypeError, ValueError, OverflowError):
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
    if not is_integer_id(r.get("ID")):
        bad("id_format", "ID", f"ID {r.get('ID')!r} is not an integer")
    return out


_INT_TEXT = re.compile(r"^[+-]?[0-9]+$")


def is_integer_id(value: Any) -> bool:
    """An integer ID: an int, an integral float, or the text of an integer (``3``, ``"3"``, ``3.0``)."""
    if isinstance(value, (bool, np.bool_)):
        return False
    if isinstance(value, numbers.Integral):
        return True
    if isinstance(value, (float, np.floating)):
        return math.isfinite(value) and float(value).is_integer()
    return isinstance(value, str) and bool(_INT_TEXT.match(value.strip()))


def _raise_first(problems: list[Problem], strict: bool) -> None:
    if strict and problems:
        raise problems[0].error()


# ----------------------------------------------------------------------------------------- legacy

def read_parquet_file(path: Path) -> pd.DataFrame:
    """A parquet file (a regular file: a folder of parquet parts or a device is refused)."""
    with open_regular(path) as f:
        try:
            return pd.read_parquet(f)
        except Exception as e:  # noqa: BLE001 -- pyarrow raises several types for a damaged file
            msg = " ".join(str(e).split())
            raise InputError(f"cannot read parquet ({msg})", file=path) from None


def load_legacy(path: str | os.PathLike, *, strict: bool = True, tasks: Iterable[str] | None = None,
                known_tasks: Collection[str] | None = None) -> tuple[pd.DataFrame, list[Problem]]:
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
        df = read_parquet_file(path)
        cols = list(df.columns)
        if len(df) == 0:
            raise InputError("the legacy benchmark has no rows (empty file)", file=path)
        index = np.arange(len(df))
        if tasks is not None and "Task" in df.columns:
            keep = df["Task"].isin(list(tasks)).to_numpy()
            df, index = df[keep], index[keep]
        records = df.to_dict("records")
    else:
        records = read_jsonl(path)
        if not records:
            raise InputError("the legacy benchmark has no rows (empty file)", file=path)
        cols = sorted({k for r in records for k in r})
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
        problems += validate_row(r, file=path, row=i, known_tasks=known_tasks)
        _raise_first(problems, strict)
    keys = legacy_row_keys(records)
    out = pd.DataFrame.from_records(records, columns=list(cols))
    out["row"] = index
    out["Legacy Row Key"] = keys
    return out, problems


# ---------------------------------------------------------------------------------------- release

def _row_id(r: dict, i: int) -> Any:
    for col in ("ReSTI ID", "Legacy Row Key"):
        v = r.get(col)
        if isinstance(v, str) and v.strip():
            return v
    return i


_KEY_RE = re.compile(r"^(?P<source>[^|]*)\|(?P<task>[^|]*)\|(?P<video>[^|]*)\|(?P<id>[^|]*)\|uid=[0-9a-f]{16}$")


def key_problem(key: Any, *, source: Any, task: Any, video: Any, legacy_id: Any) -> str | None:
    """Why ``key`` is not the Legacy Row Key of a row with these fields (``None`` when it is).

    A key is ``Source|Task|Video|ID|uid=<16 lowercase hex>`` (:func:`legacy_row_keys`) and its
    first four parts are the row's own fields.
    """
    if not isinstance(key, str):
        return f"Legacy Row Key is {key!r}, not text"
    m = _KEY_RE.match(key)
    if m is None:
        return f"Legacy Row Key {key!r} is not Source|Task|Video|ID|uid=<16 hex>"
    stated = {"Source": source, "Task": task, "Video": key_part(video), "ID": legacy_id}
    parts = {"Source": m["source"], "Task": m["task"], "Video": m["video"], "ID": m["id"]}
    wrong = [k for k in stated if parts[k] != str(stated[k])]
    if wrong:
        return (f"Legacy Row Key {key!r} names {', '.join(f'{k} {parts[k]!r}' for k in wrong)} but the row has "
                f"{', '.join(f'{k} {stated[k]!r}' for k in wrong)}")
    return None


def validate_release_rows(records: list[dict], file: Path | None, known_tasks: Collection[str] | None = None
                          ) -> list[Problem]:
    """Schema problems of accepted release rows (per row) and duplicate ids (across rows)."""
    problems: list[Problem] = []
    fname = str(file) if file else None
    for i, r in enumerate(records):
        rid = _row_id(r, i)
        missing = [c for c in RELEASE_COLUMNS if c not in r]
        if missing:
            problems.append(Problem("columns", rid, missing[0], f"missing field(s) {missing}", fname))
        problems += validate_row(r, file=file, row=rid, known_tasks=known_tasks)
        for col in ("ReSTI ID", "Legacy Row Key"):
            v = r.get(col)
            if col in r and not (isinstance(v, str) and v.strip()):
                problems.append(Problem("row_ids", rid, col, f"{col} is {v!r}, not a non-empty text", fname))
        if isinstance(r.get("Legacy Row Key"), str) and r["Legacy Row Key"].strip():
            msg = key_problem(r["Legacy Row Key"], source=r.get("Source"), task=r.get("Task"),
                              video=r.get("Video"), legacy_id=r.get("ID"))
            if msg:
                problems.append(Problem("legacy_key_format", rid, "Legacy Row Key", msg, fname))
    for col in ("ReSTI ID", "Legacy Row Key"):
        counts = Counter(r.get(col) for r in records if isinstance(r.get(col), str))
        for v, n in counts.items():
            if n > 1:
                problems.append(Problem("unique_ids", v, col, f"{col} {v!r} appears {n} times", fname))
    return problems


def validate_excluded(records: list[dict], file: Path | None, known_tasks: Collection[str] | None = None
                      ) -> list[Problem]:
    problems: list[Problem] = []
    fname = str(file) if file else None
    for i, r in enumerate(records):
        rid = r["key"] if isinstance(r.get("key"), str) and r["key"].strip() else i
        missing = [c for c in EXCLUDED_REQUIRED if c not in r]
        if missing:
            problems.append(Problem("columns", rid, missing[0], f"exclusion record lacks {missing}", fname))
            continue
        if not (isinstance(r["key"], str) and r["key"].strip()):
            problems.append(Problem("row_ids", rid, "key", f"key is {r['key']!r}, not a non-empty text", fname))
        else:
            msg = key_problem(r["key"], source=r.get("source"), task=r.get("task"), video=r.get("legacy_video"),
                              legacy_id=r.get("legacy_id"))
            if msg:
                problems.append(Problem("legacy_key_format", rid, "key", msg, fname))
        if not isinstance(r["reason_codes"], list) or not r["reason_codes"]:
            problems.append(Problem("exclusion_reasons", rid, "reason_codes", "reason_codes is empty",
                                    str(file) if file else None))
        malformed = "malformed_row" in (r.get("reason_codes") or [])  # an unknown task/source is its reason
        if known_tasks is not None and r.get("task") not in known_tasks and not malformed:
            problems.append(Problem("known_task", rid, "task", f"unknown task {r.get('task')!r}",
                                    str(file) if file else None))
        if r.get("source") not in SOURCES and not malformed:
            problems.append(Problem("known_source", rid, "source", f"unknown source {r.get('source')!r}",
                                    str(file) if file else None))
    counts = Counter(r.get("key") for r in records if isinstance(r.get("key"), str))
    for v, n in counts.items():
        if n > 1:
            problems.append(Problem("unique_ids", v, "key", f"exclusion key {v!r} appears {n} times",
                                    str(file) if file else None))
    return problems


def _find(root: Path, names: Iterable[str]) -> Path | None:
    for n in names:
        for cand in (root / n, root / "annotations" / n):
            if cand.exists() or cand.is_symlink():
                return cand
    return None


def _read_meta(meta_file: Path, strict: bool) -> tuple[dict | None, str | None]:
    """``release.json`` as an object, or (non-strict) ``None`` and why it cannot be used."""
    try:
        meta = read_json_object(meta_file)
    except InputError as e:
        if strict:
            raise
        return None, e.message
    counts = meta.get("counts")
    if strict and counts is not None and not isinstance(counts, dict):
        raise InputError(f"counts is a JSON {type(counts).__name__}, not an object", file=meta_file,
                         field="counts")
    return meta, None


def read_release_rows(path: Path) -> list[dict]:
    """The accepted rows of one row file (``.jsonl`` or ``.parquet``), Candidates as mappings."""
    return _accepted_records(Path(path), strict=False)


def _accepted_records(acc: Path, strict: bool) -> list[dict]:
    if acc.suffix == ".parquet":
        records = read_parquet_file(acc).to_dict("records")
    else:
        records = read_jsonl(acc)
    for i, r in enumerate(records):
        if isinstance(r.get("Candidates"), dict):
            if acc.suffix == ".parquet":  # parquet structs may carry None for absent letters
                r["Candidates"] = {k: v for k, v in r["Candidates"].items() if v is not None}
            continue
        try:
            r["Candidates"] = _candidates(r.get("Candidates"), file=acc, row=_row_id(r, i))
        except InputError:
            if strict:
                raise
    return records


def load_release(path: str | os.PathLike, *, strict: bool = True, known_tasks: Collection[str] | None = None
                 ) -> Release:
    """Read a ReSTI-schema release: a folder (``resti.jsonl`` or ``resti.parquet``, ``excluded.jsonl``,
    optional ``release.json``) or a single accepted-rows file (``.jsonl`` / ``.parquet``).

    Files that cannot be read at all (not UTF-8, not a regular file, a line that is not a JSON
    object) raise :class:`InputError`. Row problems raise when ``strict``; otherwise they are
    returned in :attr:`Release.problems` (``resti verify`` reports them per check). A ``release.json``
    that is not a JSON object is, when not strict, reported in :attr:`Release.meta_error`.
    ``known_tasks``: the tasks a row may name (the task registry; None: not checked).
    """
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
    records = _accepted_records(acc, strict)
    problems = validate_release_rows(records, acc, known_tasks)
    exc_file = _find(root, ("excluded.jsonl",)) if path.is_dir() else None
    excluded = read_jsonl(exc_file) if exc_file else []
    problems += validate_excluded(excluded, exc_file, known_tasks)
    _raise_first(problems, strict)
    meta_file = _find(root, ("release.json",)) if path.is_dir() else None
    meta, meta_error = _read_meta(meta_file, strict) if meta_file else (None, None)
    df = pd.DataFrame.from_records(records)
    return Release(accepted=df, excluded=excluded, meta=meta, root=root, accepted_file=acc,
                   excluded_file=exc_file, problems=problems, meta_file=meta_file, meta_error=meta_error)


# ---------------------------------------------------------------------------------------- writers

def jsonl_text(rows: Iterable[dict], *, sort_keys: bool = False) -> str:
    """One JSON object per line, UTF-8 text kept as is (the v5 encoding), trailing newline."""
    return "".join(json.dumps(r, ensure_ascii=False, sort_keys=sort_keys) + "\n" for r in rows)


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
