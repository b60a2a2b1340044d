"""The exceptions of resti: one base, :class:`RestiError`, that the command line catches.

Every error a user can cause (bad input, a refused output folder, a busy output, a failing
notebook, a release that breaks an invariant) is a :class:`RestiError` carrying, where it applies,
the ``file``, the ``row`` (ReSTI ID, Legacy Row Key, a frame index or a 0-based row index) and the
``field``; ``str(error)`` is one line that names them. Anything else that escapes is a bug.

==================== =====================================================================
class                raised when
==================== =====================================================================
InputError           an input file, row, field or parameter is missing, unreadable or invalid
ContractError        a measurement contract cannot be evaluated (unknown id, time out of range)
OutputError          an output folder is refused (not a resti output, or an input of the run)
BusyError            another resti process holds the output folder (lock)
NotebookError        a notebook failed (names the notebook and the cell)
InvariantError       a release invariant failed (rows lost or duplicated, verify failing)
ReoptionError        a release could not be re-optioned (the rebuilt release fails verify)
OptionError          five valid candidates cannot be built for a row
==================== =====================================================================
"""

from __future__ import annotations

from pathlib import Path


class RestiError(Exception):
    """Base of every resti error.

    Parameters
    ----------
    message:
        What is wrong, in plain words.
    file:
        The file being read or written (path or name); ``None`` when not file-backed.
    row:
        The row identifier: ReSTI ID, Legacy Row Key, a frame index or a 0-based row index.
    field:
        The column, key or binary field at fault.
    """

    def __init__(self, message: str = "", *, file: str | Path | None = None, row: object = None,
                 field: str | None = None):
        self.message = str(message)
        self.file = str(file) if file is not None else None
        self.row = row
        self.field = field
        super().__init__(self.one_line())

    def one_line(self) -> str:
        parts = []
        if self.file is not None:
            parts.append(f"file {self.file}")
        if self.row is not None:
            parts.append(f"row {self.row}")
        if self.field is not None:
            parts.append(f"field {self.field!r}")
        where = ", ".join(parts)
        text = f"{where}: {self.message}" if where else self.message
        return " ".join(text.split("\n"))

    def __str__(self) -> str:
        return self.one_line()


class InputError(RestiError, ValueError):
    """Bad input data (a file, row, field or parameter)."""


class SourceError(InputError):
    """A source file fails a check of what it must hold (a timestamp out of order, a field of the
    wrong type, a non-finite vertex): named by file, row and field. In a run the row that needs it is
    excluded (``source_damaged``) with the file in its evidence; ``resti measure`` exits 2."""


class SourceGapError(SourceError):
    """The source's samples inside a question's window are further apart than the stated multiple of
    the track's own sampling interval: the row is excluded (``source_gap``), never interpolated."""


class ContractError(RestiError, ValueError):
    """A measurement contract that cannot be evaluated (unknown id, time out of range, ...)."""


class OutputError(RestiError, OSError):
    """An output folder that resti refuses to write (not ours, or an input of the run)."""


class BusyError(RestiError, RuntimeError):
    """Another resti process holds the output folder."""


class NotebookError(RestiError, RuntimeError):
    """A notebook failed: names the notebook, the cell (index and first line) and the error.
    ``input_message``: the one line of an input error raised inside the notebook (else None)."""

    input_message: str | None = None


class InvariantError(RestiError, RuntimeError):
    """A release invariant failed (rows lost or duplicated, ids not unique, verify failing)."""


class ReoptionError(RestiError, RuntimeError):
    """The rebuilt release could not be made or fails verification (nothing is published)."""


class OptionError(RestiError, RuntimeError):
    """Five valid candidates cannot be built for a row under the constraints."""


__all__ = ["BusyError", "ContractError", "InputError", "InvariantError", "NotebookError", "OptionError",
           "OutputError", "ReoptionError", "RestiError", "SourceError", "SourceGapError"]
