"""The output folder of ``kmpipe run``: its layout, its lock, and the clean-up of what killed writes left."""

from __future__ import annotations

import contextlib
import datetime
import fcntl
import json
import os
import re
import shutil
import socket
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from kmpipe.errors import InputError
from kmpipe.formats.files import within

if TYPE_CHECKING:
    from kmpipe.run.planning import RunPlan

#: kmpipe's own folder under the output folder: task records and the lock.
STATE = Path(".kmpipe")


#: Where task records live, under the output folder.
RECORDS = STATE / "tasks"


#: The lock of the output folder: held by the run writing it, with its pid, host and start time inside.
LOCK = STATE / "lock"


#: Where the products' materials and sessions live, under the output folder.
PRODUCTS = Path("products")


#: Where ``kmpipe trade`` writes its files, under the output folder (``kmpipe run`` reads its frame settings there).
TRADE = Path("trade")


#: Names of the temporary files kmpipe's writers make beside their targets (deleted at the start of a run): every
#: atomic writer (kmpipe.formats.atomic_write, renderer.atomic_write, instruments.atomic_write) names them
#: ``.NAME.<16 hex>.tmp``.
TEMPORARY = re.compile(r"\..+\.[0-9a-f]{16}\.tmp")


#: Whose the records folder is.
RECORDS_OWNER = "kmpipe's task records and lock"


def remove_tree(path: Path) -> None:
    """Delete ``path`` (a folder and everything in it, a file or a symlink) without following any symlink."""
    try:
        info = os.lstat(path)
    except FileNotFoundError:
        return
    if stat.S_ISDIR(info.st_mode):
        shutil.rmtree(path)  # removes symlinks inside as links (shutil.rmtree.avoids_symlink_attacks on Linux)
    else:
        os.unlink(path)


def refuse_symlinks(folder: Path) -> None:
    """Refuse a session folder that holds a symlink (its files are written again, and must stay where they are)."""
    for top, folders, files in os.walk(folder):
        for name in folders + files:
            if os.path.islink(os.path.join(top, name)):
                raise InputError("is a symlink inside a session folder; kmpipe writes a session's files only in "
                                 "its own folder: remove it", path=Path(top, name))  # fmt: skip


@contextlib.contextmanager
def locked(out_dir: str | Path, *, wait: bool = False) -> Iterator[Path]:
    """Hold the lock of an output folder (``.kmpipe/lock``, created with the folder if need be) while in the block.

    The lock is an ``flock`` on the open file, which holds the holder's pid, host and start time (JSON). Another
    holder is refused (InputError naming it: pid, host, since when) unless ``wait``, which waits until it lets go.
    The lock goes on any exit of the block, and with the process, however it ends: a lock file left by a process
    that died holds no lock.
    """
    out_dir = Path(out_dir).absolute()
    path = within(out_dir, LOCK, field="-o")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        descriptor = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, 0o666)
    except OSError as err:
        raise InputError(f"the lock of the output folder cannot be made ({err.strerror or err})", path=path,
                         field="-o") from None  # fmt: skip
    try:
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            raise InputError("is not a regular file; kmpipe's lock of the output folder is", path=path, field="-o")
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            raise InputError(f"the output folder is being written by another kmpipe run ({_holder(descriptor)}); "
                             "wait until it has finished and run again, or run with --wait", path=path,
                             field="-o") from None  # fmt: skip
        holder = {"pid": os.getpid(), "host": socket.gethostname(),
                  "since": datetime.datetime.now().astimezone().isoformat(timespec="seconds")}  # fmt: skip
        os.ftruncate(descriptor, 0)
        os.pwrite(descriptor, (json.dumps(holder) + "\n").encode(), 0)
        try:
            yield path
        finally:
            os.ftruncate(descriptor, 0)  # let go: no holder to name
            fcntl.flock(descriptor, fcntl.LOCK_UN)
    finally:
        os.close(descriptor)


def _holder(descriptor: int) -> str:
    """Who holds a lock, as its file says (it may be still writing it)."""
    try:
        holder = json.loads(os.pread(descriptor, 4096, 0))
        return f"pid {int(holder['pid'])} on {holder['host']}, since {holder['since']}"
    except (OSError, ValueError, TypeError, KeyError):
        return "its pid, host and start time are not written yet"


def clean_temporaries(plan: RunPlan) -> list[Path]:
    """Delete the temporary files that killed writes left in the run's folders (names matching :data:`TEMPORARY`,
    regular files only, never following a symlink); the files deleted. For a run that holds the lock."""
    removed = []
    sheet = next((Path(t.outputs[0]) for t in plan.tasks.values() if t.kind == "sheet"), None)
    places = [(folder, True) for folder in plan.folders()]
    if sheet is not None:
        places.append((plan.out_dir / sheet.parent, False))
    for folder, deep in places:
        if not within(plan.out_dir, folder, field="-o").is_dir():
            continue
        for top, folders, files, descriptor in os.fwalk(folder, follow_symlinks=False):  # a symlink is not entered
            for name in filter(TEMPORARY.fullmatch, files):
                with contextlib.suppress(FileNotFoundError):
                    if stat.S_ISREG(os.stat(name, dir_fd=descriptor, follow_symlinks=False).st_mode):
                        os.unlink(name, dir_fd=descriptor)
                        removed.append(Path(top, name))
            if not deep:
                folders.clear()
    return removed
