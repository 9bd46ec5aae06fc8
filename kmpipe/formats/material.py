"""Fitted materials and their JSON file (``kmpipe-material``, documented in docs/formats.md).

A material is what ``kmpipe fit`` writes and what validation and rendering read: K and S per mm on a
wavelength grid (or per camera channel), with flags, standard errors, residuals and provenance.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.atomic_write import write_text_atomically
from kmpipe.formats.files import name_problem
from kmpipe.formats.material_budget import budget_from_dict, budget_to_dict
from kmpipe.physics.fit_covariance import Budget
from kmpipe.physics.flags import Flag, wavelengths_by_flag

FORMAT = "kmpipe-material/1"
#: The K/S convention a material states (thesis eq. 3.7; the radiative-transfer one has 4 R_inf).
KS_CONVENTION = "Kubelka-Munk: K/S = (1 - R_inf)^2 / (2 R_inf)"
#: Largest K or S a material may hold (1/mm): one absorption or scattering event per nm of film, far beyond any
#: pigment film, and small enough that the forward model's products (K X)^2 stay finite.
MAX_COEFFICIENT_PER_MM = 1e9
#: Largest film thickness a material's measurement may give (mm); the manifests' limit (kmpipe.formats.manifest).
MAX_THICKNESS_MM = 100.0
#: Most entries of a material's grid, and the longest wavelength (nm) it may hold.
MAX_GRID_POINTS = 100_000
MAX_WAVELENGTH_NM = 1e6
#: Largest residual (predicted - measured reflectance) a material may hold: readings lie in [0, 1.5].
MAX_RESIDUAL = 1.5


class ResidualFigures:
    """RMSE and where the largest error is, for anything with ``residuals`` (predicted - measured)."""

    residuals: np.ndarray

    @property
    def rmse(self) -> float:
        return float(np.sqrt(np.mean(self.residuals**2)))

    @property
    def max_abs_index(self) -> int:
        return int(np.argmax(np.abs(self.residuals)))


@dataclass(frozen=True)
class MeasurementFit(ResidualFigures):
    """How well the material reproduces one measurement (residual = predicted - measured reflectance)."""

    id: str
    role: str
    over: str | None
    thickness_mm: float
    residuals: np.ndarray


@dataclass(frozen=True)
class Material:
    """K and S (per mm) of one sample, as fitted, with what a reviewer needs to trust them."""

    name: str
    product: str
    kind: str
    wavelengths: np.ndarray | None  # nm
    channels: tuple[str, ...] | None
    K: np.ndarray
    S: np.ndarray
    K_stderr: np.ndarray | None
    S_stderr: np.ndarray | None
    flags: np.ndarray
    method: str
    saunderson: tuple[float, float] | None
    fit: dict
    measurements: tuple[MeasurementFit, ...]
    provenance: dict = field(default_factory=dict)
    budget: Budget | None = None  # the uncertainty budget of K and S (kmpipe.physics.fit_covariance)

    @property
    def labels(self) -> list:
        return [float(w) for w in self.wavelengths] if self.wavelengths is not None else list(self.channels)

    @property
    def ks_ratio(self) -> np.ndarray:
        """K/S, finite wherever S > 0 (where S = 0, K/S of a pure absorber is reported as inf)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.S > 0.0, self.K / np.where(self.S > 0.0, self.S, 1.0), np.inf)


def _numbers(values) -> list:
    """Floats for JSON; non-finite values (an unbounded standard error) become null."""
    return [float(v) if math.isfinite(v) else None for v in np.asarray(values, dtype=np.float64)]


def material_to_dict(material: Material) -> dict:
    """The JSON document of a material."""
    labels = material.labels
    ks = material.ks_ratio
    return {
        "format": FORMAT,
        "name": material.name,
        "product": material.product,
        "kind": material.kind,
        "grid": {"wavelengths_nm": labels} if material.wavelengths is not None else {"channels": labels},
        "units": {"K": "1/mm", "S": "1/mm", "thickness": "mm"},
        "ks_convention": KS_CONVENTION,
        "K": _numbers(material.K),
        "S": _numbers(material.S),
        "K_stderr": None if material.K_stderr is None else _numbers(material.K_stderr),
        "S_stderr": None if material.S_stderr is None else _numbers(material.S_stderr),
        "ks_ratio": _numbers(ks),
        "flags": wavelengths_by_flag(material.flags, labels),
        "method": material.method,
        "saunderson": None
        if material.saunderson is None
        else {"k1": material.saunderson[0], "k2": material.saunderson[1]},
        "fit": material.fit,
        "measurements": [
            {
                "id": m.id,
                "role": m.role,
                "over": m.over,
                "thickness_mm": None if not math.isfinite(m.thickness_mm) else m.thickness_mm,
                "rmse": m.rmse,
                "max_abs_residual": float(abs(m.residuals[m.max_abs_index])),
                "max_abs_residual_at": labels[m.max_abs_index],
                "residuals": _numbers(m.residuals),
            }
            for m in material.measurements
        ],
        "provenance": material.provenance,
        **({} if material.budget is None else {"uncertainty": budget_to_dict(material.budget)}),
    }


def write_material(material: Material, path: str | Path) -> None:
    """Write the material's JSON atomically (a temporary file in the same folder, then rename).

    The document is checked as :func:`read_material` checks it before anything is written, so a material that
    could not be read back (a non-finite or out-of-range K or S, a residual that is not finite) is an InputError
    naming the output file and the field, and no file is written.

    >>> import kmpipe, pathlib, tempfile, numpy as np
    >>> from kmpipe.formats.sample import load_sample
    >>> from kmpipe.stages.fit import fit_sample
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> sample = load_sample(F1 / "manifest.toml")
    >>> material = fit_sample(sample, method="black-white")
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "F1.json"
    >>> write_material(material, path)
    >>> again = read_material(path)
    >>> again.name, bool(np.array_equal(again.K, material.K) and np.array_equal(again.S, material.S))
    ('F1', True)
    """
    path = Path(path)
    document = material_to_dict(material)
    _check_document(document, path)
    field = _non_finite(document, "")
    if field is not None:
        raise InputError(f"the fit of {material.name!r} gave a value that is not a finite number: the readings "
                         "cannot be explained by the model; nothing was written", path=path, field=field)  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomically(path, json.dumps(document, indent=1, allow_nan=False) + "\n")


def read_material(path: str | Path) -> Material:
    """Read a material JSON written by :func:`write_material`; InputError naming the file and the field on any
    problem: a file that is not a regular file of at most ``files.LIMITS["material"]`` bytes, not UTF-8 JSON
    (``NaN`` and ``Infinity`` included), nested deeper than JSON parsing allows, or a document that breaks a rule
    of docs/formats.md ("Material JSON"): every field is checked for its type and range where it is read.

    >>> import pathlib, tempfile
    >>> broken = pathlib.Path(tempfile.mkdtemp()) / "broken.json"
    >>> _ = broken.write_text('{"format": "kmpipe-material/1", "K": [NaN]}')
    >>> try:
    ...     read_material(broken)
    ... except InputError as err:
    ...     print(err.message)
    not a kmpipe material: not valid JSON: NaN is not a JSON number (JSON has no NaN or Infinity)
    """
    path = Path(path)
    return _check_document(files.read_json(path, "material", "kmpipe material"), path)


class _Fields:
    """Checked access to the fields of a material document: each problem an InputError naming the field."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, field: str, message: str):
        raise InputError(message, path=self.path, field=field)

    def get(self, table: dict, key: str, where: str, default=...):
        if not isinstance(table, dict):
            self.fail(where or key, f"expected an object, got {_kind(table)}")
        if key not in table:
            if default is ...:
                self.fail(_join(where, key), "missing field")
            return default
        return table[key]

    def text(self, value, field: str, *, optional: bool = False) -> str | None:
        if value is None and optional:
            return None
        if not isinstance(value, str):
            self.fail(field, f"expected text, got {_kind(value)}")
        return value

    def number(self, value, field: str, lo: float, hi: float, *, low_open: bool = False, null: bool = False):
        """A finite number in [lo, hi] (``(lo, hi]`` with ``low_open``), or None where ``null`` allows it."""
        if value is None and null:
            return None
        if isinstance(value, bool) or not isinstance(value, int | float):
            self.fail(field, f"expected a number, got {_kind(value)}")
        try:
            number = float(value)
        except OverflowError:
            number = math.inf
        if not (math.isfinite(number) and (lo < number if low_open else lo <= number) and number <= hi):
            self.fail(field, f"expected a finite number in {'(' if low_open else '['}{lo:g}, {hi:g}], got {value!r}")
        return number

    def numbers(self, values, field: str, n: int, lo: float, hi: float, *, null: bool = False) -> np.ndarray:
        """n numbers (see :meth:`number`) as float64; a null, where allowed, reads as +inf."""
        if not isinstance(values, list) or len(values) != n:
            length = f"a list of {len(values)}" if isinstance(values, list) else _kind(values)
            self.fail(field, f"expected a list of {n} numbers (one per grid entry), got {length}")
        out = [self.number(v, f"{field}[{i + 1}]", lo, hi, null=null) for i, v in enumerate(values)]
        return np.array([math.inf if v is None else v for v in out], dtype=np.float64)


def _kind(value) -> str:
    if value is None:
        return "null"
    names = {bool: "a boolean", str: "text", list: "a list", dict: "an object", int: "a number", float: "a number"}
    shown = repr(value) if not isinstance(value, list | dict) else ""
    return f"{names.get(type(value), type(value).__name__)} {shown}".strip()[:80]


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def _check_grid(grid, check: _Fields) -> tuple[np.ndarray | None, tuple[str, ...] | None]:
    """The grid's wavelengths (nm: finite, positive, strictly increasing) or channel names (unique text)."""
    if not isinstance(grid, dict) or len(grid) != 1 or not set(grid) <= {"wavelengths_nm", "channels"}:
        check.fail("grid", 'expected {"wavelengths_nm": [...]} or {"channels": [...]}')
    if "wavelengths_nm" in grid:
        values = grid["wavelengths_nm"]
        if not isinstance(values, list) or not 1 <= len(values) <= MAX_GRID_POINTS:
            check.fail("grid.wavelengths_nm", f"expected a list of 1 to {MAX_GRID_POINTS} wavelengths (nm)")
        wavelengths = check.numbers(values, "grid.wavelengths_nm", len(values), 0.0, MAX_WAVELENGTH_NM)
        if wavelengths[0] <= 0.0 or np.any(np.diff(wavelengths) <= 0.0):
            check.fail("grid.wavelengths_nm", "wavelengths must be positive and strictly increasing (nm)")
        return wavelengths, None
    channels = grid["channels"]
    if not isinstance(channels, list) or not 1 <= len(channels) <= MAX_GRID_POINTS:
        check.fail("grid.channels", f"expected a list of 1 to {MAX_GRID_POINTS} channel names")
    for i, name in enumerate(channels):
        if not isinstance(name, str) or not name:
            check.fail(f"grid.channels[{i + 1}]", f"expected a channel name (non-empty text), got {_kind(name)}")
    if len(set(channels)) != len(channels):
        check.fail("grid.channels", "channel names must differ")
    return None, tuple(channels)


def _check_flags(flags, labels: list, check: _Fields) -> np.ndarray:
    """The flag bits per grid entry from ``{flag name: [labels]}``."""
    out = np.zeros(len(labels), dtype=np.uint8)
    if not isinstance(flags, dict):
        check.fail("flags", f"expected an object {{flag name: [wavelengths or channels]}}, got {_kind(flags)}")
    index = {label: i for i, label in enumerate(labels)}
    for name, where in flags.items():
        try:
            bit = Flag[name.upper()]
        except KeyError:
            check.fail(f"flags.{name}", f"unknown flag; expected one of {', '.join(f.name.lower() for f in Flag)}")
        if not isinstance(where, list):
            check.fail(f"flags.{name}", f"expected a list of wavelengths or channels, got {_kind(where)}")
        for i, label in enumerate(where):
            if isinstance(label, bool) or not isinstance(label, str | int | float) or label not in index:
                check.fail(f"flags.{name}[{i + 1}]", f"{_kind(label)} is not a wavelength or channel of the grid")
            out[index[label]] |= np.uint8(bit)
    return out


def _check_measurement(entry, i: int, n: int, check: _Fields) -> MeasurementFit:
    where = f"measurements[{i + 1}]"
    role = check.text(check.get(entry, "role", where), f"{where}.role")
    if role not in ("masstone", "film"):
        check.fail(f"{where}.role", f"expected 'masstone' or 'film', got {role!r}")
    thickness = check.number(check.get(entry, "thickness_mm", where), f"{where}.thickness_mm", 0.0,
                             MAX_THICKNESS_MM, low_open=True, null=True)  # fmt: skip
    if (thickness is None) != (role == "masstone"):
        check.fail(f"{where}.thickness_mm", "a masstone has null (infinite) thickness, a film a number of mm")
    return MeasurementFit(
        id=check.text(check.get(entry, "id", where), f"{where}.id"),
        role=role,
        over=check.text(check.get(entry, "over", where), f"{where}.over", optional=True),
        thickness_mm=math.inf if thickness is None else thickness,
        residuals=check.numbers(
            check.get(entry, "residuals", where), f"{where}.residuals", n, -MAX_RESIDUAL, MAX_RESIDUAL
        ),
    )


def _check_provenance(provenance, check: _Fields) -> dict:
    """Provenance: an object whose ``manifest`` (if any) is text and whose ``inputs`` (if any) are
    ``{"path": text, "sha256": text}`` objects (validation reads them)."""
    if not isinstance(provenance, dict):
        check.fail("provenance", f"expected an object, got {_kind(provenance)}")
    check.text(provenance.get("manifest"), "provenance.manifest", optional=True)
    inputs = provenance.get("inputs", [])
    if not isinstance(inputs, list):
        check.fail("provenance.inputs", f"expected a list, got {_kind(inputs)}")
    for i, entry in enumerate(inputs):
        for key in ("path", "sha256"):
            check.text(check.get(entry, key, f"provenance.inputs[{i + 1}]"), f"provenance.inputs[{i + 1}].{key}")
    return provenance


def _non_finite(value, where: str) -> str | None:
    """The field of the first NaN or infinite number in a JSON-like value, or None."""
    if isinstance(value, float) and not math.isfinite(value):
        return where
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for key, item in items:
        found = _non_finite(item, f"{where}[{key + 1}]" if isinstance(key, int) else _join(where, key))
        if found is not None:
            return found
    return None


def _check_document(doc, path: Path) -> Material:
    """The Material a material document describes; InputError naming the field of the first broken rule."""
    check = _Fields(path)
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        check.fail("format", f'not a kmpipe material (expected "format": "{FORMAT}")')
    name = check.text(check.get(doc, "name", ""), "name")
    problem = name_problem(name)
    if problem is not None:
        check.fail("name", problem)
    wavelengths, channels = _check_grid(check.get(doc, "grid", ""), check)
    labels = [float(w) for w in wavelengths] if wavelengths is not None else list(channels)
    n = len(labels)
    K = check.numbers(check.get(doc, "K", ""), "K", n, 0.0, MAX_COEFFICIENT_PER_MM)
    S = check.numbers(check.get(doc, "S", ""), "S", n, 0.0, MAX_COEFFICIENT_PER_MM)
    stderr = {}
    for key in ("K_stderr", "S_stderr"):
        value = check.get(doc, key, "")
        stderr[key] = None if value is None else check.numbers(value, key, n, 0.0, math.inf, null=True)
    saunderson = check.get(doc, "saunderson", "")
    if saunderson is not None:
        saunderson = tuple(
            check.number(check.get(saunderson, k, "saunderson"), f"saunderson.{k}", 0.0, 1.0) for k in ("k1", "k2")
        )
        if max(saunderson) >= 1.0:
            check.fail("saunderson", f"Saunderson constants k1, k2 must each lie in [0, 1), got {saunderson}")
    fit = check.get(doc, "fit", "")
    if not isinstance(fit, dict):
        check.fail("fit", f"expected an object, got {_kind(fit)}")
    provenance = _check_provenance(check.get(doc, "provenance", "", {}), check)
    measurements = check.get(doc, "measurements", "")
    if not isinstance(measurements, list):
        check.fail("measurements", f"expected a list, got {_kind(measurements)}")
    budget = check.get(doc, "uncertainty", "", None)
    if budget is not None:
        budget = budget_from_dict(budget, K, S, check.fail)
    return Material(
        name=name,
        product=check.text(check.get(doc, "product", "", ""), "product"),
        kind=check.text(check.get(doc, "kind", "", ""), "kind"),
        wavelengths=wavelengths,
        channels=channels,
        K=K,
        S=S,
        K_stderr=stderr["K_stderr"],
        S_stderr=stderr["S_stderr"],
        flags=_check_flags(check.get(doc, "flags", ""), labels, check),
        method=check.text(check.get(doc, "method", ""), "method"),
        saunderson=saunderson,
        fit=fit,
        measurements=tuple(_check_measurement(m, i, n, check) for i, m in enumerate(measurements)),
        provenance=provenance,
        budget=budget,
    )
