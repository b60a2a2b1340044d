"""One error type for bad input: it always names the file, the row and the field."""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad input data.

    Parameters
    ----------
    message:
        What is wrong, in plain words.
    file:
        The file being read (path or name); ``None`` when not file-backed.
    row:
        The row identifier: ReSTI ID, Legacy Row Key, a frame index or a 0-based row index.
    field:
        The column, key or binary field at fault.
    """

    def __init__(self, message: str, *, file: str | Path | None = None, row: object = None,
                 field: str | None = None):
        self.message = message
        self.file = str(file) if file is not None else None
        self.row = row
        self.field = field
        parts = []
        if self.file is not None:
            parts.append(f"file {self.file}")
        if row is not None:
            parts.append(f"row {row}")
        if field is not None:
            parts.append(f"field {field!r}")
        where = ", ".join(parts)
        super().__init__(f"{where}: {message}" if where else message)


class ContractError(ValueError):
    """A measurement contract that cannot be evaluated (unknown id, time out of range, ...)."""
