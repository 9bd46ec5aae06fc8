"""Optical tables and the render plan: working space, render modes against independent spectral references."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import colour
import numpy as np
import pytest
from simulation import rit_pigments

from kmpipe.physics.kubelka_munk import film_reflectance_transmittance, stack_over_substrate
from kmpipe.physics.optical_tables import (
    OpticalTable,
    Stack,
    band_partition,
    composite,
    mode_error,
    working_space,
    working_space_matrix,
)
from kmpipe.stages.render_plan import plan_render

MODES = ("rgb", "bands:3", "bands:6", "exact")


@dataclass(frozen=True)
class Film:
    name: str
    wavelengths: np.ndarray
    K: np.ndarray
    S: np.ndarray


def _pigments() -> dict[str, Film]:
    """The 19 RIT paints, K and S x 60 read as 1/mm, on the table's 380-750 nm / 10 nm grid."""
    table = rit_pigments()
    return {name: Film(name, table.wavelengths, 60.0 * table.K[name], 60.0 * table.S[name]) for name in table.names}


PAINTS = _pigments()
WL = next(iter(PAINTS.values())).wavelengths
_SKIN_SD = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]["light skin"]
SKIN = np.interp(WL, _SKIN_SD.wavelengths, _SKIN_SD.values)
THICKNESS = (0.010, 0.040)


def _white(name: str = "white") -> Film:
    return Film(name, WL, np.zeros_like(WL), np.full_like(WL, 1e6))


@pytest.mark.parametrize("illuminant", ["D65", "A"])
def test_perfect_white_maps_to_working_white(illuminant):
    space = working_space(WL, illuminant)
    table = OpticalTable.build(_white(), [10.0], "exact", space)
    rgb = composite([table], [10.0], np.zeros_like(WL), "exact")
    np.testing.assert_allclose(rgb, 1.0, atol=1e-6)
    np.testing.assert_allclose(np.ones_like(WL) @ working_space_matrix(WL, illuminant), 1.0, atol=1e-12)


@pytest.mark.parametrize("mode", MODES)
def test_zero_thickness_film_leaves_substrate(mode):
    space = working_space(WL)
    table = OpticalTable.build(PAINTS["PyrroleRed"], [0.0, 0.02], mode, space)
    rgb = composite([table], [0.0], SKIN, mode)
    if mode == "rgb":
        expected = np.clip(SKIN @ space.matrix, 0.0, 1.0)
    elif mode == "exact":
        expected = SKIN @ space.matrix
    else:
        bands = band_partition(WL, int(mode.split(":")[1]), space=space)
        expected = (SKIN @ bands.averaging) @ bands.to_rgb
    np.testing.assert_allclose(rgb, expected, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("mode", MODES)
def test_white_non_absorbing_layers_never_exceed_the_light(mode):
    space = working_space(WL, "A")
    films = [Film(f"w{i}", WL, np.zeros_like(WL), np.full_like(WL, s)) for i, s in enumerate((5.0, 50.0, 500.0))]
    tables = [OpticalTable.build(f, [0.0, 0.01, 0.05, 1.0], mode, space) for f in films]
    X = np.array(list(itertools.product([0.0, 0.01, 0.05, 1.0], repeat=3))).T
    rgb = composite(tables, list(X), np.ones_like(WL), mode)
    assert np.all(rgb <= 1.0 + 1e-9)
    np.testing.assert_allclose(rgb, 1.0, atol=1e-9)  # nothing absorbs over a perfect white: all light returns


@pytest.mark.filterwarnings("ignore::colour.utilities.ColourRuntimeWarning")
@pytest.mark.parametrize("illuminant", ["D65", "A"])
def test_exact_mode_matches_independent_spectral_computation(illuminant):
    layers = [PAINTS["QuinacridoneMagenta"], PAINTS["TitaniumWhite"], PAINTS["PhthaloGreenBlueShade"]]
    X = [0.012, 0.025, 0.033]
    space = working_space(WL, illuminant)
    tables = [OpticalTable.build(m, [0.01, x, 0.04], "exact", space) for m, x in zip(layers, X, strict=True)]
    rgb = composite(tables, X, SKIN, "exact")

    films = [film_reflectance_transmittance(m.K, m.S, x) for m, x in zip(layers, X, strict=True)]
    R = stack_over_substrate(np.array([f[0] for f in films]), np.array([f[1] for f in films]), SKIN)
    # colour-science's integration with its own CMFs and illuminant (it brings them to the spectrum's grid).
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    light = colour.SDS_ILLUMINANTS[illuminant]

    def to_rgb(values):
        XYZ = colour.sd_to_XYZ(colour.SpectralDistribution(values, WL), cmfs, light, method="Integration") / 100
        white = (
            colour.sd_to_XYZ(colour.SpectralDistribution(np.ones_like(WL), WL), cmfs, light, method="Integration") / 100
        )
        return colour.XYZ_to_RGB(
            XYZ,
            colour.RGB_COLOURSPACES["sRGB"],
            illuminant=colour.XYZ_to_xy(white),
            chromatic_adaptation_transform="CAT02",
        )

    # The working space is normalized so that the perfect white is (1, 1, 1): divide by the reference's white.
    expected = to_rgb(R) / to_rgb(np.ones_like(WL))
    np.testing.assert_allclose(rgb, expected, atol=1e-6)


def _rit_stacks() -> list[Stack]:
    names = list(PAINTS)
    singles = [Stack(n, (n,), SKIN) for n in names]
    pairs = [Stack(f"{a}/{b}", (a, b), SKIN) for a, b in zip(names, names[1:] + names[:1], strict=True)]
    return singles + pairs


def test_band_error_shrinks_with_more_bands_and_rgb_is_worst():
    stacks = _rit_stacks()
    ranges = dict.fromkeys(PAINTS, THICKNESS)
    worst = {
        m: mode_error(stacks, m, PAINTS, ranges).max()
        for m in ("rgb", "bands:3", "bands:6", "bands:9", "bands:12", "exact")
    }
    assert worst["rgb"] > worst["bands:3"] > worst["bands:6"] > worst["bands:9"] > worst["bands:12"]
    assert worst["exact"] < 1e-6


def test_band_partition_is_contiguous_and_exact_for_band_constant_spectra():
    space = working_space(WL, "A")
    bands = band_partition(WL, 7, space=space)
    assert np.all(np.diff(bands.labels) >= 0) and set(bands.labels) == set(range(7))
    np.testing.assert_allclose(bands.averaging.sum(axis=0), 1.0)
    spectrum = np.linspace(0.1, 0.9, 7)[bands.labels]
    np.testing.assert_allclose((spectrum @ bands.averaging) @ bands.to_rgb, spectrum @ space.matrix, atol=1e-12)


def test_planner_picks_rgb_for_loose_target_and_finer_for_tight():
    stacks = _rit_stacks()[:6]
    ranges = dict.fromkeys(PAINTS, THICKNESS)
    loose = plan_render(PAINTS, stacks, ranges, "D65", accuracy_target_dE=50.0)
    assert loose.mode == "rgb"
    rgb_errors = mode_error(stacks, "rgb", PAINTS, ranges)
    assert loose.candidates[0].max_dE == pytest.approx(rgb_errors.max(), rel=1e-12)
    assert loose.candidates[0].mean_dE == pytest.approx(rgb_errors.mean(), rel=1e-12)

    tight = plan_render(PAINTS, stacks, ranges, "D65", accuracy_target_dE=0.5)
    assert tight.mode != "rgb" and tight.candidates[-1].mode == tight.mode
    for candidate in tight.candidates:
        errors = mode_error(stacks, candidate.mode, PAINTS, ranges)
        assert candidate.max_dE == pytest.approx(errors.max(), rel=1e-12)
    assert tight.candidates[-1].max_dE <= 0.5 < tight.candidates[-2].max_dE

    # Interpolation on the planned axes stays within a quarter of the target, checked at random thicknesses.
    space = working_space(WL)
    tables = tight.build_tables(PAINTS)
    rng = np.random.default_rng(1)
    for name in tight.materials:
        X = rng.uniform(*THICKNESS, 50)
        direct = OpticalTable.build(PAINTS[name], X, tight.mode, space)
        dE = colour.delta_E(
            space.to_Lab(composite([tables[name]], [X], SKIN, tight.mode)),
            space.to_Lab(composite([direct], [X], SKIN, tight.mode)),
            method="CIE 2000",
        )
        assert np.max(dE) <= 0.25 * 0.5


def test_single_thickness_has_no_axis_and_explanation_says_so():
    stacks = [Stack("lip", ("PyrroleRed", "TitaniumWhite"), SKIN), Stack("bare", (), SKIN)]
    ranges = {"PyrroleRed": (0.02, 0.02), "TitaniumWhite": THICKNESS}
    plan = plan_render(PAINTS, stacks, ranges, "A", accuracy_target_dE=2.0)
    sizes = {t.material: t for t in plan.tables}
    assert sizes["PyrroleRed"].n_samples == 1
    assert sizes["TitaniumWhite"].n_samples >= 2
    assert plan.build_tables(PAINTS)["PyrroleRed"].thickness_mm is None
    text = plan.explain()
    assert "PyrroleRed: single thickness 0.02 mm -> no thickness axis" in text
    assert "stack bare: no layers (bare substrate) -> no tables" in text
    assert "material BoneBlack: not in any stack -> no table" in text
    assert set(plan.materials) == {"PyrroleRed", "TitaniumWhite"}
