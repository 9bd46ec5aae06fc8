"""Tone mapping: scene-referred linear RGB to display-referred linear RGB in [0, 1], ready for ``write_png``.

Values are linear and relative, in the units of the render (a white Lambert surface facing the light renders to the
light's radiance ``E``; see :mod:`renderer.layers`). :func:`tone_map` returns linear values in [0, 1];
:func:`renderer.image_io.write_png` then applies the sRGB transfer function, so nothing here encodes gamma.

Every operator starts with an exposure of ``ev`` stops and clamps negative values to 0::

    x = max(linear, 0) 2^ev

then maps ``x`` with one of :data:`OPERATORS`:

``none``
    ``y = clip(x, 0, 1)``; at 0 EV this is exactly the identity on [0, 1].
``reinhard``
    Extended Reinhard on luminance (Reinhard et al. 2002, "Photographic tone reproduction for digital images",
    eq. 4), with Rec. 709 luminance and the chromaticity kept::

        L  = 0.2126 r + 0.7152 g + 0.0722 b
        Ld = L (1 + L / Lw^2) / (1 + L)
        y  = clip(x Ld / L, 0, 1)            (Ld / L = (1 + L / Lw^2) / (1 + L), which is 1 at L = 0)

    ``Lw`` (``white``) is the smallest luminance mapped to 1. Ld is monotone in L, ``Ld(Lw) = 1``, ``Ld ~ L`` as
    ``L -> 0``, and ``Ld -> L / (1 + L)`` as ``Lw -> inf``.
``aces``
    Narkowicz 2015 ("ACES filmic tone mapping curve") fit of the ACES RRT + ODT, per channel::

        y = clip(x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14), 0, 1)

    The curve rises monotonically from ``f(0) = 0`` and crosses 1 at ``x = (0.56 + sqrt(0.3584)) / 0.16 ~ 7.24``.
"""

from __future__ import annotations

import math

import numpy as np

#: The operator names :func:`tone_map` accepts.
OPERATORS = ("none", "reinhard", "aces")

#: Rec. 709 / sRGB luminance weights of linear (r, g, b); they sum to exactly 1.0 in float64.
LUMINANCE_WEIGHTS = (0.2126, 0.7152, 0.0722)

#: Smallest default ``white`` (luminance) for ``reinhard``, so a black image does not divide by zero.
MIN_WHITE = 1e-6

_BIG = float(np.finfo(np.float64).max)
# Past 2^2200 every positive float64 overflows and every finite one underflows, so clamping the stops there is exact.
_MAX_STOPS = 2200
# f(x) >= 1 for x >= 7.25 (the ACES fit is monotone), so larger x clip to 1 whatever they are; cap them to avoid
# overflow in x^2.
_ACES_CAP = 8.0


def _expose(linear: np.ndarray, exposure_ev: float) -> np.ndarray:
    """``max(linear, 0) 2^exposure_ev`` in float64, saturating at the largest finite float64 instead of overflowing."""
    x = np.where(linear > 0.0, linear, 0.0)
    stops = round(exposure_ev)
    fraction = exposure_ev - stops  # in [-0.5, 0.5]; 0 for whole stops, which then scale exactly
    with np.errstate(over="ignore", under="ignore"):
        x = np.ldexp(x * math.pow(2.0, fraction), max(-_MAX_STOPS, min(_MAX_STOPS, stops)))
    return np.minimum(x, _BIG)


def _reinhard(x: np.ndarray, white: float | None) -> np.ndarray:
    """Extended Reinhard (2002, eq. 4) on Rec. 709 luminance of exposed ``x`` (float64, >= 0, finite); not clipped."""
    r, g, b = LUMINANCE_WEIGHTS
    with np.errstate(over="ignore"):
        luminance = np.minimum(r * x[..., 0] + g * x[..., 1] + b * x[..., 2], _BIG)
        if white is None:
            white = max(float(luminance.max(initial=0.0)), MIN_WHITE)
        # Ld / L = (1 + L / Lw^2) / (1 + L); L / Lw / Lw rather than L / Lw^2 so that Lw^2 cannot overflow.
        scale = np.minimum((1.0 + luminance / white / white) / (1.0 + luminance), _BIG)
        return x * scale[..., np.newaxis]  # may overflow to inf: clipped to 1 by the caller


def _aces(x: np.ndarray) -> np.ndarray:
    """Narkowicz 2015 ACES filmic fit of exposed ``x`` (float64, >= 0, finite) per channel; not clipped."""
    x = np.minimum(x, _ACES_CAP)
    return (x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)


def tone_map(
    linear: np.ndarray,
    operator: str = "none",
    exposure_ev: float = 0.0,
    white: float | None = None,
) -> np.ndarray:
    """Map scene-referred linear RGB to display-referred linear RGB in [0, 1] (see the module docstring).

    Parameters
    ----------
    linear
        Scene-referred linear RGB, shape (..., 3), in the render's relative radiance units; any finite value
        (negative values are clamped to 0 before anything else).
    operator
        One of :data:`OPERATORS`: ``"none"`` (clip), ``"reinhard"`` (extended Reinhard on luminance) or ``"aces"``
        (Narkowicz's ACES filmic fit, per channel).
    exposure_ev
        Exposure in stops (EV), applied first: values are multiplied by ``2^exposure_ev``. Must be finite.
    white
        ``reinhard`` only: the smallest luminance (after exposure, in the same units) mapped to 1; must be finite and
        positive. Default: the image's largest luminance after exposure, but at least :data:`MIN_WHITE`. Because
        ``reinhard`` scales r, g and b by the same factor, a saturated pixel can have a channel above 1 while its
        luminance is not: channels are then clipped to 1, which shifts that pixel's chromaticity. Passing ``white``
        with ``"none"`` or ``"aces"`` raises :class:`ValueError` rather than being silently ignored (neither curve has
        a white point to set: ``aces`` reaches 1 at about 7.24, ``none`` at 1; use ``exposure_ev`` instead).

    Returns
    -------
    numpy.ndarray
        float32, the shape of ``linear``, every value in [0, 1]: linear display values for
        :func:`renderer.image_io.write_png`, which sRGB-encodes them.

    Raises
    ------
    ValueError
        An unknown ``operator``; ``linear`` not of shape (..., 3) or containing NaN or infinite values; a non-finite
        ``exposure_ev``; ``white`` not finite and positive, or given for an operator other than ``reinhard``.
    """
    if operator not in OPERATORS:
        raise ValueError(f"unknown tone-mapping operator {operator!r}; expected one of {OPERATORS}")
    exposure_ev = float(exposure_ev)
    if not math.isfinite(exposure_ev):
        raise ValueError(f"exposure_ev must be finite, got {exposure_ev}")
    if white is not None:
        if operator != "reinhard":
            raise ValueError(f"white applies only to the 'reinhard' operator, not {operator!r}")
        white = float(white)
        if not (math.isfinite(white) and white > 0.0):
            raise ValueError(f"white must be finite and positive, got {white}")
    image = np.asarray(linear, dtype=np.float64)
    if image.ndim < 1 or image.shape[-1] != 3:
        raise ValueError(f"expected linear RGB of shape (..., 3), got {image.shape}")
    nans = int(np.count_nonzero(np.isnan(image)))
    infinities = int(np.count_nonzero(np.isinf(image)))
    if nans or infinities:
        raise ValueError(f"linear RGB must be finite: it has {nans} NaN and {infinities} infinite value(s)")

    x = _expose(image, exposure_ev)
    if operator == "reinhard":
        x = _reinhard(x, white)
    elif operator == "aces":
        x = _aces(x)
    return np.clip(x, 0.0, 1.0).astype(np.float32)
