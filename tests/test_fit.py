"""Fitting K and S (kmpipe fit, kmpipe.stages.fit, kmpipe.physics.joint_fit, kmpipe.formats.material) against known
truth.

Samples are simulated in a temporary folder from known K and S (Duncan mixtures of the RIT Golden acrylic
table, scaled x60 to 1/mm) with the closed-form Kubelka-Munk forward model of ``kmpipe.physics.kubelka_munk``
(itself checked against 50-digit arithmetic in test_kubelka_munk.py), written as reflectance CSVs with a
manifest (``simulation.simulate_sample``), and fitted through the command line. The fitted K and S are compared
with the truth that made the readings; standard errors are checked by their coverage of the truth over many noisy
repeats; the joint fit's analytic derivatives are compared with mpmath differentiation of the textbook formula.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from pathlib import Path

import mpmath
import numpy as np
import pytest
from simulation import FOUNDATION, REFLECTANCE, cards, rit_mixture, simulate_sample

from kmpipe import cli
from kmpipe.formats.material import read_material, write_material
from kmpipe.formats.sample import load_sample
from kmpipe.formats.spectra import SpectralTable, read_spectra_csv, write_spectra_csv
from kmpipe.formats.spectral_grid import uniform_grid
from kmpipe.physics.joint_fit import _Model, _second_difference_penalty
from kmpipe.physics.kubelka_munk import reflectance_infinite, reflectance_over_background
from kmpipe.physics.white import baso4_typical
from kmpipe.stages.fit import fit_sample

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "recipes" / "samples"
SAUNDERSON = (0.04, 0.6)


def _no_constants(name: str):
    raise AssertionError(f"the JSON holds {name}")


def strict_json(path: Path):
    """The JSON document at ``path``, refusing NaN and Infinity (which are not JSON)."""
    return json.loads(path.read_text(encoding="utf-8"), parse_constant=_no_constants)


def run_fit(capsys, *args: str) -> tuple[int, str]:
    status = cli.main(["fit", *args])
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    return status, captured.err


def rel_err(got, want) -> np.ndarray:
    return np.abs(np.asarray(got) / np.asarray(want) - 1.0)


@pytest.fixture(scope="module")
def foundation():
    return rit_mixture(FOUNDATION)


# --- noise-free recovery ------------------------------------------------------------------------------------


@pytest.mark.parametrize("saunderson", [None, SAUNDERSON], ids=["plain", "saunderson"])
@pytest.mark.parametrize("method", ["two-constant", "black-white", "lsq"])
def test_noise_free_readings_give_back_k_and_s(tmp_path, capsys, foundation, method, saunderson):
    wavelengths, K, S = foundation
    manifest = simulate_sample(tmp_path / "sample", wavelengths, K, S, saunderson=saunderson).manifest
    out = tmp_path / "material.json"
    extra = ["--saunderson", f"{saunderson[0]},{saunderson[1]}"] if saunderson else []
    status, err = run_fit(capsys, str(manifest), "-o", str(out), "--method", method, *extra)
    assert status == 0, err
    material = read_material(out)
    strict_json(out)
    assert material.method == method
    assert material.saunderson == saunderson
    assert np.array_equal(material.wavelengths, wavelengths)
    tolerance = 1e-9 if method == "lsq" else 1e-6
    assert np.max(rel_err(material.K, K)) < tolerance
    assert np.max(rel_err(material.S, S)) < tolerance
    assert not material.flags.any()
    # The fitted material reproduces every reading it came from.
    assert max(m.rmse for m in material.measurements) < 1e-9
    # K/S is the KM convention's: (1 - R_inf)^2 / (2 R_inf) of the true masstone.
    R_inf = reflectance_infinite(K, S)
    assert np.max(rel_err(material.ks_ratio, (1.0 - R_inf) ** 2 / (2.0 * R_inf))) < tolerance


def test_fit_settings_from_the_manifest_equal_command_line_options(tmp_path, capsys, foundation):
    wavelengths, K, S = foundation
    fit_table = f'[fit]\nmethod = "black-white"\nsaunderson = [{SAUNDERSON[0]}, {SAUNDERSON[1]}]\n'
    in_manifest = simulate_sample(tmp_path / "a", wavelengths, K, S, saunderson=SAUNDERSON, fit_table=fit_table)
    on_line = simulate_sample(tmp_path / "b", wavelengths, K, S, saunderson=SAUNDERSON).manifest
    assert run_fit(capsys, str(in_manifest.manifest), "-o", str(tmp_path / "a.json"))[0] == 0
    options = ["--method", "black-white", "--saunderson", f"{SAUNDERSON[0]},{SAUNDERSON[1]}"]
    assert run_fit(capsys, str(on_line), "-o", str(tmp_path / "b.json"), *options)[0] == 0
    a, b = read_material(tmp_path / "a.json"), read_material(tmp_path / "b.json")
    assert a.method == b.method == "black-white"
    assert a.saunderson == b.saunderson == SAUNDERSON
    assert np.array_equal(a.K, b.K) and np.array_equal(a.S, b.S)
    assert np.max(rel_err(a.K, K)) < 1e-6


def test_repeats_are_several_entries_with_the_same_film(tmp_path, foundation):
    """Two identical film entries (a repeat) change nothing in a noise-free fit."""
    wavelengths, K, S = foundation
    manifest = simulate_sample(tmp_path / "s", wavelengths, K, S).manifest
    text = manifest.read_text(encoding="utf-8")
    repeat = '\n[[film]]\nfile = "readings.csv"\ncolumn = "film_15um_black_1"\nover = "black"\nthickness = "15 um"\n'
    manifest.write_text(text + repeat, encoding="utf-8")
    sample = load_sample(manifest)
    assert len(sample.measurements) == 6
    material = fit_sample(sample, method="lsq")
    assert np.max(rel_err(material.K, K)) < 1e-9
    assert np.max(rel_err(material.S, S)) < 1e-9


# --- standard errors: coverage of the truth -----------------------------------------------------------------


@pytest.mark.parametrize("given", [True, False], ids=["noise-given", "noise-from-residuals"])
def test_standard_errors_cover_the_truth(tmp_path, foundation, given):
    """Gaussian noise of known sigma on every reading; 25 independent repeats of the sample, 38 wavelengths.

    The fraction of (repeat, wavelength) pairs whose true K (and S) lies within +-1 reported standard
    error must be near 0.683, within +-2 near 0.954. With the sigma estimated from the residuals (3 degrees
    of freedom per wavelength, pooled over wavelengths) the coverage is about the same.
    """
    wavelengths, K, S = foundation
    sigma = 0.002
    rng = np.random.default_rng(20261121)
    z_K, z_S, sigmas = [], [], []
    for repeat in range(25):
        manifest = simulate_sample(tmp_path / f"r{repeat}", wavelengths, K, S, noise=sigma, rng=rng).manifest
        material = fit_sample(load_sample(manifest), method="lsq", noise=sigma if given else None)
        assert material.fit["noise_source"] == ("given" if given else "residuals")
        sigmas.append(material.fit["noise_sigma"])
        assert np.all(np.isfinite(material.K_stderr)) and np.all(material.K_stderr > 0)
        z_K.append((material.K - K) / material.K_stderr)
        z_S.append((material.S - S) / material.S_stderr)
    z_K, z_S = np.abs(np.concatenate(z_K)), np.abs(np.concatenate(z_S))
    for z in (z_K, z_S):
        assert 0.60 <= np.mean(z <= 1.0) <= 0.76
        assert 0.92 <= np.mean(z <= 2.0) <= 0.985
    if given:
        assert sigmas == [sigma] * 25
    else:
        assert np.mean(sigmas) == pytest.approx(sigma, rel=0.05)


# --- the bundled (simulated) samples ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bundled(tmp_path_factory):
    out = tmp_path_factory.mktemp("bundled")
    manifests = sorted(str(p) for p in SAMPLES.glob("*/manifest.toml"))
    status = cli.main(["fit", *manifests, "-o", str(out)])
    return status, out, manifests


def test_bundled_samples_fit_close_to_their_truth(bundled):
    status, out, manifests = bundled
    assert status == 0
    assert sorted(Path(m).parent.name for m in manifests) == ["B1", "E1", "F1", "F2", "L1", "L2"]
    written = sorted(p.name for p in out.glob("*.json"))
    assert written == sorted(f"{Path(m).parent.name}.json" for m in manifests)
    for manifest in manifests:
        name = Path(manifest).parent.name
        truth = json.loads((Path(manifest).parent / "truth.json").read_text(encoding="utf-8"))
        material = read_material(out / f"{name}.json")
        assert material.name == name
        grid = material.wavelengths
        K = np.interp(grid, truth["wavelengths_nm"], truth["K_per_mm"])
        S = np.interp(grid, truth["wavelengths_nm"], truth["S_per_mm"])
        assert np.median(rel_err(material.K, K)) < 0.05, name
        assert np.median(rel_err(material.S, S)) < 0.05, name
        # Noise there is ~0.6 % of each reading (not one sigma for all), so the errors are approximate.
        assert np.mean(np.abs(material.K - K) <= 2.0 * material.K_stderr) >= 0.5, name
        assert np.mean(np.abs(material.S - S) <= 2.0 * material.S_stderr) >= 0.5, name


def test_bundled_materials_are_strict_json_with_true_provenance(bundled):
    status, out, manifests = bundled
    assert status == 0
    for manifest in manifests:
        folder = Path(manifest).parent
        doc = strict_json(out / f"{folder.name}.json")
        provenance = doc["provenance"]
        inputs = {(out / item["path"]).resolve(): item["sha256"] for item in provenance["inputs"]}
        expected = {
            folder / "manifest.toml",
            folder / f"{folder.name}.csv",
            folder / "backings.csv",
            folder / "white.csv",
        }
        assert set(inputs) == {p.resolve() for p in expected}
        for path, digest in inputs.items():
            assert digest == hashlib.sha256(path.read_bytes()).hexdigest()
        assert (out / provenance["manifest"]).resolve() == (folder / "manifest.toml").resolve()


# --- the material file --------------------------------------------------------------------------------------


def test_material_round_trip_is_exact(tmp_path, foundation):
    wavelengths, K, S = foundation
    rng = np.random.default_rng(7)
    manifest = simulate_sample(tmp_path / "s", wavelengths, K, S, noise=0.002, rng=rng).manifest
    material = fit_sample(load_sample(manifest), method="lsq")
    # Make the round trip harder: unbounded errors at a few wavelengths and every flag somewhere.
    K_se = material.K_stderr.copy()
    S_se = material.S_stderr.copy()
    K_se[[0, 5]] = np.inf
    S_se[[5, 9]] = np.inf
    flags = np.zeros(wavelengths.size, dtype=np.uint8)
    flags[[1, 2]] = 1
    flags[3] = 2 | 8
    flags[4] = 4
    flags[10] = 1 | 2 | 4 | 8
    material = dataclasses.replace(material, K_stderr=K_se, S_stderr=S_se, flags=flags, provenance={"note": "test"})
    path = tmp_path / "m.json"
    write_material(material, path)
    doc = strict_json(path)
    assert doc["K_stderr"][0] is None and doc["K_stderr"][5] is None
    assert doc["S_stderr"][5] is None and doc["S_stderr"][9] is None
    assert sum(v is None for v in doc["K_stderr"] + doc["S_stderr"]) == 4
    assert doc["flags"]["opaque"] == [wavelengths[1], wavelengths[2], wavelengths[10]]
    assert doc["flags"]["no_contrast"] == [wavelengths[4], wavelengths[10]]
    back = read_material(path)
    for name in ("wavelengths", "K", "S", "K_stderr", "S_stderr", "flags"):
        assert np.array_equal(getattr(back, name), getattr(material, name)), name
    assert back.flags.dtype == np.uint8
    for a, b in zip(back.measurements, material.measurements, strict=True):
        assert (a.id, a.role, a.over, a.thickness_mm) == (b.id, b.role, b.over, b.thickness_mm)
        assert np.array_equal(a.residuals, b.residuals)
    assert math.isinf(back.measurements[0].thickness_mm)
    assert doc["measurements"][0]["thickness_mm"] is None
    for name in ("name", "product", "kind", "method", "saunderson", "fit", "provenance", "channels"):
        assert getattr(back, name) == getattr(material, name), name
    assert doc["units"] == {"K": "1/mm", "S": "1/mm", "thickness": "mm"}
    assert "2 R_inf" in doc["ks_convention"]


@pytest.mark.parametrize("method", ["black-white", "lsq"])
def test_exactly_determined_fit_has_null_standard_errors(tmp_path, capsys, foundation, method):
    """One thickness over two cards, no masstone: two readings, two unknowns, no residual to show noise.

    K and S come back exactly, the standard errors are null (unknown), and nothing is flagged: the film
    (S X ~ 1) is far from opaque.
    """
    wavelengths, K, S = foundation
    manifest = simulate_sample(tmp_path / "s", wavelengths, K, S, thicknesses_um=(20,), masstones=0).manifest
    out = tmp_path / "m.json"
    status, err = run_fit(capsys, str(manifest), "-o", str(out), "--method", method)
    assert status == 0, err
    doc = strict_json(out)
    assert doc["K_stderr"] is None and doc["S_stderr"] is None
    assert doc["fit"]["noise_sigma"] is None
    material = read_material(out)
    assert material.K_stderr is None and material.S_stderr is None
    assert np.max(rel_err(material.K, K)) < 1e-6
    assert np.max(rel_err(material.S, S)) < 1e-6
    assert doc["flags"] == {}


def cli_status(capsys, args: list[str]) -> tuple[int, str]:
    """Exit status of ``kmpipe ARGS`` run in-process (argparse refusals raise SystemExit) and its stderr."""
    try:
        status = cli.main(args)
    except SystemExit as stop:
        status = stop.code
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return status, err


@pytest.mark.parametrize(
    "option", [["--noise=-0.01"], ["--noise=0"], ["--noise=nan"], ["--noise=inf"], ["--smoothness=-1"]]
)
def test_fit_options_are_checked_like_the_manifest_fields(tmp_path, capsys, foundation, option):
    """The manifest refuses noise outside (0, 0.5) and negative smoothness; the options must refuse them too."""
    wavelengths, K, S = foundation
    manifest = simulate_sample(tmp_path / "s", wavelengths, K, S).manifest
    out = tmp_path / "m.json"
    status, err = cli_status(capsys, ["fit", str(manifest), "-o", str(out), *option])
    assert status == 2
    assert option[0].split("=")[0] in err
    assert not out.exists()


def test_two_samples_with_one_name_do_not_overwrite_each_other(tmp_path, capsys, foundation):
    """Two manifests whose [sample] name is the same would both be written to OUT/NAME.json.

    The second would silently replace the first; kmpipe must refuse (exit 2) instead.
    """
    wavelengths, K, S = foundation
    first = simulate_sample(tmp_path / "a", wavelengths, K, S, name="same").manifest
    second = simulate_sample(tmp_path / "b", wavelengths, K * 1.1, S, name="same").manifest
    out = tmp_path / "out"
    status, err = cli_status(capsys, ["fit", str(first), str(second), "-o", str(out)])
    assert status == 2
    assert "same" in err


# --- opaque films -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["two-constant", "black-white", "lsq"])
def test_opaque_films_are_flagged_and_keep_exact_k_over_s(tmp_path, capsys, foundation, method):
    """Films of 2 and 5 mm (S X of 40-300) hide both cards: thickness is not identifiable.

    Every wavelength is flagged opaque, K/S equals (1 - R)^2 / (2 R) of the masstone reading, K and S are
    finite, non-negative and no larger than the truth (the lower bound at which the film looks opaque).
    """
    wavelengths, K, S = foundation
    manifest = simulate_sample(tmp_path / "s", wavelengths, K, S, thicknesses_um=(2000, 5000)).manifest
    out = tmp_path / "m.json"
    status, err = run_fit(capsys, str(manifest), "-o", str(out), "--method", method)
    assert status == 0, err
    doc = strict_json(out)
    assert doc["flags"]["opaque"] == list(wavelengths)
    material = read_material(out)
    R = read_spectra_csv(tmp_path / "s" / "readings.csv").column("masstone_1")
    assert np.max(rel_err(material.ks_ratio, (1.0 - R) ** 2 / (2.0 * R))) < 1e-6
    for values in (material.K, material.S):
        assert np.all(np.isfinite(values)) and np.all(values >= 0.0)
    assert np.all(material.S <= S * (1 + 1e-9)) and np.all(material.K <= K * (1 + 1e-9))


# --- fitting grid -------------------------------------------------------------------------------------------


def test_grid_option_fits_on_that_grid(tmp_path, capsys, foundation):
    wavelengths, K, S = foundation
    manifest = simulate_sample(tmp_path / "s", wavelengths, K, S).manifest
    out = tmp_path / "m.json"
    status, err = run_fit(capsys, str(manifest), "-o", str(out), "--grid", "400:700:10")
    assert status == 0, err
    material = read_material(out)
    grid = uniform_grid(400, 700, 10)
    assert np.array_equal(material.wavelengths, grid)
    keep = np.isin(wavelengths, grid)
    assert np.max(rel_err(material.K, K[keep])) < 1e-9
    assert np.max(rel_err(material.S, S[keep])) < 1e-9


def test_default_grid_is_5_nm_for_finer_data_and_the_data_grid_otherwise(tmp_path, capsys, foundation):
    table_grid, K10, S10 = foundation
    fine = uniform_grid(382, 748, 1)  # 1 nm data whose ends are not multiples of 5 nm
    K, S = np.interp(fine, table_grid, K10), np.interp(fine, table_grid, S10)
    out = tmp_path / "fine.json"
    assert run_fit(capsys, str(simulate_sample(tmp_path / "fine", fine, K, S).manifest), "-o", str(out))[0] == 0
    material = read_material(out)
    assert np.array_equal(material.wavelengths, uniform_grid(385, 745, 5))
    keep = np.isin(fine, material.wavelengths)
    assert np.max(rel_err(material.K, K[keep])) < 1e-9
    out = tmp_path / "coarse.json"
    coarse = simulate_sample(tmp_path / "coarse", table_grid, K10, S10).manifest
    assert run_fit(capsys, str(coarse), "-o", str(out))[0] == 0
    assert np.array_equal(read_material(out).wavelengths, table_grid)


def test_grid_in_the_manifest_fits_on_that_grid(tmp_path, capsys, foundation):
    wavelengths, K, S = foundation
    manifest = simulate_sample(tmp_path / "s", wavelengths, K, S, fit_table='[fit]\ngrid = "450:650:20"\n').manifest
    out = tmp_path / "m.json"
    assert run_fit(capsys, str(manifest), "-o", str(out))[0] == 0
    assert np.array_equal(read_material(out).wavelengths, uniform_grid(450, 650, 20))


@pytest.mark.parametrize("grid", ["300:700:10", "400:800:10"])
def test_grid_beyond_the_data_is_refused(tmp_path, capsys, foundation, grid):
    wavelengths, K, S = foundation
    manifest = simulate_sample(tmp_path / "s", wavelengths, K, S).manifest
    out = tmp_path / "m.json"
    status, err = run_fit(capsys, str(manifest), "-o", str(out), "--grid", grid)
    assert status == 2
    message = " ".join(err.split())
    assert "cards.csv" in message or "readings.csv" in message
    assert "380" in message and "750" in message
    assert not out.exists()


# --- kmpipe ingest ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("with_dark", [False, True], ids=["no-dark", "dark"])
def test_ingest_gives_back_the_simulated_reflectance(tmp_path, capsys, foundation, with_dark):
    wavelengths, K, S = foundation
    backings = cards(wavelengths)
    reflectance = np.array(
        [
            reflectance_infinite(K, S),
            reflectance_over_background(K, S, 0.015, backings["black"]),
            reflectance_over_background(K, S, 0.015, backings["white"]),
            backings["white"],
        ]
    )
    columns = ("masstone", "film_over_black", "film_over_white", "white_card")
    lamp = 0.01 * (1.0 + 0.5 * np.sin(wavelengths / 50.0))  # radiance of a perfect white, W sr-1 m-2 nm-1
    dark = 2e-6 * (1.0 + 0.1 * np.cos(wavelengths / 30.0)) if with_dark else np.zeros(wavelengths.size)
    certified = baso4_typical(wavelengths)
    white = lamp * certified + dark
    radiance = lamp * reflectance + dark
    meta = {"quantity": "radiance", "units": "W sr-1 m-2 nm-1", "instrument": "simulated"}
    write_spectra_csv(SpectralTable(wavelengths, None, columns, radiance, meta), tmp_path / "radiance.csv")
    write_spectra_csv(
        SpectralTable(wavelengths, None, ("baso4", "dark"), np.array([white, dark]), meta), tmp_path / "white.csv"
    )
    args = [
        "ingest",
        str(tmp_path / "radiance.csv"),
        "--white",
        f"{tmp_path / 'white.csv'}:baso4",
        "--certified",
        "builtin:baso4",
        "-o",
        str(tmp_path / "reflectance.csv"),
    ]
    if with_dark:
        args += ["--dark", f"{tmp_path / 'white.csv'}:dark"]
    status = cli.main(args)
    err = capsys.readouterr().err
    assert status == 0, err
    table = read_spectra_csv(tmp_path / "reflectance.csv")
    assert table.quantity == "reflectance" and table.metadata["units"] == "1"
    assert table.metadata["instrument"] == "simulated"
    assert table.columns == columns
    assert np.array_equal(table.wavelengths, wavelengths)
    assert np.max(np.abs(table.values - reflectance)) < 1e-12


def test_ingest_refuses_reflectance(tmp_path, capsys, foundation):
    wavelengths, K, S = foundation
    write_spectra_csv(
        SpectralTable(wavelengths, None, ("masstone",), reflectance_infinite(K, S)[None, :], REFLECTANCE),
        tmp_path / "already.csv",
    )
    already = tmp_path / "already.csv"
    out = tmp_path / "out.csv"
    status = cli.main(["ingest", str(already), "--white", f"{already}:masstone", "-o", str(out)])
    err = capsys.readouterr().err
    assert status == 2
    assert "Traceback" not in err
    assert "already.csv" in err and "reflectance" in err
    assert not (tmp_path / "out.csv").exists()


# --- joint fit internals: analytic derivatives against mpmath -----------------------------------------------

DPS = 50


def textbook_film(K, S, X, G):
    """R of a KM film over G, textbook sinh/cosh form (thesis eq. 3.8, thesis eq. 3.9, thesis eq. 3.14); K = 0 by its
    limit."""
    K, S, X, G = (mpmath.mpf(v) for v in (K, S, X, G))
    if K == 0:
        R0, T = S * X / (1 + S * X), 1 / (1 + S * X)
    else:
        a = 1 + K / S
        b = mpmath.sqrt(K * (K + 2 * S)) / S
        x = b * S * X
        den = a * mpmath.sinh(x) + b * mpmath.cosh(x)
        R0, T = mpmath.sinh(x) / den, b / den
    return R0 + T * T * G / (1 - R0 * G)


def textbook_masstone(K, S):
    """R_inf = a - b, a = 1 + K/S, b = sqrt(a^2 - 1)."""
    a = 1 + mpmath.mpf(K) / mpmath.mpf(S)
    return a - mpmath.sqrt(a * a - 1)


def surface(R, saunderson):
    if saunderson is None:
        return R
    k1, k2 = (mpmath.mpf(v) for v in saunderson)
    return k1 + (1 - k1) * (1 - k2) * R / (1 - k2 * R)


def derivative(f, x):
    """df/dx by mpmath with a step far below x (so K stays positive), at a precision that resolves it."""
    x = mpmath.mpf(x)
    return mpmath.diff(f, x, h=x * mpmath.mpf("1e-20") if x else mpmath.mpf("1e-30"))


def precision_for(K, S) -> int:
    """Digits needed: R_inf = 1 - sqrt(2 K/S) + ... cancels ~log10(S/K) digits."""
    return DPS + max(0, int(-math.log10(K / S))) if K > 0 else DPS


@pytest.mark.parametrize("saunderson", [None, SAUNDERSON], ids=["plain", "saunderson"])
@pytest.mark.parametrize("K", [1e-300, 1e-30, 1e-12, 1e-9, 1e-6, 1e-3, 0.3, 10.0, 300.0, 1e5])
def test_joint_fit_derivatives_match_mpmath(K, saunderson):
    """Rows: a masstone and films of 5, 20 and 300 um over black and white, at S = 50 /mm."""
    S = 50.0
    thickness = np.array([np.inf, 0.005, 0.005, 0.02, 0.02, 0.3])
    G = np.array([0.0, 0.035, 0.85, 0.035, 0.85, 0.5])
    model, p, r = _Model.at(np.array([K]), np.array([S]), thickness, G[:, None], saunderson)
    R, dR_dp, dR_dr, dR_dK, dR_dS = (v[:, 0] for v in model.evaluate(p, r))
    K0, S0, p0, r0 = float(model.K0[0]), float(model.S0[0]), float(p[0]), float(r[0])
    assert K0 * p0 * p0 == pytest.approx(K, rel=1e-15) and S0 * r0 * r0 == pytest.approx(S, rel=1e-15)
    with mpmath.workdps(precision_for(K, S)):
        for i, (X, Gi) in enumerate(zip(thickness, G, strict=True)):
            if math.isinf(X):

                def reading(k, s):
                    return surface(textbook_masstone(k, s), saunderson)
            else:

                def reading(k, s, X=X, Gi=Gi):
                    return surface(textbook_film(k, s, X, Gi), saunderson)

            want = {
                "R": reading(K, S),
                "dR/dK": derivative(lambda k: reading(k, S), K),
                "dR/dS": derivative(lambda s: reading(K, s), S),
                "dR/dp": derivative(lambda q: reading(K0 * q * q, S), p0),
                "dR/dr": derivative(lambda q: reading(K, S0 * q * q), r0),
            }
            got = {"R": R[i], "dR/dK": dR_dK[i], "dR/dS": dR_dS[i], "dR/dp": dR_dp[i], "dR/dr": dR_dr[i]}
            # The masstone's dR/dS is ~sqrt(K/S)/S, below rounding of R itself when K/S < 1e-14: there
            # an absolute accuracy of a few ulps of R per unit S is all that is meaningful.
            for name, value in want.items():
                error = abs(mpmath.mpf(float(got[name])) - value)
                scale = abs(value)
                if math.isinf(X) and name in ("dR/dS", "dR/dr") and K / S < 1e-12:
                    assert error <= 1e-15 * (1 if name == "dR/dS" else 2 * S0 * r0) / S, (i, name)
                else:
                    assert error <= 1e-9 * scale, (i, name, float(got[name]), float(value))


def test_masstone_slope_at_k_zero_is_steep_not_flat():
    """R_inf = 1 - sqrt(2 K / S) + ... falls with infinite slope at K = 0.

    The joint-fit docstring promises a huge but finite dR/dK there (p floored at 1e-150).
    """
    model, p, r = _Model.at(
        np.array([0.0]), np.array([50.0]), np.array([np.inf, 0.02]), np.array([[0.0], [0.85]]), None
    )
    R, _, _, dR_dK, _ = model.evaluate(p, r)
    assert R[0, 0] == 1.0
    with mpmath.workdps(precision_for(1e-200, 50.0)):
        at_tiny_k = derivative(lambda k: textbook_masstone(k, 50), mpmath.mpf("1e-200"))
    assert at_tiny_k < -1e90  # the reference slope just above 0: -1 / sqrt(2 K S)
    assert dR_dK[0, 0] < -1e90


def test_second_difference_penalty_gradient():
    """Gradient of sum((d2 v / scale)^2) against mpmath differentiation of the same sum."""
    rng = np.random.default_rng(3)
    v = rng.uniform(1.0, 5.0, 9)
    scale = 2.5
    value, grad = _second_difference_penalty(v, scale)

    def penalty(values):
        second = [values[i + 2] - 2 * values[i + 1] + values[i] for i in range(len(values) - 2)]
        return sum((d / scale) ** 2 for d in second)

    with mpmath.workdps(30):
        exact = [mpmath.mpf(float(x)) for x in v]
        assert abs(value - penalty(exact)) <= 1e-12 * abs(penalty(exact))
        for j in range(v.size):

            def along(t, j=j):
                moved = list(exact)
                moved[j] = t
                return penalty(moved)

            assert abs(grad[j] - mpmath.diff(along, exact[j])) <= 1e-10 * (1 + abs(value))


# --- readings the model cannot explain ----------------------------------------------------------------------


@pytest.mark.parametrize("saunderson", [None, SAUNDERSON], ids=["plain", "saunderson"])
@pytest.mark.parametrize("method", ["two-constant", "black-white", "lsq"])
@pytest.mark.parametrize("where", ["film over black", "white card and every reading"])
def test_readings_of_1_5_give_finite_flagged_k_and_s(tmp_path, capsys, foundation, method, saunderson, where):
    """1.5, the spectral CSV's largest reflectance, cannot come from a KM film (at most 1, with or without surface
    reflection); over a backing above 1 the model diverged (inf, then NaN in MATERIAL.json: exit 70). Now such
    readings are fitted as 1 and their wavelengths flagged out_of_range; the residuals keep the readings."""
    wavelengths, K, S = foundation
    manifest = simulate_sample(tmp_path / "s", wavelengths, K, S, saunderson=saunderson).manifest
    spike = 10
    for name in ("readings.csv", "cards.csv"):
        table = read_spectra_csv(manifest.parent / name)
        values = np.array(table.values)
        if name == "cards.csv" and where.startswith("white card"):
            values[1, spike] = 1.5
        if name == "readings.csv":
            rows = [1] if where == "film over black" else slice(None)
            values[rows, spike] = 1.5
        write_spectra_csv(dataclasses.replace(table, values=values), manifest.parent / name)
    out = tmp_path / "m.json"
    extra = ["--saunderson", f"{saunderson[0]},{saunderson[1]}"] if saunderson else []
    status, err = run_fit(capsys, str(manifest), "-o", str(out), "--method", method, *extra)
    assert status == 0, err
    doc = strict_json(out)
    assert float(wavelengths[spike]) in doc["flags"]["out_of_range"]
    material = read_material(out)
    assert np.all(np.isfinite(material.K)) and np.all(np.isfinite(material.S))
    film = material.measurements[1]
    assert film.residuals[spike] < -0.4  # predicted (at most 1) minus the 1.5 read
