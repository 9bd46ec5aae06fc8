"""``kmpipe trade``: the speed/accuracy trade of a line measured on its own products (kmpipe.stages.trade,
kmpipe.run.trade).

References: the most exact setting against itself is Delta E 0 (a frame equals itself); a frame against itself as
planned is 0 in "vs planned"; colour-science's own CIEDE2000 for the per-pixel statistics; the Pareto front checked
by its definition against every row; a knob that cannot change a product's frame (no skin: no scattering; no
environment; no area light) is reported not applicable, never measured.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import re
import shutil

import colour
import numpy as np
import pytest
from test_run import edit, make_line

from kmpipe.cli import main
from kmpipe.formats.recipe import load_recipe, slug
from kmpipe.formats.scene import load_scene
from kmpipe.run.folder import PRODUCTS
from kmpipe.run.trade import trade_line
from kmpipe.stages.frame_choice import apply_choice, free_knobs, scene_fingerprint
from kmpipe.stages.render_plan import plan_scene
from kmpipe.stages.trade import (
    KNOBS,
    Setting,
    _Product,
    _with_settings,
    aggregate,
    cheapest_within,
    delta_e_stats,
    rebuild_for,
)
from kmpipe.stages.trade_files import write_trade
from renderer.image_io import read_exr

pytestmark = pytest.mark.filterwarnings("ignore:Aligning:colour.utilities.ColourRuntimeWarning")


@pytest.fixture(scope="module")
def traded(tmp_path_factory):
    folder = tmp_path_factory.mktemp("trade")
    recipe = make_line(folder / "line")
    return folder, recipe, trade_line(recipe, folder / "out", echo=lambda _: None)


def test_every_product_gets_every_knob_measured_or_said_not_applicable(traded):
    _, _, result = traded
    products = {s.product for s in result.settings}
    assert products == {"Foundation F1", "Lipstick L1", "Face"}  # the products with layers; B1 has none
    for product in products:
        knobs = {s.knob for s in result.settings if s.product == product}
        assert knobs == set(KNOBS), product
    for s in result.settings:
        if s.seconds is None:
            assert s.note.startswith("not applicable") and s.mean_de is None
        else:
            assert s.seconds > 0.0 and np.isfinite(s.mean_de) and s.p95_de >= 0.0


def test_the_most_exact_setting_is_delta_e_0_against_itself_and_the_plan_0_against_the_plan(traded):
    _, _, result = traded
    for s in result.settings:
        if s.knob == "planned" and s.value.startswith("the reference"):
            assert s.mean_de == 0.0 and s.p95_de == 0.0
        if s.knob == "planned" and s.value == "as planned":
            assert s.shift_de == 0.0 and s.planned


def test_knobs_that_cannot_change_a_frame_are_not_applicable(traded):
    _, _, result = traded

    def said(product, knob):
        return [s for s in result.settings if s.product == product and s.knob == knob]

    for product in ("Foundation F1", "Lipstick L1"):  # no skin
        [s] = said(product, "subsurface scattering")
        assert s.seconds is None and "no skin" in s.note
        [s] = said(product, "thickness samples")  # uniform films
        assert s.seconds is None and "one thickness" in s.note
    for product in ("Foundation F1", "Lipstick L1", "Face"):  # no environment, no area light
        assert said(product, "environment")[0].seconds is None
        assert said(product, "soft shadows")[0].seconds is None
    assert {s.value for s in said("Face", "subsurface scattering")} == {"on", "off"}
    assert len(said("Face", "thickness samples")) == 3  # the cosmetic map's films


def test_the_per_pixel_statistics_are_colour_sciences_ciede2000():
    rng = np.random.default_rng(3)
    a, b = rng.random((6, 7, 3)) * 0.8, rng.random((6, 7, 3)) * 0.8
    mask = rng.random((6, 7)) > 0.3
    lab = [
        colour.XYZ_to_Lab(
            colour.RGB_to_XYZ(x[mask], colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False),
            colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"],
        )
        for x in (a, b)
    ]
    expected = colour.delta_E(lab[0], lab[1], method="CIE 2000")  # fmt: skip
    mean, p95 = delta_e_stats(a, b, mask)
    assert mean == pytest.approx(expected.mean(), rel=1e-12)
    assert p95 == pytest.approx(np.percentile(expected, 95), rel=1e-12)


def test_the_pareto_front_holds_exactly_the_settings_no_other_beats():
    rng = np.random.default_rng(11)
    settings = [Setting(p, f"k{i % 3}", f"v{i}", float(t), float(d), float(d), planned=i == 0, shift_de=0.0)
                for i, (t, d) in enumerate(rng.random((25, 2))) for p in ("A", "B")]  # fmt: skip
    settings.append(Setting("A", "k9", "only A", 0.0, 0.0, 0.0, shift_de=0.0))  # best, but on one product only
    rows = aggregate(settings)
    whole = [r for r in rows if r.products == 2]
    for r in whole:
        beaten = any(o.seconds <= r.seconds and o.mean_de <= r.mean_de and (o.seconds, o.mean_de) != (r.seconds,
                     r.mean_de) for o in whole)  # fmt: skip
        assert r.front == (not beaten)
    assert any(r.front for r in whole) and not next(r for r in rows if r.value == "only A").front
    chosen = cheapest_within(rows, 0.5)
    for knob, row in chosen.items():
        assert row.mean_de <= 0.5
        assert all(o.seconds >= row.seconds for o in rows if o.knob == knob and o.mean_de <= 0.5)


def test_front_settings_drawn_on_one_spot_share_a_number_and_others_do_not():
    """trade.png numbers the front: settings within HUDDLE_PX of each other on the plot (here, linear axes of 100 px
    per unit) get one number, each farther one its own."""
    from matplotlib.figure import Figure

    from kmpipe.stages.trade import Aggregate
    from kmpipe.stages.trade_files import HUDDLE_PX, _huddles

    figure = Figure(figsize=(4.0, 4.0), dpi=100)
    axes = figure.add_axes((0.0, 0.0, 1.0, 1.0), xlim=(0.0, 4.0), ylim=(0.0, 4.0))
    step = 0.9 * HUDDLE_PX / 100.0  # just inside
    points = [(0.5, 3.0), (0.5 + step, 3.0), (0.5, 3.0 - step), (2.0, 1.0), (2.0 + 1.2 * HUDDLE_PX / 100.0, 1.0)]
    front = [Aggregate("k", str(i), 2, y, x, x, False, 0.0, True) for i, (x, y) in enumerate(points)]
    assert [[r.value for r in group] for group in _huddles(front, axes)] == [["0", "1", "2"], ["3"], ["4"]]


def test_the_files_hold_the_measurements(traded):
    folder, _, result = traded
    trade = folder / "out" / "trade"
    with open(trade / "trade.csv", encoding="utf-8", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == len(result.settings)
    assert {r["knob"] for r in rows} == set(KNOBS)
    doc = json.loads((trade / "trade.json").read_text(encoding="utf-8"))
    assert doc["target_delta_e"] == result.target == 0.5
    assert len(doc["settings"]) == len(result.settings) and len(doc["line_settings"]) == len(result.rows)
    assert (trade / "trade.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_command_prints_the_table_and_refuses_an_unknown_product(traded, capsys):
    folder, recipe, _ = traded
    assert main(["trade", str(recipe), "-o", str(folder / "out"), "--only", "Lipstick L1"]) == 0
    out = capsys.readouterr().out
    assert "kmpipe trade: Test line" in out and "the reference (most exact)" in out and "as planned:" in out
    assert main(["trade", str(recipe), "-o", str(folder / "out"), "--only", "Nothing"]) == 2
    assert "--only" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------- frame settings ---


def _product(recipe_path, out, name) -> _Product:
    """The trade's view of product ``name`` of the line, its materials those made in ``out``."""
    recipe = load_recipe(recipe_path)
    index = [p.name for p in recipe.info.product].index(name)
    layers = recipe.info.product[index].layer
    owners = [name if layer.get("material") == "self" else layer["material"] for layer in layers]
    rebuild = rebuild_for(recipe, index)
    return _Product(name, rebuild({o: out / PRODUCTS / slug(o) / "material.json" for o in owners}), rebuild)


def _p95(product: _Product, settings: dict, against: np.ndarray) -> float:
    image = product.render_once(_with_settings(product, settings))
    return delta_e_stats(image, against, product.mask)[1]


def test_each_product_gets_the_frame_settings_its_target_allows_found_as_documented(traded):
    """Against the frame with the free knobs at their most exact, the choice re-measured keeps 95 % of the product's
    pixels within the target; and, knob by knob in the documented order (earlier knobs as chosen, later ones at their
    most exact), every cheaper setting than the one chosen does not."""
    folder, recipe, result = traded
    assert set(result.choices) == {"Foundation F1", "Lipstick L1", "Face"}
    for name, choice in result.choices.items():
        product = _product(recipe, folder / "out", name)
        knobs = free_knobs(product.scene, product.plan)
        assert set(knobs) == ({"antialiasing", "shadow map", "subsurface scattering"} if name == "Face" else
                              {"antialiasing", "shadow map"})  # fmt: skip
        chosen = {"antialiasing": choice.antialiasing, "shadow map": choice.shadow_map,
                  "subsurface scattering": choice.scattering}  # fmt: skip
        chosen = {knob: chosen[knob] for knob in knobs}
        assert choice.scene_sha256 == scene_fingerprint(product.scene) and choice.target_de == 0.5
        best = product.render_once(_with_settings(product, {k: options[-1] for k, options in knobs.items()}))
        assert _p95(product, chosen, best) == pytest.approx(choice.p95_de, abs=1e-9) and choice.p95_de <= 0.5
        order = list(knobs)
        for position, knob in enumerate(order):
            options = knobs[knob]
            for cheaper in options[: options.index(chosen[knob])]:
                settings = {**{k: chosen[k] for k in order[:position]}, knob: cheaper,
                            **{k: knobs[k][-1] for k in order[position + 1 :]}}  # fmt: skip
                assert _p95(product, settings, best) > 0.5, (name, knob, cheaper)


def test_kmpipe_run_plans_each_product_with_its_frame_settings_and_says_so(traded, tmp_path, capsys):
    folder, recipe, result = traded
    line, out = tmp_path / "line", tmp_path / "out"
    shutil.copytree(recipe.parent, line)
    shutil.copytree(folder / "out", out)
    # the fixture's choices (another test may have traded one product alone into its folder)
    write_trade(out / "trade", result.line, result.target, result.settings, result.rows, result.chosen,
                result.choices)  # fmt: skip
    assert main(["run", str(line / "recipe.toml"), "-o", str(out), "--explain"]) == 0
    printed = capsys.readouterr().out
    for name, choice in result.choices.items():
        plan = json.loads((out / "frames" / slug(name) / "plan.json").read_text(encoding="utf-8"))
        method, side = {"4 x multisampling": ("multisample", 2), "2 x 2 supersampling": ("supersample", 2),
                        "3 x 3 supersampling": ("supersample", 3)}[choice.antialiasing]  # fmt: skip
        assert (plan["antialiasing"], plan["antialias_side"]) == (method, side)
        assert plan["shadow_map_size"] == choice.shadow_map
        assert (plan["scattering"] is None) == (name != "Face" or choice.scattering == "off")
        assert any("measured by kmpipe trade" in line for line in plan["explain"])
        _, header = read_exr(out / "frames" / slug(name) / "frame_000.exr")
        assert header["antialias"] == choice.antialiasing
    assert printed.count("measured by kmpipe trade on this product's frame") == 3

    # another version of a product's scene: its choice is not used, and the plan says why
    edit(line / "recipe.toml", 'thickness = "1 mm", specular', 'thickness = "0.8 mm", specular')
    assert main(["run", str(line / "recipe.toml"), "-o", str(out), "--only", "Lipstick L1"]) == 0
    plan = json.loads((out / "frames" / "lipstick-l1" / "plan.json").read_text(encoding="utf-8"))
    assert any("measured on another version of this scene" in line for line in plan["explain"])
    assert plan["antialias_side"] is None


def test_a_damaged_trade_file_stops_kmpipe_run_naming_the_field(traded, tmp_path, capsys):
    _, recipe, result = traded
    out = tmp_path / "out"
    (out / "trade").mkdir(parents=True)
    write_trade(out / "trade", result.line, result.target, result.settings, result.rows, result.chosen,
                result.choices)  # fmt: skip
    path = out / "trade" / "trade.json"
    doc = json.loads(path.read_text(encoding="utf-8"))
    doc["frame_settings"]["Face"]["shadow_map"] = 777
    path.write_text(json.dumps(doc), encoding="utf-8")
    assert main(["run", str(recipe), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "frame_settings.Face.shadow_map" in err and "trade.json" in err


def test_what_the_scene_sets_itself_stays_the_scenes(traded, tmp_path):
    folder, _, result = traded
    material = folder / "out" / PRODUCTS / "foundation-f1" / "material.json"
    base = (f'[scene]\nname = "F1"\nmesh = "compact"\nresolution = [32, 32]\n{{scene}}[substrate]\nreflectance = 0.8\n'
            f'[[layer]]\nmaterial = "{material}"\nthickness = "40 um"\n[[light]]\ndirection = [0.4, 0.8, 0.6]\n'
            '[ground]\nreflectance = 0.35\n{output}')  # fmt: skip
    path = tmp_path / "scene.toml"
    for extra_scene, output, free in (
        ("", "", {"antialiasing", "shadow map"}),
        ("shadow_map = 1024\n", "", {"antialiasing"}),
        ("", "[output]\nantialias = 2\n", {"shadow map"}),
        ("", '[output]\nantialias_method = "supersample"\n', {"shadow map"}),
    ):
        path.write_text(base.format(scene=extra_scene, output=output), encoding="utf-8")
        scene = load_scene(path)
        plan = plan_scene(scene)
        assert set(free_knobs(scene, plan)) == free
        choice = dataclasses.replace(result.choices["Foundation F1"], scene_sha256=scene_fingerprint(scene),
                                     antialiasing="2 x 2 supersampling", shadow_map=512)  # fmt: skip
        applied = apply_choice(plan, scene, choice)
        assert (applied.shadow_map_size == 512) == ("shadow map" in free)
        assert (applied.antialias_side == 2 and applied.antialiasing == "supersample") == ("antialiasing" in free)
        assert applied.shadow_map_size in (512, plan.shadow_map_size)


# ------------------------------------------------------------------------------------ kmpipe render --measure-settings

LABELS = {"4 x multisampling": ("multisample", 2), "2 x 2 supersampling": ("supersample", 2),
          "3 x 3 supersampling": ("supersample", 3)}  # fmt: skip


def _scene(path, material, *, scene="", output="", base="[substrate]\nreflectance = 0.8\n", mesh="compact"):
    path.write_text(f'[scene]\nname = "F1"\nmesh = "{mesh}"\nresolution = [32, 32]\n{scene}{base}[[layer]]\n'
                    f'material = "{material}"\nthickness = "40 um"\n[[light]]\ndirection = [0.4, 0.8, 0.6]\n'
                    f'[ground]\nreflectance = 0.35\n[turntable]\nframes = 2\n{output}', encoding="utf-8")  # fmt: skip
    return path


def _frames(folder) -> list[np.ndarray]:
    return [read_exr(folder / f"frame_{i:03d}.exr")[0] for i in range(2)]


def _settings_of(printed: str, folder) -> tuple[str, int]:
    """The antialiasing (label, from the frame's header) and shadow map (texels, from --explain) a render used."""
    shadow = re.search(r"(\d+) x \1 texels \(chosen by kmpipe render --measure-settings\)", printed)
    return read_exr(folder / "frame_000.exr")[1]["antialias"], int(shadow[1])


@pytest.mark.parametrize("skin", [False, True], ids=["substrate", "skin-no-sss"])
def test_kmpipe_render_measures_its_frame_settings_and_renders_every_frame_with_them(traded, tmp_path, capsys, skin):
    """The settings chosen keep 95 % of the product's pixels within the target of the most exact frame, and the
    turntable rendered with them equals, pixel for pixel, the scene rendered with them written into it. With
    --no-sss on skin, scattering is not measured: the frames are the scene's with its scattering off."""
    folder, _, _ = traded
    material = folder / "out" / PRODUCTS / "foundation-f1" / "material.json"
    base = '[skin]\nreflectance = "colorchecker:light skin"\n' if skin else "[substrate]\nreflectance = 0.8\n"
    mesh = "sphere" if skin else "compact"
    path = _scene(tmp_path / "scene.toml", material, base=base, mesh=mesh)
    options = ["--no-sss"] if skin else []
    assert main(["render", str(path), "-o", str(tmp_path / "measured"), "--measure-settings", "--explain",
                 *options]) == 0  # fmt: skip
    printed = capsys.readouterr().out
    assert "measured by kmpipe render --measure-settings on this product's frame" in printed
    assert "subsurface scattering: off -- chosen" not in printed
    label, shadow_map = _settings_of(printed, tmp_path / "measured")

    scene = load_scene(path)
    if skin:  # what --no-sss renders
        scene = dataclasses.replace(scene, info=scene.info.model_copy(update={"skin": scene.info.skin.model_copy(
            update={"scattering": False})}))  # fmt: skip
    product = _Product("F1", scene, None)
    knobs = free_knobs(scene, product.plan)
    assert set(knobs) == {"antialiasing", "shadow map"}
    best = product.render_once(_with_settings(product, {k: options[-1] for k, options in knobs.items()}))
    assert _p95(product, {"antialiasing": label, "shadow map": shadow_map}, best) <= 0.5

    method, side = LABELS[label]
    base += "scattering = false\n" if skin else ""
    explicit = _scene(tmp_path / "explicit.toml", material, scene=f"shadow_map = {shadow_map}\n", base=base, mesh=mesh,
                      output=f'[output]\nantialias = {side}\nantialias_method = "{method}"\n')  # fmt: skip
    assert main(["render", str(explicit), "-o", str(tmp_path / "explicit")]) == 0
    for measured, written in zip(_frames(tmp_path / "measured"), _frames(tmp_path / "explicit"), strict=True):
        assert np.array_equal(measured, written)
    if skin:
        assert read_exr(tmp_path / "measured" / "frame_000.exr")[1]["subsurface_scattering"] == "off"


def test_kmpipe_render_with_nothing_to_measure_says_so_and_renders_as_planned(traded, tmp_path, capsys):
    folder, _, _ = traded
    material = folder / "out" / PRODUCTS / "foundation-f1" / "material.json"
    path = _scene(tmp_path / "scene.toml", material, scene="shadow_map = 1024\n", output="[output]\nantialias = 2\n")
    assert main(["render", str(path), "-o", str(tmp_path / "measured"), "--measure-settings", "--explain"]) == 0
    assert "frame settings: nothing to measure (--measure-settings)" in capsys.readouterr().out
    assert main(["render", str(path), "-o", str(tmp_path / "planned")]) == 0
    for measured, planned in zip(_frames(tmp_path / "measured"), _frames(tmp_path / "planned"), strict=True):
        assert np.array_equal(measured, planned)


def test_kmpipe_render_measuring_for_an_ab_sheet_keeps_the_skins_scattering(traded, tmp_path, capsys):
    """--ab-sss compares frames with and without subsurface scattering: measuring leaves scattering on (it is not
    among the knobs), so the two rows of the sheet differ."""
    folder, _, _ = traded
    material = folder / "out" / PRODUCTS / "foundation-f1" / "material.json"
    path = _scene(tmp_path / "scene.toml", material, base='[skin]\nreflectance = "colorchecker:light skin"\n',
                  mesh="sphere")  # fmt: skip
    out = tmp_path / "measured"
    assert main(["render", str(path), "-o", str(out), "--measure-settings", "--ab-sss", "--explain"]) == 0
    printed = capsys.readouterr().out
    assert "measured by kmpipe render --measure-settings" in printed and "scattering: off -- chosen" not in printed
    with_sss, header = read_exr(out / "frame_000.exr")
    assert header["subsurface_scattering"].startswith("alpha")
    assert not np.array_equal(with_sss, read_exr(out / "no_sss" / "frame_000.exr")[0])
    assert (out / "ab_sss.png").is_file()
