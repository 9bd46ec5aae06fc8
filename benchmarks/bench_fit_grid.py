"""Benchmark: speed against accuracy of the wavelength grid of the joint fit (10, 5 or 1 nm).

Samples are simulated at 1 nm (380-780 nm) as in :mod:`bench_fit` (six measurements, noise 0.002), with true
K and S from the RIT table interpolated by a monotone cubic (PCHIP): the table is tabulated every 10 nm, and a
truth that is piecewise linear between those points would make a 10 nm fit exact by construction. The 5 and
10 nm fits see every 5th / 10th 1 nm reading (an instrument sampling at that step, same noise per reading).
Each fit's K and S are resampled linearly to 1 nm and the six measurements are predicted at 1 nm; the table
gives the |Delta E 2000| of those predictions against the 1 nm fit's (the most exact setting) and against the
noise-free truth, with the fit time per sample. The closed form alone (black_white on one film pair, no fit)
is listed on each grid as the cheapest method.

Run alone: ``.venv/bin/python benchmarks/bench_fit_grid.py [--samples N]``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import numpy as np
from bench_fit import closed_form_start, fit_sample, make_samples, predict
from common import Table, delta_e_2000, load_pigments, wavelength_grid

N_SAMPLES = 16
STEPS = (10, 5, 1)


@dataclass
class Row:
    method: str
    step: int
    times_ms: np.ndarray
    evaluations: np.ndarray | None
    dE_reference: np.ndarray | None  # (samples, 6) vs the 1 nm fit
    dE_truth: np.ndarray  # (samples, 6) vs the noise-free 1 nm readings


def _to_1nm(values: np.ndarray, grid: np.ndarray, fine: np.ndarray) -> np.ndarray:
    return np.interp(fine, grid, values)


def run(n_samples: int = N_SAMPLES, seed: int = 23) -> dict:
    fine = wavelength_grid(1)
    pigments = load_pigments(fine, kind="pchip")
    samples = make_samples(pigments, n_samples, seed)
    truth = np.array([s.clean for s in samples])
    fit_sample(samples[0], columns=slice(None, None, 10))  # warm up

    predictions: dict[tuple[str, int], np.ndarray] = {}
    rows: list[Row] = []
    for step in STEPS:
        columns = slice(None, None, step)
        grid = fine[columns]
        for method in ("joint fit", "closed form"):
            times, evaluations, predicted = [], [], []
            for sample in samples:
                start = time.perf_counter()
                if method == "joint fit":
                    result = fit_sample(sample, columns=columns)
                    evaluations.append(result.evaluations)
                else:
                    result = closed_form_start(sample, columns)
                times.append(1e3 * (time.perf_counter() - start))
                K = _to_1nm(result.K, grid, fine)
                S = _to_1nm(result.S, grid, fine)
                predicted.append(predict(K, S, sample.thickness, sample.backgrounds))
            predictions[method, step] = np.array(predicted)
            rows.append(
                Row(
                    method,
                    step,
                    np.array(times),
                    np.array(evaluations) if evaluations else None,
                    None,
                    delta_e_2000(truth, predictions[method, step], fine),
                )
            )
    reference = predictions["joint fit", 1]
    for row in rows:
        row.dE_reference = delta_e_2000(reference, predictions[row.method, row.step], fine)
    return {"rows": rows, "n_samples": n_samples}


def tables(results: dict) -> list[Table]:
    rows = []
    by_key = {(r.method, r.step): r for r in results["rows"]}
    reference_ms = float(np.median(by_key["joint fit", 1].times_ms))
    for r in sorted(results["rows"], key=lambda r: (r.method != "joint fit", -r.step)):
        median_ms = float(np.median(r.times_ms))
        rows.append(
            [
                r.method,
                f"{r.step} nm",
                f"{median_ms:.2f}",
                f"{reference_ms / median_ms:.1f}",
                "" if r.evaluations is None else f"{np.median(r.evaluations):.0f}",
                f"{np.median(r.dE_reference):.3f}",
                f"{np.percentile(r.dE_reference, 95):.3f}",
                f"{r.dE_reference.max():.3f}",
                f"{np.median(r.dE_truth):.3f}",
                f"{np.percentile(r.dE_truth, 95):.3f}",
            ]
        )
    return [
        Table(
            "Wavelength grid of the fit: speed vs accuracy (predictions at 1 nm, 380-780 nm)",
            [
                "method",
                "grid",
                "ms/sample",
                "x faster than 1 nm fit",
                "evaluations",
                "dE00 vs 1 nm fit median",
                "p95",
                "max",
                "dE00 vs truth median",
                "p95",
            ],
            rows,
            [
                f"{results['n_samples']} samples x 6 measurements (as in bench_fit), noise sd 0.002 "
                "per reading; truth K, S: RIT table, PCHIP to 1 nm",
                "coarser fits: K and S resampled linearly to 1 nm before predicting; closed form = black_white "
                "on the X2 pair only (no joint fit)",
                "Delta E 2000: D65, CIE 1931 2 degree observer, colour.sd_to_XYZ (ASTM E308) on the 1 nm predictions",
            ],
        )
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=N_SAMPLES)
    arguments = parser.parse_args()
    for table in tables(run(arguments.samples)):
        table.print()


if __name__ == "__main__":
    main()
