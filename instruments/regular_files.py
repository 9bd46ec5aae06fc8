"""Reading a file a user named, as instruments must (they never import kmpipe, whose ``files`` module does the same
for the pipeline): regular files only (never a device such as ``/dev/zero`` or a FIFO, which would be read until
memory runs out or block forever), opened without blocking, at most ``limit`` bytes."""

from __future__ import annotations

import os
import stat
from pathlib import Path


class NotReadable(ValueError):
    """The path is not a regular file, or the file is larger than the limit; the message says which."""


def read_regular(path: str | os.PathLike[str], limit: int) -> bytes:
    """The bytes of the regular file ``path`` (a symlink to one is fine), of at most ``limit`` bytes.

    Raises
    ------
    NotReadable
        Not a regular file (a folder, device, FIFO, socket) or larger than ``limit`` bytes.
    OSError
        The file does not exist or cannot be opened.
    """
    path = Path(path)
    if not stat.S_ISREG(os.stat(path).st_mode):
        raise NotReadable(f"{path}: not a regular file (a folder, device, FIFO or socket)")
    with open(path, "rb", opener=lambda name, flags: os.open(name, flags | os.O_NONBLOCK)) as handle:
        if not stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
            raise NotReadable(f"{path}: not a regular file")
        data = handle.read(limit + 1)
    if len(data) > limit:
        raise NotReadable(f"{path}: larger than {limit >> 20} MiB, the limit for this kind of file")
    return data
