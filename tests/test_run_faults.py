"""``kmpipe run`` (kmpipe.run) against a hostile or busy output folder: symlinks leading out of it, recipe outputs
that collide, a run killed part way (records, temporary files), two runs at once (the lock), bad scheduler addresses,
damaged task records and a contact sheet too large to make.

Most tests stop at planning or run a tiny line (one product whose material is a file, one frame of 16 px); the
failing-task tests replace the task functions of a plan with stand-ins that write their outputs or fail.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import socket
import threading
from pathlib import Path

import numpy as np
import pytest
from test_run import F1, FACE, L1, make_line

from kmpipe import cli
from kmpipe.errors import InputError
from kmpipe.run.execute import execute
from kmpipe.run.executors import check_executor
from kmpipe.run.folder import LOCK, RECORDS, locked, remove_tree
from kmpipe.run.planning import plan_run

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.filterwarnings("ignore:Aligning:colour.utilities.ColourRuntimeWarning")

TINY = """\
[line]
name = "Tiny line"

[scene]
mesh = "compact"
resolution = [16, 16]
[substrate]
reflectance = 0.8
[[light]]
direction = [0.4, 0.8, 0.6]
[turntable]
frames = 1

[[product]]
name = "M"
material = "m.json"
layer = [{ material = "self", thickness = "1 mm" }]
"""
TINY_TASKS = {"material:m", "plan:m", "render:m:0-0", "sheet"}


@pytest.fixture(scope="module")
def material(tmp_path_factory) -> Path:
    """L1's material, fitted once."""
    path = tmp_path_factory.mktemp("material") / "m.json"
    assert cli.main(["fit", str(ROOT / "recipes" / "samples" / "L1" / "manifest.toml"), "-o", str(path)]) == 0
    return path


def make_tiny(folder: Path, material: Path) -> Path:
    """A line of one product whose material is a file, rendered in one frame of 16 px; returns its recipe."""
    folder.mkdir(parents=True)
    shutil.copyfile(material, folder / "m.json")
    recipe = folder / "recipe.toml"
    recipe.write_text(TINY, encoding="utf-8")
    return recipe


def run(recipe: Path, out: Path, *options: str) -> int:
    return cli.main(["run", str(recipe), "-o", str(out), *options])


def recorded(out: Path) -> set[str]:
    return {p.stem.replace("__", ":") for p in (out / RECORDS).glob("*.json")}


def snapshot(folder: Path) -> dict[str, tuple]:
    """Every entry under ``folder`` (not following symlinks): its kind, content hash and modification time."""
    entries = {}
    for path in [folder, *folder.rglob("*")]:
        info = path.lstat()
        digest = hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() and not path.is_symlink() else None
        entries[str(path.relative_to(folder))] = (info.st_mode, info.st_mtime_ns, info.st_size, digest)
    return entries


def outside_folder(tmp_path: Path) -> Path:
    """A folder beside the output folder, with files in it, that no run may touch."""
    outside = tmp_path / "outside"
    (outside / "session").mkdir(parents=True)
    (outside / "keep.txt").write_text("mine\n", encoding="utf-8")
    (outside / "session" / "session.json").write_text("{}\n", encoding="utf-8")
    return outside


def one_line(text: str) -> str:
    return " ".join(text.split())


# ------------------------------------------------------------------------------------------------- symlinks ---


@pytest.mark.parametrize(
    "link",
    ["products", ".kmpipe", ".kmpipe/tasks", "frames", "reports", f"frames/{FACE}", f"products/{F1}",
     f"products/{F1}/session", f"reports/{L1}", "sheet.png", f"frames/{FACE}/frame_000.exr"],
)  # fmt: skip
def test_a_symlink_leading_out_of_the_output_folder_is_refused_and_nothing_outside_changes(tmp_path, capsys, link):
    recipe = make_line(tmp_path / "line")
    out = tmp_path / "out"
    outside = outside_folder(tmp_path)
    target = outside / "keep.txt" if Path(link).suffix else outside
    (out / link).parent.mkdir(parents=True, exist_ok=True)
    (out / link).symlink_to(target)
    before = snapshot(outside)
    assert run(recipe, out) == cli.EXIT_BAD_INPUT
    err = one_line(capsys.readouterr().err)
    assert str(out / link) in err and "leads outside the output folder" in err
    assert snapshot(outside) == before
    assert recorded(out) == set()


def test_a_symlink_made_after_planning_is_refused_by_the_task_before_it_deletes(tmp_path):
    """The replay of F1 deletes its session folder first: a symlink there, made after planning, is refused."""
    recipe = make_line(tmp_path / "line")
    out = tmp_path / "out"
    outside = outside_folder(tmp_path)
    plan = plan_run(recipe, out, only=["Foundation F1"])
    (out / "products" / F1).mkdir(parents=True)
    (out / "products" / F1 / "session").symlink_to(outside / "session")
    before = snapshot(outside)
    summary = execute(plan)
    material = plan.tasks[f"material:{F1}"]
    assert material.state == "failed"
    assert str(out / "products" / F1 / "session") in material.reason
    assert "leads outside the output folder" in material.reason
    assert summary.failed and snapshot(outside) == before
    assert recorded(out) == set()  # the rest needs F1's material: skipped


def test_removing_a_session_folder_never_follows_a_symlink(tmp_path):
    outside = outside_folder(tmp_path)
    session = tmp_path / "out" / "session"
    (session / "inner").mkdir(parents=True)
    (session / "inner" / "link").symlink_to(outside)
    (session / "file").symlink_to(outside / "keep.txt")
    before = snapshot(outside)
    remove_tree(session)
    assert not os.path.lexists(session)
    link = tmp_path / "out" / "link"
    link.symlink_to(outside)
    remove_tree(link)  # a symlink where the folder was: the link goes, not what it leads to
    assert not os.path.lexists(link)
    assert snapshot(outside) == before


# ------------------------------------------------------------------------------------------------ collisions ---


COLLISIONS = {
    # case: ([outputs] lines, field named, what it collides with)
    "sheet on a frame": (f'sheet = "frames/{FACE}/frame_000.png"', "outputs.sheet", f"render:{FACE}:0-3"),
    "sheet on a record": ('sheet = ".kmpipe/tasks/sheet.png"', "outputs.sheet", "kmpipe's task records"),
    "sheet in a session": (f'sheet = "products/{F1}/session/s.png"', "outputs.sheet", "the material of Foundation F1"),
    "sheet in a report": (f'sheet = "reports/{L1}/s.png"', "outputs.sheet", "the report of Lipstick L1"),
    "frames in products": ('frames = "products"', "outputs.frames", "the products folder"),
    "frames are the reports": ('frames = "out"\nreports = "out"', "outputs.frames", "the reports folder"),
    "reports in the frames": ('reports = "frames/reports"', "outputs.frames", "the reports folder"),
    "frames in records": ('frames = ".kmpipe/frames"', "outputs.frames", "kmpipe's task records"),
    "frames the output folder": ('frames = "."', "outputs.frames", "the output folder"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(COLLISIONS))
def test_colliding_outputs_are_refused_at_planning_and_nothing_is_written(tmp_path, capsys, case):
    lines, field, other = COLLISIONS[case]
    recipe = make_line(tmp_path / "line")
    recipe.write_text(recipe.read_text(encoding="utf-8") + f"\n[outputs]\n{lines}\n", encoding="utf-8")
    out = tmp_path / "out"
    before = snapshot(tmp_path)
    assert run(recipe, out) == cli.EXIT_BAD_INPUT
    err = one_line(capsys.readouterr().err)
    assert f"field '{field}'" in err and "collides with" in err and other in err
    assert snapshot(tmp_path) == before
    assert not out.exists()


def test_the_sheet_in_the_reports_folder_is_no_collision(tmp_path):
    recipe = make_line(tmp_path / "line")
    recipe.write_text(recipe.read_text(encoding="utf-8") + '\n[outputs]\nsheet = "reports/sheet.png"\n',
                      encoding="utf-8")  # fmt: skip
    plan = plan_run(recipe, tmp_path / "out")
    assert plan.tasks["sheet"].outputs == (str(Path("reports", "sheet.png")),)


def test_a_sheet_too_large_to_make_is_refused_at_planning(tmp_path, capsys, material):
    recipe = make_tiny(tmp_path / "line", material)
    text = recipe.read_text(encoding="utf-8").replace("resolution = [16, 16]", "resolution = [4096, 4096]")
    products = "".join(f'\n[[product]]\nname = "N{i}"\nlayer = [{{ material = "M", thickness = "1 mm" }}]\n'
                       for i in range(5))  # fmt: skip
    recipe.write_text(text.replace("frames = 1", "frames = 4") + products, encoding="utf-8")
    assert run(recipe, tmp_path / "out", "--dry-run") == cli.EXIT_BAD_INPUT
    err = one_line(capsys.readouterr().err)
    assert "field 'outputs.sheet'" in err and "at most 300 million pixels of frames" in err


# -------------------------------------------------------------------------------------- records and leftovers ---


def _write_outputs(paths: list[str]) -> dict:
    for path in paths:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text("done\n", encoding="utf-8")
    return {}


def _interrupted(paths: list[str]) -> dict:
    raise KeyboardInterrupt  # as a run killed while this task runs


def test_each_task_is_recorded_as_it_finishes(tmp_path):
    """Three materials ready at once; the second is interrupted: the first one's record is on disk already."""
    recipe = make_line(tmp_path / "line")
    out = tmp_path / "out"
    plan = plan_run(recipe, out)
    plan.tasks = {k: t for k, t in plan.tasks.items() if k.startswith("material:")}
    assert list(plan.tasks) == [f"material:{F1}", f"material:{L1}", "material:blush-b1"]
    for task in plan.tasks.values():
        task.function, task.args = _write_outputs, {"paths": [str(out / o) for o in task.outputs]}
    plan.tasks[f"material:{L1}"].function = _interrupted
    with pytest.raises(KeyboardInterrupt):
        execute(plan)
    assert recorded(out) == {f"material:{F1}"}
    with locked(out):  # let go on the way out
        pass
    again = plan_run(recipe, out)
    assert again.tasks[f"material:{F1}"].state == "cached"


TEMPORARIES = [f"frames/{FACE}/.frame_003.png.a1b2c3d4e5f60718.tmp",
               f"frames/{FACE}/.frame_003.exr.0a1b2c3d4e5f6071.tmp",
               f"frames/{FACE}/..frame_002.exr.0123456789abcdef.tmp.0123456789abcdef.tmp",
               f"reports/{L1}/.report.html.0123456789abcdef.tmp",
               f"products/{F1}/session/.radiance.csv.fedcba9876543210.tmp",
               ".kmpipe/tasks/.sheet.json.00112233445566ff.tmp", ".sheet.png.a1b2c3d4e5f60718.tmp"]  # fmt: skip
KEPT = [f"frames/{FACE}/.notes.txt", f"frames/{FACE}/frame_003.png", "reports/.report.html.tmp", ".hidden.tmp",
        "notes/.sheet.png.a1b2c3d4e5f60718.tmp", f"frames/{FACE}/.frame_002.0123456789abcdef.exr",
        f"frames/{FACE}/.frame_003.abcdefgh.exr",
        f"products/{F1}/.material.json.tmp"]  # not names kmpipe's writers make  # fmt: skip


def test_temporary_files_of_killed_writes_are_deleted_by_the_next_run(tmp_path):
    """kmpipe's own temporary names in the run's folders go; anything else stays, and nothing is followed out."""
    recipe = make_line(tmp_path / "line")
    out = tmp_path / "out"
    outside = outside_folder(tmp_path)
    (outside / ".frame_000.abcdefgh.png").write_bytes(b"not kmpipe's")
    (outside / ".x.0123456789abcdef.tmp").write_bytes(b"not kmpipe's")
    for relative in TEMPORARIES + KEPT:
        (out / relative).parent.mkdir(parents=True, exist_ok=True)
        (out / relative).write_bytes(b"partial")
    (out / "frames" / "elsewhere").symlink_to(outside)  # not a path the run writes: kept, and not entered
    (out / "frames" / FACE / ".frame_004.0123abcd.png").symlink_to(outside / ".frame_000.abcdefgh.png")
    (out / "reports" / ".y.0123456789abcdef.tmp").symlink_to(outside / ".x.0123456789abcdef.tmp")
    before = snapshot(outside)
    plan = plan_run(recipe, out)
    for task in plan.tasks.values():  # nothing to run: the leftovers are cleared before the tasks start
        task.state = "cached"
    execute(plan)
    assert not [relative for relative in TEMPORARIES if os.path.lexists(out / relative)]
    assert all((out / relative).read_bytes() == b"partial" for relative in KEPT)
    assert (out / "frames" / FACE / ".frame_004.0123abcd.png").is_symlink()
    assert (out / "reports" / ".y.0123456789abcdef.tmp").is_symlink()
    assert snapshot(outside) == before


@pytest.mark.parametrize("damage", ["fifo", "garbage", "list", "empty"])
def test_a_damaged_task_record_means_not_cached(tmp_path, material, damage):
    recipe = make_tiny(tmp_path / "line", material)
    out = tmp_path / "out"
    assert run(recipe, out) == cli.EXIT_OK
    record = out / RECORDS / "material__m.json"
    record.unlink()
    if damage == "fifo":
        os.mkfifo(record)  # reading it would wait forever for a writer
    else:
        record.write_text({"garbage": "{not json", "list": "[1, 2]", "empty": ""}[damage], encoding="utf-8")
    plan = plan_run(recipe, out)
    assert plan.tasks["material:m"].state == "pending"
    assert {t.state for k, t in plan.tasks.items() if k != "material:m"} == {"cached"}
    execute(plan)
    assert plan_run(recipe, out).tasks["material:m"].state == "cached"


def test_a_folder_where_a_task_record_goes_is_refused_at_planning(tmp_path, capsys, material):
    recipe = make_tiny(tmp_path / "line", material)
    out = tmp_path / "out"
    (out / RECORDS / "material__m.json").mkdir(parents=True)
    assert run(recipe, out) == cli.EXIT_BAD_INPUT
    assert f"{out / RECORDS / 'material__m.json'}: field '-o': is a folder" in one_line(capsys.readouterr().err)


# ------------------------------------------------------------------------------------------------------ lock ---


def test_a_second_run_on_a_locked_output_folder_is_refused_naming_the_holder(tmp_path, capsys, material):
    recipe = make_tiny(tmp_path / "line", material)
    out = tmp_path / "out"
    with locked(out):
        assert run(recipe, out) == cli.EXIT_BAD_INPUT
        err = one_line(capsys.readouterr().err)
        assert f"pid {os.getpid()} on {socket.gethostname()}" in err and str(out / LOCK) in err
        assert recorded(out) == set()
        assert run(recipe, out, "--dry-run") == cli.EXIT_OK  # planning needs no lock
    assert run(recipe, out) == cli.EXIT_OK
    assert recorded(out) == TINY_TASKS


def test_a_lock_file_left_by_a_dead_run_does_not_block(tmp_path, material):
    recipe = make_tiny(tmp_path / "line", material)
    out = tmp_path / "out"
    (out / LOCK).parent.mkdir(parents=True)
    (out / LOCK).write_text('{"pid": 999999999, "host": "gone", "since": "2020-01-01T00:00:00"}\n', encoding="utf-8")
    assert run(recipe, out) == cli.EXIT_OK
    assert (out / LOCK).read_text(encoding="utf-8") == ""  # let go: no holder named


def test_a_run_told_to_wait_waits_for_the_lock(tmp_path, material):
    recipe = make_tiny(tmp_path / "line", material)
    out = tmp_path / "out"
    plan = plan_run(recipe, out)
    plan.tasks = {"material:m": plan.tasks["material:m"]}  # a file copy: no GL context in the thread
    finished = []
    waiting = threading.Thread(target=lambda: finished.append(execute(plan, wait=True)))
    with locked(out):
        waiting.start()
        waiting.join(1.0)
        assert waiting.is_alive() and not finished and recorded(out) == set()
    waiting.join()
    assert finished[0].ran == 1
    assert recorded(out) == {"material:m"}


def test_the_lock_must_be_a_regular_file(tmp_path, material):
    recipe = make_tiny(tmp_path / "line", material)
    out = tmp_path / "out"
    (out / LOCK).parent.mkdir(parents=True)
    os.mkfifo(out / LOCK)
    with pytest.raises(InputError, match="not a regular file"):
        execute(plan_run(recipe, out))


# ------------------------------------------------------------------------------------------------- scheduler ---


@pytest.mark.parametrize("address", ["not a url", "tcp://host", "host:99999", "http://host:8786", "tcp://:8786",
                                     "host:8786/x", ""])  # fmt: skip
def test_a_scheduler_address_that_is_not_one_is_refused(tmp_path, capsys, material, address):
    recipe = make_tiny(tmp_path / "line", material)
    assert run(recipe, tmp_path / "out", "--executor", "dask", "--scheduler", address) == cli.EXIT_BAD_INPUT
    assert "field '--scheduler'" in one_line(capsys.readouterr().err)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:8786", "tls://scheduler.example.org:8786", "localhost:8786",
                                     "[::1]:8786", "inproc://10.0.0.1/1234/1"])  # fmt: skip
def test_scheduler_addresses_are_accepted(address):
    check_executor("dask", 1, address)


def test_a_scheduler_that_fails_becomes_bad_input(monkeypatch):
    import distributed

    from kmpipe.run.executors import _Dask

    def refuse(address, **_):
        raise ValueError(f"unexpected scheme in {address}")

    monkeypatch.setattr(distributed, "Client", refuse)
    with pytest.raises(InputError, match=r"tcp://127\.0\.0\.1:8786") as raised:
        _Dask("tcp://127.0.0.1:8786", 1)
    assert raised.value.field == "--scheduler"


def test_a_render_task_killed_part_way_keeps_the_frames_it_finished(material, tmp_path):
    """A render task whose record is missing (killed after some frames) renders only the frames not on disk: the
    frames it finished carry its key in their header and are kept, byte for byte; a frame left by another key (the
    recipe changed) is rendered again."""
    from renderer.image_io import read_exr

    recipe = make_tiny(tmp_path / "line", material)
    recipe.write_text(TINY.replace("frames = 1", "frames = 3"), encoding="utf-8")
    out = tmp_path / "out"
    assert run(recipe, out) == 0
    frames = out / "frames" / "m"
    kept = {n: (frames / n).stat().st_mtime_ns for n in ("frame_000.exr", "frame_000.png", "frame_002.exr")}
    pixels = read_exr(frames / "frame_001.exr")[0]
    (out / RECORDS / "render__m__0-2.json").unlink()  # as if killed after its frames 0 and 2 were written
    (frames / "frame_001.exr").unlink()
    assert run(recipe, out) == 0
    assert {n: (frames / n).stat().st_mtime_ns for n in kept} == kept
    np.testing.assert_array_equal(read_exr(frames / "frame_001.exr")[0], pixels)
    assert "render:m:0-2" in recorded(out)

    recipe.write_text(TINY.replace("frames = 1", "frames = 3").replace("1 mm", "2 mm"), encoding="utf-8")
    assert run(recipe, out) == 0
    assert all((frames / n).stat().st_mtime_ns != t for n, t in kept.items())
