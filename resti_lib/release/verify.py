"""``resti verify``: structural validation of a ReSTI-schema release.

Release-level checks (release.json counts, sha256 of artifacts, unique ids, accepted/excluded
disjoint, a release that is not empty, optional coverage of a legacy benchmark) plus every row
check registered in :mod:`resti_lib.options.checks` and every schema problem found while reading
(null ids, malformed Legacy Row Keys, ...). The result is one validation object (``--json``).

Each check is ``pass``, ``fail`` or ``skipped`` (not checked, with the reason). Nothing that was
not compared is reported as passing: a ``release.json`` without counts fails; a ``SHA256SUMS`` entry
naming an absent file fails; an artifact of ``release.json`` absent from the folder is listed as
not checked. ``SHA256SUMS`` entries are confined to the release folder and only regular files are
opened (an entry with ``..``, an absolute path, a folder or a device fails unread).
"""

from __future__ import annotations

import json
import os
import re
import stat
from collections import Counter
from pathlib import Path

from .. import LETTERS
from .. import tasks as task_registry
from ..errors import InputError
from ..io.benchmark import Release, load_release
from ..io.files import decode_text, file_kind, read_bytes, sha256_file
from ..options.checks import ROW_CHECKS, parse_row
from ..options.spec import Interface, deep_merge

MAX_LISTED = 200  # failing ids listed per check (the count is always complete)


def _status(failing: list, skipped: str | None = None, detail: str | None = None,
            messages: dict | None = None) -> dict:
    if skipped:
        return {"status": "skipped", "reason": skipped, "n_failing": 0, "failing": []}
    out = {"status": "fail" if failing else "pass", "n_failing": len(failing),
           "failing": [str(x) for x in failing[:MAX_LISTED]]}
    if detail:
        out["detail"] = detail
    if messages:
        out["messages"] = {str(k): v for k, v in list(messages.items())[:MAX_LISTED]}
    return out


def _column(acc, name: str) -> list:
    return list(acc[name]) if name in acc else [None] * len(acc)


def _hashable(v):
    return v if isinstance(v, (str, int, float, type(None))) else repr(v)


def summarize(rel: Release) -> dict:
    acc = rel.accepted
    tasks = [_hashable(t) for t in _column(acc, "Task")]
    sources = [_hashable(x) for x in _column(acc, "Source")]
    by_task = Counter(tasks)
    by_source = Counter(sources)
    letters = Counter(_hashable(a) for a in _column(acc, "Answer"))
    exc_task = Counter(_hashable(r.get("task")) for r in rel.excluded)
    exc_source = Counter(_hashable(r.get("source")) for r in rel.excluded)
    task_order = {t: i for i, t in enumerate(task_registry.names())}

    def ordered(c: Counter) -> dict:
        return dict(sorted(c.items(), key=lambda kv: str(kv[0])))

    return {
        "accepted_rows": int(len(acc)),
        "excluded_rows": int(len(rel.excluded)),
        "total_rows": int(len(acc) + len(rel.excluded)),
        "by_task": ordered(by_task),
        "by_source": ordered(by_source),
        "excluded_by_task": dict(sorted(exc_task.items(), key=lambda kv: (task_order.get(kv[0], 99), str(kv[0])))),
        "excluded_by_source": ordered(exc_source),
        "answer_letters": {k: int(letters.get(k, 0)) for k in LETTERS},
        "by_task_source": {f"{t}|{s}": int(n) for (t, s), n in
                           sorted(Counter(zip(tasks, sources)).items(), key=lambda kv: str(kv[0]))},
    }


def _is_count(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0


def _check_release_json(rel: Release, summary: dict) -> dict:
    if rel.meta_error is not None:
        return _status(["release.json"], messages={"release.json": rel.meta_error})
    if rel.meta is None:
        return _status([], skipped="no release.json: counts not checked")
    meta = rel.meta
    counts = meta.get("counts")
    if not isinstance(counts, dict):
        why = "has no counts" if counts is None else f"counts is a JSON {type(counts).__name__}, not an object"
        return _status(["counts"], messages={"counts": f"release.json {why}: nothing could be compared"})
    failing, msgs = [], {}
    for k in ("accepted", "excluded"):
        if not _is_count(counts.get(k)):
            failing.append(f"counts.{k}")
            msgs[f"counts.{k}"] = f"release.json counts.{k} is {counts.get(k)!r}, not a row count"
    want = {
        "counts.accepted": (counts.get("accepted"), summary["accepted_rows"]),
        "counts.excluded": (counts.get("excluded"), summary["excluded_rows"]),
        "counts.original": (counts.get("original"), summary["total_rows"]),
        "accepted_by_task": (meta.get("accepted_by_task"), summary["by_task"]),
        "accepted_by_source": (meta.get("accepted_by_source"), summary["by_source"]),
        "excluded_by_task": (meta.get("excluded_by_task"),
                             dict(sorted(summary["excluded_by_task"].items(), key=lambda kv: str(kv[0])))),
        "answer_letters": (meta.get("answer_letters"), summary["answer_letters"]),
    }
    for name, (stated, computed) in want.items():
        if stated is None or name in failing:
            continue
        if isinstance(stated, dict):
            stated = dict(sorted(stated.items(), key=lambda kv: str(kv[0])))
            computed = dict(sorted(computed.items(), key=lambda kv: str(kv[0])))
        if stated != computed:
            failing.append(name)
            msgs[name] = f"release.json {stated} != computed {computed}"
    return _status(failing, messages=msgs)


_HEX64 = re.compile(r"^[0-9a-fA-F]{64}$")


def _confined(root: Path, name: str) -> tuple[Path | None, str | None]:
    """The regular file ``name`` inside ``root`` (``None`` and why when it is not one).

    Absolute names, ``..`` parts and anything that resolves outside ``root`` are refused before
    the file system is touched further; a folder, device, FIFO or socket is refused unopened.
    """
    if not name or name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", name):
        return None, "absolute or empty path (outside the release folder)"
    parts = Path(name).parts
    if ".." in parts or "\\" in name:
        return None, "path leaves the release folder ('..')"
    p = root / name
    try:
        real = Path(os.path.realpath(p))
        if os.path.commonpath([real, os.path.realpath(root)]) != os.path.realpath(root):
            return None, "resolves outside the release folder"
        st = os.stat(p)
    except FileNotFoundError:
        return None, "absent"
    except OSError as e:
        return None, f"cannot be read ({e.strerror})"
    if not stat.S_ISREG(st.st_mode):
        return None, f"is {file_kind(st.st_mode)}, not a regular file (not opened)"
    return p, None


def _artifact_path(root: Path, name: str) -> tuple[Path | None, str | None]:
    """``release.json`` artifact names may carry the original sub-folder (``annotations/x``)."""
    why = None
    for cand in dict.fromkeys((name, Path(name).name, f"annotations/{Path(name).name}")):
        p, why_c = _confined(root, cand)
        if p is not None:
            return p, None
        if why_c != "absent":
            return None, why_c
        why = why_c
    return None, why


def _sha256sums(root: Path) -> tuple[list[tuple[str, str]], dict]:
    """Entries (name, digest) of ``SHA256SUMS`` and the problems of its malformed lines."""
    entries, bad = [], {}
    f = root / "SHA256SUMS"
    try:
        text = decode_text(read_bytes(f), file=f)
    except InputError as e:
        return [], {"SHA256SUMS": e.message}
    for n, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        parts = line.strip().split(None, 1)
        if len(parts) != 2 or not _HEX64.match(parts[0]) or not parts[1].strip().lstrip("*"):
            bad[f"SHA256SUMS line {n}"] = f"not '<64 hex digits>  <file name>': {line[:80]!r}"
            continue
        entries.append((parts[1].strip().lstrip("*"), parts[0].lower()))
    return entries, bad


def _check_sha256(rel: Release) -> dict:
    root = rel.root
    failing, msgs = [], {}
    sums: list[tuple[str, str, int | None, str]] = []  # name, digest, bytes, origin
    has_sums = root is not None and os.path.lexists(root / "SHA256SUMS")
    if has_sums:
        entries, bad = _sha256sums(root)
        failing += list(bad)
        msgs.update(bad)
        sums += [(name, digest, None, "SHA256SUMS") for name, digest in entries]
    if isinstance(rel.meta, dict) and isinstance(rel.meta.get("artifacts"), dict):
        for name, art in rel.meta["artifacts"].items():
            if isinstance(art, dict) and isinstance(art.get("sha256"), str):
                nbytes = art.get("bytes") if _is_count(art.get("bytes")) else None
                sums.append((str(name), art["sha256"].lower(), nbytes, "release.json"))
    if not sums and not failing:
        return _status([], skipped="no SHA256SUMS and no artifact digests: not checked")
    checked, absent, covered = 0, [], set()
    for name, digest, nbytes, origin in sums:
        p, why = _confined(root, name) if origin == "SHA256SUMS" else _artifact_path(root, name)
        label = f"{origin}: {name}"
        if p is None:
            if why == "absent" and origin == "release.json":
                absent.append(name)  # a release may ship a subset of its listed artifacts
                continue
            failing.append(name)
            msgs[label] = f"{name} {why}" if why != "absent" else f"{name} is named but absent"
            continue
        checked += 1
        covered.add(os.path.realpath(p))
        got = sha256_file(p)
        if got != digest:
            failing.append(name)
            msgs[label] = f"sha256 {got} != stated {digest}"
        elif nbytes is not None and p.stat().st_size != nbytes:
            failing.append(name)
            msgs[label] = f"{p.stat().st_size} bytes != stated {nbytes}"
    for f in (rel.accepted_file, rel.excluded_file):
        if f is not None and root is not None and f.parent in (root, root / "annotations") \
                and os.path.realpath(f) not in covered and f.name not in failing:
            failing.append(f.name)
            msgs[f"not covered: {f.name}"] = f"{f.name} is read but no digest covers it"
    detail = f"{checked} digests checked"
    if absent:
        detail += f"; artifacts of release.json not present here (not checked): {sorted(set(absent))}"
    return _status(list(dict.fromkeys(failing)), detail=detail, messages=msgs)


def _check_non_empty(rel: Release) -> dict:
    if len(rel.accepted) == 0:
        return _status(["resti"], messages={"resti": f"{rel.accepted_file} has no accepted rows"})
    return _status([])


def _canonical(row: dict) -> str:
    """A row as comparable text (numbers as JSON numbers, Candidates as a mapping)."""
    def plain(v):
        if hasattr(v, "item") and not isinstance(v, (str, bytes)):
            v = v.item()
        if isinstance(v, dict):
            return {str(k): plain(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return v

    return json.dumps(plain(row), sort_keys=True, ensure_ascii=False)


def _check_row_files_agree(rel: Release) -> dict:
    """``resti.jsonl`` and ``resti.parquet``, when both ship, hold the same rows in the same order."""
    from ..io.benchmark import read_release_rows

    root = rel.root
    if root is None or not (root / "resti.jsonl").is_file() or not (root / "resti.parquet").is_file():
        return _status([], skipped="one row file (resti.jsonl or resti.parquet) only")
    try:
        a = read_release_rows(root / "resti.jsonl")
        b = read_release_rows(root / "resti.parquet")
    except InputError as e:
        return _status(["row_files"], messages={"row_files": e.one_line()})
    failing, msgs = [], {}
    if len(a) != len(b):
        failing.append("count")
        msgs["count"] = f"resti.jsonl has {len(a)} rows, resti.parquet {len(b)}"
    for i, (x, y) in enumerate(zip(a, b)):
        if _canonical(x) != _canonical(y):
            rid = x.get("ReSTI ID") or y.get("ReSTI ID") or i
            diff = sorted(k for k in set(x) | set(y) if _canonical({k: x.get(k)}) != _canonical({k: y.get(k)}))
            failing.append(str(rid))
            msgs[str(rid)] = f"row {i} differs between resti.jsonl and resti.parquet in {', '.join(diff)}"
    return _status(failing, messages=msgs)


def _ids(values) -> list[str]:
    return [v for v in values if isinstance(v, str)]


def _check_unique(rel: Release) -> dict:
    failing = []
    for col in ("ReSTI ID", "Legacy Row Key"):
        if col in rel.accepted:
            c = Counter(_ids(rel.accepted[col]))
            failing += [k for k, n in c.items() if n > 1]
    c = Counter(_ids(r.get("key") for r in rel.excluded))
    failing += [k for k, n in c.items() if n > 1]
    return _status(failing)


def _check_disjoint(rel: Release) -> dict:
    if "Legacy Row Key" not in rel.accepted:
        return _status([], skipped="no Legacy Row Key column: not checked")
    both = sorted(set(_ids(rel.accepted["Legacy Row Key"])) & set(_ids(r.get("key") for r in rel.excluded)))
    return _status(both)


def _check_coverage(rel: Release, legacy_keys: list[str] | None) -> dict:
    if legacy_keys is None:
        return _status([], skipped="no legacy benchmark given")
    have = set(_ids(rel.accepted.get("Legacy Row Key", []))) | set(_ids(r.get("key") for r in rel.excluded))
    want = set(legacy_keys)
    missing = sorted(want - have)
    extra = sorted(have - want)
    return _status(missing + extra, detail=f"{len(missing)} legacy rows missing, {len(extra)} unknown keys")


# Schema problems found while reading, reported under their own check names (those that are also
# row checks are merged into the row check of the same name).
SCHEMA_CHECKS = ("columns", "row_ids", "legacy_key_format", "id_format", "known_task", "known_source", "video_name",
                 "exclusion_reasons", "answer_letter", "answer_in_candidates", "candidates_json",
                 "candidate_strings", "answer_detail", "finite_times")


def integrity_checks(rel: Release) -> dict:
    """The release-level checks that detect damage to a release as a whole (counts against
    ``release.json``, digests, an empty release, duplicated ids)."""
    return {"release_json": _check_release_json(rel, summarize(rel)), "sha256": _check_sha256(rel),
            "row_files_agree": _check_row_files_agree(rel), "non_empty": _check_non_empty(rel),
            "unique_ids": _check_unique(rel)}


def release_interface(rel: Release, *, options: dict | None = None):
    """The answer interface a release's options are checked against: the option params and task
    rules recorded under ``answer_interface`` in its ``release.json`` (what they were built with),
    else this version's defaults (``params/options.yaml`` and each registered task's params), with
    the question reader of each registered task; ``options``: overrides on top. Returns
    ``(interface, where)``, ``where`` saying which."""
    meta = rel.meta if isinstance(rel.meta, dict) else {}
    record = meta.get("answer_interface")
    iface = task_registry.interface().with_record(record, file=rel.root / "release.json" if rel.root else None)
    if options:
        iface = Interface(deep_merge(iface.options, options), iface.tasks)
    where = "release.json answer_interface" if record is not None else \
        "defaults of this resti version (release.json records no answer_interface)"
    return iface, where


def verify_release(rel: Release, *, legacy_keys: list[str] | None = None, iface=None) -> dict:
    """Run every check; returns the validation object (``passed`` is True when no check fails;
    ``not_checked`` lists the checks that could not run, with the reason). The answer-interface
    checks read ``iface`` (default: :func:`release_interface`, what the release records)."""
    where = "given"
    if iface is None:
        iface, where = release_interface(rel)
    summary = summarize(rel)
    checks: dict[str, dict] = {}
    schema_fail: dict = {}
    for p in rel.problems:
        if p.check == "unique_ids":
            continue  # recomputed by _check_unique over accepted and excluded rows together
        schema_fail.setdefault(p.check, {})[_hashable(p.row)] = f"{p.field}: {p.message}"
    checks["release_json"] = _check_release_json(rel, summary)
    checks["sha256"] = _check_sha256(rel)
    checks["row_files_agree"] = _check_row_files_agree(rel)
    checks["non_empty"] = _check_non_empty(rel)
    checks["unique_ids"] = _check_unique(rel)
    checks["accepted_excluded_disjoint"] = _check_disjoint(rel)
    checks["legacy_coverage"] = _check_coverage(rel, legacy_keys)
    names = list(SCHEMA_CHECKS) + sorted(set(schema_fail) - set(SCHEMA_CHECKS) - set(ROW_CHECKS))
    for name in names:
        fails = schema_fail.get(name, {})
        checks[name] = _status(list(fails), messages=fails)

    row_fail: dict[str, dict] = {name: dict(schema_fail.get(name, {})) for name in ROW_CHECKS}
    records = rel.accepted.to_dict("records")
    for i, r in enumerate(records):
        rid = next((r[c] for c in ("ReSTI ID", "Legacy Row Key") if isinstance(r.get(c), str) and r[c].strip()), i)
        pr = parse_row(r, rid, iface)
        for name, fn in ROW_CHECKS.items():
            msg = fn(pr)
            if msg:
                row_fail[name][rid] = msg
    for name, fails in row_fail.items():
        checks[name] = _status(list(fails), messages=fails)
    out = dict(summary)
    out["answer_interface"] = where
    out["checks"] = checks
    out["passed"] = all(c["status"] != "fail" for c in checks.values())
    return out


def verify_path(path: str | Path, *, legacy: str | Path | None = None) -> dict:
    """Load (non-strict, so every problem is reported) and verify a release folder or file."""
    rel = load_release(path, strict=False, known_tasks=task_registry.names())
    keys = None
    if legacy is not None:
        from ..io.benchmark import load_legacy

        df, _ = load_legacy(legacy, strict=False, known_tasks=task_registry.names())
        keys = list(df["Legacy Row Key"])
    return verify_release(rel, legacy_keys=keys)


def format_text(v: dict) -> str:
    lines = [f"accepted {v['accepted_rows']}, excluded {v['excluded_rows']}, total {v['total_rows']}",
             "by task: " + ", ".join(f"{k} {n}" for k, n in v["by_task"].items()),
             "by source: " + ", ".join(f"{k} {n}" for k, n in v["by_source"].items()),
             "answer letters: " + " ".join(f"{k}={n}" for k, n in v["answer_letters"].items()),
             "checks:"]
    for name, c in v["checks"].items():
        extra = ""
        if c["status"] == "fail":
            extra = f" ({c['n_failing']} failing: {', '.join(c['failing'][:5])}" + \
                    (" ..." if c["n_failing"] > 5 else "") + ")"
        elif c["status"] == "skipped":
            extra = f" ({c['reason']})"
        elif c.get("detail"):
            extra = f" ({c['detail']})"
        status = "NOT CHECKED" if c["status"] == "skipped" else c["status"].upper()
        lines.append(f"  {status:11s} {name}{extra}")
    skipped = [n for n, c in v["checks"].items() if c["status"] == "skipped"]
    verdict = "PASSED" if v["passed"] else "FAILED"
    if skipped:
        verdict += f" (not checked: {', '.join(skipped)})"
    lines.append(verdict)
    return "\n".join(lines)


def to_json(v: dict) -> str:
    return json.dumps(v, indent=2, ensure_ascii=False, sort_keys=False)
