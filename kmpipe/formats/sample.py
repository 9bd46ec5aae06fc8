"""One sample's measurements, loaded from its manifest onto one wavelength grid as reflectance.

Reading a manifest resolves every CSV column it names, converts radiance to reflectance with the white
standard when the manifest has a ``[white]``, resamples onto the fitting grid, and arranges the
measurements as arrays that the inversions and the joint fit take directly.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kmpipe.errors import InputError
from kmpipe.formats.files import regular_file
from kmpipe.formats.manifest import (
    WHITE_UNCERTAINTY,
    FitSettings,
    Manifest,
    load_manifest,
    manifest_files,
    parse_grid,
)
from kmpipe.formats.spectra import SpectralTable, read_spectra_csv
from kmpipe.formats.spectral_grid import resample, uniform_grid
from kmpipe.formats.toml_input import field_line
from kmpipe.physics.white import ReadingSource, certified_reflectance, certified_uncertainty, radiance_to_reflectance

#: Default fitting step (nm) for finer data: 8x faster than 1 nm for a median Delta E 2000 of 0.04
#: (docs/benchmarks.md, "Wavelength grid").
DEFAULT_STEP_NM = 5.0

#: Reflectance above this after white normalization means the white reading or the units are wrong.
MAX_REFLECTANCE = 1.5


def named_in(err: InputError, manifest: Path, field: str, line: int | None) -> InputError:
    """``err`` (about a file a manifest names) saying also which manifest, line and field named the file."""
    where = f"{manifest}" + (f", line {line}" if line else "") + f", field '{field}'"
    if str(manifest) in err.message:
        return err
    return InputError(f"{err.message} (the file named in {where})", path=err.path, line=err.line, field=err.field)


@dataclass(frozen=True)
class Measurement:
    """One measured column: a masstone (opaque layer) or a film of known thickness over a named backing."""

    id: str  # "FILE:COLUMN"
    role: str  # "masstone" | "film"
    file: Path
    column: str
    over: str | None
    thickness_mm: float  # inf for a masstone (the fit treats it as opaque)
    declared_mm: float | None = None  # a masstone's thickness as drawn, if the manifest gives it
    thickness_u_mm: float = 0.0  # a film's thickness's standard uncertainty ("30 um +- 2 um"); 0: none stated


@dataclass(frozen=True)
class Sample:
    """A sample's reflectances on one grid (wavelength or channel last)."""

    name: str
    product: str
    kind: str
    manifest_path: Path
    wavelengths: np.ndarray | None  # nm; None for camera-channel data
    channels: tuple[str, ...] | None
    measurements: tuple[Measurement, ...]
    readings: np.ndarray  # (m, n) reflectance as measured (surface reflection included)
    backings: dict[str, np.ndarray]  # name -> (n,) measured reflectance of the bare backing
    settings: FitSettings
    inputs: tuple[Path, ...]  # every file read, manifest first (manifest_files)
    white_u: np.ndarray | None = None  # (n,) relative standard uncertainty of the white standard; None: no [white]

    @property
    def labels(self) -> list:
        """Wavelengths (nm, as numbers) or channel names, one per column of ``readings``."""
        if self.wavelengths is not None:
            return [float(w) for w in self.wavelengths]
        return list(self.channels)

    @property
    def thickness_mm(self) -> np.ndarray:
        return np.array([m.thickness_mm for m in self.measurements])

    def background_of(self, measurement: Measurement) -> np.ndarray:
        """Measured reflectance of the backing beneath a film (zeros for a masstone, which has none)."""
        if measurement.over is None:
            return np.zeros(self.readings.shape[1])
        return self.backings[measurement.over]


class _Tables:
    """Reads each CSV once and checks that its quantity is what the manifest implies."""

    def __init__(self, base: Path, manifest_path: Path, quantity: str) -> None:
        self.base = base
        self.manifest_path = manifest_path
        self.quantity = quantity
        self.cache: dict[Path, SpectralTable] = {}

    def get(self, ref, field: str) -> tuple[SpectralTable, Path]:
        path = (self.base / ref.file).resolve()
        if path not in self.cache:
            line = field_line(self.manifest_path, field + ".file")
            try:
                regular_file(path, "spectral CSV")
            except InputError as err:
                raise InputError(f"names the file {ref.file!r}, which {err.message} (looked for {path})",
                                 path=self.manifest_path, line=line, field=field + ".file") from None  # fmt: skip
            try:
                table = read_spectra_csv(path)
            except InputError as err:
                raise named_in(err, self.manifest_path, field + ".file", line) from None
            if table.quantity != self.quantity:
                why = "the manifest has a [white] reference" if self.quantity == "radiance" else "there is no [white]"
                raise InputError(
                    f"holds {table.quantity}, but {why}, so it must hold {self.quantity} "
                    f"(set '# quantity: {self.quantity}' or change the manifest)",
                    path=path,
                    field="quantity",
                )
            self.cache[path] = table
        table = self.cache[path]
        if ref.column not in table.columns:
            raise InputError(
                f"names column {ref.column!r} of {ref.file}, which has the columns: {', '.join(table.columns)}",
                path=self.manifest_path,
                line=field_line(self.manifest_path, field + ".column"),
                field=field + ".column",
            )
        return table, path


def _fitting_grid(settings: FitSettings, first: SpectralTable, override: str | None, manifest_path: Path):
    """The grid to fit on (nm): --grid, else the manifest's [fit] grid, else `DEFAULT_STEP_NM` steps over the
    first file's range (its own grid when that is already as coarse)."""
    if first.wavelengths is None:
        return None
    if isinstance(override, np.ndarray):
        return np.asarray(override, dtype=np.float64)
    text = override or settings.grid
    if text is None:
        own = np.asarray(first.wavelengths, dtype=np.float64)
        start = np.ceil(own[0] / DEFAULT_STEP_NM) * DEFAULT_STEP_NM
        stop = np.floor(own[-1] / DEFAULT_STEP_NM) * DEFAULT_STEP_NM
        if np.min(np.diff(own)) >= DEFAULT_STEP_NM or stop - start < DEFAULT_STEP_NM:
            return own
        return uniform_grid(f"{start:g}", f"{stop:g}", f"{DEFAULT_STEP_NM:g}")
    where = (
        {"field": "--grid"}
        if override
        else {"field": "fit.grid", "path": manifest_path, "line": field_line(manifest_path, "fit.grid")}
    )
    try:
        return uniform_grid(*parse_grid(text))
    except ValueError as err:
        raise InputError(str(err), **where) from None
    except InputError as err:
        raise InputError(err.message, **where) from None


def _on_grid(table: SpectralTable, grid: np.ndarray | None, channels) -> SpectralTable:
    if grid is None:
        if table.channels != channels:
            raise InputError(
                f"has channels {table.channels}, but the sample's first file has {channels}", path=table.path
            )
        return table
    if table.wavelengths is None:
        raise InputError("holds camera channels, but the sample's other files hold spectra", path=table.path)
    if table.wavelengths.shape == grid.shape and np.array_equal(table.wavelengths, grid):
        return table
    return resample(table, grid)


def load_sample(manifest_path: str | Path, *, grid: str | np.ndarray | None = None) -> Sample:
    """Load a sample manifest and everything it names, as reflectance on one grid.

    Parameters
    ----------
    manifest_path
        The TOML manifest; file names inside it are relative to its folder.
    grid
        'START:STOP:STEP' in nm, or the wavelengths themselves (nm), overriding the manifest's ``[fit]
        grid``; default: see :func:`_fitting_grid`.

    >>> import kmpipe, pathlib
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> sample = load_sample(F1 / "manifest.toml")
    >>> sample.name, sample.readings.shape, [m.role for m in sample.measurements]
    ('F1', (5, 81), ['masstone', 'film', 'film', 'film', 'film'])
    >>> [path.name for path in sample.inputs]
    ['manifest.toml', 'white.csv', 'backings.csv', 'F1.csv']
    """
    manifest_path = Path(manifest_path)
    manifest: Manifest = load_manifest(manifest_path)
    base = manifest_path.parent
    quantity = "radiance" if manifest.white is not None else "reflectance"
    tables = _Tables(base, manifest_path, quantity)

    loaded = [(field, ref, *tables.get(ref, field)) for field, ref in manifest.references()]
    first = loaded[0][2]
    fit_grid = _fitting_grid(manifest.fit, first, grid, manifest_path)
    on_grid = {path: _on_grid(table, fit_grid, first.channels) for _, _, table, path in loaded}

    def column(ref, path) -> np.ndarray:
        return np.asarray(on_grid[path].column(ref.column), dtype=np.float64)

    labels = tuple(f"{w:g}" for w in fit_grid) if fit_grid is not None else ()

    def reflectance(ref, path) -> np.ndarray:
        values = column(ref, path)
        if manifest.white is not None:
            source = ReadingSource(path=path, white=white_name, samples=(ref.column,), labels=labels)
            values = radiance_to_reflectance(values, white, certified, dark=dark, source=source)
        bad = np.flatnonzero(values > MAX_REFLECTANCE)
        if bad.size:
            label = f"{fit_grid[bad[0]]:g} nm" if fit_grid is not None else f"channel {first.channels[bad[0]]}"
            raise InputError(
                f"column {ref.column!r} has reflectance {values[bad[0]]:.4g} at {label}, "
                f"above {MAX_REFLECTANCE}: check the white reference and the units",
                path=path,
            )
        return values

    white = certified = dark = white_name = None
    if manifest.white is not None:
        white_path = next(path for field, _, _, path in loaded if field == "white")
        white = column(manifest.white, white_path)
        white_name = f"{white_path}:{manifest.white.column}"
        if manifest.white.dark is not None:
            dark_path = next(path for field, _, _, path in loaded if field == "white.dark")
            dark = column(manifest.white.dark, dark_path)
        if fit_grid is None:
            raise InputError(
                "has a [white] radiance reference, but its files hold camera channels: camera data must be "
                "given as reflectance (kmpipe ingest-raw writes it so); remove [white]",
                path=manifest_path,
                field="white",
            )
        try:
            certified = certified_reflectance(manifest.white.certified, fit_grid, base_dir=base)
        except InputError as err:
            if err.path is None:
                err.path, err.field = manifest_path, "white.certified"
                raise
            line = field_line(manifest_path, "white.certified")
            raise named_in(err, manifest_path, "white.certified", line) from None
        # Check the white (and dark) reading on its own first, so that a refusal names the white's file.
        white_source = ReadingSource(
            path=white_path,
            white=manifest.white.column,
            samples=(manifest.white.column,),
            dark=None if manifest.white.dark is None else manifest.white.dark.column,
            labels=labels,
        )
        radiance_to_reflectance(white, white, certified, dark=dark, source=white_source)

    backings = {}
    measurements, readings = [], []
    for field, ref, _, path in loaded:
        if field.startswith("backing"):
            backings[ref.name] = reflectance(ref, path)
        elif field.startswith(("masstone", "film")):
            is_film = field.startswith("film")
            measurements.append(
                Measurement(
                    id=f"{ref.file}:{ref.column}",
                    role="film" if is_film else "masstone",
                    file=path,
                    column=ref.column,
                    over=ref.over if is_film else None,
                    thickness_mm=ref.thickness_mm if is_film else float("inf"),
                    declared_mm=None if is_film else ref.thickness_mm,
                    thickness_u_mm=ref.thickness_u_mm if is_film else 0.0,
                )
            )
            readings.append(reflectance(ref, path))

    return Sample(
        name=manifest.sample.name,
        product=manifest.sample.product,
        kind=manifest.sample.kind,
        manifest_path=manifest_path,
        wavelengths=fit_grid,
        channels=first.channels if fit_grid is None else None,
        measurements=tuple(measurements),
        readings=np.array(readings),
        backings=backings,
        settings=manifest.fit,
        inputs=manifest_files(manifest_path, manifest),
        white_u=None if manifest.white is None else _white_u(manifest, fit_grid, certified, manifest_path),
    )


def _white_u(manifest: Manifest, grid: np.ndarray, certified: np.ndarray, manifest_path: Path) -> np.ndarray:
    """Relative standard uncertainty u(R_white) / R_white (n,) of the white standard: the manifest's
    ``white.uncertainty`` (a fraction, or PATH:COLUMN), else :data:`kmpipe.formats.manifest.WHITE_UNCERTAINTY`."""
    given = manifest.white.uncertainty
    if given is None:
        kind = "builtin" if manifest.white.certified.startswith("builtin:") else "certificate"
        return WHITE_UNCERTAINTY[kind] / certified
    if not isinstance(given, str):
        return float(given) / certified
    try:
        return certified_uncertainty(given, grid, base_dir=manifest_path.parent) / certified
    except InputError as err:
        raise named_in(
            err, manifest_path, "white.uncertainty", field_line(manifest_path, "white.uncertainty")
        ) from None
