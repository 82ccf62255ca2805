"""The one exception type for bad user input: it names the file and the object."""

from __future__ import annotations

from pathlib import Path


class UserError(Exception):
    """Bad input. The CLI prints `file: object: message` and exits 1, no traceback.
    `more`: further (object, message) problems of the same file, found by the same
    check and reported with the first, one line each (a config's every problem at once)."""

    def __init__(self, file: str, obj: str | None, message: str, more=()):
        self.file = str(file)
        self.obj = obj
        self.message = message
        self.more = tuple(more)
        super().__init__(str(self))

    def __str__(self) -> str:
        return "\n".join(self._line(o, m) for o, m in ((self.obj, self.message), *self.more))

    def _line(self, obj: str | None, message: str) -> str:
        where = self.file if not obj else f"{self.file}: {obj}"
        return f"{where}: {message}"


def raise_all(file, problems: list[tuple[str | None, str]]) -> None:
    """One UserError holding every (object, message) problem of `file`; none: nothing."""
    if problems:
        raise UserError(file, *problems[0], more=problems[1:])


def read_input(path: str | Path) -> bytes:
    """The bytes of a file the user gave; one missing or unreadable is a UserError naming it."""
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise UserError(path, None, "file not found") from None
    except OSError as e:
        raise UserError(path, None, f"cannot read: {e.strerror}") from None
