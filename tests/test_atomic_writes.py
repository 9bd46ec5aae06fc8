"""The atomic writers (kmpipe.formats.atomic_write and the leaves' copies, instruments.atomic_write and
renderer.atomic_write): a file is replaced whole or not at all, and both the file and its folder entry reach the disk
(fsync) before the writer returns. Every test runs on all three."""

from __future__ import annotations

import importlib
import os
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from kmpipe.errors import InputError
from kmpipe.formats.atomic_write import write_text_atomically

ROOT = Path(__file__).resolve().parents[1]
OLD = b"the old content, whole\n" * 100
NEW = bytes(range(256)) * 4000  # 1 MB: written in several pieces
WRITERS = ["kmpipe.formats.atomic_write", "instruments.atomic_write", "renderer.atomic_write"]


@pytest.fixture(params=WRITERS)
def atomic_write(request):
    return importlib.import_module(request.param)


def test_the_new_content_is_complete_and_nothing_else_is_left(atomic_write, tmp_path):
    path = tmp_path / "card.png"
    path.write_bytes(OLD)
    atomic_write.write_atomically(path, lambda temporary: temporary.write_bytes(NEW))
    assert path.read_bytes() == NEW
    assert [p.name for p in tmp_path.iterdir()] == ["card.png"]
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask  # an ordinary file's mode


def test_a_write_that_fails_midway_leaves_the_old_file_whole(atomic_write, tmp_path):
    path = tmp_path / "card.png"
    path.write_bytes(OLD)

    def half_then_fail(temporary: Path) -> None:
        temporary.write_bytes(NEW[: len(NEW) // 2])
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match="No space left"):
        atomic_write.write_atomically(path, half_then_fail)
    assert path.read_bytes() == OLD
    assert [p.name for p in tmp_path.iterdir()] == ["card.png"]  # the temporary file is removed


def test_a_process_killed_midway_leaves_the_old_file_whole(atomic_write, tmp_path):
    """A crash (no cleanup at all: the process ends inside the writer) never touches the destination."""
    path = tmp_path / "layout.toml"
    path.write_bytes(OLD)
    child = textwrap.dedent(f"""
        import os, sys
        sys.path.insert(0, {str(ROOT)!r})
        from {atomic_write.__name__} import write_atomically

        def crash(temporary):
            with open(temporary, "wb") as handle:
                handle.write(b"half of the new")
                handle.flush()
                os._exit(9)

        write_atomically({str(path)!r}, crash)
    """)
    assert subprocess.run([sys.executable, "-c", child], check=False).returncode == 9
    assert path.read_bytes() == OLD
    leftovers = [p.name for p in tmp_path.iterdir() if p.name != "layout.toml"]
    assert all(name.startswith(".layout.toml.") and name.endswith(".tmp") for name in leftovers)  # hidden


def test_the_file_is_fsynced_before_the_rename_and_the_folder_after(atomic_write, tmp_path, monkeypatch):
    path = tmp_path / "card.pdf"
    synced: list[tuple[str, str, bool]] = []  # (kind, what the descriptor names, destination exists yet)
    real_fsync = os.fsync

    def recording_fsync(descriptor: int) -> None:
        mode = os.fstat(descriptor).st_mode
        target = os.readlink(f"/proc/self/fd/{descriptor}")
        synced.append(("folder" if stat.S_ISDIR(mode) else "file", target, path.exists()))
        real_fsync(descriptor)

    monkeypatch.setattr(atomic_write.os, "fsync", recording_fsync)
    atomic_write.write_atomically(path, lambda temporary: temporary.write_bytes(NEW))
    assert len(synced) == 2
    (kind, target, existed), (folder_kind, folder, _) = synced
    assert kind == "file" and Path(target).parent == tmp_path and Path(target).name.startswith(".card.pdf.")
    assert not existed  # the content was on disk before the new name pointed at it
    assert (folder_kind, Path(folder)) == ("folder", tmp_path)


def test_a_missing_folder_is_an_os_error_and_writes_nothing(atomic_write, tmp_path):
    with pytest.raises(FileNotFoundError):
        atomic_write.write_atomically(tmp_path / "missing" / "card.png", lambda temporary: temporary.write_bytes(NEW))
    assert list(tmp_path.iterdir()) == []


def test_kmpipe_s_text_writer_gives_a_user_facing_error_naming_the_file(tmp_path):
    with pytest.raises(InputError, match="cannot be written") as caught:
        write_text_atomically(tmp_path / "missing" / "material.json", "{}")
    assert caught.value.path == tmp_path / "missing" / "material.json"
    write_text_atomically(tmp_path / "material.json", "ü")
    assert (tmp_path / "material.json").read_bytes() == "ü".encode()
