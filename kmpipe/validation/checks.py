"""Validate a fitted material against the measurements it was fitted from.

:func:`validate_material` re-reads the sample (through the manifest named in the material's provenance),
predicts every measurement from K and S, and reports per measurement the spectral residual and the colour
difference (Delta E 2000 under each chosen illuminant), the spread of repeated readings, a list of findings
(each check with a reason code, the wavelengths it concerns and a one-line explanation) and a verdict:
``pass``, ``warn`` or ``fail``. The checks are listed in :data:`CHECKS`; ``docs/formats.md`` documents the
``validation.json`` document that :func:`report_to_dict` gives.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from kmpipe.errors import InputError
from kmpipe.formats.files import is_regular, sha256
from kmpipe.formats.material import Material, ResidualFigures, read_material
from kmpipe.formats.sample import Sample, load_sample
from kmpipe.formats.toml_input import read_toml
from kmpipe.physics.colorimetry import delta_E_2000, reflectance_to_Lab
from kmpipe.physics.flags import Flag
from kmpipe.physics.joint_fit import predict_readings
from kmpipe.physics.kubelka_munk import reflectance_infinite, reflectance_over_background
from kmpipe.physics.saunderson import saunderson_forward, saunderson_inverse

FORMAT = "kmpipe-validation/1"

#: Smallest noise level (reflectance) the checks assume: below it, differences are rounding, not readings.
MIN_NOISE = 2e-4
SEVERITIES = ("pass", "warn", "fail")

#: Every check: reason code -> (severity, what it means for a technician).
CHECKS = {
    "delta_e": (
        "warn/fail",
        "a predicted colour differs from the measured one by more than the Delta E threshold",
    ),
    "rmse": (
        "warn/fail",
        "a predicted spectrum differs from the measured one by more than the RMSE threshold",
    ),
    "k_or_s_not_positive": (
        "warn",
        "K or S is 0: no absorption or no scattering, or noise pushed it below 0",
    ),
    "out_of_range": (
        "warn",
        "readings outside what the model and the backings allow; K, S moved to the boundary",
    ),
    "extreme_ks": ("warn", "K/S outside the range cosmetic films show (a near-black or near-white material)"),
    "reflectance_out_of_range": ("fail", "a measured reflectance outside [0, 1]: check the white reference"),
    "thickness_not_monotone": ("fail", "a thicker film reads farther from the masstone than a thinner one"),
    "opaque": ("warn", "the film hides its backing: thickness not identifiable, K and S are lower bounds"),
    "poor_conditioning": ("warn", "large standard errors: the measurements barely determine K and S"),
    "structured_residuals": ("warn", "residuals keep one sign over a long stretch: a bias, not noise"),
    "masstone_not_opaque": ("fail", "the masstone is too thin to hide its backing, so it is not R_inf"),
    "residual_above_noise": ("warn", "the fit misses repeated readings by far more than they differ"),
    "inputs_changed": ("warn", "a measurement file changed since the fit: refit before trusting this report"),
}


@dataclass(frozen=True)
class Thresholds:
    """Limits of the verdict; set on the command line or in a TOML file's ``[thresholds]`` table."""

    delta_e_warn: float = 1.0  # Delta E 2000
    delta_e_fail: float = 2.0
    rmse_warn: float = 0.01  # reflectance
    rmse_fail: float = 0.02
    relative_stderr: float = 0.25  # standard error / value, for poor_conditioning
    ks_min: float = 1e-4  # K/S below: extreme (R_inf above ~0.986)
    ks_max: float = 200.0  # K/S above: extreme (R_inf below ~0.0025)
    noise_factor: float = 3.0  # residual_above_noise: residual / repeat spread; also the sigma multiple of checks
    runs_z: float = 3.5  # structured_residuals: |z| of the Wald-Wolfowitz runs test

    @classmethod
    def from_toml(cls, path: Path) -> Thresholds:
        """Read ``[thresholds]`` from a TOML file (read as :func:`kmpipe.formats.manifest.read_toml` reads: a regular
        file
        within the TOML size limit); InputError naming the field on a bad value."""
        _, data = read_toml(Path(path), "validation config")
        extra = sorted(set(data) - {"thresholds"})
        if extra:
            raise InputError("unknown table or key; the file holds one [thresholds] table", path=path, field=extra[0])
        table = data.get("thresholds")
        if not isinstance(table, dict):
            raise InputError("expected a [thresholds] table", path=path, field="thresholds")
        return cls().updated(_source=path, **table)

    def updated(self, _source: Path | None = None, **values) -> Thresholds:
        """A copy with the given (non-None) values, each checked: a known name, a positive finite number,
        warn levels at most the fail levels, ks_min below ks_max. ``_source``: the config file, for messages."""
        known = {f.name for f in fields(self)}
        prefix = "thresholds." if _source is not None else ""
        given = {}
        for key, value in values.items():
            if value is None:
                continue
            if key not in known:
                raise InputError(
                    f"unknown threshold; expected one of {', '.join(sorted(known))}", path=_source, field=prefix + key
                )
            if isinstance(value, bool) or not isinstance(value, int | float) or not (0.0 < value < math.inf):
                raise InputError(f"expected a positive number, got {value!r}", path=_source, field=prefix + key)
            given[key] = float(value)
        out = replace(self, **given)
        for low, high in (("delta_e_warn", "delta_e_fail"), ("rmse_warn", "rmse_fail"), ("ks_min", "ks_max")):
            if getattr(out, low) > getattr(out, high):
                raise InputError(
                    f"{low} ({getattr(out, low):g}) exceeds {high} ({getattr(out, high):g})",
                    path=_source,
                    field=prefix + low,
                )
        return out


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
    """Everything :func:`validate_material` found for one material."""

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


# --- helpers ---------------------------------------------------------------------------------------------


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


def _where(labels: list, mask: np.ndarray) -> list:
    return [labels[i] for i in np.flatnonzero(mask)]


def _repeat_groups(sample: Sample) -> dict[tuple, list[int]]:
    groups: dict[tuple, list[int]] = {}
    for i, m in enumerate(sample.measurements):
        groups.setdefault((m.role, m.over, m.thickness_mm), []).append(i)
    return groups


def _group_name(key: tuple) -> str:
    role, over, thickness = key
    if role == "masstone":
        return "masstone"
    return f"{thickness * 1000:g} um over {over}"


#: Wavelengths (grid points) over which the noise level is taken as locally constant.
NOISE_WINDOW = 11


def _windowed(values: np.ndarray, statistic, window: int = NOISE_WINDOW, offset: int = 0) -> np.ndarray:
    """``statistic`` (e.g. np.median) of (m, k) values over windows of ``window`` points along the last axis,
    one per output point: centred on it, shifted inwards at the ends (never padded, which would let one value
    stand for the whole window there). Value j belongs to output point j + ``offset``; n = k + 2 offset."""
    width = min(window, values.shape[1])
    per_start = statistic(np.lib.stride_tricks.sliding_window_view(values, width, axis=1), axis=-1)
    n = values.shape[1] + 2 * offset
    start = np.clip(np.arange(n) - offset - width // 2, 0, per_start.shape[1] - 1)
    return per_start[:, start]


def _roughness_noise(readings: np.ndarray, window: int = NOISE_WINDOW) -> np.ndarray:
    """Noise of each reading at each wavelength (m, n), from the reading's own roughness: model-free.

    For white noise of standard deviation sigma, d2 = y[i-1] - 2 y[i] + y[i+1] has standard deviation
    sqrt(6) sigma. The median of |d2| / 0.6745 over a window of ``window`` points estimates it robustly
    (the few large second differences at the steep edge of a smooth spectrum do not count) and locally, so
    noise that grows with the signal, as a spectroradiometer's does, is followed across the spectrum.
    """
    m, n = readings.shape
    if n < 3:
        return np.zeros((m, n))
    d2 = np.abs(readings[:, 2:] - 2.0 * readings[:, 1:-1] + readings[:, :-2])  # centred on points 1 .. n-2
    return _windowed(d2, np.median, window, offset=1) / 0.6745 / math.sqrt(6.0)


def _noise_map(sample: Sample, groups: dict[tuple, list[int]]) -> tuple[np.ndarray, str]:
    """Noise (standard deviation, reflectance) of every reading at every wavelength, and where it came from.

    Readings with repeats: the repeats' standard deviation, smoothed over `NOISE_WINDOW` points; others:
    :func:`_roughness_noise`. Never from the fit, whose residuals a faulty measurement would inflate.
    Floored at `MIN_NOISE`.
    """
    sigma = _roughness_noise(sample.readings)
    repeated = 0
    for members in groups.values():
        if len(members) > 1:
            sd = sample.readings[members].std(axis=0, ddof=1)
            sigma[members] = np.sqrt(_windowed(sd[None, :] ** 2, np.mean))[0]
            repeated += len(members)
    total = len(sample.measurements)
    floor = f"; floored at {MIN_NOISE:g}" if np.median(sigma) < MIN_NOISE else ""
    if repeated == total:
        source = "spread of repeats"
    elif repeated:
        source = "spread of repeats; roughness of single readings"
    else:
        source = "roughness of the readings (local second differences)"
    return np.maximum(sigma, MIN_NOISE), source + floor


def _runs_z(residuals: np.ndarray) -> float:
    """z of the Wald-Wolfowitz runs test on the signs of the residuals (negative: too few sign changes)."""
    signs = residuals[residuals != 0.0] > 0.0
    n = signs.size
    n_pos = int(signs.sum())
    n_neg = n - n_pos
    if n_pos == 0 or n_neg == 0:
        return -math.inf if n >= 10 else 0.0
    runs = 1 + int(np.count_nonzero(signs[1:] != signs[:-1]))
    expected = 1.0 + 2.0 * n_pos * n_neg / n
    variance = 2.0 * n_pos * n_neg * (2.0 * n_pos * n_neg - n) / (n * n * (n - 1.0))
    return (runs - expected) / math.sqrt(variance) if variance > 0 else 0.0


def _longest_run(residuals: np.ndarray) -> np.ndarray:
    """Mask of the longest stretch of residuals of one sign."""
    signs = np.sign(residuals)
    best = (0, 0)
    start = 0
    for i in range(1, signs.size + 1):
        if i == signs.size or signs[i] != signs[start]:
            if i - start > best[1] - best[0]:
                best = (start, i)
            start = i
    mask = np.zeros(signs.size, dtype=bool)
    mask[best[0] : best[1]] = True
    return mask


# --- the checks ------------------------------------------------------------------------------------------


def _check_coefficients(material: Material, labels, thresholds: Thresholds) -> list[Finding]:
    out = []
    zero_k, zero_s = material.K <= 0.0, material.S <= 0.0
    if np.any(zero_k | zero_s):
        parts = []
        if zero_k.any():
            parts.append(f"K is 0 at {format_ranges(labels, zero_k)}")
        if zero_s.any():
            parts.append(f"S is 0 at {format_ranges(labels, zero_s)}")
        out.append(
            Finding(
                "k_or_s_not_positive",
                "warn",
                "; ".join(parts) + ": the film absorbs or scatters nothing there, or noise pushed the "
                "estimate below 0 (check the thin films' readings)",
                _where(labels, zero_k | zero_s),
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
            out.append(Finding(code, "warn", text.format(format_ranges(labels, mask)), _where(labels, mask)))
    with np.errstate(divide="ignore", invalid="ignore"):
        ks = material.ks_ratio
    extreme = ((ks > thresholds.ks_max) | (ks < thresholds.ks_min)) & ~(zero_k | zero_s)
    if extreme.any():
        out.append(
            Finding(
                "extreme_ks",
                "warn",
                f"K/S is outside [{thresholds.ks_min:g}, {thresholds.ks_max:g}] at {format_ranges(labels, extreme)} "
                f"(from {np.nanmin(ks[extreme]):.3g} to {np.nanmax(ks[extreme]):.3g}): a nearly black or "
                "nearly white material, where small reading errors change K/S a lot",
                _where(labels, extreme),
            )
        )
    if material.K_stderr is not None and material.S_stderr is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.maximum(material.K_stderr / material.K, material.S_stderr / material.S)
        opaque = (material.flags & np.uint8(Flag.OPAQUE)) != 0
        poor = ~(rel <= thresholds.relative_stderr) & ~opaque & ~(zero_k | zero_s)
        if poor.any():
            out.append(
                Finding(
                    "poor_conditioning",
                    "warn",
                    f"the standard error of K or S exceeds {thresholds.relative_stderr:.0%} of its value at "
                    f"{format_ranges(labels, poor)}: these measurements barely determine K and S there "
                    "(add a film of another thickness or over another backing)",
                    _where(labels, poor),
                )
            )
    return out


def _check_readings(sample: Sample, labels) -> list[Finding]:
    out = []
    rows = [(m.id, sample.readings[i]) for i, m in enumerate(sample.measurements)]
    rows += [(f"backing '{name}'", values) for name, values in sample.backings.items()]
    for name, values in rows:
        bad = (values < 0.0) | (values > 1.0)
        if bad.any():
            out.append(
                Finding(
                    "reflectance_out_of_range",
                    "fail",
                    f"{name} reads {values[bad].max() if (values > 1).any() else values[bad].min():.4g} "
                    f"at {format_ranges(labels, bad)}, outside [0, 1]: check the white reference, its certified "
                    "curve and the dark reading",
                    _where(labels, bad),
                    name,
                )
            )
    return out


def _check_thickness_series(
    sample: Sample, material: Material, labels, sigma: np.ndarray, factor: float
) -> list[Finding]:
    """Over each backing, a thicker film must read closer to the masstone (R_inf) than a thinner one."""
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
                    Finding(
                        "thickness_not_monotone",
                        "fail",
                        f"over {backing}, the {thick * 1000:g} um film reads {direction} than the "
                        f"{thin * 1000:g} um film at {format_ranges(labels, wrong)}, although a thicker film must come "
                        "closer to the masstone: the film is probably uneven, or the thicknesses are wrong",
                        _where(labels, wrong),
                    )
                )
    return out


def _check_masstones(sample: Sample, material: Material, labels, sigma: np.ndarray, factor: float) -> list[Finding]:
    """A masstone of declared thickness must hide the darkest backing to within the noise."""
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
                Finding(
                    "masstone_not_opaque",
                    "fail",
                    f"at {thickness * 1000:g} um the masstone would still show a {darkest} backing at "
                    f"{format_ranges(labels, see_through)} (by up to {np.max(np.abs(R_inf - R_thin)):.3f} in "
                    "reflectance): it is not R_inf there; draw it thicker",
                    _where(labels, see_through),
                    ", ".join(ids),
                )
            )
    return out


def _check_residuals(
    checks: list[MeasurementCheck], labels, thresholds: Thresholds, sigma: np.ndarray, opaque: np.ndarray
) -> list[Finding]:
    """Structure (runs test on residual signs, outside opaque wavelengths, larger than the noise) and size
    against the repeat spread."""
    out = []
    keep = ~opaque
    for k, c in enumerate(checks):
        residuals = np.where(keep, c.residuals, 0.0)
        if keep.sum() >= 10 and _runs_z(c.residuals[keep]) < -thresholds.runs_z:
            run = _longest_run(residuals) & keep
            # The bias over the run must stand out from the noise of a mean of that many readings (this
            # keeps quiet on residuals at rounding level, e.g. the lower-bound K, S of opaque films).
            bias = abs(float(np.mean(residuals[run])))
            if bias <= 2.0 * float(np.sqrt(np.mean(sigma[k][run] ** 2) / run.sum())):
                continue
            sign = "above" if np.mean(residuals[run]) > 0 else "below"
            out.append(
                Finding(
                    "structured_residuals",
                    "warn",
                    f"{c.id}: the prediction stays {sign} the measurement over {format_ranges(labels, run)} "
                    "(too few sign changes for noise): a bias the model does not capture "
                    "(surface reflection? Try --saunderson)",
                    _where(labels, run),
                    c.id,
                )
            )
        if c.repeat_spread is not None and c.repeat_spread > 0 and c.rmse > thresholds.noise_factor * c.repeat_spread:
            out.append(
                Finding(
                    "residual_above_noise",
                    "warn",
                    f"{c.id}: residual {c.rmse:.4f} is {c.rmse / c.repeat_spread:.1f} times the spread of its "
                    f"{c.repeat_count} repeats ({c.repeat_spread:.4f}): the model misses these readings by far more "
                    "than they differ",
                    [],
                    c.id,
                )
            )
    return out


def _check_thresholds(checks: list[MeasurementCheck], thresholds: Thresholds) -> list[Finding]:
    out = []
    for c in checks:
        for illuminant, value in c.delta_e.items():
            level = "fail" if value > thresholds.delta_e_fail else "warn" if value > thresholds.delta_e_warn else None
            if level:
                limit = thresholds.delta_e_fail if level == "fail" else thresholds.delta_e_warn
                out.append(
                    Finding(
                        "delta_e",
                        level,
                        f"{c.id}: Delta E 2000 {value:.2f} under {illuminant} exceeds {limit:g}",
                        [],
                        c.id,
                    )
                )
        level = "fail" if c.rmse > thresholds.rmse_fail else "warn" if c.rmse > thresholds.rmse_warn else None
        if level:
            limit = thresholds.rmse_fail if level == "fail" else thresholds.rmse_warn
            out.append(Finding("rmse", level, f"{c.id}: spectral RMSE {c.rmse:.4f} exceeds {limit:g}", [], c.id))
    return out


# --- the whole validation --------------------------------------------------------------------------------


def _changed_inputs(material: Material, material_path: Path) -> list[str]:
    changed = []
    for entry in material.provenance.get("inputs", []):
        path = material_path.parent / entry["path"]
        if not is_regular(path):
            changed.append(f"{entry['path']} (missing)")
        elif sha256(path) != entry["sha256"]:
            changed.append(entry["path"])
    return changed


def validate_material(
    material_path: str | Path,
    *,
    manifest: str | Path | None = None,
    illuminants: tuple[str, ...] = ("D65",),
    observer: str = "2",
    thresholds: Thresholds | None = None,
) -> SampleReport:
    """Validate one MATERIAL.json against its measurements; see the module docstring."""
    material_path = Path(material_path)
    thresholds = thresholds or Thresholds()
    material = read_material(material_path)
    if manifest is None:
        named = material.provenance.get("manifest")
        if not named:
            raise InputError(
                "names no manifest in its provenance; pass --manifest",
                path=material_path,
                field="provenance.manifest",
            )
        manifest = material_path.parent / named
        if not Path(manifest).is_file():
            raise InputError(
                f"names the manifest {named}, which does not exist (looked for {manifest}); pass --manifest",
                path=material_path,
                field="provenance.manifest",
            )
    manifest = Path(manifest).resolve()
    changed = _changed_inputs(material, material_path)
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

    groups = _repeat_groups(sample)
    spreads: dict[tuple, float] = {}
    for key, members in groups.items():
        if len(members) > 1:
            sd = sample.readings[members].std(axis=0, ddof=1)
            spreads[key] = float(np.sqrt(np.mean(sd**2)))
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
                repeat_group=_group_name(key),
                repeat_count=len(groups[key]),
                repeat_spread=spreads.get(key),
            )
        )
    sigma, source = _noise_map(sample, groups)

    findings: list[Finding] = []
    if changed:
        findings.append(
            Finding(
                "inputs_changed",
                "warn",
                f"{', '.join(changed)} changed since the fit (SHA-256 differs): refit before trusting this report",
                [],
            )
        )
    findings += _check_thresholds(checks, thresholds)
    findings += _check_coefficients(material, labels, thresholds)
    findings += _check_readings(sample, labels)
    findings += _check_thickness_series(sample, material, labels, sigma, thresholds.noise_factor)
    findings += _check_masstones(sample, material, labels, sigma, thresholds.noise_factor)
    findings += _check_residuals(checks, labels, thresholds, sigma, (material.flags & np.uint8(Flag.OPAQUE)) != 0)
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
    )


def _number(value: float | None):
    return None if value is None or not math.isfinite(value) else float(value)


def report_to_dict(report: SampleReport, *, html: str | None = None) -> dict:
    """The ``validation.json`` document (format in docs/formats.md)."""
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
        "report_html": html,
    }
