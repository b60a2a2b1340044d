"""Reading and writing files safely: regular files only, UTF-8 text, bounded JSON, atomic writes.

Every reader here turns a damaged file into one :class:`~resti_lib.errors.InputError` naming the
file (and the line where it applies), never a traceback:

- :func:`open_regular` opens a path only when it is a regular file (a folder, a device, a FIFO or
  a socket is refused without blocking on it);
- :func:`read_text` decodes UTF-8 strictly (a UTF-8 byte-order mark is skipped; UTF-16 text and
  invalid bytes are named with their line);
- :func:`parse_json` refuses invalid JSON and nesting deeper than :data:`MAX_JSON_DEPTH`;
- :func:`read_jsonl` reads one JSON object per line;
- :func:`atomic_write_bytes` writes through a temporary file and a rename, with the permissions a
  plain ``open`` would give (the process umask), never a forced mode.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
import tempfile
import threading
from pathlib import Path

from ..errors import InputError

MAX_JSON_DEPTH = 64  # deepest nesting accepted in a JSON document (ReSTI rows nest 3 levels)

_UTF16_BOMS = (b"\xff\xfe", b"\xfe\xff")
_UTF8_BOM = b"\xef\xbb\xbf"
_KIND = {stat.S_IFDIR: "a folder", stat.S_IFCHR: "a character device", stat.S_IFBLK: "a block device",
         stat.S_IFIFO: "a FIFO", stat.S_IFSOCK: "a socket", stat.S_IFLNK: "a symbolic link"}


def file_kind(mode: int) -> str:
    """``"a regular file"``, ``"a folder"``, ``"a FIFO"``, ... for an ``st_mode``."""
    return "a regular file" if stat.S_ISREG(mode) else _KIND.get(stat.S_IFMT(mode), "not a regular file")


def open_regular(path: str | os.PathLike, *, field: str | None = None):
    """Open ``path`` for binary reading when it is a regular file (symbolic links are followed).

    The file is opened non-blocking and checked with ``fstat`` before any byte is read, so a FIFO or
    a device never blocks the process and is never read.
    """
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise InputError("file not found", file=path, field=field) from None
    except IsADirectoryError:
        raise InputError("is a folder, not a file", file=path, field=field) from None
    except OSError as e:
        raise InputError(f"cannot open ({e.strerror})", file=path, field=field) from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise InputError(f"is {file_kind(mode)}, not a regular file (not read)", file=path, field=field)
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_bytes(path: str | os.PathLike, *, field: str | None = None) -> bytes:
    with open_regular(path, field=field) as f:
        return f.read()


def decode_text(data: bytes, *, file=None, field: str | None = None) -> str:
    """UTF-8 text of ``data``; a leading UTF-8 byte-order mark is dropped."""
    if data.startswith(_UTF16_BOMS):
        raise InputError("is UTF-16 text; resti reads UTF-8 (convert the file to UTF-8)", file=file, field=field)
    data = data.removeprefix(_UTF8_BOM)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data[: e.start].count(b"\n") + 1
        hint = " (UTF-16 text without a byte-order mark?)" if b"\x00" in data[:4096] else ""
        raise InputError(f"is not UTF-8 text: byte 0x{data[e.start]:02x} at line {line}, byte offset "
                         f"{e.start}{hint}", file=file, row=f"line {line}", field=field) from None


def read_text(path: str | os.PathLike, *, field: str | None = None) -> str:
    return decode_text(read_bytes(path, field=field), file=path, field=field)


def _depth(obj, limit: int) -> int:
    """Nesting depth of a parsed JSON value, stopping once it exceeds ``limit``."""
    depth, level = 0, [obj]
    while level:
        depth += 1
        if depth > limit:
            return depth
        nxt = []
        for o in level:
            if isinstance(o, dict):
                nxt.extend(o.values())
            elif isinstance(o, list):
                nxt.extend(o)
        level = nxt
    return depth - 1 if depth else 0


def parse_json(text: str, *, file=None, row=None, field: str | None = None, what: str = "JSON"):
    """``json.loads`` with one clear error for invalid text and for nesting deeper than
    :data:`MAX_JSON_DEPTH` levels."""
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"{what} is not valid JSON ({e.msg} at char {e.pos}); truncated or damaged?",
                         file=file, row=row, field=field) from None
    except RecursionError:
        raise InputError(f"{what} is nested too deeply (more than {MAX_JSON_DEPTH} levels)",
                         file=file, row=row, field=field) from None
    except ValueError as e:  # e.g. an integer literal longer than Python converts
        raise InputError(f"{what} is not valid JSON ({e})", file=file, row=row, field=field) from None
    if isinstance(obj, (dict, list)) and _depth(obj, MAX_JSON_DEPTH) > MAX_JSON_DEPTH:
        raise InputError(f"{what} is nested too deeply (more than {MAX_JSON_DEPTH} levels)",
                         file=file, row=row, field=field)
    return obj


MAX_LINE_BYTES = 4_000_000  # one row of a JSONL file (a release row is a few kB; a longer line is refused)


def read_jsonl(path: str | os.PathLike, *, max_line: int = MAX_LINE_BYTES) -> list[dict]:
    """One JSON object per non-blank line of a UTF-8 file, read line by line: a line over
    ``max_line`` bytes is refused (file and line named) before it is held whole in memory."""
    path = Path(path)
    rows = []
    with open_regular(path) as f:
        n = 0
        while True:
            raw = f.readline(max_line + 1)
            if not raw:
                break
            n += 1
            if len(raw) > max_line and not raw.endswith(b"\n"):
                raise InputError(f"line {n} is longer than {max_line:,} bytes (a JSONL row is a few kB; damaged "
                                 "or not a row file?)", file=path, row=f"line {n}")
            if n == 1:
                if raw.startswith(_UTF16_BOMS):
                    raise InputError("is UTF-16 text; resti reads UTF-8 (convert the file to UTF-8)", file=path)
                raw = raw.removeprefix(_UTF8_BOM)
            try:
                line = raw.decode("utf-8")
            except UnicodeDecodeError as e:
                raise InputError(f"is not UTF-8 text: byte 0x{raw[e.start]:02x} at line {n}", file=path,
                                 row=f"line {n}") from None
            if not line.strip():
                continue
            obj = parse_json(line, file=path, row=f"line {n}", what=f"line {n}")
            if not isinstance(obj, dict):
                raise InputError(f"line {n} is a JSON {type(obj).__name__}, not an object", file=path,
                                 row=f"line {n}")
            rows.append(obj)
    return rows


def read_json_object(path: str | os.PathLike, *, what: str | None = None) -> dict:
    """A UTF-8 JSON file holding one object (e.g. ``release.json``)."""
    path = Path(path)
    obj = parse_json(read_text(path), file=path, what=what or path.name)
    if not isinstance(obj, dict):
        raise InputError(f"{what or path.name} holds a JSON {type(obj).__name__}, not an object", file=path)
    return obj


# ------------------------------------------------------------------------------------ digests

def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | os.PathLike) -> str:
    """sha256 of a regular file (anything else is refused unread, see :func:`open_regular`)."""
    h = hashlib.sha256()
    with open_regular(path) as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


# ------------------------------------------------------------------------------------ writing

_UMASK_LOCK = threading.Lock()


def current_umask() -> int:
    """The process umask (read from ``/proc`` where possible, else set and restored under a lock)."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    with _UMASK_LOCK:
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def default_mode(folder: bool = False) -> int:
    """The mode ``open``/``mkdir`` would give a new file/folder under the current umask."""
    return (0o777 if folder else 0o666) & ~current_umask()


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write to a temporary file in the same folder, then rename over ``path``.

    The file gets the permissions a plain ``open`` would give (``0666`` less the umask).
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as e:
        raise _named(e, path) from None
    try:
        os.fchmod(fd, default_mode())
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException as e:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(e, OSError):
            raise _named(e, path) from None
        raise


def _named(e: OSError, path: Path) -> OSError:
    """The same system error, naming the file it was writing (a full disk names no file itself)."""
    return e if e.filename else type(e)(e.errno, e.strerror or str(e), str(path))


def write_json_bytes(obj) -> bytes:
    """The one layout of resti's JSON files: 2-space indent, UTF-8 as is, trailing newline."""
    return (json.dumps(obj, indent=2, ensure_ascii=False) + "\n").encode("utf-8")
