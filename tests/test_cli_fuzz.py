"""Command-line fuzzing: every command fed malformed files of each format it reads, as a careless or hostile user
would hand them over.

Each example copies valid inputs into a fresh folder, breaks one file (random bytes, truncation, one value replaced
by a hostile token, or the file swapped for a FIFO, a symlink to ``/dev/zero``, a folder, or nothing), runs the
command in-process and asserts what every run must give: exit status 0, 1 or 2 only; no traceback; with status 2, a
message naming the broken file; no input changed and nothing written outside the output folder (the whole work
folder is snapshotted before and after, outside the output folder). The options that name outputs are tried with
an existing file, a folder, a missing parent and an input of the command.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import re
import shutil
import struct
import tempfile
import warnings
import zlib
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from kmpipe.cli import main

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "recipes" / "samples" / "F1"
GOLDEN = ROOT / "tests" / "data" / "golden"

#: Values a careless or hostile file puts where a number, a string or a table belongs.
HOSTILE = (
    "nan", "NaN", "inf", "-inf", "Infinity", "-1", "0", "1e308", "-1e308", "5e-324", "1.5", "1e9", "99", '""',
    '"../../x"', '"/etc/passwd"', '"[/]"', '"bands:99"', "null", "[]", "[[[[[[[[[[1]]]]]]]]]]", "{}", '"\\u0000"',
    "true", '"' + "x" * 300 + '"', '"nan"', '"-1 um"', '"1e400 mm"',
)  # fmt: skip
#: Tokens of a text file that a mutation may replace: numbers, quoted strings, booleans, null.
TOKEN = re.compile(rb'-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?|"[^"\n]*"|\btrue\b|\bfalse\b|\bnull\b')


def snapshot(folder: Path, skip: Path) -> dict[str, tuple]:
    """Every entry under ``folder`` except ``skip``: kind and content hash (files), target (links)."""
    entries = {}
    for dirpath, dirnames, filenames in os.walk(folder):
        here = Path(dirpath)
        dirnames[:] = [d for d in dirnames if here / d != skip and not (here / d).is_symlink()]
        for name in [*filenames, *(d for d in os.listdir(here) if (here / d).is_symlink())]:
            path = here / name
            if path == skip:
                continue
            if path.is_symlink():
                entries[str(path)] = ("link", os.readlink(path))
            elif path.is_file():
                entries[str(path)] = ("file", hashlib.sha256(path.read_bytes()).hexdigest())
            else:
                entries[str(path)] = ("other",)
        entries[str(here)] = ("dir",)
    return entries


def run_cli(argv: list) -> tuple[int, str, str]:
    """Exit status, stdout and stderr of ``kmpipe ARGV``; a numpy RuntimeWarning (printed on a user's stderr) fails."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always", RuntimeWarning)
        try:
            status = main([str(a) for a in argv])
        except SystemExit as exit_:  # argparse
            status = exit_.code
    noise = [w for w in seen if issubclass(w.category, RuntimeWarning)]
    assert not noise, f"a RuntimeWarning reached the user: {noise[0].filename}:{noise[0].lineno}: {noise[0].message}"
    return status, out.getvalue(), err.getvalue()


def assert_well_behaved(argv: list, work: Path, output: Path, broken: Path | None) -> tuple[int, str]:
    """Run ``argv`` and assert the promises every command keeps on any input; the status and stderr."""
    before = snapshot(work, output)
    status, _, err = run_cli(argv)
    assert status in (0, 1, 2), f"exit {status}: {err}"
    assert "Traceback" not in err and "internal error" not in err, err
    if status == 2 and broken is not None:
        assert broken.name in err, f"the message does not name {broken.name}: {err}"
    assert snapshot(work, output) == before, "an input changed or a file was written outside the output folder"
    return status, err


@dataclass(frozen=True)
class Breakage:
    """How one file is broken: ``kind`` and its parameters (drawn by hypothesis)."""

    kind: str
    position: float = 0.0
    token: str = ""
    data: bytes = b""

    def apply(self, path: Path) -> None:
        original = path.read_bytes()
        if self.kind in ("fifo", "devzero", "folder", "missing"):
            path.unlink()
            if self.kind == "fifo":
                os.mkfifo(path)
            elif self.kind == "devzero":
                path.symlink_to("/dev/zero")
            elif self.kind == "folder":
                path.mkdir()
        elif self.kind == "bytes":
            path.write_bytes(self.data)
        elif self.kind == "truncate":
            path.write_bytes(original[: int(self.position * len(original))])
        else:  # one token replaced by a hostile value
            tokens = list(TOKEN.finditer(original))
            if not tokens:
                path.write_bytes(self.token.encode())
                return
            match = tokens[min(int(self.position * len(tokens)), len(tokens) - 1)]
            path.write_bytes(original[: match.start()] + self.token.encode() + original[match.end() :])


fractions = st.floats(0, 1, exclude_max=True)
breakages = st.one_of(
    st.builds(Breakage, kind=st.just("token"), position=fractions, token=st.sampled_from(HOSTILE)),
    st.builds(Breakage, kind=st.just("truncate"), position=fractions),
    st.builds(Breakage, kind=st.just("bytes"), data=st.binary(max_size=400)),
    st.sampled_from([Breakage("fifo"), Breakage("devzero"), Breakage("folder"), Breakage("missing")]),
)  # fmt: skip
text_breakages = breakages.filter(lambda b: b.kind != "bytes")  # where random bytes say nothing new
FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
FUZZ_SLOW = settings(FUZZ, max_examples=15)


@contextlib.contextmanager
def workspace(setup: Callable[[Path], None]):
    with tempfile.TemporaryDirectory() as name:
        work = Path(name)
        setup(work)
        yield work


def copy_sample(work: Path) -> None:
    for name in ("F1.csv", "backings.csv", "white.csv", "manifest.toml", "plan.toml"):
        shutil.copy(SAMPLE / name, work / name)


@pytest.fixture(scope="module")
def material(tmp_path_factory) -> Path:
    """F1 fitted from its manifest: a real material whose provenance points at real measurements."""
    folder = tmp_path_factory.mktemp("material")
    copy_sample(folder)
    status, _, err = run_cli(["fit", folder / "manifest.toml", "-o", folder / "F1.json"])
    assert status == 0, err
    return folder


# ------------------------------------------------------------------------------------------- malformed files ---


@FUZZ
@given(target=st.sampled_from(["F1.csv", "white.csv"]), breakage=breakages)
def test_ingest_on_broken_spectra(target, breakage):
    with workspace(copy_sample) as work:
        breakage.apply(work / target)
        argv = ["ingest", work / "F1.csv", "--white", f"{work / 'white.csv'}:baso4",
                "--dark", f"{work / 'white.csv'}:dark", "-o", work / "out" / "r.csv"]  # fmt: skip
        (work / "out").mkdir()
        assert_well_behaved(argv, work, work / "out", work / target)


@FUZZ
@given(target=st.sampled_from(["manifest.toml", "F1.csv", "backings.csv", "white.csv"]), breakage=text_breakages)
@example(target="manifest.toml", breakage=Breakage(kind="token", position=0.5, token='"\\u0000"'))  # a NUL in a path
def test_fit_on_broken_manifests_and_spectra(target, breakage):
    with workspace(copy_sample) as work:
        breakage.apply(work / target)
        (work / "out").mkdir()
        argv = ["fit", work / "manifest.toml", "-o", work / "out" / "F1.json", "--grid", "400:700:20"]
        status, _ = assert_well_behaved(argv, work, work / "out", work / target)
        if status == 0:
            assert (
                "NaN" not in (work / "out" / "F1.json").read_text()
                and "Infinity" not in (work / "out" / "F1.json").read_text()
            )


@FUZZ_SLOW
@given(breakage=breakages)
@example(breakage=Breakage(kind="token", position=0.5, token="1e308"))  # (draws: a budget whose covariance overflows,
@example(breakage=Breakage(kind="token", position=0.5, token="-1e308"))  # a noise block that is not semidefinite)
def test_validate_on_broken_materials(material, breakage):
    def setup(work: Path) -> None:
        copy_sample(work)
        shutil.copy(material / "F1.json", work / "F1.json")
        (work / "good").mkdir()
        shutil.copy(material / "F1.json", work / "good" / "G1.json")

    with workspace(setup) as work:
        breakage.apply(work / "F1.json")
        assert_well_behaved(["validate", work / "F1.json", "-o", work / "out"], work, work / "out", work / "F1.json")


def test_validate_folder_reports_the_broken_material_and_goes_on(material, tmp_path):
    line = tmp_path / "line"
    line.mkdir()
    copy_sample(line)  # the materials' provenance names the manifest beside them
    shutil.copy(material / "F1.json", line / "F1.json")
    text = (material / "F1.json").read_text()
    (line / "B1.json").write_text(text.replace('"name": "F1"', '"name": "B1"').replace('"K": [', '"K": [NaN, ', 1))
    os.mkfifo(line / "Z9.json")  # a FIFO among the materials is reported, not read until memory runs out
    status, err = assert_well_behaved(["validate", line, "-o", tmp_path / "out"], tmp_path, tmp_path / "out", None)
    assert status == 2
    assert "B1.json" in err and "Z9.json" in err and "not a regular file" in err
    assert (tmp_path / "out" / "F1" / "report.html").is_file()  # the good one was validated


@FUZZ
@given(target=st.sampled_from(["plan.toml", "F1.jsonl"]), breakage=text_breakages)
def test_measure_replay_on_broken_plans_and_logs(target, breakage):
    def setup(work: Path) -> None:
        shutil.copy(SAMPLE / "plan.toml", work / "plan.toml")
        shutil.copy(ROOT / "recipes" / "demo" / "sessions" / "F1.jsonl", work / "F1.jsonl")

    with workspace(setup) as work:
        breakage.apply(work / target)
        argv = ["measure", work / "plan.toml", "--port", f"replay://{work / 'F1.jsonl'}", "--unattended",
                "-o", work / "out"]  # fmt: skip
        assert_well_behaved(argv, work, work / "out", work / target)


@FUZZ_SLOW
@given(breakage=text_breakages)
def test_card_on_broken_layouts(breakage):
    def setup(work: Path) -> None:
        status, _, err = run_cli(["card", "-o", work / "card.png"])
        assert status == 0, err
        (work / "card.png").unlink()

    with workspace(setup) as work:
        breakage.apply(work / "card.layout.toml")
        (work / "out").mkdir()
        argv = ["card", "--layout", work / "card.layout.toml", "-o", work / "out" / "card.png"]
        assert_well_behaved(argv, work, work / "out", work / "card.layout.toml")


@FUZZ_SLOW
@given(breakage=breakages)
def test_sheet_on_broken_frames(breakage):
    def setup(work: Path) -> None:
        for name in ("compact_000.exr", "compact_001.exr"):
            shutil.copy(GOLDEN / name, work / name)

    with workspace(setup) as work:
        breakage.apply(work / "compact_001.exr")
        (work / "out").mkdir()
        argv = ["sheet", work / "compact_000.exr", work / "compact_001.exr", "-o", work / "out" / "sheet.png"]
        assert_well_behaved(argv, work, work / "out", work / "compact_001.exr")


def small_scene(work: Path, material: Path) -> None:
    (work / "materials").mkdir()
    shutil.copy(material / "F1.json", work / "materials" / "F1.json")
    text = (ROOT / "recipes" / "scenes" / "F1_compact.toml").read_text()
    text = text.replace("resolution = [256, 256]", "resolution = [48, 48]").replace("frames = 8", "frames = 1")
    (work / "scene.toml").write_text(text)


@FUZZ_SLOW
@given(target=st.sampled_from(["scene.toml", "materials/F1.json"]), breakage=text_breakages)
def test_render_on_broken_scenes_and_materials(material, target, breakage):
    with workspace(lambda work: small_scene(work, material)) as work:
        breakage.apply(work / target)
        argv = ["render", work / "scene.toml", "-o", work / "out"]
        status, _ = assert_well_behaved(argv, work, work / "out", work / target)
        if status == 0:
            assert sorted(p.name for p in (work / "out").iterdir()) == ["frame_000.exr", "frame_000.png"]


def small_recipe(work: Path, material: Path) -> None:
    shutil.copy(material / "F1.json", work / "F1.json")
    (work / "recipe.toml").write_text(
        '[line]\nname = "Fuzz line"\nilluminant = "D65"\n\n[scene]\nmesh = "card"\nresolution = [32, 32]\n\n'
        "[substrate]\nreflectance = 0.8\n\n[[light]]\ndirection = [0.3, 0.8, 0.5]\nradiance = [1.0, 1.0, 1.0]\n\n"
        '[turntable]\nframes = 2\n\n[[product]]\nname = "F1"\nshade = "Beige"\nmaterial = "F1.json"\n\n'
        '[[product.layer]]\nmaterial = "self"\nthickness = "30 um"\n'
    )


@FUZZ
@given(breakage=text_breakages)
@example(breakage=Breakage(kind="token", position=0.875, token='"\\u0000"'))  # (CI's draw: a path with a NUL)
def test_run_plans_broken_recipes(material, breakage):
    with workspace(lambda work: small_recipe(work, material)) as work:
        breakage.apply(work / "recipe.toml")
        argv = ["run", work / "recipe.toml", "-o", work / "out", "--dry-run"]
        assert_well_behaved(argv, work, work / "out", work / "recipe.toml")


def test_the_small_recipe_runs(material, tmp_path):
    """The recipe the fuzzer breaks is itself good: it renders its two frames, their videos and a sheet."""
    small_recipe(tmp_path, material)
    status, _, err = run_cli(["run", tmp_path / "recipe.toml", "-o", tmp_path / "out"])
    assert status == 0, err
    assert sorted(p.name for p in (tmp_path / "out" / "frames" / "f1").iterdir()) == [
        "frame_000.exr", "frame_000.png", "frame_001.exr", "frame_001.png", "plan.json", "turntable.mp4",
        "turntable.webp"]  # fmt: skip


@pytest.fixture(scope="module")
def raw_card(tmp_path_factory):
    from instruments.drawdown_card.layout import default_layout
    from kmpipe.formats.card_layout import write_card_layout
    from tests.card_photo import Scene, photograph

    folder = tmp_path_factory.mktemp("raw")
    layout = default_layout()
    write_card_layout(layout, folder / "layout.toml")
    scene = Scene(backings={"black": np.array([0.04, 0.035, 0.03]), "white": np.array([0.86, 0.84, 0.8])},
                  K=np.array([8.0, 15.0, 30.0]), S=np.array([60.0, 55.0, 50.0]))  # fmt: skip
    photograph(layout, replace(scene, angle_deg=5.0), folder / "photo.dng", seed=0)
    return folder


@FUZZ_SLOW
@given(target=st.sampled_from(["photo.dng", "layout.toml"]), breakage=breakages)
# found by a random draw in CI: a RAW that still decodes, its black backing read at a negative reflectance
@example(target="photo.dng", breakage=Breakage(kind="token", position=0.875, token="-inf"))
def test_ingest_raw_on_broken_photos_and_layouts(raw_card, target, breakage):
    def setup(work: Path) -> None:
        for name in ("photo.dng", "layout.toml"):
            shutil.copy(raw_card / name, work / name)

    with workspace(setup) as work:
        breakage.apply(work / target)
        argv = ["ingest-raw", work / "photo.dng", "--layout", work / "layout.toml", "-o", work / "out",
                "--thickness", "30 um"]  # fmt: skip
        assert_well_behaved(argv, work, work / "out", work / target)


# --------------------------------------------------------------------------------------------- output paths ---


def _commands(work: Path, out: Path) -> dict[str, list]:
    """Each command with valid inputs in ``work`` and its output option set to ``out``."""
    return {
        "ingest": ["ingest", work / "F1.csv", "--white", f"{work / 'white.csv'}:baso4", "-o", out],
        "fit": ["fit", work / "manifest.toml", "-o", out, "--grid", "400:700:50"],
        "validate": ["validate", work / "F1.json", "-o", out],
        "measure": [
            "measure",
            work / "plan.toml",
            "--port",
            f"replay://{work / 'F1.jsonl'}",
            "--unattended",
            "-o",
            out,
        ],
        "card": ["card", "-o", out],
        "sheet": ["sheet", work / "compact_000.exr", "-o", out],
        "render": ["render", work / "scene.toml", "-o", out],
        "run": ["run", work / "recipe.toml", "-o", out],
    }


#: What each command writes: a file (with its suffix) or a folder.
WRITES = {"ingest": ".csv", "fit": ".json", "validate": "/", "measure": "/", "card": ".png", "sheet": ".png",
          "render": "/", "run": "/"}  # fmt: skip


def _all_inputs(work: Path, material: Path) -> None:
    copy_sample(work)
    shutil.copy(material / "F1.json", work / "F1.json")
    shutil.copy(ROOT / "recipes" / "demo" / "sessions" / "F1.jsonl", work / "F1.jsonl")
    shutil.copy(GOLDEN / "compact_000.exr", work / "compact_000.exr")
    from instruments.drawdown_card.layout import default_layout
    from kmpipe.formats.card_layout import write_card_layout

    write_card_layout(default_layout(), work / "L.png")  # a layout under a name a card could have
    small_scene(work, material)
    small_recipe(work, material)


def _output_cases():
    for command, writes in sorted(WRITES.items()):
        cases = ["file-for-folder", "bad-parent", "an-input"]
        if writes != "/" and command != "fit":  # fit -o FOLDER writes SAMPLE.json into it
            cases.append("folder-for-file")
        yield from ((command, case) for case in cases)


#: The input each command is asked to write over.
INPUT_OF = {"ingest": "F1.csv", "fit": "manifest.toml", "validate": "F1.json", "measure": "plan.toml",
            "card": "L.png", "sheet": "compact_000.exr", "render": "scene.toml", "run": "recipe.toml"}  # fmt: skip


@pytest.mark.parametrize(("command", "case"), list(_output_cases()))
def test_output_options_are_checked(material, tmp_path, command, case):
    _all_inputs(tmp_path, material)
    writes = WRITES[command]
    if case == "folder-for-file":
        out = tmp_path / f"taken{writes}"
        out.mkdir()
    elif case == "file-for-folder":
        out = tmp_path / "taken"
        out.write_text("not to be replaced\n")
        if writes != "/":
            out = out / f"inside{writes}"  # a file where the output's folder must be
    elif case == "bad-parent":
        out = tmp_path / "no" / "such" / f"file{writes}" if writes != "/" else tmp_path / "plan.toml" / "folder"
    else:
        out = tmp_path / INPUT_OF[command]
    argv = _commands(tmp_path, out)[command]
    if command == "card" and case == "an-input":
        argv = ["card", "--layout", out, "-o", out]
    before = snapshot(tmp_path, tmp_path / "never")
    status, _, err = run_cli(argv)
    assert status == 2, err
    assert "Traceback" not in err
    assert out.name in err or out.parent.name in err
    assert snapshot(tmp_path, tmp_path / "never") == before


# ------------------------------------------------------------------------------ the audit's cases, by name ---


def test_ingest_never_writes_over_its_dark_or_certified_file(tmp_path):
    copy_sample(tmp_path)
    certified = tmp_path / "certified.csv"
    certified.write_text("# kmpipe-spectra: 1\n# quantity: reflectance\n# units: 1\nwavelength_nm,baso4\n"
                         + "".join(f"{w},0.97\n" for w in range(380, 781)))  # fmt: skip
    for output, extra in ((tmp_path / "white.csv", ["--dark", f"{tmp_path / 'white.csv'}:dark"]),
                          (certified, ["--certified", f"{certified}:baso4"]),
                          (certified, ["--certified", str(certified)])):  # fmt: skip
        before = snapshot(tmp_path, tmp_path / "never")
        argv = ["ingest", tmp_path / "F1.csv", "--white", f"{tmp_path / 'backings.csv'}:white", *extra, "-o", output]
        status, _, err = run_cli(argv)
        assert status == 2 and "never writes over its inputs" in err and output.name in err, err
        assert snapshot(tmp_path, tmp_path / "never") == before


def test_card_keeps_an_edited_layout_beside_it(tmp_path):
    card = tmp_path / "X.png"
    assert run_cli(["card", "-o", card])[0] == 0
    layout = tmp_path / "X.layout.toml"
    assert run_cli(["card", "-o", card])[0] == 0  # the built-in layout, unchanged: written again, the same
    commented = layout.read_text().replace("[card]", "# printed on our Epson\n[card]", 1)
    layout.write_text(commented)  # the same layout with a comment: kept as it is, the card drawn from it
    assert run_cli(["card", "-o", card])[0] == 0
    assert layout.read_text() == commented
    edited = commented.replace("{ id = 1, x_mm = 190.0,", "{ id = 1, x_mm = 189.0,", 1)
    assert edited != commented
    layout.write_text(edited)  # another layout: never replaced, the card not drawn over it
    status, _, err = run_cli(["card", "-o", card])
    assert status == 2 and "X.layout.toml" in err and "--layout" in err
    assert layout.read_text() == edited
    assert run_cli(["card", "--layout", layout, "-o", card])[0] == 0  # drawn from the edited layout
    assert layout.read_text() == edited


def test_fit_refuses_sample_names_that_leave_the_output_folder(tmp_path):
    for name in ("../../x", "/tmp/x", ".."):
        work = tmp_path / name.strip("./").replace("/", "_") if name != ".." else tmp_path / "dots"
        work.mkdir()
        copy_sample(work)
        text = (work / "manifest.toml").read_text().replace('name = "F1"', f"name = {json.dumps(name)}")
        (work / "manifest.toml").write_text(text)
        shutil.copy(work / "manifest.toml", work / "second.toml")
        (work / "out").mkdir()
        before = snapshot(tmp_path, work / "out")
        status, _, err = run_cli(["fit", work / "manifest.toml", work / "second.toml", "-o", work / "out"])
        assert status == 2 and "sample.name" in err and "manifest.toml" in err, err
        assert snapshot(tmp_path, work / "out") == before and not any((work / "out").iterdir())


def test_ingest_raw_refuses_a_name_that_leaves_the_output_folder(raw_card, tmp_path):
    argv = ["ingest-raw", raw_card / "photo.dng", "--layout", raw_card / "layout.toml", "-o", tmp_path / "S",
            "--thickness", "30 um", "--name", "../../x"]  # fmt: skip
    status, _, err = run_cli(argv)
    assert status == 2 and "--name" in err and not (tmp_path / "S").exists()


def test_user_text_is_printed_as_it_is_not_as_markup(material, tmp_path):
    """A line or product name holding rich markup ([/], [bold]) is shown literally; it crashed the table before."""
    small_recipe(tmp_path, material)
    text = (tmp_path / "recipe.toml").read_text()
    text = text.replace('name = "Fuzz line"', 'name = "Line [/] [bold]x"').replace('name = "F1"', 'name = "F1 [red]"')
    (tmp_path / "recipe.toml").write_text(text.replace('"Beige"', '"Beige [/]"'))
    status, out, err = run_cli(["run", tmp_path / "recipe.toml", "-o", tmp_path / "out"])
    assert status == 0, err
    assert "Line [/] [bold]x" in out and "F1 [red]" in out


def test_debug_adds_the_traceback_and_keeps_the_exit_status(tmp_path):
    status, _, err = run_cli(["--debug", "fit", tmp_path / "missing.toml", "-o", tmp_path / "m.json"])
    assert status == 2
    assert "Traceback" in err and "InputError" in err and "missing.toml" in err


def _png_header_only(path: Path, width: int, height: int) -> None:
    """A PNG whose header says ``width`` x ``height`` (8-bit grey) and whose pixels are missing: a reader that
    checks the header first refuses it at once; one that decodes first would allocate width x height bytes."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"")) +
                     chunk(b"IEND", b""))  # fmt: skip


def test_sheet_refuses_a_frame_too_large_from_its_header(tmp_path):
    _png_header_only(tmp_path / "huge.png", 20000, 20000)
    shutil.copy(GOLDEN / "compact_000.exr", tmp_path / "a.exr")
    status, _, err = run_cli(["sheet", tmp_path / "a.exr", tmp_path / "huge.png", "-o", tmp_path / "s.png"])
    assert status == 2 and "huge.png" in err and "20000 x 20000" in err, err
    assert not (tmp_path / "s.png").exists()


def test_render_never_writes_over_a_file_its_scene_reads(material, tmp_path):
    """A thickness map named like a frame, in the output folder: refused before any frame is written."""
    small_scene(tmp_path, material)
    from renderer.image_io import write_png

    write_png(tmp_path / "frame_000.png", np.full((8, 8, 3), 0.5))
    text = (
        (tmp_path / "scene.toml")
        .read_text()
        .replace('thickness = "40 um"', 'thickness_map = { file = "frame_000.png", max = "40 um" }')
    )
    (tmp_path / "scene.toml").write_text(text.replace('mesh = "compact"', 'mesh = "card"'))
    before = snapshot(tmp_path, tmp_path / "never")
    status, _, err = run_cli(["render", tmp_path / "scene.toml", "-o", tmp_path])
    assert status == 2 and "frame_000.png" in err and "never writes over its inputs" in err, err
    assert snapshot(tmp_path, tmp_path / "never") == before


@FUZZ
@given(target=st.sampled_from(["emulator.toml", "emulator_reflectance.csv"]), breakage=breakages)
def test_emulate_on_broken_scripts(target, breakage):
    """A broken samples script or reflectance file: the emulator's loader says so (InputError), and ``kmpipe
    emulate`` exits 2 naming the file before it listens; a script still valid loads (it would serve forever)."""
    from kmpipe.errors import InputError
    from kmpipe.formats.emulator_script import emulator_from_script

    def setup(work: Path) -> None:
        for name in ("emulator.toml", "emulator_reflectance.csv"):
            shutil.copy(SAMPLE / name, work / name)

    with workspace(setup) as work:
        breakage.apply(work / target)
        try:
            emulator_from_script(work / "emulator.toml")
        except InputError:
            argv = ["emulate", "--samples", work / "emulator.toml", "--link", work / "out" / "cs2000"]
            status, _ = assert_well_behaved(argv, work, work / "out", work / target)
            assert status == 2


def test_a_csv_named_by_a_manifest_is_named_with_the_manifest_and_emoji_codes_stay_text(tmp_path):
    """The broken file and the manifest that named it are both in the message; ':x:' in it is not an emoji."""
    copy_sample(tmp_path)
    (tmp_path / "odd.csv").write_text("root:x:0:0\n")
    text = (tmp_path / "manifest.toml").read_text().replace('file = "F1.csv"', 'file = "odd.csv"', 1)
    (tmp_path / "manifest.toml").write_text(text)
    status, _, err = run_cli(["fit", tmp_path / "manifest.toml", "-o", tmp_path / "m.json"])
    assert status == 2 and "odd.csv" in err and "manifest.toml" in err and "masstone" in err, err
    assert "root:x:0:0" in err


def test_validate_never_writes_its_report_over_an_input(material, tmp_path):
    """A manifest named validation.json beside its material, reports asked for in that folder: refused."""
    copy_sample(tmp_path)
    (tmp_path / "manifest.toml").rename(tmp_path / "validation.json")
    shutil.copy(material / "F1.json", tmp_path / "F1.json")
    before = snapshot(tmp_path, tmp_path / "never")
    argv = ["validate", tmp_path / "F1.json", "--manifest", tmp_path / "validation.json", "-o", tmp_path]
    status, _, err = run_cli(argv)
    assert status == 2 and "never writes over its inputs" in err and "validation.json" in err, err
    assert snapshot(tmp_path, tmp_path / "never") == before
