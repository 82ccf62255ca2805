"""The one exception type for bad user input: it names the file and the object."""

from __future__ import annotations


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
