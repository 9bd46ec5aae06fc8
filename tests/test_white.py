"""Tests of white-standard normalisation (kmpipe.physics.white)."""

from __future__ import annotations

import re
from pathlib import Path

import colour
import numpy as np
import pytest

from kmpipe.errors import InputError
from kmpipe.formats.spectra import SpectralTable, read_spectra_csv, write_spectra_csv
from kmpipe.formats.spectral_grid import uniform_grid
from kmpipe.physics.white import (
    ReadingSource,
    baso4_typical,
    certified_reflectance,
    radiance_to_reflectance,
)

BUILTIN_FILE = Path(__file__).resolve().parents[1] / "kmpipe" / "data" / "baso4_typical.csv"
GRID = uniform_grid(380, 780, 5)


def d55() -> np.ndarray:
    """CIE D55 relative spectral power on GRID, scaled to a plausible radiance (W sr-1 m-2 nm-1)."""
    sd = colour.SDS_ILLUMINANTS["D55"]
    return np.array([sd[w] for w in GRID]) * 0.01 / np.pi


def skin() -> np.ndarray:
    """Reflectance of the ColorChecker (N. Ohta) 'dark skin' and 'light skin' patches on GRID: (2, n)."""
    patches = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    return np.array([[patches[name][w] for w in GRID] for name in ("dark skin", "light skin")])


def write_reflectance(path: Path, grid, columns: dict[str, np.ndarray], **metadata) -> Path:
    metadata = {"quantity": "reflectance", "units": "1", **metadata}
    values = np.array(list(columns.values()))
    write_spectra_csv(SpectralTable(np.asarray(grid, float), None, tuple(columns), values, metadata), path)
    return path


# --- the built-in typical BaSO4 curve -----------------------------------------------------------------------


def test_builtin_curve_file_is_a_typical_curve_not_a_certificate():
    table = read_spectra_csv(BUILTIN_FILE)
    assert table.quantity == "reflectance" and table.metadata["units"] == "1"
    assert table.columns == ("baso4",)
    assert np.array_equal(table.wavelengths, GRID)
    header = " ".join(table.metadata.values()).lower()
    assert "typical" in header and "not a calibration certificate" in header
    assert "certificate, pass that file instead" in header


def test_builtin_curve_has_the_typical_shape():
    fine = uniform_grid(380, 780, 1)
    r = baso4_typical(fine)
    at = dict(zip(fine.tolist(), r, strict=True))
    assert at[380] == pytest.approx(0.95, abs=0.005)
    assert at[400] == pytest.approx(0.975, abs=0.005)
    assert all(0.98 <= at[w] <= 0.99 for w in range(450, 701))
    assert at[780] == pytest.approx(0.984, abs=0.002)
    assert np.all(np.diff(r[:60]) > 0)  # rising out of the UV
    assert np.max(np.abs(np.diff(r, 2))) < 2e-4  # smooth at 1 nm
    assert np.array_equal(r[::5], read_spectra_csv(BUILTIN_FILE).column("baso4"))  # data points kept exactly


def test_builtin_curve_refuses_a_grid_beyond_380_780():
    with pytest.raises(InputError, match="380-780 nm") as err:
        baso4_typical(uniform_grid(360, 780, 10))
    assert "extrapolate" in str(err.value)


# --- certified reflectance of the white standard ------------------------------------------------------------


def test_certified_builtin_and_files(tmp_path):
    fine = uniform_grid(400, 700, 1)
    assert np.array_equal(certified_reflectance("builtin:baso4", fine, base_dir=tmp_path), baso4_typical(fine))

    cert_grid = uniform_grid(360, 830, 10)
    spectralon = 0.99 - 0.01 * np.exp(-(cert_grid - 360) / 30)
    (tmp_path / "certs").mkdir()
    write_reflectance(tmp_path / "certs" / "spectralon.csv", cert_grid, {"R": spectralon})
    got = certified_reflectance("certs/spectralon.csv", fine, base_dir=tmp_path)
    assert got.shape == fine.shape
    assert np.array_equal(got[::10], spectralon[4:35])  # 400, 410, ... 700 nm copied exactly
    assert np.max(np.abs(got - (0.99 - 0.01 * np.exp(-(fine - 360) / 30)))) < 1e-6

    two = write_reflectance(tmp_path / "two.csv", cert_grid, {"front": spectralon, "back": spectralon - 0.01})
    assert np.array_equal(certified_reflectance("two.csv:back", cert_grid, base_dir=tmp_path), spectralon - 0.01)
    assert np.array_equal(certified_reflectance(f"{two}:front", cert_grid, base_dir=Path("/")), spectralon)

    colon = write_reflectance(tmp_path / "cert:2026.csv", cert_grid, {"R": spectralon})
    assert np.array_equal(certified_reflectance(colon.name, cert_grid, base_dir=tmp_path), spectralon)


def certified_refusal(tmp_path, spec, grid=GRID):
    with pytest.raises(InputError) as err:
        certified_reflectance(spec, grid, base_dir=tmp_path)
    return str(err.value)


def test_certified_refusals(tmp_path):
    write_reflectance(tmp_path / "two.csv", GRID, {"front": np.full(GRID.size, 0.98), "back": np.full(81, 0.97)})
    write_reflectance(tmp_path / "narrow.csv", uniform_grid(400, 700, 10), {"R": np.full(31, 0.98)})
    dim = np.full(GRID.size, 0.98)
    dim[20] = 0.45
    write_reflectance(tmp_path / "grey.csv", GRID, {"R": dim})
    write_reflectance(tmp_path / "bright.csv", GRID, {"R": np.full(GRID.size, 1.2)})
    radiance = SpectralTable(GRID, None, ("L",), np.ones((1, GRID.size)), {"quantity": "radiance"})
    write_spectra_csv(radiance, tmp_path / "radiance.csv")
    write_spectra_csv(
        SpectralTable(GRID, None, ("R",), np.full((1, GRID.size), 0.98), {}), tmp_path / "no_quantity.csv"
    )
    camera = SpectralTable(None, ("R", "G", "B"), ("w",), np.full((1, 3), 0.98), {"quantity": "reflectance"})
    write_spectra_csv(camera, tmp_path / "camera.csv")

    assert "unknown built-in white standard 'builtin:spectralon'" in certified_refusal(tmp_path, "builtin:spectralon")
    message = certified_refusal(tmp_path, "missing.csv")
    assert "'missing.csv' not found" in message and "PATH:COLUMN" in message
    assert "'two.csv' has 2 columns (front, back); name one as PATH:COLUMN" in certified_refusal(tmp_path, "two.csv")
    message = certified_refusal(tmp_path, "two.csv:side")
    assert "two.csv" in message and "no column 'side'" in message and "'front', 'back'" in message
    message = certified_refusal(tmp_path, "narrow.csv")
    assert "narrow.csv" in message and "380-780 nm" in message and "400-700 nm" in message
    message = certified_refusal(tmp_path, "grey.csv")
    assert "'grey.csv' is 0.45 at 480 nm" in message and "(0.5, 1.05]" in message
    assert "1.2 at 380 nm" in certified_refusal(tmp_path, "bright.csv")
    assert "holds radiance" in certified_refusal(tmp_path, "radiance.csv")
    assert "no 'quantity' line" in certified_refusal(tmp_path, "no_quantity.csv")
    assert "camera channel table" in certified_refusal(tmp_path, "camera.csv")


# --- radiance to reflectance ---


def test_recovers_reflectance_from_simulated_radiance():
    illuminant = d55()
    certified = baso4_typical(GRID)
    reflectance = skin()
    dark = 2e-4 + 1e-7 * (GRID - 380)  # stray light rising towards the red
    white = illuminant * certified + dark
    sample = illuminant * reflectance + dark
    got = radiance_to_reflectance(sample, white, certified, dark=dark)
    assert got.shape == reflectance.shape
    assert np.max(np.abs(got - reflectance)) < 1e-12
    one = radiance_to_reflectance(sample[1], illuminant * certified, certified, dark=None)
    assert np.max(np.abs(one - (reflectance[1] + dark / illuminant))) < 1e-12  # no dark: offset stays in
    assert np.max(np.abs(radiance_to_reflectance(sample - dark, white - dark, certified) - reflectance)) < 1e-12
    scalar = radiance_to_reflectance(sample - dark + 1e-3, white - dark + 1e-3, certified, dark=1e-3)
    assert np.max(np.abs(scalar - reflectance)) < 1e-12


@pytest.fixture
def session(tmp_path):
    """A measurement file with dark, white and sample radiance, and the source describing it."""
    illuminant = d55()
    certified = baso4_typical(GRID)
    dark = np.full(GRID.size, 2e-4)
    values = np.array([dark, illuminant * certified + dark, illuminant * skin()[1] + dark])
    table = SpectralTable(GRID, None, ("dark", "baso4", "film"), values, {"quantity": "radiance"})
    write_spectra_csv(table, tmp_path / "session.csv")
    table = read_spectra_csv(tmp_path / "session.csv")
    source = ReadingSource.from_table(table, white="baso4", samples=["film"], dark="dark")
    readings = {name: np.array(table.column(name)) for name in table.columns}
    return readings, certified, source


def refusal(readings, reference, source, **changes):
    arrays = {**readings, **changes}
    with pytest.raises(InputError) as err:
        radiance_to_reflectance(
            arrays["film"],
            arrays["baso4"],
            arrays.get("certified", reference),
            dark=arrays["dark"],
            source=source,
        )
    assert err.value.path == source.path
    return err.value


def modified(array, index, value):
    array = array.copy()
    array[index] = value
    return array


def test_refuses_a_missing_white(session):
    readings, certified, source = session
    err = refusal(readings, certified, source, baso4=None)
    assert "no white-standard reading" in str(err) and "session.csv" in str(err)


def test_refuses_saturated_white(session):
    readings, certified, source = session
    white = readings["baso4"]
    err = refusal(readings, certified, source, baso4=modified(white, 20, -9.9999e9))
    assert "white reading 'baso4'" in str(err) and "480 nm" in str(err) and "CS-2000" in str(err)
    assert err.field == "baso4"
    err = refusal(readings, certified, source, baso4=modified(white, 3, 0.0))
    assert "395 nm" in str(err) and "positive" in str(err)
    peak = int(np.argmax(white))
    err = refusal(readings, certified, source, baso4=modified(white, slice(peak - 2, peak + 3), white.max() * 1.01))
    assert "clipped" in str(err) and "5 consecutive" in str(err)
    # a smooth peak printed with few digits may repeat its maximum two or three times: accepted
    rounded = modified(white, slice(peak - 1, peak + 2), white.max())
    radiance_to_reflectance(readings["film"], rounded, certified, dark=readings["dark"], source=source)


def test_refuses_saturated_or_non_finite_sample(session):
    readings, certified, source = session
    err = refusal(readings, certified, source, film=modified(readings["film"], 0, -9.9999e9))
    assert "sample reading 'film'" in str(err) and "380 nm" in str(err) and "CS-2000" in str(err)
    assert err.field == "film"
    err = refusal(readings, certified, source, film=modified(readings["film"], 1, np.nan))
    assert "385 nm" in str(err) and "finite" in str(err)


def test_refuses_implausibly_dim_white(session):
    readings, certified, source = session
    dark = modified(readings["dark"], 10, readings["baso4"][10] * 1.5)
    err = refusal(readings, certified, source, dark=dark)
    assert "not above the dark reading" in str(err) and "430 nm" in str(err) and err.field == "baso4"
    err = refusal(readings, certified, source, baso4=readings["film"], film=readings["baso4"])
    assert "darker than the sample" in str(err) and "white reading 'film'" not in str(err)
    err = refusal(readings, certified, source, baso4=readings["baso4"] * 0.5)
    assert "darker than the sample" in str(err) and "'baso4'" in str(err)


def test_refuses_dark_larger_than_reading(session):
    readings, certified, source = session
    dark = modified(readings["dark"], 30, readings["film"][30] * 1.01)
    err = refusal(readings, certified, source, dark=dark)
    assert "larger than the sample reading 'film'" in str(err) and "530 nm" in str(err)
    assert err.field == "film"
    err = refusal(readings, certified, source, dark=modified(readings["dark"], 2, -1e-6))
    assert "dark reading 'dark'" in str(err) and "negative" in str(err) and err.field == "dark"


def test_refuses_mismatched_shapes_and_bad_certified(session):
    readings, certified, source = session
    err = refusal(readings, certified, source, film=readings["film"][:-1])
    assert "do not share one wavelength grid" in str(err)
    err = refusal(readings, certified, source, dark=readings["dark"][:3])
    assert "do not share one wavelength grid" in str(err)
    err = refusal(readings, certified, source, certified=certified * 100)
    assert "percent" in str(err) and "380 nm" in str(err)


def test_source_may_be_a_plain_path():
    white = d55()
    with pytest.raises(InputError, match=re.escape("cs2000/run_7.csv: white reading is")):
        radiance_to_reflectance(
            white * 0.5, modified(white, 0, 0.0), np.full(GRID.size, 0.98), source="cs2000/run_7.csv"
        )
