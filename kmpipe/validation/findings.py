"""What a validation finds: findings, per-measurement figures, the report of a sample and its ``validation.json``.

A :class:`SampleReport` (what :func:`kmpipe.validation.material.validate_material` returns) holds the figures of
every measurement (:class:`MeasurementCheck`) and the :class:`Finding` of each check that fired; its verdict is
the most severe finding's severity, ``pass`` when none fired. :func:`report_to_dict` gives the
``validation.json`` document (``kmpipe-validation/1``, docs/formats.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from kmpipe.formats.material import Material, ResidualFigures
from kmpipe.formats.thresholds import Thresholds

if TYPE_CHECKING:
    from kmpipe.validation.uncertainty import UncertaintyReport

FORMAT = "kmpipe-validation/1"

#: Verdicts and severities, least severe first.
SEVERITIES = ("pass", "warn", "fail")


@dataclass(frozen=True)
class Finding:
    """One check that fired: reason code, severity, one-line message, the wavelengths (or channels) concerned."""

    code: str
    severity: str  # "warn" | "fail"
    message: str
    where: list = field(default_factory=list)
    measurement: str | None = None


@dataclass(frozen=True)
class MeasurementCheck(ResidualFigures):
    """One measurement: measured and predicted reflectance, residual figures, colour differences, repeats."""

    id: str
    role: str
    over: str | None
    thickness_mm: float
    measured: np.ndarray
    predicted: np.ndarray
    delta_e: dict[str, float]  # illuminant -> Delta E 2000
    repeat_group: str
    repeat_count: int
    repeat_spread: float | None  # RMS over wavelength of the per-wavelength standard deviation of the repeats

    @property
    def residuals(self) -> np.ndarray:
        return self.predicted - self.measured


@dataclass(frozen=True)
class SampleReport:
    """Everything :func:`kmpipe.validation.material.validate_material` found for one material."""

    material_path: Path
    manifest_path: Path
    material: Material
    labels: list
    spectral: bool
    illuminants: tuple[str, ...]
    observer: str
    thresholds: Thresholds
    measurements: tuple[MeasurementCheck, ...]
    backings: dict[str, np.ndarray]
    noise_sigma: float
    noise_source: str
    findings: tuple[Finding, ...]
    changed_inputs: tuple[str, ...]
    uncertainty: UncertaintyReport | None = None  # the rendered colour's doubt (spectral materials)

    @property
    def verdict(self) -> str:
        worst = max((SEVERITIES.index(f.severity) for f in self.findings), default=0)
        return SEVERITIES[worst]

    @property
    def worst_delta_e(self) -> float | None:
        values = [v for m in self.measurements for v in m.delta_e.values()]
        return max(values) if values else None

    @property
    def reasons(self) -> list[str]:
        """Reason codes that fired, most severe first, each once."""
        ordered = sorted(self.findings, key=lambda f: -SEVERITIES.index(f.severity))
        return list(dict.fromkeys(f.code for f in ordered))


def format_ranges(labels: list, mask: np.ndarray) -> str:
    """'380-500, 620 nm' for spectral labels, 'R, G' for channels, from a boolean mask."""
    picked = [labels[i] for i in np.flatnonzero(mask)]
    if not picked:
        return ""
    if not isinstance(picked[0], float):
        return ", ".join(str(p) for p in picked)
    index = np.flatnonzero(mask)
    runs, start = [], index[0]
    for a, b in zip(index, [*index[1:], None], strict=True):
        if b is None or b != a + 1:
            runs.append(f"{labels[start]:g}" if start == a else f"{labels[start]:g}-{labels[a]:g}")
            if b is not None:
                start = b
    return ", ".join(runs) + " nm"


def labels_at(labels: list, mask: np.ndarray) -> list:
    """The labels (wavelengths or channels) a boolean mask picks: a finding's ``where``."""
    return [labels[i] for i in np.flatnonzero(mask)]


def _number(value: float | None):
    return None if value is None or not math.isfinite(value) else float(value)


def report_to_dict(report: SampleReport, *, html: str | None = None) -> dict:
    """The ``validation.json`` document (format in docs/formats.md); ``html``: the report page it goes with."""
    from kmpipe.validation.uncertainty import uncertainty_to_dict

    axis = "wavelengths_nm" if report.spectral else "channels"
    return {
        "format": FORMAT,
        "sample": report.material.name,
        "product": report.material.product,
        "material": str(report.material_path),
        "manifest": str(report.manifest_path),
        "verdict": report.verdict,
        "reasons": report.reasons,
        "worst_delta_e_2000": _number(report.worst_delta_e),
        "illuminants": list(report.illuminants),
        "observer": report.observer,
        "thresholds": {f.name: getattr(report.thresholds, f.name) for f in fields(report.thresholds)},
        "noise": {"sigma": report.noise_sigma, "source": report.noise_source},
        "inputs_changed": list(report.changed_inputs),
        "measurements": [
            {
                "id": c.id,
                "role": c.role,
                "over": c.over,
                "thickness_mm": _number(c.thickness_mm),
                "rmse": c.rmse,
                "max_abs_error": float(abs(c.residuals[c.max_abs_index])),
                "max_abs_error_at": report.labels[c.max_abs_index],
                "delta_e_2000": c.delta_e,
                "repeat_group": c.repeat_group,
                "repeats": c.repeat_count,
                "repeat_spread": c.repeat_spread,
            }
            for c in report.measurements
        ],
        "findings": [
            {
                "code": f.code,
                "severity": f.severity,
                "message": f.message,
                axis: f.where,
                "measurement": f.measurement,
            }
            for f in report.findings
        ],
        "uncertainty": None if report.uncertainty is None else uncertainty_to_dict(report.uncertainty, report.labels),
        "report_html": html,
    }
