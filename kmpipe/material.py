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

from kmpipe.atomic_write import write_text_atomically
from kmpipe.errors import InputError
from kmpipe.flags import Flag, wavelengths_by_flag

FORMAT = "kmpipe-material/1"
KS_CONVENTION = "Kubelka-Munk: K/S = (1 - R_inf)^2 / (2 R_inf)"


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


def _array(values, what: str, path: Path, n: int, *, allow_null: bool = False) -> np.ndarray:
    if not isinstance(values, list) or len(values) != n:
        raise InputError(f"expected a list of {n} numbers", path=path, field=what)
    out = np.array([np.inf if v is None and allow_null else v for v in values], dtype=object)
    try:
        return out.astype(np.float64)
    except (TypeError, ValueError):
        raise InputError("expected numbers" + (" or null" if allow_null else ""), path=path, field=what) from None


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
    }


def write_material(material: Material, path: str | Path) -> None:
    """Write the material's JSON atomically (a temporary file in the same folder, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomically(path, json.dumps(material_to_dict(material), indent=1, allow_nan=False) + "\n")


def read_material(path: str | Path) -> Material:
    """Read a material JSON written by :func:`write_material`; InputError naming the field on any problem."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("the material file does not exist", path=path) from None
    except json.JSONDecodeError as err:
        raise InputError(f"not valid JSON: {err.msg}", path=path, line=err.lineno) from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputError(f'not a kmpipe material (expected "format": "{FORMAT}")', path=path, field="format")
    try:
        grid = doc["grid"]
        wavelengths = grid.get("wavelengths_nm")
        channels = grid.get("channels")
        labels = wavelengths if wavelengths is not None else channels
        n = len(labels)
        flags = np.zeros(n, dtype=np.uint8)
        index = {label: i for i, label in enumerate(labels)}
        for name, where in doc["flags"].items():
            try:
                bit = Flag[name.upper()]
            except KeyError:
                raise InputError(f"unknown flag {name!r}", path=path, field="flags") from None
            for label in where:
                flags[index[label]] |= np.uint8(bit)
        measurements = tuple(
            MeasurementFit(
                id=m["id"],
                role=m["role"],
                over=m["over"],
                thickness_mm=math.inf if m["thickness_mm"] is None else float(m["thickness_mm"]),
                residuals=_array(m["residuals"], f"measurements[{i + 1}].residuals", path, n),
            )
            for i, m in enumerate(doc["measurements"])
        )
        saunderson = doc["saunderson"]
        return Material(
            name=doc["name"],
            product=doc.get("product", ""),
            kind=doc.get("kind", ""),
            wavelengths=None if wavelengths is None else np.asarray(wavelengths, dtype=np.float64),
            channels=None if channels is None else tuple(channels),
            K=_array(doc["K"], "K", path, n),
            S=_array(doc["S"], "S", path, n),
            K_stderr=None if doc["K_stderr"] is None else _array(doc["K_stderr"], "K_stderr", path, n, allow_null=True),
            S_stderr=None if doc["S_stderr"] is None else _array(doc["S_stderr"], "S_stderr", path, n, allow_null=True),
            flags=flags,
            method=doc["method"],
            saunderson=None if saunderson is None else (float(saunderson["k1"]), float(saunderson["k2"])),
            fit=doc["fit"],
            measurements=measurements,
            provenance=doc.get("provenance", {}),
        )
    except KeyError as err:
        raise InputError(f"missing field {err.args[0]!r}", path=path, field=str(err.args[0])) from None
    except (TypeError, AttributeError):
        raise InputError("malformed material document (a field has the wrong type)", path=path) from None
