"""Wavelength grids and resampling of spectral tables onto them.

A grid is a strictly increasing array of wavelengths in nm; :func:`uniform_grid` builds one exactly from decimal
bounds, :func:`resample` interpolates a :class:`~kmpipe.formats.spectra.SpectralTable` onto any grid (Sprague on
uniform data, else PCHIP; colour-science's interpolators), refusing extrapolation and clipping only rounding-sized
undershoot below zero.
"""

from __future__ import annotations

from collections.abc import Sequence
from decimal import Decimal, InvalidOperation
from pathlib import Path

import numpy as np

from kmpipe.errors import InputError
from kmpipe.formats.spectra import SpectralTable, format_number

METHODS = ("auto", "sprague", "cubic", "pchip")
OVERSHOOT_TOLERANCE = 1e-3
"""Interpolation undershoot below zero that `resample` clips to 0, relative to 1 (reflectance) or to the
column's peak (radiance). Anything further below zero is refused."""
COINCIDE_NM = 1e-6
"""Target and source wavelengths closer than this (nm) are the same wavelength: the value is copied."""
MAX_GRID_POINTS = 1_000_000


def _to_decimal(value: float | int | str | Decimal, name: str) -> Decimal:
    try:
        number = Decimal(repr(value)) if isinstance(value, float) else Decimal(value)
    except (InvalidOperation, TypeError, ValueError):
        raise InputError(f"{value!r} is not a number; expected a wavelength in nm", field=name) from None
    if not number.is_finite():
        raise InputError(f"{value!r} is not a finite wavelength in nm", field=name)
    return number


def uniform_grid(
    start_nm: float | int | str | Decimal,
    stop_nm: float | int | str | Decimal,
    step_nm: float | int | str | Decimal,
) -> np.ndarray:
    """Wavelengths ``start, start + step, ..., stop`` in nm, both ends included.

    Each point is computed as the exact decimal ``start + i * step`` and rounded once to the nearest float,
    so ``uniform_grid(380, 780, 0.1)[1]`` is exactly ``float("380.1")``, the value a CSV cell "380.1" reads
    as (no accumulated rounding). Floats are taken at their shortest decimal form (``0.1`` means 1/10).

    Raises
    ------
    InputError
        If a bound is not a finite number, the step is not positive, ``stop < start``, ``stop - start`` is not
        a whole number of steps, or the grid would exceed `MAX_GRID_POINTS` points.
    """
    start = _to_decimal(start_nm, "start_nm")
    stop = _to_decimal(stop_nm, "stop_nm")
    step = _to_decimal(step_nm, "step_nm")
    if step <= 0:
        raise InputError(f"grid step {step} nm must be positive", field="step_nm")
    if stop < start:
        raise InputError(f"grid stop {stop} nm is below its start {start} nm", field="stop_nm")
    count = (stop - start) / step
    if count != count.to_integral_value():
        raise InputError(
            f"grid {start}-{stop} nm is not a whole number of {step} nm steps; adjust the stop or the step",
            field="stop_nm",
        )
    if count + 1 > MAX_GRID_POINTS:
        raise InputError(f"grid {start}-{stop} nm in {step} nm steps has too many points", field="step_nm")
    return np.array([float(start + i * step) for i in range(int(count) + 1)])


def _is_uniform(wavelengths: np.ndarray) -> bool:
    steps = np.diff(wavelengths)
    return bool(np.all(np.abs(steps - steps[0]) <= COINCIDE_NM))


#: Method -> colour-science's interpolator (colour.algebra), imported when a table is resampled: importing
#: colour-science takes most of a second, which a command that resamples nothing does not pay.
_INTERPOLATORS = {"sprague": "SpragueInterpolator", "cubic": "CubicSplineInterpolator", "pchip": "PchipInterpolator"}


def _interpolator(method: str, source: np.ndarray, path: Path | None) -> type:
    import colour.algebra

    return getattr(colour.algebra, _INTERPOLATORS[_method(method, source, path)])


def _method(method: str, source: np.ndarray, path: Path | None) -> str:
    """The interpolation ``method`` to use on the ``source`` wavelengths ("auto" decided), or an InputError."""
    if method not in METHODS:
        raise InputError(f"interpolation method '{method}' is not one of {', '.join(METHODS)}", field="method")
    uniform = _is_uniform(source)
    n = source.size
    if method == "auto":
        return "sprague" if uniform and n >= 6 else "pchip"
    if method == "sprague" and not (uniform and n >= 6):
        raise InputError(
            "Sprague interpolation needs a uniform source grid of at least 6 wavelengths; use 'pchip' or 'cubic'",
            path=path,
            field="method",
        )
    if method == "cubic" and n < 4:
        raise InputError("cubic spline interpolation needs at least 4 wavelengths", path=path, field="method")
    return method


def resample(table: SpectralTable, wavelengths: Sequence[float] | np.ndarray, *, method: str = "auto") -> SpectralTable:
    """The table's measurements at other wavelengths (nm), by interpolation; never extrapolates.

    Where a target wavelength coincides with a source wavelength (within `COINCIDE_NM`), the source value is
    copied exactly, so 1 nm -> 5 nm -> 10 nm on coinciding grids keeps the measured numbers. Elsewhere, with
    colour-science's interpolators:

    - ``"auto"`` (default): *Sprague (1880)* fifth-order interpolation (``SpragueInterpolator``, recommended
      by CIE 167:2005) when the source grid is uniform with at least 6 wavelengths (e.g. CS-2000 data at
      1 nm, the built-in 5 nm BaSO4 curve); otherwise PCHIP (``PchipInterpolator``). PCHIP is chosen for
      uneven grids (e.g. the ~2.3 nm Kimera spectrophotometer grid) rather than a cubic spline as it is local
      and shape-preserving: it never overshoots the neighbouring samples, so noisy or near-zero measured data
      cannot produce spurious ripples or negative values; its accuracy on smooth spectra sampled every few nm
      is far below measurement noise.
    - ``"sprague"``, ``"cubic"`` (not-a-knot cubic spline, ``CubicSplineInterpolator``), ``"pchip"``: forced.

    Interpolated values a little below zero (overshoot of Sprague or the spline next to near-zero data) are
    set to 0 when they lie within `OVERSHOOT_TOLERANCE` of zero, relative to 1 for reflectance and to the
    column's peak for radiance; larger undershoots are refused.

    Parameters
    ----------
    table
        A spectral table (not a channel table).
    wavelengths
        Target wavelengths in nm, strictly increasing, inside the table's wavelength range.
    method
        One of `METHODS`.

    Returns
    -------
    SpectralTable
        Same columns, metadata and path; ``wavelengths`` as given.

    Raises
    ------
    InputError
        For a channel table, a target grid that is not finite and strictly increasing, a target grid
        extending beyond the source range (naming the file and both ranges), an unknown or unsuitable method,
        or an undershoot beyond the tolerance.
    """
    if table.wavelengths is None:
        raise InputError("a camera channel table cannot be resampled to wavelengths", path=table.path)
    target = np.array(wavelengths, dtype=float)
    if target.ndim != 1 or target.size == 0 or not np.all(np.isfinite(target)) or np.any(np.diff(target) <= 0):
        raise InputError(
            "target wavelengths must be a non-empty, finite, strictly increasing list (nm)",
            field="wavelengths",
        )
    source = table.wavelengths
    if target[0] < source[0] - COINCIDE_NM or target[-1] > source[-1] + COINCIDE_NM:
        raise InputError(
            f"target grid {format_number(target[0])}-{format_number(target[-1])} nm extends beyond the "
            f"range {format_number(source[0])}-{format_number(source[-1])} nm covered by the data; kmpipe "
            "does not extrapolate: choose a grid inside that range",
            path=table.path,
            field="wavelengths",
        )

    right = np.clip(np.searchsorted(source, target), 1, source.size - 1)
    nearest = np.where(target - source[right - 1] <= source[right] - target, right - 1, right)
    coincide = np.abs(source[nearest] - target) <= COINCIDE_NM
    result = np.empty((len(table.columns), target.size))
    result[:, coincide] = table.values[:, nearest[coincide]]
    between = ~coincide
    if between.any():
        interpolator = _interpolator(method, source, table.path)
        for k, row in enumerate(table.values):
            result[k, between] = interpolator(source, row)(target[between])

    if np.any(result < 0):
        for k in range(result.shape[0]):
            scale = 1.0 if table.quantity == "reflectance" else float(np.max(table.values[k]))
            worst = int(np.argmin(result[k]))
            if result[k, worst] < -OVERSHOOT_TOLERANCE * scale:
                raise InputError(
                    f"interpolation undershoots to {format_number(result[k, worst])} at "
                    f"{format_number(target[worst])} nm, more than {format_number(OVERSHOOT_TOLERANCE)} x "
                    f"{format_number(scale)} below zero; the data are too coarse or noisy for this method "
                    "(try method 'pchip')",
                    path=table.path,
                    field=table.columns[k],
                )
        result = np.maximum(result, 0.0)

    return SpectralTable(
        wavelengths=target,
        channels=None,
        columns=table.columns,
        values=result,
        metadata=table.metadata,
        path=table.path,
    )
