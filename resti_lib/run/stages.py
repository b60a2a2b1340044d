"""Stage bookkeeping of the main job, so that a rerun redoes only what changed.

A stage's **key** is the sha256 of four digests:

* ``code``: its notebook, every module of the package and the versions of the libraries;
* ``params``: its merged parameters (output locations left out, :data:`runinfo.OUTPUT_KEYS`);
* ``inputs``: every parameter naming an existing file or folder outside the outputs (a file by its
  content up to :data:`HASH_LIMIT` bytes, a larger file or a folder by names, sizes and
  modification times);
* ``needs``: the recorded keys of the stages it reads from (``needs:`` in the stage list; by
  default every stage of an earlier wave).

After a stage ran, the files it wrote under the output folder are recorded with their size and
modification time (its *products*). A stage is up to date when its recorded key equals the
current one and its products are all still there, unchanged. The state lives in
``<output_dir>/.resti/stages.json`` and is replaced atomically after every wave.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from .. import paths
from .runinfo import OUTPUT_KEYS, digest, stage_params_digest

STATE_DIR = ".resti"
STATE_FILE = "stages.json"
HASH_LIMIT = 64 * 1024 * 1024  # files up to this size are fingerprinted by content
FORMAT = 1


def _file_sha(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def fingerprint(path: Path) -> str:
    """Content digest of a file (stat when it is larger than :data:`HASH_LIMIT`); names, sizes and
    modification times of every file of a folder."""
    st = path.stat()
    if path.is_file():
        if st.st_size <= HASH_LIMIT:
            return "sha256:" + _file_sha(path)
        return f"stat:{st.st_size}:{st.st_mtime_ns}"
    h = hashlib.sha256()
    for dirpath, dirnames, filenames in os.walk(path):
        dirnames.sort()
        for name in sorted(filenames):
            p = os.path.join(dirpath, name)
            try:
                s = os.stat(p)
            except OSError:
                continue
            h.update(f"{os.path.relpath(p, path)}\0{s.st_size}\0{s.st_mtime_ns}\n".encode())
    return "tree:" + h.hexdigest()


#: Params files the package reads itself (not passed to one notebook): they count as code, so an
#: edit reruns every stage that uses them (the option stage runs in every task).
LIBRARY_PARAMS = ("params/options.yaml", "params/measure.yaml")


def code_digest() -> str:
    """sha256 of every module of the package and of the params files it reads itself (relative path
    and bytes)."""
    h = hashlib.sha256()
    pkg = paths.ROOT / "resti_lib"
    for f in sorted(pkg.rglob("*.py")):
        if "__pycache__" in f.parts:
            continue
        h.update(f.relative_to(pkg).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    for name in LIBRARY_PARAMS:
        f = paths.ROOT / name
        if f.exists():
            h.update(name.encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


def _under(p: Path, root: Path) -> bool:
    try:
        p.relative_to(root)
        return True
    except ValueError:
        return False


class Fingerprints:
    """Input fingerprints, computed once per run and path."""

    def __init__(self, out_root: Path):
        self.out_root = out_root.resolve()
        self._memo: dict[Path, str] = {}

    def forget_outputs(self) -> None:
        """Drop the fingerprints of paths under the output folder (a stage may have rewritten them)."""
        self._memo = {p: v for p, v in self._memo.items() if not _under(p, self.out_root)}

    def of(self, path: Path) -> str:
        path = path.resolve()
        if path not in self._memo:
            self._memo[path] = fingerprint(path)
        return self._memo[path]

    def inputs(self, params: dict) -> dict[str, str]:
        """Parameter name -> fingerprint, for every parameter naming an existing path that is not
        an output location (the output folder itself, or a folder holding it)."""
        out = {}
        for k, v in sorted(params.items()):
            if k in OUTPUT_KEYS or not isinstance(v, str) or not v.strip():
                continue
            try:
                p = paths.resolve(v)
                if not p.exists():
                    continue
                p = p.resolve()
            except (OSError, ValueError):
                continue
            if _under(self.out_root, p):  # the outputs, or a folder holding them
                continue
            out[k] = self.of(p)
        return out


def scan(out_root: Path, exclude: list[Path]) -> dict[str, list[int]]:
    """Relative path -> [size, mtime_ns] of every file under the output folder, except those under
    ``exclude`` (the mini-world, the state) and hidden temporaries."""
    out: dict[str, list[int]] = {}
    if not out_root.exists():
        return out
    skip = {p.resolve() for p in exclude}
    root = out_root.resolve()
    for dirpath, dirnames, filenames in os.walk(root):
        d = Path(dirpath)
        dirnames[:] = sorted(n for n in dirnames if not n.startswith(".") and (d / n).resolve() not in skip)
        for name in filenames:
            if name.startswith("."):
                continue
            p = d / name
            try:
                s = p.stat()
            except OSError:
                continue
            out[p.relative_to(root).as_posix()] = [s.st_size, s.st_mtime_ns]
    return out


@dataclass
class StageKey:
    """The four digests of a stage and their combination."""

    code: str
    params: str
    inputs: str
    needs: str
    key: str = field(init=False)
    own_params: str = field(init=False, default="")  # the params digest without a run context

    def __post_init__(self):
        self.key = digest([self.code, self.params, self.inputs, self.needs])

    def parts(self) -> dict:
        return {"key": self.key, "code": self.code, "params": self.params, "inputs": self.inputs,
                "needs": self.needs}


def stage_key(notebook: Path, params: dict, *, code: str, env: dict, inputs: dict, needs: dict) -> StageKey:
    """The key of a stage run with ``params`` (a ``run_context`` among them counts as params)."""
    nb_sha = _file_sha(notebook)
    p = stage_params_digest(params)
    if "run_context" in params:
        p = digest([p, params["run_context"]])
    return StageKey(code=digest([nb_sha, code, env]), params=p, inputs=digest(inputs), needs=digest(needs))


def owners(rel: str, names: list[str]) -> list[str]:
    """Which of the stages that ran together wrote ``rel``: files are named after their notebook
    (``tables/03_dimensional_summary.csv``, ``figures/99_attacks_after.png``) or sit in a folder
    named after its subject (``tasks/dimensional-measurement/``, ``answer_interface/``); a file
    that names none of them is owned by all of them."""
    parts = rel.split("/")
    base = parts[-1]
    found = [n for n in names if n in rel]
    if not found:
        numbers = [n for n in names if base.startswith(n.split("_", 1)[0] + "_")]
        found = numbers if len(numbers) == 1 else []
    if not found:
        words = [set(re.split(r"[-_]", d)) | {d} for d in parts[:-1]]
        found = [n for n in names if any(n.split("_", 1)[-1] in w for w in words)]
    return sorted(found or names)


class State:
    """``<output_dir>/.resti/stages.json``: per stage its key digests, seconds and products."""

    def __init__(self, out_root: Path):
        self.out_root = out_root
        self.path = out_root / STATE_DIR / STATE_FILE
        self.data = {"format": FORMAT, "stages": {}, "products": {}, "declared": {}}
        if self.path.exists():
            try:
                data = json.loads(self.path.read_text(encoding="utf-8"))
                if isinstance(data, dict) and data.get("format") == FORMAT:
                    self.data.update(data)
            except (OSError, ValueError):
                pass  # unreadable state: every stage is stale

    @property
    def stages(self) -> dict:
        return self.data["stages"]

    def key_of(self, name: str) -> str | None:
        return (self.stages.get(name) or {}).get("key")

    def declared(self, notebook: Path) -> list[str] | None:
        """Cached names of a notebook's parameters cell (by notebook digest)."""
        return self.data["declared"].get(_file_sha(notebook))

    def remember_declared(self, notebook: Path, names) -> None:
        self.data["declared"][_file_sha(notebook)] = sorted(names)

    def changed_products(self, name: str, current: dict) -> list[str]:
        """Recorded products of ``name`` that are missing or differ now."""
        out = []
        for rel, rec in self.data["products"].items():
            if name in rec["by"] and current.get(rel) != rec["stat"]:
                out.append(rel)
        return sorted(out)

    def stale_reason(self, name: str, key: StageKey, current: dict) -> str | None:
        """None when ``name`` is up to date, else why not (in words)."""
        old = self.stages.get(name)
        if not old:
            return "never run here"
        changed = [what for what in ("code", "params", "inputs", "needs") if old.get(what) != getattr(key, what)]
        if changed:
            words = {"code": "code or notebook", "params": "params", "inputs": "inputs",
                     "needs": "upstream stages"}
            return " and ".join(words[c] for c in changed) + " changed"
        gone = self.changed_products(name, current)
        if gone:
            return f"{len(gone)} output file(s) changed or missing, e.g. {gone[0]}"
        return None

    def record(self, names: list[str], parts: dict[str, dict], seconds: dict[str, float],
               before: dict, after: dict) -> None:
        """Stages ``names`` ran together (one wave; ``parts``: their key digests): files new or
        changed between the two scans are their products; files that vanished are forgotten."""
        changed = [rel for rel, st in after.items() if before.get(rel) != st]
        prods = self.data["products"]
        for rel in [r for r in prods if r not in after]:
            del prods[rel]
        for rel in changed:
            prods[rel] = {"stat": after[rel], "by": owners(rel, names)}
        for n in names:
            self.stages[n] = {**parts[n], "seconds": round(seconds.get(n, 0.0), 2)}

    def forget(self, name: str) -> None:
        self.stages.pop(name, None)

    def save(self) -> None:
        from ..io.files import atomic_write_bytes

        text = json.dumps(self.data, indent=1, sort_keys=True) + "\n"
        atomic_write_bytes(self.path, text.encode("utf-8"))


def memo_frame(cache_dir: Path, name: str, key, compute, *, products: tuple = ()):
    """``compute()`` (a DataFrame) once per ``key`` and package code: kept as
    ``<cache_dir>/<name>.<digest>.parquet`` and read back while ``key``, the code and every path of
    ``products`` (files ``compute`` writes as a side effect) are unchanged. For the expensive
    parts of a stage whose inputs did not change when the stage reruns (e.g. the attacks on the
    legacy benchmark when one task's params changed)."""
    import pandas as pd

    from ..io.files import atomic_write_bytes

    cache_dir = Path(cache_dir)
    tag = digest([name, key, code_digest()])[:20]
    path = cache_dir / f"{name}.{tag}.parquet"
    if path.exists() and all(Path(p).exists() for p in products):
        try:
            return pd.read_parquet(path)
        except (OSError, ValueError):
            pass
    df = compute()
    import io

    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    for old in cache_dir.glob(f"{name}.*.parquet"):
        old.unlink(missing_ok=True)
    atomic_write_bytes(path, buf.getvalue())
    return df


def file_digest(path) -> str:
    """Content digest of a file, or names/sizes/times of a folder (:func:`fingerprint`)."""
    return fingerprint(Path(path))
