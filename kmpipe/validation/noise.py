"""Noise statistics of spectral readings, model-free: what the validation checks compare differences against.

Pure numpy on arrays of readings (m readings x n wavelengths or channels, reflectance); nothing here knows
samples, materials or files.

- :func:`roughness_noise`: the noise of a single reading from its own roughness (local second differences).
- :func:`noise_map`: the noise of every reading: the spread of its repeats where it has some, its roughness
  otherwise, floored at :data:`MIN_NOISE`.
- :func:`repeat_spread`: one number for the spread of a group of repeats.
- :func:`runs_z` and :func:`longest_run`: the Wald-Wolfowitz runs test on the signs of residuals, and the
  stretch of one sign it points at.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence

import numpy as np

#: Smallest noise level (reflectance) the checks assume: below it, differences are rounding, not readings.
MIN_NOISE = 2e-4

#: Wavelengths (grid points) over which the noise level is taken as locally constant.
NOISE_WINDOW = 11


def windowed(values: np.ndarray, statistic: Callable, window: int = NOISE_WINDOW, offset: int = 0) -> np.ndarray:
    """``statistic`` (e.g. ``np.median``) of (m, k) ``values`` over windows of ``window`` points along the last
    axis, one per output point: centred on it, shifted inwards at the ends (never padded, which would let one value
    stand for the whole window there). Value j belongs to output point j + ``offset``; the output is (m, k + 2
    ``offset``)."""
    width = min(window, values.shape[1])
    per_start = statistic(np.lib.stride_tricks.sliding_window_view(values, width, axis=1), axis=-1)
    n = values.shape[1] + 2 * offset
    start = np.clip(np.arange(n) - offset - width // 2, 0, per_start.shape[1] - 1)
    return per_start[:, start]


def roughness_noise(readings: np.ndarray, window: int = NOISE_WINDOW) -> np.ndarray:
    """Noise (standard deviation, reflectance) of each reading at each wavelength (m, n), from the reading's own
    roughness.

    For white noise of standard deviation sigma, d2 = y[i-1] - 2 y[i] + y[i+1] has standard deviation
    sqrt(6) sigma, so sigma = median(|d2|) / 0.6745 / sqrt(6) over a window of ``window`` points (0.6745: the
    median of |z| for a standard normal z). The median estimates it robustly (the few large second differences at
    the steep edge of a smooth spectrum do not count) and locally, so noise that grows with the signal, as a
    spectroradiometer's does, is followed across the spectrum. Fewer than 3 points: zeros.
    """
    m, n = readings.shape
    if n < 3:
        return np.zeros((m, n))
    d2 = np.abs(readings[:, 2:] - 2.0 * readings[:, 1:-1] + readings[:, :-2])  # centred on points 1 .. n-2
    return windowed(d2, np.median, window, offset=1) / 0.6745 / math.sqrt(6.0)


def noise_map(readings: np.ndarray, groups: Iterable[Sequence[int]]) -> tuple[np.ndarray, str]:
    """Noise (standard deviation, reflectance) of every reading at every wavelength (m, n), and where it came from.

    ``groups`` lists the rows of ``readings`` that repeat one another. A reading in a group of two or more gets
    sqrt(mean over a window of `NOISE_WINDOW` points of the repeats' variance (ddof 1)); any other reading its
    :func:`roughness_noise`. Never from a fit, whose residuals a faulty measurement would inflate. Floored at
    `MIN_NOISE` (the source then says so).
    """
    sigma = roughness_noise(readings)
    repeated = 0
    for members in groups:
        rows = list(members)
        if len(rows) > 1:
            sd = readings[rows].std(axis=0, ddof=1)
            sigma[rows] = np.sqrt(windowed(sd[None, :] ** 2, np.mean))[0]
            repeated += len(rows)
    total = readings.shape[0]
    floor = f"; floored at {MIN_NOISE:g}" if np.median(sigma) < MIN_NOISE else ""
    if repeated == total:
        source = "spread of repeats"
    elif repeated:
        source = "spread of repeats; roughness of single readings"
    else:
        source = "roughness of the readings (local second differences)"
    return np.maximum(sigma, MIN_NOISE), source + floor


def repeat_spread(repeats: np.ndarray) -> float:
    """Spread of (k, n) repeated readings, k >= 2: sqrt(mean over wavelength of the per-wavelength variance, ddof 1),
    i.e. the RMS over wavelength of their standard deviation (reflectance)."""
    sd = repeats.std(axis=0, ddof=1)
    return float(np.sqrt(np.mean(sd**2)))


def runs_z(residuals: np.ndarray) -> float:
    """z of the Wald-Wolfowitz runs test on the signs of ``residuals`` (zeros left out); negative: too few sign
    changes for noise.

    With n1 positive and n2 negative values (n = n1 + n2) and R runs of one sign,
    z = (R - mu) / sqrt(var), mu = 1 + 2 n1 n2 / n, var = 2 n1 n2 (2 n1 n2 - n) / (n^2 (n - 1)).
    All of one sign: -inf for 10 or more values (as structured as residuals get), 0 for fewer; var 0: 0.
    """
    signs = residuals[residuals != 0.0] > 0.0
    n = signs.size
    n_pos = int(signs.sum())
    n_neg = n - n_pos
    if n_pos == 0 or n_neg == 0:
        return -math.inf if n >= 10 else 0.0
    runs = 1 + int(np.count_nonzero(signs[1:] != signs[:-1]))
    expected = 1.0 + 2.0 * n_pos * n_neg / n
    variance = 2.0 * n_pos * n_neg * (2.0 * n_pos * n_neg - n) / (n * n * (n - 1.0))
    return (runs - expected) / math.sqrt(variance) if variance > 0 else 0.0


def longest_run(residuals: np.ndarray) -> np.ndarray:
    """Mask of the longest stretch of ``residuals`` of one sign (np.sign: zeros form runs of their own); the first
    of equally long stretches."""
    signs = np.sign(residuals)
    best = (0, 0)
    start = 0
    for i in range(1, signs.size + 1):
        if i == signs.size or signs[i] != signs[start]:
            if i - start > best[1] - best[0]:
                best = (start, i)
            start = i
    mask = np.zeros(signs.size, dtype=bool)
    mask[best[0] : best[1]] = True
    return mask
