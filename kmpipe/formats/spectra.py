"""Spectral tables: the CSV interchange format between stages (grids and resampling onto them are in
:mod:`kmpipe.formats.spectral_grid`).

A table holds one or more named measurements sampled either at wavelengths (nm, strictly increasing) or at
camera channels (e.g. R, G, B). Values are radiance (W sr-1 m-2 nm-1) or reflectance (a fraction, 1 = perfect
white), stored with the wavelength (or channel) axis last: ``values[k, i]`` is column ``k`` at sample ``i``.

The file format is described in ``docs/formats.md`` (section "Spectral CSV"). Reading refuses anything a
person should fix (with the file, the 1-based line and the column); nothing is silently dropped or clipped.
"""

from __future__ import annotations

import csv
import io
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.atomic_write import write_text_atomically

FORMAT_KEY = "kmpipe-spectra"
"""Metadata key of the format version line; reading checks and removes it, writing always puts it first."""
FORMAT_VERSION = "1"
WAVELENGTH_COLUMN = "wavelength_nm"
CHANNEL_COLUMN = "channel"
QUANTITIES = ("radiance", "reflectance")
REFLECTANCE_MAX = 1.5
"""Largest reflectance accepted (fluorescent or glossy samples can exceed 1; percent values cannot pass)."""
CS2000_ERROR_SENTINEL = -9.9999e9
"""Value the Konica Minolta CS-2000 software writes for a calculation error (over-range or failed reading)."""

_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")
_NON_FINITE_WORDS = {"nan", "inf", "infinity"}


def format_number(value: float) -> str:
    """Shortest text that reads back as exactly the same float (``repr``), without a trailing ``.0``."""
    text = repr(float(value))
    return text[:-2] if text.endswith(".0") else text


def _readonly(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


@dataclass(frozen=True, eq=False)
class SpectralTable:
    """Named measurements on a common wavelength grid (or set of camera channels).

    Attributes
    ----------
    wavelengths
        Wavelengths in nm, shape ``(n,)``, strictly increasing, at least 2; ``None`` for a channel table.
    channels
        Channel names of a camera table (e.g. ``("R", "G", "B")``), unique, non-empty; ``None`` for spectra.
    columns
        Measurement names, unique and non-empty.
    values
        Shape ``(len(columns), n)``, wavelength (or channel) axis last; finite. Radiance in W sr-1 m-2 nm-1,
        reflectance as a fraction. Stored read-only (copy before modifying).
    metadata
        Header ``key: value`` pairs in file order (the format version line is not included).
    path
        File the table was read from, used in error messages.

    Raises
    ------
    ValueError
        On construction, for inconsistent structure (a programming error): both or neither of
        ``wavelengths`` and ``channels``, a ``values`` shape that does not match, the reserved metadata key.
    InputError
        On construction, for bad content: fewer than 2 wavelengths or not strictly increasing and positive,
        no channel, empty or repeated names, non-finite values, an unknown quantity, reflectance units
        other than 1. Impossible values (negative, reflectance > 1.5) are checked by `validate_values`.
    """

    wavelengths: np.ndarray | None
    channels: tuple[str, ...] | None
    columns: tuple[str, ...]
    values: np.ndarray
    metadata: dict[str, str] = field(default_factory=dict)
    path: Path | None = None

    def __post_init__(self) -> None:
        if (self.wavelengths is None) == (self.channels is None):
            raise ValueError("a SpectralTable needs exactly one of wavelengths or channels")
        columns = tuple(self.columns)
        values = np.array(self.values, dtype=float)
        if self.wavelengths is not None:
            axis = np.array(self.wavelengths, dtype=float)
            if axis.ndim != 1:
                raise ValueError("wavelengths must be one-dimensional")
            object.__setattr__(self, "wavelengths", _readonly(axis))
            n = axis.size
        else:
            channels = tuple(self.channels)
            object.__setattr__(self, "channels", channels)
            n = len(channels)
        if values.shape != (len(columns), n):
            raise ValueError(f"values have shape {values.shape}, expected ({len(columns)}, {n})")
        path = None if self.path is None else Path(self.path)
        object.__setattr__(self, "path", path)
        object.__setattr__(self, "columns", columns)
        object.__setattr__(self, "values", _readonly(values))
        object.__setattr__(self, "metadata", dict(self.metadata))
        if FORMAT_KEY in self.metadata:
            raise ValueError(f"metadata key '{FORMAT_KEY}' is reserved for the file format version")

        if self.wavelengths is not None:
            w = self.wavelengths
            if w.size < 2:
                raise InputError("a spectral table needs at least 2 wavelengths", path=path)
            if not np.all(np.isfinite(w)) or w[0] <= 0 or np.any(np.diff(w) <= 0):
                raise InputError("wavelengths must be finite, positive and strictly increasing (nm)", path=path)
        else:
            if not self.channels:
                raise InputError("a camera table needs at least one channel", path=path)
            _check_names(self.channels, "channel", path)
        _check_names(columns, "column", path)
        if not columns:
            raise InputError("a spectral table needs at least one measurement column", path=path)
        if not np.all(np.isfinite(values)):
            k, i = np.argwhere(~np.isfinite(values))[0]
            raise InputError(
                f"value {format_number(values[k, i])} at {self.sample_labels[i]} is not a finite number",
                path=path,
                field=columns[k],
            )
        _check_metadata(self.metadata, path)

    @property
    def quantity(self) -> str:
        """``"radiance"`` or ``"reflectance"`` (checked on construction); InputError if the line is absent."""
        quantity = self.metadata.get("quantity")
        if quantity is None:
            raise InputError(
                "the header has no 'quantity' line; expected '# quantity: radiance' or '# quantity: reflectance'",
                path=self.path,
                field="quantity",
            )
        return quantity

    @property
    def sample_labels(self) -> list[str]:
        """Wavelengths formatted as text (e.g. ``"380"``, ``"381.2148"``), or the channel names."""
        if self.wavelengths is None:
            return list(self.channels)
        return [format_number(w) for w in self.wavelengths]

    def column(self, name: str) -> np.ndarray:
        """The values of measurement ``name`` (read-only, shape ``(n,)``); InputError if there is none."""
        try:
            k = self.columns.index(name)
        except ValueError:
            available = ", ".join(f"'{c}'" for c in self.columns)
            raise InputError(f"no column '{name}'; the table has {available}", path=self.path, field=name) from None
        return self.values[k]

    def validate_values(self, *, lines: Sequence[int] | None = None) -> None:
        """Refuse physically impossible values: any negative value, and reflectance above `REFLECTANCE_MAX`.

        Parameters
        ----------
        lines
            1-based file line of each sample (along the last axis), to name the line in the error.

        Raises
        ------
        InputError
            Naming the column, the wavelength (or channel), the value and, when ``lines`` is given, the line.
            The first offending value in file order is reported. A tiny negative such as -1e-6 (dark-reading
            noise) is refused too: measured data are never clipped silently.
        """
        quantity = self.metadata.get("quantity")
        noun = quantity if quantity in QUANTITIES else "value"
        bad = self.values < 0
        if quantity == "reflectance":
            bad |= self.values > REFLECTANCE_MAX
        if not bad.any():
            return
        i, k = np.argwhere(bad.T)[0]
        value = float(self.values[k, i])
        if value < 0:
            message = f"negative {noun} {value!r} in column '{self.columns[k]}' at {self._where(i)}; "
            if value <= CS2000_ERROR_SENTINEL * (1 - 1e-4):
                message += "this is the CS-2000 calculation-error value (over-range or failed reading): re-measure"
            else:
                message += (
                    "radiance and reflectance must be >= 0 (kmpipe does not clip measured data: correct "
                    "the dark offset or re-measure)"
                )
        else:
            message = (
                f"reflectance {value!r} in column '{self.columns[k]}' at {self._where(i)} is above "
                f"{format_number(REFLECTANCE_MAX)}; reflectance is a fraction (1 = perfect white), "
                "not percent"
            )
        line = None if lines is None else lines[i]
        raise InputError(message, path=self.path, line=line, field=self.columns[k])

    def _where(self, i: int) -> str:
        label = self.sample_labels[i]
        return f"{label} nm" if self.wavelengths is not None else f"channel '{label}'"


def _check_names(names: Iterable[str], kind: str, path: Path | None) -> None:
    seen = set()
    for name in names:
        if not isinstance(name, str) or not name:
            raise InputError(f"every {kind} needs a non-empty name", path=path)
        if name in seen:
            raise InputError(f"{kind} name '{name}' appears twice; names must be unique", path=path, field=name)
        seen.add(name)


def _check_metadata(metadata: dict[str, str], path: Path | None, lines: dict[str, int] | None = None) -> None:
    """Check the metadata keys kmpipe interprets: ``quantity`` and, for reflectance, ``units``."""

    def line(key: str) -> int | None:
        return None if lines is None else lines[key]

    quantity = metadata.get("quantity")
    if quantity is not None and quantity not in QUANTITIES:
        raise InputError(
            f"quantity '{quantity}' is not one of {', '.join(QUANTITIES)}",
            path=path,
            line=line("quantity"),
            field="quantity",
        )
    units = metadata.get("units")
    if quantity == "reflectance" and units is not None and units != "1":
        raise InputError(
            f"reflectance units '{units}' are not supported; expected '# units: 1' (a fraction, not percent)",
            path=path,
            line=line("units"),
            field="units",
        )


def _parse_number(cell: str, what: str, path: Path, line: int, column: str) -> float:
    text = cell.strip()
    if text.lower().lstrip("+-") in _NON_FINITE_WORDS:
        raise InputError(f"{what} '{text}' is not a finite number", path=path, line=line, field=column)
    if not _NUMBER.fullmatch(text):
        shown = f"'{text}'" if text else "an empty cell"
        raise InputError(
            f"{what} is {shown}; expected a decimal number such as 0.0123 or 1.5e-3",
            path=path,
            line=line,
            field=column,
        )
    value = float(text)
    if not np.isfinite(value):
        raise InputError(f"{what} '{text}' overflows a float", path=path, line=line, field=column)
    return value


def _read_text(path: Path) -> str:
    """The text of a spectral CSV: a regular UTF-8 file (a byte order mark is dropped) of at most
    ``files.LIMITS["spectral CSV"]`` bytes (:func:`kmpipe.formats.files.read_text`)."""
    return files.read_text(path, "spectral CSV", encoding="utf-8-sig")


def _split_csv(line: str, path: Path, line_no: int) -> list[str]:
    try:
        return next(csv.reader([line], strict=True))
    except csv.Error as err:
        raise InputError(f"the line is not valid CSV ({err})", path=path, line=line_no) from None


def read_spectra_csv(path: str | os.PathLike[str]) -> SpectralTable:
    """Read a spectral CSV file (format in ``docs/formats.md``) and validate it.

    Returns
    -------
    SpectralTable
        Values as stored (radiance in W sr-1 m-2 nm-1, reflectance as a fraction); ``path`` set.

    Raises
    ------
    InputError
        With the file, the 1-based line and the column where relevant, for: an unreadable file; an
        unsupported format version; a repeated metadata key or metadata after the header row; a missing or
        unknown first column; empty or duplicate column names; a row with the wrong number of fields; a
        non-numeric, NaN or infinite cell; wavelengths that are not positive and strictly increasing;
        duplicate channel names; no rows, or fewer than 2 wavelengths; a negative value; a reflectance above
        1.5; a quantity other than radiance or reflectance; reflectance units other than 1.

    >>> import kmpipe, pathlib
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> table = read_spectra_csv(F1 / "F1.csv")
    >>> table.quantity, float(table.wavelengths[0]), float(table.wavelengths[-1]), table.values.shape
    ('radiance', 380.0, 780.0, (5, 401))
    >>> table.columns[:2]
    ('masstone', 'film_15um_over_black')
    """
    path = Path(path)
    text = _read_text(path)
    metadata: dict[str, str] = {}
    meta_lines: dict[str, int] = {}
    header: list[str] | None = None
    header_line = 0
    axis: list[float] = []
    labels: list[str] = []
    rows: list[list[float]] = []
    row_lines: list[int] = []

    for line_no, raw in enumerate(text.split("\n"), start=1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            body = line.lstrip("#").strip()
            if ":" not in body:
                continue
            if header is not None:
                raise InputError(
                    "metadata line after the header row; put '# key: value' lines before the header",
                    path=path,
                    line=line_no,
                )
            key, value = (part.strip() for part in body.split(":", 1))
            if not key:
                raise InputError("metadata line has no key before ':'", path=path, line=line_no)
            if key in meta_lines:
                raise InputError(
                    f"metadata key '{key}' appears twice (first on line {meta_lines[key]}); give it once",
                    path=path,
                    line=line_no,
                    field=key,
                )
            if key == FORMAT_KEY and value != FORMAT_VERSION:
                raise InputError(
                    f"format version '{value}' is not supported; expected '# {FORMAT_KEY}: {FORMAT_VERSION}'",
                    path=path,
                    line=line_no,
                    field=key,
                )
            meta_lines[key] = line_no
            if key != FORMAT_KEY:
                metadata[key] = value
            continue

        cells = _split_csv(line, path, line_no)
        if header is None:
            header = [cell.strip() for cell in cells]
            header_line = line_no
            _check_header(header, path, line_no)
            continue
        if len(cells) != len(header):
            raise InputError(
                f"row has {len(cells)} fields, expected {len(header)} ({', '.join(header)})",
                path=path,
                line=line_no,
            )
        if header[0] == WAVELENGTH_COLUMN:
            w = _parse_number(cells[0], "wavelength", path, line_no, WAVELENGTH_COLUMN)
            if w <= 0:
                raise InputError(
                    f"wavelength {cells[0].strip()} nm is not positive",
                    path=path,
                    line=line_no,
                    field=header[0],
                )
            if axis and w <= axis[-1]:
                kind = "repeats" if w == axis[-1] else "is smaller than"
                raise InputError(
                    f"wavelength {format_number(w)} nm {kind} the previous row's "
                    f"{format_number(axis[-1])} nm; wavelengths must be strictly increasing",
                    path=path,
                    line=line_no,
                    field=header[0],
                )
            axis.append(w)
        else:
            label = cells[0].strip()
            if not label:
                raise InputError("channel name is empty", path=path, line=line_no, field=CHANNEL_COLUMN)
            if label in labels:
                raise InputError(
                    f"channel '{label}' appears twice; channel names must be unique",
                    path=path,
                    line=line_no,
                    field=CHANNEL_COLUMN,
                )
            labels.append(label)
        rows.append(
            [
                _parse_number(cell, "value", path, line_no, name)
                for cell, name in zip(cells[1:], header[1:], strict=True)
            ]
        )
        row_lines.append(line_no)

    if header is None:
        raise InputError(
            f"the file has no header row; expected a line such as '{WAVELENGTH_COLUMN},sample_1' after the '#' lines",
            path=path,
        )
    if not rows:
        raise InputError("the table has a header but no data rows", path=path, line=header_line)
    if header[0] == WAVELENGTH_COLUMN and len(rows) < 2:
        raise InputError("a spectral table needs at least 2 wavelengths, found 1", path=path, line=row_lines[0])

    _check_metadata(metadata, path, meta_lines)
    table = SpectralTable(
        wavelengths=np.array(axis) if header[0] == WAVELENGTH_COLUMN else None,
        channels=tuple(labels) if header[0] == CHANNEL_COLUMN else None,
        columns=tuple(header[1:]),
        values=np.array(rows).T,
        metadata=metadata,
        path=path,
    )
    table.validate_values(lines=row_lines)
    return table


def _check_header(header: list[str], path: Path, line_no: int) -> None:
    first = header[0]
    if first not in (WAVELENGTH_COLUMN, CHANNEL_COLUMN):
        hint = " (is the file comma-separated?)" if (";" in first or "\t" in first) else ""
        raise InputError(
            f"first column is '{first}', expected '{WAVELENGTH_COLUMN}' (spectra) or '{CHANNEL_COLUMN}' "
            f"(camera channels){hint}",
            path=path,
            line=line_no,
            field=first,
        )
    if len(header) < 2:
        raise InputError(f"the header has no measurement columns after '{first}'", path=path, line=line_no, field=first)
    seen = set()
    for position, name in enumerate(header[1:], start=2):
        if not name:
            raise InputError(f"column {position} of the header has no name", path=path, line=line_no)
        if name in seen:
            raise InputError(
                f"column name '{name}' appears twice; names must be unique",
                path=path,
                line=line_no,
                field=name,
            )
        seen.add(name)


def _check_writable_text(text: str, what: str, path: Path, key: str, *, allow_empty: bool = False) -> None:
    """Refuse text that would not read back identically from the CSV format (InputError naming ``key``)."""
    problem = None
    if not text:
        problem = None if allow_empty else "is empty"
    elif text != text.strip():
        problem = "has leading or trailing whitespace"
    elif any(ord(ch) < 32 or ord(ch) == 127 for ch in text) or "\u2028" in text or "\u2029" in text:
        problem = "contains a line break or control character"
    elif what in ("metadata key", "channel name") and text.startswith("#"):
        problem = "starts with '#'"
    elif what == "metadata key" and ":" in text:
        problem = "contains ':'"
    if problem:
        raise InputError(f"{what} {text!r} {problem}, so it cannot be written to the CSV", path=path, field=key)


def write_spectra_csv(table: SpectralTable, path: str | os.PathLike[str]) -> None:
    """Write ``table`` to ``path`` atomically in the spectral CSV format.

    The text is written to a new temporary file in the destination directory, flushed and fsynced, then
    renamed over ``path`` (``os.replace``), so readers see either the old file or the complete new one.
    Numbers are written with ``repr`` (shortest exact form), so reading the file back gives identical floats;
    the ``kmpipe-spectra`` version line is written first, then the metadata in order.

    Raises
    ------
    InputError
        If a value is impossible (see `SpectralTable.validate_values`); if a name, metadata key or metadata
        value would not read back identically (an empty name or key, surrounding whitespace, a line break or
        control character, a channel name or key starting with '#', a key containing ':'); or if the file
        cannot be written.

    >>> import kmpipe, pathlib, tempfile, numpy as np
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> table = read_spectra_csv(F1 / "F1.csv")
    >>> copy = pathlib.Path(tempfile.mkdtemp()) / "copy.csv"
    >>> write_spectra_csv(table, copy)
    >>> again = read_spectra_csv(copy)  # numbers written in their shortest exact form read back identical
    >>> bool(np.array_equal(again.values, table.values)), again.columns == table.columns
    (True, True)
    """
    path = Path(path)
    table.validate_values()
    for key, value in table.metadata.items():
        _check_writable_text(key, "metadata key", path, key)
        _check_writable_text(value, "metadata value", path, key, allow_empty=True)
    for name in table.columns:
        _check_writable_text(name, "column name", path, name)
    for name in table.channels or ():
        _check_writable_text(name, "channel name", path, name)

    buffer = io.StringIO()
    buffer.write(f"# {FORMAT_KEY}: {FORMAT_VERSION}\n")
    for key, value in table.metadata.items():
        buffer.write(f"# {key}: {value}\n" if value else f"# {key}:\n")
    writer = csv.writer(buffer, lineterminator="\n")
    first = WAVELENGTH_COLUMN if table.wavelengths is not None else CHANNEL_COLUMN
    writer.writerow([first, *table.columns])
    for i, label in enumerate(table.sample_labels):
        writer.writerow([label, *(format_number(v) for v in table.values[:, i])])
    write_text_atomically(path, buffer.getvalue())
