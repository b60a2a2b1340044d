"""Publishing an output folder: the one writer of releases (``resti run``, ``resti reoption``) and of
the mini-world (``resti synth``).

``with publishing(target, kind="release", inputs=[...]) as stage:`` — the caller writes every file
into ``stage``; when the block ends without an error the folder is published at ``target``:

1. **Ours only.** ``target`` must be absent, an empty folder, or a folder that resti wrote (the
   marker file :data:`MARKER` names its kind). Anything else — a folder of other files, a file, an
   output of another kind — is refused with :class:`OutputError`, before any work. ``target`` is
   never an input of the run, nor a folder holding an input, nor a folder inside one.
2. **One writer.** The block runs under the lock ``<parent>/.<name>.lock``
   (:mod:`resti_lib.io.lock`): a second writer of the same folder gets :class:`BusyError`.
3. **Staging.** ``stage`` is a new folder ``<parent>/.<name>.tmp-<random>`` beside the target
   (same file system), created with the permissions of the process umask; nothing is forced.
4. **Swap.** The finished stage and the old folder are exchanged in one atomic step where the
   system offers it (``renameat2(RENAME_EXCHANGE)``), so the path always holds a complete folder.
   Elsewhere the old folder is renamed to ``<parent>/.<name>.old-<random>`` and the stage renamed
   into place; a kill between the two renames leaves the old folder there, and the next start
   puts it back (:func:`recover`).
5. **Clean start.** Under the lock, before any work, an interrupted swap is undone and the
   temporaries of killed runs (``.<name>.tmp-*``, ``.<name>.old-*``, ``.<name>.prev``) are removed.

An error (or a kill) inside the block leaves the previous folder untouched.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import json
import os
import secrets
import shutil
from contextlib import contextmanager
from pathlib import Path

from ..errors import OutputError
from ..io.files import atomic_write_bytes
from ..io.lock import folder_lock

MARKER = ".resti-output"

# Entries a folder of each kind holds, and how a folder written before the marker existed is
# recognised (a JSON file and the generator it names). Only for such folders are the names used:
# a folder without the marker is ours only if it holds nothing else.
KNOWN_ENTRIES = {
    "release": {"resti.jsonl", "resti.parquet", "excluded.jsonl", "provenance.parquet", "validation.json",
                "release.json", "SHA256SUMS"},
    "world": {"scannet", "waymo", "omni6d", "legacy", "manifest.jsonl", "world.json", ".generator_stamp"},
}
_SIGNATURE = {"release": "release.json", "world": "world.json"}


def marker_bytes(kind: str) -> bytes:
    """The marker file: no dates or paths, so reruns stay byte-identical."""
    return (json.dumps({"kind": kind, "written_by": "resti"}, sort_keys=True) + "\n").encode("utf-8")


def _real(p: str | os.PathLike) -> Path:
    return Path(os.path.realpath(os.path.expanduser(str(p))))


# the rebuilder's module name, and its name before the release wing
_REOPTION_GENERATORS = ("resti_lib.release.reoption", "resti_lib.reoption")


def _written_by_resti(kind: str, meta: dict) -> bool:
    if kind == "release":
        gen = str(meta.get("generator", ""))
        re_gen = (meta.get("reoption") or {}).get("generator") if isinstance(meta.get("reoption"), dict) else None
        return gen.startswith("resti ") or re_gen in _REOPTION_GENERATORS
    return meta.get("generator") == "resti_lib.synth"


def read_marker(folder: Path) -> str | None:
    """The kind named by the folder's marker, ``None`` without one (or an unreadable one)."""
    m = folder / MARKER
    if not m.is_file() or m.is_symlink():
        return None
    try:
        obj = json.loads(m.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return obj.get("kind") if isinstance(obj, dict) and obj.get("written_by") == "resti" else None


def owner_problem(target: Path, kind: str) -> str | None:
    """Why ``target`` may not be replaced by a ``kind`` folder (``None`` when it may)."""
    if not os.path.lexists(target):
        return None
    if target.is_symlink() or not target.is_dir():
        return "exists and is not a folder"
    entries = sorted(p.name for p in target.iterdir())
    if not entries:
        return None
    found = read_marker(target)
    if found == kind:
        return None
    if found is not None:
        return f"is a resti {found} folder, not a {kind} folder"
    unknown = [e for e in entries if e not in KNOWN_ENTRIES[kind]]
    sig = target / _SIGNATURE[kind]
    if not unknown and sig.is_file():
        try:
            meta = json.loads(sig.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            meta = None
        if isinstance(meta, dict) and _written_by_resti(kind, meta):
            return None  # written by resti before the marker existed
    shown = ", ".join(unknown[:5] or entries[:5]) + (" ..." if len(unknown or entries) > 5 else "")
    return (f"is not empty and was not written by resti (no {MARKER} marker; it holds {shown}); "
            "nothing was changed: choose a new or empty folder, or remove it yourself")


def input_problem(target: Path, inputs) -> str | None:
    """Why ``target`` collides with an input (it is one, holds one, or lies inside one)."""
    for inp in inputs:
        if inp is None or not os.path.lexists(inp):
            continue
        i = _real(inp)
        if i == target:
            return f"is an input of this run ({i})"
        if target in i.parents:
            return f"holds an input of this run ({i})"
        if i in target.parents:
            return f"lies inside an input of this run ({i})"
    return None


# ------------------------------------------------------------------------------------------- swap

_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _load_renameat2():
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    fn.restype = ctypes.c_int
    return fn


_renameat2 = _load_renameat2()


def exchange(a: Path, b: Path) -> bool:
    """Atomically exchange two existing paths; ``False`` where the system cannot."""
    if _renameat2 is None:
        return False
    rc = _renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    return rc == 0


def _sibling(target: Path, tag: str) -> Path:
    return target.with_name(f".{target.name}.{tag}-{secrets.token_hex(6)}")


def swap_in(stage: Path, target: Path) -> None:
    """Put the finished ``stage`` at ``target``; the old folder (if any) is removed afterwards."""
    if not os.path.lexists(target):
        os.rename(stage, target)
        return
    if target.is_dir() and not any(target.iterdir()):
        os.rmdir(target)
        os.rename(stage, target)
        return
    if exchange(stage, target):
        shutil.rmtree(stage, ignore_errors=True)  # now the old folder
        return
    old = _sibling(target, "old")
    os.rename(target, old)
    # a kill here leaves `old` and no target: recover() puts `old` back at the next start
    os.rename(stage, target)
    shutil.rmtree(old, ignore_errors=True)


def _temporaries(target: Path, tag: str) -> list[Path]:
    return sorted(target.parent.glob(f".{target.name}.{tag}-*"))


def recover(target: str | os.PathLike) -> list[str]:
    """Undo an interrupted swap and remove the temporaries of killed runs (call under the lock).

    Returns what was done, one line per action.
    """
    target = _real(target)
    done = []
    olds = [p for p in _temporaries(target, "old") if p.is_dir()]
    prev = target.with_name(f".{target.name}.prev")  # the swap of earlier versions
    if prev.is_dir():
        olds.append(prev)
    if not os.path.lexists(target) and olds:
        newest = max(olds, key=lambda p: p.stat().st_mtime)
        os.rename(newest, target)
        olds.remove(newest)
        done.append(f"restored {target} from the interrupted swap {newest.name}")
    for p in olds + [p for p in _temporaries(target, "tmp")]:
        shutil.rmtree(p, ignore_errors=True) if p.is_dir() and not p.is_symlink() else p.unlink(missing_ok=True)
        done.append(f"removed the temporary {p.name} of an earlier run")
    return done


@contextmanager
def publishing(target: str | os.PathLike, *, kind: str = "release", inputs=(), what: str | None = None,
               wait: bool = False):
    """Stage a ``kind`` folder and publish it at ``target`` (see the module text). Yields the stage."""
    if kind not in KNOWN_ENTRIES:
        raise ValueError(f"kind must be one of {sorted(KNOWN_ENTRIES)}")
    target = _real(target)
    label = what or f"{kind} folder"
    if not target.name or target == target.parent:
        raise OutputError(f"cannot use {target} as the {label}", file=target)
    why = input_problem(target, inputs)
    if why:
        raise OutputError(f"the {label} {why}; nothing was written", file=target)
    target.parent.mkdir(parents=True, exist_ok=True)
    with folder_lock(target, what=f"{label} {target}", wait=wait):
        recover(target)
        why = owner_problem(target, kind)
        if why:
            raise OutputError(f"refusing to replace the {label}: it {why}", file=target)
        stage = _sibling(target, "tmp")
        os.mkdir(stage)  # permissions from the umask
        try:
            yield stage
            atomic_write_bytes(stage / MARKER, marker_bytes(kind))
            swap_in(stage, target)
        except BaseException:
            shutil.rmtree(stage, ignore_errors=True)
            raise
