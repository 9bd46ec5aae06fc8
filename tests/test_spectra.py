"""Tests of the spectral CSV format and of resampling (kmpipe.formats.spectra)."""

from __future__ import annotations

import json
import math
import os
import re
import tempfile
from pathlib import Path

import numpy as np
import pytest
from colour.algebra import SpragueInterpolator
from hypothesis import given, settings
from hypothesis import strategies as st

from kmpipe.errors import InputError
from kmpipe.formats.spectra import SpectralTable, read_spectra_csv, write_spectra_csv
from kmpipe.formats.spectral_grid import resample, uniform_grid

ROOT = Path(__file__).resolve().parents[1]


def smooth(wavelength_nm: np.ndarray) -> np.ndarray:
    """An analytic reflectance-like curve: a slope plus a Gaussian bump (fraction)."""
    x = np.asarray(wavelength_nm, dtype=float)
    return 0.2 + 0.0005 * (x - 380) + 0.5 * np.exp(-0.5 * ((x - 550) / 40) ** 2)


def write_text(tmp_path: Path, text: str, name: str = "spectra.csv") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def table(wavelengths, values, columns=("a",), **metadata) -> SpectralTable:
    return SpectralTable(
        wavelengths=np.asarray(wavelengths, dtype=float),
        channels=None,
        columns=tuple(columns),
        values=np.atleast_2d(np.asarray(values, dtype=float)),
        metadata=metadata,
    )


# --- reading and writing ------------------------------------------------------------------------------------


def test_read_example_with_metadata_comments_and_blank_lines(tmp_path):
    path = write_text(
        tmp_path,
        "# kmpipe-spectra: 1\n"
        "# a comment without a colon\n"
        "# quantity: reflectance\n"
        "# units: 1\n"
        "\n"
        "# geometry: d:8 / 45:0\n"
        "# lab notebook: p. 12\n"
        "wavelength_nm,baso4,thin_over_black\n"
        "380,0.95,0.0045\n"
        "\n"
        "381.5, 0.96 ,1e-3\n"
        "# 382,0.97,0.5 (commented-out row)\n"
        "390,0.97,0.5\n",
    )
    t = read_spectra_csv(path)
    assert t.path == path
    assert t.channels is None
    assert t.columns == ("baso4", "thin_over_black")
    assert t.wavelengths.tolist() == [380.0, 381.5, 390.0]
    assert t.values.tolist() == [[0.95, 0.96, 0.97], [0.0045, 0.001, 0.5]]
    assert list(t.metadata.items()) == [
        ("quantity", "reflectance"),
        ("units", "1"),
        ("geometry", "d:8 / 45:0"),
        ("lab notebook", "p. 12"),
    ]
    assert t.quantity == "reflectance"
    assert t.sample_labels == ["380", "381.5", "390"]
    assert t.column("thin_over_black").tolist() == [0.0045, 0.001, 0.5]


def test_crlf_and_byte_order_mark_are_accepted(tmp_path):
    path = tmp_path / "excel.csv"
    path.write_bytes(b"\xef\xbb\xbf# quantity: radiance\r\nwavelength_nm,a\r\n380,1\r\n385,2\r\n")
    t = read_spectra_csv(path)
    assert t.metadata == {"quantity": "radiance"}
    assert t.wavelengths.tolist() == [380.0, 385.0]


def test_round_trip_is_exact_and_keeps_metadata_order(tmp_path):
    rng = np.random.default_rng(7)
    wavelengths = uniform_grid(380, 780, 1)
    values = rng.uniform(0, 0.3, size=(3, wavelengths.size))
    values[0, 5] = 0.1 + 0.2  # 0.30000000000000004: needs all 17 significant digits
    values[1, 7] = 5e-324  # smallest subnormal
    metadata = {
        "quantity": "radiance",
        "units": "W sr-1 m-2 nm-1",
        "instrument": "Konica Minolta CS-2000A",
        "time": "2026-11-21T10:00:00Z",
        "geometry": "d:8 / 45:0",
        "empty": "",
        "zzz unknown key": "kept, with commas: and colons",
    }
    original = SpectralTable(wavelengths, None, ("baso4", 'film "A", thin', "über"), values, metadata)
    path = tmp_path / "out.csv"
    write_spectra_csv(original, path)
    back = read_spectra_csv(path)
    assert np.array_equal(back.wavelengths, wavelengths)
    assert np.array_equal(back.values, values)
    assert back.values[0, 5] == 0.30000000000000004
    assert back.values[1, 7] == 5e-324
    assert back.columns == original.columns
    assert list(back.metadata.items()) == list(metadata.items())
    text = path.read_text(encoding="utf-8")
    assert text.startswith("# kmpipe-spectra: 1\n# quantity: radiance\n")
    assert "\n380," in text and "\n780," in text  # whole wavelengths without ".0"


def test_channel_table_round_trip(tmp_path):
    camera = SpectralTable(
        wavelengths=None,
        channels=("R", "G", "B"),
        columns=("thin_over_black", "thin_over_white"),
        values=np.array([[0.412, 0.301, 0.226], [0.655, 0.54, 0.471]]),
        metadata={"quantity": "reflectance", "units": "1", "channels": "linear camera RGB, Canon EOS R5"},
    )
    path = tmp_path / "camera.csv"
    write_spectra_csv(camera, path)
    back = read_spectra_csv(path)
    assert back.wavelengths is None
    assert back.channels == ("R", "G", "B")
    assert back.sample_labels == ["R", "G", "B"]
    assert back.columns == camera.columns
    assert np.array_equal(back.values, camera.values)
    assert back.metadata == camera.metadata
    assert path.read_text(encoding="utf-8").splitlines()[4:] == [
        "channel,thin_over_black,thin_over_white",
        "R,0.412,0.655",
        "G,0.301,0.54",
        "B,0.226,0.471",
    ]


def test_write_replaces_atomically_and_leaves_no_temporary_file(tmp_path, monkeypatch):
    path = tmp_path / "out.csv"
    first = table([380, 390], [0.1, 0.2], quantity="reflectance")
    write_spectra_csv(first, path)
    write_spectra_csv(table([380, 390], [0.3, 0.4], quantity="reflectance"), path)
    assert read_spectra_csv(path).values.tolist() == [[0.3, 0.4]]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]

    before = path.read_bytes()

    def failing_fsync(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", failing_fsync)
    with pytest.raises(InputError) as err:
        write_spectra_csv(first, path)
    assert "No space left on device" in str(err.value) and "out.csv" in str(err.value)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_write_into_missing_directory_is_refused(tmp_path):
    with pytest.raises(InputError) as err:
        write_spectra_csv(table([380, 390], [0.1, 0.2]), tmp_path / "no" / "out.csv")
    assert "out.csv" in str(err.value)


@pytest.mark.parametrize(
    ("columns", "metadata", "fragment"),
    [
        ((" padded",), {}, "whitespace"),
        (("two\nlines",), {}, "line break"),
        (("a",), {"key:colon": "v"}, "contains ':'"),
        (("a",), {"#hash": "v"}, "starts with '#'"),
        (("a",), {"note": "two\nlines"}, "line break"),
    ],
)
def test_write_refuses_names_that_would_not_read_back(tmp_path, columns, metadata, fragment):
    path = tmp_path / "out.csv"
    with pytest.raises(InputError, match=re.escape(fragment)):
        write_spectra_csv(table([380, 390], [[0.1, 0.2]] * len(columns), columns, **metadata), path)
    assert not path.exists()


def test_write_refuses_impossible_values(tmp_path):
    with pytest.raises(InputError, match="negative"):
        write_spectra_csv(table([380, 390], [0.1, -0.2], quantity="reflectance"), tmp_path / "out.csv")


# --- refusals while reading: (file text, 1-based line, fragments the message must contain) ---

HEAD = "# quantity: reflectance\n# units: 1\n"  # lines 1 and 2

REFUSALS = {
    "missing first column": (HEAD + "baso4,film\n0.9,0.1\n", 3, ["first column is 'baso4'", "wavelength_nm"]),
    "unknown first column": (HEAD + "wavelength,a\n380,0.1\n", 3, ["'wavelength'", "'channel'"]),
    "semicolon separated": (HEAD + "wavelength_nm;a\n380;0.1\n", 3, ["comma-separated"]),
    "no measurement column": (HEAD + "wavelength_nm\n380\n", 3, ["no measurement columns"]),
    "too many fields": (
        HEAD + "wavelength_nm,a,b\n380,0.1,0.2\n390,0.1,0.2,0.3\n",
        5,
        ["4 fields, expected 3"],
    ),
    "too few fields": (HEAD + "wavelength_nm,a,b\n380,0.1\n", 4, ["2 fields, expected 3"]),
    "non-numeric": (HEAD + "wavelength_nm,a,b\n380,0.1,0.2\n390,0.1,abc\n", 5, ["'abc'", "decimal number"]),
    "empty cell": (HEAD + "wavelength_nm,a\n380,0.1\n390,\n", 5, ["empty cell"]),
    "underscore number": (HEAD + "wavelength_nm,a\n380,0.1\n390,1_0\n", 5, ["'1_0'"]),
    "nan": (HEAD + "wavelength_nm,a\n380,0.1\n390,NaN\n", 5, ["'NaN'", "finite"]),
    "inf": (HEAD + "wavelength_nm,a\n380,inf\n390,0.1\n", 4, ["'inf'", "finite"]),
    "overflow": (HEAD + "wavelength_nm,a\n380,1e999\n390,0.1\n", 4, ["'1e999'", "overflows"]),
    "nan wavelength": (HEAD + "wavelength_nm,a\n380,0.1\nnan,0.1\n", 5, ["wavelength 'nan'"]),
    "tiny negative radiance": (
        "# quantity: radiance\nwavelength_nm,dark,white\n380,0.0001,0.5\n381,-1e-06,0.6\n",
        4,
        ["negative radiance -1e-06", "column 'dark'", "381 nm"],
    ),
    "negative reflectance": (HEAD + "wavelength_nm,a,b\n380,0.1,0.2\n390,0.1,-0.02\n", 5, ["-0.02", "'b'"]),
    "negative without quantity": ("wavelength_nm,a\n380,0.1\n390,-0.5\n", 3, ["negative value -0.5"]),
    "cs2000 error value": (
        "# quantity: radiance\nwavelength_nm,white\n380,0.2\n381,-9.9999E+09\n",
        4,
        ["CS-2000 calculation-error value"],
    ),
    "reflectance in percent": (
        HEAD + "wavelength_nm,a\n380,88.2\n390,87.1\n",
        4,
        ["88.2", "above 1.5", "percent"],
    ),
    "reflectance slightly above 1.5": (HEAD + "wavelength_nm,a\n380,0.9\n390,1.51\n", 5, ["1.51"]),
    "unsorted wavelengths": (
        HEAD + "wavelength_nm,a\n380,0.1\n390,0.1\n385,0.1\n",
        6,
        ["385 nm is smaller than the previous row's 390 nm"],
    ),
    "duplicate wavelength": (HEAD + "wavelength_nm,a\n380,0.1\n380,0.2\n", 5, ["380 nm repeats"]),
    "negative wavelength": (HEAD + "wavelength_nm,a\n-380,0.1\n390,0.2\n", 4, ["not positive"]),
    "duplicate column names": (HEAD + "wavelength_nm,a,b,a\n380,1,1,1\n", 3, ["'a' appears twice"]),
    "empty column name": (HEAD + "wavelength_nm,a,,b\n380,1,1,1\n", 3, ["column 3", "no name"]),
    "empty table": (HEAD + "wavelength_nm,a\n\n", 3, ["no data rows"]),
    "one wavelength": (HEAD + "wavelength_nm,a\n550,0.5\n", 4, ["at least 2 wavelengths"]),
    "duplicate channel": (HEAD + "channel,a\nR,0.1\nG,0.2\nR,0.3\n", 6, ["channel 'R' appears twice"]),
    "empty channel": (HEAD + "channel,a\n,0.1\n", 4, ["channel name is empty"]),
    "metadata after header": (
        HEAD + "wavelength_nm,a\n380,0.1\n# time: today\n390,0.1\n",
        5,
        ["after the header"],
    ),
    "duplicate metadata key": (
        "# note: one\n# note: two\nwavelength_nm,a\n380,1\n390,1\n",
        2,
        ["'note'", "twice"],
    ),
    "unknown quantity": ("# quantity: irradiance\nwavelength_nm,a\n380,1\n390,1\n", 1, ["'irradiance'"]),
    "percent units": (
        "# quantity: reflectance\n# units: %\nwavelength_nm,a\n380,1\n390,1\n",
        2,
        ["'%'", "percent"],
    ),
    "format version 2": ("# kmpipe-spectra: 2\nwavelength_nm,a\n380,1\n390,1\n", 1, ["version '2'"]),
    "broken quoting": (HEAD + 'wavelength_nm,"a\n380,1\n', 3, ["not valid CSV"]),
}


@pytest.mark.parametrize("case", list(REFUSALS))
def test_refusals_name_file_and_line(tmp_path, case):
    text, line, fragments = REFUSALS[case]
    path = write_text(tmp_path, text, "bad_input.csv")
    with pytest.raises(InputError) as err:
        read_spectra_csv(path)
    assert err.value.path == path
    assert err.value.line == line
    message = str(err.value)
    assert message.startswith(f"{path}, line {line}:")
    for fragment in fragments:
        assert fragment in message


def test_refusals_without_a_line(tmp_path):
    with pytest.raises(InputError, match="does not exist") as err:
        read_spectra_csv(tmp_path / "absent.csv")
    assert err.value.path == tmp_path / "absent.csv"
    with pytest.raises(InputError, match="is a folder; expected a spectral CSV file") as err:
        read_spectra_csv(tmp_path)
    with pytest.raises(InputError, match="not a regular file"):
        read_spectra_csv("/dev/zero")

    only_metadata = write_text(tmp_path, "# quantity: radiance\n\n# note: nothing\n", "header_only.csv")
    with pytest.raises(InputError, match="no header row") as err:
        read_spectra_csv(only_metadata)
    assert "header_only.csv" in str(err.value)

    latin1 = tmp_path / "latin1.csv"
    latin1.write_bytes("# note: caf\u00e9\nwavelength_nm,a\n380,1\n390,1\n".encode("latin-1"))
    with pytest.raises(InputError, match="not UTF-8"):
        read_spectra_csv(latin1)


def test_table_accessors_refuse_with_names(tmp_path):
    path = write_text(tmp_path, "wavelength_nm,baso4,film\n380,0.9,0.1\n390,0.9,0.2\n", "session.csv")
    t = read_spectra_csv(path)
    with pytest.raises(InputError) as err:
        t.column("white")
    message = str(err.value)
    assert "session.csv" in message and "'white'" in message and "'baso4', 'film'" in message
    with pytest.raises(InputError, match="no 'quantity' line") as err:
        _ = t.quantity
    assert err.value.field == "quantity" and err.value.path == path


def test_construction_checks():
    with pytest.raises(ValueError, match="shape"):
        SpectralTable(np.array([380.0, 390.0]), None, ("a", "b"), np.zeros((1, 2)), {})
    with pytest.raises(ValueError, match="exactly one of"):
        SpectralTable(None, None, ("a",), np.zeros((1, 0)), {})
    with pytest.raises(InputError, match="at least one channel"):
        SpectralTable(None, (), ("a",), np.zeros((1, 0)), {})
    with pytest.raises(InputError, match="'a' appears twice"):
        table([380, 390], [[0.1, 0.2], [0.1, 0.2]], ("a", "a"))
    with pytest.raises(InputError, match="strictly increasing"):
        table([390, 380], [0.1, 0.2])
    with pytest.raises(InputError, match="not a finite number") as err:
        table([380, 390], [0.1, np.inf])
    assert err.value.field == "a" and "390" in str(err.value)
    with pytest.raises(InputError, match="'%'"):
        table([380, 390], [0.1, 0.2], quantity="reflectance", units="%")


def test_values_are_read_only():
    t = table([380, 390], [0.1, 0.2])
    with pytest.raises(ValueError, match="read-only"):
        t.values[0, 0] = 1.0


def test_docs_examples_are_valid(tmp_path):
    text = (ROOT / "docs" / "formats.md").read_text(encoding="utf-8")
    section = text.split("## Spectral CSV", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 2
    spectra = read_spectra_csv(write_text(tmp_path, blocks[0], "example.csv"))
    camera = read_spectra_csv(write_text(tmp_path, blocks[1], "camera.csv"))
    assert spectra.quantity == "reflectance" and spectra.wavelengths.tolist() == [380, 390, 400, 410]
    assert camera.channels == ("R", "G", "B")


# --- uniform grids ------------------------------------------------------------------------------------------


def test_uniform_grid_is_inclusive_and_exact_in_decimal():
    grid = uniform_grid(380, 780, 0.1)
    assert grid.size == 4001
    assert grid[0] == 380.0 and grid[-1] == 780.0
    assert grid[1] == float("380.1") and grid[2345] == float("614.5")
    assert np.array_equal(uniform_grid("380", "780", "5"), np.arange(380.0, 781.0, 5.0))
    assert uniform_grid(400.5, 400.5, 1).tolist() == [400.5]


@pytest.mark.parametrize(
    ("start", "stop", "step", "fragment"),
    [
        (380, 780, 0, "must be positive"),
        (380, 780, -5, "must be positive"),
        (780, 380, 5, "below its start"),
        (380, 781, 5, "whole number"),
        (380, float("nan"), 5, "finite"),
        (380, "abc", 5, "not a number"),
    ],
)
def test_uniform_grid_refusals(start, stop, step, fragment):
    with pytest.raises(InputError, match=re.escape(fragment)):
        uniform_grid(start, stop, step)


# --- resampling ---------------------------------------------------------------------------------------------


def test_resample_1_to_5_to_10_nm_keeps_coinciding_values_exactly():
    fine = uniform_grid(380, 780, 1)
    source = table(fine, [smooth(fine), 2 * smooth(fine)], ("a", "b"), quantity="reflectance")
    five = resample(source, uniform_grid(380, 780, 5))
    ten = resample(five, uniform_grid(380, 780, 10))
    assert np.array_equal(five.values, source.values[:, ::5])
    assert np.array_equal(ten.values, source.values[:, ::10])
    assert np.array_equal(ten.wavelengths, np.arange(380.0, 781.0, 10.0))
    assert np.allclose(ten.values[0], smooth(np.arange(380.0, 781.0, 10.0)), rtol=0, atol=1e-15)
    assert ten.columns == ("a", "b") and ten.metadata == {"quantity": "reflectance"}


def test_resample_between_samples_matches_the_analytic_curve():
    coarse = uniform_grid(380, 780, 5)
    source = table(coarse, smooth(coarse), quantity="reflectance")
    target = uniform_grid(382.5, 777.5, 5)  # no coinciding wavelengths: all Sprague
    result = resample(source, target)
    assert np.max(np.abs(result.values[0] - smooth(target))) < 1e-5
    fine = resample(source, uniform_grid(380, 780, 1))
    assert np.max(np.abs(fine.values[0] - smooth(fine.wavelengths))) < 1e-5


@pytest.fixture(scope="module")
def kimera(shared_data) -> tuple[np.ndarray, list[dict]]:
    """(wavelengths nm, entries) of the Kimera acrylic masstones: miciwan/PaintMixing data/masstone.json (MIT), in
    the shared data folder (see its README.md)."""
    entries = json.loads((shared_data / "paints" / "kimera_masstone.json").read_text(encoding="utf-8"))
    return np.array(entries[0]["values"], dtype=float), entries[1:]


@pytest.mark.parametrize("method", ["auto", "pchip", "cubic"])
def test_resample_uneven_kimera_grid_to_10_nm(kimera, method):
    wavelengths, _ = kimera
    assert wavelengths.size == 170 and np.ptp(np.diff(wavelengths)) > 0.5  # really uneven
    source = table(wavelengths, smooth(wavelengths), quantity="reflectance")
    target = uniform_grid(390, 710, 10)
    result = resample(source, target, method=method)
    assert np.max(np.abs(result.values[0] - smooth(target))) < 1e-3


def test_resample_real_kimera_masstones_stays_within_neighbouring_samples(kimera):
    wavelengths, entries = kimera
    names = [f"{e['name']}_{i}" for i, e in enumerate(entries)]
    values = np.array([e["reflectance"] for e in entries]) / 100  # percent -> fraction
    source = table(wavelengths, values, names, quantity="reflectance")
    target = uniform_grid(390, 710, 10)
    result = resample(source, target)
    right = np.searchsorted(wavelengths, target)
    low = np.minimum(values[:, right - 1], values[:, right])
    high = np.maximum(values[:, right - 1], values[:, right])
    assert np.all(result.values >= low) and np.all(result.values <= high)  # PCHIP: no overshoot


@pytest.mark.parametrize("grid", [(375, 780, 5), (380, 785, 5), (300, 900, 10)])
def test_resample_refuses_to_extrapolate(tmp_path, grid):
    path = write_text(tmp_path, HEAD + "wavelength_nm,a\n380,0.1\n580,0.2\n780,0.3\n", "narrow.csv")
    with pytest.raises(InputError) as err:
        resample(read_spectra_csv(path), uniform_grid(*grid))
    message = str(err.value)
    assert "narrow.csv" in message
    assert f"{grid[0]}-{grid[1]} nm" in message and "380-780 nm" in message and "extrapolate" in message


def test_resample_refuses_channel_tables_bad_grids_and_bad_methods(kimera):
    camera = SpectralTable(None, ("R", "G", "B"), ("a",), np.array([[0.1, 0.2, 0.3]]), {})
    with pytest.raises(InputError, match="channel table"):
        resample(camera, [450, 550])
    spectrum = table(uniform_grid(380, 780, 5), smooth(uniform_grid(380, 780, 5)))
    for grid in ([], [500, 450], [450, np.nan], [[450, 550]]):
        with pytest.raises(InputError, match="strictly increasing"):
            resample(spectrum, grid)
    with pytest.raises(InputError, match="'spline' is not one of"):
        resample(spectrum, [452.5], method="spline")
    wavelengths, _ = kimera
    uneven = table(wavelengths, smooth(wavelengths))
    with pytest.raises(InputError, match="uniform source grid"):
        resample(uneven, [500.0], method="sprague")


def test_resample_clips_small_overshoot_and_refuses_large(tmp_path):
    grid = uniform_grid(380, 480, 5)
    step_up = np.where(grid < 430, 0.0, 1.0)

    def sprague(values, at):
        return SpragueInterpolator(grid, values)(at)

    target = uniform_grid(382.5, 477.5, 5)
    small = step_up * 0.01
    assert -1e-3 < sprague(small, target).min() < 0  # the reference interpolator undershoots, a little
    result = resample(table(grid, small, quantity="reflectance"), target)
    assert result.values.min() == 0.0
    assert np.array_equal(result.values[0], np.maximum(sprague(small, target), 0.0))

    assert sprague(step_up, target).min() < -1e-3
    path = write_text(
        tmp_path,
        HEAD + "wavelength_nm,edge\n" + "".join(f"{w:g},{v:g}\n" for w, v in zip(grid, step_up, strict=True)),
        "edge.csv",
    )
    with pytest.raises(InputError) as err:
        resample(read_spectra_csv(path), target)
    assert "edge.csv" in str(err.value) and err.value.field == "edge" and "undershoots" in str(err.value)
    assert np.all(resample(read_spectra_csv(path), target, method="pchip").values >= 0)


def test_radiance_overshoot_tolerance_scales_with_the_column_peak():
    grid = uniform_grid(380, 780, 5)
    target = uniform_grid(382.5, 777.5, 5)
    edge = np.where(grid < 430, 0.0, 0.01)  # Sprague undershoots this edge by about 9e-4
    assert SpragueInterpolator(grid, edge)(target).min() < -5e-4
    bright = edge + 10 * np.exp(-0.5 * ((grid - 650) / 40) ** 2)  # same edge, in a column peaking at ~10
    result = resample(table(grid, bright, quantity="radiance"), target)
    assert result.values.min() == 0.0
    with pytest.raises(InputError, match="undershoots"):  # 9e-4 below zero in a column peaking at 0.01
        resample(table(grid, edge, quantity="radiance"), target)


# --- property: any valid table survives a write and a read unchanged ---

NAME = st.text(
    alphabet=st.characters(codec="utf-8", exclude_categories=("Cc", "Cs", "Zl", "Zp")),
    min_size=1,
    max_size=12,
).filter(lambda s: s == s.strip() and not s.startswith("#"))
KEY = NAME.filter(lambda s: ":" not in s and s not in ("kmpipe-spectra", "quantity", "units"))
VALUE = st.one_of(st.just(""), NAME)


@st.composite
def tables(draw) -> SpectralTable:
    quantity = draw(st.sampled_from(["radiance", "reflectance"]))
    high = 1.5 if quantity == "reflectance" else 1e6
    columns = draw(st.lists(NAME, min_size=1, max_size=4, unique=True))
    if draw(st.booleans()):
        wavelengths = sorted(
            draw(st.lists(st.floats(min_value=1e-3, max_value=1e5), min_size=2, max_size=15, unique=True))
        )
        channels, n = None, len(wavelengths)
    else:
        wavelengths, channels = None, tuple(draw(st.lists(NAME, min_size=1, max_size=5, unique=True)))
        n = len(channels)
    values = draw(
        st.lists(
            st.lists(st.floats(min_value=0, max_value=high, allow_subnormal=True), min_size=n, max_size=n),
            min_size=len(columns),
            max_size=len(columns),
        )
    )
    extra = draw(st.dictionaries(KEY, VALUE, max_size=4))
    metadata = {"quantity": quantity, **extra}
    return SpectralTable(wavelengths, channels, tuple(columns), np.array(values), metadata)


@settings(max_examples=150, deadline=None)
@given(tables())
def test_random_tables_round_trip_exactly(original):
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "t.csv"
        write_spectra_csv(original, path)
        back = read_spectra_csv(path)
    assert back.columns == original.columns
    assert back.channels == original.channels
    if original.wavelengths is None:
        assert back.wavelengths is None
    else:
        assert back.wavelengths.tobytes() == original.wavelengths.tobytes()
    assert np.array_equal(back.values, original.values)
    assert all(
        math.copysign(1, a) == math.copysign(1, b) for a, b in zip(back.values.flat, original.values.flat, strict=True)
    )
    assert list(back.metadata.items()) == list(original.metadata.items())
