"""``kmpipe run`` (kmpipe.run, kmpipe.formats.recipe, kmpipe.cli): a product line's recipe as a graph of cached
tasks.

Every test builds its line in a temporary folder: a copy of the recorded CS-2000 session of F1
(tests/data/sessions/complete.jsonl) with F1's plan, the bundled L1 and B1 samples, a small thickness map, and a
recipe of four products (F1 replayed, L1 and B1 fitted, a face made of the three) at 32 px and 5 frames, so that
each rendered product has a plan task and two render tasks (frames 0-3 and 4). What a test expects comes from the
recipe's structure (which product uses which material, frames per task) and from independent facts: files that parse,
frames equal pixel for pixel between runs, never numbers the code produced.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from kmpipe import cli
from kmpipe.formats.spectra import read_spectra_csv
from kmpipe.run.execute import execute
from kmpipe.run.executors import QUIET, THREAD_VARIABLES, make_executor, worker_environment
from kmpipe.run.folder import LOCK
from kmpipe.run.planning import FRAMES_PER_TASK, plan_run
from renderer.image_io import read_exr, write_map

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "recipes" / "samples"
SESSION = ROOT / "tests" / "data" / "sessions" / "complete.jsonl"
FRAMES = 5

# colour-science warns that it aligns the CMFs and illuminants to the spectra's grid (intended; see test_report).
pytestmark = pytest.mark.filterwarnings("ignore:Aligning:colour.utilities.ColourRuntimeWarning")

RECIPE = f"""\
[line]
name = "Test line"
illuminant = "D65"

[validation]
illuminants = ["D65", "A"]

[scene]
mesh = "compact"
resolution = [32, 32]
[substrate]
reflectance = 0.8
[[light]]
direction = [0.4, 0.8, 0.6]
[ground]
reflectance = 0.35
[camera]
elevation_deg = 30.0
[turntable]
frames = {FRAMES}

[[product]]
name = "Foundation F1"
shade = "F1"
replay = {{ log = "F1.jsonl", plan = "F1/plan.toml" }}
layer = [{{ material = "self", thickness = "40 um" }}]

[[product]]
name = "Lipstick L1"
shade = "L1"
fit = "L1/manifest.toml"
mesh = "lipstick"
layer = [{{ material = "self", thickness = "1 mm", specular = {{ roughness = 0.2 }} }}]

[[product]]
name = "Blush B1"
fit = "B1/manifest.toml"

[[product]]
name = "Face"
mesh = "head"
skin = {{ reflectance = "colorchecker:light skin" }}
[[product.layer]]
material = "Lipstick L1"
thickness_map = {{ file = "map.png", channel = "B", max = "20 um" }}
[[product.layer]]
material = "Blush B1"
thickness_map = {{ file = "map.png", channel = "G", max = "30 um" }}
[[product.layer]]
material = "Foundation F1"
thickness_map = {{ file = "map.png", channel = "R", max = "15 um" }}
"""

# The recipe's structure: product folder names, whose materials are measured (validated), who is rendered with
# which materials.
F1, L1, B1, FACE = "foundation-f1", "lipstick-l1", "blush-b1", "face"
MEASURED = (F1, L1, B1)
STACKS = {F1: (F1,), L1: (L1,), FACE: (L1, B1, F1)}
CHUNKS = [f"{s}-{min(s + FRAMES_PER_TASK, FRAMES) - 1}" for s in range(0, FRAMES, FRAMES_PER_TASK)]


def material_tasks(*products: str) -> set[str]:
    return {f"{kind}:{p}" for p in products for kind in ("material", "validate")}


def render_tasks(*products: str) -> set[str]:
    """A product's render plan, its render chunks and its turntable's videos (the plan is made again whenever a
    render would be, the videos whenever a frame is)."""
    return {f"render:{p}:{c}" for p in products for c in CHUNKS} | {f"{k}:{p}" for p in products
                                                                    for k in ("plan", "video")}  # fmt: skip


ALL_TASKS = material_tasks(*MEASURED) | render_tasks(*STACKS) | {"reports", "sheet"}


def make_line(folder: Path) -> Path:
    """The test line's files in ``folder``; returns its recipe."""
    folder.mkdir(parents=True)
    shutil.copyfile(SESSION, folder / "F1.jsonl")
    (folder / "F1").mkdir()
    shutil.copyfile(SAMPLES / "F1" / "plan.toml", folder / "F1" / "plan.toml")
    for sample in ("L1", "B1"):
        shutil.copytree(SAMPLES / sample, folder / sample)
    y, x = np.mgrid[0:32, 0:32] / 31.0
    write_map(folder / "map.png", np.stack([x, y, (x + y) / 2.0], axis=-1))
    recipe = folder / "recipe.toml"
    recipe.write_text(RECIPE, encoding="utf-8")
    return recipe


def edit(path: Path, old: str, new: str) -> None:
    text = path.read_text(encoding="utf-8")
    assert text.count(old) == 1, f"{old!r} is not once in {path}"
    path.write_text(text.replace(old, new), encoding="utf-8")


def line_of(path: Path, text: str) -> int:
    """1-based line of the only line of ``path`` holding ``text``."""
    numbers = [i for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1) if text in line]
    assert len(numbers) == 1, f"{text!r} is on lines {numbers} of {path}"
    return numbers[0]


def run(recipe: Path, out: Path, *options: str) -> int:
    return cli.main(["run", str(recipe), "-o", str(out), *options])


def run_tasks(recipe: Path, out: Path, **options) -> set[str]:
    """Plan and execute in this process; the ids of the tasks that ran."""
    plan = plan_run(recipe, out, **options)
    execute(plan)
    assert all(t.state in ("run", "cached") for t in plan.tasks.values()), plan.explain()
    return {t.id for t in plan.tasks.values() if t.state == "run"}


def recorded(out: Path) -> set[str]:
    """Ids of the tasks with a record in the output folder."""
    return {p.stem.replace("__", ":") for p in (out / ".kmpipe" / "tasks").glob("*.json")}


def frame_files(out: Path) -> list[Path]:
    return sorted(p.relative_to(out) for p in (out / "frames").rglob("frame_*.*"))


def pixels(path: Path) -> np.ndarray:
    if path.suffix == ".exr":
        return read_exr(path)[0]
    with Image.open(path) as image:
        return np.asarray(image)


def assert_same_frames(out: Path, reference: Path) -> None:
    """Both folders hold every frame of every rendered product, equal pixel for pixel."""
    expected = sorted(Path("frames") / p / f"frame_{i:03d}.{ext}" for p in STACKS for i in range(FRAMES)
                      for ext in ("exr", "png"))  # fmt: skip
    assert frame_files(reference) == expected
    assert frame_files(out) == expected
    for relative in expected:
        assert np.array_equal(pixels(out / relative), pixels(reference / relative)), relative


def visible_files(out: Path) -> set[Path]:
    """Files under ``out`` with no hidden component (outputs; not records or temporary files)."""
    return {p.relative_to(out) for p in out.rglob("*")
            if p.is_file() and not any(part.startswith(".") for part in p.relative_to(out).parts)}  # fmt: skip


def summary_counts(stdout: str) -> tuple[int, int, int, int]:
    """(run, cached, skipped, failed) from the summary line of ``kmpipe run``."""
    text = " ".join(stdout.split())
    found = re.search(r"(\d+) tasks run, (\d+) cached, (\d+) skipped, (\d+) failed", text)
    assert found, stdout
    return tuple(int(n) for n in found.groups())


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> tuple[Path, Path]:
    """The test line run once, uninterrupted, in this process: (recipe, output folder)."""
    folder = tmp_path_factory.mktemp("reference")
    recipe = make_line(folder / "line")
    out = folder / "out"
    assert run(recipe, out) == cli.EXIT_OK
    return recipe, out


# ---------------------------------------------------------------------------------------------- recipe errors ---


def _append(text: str):
    def change(recipe: Path) -> None:
        recipe.write_text(recipe.read_text(encoding="utf-8") + text, encoding="utf-8")

    return change


def _replace(old: str, new: str):
    return lambda recipe: edit(recipe, old, new)


BAD_RECIPES = {
    # case: (change, field named, text of the line named, text the message names)
    "unknown field": (_replace('name = "Test line"', 'nmae = "Test line"'), "line.nmae", "nmae =", "unknown field"),
    "wrong type": (_replace("resolution = [32, 32]", 'resolution = "big"'), "scene.resolution", '"big"', ""),
    "missing replay log": (
        _replace('log = "F1.jsonl"', 'log = "absent.jsonl"'), "product[1].replay.log", "absent.jsonl",
        "absent.jsonl",
    ),
    "missing manifest": (
        _replace('fit = "L1/manifest.toml"', 'fit = "L1/absent.toml"'), "product[2].fit", "absent.toml",
        "absent.toml",
    ),
    "path escaping the output folder": (
        _append('\n[outputs]\nsheet = "../escape.png"\n'), "outputs.sheet", "../escape.png", "../escape.png",
    ),
    "layer naming an unknown product": (
        _replace('layer = [{ material = "self", thickness = "1 mm"', 'layer = [{ material = "Lipstick L9", '
                 'thickness = "1 mm"'), "product[2].layer[1].material", "Lipstick L9", "Lipstick L9",
    ),
}  # fmt: skip


@pytest.mark.parametrize("case", list(BAD_RECIPES))
def test_recipe_error_names_file_line_and_field(tmp_path, capsys, case):
    change, field, line_text, message = BAD_RECIPES[case]
    recipe = make_line(tmp_path / "line")
    change(recipe)
    before = set(tmp_path.rglob("*"))
    assert run(recipe, tmp_path / "out") == cli.EXIT_BAD_INPUT
    err = " ".join(capsys.readouterr().err.split())
    assert f"{recipe}, line {line_of(recipe, line_text)}: field '{field}'" in err
    assert message in err
    # Refused at load: nothing written, neither the output folder nor anything beside it.
    assert set(tmp_path.rglob("*")) == before
    assert not (tmp_path / "out").exists()


def test_recipe_error_in_a_layer_table_names_its_line(tmp_path, capsys):
    recipe = make_line(tmp_path / "line")
    edit(recipe, 'material = "Blush B1"', 'material = "Blush B2"')
    assert run(recipe, tmp_path / "out") == cli.EXIT_BAD_INPUT
    err = " ".join(capsys.readouterr().err.split())
    assert f"{recipe}, line {line_of(recipe, 'Blush B2')}: field 'product[4].layer[2].material'" in err


def test_a_sheet_not_named_png_is_refused_at_load(tmp_path, capsys):
    recipe = make_line(tmp_path / "line")
    recipe.write_text(recipe.read_text(encoding="utf-8") + '\n[outputs]\nsheet = "sheet.jpg"\n', encoding="utf-8")
    assert run(recipe, tmp_path / "out", "--dry-run") == cli.EXIT_BAD_INPUT
    err = " ".join(capsys.readouterr().err.split())
    assert f"{recipe}, line {line_of(recipe, 'sheet.jpg')}: field 'outputs.sheet'" in err


def test_only_naming_an_unknown_product_is_refused(tmp_path, capsys):
    recipe = make_line(tmp_path / "line")
    assert run(recipe, tmp_path / "out", "--only", "Face", "Lipstick L9") == cli.EXIT_BAD_INPUT
    err = " ".join(capsys.readouterr().err.split())
    assert "field '--only'" in err
    assert "Lipstick L9" in err
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------------------------------------------- caching ---


def test_second_run_does_nothing_and_a_change_reruns_only_what_it_affects(tmp_path, capsys):
    recipe = make_line(tmp_path / "line")
    out = tmp_path / "out"
    capsys.readouterr()
    assert run(recipe, out) == cli.EXIT_OK
    assert summary_counts(capsys.readouterr().out) == (len(ALL_TASKS), 0, 0, 0)
    assert recorded(out) == ALL_TASKS

    # Again: every task cached, none executed.
    plan = plan_run(recipe, out)
    assert {t.id for t in plan.tasks.values()} == ALL_TASKS
    assert {t.state for t in plan.tasks.values()} == {"cached"}
    assert execute(plan).ran == 0
    assert run(recipe, out) == cli.EXIT_OK
    assert summary_counts(capsys.readouterr().out) == (0, len(ALL_TASKS), 0, 0)

    # A tiny change to one measurement of L1: L1's tasks, the face (its stack uses L1), the index and the sheet.
    csv = tmp_path / "line" / "L1" / "L1.csv"
    lines = csv.read_text(encoding="utf-8").splitlines(keepends=True)
    row = next(i for i, line in enumerate(lines) if line.startswith("550,"))
    cells = lines[row].rstrip("\n").split(",")
    cells[1] = repr(float(cells[1]) * 1.001)
    lines[row] = ",".join(cells) + "\n"
    csv.write_text("".join(lines), encoding="utf-8")
    assert run_tasks(recipe, out) == material_tasks(L1) | render_tasks(L1, FACE) | {"reports", "sheet"}

    # L1's render thickness: where L1's rendered colour is validated (its uncertainty at that thickness), so L1's
    # validation, the renders that carry its verdict and radius (L1's and the face's), the index and the sheet.
    edit(recipe, 'thickness = "1 mm"', 'thickness = "0.9 mm"')
    assert run_tasks(recipe, out) == {f"validate:{L1}"} | render_tasks(L1, FACE) | {"reports", "sheet"}

    # A thickness map only the face reads: the face's render tasks and the sheet.
    y, x = np.mgrid[0:32, 0:32] / 31.0
    write_map(tmp_path / "line" / "map.png", np.stack([y, x, (x + y) / 2.0], axis=-1))
    assert run_tasks(recipe, out) == render_tasks(FACE) | {"sheet"}
    assert run_tasks(recipe, out) == set()


# ------------------------------------------------------------------------------------------------ crash safety ---


def _complete(path: Path) -> None:
    """Raise unless ``path``, an output, reads completely as what its name says."""
    suffix = path.suffix
    if suffix == ".exr":
        image, _ = read_exr(path)
        assert image.shape[:2] == (32, 32) and np.all(np.isfinite(image)), path
    elif suffix == ".png":
        with Image.open(path) as image:
            image.load()
    elif suffix == ".json":
        json.loads(path.read_text(encoding="utf-8"))
    elif suffix == ".toml":
        tomllib.loads(path.read_text(encoding="utf-8"))
    elif suffix == ".csv":
        read_spectra_csv(path)
    elif suffix == ".html":
        assert path.read_text(encoding="utf-8").rstrip().endswith("</html>"), path
    else:
        raise AssertionError(f"unexpected output {path}")


def test_killed_run_leaves_no_partial_output_and_resumes(tmp_path, reference):
    recipe = make_line(tmp_path / "line")
    out = tmp_path / "out"
    process = subprocess.Popen(
        [sys.executable, "-m", "kmpipe", "run", str(recipe), "-o", str(out)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60.0
        while not list((out / "frames").rglob("frame_*.exr")):
            assert process.poll() is None, "the run ended before its first frame was seen"
            assert time.monotonic() < deadline, "no frame after 60 s"
            time.sleep(0.002)
        process.send_signal(signal.SIGKILL)
    finally:
        process.kill()
        process.wait()
    assert process.returncode == -signal.SIGKILL

    # Every output (a file with no hidden part in its path) reads completely; so does every task record, and the
    # outputs it lists exist.
    for relative in visible_files(out):
        _complete(out / relative)
    records = list((out / ".kmpipe" / "tasks").glob("*.json"))
    for path in records:
        record = json.loads(path.read_text(encoding="utf-8"))
        assert all((out / o).is_file() for o in record["outputs"]), path
    assert recorded(out) < ALL_TASKS  # killed part way
    # Temporary files of interrupted writes may remain; they are hidden (a leading dot), never outputs.
    hidden = {p.relative_to(out) for p in out.rglob("*") if p.is_file()} - visible_files(out) - {LOCK}
    leftovers = {p for p in hidden if p.name.startswith(".")}
    assert {p.parent for p in hidden - leftovers} <= {Path(".kmpipe", "tasks")}  # the rest are task records
    print("temporary files left by the killed run:", sorted(map(str, leftovers)))

    assert run(recipe, out) == cli.EXIT_OK
    assert recorded(out) == ALL_TASKS
    hidden = {p.relative_to(out) for p in out.rglob("*") if p.is_file()} - visible_files(out)
    assert {p for p in hidden if p.parent != Path(".kmpipe", "tasks")} == {LOCK}  # the leftovers are gone
    assert visible_files(out) == visible_files(reference[1])
    assert_same_frames(out, reference[1])


# ------------------------------------------------------------------------------------------------- executors ---


@pytest.mark.parametrize(
    "options", [("--executor", "dask", "--workers", "2"), ("--workers", "2")], ids=["dask-local-cluster", "pool"]
)
def test_other_executors_render_the_same_frames(tmp_path, reference, options):
    recipe = make_line(tmp_path / "line")
    out = tmp_path / "out"
    assert run(recipe, out, *options) == cli.EXIT_OK
    assert recorded(out) == ALL_TASKS
    assert_same_frames(out, reference[1])


def test_worker_environment_shares_the_cores_and_keeps_what_the_user_set(monkeypatch):
    cores = len(os.sched_getaffinity(0))
    for name in THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    assert worker_environment(1) == dict.fromkeys(THREAD_VARIABLES, str(cores))
    assert worker_environment(2 * cores) == dict.fromkeys(THREAD_VARIABLES, "1")  # at least one thread each
    monkeypatch.setenv("LP_NUM_THREADS", "3")
    assert "LP_NUM_THREADS" not in worker_environment(1)


@pytest.mark.parametrize("kind", ["local", "dask"])
def test_workers_start_with_their_share_and_this_process_keeps_its_environment(kind, monkeypatch):
    for name in THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    before = dict(os.environ)
    pool = make_executor(kind, 2, None)
    try:
        seen = {name: pool.submit(os.getenv, name) for name in (*THREAD_VARIABLES, "MALLOC_TRIM_THRESHOLD_")}
        seen = {name: future.result() for name, future in seen.items()}
    finally:
        pool.close()
    share = str(max(1, len(os.sched_getaffinity(0)) // 2))
    assert seen == {**dict.fromkeys(THREAD_VARIABLES, share), "MALLOC_TRIM_THRESHOLD_": None}
    assert dict(os.environ) == before


def test_a_local_dask_cluster_runs_its_workers_without_dashboard_monitors():
    """The local cluster's workers get :data:`QUIET` (their profiler off, monitors slower): it must reach the worker
    processes, which the nanny spawns with the configuration it had when it was made."""
    import dask
    import distributed  # noqa: F401 (its configuration defaults load with it)

    before = {key: dask.config.get(key) for key in QUIET}
    pool = make_executor("dask", 2, None)
    try:
        seen = {key: pool.client.run(dask.config.get, key) for key in QUIET}
    finally:
        pool.close()
    assert all(len(workers) == 2 for workers in seen.values())
    assert {key: set(map(str, workers.values())) for key, workers in seen.items()} == {
        key: {str(value)} for key, value in QUIET.items()
    }
    assert {key: dask.config.get(key) for key in QUIET} == before  # this process's configuration is untouched


# ---------------------------------------------------------------------------------------------------- dry run ---


def _listed(stdout: str) -> dict[str, str]:
    """Task id -> state from the lines of ``--dry-run``."""
    return dict(re.findall(r"^\s+(\S+)\s+(will run|cached|skipped)\b", stdout, flags=re.MULTILINE))


def test_dry_run_lists_every_task_and_writes_nothing(tmp_path, capsys, reference):
    recipe = make_line(tmp_path / "line")
    out = tmp_path / "out"
    before = set(tmp_path.rglob("*"))
    capsys.readouterr()
    assert run(recipe, out, "--dry-run") == cli.EXIT_OK
    assert _listed(capsys.readouterr().out) == dict.fromkeys(ALL_TASKS, "will run")
    assert set(tmp_path.rglob("*")) == before

    recipe, out = reference
    records = {p: p.read_bytes() for p in (out / ".kmpipe" / "tasks").glob("*.json")}
    assert run(recipe, out, "--dry-run") == cli.EXIT_OK
    assert _listed(capsys.readouterr().out) == dict.fromkeys(ALL_TASKS, "cached")
    assert {p: p.read_bytes() for p in (out / ".kmpipe" / "tasks").glob("*.json")} == records


# ---------------------------------------------------------------------------------------- failed validation ---


def make_failing_line(folder: Path) -> Path:
    """The test line with L1's film thicknesses swapped in its manifest: the thicker film then reads farther
    from the masstone than the thinner one, which validation fails."""
    recipe = make_line(folder)
    manifest = folder / "L1" / "manifest.toml"
    text = manifest.read_text(encoding="utf-8")
    assert text.count('thickness = "10 um"') == 2 and text.count('thickness = "20 um"') == 2
    swapped = text.replace('"10 um"', '"x"').replace('"20 um"', '"10 um"').replace('"x"', '"20 um"')
    manifest.write_text(swapped, encoding="utf-8")
    return recipe


@pytest.fixture(scope="module")
def failing(tmp_path_factory) -> tuple[Path, Path, int]:
    """The failing line run without --keep-going: (recipe, output folder, exit status)."""
    folder = tmp_path_factory.mktemp("failing")
    recipe = make_failing_line(folder / "line")
    out = folder / "out"
    status = run(recipe, out)
    verdict = json.loads((out / "reports" / L1 / "validation.json").read_text(encoding="utf-8"))["verdict"]
    assert verdict == "fail"
    return recipe, out, status


def test_failed_validation_skips_the_renders_that_use_it(failing):
    _, out, status = failing
    assert status == cli.EXIT_CHECK_FAILED
    assert not list((out / "frames").rglob(f"{L1}/frame_*"))
    assert not list((out / "frames").rglob(f"{FACE}/frame_*"))  # the face's stack uses L1
    assert frame_files(out) == sorted(Path("frames") / F1 / f"frame_{i:03d}.{ext}" for i in range(FRAMES)
                                      for ext in ("exr", "png"))  # fmt: skip
    assert recorded(out) >= material_tasks(*MEASURED) | render_tasks(F1)
    assert recorded(out) & render_tasks(*STACKS) == render_tasks(F1)


def test_failed_validation_leaves_its_row_out_of_the_sheet(failing, tmp_path):
    recipe, out, _ = failing
    assert (out / "sheet.png").is_file()
    # The same sheet as that of the one product that passed, rendered alone.
    alone = tmp_path / "alone"
    assert run(recipe, alone, "--only", "Foundation F1") == cli.EXIT_OK
    assert np.array_equal(pixels(out / "sheet.png"), pixels(alone / "sheet.png"))


def test_failed_validation_is_listed_in_the_index(failing):
    _, out, _ = failing
    index = out / "reports" / "index.html"
    assert index.is_file()
    assert f"{L1}/report.html" in index.read_text(encoding="utf-8")


def test_keep_going_renders_failed_products_marked(tmp_path):
    recipe = make_failing_line(tmp_path / "line")
    out = tmp_path / "out"
    assert run(recipe, out, "--keep-going") == cli.EXIT_CHECK_FAILED  # a check failed, even if rendered
    assert recorded(out) == ALL_TASKS
    for product in STACKS:
        for i in range(FRAMES):
            _, header = read_exr(out / "frames" / product / f"frame_{i:03d}.exr")
            marked = str(header["validation"])
            if L1 in STACKS[product]:
                assert marked.startswith("fail") and "Lipstick L1" in marked, (product, marked)
            else:
                assert not marked.startswith("fail"), (product, marked)
    _complete(out / "sheet.png")


# ------------------------------------------------------------------------------------------------------- only ---


@pytest.mark.parametrize(
    ("product", "slug"), [("Face", FACE), ("Lipstick L1", L1), ("Blush B1", None)], ids=["face", "lipstick", "blush"]
)
def test_only_runs_a_product_and_the_materials_it_uses(tmp_path, product, slug):
    recipe = make_line(tmp_path / "line")
    out = tmp_path / "out"
    ran = run_tasks(recipe, out, only=[product])
    if slug is None:  # not rendered: its material, its validation and the index
        assert ran == material_tasks(B1) | {"reports"}
    else:
        assert ran == material_tasks(*STACKS[slug]) | render_tasks(slug) | {"reports", "sheet"}
    rendered = {p.parts[1] for p in frame_files(out)}
    assert rendered == (set() if slug is None else {slug})
    assert {p.name for p in (out / "products").iterdir()} == set(STACKS.get(slug, (B1,)))
    assert len(frame_files(out)) == (0 if slug is None else 2 * FRAMES)


def test_only_then_a_full_run_completes_the_line(tmp_path, reference):
    recipe = make_line(tmp_path / "line")
    out = tmp_path / "out"
    run_tasks(recipe, out, only=["Lipstick L1"])
    ran = run_tasks(recipe, out)
    assert ran == ALL_TASKS - material_tasks(L1) - render_tasks(L1)
    assert_same_frames(out, reference[1])
    assert os.path.getsize(out / "sheet.png") > 0


# ---------------------------------------------------------------------------------------------- live measuring ---


def test_a_sample_measured_live_is_measured_once_and_its_recording_replays_to_the_same_material(tmp_path):
    """A product measured on the (emulated) CS-2000 at the recipe's port: the run records the session; a second run
    needs no instrument (the emulator is gone); replaying the recording gives the same K and S."""
    from kmpipe.formats.emulator_script import emulator_from_script
    from kmpipe.formats.material import read_material

    folder = tmp_path / "line"
    folder.mkdir()
    shutil.copyfile(SAMPLES / "F1" / "plan.toml", folder / "plan.toml")
    recipe = folder / "recipe.toml"
    out = tmp_path / "out"
    with emulator_from_script(SAMPLES / "F1" / "emulator.toml", time_scale=0.01, link=tmp_path / "cs2000") as emulator:
        recipe.write_text(
            f'[line]\nname = "Live"\n\n[[product]]\nname = "F1"\nmeasure = {{ plan = "plan.toml", port = '
            f'"{emulator.link}" }}\n',
            encoding="utf-8",
        )
        assert run(recipe, out) == cli.EXIT_OK
    log = out / "products" / "f1" / "session.jsonl"
    assert json.loads(log.read_text(encoding="utf-8").splitlines()[0])["kmpipe_session_log"] == 1
    assert run_tasks(recipe, out) == set()  # measured once: the instrument is not needed again

    replayed = tmp_path / "replayed"
    replayed.mkdir()
    shutil.copyfile(log, replayed / "F1.jsonl")
    shutil.copyfile(folder / "plan.toml", replayed / "plan.toml")
    (replayed / "recipe.toml").write_text(
        '[line]\nname = "Replayed"\n\n[[product]]\nname = "F1"\nreplay = { log = "F1.jsonl", plan = "plan.toml" }\n',
        encoding="utf-8",
    )
    assert run(replayed / "recipe.toml", tmp_path / "out2") == cli.EXIT_OK
    live, again = (read_material(o / "products" / "f1" / "material.json") for o in (out, tmp_path / "out2"))
    np.testing.assert_array_equal(live.K, again.K)
    np.testing.assert_array_equal(live.S, again.S)
