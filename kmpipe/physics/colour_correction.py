"""A camera RGB -> CIE XYZ matrix fitted to a photographed 24-patch ColorChecker.

The reference is colour-science's 'ColorChecker N Ohta' set: 24 spectral reflectances (380-780 nm, 5 nm) of the
classic chart, in the standard order (dark skin ... black). Their XYZ under the chosen CIE illuminant and observer
(:func:`kmpipe.physics.colorimetry.reflectance_to_XYZ`, Y = 100 for the perfect white, 5 nm grid) are the targets.

The fit (:func:`fit_camera_to_XYZ`) is ordinary (optionally weighted) linear least squares for the 3 x 3 matrix M
with XYZ ~= camera_rgb @ M.T, then scaled by one factor so that the white patch's fitted Y equals its reference Y: the
camera's exposure and the paper-to-chart light level drop out, and the matrix gives XYZ on the reference scale. The
fit quality is reported as CIE Delta E 2000 (:func:`kmpipe.physics.colorimetry.delta_E_2000`) per patch between the
fitted
and the reference colours, CIELAB relative to the perfect white under the same illuminant.

Why not ``cv2.ccm.ColorCorrectionModel`` (opencv-contrib 5.x, which can minimize Delta E 2000 directly): it expects
sRGB-like input in [0, 1] with a linearization step and reference data of its own (measured Lab under D50), while
here the references are spectral, the illuminant is the caller's, and camera values are already linear. A linear
least-squares fit is exact for a camera whose sensitivities are linear mixtures of the CMFs (the Luther condition)
and, for real cameras, within a few tenths of a Delta E unit of a Delta-E-optimal matrix on this chart.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import colour
import numpy as np

from kmpipe.physics.colorimetry import delta_E_2000, reflectance_to_XYZ, white_XYZ

__all__ = ["CHART", "CameraMatrix", "fit_camera_to_XYZ", "reference_XYZ"]

CHART = "ColorChecker N Ohta"
"""colour-science's set of ColorChecker reflectance spectra used as the reference."""

_GRID = np.arange(380.0, 781.0, 5.0)  # nm


def reference_XYZ(illuminant: str = "D65", observer: str = "2") -> np.ndarray:
    """(24, 3) XYZ (perfect white Y = 100) of the ColorChecker's reference spectra, standard order, on a 5 nm grid."""
    sds = colour.SDS_COLOURCHECKERS[CHART]
    shape = colour.SpectralShape(_GRID[0], _GRID[-1], 5.0)
    spectra = np.array([sd.copy().align(shape).values for sd in sds.values()])
    return reflectance_to_XYZ(spectra, _GRID, illuminant, observer)


def _Lab(XYZ: np.ndarray, illuminant: str, observer: str) -> np.ndarray:
    white = white_XYZ(_GRID, illuminant, observer) / 100.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", colour.utilities.ColourWarning)
        return colour.XYZ_to_Lab(np.asarray(XYZ) / 100.0, colour.XYZ_to_xy(white))


@dataclass(frozen=True, eq=False)
class CameraMatrix:
    """A fitted camera RGB -> XYZ matrix and how well it fits the chart.

    ``matrix`` (3, 3): XYZ = camera_rgb @ matrix.T, XYZ on the reference scale (perfect white Y = 100) for camera RGB
    in the units it was fitted on. ``delta_E`` (24,): CIE Delta E 2000 of each patch, fitted vs reference (excluded
    patches included, for information); ``mean_delta_E``, ``max_delta_E``: over the patches used in the fit;
    ``used`` (24,) bool: patches that entered the fit; ``excluded``: their indices left out (e.g. clipped);
    ``white_patch``: index (0-23) of the patch whose Y set the scale; ``illuminant``, ``observer``: of the reference.
    """

    matrix: np.ndarray
    delta_E: np.ndarray
    mean_delta_E: float
    max_delta_E: float
    used: np.ndarray
    excluded: tuple[int, ...]
    white_patch: int
    illuminant: str
    observer: str

    def apply(self, rgb) -> np.ndarray:
        """XYZ (..., 3) (perfect white Y = 100) of camera RGB (..., 3), in the camera units of the fit."""
        rgb = np.asarray(rgb, dtype=np.float64)
        if rgb.shape[-1] != 3:
            raise ValueError(f"camera RGB must have 3 channels last, got shape {rgb.shape}")
        return rgb @ self.matrix.T


def fit_camera_to_XYZ(
    camera_rgb,
    *,
    illuminant: str = "D65",
    observer: str = "2",
    white_patch: int = 19,
    weights: Sequence[float] | np.ndarray | None = None,
    clipped_fraction: Sequence[float] | np.ndarray | None = None,
) -> CameraMatrix:
    """Fit the 3 x 3 camera RGB -> XYZ matrix to a photographed ColorChecker.

    Parameters
    ----------
    camera_rgb
        (24, 3) linear camera RGB of the patches in the standard order (dark skin ... black), e.g.
        ``ColorCheckerSample.mean``, flat-fielded if the light varies across the chart. Any scale (exposure).
    illuminant, observer
        Of the reference XYZ (:func:`reference_XYZ`) and of the CIELAB used for Delta E.
    white_patch
        X-Rite patch **number** (1-24) that sets the scale: 19 is white 9.5. If it is excluded, the brightest neutral
        patch used (numbers 20-24) sets it instead.
    weights
        Optional (24,) non-negative least-squares weights (0 leaves a patch out).
    clipped_fraction
        Optional (24,) fraction of each patch's pixels clipped (``ColorCheckerSample.clipped_fraction``): patches with
        any clipped pixel are left out and listed in ``excluded``.

    Raises ValueError for a wrong shape, non-finite values, or fewer than 6 patches left to fit (3 x 3 unknowns per
    row need at least 3; 6 keeps the fit from following the noise of a few patches).
    """
    rgb = np.asarray(camera_rgb, dtype=np.float64)
    if rgb.shape != (24, 3):
        raise ValueError(f"camera_rgb must be (24, 3) (the 24 patches, standard order), got shape {rgb.shape}")
    if not np.all(np.isfinite(rgb)):
        raise ValueError("camera_rgb has non-finite values")
    if not 1 <= white_patch <= 24:
        raise ValueError(f"white_patch is an X-Rite patch number, 1 to 24; got {white_patch!r}")
    w = np.ones(24) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (24,) or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be 24 finite numbers >= 0")
    used = w > 0
    if clipped_fraction is not None:
        clipped = np.asarray(clipped_fraction, dtype=np.float64)
        if clipped.shape != (24,):
            raise ValueError(f"clipped_fraction must be (24,), got shape {clipped.shape}")
        used &= ~(clipped > 0)
    if used.sum() < 6:
        raise ValueError(f"only {int(used.sum())} patches left to fit (clipped or weighted out); at least 6 are needed")

    target = reference_XYZ(illuminant, observer)
    root_w = np.sqrt(w[used])[:, None]
    solution, *_ = np.linalg.lstsq(rgb[used] * root_w, target[used] * root_w, rcond=None)
    matrix = solution.T  # XYZ = rgb @ matrix.T

    white = white_patch - 1
    if not used[white]:
        neutrals = [i for i in range(18, 24) if used[i] and i > white]
        if not neutrals:
            raise ValueError("no neutral patch left to set the scale (white and greys all excluded)")
        white = neutrals[0]
    fitted_Y = float(rgb[white] @ matrix[1])
    if not fitted_Y > 0:
        raise ValueError(f"patch {white + 1} fits a Y of {fitted_Y:g}: the camera data do not look like a ColorChecker")
    matrix = matrix * (target[white, 1] / fitted_Y)

    dE = delta_E_2000(_Lab(rgb @ matrix.T, illuminant, observer), _Lab(target, illuminant, observer))
    return CameraMatrix(
        matrix=matrix,
        delta_E=dE,
        mean_delta_E=float(dE[used].mean()),
        max_delta_E=float(dE[used].max()),
        used=used,
        excluded=tuple(int(i) for i in np.flatnonzero(~used)),
        white_patch=white,
        illuminant=illuminant,
        observer=observer,
    )
