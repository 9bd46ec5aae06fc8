"""Noise statistics of validation (kmpipe.validation.noise) against references written out plainly: closed forms,
the exact distribution of the runs test by enumeration, and loops over windows."""

from __future__ import annotations

import itertools
import math
import statistics

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from kmpipe.validation.noise import (
    MIN_NOISE,
    NOISE_WINDOW,
    longest_run,
    noise_map,
    repeat_spread,
    roughness_noise,
    runs_z,
    windowed,
)

# --- windowed statistics ------------------------------------------------------------------------------------


def windowed_reference(values: np.ndarray, statistic, window: int, offset: int) -> np.ndarray:
    """For output point i: ``statistic`` of the ``window`` values centred on value i - offset, the window moved
    inwards where it would run over an end (shorter rows: the whole row)."""
    k = values.shape[1]
    width = min(window, k)
    out = np.empty((values.shape[0], k + 2 * offset))
    for i in range(k + 2 * offset):
        start = min(max(i - offset - width // 2, 0), k - width)
        for row in range(values.shape[0]):
            out[row, i] = statistic(list(values[row, start : start + width]))
    return out


@settings(max_examples=60, deadline=None)
@given(
    values=arrays(np.float64, st.tuples(st.integers(1, 3), st.integers(1, 30)), elements=st.floats(-1.0, 1.0)),
    window=st.integers(1, 15),
    offset=st.integers(0, 2),
)
def test_windowed_median_and_mean_match_a_loop_over_windows(values, window, offset):
    got_median = windowed(values, np.median, window, offset)
    got_mean = windowed(values, np.mean, window, offset)
    np.testing.assert_allclose(got_median, windowed_reference(values, statistics.median, window, offset), atol=1e-15)
    np.testing.assert_allclose(got_mean, windowed_reference(values, statistics.fmean, window, offset), atol=1e-15)


# --- roughness noise ----------------------------------------------------------------------------------------


def test_roughness_of_a_straight_line_is_zero():
    line = (0.25 + np.arange(81) / 1024)[None, :]  # dyadic steps: second differences exactly 0
    np.testing.assert_array_equal(roughness_noise(line), np.zeros((1, 81)))


def test_roughness_of_a_parabola_is_its_constant_second_difference():
    """y = a i^2: every second difference is 2a, so sigma = 2a / 0.6745 / sqrt(6) at every point."""
    a = 1e-4
    i = np.arange(40, dtype=float)
    got = roughness_noise((a * i**2)[None, :])
    np.testing.assert_allclose(got, np.full((1, 40), 2 * a / 0.6745 / math.sqrt(6.0)), rtol=1e-9)


def test_roughness_of_fewer_than_three_points_is_zero():
    np.testing.assert_array_equal(roughness_noise(np.array([[0.3, 0.5]])), np.zeros((1, 2)))


def test_roughness_recovers_the_standard_deviation_of_white_noise_and_follows_it_across_the_spectrum():
    """Gaussian noise of sd 0.002 over the first half and 0.006 over the second half of a smooth spectrum: the
    estimate of each half (median over its points, away from the step) is within 10 % of the true sd."""
    rng = np.random.default_rng(7)
    n = 4000
    x = np.linspace(0.0, 1.0, n)
    sd = np.where(np.arange(n) < n // 2, 0.002, 0.006)
    readings = (0.4 + 0.2 * np.sin(3 * x) + rng.normal(0.0, sd))[None, :]
    sigma = roughness_noise(readings)[0]
    margin = 2 * NOISE_WINDOW
    assert np.median(sigma[margin : n // 2 - margin]) == pytest.approx(0.002, rel=0.10)
    assert np.median(sigma[n // 2 + margin : -margin]) == pytest.approx(0.006, rel=0.10)


# --- noise of every reading ---------------------------------------------------------------------------------


def test_noise_map_takes_repeats_from_their_spread_and_singles_from_their_roughness():
    """Rows 0 and 1 repeat each other and differ by a constant 0.01 (sd 0.01 / sqrt 2 at every wavelength); row 2
    is a parabola of second difference 2e-3 (roughness 2e-3 / 0.6745 / sqrt 6)."""
    i = np.arange(30, dtype=float)
    base = 0.3 + 0.001 * i
    readings = np.array([base, base + 0.01, 0.2 + 1e-3 * i**2])
    sigma, source = noise_map(readings, [[0, 1], [2]])
    np.testing.assert_allclose(sigma[0], np.full(30, 0.01 / math.sqrt(2.0)), rtol=1e-9)
    np.testing.assert_allclose(sigma[1], sigma[0])
    np.testing.assert_allclose(sigma[2], np.full(30, 2e-3 / 0.6745 / math.sqrt(6.0)), rtol=1e-9)
    assert source == "spread of repeats; roughness of single readings"


def test_noise_map_names_its_source_and_floors_at_min_noise():
    flat = np.full((2, 20), 0.5)
    sigma, source = noise_map(flat, [[0, 1]])
    np.testing.assert_array_equal(sigma, np.full((2, 20), MIN_NOISE))
    assert source == f"spread of repeats; floored at {MIN_NOISE:g}"
    sigma, source = noise_map(flat, [[0], [1]])
    np.testing.assert_array_equal(sigma, np.full((2, 20), MIN_NOISE))
    assert source == f"roughness of the readings (local second differences); floored at {MIN_NOISE:g}"


def test_repeat_spread_is_the_rms_of_the_per_wavelength_standard_deviation():
    repeats = np.array([[0.20, 0.40, 0.60], [0.22, 0.40, 0.57], [0.21, 0.43, 0.60]])
    per_wavelength = [statistics.stdev(column) for column in repeats.T]
    expected = math.sqrt(sum(s * s for s in per_wavelength) / len(per_wavelength))
    assert repeat_spread(repeats) == pytest.approx(expected, rel=1e-12)


# --- runs test ----------------------------------------------------------------------------------------------


def runs(signs: tuple[bool, ...]) -> int:
    return 1 + sum(a != b for a, b in itertools.pairwise(signs))


@pytest.mark.parametrize("n_pos, n_neg", [(4, 5), (6, 6), (3, 9), (7, 4)])
def test_runs_z_uses_the_exact_mean_and_variance_of_the_number_of_runs(n_pos, n_neg):
    """Under the null every arrangement of n1 positive and n2 negative signs is equally likely: the mean and
    variance of the number of runs over all arrangements, enumerated, give the z of each arrangement."""
    n = n_pos + n_neg
    arrangements = [
        tuple(i in chosen for i in range(n)) for chosen in map(set, itertools.combinations(range(n), n_pos))
    ]
    counts = [runs(a) for a in arrangements]
    mean = statistics.fmean(counts)
    sd = math.sqrt(statistics.pvariance(counts))
    for signs in arrangements[:: max(1, len(arrangements) // 25)]:
        residuals = np.where(signs, 0.01, -0.02)
        assert runs_z(residuals) == pytest.approx((runs(signs) - mean) / sd, rel=1e-12, abs=1e-12)


def test_runs_z_leaves_zeros_out():
    with_zeros = np.array([0.1, 0.0, -0.1, 0.0, 0.1, -0.1, 0.0, 0.1, -0.1, 0.1, 0.0])
    assert runs_z(with_zeros) == runs_z(with_zeros[with_zeros != 0.0])


def test_runs_z_of_one_sign_is_minus_infinity_from_ten_values_and_zero_below():
    assert runs_z(np.full(10, 0.01)) == -math.inf
    assert runs_z(np.full(9, -0.01)) == 0.0
    assert runs_z(np.zeros(20)) == 0.0


def longest_run_reference(values: np.ndarray) -> np.ndarray:
    """The first longest stretch of equal np.sign, by itertools.groupby."""
    best_start, best_length, start = 0, 0, 0
    for _, group in itertools.groupby(np.sign(values)):
        length = len(list(group))
        if length > best_length:
            best_start, best_length = start, length
        start += length
    mask = np.zeros(values.size, dtype=bool)
    mask[best_start : best_start + best_length] = True
    return mask


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, st.integers(0, 40), elements=st.sampled_from([-0.2, -0.01, 0.0, 0.01, 0.3])))
def test_longest_run_is_the_first_longest_stretch_of_one_sign(values):
    np.testing.assert_array_equal(longest_run(values), longest_run_reference(values))


def test_longest_run_of_an_example():
    values = np.array([0.1, -0.1, -0.2, -0.3, 0.1, 0.2, 0.3, -0.1])
    assert longest_run(values).tolist() == [False, True, True, True, False, False, False, False]
