"""The file system as a careless or hostile user may hand it over: read regular files only, within a size
limit per format, and write only where the user asked, never over an input and never outside an output folder.

Every problem is an :class:`~kmpipe.errors.InputError` naming the path (and the option or field) and what was
expected, so the command line exits with status 2 and nothing already written is touched.

- :func:`read_bytes` / :func:`read_text`: a device (``/dev/zero``), a FIFO or a folder is "not a regular file" (it is
  never opened for reading, so nothing blocks or fills memory), a file over the format's limit is refused with the
  limit named, and a file that is missing "does not exist".
- :func:`output_file` / :func:`output_folder`: where a command writes: a file's folder must exist, a file is not a
  folder, a folder is not a file, an output is never one of the command's inputs (compared as resolved paths).
- :func:`within`: a path under an output folder that a symlink would lead outside of it is refused.
- :func:`safe_name`: a name that becomes a file name (a sample, a plan, a product): no path separators, not ``.`` or
  ``..``, no control characters.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import stat
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO

from kmpipe.errors import InputError

MiB = 1 << 20
#: Largest file kmpipe reads, in bytes, per format: far above any real file, far below the machine's memory.
LIMITS = {
    "spectral CSV": 64 * MiB,  # 401 wavelengths x 10,000 columns of 15-digit numbers is ~60 MiB
    "TOML": 4 * MiB,  # manifests, plans, recipes, scenes, card layouts, configs
    "material": 64 * MiB,
    "session log": 256 * MiB,
    "session state": 16 * MiB,
    "JSON": 64 * MiB,  # validation documents, task records
    "image": 512 * MiB,  # thickness maps, albedo textures, frames
    "RAW photo": 512 * MiB,
    "mesh": 512 * MiB,
}


#: The limit of a file read in chunks or only in part (hashed, recognised by its first bytes).
UNLIMITED = 1 << 62


def _size(count: int) -> str:
    return f"{count / MiB:.0f} MiB" if count >= MiB else f"{count} bytes"


def is_regular(path: str | os.PathLike) -> bool:
    """True when ``path`` names a regular file (following symlinks); False for anything else, also for a name the
    system refuses (too long, a loop of links), never an exception."""
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except (OSError, ValueError):
        return False


def regular_file(path: str | os.PathLike, what: str, *, field: str | None = None, limit: int | None = None) -> Path:
    """``path`` if it names an existing regular file (a symlink to one is fine) of at most ``limit`` bytes.

    ``what`` says what the file should be (e.g. ``"spectral CSV"``) and picks the limit from :data:`LIMITS`
    unless ``limit`` is given. Refused: a missing file, a folder, anything that is not a regular file (device,
    FIFO, socket), a file over the limit, a name holding a NUL character.
    """
    path = Path(path)
    limit = LIMITS.get(what, 64 * MiB) if limit is None else limit
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise InputError(f"does not exist; expected a {what} file", path=path, field=field) from None
    except OSError as err:
        raise InputError(f"cannot be read ({err.strerror or err}); expected a {what} file", path=path,
                         field=field) from None  # fmt: skip
    except ValueError:  # a name no file can have: the system refuses a NUL character in it
        raise InputError(f"is not a file name (it holds a NUL character); expected a {what} file", path=path,
                         field=field) from None  # fmt: skip
    if stat.S_ISDIR(info.st_mode):
        raise InputError(f"is a folder; expected a {what} file", path=path, field=field)
    if not stat.S_ISREG(info.st_mode):
        raise InputError(f"is not a regular file (a device, FIFO or socket); expected a {what} file", path=path,
                         field=field)  # fmt: skip
    if info.st_size > limit:
        raise InputError(f"is {_size(info.st_size)}; a {what} file may be at most {_size(limit)} (kmpipe's limit "
                         "for this format)", path=path, field=field)  # fmt: skip
    return path


@contextlib.contextmanager
def _opened(path: Path, what: str, field: str | None) -> Iterator[IO[bytes]]:
    """``path`` (checked by :func:`regular_file`) opened for reading without blocking and checked again once open,
    so that a path swapped for a FIFO or a device between the check and the read is still refused."""
    try:
        handle = open(path, "rb", opener=lambda name, flags: os.open(name, flags | os.O_NONBLOCK))  # noqa: SIM115
    except OSError as err:
        raise InputError(f"cannot be read ({err.strerror or err}); expected a {what} file", path=path,
                         field=field) from None  # fmt: skip
    with handle:
        if not stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
            raise InputError(f"is not a regular file; expected a {what} file", path=path, field=field)
        yield handle


def read_bytes(path: str | os.PathLike, what: str, *, field: str | None = None, limit: int | None = None) -> bytes:
    """The bytes of a regular file of at most the format's limit (see :func:`regular_file`); no more than
    ``limit + 1`` bytes are ever read."""
    path = regular_file(path, what, field=field, limit=limit)
    limit = LIMITS.get(what, 64 * MiB) if limit is None else limit
    with _opened(path, what, field) as handle:
        data = handle.read(limit + 1)
    if len(data) > limit:
        raise InputError(f"is larger than {_size(limit)}, kmpipe's limit for a {what} file", path=path, field=field)
    return data


def read_head(path: str | os.PathLike, count: int) -> bytes:
    """The first ``count`` bytes of a regular file (to recognise its format); InputError if it is not one."""
    path = regular_file(path, "file", limit=UNLIMITED)
    with _opened(path, "file", None) as handle:
        return handle.read(count)


def sha256(path: str | os.PathLike, what: str = "input") -> str:
    """Hex SHA-256 of a regular file's bytes (read in 1 MiB chunks: no size limit), the one file hash of kmpipe
    (provenance, cache keys, the plan a session follows); InputError if ``path`` is not a regular file."""
    path = regular_file(path, what, limit=UNLIMITED)
    digest = hashlib.sha256()
    with _opened(path, what, None) as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def read_text(
    path: str | os.PathLike,
    what: str,
    *,
    field: str | None = None,
    limit: int | None = None,
    encoding: str = "utf-8",
) -> str:
    """The text of a regular file (see :func:`read_bytes`); a file that is not ``encoding`` text is refused."""
    data = read_bytes(path, what, field=field, limit=limit)
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as err:
        raise InputError(f"is not UTF-8 text ({err.reason} at byte {err.start}); expected a {what} file",
                         path=path, field=field) from None  # fmt: skip


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True when the two paths name the same file (resolved; hard links count when both exist)."""
    a, b = Path(a), Path(b)
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def refuse_inputs(output: str | os.PathLike, inputs: Iterable, *, field: str | None = "-o") -> None:
    """Refuse an output that is one of the command's ``inputs`` (paths; ``None`` entries are ignored)."""
    for path in inputs:
        if path is not None and same_file(output, path):
            raise InputError(f"is also an input ({path}); kmpipe never writes over its inputs: choose another "
                             "output", path=output, field=field)  # fmt: skip


def output_file(
    path: str | os.PathLike, *, field: str | None = "-o", inputs: Iterable = (), suffixes: Iterable[str] = ()
) -> Path:
    """``path`` checked as a file to write: not a folder, in a folder that exists, not one of ``inputs``.

    An existing regular file is replaced (atomically, by the writer); anything else there is refused.
    ``suffixes`` (e.g. ``(".png",)``), if given, are the file endings accepted.
    """
    path = Path(path)
    suffixes = tuple(suffixes)
    if suffixes and path.suffix.lower() not in suffixes:
        raise InputError(f"must end in {' or '.join(suffixes)}", path=path, field=field)
    if path.is_dir():
        raise InputError("is a folder; expected the name of a file to write", path=path, field=field)
    if os.path.lexists(path) and not path.is_file():
        raise InputError("exists and is not a regular file; kmpipe writes only regular files", path=path,
                         field=field)  # fmt: skip
    parent = path.parent
    if not parent.exists():
        raise InputError(f"cannot be written: its folder {parent} does not exist", path=path, field=field)
    if not parent.is_dir():
        raise InputError(f"cannot be written: {parent} is not a folder", path=path, field=field)
    refuse_inputs(path, inputs, field=field)
    return path


def output_folder(path: str | os.PathLike, *, field: str | None = "-o", create: bool = True) -> Path:
    """``path`` checked as a folder to write into (created with its parents when ``create``)."""
    path = Path(path)
    if os.path.lexists(path) and not path.is_dir():
        raise InputError("exists and is not a folder; expected a folder to write into", path=path, field=field)
    ancestor = path.absolute().parent
    while not os.path.lexists(ancestor):
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise InputError(f"cannot be created: {ancestor} is not a folder", path=path, field=field)
    if create:
        try:
            path.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise InputError(f"the folder cannot be created ({err.strerror or err})", path=path, field=field) from None
    return path


def within(root: str | os.PathLike, path: str | os.PathLike, *, field: str | None = None) -> Path:
    """``path`` (absolute, or relative to ``root``) resolved, refused if it or a symlink on the way leaves ``root``."""
    root = Path(root).resolve()
    try:
        target = (root / path).resolve()
    except (RuntimeError, OSError):  # a loop of symlinks (RuntimeError up to Python 3.12)
        raise InputError("is a loop of symlinks; kmpipe writes only inside the output folder", path=root / path,
                         field=field) from None  # fmt: skip
    if not (target == root or target.is_relative_to(root)):
        raise InputError(f"leads outside the output folder {root} (to {target}, through a symlink or '..'); "
                         "kmpipe writes only inside it", path=Path(root) / path, field=field)  # fmt: skip
    return target


_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def name_problem(name: object) -> str | None:
    """Why ``name`` cannot become a file name (None when it can): a non-empty string without ``/``, ``\\``,
    control characters or surrounding spaces, not ``.`` or ``..``, at most 120 characters."""
    if not isinstance(name, str):
        return f"a name is text, got {type(name).__name__} {name!r}"
    if not name or name.strip() != name:
        return f"a name is non-empty text without leading or trailing spaces, got {name!r}"
    if name in (".", "..") or any(c in name for c in "/\\") or _CONTROL.search(name):
        return f"a name becomes a file name: no '/', '\\', control characters, not '.' or '..'; got {name!r}"
    if len(name) > 120:
        return f"a name is at most 120 characters, got {len(name)}"
    return None


def safe_name(name: object, *, path: str | os.PathLike | None = None, field: str | None = None,
              line: int | None = None) -> str:  # fmt: skip
    """``name`` if it can become a file name (see :func:`name_problem`), else an InputError at ``path``/``field``."""
    problem = name_problem(name)
    if problem is not None:
        raise InputError(problem, path=path, line=line, field=field)
    return name


def _refuse_constant(name: str):
    raise ValueError(f"{name} is not a JSON number (JSON has no NaN or Infinity)")


def read_json(path: str | os.PathLike[str], kind: str, what: str) -> object:
    """The parsed JSON of the regular file ``path`` (at most ``LIMITS[kind]`` bytes), strictly: ``NaN`` and
    ``Infinity`` are refused, as JSON has neither. InputError naming the file (and line) and saying what it should
    have been ("not a {what}: not valid JSON: ...", "not a {what}: the JSON is nested too deeply")."""
    path = Path(path)
    text = read_text(path, kind)
    try:
        return json.loads(text, parse_constant=_refuse_constant)
    except json.JSONDecodeError as err:
        raise InputError(f"not a {what}: not valid JSON: {err.msg}", path=path, line=err.lineno) from None
    except ValueError as err:  # NaN or Infinity, or an integer too long to convert
        raise InputError(f"not a {what}: not valid JSON: {err}", path=path) from None
    except RecursionError:
        raise InputError(f"not a {what}: the JSON is nested too deeply", path=path) from None
