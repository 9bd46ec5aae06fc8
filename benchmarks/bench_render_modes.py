"""Benchmark: Delta E 2000 of the rgb and bands:N render modes against exact, and the time to build tables.

All 19 RIT paints (see :mod:`common`; here K and S x 60 per mm, i.e. ``load_pigments`` x 6) on the table's
380-750 nm / 10 nm grid, as single layers and as 2-layer stacks (every ordered pair) over the ColorChecker
N Ohta "light skin" patch, under D65, each layer at 10, 25 and 40 um. Errors are from
:func:`kmpipe.physics.optical_tables.mode_error` (tables at exactly those thicknesses: the mode's own error).

Run alone: ``.venv/bin/python benchmarks/bench_render_modes.py``.
"""

from __future__ import annotations

import time

import colour
import numpy as np
from common import Table, load_pigments

from kmpipe.physics.optical_tables import OpticalTable, Stack, band_partition, mode_error, working_space
from kmpipe.stages.render_plan import DEFAULT_TARGET_DE, plan_render
from renderer.stack import MAX_CHANNELS

MODES = ("rgb", "bands:3", "bands:6", "bands:9", "bands:12")


class _Paint:
    def __init__(self, name, wavelengths, K, S):
        self.name, self.wavelengths, self.K, self.S = name, wavelengths, K, S


def run() -> list[list[str]]:
    """Rows: mode, stacks, mean / p95 / max Delta E 2000 against exact, ms to build 19 tables x 65 thicknesses."""
    wavelengths = np.arange(380.0, 751.0, 10.0)
    pigments = load_pigments(wavelengths)
    paints = {
        n: _Paint(n, wavelengths, 6.0 * K, 6.0 * S)
        for n, K, S in zip(pigments.names, pigments.K, pigments.S, strict=True)
    }
    sd = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]["light skin"]
    skin = np.interp(wavelengths, sd.wavelengths, sd.values)
    names = list(paints)
    singles = [Stack(n, (n,), skin) for n in names]
    pairs = [Stack(f"{a}/{b}", (a, b), skin) for a in names for b in names if a != b]
    ranges = dict.fromkeys(names, (0.010, 0.040))
    space = working_space(wavelengths)
    rows = []
    for mode in MODES:
        bands = band_partition(wavelengths, int(mode.split(":")[1]), space=space) if mode != "rgb" else None
        start = time.perf_counter()
        for paint in paints.values():
            OpticalTable.build(paint, np.linspace(0.010, 0.040, 65), mode, space, bands)
        build_ms = 1e3 * (time.perf_counter() - start)
        for label, stacks in ((f"{len(singles)} single layers", singles), (f"{len(pairs)} 2-layer stacks", pairs)):
            e = mode_error(stacks, mode, paints, ranges)
            rows.append(
                [mode, label, f"{e.mean():.3f}", f"{np.percentile(e, 95):.3f}", f"{e.max():.3f}", f"{build_ms:.2f}"]
            )
    for label, stacks in ((f"{len(singles)} single layers", singles), (f"{len(pairs)} 2-layer stacks", pairs)):
        errors, chosen = [], []
        for stack in stacks:  # the planner's default, one scene per stack, as kmpipe render would plan it
            plan = plan_render(paints, [stack], ranges, max_bands=MAX_CHANNELS)
            chosen.append(plan.mode)
            errors.append(mode_error([stack], plan.mode, paints, ranges))
        e = np.concatenate(errors)
        modes, counts = np.unique(chosen, return_counts=True)
        picked = ", ".join(f"{m} x{c}" for m, c in sorted(zip(modes, counts, strict=True), key=lambda mc: -mc[1]))
        rows.append(
            [f"default ({picked})", label, f"{e.mean():.3f}", f"{np.percentile(e, 95):.3f}", f"{e.max():.3f}", "-"]
        )
    return rows


def tables(rows: list[list[str]]) -> list[Table]:
    return [
        Table(
            "Render modes against exact (19 RIT paints over light skin, D65, layers of 10, 25 and 40 um)",
            ["mode", "stacks", "dE00 mean", "p95", "max", "ms to build 19 tables x 65 thicknesses"],
            rows,
            [
                "errors from kmpipe.physics.optical_tables.mode_error: tables at exactly the probe "
                "thicknesses (the mode's own "
                "error, no interpolation)",
                "the planner (kmpipe.stages.render_plan) picks the cheapest mode whose worst error "
                "on the scene's own stacks meets its target",
                f"default: each stack planned as its own scene with the default target (max dE00 {DEFAULT_TARGET_DE}); "
                "target from the issue: mean dE00 of the default mode against exact below 0.5",
            ],
        )
    ]


def main() -> None:
    for table in tables(run()):
        table.print()


if __name__ == "__main__":
    main()
