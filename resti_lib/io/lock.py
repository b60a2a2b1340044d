"""One writer at a time: an advisory lock (``flock``) on a lock file beside what is written.

``resti run`` holds ``<output_dir>/.resti.lock`` for the whole run; every folder that is published
(:mod:`resti_lib.release.publish`: a release, a rebuilt release, the mini-world) is written under
``<parent>/.<name>.lock``. The holder removes the lock file when it is done (a killed holder leaves
an unlocked file behind, which the next process simply locks). A second process that finds the lock
held gets a :class:`BusyError` naming the holder (pid, command, start time), or waits when asked to. The kernel releases the lock
when its holder exits, also when it is killed, so a crashed run never leaves a stale lock.

Locks are re-entrant within one process (the world lock is taken by the run, then again by the
generator it calls).
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

from ..errors import BusyError
from .files import default_mode

try:
    import fcntl
except ImportError:  # pragma: no cover - resti runs on POSIX systems
    fcntl = None

_HELD: dict[str, list] = {}  # lock file (real path) -> [fd, depth]
_GUARD = threading.Lock()


def lock_file_for(folder: str | os.PathLike) -> Path:
    """``<parent>/.<name>.lock``: the lock of a folder that is replaced as a whole."""
    folder = Path(os.path.realpath(folder))
    return folder.parent / f".{folder.name}.lock"


def _holder(path: Path) -> str:
    try:
        info = json.loads(path.read_text(encoding="utf-8") or "{}")
    except (OSError, ValueError):
        return "another process"
    if not isinstance(info, dict):
        return "another process"
    return (f"pid {info.get('pid')} ({' '.join(str(a) for a in info.get('argv', []))[:120]!s}, "
            f"since {info.get('started')})")


def _try_lock(fd: int) -> bool:
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False


@contextmanager
def hold(lock_path: str | os.PathLike, *, what: str, wait: bool = False, timeout: float | None = None,
         poll: float = 0.2):
    """Hold the lock file ``lock_path`` for the ``with`` block.

    ``what`` names the locked thing in messages. ``wait=False``: a held lock raises
    :class:`BusyError` at once; ``wait=True``: wait (up to ``timeout`` seconds, ``None`` = no limit),
    printing once to stderr who holds it.
    """
    if fcntl is None:  # pragma: no cover
        yield
        return
    lock_path = Path(lock_path)
    lock_path.parent.mkdir(parents=True, exist_ok=True)
    key = os.path.realpath(lock_path)
    with _GUARD:
        if key in _HELD:
            _HELD[key][1] += 1
            reentered = True
        else:
            reentered = False
    if reentered:
        try:
            yield
        finally:
            with _GUARD:
                _HELD[key][1] -= 1
        return
    fd = _acquire(lock_path, what=what, wait=wait, timeout=timeout, poll=poll)
    try:
        info = {"pid": os.getpid(), "argv": sys.argv[:6], "started": time.strftime("%Y-%m-%d %H:%M:%S")}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(info) + "\n").encode("utf-8"), 0)
        with _GUARD:
            _HELD[key] = [fd, 1]
        try:
            yield
        finally:
            with _GUARD:
                del _HELD[key]
            # removed while still locked: a process that opened the old file re-checks and retries
            try:
                os.unlink(lock_path)
            except OSError:
                pass
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def _same_file(fd: int, path: Path) -> bool:
    try:
        a, b = os.fstat(fd), os.stat(path)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _acquire(lock_path: Path, *, what: str, wait: bool, timeout: float | None, poll: float) -> int:
    """An open, locked descriptor of ``lock_path`` (the file still at that path once locked)."""
    t0 = time.monotonic()
    told = False
    while True:
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), default_mode())
        try:
            if _try_lock(fd):
                if _same_file(fd, lock_path):
                    return fd
                os.close(fd)  # the holder removed it as we locked: lock the new one
                continue
            holder = _holder(lock_path)
            if not wait:
                raise BusyError(f"{what} is being written by {holder}; wait for it to finish or use another "
                                "folder", file=lock_path.parent)
            if timeout is not None and time.monotonic() - t0 > timeout:
                raise BusyError(f"{what} is still being written by {holder} after {timeout:.0f} s",
                                file=lock_path.parent)
            if not told:
                print(f"resti: waiting for {what} (held by {holder}) ...", file=sys.stderr)
                told = True
        except BaseException:
            os.close(fd)
            raise
        os.close(fd)
        time.sleep(poll)


def folder_lock(folder: str | os.PathLike, *, what: str | None = None, wait: bool = False,
                timeout: float | None = None):
    """The lock of a folder that is replaced as a whole (``<parent>/.<name>.lock``)."""
    return hold(lock_file_for(folder), what=what or f"folder {os.path.realpath(folder)}", wait=wait,
                timeout=timeout)


def run_lock(output_dir: str | os.PathLike):
    """The lock of one ``resti run`` output folder (``<output_dir>/.resti.lock``), not waited for."""
    out = Path(os.path.realpath(output_dir))
    return hold(out / ".resti.lock", what=f"output folder {out} (another resti run)", wait=False)
