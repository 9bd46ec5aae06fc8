"""Benchmark: Delta E 2000 of the rgb and bands:N render modes against exact, and the time to build tables.

All 19 RIT paints (see :mod:`common`; here K and S x 60 per mm, i.e. ``load_pigments`` x 6) on the table's
380-750 nm / 10 nm grid, as single layers and as 2-layer stacks (every ordered pair) over the ColorChecker
N Ohta "light skin" patch, under D65, each layer at 10, 25 and 40 um. Errors are from
:func:`kmpipe.optical_tables.mode_error` (tables at exactly those thicknesses: the mode's own error).

Run alone: ``.venv/bin/python benchmarks/bench_render_modes.py``.
"""

from __future__ import annotations

import time

import colour
import numpy as np
from common import load_pigments

from kmpipe.optical_tables import OpticalTable, Stack, band_partition, mode_error, working_space

MODES = ("rgb", "bands:3", "bands:6", "bands:9", "bands:12")


class _Paint:
    def __init__(self, name, wavelengths, K, S):
        self.name, self.wavelengths, self.K, self.S = name, wavelengths, K, S


def main() -> None:
    wavelengths = np.arange(380.0, 751.0, 10.0)
    pigments = load_pigments(wavelengths)
    paints = {n: _Paint(n, wavelengths, 6.0 * K, 6.0 * S)
              for n, K, S in zip(pigments.names, pigments.K, pigments.S, strict=True)}
    sd = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]["light skin"]
    skin = np.interp(wavelengths, sd.wavelengths, sd.values)
    names = list(paints)
    singles = [Stack(n, (n,), skin) for n in names]
    pairs = [Stack(f"{a}/{b}", (a, b), skin) for a in names for b in names if a != b]
    ranges = dict.fromkeys(names, (0.010, 0.040))
    space = working_space(wavelengths)
    print(f"{len(singles)} single layers, {len(pairs)} 2-layer stacks over light skin, D65, 10/25/40 um")
    print(f"{'mode':>9} {'stacks':>7} {'mean dE00':>10} {'p95':>8} {'max':>8} {'build 19 tables x 65 X (ms)':>28}")
    for mode in MODES:
        bands = band_partition(wavelengths, int(mode.split(":")[1]), space=space) if mode != "rgb" else None
        start = time.perf_counter()
        for paint in paints.values():
            OpticalTable.build(paint, np.linspace(0.010, 0.040, 65), mode, space, bands)
        build_ms = 1e3 * (time.perf_counter() - start)
        for label, stacks in (("1-layer", singles), ("2-layer", pairs)):
            e = mode_error(stacks, mode, paints, ranges)
            print(f"{mode:>9} {label:>7} {e.mean():10.3f} {np.percentile(e, 95):8.3f} {e.max():8.3f} {build_ms:28.2f}")


if __name__ == "__main__":
    main()
