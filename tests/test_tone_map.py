"""Tone mapping (renderer.tone_map) against references written here from the published formulas.

References are evaluated with mpmath at 50 digits (or plain Python floats for the closed forms), never with numbers
the module produced: Rec. 709 luminance L = 0.2126 r + 0.7152 g + 0.0722 b; extended Reinhard (Reinhard et al.
2002, eq. 4) Ld = L (1 + L / Lw^2) / (1 + L), rgb scaled by Ld / L and clipped to 1; Narkowicz 2015 ACES fit
f(x) = x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14), clipped to 1.
"""

from __future__ import annotations

import math

import mpmath
import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from renderer.tone_map import OPERATORS, tone_map

_mp = mpmath.MPContext()
_mp.dps = 50
mpf = _mp.mpf

WEIGHTS = (mpf("0.2126"), mpf("0.7152"), mpf("0.0722"))


def luminance_ref(rgb) -> mpmath.mpf:
    return sum((w * mpf(float(c)) for w, c in zip(WEIGHTS, rgb, strict=True)), mpf(0))


def reinhard_ref(rgb, white: float) -> list[float]:
    """Extended Reinhard of one pixel (already exposed), channels clipped to [0, 1]."""
    lum = luminance_ref(rgb)
    if lum == 0:
        return [0.0, 0.0, 0.0]
    w = mpf(float(white))
    ld = lum * (1 + lum / w**2) / (1 + lum)
    return [float(min(mpf(float(c)) * ld / lum, mpf(1))) for c in rgb]


def aces_ref(x: float) -> float:
    """Narkowicz 2015 fitted ACES curve, clipped to [0, 1]."""
    x = mpf(float(x))
    f = x * (mpf("2.51") * x + mpf("0.03")) / (x * (mpf("2.43") * x + mpf("0.59")) + mpf("0.14"))
    return float(min(max(f, mpf(0)), mpf(1)))


def pixel(rgb) -> np.ndarray:
    return np.array([rgb], dtype=np.float64)


unit32 = st.floats(0.0, 1.0, width=32)
channel = st.one_of(st.just(0.0), st.floats(1e-20, 100.0))
rgb_pixels = st.tuples(channel, channel, channel)
whites = st.floats(1e-3, 1e4)
image_shapes = hnp.array_shapes(min_dims=1, max_dims=3, max_side=5).map(lambda s: (*s, 3))


# --------------------------------------------------------------------------------------------- none and exposure
@given(hnp.arrays(np.float32, image_shapes, elements=unit32))
def test_none_at_zero_ev_is_the_identity_on_unit_interval(image):
    out = tone_map(image)
    assert out.dtype == np.float32 and out.shape == image.shape
    np.testing.assert_array_equal(out, image)


@given(hnp.arrays(np.float64, image_shapes, elements=st.floats(1.0, 1e30, exclude_min=True)))
def test_none_clips_above_one(image):
    np.testing.assert_array_equal(tone_map(image, "none"), np.ones(image.shape, dtype=np.float32))


@given(hnp.arrays(np.float32, image_shapes, elements=st.floats(0.0, 0.5, width=32, exclude_max=True)))
def test_plus_one_ev_doubles_values_below_half(image):
    np.testing.assert_array_equal(tone_map(image, "none", exposure_ev=1.0), image * np.float32(2.0))


@given(st.floats(0.0, 1.0), st.floats(-20.0, 0.0))
def test_fractional_exposure_scales_by_power_of_two(value, ev):
    expected = value * math.pow(2.0, ev)
    out = tone_map(pixel((value, value, value)), "none", exposure_ev=ev)
    np.testing.assert_allclose(out, np.full((1, 3), expected), rtol=1e-6, atol=1e-30)


def test_negative_values_are_clamped_to_zero_first():
    out = tone_map(pixel((-1.0, 0.25, -0.0)), "reinhard", white=1.0)
    np.testing.assert_array_equal(out, tone_map(pixel((0.0, 0.25, 0.0)), "reinhard", white=1.0))
    np.testing.assert_array_equal(tone_map(pixel((-5.0, -1e-30, 0.5))), np.array([[0.0, 0.0, 0.5]], np.float32))
    assert not np.signbit(tone_map(pixel((-0.0, -1.0, 0.0)))).any()


# --------------------------------------------------------------------------------------------- reinhard
@given(st.floats(1e-3, 1e6))
def test_reinhard_maps_white_to_exactly_one(white):
    grey = pixel((white, white, white))  # luminance of a grey pixel is its value: the weights sum to 1
    np.testing.assert_allclose(tone_map(grey, "reinhard", white=white), np.ones((1, 3)), rtol=0, atol=1e-6)
    # default white: the brightest luminance in the image
    image = np.concatenate([grey, grey / 3.0])
    np.testing.assert_allclose(tone_map(image, "reinhard")[0], np.ones(3), rtol=0, atol=1e-6)


@given(rgb_pixels, whites)
def test_reinhard_matches_reference(rgb, white):
    out = tone_map(pixel(rgb), "reinhard", white=white)
    np.testing.assert_allclose(out[0], reinhard_ref(rgb, white), rtol=2e-6, atol=1e-30)


@given(st.lists(rgb_pixels, min_size=1, max_size=6), st.floats(-4.0, 4.0))
def test_reinhard_default_white_is_the_largest_exposed_luminance(pixels, ev):
    exposed = [tuple(c * 2.0**ev for c in rgb) for rgb in pixels]
    white = max(float(max(luminance_ref(rgb) for rgb in exposed)), 1e-6)
    out = tone_map(np.array(pixels), "reinhard", exposure_ev=ev)
    expected = [reinhard_ref(rgb, white) for rgb in exposed]
    np.testing.assert_allclose(out, expected, rtol=2e-6, atol=1e-30)


@given(
    st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.floats(0.0, 1.0)).filter(lambda c: max(c) > 0.0),
    st.lists(st.floats(0.0, 1e6), min_size=2, max_size=20),
    whites,
)
def test_reinhard_is_monotone_in_luminance(base, multipliers, white):
    image = np.array([[k * c for c in base] for k in sorted(multipliers)])  # luminance rises down the rows
    out = tone_map(image, "reinhard", white=white)
    assert np.all(np.diff(out, axis=0) >= 0.0)


positive = st.floats(1e-6, 1.0)


@given(st.tuples(positive, positive, positive), st.floats(1.0, 1e4))
def test_reinhard_preserves_chromaticity_below_one(rgb, white):
    # with white >= 1, Ld / L = (1 + L / white^2) / (1 + L) <= 1, so channels <= 1 stay <= 1
    assume(max(reinhard_ref(rgb, white)) < 1.0)
    out = tone_map(pixel(rgb), "reinhard", white=white)[0].astype(np.float64)
    ratios = out / np.array(rgb)  # r:g:b kept means one common factor Ld / L
    np.testing.assert_allclose(ratios, np.full(3, ratios[1]), rtol=2e-6)
    np.testing.assert_allclose(out[0] / out[1], rgb[0] / rgb[1], rtol=2e-6)
    np.testing.assert_allclose(out[2] / out[1], rgb[2] / rgb[1], rtol=2e-6)


@given(rgb_pixels.filter(lambda c: max(c) > 0.0), st.floats(1e-12, 1e-8), st.floats(0.5, 100.0))
def test_reinhard_is_identity_near_black(rgb, scale, white):
    tiny = np.array(rgb) / max(rgb) * scale  # luminance <= 1e-8, so Ld / L = 1 + O(1e-8 / white^2)
    out = tone_map(tiny[np.newaxis], "reinhard", white=white)[0]
    np.testing.assert_allclose(out, tiny, rtol=1e-6, atol=1e-30)
    # slope 1 at L = 0: the difference quotient of a grey ramp
    eps = 1e-9
    low, high = (
        tone_map(pixel((eps, eps, eps)), "reinhard", white=white)[0, 0],
        tone_map(pixel((2 * eps, 2 * eps, 2 * eps)), "reinhard", white=white)[0, 0],
    )
    assert (float(high) - float(low)) / eps == pytest.approx(1.0, rel=1e-5)
    np.testing.assert_array_equal(tone_map(np.zeros((2, 3)), "reinhard", white=white), np.zeros((2, 3)))


@given(rgb_pixels)
def test_reinhard_with_infinite_white_is_simple_reinhard(rgb):
    lum = 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
    expected = [min(c / (1.0 + lum), 1.0) for c in rgb]  # Ld = L / (1 + L), scaled by Ld / L = 1 / (1 + L)
    out = tone_map(pixel(rgb), "reinhard", white=1e30)[0]
    np.testing.assert_allclose(out, expected, rtol=2e-6, atol=1e-30)
    grey = tone_map(pixel((lum, lum, lum)), "reinhard", white=1e30)[0, 0]
    assert float(grey) == pytest.approx(lum / (1.0 + lum), rel=2e-6, abs=1e-30)


def test_reinhard_clips_a_channel_whose_luminance_is_below_one():
    # saturated blue: L = 0.0722 * 4 = 0.2888 < white, so Ld < 1, but blue * Ld / L > 1
    out = tone_map(pixel((0.0, 0.0, 4.0)), "reinhard", white=0.5)[0]
    assert reinhard_ref((0.0, 0.0, 4.0), 0.5) == [0.0, 0.0, 1.0]
    np.testing.assert_array_equal(out, [0.0, 0.0, 1.0])


# --------------------------------------------------------------------------------------------- aces
@pytest.mark.parametrize("x", [0.0, 0.18, 0.5, 1.0, 5.0, 7.0, 7.5, 10.0, 1e6])
def test_aces_matches_published_formula(x):
    out = tone_map(pixel((x, x, x)), "aces")[0]
    np.testing.assert_allclose(out, np.full(3, aces_ref(x)), rtol=1e-6, atol=0)


def test_aces_reference_points():
    assert aces_ref(0.0) == 0.0 and aces_ref(10.0) == 1.0  # f(10) = 281.3 / 249.04 > 1: clipped
    assert tone_map(np.zeros((1, 3)), "aces")[0, 0] == 0.0
    out = tone_map(pixel((0.0, 0.18, 1.0)), "aces")[0]  # per channel
    np.testing.assert_allclose(out, [aces_ref(0.0), aces_ref(0.18), aces_ref(1.0)], rtol=1e-6)


@given(st.tuples(channel, channel, channel), st.floats(-8.0, 8.0))
def test_aces_matches_reference_per_channel_with_exposure(rgb, ev):
    out = tone_map(pixel(rgb), "aces", exposure_ev=ev)[0]
    np.testing.assert_allclose(out, [aces_ref(c * 2.0**ev) for c in rgb], rtol=2e-6, atol=1e-30)


@given(st.lists(st.floats(0.0, 1e30), min_size=2, max_size=30))
def test_aces_is_monotone_and_bounded(values):
    ramp = np.repeat(np.sort(np.array(values))[:, np.newaxis], 3, axis=1)
    out = tone_map(ramp, "aces")
    assert np.all(np.diff(out, axis=0) >= 0.0)
    assert np.all((out >= 0.0) & (out <= 1.0))


@pytest.mark.parametrize("operator", ["none", "aces"])
def test_white_is_rejected_outside_reinhard(operator):
    with pytest.raises(ValueError, match="white"):
        tone_map(np.ones((1, 3)), operator, white=2.0)


# --------------------------------------------------------------------------------------------- robustness
extreme = st.one_of(
    st.sampled_from([0.0, 1e-30, 1e30, 5e-324, 1e-300, 1e300, float(np.finfo(np.float64).max)]),
    st.floats(0.0, 1e30),
    st.floats(-1e30, 0.0),
)


@given(
    hnp.arrays(np.float64, image_shapes, elements=extreme),
    st.sampled_from(OPERATORS),
    st.one_of(st.floats(-60.0, 60.0), st.sampled_from([-1e300, -5000.0, 5000.0, 1e300])),
)
def test_output_is_finite_float32_in_unit_interval(image, operator, ev):
    out = tone_map(image, operator, exposure_ev=ev)
    assert out.dtype == np.float32 and out.shape == image.shape
    assert np.all(np.isfinite(out)) and np.all((out >= 0.0) & (out <= 1.0))


@given(hnp.arrays(np.float32, image_shapes, elements=st.floats(0.0, float(np.float32(1e30)), width=32)), whites)
def test_reinhard_with_extreme_white_stays_finite(image, white):
    for w in (white, 1e-300, 1e300):
        out = tone_map(image, "reinhard", white=w)
        assert out.dtype == np.float32 and np.all(np.isfinite(out)) and np.all((out >= 0.0) & (out <= 1.0))


def test_empty_image():
    assert tone_map(np.zeros((0, 3)), "reinhard").shape == (0, 3)


@pytest.mark.parametrize("operator", OPERATORS)
@pytest.mark.parametrize(("bad", "message"), [(math.nan, "NaN"), (math.inf, "infinite"), (-math.inf, "infinite")])
def test_non_finite_input_raises(operator, bad, message):
    image = np.full((2, 2, 3), 0.5)
    image[1, 0, 2] = bad
    with pytest.raises(ValueError, match=message):
        tone_map(image, operator)


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="'none', 'reinhard', 'aces'"):
        tone_map(np.ones((1, 3)), "filmic")
    for ev in (math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError, match="exposure_ev"):
            tone_map(np.ones((1, 3)), exposure_ev=ev)
    for white in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="white"):
            tone_map(np.ones((1, 3)), "reinhard", white=white)
    for shape in ((3, 4), (), (2, 2)):
        with pytest.raises(ValueError, match="shape"):
            tone_map(np.ones(shape))
