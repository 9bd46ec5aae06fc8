"""What people read after validation: a self-contained HTML page per sample, and an index of a batch.

:func:`write_sample_report` writes ``validation.json`` (see :func:`kmpipe.validation.findings.report_to_dict`) and
``report.html``: a header with the verdict, the findings, a table of the measurements with the cells over
the thresholds marked, and three figures (measured vs predicted reflectance with residuals, K and S with
their standard errors, colour swatches). :func:`write_index` writes ``index.html`` and ``summary.json``
for a batch, failing samples first. Every file is written atomically and the HTML pages need nothing but
themselves: the figures are embedded PNGs, the styles inline.

Figures are drawn with :class:`matplotlib.figure.Figure` on the Agg canvas, so no pyplot state is touched
and nothing needs closing.
"""

from __future__ import annotations

import html
import itertools
import json
import math
import os
from collections.abc import Sequence
from dataclasses import fields
from pathlib import Path
from urllib.parse import quote

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

from kmpipe.formats.atomic_write import write_text_atomically
from kmpipe.physics.colorimetry import reflectance_to_sRGB
from kmpipe.physics.flags import Flag
from kmpipe.validation.findings import SEVERITIES, SampleReport, format_ranges, report_to_dict
from kmpipe.validation.html_parts import png_img, table
from kmpipe.validation.uncertainty_page import uncertainty_section

SPECTRA_SIZE = (9.0, 7.0)  # inches
KS_SIZE = (9.0, 5.0)
SWATCH_COLUMNS = 5

STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 960px; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: left; vertical-align: top; }
th { background: #f2f2f2; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
.badge { display: inline-block; padding: 0.1em 0.7em; border-radius: 0.8em; color: #fff; font-weight: bold; }
.badge.pass { background: #2e7d32; } .badge.warn { background: #e69500; } .badge.fail { background: #c62828; }
td.warn { background: #fff1cc; } td.fail { background: #f9d0d0; font-weight: bold; }
tr.warn td:first-child { border-left: 4px solid #e69500; } tr.fail td:first-child { border-left: 4px solid #c62828; }
dl { display: grid; grid-template-columns: max-content auto; gap: 0.2em 1em; }
dt { font-weight: bold; } dd { margin: 0; }
img { max-width: 100%; height: auto; }
.note { background: #eef3fb; border-left: 4px solid #5b7fbf; padding: 0.5em 1em; }
"""


# --- files -----------------------------------------------------------------------------------------------


def _page(title: str, body: str) -> str:
    return (
        f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n<title>{html.escape(title)}'
        f"</title>\n<style>{STYLE}</style>\n</head>\n<body>\n{body}\n</body>\n</html>\n"
    )


def _badge(verdict: str) -> str:
    return f'<span class="badge {verdict}">{verdict}</span>'


# --- figures ---------------------------------------------------------------------------------------------


def swatch_figsize(count: int) -> tuple[float, float]:
    """Size (inches) of the swatch figure for ``count`` measurements: rows of :data:`SWATCH_COLUMNS`."""
    rows = max(1, math.ceil(count / SWATCH_COLUMNS))
    return 9.0, 0.6 + 2.2 * rows


def _x_axis(report: SampleReport) -> np.ndarray:
    """Wavelengths (nm), or positions 0, 1, ... of camera channels."""
    if report.spectral:
        return np.asarray(report.material.wavelengths, dtype=np.float64)
    return np.arange(len(report.labels), dtype=np.float64)


def _label_x_axis(ax, report: SampleReport) -> None:
    if report.spectral:
        ax.set_xlabel("wavelength (nm)")
    else:
        ax.set_xticks(_x_axis(report), [str(label) for label in report.labels])
        ax.set_xlabel("camera channel")


def _colours(count: int) -> list:
    """Distinct colours for ``count`` measurements (tab10, or tab20 cycled for more than ten)."""
    cmap = colormaps["tab10" if count <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(count)]


def draw_spectra(report: SampleReport) -> Figure:
    """Measured reflectance (markers) and predicted (same colour: a line over wavelength, a bar per camera
    channel) for every measurement, the backings in thin grey, and beneath them the residuals (predicted -
    measured) with the noise level shaded."""
    x = _x_axis(report)
    fig = Figure(figsize=SPECTRA_SIZE, layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=(3, 1.3))
    handles, names = [], []
    for (name, values), style in zip(report.backings.items(), itertools.cycle(("-", "--", ":", "-.")), strict=False):
        handles += top.plot(x, values, style, color="0.55", linewidth=0.8, zorder=1)
        names.append(f"backing: {name}")
    predicted_style = (
        {"linestyle": "-", "linewidth": 1.4}
        if report.spectral
        else {"linestyle": "none", "marker": "_", "markersize": 18, "markeredgewidth": 2}
    )
    for c, colour in zip(report.measurements, _colours(len(report.measurements)), strict=True):
        (points,) = top.plot(x, c.measured, "o", markersize=3 if report.spectral else 5, color=colour, zorder=3)
        (predicted,) = top.plot(x, c.predicted, color=colour, zorder=2, **predicted_style)
        bottom.plot(x, c.residuals, "-" if report.spectral else "o", color=colour)
        handles.append((points, predicted))
        names.append(c.id)
    top.legend(handles, names, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    top.set_ylabel("reflectance")
    shape = "lines" if report.spectral else "bars"
    top.set_title(f"{report.material.name}: measured (markers) vs predicted ({shape}) reflectance")
    top.grid(alpha=0.3)
    sigma = report.noise_sigma
    bottom.axhspan(-sigma, sigma, color="0.85", zorder=0, label=f"±1σ noise ({report.noise_source})")
    bottom.axhline(0.0, color="0.3", linewidth=0.8)
    bottom.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    bottom.set_ylabel("predicted − measured\n(reflectance)")
    bottom.grid(alpha=0.3)
    _label_x_axis(bottom, report)
    return fig


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of each run of True in a boolean mask."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(np.int8), [0]))))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def draw_ks(report: SampleReport) -> Figure:
    """K and S (1/mm) on a log axis with ±1 standard-error bands and the opaque wavelengths shaded."""
    material = report.material
    x = _x_axis(report)
    fig = Figure(figsize=KS_SIZE, layout="constrained")
    ax = fig.subplots()
    positive = np.concatenate([v[(v > 0) & np.isfinite(v)] for v in (material.K, material.S)])
    floor = positive.min() / 10.0 if positive.size else 1e-3
    ceiling = positive.max() * 100.0 if positive.size else 1e3  # a band above this is unbounded: drawn to here
    for name, values, stderr, colour in (
        ("K", material.K, material.K_stderr, "C3"),
        ("S", material.S, material.S_stderr, "C0"),
    ):
        ax.plot(x, np.where(values > 0, values, np.nan), "-o", markersize=2.5, color=colour, label=name)
        if stderr is not None:
            known = np.isfinite(stderr)
            ax.fill_between(
                x,
                np.maximum(values - np.where(known, stderr, 0.0), floor),
                np.minimum(values + np.where(known, stderr, 0.0), ceiling),
                where=known & (values > 0),
                color=colour,
                alpha=0.2,
                linewidth=0,
                label=f"{name} ± 1 standard error",
            )
    step = float(np.median(np.diff(x))) if x.size > 1 else 1.0
    opaque = (material.flags & np.uint8(Flag.OPAQUE)) != 0
    for n, (first, last) in enumerate(_runs(opaque)):
        ax.axvspan(
            x[first] - step / 2,
            x[last] + step / 2,
            color="0.8",
            alpha=0.6,
            zorder=0,
            linewidth=0,
            label="opaque: K, S are lower bounds" if n == 0 else None,
        )
    ax.set_yscale("log")
    ax.set_ylim(bottom=floor)
    ax.set_ylabel("K, S (1/mm)")
    ax.set_title(f"{material.name}: absorption K and scattering S ({material.method})")
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    _label_x_axis(ax, report)
    return fig


def draw_swatches(report: SampleReport) -> Figure:
    """One square per measurement, measured colour left and predicted right (sRGB under the first
    illuminant), titled with the measurement id and Delta E 2000 (coloured by its threshold level)."""
    illuminant = report.illuminants[0]
    wavelengths = report.material.wavelengths
    measured = reflectance_to_sRGB(
        np.array([c.measured for c in report.measurements]), wavelengths, illuminant, report.observer
    )
    predicted = reflectance_to_sRGB(
        np.array([c.predicted for c in report.measurements]), wavelengths, illuminant, report.observer
    )
    count = len(report.measurements)
    rows = max(1, math.ceil(count / SWATCH_COLUMNS))
    fig = Figure(figsize=swatch_figsize(count), layout="constrained")
    axes = fig.subplots(rows, SWATCH_COLUMNS, squeeze=False).ravel()
    for ax in axes:
        ax.set_axis_off()
    colours = {"pass": "black", "warn": "#b36b00", "fail": "#c62828"}
    for ax, c, left, right in zip(axes, report.measurements, measured, predicted, strict=False):
        ax.imshow(np.array([[left, right]]), extent=(0, 2, 0, 2), interpolation="nearest")
        ax.axvline(1.0, color="white", linewidth=1)
        ax.text(0.5, -0.15, "measured", ha="center", va="top", fontsize=7)
        ax.text(1.5, -0.15, "predicted", ha="center", va="top", fontsize=7)
        value = c.delta_e[illuminant]
        level = _level(value, report.thresholds.delta_e_warn, report.thresholds.delta_e_fail)
        ax.set_title(c.id.replace(":", ":\n", 1) + f"\nΔE00 {value:.2f}", fontsize=8, color=colours[level])
    fig.suptitle(
        f"{report.material.name}: colour under {illuminant}, {report.observer}° observer "
        "(left measured, right predicted)"
    )
    return fig


# --- tables ----------------------------------------------------------------------------------------------


def _level(value: float | None, warn: float, fail: float) -> str:
    """'fail', 'warn' or 'pass' for a value against its thresholds (over, not at, a threshold fires)."""
    if value is None or value <= warn:
        return "pass"
    return "fail" if value > fail else "warn"


def _where(report: SampleReport, where: list) -> str:
    """Compact ranges of a finding's wavelengths or channels: '380-500, 620 nm', 'R, G'."""
    wanted = set(where)
    return format_ranges(report.labels, np.array([label in wanted for label in report.labels], dtype=bool))


def _header(report: SampleReport) -> str:
    m = report.material
    thresholds = ", ".join(f"{f.name} {getattr(report.thresholds, f.name):g}" for f in fields(report.thresholds))
    items = {
        "product": m.product,
        "material file": str(report.material_path),
        "manifest": str(report.manifest_path),
        "method": m.method
        + ("" if m.saunderson is None else f", Saunderson k1 {m.saunderson[0]:g}, k2 {m.saunderson[1]:g}"),
        "reasons": ", ".join(report.reasons) or "none",
        "noise σ": f"{report.noise_sigma:.2g} reflectance (from {report.noise_source})",
        "illuminants": ", ".join(report.illuminants) or ("none" if report.spectral else "none (camera channels)"),
        "observer": f"{report.observer}°",
        "thresholds": thresholds,
        "data": '<a href="validation.json">validation.json</a>',
    }
    rows = "\n".join(
        f"<dt>{html.escape(k)}</dt><dd>{v if k == 'data' else html.escape(v)}</dd>" for k, v in items.items()
    )
    return f"<h1>{html.escape(m.name)} {_badge(report.verdict)}</h1>\n<dl>\n{rows}\n</dl>"


def _findings_table(report: SampleReport) -> str:
    if not report.findings:
        return "<p>No findings: every check passed.</p>"
    ordered = sorted(report.findings, key=lambda f: -SEVERITIES.index(f.severity))
    rows = [
        f'<tr class="{f.severity}"><td>{_badge(f.severity)}</td><td><code>{html.escape(f.code)}</code></td>'
        f"<td>{html.escape(f.message)}</td><td>{html.escape(f.measurement or '—')}</td>"
        f"<td>{html.escape(_where(report, f.where)) or '—'}</td></tr>"
        for f in ordered
    ]
    return table(["severity", "code", "message", "measurement", "where"], rows)


def _measurement_table(report: SampleReport) -> str:
    t = report.thresholds
    unit = " nm" if report.spectral else ""
    header = [
        "id",
        "role",
        "over",
        "thickness (µm)",
        "RMSE",
        "max |error|",
        "at",
        *(f"ΔE00 {name}" for name in report.illuminants),
        "repeats",
        "repeat spread",
    ]
    rows = []
    for c in report.measurements:
        row_level = max(
            (f.severity for f in report.findings if f.measurement == c.id), key=SEVERITIES.index, default="pass"
        )
        at = report.labels[c.max_abs_index]
        cells = [
            html.escape(c.id),
            c.role,
            html.escape(c.over or "—"),
            "masstone" if math.isinf(c.thickness_mm) else f"{c.thickness_mm * 1000:g}",
        ]
        cells = [f"<td>{cell}</td>" for cell in cells]
        cells.append(f'<td class="num {_level(c.rmse, t.rmse_warn, t.rmse_fail)}">{c.rmse:.4f}</td>')
        cells.append(f'<td class="num">{abs(c.residuals[c.max_abs_index]):.4f}</td>')
        cells.append(f"<td>{html.escape(f'{at:g}' if report.spectral else str(at))}{unit}</td>")
        for name in report.illuminants:
            value = c.delta_e[name]
            cells.append(f'<td class="num {_level(value, t.delta_e_warn, t.delta_e_fail)}">{value:.2f}</td>')
        spread = "—" if c.repeat_spread is None else f"{c.repeat_spread:.4f}"
        cells.append(f'<td class="num">{c.repeat_count}</td><td class="num">{spread}</td>')
        rows.append(f'<tr class="{row_level}">' + "".join(cells) + "</tr>")
    return table(header, rows)


# --- the pages -------------------------------------------------------------------------------------------


def render_sample_html(report: SampleReport) -> str:
    """The whole self-contained report page of one sample."""
    name = report.material.name
    parts = [
        _header(report),
        "<h2>Findings</h2>",
        _findings_table(report),
        "<h2>Measurements</h2>",
        f"<p>Cells over the warn thresholds are amber, over the fail thresholds red (RMSE "
        f"{report.thresholds.rmse_warn:g} / {report.thresholds.rmse_fail:g}, ΔE00 "
        f"{report.thresholds.delta_e_warn:g} / {report.thresholds.delta_e_fail:g}); "
        "a row's left edge shows the worst finding about it.</p>",
        _measurement_table(report),
        "<h2>Measured vs predicted</h2>",
        png_img(
            draw_spectra(report),
            "plot-spectra",
            f"{name}: measured and predicted reflectance of every measurement, with residuals",
        ),
        "<h2>K and S</h2>",
        png_img(draw_ks(report), "plot-ks", f"{name}: K and S per mm with standard-error bands"),
    ]
    if report.illuminants:
        parts += [
            "<h2>Colour swatches</h2>",
            png_img(
                draw_swatches(report),
                "plot-swatches",
                f"{name}: measured and predicted colour of every measurement under {report.illuminants[0]}",
            ),
        ]
        parts.append(uncertainty_section(report))
    elif report.spectral:
        parts.append('<p class="note">No illuminant was chosen, so no colour differences or swatches.</p>')
    else:
        parts.append(
            '<p class="note">Camera-channel material: colour differences (ΔE 2000) and colour '
            "swatches need spectra, so they are not computed for this sample.</p>"
        )
    return _page(f"kmpipe validation: {name}", "\n".join(parts))


def write_sample_report(report: SampleReport, out_dir: Path) -> Path:
    """Write ``report.html`` and then ``validation.json`` into ``out_dir`` (created); return the HTML path.

    Both documents are made before either is written, and the JSON (what batch readers look for) is written last,
    so an exit at any moment never leaves a validation.json without its report.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    document = json.dumps(report_to_dict(report, html="report.html"), indent=1, allow_nan=False)
    page = render_sample_html(report)
    path = out_dir / "report.html"
    write_text_atomically(path, page)
    write_text_atomically(out_dir / "validation.json", document + "\n")
    return path


def write_index(entries: list[tuple[dict, Path]], out_dir: Path, links: Sequence[tuple[str, Path]] = ()) -> Path:
    """Write ``index.html`` and ``summary.json`` for a batch into ``out_dir``, failing samples first; ``entries``
    pair each report's document (:func:`report_to_dict`, as in validation.json) with its report.html; ``links``
    (title, page) are listed above the table (the line's shade review). Return the index path."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    ordered = sorted(entries, key=lambda e: (-SEVERITIES.index(e[0]["verdict"]), e[0]["sample"]))
    summary, rows = [], []
    for doc, page in ordered:
        link = Path(os.path.relpath(Path(page).resolve(), out_dir.resolve())).as_posix()
        worst = doc["worst_delta_e_2000"]
        summary.append(
            {key: doc[key] for key in ("sample", "product", "verdict", "worst_delta_e_2000", "reasons")}
            | {"report": link}
        )
        rows.append(
            f'<tr class="{doc["verdict"]}"><td>{html.escape(doc["sample"])}</td>'
            f"<td>{html.escape(doc['product'])}</td><td>{_badge(doc['verdict'])}</td>"
            f'<td class="num">{"—" if worst is None else f"{worst:.2f}"}</td>'
            f"<td>{html.escape(', '.join(doc['reasons'])) or '—'}</td>"
            f'<td><a href="{html.escape(quote(link))}">{html.escape(link)}</a></td></tr>'
        )
    counts = ", ".join(f"{sum(e[0]['verdict'] == v for e in entries)} {v}" for v in reversed(SEVERITIES))
    pages = "".join(
        f'<p><a href="{html.escape(quote(Path(os.path.relpath(Path(page).resolve(), out_dir.resolve())).as_posix()))}">'
        f"{html.escape(title)}</a></p>\n"
        for title, page in links
    )
    body = f"<h1>kmpipe validation: {len(entries)} samples</h1>\n<p>{counts}</p>\n{pages}" + table(
        ["sample", "product", "verdict", "worst ΔE00", "reasons", "report"], rows
    )
    write_text_atomically(out_dir / "summary.json", json.dumps(summary, indent=1, allow_nan=False) + "\n")
    path = out_dir / "index.html"
    write_text_atomically(path, _page("kmpipe validation summary", body))
    return path
