"""The checks of a validation, each a function returning the :class:`~kmpipe.validation.findings.Finding` s it fired.

:data:`CHECKS` is the registry: every reason code with its severity and what it means for a technician
(docs/formats.md, "Checks", lists the same). A check never chooses a severity of its own: :func:`finding` takes it
from the registry, and a graded check (``warn/fail``) only says which of the registry's levels applies.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import NamedTuple

import numpy as np

from kmpipe.formats.files import is_regular, sha256
from kmpipe.formats.material import Material
from kmpipe.formats.sample import Sample
from kmpipe.formats.thresholds import Thresholds
from kmpipe.physics.flags import Flag
from kmpipe.physics.kubelka_munk import reflectance_infinite, reflectance_over_background
from kmpipe.physics.saunderson import saunderson_forward, saunderson_inverse
from kmpipe.validation.findings import Finding, MeasurementCheck, format_ranges, labels_at
from kmpipe.validation.noise import longest_run, runs_z


class Check(NamedTuple):
    """A check in the registry: its severity (``warn``, ``fail``, or ``warn/fail`` for one graded by thresholds)
    and what it means for a technician."""

    severity: str
    meaning: str

    @property
    def levels(self) -> tuple[str, ...]:
        return tuple(self.severity.split("/"))


#: Every check: reason code -> its severity and what it means.
CHECKS = {
    "delta_e": Check(
        "warn/fail",
        "a predicted colour differs from the measured one by more than the Delta E threshold",
    ),
    "rmse": Check(
        "warn/fail",
        "a predicted spectrum differs from the measured one by more than the RMSE threshold",
    ),
    "k_or_s_not_positive": Check(
        "warn",
        "K or S is 0: no absorption or no scattering, or noise pushed it below 0",
    ),
    "out_of_range": Check(
        "warn",
        "readings outside what the model and the backings allow; K, S moved to the boundary",
    ),
    "extreme_ks": Check("warn", "K/S outside the range cosmetic films show (a near-black or near-white material)"),
    "reflectance_out_of_range": Check("fail", "a measured reflectance outside [0, 1]: check the white reference"),
    "thickness_not_monotone": Check("fail", "a thicker film reads farther from the masstone than a thinner one"),
    "opaque": Check("warn", "the film hides its backing: thickness not identifiable, K and S are lower bounds"),
    "poor_conditioning": Check("warn", "large standard errors: the measurements barely determine K and S"),
    "structured_residuals": Check("warn", "residuals keep one sign over a long stretch: a bias, not noise"),
    "masstone_not_opaque": Check("fail", "the masstone is too thin to hide its backing, so it is not R_inf"),
    "residual_above_noise": Check("warn", "the fit misses repeated readings by far more than they differ"),
    "colour_uncertainty": Check(
        "warn/fail",
        "the rendered colour is known less well than the uncertainty threshold (95 % radius, Delta E 2000)",
    ),
    "uncertainty_nonlinear": Check(
        "warn",
        "the Monte Carlo and the linearized radius disagree: the model bends (a nearly opaque or transparent film)",
    ),
    "not_separable": Check("warn", "K and S cannot be told apart at some wavelengths: the radius covers K/S only"),
    "inputs_changed": Check("warn", "a measurement file changed since the fit: refit before trusting this report"),
}


def finding(
    code: str, message: str, where: list | None = None, measurement: str | None = None, *, level: str | None = None
) -> Finding:
    """The finding of check ``code``, its severity from :data:`CHECKS`; a graded check names its ``level``
    (one of the registry's). ValueError for a code or level the registry does not list (a bug, not bad input)."""
    levels = CHECKS[code].levels
    severity = levels[0] if level is None and len(levels) == 1 else level
    if severity not in levels:
        raise ValueError(f"check {code!r} has severities {'/'.join(levels)}, not {level!r}")
    return Finding(code, severity, message, [] if where is None else where, measurement)


def changed_inputs(material: Material, material_path: Path) -> list[str]:
    """The files of the material's provenance (paths relative to its folder) whose SHA-256 differs from the one
    recorded at the fit, or that are missing (``"PATH (missing)"``)."""
    changed = []
    for entry in material.provenance.get("inputs", []):
        path = material_path.parent / entry["path"]
        if not is_regular(path):
            changed.append(f"{entry['path']} (missing)")
        elif sha256(path) != entry["sha256"]:
            changed.append(entry["path"])
    return changed


def check_inputs(changed: list[str]) -> list[Finding]:
    """``inputs_changed`` when :func:`changed_inputs` found any."""
    if not changed:
        return []
    return [
        finding(
            "inputs_changed",
            f"{', '.join(changed)} changed since the fit (SHA-256 differs): refit before trusting this report",
        )
    ]


def check_thresholds(checks: list[MeasurementCheck], thresholds: Thresholds) -> list[Finding]:
    """``delta_e`` per measurement and illuminant, ``rmse`` per measurement: fail above the fail threshold, warn
    above the warn threshold."""
    out = []
    for c in checks:
        for illuminant, value in c.delta_e.items():
            level = "fail" if value > thresholds.delta_e_fail else "warn" if value > thresholds.delta_e_warn else None
            if level:
                limit = thresholds.delta_e_fail if level == "fail" else thresholds.delta_e_warn
                out.append(
                    finding(
                        "delta_e",
                        f"{c.id}: Delta E 2000 {value:.2f} under {illuminant} exceeds {limit:g}",
                        measurement=c.id,
                        level=level,
                    )
                )
        level = "fail" if c.rmse > thresholds.rmse_fail else "warn" if c.rmse > thresholds.rmse_warn else None
        if level:
            limit = thresholds.rmse_fail if level == "fail" else thresholds.rmse_warn
            out.append(
                finding("rmse", f"{c.id}: spectral RMSE {c.rmse:.4f} exceeds {limit:g}", measurement=c.id, level=level)
            )
    return out


def check_coefficients(material: Material, labels: list, thresholds: Thresholds) -> list[Finding]:
    """What K and S themselves show: ``k_or_s_not_positive``, the fit's ``out_of_range`` and ``opaque`` flags,
    ``extreme_ks`` (K/S outside [ks_min, ks_max]) and ``poor_conditioning`` (standard error of K or S above
    relative_stderr of its value, not where opaque or 0)."""
    out = []
    zero_k, zero_s = material.K <= 0.0, material.S <= 0.0
    if np.any(zero_k | zero_s):
        parts = []
        if zero_k.any():
            parts.append(f"K is 0 at {format_ranges(labels, zero_k)}")
        if zero_s.any():
            parts.append(f"S is 0 at {format_ranges(labels, zero_s)}")
        out.append(
            finding(
                "k_or_s_not_positive",
                "; ".join(parts) + ": the film absorbs or scatters nothing there, or noise pushed the "
                "estimate below 0 (check the thin films' readings)",
                labels_at(labels, zero_k | zero_s),
            )
        )
    for flag, code, text in (
        (
            Flag.OUT_OF_RANGE,
            "out_of_range",
            "readings outside what the model and the backings allow at {}: "
            "K and S were moved to the nearest physical values (re-measure, or check the backings)",
        ),
        (
            Flag.OPAQUE,
            "opaque",
            "the film hides its backing at {}: its thickness cannot be identified there, "
            "so K and S are lower bounds (K/S is exact); measure a thinner film to pin them down",
        ),
    ):
        mask = (material.flags & np.uint8(flag)) != 0
        if mask.any():
            out.append(finding(code, text.format(format_ranges(labels, mask)), labels_at(labels, mask)))
    with np.errstate(divide="ignore", invalid="ignore"):
        ks = material.ks_ratio
    extreme = ((ks > thresholds.ks_max) | (ks < thresholds.ks_min)) & ~(zero_k | zero_s)
    if extreme.any():
        out.append(
            finding(
                "extreme_ks",
                f"K/S is outside [{thresholds.ks_min:g}, {thresholds.ks_max:g}] at {format_ranges(labels, extreme)} "
                f"(from {np.nanmin(ks[extreme]):.3g} to {np.nanmax(ks[extreme]):.3g}): a nearly black or "
                "nearly white material, where small reading errors change K/S a lot",
                labels_at(labels, extreme),
            )
        )
    if material.K_stderr is not None and material.S_stderr is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.maximum(material.K_stderr / material.K, material.S_stderr / material.S)
        opaque = (material.flags & np.uint8(Flag.OPAQUE)) != 0
        poor = ~(rel <= thresholds.relative_stderr) & ~opaque & ~(zero_k | zero_s)
        if poor.any():
            out.append(
                finding(
                    "poor_conditioning",
                    f"the standard error of K or S exceeds {thresholds.relative_stderr:.0%} of its value at "
                    f"{format_ranges(labels, poor)}: these measurements barely determine K and S there "
                    "(add a film of another thickness or over another backing)",
                    labels_at(labels, poor),
                )
            )
    return out


def check_readings(sample: Sample, labels: list) -> list[Finding]:
    """``reflectance_out_of_range``: a film, masstone or backing reading below 0 or above 1."""
    out = []
    rows = [(m.id, sample.readings[i]) for i, m in enumerate(sample.measurements)]
    rows += [(f"backing '{name}'", values) for name, values in sample.backings.items()]
    for name, values in rows:
        bad = (values < 0.0) | (values > 1.0)
        if bad.any():
            out.append(
                finding(
                    "reflectance_out_of_range",
                    f"{name} reads {values[bad].max() if (values > 1).any() else values[bad].min():.4g} "
                    f"at {format_ranges(labels, bad)}, outside [0, 1]: check the white reference, its certified "
                    "curve and the dark reading",
                    labels_at(labels, bad),
                    name,
                )
            )
    return out


def check_thickness_series(
    sample: Sample, material: Material, labels: list, sigma: np.ndarray, factor: float
) -> list[Finding]:
    """``thickness_not_monotone``: over each backing, a thicker film must read closer to the masstone (R_inf) than
    a thinner one, by more than ``factor`` x sqrt(sigma1^2 / n1 + sigma2^2 / n2) (``sigma``: noise per reading and
    wavelength; n: repeats)."""
    out = []
    masstones = [i for i, m in enumerate(sample.measurements) if m.role == "masstone"]
    if masstones:
        R_inf = sample.readings[masstones].mean(axis=0)
    else:  # as it would read, like the backings: with surface reflection when the fit modelled it
        R_inf = reflectance_infinite(material.K, material.S)
        if material.saunderson is not None:
            R_inf = saunderson_forward(R_inf, *material.saunderson)
    for backing, background in sample.backings.items():
        by_thickness: dict[float, list[int]] = {}
        for i, m in enumerate(sample.measurements):
            if m.role == "film" and m.over == backing:
                by_thickness.setdefault(m.thickness_mm, []).append(i)
        series = sorted(by_thickness.items())
        toward = np.sign(R_inf - background)
        for (thin, i_thin), (thick, i_thick) in itertools.pairwise(series):
            R_thin = sample.readings[i_thin].mean(axis=0)
            R_thick = sample.readings[i_thick].mean(axis=0)
            noise = factor * np.sqrt(
                np.mean(sigma[i_thin] ** 2, axis=0) / len(i_thin) + np.mean(sigma[i_thick] ** 2, axis=0) / len(i_thick)
            )
            # Where the backing reads like the masstone, a film cannot move it either way: no direction to check.
            wrong = (toward * (R_thick - R_thin) < -noise) & (np.abs(R_inf - background) > noise)
            if wrong.any():
                direction = "darker" if np.mean(toward[wrong]) > 0 else "lighter"
                out.append(
                    finding(
                        "thickness_not_monotone",
                        f"over {backing}, the {thick * 1000:g} um film reads {direction} than the "
                        f"{thin * 1000:g} um film at {format_ranges(labels, wrong)}, although a thicker film must come "
                        "closer to the masstone: the film is probably uneven, or the thicknesses are wrong",
                        labels_at(labels, wrong),
                    )
                )
    return out


def check_masstones(
    sample: Sample, material: Material, labels: list, sigma: np.ndarray, factor: float
) -> list[Finding]:
    """``masstone_not_opaque``: a masstone of declared thickness must hide the darkest backing, |R_inf - R(d, G)|
    at most ``factor`` x sigma (R(d, G): a layer of the declared thickness d over the backing's reflectance G)."""
    out = []
    if not sample.backings:
        return out
    darkest = min(sample.backings, key=lambda name: float(np.mean(sample.backings[name])))
    G = sample.backings[darkest]
    if material.saunderson is not None:
        G = saunderson_inverse(G, *material.saunderson)
    declared: dict[float, list[int]] = {}  # repeats of one masstone share a finding
    for i, m in enumerate(sample.measurements):
        if m.role == "masstone" and m.declared_mm is not None:
            declared.setdefault(m.declared_mm, []).append(i)
    for thickness, rows in declared.items():
        ids = [sample.measurements[i].id for i in rows]
        R_inf = reflectance_infinite(material.K, material.S)
        R_thin = reflectance_over_background(material.K, material.S, thickness, G)
        if material.saunderson is not None:
            R_inf, R_thin = (saunderson_forward(v, *material.saunderson) for v in (R_inf, R_thin))
        see_through = np.abs(R_inf - R_thin) > factor * np.sqrt(np.mean(sigma[rows] ** 2, axis=0))
        if see_through.any():
            out.append(
                finding(
                    "masstone_not_opaque",
                    f"at {thickness * 1000:g} um the masstone would still show a {darkest} backing at "
                    f"{format_ranges(labels, see_through)} (by up to {np.max(np.abs(R_inf - R_thin)):.3f} in "
                    "reflectance): it is not R_inf there; draw it thicker",
                    labels_at(labels, see_through),
                    ", ".join(ids),
                )
            )
    return out


def check_residuals(
    checks: list[MeasurementCheck], labels: list, thresholds: Thresholds, sigma: np.ndarray, opaque: np.ndarray
) -> list[Finding]:
    """``structured_residuals`` (runs test on residual signs, outside ``opaque`` wavelengths, over a stretch whose
    mean stands out from the noise) and ``residual_above_noise`` (RMSE above noise_factor x the repeat spread)."""
    out = []
    keep = ~opaque
    for k, c in enumerate(checks):
        residuals = np.where(keep, c.residuals, 0.0)
        if keep.sum() >= 10 and runs_z(c.residuals[keep]) < -thresholds.runs_z:
            run = longest_run(residuals) & keep
            # The bias over the run must stand out from the noise of a mean of that many readings (this
            # keeps quiet on residuals at rounding level, e.g. the lower-bound K, S of opaque films).
            bias = abs(float(np.mean(residuals[run])))
            if bias <= 2.0 * float(np.sqrt(np.mean(sigma[k][run] ** 2) / run.sum())):
                continue
            sign = "above" if np.mean(residuals[run]) > 0 else "below"
            out.append(
                finding(
                    "structured_residuals",
                    f"{c.id}: the prediction stays {sign} the measurement over {format_ranges(labels, run)} "
                    "(too few sign changes for noise): a bias the model does not capture "
                    "(surface reflection? Try --saunderson)",
                    labels_at(labels, run),
                    c.id,
                )
            )
        if c.repeat_spread is not None and c.repeat_spread > 0 and c.rmse > thresholds.noise_factor * c.repeat_spread:
            out.append(
                finding(
                    "residual_above_noise",
                    f"{c.id}: residual {c.rmse:.4f} is {c.rmse / c.repeat_spread:.1f} times the spread of its "
                    f"{c.repeat_count} repeats ({c.repeat_spread:.4f}): the model misses these readings by far more "
                    "than they differ",
                    [],
                    c.id,
                )
            )
    return out
