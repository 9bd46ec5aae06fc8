"""The render plan as a stage with a file (kmpipe.stages.plan_file): ``kmpipe run`` plans each product once, writes
``plan.json`` beside its frames, and renders every chunk from it; a plan read back renders the same pixels as the
plan it was written from; a damaged or foreign plan file is refused naming the file and the field.

References: what ``kmpipe render --explain`` prints for the same scene written as a scene file, the frames rendered by
planning directly (pixel for pixel), and the structure of the line (which products are rendered, in how many
chunks).
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from kmpipe import cli
from kmpipe.errors import InputError
from kmpipe.formats.scene import load_scene
from kmpipe.run.execute import execute
from kmpipe.run.planning import FRAMES_PER_TASK, plan_run
from kmpipe.stages import render_plan
from kmpipe.stages.plan_file import PLAN_FORMAT, plan_to_file, read_plan
from kmpipe.stages.render import render_scene
from renderer.image_io import read_exr, read_png, write_map

REPO = Path(__file__).resolve().parent.parent
FRAMES = 5  # two render tasks a product: frames 0-3 and 4

# colour-science warns that it aligns the CMFs and illuminants to the spectra's grid (intended; see test_report).
pytestmark = pytest.mark.filterwarnings("ignore:Aligning:colour.utilities.ColourRuntimeWarning")

# The scene tables every product of the line shares, as a recipe's template and in each product's scene file.
COMMON = f"""[[light]]
direction = [0.4, 0.8, 0.6]

[camera]
elevation_deg = 30.0

[turntable]
frames = {FRAMES}
"""
# Per product: its recipe entry, and the same scene as a scene file's own tables.
PRODUCTS = {
    "compact": (
        '[[product]]\nname = "Compact"\nmaterial = "F1.json"\nmesh = "compact"\nsubstrate = { reflectance = 0.8 }\n'
        'layer = [{ material = "self", thickness = "40 um", specular = { roughness = 0.3 } }]\n',
        '[scene]\nname = "Plan line"\nproduct = "Compact"\nshade = "Compact"\nmesh = "compact"\nresolution = [32, 32]\n'
        "[substrate]\nreflectance = 0.8\n[ground]\nreflectance = 0.35\n"
        '[[layer]]\nmaterial = "F1.json"\nthickness = "40 um"\nspecular = { roughness = 0.3 }\n',
    ),
    "skin": (
        '[[product]]\nname = "Skin"\nmesh = "sphere"\nskin = { reflectance = "colorchecker:light skin" }\n'
        'layer = [{ material = "Compact", thickness_map = { file = "map.png", channel = "R", max = "20 um" } }]\n',
        '[scene]\nname = "Plan line"\nproduct = "Skin"\nshade = "Skin"\nmesh = "sphere"\nresolution = [32, 32]\n'
        '[skin]\nreflectance = "colorchecker:light skin"\n[ground]\nreflectance = 0.35\n'
        '[[layer]]\nmaterial = "F1.json"\nthickness_map = { file = "map.png", channel = "R", max = "20 um" }\n',
    ),
}
RECIPE = (
    '[line]\nname = "Plan line"\nilluminant = "D65"\n\n[scene]\nresolution = [32, 32]\n\n'
    + "[ground]\nreflectance = 0.35\n\n"
    + COMMON
    + "\n"
    + "\n".join(entry for entry, _ in PRODUCTS.values())
)


@pytest.fixture(scope="module")
def line(tmp_path_factory) -> Path:
    """The line's folder: F1 fitted, a thickness map, the recipe and each product's scene file."""
    folder = tmp_path_factory.mktemp("line")
    assert cli.main(["fit", str(REPO / "recipes/samples/F1/manifest.toml"), "-o", str(folder / "F1.json")]) == 0
    y, x = np.mgrid[0:16, 0:16] / 15.0
    write_map(folder / "map.png", np.stack([x, y, (x + y) / 2.0], axis=-1))
    (folder / "recipe.toml").write_text(RECIPE, encoding="utf-8")
    for slug, (_, scene) in PRODUCTS.items():
        (folder / f"{slug}.toml").write_text(scene + COMMON, encoding="utf-8")
    return folder


@pytest.fixture(scope="module")
def ran(line, tmp_path_factory) -> tuple[Path, int]:
    """The line run in this process with planning counted: (output folder, how many times a scene was planned)."""
    out = tmp_path_factory.mktemp("out")
    planned = []
    real = render_plan.plan_render
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(render_plan, "plan_render", lambda *a, **k: planned.append(1) or real(*a, **k))
        plan = plan_run(line / "recipe.toml", out)
        summary = execute(plan)
    assert summary.failed == [] and summary.frames == FRAMES * len(PRODUCTS)
    return out, len(planned)


def plan_document(out: Path, slug: str) -> dict:
    return json.loads((out / "frames" / slug / "plan.json").read_text(encoding="utf-8"))


# --- kmpipe run -------------------------------------------------------------------------------------------------


def test_each_product_is_planned_once_and_its_chunks_render_from_the_plan(line, ran, tmp_path):
    out, planned = ran
    chunks = -(-FRAMES // FRAMES_PER_TASK)
    assert chunks == 2 and planned == len(PRODUCTS)  # one plan per product, none for its render chunks
    tasks = plan_run(line / "recipe.toml", out).tasks
    for slug in PRODUCTS:
        assert tasks[f"plan:{slug}"].outputs == (str(Path("frames", slug, "plan.json")),)
        renders = [t for t in tasks.values() if t.id.startswith(f"render:{slug}:")]
        assert len(renders) == chunks and all(f"plan:{slug}" in t.deps for t in renders)
    # Frames rendered again (their plan cached): still no planning.
    for path in (out / "frames" / "compact").glob("frame_*"):
        path.unlink()
    planned = []
    real = render_plan.plan_render
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(render_plan, "plan_render", lambda *a, **k: planned.append(1) or real(*a, **k))
        again = plan_run(line / "recipe.toml", out)
        assert {t.id for t in again.tasks.values() if t.state == "pending"} == {
            "render:compact:0-3",
            "render:compact:4-4",
        }
        assert execute(again).failed == []
    assert planned == []


@pytest.mark.parametrize("slug", list(PRODUCTS))
def test_the_plan_file_holds_what_kmpipe_render_explain_prints(line, ran, slug, tmp_path, capsys):
    out, _ = ran
    document = plan_document(out, slug)
    capsys.readouterr()
    assert cli.main(["render", str(line / f"{slug}.toml"), "-o", str(tmp_path / "render"), "--explain"]) == 0
    printed = capsys.readouterr().out
    explain = "\n".join(document["explain"])
    assert explain.startswith("Render plan under D65") and explain in printed
    assert document["format"] == PLAN_FORMAT
    _, header = read_exr(out / "frames" / slug / "frame_000.exr")
    assert document["mode"] == header["render_mode"]
    assert re_chosen(explain) == [document["mode"]]


def re_chosen(explain: str) -> list[str]:
    return re.findall(r"^ +(\S+): max .*<- chosen$", explain, re.M)


def test_the_line_renders_the_frames_kmpipe_render_renders(line, ran, tmp_path, capsys):
    out, _ = ran
    for slug in PRODUCTS:
        assert cli.main(["render", str(line / f"{slug}.toml"), "-o", str(tmp_path / slug)]) == 0
        for i in range(FRAMES):
            for ext in ("exr", "png"):
                assert_same_pixels(
                    out / "frames" / slug / f"frame_{i:03d}.{ext}", tmp_path / slug / f"frame_{i:03d}.{ext}"
                )
    capsys.readouterr()


def assert_same_pixels(a: Path, b: Path) -> None:
    if a.suffix == ".exr":
        np.testing.assert_array_equal(read_exr(a)[0], read_exr(b)[0])
    else:
        np.testing.assert_array_equal(read_png(a), read_png(b))


def test_a_damaged_plan_file_makes_the_run_exit_2_naming_it(line, ran, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(ran[0], out)
    plan = out / "frames" / "compact" / "plan.json"
    document = json.loads(plan.read_text(encoding="utf-8"))
    document["candidates"][-1]["max_dE"] += 0.25  # still a number in range: only the explanation tells
    plan.write_text(json.dumps(document), encoding="utf-8")
    (out / "frames" / "compact" / "frame_004.exr").unlink()  # its render task runs again and reads the plan
    capsys.readouterr()
    assert cli.main(["run", str(line / "recipe.toml"), "-o", str(out)]) == cli.EXIT_BAD_INPUT
    err = " ".join(capsys.readouterr().err.split())
    assert f"render:compact:4-4: {plan}: field 'explain'" in err
    assert not (out / "frames" / "compact" / "frame_004.exr").exists()
    plan.unlink()  # planned again, the run completes
    assert cli.main(["run", str(line / "recipe.toml"), "-o", str(out)]) == cli.EXIT_OK
    assert plan_document(out, "compact") == plan_document(ran[0], "compact")


# --- reading a plan back ----------------------------------------------------------------------------------------


def _set(path: tuple, value):
    def change(document: dict) -> None:
        target = document
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    return change


def _drop(key: str):
    return lambda document: document.pop(key)


DAMAGES = {
    # case: (change of the document, field named)
    "another format": (_set(("format",), "kmpipe-material/1"), "format"),
    "an unknown field": (_set(("colour",), "red"), "colour"),
    "a missing field": (_drop("shadow_lights"), "shadow_lights"),
    "a number as text": (_set(("target_dE",), "0.5"), "target_dE"),
    "a float where an integer goes": (_set(("tables", 0, "n_samples"), 1.0), "tables[1].n_samples"),
    "a negative Delta E": (_set(("candidates", 0, "mean_dE"), -1.0), "candidates[1].mean_dE"),
    "a reflectance above 1": (_set(("stacks", 0, "substrate", 3), 1.5), "stacks[1].substrate[4]"),
    "an unknown mode": (_set(("mode",), "bands:x"), "mode"),
    "a mode that was not tried last": (_set(("mode",), "exact"), "candidates"),
    "channels of another mode": (_set(("tables", 0, "n_channels"), 7), "tables[1].n_channels"),
    "a thickness range that is not its table's": (_set(("thickness_ranges", "F1"), [0.0, 0.04]), "thickness_ranges.F1"),
    "a changed note": (_set(("notes", 0), "shadow maps: none"), "explain"),
    "another scene": (_set(("scene",), "Another line"), "scene"),
    "another scene's fields": (_set(("scene_sha256",), "0" * 64), "scene_sha256"),
    "another material file": (_set(("layers", 0, "sha256"), "0" * 64), "layers"),
    "other lights": (_set(("shadow_lights",), [True, False]), "shadow_lights"),
    "an unknown antialiasing": (_set(("antialiasing",), "fxaa"), "antialiasing"),
    "samples a pixel beyond the renderer's": (_set(("antialias_side",), 9), "antialias_side"),
    "samples that are not the antialiasing's": (
        lambda d: d.update(antialiasing="none", antialias_side=2),
        "antialias_side",
    ),
}


@pytest.mark.parametrize("case", list(DAMAGES))
def test_a_damaged_or_foreign_plan_is_refused_naming_the_field(line, ran, tmp_path, case):
    change, field = DAMAGES[case]
    document = plan_document(ran[0], "compact")
    change(document)
    path = tmp_path / "plan.json"
    path.write_text(json.dumps(document), encoding="utf-8")
    with pytest.raises(InputError) as refused:
        read_plan(path, load_scene(line / "compact.toml"))
    assert (refused.value.path, refused.value.field) == (path, field)


def test_a_plan_written_before_the_antialiasing_field_reads_as_supersampled(line, ran, tmp_path):
    """Plans written before multisampling existed supersampled their frames; read back, they still do."""
    document = plan_document(ran[0], "compact")
    assert document.pop("antialiasing") in ("multisample", "supersample", "none")
    path = tmp_path / "plan.json"
    path.write_text(json.dumps(document), encoding="utf-8")
    assert read_plan(path, load_scene(line / "compact.toml")).antialiasing == "supersample"


@pytest.mark.parametrize("text", ["", "{", '{"format": "kmpipe-render-plan/1", "target_dE": NaN}', "[]"])
def test_a_plan_file_that_is_not_json_or_not_a_plan_is_refused(line, tmp_path, text):
    path = tmp_path / "plan.json"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError, match=r"not a (kmpipe )?render plan") as refused:
        read_plan(path, load_scene(line / "compact.toml"))
    assert refused.value.path == path


def test_the_plan_of_another_product_of_the_line_is_refused(line, ran):
    """Same line, same material (F1), same lights: only the scene's fields tell the skin's plan from the compact's."""
    path = ran[0] / "frames" / "skin" / "plan.json"
    with pytest.raises(InputError) as refused:
        read_plan(path, load_scene(line / "compact.toml"))
    assert (refused.value.path, refused.value.field) == (path, "scene_sha256")
    assert "plan of another scene" in refused.value.message


# --- frames from a plan read back -------------------------------------------------------------------------------

MODES = ["rgb", "bands:6", "exact"]


@pytest.mark.parametrize("slug", list(PRODUCTS))
@pytest.mark.parametrize("mode", MODES)
def test_frames_rendered_from_a_plan_read_back_equal_frames_rendered_by_planning(line, slug, mode, tmp_path):
    """Every mode, on a product substrate (lobes, shadows on a ground) and on skin (a thickness map, the skin's lobe,
    subsurface scattering): the same pixels, EXR and PNG, frame for frame."""
    text = (line / f"{slug}.toml").read_text(encoding="utf-8")
    scene_path = line / f"{slug}_{mode.replace(':', '')}.toml"
    text = text.replace("[scene]\n", f'[scene]\nmode = "{mode}"\n').replace(f"frames = {FRAMES}", "frames = 2")
    scene_path.write_text(text, encoding="utf-8")
    scene = load_scene(scene_path)
    direct = render_scene(scene, tmp_path / "direct", echo=lambda _: None)
    plan_to_file(scene, tmp_path / "plan.json")
    again = render_scene(scene, tmp_path / "again", plan=read_plan(tmp_path / "plan.json", scene), echo=lambda _: None)
    assert [p.name for p in direct] == [p.name for p in again] == ["frame_000.exr", "frame_000.png", "frame_001.exr",
                                                                   "frame_001.png", "turntable.mp4",
                                                                   "turntable.webp"]  # fmt: skip
    for a, b in zip(direct[:4], again[:4], strict=True):  # the frames (the videos are made from them)
        assert_same_pixels(a, b)
    assert read_exr(direct[0])[1]["render_mode"] == mode
