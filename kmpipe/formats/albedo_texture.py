"""Albedo textures: a substrate (skin) whose colour varies over the mesh's uv, kept spectral.

An albedo texture gives the substrate's linear RGB albedo A(uv) in the working space
(:mod:`kmpipe.physics.optical_tables`).
Rendering composes films per wavelength or band, so each texel needs a reflectance spectrum. It is built from the
substrate's measured spectrum S(l) split into three basis spectra, S_c(l) = S(l) B_c(l) with
B_c(l) = max(W_c(l), 0) / sum_c' max(W_c'(l), 0) (W the working-space weights: B_c is the share of channel c at each
wavelength, a partition of unity), mixed with weights k(uv):

    R(l, uv) = sum_c k_c(uv) S_c(l),   k(uv) = A(uv) M^-1,   M[c, c'] = RGB c' of S_c

so the bare substrate renders exactly the texture's colour, and a texel the colour of S gets S itself (k = 1, 1, 1).
Where a texel's colour lies far from S the spectrum is a guess (three smooth pieces of S), like any upsampling.
"""

from __future__ import annotations

import numpy as np

from kmpipe.physics.optical_tables import WorkingSpace


def basis_spectra(substrate: np.ndarray, space: WorkingSpace) -> np.ndarray:
    """The three basis spectra S_c(l), shape (3, n_wavelengths), of a substrate spectrum on the space's grid."""
    positive = np.clip(space.matrix, 0.0, None)
    total = positive.sum(axis=1, keepdims=True)
    shares = np.divide(positive, total, out=np.full_like(positive, 1.0 / 3.0), where=total > 0.0)
    return (np.asarray(substrate, dtype=float)[:, None] * shares).T


def texture_weights(albedo_rgb: np.ndarray, basis: np.ndarray, space: WorkingSpace) -> np.ndarray:
    """Weights k (..., 3) that make the mix of ``basis`` render as ``albedo_rgb`` (..., 3) in the working space."""
    mix = basis @ space.matrix  # row c: the RGB of basis spectrum c
    if abs(np.linalg.det(mix)) < 1e-12:
        raise ValueError("the substrate spectrum is (nearly) black in some channel: an albedo texture cannot tint it")
    return np.asarray(albedo_rgb, dtype=float) @ np.linalg.inv(mix)
