"""Colour computed by colour-science alone, as an independent reference for kmpipe's colorimetry in tests."""

from __future__ import annotations

import colour
import numpy as np


def colour_lab(reflectance, wavelengths, illuminant: str) -> np.ndarray:
    """CIELAB of a reflectance spectrum under a CIE illuminant relative to its perfect white (CIE 1931 2 degree
    observer), by ``colour.sd_to_XYZ`` (integration) and ``colour.XYZ_to_Lab``."""
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    light = colour.SDS_ILLUMINANTS[illuminant]
    sd = colour.SpectralDistribution(dict(zip(np.asarray(wavelengths, float), reflectance, strict=True)))
    XYZ = colour.sd_to_XYZ(sd, cmfs, light, method="Integration")
    white = colour.sd_to_XYZ(colour.sd_ones(sd.shape), cmfs, light, method="Integration")
    return colour.XYZ_to_Lab(XYZ / 100.0, colour.XYZ_to_xy(white / 100.0))
