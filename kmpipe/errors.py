"""Errors that the command line turns into a one-paragraph message and exit status 2.

Physics functions never raise these for a value that is merely ill-conditioned (they flag it);
these are for input a person supplied and can fix: a file, a line in it, a field of a manifest.
"""

from __future__ import annotations

from pathlib import Path


class InputError(Exception):
    """Bad input: names where it is (file, line, field) and what was expected.

    Parameters
    ----------
    message
        What is wrong and what was expected, in one or two sentences.
    path
        The file concerned, if any.
    line
        1-based line number in ``path``, if known.
    field
        Manifest field, CSV column or option name, if any.
    """

    def __init__(
        self,
        message: str,
        *,
        path: str | Path | None = None,
        line: int | None = None,
        field: str | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.path = None if path is None else Path(path)
        self.line = line
        self.field = field

    def __str__(self) -> str:
        where = []
        if self.path is not None:
            where.append(str(self.path) + (f", line {self.line}" if self.line is not None else ""))
        elif self.line is not None:
            where.append(f"line {self.line}")
        if self.field is not None:
            where.append(f"field '{self.field}'")
        prefix = ": ".join(where)
        return f"{prefix}: {self.message}" if prefix else self.message
