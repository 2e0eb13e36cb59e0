"""The one exception type for expected failures.

An expected failure (a missing file, a corrupt image, a wrong shape, a non-rigid pose, an empty
vocabulary...) raises :class:`PanovoccError` with a one-line message that names the file and what
was expected. The CLI prints that line and exits with status 2; unexpected errors keep their traceback.
"""

from __future__ import annotations

from pathlib import Path

EXIT_BAD_INPUT = 2


def printable(text: str) -> str:
    """``text`` with any undecodable path bytes (``os.fsdecode``'s surrogate escapes, a name that is not UTF-8)
    shown as backslash escapes (``seq-\\xff``): safe to print, write as UTF-8 or draw in a figure title."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


class PanovoccError(Exception):
    """An expected failure: bad input or an impossible request. ``str(err)`` is the one-line message."""

    def __init__(self, message: str, path: str | Path | None = None):
        self.path = None if path is None else Path(path)
        super().__init__(f"{path}: {message}" if path is not None else message)
