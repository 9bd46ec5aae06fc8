"""Validate a fitted material against the measurements it was fitted from.

:func:`validate_material` re-reads the sample (through the manifest named in the material's provenance),
predicts every measurement from K and S, and reports per measurement the spectral residual and the colour
difference (Delta E 2000 under each chosen illuminant), the spread of repeated readings, a list of findings
(each check with a reason code, the wavelengths it concerns and a one-line explanation) and a verdict:
``pass``, ``warn`` or ``fail``. The checks are those of :data:`kmpipe.validation.checks.CHECKS`;
``docs/formats.md`` documents the ``validation.json`` document that
:func:`kmpipe.validation.findings.report_to_dict` gives.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from kmpipe.errors import InputError
from kmpipe.formats.material import read_material
from kmpipe.formats.sample import Sample, load_sample
from kmpipe.formats.scene import SubstrateInfo, resolve_reflectance
from kmpipe.formats.thresholds import Thresholds
from kmpipe.physics.colorimetry import delta_E_2000, reflectance_to_Lab
from kmpipe.physics.flags import Flag
from kmpipe.physics.joint_fit import predict_readings
from kmpipe.physics.saunderson import saunderson_inverse
from kmpipe.validation.checks import (
    changed_inputs,
    check_coefficients,
    check_inputs,
    check_masstones,
    check_readings,
    check_residuals,
    check_thickness_series,
    check_thresholds,
)
from kmpipe.validation.findings import MeasurementCheck, SampleReport
from kmpipe.validation.noise import noise_map, repeat_spread
from kmpipe.validation.uncertainty import (
    DRAWS,
    RenderContext,
    check_uncertainty,
    default_context,
    uncertainty_findings,
)


def repeat_groups(sample: Sample) -> dict[tuple, list[int]]:
    """Measurements that repeat one another: (role, backing, thickness in mm) -> their indices, in order."""
    groups: dict[tuple, list[int]] = {}
    for i, m in enumerate(sample.measurements):
        groups.setdefault((m.role, m.over, m.thickness_mm), []).append(i)
    return groups


def group_name(key: tuple) -> str:
    """A repeat group's name in reports: ``masstone`` or ``20 um over black``."""
    role, over, thickness = key
    if role == "masstone":
        return "masstone"
    return f"{thickness * 1000:g} um over {over}"


def _manifest_of(material_path: Path, named: str | None) -> Path:
    """The manifest the material's provenance names, relative to the material's folder."""
    if not named:
        raise InputError(
            "names no manifest in its provenance; pass --manifest", path=material_path, field="provenance.manifest"
        )
    manifest = material_path.parent / named
    if not manifest.is_file():
        raise InputError(
            f"names the manifest {named}, which does not exist (looked for {manifest}); pass --manifest",
            path=material_path,
            field="provenance.manifest",
        )
    return manifest


def validate_material(
    material_path: str | Path,
    *,
    manifest: str | Path | None = None,
    illuminants: tuple[str, ...] = ("D65",),
    observer: str = "2",
    thresholds: Thresholds | None = None,
    contexts: list[dict] | None = None,
    draws: int = DRAWS,
) -> SampleReport:
    """Validate one MATERIAL.json against its measurements (``manifest``: default, the one its provenance names);
    see the module docstring. Delta E 2000 only for spectral materials, under each of ``illuminants`` with the CIE
    ``observer`` ("2" or "10"). InputError naming the file and field for a material or sample that cannot be read.

    ``contexts``: where the rendered colour's doubt is judged (:mod:`kmpipe.validation.uncertainty`), each a dict
    of ``thickness_mm``, ``over`` (a backing of the sample, or a reflectance as scenes give one: a number,
    ``colorchecker:NAME``, ``FILE.csv[:COLUMN]`` relative to ``base``), ``base`` and an optional ``label``; a
    thickness or ``over`` left None, and no context at all, mean the median measured film over the lightest backing.
    ``draws``: Monte Carlo draws of that check (0: linearized only).

    >>> import kmpipe, pathlib, tempfile
    >>> from kmpipe.stages.fit import fit_manifests
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> [(path, _)] = fit_manifests([F1 / "manifest.toml"], pathlib.Path(tempfile.mkdtemp()) / "F1.json")
    >>> report = validate_material(path, illuminants=("D65", "A"))
    >>> report.verdict, len(report.measurements), report.worst_delta_e < 1.0
    ('pass', 5, True)
    """
    material_path = Path(material_path)
    thresholds = thresholds or Thresholds()
    material = read_material(material_path)
    if manifest is None:
        manifest = _manifest_of(material_path, material.provenance.get("manifest"))
    manifest = Path(manifest).resolve()
    changed = changed_inputs(material, material_path)
    sample = load_sample(manifest, grid=material.wavelengths)
    labels = material.labels
    if sample.readings.shape[1] != len(labels):
        raise InputError(
            f"has {len(labels)} grid points but the sample's files give {sample.readings.shape[1]}",
            path=material_path,
            field="grid",
        )

    saunderson = material.saunderson
    backgrounds = np.array([sample.background_of(m) for m in sample.measurements])
    if saunderson is not None:
        backgrounds = saunderson_inverse(backgrounds, *saunderson)
    predicted = predict_readings(material.K, material.S, sample.thickness_mm, backgrounds, saunderson)
    spectral = material.wavelengths is not None
    delta_e: dict[str, np.ndarray] = {}
    if spectral:
        for illuminant in illuminants:
            measured_Lab = reflectance_to_Lab(sample.readings, material.wavelengths, illuminant, observer)
            predicted_Lab = reflectance_to_Lab(predicted, material.wavelengths, illuminant, observer)
            delta_e[illuminant] = delta_E_2000(measured_Lab, predicted_Lab)

    groups = repeat_groups(sample)
    spreads = {key: repeat_spread(sample.readings[rows]) for key, rows in groups.items() if len(rows) > 1}
    checks = []
    for i, m in enumerate(sample.measurements):
        key = (m.role, m.over, m.thickness_mm)
        checks.append(
            MeasurementCheck(
                id=m.id,
                role=m.role,
                over=m.over,
                thickness_mm=m.thickness_mm,
                measured=sample.readings[i],
                predicted=predicted[i],
                delta_e={name: float(values[i]) for name, values in delta_e.items()},
                repeat_group=group_name(key),
                repeat_count=len(groups[key]),
                repeat_spread=spreads.get(key),
            )
        )
    sigma, source = noise_map(sample.readings, groups.values())
    opaque = (material.flags & np.uint8(Flag.OPAQUE)) != 0

    uncertainty = None
    if spectral:
        resolved = [resolve_context(c, sample) for c in contexts] if contexts else [default_context(sample)]
        uncertainty = check_uncertainty(material, sample, resolved, tuple(illuminants), observer, draws)
    findings = [
        *check_inputs(changed),
        *check_thresholds(checks, thresholds),
        *check_coefficients(material, labels, thresholds),
        *check_readings(sample, labels),
        *check_thickness_series(sample, material, labels, sigma, thresholds.noise_factor),
        *check_masstones(sample, material, labels, sigma, thresholds.noise_factor),
        *check_residuals(checks, labels, thresholds, sigma, opaque),
        *([] if uncertainty is None else uncertainty_findings(uncertainty, labels, thresholds)),
    ]
    return SampleReport(
        material_path=material_path,
        manifest_path=manifest,
        material=material,
        labels=labels,
        spectral=spectral,
        illuminants=tuple(illuminants) if spectral else (),
        observer=observer,
        thresholds=thresholds,
        measurements=tuple(checks),
        backings=sample.backings,
        noise_sigma=float(np.median(sigma)),
        noise_source=source,
        findings=tuple(findings),
        changed_inputs=tuple(changed),
        uncertainty=uncertainty,
    )


def resolve_context(context: dict, sample: Sample) -> RenderContext:
    """A render context (see :func:`validate_material`) on the sample's grid; InputError naming ``--over``."""
    fallback = default_context(sample)
    over = context.get("over")
    thickness = fallback.thickness_mm if context.get("thickness_mm") is None else float(context["thickness_mm"])
    if over is None:
        return RenderContext(f"{thickness * 1000:g} um over {fallback.label.partition(' over ')[2]}", thickness,
                             fallback.substrate)  # fmt: skip
    label = context.get("label") or f"{thickness * 1000:g} um over {over}"
    if isinstance(over, str) and over in sample.backings:
        return RenderContext(label, thickness, np.minimum(sample.backings[over], 1.0))
    where = {"field": context.get("field", "--over")}
    with contextlib.suppress(ValueError):
        over = float(over)
    try:
        SubstrateInfo(reflectance=over)
    except ValidationError:
        raise InputError(f"expected a backing of the sample ({', '.join(sample.backings) or 'none'}), a reflectance "
                         f"in [0, 1], 'colorchecker:NAME' or 'FILE.csv[:COLUMN]', got {context['over']!r}",
                         **where) from None  # fmt: skip
    substrate = resolve_reflectance(over, sample.wavelengths, Path(context.get("base", ".")), where)
    return RenderContext(label, thickness, substrate)
