"""Assemble the task outputs into one release, check the invariants, write it atomically.

Files (``outputs/release/``): ``resti.jsonl`` and ``resti.parquet`` (identical rows, ReSTI v5 fields),
``excluded.jsonl``, ``provenance.parquet`` (every legacy row: contract, source files, frames,
transform chain, verdict, evidence), ``validation.json`` (``resti verify``), ``release.json``
(counts, exclusions by task, answer letters, bytes and sha256 of every artifact) and ``SHA256SUMS``.

Invariants, checked on every run (an :class:`InvariantError` stops the run, nothing is written):
accepted + excluded == legacy rows; every legacy key exactly once; ids unique; verify passes.
The files are written by the one release writer (:class:`ReleaseStage` over
:func:`resti_lib.release.publish.publishing`), also used by ``resti reoption``: a staging folder beside the
target, swapped in when complete, so a crash leaves the previous release intact; a target that is
not a resti output (or is an input) is refused. No timestamps are written: reruns are byte-identical.
"""

from __future__ import annotations

import io
import json
import os
from collections import Counter
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pandas as pd

from .. import LETTERS, __version__
from ..errors import InvariantError
from ..io.benchmark import jsonl_text, load_legacy, load_release, rows_to_parquet_bytes
from ..io.files import atomic_write_bytes, read_json_object, read_jsonl, sha256_bytes, write_json_bytes
from ..tasks import all_tasks, names
from ..tasks.base import slug
from .publish import publishing
from .verify import verify_release

__all__ = ["InvariantError", "ReleaseStage", "assemble", "check_invariants", "collect", "release_stage",
           "write_release"]


def _read_jsonl(path: Path) -> list[dict]:
    return read_jsonl(path) if path.exists() else []


def collect(tasks_dir: Path, legacy: pd.DataFrame) -> tuple[list[dict], list[dict], pd.DataFrame, dict]:
    """Read every registered task's outputs: accepted rows, exclusions, provenance and the answer
    interface its options were built with (merged into one ``answer_interface`` record for
    ``release.json``; the tasks of one release share one set of option params). Legacy rows of a
    task that no registered task audits become exclusions (``malformed_row``)."""
    accepted, excluded, prov = [], [], []
    record: dict = {"options": None, "rules": {}}
    present = set(legacy["Task"])
    for task in all_tasks():
        if task.name not in present:
            continue
        d = tasks_dir / slug(task.name)
        if not (d / "accepted.jsonl").exists():
            raise InvariantError(f"no outputs for task {task.name!r} in {d}: run its notebook first")
        accepted += _read_jsonl(d / "accepted.jsonl")
        excluded += _read_jsonl(d / "excluded.jsonl")
        prov.append(pd.read_parquet(d / "provenance.parquet"))
        _merge_interface(record, d / "interface.json", task.name)
    known = set(names())
    for r in legacy[~legacy["Task"].isin(known)].to_dict("records"):
        excluded.append({"key": r["Legacy Row Key"], "legacy_id": r.get("ID"), "legacy_video": r.get("Video"),
                         "source": r.get("Source"), "task": r.get("Task"), "reason_codes": ["malformed_row"],
                         "verification_verdict": "excluded_malformed_row",
                         "verification_evidence": {"field": "Task", "problem": f"unknown task {r.get('Task')!r}"}})
        prov.append(pd.DataFrame([{"row": int(r["row"]), "key": r["Legacy Row Key"], "resti_id": None,
                                   "task": str(r.get("Task")), "source": str(r.get("Source")),
                                   "video": str(r.get("Video")), "verdict": "excluded",
                                   "reasons": '["malformed_row"]', "defects": "[]"}]))
    provenance = pd.concat(prov, ignore_index=True) if prov else pd.DataFrame()
    del prov  # the task frames go before the legacy-order copy: one copy of the provenance at a time
    return accepted, excluded, _in_legacy_order(provenance, legacy), record if record["options"] is not None else {}


def _merge_interface(record: dict, path: Path, task: str) -> None:
    """Add one task's ``interface.json`` to the release's ``answer_interface`` record."""
    if not path.exists():
        raise InvariantError(f"no interface.json for task {task!r} in {path.parent}: rerun its notebook")
    own = read_json_object(path)
    if not isinstance(own, dict) or not isinstance(own.get("rules"), dict) or task not in own["rules"]:
        raise InvariantError(f"{path} does not record the answer interface of {task!r}")
    if record["options"] is None:
        record["options"] = own.get("options")
    elif own.get("options") != record["options"]:
        first = next(iter(record["rules"]))
        raise InvariantError(f"tasks {first!r} and {task!r} built their options with different option params "
                             f"(params/options.yaml changed between their runs?): rerun both")
    record["rules"][task] = own["rules"][task]
    record.setdefault("adversarial_filter", {})[task] = own.get("adversarial_filter", [])


def _in_legacy_order(provenance: pd.DataFrame, legacy: pd.DataFrame) -> pd.DataFrame:
    """Provenance rows in the order of the legacy rows (the frame itself when already so)."""
    if provenance.empty:
        return provenance.reset_index(drop=True)
    order = {k: i for i, k in enumerate(legacy["Legacy Row Key"])}
    o = provenance["key"].map(order).to_numpy(dtype=float, na_value=np.inf)
    if (np.diff(o) >= 0).all():
        return provenance.reset_index(drop=True)
    return provenance.take(np.argsort(o, kind="stable")).reset_index(drop=True)


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


def count_fields(accepted: list[dict], excluded: list[dict], *, excluded_order: str = "task") -> dict:
    """The row counts every ``release.json`` carries (``counts``, accepted by source and by task,
    exclusions by task, answer letters), computed once for both layouts (:func:`release_meta` and
    :func:`resti_lib.release.reoption.release_meta`). ``excluded_order``: ``task`` (the order of
    :func:`resti_lib.tasks.names`) or ``name``."""
    by_task = Counter(r["Task"] for r in accepted)
    by_source = Counter(r["Source"] for r in accepted)
    ex_task = Counter(r.get("task") for r in excluded)
    letters = Counter(r["Answer"] for r in accepted)
    order = {t: i for i, t in enumerate(names())}
    ex_items = sorted(ex_task.items(), key=lambda kv: order.get(kv[0], 99)) if excluded_order == "task" \
        else sorted(ex_task.items())
    return {
        "counts": {"accepted": len(accepted), "excluded": len(excluded), "original": len(accepted) + len(excluded)},
        "accepted_by_source": dict(sorted(by_source.items())),
        "accepted_by_task": dict(sorted(by_task.items())),
        "excluded_by_task": dict(ex_items),
        "answer_letters": {k: int(letters.get(k, 0)) for k in LETTERS},
    }


def release_meta(accepted: list[dict], excluded: list[dict], artifacts: dict, *, context: dict | None = None,
                 answer_interface: dict | None = None, adversarial_filter: dict | None = None) -> dict:
    """The ``release.json`` object of an assembled release; ``context``: the run that made it, under
    ``run`` (:func:`resti_lib.run.runinfo.run_context`: input, params digest, code and package versions);
    ``answer_interface``: the option params and task rules the options were built with
    (:meth:`resti_lib.options.spec.Interface.to_dict`), which ``resti verify`` and ``resti reoption``
    read back; ``adversarial_filter``: the option stage's adversarial checks of each task (task ->
    rounds: :meth:`resti_lib.options.stage.Stage.adversarial_filter`)."""
    meta = {"name": "ReSTI", "format": "ReSTI v5 schema", "generator": f"resti {__version__}",
            **count_fields(accepted, excluded), "artifacts": artifacts}
    if answer_interface:
        meta["answer_interface"] = answer_interface
    if adversarial_filter:
        meta["adversarial_filter"] = adversarial_filter
    if context:
        meta["run"] = context
    return meta


# ------------------------------------------------------------------------------ the release writer

class ReleaseStage:
    """The files of one release being written into a staging folder (see :func:`release_stage`).

    Every file goes through :meth:`write`, which records its size and sha256 for ``release.json``
    and ``SHA256SUMS`` (:meth:`seal`); :meth:`verify` writes ``validation.json``.
    """

    def __init__(self, folder: Path):
        self.dir = Path(folder)
        self.digests: dict[str, dict] = {}

    def write(self, name: str, data: bytes) -> None:
        atomic_write_bytes(self.dir / name, data)
        self.digests[name] = {"bytes": len(data), "sha256": sha256_bytes(data)}

    def artifacts(self, names) -> dict:
        """``{name: {"bytes", "sha256"}}`` of files already written."""
        return {n: dict(self.digests[n]) for n in names}

    def verify(self, *, legacy_keys: list[str] | None = None, meta: dict | None = None) -> dict:
        """Verify the staged release and write ``validation.json``; returns the validation object.
        ``meta``: the ``release.json`` that :meth:`seal` will write (written after this file, so its
        counts are checked from here rather than reported as absent)."""
        rel = load_release(self.dir, strict=False, known_tasks=names())
        if meta is not None and rel.meta is None:
            rel.meta = meta
        validation = verify_release(rel, legacy_keys=legacy_keys)
        self.write("validation.json", write_json_bytes(validation))
        return validation

    def seal(self, meta: dict, covered) -> None:
        """Write ``release.json`` (``meta``) and ``SHA256SUMS`` over ``covered`` and ``release.json``."""
        self.write("release.json", write_json_bytes(meta))
        names = [*covered, "release.json"]
        self.write("SHA256SUMS", "".join(f"{self.digests[n]['sha256']}  {n}\n" for n in names).encode("utf-8"))


def failing_checks(validation: dict) -> dict:
    """``{check: first failing ids}`` of a validation object (for error messages)."""
    return {k: c["failing"][:3] for k, c in validation["checks"].items() if c["status"] == "fail"}


@contextmanager
def release_stage(out_dir: str | os.PathLike, *, inputs=()):
    """Write a release: yields a :class:`ReleaseStage`; published at ``out_dir`` when the block ends
    without an error (:func:`resti_lib.release.publish.publishing`: ours only, locked, atomic swap)."""
    with publishing(out_dir, kind="release", inputs=inputs, what="release folder") as stage:
        yield ReleaseStage(stage)


def write_release(accepted: list[dict], excluded: list[dict], provenance: pd.DataFrame, legacy: pd.DataFrame,
                  out_dir: str | Path, *, inputs=(), context: dict | None = None, answer_interface: dict | None = None,
                  adversarial_filter: dict | None = None) -> dict:
    """Write the release atomically; returns the validation object. The rows carry the options the
    task runs built through the option stage (:mod:`resti_lib.options.stage`); they ship unchanged.
    ``inputs``: paths the release is made from (the release folder may not be one of them, nor hold
    one); ``context``: the run block of ``release.json`` (:func:`resti_lib.run.runinfo.run_context`);
    ``adversarial_filter``: each task's filter checks (task -> rounds), recorded as built."""
    with release_stage(out_dir, inputs=inputs) as st:
        check_invariants(legacy, accepted, excluded)
        order = {k: i for i, k in enumerate(legacy["Legacy Row Key"])}
        accepted = sorted(accepted, key=lambda r: order[r["Legacy Row Key"]])
        excluded = sorted(excluded, key=lambda r: order[r["key"]])
        provenance = _in_legacy_order(provenance, legacy)
        st.write("resti.jsonl", jsonl_text(accepted).encode("utf-8"))
        st.write("resti.parquet", rows_to_parquet_bytes(accepted))
        st.write("excluded.jsonl", jsonl_text(excluded, sort_keys=True).encode("utf-8"))
        st.write("provenance.parquet", _parquet_bytes(provenance))
        validation = st.verify(legacy_keys=list(legacy["Legacy Row Key"]),
                               meta=release_meta(accepted, excluded, {}, context=context,
                                                 answer_interface=answer_interface,
                                                 adversarial_filter=adversarial_filter))
        if not validation["passed"]:
            raise InvariantError(f"the assembled release fails verify: {failing_checks(validation)}")
        names = ["resti.jsonl", "resti.parquet", "excluded.jsonl", "provenance.parquet", "validation.json"]
        st.seal(release_meta(accepted, excluded, st.artifacts(names), context=context,
                             answer_interface=answer_interface, adversarial_filter=adversarial_filter), names)
    return validation


def _lean_arrow_pool() -> None:
    """Assembly holds every task's provenance (arrow strings) and frees a copy of it at each step;
    arrow's jemalloc pool hands freed pages back where its default pool keeps them (peak memory at
    the 2,064-row x 10 structure: 519 MB against 672 MB). Kept when the user chose a pool
    (``ARROW_DEFAULT_MEMORY_POOL``) or the build has no jemalloc."""
    import pyarrow as pa

    if os.environ.get("ARROW_DEFAULT_MEMORY_POOL"):
        return
    try:
        pa.set_memory_pool(pa.jemalloc_memory_pool())
    except (NotImplementedError, AttributeError):
        pass


def assemble(legacy_path: str | Path, tasks_dir: str | Path, out_dir: str | Path, *,
             context: dict | None = None) -> dict:
    """Read the legacy benchmark and every task's outputs, then :func:`write_release`."""
    _lean_arrow_pool()
    legacy, _ = load_legacy(legacy_path, strict=False, known_tasks=names())
    accepted, excluded, provenance, answer_interface = collect(Path(tasks_dir), legacy)
    adversarial = answer_interface.pop("adversarial_filter", None)
    return write_release(accepted, excluded, provenance, legacy, out_dir, inputs=[legacy_path, tasks_dir],
                         context=context, answer_interface=answer_interface, adversarial_filter=adversarial)


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
