"""A sample's uncertainty budget: what doubt each of its inputs carries (:class:`kmpipe.physics.fit_covariance.Doubts`)
and the covariance of its fitted K and S (:func:`kmpipe.physics.fit_covariance.budget`), for the fit stage to write
into MATERIAL.json and for validation to carry to the rendered colour.

The doubts, each a standard uncertainty (k = 1):

- reading noise: the spread of a reading's repeats, or its roughness, floored at ``MIN_NOISE``
  (:func:`kmpipe.validation.noise.noise_map`, as validation uses it); the manifest's ``[fit] noise`` wins when given;
- each bare backing: its own roughness (one reading of a card);
- film thickness: the manifest's ``"30 um +- 2 um"``; films of one nominal thickness are one drawdown (the same film
  over the black and the white half of a chart), so they share one thickness error;
- the white standard: ``white.uncertainty`` or the default for its kind of certificate, relative to its reflectance
  (:attr:`kmpipe.formats.sample.Sample.white_u`).
"""

from __future__ import annotations

import numpy as np

from kmpipe.formats.sample import Sample
from kmpipe.physics.fit_covariance import Budget, Doubts, budget
from kmpipe.validation.noise import MIN_NOISE, noise_map, roughness_noise


def drawdowns(sample: Sample) -> tuple[np.ndarray, tuple[str, ...]]:
    """Index (m,) of each measurement's drawdown (-1 for a masstone) and the drawdowns' names (``30 um``)."""
    names: list[float] = []
    index = np.full(len(sample.measurements), -1)
    for i, m in enumerate(sample.measurements):
        if m.role == "film":
            if m.thickness_mm not in names:
                names.append(m.thickness_mm)
            index[i] = names.index(m.thickness_mm)
    return index, tuple(f"{x * 1000:g} um" for x in names)


def backing_readings(sample: Sample) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """The backings' names, readings (B, n) and index (m,) of the backing under each measurement (-1: none)."""
    names = tuple(sample.backings)
    readings = np.array([sample.backings[b] for b in names]) if names else np.zeros((0, sample.readings.shape[1]))
    index = np.array([names.index(m.over) if m.over is not None else -1 for m in sample.measurements])
    return names, readings, index


def sample_doubts(sample: Sample, noise: float | None = None) -> Doubts:
    """The doubts of a sample's inputs (module docstring); ``noise``: the readings' noise when given."""
    from kmpipe.validation.material import repeat_groups

    if noise is not None:
        sigma = np.full(sample.readings.shape, float(noise))
    else:
        sigma, _ = noise_map(sample.readings, repeat_groups(sample).values())
    names, readings, index = backing_readings(sample)
    backing_sigma = np.maximum(roughness_noise(readings), MIN_NOISE) if len(names) else readings
    drawdown, drawdown_names = drawdowns(sample)
    return Doubts(
        sigma=sigma,
        thickness_u=np.array([m.thickness_u_mm for m in sample.measurements]),
        drawdown=drawdown,
        backing=index,
        backing_readings=readings,
        backing_sigma=backing_sigma,
        backing_names=names,
        white_u=sample.white_u,
        drawdown_names=drawdown_names,
    )


def sample_budget(
    sample: Sample,
    K: np.ndarray,
    S: np.ndarray,
    *,
    saunderson=None,
    smoothness: float = 0.0,
    penalty_scales: tuple[float, float] = (1.0, 1.0),
    noise: float | None = None,
) -> Budget:
    """The budget of K, S fitted to ``sample`` with the fit's settings."""
    doubts = sample_doubts(sample, noise)
    G = np.array([np.minimum(sample.background_of(m), 1.0) for m in sample.measurements])
    return budget(K, S, sample.thickness_mm, G, np.minimum(sample.readings, 1.0), doubts, saunderson=saunderson,
                  smoothness=smoothness, penalty_scales=penalty_scales)  # fmt: skip
