"""Run every kmpipe benchmark, print the tables, and write them as Markdown to docs/benchmarks.md.

Usage (from the repository root): ``.venv/bin/python benchmarks/run_all.py``. Takes a few minutes and up to
about 7 GB of memory (the closed-form inversion works on 100,000 x 401 arrays). Benchmarks report speed and
accuracy; they do not pass or fail (speed is never part of the tests).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import bench_fit
import bench_fit_grid
import bench_inversion
import bench_look
import bench_render
import bench_render_modes
import bench_review
import bench_run
import bench_skin
import bench_trade
import bench_uncertainty
import numpy as np
from common import REPO, Table, machine

COMMAND = ".venv/bin/python benchmarks/run_all.py"


def _summary(
    inversion: dict,
    fit: dict,
    render_rows: list,
    mode_rows: list,
    skin_rows: list,
    look: dict,
    run_rows: dict,
    review_rows: list,
    uncertainty: dict,
    trade: dict,
) -> Table:
    rows = []
    for t in inversion["timings"]:
        if t.data != "noisy":
            continue
        rows.append(
            [
                f"{t.method}: time / log1p floor",
                f"<= {bench_inversion.FLOOR_TARGETS[t.method]:g} (goal {bench_inversion.FLOOR_GOAL:g})",
                f"{t.floor_ratio:.1f}",
                "yes" if t.floor_ratio <= bench_inversion.FLOOR_TARGETS[t.method] else "no",
            ]
        )
        rows.append(
            [
                f"{t.method}: speed-up over a Python loop",
                ">= 100",
                f"{t.loop_ratio:.0f}",
                "yes" if t.loop_ratio >= bench_inversion.LOOP_TARGET else "no",
            ]
        )
    for v in fit["variants"]:
        median_ms = float(np.median(v.times_ms))
        rows.append(
            [
                f"joint fit ({v.name}): ms per sample",
                "<= 50",
                f"{median_ms:.1f}",
                "yes" if median_ms <= bench_fit.TARGET_MS else "no",
            ]
        )
    turntable = max(float(r[2]) for r in render_rows if r[1] == "512 x 512")
    rows.append(
        [
            "36-frame turntable at 512 x 512, slowest mode: s",
            "< 10",
            f"{turntable:.1f}",
            "yes" if turntable < 10.0 else "no",
        ]
    )
    for r in mode_rows:
        if r[0].startswith("default"):
            rows.append(
                [
                    f"default render mode, mean dE00 against exact ({r[1]})",
                    "< 0.5",
                    r[2],
                    "yes" if float(r[2]) < 0.5 else "no",
                ]
            )
    for r in skin_rows:
        if r[1] == "512 x 512":
            seconds = float(r[5]) / 1e3
            rows.append(
                [
                    f"frame on skin, the demo face (4 films), shadows, SSS at 512 x 512 ({r[0]}): s",
                    "< 0.3",
                    f"{seconds:.3f}",
                    "yes" if seconds < bench_skin.TARGET_S else "no",
                ]
            )
    full = look["look"][0]
    rows.append([f"the full look at {bench_look.SIZE} x {bench_look.SIZE} (4 x AA), s per frame", "<= 1.0", full[1],
                 full[5]])  # fmt: skip
    packshot = look["turntable"][0]
    rows.append(["36-frame 512 x 512 packshot turntable, environment + AA: s", "<= 10", packshot[1], packshot[3]])
    for r in run_rows["demo"]:
        rows.append([f"demo line end to end ({r[0]}): s", "< 120", r[2], r[5]])
        rows.append([f"demo line, cached re-run ({r[0]}): s", "< 3", r[4], r[6]])
    one, pool, dask = run_rows["scaling"][:3]
    ratio = float(one[2]) / float(pool[2])
    rows.append(["16-product line: throughput of 2 processes / 1 process", ">= 1.8", f"{ratio:.2f}",
                 "yes" if ratio >= 1.8 else "no"])  # fmt: skip
    rows.append(["16-product line: throughput of 2 processes / 1 process on 1 core", "-",
                 f"{run_rows['per_core']:.2f}", "-"])  # fmt: skip
    slower = float(dask[2]) / float(pool[2]) - 1.0
    rows.append(["16-product line: Dask local cluster (2 workers) against the local pool: time", "within 10 %",
                 f"{slower:+.1%}", "yes" if abs(slower) <= 0.1 else "no"])  # fmt: skip
    own = float(one[7]) - run_rows["start"]
    rows.append(["16-product line, cached re-run beyond interpreter start and its imports: s", "< 1", f"{own:.2f}",
                 "yes" if own < 1.0 else "no"])  # fmt: skip
    for r in review_rows:
        rows.append([f"shade review 10 x 8 x 3, tiles 256, end to end ({r[0]}): s", "< 60", r[2], r[5]])
        rows.append([f"shade review, cached re-run ({r[0]}): s", "< 2", r[4], r[6]])
    limits = {"linear_s": bench_uncertainty.LINEAR_TARGET_S, "total_s": bench_uncertainty.MONTE_CARLO_TARGET_S}
    labels = {"linear_s": "budget + linearized colour radius, one sample: ms", "total_s": "... + 1,000 Monte Carlo: ms"}
    for key, target in limits.items():
        met = "yes" if uncertainty[key] <= target else "no"
        rows.append([labels[key], f"<= {target * 1e3:.0f}", f"{uncertainty[key] * 1e3:.0f}", met])
    met = "yes" if trade["seconds"] < bench_trade.TARGET_S else "no"
    rows.append(["kmpipe trade on the demo line, end to end: s", "< 300", f"{trade['seconds']:.0f}", met])
    return Table(
        "Targets", ["quantity", "target", "measured", "met"], rows, ["inversion and fit rows on noisy readings"]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--spectra",
        type=int,
        default=bench_inversion.N_SPECTRA,
        help="spectra in the inversion benchmark (default %(default)s)",
    )
    parser.add_argument(
        "--samples",
        type=int,
        default=bench_fit.N_SAMPLES,
        help="samples in the joint fit benchmark (default %(default)s)",
    )
    parser.add_argument(
        "--grid-samples",
        type=int,
        default=bench_fit_grid.N_SAMPLES,
        help="samples in the wavelength grid benchmark (default %(default)s)",
    )
    parser.add_argument("--output", type=Path, default=REPO / "docs" / "benchmarks.md")
    arguments = parser.parse_args()

    started = time.perf_counter()
    info = machine()
    if os.getloadavg()[0] > 0.5:
        print(
            f"note: 1-minute load average {os.getloadavg()[0]:.2f} at start; other work running now "
            "slows the timings (the numbers assume an idle machine)",
            file=sys.stderr,
        )
    parts: list[tuple[str, list[Table], float]] = []

    def measure(title: str, module, *args):
        """Run one benchmark module, keep its tables and time under ``title``, return its results."""
        print(f"{title} ...", file=sys.stderr, flush=True)
        clock = time.perf_counter()
        results = module.run(*args)
        parts.append((title, module.tables(results), time.perf_counter() - clock))
        return results

    inversion = measure("Closed-form inversion", bench_inversion, arguments.spectra)
    fit = measure("Joint fit", bench_fit, arguments.samples)
    measure("Wavelength grid of the fit", bench_fit_grid, arguments.grid_samples)
    mode_rows = measure("Render modes", bench_render_modes)
    render_rows = measure("Rendering", bench_render)
    skin_rows = measure("Makeup on skin", bench_skin)
    look = measure("The full look", bench_look)
    run_rows = measure("Product line", bench_run)
    uncertainty = measure("Uncertainty to the rendered colour", bench_uncertainty)
    review_rows = measure("Shade review", bench_review)
    trade = measure("The speed/accuracy trade of the demo line", bench_trade)
    total = time.perf_counter() - started

    summary = _summary(inversion, fit, render_rows, mode_rows, skin_rows, look, run_rows, review_rows, uncertainty,
                       trade)  # fmt: skip
    summary.print()
    for _, tables, _ in parts:
        for table in tables:
            table.print()
    print(f"total {total:.0f} s", file=sys.stderr)

    lines = [
        "# Benchmarks",
        "",
        "Speed and accuracy of kmpipe's closed-form inversions, joint K, S fit, render modes, rendering, skin, the",
        "full look on the bundled head, product-line runs, the uncertainty of the rendered colour, the shade",
        "review and the demo line's speed/accuracy trade (kmpipe trade), on simulated drawdowns",
        "of real paint K and S (RIT Artist Paint Spectral Database, Golden acrylics; titanium white plus 1-3",
        "paints, Duncan mixing, K and S of the table x 10 read as 1/mm). Written by `benchmarks/run_all.py`:",
        "do not edit by hand; rerun it. Benchmarks measure, they do not pass or fail; speed never goes into",
        "the tests.",
        "",
        "Reproduce (from the repository root):",
        "",
        "```",
        COMMAND,
        "```",
        "",
        "## Machine",
        "",
        "| | |",
        "|---|---|",
        *(f"| {key} | {value} |" for key, value in info.items()),
        f"| run time | {total:.0f} s |",
        "",
        summary.markdown(),
    ]
    for title, tables, seconds in parts:
        lines += [f"## {title}", "", f"({seconds:.0f} s)", ""]
        lines += [table.markdown() for table in tables]
    arguments.output.parent.mkdir(parents=True, exist_ok=True)
    temporary = arguments.output.with_suffix(".md.tmp")
    temporary.write_text("\n".join(lines).rstrip("\n") + "\n")
    os.replace(temporary, arguments.output)
    print(f"wrote {arguments.output}", file=sys.stderr)


if __name__ == "__main__":
    main()
