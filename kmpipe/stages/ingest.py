"""The ingest stage: radiance spectra to reflectance with a white standard (``kmpipe ingest``).

R(lambda) = (L(lambda) - L_dark(lambda)) / (L_white(lambda) - L_dark(lambda)) x R_cert(lambda), per sample column,
where L is spectral radiance (W sr-1 m-2 nm-1 or any unit shared by the three readings) and R_cert the certified
reflectance of the white standard (:func:`kmpipe.physics.white.radiance_to_reflectance`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.manifest import parse_grid
from kmpipe.formats.spectra import SpectralTable, read_spectra_csv, write_spectra_csv
from kmpipe.formats.spectral_grid import resample, uniform_grid
from kmpipe.physics.white import (
    BUILTIN_BASO4,
    ReadingSource,
    certified_file,
    certified_reflectance,
    radiance_to_reflectance,
)


def column_reference(text: str, option: str) -> tuple[Path, str]:
    """``FILE:COLUMN`` as (file, column); InputError naming ``option`` otherwise."""
    file, sep, column = text.rpartition(":")
    if not sep or not file or not column:
        raise InputError(f"expected FILE:COLUMN, got {text!r}", field=option)
    return Path(file), column


def ingest(
    radiance: str | Path,
    output: str | Path,
    *,
    white: str,
    certified: str = BUILTIN_BASO4,
    dark: str | None = None,
    grid: str | None = None,
) -> SpectralTable:
    r"""Convert every column of the radiance CSV ``radiance`` to reflectance and write it to ``output``.

    ``white`` and ``dark`` are ``FILE:COLUMN`` readings of the white standard and of the dark (any radiance CSV,
    resampled onto the sample's grid); ``certified`` is ``builtin:baso4`` or the standard's certificate
    ``FILE[:COLUMN]`` (relative to the working folder); ``grid`` is ``START:STOP:STEP`` in nm to resample onto
    (default: the radiance file's own grid). Never writes over one of its inputs. Returns the table written.

    >>> import tempfile, pathlib
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (folder / "radiance.csv").write_text(
    ...     "# quantity: radiance\n# units: W sr-1 m-2 nm-1\nwavelength_nm,white,sample\n"
    ...     "500,2.0,1.0\n505,2.0,0.5\n510,2.0,0.25\n")
    >>> table = ingest(folder / "radiance.csv", folder / "reflectance.csv", white=f"{folder}/radiance.csv:white")
    >>> table.columns, table.metadata["quantity"]
    (('white', 'sample'), 'reflectance')
    >>> [round(float(r) / float(c), 6) for r, c in zip(table.column("sample"), table.column("white"))]
    [0.5, 0.25, 0.125]
    """
    radiance, output = Path(radiance), Path(output)
    certificate = None if certified.startswith("builtin:") else certified_file(certified, Path.cwd())[0]
    inputs = [radiance, column_reference(white, "--white")[0], certificate]
    if dark:
        inputs.append(column_reference(dark, "--dark")[0])
    files.output_file(output, inputs=inputs)
    table = read_spectra_csv(radiance)
    if table.quantity != "radiance":
        raise InputError(f"holds {table.quantity}; kmpipe ingest converts radiance", path=radiance, field="quantity")
    if table.wavelengths is None:
        raise InputError("holds camera channels; kmpipe ingest works on spectra", path=radiance)
    wavelengths = uniform_grid(*parse_grid(grid)) if grid else table.wavelengths
    if grid:
        table = resample(table, wavelengths)

    def reference(text: str, option: str) -> np.ndarray:
        path, column = column_reference(text, option)
        ref_table = read_spectra_csv(path)
        if ref_table.quantity != "radiance":
            raise InputError(f"holds {ref_table.quantity}, expected radiance", path=path, field=option)
        if ref_table.wavelengths is None or not np.array_equal(ref_table.wavelengths, wavelengths):
            ref_table = resample(ref_table, wavelengths)
        return ref_table.column(column)

    white_reading = reference(white, "--white")
    dark_reading = reference(dark, "--dark") if dark else None
    reflectance = certified_reflectance(certified, wavelengths, base_dir=Path.cwd())

    def source(column: str) -> ReadingSource:  # white, dark and sample may each come from another file
        return ReadingSource(white=white, dark=dark, samples=(f"{radiance}:{column}",),
                             labels=tuple(table.sample_labels))  # fmt: skip

    values = np.array(
        [
            radiance_to_reflectance(table.column(c), white_reading, reflectance, dark=dark_reading, source=source(c))
            for c in table.columns
        ]
    )
    metadata = dict(table.metadata)
    metadata.update(quantity="reflectance", units="1", white_reference=f"{white} x {certified}")
    if dark:
        metadata["dark_reading"] = dark
    out = SpectralTable(wavelengths=wavelengths, channels=None, columns=table.columns, values=values, metadata=metadata)
    write_spectra_csv(out, output)
    return out
