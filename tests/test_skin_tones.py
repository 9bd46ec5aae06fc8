"""Skin tones for shade reviews (kmpipe.formats.skin_tones): the built-in chart and complexion samples against
colour-science's own data and colorimetry, the lab's CSV and panel files, and what is refused."""

from __future__ import annotations

import math
from pathlib import Path

import colour
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from kmpipe.errors import InputError
from kmpipe.formats.skin_tones import BUILTIN, read_tones, tone_digests, tone_id
from kmpipe.formats.spectra import SpectralTable, write_spectra_csv

GRID = np.arange(380.0, 781.0, 5.0)

pytestmark = pytest.mark.filterwarnings("ignore:Aligning:colour.utilities.ColourRuntimeWarning")


def write_skin(path: Path, wavelengths, columns: dict[str, np.ndarray], **metadata) -> Path:
    table = SpectralTable(np.asarray(wavelengths, float), None, tuple(columns), np.array(list(columns.values())),
                          {"quantity": "reflectance", "units": "1", **metadata})  # fmt: skip
    write_spectra_csv(table, path)
    return path


def write_raw_skin(path: Path, wavelengths, values) -> Path:
    """A reflectance CSV written as text (kmpipe's writer refuses impossible values itself)."""
    rows = "".join(f"{w:g},{v!r}\n" for w, v in zip(wavelengths, values, strict=True))
    path.write_text(f"# kmpipe-spectra: 1\n# quantity: reflectance\n# units: 1\nwavelength_nm,tone\n{rows}")
    return path


def smooth_skin(wavelengths) -> np.ndarray:
    w = np.asarray(wavelengths, float)
    return 0.15 + 0.45 / (1.0 + np.exp(-(w - 590.0) / 25.0))


def test_builtin_tones_are_colour_sciences_chart_and_complexion_samples():
    tones = read_tones(["builtin"], None, Path("."), {})
    assert [t.id for t in tones] == list(BUILTIN)
    assert {t.kind for t in tones} == {"chart patch", "complexion sample"}
    pmc = colour.SDS_COLOURCHECKERS["PMC"]
    tcs = colour.quality.SDS_TCS
    expected = {"pmc-1": pmc["Caucasian"], "pmc-4": pmc["African"], "tcs13": tcs["CIE 1995"]["TCS13"],
                "tcs15": tcs["CIE 2024"]["TCS15"],
                "cc-dark-skin": colour.SDS_COLOURCHECKERS["BabelColor Average"]["dark skin"]}  # fmt: skip
    by_id = {t.id: t for t in tones}
    for key, sd in expected.items():
        np.testing.assert_array_equal(by_id[key].wavelengths, sd.wavelengths)
        np.testing.assert_allclose(by_id[key].reflectance, sd.values, rtol=0, atol=1e-12)
        assert "skin" in by_id[key].name.lower() or "complexion" in by_id[key].name.lower()


def test_a_builtin_tone_outside_its_data_keeps_its_end_values():
    [tone] = read_tones(["builtin:pmc-2"], GRID, Path("."), {})
    sd = colour.SDS_COLOURCHECKERS["PMC"]["Oriental"]
    assert tone.reflectance[GRID < 400].tolist() == [sd.values[0]] * 4
    assert tone.reflectance[GRID > 700].tolist() == [sd.values[-1]] * 16
    on = np.isin(GRID, sd.wavelengths)
    np.testing.assert_allclose(tone.reflectance[on], sd.values, atol=1e-12)


def test_ita_agrees_with_colour_science_lab_under_d65_10_degree():
    for tone in read_tones(["builtin"], None, Path("."), {}):
        cmfs = colour.MSDS_CMFS["CIE 1964 10 Degree Standard Observer"]
        sd = colour.SpectralDistribution(dict(zip(tone.wavelengths, tone.reflectance, strict=True)))
        illuminant = colour.SDS_ILLUMINANTS["D65"]
        XYZ = colour.sd_to_XYZ(sd, cmfs, illuminant, method="Integration") / 100.0
        white = colour.sd_to_XYZ(colour.sd_ones(sd.shape), cmfs, illuminant, method="Integration")
        L, _, b = colour.XYZ_to_Lab(XYZ, colour.XYZ_to_xy(white / 100.0))
        assert tone.ita_deg == pytest.approx(math.degrees(math.atan2(L - 50.0, b)), abs=1e-9)
    by_id = {t.id: t for t in read_tones(["builtin"], GRID, Path("."), {})}
    assert by_id["tcs13"].ita_class == "very light" and by_id["cc-dark-skin"].ita_class == "dark"  # Chardon bounds


def test_csv_tones_are_resampled_named_and_sited(tmp_path):
    w = np.arange(360.0, 831.0, 1.0)
    write_skin(tmp_path / "panel.csv", w, {"V01 cheek": smooth_skin(w), "V02": 0.8 * smooth_skin(w)},
                      **{"site.V01 cheek": "cheek"})  # fmt: skip
    tones = read_tones(["panel.csv"], GRID, tmp_path, {})
    assert [(t.id, t.name, t.site, t.kind) for t in tones] == [("v01-cheek", "V01 cheek", "cheek", "measured"),
                                                                ("v02", "V02", None, "measured")]  # fmt: skip
    np.testing.assert_allclose(tones[0].reflectance, smooth_skin(GRID), atol=1e-9)  # samples coincide: copied
    [one] = read_tones(["panel.csv:V02"], GRID, tmp_path, {})
    np.testing.assert_allclose(one.reflectance, 0.8 * smooth_skin(GRID), atol=1e-9)


def test_a_panel_file_gives_names_sites_and_ids(tmp_path):
    write_skin(tmp_path / "skin.csv", GRID, {"a": smooth_skin(GRID), "b": 0.5 * smooth_skin(GRID)})
    (tmp_path / "panel.toml").write_text(
        '[[tone]]\nname = "Volunteer 7"\nsite = "inner forearm"\nspectrum = "skin.csv:b"\n'
        '[[tone]]\nname = "Volunteer 8"\nid = "v8"\nspectrum = "skin.csv:a"\n',
        encoding="utf-8",
    )
    tones = read_tones(["panel.toml"], GRID, tmp_path, {})
    assert [(t.id, t.name, t.site) for t in tones] == [("volunteer-7", "Volunteer 7", "inner forearm"),
                                                       ("v8", "Volunteer 8", None)]  # fmt: skip
    np.testing.assert_allclose(tones[0].reflectance, 0.5 * smooth_skin(GRID), atol=1e-12)
    native = read_tones(["panel.toml"], None, tmp_path, {})  # as read: the CSV's own grid
    np.testing.assert_array_equal(native[1].wavelengths, GRID)
    assert [i for _, i, _ in tone_digests(["panel.toml"], tmp_path, {})] == ["volunteer-7", "v8"]


@pytest.mark.parametrize(
    ("make", "words", "field"),
    [
        (lambda w: smooth_skin(w), "covers 400-700 nm; the review needs 380-780", "wavelength"),
        (lambda w: smooth_skin(w) - 0.2, "negative reflectance", "tone"),
        (lambda w: smooth_skin(w) + 0.5, "is above 1", "tone"),
    ],
    ids=["off the grid", "negative", "above 1"],
)
def test_bad_skin_csv_is_refused_naming_the_file(tmp_path, make, words, field):
    w = np.arange(400.0, 701.0, 10.0) if "covers" in words else GRID
    path = write_raw_skin(tmp_path / "skin.csv", w, make(w))
    with pytest.raises(InputError) as err:
        read_tones(["skin.csv"], GRID, tmp_path, {})
    assert words in err.value.message and err.value.path == path and err.value.field == field


def test_unknown_sources_ids_and_repeats_are_refused(tmp_path):
    write_skin(tmp_path / "skin.csv", GRID, {"light skin": smooth_skin(GRID)})
    cases = {"builtin:nobody": "no built-in skin tone 'nobody'", "skin.txt": "unknown skin-tone source",
             "missing.csv": "does not exist", "skin.csv:other": "no column 'other'"}  # fmt: skip
    for source, words in cases.items():
        with pytest.raises(InputError, match=words):
            read_tones([source], GRID, tmp_path, {"field": "review.tones"})
    with pytest.raises(InputError, match="share the id"):
        read_tones(["skin.csv", "skin.csv"], GRID, tmp_path, {})
    (tmp_path / "panel.toml").write_text('[[tone]]\nname = "x"\nspectrum = "skin.csv"\n', encoding="utf-8")
    with pytest.raises(InputError, match="give the column") as err:
        read_tones(["panel.toml"], GRID, tmp_path, {})
    assert err.value.field == "tone[1].spectrum"


def test_digests_change_only_for_the_tone_that_changed(tmp_path):
    write_skin(tmp_path / "skin.csv", GRID, {"a": smooth_skin(GRID)})
    before = {i: d for _, i, d in tone_digests(["builtin:tcs13", "skin.csv"], tmp_path, {})}
    write_skin(tmp_path / "skin.csv", GRID, {"a": smooth_skin(GRID), "b": 0.9 * smooth_skin(GRID)})
    after = {i: d for _, i, d in tone_digests(["builtin:tcs13", "skin.csv"], tmp_path, {})}
    assert after["a"] == before["a"] and after["tcs13"] == before["tcs13"] and set(after) == {"tcs13", "a", "b"}
    write_skin(tmp_path / "skin.csv", GRID, {"a": 0.99 * smooth_skin(GRID), "b": 0.9 * smooth_skin(GRID)})
    again = {i: d for _, i, d in tone_digests(["skin.csv"], tmp_path, {})}
    assert again["a"] != after["a"] and again["b"] == after["b"]


@given(st.text(min_size=0, max_size=40))
def test_tone_ids_are_file_safe(name):
    ident = tone_id(name)
    assert ident and all(c.isascii() and (c.isalnum() or c == "-") for c in ident)
    assert ident == ident.lower() and ident not in (".", "..")
