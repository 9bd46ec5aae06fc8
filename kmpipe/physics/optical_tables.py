"""Optical tables for rendering Kubelka-Munk films: R0 and T per thickness, in a linear RGB working space.

Colour (method notes, "Colour"): reflectance spectra R(l) under the scene illuminant S(l) become CIE XYZ
(colour-science integration on the spectra's own grid, the same as :mod:`kmpipe.physics.colorimetry`), are adapted
by CAT02 from the white of the illuminant to D65 and are expressed in linear sRGB / Rec.709 (not the thesis's
CIE RGB under illuminant E, thesis eq. A.4, which is no display space). All of this is linear in R, so it is one
weight matrix W (n_wavelengths x 3): linear RGB = R(l) @ W.

Render modes (issue "The bundled OSMesa renderer", part 2):

- ``rgb``: each layer's R0 and T reduced to RGB by W, layers composited per RGB channel (thesis eq. 3.14, bottom-up).
  Reducing R0 and T separately and compositing afterwards is the approximation of this mode: the KM
  composition is non-linear, so it does not commute with the spectral integral.
- ``bands:N``: R0 and T averaged over N contiguous spectral bands, composited per band, then band -> RGB.
- ``exact``: R0 and T kept per wavelength, composited spectrally, then W.

Lengths in mm, K and S in 1/mm, reflectances and transmittances dimensionless in [0, 1].
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import colour
import numpy as np

from kmpipe.physics.colorimetry import reflectance_to_XYZ
from kmpipe.physics.kubelka_munk import film_reflectance_transmittance, stack_over_substrate


class FilmCoefficients(Protocol):
    """What the tables need of a material (``kmpipe.formats.material.Material`` qualifies): K, S per mm on a grid in
    nm."""

    name: str
    wavelengths: np.ndarray
    K: np.ndarray
    S: np.ndarray


@dataclass(frozen=True)
class WorkingSpace:
    """Linear sRGB (Rec.709 primaries, D65 white) seen from spectra under a scene illuminant.

    Attributes
    ----------
    matrix
        W, shape (n_wavelengths, 3): linear RGB = R(l) @ W. Built as W = W_XYZ @ A with
        W_XYZ[l] = k S(l) (xbar, ybar, zbar)(l) dl, k = 1 / sum S ybar dl (so the perfect white has Y = 1), and
        A (3 x 3) = CAT02 adaptation from the illuminant's white (its XYZ on this grid) to D65, then colour-science's
        XYZ -> sRGB matrix, then a per-channel scale so that the perfect white R(l) = 1 maps to exactly (1, 1, 1).
        The scale only removes the rounding of the 4-decimal IEC 61966-2-1 matrix (white would be 1 +- 1.6e-4).
    rgb_to_XYZ
        inv(A): XYZ under the scene illuminant (white Y = 1) = RGB @ rgb_to_XYZ.
    white_XYZ
        XYZ of the perfect white under the scene illuminant on this grid (Y = 1); (1, 1, 1) @ rgb_to_XYZ.
    """

    wavelengths: np.ndarray
    illuminant: str
    observer: str
    matrix: np.ndarray
    rgb_to_XYZ: np.ndarray
    white_XYZ: np.ndarray

    def to_Lab(self, rgb) -> np.ndarray:
        """CIELAB under the scene illuminant (reference white: the perfect white) of linear working-space RGB."""
        XYZ = np.asarray(rgb, dtype=np.float64) @ self.rgb_to_XYZ
        return colour.XYZ_to_Lab(XYZ, colour.XYZ_to_xy(self.white_XYZ))


def working_space(wavelengths, illuminant: str = "D65", observer: str = "2") -> WorkingSpace:
    """The :class:`WorkingSpace` of spectra sampled at ``wavelengths`` (nm) under ``illuminant``."""
    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    # XYZ is linear in R: the XYZ of the unit impulses are the rows of W_XYZ.
    W_XYZ = reflectance_to_XYZ(np.eye(len(wavelengths)), wavelengths, illuminant, observer) / 100.0
    white = W_XYZ.sum(axis=0)

    def to_rgb(XYZ):
        return colour.XYZ_to_RGB(
            XYZ,
            colour.RGB_COLOURSPACES["sRGB"],
            illuminant=colour.XYZ_to_xy(white),
            chromatic_adaptation_transform="CAT02",
        )

    A = to_rgb(np.eye(3))
    A = A / (white @ A)  # per-channel scale: the perfect white -> (1, 1, 1) exactly
    return WorkingSpace(wavelengths, illuminant, observer, W_XYZ @ A, np.linalg.inv(A), white)


def working_space_matrix(wavelengths, illuminant: str = "D65", observer: str = "2") -> np.ndarray:
    """W (n_wavelengths x 3): linear sRGB = R(l) @ W under ``illuminant``, CAT02-adapted; white -> (1, 1, 1).

    See :class:`WorkingSpace` for the construction.
    """
    return working_space(wavelengths, illuminant, observer).matrix


@dataclass(frozen=True)
class BandPartition:
    """N contiguous spectral bands and the weights that go with them.

    Attributes
    ----------
    labels
        Band index of each wavelength, shape (n_wavelengths,), non-decreasing, every band non-empty.
    averaging
        Shape (n_wavelengths, N), columns summing to 1: band value R_b = R(l) @ averaging, the average of R over
        band b weighted by e(l) = S(l) (xbar + ybar + zbar)(l), the illuminant-weighted colour-matching energy.
    to_rgb
        Shape (N, 3): B_b = sum of the rows of W over band b; linear RGB = R_b @ to_rgb. Exact for a spectrum
        that is constant within each band, and the perfect white still maps to (1, 1, 1).
    """

    labels: np.ndarray
    averaging: np.ndarray
    to_rgb: np.ndarray

    @property
    def n_bands(self) -> int:
        return self.to_rgb.shape[0]


def band_partition(
    wavelengths, n_bands: int, illuminant: str = "D65", observer: str = "2", space: WorkingSpace | None = None
) -> BandPartition:
    """Split the grid into ``n_bands`` contiguous bands of (about) equal energy e(l) = S(l) (xbar + ybar + zbar)(l).

    Equal energy rather than equal width: bands are narrow where the scene light and the eye's three responses
    carry colour and wide in the tails (below 420 nm, above 680 nm) where they carry little. Band b starts at
    the first wavelength where the cumulative energy reaches b / N of the total (moved so that no band is empty).
    """
    space = space if space is not None else working_space(wavelengths, illuminant, observer)
    n = len(space.wavelengths)
    if not 1 <= n_bands <= n:
        raise ValueError(f"n_bands must lie in 1..{n} (the number of wavelengths), got {n_bands}")
    # Rows of W_XYZ = W @ inv(A): e(l) = X + Y + Z of the unit impulse at l, >= 0.
    energy = np.clip((space.matrix @ space.rgb_to_XYZ).sum(axis=1), 0.0, None)
    cumulative = np.cumsum(energy)
    starts = np.searchsorted(cumulative, cumulative[-1] * np.arange(1, n_bands) / n_bands, side="left") + 1
    starts = np.concatenate([[0], starts])
    for b in range(1, n_bands):  # strictly increasing, and leave room for the bands after b
        starts[b] = min(max(starts[b], starts[b - 1] + 1), n - (n_bands - b))
    labels = np.searchsorted(starts, np.arange(n), side="right") - 1
    member = labels[:, None] == np.arange(n_bands)[None, :]
    weights = member * energy[:, None]
    sums = weights.sum(axis=0)
    averaging = np.where(sums > 0.0, weights / np.where(sums > 0.0, sums, 1.0), member / member.sum(axis=0))
    return BandPartition(labels, averaging, member.T.astype(np.float64) @ space.matrix)


def parse_mode(mode: str) -> tuple[str, int | None]:
    """``"rgb"`` -> ("rgb", None), ``"bands:6"`` -> ("bands", 6), ``"exact"`` -> ("exact", None)."""
    if mode in ("rgb", "exact"):
        return mode, None
    kind, _, count = mode.partition(":")
    if kind == "bands" and count.isdigit() and int(count) >= 1:
        return kind, int(count)
    raise ValueError(f"render mode must be 'rgb', 'bands:N' (N >= 1) or 'exact', got {mode!r}")


@dataclass(frozen=True)
class OpticalTable:
    """R0 and T of one material's film over a thickness axis, in the channels of one render mode.

    Attributes
    ----------
    thickness_mm
        Sorted thickness samples (mm), or None when the scene uses a single thickness (no axis).
    single_thickness_mm
        That single thickness (mm) when ``thickness_mm`` is None, else None.
    R0, T
        Shape (n_thickness, n_channels), or (n_channels,) without an axis. Channels: 3 (``rgb``: R0 @ W and
        T @ W, clipped to [0, 1] so the per-channel composition stays that of physical films), N (``bands:N``:
        band averages, see :class:`BandPartition`), or n_wavelengths (``exact``).
    """

    material: str
    mode: str
    thickness_mm: np.ndarray | None
    single_thickness_mm: float | None
    R0: np.ndarray
    T: np.ndarray
    space: WorkingSpace
    bands: BandPartition | None

    @classmethod
    def build(
        cls,
        material: FilmCoefficients,
        thicknesses_mm,
        mode: str,
        space: WorkingSpace,
        bands: BandPartition | None = None,
    ) -> OpticalTable:
        """Tabulate ``material`` at the distinct values of ``thicknesses_mm`` (mm) in ``mode``."""
        kind, n_bands = parse_mode(mode)
        if kind == "bands" and (bands is None or bands.n_bands != n_bands):
            bands = band_partition(space.wavelengths, n_bands, space=space)
        X = np.unique(np.asarray(thicknesses_mm, dtype=np.float64).ravel())
        if X.size == 0 or X[0] < 0.0:
            raise ValueError("thicknesses must be non-empty and >= 0 (mm)")
        R0, T = film_reflectance_transmittance(material.K, material.S, X[:, None])
        R0, T = (_reduce(v, kind, space, bands) for v in (R0, T))
        if X.size == 1:
            return cls(material.name, mode, None, float(X[0]), R0[0], T[0], space, bands if kind == "bands" else None)
        return cls(material.name, mode, X, None, R0, T, space, bands if kind == "bands" else None)

    @property
    def n_channels(self) -> int:
        return self.R0.shape[-1]

    def lookup(self, thickness_mm) -> tuple[np.ndarray, np.ndarray]:
        """R0 and T at ``thickness_mm`` (any shape), linearly interpolated along the axis; shape (..., n_channels).

        Exact at the samples. Without an axis only the single thickness is accepted (to 1e-12 relative).
        """
        X = np.asarray(thickness_mm, dtype=np.float64)
        if self.thickness_mm is None:
            if not np.allclose(X, self.single_thickness_mm, rtol=1e-12, atol=0.0):
                raise ValueError(f"{self.material}: table holds only {self.single_thickness_mm} mm")
            shape = (*X.shape, self.n_channels)
            return np.broadcast_to(self.R0, shape).copy(), np.broadcast_to(self.T, shape).copy()
        axis = self.thickness_mm
        if np.any(X < axis[0]) or np.any(X > axis[-1]):
            raise ValueError(f"{self.material}: thickness outside the table's {axis[0]}..{axis[-1]} mm")
        i = np.clip(np.searchsorted(axis, X, side="right") - 1, 0, axis.size - 2)
        f = ((X - axis[i]) / (axis[i + 1] - axis[i]))[..., None]
        return (1.0 - f) * self.R0[i] + f * self.R0[i + 1], (1.0 - f) * self.T[i] + f * self.T[i + 1]


def _reduce(values: np.ndarray, kind: str, space: WorkingSpace, bands: BandPartition | None) -> np.ndarray:
    """Spectra (..., n_wavelengths) -> the channels of a mode."""
    if kind == "rgb":
        return np.clip(values @ space.matrix, 0.0, 1.0)
    if kind == "bands":
        return values @ bands.averaging
    return values


def composite(tables: Sequence[OpticalTable], thicknesses, substrate, mode: str) -> np.ndarray:
    """Linear working-space RGB of a stack of films (``tables[0]`` on top) over a substrate, in ``mode``.

    The layers are composed bottom-up onto the substrate by thesis eq. 3.14
    (:func:`kmpipe.physics.kubelka_munk.stack_over_substrate`) in the mode's channels, then converted once:
    ``rgb`` per RGB channel (result as is), ``bands:N`` per band (then @ to_rgb), ``exact`` per wavelength
    (then @ W).

    Parameters
    ----------
    thicknesses
        One thickness (mm, scalar or array; arrays broadcast together) per table.
    substrate
        Spectral reflectance on the tables' grid (..., n_wavelengths), reduced like the layers; in ``rgb`` mode an
        RGB reflectance (..., 3) is also accepted and used as is.
    """
    if not tables or len(tables) != len(thicknesses):
        raise ValueError("need one thickness per table and at least one table")
    if any(t.mode != mode for t in tables):
        raise ValueError(f"every table must be in mode {mode!r}")
    kind, _ = parse_mode(mode)
    space, bands = tables[0].space, tables[0].bands
    substrate = np.asarray(substrate, dtype=np.float64)
    if substrate.shape[-1] == len(space.wavelengths):
        substrate = _reduce(substrate, kind, space, bands)
    elif not (kind == "rgb" and substrate.shape[-1] == 3):
        raise ValueError(f"substrate must be spectral ({len(space.wavelengths)} values) or, in rgb mode, RGB")
    looked_up = [table.lookup(X) for table, X in zip(tables, thicknesses, strict=True)]
    R0 = np.stack(np.broadcast_arrays(*(r for r, _ in looked_up)))
    T = np.stack(np.broadcast_arrays(*(t for _, t in looked_up)))
    R = stack_over_substrate(R0, T, substrate)
    if kind == "bands":
        return R @ bands.to_rgb
    if kind == "exact":
        return R @ space.matrix
    return R


@dataclass(frozen=True)
class Stack:
    """A stack of films in a scene: material names top first, over a spectral substrate reflectance."""

    name: str
    layers: tuple[str, ...]
    substrate: np.ndarray


def probe_thicknesses(thickness_range: tuple[float, float]) -> tuple[float, ...]:
    """The thicknesses (mm) at which a layer is checked: (lo,) for a single thickness, else (lo, mid, hi)."""
    lo, hi = (float(v) for v in thickness_range)
    if not 0.0 <= lo <= hi:
        raise ValueError(f"thickness range must satisfy 0 <= min <= max (mm), got {thickness_range}")
    return (lo,) if lo == hi else (lo, 0.5 * (lo + hi), hi)


def exact_rgb(materials: Sequence[FilmCoefficients], thicknesses, substrate, space: WorkingSpace) -> np.ndarray:
    """Reference: KM films computed per wavelength from K and S (no table), composed spectrally, then @ W."""
    return exact_stack(materials, thicknesses, substrate, space)[0]


def exact_stack(
    materials: Sequence[FilmCoefficients], thicknesses, substrate, space: WorkingSpace
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A stack (top first) composed per wavelength, in linear working-space RGB.

    Returns ``(R @ W, R_black @ W, A @ W)``: the reflectance of the films over the substrate and over a black one,
    shape (..., 3), and the spectral attenuation of a specular lobe by the films above it, for each film i
    ``A_i = prod_{j < i} T_j^2`` (1 for the top film) and last for the substrate (all films), as the RGB of white
    light so attenuated, shape (n_films + 1, ..., 3). Thicknesses (mm) broadcast together.
    """
    films = [
        film_reflectance_transmittance(m.K, m.S, np.asarray(X, dtype=np.float64)[..., None])
        for m, X in zip(materials, thicknesses, strict=True)
    ]
    R0 = np.stack(np.broadcast_arrays(*(r for r, _ in films)))
    T = np.stack(np.broadcast_arrays(*(t for _, t in films)))
    above = np.concatenate([np.ones_like(T[:1]), np.cumprod(T**2, axis=0)])
    W = space.matrix
    return stack_over_substrate(R0, T, substrate) @ W, stack_over_substrate(R0, T, 0.0) @ W, above @ W


def mode_error(
    stacks: Sequence[Stack],
    mode: str,
    materials: Mapping[str, FilmCoefficients],
    thickness_ranges: Mapping[str, tuple[float, float]],
    illuminant: str = "D65",
    observer: str = "2",
) -> np.ndarray:
    """CIE Delta E 2000 of ``mode`` against the exact spectral result, for each stack and probe thickness.

    Each layer is probed at :func:`probe_thicknesses` of its material's range; every combination of the layers'
    probes is one point (stacks in order, combinations in ``itertools.product`` order). Tables are built at exactly
    those thicknesses, so this is the error of the mode alone (no thickness interpolation). Both results (linear
    RGB) go back to XYZ under the scene illuminant by inv(A) (see :class:`WorkingSpace`), then to CIELAB with the
    perfect white under that illuminant as reference, and colour-science's Delta E 2000 (CIE 142-2001).
    """
    used = list(dict.fromkeys(name for stack in stacks for name in stack.layers))
    space = working_space(materials[used[0]].wavelengths, illuminant, observer)
    kind, n_bands = parse_mode(mode)
    bands = band_partition(space.wavelengths, n_bands, space=space) if kind == "bands" else None
    probes = {name: probe_thicknesses(thickness_ranges[name]) for name in used}
    tables = {name: OpticalTable.build(materials[name], probes[name], mode, space, bands) for name in used}
    errors = []
    for stack in stacks:
        points = np.array(list(itertools.product(*(probes[name] for name in stack.layers))))
        X = list(points.T)
        approximate = composite([tables[name] for name in stack.layers], X, stack.substrate, mode)
        reference = exact_rgb([materials[name] for name in stack.layers], X, stack.substrate, space)
        dE = colour.delta_E(space.to_Lab(approximate), space.to_Lab(reference), method="CIE 2000")
        errors.append(np.asarray(dE))
    return np.concatenate(errors)
