"""recipes/thesis/recipe.toml: the thesis's head figures (5.5, 5.58, 5.59) as a product line, planned, not rendered.

The plan is what ``kmpipe run --dry-run`` prints (:func:`kmpipe.run.planning.plan_run`); the expected products,
stacks and thicknesses are the ones recipes/thesis/README.md states, written out here by hand.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from kmpipe import cli
from kmpipe.formats.manifest import parse_thickness_mm
from kmpipe.formats.recipe import load_recipe, slug
from kmpipe.formats.scene import SceneFile
from kmpipe.run.planning import plan_run

THESIS = Path(__file__).resolve().parents[1] / "recipes" / "thesis"
RECIPE = THESIS / "recipe.toml"
MAP = THESIS.parent / "scenes" / "head_makeup.png"

MATERIALS = {"Foundation F1": "F1", "Foundation F2": "F2", "Blush B1": "B1", "Lipstick L1": "L1", "Lipstick L2": "L2"}
#: Figures 5.5 (with scattering) and 5.58 (without): F1 at the thesis's 0, 0.1, 0.5 and 1.0 (1.0 = 30 um), mm.
THICKNESS_ROWS = {
    "5.5 skin": (0.0, True),
    "5.5 F1 thin": (0.003, True),
    "5.5 F1 medium": (0.015, True),
    "5.5 F1 thick": (0.030, True),
    "5.58 skin": (0.0, False),
    "5.58 F1 thin": (0.003, False),
    "5.58 F1 medium": (0.015, False),
    "5.58 F1 thick": (0.030, False),
}
LIPSTICK, BLUSH, FOUNDATION = ("B", 0.020), ("G", 0.010), ("R", 0.015)  # cosmetic map channel, largest film (mm)
#: Figure 5.59 (c)-(f): stacks top first, (material, channel, largest thickness in mm).
LOOKS = {
    "5.59 look c": [("Lipstick L1", *LIPSTICK), ("Blush B1", *BLUSH), ("Foundation F1", *FOUNDATION)],
    "5.59 look d": [("Lipstick L1", *LIPSTICK), ("Blush B1", *BLUSH), ("Foundation F2", *FOUNDATION)],
    "5.59 look e": [("Lipstick L2", *LIPSTICK), ("Blush B1", *BLUSH), ("Foundation F2", *FOUNDATION)],
    "5.59 look f": [("Lipstick L2", *LIPSTICK), ("Foundation F1", *FOUNDATION)],
}
FIGURE_ORDER = [*THICKNESS_ROWS, *LOOKS]


def _scene(name: str) -> SceneFile:
    """A product's composed scene, checked as a scene file (materials stand in by name)."""
    recipe = load_recipe(RECIPE)
    product = recipe.product(name)
    owners = {layer["material"] for layer in product.layer}
    return SceneFile.model_validate(recipe.scene_data(product, {o: Path(f"{slug(o)}.json") for o in owners}))


def test_the_plan_fits_every_sample_and_renders_one_frame_of_each_figure_panel(tmp_path):
    out = tmp_path / "out"
    plan = plan_run(RECIPE, out)
    tasks = list(plan.tasks.values())
    assert {t.product for t in tasks if t.kind == "material"} == set(MATERIALS)
    assert {t.product for t in tasks if t.kind == "validate"} == set(MATERIALS)
    renders = [t for t in tasks if t.kind == "render"]
    assert [t.product for t in renders] == FIGURE_ORDER  # the materials are fitted, never rendered
    assert all(t.args["frames"] == [0] for t in renders)
    assert not [t for t in tasks if t.kind == "video"]  # one frame: no turntable video
    assert [t.kind for t in tasks].count("sheet") == 1
    assert {t.state for t in tasks} == {"pending"}
    assert not out.exists()  # planning writes nothing


def test_dry_run_exits_ok_and_writes_nothing(tmp_path, capsys):
    assert cli.main(["run", str(RECIPE), "-o", str(tmp_path / "out"), "--dry-run"]) == cli.EXIT_OK
    printed = capsys.readouterr().out
    for name in FIGURE_ORDER:
        assert f"render:{slug(name)}:0-0" in printed
    assert not (tmp_path / "out").exists()


def test_the_materials_are_the_recorded_sessions_of_the_bundled_samples():
    recipe = load_recipe(RECIPE)
    for name, sample in MATERIALS.items():
        product = recipe.product(name)
        assert product.source == "replay" and not product.layer
        assert (recipe.base / product.replay.log).resolve() == THESIS.parent / "demo" / "sessions" / f"{sample}.jsonl"
        assert (recipe.base / product.replay.plan).resolve() == THESIS.parent / "samples" / sample / "plan.toml"


def test_figures_5_5_and_5_58_are_F1_at_three_thicknesses_with_and_without_scattering():
    for name, (thickest_mm, scattered) in THICKNESS_ROWS.items():
        scene = _scene(name)
        assert scene.scene.mesh == "head"
        assert scene.skin is not None and scene.skin.reflectance == "colorchecker:light skin"
        assert bool(scene.skin.scattering) is scattered, name
        [layer] = scene.layer
        assert layer.material == "foundation-f1.json"
        if thickest_mm == 0.0:
            assert parse_thickness_mm(layer.thickness, allow_zero=True) == 0.0
        else:
            assert (layer.thickness_map.file, layer.thickness_map.channel) == ("../scenes/head_makeup.png", "R")
            assert parse_thickness_mm(layer.thickness_map.min, allow_zero=True) == 0.0
            assert np.isclose(parse_thickness_mm(layer.thickness_map.max), thickest_mm, rtol=0, atol=1e-12)


def test_figure_5_59_looks_stack_the_cosmetic_maps_channels_over_scattering_skin():
    for name, stack in LOOKS.items():
        scene = _scene(name)
        assert scene.scene.mesh == "head" and scene.skin.scattering is True
        got = [(layer.material, layer.thickness_map.channel, parse_thickness_mm(layer.thickness_map.max))
               for layer in scene.layer]  # fmt: skip
        want = [(f"{slug(material)}.json", channel, mm) for material, channel, mm in stack]
        assert [g[:2] for g in got] == [w[:2] for w in want], name
        assert np.allclose([g[2] for g in got], [w[2] for w in want], rtol=0, atol=1e-12), name


def test_the_largest_thickness_is_reached_where_the_map_is_full():
    """Each channel the recipe reads reaches full scale somewhere (to 0.1 %), so each ``max`` is a thickness the head
    really wears."""
    image = oiio.ImageBuf(str(MAP))
    pixels = image.get_pixels(oiio.FLOAT)
    names = list(image.spec().channelnames)
    for channel in "RGB":
        assert pixels[..., names.index(channel)].max() >= 0.999, channel


def test_every_panel_has_the_same_front_camera_and_light():
    scenes = [_scene(name) for name in FIGURE_ORDER]
    assert {(s.camera.elevation_deg, s.camera.azimuth_deg, s.camera.distance_mm) for s in scenes} == {(5.0, 0.0, 540.0)}
    assert len({tuple(map(repr, s.light)) for s in scenes}) == 1
    assert {s.turntable for s in scenes} == {None}


def test_the_runs_sheet_lays_the_panels_out_as_the_figures(tmp_path):
    """One frame per panel: the sheet fills four columns row by row, in figure order (5.5, 5.58, 5.59), each cell
    captioned with its panel (the frames the plan's render tasks write)."""
    plan = plan_run(RECIPE, tmp_path / "out")
    [sheet] = [t for t in plan.tasks.values() if t.kind == "sheet"]
    assert sheet.args["captions"] is True and sheet.args["columns"] == 4
    frames = [f for row in sheet.args["rows"] for f in row["frames"]]
    assert frames == [str(tmp_path / "out" / "frames" / slug(name) / "frame_000.exr") for name in FIGURE_ORDER]
    rendered = [o for t in plan.tasks.values() if t.kind == "render" for o in t.outputs if o.endswith(".exr")]
    assert rendered == [f"frames/{slug(name)}/frame_000.exr" for name in FIGURE_ORDER]
