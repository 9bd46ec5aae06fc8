"""Saunderson correction for reflection at the sample's surface (Saunderson 1942).

A measured reflectance R_m includes light reflected at the air-film interface (k1, external, for
collimated light ~ ((n - 1)/(n + 1))^2 ~ 0.04 for n ~ 1.5) and light trapped by internal reflection
(k2, for diffuse light from inside, ~0.4-0.65). The KM reflectance R is the body reflectance beneath
the surface. For specular-excluded geometry pass k1 = 0. Arrays of any broadcastable shape.
"""

from __future__ import annotations

import numpy as np


def saunderson_forward(R, k1: float, k2: float) -> np.ndarray:
    """Measured reflectance from KM reflectance: R_m = k1 + (1 - k1)(1 - k2) R / (1 - k2 R).

    >>> float(saunderson_forward(0.0, 0.04, 0.6))  # a black body still reflects its surface's k1
    0.04
    >>> round(float(saunderson_inverse(saunderson_forward(0.5, 0.04, 0.6), 0.04, 0.6)), 12)
    0.5
    """
    R = np.asarray(R, dtype=np.float64)
    return k1 + (1.0 - k1) * (1.0 - k2) * R / (1.0 - k2 * R)


def saunderson_inverse(R_m, k1: float, k2: float) -> np.ndarray:
    """KM reflectance from measured reflectance: R = (R_m - k1) / (1 - k1 - k2 + k2 R_m).

    >>> float(saunderson_forward(0.0, 0.04, 0.6))  # a black body still reflects its surface's k1
    0.04
    >>> round(float(saunderson_inverse(saunderson_forward(0.5, 0.04, 0.6), 0.04, 0.6)), 12)
    0.5
    """
    R_m = np.asarray(R_m, dtype=np.float64)
    return (R_m - k1) / (1.0 - k1 - k2 + k2 * R_m)


def saunderson_slope(R, k1: float, k2: float) -> np.ndarray:
    """dR_m / dR = (1 - k1)(1 - k2) / (1 - k2 R)^2, for least-squares Jacobians."""
    R = np.asarray(R, dtype=np.float64)
    return (1.0 - k1) * (1.0 - k2) / (1.0 - k2 * R) ** 2


def check_constants(k1: float, k2: float) -> None:
    """Refuse constants that make the correction meaningless: 0 <= k1 < 1, 0 <= k2 < 1."""
    if not (0.0 <= k1 < 1.0 and 0.0 <= k2 < 1.0):
        raise ValueError(f"Saunderson constants must satisfy 0 <= k1 < 1 and 0 <= k2 < 1, got k1={k1}, k2={k2}")
