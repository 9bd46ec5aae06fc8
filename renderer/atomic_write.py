"""Writing a rendered image so that nothing half-written is ever left behind.

The leaves never import kmpipe, so this is the renderer's copy of ``kmpipe.formats.atomic_write``, with the same
guarantee: the content goes to a new temporary file in the destination folder, which is fsynced, then renamed over
the destination (``os.replace``, atomic on POSIX), and the folder entry is fsynced. Readers see either the old file
or the complete new one, and a crash at any moment leaves no partial output.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable
from pathlib import Path


def write_atomically(path: str | os.PathLike[str], write: Callable[[Path], object]) -> None:
    """Write ``path`` atomically: ``write(temporary)`` fills a new file beside it (created empty, mode 0666 less the
    umask, like an ordinary file), which is then fsynced, renamed to ``path``, and the folder fsynced.

    ``write`` gets the temporary file's path, so that a writer that opens files by name (OpenImageIO, matplotlib)
    can write it. If ``write`` raises, the temporary file is removed and ``path`` is untouched.

    Raises
    ------
    OSError
        The folder is missing or not writable, the disk is full; or whatever ``write`` raises.
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
