"""Shade matching and metamerism (kmpipe.physics.shade_match) against colour-science computed directly, a
metameric pair built by construction, and the limits of Kubelka-Munk (no film, an opaque film)."""

from __future__ import annotations

import colour
import numpy as np
import pytest
from colour_reference import colour_lab
from hypothesis import given
from hypothesis import strategies as st

from kmpipe.physics.colorimetry import xyz_weights
from kmpipe.physics.shade_match import (
    broken_matches,
    made_up,
    masstone,
    pair_delta_e,
    rank_shades,
    shift_words,
)

GRID = np.arange(380.0, 781.0, 5.0)

pytestmark = pytest.mark.filterwarnings("ignore:Aligning:colour.utilities.ColourRuntimeWarning")


def metameric_pair() -> tuple[np.ndarray, np.ndarray]:
    """A skin-like spectrum and one with the same XYZ under D65 by construction: a smooth wiggle projected onto
    the null space of the D65 colour-matching weights (a metameric black) added to it."""
    base = 0.2 + 0.4 / (1.0 + np.exp(-(GRID - 590.0) / 25.0))
    wiggle = 0.06 * np.sin((GRID - 380.0) / 400.0 * 3.0 * 2.0 * np.pi)
    W = xyz_weights(GRID, "D65")
    black = wiggle - W @ np.linalg.lstsq(W.T @ W, W.T @ wiggle, rcond=None)[0]
    return base, base + black


def test_a_pair_metameric_under_d65_matches_there_and_parts_under_a_by_colour_sciences_figure():
    first, second = metameric_pair()
    assert 0.0 < second.min() and second.max() < 1.0
    delta_e = pair_delta_e(first, second, GRID, ["D65", "A"])
    assert delta_e[0] < 1e-6
    expected = colour.delta_E(colour_lab(first, GRID, "A"), colour_lab(second, GRID, "A"), method="CIE 2000")
    assert expected > 1.0  # the construction makes a real metamer
    assert delta_e[1] == pytest.approx(expected, rel=1e-6)
    broken = broken_matches(delta_e[:, None], 0, threshold=1.0)
    assert broken[:, 0].tolist() == [False, True]
    assert not broken_matches(delta_e[:, None] + 5.0, 0, threshold=1.0).any()  # no match under D65: nothing breaks


def test_coverage_is_zero_without_film_and_the_masstone_difference_when_opaque():
    K = 0.5 + 2.0 * np.exp(-(((GRID - 450.0) / 60.0) ** 2))
    S = np.full_like(GRID, 30.0)
    skin = 0.2 + 0.35 / (1.0 + np.exp(-(GRID - 590.0) / 25.0))
    np.testing.assert_array_equal(made_up(K, S, 0.0, skin), skin)
    assert pair_delta_e(made_up(K, S, 0.0, skin), skin, GRID, ["D65"])[0] == 0.0
    opaque = made_up(K, S, 5.0, skin)  # S X = 150: nothing of the skin shows
    np.testing.assert_allclose(opaque, masstone(K, S), atol=1e-12)
    expected = colour.delta_E(colour_lab(skin, GRID, "D65"), colour_lab(masstone(K, S), GRID, "D65"), method="CIE 2000")
    assert pair_delta_e(skin, opaque, GRID, ["D65"])[0] == pytest.approx(expected, rel=1e-6)
    thin, thicker = (pair_delta_e(skin, made_up(K, S, x, skin), GRID, ["D65"])[0] for x in (0.005, 0.02))
    assert 0.0 < thin < thicker < expected


def test_a_tone_that_is_a_shades_masstone_is_matched_by_that_shade():
    shades = [(np.full_like(GRID, k), np.full_like(GRID, 20.0)) for k in (0.5, 2.0, 6.0)]
    masstones = np.stack([masstone(K, S) for K, S in shades])
    for index in range(3):
        match = pair_delta_e(masstones, masstones[index], GRID, ["D65"])[0]
        ranking = rank_shades(match)
        assert ranking.best == index and match[index] < 1e-9 and ranking.margin == pytest.approx(np.sort(match)[1])
        K, S = shades[index]
        np.testing.assert_allclose(made_up(K, S, 0.015, masstones[index]), masstones[index], atol=1e-12)
    assert rank_shades(np.array([3.0])).second is None


def test_shifts_are_named_largest_first():
    assert shift_words(np.array([50.0, 8.0, 10.0]), np.array([50.0, 2.0, 10.5])) == "pinker"
    assert shift_words(np.array([45.0, 2.0, 13.0]), np.array([50.0, 2.0, 10.0])) == "darker and yellower"
    assert shift_words(np.array([50.0, 0.0, 0.0]), np.array([50.0, 0.0, 0.0])) == "the same"


@given(
    st.floats(1e-9, 1e6),
    st.floats(1e-9, 1e6),
    st.floats(0.0, 100.0),
    st.floats(1e-6, 1.0),
)
def test_made_up_skin_is_a_reflectance_at_the_extremes(k, s, thickness, skin):
    R = made_up(np.full(4, k), np.full(4, s), thickness, np.full(4, skin))
    assert np.all(np.isfinite(R)) and np.all(R >= 0.0) and np.all(R <= 1.0 + 1e-12)
    R_inf = masstone(np.full(4, k), np.full(4, s))
    assert np.all(np.minimum(R_inf, skin) - 1e-9 <= R) and np.all(R <= np.maximum(R_inf, skin) + 1e-9)
