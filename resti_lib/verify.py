"""``resti verify``: structural validation of a ReSTI-schema release.

Release-level checks (release.json counts, sha256 of artifacts, unique ids, accepted/excluded
disjoint, optional coverage of a legacy benchmark) plus every row check registered in
:mod:`resti_lib.options.checks`. The result is one validation object (``--json``).
"""

from __future__ import annotations

import hashlib
import json
from collections import Counter
from pathlib import Path

from . import LETTERS, TASKS
from .io.benchmark import Problem, Release, load_release
from .options.checks import ROW_CHECKS, parse_row

MAX_LISTED = 200  # failing ids listed per check (the count is always complete)


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


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


def summarize(rel: Release) -> dict:
    acc = rel.accepted
    by_task = Counter(acc["Task"]) if len(acc) else Counter()
    by_source = Counter(acc["Source"]) if len(acc) else Counter()
    letters = Counter(acc["Answer"]) if len(acc) else Counter()
    exc_task = Counter(r.get("task") for r in rel.excluded)
    exc_source = Counter(r.get("source") for r in rel.excluded)
    task_order = {t: i for i, t in enumerate(TASKS)}
    return {
        "accepted_rows": int(len(acc)),
        "excluded_rows": int(len(rel.excluded)),
        "total_rows": int(len(acc) + len(rel.excluded)),
        "by_task": dict(sorted(by_task.items())),
        "by_source": dict(sorted(by_source.items())),
        "excluded_by_task": dict(sorted(exc_task.items(), key=lambda kv: task_order.get(kv[0], 99))),
        "excluded_by_source": dict(sorted(exc_source.items())),
        "answer_letters": {k: int(letters.get(k, 0)) for k in LETTERS},
        "by_task_source": {f"{t}|{s}": int(n) for (t, s), n in
                           sorted(Counter(zip(acc["Task"], acc["Source"])).items())} if len(acc) else {},
    }


def _check_release_json(rel: Release, summary: dict) -> dict:
    if rel.meta is None:
        return _status([], skipped="no release.json")
    meta = rel.meta
    want = {
        "counts.accepted": (meta.get("counts", {}).get("accepted"), summary["accepted_rows"]),
        "counts.excluded": (meta.get("counts", {}).get("excluded"), summary["excluded_rows"]),
        "counts.original": (meta.get("counts", {}).get("original"), summary["total_rows"]),
        "accepted_by_task": (meta.get("accepted_by_task"), summary["by_task"]),
        "accepted_by_source": (meta.get("accepted_by_source"), summary["by_source"]),
        "excluded_by_task": (meta.get("excluded_by_task"),
                             dict(sorted(summary["excluded_by_task"].items()))),
        "answer_letters": (meta.get("answer_letters"), summary["answer_letters"]),
    }
    failing, msgs = [], {}
    for name, (stated, computed) in want.items():
        if stated is None:
            continue
        if isinstance(stated, dict):
            stated = dict(sorted(stated.items()))
            computed = dict(sorted(computed.items()))
        if stated != computed:
            failing.append(name)
            msgs[name] = f"release.json {stated} != computed {computed}"
    return _status(failing, messages=msgs)


def _artifact_path(root: Path, name: str) -> Path | None:
    for cand in (root / name, root / Path(name).name, root / "annotations" / Path(name).name):
        if cand.exists():
            return cand
    return None


def _check_sha256(rel: Release) -> dict:
    root = rel.root
    entries: list[tuple[str, str, int | None]] = []
    if root is not None and (root / "SHA256SUMS").exists():
        for line in (root / "SHA256SUMS").read_text().splitlines():
            if line.strip():
                digest, name = line.split(None, 1)
                entries.append((name.strip().lstrip("*"), digest, None))
    if rel.meta:
        for name, art in (rel.meta.get("artifacts") or {}).items():
            if isinstance(art, dict) and art.get("sha256"):
                entries.append((name, art["sha256"], art.get("bytes")))
    if not entries:
        return _status([], skipped="no SHA256SUMS and no artifact digests")
    failing, msgs, checked, absent = [], {}, 0, []
    for name, digest, nbytes in entries:
        p = _artifact_path(root, name)
        if p is None:
            absent.append(name)
            continue
        checked += 1
        got = sha256_file(p)
        if got != digest:
            failing.append(name)
            msgs[name] = f"sha256 {got} != stated {digest}"
        elif nbytes is not None and p.stat().st_size != nbytes:
            failing.append(name)
            msgs[name] = f"{p.stat().st_size} bytes != stated {nbytes}"
    detail = f"{checked} digests checked"
    if absent:
        detail += f"; not present here (not checked): {sorted(set(absent))}"
    return _status(failing, detail=detail, messages=msgs)


def _check_unique(rel: Release) -> dict:
    failing = []
    for col in ("ReSTI ID", "Legacy Row Key"):
        if col in rel.accepted:
            c = Counter(rel.accepted[col])
            failing += [k for k, n in c.items() if n > 1]
    c = Counter(r.get("key") for r in rel.excluded)
    failing += [k for k, n in c.items() if n > 1]
    return _status(failing)


def _check_disjoint(rel: Release) -> dict:
    if "Legacy Row Key" not in rel.accepted:
        return _status([], skipped="no Legacy Row Key column")
    both = sorted(set(rel.accepted["Legacy Row Key"]) & {r.get("key") for r in rel.excluded})
    return _status(both)


def _check_coverage(rel: Release, legacy_keys: list[str] | None) -> dict:
    if legacy_keys is None:
        return _status([], skipped="no legacy benchmark given")
    have = set(rel.accepted.get("Legacy Row Key", [])) | {r.get("key") for r in rel.excluded}
    want = set(legacy_keys)
    missing = sorted(want - have)
    extra = sorted(have - want)
    return _status(missing + extra, detail=f"{len(missing)} legacy rows missing, {len(extra)} unknown keys")


def verify_release(rel: Release, *, legacy_keys: list[str] | None = None) -> dict:
    """Run every check; returns the validation object (``passed`` is True when no check fails)."""
    summary = summarize(rel)
    checks: dict[str, dict] = {}
    schema_fail: dict = {}
    for p in rel.problems:
        schema_fail.setdefault(p.check, {})[p.row] = f"{p.field}: {p.message}"
    checks["release_json"] = _check_release_json(rel, summary)
    checks["sha256"] = _check_sha256(rel)
    checks["unique_ids"] = _check_unique(rel)
    checks["accepted_excluded_disjoint"] = _check_disjoint(rel)
    checks["legacy_coverage"] = _check_coverage(rel, legacy_keys)
    for name in ("columns", "known_task", "known_source", "exclusion_reasons", "answer_letter",
                 "answer_in_candidates", "candidates_json"):
        fails = schema_fail.get(name, {})
        checks[name] = _status(list(fails), messages=fails)

    row_fail: dict[str, dict] = {name: {} for name in ROW_CHECKS}
    records = rel.accepted.to_dict("records")
    for i, r in enumerate(records):
        rid = r.get("ReSTI ID") or r.get("Legacy Row Key") or i
        pr = parse_row(r, rid)
        for name, fn in ROW_CHECKS.items():
            msg = fn(pr)
            if msg:
                row_fail[name][rid] = msg
    for name, fails in row_fail.items():
        checks[name] = _status(list(fails), messages=fails)
    out = dict(summary)
    out["checks"] = checks
    out["passed"] = all(c["status"] != "fail" for c in checks.values())
    return out


def verify_path(path: str | Path, *, legacy: str | Path | None = None) -> dict:
    """Load (non-strict, so every problem is reported) and verify a release folder or file."""
    rel = load_release(path, strict=False)
    keys = None
    if legacy is not None:
        from .io.benchmark import load_legacy

        df, _ = load_legacy(legacy, strict=False)
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
        lines.append(f"  {c['status'].upper():7s} {name}{extra}")
    lines.append("PASSED" if v["passed"] else "FAILED")
    return "\n".join(lines)


def problems_to_dict(problems: list[Problem]) -> list[dict]:
    return [{"check": p.check, "row": str(p.row), "field": p.field, "message": p.message} for p in problems]


def to_json(v: dict) -> str:
    return json.dumps(v, indent=2, ensure_ascii=False, sort_keys=False)
