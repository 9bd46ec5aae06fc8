"""Writing files so that nothing half-written is ever left behind.

The text goes to a new temporary file in the destination folder, is flushed and fsynced, then renamed over
the destination (``os.replace``, atomic on POSIX), and the folder entry is fsynced: readers see either the
old file or the complete new one, and a crash at any moment leaves no partial output.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path

from kmpipe.errors import InputError


def write_text_atomically(path: str | Path, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically (mode 0666 less the umask, like an ordinary file).

    An OS error (no such folder, no permission, disk full) becomes an InputError naming the file.
    """
    path = Path(path)
    temporary = path.with_name(f".{path.name}.{secrets.token_hex(8)}.tmp")
    try:
        descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        try:
            with os.fdopen(descriptor, "wb") as handle:
                handle.write(text.encode("utf-8"))
                handle.flush()
                os.fsync(handle.fileno())
            os.replace(temporary, path)
        except BaseException:
            temporary.unlink(missing_ok=True)
            raise
        directory = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(directory)
        finally:
            os.close(directory)
    except OSError as err:
        raise InputError(f"the file cannot be written ({err.strerror or err})", path=path) from None
