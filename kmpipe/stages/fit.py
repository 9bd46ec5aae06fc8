"""Fit one sample: a closed-form inversion, or a joint least-squares fit started from one.

Methods (``kmpipe fit --method``):

- ``two-constant``: masstone R_inf and each film over its backing, thesis eq. 4.1 in real form
  (:func:`kmpipe.physics.inversion.two_constant`); estimates from several films are averaged.
- ``black-white``: films of one thickness over two backings (:func:`kmpipe.physics.inversion.black_white`);
  estimates from several thicknesses are averaged.
- ``lsq``: every measurement at once (:func:`kmpipe.physics.joint_fit.fit_joint`), started from black-white
  when the sample has such pairs and from two-constant otherwise.

Averaging uses only unflagged estimates; where every estimate is flagged, the largest S (the tightest
lower bound for an opaque film) is kept with the union of the flags. At wavelengths where the closed
form finds the film opaque, lsq keeps the closed-form K and S (exact K/S, lower-bound S).
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from kmpipe import __version__
from kmpipe.errors import InputError
from kmpipe.formats.files import sha256
from kmpipe.formats.material import MAX_COEFFICIENT_PER_MM, Material, MeasurementFit
from kmpipe.formats.sample import Sample
from kmpipe.physics.flags import Flag
from kmpipe.physics.inversion import Inversion, black_white, two_constant
from kmpipe.physics.joint_fit import fit_joint, predict_readings, standard_errors
from kmpipe.physics.saunderson import saunderson_inverse
from kmpipe.validation.doubts import sample_budget


def _combine(inversions: list[Inversion]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Average the good (unflagged, or merely AT_BOUND) K and S of several estimates; where there is none,
    keep the largest-S flagged one with the union of the flags."""
    K = np.array([i.K for i in inversions])
    S = np.array([i.S for i in inversions])
    flags = np.array([i.flags for i in inversions])
    good = (flags & ~np.uint8(Flag.AT_BOUND)) == 0  # K = 0 at the bound is an estimate like any other
    count = good.sum(axis=0)
    any_good = count > 0
    mean_K = np.where(good, K, 0.0).sum(axis=0) / np.maximum(count, 1)
    mean_S = np.where(good, S, 0.0).sum(axis=0) / np.maximum(count, 1)
    pick = np.argmax(S, axis=0)
    columns = np.arange(K.shape[1])
    union = np.bitwise_or.reduce(flags, axis=0)
    return (
        np.where(any_good, mean_K, K[pick, columns]),
        np.where(any_good, mean_S, S[pick, columns]),
        np.where(any_good, np.bitwise_or.reduce(np.where(good, flags, 0), axis=0), union).astype(np.uint8),
    )


def _explainable(sample: Sample) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Readings and backgrounds (m, n) that the model can explain, and where (n,) some could not.

    A KM film over any backing, with or without Saunderson's surface reflection (R_m(1) = 1), reflects at most as
    much as a perfect white, and over a backing above 1 its multiple reflections diverge (1 - R0 G reaches 0). A
    spectral CSV may hold reflectance up to 1.5 (noisy instruments, fluorescent samples): such readings and
    backings are fitted as 1, the nearest value the model allows, and their wavelengths flagged
    ``OUT_OF_RANGE``; residuals stay against the readings as measured, and validation fails them
    (``reflectance_out_of_range``).
    """
    readings = sample.readings
    backgrounds = np.array([sample.background_of(m) for m in sample.measurements])
    above = np.any(readings > 1.0, axis=0) | np.any(backgrounds > 1.0, axis=0)
    return np.minimum(readings, 1.0), np.minimum(backgrounds, 1.0), above


def _km_reflectance(readings: np.ndarray, backgrounds: np.ndarray, saunderson) -> tuple[np.ndarray, np.ndarray]:
    """Readings and backgrounds as KM body reflectance (surface reflection removed when Saunderson is on)."""
    if saunderson is None:
        return readings, backgrounds
    return saunderson_inverse(readings, *saunderson), saunderson_inverse(backgrounds, *saunderson)


def _two_constant(sample: Sample, y, G, tolerance) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    roles = [m.role for m in sample.measurements]
    masstones = [i for i, r in enumerate(roles) if r == "masstone"]
    films = [i for i, r in enumerate(roles) if r == "film"]
    if not masstones:
        raise InputError(
            "the two-constant method needs a [[masstone]] (an opaque layer of the sample); "
            "use --method black-white or lsq for films over two backings",
            path=sample.manifest_path,
            field="masstone",
        )
    R_inf = y[masstones].mean(axis=0)
    X = sample.thickness_mm
    return _combine([two_constant(R_inf, y[i], G[i], X[i], tolerance=tolerance) for i in films])


def _black_white_pairs(sample: Sample) -> list[tuple[int, int]]:
    """(film over the darker backing, film over the lighter backing) for every thickness that has both."""
    by_thickness: dict[float, list[int]] = {}
    for i, m in enumerate(sample.measurements):
        if m.role == "film":
            by_thickness.setdefault(m.thickness_mm, []).append(i)
    pairs = []
    for indices in by_thickness.values():
        overs = {sample.measurements[i].over for i in indices}
        if len(overs) < 2:
            continue
        brightness = {i: float(np.mean(sample.backings[sample.measurements[i].over])) for i in indices}
        dark = min(indices, key=brightness.get)
        light = max(indices, key=brightness.get)
        pairs.append((dark, light))
    return pairs


def _black_white(sample: Sample, y, G, tolerance) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pairs = _black_white_pairs(sample)
    if not pairs:
        raise InputError(
            "the black-white method needs films of the same thickness over two different backings",
            path=sample.manifest_path,
            field="film",
        )
    X = sample.thickness_mm
    return _combine([black_white(y[b], y[w], G[b], G[w], X[b], tolerance=tolerance) for b, w in pairs])


def fit_sample(
    sample: Sample,
    *,
    method: str | None = None,
    saunderson: tuple[float, float] | None = None,
    smoothness: float | None = None,
    noise: float | None = None,
) -> Material:
    """Fit K and S (per mm) of one sample; arguments left None come from the manifest's ``[fit]`` table.

    >>> import json, kmpipe, pathlib, numpy as np
    >>> from kmpipe.formats.sample import load_sample
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> material = fit_sample(load_sample(F1 / "manifest.toml"))  # the manifest's [fit]: lsq
    >>> truth = json.loads((F1 / "truth.json").read_text())  # the K and S the simulated readings came from
    >>> K, S = (np.interp(material.wavelengths, truth["wavelengths_nm"], truth[q]) for q in ("K_per_mm", "S_per_mm"))
    >>> material.method, bool(np.median(abs(material.K / K - 1)) < 0.03 and np.median(abs(material.S / S - 1)) < 0.03)
    ('lsq', True)
    """
    settings = sample.settings
    method = method or settings.method
    saunderson = saunderson if saunderson is not None else settings.saunderson
    smoothness = settings.smoothness if smoothness is None else smoothness
    noise = settings.noise if noise is None else noise
    tolerance = settings.opaque_tolerance
    readings, backgrounds, above_one = _explainable(sample)
    y_km, G_km = _km_reflectance(readings, backgrounds, saunderson)
    thickness = sample.thickness_mm
    fit_info: dict = {"opaque_tolerance": tolerance}

    if method == "two-constant":
        K, S, flags = _two_constant(sample, y_km, G_km, tolerance)
    elif method == "black-white":
        K, S, flags = _black_white(sample, y_km, G_km, tolerance)
    elif method == "lsq":
        start = "black-white" if _black_white_pairs(sample) else "two-constant"
        start_fn = _black_white if start == "black-white" else _two_constant
        K0, S0, start_flags = start_fn(sample, y_km, G_km, tolerance)
        result = fit_joint(
            readings,
            G_km,
            thickness,
            K0,
            S0,
            sigma=noise,
            saunderson=saunderson,
            smoothness=smoothness,
        )
        # Where the closed form found the film opaque, K and S are not separable: keep its exact K/S and
        # its lower-bound S (the fit can only wander along the K/S = const valley there).
        opaque = (start_flags & np.uint8(Flag.OPAQUE)) != 0
        K = np.where(opaque, K0, result.K)
        S = np.where(opaque, S0, result.S)
        flags = np.where(opaque, start_flags, result.flags).astype(np.uint8)
        fit_info.update(
            start=start,
            library="nlopt",
            algorithm=result.algorithm,
            evaluations=result.evaluations,
            status=result.status,
            smoothness=smoothness,
        )
        if smoothness > 0.0:
            fit_info["penalty_scales"] = list(result.penalty_scales)
    else:
        raise InputError(f"unknown method {method!r}; expected one of two-constant, black-white, lsq", field="--method")

    flags = np.where(above_one, flags | np.uint8(Flag.OUT_OF_RANGE), flags)
    # Coefficients beyond what a material file holds (films of nanometres, readings at the model's edge): capped and
    # flagged, so that the material says so instead of failing to be written.
    beyond = (K > MAX_COEFFICIENT_PER_MM) | (S > MAX_COEFFICIENT_PER_MM)
    K, S = np.minimum(K, MAX_COEFFICIENT_PER_MM), np.minimum(S, MAX_COEFFICIENT_PER_MM)
    flags = np.where(beyond, flags | np.uint8(Flag.OUT_OF_RANGE), flags)
    predicted = predict_readings(K, S, thickness, G_km, saunderson)
    residuals = predicted - sample.readings
    K_se, S_se, sigma = standard_errors(K, S, thickness, G_km, readings, saunderson, noise)
    fit_info.update(
        noise_sigma=sigma,
        noise_source="given"
        if noise is not None
        else ("residuals" if sigma is not None else "none (exactly determined)"),
    )
    scales = tuple(fit_info.get("penalty_scales", (1.0, 1.0)))
    uncertainty = sample_budget(sample, K, S, saunderson=saunderson, smoothness=smoothness if method == "lsq" else 0.0,
                                penalty_scales=scales, noise=noise)  # fmt: skip
    measurements = tuple(
        MeasurementFit(id=m.id, role=m.role, over=m.over, thickness_mm=m.thickness_mm, residuals=residuals[i])
        for i, m in enumerate(sample.measurements)
    )
    return Material(
        name=sample.name,
        product=sample.product,
        kind=sample.kind,
        wavelengths=sample.wavelengths,
        channels=sample.channels,
        K=K,
        S=S,
        K_stderr=K_se,
        S_stderr=S_se,
        flags=np.asarray(flags, dtype=np.uint8),
        method=method,
        saunderson=saunderson,
        fit=fit_info,
        measurements=measurements,
        provenance={},
        budget=uncertainty,
    )


def provenance(sample: Sample, output: Path) -> dict:
    """Where a material came from: the kmpipe version, the time, and every input with its SHA-256.

    Paths are relative to the output file's folder, so a material and its measurements can move together.
    """
    base = output.resolve().parent

    def rel(path: Path) -> str:
        return os.path.relpath(path.resolve(), base)

    return {
        "kmpipe_version": __version__,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "manifest": rel(sample.manifest_path),
        "inputs": [{"path": rel(p), "sha256": sha256(p)} for p in sample.inputs],
    }


def fit_manifests(
    manifests: Sequence[str | Path],
    output: str | Path,
    *,
    grid: str | None = None,
    method: str | None = None,
    saunderson: tuple[float, float] | None = None,
    smoothness: float | None = None,
    noise: float | None = None,
) -> list[tuple[Path, Material]]:
    """The fit stage: fit the sample of each manifest and write its material, with provenance (``kmpipe fit``).

    ``output`` is the MATERIAL.json of a single manifest, or a folder receiving one ``SAMPLE.json`` per sample when
    there are several manifests or it is a folder. Settings left None come from each manifest's ``[fit]`` table
    (see :func:`fit_sample`). A material is never written over one of the files it was fitted from, and two
    manifests naming the same sample are refused before the second is written. Returns (path, material) pairs.

    >>> import tempfile, pathlib, kmpipe
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> manifest = F1 / "manifest.toml"
    >>> [(path, material)] = fit_manifests([manifest], pathlib.Path(tempfile.mkdtemp()) / "F1.json")
    >>> path.name, material.method, material.name, len(material.wavelengths)
    ('F1.json', 'lsq', 'F1', 81)
    >>> bool(material.K.min() >= 0 and material.S.min() > 0)
    True
    """
    from kmpipe.formats import files
    from kmpipe.formats.material import write_material
    from kmpipe.formats.sample import load_sample

    manifests, output = [Path(m) for m in manifests], Path(output)
    to_folder = len(manifests) > 1 or output.is_dir()
    if to_folder and output.exists() and not output.is_dir():
        raise InputError(
            "is a file; with several manifests, -o must name a folder (one SAMPLE.json is written there per sample)",
            path=output,
            field="-o",
        )
    if to_folder:
        files.output_folder(output)
    else:
        files.output_file(output, inputs=manifests)
    written: list[tuple[Path, Material]] = []
    for manifest in manifests:
        sample = load_sample(manifest, grid=grid)
        # the manifest's sample name is a safe file name; resolved, it must still stay in the folder
        target = files.within(output, f"{sample.name}.json", field="sample.name") if to_folder else output
        if any(path == target for path, _ in written):
            raise InputError(
                f"names sample {sample.name!r}, like an earlier manifest; each sample needs its own name "
                f"(its material is written to {target}); nothing was written for this one",
                path=manifest,
                field="sample.name",
            )
        files.refuse_inputs(target, [*manifests, *sample.inputs])
        material = fit_sample(sample, method=method, saunderson=saunderson, smoothness=smoothness, noise=noise)
        material = dataclasses.replace(material, provenance=provenance(sample, target))
        write_material(material, target)
        written.append((target, material))
    return written
