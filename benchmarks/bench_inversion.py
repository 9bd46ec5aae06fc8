"""Benchmark: closed-form K, S inversions on 100,000 spectra x 401 wavelengths (380-780 nm, 1 nm).

Inputs are simulated drawdowns of realistic paint mixtures (see :mod:`common`): titanium white plus one
to three RIT paints per spectrum (Duncan mixing), films 10-60 um thick, read over the black (~0.035-0.041) and
white (~0.78-0.86) halves of a card and as a masstone, with Gaussian reading noise of 0.002. Curtis's method
assumes ideal backings, so it gets its own readings over backgrounds of exactly 0 and 1.

Reported per method, on noisy and on noise-free readings:

- values per second (spectra x wavelengths / s), best of 3 runs on the whole array;
- the time relative to the floor, one ``numpy.log1p`` pass over an array of the same size into a freshly
  allocated result (best of 3): target at most 10x (two_constant: 5x), goal 3x;
- the speed-up over a plain per-value Python loop of the same formula written with the ``math`` module
  (timed on a 20,000-value subsample, best of 3, scaled per value): target at least 100x;
- the fraction of values flagged, and the median and 99th percentile relative error of K and S against the
  truth at unflagged values of the noise-free readings.

Run alone: ``.venv/bin/python benchmarks/bench_inversion.py [--spectra N]``.
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import io
import math
import pstats
from dataclasses import dataclass

import numpy as np
from common import (
    NOISE,
    THICKNESS_RANGE,
    Pigments,
    Table,
    best_of,
    load_pigments,
    peak_rss_mib,
    random_recipes,
    sig,
    wavelength_grid,
)
from simulated_drawdowns import cards  # on sys.path through common

from kmpipe.physics.inversion import black_white, curtis, two_constant
from kmpipe.physics.kubelka_munk import film_over_background, film_reflectance_transmittance, reflectance_infinite

N_SPECTRA = 100_000
LOOP_VALUES = 20_000
#: Time over the log1p floor that each method must stay within; the goal for all three is 3.
FLOOR_TARGETS = {"black_white": 10.0, "curtis": 10.0, "two_constant": 5.0}
FLOOR_GOAL = 3.0
LOOP_TARGET = 100.0
CHUNK = 4096
#: Spectra used for the profile (a view of the first rows).
PROFILE_SPECTRA = 25_000


@dataclass
class Problem:
    """Mixtures (concentrations C), thicknesses X (rows, 1) and card reflectances; K, S are made on demand."""

    pigments: Pigments
    C: np.ndarray
    X: np.ndarray
    black: np.ndarray
    white: np.ndarray
    seed: int

    @property
    def shape(self) -> tuple[int, int]:
        return self.C.shape[0], self.pigments.wavelengths.size

    def truth(self, rows: slice) -> tuple[np.ndarray, np.ndarray]:
        return self.C[rows] @ self.pigments.K, self.C[rows] @ self.pigments.S

    def fill(self, buffers: list[np.ndarray], kind: str, noisy: bool) -> None:
        """Write readings into ``buffers``: kind "cards" = (R over black, R over white, masstone);
        kind "ideal" = (R over 0, R over 1). Noise is drawn per chunk from a seed of (seed, kind, chunk)."""
        n_rows = self.shape[0]
        for index, lo in enumerate(range(0, n_rows, CHUNK)):
            rows = slice(lo, min(lo + CHUNK, n_rows))
            K, S = self.truth(rows)
            R0, T = film_reflectance_transmittance(K, S, self.X[rows])
            if kind == "cards":
                parts = (
                    film_over_background(R0, T, self.black),
                    film_over_background(R0, T, self.white),
                    reflectance_infinite(K, S),
                )
            else:
                parts = (R0, film_over_background(R0, T, 1.0))
            rng = np.random.default_rng((self.seed, 1 if kind == "cards" else 2, index))
            for target, values in zip(buffers, parts, strict=False):
                target[rows] = values
                if noisy:
                    target[rows] += NOISE * rng.standard_normal(values.shape)


def make_problem(n_spectra: int = N_SPECTRA, seed: int = 20240611) -> Problem:
    wavelengths = wavelength_grid(1)
    pigments = load_pigments(wavelengths)
    rng = np.random.default_rng(seed)
    C = random_recipes(rng, n_spectra, len(pigments.names), pigments.white)
    X = rng.uniform(*THICKNESS_RANGE, size=(n_spectra, 1))
    backings = cards(wavelengths)
    return Problem(pigments, C, X, backings["black"], backings["white"], seed)


# ---------------------------------------------------------------------------- plain Python loops (reference)


def loop_black_white(Rb, Rw, Gb, Gw, X):
    """Per-value black/white inversion (notes.md): the 2x2 system in u = a - 1 and y = b coth(b S X)."""
    sqrt, log = math.sqrt, math.log
    K_out, S_out = [], []
    for rb, rw, gb, gw, x in zip(Rb, Rw, Gb, Gw, X, strict=True):
        s_b, d_b, s_w, d_w = rb + gb, rb - gb, rw + gw, rw - gw
        c_b, c_w = (1.0 - rb) * (1.0 - gb), (1.0 - rw) * (1.0 - gw)
        D = s_w * d_b - s_b * d_w
        u = (c_w * d_b - c_b * d_w) / D if D > 0.0 else -1.0
        y = (s_w * c_b - s_b * c_w) / D if D > 0.0 else 0.0
        a = 1.0 + u
        b = sqrt(a * a - 1.0) if u > 0.0 else 0.0
        if b > 0.0 and y > b:
            SX = 0.5 * log((y + b) / (y - b)) / b
            K_out.append(u * SX / x)
            S_out.append(SX / x)
        else:
            K_out.append(math.nan)
            S_out.append(math.nan)
    return K_out, S_out


def loop_two_constant(R_inf, R, R_g, X):
    """Per-value masstone + film inversion, the real-valued ln form of thesis eq. 4.1 (notes.md)."""
    log = math.log
    K_out, S_out = [], []
    for ri, r, g, x in zip(R_inf, R, R_g, X, strict=True):
        ks = (1.0 - ri) ** 2 / (2.0 * ri)
        den = (ri - r) * (1.0 / ri - g)
        q = (1.0 / ri - r) * (ri - g) / den if den != 0.0 else -1.0
        if q > 0.0:
            SX = log(q) / (1.0 / ri - ri)
            K_out.append(SX * ks / x)
            S_out.append(SX / x)
        else:
            K_out.append(math.nan)
            S_out.append(math.nan)
    return K_out, S_out


def loop_curtis(Rb, Rw, X):
    """Per-value Curtis et al. 1997 in the stable form of notes.md (ideal backings)."""
    sqrt, log1p = math.sqrt, math.log1p
    K_out, S_out = [], []
    for rb, rw, x in zip(Rb, Rw, X, strict=True):
        am1 = (1.0 - rw) * (1.0 - rb) / (2.0 * rb) if rb > 0.0 else -1.0
        if am1 > 0.0 and rw < 1.0:
            b = sqrt(am1 * (am1 + 2.0))
            z = am1 * (1.0 + rw) / (b * (1.0 - rw))
            if z > 1.0:
                SX = log1p(2.0 / (z - 1.0)) / (2.0 * b)
                K_out.append(am1 * SX / x)
                S_out.append(SX / x)
                continue
        K_out.append(math.nan)
        S_out.append(math.nan)
    return K_out, S_out


# ---------------------------------------------------------------------------------------------- measuring


@dataclass
class Timing:
    method: str
    data: str
    seconds: float
    values: int
    flagged: float
    floor_seconds: float
    loop_seconds_per_value: float | None = None
    loop_check: float | None = None  # largest relative K, S difference loop vs vectorized (unflagged values)

    @property
    def rate(self) -> float:
        return self.values / self.seconds

    @property
    def floor_ratio(self) -> float:
        return self.seconds / self.floor_seconds

    @property
    def loop_ratio(self) -> float | None:
        if self.loop_seconds_per_value is None:
            return None
        return self.loop_seconds_per_value * self.values / self.seconds


@dataclass
class Accuracy:
    method: str
    unflagged: float
    K_median: float
    K_p99: float
    S_median: float
    S_p99: float


def _relative_errors(problem: Problem, result) -> tuple[np.ndarray, np.ndarray]:
    """Relative errors of K and S at unflagged values (float32, to keep memory low), chunk by chunk."""
    K_errors, S_errors = [], []
    for lo in range(0, problem.shape[0], CHUNK):
        rows = slice(lo, lo + CHUNK)
        K_true, S_true = problem.truth(rows)
        ok = result.flags[rows] == 0
        K_errors.append(np.abs(result.K[rows][ok] / K_true[ok] - 1.0).astype(np.float32))
        S_errors.append(np.abs(result.S[rows][ok] / S_true[ok] - 1.0).astype(np.float32))
    return np.concatenate(K_errors), np.concatenate(S_errors)


def _accuracy(method: str, problem: Problem, result) -> Accuracy:
    K_err, S_err = _relative_errors(problem, result)
    total = result.flags.size
    if K_err.size == 0:
        return Accuracy(method, 0.0, *(math.nan,) * 4)
    K_q = np.percentile(K_err, [50, 99])
    S_q = np.percentile(S_err, [50, 99])
    return Accuracy(method, K_err.size / total, float(K_q[0]), float(K_q[1]), float(S_q[0]), float(S_q[1]))


def _subsample(rng, shape, count):
    rows = rng.integers(0, shape[0], size=count)
    cols = rng.integers(0, shape[1], size=count)
    return rows, cols


def _loop_check(result, rows, cols, K_loop, S_loop) -> float:
    """Largest relative difference of the loop's K and S from the vectorized result at unflagged values."""
    K_vec, S_vec = result.K[rows, cols], result.S[rows, cols]
    ok = (result.flags[rows, cols] == 0) & np.isfinite(K_loop) & np.isfinite(S_loop)
    ok &= (K_vec > 0) & (S_vec > 0)
    if not ok.any():
        return math.nan
    K_diff = np.abs(np.asarray(K_loop)[ok] / K_vec[ok] - 1.0)
    S_diff = np.abs(np.asarray(S_loop)[ok] / S_vec[ok] - 1.0)
    return float(max(K_diff.max(), S_diff.max()))


def run(n_spectra: int = N_SPECTRA, repeats: int = 3, loop_values: int = LOOP_VALUES) -> dict:
    """Time and check all three inversions; returns {"timings", "accuracy", "profile", "info"}."""
    problem = make_problem(n_spectra)
    shape = problem.shape
    values = shape[0] * shape[1]
    X, Gb, Gw = problem.X, problem.black, problem.white
    buffers = [np.empty(shape) for _ in range(3)]
    timings: list[Timing] = []
    accuracy: list[Accuracy] = []
    rng = np.random.default_rng(7)
    rows, cols = _subsample(rng, shape, loop_values)
    X_sample = X[rows, 0].tolist()

    floors: list[float] = []

    def measure(method: str, data: str, call, loop=None, loop_args=()):
        # Floor: one log1p pass over an array of this size into a freshly allocated result, timed next to
        # every method (the smallest of all is used) so that a busy moment does not skew the ratios.
        floors.append(best_of(lambda: np.log1p(buffers[0]), repeats)[0])
        seconds, result = best_of(call, repeats)
        timing = Timing(method, data, seconds, values, float(np.mean(result.flags != 0)), math.nan)
        if loop is not None:
            loop_seconds, (K_loop, S_loop) = best_of(lambda: loop(*loop_args), repeats)
            timing.loop_seconds_per_value = loop_seconds / loop_values
            timing.loop_check = _loop_check(result, rows, cols, K_loop, S_loop)
        else:
            accuracy.append(_accuracy(method, problem, result))
        timings.append(timing)
        del result
        gc.collect()

    for noisy in (True, False):
        data = "noisy" if noisy else "noise-free"
        problem.fill(buffers, "cards", noisy=noisy)
        Rb, Rw, Ri = buffers
        sample = {name: array[rows, cols].tolist() for name, array in (("Rb", Rb), ("Rw", Rw), ("Ri", Ri))}
        measure(
            "black_white",
            data,
            lambda: black_white(Rb, Rw, Gb, Gw, X),  # noqa: B023
            loop_black_white if noisy else None,
            (sample["Rb"], sample["Rw"], Gb[cols].tolist(), Gw[cols].tolist(), X_sample),
        )
        measure(
            "two_constant",
            data,
            lambda: two_constant(Ri, Rb, Gb, X),  # noqa: B023
            loop_two_constant if noisy else None,
            (sample["Ri"], sample["Rb"], Gb[cols].tolist(), X_sample),
        )
    for noisy in (True, False):
        data = "noisy" if noisy else "noise-free"
        problem.fill(buffers, "ideal", noisy=noisy)
        R0, R1 = buffers[0], buffers[1]
        measure(
            "curtis",
            data,
            lambda: curtis(R0, R1, X),  # noqa: B023
            loop_curtis if noisy else None,
            (R0[rows, cols].tolist(), R1[rows, cols].tolist(), X_sample),
        )
    floor = min(floors)
    for timing in timings:
        timing.floor_seconds = floor
    peak = peak_rss_mib()

    # Where the time goes, on the first PROFILE_SPECTRA noisy spectra (row views, no copies); each profiled
    # call follows an unprofiled one so that it does not pay for first-touch page faults.
    problem.fill(buffers, "cards", noisy=True)
    rows_profiled = slice(0, min(PROFILE_SPECTRA, shape[0]))
    Rb, Rw, Ri = (b[rows_profiled] for b in buffers)
    Xp = X[rows_profiled]
    calls = {
        "black_white": lambda: black_white(Rb, Rw, Gb, Gw, Xp),
        "two_constant": lambda: two_constant(Ri, Rb, Gb, Xp),
    }
    profiles = {}
    for method, call in calls.items():
        call()
        profiles[method] = _profile(call)
    info = {
        "spectra": shape[0],
        "wavelengths": shape[1],
        "values": values,
        "floor_seconds": floor,
        "peak_rss_mib": peak,
        "loop_values": loop_values,
        "repeats": repeats,
        "profiled_spectra": rows_profiled.stop,
    }
    return {"timings": timings, "accuracy": accuracy, "profile": profiles, "info": info}


def _profile(function, top: int = 8) -> list[tuple[str, int, float, float]]:
    """cProfile of one call: the ``top`` entries by own time as (function, calls, own s, cumulative s).

    numpy ufuncs are not seen by cProfile: their time counts as the own time of the Python function that
    calls them.
    """
    profiler = cProfile.Profile()
    profiler.enable()
    function()
    profiler.disable()
    stats = pstats.Stats(profiler, stream=io.StringIO())
    entries = []
    for (filename, line, name), (_, calls, own, cumulative, _) in stats.stats.items():
        short = filename.rsplit("/", 2)
        where = f"{short[-2]}/{short[-1]}:{line}" if len(short) >= 2 and line else filename
        entries.append((f"{name} ({where})", calls, own, cumulative))
    entries.sort(key=lambda entry: -entry[2])
    return entries[:top]


# ---------------------------------------------------------------------------------------------- reporting


def tables(results: dict) -> list[Table]:
    info = results["info"]
    speed_rows = []
    for t in results["timings"]:
        loop = t.loop_ratio
        missed = [
            name
            for name, ok in (
                ("floor", t.floor_ratio <= FLOOR_TARGETS[t.method]),
                ("loop", loop is None or loop >= LOOP_TARGET),
            )
            if not ok
        ]
        speed_rows.append(
            [
                t.method,
                t.data,
                f"{t.seconds:.3f}",
                f"{t.rate / 1e6:.1f}",
                f"{t.floor_ratio:.1f}",
                "" if loop is None else f"{loop:.0f}",
                f"{100 * t.flagged:.2f}",
                "yes" if not missed else "no (" + ", ".join(missed) + ")",
            ]
        )
    loop_notes = [
        f"{t.method}: plain loop {1e9 * t.loop_seconds_per_value:.0f} ns/value "
        f"({1e-6 / t.loop_seconds_per_value:.2f} M values/s); loop vs vectorized at unflagged values: "
        f"max relative difference {sig(t.loop_check, 2)}"
        for t in results["timings"]
        if t.loop_seconds_per_value is not None
    ]
    speed = Table(
        f"Closed-form inversion speed: {info['spectra']:,} spectra x {info['wavelengths']} wavelengths "
        f"= {info['values'] / 1e6:.1f} M values",
        [
            "method",
            "readings",
            "time (s)",
            "M values/s",
            "x log1p floor (<= 10; two_constant <= 5; goal 3)",
            "x loop speed-up (>= 100)",
            "flagged %",
            "targets met",
        ],
        speed_rows,
        [
            f"floor: one numpy.log1p pass over {info['values'] / 1e6:.1f} M values into a new array, "
            f"best of {info['repeats']} next to each method, smallest: {info['floor_seconds'] * 1e3:.1f} ms "
            f"({info['values'] / info['floor_seconds'] / 1e6:.0f} M values/s)",
            "first touch of fresh memory costs up to ~20 ns/value on this VM (guest pages not yet backed); "
            "best-of-3 times leave it out",
            "the regular paths' arithmetic runs in two numba loops per block (kmpipe/physics/inversion_kernels.py) "
            "around numpy's SIMD arctanh (black_white, curtis) or log1p (two_constant); the profiles below charge "
            "the first writes to the outputs (K, S, K/S and the flags; with the two readings about 41 bytes a value "
            "against the floor's 16) to the first loop",
            f"times are the best of {info['repeats']} runs on the whole array; the loop is timed on "
            f"{info['loop_values']:,} values and scaled per value",
            *loop_notes,
            "inputs: titanium white + 1-3 RIT Golden acrylics (Duncan mixing), 10-60 um films; cards ~0.035-0.041 / "
            "~0.78-0.86 (curtis: ideal 0 / 1); two_constant: masstone and the film over black; noise sd 0.002",
            f"peak resident memory of the benchmark process: {info['peak_rss_mib'] / 1024:.2f} GiB",
        ],
    )
    accuracy = Table(
        "Closed-form inversion accuracy (noise-free readings, unflagged values): relative error vs truth",
        ["method", "unflagged %", "K median", "K 99th pct", "S median", "S 99th pct"],
        [
            [
                a.method,
                f"{100 * a.unflagged:.2f}",
                sig(a.K_median, 2),
                sig(a.K_p99, 2),
                sig(a.S_median, 2),
                sig(a.S_p99, 2),
            ]
            for a in results["accuracy"]
        ],
        [],
    )
    profile_tables = []
    for method, entries in results["profile"].items():
        total = max(entry[3] for entry in entries) if entries else 1.0
        profile_tables.append(
            Table(
                f"cProfile of one {method} call (noisy readings, {info['profiled_spectra']:,} spectra, after a "
                "warm-up call), top entries by own time",
                ["function", "calls", "own s", "cumulative s", "own % of call"],
                [
                    [name, str(calls), f"{own:.3f}", f"{cumulative:.3f}", f"{100 * own / total:.0f}"]
                    for name, calls, own, cumulative in entries
                ],
                ["cProfile does not see numpy ufuncs: their time is the own time of the function calling them"],
            )
        )
    return [speed, accuracy, *profile_tables]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spectra", type=int, default=N_SPECTRA)
    parser.add_argument("--repeats", type=int, default=3)
    arguments = parser.parse_args()
    for table in tables(run(arguments.spectra, arguments.repeats)):
        table.print()


if __name__ == "__main__":
    main()
