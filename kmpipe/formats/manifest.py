"""Sample manifests (TOML): what was measured for one sample, and how to fit it.

The format is documented in ``docs/formats.md`` ("Sample manifest"). Parsing is strict (unknown keys are
errors, so a typo never silently drops a setting) and every error names the file, the line and the field.
"""

from __future__ import annotations

import math
import re
from decimal import Decimal, DecimalException
from pathlib import Path
from typing import Annotated, Literal

from pydantic import AfterValidator, Field, ValidationError, field_validator, model_validator

from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.spectral_grid import uniform_grid
from kmpipe.formats.toml_input import (
    StrictModel,
    field_line,
    first_validation_error,
    format_field,
    read_toml,
    toml_line,
)

METHODS = ("two-constant", "black-white", "lsq")
#: Standard uncertainty (k = 1) of a white standard's reflectance where the manifest states none: the typical curve
#: (``builtin:baso4``) stands for a pressed BaSO4 that may differ from it by about 1 %; a certificate's own figure is
#: usually 0.3-0.5 %.
WHITE_UNCERTAINTY = {"builtin": 0.01, "certificate": 0.005}
#: Thickest film a TOML format may give (mm): far beyond any drawdown, small enough that (K X)^2 stays finite for
#: every K a material may hold.
MAX_THICKNESS_MM = 100.0
#: Largest ``[fit] smoothness``: the penalty then outweighs any misfit by 12 orders of magnitude.
MAX_SMOOTHNESS = 1e6
#: Longest wavelength (nm) a ``[fit] grid`` may reach.
MAX_GRID_NM = 100_000.0

_LENGTH_UNITS_MM = {
    "nm": Decimal("1e-6"),
    "um": Decimal("1e-3"),
    "µm": Decimal("1e-3"),
    "μm": Decimal("1e-3"),
    "mm": Decimal(1),
}
_PLUS_MINUS = ("+-", "±", "+/-")
_LENGTH = re.compile(r"^\s*([-+]?[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*([a-zµμ]+)\s*$")


def parse_thickness_mm(text: str, *, allow_zero: bool = False) -> float:
    """'30 um', '0.03 mm', '30000 nm' -> thickness in mm (> 0, or >= 0 with ``allow_zero``; at most
    :data:`MAX_THICKNESS_MM`).

    Raises ValueError with what was expected.
    """
    if any(mark in str(text) for mark in _PLUS_MINUS):
        raise ValueError(
            f"takes no uncertainty, got {text!r}: a '+-' belongs to a measured film's thickness (a [[film]] of a "
            "manifest or a plan); a masstone is fitted as opaque and a render thickness is exact"
        )
    match = _LENGTH.match(str(text))
    if not match or match.group(2) not in _LENGTH_UNITS_MM:
        raise ValueError(
            f"expected a thickness with a unit, like '30 um' or '0.03 mm' (units: nm, um, mm), got {text!r}"
        )
    # Decimal arithmetic, so that '25000 nm', '25 um' and '0.025 mm' give the same float (repeats group by it).
    try:
        value = float(Decimal(match.group(1)) * _LENGTH_UNITS_MM[match.group(2)])
    except DecimalException:  # an exponent beyond Decimal's range
        value = math.inf
    if not ((value >= 0.0 if allow_zero else value > 0.0) and value <= MAX_THICKNESS_MM):
        raise ValueError(
            f"thickness must be {'>= 0' if allow_zero else '> 0'} and at most {MAX_THICKNESS_MM:g} mm, got {text!r}"
        )
    return value


def parse_measured_thickness(text: str) -> tuple[float, float]:
    """A measured film's thickness: '30 um' -> (0.03, 0.0); '30 um +- 2 um' or '30 um ± 2 um' -> (0.03, 0.002);
    '30 um +- 5 %' -> (0.03, 0.0015). The uncertainty is a standard uncertainty (one standard deviation, k = 1), in
    mm; 0 when none is stated. Raises ValueError with what was expected.

    >>> parse_measured_thickness("30 um +- 2 um")
    (0.03, 0.002)
    """
    text = str(text)
    mark = next((m for m in _PLUS_MINUS if m in text), None)
    if mark is None:
        return parse_thickness_mm(text), 0.0
    value_text, _, doubt = text.partition(mark)
    value = parse_thickness_mm(value_text)
    doubt = doubt.strip()
    percent = re.match(r"^([-+]?[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*%$", doubt)
    try:
        u = value * float(percent.group(1)) / 100.0 if percent else parse_thickness_mm(doubt, allow_zero=True)
    except ValueError:
        u = math.nan
    if not (math.isfinite(u) and 0.0 <= u < value):
        raise ValueError(
            f"expected a thickness and its standard uncertainty, like '30 um +- 2 um' or '30 um +- 5 %' (an "
            f"uncertainty >= 0 and below the thickness), got {text!r}"
        )
    return value, u


def _checked_measured(value: str) -> str:
    parse_measured_thickness(value)
    return value


def _checked_thickness(value: str) -> str:
    parse_thickness_mm(value)
    return value


def _checked_thickness_or_zero(value: str) -> str:
    parse_thickness_mm(value, allow_zero=True)
    return value


#: A measured film's thickness, with an optional standard uncertainty ("30 um +- 2 um"): manifests and plans.
MeasuredThickness = Annotated[str, AfterValidator(_checked_measured)]
#: A thickness field as people write it ("30 um", "0.03 mm"), checked on reading; every TOML format uses it.
Thickness = Annotated[str, AfterValidator(_checked_thickness)]
#: The same, where no film at all ("0 um") makes sense: render scenes.
ThicknessOrZero = Annotated[str, AfterValidator(_checked_thickness_or_zero)]


def parse_grid(text: str) -> tuple[float, float, float]:
    """'400:700:10' -> (400, 700, 10) in nm: start, stop (inclusive), and a step that fits a whole number
    of times between them."""
    parts = str(text).split(":")
    try:
        start, stop, step = (float(p) for p in parts)
    except ValueError:
        raise ValueError(f"expected START:STOP:STEP in nm, like '400:700:10', got {text!r}") from None
    if not (0.0 < start < stop <= MAX_GRID_NM and step > 0.0):
        raise ValueError(f"grid needs 0 < START < STOP <= {MAX_GRID_NM:g} nm and STEP > 0, got {text!r}")
    try:
        uniform_grid(*parts)
    except InputError as err:
        raise ValueError(err.message) from None
    return start, stop, step


def _file_name(value: str) -> str:
    """A name that becomes a file name (:func:`kmpipe.formats.files.name_problem`)."""
    problem = files.name_problem(value)
    if problem is not None:
        raise ValueError(problem)
    return value


#: A name that becomes a file name (a sample's, a scene's): no '/', '\\', control characters, not '.' or '..'.
FileName = Annotated[str, AfterValidator(_file_name)]


class SampleInfo(StrictModel):
    name: FileName
    product: str = ""
    kind: str = ""


def _path_text(value: str) -> str:
    """A path the system can look up: no NUL character (every call on such a name raises, before any file is seen)."""
    if "\0" in value:
        raise ValueError(f"a file path holds no NUL character, got {value!r}")
    return value


#: A file's path as a manifest gives it (relative to the manifest): non-empty, no NUL character.
PathText = Annotated[str, Field(min_length=1), AfterValidator(_path_text)]


class ColumnRef(StrictModel):
    """A column of a spectral CSV, the file relative to the manifest."""

    file: PathText
    column: str = Field(min_length=1)


class WhiteReference(ColumnRef):
    certified: PathText = "builtin:baso4"
    dark: ColumnRef | None = None
    #: Standard uncertainty of the certified reflectance (k = 1): a fraction, or a CSV 'PATH:COLUMN' of one per
    #: wavelength; None: :data:`WHITE_UNCERTAINTY` of the kind of certificate.
    uncertainty: float | str | None = None

    @field_validator("uncertainty")
    @classmethod
    def _uncertainty(cls, value):
        if isinstance(value, bool) or (isinstance(value, float | int) and not (0.0 <= value <= 0.1)):
            raise ValueError(
                f"expected a standard uncertainty in [0, 0.1] (a fraction) or 'PATH:COLUMN', got {value!r}"
            )
        if isinstance(value, str) and not value.strip():
            raise ValueError("expected a standard uncertainty in [0, 0.1] (a fraction) or 'PATH:COLUMN'")
        return value


class Backing(ColumnRef):
    name: str = Field(min_length=1)


class Masstone(ColumnRef):
    """An opaque layer of the sample; ``thickness`` (optional) lets validation check that it is opaque."""

    thickness: Thickness | None = None

    @property
    def thickness_mm(self) -> float | None:
        return None if self.thickness is None else parse_thickness_mm(self.thickness)


class Film(ColumnRef):
    over: str = Field(min_length=1)
    thickness: MeasuredThickness

    @property
    def thickness_mm(self) -> float:
        return parse_measured_thickness(self.thickness)[0]

    @property
    def thickness_u_mm(self) -> float:
        """Standard uncertainty of the thickness (mm); 0 where the manifest states none."""
        return parse_measured_thickness(self.thickness)[1]


class FitSettings(StrictModel):
    method: Literal["two-constant", "black-white", "lsq"] = "lsq"
    grid: str | None = None
    saunderson: tuple[float, float] | None = None
    noise: float | None = Field(default=None, gt=0.0, lt=0.5)
    smoothness: float = Field(default=0.0, ge=0.0, le=MAX_SMOOTHNESS)
    opaque_tolerance: float = Field(default=1e-3, gt=0.0, lt=0.5)

    @field_validator("grid")
    @classmethod
    def _grid(cls, value: str | None) -> str | None:
        if value is not None:
            parse_grid(value)
        return value

    @field_validator("saunderson")
    @classmethod
    def _saunderson(cls, value):
        if value is not None and not all(0.0 <= k < 1.0 for k in value):
            raise ValueError("Saunderson constants [k1, k2] must each lie in [0, 1), e.g. [0.04, 0.6]")
        return value


class Manifest(StrictModel):
    sample: SampleInfo
    white: WhiteReference | None = None
    backing: list[Backing] = Field(default_factory=list)
    masstone: list[Masstone] = Field(default_factory=list)
    film: list[Film] = Field(min_length=1)
    fit: FitSettings = FitSettings()

    @model_validator(mode="after")
    def _references(self) -> Manifest:
        names = [b.name for b in self.backing]
        for i, name in enumerate(names):
            if name in names[:i]:
                raise _LocatedError(("backing", i, "name"), f"backing name {name!r} is used twice")
        for i, film in enumerate(self.film):
            if film.over not in names:
                known = ", ".join(repr(n) for n in names) or "none is defined"
                raise _LocatedError(("film", i, "over"), f"names backing {film.over!r}, but the backings are: {known}")
        return self

    def references(self) -> list[tuple[str, ColumnRef]]:
        """The CSV columns the manifest names, by field (``white``, ``white.dark``, ``backing[1]``, ...,
        ``masstone[1]``, ..., ``film[1]``, ...), in the order a sample is read."""
        refs: list[tuple[str, ColumnRef]] = []
        if self.white is not None:
            refs.append(("white", self.white))
            if self.white.dark is not None:
                refs.append(("white.dark", self.white.dark))
        refs += [(f"backing[{i + 1}]", b) for i, b in enumerate(self.backing)]
        refs += [(f"masstone[{i + 1}]", m) for i, m in enumerate(self.masstone)]
        refs += [(f"film[{i + 1}]", f) for i, f in enumerate(self.film)]
        return refs


class _LocatedError(ValueError):
    """A cross-field error that knows which field it belongs to."""

    def __init__(self, loc: tuple, message: str) -> None:
        super().__init__(message)
        self.loc = loc
        self.message = message


def load_manifest(path: str | Path) -> Manifest:
    """Read and validate a sample manifest; InputError (file, line, field) on any problem.

    >>> import kmpipe, pathlib
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> manifest = load_manifest(F1 / "manifest.toml")
    >>> manifest.sample.name, [b.name for b in manifest.backing], len(manifest.film), manifest.fit.method
    ('F1', ['black', 'white'], 4, 'lsq')
    """
    path = Path(path)
    text, data = read_toml(path, "sample manifest")
    try:
        return Manifest.model_validate(data)
    except ValidationError as err:
        first = first_validation_error(err)
        loc = tuple(first["loc"])
        message = first["msg"]
        context = first.get("ctx", {}).get("error")
        if isinstance(context, _LocatedError):
            loc, message = context.loc, context.message
        elif first["type"] == "extra_forbidden":
            message = "unknown field (check its spelling; see docs/formats.md for the manifest's fields)"
        elif first["type"] == "missing":
            message = "is required but missing"
        message = message.removeprefix("Value error, ")
        more = len(err.errors()) - 1
        suffix = f" ({more} more problem{'s' if more > 1 else ''} after this one)" if more else ""
        raise InputError(message + suffix, path=path, line=toml_line(text, loc), field=format_field(loc)) from None


def manifest_files(path: str | Path, manifest: Manifest | None = None) -> tuple[Path, ...]:
    r"""Every file a fit of the manifest at ``path`` reads, without reading any data: the manifest (resolved), then
    each CSV it names once, in the order they are read, then the white standard's certificate when it is a file.

    This is the list a cache hashes (``kmpipe run``) and a material's provenance records. ``manifest``: the already
    validated manifest, to save reading it again.

    >>> import tempfile, pathlib
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (folder / "m.toml").write_text(
    ...     '[sample]\nname = "F1"\n[[backing]]\nname = "black"\nfile = "cards.csv"\ncolumn = "black"\n'
    ...     '[[film]]\nfile = "films.csv"\ncolumn = "f1"\nover = "black"\nthickness = "30 um"\n')
    >>> [p.name for p in manifest_files(folder / "m.toml")]
    ['m.toml', 'cards.csv', 'films.csv']
    """
    from kmpipe.physics.white import BUILTIN_BASO4, certified_file

    path = Path(path)
    manifest = manifest if manifest is not None else load_manifest(path)
    found = [path.resolve()]
    for _, ref in manifest.references():
        data = (path.parent / ref.file).resolve()
        if data not in found:
            found.append(data)
    white = manifest.white
    named = [] if white is None else [("certified", white.certified), ("uncertainty", white.uncertainty)]
    for key, spec in named:  # the certificate and its uncertainty, where they are files
        if not isinstance(spec, str) or spec == BUILTIN_BASO4:
            continue
        try:
            table = certified_file(spec, path.parent)[0].resolve()
        except InputError as err:
            raise InputError(err.message, path=path, line=field_line(path, f"white.{key}"),
                             field=f"white.{key}") from None  # fmt: skip
        if table not in found:
            found.append(table)
    return tuple(found)
