"""Validation of fitted materials (kmpipe.validation, ``kmpipe validate``) against independently known answers.

Every check is triggered by a sample simulated into a temporary folder with exactly the fault it must catch
(the thesis's sample F2, noise that drives K below 0, an opaque film, a masstone drawn too thin, surface
reflection left out of the model, ...), fitted through the command line and validated. What each check
must report is worked out here from the readings as written, with formulas written out in this file (the
textbook hyperbolic Kubelka-Munk form, the black/white linear system of ``shared/method/notes.md``, the
Wald-Wolfowitz runs test, colour-science called directly), not by asking kmpipe again. A clean round trip
(low noise, repeats, so the noise floor is known) must pass with no finding at all.

Sources: RIT Artist Paint Spectral Database K and S (via waacton/Unicolour, MIT) for plausible pigments;
the Kimera yellow masstones (miciwan/PaintMixing ``data/masstone.json``, MIT) as a real "not quite
opaque" masstone; both read from ``shared/data`` (see its README).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import colour
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from simulation import FOUNDATION, Simulated, cards, rit_mixture, shared_data, simulate_sample, write_sample

from kmpipe import cli
from kmpipe.errors import InputError
from kmpipe.formats.thresholds import Thresholds
from kmpipe.physics.kubelka_munk import reflectance_over_background
from kmpipe.validation.checks import CHECKS
from kmpipe.validation.findings import report_to_dict
from kmpipe.validation.material import validate_material
from kmpipe.validation.noise import MIN_NOISE

ROOT = Path(__file__).resolve().parents[1]
# Kimera acrylic masstones, percent reflectance, 3 repeats each: miciwan/PaintMixing data/masstone.json (MIT).
SAUNDERSON = (0.04, 0.6)
COLOUR_NAMES = {"D65": "D65", "A": "A", "F11": "FL11"}
OBSERVER_NAMES = {"2": "CIE 1931 2 Degree Standard Observer", "10": "CIE 1964 10 Degree Standard Observer"}

# colour-science announces that it aligns the CMFs and illuminants to a 10 nm grid: intended, here and in kmpipe.
pytestmark = pytest.mark.filterwarnings("ignore:Aligning:colour.utilities.ColourRuntimeWarning")


# --- independent references ---------------------------------------------------------------------------------


def textbook_film(K, S, X, G):
    """KM reflectance of a film over G (thesis eq. 3.8, thesis eq. 3.9 and thesis eq. 3.14); K, S > 0.

    R0 = sinh(x) / (a sinh(x) + b cosh(x)), T = b / (a sinh(x) + b cosh(x)), x = b S X, written with
    e = exp(-x) so that thick films do not overflow: R0 = (1 - e^2) / (a + b - (a - b) e^2),
    T = 2 b e / (a + b - (a - b) e^2); then R = R0 + T^2 G / (1 - R0 G).
    """
    K, S, G = (np.asarray(v, dtype=np.float64) for v in (K, S, G))
    a = 1.0 + K / S
    b = np.sqrt(a * a - 1.0)
    e = np.exp(-b * S * X)
    den = a + b - (a - b) * e * e
    R0, T = (1.0 - e * e) / den, 2.0 * b * e / den
    return R0 + T * T * G / (1.0 - R0 * G)


def textbook_masstone(K, S):
    """R_inf = a - sqrt(a^2 - 1), a = 1 + K/S."""
    a = 1.0 + np.asarray(K, dtype=np.float64) / np.asarray(S, dtype=np.float64)
    return a - np.sqrt(a * a - 1.0)


def surface(R, saunderson):
    """Saunderson: measured = k1 + (1 - k1)(1 - k2) R / (1 - k2 R) (notes, KM section)."""
    if saunderson is None:
        return np.asarray(R, dtype=np.float64)
    k1, k2 = saunderson
    return k1 + (1.0 - k1) * (1.0 - k2) * R / (1.0 - k2 * R)


def body(Rm, saunderson):
    """The inverse of :func:`surface`: R = (Rm - k1) / (1 - k1 - k2 + k2 Rm)."""
    if saunderson is None:
        return np.asarray(Rm, dtype=np.float64)
    k1, k2 = saunderson
    return (Rm - k1) / (1.0 - k1 - k2 + k2 * Rm)


def runs_z(residuals: np.ndarray) -> float:
    """Wald-Wolfowitz runs test on the signs (zeros dropped): z of the number of runs; -inf for one sign."""
    signs = residuals[residuals != 0.0] > 0.0
    n, n1 = signs.size, int(np.sum(signs))
    n2 = n - n1
    if n1 == 0 or n2 == 0:
        return -math.inf
    runs = 1 + sum(1 for i in range(1, n) if signs[i] != signs[i - 1])
    mean = 2.0 * n1 * n2 / n + 1.0
    var = 2.0 * n1 * n2 * (2.0 * n1 * n2 - n) / (n**2 * (n - 1))
    return (runs - mean) / math.sqrt(var)


def lab(R, wavelengths, illuminant: str, observer: str):
    """CIELAB of one reflectance spectrum by colour-science, relative to the perfect white on the same grid."""
    cmfs = colour.MSDS_CMFS[OBSERVER_NAMES[observer]]
    sd_illuminant = colour.SDS_ILLUMINANTS[COLOUR_NAMES[illuminant]]

    def XYZ(values):
        sd = colour.SpectralDistribution(dict(zip(wavelengths, values, strict=True)))
        return colour.sd_to_XYZ(sd, cmfs=cmfs, illuminant=sd_illuminant, method="Integration")

    white = XYZ(np.ones(len(wavelengths)))
    return colour.XYZ_to_Lab(XYZ(R) / 100.0, colour.XYZ_to_xy(white / 100.0))


def delta_e_2000(R1, R2, wavelengths, illuminant: str, observer: str) -> float:
    return float(
        colour.delta_E(
            lab(R1, wavelengths, illuminant, observer), lab(R2, wavelengths, illuminant, observer), method="CIE 2000"
        )
    )


# --- simulated samples --------------------------------------------------------------------------------------


def fit(manifest: Path, out: Path, *options: str) -> Path:
    status = cli.main(["fit", str(manifest), "-o", str(out), *options])
    assert status == 0
    return out


def read_json(path: Path):
    def refuse(name):
        raise AssertionError(f"{path} holds {name}, which is not JSON")

    return json.loads(Path(path).read_text(encoding="utf-8"), parse_constant=refuse)


def window_of(i: int, n: int, width: int = 11) -> range:
    """The `width` points centred on point i of n, moved inwards at the ends."""
    width = min(width, n)
    start = min(max(i - width // 2, 0), n - width)
    return range(start, start + width)


def reference_noise(sim: Simulated) -> dict[str, np.ndarray]:
    """Noise of each reading at each wavelength as the validator defines it, written out plainly: for a
    reading with repeats, sqrt of the mean of the repeats' variance over an 11-point window; otherwise the
    median of |second difference| over an 11-point window / 0.6745 / sqrt(6); at least MIN_NOISE."""
    n = sim.wavelengths.size
    out = {}
    for e in sim.entries:
        members = [
            m["column"]
            for m in sim.entries
            if (m["role"], m["over"], m["thickness_mm"]) == (e["role"], e["over"], e["thickness_mm"])
        ]
        if len(members) > 1:
            var = np.var([sim.columns[c] for c in members], axis=0, ddof=1)
            sigma = np.array([math.sqrt(np.mean(var[list(window_of(i, n))])) for i in range(n)])
        else:
            y = sim.columns[e["column"]]
            d2 = np.abs(y[2:] - 2.0 * y[1:-1] + y[:-2])
            sigma = np.array([np.median(d2[list(window_of(i - 1, n - 2))]) for i in range(n)]) / 0.6745 / math.sqrt(6)
        out[e["column"]] = np.maximum(sigma, MIN_NOISE)
    return out


def predictions(sim: Simulated, material: dict) -> dict[str, np.ndarray]:
    """Each entry's reading as the material predicts it, by the textbook formulas (K, S > 0 needed)."""
    K, S = np.array(material["K"]), np.array(material["S"])
    saunderson = (
        None if material["saunderson"] is None else (material["saunderson"]["k1"], material["saunderson"]["k2"])
    )
    out = {}
    for e in sim.entries:
        if e["role"] == "masstone":
            R = textbook_masstone(K, S)
        else:
            R = textbook_film(K, S, e["thickness_mm"], body(sim.cards[e["over"]], saunderson))
        out[e["column"]] = surface(R, saunderson)
    return out


def codes(report) -> list[str]:
    return [f.code for f in report.findings]


def only(report, code: str):
    found = [f for f in report.findings if f.code == code]
    assert found, f"{code} did not fire; findings: {codes(report)}"
    return found


def between(where, low, high) -> bool:
    return all(low <= w <= high for w in where)


@dataclass
class Case:
    sim: Simulated
    material_path: Path
    report: object

    @property
    def material(self) -> dict:
        return read_json(self.material_path)


def make_case(tmp_path_factory, label: str, build, *fit_options: str, **validate_options) -> Case:
    folder = tmp_path_factory.mktemp(label)
    sim = build(folder / "sample")
    out = fit(sim.manifest, folder / f"{label}.json", *fit_options)
    return Case(sim, out, validate_material(out, **validate_options))


# --- fixtures: one sample per fault -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def foundation():
    return rit_mixture(FOUNDATION)


@pytest.fixture(scope="module")
def clean(tmp_path_factory, foundation):
    """Low noise (0.001), three repeats of every film and of the masstone: nothing may fire."""
    wl, K, S = foundation
    return make_case(
        tmp_path_factory,
        "clean",
        lambda f: simulate_sample(f, wl, K, S, repeats=3, masstones=3, noise=0.001, rng=11, name="clean"),
        illuminants=("D65", "A", "F11"),
    )


F2_LOW, F2_HIGH = 380.0, 500.0


@pytest.fixture(scope="module")
def f2(tmp_path_factory, foundation):
    """Thesis sample F2: between 380 and 500 nm the thicker film over black reads darker than the thinner one.

    Films of 20 and 25 um; every repeat of the 25 um film over black is scaled by 0.95 there (5 %).
    """
    wl, K, S = foundation

    def uneven(columns, wavelengths):
        band = (wavelengths >= F2_LOW) & (wavelengths <= F2_HIGH)
        for name in columns:
            if name.startswith("film_25um_black"):
                columns[name] = np.where(band, 0.95 * columns[name], columns[name])

    return make_case(
        tmp_path_factory,
        "f2",
        lambda f: simulate_sample(
            f,
            wl,
            K,
            S,
            thicknesses_um=(20, 25),
            repeats=3,
            masstones=3,
            noise=0.001,
            rng=2,
            edit=uneven,
            name="F2like",
        ),
    )


@pytest.fixture(scope="module")
def white(tmp_path_factory):
    """A nearly non-absorbing white (RIT titanium white), one 30 um film over each card, noise 0.003."""
    wl, K, S = rit_mixture({"TitaniumWhite": 1.0})
    return make_case(
        tmp_path_factory,
        "white",
        lambda f: simulate_sample(f, wl, K, S, thicknesses_um=(30,), masstones=0, noise=0.003, rng=5, name="white"),
        "--method",
        "black-white",
    )


@pytest.fixture(scope="module")
def opaque(tmp_path_factory, foundation):
    """Films of 2 and 5 mm hide both cards."""
    wl, K, S = foundation
    return make_case(
        tmp_path_factory, "opaque", lambda f: simulate_sample(f, wl, K, S, thicknesses_um=(2000, 5000), name="opaque")
    )


@pytest.fixture(scope="module")
def saunderson(tmp_path_factory, foundation):
    """Readings with surface reflection (k1 0.04, k2 0.6), fitted without --saunderson."""
    wl, K, S = foundation
    return make_case(
        tmp_path_factory,
        "saunderson",
        lambda f: simulate_sample(f, wl, K, S, saunderson=SAUNDERSON, name="surface"),
        illuminants=("D65", "A", "F11"),
    )


@pytest.fixture(scope="module")
def biased(tmp_path_factory, foundation):
    """Three close repeats of every film (noise 0.0005); all three 15 um films over black read 0.02 high."""
    wl, K, S = foundation

    def bias(columns, wavelengths):
        for name in columns:
            if name.startswith("film_15um_black"):
                columns[name] = columns[name] + 0.02

    return make_case(
        tmp_path_factory,
        "biased",
        lambda f: simulate_sample(f, wl, K, S, repeats=3, noise=0.0005, rng=8, edit=bias, name="biased"),
    )


BRIGHT_AT = 550.0


@pytest.fixture(scope="module")
def bright(tmp_path_factory, foundation):
    """One film reading reads 1.2 at 550 nm (a wrong white reference), still below the loader's 1.5."""
    wl, K, S = foundation

    def spike(columns, wavelengths):
        columns["film_15um_white_1"] = np.where(wavelengths == BRIGHT_AT, 1.2, columns["film_15um_white_1"])

    return make_case(tmp_path_factory, "bright", lambda f: simulate_sample(f, wl, K, S, edit=spike, name="bright"))


@pytest.fixture(scope="module")
def black(tmp_path_factory):
    """A near-black: RIT bone black with 20 times its absorption (K/S about 170-260), films of 3 and 6 um."""
    wl, K, S = rit_mixture({"BoneBlack": 1.0})
    return make_case(
        tmp_path_factory, "black", lambda f: simulate_sample(f, wl, 20.0 * K, S, thicknesses_um=(3, 6), name="black")
    )


@pytest.fixture(scope="module")
def thick(tmp_path_factory, foundation):
    """Nearly opaque films (60 and 90 um) with noise 0.003: K and S barely determined at some wavelengths."""
    wl, K, S = foundation
    return make_case(
        tmp_path_factory,
        "thick",
        lambda f: simulate_sample(f, wl, K, S, thicknesses_um=(60, 90), noise=0.003, rng=1, name="thick"),
    )


KIMERA_GRID = np.arange(420.0, 681.0, 10.0)  # the README: below ~410 nm and above ~680 nm less reliable


def kimera_sample(folder: Path, paint: str, masstone_thickness: str) -> Simulated:
    """The three measured Kimera masstones of ``paint`` (percent -> fraction, linear interpolation from the
    instrument's uneven grid onto 420-680 nm every 10 nm) and films of 20 and 40 um over black and white
    simulated from K, S consistent with them: K/S = (1 - R)^2 / (2 R) of the repeats' mean, S of RIT Hansa
    Yellow Opaque (x60 per mm), K = K/S x S."""
    # Source: miciwan/PaintMixing data/masstone.json (MIT), via shared/data/paints/kimera_masstone.json.
    entries_in = json.loads((shared_data() / "paints" / "kimera_masstone.json").read_text(encoding="utf-8"))
    source_grid = np.array(entries_in[0]["values"], dtype=np.float64)
    repeats = [
        np.interp(KIMERA_GRID, source_grid, np.array(e["reflectance"]) / 100.0)
        for e in entries_in[1:]
        if e.get("name") == paint
    ]
    assert len(repeats) == 3
    R = np.mean(repeats, axis=0)
    rit_grid, _, S_rit = rit_mixture({"HansaYellowOpaque": 1.0})
    S = np.interp(KIMERA_GRID, rit_grid, S_rit)
    K = (1.0 - R) ** 2 / (2.0 * R) * S
    card_values = cards(KIMERA_GRID)
    columns, entries = {}, []
    for i, values in enumerate(repeats):
        columns[f"masstone_{i + 1}"] = values
        entries.append({"role": "masstone", "column": f"masstone_{i + 1}", "over": None, "thickness_mm": math.inf})
    for um in (20, 40):
        for over in ("black", "white"):
            columns[f"film_{um}um_{over}"] = reflectance_over_background(K, S, um / 1000.0, card_values[over])
            entries.append({"role": "film", "column": f"film_{um}um_{over}", "over": over, "thickness_mm": um / 1000})
    return write_sample(
        folder,
        KIMERA_GRID,
        card_values,
        columns,
        entries,
        name=paint.replace(" ", "-"),
        masstone_thickness=masstone_thickness,
    )


@pytest.fixture(scope="module", params=["cold yellow", "warm yellow"])
def kimera(request, tmp_path_factory):
    """The same yellow, its masstone declared 40 um (not opaque at long wavelengths) and 5 mm (opaque)."""
    paint = request.param
    label = paint.replace(" ", "_")
    thin = make_case(tmp_path_factory, f"{label}_40um", lambda f: kimera_sample(f, paint, "40 um"))
    thick = make_case(tmp_path_factory, f"{label}_5mm", lambda f: kimera_sample(f, paint, "5 mm"))
    return paint, thin, thick


# --- the clean round trip -----------------------------------------------------------------------------------


def test_clean_round_trip_passes_with_no_finding(clean):
    report, sim = clean.report, clean.sim
    assert report.verdict == "pass"
    assert report.findings == ()
    assert report.reasons == []
    assert report.changed_inputs == ()
    # The noise level is the local spread of the repeats, close to the 0.001 that was added.
    assert report.noise_source == "spread of repeats"
    noise = reference_noise(sim)
    assert report.noise_sigma == pytest.approx(float(np.median(np.array(list(noise.values())))), rel=1e-12)
    assert report.noise_sigma == pytest.approx(0.001, rel=0.15)
    predicted = predictions(sim, clean.material)
    assert [c.id for c in report.measurements] == [f"readings.csv:{e['column']}" for e in sim.entries]
    for check, entry in zip(report.measurements, sim.entries, strict=True):
        column = entry["column"]
        assert np.array_equal(check.measured, sim.columns[column])
        assert np.max(np.abs(check.predicted - predicted[column])) < 1e-12
        assert check.rmse == pytest.approx(np.sqrt(np.mean((predicted[column] - sim.columns[column]) ** 2)), rel=1e-9)
        assert check.repeat_count == 3
        members = [
            sim.columns[c]
            for c in sim.group(
                entry["role"], entry["over"], None if entry["role"] == "masstone" else entry["thickness_mm"] * 1000
            )
        ]
        spread = np.sqrt(np.mean(np.std(members, axis=0, ddof=1) ** 2))
        assert check.repeat_spread == pytest.approx(spread, rel=1e-12)
        assert set(check.delta_e) == {"D65", "A", "F11"}
        assert max(check.delta_e.values()) < 1.0


# --- one fixture per check ----------------------------------------------------------------------------------


def test_thickness_series_not_monotone_like_thesis_sample_f2_fails(f2):
    report, sim = f2.report, f2.sim
    found = only(report, "thickness_not_monotone")
    assert len(found) == 1
    finding = found[0]
    assert finding.severity == "fail" and report.verdict == "fail"
    assert "over black" in finding.message and "darker" in finding.message
    assert finding.where and between(finding.where, F2_LOW, F2_HIGH)
    # Expected: where the mean of the 25 um repeats over black lies below the 20 um mean by more than
    # 3 sigma of the difference of two means of 3 (sigma the local repeat spread of each).
    noise = reference_noise(sim)
    thin_members, thick_members = sim.group("film", "black", 20), sim.group("film", "black", 25)
    thin = np.mean([sim.columns[c] for c in thin_members], axis=0)
    thicker = np.mean([sim.columns[c] for c in thick_members], axis=0)
    spread = np.sqrt(sum(np.mean([noise[c] ** 2 for c in g], axis=0) / len(g) for g in (thin_members, thick_members)))
    wrong = thicker - thin < -3.0 * spread
    assert finding.where == list(sim.wavelengths[wrong])
    assert len(finding.where) >= 10  # most of 380-500 nm (13 wavelengths)
    assert f"{finding.where[0]:g}" in finding.message and f"{finding.where[-1]:g} nm" in finding.message


def black_white_ks(R_black, R_white, G_black, G_white) -> np.ndarray:
    """K/S = a - 1 from the linear system (R_i + G_i) a + (R_i - G_i) y = 1 + R_i G_i of two backings."""
    out = []
    for j in range(R_black.size):
        A = np.array(
            [[R_black[j] + G_black[j], R_black[j] - G_black[j]], [R_white[j] + G_white[j], R_white[j] - G_white[j]]]
        )
        rhs = np.array([1.0 + R_black[j] * G_black[j], 1.0 + R_white[j] * G_white[j]])
        out.append(np.linalg.solve(A, rhs)[0] - 1.0)
    return np.array(out)


def test_noise_that_drives_k_negative_is_reported_where_it_happens(white):
    report, sim = white.report, white.sim
    ks = black_white_ks(
        sim.columns["film_30um_black_1"], sim.columns["film_30um_white_1"], sim.cards["black"], sim.cards["white"]
    )
    negative = ks < 0.0
    assert 5 <= negative.sum() < ks.size
    (not_positive,) = only(report, "k_or_s_not_positive")
    assert not_positive.severity == "warn"
    assert not_positive.where == list(sim.wavelengths[negative])
    assert np.all(np.array(white.material["K"])[negative] == 0.0)
    # Below -opaque_tolerance (1e-3) the readings are out of range, not just rounded to K = 0.
    (beyond,) = only(report, "out_of_range")
    assert beyond.severity == "warn"
    assert beyond.where == list(sim.wavelengths[ks < -1e-3])
    assert beyond.where and set(beyond.where) < set(not_positive.where)
    assert report.verdict == "warn"


def test_opaque_films_are_reported_opaque(opaque):
    report, sim = opaque.report, opaque.sim
    (finding,) = only(report, "opaque")
    assert finding.severity == "warn"
    hides = np.ones(sim.wavelengths.size, dtype=bool)
    for um in (2000, 5000):
        Rb, Rw = sim.columns[f"film_{um}um_black_1"], sim.columns[f"film_{um}um_white_1"]
        hides &= np.abs(1.0 - Rb / Rw) <= 1e-3
    assert hides.all()
    assert finding.where == list(sim.wavelengths)
    assert opaque.material["flags"]["opaque"] == finding.where
    assert "poor_conditioning" not in codes(report)  # K and S are lower bounds there, not badly determined
    assert report.verdict == "warn"


def test_masstone_too_thin_to_hide_its_backing_fails(kimera):
    paint, thin, thick = kimera
    assert thin.report.material.name == paint.replace(" ", "-")
    report, sim, material = thin.report, thin.sim, thin.material
    found = only(report, "masstone_not_opaque")
    # one finding for the three repeats of the one masstone, naming all of them
    assert [f.measurement for f in found] == [", ".join(f"readings.csv:masstone_{i}" for i in (1, 2, 3))]
    assert all(f.severity == "fail" for f in found) and report.verdict == "fail"
    # Expected: R_inf of the fitted K, S against a 40 um layer of it over the black card, beyond 3 sigma
    # of the masstones' local repeat spread (the only repeats of this sample).
    K, S = np.array(material["K"]), np.array(material["S"])
    gap = np.abs(textbook_masstone(K, S) - textbook_film(K, S, 0.040, sim.cards["black"]))
    noise = reference_noise(sim)
    masstone_sigma = np.sqrt(np.mean([noise[c] ** 2 for c in sim.group("masstone")], axis=0))
    see_through = gap > 3.0 * masstone_sigma
    for finding in found:
        assert finding.where == list(sim.wavelengths[see_through])
        # The yellow absorbs strongly below ~500 nm (hidden there) and little at long wavelengths.
        assert between(finding.where, 500.0, 680.0)
        assert {600.0, 640.0, 680.0} <= set(finding.where)
    # Declared 5 mm, the same readings pass the check.
    assert "masstone_not_opaque" not in codes(thick.report)
    assert thick.report.verdict != "fail"


def test_surface_reflection_left_out_of_the_model_gives_structured_residuals(saunderson, tmp_path):
    report, sim = saunderson.report, saunderson.sim
    predicted = predictions(sim, saunderson.material)
    residuals = {f"readings.csv:{c}": predicted[c] - sim.columns[c] for c in sim.columns}
    noise = {f"readings.csv:{c}": sigma for c, sigma in reference_noise(sim).items()}

    def biased(name):  # the longest one-signed run's mean beyond 2 standard errors of a mean of noise
        r = residuals[name]
        runs = np.split(np.arange(r.size), np.flatnonzero(np.diff(np.sign(r))) + 1)
        run = max(runs, key=len)
        return abs(np.mean(r[run])) > 2.0 * math.sqrt(np.mean(noise[name][run] ** 2) / run.size)

    expected = {name for name, r in residuals.items() if runs_z(r) < -3.5 and biased(name)}
    found = only(report, "structured_residuals")
    assert {f.measurement for f in found} == expected
    assert len(expected) >= len(sim.columns) - 2  # nearly every reading shows the missing surface reflection
    for finding in found:
        r = residuals[finding.measurement]
        index = np.flatnonzero(np.isin(sim.wavelengths, finding.where))
        assert np.array_equal(index, np.arange(index[0], index[-1] + 1))  # one stretch
        assert len(set(np.sign(r[index]))) == 1
        runs = np.split(np.sign(r), np.flatnonzero(np.diff(np.sign(r))) + 1)
        assert index.size == max(len(run) for run in runs)  # the longest stretch of one sign
        assert finding.severity == "warn"
    # Modelled with the constants that made the readings, nothing is left.
    out = fit(sim.manifest, tmp_path / "with.json", "--saunderson", f"{SAUNDERSON[0]},{SAUNDERSON[1]}")
    again = validate_material(out)
    assert again.findings == () and again.verdict == "pass"


def test_repeats_that_agree_but_are_not_fitted_are_above_noise(biased):
    report, sim = biased.report, biased.sim
    predicted = predictions(sim, biased.material)
    expected = set()
    for e in sim.entries:
        members = sim.group(e["role"], e["over"], None if e["role"] == "masstone" else e["thickness_mm"] * 1000)
        if len(members) < 2:
            continue
        spread = np.sqrt(np.mean(np.std([sim.columns[c] for c in members], axis=0, ddof=1) ** 2))
        rmse = np.sqrt(np.mean((predicted[e["column"]] - sim.columns[e["column"]]) ** 2))
        if rmse > 3.0 * spread:
            expected.add(f"readings.csv:{e['column']}")
    found = only(report, "residual_above_noise")
    assert {f.measurement for f in found} == expected
    assert {f"readings.csv:film_15um_black_{i}" for i in (1, 2, 3)} <= expected
    assert all(f.severity == "warn" for f in found)


def test_reflectance_above_one_fails(bright):
    report = bright.report
    (finding,) = only(report, "reflectance_out_of_range")
    assert finding.severity == "fail" and report.verdict == "fail"
    assert finding.where == [BRIGHT_AT]
    assert finding.measurement == "readings.csv:film_15um_white_1"
    assert "1.2" in finding.message


def test_near_black_has_extreme_k_over_s(black):
    report, material = black.report, black.material
    ks = np.array(material["K"]) / np.array(material["S"])
    (finding,) = only(report, "extreme_ks")
    assert finding.severity == "warn"
    assert finding.where == list(black.sim.wavelengths[ks > 200.0])
    assert 0 < len(finding.where) < ks.size


def standard_errors(sim: Simulated, material: dict, sigma: float, where: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """sigma sqrt of the diagonal of (J^T J)^-1 at the wavelengths ``where``, J = d(reading)/d(K, S) by
    central differences of the textbook formulas (elsewhere nan)."""
    K, S = np.array(material["K"]), np.array(material["S"])

    def reading(e, K, S):
        if e["role"] == "masstone":
            return textbook_masstone(K, S)
        return textbook_film(K, S, e["thickness_mm"], sim.cards[e["over"]])

    hK, hS = 1e-6 * K, 1e-6 * S
    dK = np.array([(reading(e, K + hK, S) - reading(e, K - hK, S)) / (2 * hK) for e in sim.entries])
    dS = np.array([(reading(e, K, S + hS) - reading(e, K, S - hS)) / (2 * hS) for e in sim.entries])
    K_se, S_se = np.full(K.size, np.nan), np.full(K.size, np.nan)
    for j in np.flatnonzero(where):
        J = np.column_stack([dK[:, j], dS[:, j]])
        cov = sigma**2 * np.linalg.inv(J.T @ J)
        K_se[j], S_se[j] = math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])
    return K_se, S_se


def test_barely_determined_k_and_s_are_poorly_conditioned(thick):
    report, sim, material = thick.report, thick.sim, thick.material
    predicted = predictions(sim, material)
    residuals = np.array([predicted[c] - sim.columns[c] for c in sim.columns])
    m, n = residuals.shape
    sigma = math.sqrt(np.sum(residuals**2) / (m * n - 2 * n))  # the pooled estimate the fit documents
    K, S = np.array(material["K"]), np.array(material["S"])
    opaque = np.isin(sim.wavelengths, material["flags"].get("opaque", []))
    K_se, S_se = standard_errors(sim, material, sigma, ~opaque)
    # The material's standard errors are these (away from opaque wavelengths, where they are unbounded; near-
    # singular J^T J at some wavelengths amplifies the finite-difference error, hence 1e-2).
    assert np.allclose(np.array(material["K_stderr"], dtype=float)[~opaque], K_se[~opaque], rtol=1e-2)
    assert np.allclose(np.array(material["S_stderr"], dtype=float)[~opaque], S_se[~opaque], rtol=1e-2)
    poor = (np.maximum(K_se / K, S_se / S) > 0.25) & ~opaque
    (finding,) = only(report, "poor_conditioning")
    assert finding.severity == "warn"
    assert finding.where == list(sim.wavelengths[poor])
    assert len(finding.where) >= 3
    assert f"{finding.where[0]:g}" in finding.message and f"{finding.where[-1]:g}" in finding.message


def rewrite_value(path: Path, column: str, row: int, delta: float) -> None:
    """Change one number in a spectral CSV by hand, as a technician editing it would."""
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    header = next(i for i, line in enumerate(lines) if line.startswith("wavelength_nm"))
    names = lines[header].rstrip("\n").split(",")
    cells = lines[header + 1 + row].rstrip("\n").split(",")
    k = names.index(column)
    cells[k] = repr(float(cells[k]) + delta)
    lines[header + 1 + row] = ",".join(cells) + "\n"
    path.write_text("".join(lines), encoding="utf-8")


def test_measurement_file_changed_after_the_fit_warns(tmp_path, foundation):
    wl, K, S = foundation
    sim = simulate_sample(tmp_path / "sample", wl, K, S, repeats=2, masstones=2, noise=0.001, rng=4, name="edited")
    out = fit(sim.manifest, tmp_path / "edited.json")
    before = validate_material(out)
    assert "inputs_changed" not in codes(before)
    rewrite_value(sim.folder / "readings.csv", "film_15um_black_1", row=10, delta=0.0004)
    after = validate_material(out)
    (finding,) = only(after, "inputs_changed")
    assert finding.severity == "warn"
    assert "readings.csv" in finding.message
    assert "cards.csv" not in finding.message and "manifest.toml" not in finding.message
    assert [Path(p).name for p in after.changed_inputs] == ["readings.csv"]
    assert after.verdict in ("warn", "fail")
    # A measurement file that is gone is bad input naming it, not a crash.
    (sim.folder / "cards.csv").unlink()
    with pytest.raises(InputError, match=r"cards\.csv"):
        validate_material(out)


# --- thresholds ---------------------------------------------------------------------------------------------


def expected_threshold_findings(case: Case, warn: float, fail: float, kind: str) -> list[tuple[str, str]]:
    """(measurement, severity) of every Delta E (per illuminant) or RMSE over a threshold, from references."""
    sim, report = case.sim, case.report
    predicted = predictions(sim, case.material)
    out = []
    for e in sim.entries:
        column = e["column"]
        if kind == "delta_e":
            values = [
                delta_e_2000(sim.columns[column], predicted[column], sim.wavelengths, name, report.observer)
                for name in report.illuminants
            ]
        else:
            values = [float(np.sqrt(np.mean((predicted[column] - sim.columns[column]) ** 2)))]
        for v in values:
            if v > fail:
                out.append((f"readings.csv:{column}", "fail"))
            elif v > warn:
                out.append((f"readings.csv:{column}", "warn"))
    return sorted(out)


def fired(report, code: str) -> list[tuple[str, str]]:
    return sorted((f.measurement, f.severity) for f in report.findings if f.code == code)


@pytest.fixture(scope="module")
def worst(clean):
    """The clean sample's worst Delta E 2000 (D65, A, F11) and worst RMSE, computed here."""
    sim, predicted = clean.sim, predictions(clean.sim, clean.material)
    de = max(
        delta_e_2000(sim.columns[c], predicted[c], sim.wavelengths, name, "2")
        for c in sim.columns
        for name in ("D65", "A", "F11")
    )
    rmse = max(float(np.sqrt(np.mean((predicted[c] - sim.columns[c]) ** 2))) for c in sim.columns)
    return de, rmse


@pytest.mark.parametrize("kind", ["delta_e", "rmse"])
@pytest.mark.parametrize("source", ["updated", "toml"])
def test_thresholds_make_a_clean_sample_warn_and_fail(clean, worst, tmp_path, kind, source):
    value = worst[0] if kind == "delta_e" else worst[1]
    for warn, fail, verdict in ((0.5 * value, 2.0 * value, "warn"), (0.25 * value, 0.5 * value, "fail")):
        if source == "updated":
            thresholds = Thresholds().updated(**{f"{kind}_warn": warn, f"{kind}_fail": fail})
        else:
            config = tmp_path / f"{verdict}.toml"
            config.write_text(
                f"# validation limits\n[thresholds]\n{kind}_warn = {warn!r}\n{kind}_fail = {fail!r}\n", encoding="utf-8"
            )
            thresholds = Thresholds.from_toml(config)
        assert getattr(thresholds, f"{kind}_warn") == warn and getattr(thresholds, f"{kind}_fail") == fail
        report = validate_material(clean.material_path, illuminants=("D65", "A", "F11"), thresholds=thresholds)
        expected = expected_threshold_findings(clean, warn, fail, kind)
        assert fired(report, kind) == expected
        assert report.verdict == verdict
        assert set(codes(report)) == {kind}


def test_thresholds_defaults_and_a_full_config(tmp_path):
    defaults = Thresholds()
    assert (defaults.delta_e_warn, defaults.delta_e_fail, defaults.rmse_warn, defaults.rmse_fail) == (1, 2, 0.01, 0.02)
    config = tmp_path / "limits.toml"
    config.write_text(
        "[thresholds]\ndelta_e_warn = 0.5\ndelta_e_fail = 1\nrmse_warn = 0.005\nrmse_fail = 0.01\n"
        "relative_stderr = 0.1\nks_min = 1e-3\nks_max = 100\nnoise_factor = 4\nruns_z = 3\n",
        encoding="utf-8",
    )
    got = Thresholds.from_toml(config)
    assert got == Thresholds(0.5, 1.0, 0.005, 0.01, 0.1, 1e-3, 100.0, 4.0, 3.0)
    empty = tmp_path / "empty.toml"
    empty.write_text("[thresholds]\n", encoding="utf-8")
    assert Thresholds.from_toml(empty) == defaults


@pytest.mark.parametrize(
    ("text", "field_name"),
    [
        ("delta_e_warn = -1", "thresholds.delta_e_warn"),
        ("rmse_fail = 0", "thresholds.rmse_fail"),
        ("noise_factor = nan", "thresholds.noise_factor"),
        ("runs_z = '3'", "thresholds.runs_z"),
        ("ks_max = true", "thresholds.ks_max"),
        ("delta_e_warning = 1", "thresholds.delta_e_warning"),
        ("delta_e_warn = 3\ndelta_e_fail = 2.5", "thresholds.delta_e_warn"),
        ("rmse_warn = 0.05", "thresholds.rmse_warn"),
        ("ks_min = 500", "thresholds.ks_min"),
    ],
)
def test_bad_threshold_config_names_the_field(tmp_path, text, field_name):
    config = tmp_path / "limits.toml"
    config.write_text(f"[thresholds]\n{text}\n", encoding="utf-8")
    with pytest.raises(InputError) as caught:
        Thresholds.from_toml(config)
    assert caught.value.field == field_name
    assert field_name in str(caught.value)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(min_value=1e-9, max_value=1e9, allow_nan=False, allow_infinity=False), min_size=11, max_size=11)
)
def test_any_valid_config_reads_back_exactly(tmp_path_factory, values):
    names = [f.name for f in dataclasses.fields(Thresholds)]
    values[0:2], values[2:4] = sorted(values[0:2]), sorted(values[2:4])  # warn <= fail
    values[5:7] = sorted(values[5:7])  # ks_min <= ks_max
    values[9:11] = sorted(values[9:11])  # uncertainty_warn <= uncertainty_fail
    config = tmp_path_factory.mktemp("config") / "limits.toml"
    config.write_text(
        "[thresholds]\n" + "".join(f"{n} = {v!r}\n" for n, v in zip(names, values, strict=True)), encoding="utf-8"
    )
    assert Thresholds.from_toml(config) == Thresholds(*values)


def test_warn_above_fail_is_refused_by_updated():
    with pytest.raises(InputError) as caught:
        Thresholds().updated(delta_e_warn=3.0)
    assert caught.value.field == "delta_e_warn"
    with pytest.raises(InputError) as caught:
        Thresholds().updated(rmse_warn=0.002, rmse_fail=0.001)
    assert caught.value.field == "rmse_warn"
    assert Thresholds().updated(delta_e_warn=None) == Thresholds()


def test_missing_or_broken_config_file_is_bad_input(tmp_path):
    with pytest.raises(InputError, match=r"nothing\.toml"):
        Thresholds.from_toml(tmp_path / "nothing.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[thresholds\n", encoding="utf-8")
    with pytest.raises(InputError, match=r"broken\.toml"):
        Thresholds.from_toml(broken)


# --- colour differences against colour-science --------------------------------------------------------------


@pytest.mark.parametrize("observer", ["2", "10"])
@pytest.mark.parametrize("name", ["clean", "saunderson"])
def test_delta_e_2000_agrees_with_colour_science(request, name, observer):
    case = request.getfixturevalue(name)
    illuminants = ("D65", "A", "F11")
    report = validate_material(case.material_path, illuminants=illuminants, observer=observer)
    predicted = predictions(case.sim, case.material)
    assert report.illuminants == illuminants and report.observer == observer
    largest = 0.0
    for check, e in zip(report.measurements, case.sim.entries, strict=True):
        measured = case.sim.columns[e["column"]]
        assert np.max(np.abs(check.predicted - predicted[e["column"]])) < 1e-12
        for illuminant in illuminants:
            want = delta_e_2000(measured, predicted[e["column"]], case.sim.wavelengths, illuminant, observer)
            assert abs(check.delta_e[illuminant] - want) < 1e-9, (check.id, illuminant)
            largest = max(largest, want)
    assert report.worst_delta_e == pytest.approx(largest, abs=1e-9)
    assert largest > (0.05 if name == "clean" else 0.5)  # differences of a size worth comparing


# --- the report document ------------------------------------------------------------------------------------

ALL_CASES = ["clean", "f2", "white", "opaque", "saunderson", "biased", "bright", "black", "thick"]


@pytest.mark.parametrize("name", ALL_CASES)
def test_report_document_is_strict_json_and_lists_the_findings(request, name):
    case = request.getfixturevalue(name)
    report = case.report
    doc = report_to_dict(report, html="report.html")
    text = json.dumps(doc, allow_nan=False)  # raises on NaN or infinity
    assert json.loads(text) == doc
    assert doc["format"] == "kmpipe-validation/1"
    assert doc["verdict"] == report.verdict
    assert doc["report_html"] == "report.html"
    assert doc["findings"] == [
        {
            "code": f.code,
            "severity": f.severity,
            "message": f.message,
            "wavelengths_nm": f.where,
            "measurement": f.measurement,
        }
        for f in report.findings
    ]
    # Reasons: each code once, most severe first.
    severities = ["pass", "warn", "fail"]
    worst_first = sorted(report.findings, key=lambda f: -severities.index(f.severity))
    assert doc["reasons"] == list(dict.fromkeys(f.code for f in worst_first))
    assert doc["verdict"] == max((f.severity for f in report.findings), key=severities.index, default="pass")
    assert [m["id"] for m in doc["measurements"]] == [f"readings.csv:{e['column']}" for e in case.sim.entries]
    for m, e in zip(doc["measurements"], case.sim.entries, strict=True):
        assert m["thickness_mm"] == (None if e["role"] == "masstone" else e["thickness_mm"])
        assert m["max_abs_error"] >= m["rmse"] >= 0.0
        assert m["max_abs_error_at"] in list(case.sim.wavelengths)
    for f in report.findings:
        severity, _ = CHECKS[f.code]
        assert f.severity in severity.split("/")


def test_every_check_has_a_fixture_that_fires_it(request):
    seen = set()
    for name in ALL_CASES:
        seen |= set(codes(request.getfixturevalue(name).report))
    # masstone_not_opaque, delta_e/rmse (via thresholds) and inputs_changed have tests of their own, and so have the
    # rendered colour's checks (test_uncertainty.py).
    own = {"masstone_not_opaque", "inputs_changed", "colour_uncertainty", "uncertainty_nonlinear", "not_separable"}
    assert set(CHECKS) - seen <= own


# --- kmpipe validate ----------------------------------------------------------------------------------------


def run(capsys, *args: str) -> tuple[int, str, str]:
    """``kmpipe ARGS`` in-process: exit status (argparse refusals raise SystemExit), stdout, stderr."""
    try:
        status = cli.main([str(a) for a in args])
    except SystemExit as stop:
        status = stop.code
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return status, out, " ".join(err.split())


@pytest.mark.parametrize(
    ("name", "status", "verdict"), [("clean", 0, "pass"), ("opaque", 0, "warn"), ("f2", 1, "fail")]
)
def test_validate_exit_status_follows_the_verdict(request, capsys, tmp_path, name, status, verdict):
    case = request.getfixturevalue(name)
    got, out, err = run(capsys, "validate", case.material_path, "-o", tmp_path / "report")
    assert got == status, err
    assert case.report.material.name in out and verdict in out
    doc = read_json(tmp_path / "report" / "validation.json")
    assert doc["verdict"] == verdict
    assert doc["findings"] == report_to_dict(case.report)["findings"]
    assert (tmp_path / "report" / "report.html").is_file()


def test_validate_options_reach_the_report(capsys, clean, tmp_path):
    config = tmp_path / "limits.toml"
    config.write_text("[thresholds]\nrmse_warn = 1e-6\nrmse_fail = 1.0\n", encoding="utf-8")
    status, _, err = run(
        capsys,
        "validate",
        clean.material_path,
        "-o",
        tmp_path / "r",
        "--illuminant",
        "D65,A",
        "--observer",
        "10",
        "--config",
        config,
        "--delta-e-warn",
        "0.001",
        "--delta-e-fail",
        "5",
    )
    assert status == 0, err
    doc = read_json(tmp_path / "r" / "validation.json")
    assert doc["illuminants"] == ["D65", "A"] and doc["observer"] == "10"
    assert doc["thresholds"]["rmse_warn"] == 1e-6 and doc["thresholds"]["delta_e_warn"] == 0.001
    assert doc["verdict"] == "warn" and set(doc["reasons"]) == {"delta_e", "rmse"}


def not_a_material(tmp_path: Path) -> Path:
    path = tmp_path / "notes.json"
    path.write_text('{"format": "kmpipe-validation/1", "verdict": "pass"}\n', encoding="utf-8")
    return path


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (lambda case, tmp: [tmp / "missing.json"], "missing.json"),
        (lambda case, tmp: [not_a_material(tmp)], "notes.json"),
        (lambda case, tmp: [case.material_path, "--illuminant", "D65,D99"], "--illuminant"),
        (lambda case, tmp: [case.material_path, "--observer", "5"], "--observer"),
        (lambda case, tmp: [case.material_path, "--delta-e-warn", "3"], "delta_e_warn"),
        (lambda case, tmp: [case.material_path, "--config", tmp / "none.toml"], "none.toml"),
    ],
    ids=["missing-material", "not-a-material", "illuminant", "observer", "warn-above-fail", "missing-config"],
)
def test_validate_bad_input_exits_2_naming_it(capsys, clean, tmp_path, args, named):
    status, _, err = run(capsys, "validate", *args(clean, tmp_path), "-o", tmp_path / "r")
    assert status == 2
    assert named in err


def test_validate_unknown_threshold_in_config_exits_2(capsys, clean, tmp_path):
    config = tmp_path / "limits.toml"
    config.write_text("[thresholds]\ndelta_e_warn = 1.5\nmax_delta_e = 3\n", encoding="utf-8")
    status, _, err = run(capsys, "validate", clean.material_path, "--config", config, "-o", tmp_path / "r")
    assert status == 2
    assert "limits.toml" in err and "thresholds.max_delta_e" in err
    assert not (tmp_path / "r").exists()


def test_validate_a_folder_of_materials(capsys, tmp_path, foundation):
    """A product line: three samples fitted into one folder, validated together."""
    wl, K, S = foundation
    manifests = [
        simulate_sample(tmp_path / "a", wl, K, S, repeats=2, masstones=2, noise=0.001, rng=21, name="shade-a").manifest,
        simulate_sample(tmp_path / "b", wl, K, S, thicknesses_um=(2000, 5000), name="shade-b").manifest,
        simulate_sample(
            tmp_path / "c",
            wl,
            K,
            S,
            edit=lambda cols, w: cols.update(film_15um_white_1=np.where(w == 600.0, 1.1, cols["film_15um_white_1"])),
            name="shade-c",
        ).manifest,
    ]
    line = tmp_path / "line"
    assert cli.main(["fit", *map(str, manifests), "-o", str(line)]) == 0
    capsys.readouterr()
    (line / "notes.json").write_text('{"not": "a material"}\n', encoding="utf-8")  # skipped, not an error
    reports = tmp_path / "reports"
    status, out, err = run(capsys, "validate", f"{line}/", "-o", reports)
    assert status == 1, err  # shade-c reads 1.1 at 600 nm: reflectance_out_of_range fails
    assert out.count("Validation") == 1  # one summary table
    rows = {name: next(r for r in out.splitlines() if name in r) for name in ("shade-a", "shade-b", "shade-c")}
    assert "pass" in rows["shade-a"] and "warn" in rows["shade-b"] and "fail" in rows["shade-c"]
    index = reports / "index.html"
    assert index.is_file()
    text = index.read_text(encoding="utf-8")
    for name in ("shade-a", "shade-b", "shade-c"):
        assert name in text
        assert read_json(reports / name / "validation.json")["sample"] == name
    # Without the failing sample the batch exits 0.
    (line / "shade-c.json").unlink()
    status, out, err = run(capsys, "validate", line, "-o", tmp_path / "again")
    assert status == 0, err
    assert (tmp_path / "again" / "index.html").is_file()


# --- regressions found while writing these tests --------------------------------------------------------


def test_thickness_series_of_single_readings_like_thesis_f2_fails(tmp_path, foundation):
    """The thesis's F2 had one reading per film. Here the 30 um film over black reads 0.027-0.034 darker than
    the 15 um film over all of 380-500 nm, with reading noise 0.001 (about 30 sigma).
    """
    wl, K, S = foundation

    def uneven(columns, wavelengths):
        band = (wavelengths >= F2_LOW) & (wavelengths <= F2_HIGH)
        columns["film_30um_black_1"] = np.where(band, 0.85 * columns["film_30um_black_1"], columns["film_30um_black_1"])

    sim = simulate_sample(tmp_path / "s", wl, K, S, noise=0.001, rng=2, edit=uneven, name="F2single")
    band = (wl >= F2_LOW) & (wl <= F2_HIGH)
    darker = sim.columns["film_30um_black_1"] - sim.columns["film_15um_black_1"]
    assert np.all(darker[band] < -0.025) and np.all(darker[~band] > 0.0)
    report = validate_material(fit(sim.manifest, tmp_path / "m.json"))
    (finding,) = only(report, "thickness_not_monotone")
    assert finding.where and between(finding.where, F2_LOW, F2_HIGH)


@pytest.mark.parametrize("fault", ["opaque-films", "thick-masstone"])
def test_noise_free_readings_of_a_sound_sample_do_not_fail(tmp_path, foundation, fault):
    """Noise-free readings with repeats: the repeat spread is 0, so the checks fall back on the MIN_NOISE floor.

    Opaque films of 2 and 5 mm then differ by rounding only (1e-16), and a masstone declared 5 mm hides the
    black card to 1e-16; neither is a fault.
    """
    wl, K, S = foundation
    if fault == "opaque-films":
        sim = simulate_sample(tmp_path / "s", wl, K, S, thicknesses_um=(2000, 5000), repeats=2, name="nf")
    else:
        sim = simulate_sample(tmp_path / "s", wl, K, S, repeats=2, masstones=2, masstone_thickness="5 mm", name="nf")
    report = validate_material(fit(sim.manifest, tmp_path / "m.json"))
    assert report.noise_sigma == MIN_NOISE and report.noise_source.endswith(f"floored at {MIN_NOISE:g}")
    assert report.verdict != "fail", [f.message for f in report.findings]


def test_thickness_series_with_surface_reflection_and_no_masstone(tmp_path):
    """A sound series (films of 20 and 40 um, two repeats, noise 0.0005) of a pale yellow, with Saunderson
    surface reflection, fitted with --saunderson, without a masstone.

    Over the white card a thicker film must read darker where the measured R_inf is below the card (400-490
    nm: about 0.3-0.6 against 0.81-0.84), and does.
    """
    wl, K, S = rit_mixture({"TitaniumWhite": 1.0, "HansaYellowOpaque": 0.02})
    sim = simulate_sample(
        tmp_path / "s",
        wl,
        K,
        S,
        thicknesses_um=(20, 40),
        repeats=2,
        masstones=0,
        noise=0.0005,
        rng=1,
        saunderson=SAUNDERSON,
        name="pale",
    )
    measured_masstone = surface(textbook_masstone(K, S), SAUNDERSON)
    for over in ("black", "white"):  # the series really is monotone towards the measured masstone
        toward = np.sign(measured_masstone - sim.cards[over])
        thin = np.mean([sim.columns[c] for c in sim.group("film", over, 20)], axis=0)
        thicker = np.mean([sim.columns[c] for c in sim.group("film", over, 40)], axis=0)
        assert np.all(toward * (thicker - thin) > -3 * 0.0005)
    report = validate_material(fit(sim.manifest, tmp_path / "m.json", "--saunderson", "0.04,0.6"))
    assert "thickness_not_monotone" not in codes(report)


@pytest.mark.parametrize(
    ("values", "field_name"),
    [
        ({"rmse_warn": -1.0}, "rmse_warn"),
        ({"delta_e_warn": math.nan}, "delta_e_warn"),
        ({"delta_e_warning": 1.5}, "delta_e_warning"),
        ({"ks_min": 300.0}, "ks_min"),
    ],
)
def test_updated_thresholds_are_checked_like_the_config_file(values, field_name):
    """Thresholds.updated is the API behind the command line options; the TOML reader refuses these values."""
    with pytest.raises(InputError) as caught:
        Thresholds().updated(**values)
    assert field_name in str(caught.value)


@pytest.mark.parametrize(
    "text",
    ["thresholds = 3\n", "[threshold]\ndelta_e_warn = 0.5\n", "delta_e_warn = 0.5\n"],
    ids=["not-a-table", "misspelt-table", "outside-table"],
)
def test_config_without_a_thresholds_table_is_refused(tmp_path, text):
    """A --config file exists only to give a [thresholds] table; one without it is a mistake."""
    config = tmp_path / "limits.toml"
    config.write_text(text, encoding="utf-8")
    with pytest.raises(InputError, match=r"limits\.toml"):
        Thresholds.from_toml(config)


# --- documentation ------------------------------------------------------------------------------------------


def test_formats_doc_lists_every_field_key_and_check(clean, f2):
    text = (ROOT / "docs" / "formats.md").read_text(encoding="utf-8")
    report_doc = text[text.index("## Validation report (JSON)") : text.index("## Validation thresholds (TOML)")]
    thresholds_doc = text[text.index("## Validation thresholds (TOML)") :]
    doc = report_to_dict(clean.report, html="report.html")
    for key in [*doc, *doc["measurements"][0], *doc["noise"]]:
        assert f"`{key}`" in report_doc, key
    for key in ("code", "severity", "message", "wavelengths_nm", "measurement"):
        assert f"`{key}`" in report_doc, key
    examples = [json.loads(block) for block in re.findall(r"```json\n(.*?)```", report_doc, re.DOTALL)]
    assert list(examples[0]) == list(doc)
    assert list(examples[0]["measurements"][0]) == list(doc["measurements"][0])
    assert list(examples[0]["findings"][0]) == list(examples[1]) == list(report_to_dict(f2.report)["findings"][0])
    for code, (severity, _) in CHECKS.items():
        assert re.search(rf"^\| `{code}` \| {re.escape(severity)} \|", report_doc, re.MULTILINE), code
    defaults = Thresholds()
    for f in dataclasses.fields(Thresholds):
        assert re.search(rf"^\| `{f.name}` \| `{getattr(defaults, f.name)!r}` \|", thresholds_doc, re.MULTILINE), f.name


def test_the_report_is_written_before_validation_json(clean, tmp_path, monkeypatch):
    """validation.json (what batch readers look for) comes last: an exit between leaves no JSON without its page."""
    import kmpipe.validation.report as report_module

    order = []
    real = report_module.write_text_atomically
    monkeypatch.setattr(report_module, "write_text_atomically", lambda path, text: (order.append(path.name),
                                                                                    real(path, text)))  # fmt: skip
    report_module.write_sample_report(clean.report, tmp_path / "out")
    assert order == ["report.html", "validation.json"]
