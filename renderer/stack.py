"""The surface a mesh wears, as plain data (no GL): a Kubelka-Munk stack of films over a substrate, and their lobes.

The renderer knows nothing of K and S: each film comes as an optical table (:class:`LayerTable`), its reflectance
``R0`` (over a black backing) and transmittance ``T`` sampled at a series of thicknesses (mm), per channel. Channels
are either linear RGB (3) or spectral bands, composed per band and converted once with a (bands, 3) ``to_rgb`` matrix
(:class:`ChannelStack`); or the caller composes the stack itself and gives its linear RGB reflectance
(:class:`Precomposed`, kmpipe's ``exact`` mode). Each film may carry a specular lobe (:class:`Specular`; Kelemen /
Szirmay-Kalos with a Beckmann distribution and Schlick's Fresnel, thesis eq. 3.15), and so may the substrate (skin's
own lobe: :data:`SKIN_SPECULAR`). The layer pass (:mod:`renderer.layers`) composes and shades them, at most
:data:`MAX_LAYERS` films of :data:`MAX_CHANNELS` channels (as ``shaders/km_layers.frag`` defines them).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: Most films in one stack.
MAX_LAYERS = 4
#: Most channels (bands) per table; the layer pass works on groups of four.
MAX_CHANNELS = 32
#: A film's lobe is weighted by its cover, clamp(thickness / LOBE_COVER_MM, 0, 1) (mm): where a thickness map fades to
#: nothing the film's surface, and its gloss, fade with it (a film of zero thickness leaves the surface as it was).
LOBE_COVER_MM = 1e-3


@dataclass(frozen=True)
class LayerTable:
    """The optical table of one film: reflectance and transmittance against thickness, per channel.

    Attributes
    ----------
    thickness_mm
        Strictly increasing film thicknesses (mm), shape (n_thickness,), or a scalar for a single thickness.
    r0
        Reflectance of the film over a black backing, in [0, 1], shape (n_thickness, C), or (C,) with a scalar
        ``thickness_mm``.
    t
        Transmittance of the film (one pass, diffuse), in [0, 1], same shape as ``r0``.
    """

    thickness_mm: np.ndarray | float
    r0: np.ndarray
    t: np.ndarray

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Validated float64 ``(thickness_mm (n,), r0 (n, C), t (n, C))``; raises :class:`ValueError` on bad input."""
        x = np.asarray(self.thickness_mm, dtype=float)
        r0 = np.asarray(self.r0, dtype=float)
        t = np.asarray(self.t, dtype=float)
        if x.ndim == 0:
            x, r0, t = x.reshape(1), r0[np.newaxis], t[np.newaxis]
        if x.ndim != 1 or x.size < 1:
            raise ValueError(f"thickness_mm must be a scalar or a non-empty 1-D array, got shape {x.shape}")
        if r0.ndim != 2 or r0.shape[0] != x.size or t.shape != r0.shape:
            raise ValueError(
                f"r0 and t must both have shape (n_thickness, C) = ({x.size}, C), got {r0.shape} and {t.shape}"
            )
        if not (np.all(np.isfinite(x)) and np.all(np.diff(x) > 0.0)):
            raise ValueError("thickness_mm must be finite and strictly increasing")
        for name, values in (("r0", r0), ("t", t)):
            if not (np.all(np.isfinite(values)) and values.min() >= 0.0 and values.max() <= 1.0):
                raise ValueError(f"{name} must lie in [0, 1]")
        return x, r0, t


@dataclass(frozen=True)
class Specular:
    """A film's specular lobe: Beckmann roughness ``m`` (RMS microfacet slope, > 0) and index of refraction ``ior``.

    Schlick's Fresnel reflectance at normal incidence is ``F0 = ((ior - 1) / (ior + 1))^2`` (air above the film).
    """

    roughness: float
    ior: float = 1.5

    def __post_init__(self) -> None:
        if not (0.0 < self.roughness <= 2.0 and 1.0 <= self.ior <= 4.0):
            raise ValueError(
                f"a specular lobe needs 0 < roughness <= 2 and 1 <= ior <= 4, got {self.roughness}, {self.ior}"
            )

    @property
    def f0(self) -> float:
        return ((self.ior - 1.0) / (self.ior + 1.0)) ** 2


#: Skin's Fresnel reflectance at normal incidence (method notes) as an index of refraction: (1 + sqrt F0) / (1 - ...).
SKIN_IOR = (1.0 + 0.028**0.5) / (1.0 - 0.028**0.5)
#: Skin's own lobe by default: Beckmann roughness 0.35 (d'Eon and Luebke's fit to measured skin), F0 0.028.
SKIN_SPECULAR = Specular(0.35, SKIN_IOR)


@dataclass(frozen=True)
class ChannelStack:
    """Films composited in the shader, per channel.

    Attributes
    ----------
    tables
        Optical tables of 0 to :data:`MAX_LAYERS` films, top first (``tables[0]`` is the layer the
        light meets first, the last lies on the substrate; the order of kmpipe's stacks). All have the same number of
        channels C (3 for rgb, up to :data:`MAX_CHANNELS` bands). They are composed from the bottom up.
    thicknesses
        One per film, in mm: a number (uniform thickness) or a 2-D array (rows, columns) mapped over the mesh's uv,
        row 0 at v = 1 (the top, as in an image) and column 0 at u = 0, bilinearly filtered between texel centres.
        Thicknesses outside a table's range take the value at the nearer end.
    substrate
        Albedo of the substrate per channel, in [0, 1], shape (C,).
    to_rgb
        (C, 3) matrix converting per-channel reflectance to linear RGB (bands); if omitted C must be 3 and the
        channels are linear RGB.
    substrate_map
        A substrate that varies over uv (an albedo texture), overriding ``substrate``: (weights, basis) with
        weights (rows, columns, 3) over uv (row 0 at v = 1, bilinear) and basis (3, C) reflectances per channel;
        the substrate at a point is ``clip(weights @ basis, 0, 1)``.
    """

    tables: Sequence[LayerTable]
    thicknesses: Sequence[float | np.ndarray]
    substrate: Sequence[float] | np.ndarray
    to_rgb: np.ndarray | None = None
    substrate_map: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def n_layers(self) -> int:
        return len(self.tables)


@dataclass(frozen=True)
class Precomposed:
    """A stack composited by the caller, in linear RGB.

    Attributes
    ----------
    reflectance
        The stack's reflectance over its substrate, linear RGB: shape (3,) (uniform) or (rows, columns, 3) over uv
        (row 0 at v = 1), bilinearly filtered.
    over_black
        The stack's reflectance over a black substrate (what the films reflect by themselves), same shape.
    attenuation
        One per film, top first, then one for the substrate: the RGB attenuation ``A`` of a specular lobe by the
        films above it (1 for the top film; all films for the substrate), shape (n_layers + 1, 3) or
        (n_layers + 1, rows, columns, 3) on the grid of ``reflectance``.
    """

    reflectance: np.ndarray
    over_black: np.ndarray
    attenuation: np.ndarray

    @property
    def n_layers(self) -> int:
        return len(self.attenuation) - 1
