"""The one exception type for bad user input: it names the file and the object."""

from __future__ import annotations

from pathlib import Path


class UserError(Exception):
    """Bad input. The CLI prints `file: object: message` and exits 1, no traceback."""

    def __init__(self, file: str, obj: str | None, message: str):
        self.file = str(file)
        self.obj = obj
        self.message = message
        super().__init__(str(self))

    def __str__(self) -> str:
        where = self.file if not self.obj else f"{self.file}: {self.obj}"
        return f"{where}: {self.message}"


def read_input(path: str | Path) -> bytes:
    """The bytes of a file the user gave; one missing or unreadable is a UserError naming it."""
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise UserError(path, None, "file not found") from None
    except OSError as e:
        raise UserError(path, None, f"cannot read: {e.strerror}") from None
