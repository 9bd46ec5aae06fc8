"""White-standard normalisation: measured radiance to reflectance.

A spectroradiometer (e.g. the Konica Minolta CS-2000) measures radiance L (W sr-1 m-2 nm-1), the light's
radiance times the sample's reflectance: E_m = E_L R (thesis eq. 4.3). With a white standard of known (certified)
reflectance R_white measured under the same light and geometry (which gives E_L), and an optional dark reading
L_dark (stray light / offset, lamp off or cavity), the sample's reflectance at each wavelength is

    R = (L_sample - L_dark) / (L_white - L_dark) * R_white

BaSO4 standards reflect about 0.97-0.99 across the visible and less below 400 nm, so R_white is not 1 and not
flat. kmpipe ships a typical BaSO4 curve (``builtin:baso4``); a standard's own certificate is better.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from kmpipe.errors import InputError
from kmpipe.formats.files import is_regular
from kmpipe.formats.spectra import CS2000_ERROR_SENTINEL, SpectralTable, format_number, read_spectra_csv
from kmpipe.formats.spectral_grid import resample

BUILTIN_BASO4 = "builtin:baso4"
CERTIFIED_RANGE = (0.5, 1.05)
"""Open-closed interval (low, high] that a white standard's certified reflectance must lie in."""
FLAT_TOP_RUN = 5
"""A white reading whose maximum repeats at this many consecutive samples is taken as clipped (saturated).
A smooth peak printed to the instrument's 5 significant digits can repeat its value two or three times."""


@functools.cache
def _builtin_baso4_table() -> SpectralTable:
    with resources.as_file(resources.files("kmpipe") / "data" / "baso4_typical.csv") as path:
        return read_spectra_csv(path)


def baso4_typical(wavelengths_nm: Sequence[float] | np.ndarray) -> np.ndarray:
    """Typical reflectance (fraction) of a pressed/painted BaSO4 white standard at ``wavelengths_nm`` (nm).

    The built-in curve (``kmpipe/data/baso4_typical.csv``, 380-780 nm every 5 nm: about 0.95 at 380 nm,
    0.975 at 400 nm, 0.985 over 450-700 nm) resampled with `kmpipe.formats.spectral_grid.resample` (Sprague). It is a
    typical curve, not a certificate. InputError if the grid extends beyond 380-780 nm.
    """
    return np.array(resample(_builtin_baso4_table(), wavelengths_nm).column("baso4"))


def _check_certified(values: np.ndarray, where: Callable[[int], str], what: str, path: Path | None) -> None:
    """InputError unless every value lies in `CERTIFIED_RANGE`; ``where(i)`` names sample ``i``."""
    low, high = CERTIFIED_RANGE
    bad = ~((values > low) & (values <= high))
    if bad.any():
        i = int(np.argmax(bad))
        hint = " (percent? give a fraction)" if values[i] > 1.5 else ""
        raise InputError(
            f"{what} is {format_number(values[i])} at {where(i)}; a white standard's reflectance must be in "
            f"({format_number(low)}, {format_number(high)}]{hint}",
            path=path,
        )


def certified_file(spec: str, base_dir: Path) -> tuple[Path, str | None]:
    """The file and column (None: its only column) of a white standard's certificate ``PATH`` or ``PATH:COLUMN``
    (relative to ``base_dir``); InputError when neither names a file. Not for ``builtin:`` specs."""
    base_dir = Path(base_dir)
    path = base_dir / spec
    if spec and is_regular(path):
        return path, None
    head, colon, tail = spec.rpartition(":")
    if not (colon and head and is_regular(base_dir / head)):
        raise InputError(
            f"white standard '{spec}' not found (looked for {path}); expected '{BUILTIN_BASO4}', the "
            "path of a reflectance CSV, or PATH:COLUMN"
        )
    return base_dir / head, tail


def certified_reflectance(spec: str, wavelengths_nm: Sequence[float] | np.ndarray, *, base_dir: Path) -> np.ndarray:
    """Certified reflectance (fraction) of the white standard, resampled to ``wavelengths_nm`` (nm).

    Parameters
    ----------
    spec
        ``"builtin:baso4"`` (the typical curve of `baso4_typical`), ``"PATH"`` (a reflectance CSV with one
        measurement column) or ``"PATH:COLUMN"``; PATH is relative to ``base_dir`` unless absolute. If a file
        named exactly ``spec`` exists it is taken as PATH, so file names containing ':' work.
    wavelengths_nm
        Target grid in nm; must lie inside the file's wavelength range (no extrapolation).
    base_dir
        Directory relative paths are resolved against (usually the manifest's directory).

    Raises
    ------
    InputError
        Naming the spec or file: unknown builtin; file missing or unreadable; not a reflectance spectral
        table; several columns and no COLUMN; unknown COLUMN; grid not covered; any value outside (0.5, 1.05].
    """
    grid = np.array(wavelengths_nm, dtype=float)
    if spec.startswith("builtin:"):
        if spec != BUILTIN_BASO4:
            raise InputError(f"unknown built-in white standard '{spec}'; the built-in one is '{BUILTIN_BASO4}'")
        return baso4_typical(grid)

    path, column = certified_file(spec, base_dir)
    table = read_spectra_csv(path)
    if table.wavelengths is None:
        raise InputError(
            f"white standard '{spec}' is a camera channel table; expected a spectrum (wavelength_nm)",
            path=path,
        )
    if table.quantity != "reflectance":
        raise InputError(
            f"white standard '{spec}' holds {table.quantity}; expected '# quantity: reflectance'",
            path=path,
            field="quantity",
        )
    if column is None:
        if len(table.columns) != 1:
            names = ", ".join(table.columns)
            raise InputError(
                f"white standard '{spec}' has {len(table.columns)} columns ({names}); name one as PATH:COLUMN",
                path=path,
            )
        column = table.columns[0]
    table.column(column)
    values = np.array(resample(table, grid).column(column))
    _check_certified(values, lambda i: f"{format_number(grid[i])} nm", f"certified white reflectance '{spec}'", path)
    return values


def certified_uncertainty(spec: str, wavelengths_nm: Sequence[float] | np.ndarray, *, base_dir: Path) -> np.ndarray:
    """Standard uncertainty (k = 1, a fraction) of a white standard's certified reflectance, per wavelength, from the
    column ``PATH:COLUMN`` (or the only column of ``PATH``) of a spectral CSV of quantity ``reflectance``, resampled to
    ``wavelengths_nm``. InputError naming the file unless every value lies in [0, 0.1]."""
    path, column = certified_file(spec, base_dir)
    table = read_spectra_csv(path)
    if table.wavelengths is None or table.quantity != "reflectance":
        raise InputError(
            f"white standard uncertainty '{spec}' must be a spectrum of quantity reflectance (its standard "
            "uncertainty per wavelength, a fraction)",
            path=path,
        )
    if column is None:
        if len(table.columns) != 1:
            raise InputError(f"white standard uncertainty '{spec}' has several columns; name one as PATH:COLUMN",
                             path=path)  # fmt: skip
        column = table.columns[0]
    table.column(column)
    grid = np.array(wavelengths_nm, dtype=float)
    values = np.array(resample(table, grid).column(column))
    bad = ~((values >= 0.0) & (values <= 0.1))
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(
            f"white standard uncertainty is {format_number(values[i])} at {format_number(grid[i])} nm (column "
            f"{column!r}); expected a standard uncertainty in [0, 0.1] (a fraction, not percent)",
            path=path,
        )
    return values


@dataclass(frozen=True)
class ReadingSource:
    """Where radiance readings came from, so that refusals can name them.

    Attributes
    ----------
    path
        File holding the readings.
    white
        Column name of the white-standard reading.
    samples
        Column names of the sample readings, one per row of a 2-D ``sample`` (or one for a 1-D sample).
    dark
        Column name of the dark reading.
    labels
        Label of each sample along the wavelength axis (e.g. `SpectralTable.sample_labels`), shown in nm.
    """

    path: Path | None = None
    white: str | None = None
    samples: tuple[str, ...] = ()
    dark: str | None = None
    labels: tuple[str, ...] = ()

    @classmethod
    def from_table(
        cls,
        table: SpectralTable,
        *,
        white: str | None = None,
        samples: Sequence[str] = (),
        dark: str | None = None,
    ) -> ReadingSource:
        """Source description for readings taken from columns of ``table``."""
        return cls(table.path, white, tuple(samples), dark, tuple(table.sample_labels))

    def at(self, i: int) -> str:
        """Where along the wavelength axis sample ``i`` is, for a message."""
        return f"{self.labels[i]} nm" if self.labels else f"sample {i + 1} along the wavelength axis"

    def column(self, role: str, row: int = 0) -> str | None:
        """Column name of the ``role`` ("white", "dark" or "sample" number ``row``) reading, if known."""
        if role == "white":
            return self.white
        if role == "dark":
            return self.dark
        return self.samples[row] if row < len(self.samples) else None

    def name(self, role: str, row: int = 0) -> str:
        """The reading named for a message, e.g. "white reading 'baso4'" or "sample reading (row 2)"."""
        column = self.column(role, row)
        if column:
            return f"{role} reading '{column}'"
        return f"sample reading (row {row + 1})" if role == "sample" else f"{role} reading"

    def error(self, message: str, column: str | None) -> InputError:
        """An InputError naming the file and ``column``."""
        return InputError(message, path=self.path, field=column)


def _longest_run_at_max(values: np.ndarray) -> tuple[int, int]:
    """(start index, length) of the longest run of consecutive samples equal to the maximum."""
    at_max = np.concatenate(([False], values == values.max(), [False])).astype(np.int8)
    edges = np.diff(at_max)
    starts = np.flatnonzero(edges == 1)
    lengths = np.flatnonzero(edges == -1) - starts
    k = int(np.argmax(lengths))
    return int(starts[k]), int(lengths[k])


def radiance_to_reflectance(
    sample: np.ndarray,
    white: np.ndarray | None,
    certified: np.ndarray,
    *,
    dark: np.ndarray | float | None = None,
    source: ReadingSource | str | Path | None = None,
) -> np.ndarray:
    """Reflectance (fraction) from radiance readings and a white standard of certified reflectance.

    R = (L_sample - L_dark) / (L_white - L_dark) * R_certified, element-wise along the wavelength axis:
    thesis eq. 4.3, R = E_m / E_L, with the light E_L = (L_white - L_dark) / R_certified measured on the white standard.

    Parameters
    ----------
    sample
        Sample radiance L_sample (W sr-1 m-2 nm-1), shape ``(n,)`` or ``(m, n)`` (m samples), wavelength last.
    white
        Radiance of the white standard, shape ``(n,)``, same units, light and geometry.
    certified
        Certified reflectance of the white standard at the same ``n`` wavelengths (fraction, in (0.5, 1.05]).
    dark
        Dark reading L_dark, scalar or shape ``(n,)``, >= 0; ``None`` means 0.
    source
        Where the readings came from (file, columns, wavelength labels) for error messages; a path alone
        names the file.

    Returns
    -------
    np.ndarray
        Reflectance, shape of ``sample``.

    Raises
    ------
    InputError
        Naming ``source`` when given: no white reading; shapes that do not match; non-finite values; a
        CS-2000 calculation-error value (-9.9999e9, over-range) in any reading; a white reading <= 0 anywhere
        or with a clipped flat top (its maximum repeated at `FLAT_TOP_RUN` or more consecutive samples); a
        negative dark reading; white minus dark <= 0 anywhere (implausibly dim); a sample reading below the
        dark reading; a white whose peak (minus dark) is below a sample's peak (minus dark), i.e. a reference
        darker than the sample; certified reflectance outside (0.5, 1.05].

    >>> import numpy as np
    >>> sample, white = np.array([0.6, 1.2]), np.array([2.0, 2.4])  # W sr-1 m-2 nm-1 at two wavelengths
    >>> radiance_to_reflectance(sample, white, np.array([0.98, 0.98])).round(12).tolist()
    [0.294, 0.49]
    >>> radiance_to_reflectance(sample, white, np.array([1.0, 1.0]), dark=0.2).round(12).tolist()
    [0.222222222222, 0.454545454545]
    """
    if not isinstance(source, ReadingSource):
        source = ReadingSource(path=None if source is None else Path(source))
    if white is None:
        raise source.error(
            "no white-standard reading; reflectance = (sample - dark) / (white - dark) x certified needs the "
            "white standard measured in the same session",
            source.white,
        )
    sample = np.asarray(sample, dtype=float)
    white = np.asarray(white, dtype=float)
    certified = np.asarray(certified, dtype=float)
    dark = np.asarray(0.0 if dark is None else dark, dtype=float)
    n = white.shape[0] if white.ndim == 1 else -1
    if (
        white.ndim != 1
        or sample.ndim not in (1, 2)
        or sample.shape[-1] != n
        or certified.shape != (n,)
        or dark.shape not in ((), (n,))
    ):
        raise source.error(
            f"readings do not share one wavelength grid: sample {sample.shape}, white {white.shape}, "
            f"certified {certified.shape}, dark {dark.shape}; expected sample (n,) or (m, n), white and "
            "certified (n,), dark a scalar or (n,)",
            None,
        )
    dark = np.broadcast_to(dark, white.shape)
    rows = np.atleast_2d(sample)
    readings = [("white", 0, white), ("dark", 0, dark), *(("sample", r, row) for r, row in enumerate(rows))]

    remeasure = "re-measure with less light reaching the instrument (dimmer lamp, ND filter, smaller angle)"
    for role, r, values in readings:
        name, column = source.name(role, r), source.column(role, r)
        bad = ~np.isfinite(values)
        if bad.any():
            i = int(np.argmax(bad))
            value = format_number(values[i])
            raise source.error(f"{name} is {value} at {source.at(i)}; expected a finite radiance", column)
        sentinel = values <= CS2000_ERROR_SENTINEL * (1 - 1e-4)
        if sentinel.any():
            i = int(np.argmax(sentinel))
            raise source.error(
                f"{name} holds the CS-2000 calculation-error value {format_number(values[i])} at "
                f"{source.at(i)}: the reading was over-range (saturated) or failed; {remeasure}",
                column,
            )

    white_name = source.name("white")
    if np.any(white <= 0):
        i = int(np.argmax(white <= 0))
        raise source.error(
            f"{white_name} is {format_number(white[i])} at {source.at(i)}; a white standard reads a positive "
            "radiance everywhere (saturated or failed measurement)",
            source.white,
        )
    start, length = _longest_run_at_max(white)
    if length >= FLAT_TOP_RUN:
        raise source.error(
            f"{white_name} is clipped: its maximum {format_number(white[start])} repeats over {length} "
            f"consecutive samples from {source.at(start)} (saturated detector); {remeasure}",
            source.white,
        )
    if np.any(dark < 0):
        i = int(np.argmax(dark < 0))
        raise source.error(
            f"{source.name('dark')} is {format_number(dark[i])} at {source.at(i)}; a radiance cannot be negative",
            source.dark,
        )
    net_white = white - dark
    if np.any(net_white <= 0):
        i = int(np.argmax(net_white <= 0))
        raise source.error(
            f"{white_name} ({format_number(white[i])}) is not above the dark reading "
            f"({format_number(dark[i])}) at {source.at(i)}: implausibly dim for a white standard",
            source.white,
        )
    for r, row in enumerate(rows):
        below = row < dark
        if below.any():
            i = int(np.argmax(below))
            raise source.error(
                f"the dark reading ({format_number(dark[i])}) is larger than the {source.name('sample', r)} "
                f"({format_number(row[i])}) at {source.at(i)}; a dark reading must not exceed the reading it "
                "corrects",
                source.column("sample", r),
            )
        white_peak, sample_peak = np.max(net_white), np.max(row - dark)
        if white_peak < sample_peak:
            raise source.error(
                f"{white_name} peaks at {format_number(white_peak)} (minus dark), below the "
                f"{source.name('sample', r)} at {format_number(sample_peak)}: the reference is darker than "
                "the sample (swapped columns, or the white measured at another distance, angle or exposure)",
                source.white,
            )
    _check_certified(certified, source.at, "certified white reflectance", source.path)
    return (sample - dark) / net_white * certified
