"""Compiled inner loops of the closed-form inversions' regular paths (:mod:`kmpipe.physics.inversion`).

Each inversion's common case is a few dozen arithmetic operations per value and one transcendental function. In
numpy that is some 60 passes over a block; here the arithmetic is fused into two loops that LLVM vectorizes (numba,
compiled once per machine and cached on disk), and the transcendental stays numpy's own SIMD ``arctanh`` or
``log1p`` over the block between them. The arithmetic is the numpy version's, operation for operation and in the
same order: no fast-math, no contraction into fused multiply-adds, so every value is the one numpy computes.

Arrays are C-contiguous 2-D blocks (rows of wavelengths or channels) of float64; ``hard`` marks the elements the
regular path cannot do, which the caller redoes on its careful path.
"""

from __future__ import annotations

import numba
import numpy as np

_FLOATS = numba.types.Array(numba.float64, 2, "C")
_READINGS = numba.types.Array(numba.float64, 2, "C", readonly=True)
_FLAGS = numba.types.Array(numba.uint8, 2, "C")
_MASK = numba.types.Array(numba.boolean, 2, "C")
#: Without Python's division checks: a division by zero gives inf or nan, as in numpy with its errors ignored.
_OPTIONS = {"nogil": True, "error_model": "numpy"}


def _compiled(signature):
    """Compile a loop for ``signature`` when this module is imported, kept on disk for the next process: in
    __pycache__ beside this file, else in numba's per-user cache (NUMBA_CACHE_DIR chooses another). Where neither is
    writable (a read-only install and home), each process compiles it anew (about a second)."""

    def compile_(function):
        try:
            return numba.njit(signature, cache=True, **_OPTIONS)(function)
        except RuntimeError:  # numba: "cannot cache function ...: no locator available"
            return numba.njit(signature, **_OPTIONS)(function)

    return compile_


@_compiled(
    numba.void(_READINGS, _READINGS, _READINGS, _READINGS, numba.float64, numba.uint8, numba.uint8, numba.float64,
               numba.float64, _FLOATS, _FLOATS, _FLOATS, _FLOATS, _FLAGS, _MASK),
)  # fmt: skip
def black_white_system(Rb, Rw, Gb, Gw, tolerance, at_bound, out_of_range, tiny, max_ks, KX, SX, ks, w, flags, hard):
    """The 2 x 2 system of :func:`kmpipe.physics.inversion.black_white` by Cramer's rule, per element.

    With s = R + G, d = R - G, c = (1 - R)(1 - G) for the film over the black (b) and white (w) backings:
    D = s_w d_b - s_b d_w, N_u = c_w d_b - c_b d_w, N_y = s_w c_b - s_b c_w. Writes K/S = N_u / D (capped at
    ``max_ks``), N_u / N_y and D / N_y into ``KX`` and ``SX`` (K X and S X once multiplied by artanh(w) / w),
    w = sqrt(N_u (N_u + 2 D)) / N_y (at least ``tiny``), the flags (``at_bound`` where K/S < 0 within rounding
    to -``tolerance``, ``out_of_range`` below; N_u is then taken as 0) and ``hard``: D not clearly positive, N_y <= b D
    (no finite positive S X) or the two readings within ``tolerance`` (opaque).
    """
    for i in range(Rb.shape[0]):
        for j in range(Rb.shape[1]):
            rb, rw, gb, gw = Rb[i, j], Rw[i, j], Gb[i, j], Gw[i, j]
            s_w, d_b, s_b, d_w = rw + gw, rb - gb, rb + gb, rw - gw
            first = s_w * d_b
            D = first - s_b * d_w
            c_b = (1.0 - rb) * (1.0 - gb)
            c_w = (1.0 - rw) * (1.0 - gw)
            Nu = c_w * d_b - c_b * d_w
            Ny = s_w * c_b - s_b * c_w
            flag = np.uint8(0)
            if Nu < -1e-12 * D:  # beyond rounding: the readings ask for K < 0
                flag = out_of_range if Nu < -tolerance * D else at_bound
            flags[i, j] = flag
            if Nu < 0.0:
                Nu = 0.0
            b_D = np.sqrt((2.0 * D + Nu) * Nu)  # b |D|
            ratio = b_D / Ny
            w[i, j] = tiny if ratio < tiny else ratio  # artanh(w) = w exactly at the smallest normal float: the limit
            ratio = Nu / D
            ks[i, j] = max_ks if ratio > max_ks else ratio
            KX[i, j] = Nu / Ny
            SX[i, j] = D / Ny
            hard[i, j] = not (D > 1e-12 * abs(first)) or not (Ny > b_D) or abs(rw - rb) <= tolerance * rw


@_compiled(numba.void(_READINGS, _READINGS, _READINGS, _FLOATS, _FLOATS, _MASK))
def black_white_scale(artanh_w, w, X, K, S, hard):
    """K = (N_u / N_y) artanh(w) / w / X and S = (D / N_y) artanh(w) / w / X in place; ``hard`` where K + S is not
    finite (a thickness near 0)."""
    for i in range(K.shape[0]):
        for j in range(K.shape[1]):
            factor = artanh_w[i, j] / w[i, j] / X[i, j]
            k = K[i, j] * factor
            s = S[i, j] * factor
            K[i, j], S[i, j] = k, s
            hard[i, j] |= not (k + s < np.inf)


@_compiled(
    numba.void(_READINGS, _READINGS, _READINGS, _READINGS, numba.float64, numba.float64, _FLOATS, _FLOATS, _FLOATS,
               _MASK),
)  # fmt: skip
def two_constant_terms(R_inf, R, R_g, X, tolerance, min_reflectance, ks, delta, two_b_X, hard):
    """The terms of :func:`kmpipe.physics.inversion.two_constant`'s S X = log1p(delta) / (1/R_inf - R_inf), per element.

    K/S = (1 - R_inf)^2 / (2 R_inf) into ``ks``; delta = (1/R_inf - R_inf)(R - R_g) / ((R_inf - R)(1/R_inf - R_g))
    into ``delta``; (1/R_inf - R_inf) X into ``two_b_X``; ``hard`` where the film reads within ``tolerance`` of
    its masstone (opaque) or the masstone of the background (no contrast), delta < 1e-4 (log1p(delta) / delta needs
    its series) or R_inf lies outside [``min_reflectance``, 1].
    """
    for i in range(R_inf.shape[0]):
        for j in range(R_inf.shape[1]):
            r_inf, r, r_g = R_inf[i, j], R[i, j], R_g[i, j]
            inverse = 1.0 / r_inf
            two_b = inverse - r_inf  # (1 - R_inf)(1 + R_inf) / R_inf
            lightness = 1.0 - r_inf
            ks[i, j] = lightness * lightness * inverse * 0.5
            limit = tolerance * r_inf
            gap = r_inf - r
            d = (r - r_g) / ((inverse - r_g) * gap) * two_b
            delta[i, j] = d
            two_b_X[i, j] = two_b * X[i, j]
            hard[i, j] = (
                abs(gap) <= limit
                or abs(r_inf - r_g) <= limit
                or not (d >= 1e-4 and r_inf >= min_reflectance and r_inf <= 1.0)
            )


@_compiled(numba.void(_READINGS, _READINGS, _FLOATS, _FLOATS, _MASK))
def two_constant_scale(two_b_X, ks, S, K, hard):
    """S = log1p(delta) / ((1/R_inf - R_inf) X) in place (``S`` holds log1p(delta)), K = S K/S; ``hard`` where K is
    not finite (S overflowed: a thickness near 0)."""
    for i in range(S.shape[0]):
        for j in range(S.shape[1]):
            s = S[i, j] / two_b_X[i, j]
            k = s * ks[i, j]
            S[i, j], K[i, j] = s, k
            hard[i, j] |= not (k < np.inf)
