"""``kmpipe review`` (kmpipe.stages.review, kmpipe.stages.review_page, the review's tasks in kmpipe.run): every
foundation on every skin tone under every illuminant, its numbers checked against colour-science computed directly
from the fitted materials, its tiles' swatches against those numbers, its caching and what it refuses."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import colour
import numpy as np
import pytest
from colour_reference import colour_lab

from kmpipe import cli
from kmpipe.formats.material import read_material
from kmpipe.formats.spectra import SpectralTable, write_spectra_csv
from kmpipe.physics.kubelka_munk import reflectance_over_background
from kmpipe.run.execute import execute
from kmpipe.run.planning import plan_run
from renderer.image_io import read_png

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "recipes" / "samples"
TILE = 64
ILLUMINANTS = ["D65", "A"]

pytestmark = pytest.mark.filterwarnings("ignore:Aligning:colour.utilities.ColourRuntimeWarning")

RECIPE = """\
[line]
name = "Review line"

[scene]
mesh = "compact"
resolution = [32, 32]
[substrate]
reflectance = 0.8
[[light]]
direction = [0.4, 0.8, 0.6]

[[product]]
name = "Foundation F1"
shade = "F1"
fit = "F1/manifest.toml"
layer = [{ material = "self", thickness = "40 um" }]

[[product]]
name = "Foundation F2"
shade = "F2"
fit = "F2/manifest.toml"
layer = [{ material = "self", thickness = "20 um" }]

[review]
foundations = ["Foundation F1", "Foundation F2"]
tones = ["builtin:tcs13", "skin.csv"]
illuminants = ["D65", "A"]
thickness = "15 um"
match_delta_e = 6.0
tile = 64
"""


def skin(wavelengths, scale: float = 1.0) -> np.ndarray:
    w = np.asarray(wavelengths, float)
    return scale * (0.18 + 0.42 / (1.0 + np.exp(-(w - 590.0) / 25.0)))


def write_tones(folder: Path, columns: dict[str, float]) -> None:
    w = np.arange(360.0, 831.0, 5.0)
    table = SpectralTable(w, None, tuple(columns), np.array([skin(w, s) for s in columns.values()]),
                          {"quantity": "reflectance", "units": "1", "site.lab-03": "cheek"})  # fmt: skip
    write_spectra_csv(table, folder / "skin.csv")


def make_line(folder: Path) -> Path:
    folder.mkdir(parents=True)
    for sample in ("F1", "F2"):
        shutil.copytree(SAMPLES / sample, folder / sample)
    write_tones(folder, {"lab-03": 1.0})
    recipe = folder / "recipe.toml"
    recipe.write_text(RECIPE, encoding="utf-8")
    return recipe


@pytest.fixture(scope="module")
def reviewed(tmp_path_factory) -> tuple[Path, Path, int]:
    folder = tmp_path_factory.mktemp("review")
    recipe = make_line(folder / "line")
    out = folder / "out"
    code = cli.main(["review", str(recipe), "-o", str(out)])
    return recipe, out, code


def test_the_review_writes_its_matrix_sheet_numbers_and_page(reviewed):
    _, out, code = reviewed
    assert code == 0
    folder = out / "review"
    document = json.loads((folder / "review.json").read_text(encoding="utf-8"))
    assert document["shades"] == ["F1", "F2"] and document["illuminants"] == ILLUMINANTS
    assert [row["tone"]["id"] for row in document["tones"]] == ["tcs13", "lab-03"]
    assert (
        document["tones"][1]["tone"]["site"] == "cheek" and document["tones"][0]["tone"]["kind"] == "complexion sample"
    )
    with (folder / "review.csv").open(encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 2 * 2 * 2
    assert {(r["tone_id"], r["shade"], r["illuminant"]) for r in rows} == {
        (t, s, i) for t in ("tcs13", "lab-03") for s in ("F1", "F2") for i in ILLUMINANTS
    }
    page = (folder / "review.html").read_text(encoding="utf-8")
    for row in document["tones"]:
        for cell in row["cells"]:
            for values in cell["illuminants"].values():
                tile = folder / "tones" / row["tone"]["id"] / values["tile"]
                assert tile.is_file() and f"tones/{row['tone']['id']}/{values['tile']}" in page
    sheet = read_png(folder / "review.png")
    assert sheet.shape[0] > 2 * 160 and sheet.shape[1] > 6 * 160  # 2 tones x (bare + 2 shades) x 2 illuminants
    index = (out / "reports" / "index.html").read_text(encoding="utf-8")
    assert "../review/review.html" in index


def test_the_numbers_are_colour_sciences_for_the_fitted_films_on_each_tone(reviewed):
    _, out, _ = reviewed
    document = json.loads((out / "review" / "review.json").read_text(encoding="utf-8"))
    materials = {s: read_material(out / "products" / f"foundation-{s.lower()}" / "material.json") for s in ("F1", "F2")}
    w = materials["F1"].wavelengths
    tcs13 = colour.quality.SDS_TCS["CIE 1995"]["TCS13"]
    tones = {"lab-03": skin(w), "tcs13": np.interp(w, tcs13.wavelengths, tcs13.values)}
    for row in document["tones"]:
        bare = tones[row["tone"]["id"]]
        matches = {}
        for cell in row["cells"]:
            m = materials[cell["shade"]]
            worn = reflectance_over_background(m.K, m.S, np.full_like(m.K, 0.015), bare)
            with np.errstate(divide="ignore", invalid="ignore"):
                ks = m.K / m.S
            mass = 1.0 + ks - np.sqrt(ks * ks + 2.0 * ks)
            for ill, values in cell["illuminants"].items():
                coverage = colour.delta_E(colour_lab(bare, w, ill), colour_lab(worn, w, ill), method="CIE 2000")
                match = colour.delta_E(colour_lab(bare, w, ill), colour_lab(mass, w, ill), method="CIE 2000")
                assert values["coverage_delta_e"] == pytest.approx(coverage, abs=2e-3)
                assert values["match_delta_e"] == pytest.approx(match, abs=2e-3)
                assert values["worn_match_breaks"] == (cell["illuminants"]["D65"]["coverage_delta_e"] <= 6.0 < coverage)
            matches[cell["shade"]] = cell["illuminants"]["D65"]["match_delta_e"]
        assert row["best"] == min(matches, key=matches.get)
        assert row["margin_delta_e"] == pytest.approx(abs(matches["F1"] - matches["F2"]), abs=2e-3)


def test_each_tiles_swatch_is_the_exact_made_up_colour(reviewed):
    _, out, _ = reviewed
    document = json.loads((out / "review" / "review.json").read_text(encoding="utf-8"))
    for row in document["tones"]:
        folder = out / "review" / "tones" / row["tone"]["id"]
        for cell in row["cells"]:
            for values in cell["illuminants"].values():
                tile = read_png(folder / values["tile"])
                assert tile.shape[:2] == (TILE, TILE)
                expected = [int(values["made_up_srgb"][i : i + 2], 16) for i in (1, 3, 5)]
                corner = np.round(tile[-3, -3, :3] * 255.0) if tile.dtype.kind == "f" else tile[-3, -3, :3]
                assert np.abs(corner.astype(int) - expected).max() <= 1
                lit = tile[: TILE // 2, : TILE // 2, :3]
                assert lit.std() > 0  # a render, not a flat fill


def test_a_second_review_is_cached_and_a_new_tone_renders_only_its_row(tmp_path):
    recipe = make_line(tmp_path / "line")
    out = tmp_path / "out"
    execute(plan_run(recipe, out, review_only=True))
    plan = plan_run(recipe, out, review_only=True)
    assert {t.state for t in plan.tasks.values()} == {"cached"}
    assert not any(t.kind in ("plan", "render", "sheet") for t in plan.tasks.values())
    write_tones(tmp_path / "line", {"lab-03": 1.0, "lab-04": 0.7})
    plan = plan_run(recipe, out, review_only=True)
    assert {t.id for t in plan.tasks.values() if t.state == "pending"} == {"tone:lab-04", "review"}
    execute(plan)
    document = json.loads((out / "review" / "review.json").read_text(encoding="utf-8"))
    assert [row["tone"]["id"] for row in document["tones"]] == ["tcs13", "lab-03", "lab-04"]


@pytest.mark.parametrize(
    ("old", "new", "field", "words"),
    [
        ('illuminants = ["D65", "A"]', 'illuminants = ["D65", "A9"]', "review.illuminants", "unknown illuminant"),
        ('foundations = ["Foundation F1", "Foundation F2"]', "foundations = []", "review.foundations", "at least 1"),
        (
            'foundations = ["Foundation F1", "Foundation F2"]',
            'foundations = ["Foundation F9"]',
            "review.foundations[1]",
            "not a product",
        ),
        (
            'tones = ["builtin:tcs13", "skin.csv"]',
            'tones = ["builtin:nobody"]',
            "review.tones[1]",
            "no built-in skin tone",
        ),
        ('thickness = "15 um"', 'thickness = "-3 um"', "review.thickness", "thickness must be > 0"),
        ("match_delta_e = 6.0", 'match_delta_e = 6.0\nreference = "F11"', "review", "must be one of the illuminants"),
    ],
    ids=["unknown illuminant", "no foundations", "not a product", "unknown tone", "bad thickness", "reference"],
)
def test_bad_reviews_are_refused_naming_the_file_and_field(tmp_path, capsys, old, new, field, words):
    recipe = make_line(tmp_path / "line")
    text = recipe.read_text(encoding="utf-8")
    assert text.count(old) == 1
    recipe.write_text(text.replace(old, new), encoding="utf-8")
    assert cli.main(["review", str(recipe), "-o", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err
    assert str(recipe) in " ".join(error.split()) and field in error and words in " ".join(error.split())
    assert not (tmp_path / "out").exists()


def test_a_recipe_without_a_review_and_a_bad_skin_file_are_refused(tmp_path, capsys):
    recipe = make_line(tmp_path / "line")
    text = recipe.read_text(encoding="utf-8")
    recipe.write_text(text[: text.index("[review]")], encoding="utf-8")
    assert cli.main(["review", str(recipe), "-o", str(tmp_path / "out")]) == 2
    assert "has no [review] table" in " ".join(capsys.readouterr().err.split())
    recipe.write_text(text, encoding="utf-8")
    rows = "".join(f"{w:g},{-0.1 if w == 500 else 0.4}\n" for w in range(360, 835, 5))
    bad = tmp_path / "line" / "skin.csv"
    bad.write_text(f"# kmpipe-spectra: 1\n# quantity: reflectance\n# units: 1\nwavelength_nm,lab-03\n{rows}")
    assert cli.main(["review", str(recipe), "-o", str(tmp_path / "out")]) == 2
    error = " ".join(capsys.readouterr().err.split())
    assert str(bad) in error and "negative reflectance" in error and "500 nm" in error


def test_the_masstones_are_colour_sciences_and_shade_pairs_break_where_they_part(reviewed):
    from kmpipe.stages.review_page import _breaks

    _, out, _ = reviewed
    document = json.loads((out / "review" / "review.json").read_text(encoding="utf-8"))
    materials = [read_material(out / "products" / f"foundation-{s}" / "material.json") for s in ("f1", "f2")]
    w = materials[0].wavelengths
    with np.errstate(divide="ignore", invalid="ignore"):
        masstones = [1.0 + m.K / m.S - np.sqrt((m.K / m.S) ** 2 + 2.0 * m.K / m.S) for m in materials]
    for row in document["tones"]:
        for cell, mass in zip(row["cells"], masstones, strict=True):
            for ill, values in cell["illuminants"].items():
                np.testing.assert_allclose(values["masstone_lab"], colour_lab(mass, w, ill), atol=2e-4)
    # Two shades 1 apart under D65 and 3 apart under A (Labs chosen so), a third far from both: with a threshold of
    # 2, the first pair matches in daylight and breaks under A, "the second is yellower"; the third pairs with none.
    labs = {"D65": ([60.0, 10.0, 20.0], [60.0, 10.0, 21.6], [40.0, 5.0, 10.0]),
            "A": ([62.0, 12.0, 24.0], [62.0, 12.0, 29.0], [41.0, 6.0, 12.0])}  # fmt: skip
    cells = [{"shade": name, "illuminants": {ill: {"masstone_lab": labs[ill][k], "worn_match_breaks": False,
                                                   "shade_match_breaks": False} for ill in labs}}
             for k, name in enumerate(("S1", "S2", "S3"))]  # fmt: skip
    breaks = _breaks([{"tone": {"name": "t"}, "cells": cells}], "D65", 2.0)
    d65 = colour.delta_E(labs["D65"][0], labs["D65"][1], method="CIE 2000")
    under_a = colour.delta_E(labs["A"][0], labs["A"][1], method="CIE 2000")
    assert d65 <= 2.0 < under_a
    assert breaks == [{"tone": "", "shade": "S1 / S2", "pair": "shades", "illuminant": "A",
                       "reference_delta_e": round(d65, 3), "delta_e": round(under_a, 3), "shift": "bluer"}]  # fmt: skip


def test_a_users_spd_file_is_an_illuminant_whatever_its_scale(tmp_path, capsys):
    recipe = make_line(tmp_path / "line")
    led = colour.SDS_ILLUMINANTS["LED-B1"]
    table = SpectralTable(led.wavelengths, None, ("relative power",), 3.7 * led.values[None, :],
                          {"quantity": "radiance", "units": "relative"})  # fmt: skip
    write_spectra_csv(table, tmp_path / "line" / "home_led.csv")
    text = recipe.read_text(encoding="utf-8").replace('illuminants = ["D65", "A"]',
                                                      'illuminants = ["D65", "LED-B1", "home_led.csv"]')  # fmt: skip
    recipe.write_text(text.replace('tones = ["builtin:tcs13", "skin.csv"]', 'tones = ["skin.csv"]'), encoding="utf-8")
    assert cli.main(["review", str(recipe), "-o", str(tmp_path / "out")]) == 0
    document = json.loads((tmp_path / "out" / "review" / "review.json").read_text(encoding="utf-8"))
    assert document["illuminants"] == ["D65", "LED-B1", "home_led.csv"]
    for cell in document["tones"][0]["cells"]:
        by_name, by_file = cell["illuminants"]["LED-B1"], cell["illuminants"]["home_led.csv"]
        for key in ("coverage_delta_e", "match_delta_e", "made_up_lab", "made_up_srgb", "masstone_lab"):
            assert by_file[key] == pytest.approx(by_name[key], abs=1e-3)
    short = SpectralTable(led.wavelengths[4:], None, ("p",), led.values[None, 4:], {"quantity": "radiance"})
    write_spectra_csv(short, tmp_path / "line" / "home_led.csv")
    assert cli.main(["review", str(recipe), "-o", str(tmp_path / "out2")]) == 2
    error = " ".join(capsys.readouterr().err.split())
    assert str(tmp_path / "line" / "home_led.csv") in error and "must cover 380-780 nm" in error
    (tmp_path / "line" / "home_led.csv").unlink()
    assert cli.main(["review", str(recipe), "-o", str(tmp_path / "out2")]) == 2
    error = " ".join(capsys.readouterr().err.split())
    assert "review.illuminants[3]" in error and "does not exist" in error
