"""The validation report's section on how well the rendered colour is known: the headline and the advice, a table
per render context and illuminant (linearized and Monte Carlo radius), the budget (which source dominates, and at
which wavelengths it dominates K and S), and a figure per illuminant: the colour and its 95 % extremes as swatches
beside the a*b* plane with the uncertainty ellipse and the Monte Carlo colours.
"""

from __future__ import annotations

import html

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse
from scipy.stats import chi2

from kmpipe.physics.colorimetry import Lab_to_sRGB
from kmpipe.validation.findings import SampleReport, format_ranges
from kmpipe.validation.html_parts import png_img, table
from kmpipe.validation.uncertainty import ColourCheck, UncertaintyReport, headline, suggestion_line

#: Most Monte Carlo colours drawn in the a*b* plot.
SCATTER = 400
#: Size (inches) of each illuminant's figure.
FIGURE_SIZE = (9.0, 3.4)


def _dominance(report: UncertaintyReport, labels: list) -> dict[str, tuple[str, str]]:
    """Per source: the wavelengths where it is the largest part of the variance of K, and of S."""
    variances = {name: [u**2 for u in report.budget.standard_uncertainty(name)] for name in report.budget.sources}
    names = list(variances)
    out = {}
    for q in (0, 1):
        stack = np.array([variances[n][q] for n in names])
        top = np.argmax(stack, axis=0)
        for i, name in enumerate(names):
            out.setdefault(name, ["", ""])[q] = format_ranges(labels, top == i) or "—"
    return {name: (k, s) for name, (k, s) in out.items()}


def draw_colour_doubt(check: ColourCheck, wavelengths, observer: str) -> Figure:
    """Swatches of the colour and of its 95 % extremes along the ellipse's long axis, and the a*b* plane with the
    ellipse (the a*b* marginal, chi-square 2 at 95 %) and the Monte Carlo colours."""
    doubt = check.doubt
    fig = Figure(figsize=FIGURE_SIZE, layout="constrained")
    swatch, plane = fig.subplots(1, 2, width_ratios=(1.0, 1.3))
    values, vectors = np.linalg.eigh(doubt.covariance_lab)
    long_axis = vectors[:, -1] * np.sqrt(max(values[-1], 0.0) * chi2.ppf(0.95, 1))
    labs = np.array([doubt.lab - long_axis, doubt.lab, doubt.lab + long_axis])
    rgb = Lab_to_sRGB(labs, wavelengths, doubt.illuminant, observer)
    swatch.imshow(rgb[None, :, :], extent=(0, 3, 0, 1), interpolation="nearest")
    for x, text in zip((0.5, 1.5, 2.5), ("95 % low", "rendered", "95 % high"), strict=True):
        swatch.text(x, -0.08, text, ha="center", va="top", fontsize=8)
    swatch.set_axis_off()
    swatch.set_title(f"±{check.radius:.2f} ΔE00 (95 %) along the longest axis", fontsize=9)
    ab = doubt.covariance_lab[1:, 1:]
    a_values, a_vectors = np.linalg.eigh(ab)
    scale = np.sqrt(np.maximum(a_values, 0.0) * chi2.ppf(0.95, 2))
    angle = float(np.degrees(np.arctan2(a_vectors[1, 1], a_vectors[0, 1])))
    centre = doubt.lab[1:]
    if check.sampled_labs is not None:
        shown = check.sampled_labs[:SCATTER]
        plane.scatter(shown[:, 1], shown[:, 2], s=3, color="0.55", label=f"Monte Carlo ({len(check.sampled_labs)})")
    plane.add_patch(Ellipse(centre, 2 * scale[1], 2 * scale[0], angle=angle, fill=False, color="C3", linewidth=1.5,
                            label="95 % ellipse (linearized)"))  # fmt: skip
    plane.plot(*centre, "k+", markersize=10, label="rendered colour")
    reach = max(float(scale.max()) * 1.6, 0.05)
    plane.set_xlim(centre[0] - reach, centre[0] + reach)
    plane.set_ylim(centre[1] - reach, centre[1] + reach)
    plane.set_aspect("equal")
    plane.set_xlabel("a*")
    plane.set_ylabel("b*")
    plane.legend(fontsize=7, loc="upper right")
    plane.set_title(f"{check.context.label}, {doubt.illuminant}", fontsize=9)
    return fig


def uncertainty_section(report: SampleReport) -> str:
    """The HTML section (empty for a camera-channel material)."""
    doubt = report.uncertainty
    if doubt is None:
        return ""
    worst = doubt.worst
    parts = [
        "<h2>Rendered colour uncertainty</h2>",
        f"<p><strong>{html.escape(headline(worst))}</strong>.<br>What to measure next: "
        f"{html.escape(suggestion_line(doubt))}.</p>",
        f"<p>Radius: Delta E 2000 holding 95 % of the colour's doubt from the readings' noise, the film thickness, "
        f"the white standard and the backings, by linearization and by {doubt.draws} Monte Carlo refits "
        f"(thresholds: warn {report.thresholds.uncertainty_warn:g}, fail {report.thresholds.uncertainty_fail:g}).</p>",
    ]
    rows = []
    for c in doubt.checks:
        rgb = Lab_to_sRGB(c.doubt.lab, report.material.wavelengths, c.doubt.illuminant, report.observer)
        hexa = "#" + "".join(f"{round(float(v) * 255):02x}" for v in rgb)
        mc = "—" if c.sampled is None else f"{c.sampled:.3f}"
        flag = "" if c.agree else ' class="warn"'
        rows.append(
            f"<tr><td>{html.escape(c.context.label)}</td><td>{html.escape(c.doubt.illuminant)}</td>"
            f'<td><span style="display:inline-block;width:2.5em;height:1.2em;background:{hexa}"></span></td>'
            f'<td class="num">{" / ".join(f"{v:.2f}" for v in c.doubt.lab)}</td>'
            f'<td class="num">{c.doubt.radius:.3f}</td><td class="num"{flag}>{mc}</td>'
            f"<td>{html.escape(c.doubt.dominant or '—')}</td></tr>"
        )
    header = ["render context", "illuminant", "colour", "L* / a* / b*", "±ΔE00 linearized", "±ΔE00 Monte Carlo",
              "dominant source"]  # fmt: skip
    parts.append(table(header, rows))
    where = _dominance(doubt, report.labels)
    rows = [
        f"<tr><td>{html.escape(name)}</td><td>{html.escape(doubt.budget.kinds.get(name, ''))}</td>"
        f'<td class="num">{share:.0%}</td><td class="num">{alone:.3f}</td>'
        f"<td>{html.escape(where[name][0])}</td><td>{html.escape(where[name][1])}</td></tr>"
        for name, (alone, share) in sorted(worst.doubt.sources.items(), key=lambda item: -item[1][1])
    ]
    parts.append(f"<h3>Budget at {html.escape(worst.context.label)} under {html.escape(worst.doubt.illuminant)}</h3>")
    parts.append(table(["source", "kind", "share of ΔE²", "±ΔE00 alone", "dominates K at", "dominates S at"], rows))
    if doubt.suggestions:
        rows = [f"<tr><td>{html.escape(s.candidate.describe())}</td><td class='num'>{s.today:.2f} → {s.radius:.2f}"
                f"</td></tr>" for s in doubt.suggestions]  # fmt: skip
        parts.append("<h3>Measurements that would help most</h3>")
        parts.append(table(["add", "±ΔE00 today → after"], rows))
    shown = [c for c in doubt.checks if c.context == worst.context]
    for i, c in enumerate(shown):
        alt = f"{report.material.name}: colour and its 95 % doubt at {c.context.label} under {c.doubt.illuminant}"
        parts.append(png_img(draw_colour_doubt(c, report.material.wavelengths, report.observer),
                             f"plot-uncertainty-{i + 1}", alt))  # fmt: skip
    return "\n".join(parts)
