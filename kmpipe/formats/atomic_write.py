"""Writing files so that nothing half-written is ever left behind.

The content goes to a new temporary file in the destination folder (``.NAME.<16 hex digits>.tmp``), is fsynced, then
renamed over the destination (``os.replace``, atomic on POSIX), and the folder entry is fsynced: readers see either
the old file or the complete new one, and a crash at any moment leaves no partial output. The leaves, which never
import kmpipe, keep the same writer (``instruments.atomic_write``, ``renderer.atomic_write``); tests check all three.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable
from pathlib import Path

from kmpipe.errors import InputError


def write_atomically(path: str | os.PathLike[str], write: Callable[[Path], object]) -> None:
    """Write ``path`` atomically: ``write(temporary)`` fills a new file beside it (created empty, mode 0666 less the
    umask, like an ordinary file), which is then fsynced, renamed to ``path``, and the folder fsynced.

    ``write`` gets the temporary file's path, so that a writer that opens files by name can write it. If ``write``
    raises, the temporary file is removed and ``path`` is untouched; OSError as raised (see
    :func:`write_text_atomically` for kmpipe's user-facing form).
    """
    path = Path(path)
    temporary = path.with_name(f".{path.name}.{secrets.token_hex(8)}.tmp")
    os.close(os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    try:
        write(temporary)
        descriptor = os.open(temporary, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)


def write_text_atomically(path: str | Path, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically (:func:`write_atomically`).

    An OS error (no such folder, no permission, disk full) becomes an InputError naming the file.
    """
    path = Path(path)
    try:
        write_atomically(path, lambda temporary: temporary.write_bytes(text.encode("utf-8")))
    except OSError as err:
        raise InputError(f"the file cannot be written ({err.strerror or err})", path=path) from None
