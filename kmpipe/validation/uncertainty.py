"""Validation of how well a material's rendered colour is known: the budget carried to CIELAB, checked by Monte
Carlo, and what to measure next.

For each render context (a film thickness over a substrate: a product's layer over its substrate in a recipe,
``--at``/``--over`` on the command line, by default the median measured thickness over the lightest backing) and
each illuminant validated, :func:`check_uncertainty` gives the 95 % Delta E 2000 radius by linearization
(:func:`kmpipe.physics.colour_uncertainty.colour_doubt`) and by refitting ``draws`` perturbed copies of the sample
(:func:`kmpipe.physics.perturbed_fits.perturbed_fits`), flags the two when they differ by more than
:data:`AGREEMENT` (with 1,000 draws the Monte Carlo radius itself varies by about 3 %), and ranks the measurements
the lab could add (:mod:`kmpipe.physics.next_measurement`) for the least well known colour.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kmpipe.formats.material import Material
from kmpipe.formats.sample import Sample
from kmpipe.formats.thresholds import Thresholds
from kmpipe.physics.colour_uncertainty import (
    ColourDoubt,
    colour_doubt,
    colour_radius,
    sampled_colours,
    sampled_radius,
)
from kmpipe.physics.fit_covariance import Budget
from kmpipe.physics.next_measurement import Suggestion, rank
from kmpipe.physics.perturbed_fits import perturbed_fits
from kmpipe.validation.checks import finding
from kmpipe.validation.doubts import sample_budget, sample_doubts
from kmpipe.validation.findings import Finding, format_ranges, labels_at

#: Relative difference between the Monte Carlo and the linearized radius above which they are said to disagree.
AGREEMENT = 0.2
#: Monte Carlo draws by default.
DRAWS = 1000


@dataclass(frozen=True)
class RenderContext:
    """Where a material's colour is judged: a film of ``thickness_mm`` over ``substrate`` (n,) reflectance."""

    label: str
    thickness_mm: float
    substrate: np.ndarray


@dataclass(frozen=True)
class ColourCheck:
    """One context under one illuminant: the linearized doubt and the Monte Carlo radius."""

    context: RenderContext
    doubt: ColourDoubt
    sampled: float | None
    sampled_labs: np.ndarray | None = None  # (draws, 3) the Monte Carlo colours

    @property
    def agree(self) -> bool:
        if self.sampled is None:
            return True
        gap = abs(self.sampled - self.doubt.radius)
        return gap <= AGREEMENT * max(self.doubt.radius, self.sampled) or gap < 0.02

    @property
    def radius(self) -> float:
        """The radius the verdict uses: the larger of the two (the Monte Carlo one holds where the model bends)."""
        return max(self.doubt.radius, self.sampled or 0.0)


@dataclass(frozen=True)
class UncertaintyReport:
    """Everything :func:`check_uncertainty` found for one material."""

    budget: Budget
    checks: tuple[ColourCheck, ...]
    suggestions: tuple[Suggestion, ...]
    draws: int
    blind: np.ndarray  # (n,) wavelengths where K and S cannot be told apart
    unsettled: int = 0  # Monte Carlo draws whose refit had not settled (a nearly flat valley of K and S)

    @property
    def worst(self) -> ColourCheck:
        return max(self.checks, key=lambda c: c.radius)


def default_context(sample: Sample) -> RenderContext:
    """The median measured film thickness over the lightest backing (or a white of 0.8 without backings)."""
    films = [m.thickness_mm for m in sample.measurements if m.role == "film"]
    thickness = float(np.median(films)) if films else float("inf")
    if sample.backings:
        name = max(sample.backings, key=lambda b: float(np.mean(sample.backings[b])))
        return RenderContext(f"{thickness * 1000:g} um over {name}", thickness, np.minimum(sample.backings[name], 1.0))
    return RenderContext(f"{thickness * 1000:g} um over white 0.8", thickness, np.full(sample.readings.shape[1], 0.8))


def material_budget(material: Material, sample: Sample) -> Budget:
    """The material's stored budget, or one computed now from its sample (a material written before budgets)."""
    if material.budget is not None:
        return material.budget
    return sample_budget(sample, material.K, material.S, saunderson=material.saunderson, **_fit_settings(material))


def _fit_settings(material: Material) -> dict:
    fit = material.fit
    return {
        "smoothness": float(fit.get("smoothness", 0.0)) if material.method == "lsq" else 0.0,
        "penalty_scales": tuple(fit.get("penalty_scales", (1.0, 1.0))),
        "noise": fit.get("noise_sigma") if fit.get("noise_source") == "given" else None,
    }


def check_uncertainty(
    material: Material,
    sample: Sample,
    contexts: list[RenderContext],
    illuminants: tuple[str, ...],
    observer: str = "2",
    draws: int = DRAWS,
) -> UncertaintyReport:
    """The rendered colour's doubt in each context under each illuminant (module docstring); ``draws`` 0 skips the
    Monte Carlo check."""
    budget = material_budget(material, sample)
    settings = _fit_settings(material)
    doubts = sample_doubts(sample, settings["noise"])
    G = np.array([np.minimum(sample.background_of(m), 1.0) for m in sample.measurements])
    fits = None
    if draws > 0:
        fits = perturbed_fits(budget, sample.thickness_mm, G, np.minimum(sample.readings, 1.0), doubts,
                              saunderson=material.saunderson, smoothness=settings["smoothness"],
                              penalty_scales=settings["penalty_scales"], draws=draws)  # fmt: skip
    wavelengths = material.wavelengths
    checks = []
    for context in contexts:
        for illuminant in illuminants:
            doubt = colour_doubt(budget, context.thickness_mm, context.substrate, wavelengths, illuminant, observer)
            sampled = labs = None
            if fits is not None:
                labs = sampled_colours(fits.K, fits.S, context.thickness_mm, context.substrate, wavelengths,
                                       illuminant, observer)  # fmt: skip
                sampled = sampled_radius(labs, doubt.lab)
            checks.append(ColourCheck(context, doubt, sampled, labs))
    worst = max(checks, key=lambda c: c.radius)

    def radius_of(candidate: Budget) -> float:
        return colour_radius(candidate, worst.context.thickness_mm, worst.context.substrate, wavelengths,
                             worst.doubt.illuminant, observer)  # fmt: skip

    suggestions = rank(budget, doubts, sample.thickness_mm, radius_of, material.saunderson)
    blind = budget.inverse()[1]
    return UncertaintyReport(budget, tuple(checks), tuple(suggestions[:3]), draws, blind[0::2] | blind[1::2],
                             0 if fits is None else fits.unsettled)  # fmt: skip


def uncertainty_findings(report: UncertaintyReport, labels: list, thresholds: Thresholds) -> list[Finding]:
    """The findings of the colour's doubt: ``colour_uncertainty`` (graded by the thresholds' ``uncertainty_warn``
    and ``uncertainty_fail``), ``uncertainty_nonlinear`` and ``not_separable``."""
    out = []
    worst = report.worst
    if worst.radius > thresholds.uncertainty_warn:
        level = "fail" if worst.radius > thresholds.uncertainty_fail else "warn"
        hint = f"; what to measure next: {suggestion_line(report)}"
        out.append(finding("colour_uncertainty", f"{headline(worst)}{hint}", level=level))
    for check in report.checks:
        if not check.agree:
            out.append(finding(
                "uncertainty_nonlinear",
                f"{check.context.label} under {check.doubt.illuminant}: Monte Carlo +-{check.sampled:.2f} against "
                f"linearized +-{check.doubt.radius:.2f} Delta E 2000; the larger is used"
                + (f" ({report.unsettled} of {report.draws} refits had not settled: K and S are barely told apart)"
                   if report.unsettled else ""),
            ))  # fmt: skip
    if report.blind.any():
        out.append(finding(
            "not_separable",
            f"K and S cannot be told apart at {format_ranges(labels, report.blind)}: the radius holds only for "
            "films at least as opaque as the measured ones",
            labels_at(labels, report.blind),
        ))  # fmt: skip
    return out


#: An addition that shrinks the radius by less than this fraction is not worth suggesting.
WORTHWHILE = 0.1


def suggestion_line(report: UncertaintyReport) -> str:
    """The one-line advice: the best addition and what it buys ('add a 45 um film over black: +-0.90 -> +-0.30'), or
    why none helps (the source no added measurement reduces dominates)."""
    worst = report.worst
    if worst.doubt.radius <= 0.0:
        return "nothing: the readings carry no stated doubt"
    best = report.suggestions[0] if report.suggestions else None
    if best is not None and best.radius <= (1.0 - WORTHWHILE) * best.today:
        return best.line()
    dominant = worst.doubt.dominant
    kind = report.budget.kinds.get(dominant, "")
    remedy = {"white": "a white standard with a certificate (white.uncertainty) would",
              "thickness": "measuring the films' thickness more exactly would",
              "backing": "repeated readings of the bare backing would",
              "noise": "repeats of every reading would"}.get(kind, "")  # fmt: skip
    close = f" (at best {best.line()})" if best is not None else ""
    return f"no single added measurement shrinks it by {WORTHWHILE:.0%}: {dominant} dominates; {remedy}{close}"


def headline(check: ColourCheck) -> str:
    """'rendered colour known to +-0.42 Delta E 2000 (95 %) at 15 um over white under D65; mostly thickness 15 um
    (72 %)'."""
    dominant = check.doubt.dominant
    share = f"; mostly {dominant} ({check.doubt.sources[dominant][1]:.0%})" if dominant else ""
    return (f"rendered colour known to +-{check.radius:.2f} Delta E 2000 (95 %) at {check.context.label} under "
            f"{check.doubt.illuminant}{share}")  # fmt: skip


def uncertainty_to_dict(report: UncertaintyReport, labels: list) -> dict:
    """The ``uncertainty`` object of ``validation.json`` (docs/formats.md)."""
    worst = report.worst

    def rounded(values, digits=4):
        return np.round(np.asarray(values, dtype=float), digits).tolist()

    return {
        "radius_delta_e_2000_95": round(worst.radius, 4),
        "headline": headline(worst),
        "draws": report.draws,
        "monte_carlo_unsettled": report.unsettled,
        "colours": [
            {
                "context": c.context.label,
                "thickness_mm": c.context.thickness_mm if np.isfinite(c.context.thickness_mm) else None,
                "illuminant": c.doubt.illuminant,
                "lab": rounded(c.doubt.lab),
                "covariance_lab": rounded(c.doubt.covariance_lab, 8),
                "radius_linearized": round(c.doubt.radius, 4),
                "radius_monte_carlo": None if c.sampled is None else round(c.sampled, 4),
                "agree": c.agree,
                "sources": [
                    {
                        "name": name,
                        "kind": report.budget.kinds.get(name, "noise"),
                        "radius": round(r, 4),
                        "share": round(share, 4),
                    }
                    for name, (r, share) in c.doubt.sources.items()
                ],
            }
            for c in report.checks
        ],
        "next_measurement": [
            {
                "role": s.candidate.role,
                "over": s.candidate.over,
                "thickness": None
                if not np.isfinite(s.candidate.thickness_mm)
                else f"{s.candidate.thickness_mm * 1000:g} um",
                "thickness_u": f"{s.candidate.thickness_u_mm * 1000:.3g} um" if s.candidate.thickness_u_mm else None,
                "radius": round(s.radius, 4),
                "today": round(s.today, 4),
                "line": s.line(),
            }
            for s in report.suggestions
        ],
        "next_measurement_line": suggestion_line(report),
        "not_separable": labels_at(labels, report.blind),
    }
