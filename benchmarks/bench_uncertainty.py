"""Benchmark: the uncertainty budget of one sample carried to its rendered colour, linearized and by Monte Carlo.

One simulated sample (a RIT foundation, 81 wavelengths 380-780 nm every 5 nm, 6 readings: a masstone, 15 and 30 um
over black and white, and a repeat of the 30 um film over white; reading noise 0.002, thickness +- 1.5 um per
drawdown, white standard 0.5 %, backings 0.001). Timed, best of 5 after a warm-up, in-process:

- the budget (Jacobians, H, every source), then the linearized colour radius of a 20 um film over skin under D65,
  each source's share included (target <= 20 ms);
- the same plus 1,000 Monte Carlo refits and their colours (target <= 0.5 s);
- the ranking of what to measure next (every candidate addition, its extended budget and radius).

Beside the times, how the two radii compare (their relative difference) and how many draws the Monte Carlo radius
needs to settle (its spread over 10 seeds at each draw count). Run alone: ``.venv/bin/python
benchmarks/bench_uncertainty.py``.
"""

from __future__ import annotations

import time

import numpy as np
from common import Table

from kmpipe.physics.colour_uncertainty import colour_doubt, colour_radius, sampled_colours, sampled_radius
from kmpipe.physics.fit_covariance import Doubts, budget
from kmpipe.physics.kubelka_munk import reflectance_infinite, reflectance_over_background
from kmpipe.physics.next_measurement import rank
from kmpipe.physics.perturbed_fits import perturbed_fits

LINEAR_TARGET_S = 0.020
MONTE_CARLO_TARGET_S = 0.5
DRAWS = 1000
DESIGN = ((np.inf, None), (0.015, "black"), (0.015, "white"), (0.03, "black"), (0.03, "white"), (0.03, "white"))
FOUNDATION = {"TitaniumWhite": 1.0, "HansaYellowOpaque": 0.3, "CadmiumOrange": 0.25, "PyrroleRed": 0.05,
              "BoneBlack": 0.25}  # fmt: skip


def _sample():
    from simulated_drawdowns import cards, rit_pigments

    wavelengths = np.arange(380.0, 781.0, 5.0)
    K, S = rit_pigments().on(wavelengths).mixture(FOUNDATION, 60.0)
    card = cards(wavelengths)
    X = np.array([x for x, _ in DESIGN])
    G = np.array([card[o] if o else np.zeros(wavelengths.size) for _, o in DESIGN])
    y = np.array([reflectance_infinite(K, S) if o is None else reflectance_over_background(K, S, x, card[o])
                  for x, o in DESIGN])  # fmt: skip
    y = y + 0.002 * np.random.default_rng(0).standard_normal(y.shape)
    films = sorted({x for x, o in DESIGN if o})
    names = ("black", "white")
    doubts = Doubts(
        sigma=np.full(y.shape, 0.002),
        thickness_u=np.where(np.isfinite(X), 0.0015, 0.0),
        drawdown=np.array([films.index(x) if o else -1 for x, o in DESIGN]),
        backing=np.array([names.index(o) if o else -1 for _, o in DESIGN]),
        backing_readings=np.array([card[n] for n in names]),
        backing_sigma=np.full((2, wavelengths.size), 0.001),
        backing_names=names,
        white_u=np.full(wavelengths.size, 0.005),
        drawdown_names=tuple(f"{x * 1000:g} um" for x in films),
    )
    return wavelengths, K, S, X, G, y, doubts


def _best(fn, repeats: int = 5) -> tuple[float, object]:
    fn()
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return min(times), result


def run() -> dict:
    wavelengths, K, S, X, G, y, doubts = _sample()
    skin = np.full(wavelengths.size, 0.45)

    def linear():
        b = budget(K, S, X, G, y, doubts)
        return b, colour_doubt(b, 0.02, skin, wavelengths, "D65")

    def monte_carlo():
        b, doubt = linear()
        draws = perturbed_fits(b, X, G, y, doubts, draws=DRAWS)
        return doubt, sampled_radius(sampled_colours(draws.K, draws.S, 0.02, skin, wavelengths, "D65"), doubt.lab)

    t_linear, (b, doubt) = _best(linear)
    t_total, (_, sampled) = _best(monte_carlo)
    t_rank, ranked = _best(lambda: rank(b, doubts, X, lambda bb: colour_radius(bb, 0.02, skin, wavelengths, "D65")),
                           repeats=3)  # fmt: skip
    settle = []
    for count in (250, 1000, 4000):
        radii = []
        for seed in range(10):
            draws = perturbed_fits(b, X, G, y, doubts, draws=count, seed=seed)
            radii.append(sampled_radius(sampled_colours(draws.K, draws.S, 0.02, skin, wavelengths, "D65"), doubt.lab))
        settle.append((count, float(np.mean(radii)), float(np.std(radii))))
    return {"linear_s": t_linear, "total_s": t_total, "rank_s": t_rank, "radius": doubt.radius, "sampled": sampled,
            "dominant": doubt.dominant, "share": doubt.sources[doubt.dominant][1], "best": ranked[0].line(),
            "candidates": len(ranked), "settle": settle}  # fmt: skip


def tables(result: dict) -> list[Table]:
    rows = [
        ["budget + linearized radius", f"{result['linear_s'] * 1e3:.1f} ms", f"<= {LINEAR_TARGET_S * 1e3:.0f} ms",
         "yes" if result["linear_s"] <= LINEAR_TARGET_S else "no"],
        [f"... + {DRAWS} Monte Carlo refits", f"{result['total_s'] * 1e3:.0f} ms",
         f"<= {MONTE_CARLO_TARGET_S * 1e3:.0f} ms", "yes" if result["total_s"] <= MONTE_CARLO_TARGET_S else "no"],
        [f"what to measure next ({result['candidates']} candidates)", f"{result['rank_s'] * 1e3:.0f} ms", "-", "-"],
    ]  # fmt: skip
    accuracy = [[f"{count}", f"{mean:.4f}", f"{sd:.4f}", f"{(mean / result['radius'] - 1) * 100:+.1f} %"]
                for count, mean, sd in result["settle"]]  # fmt: skip
    notes = [
        "best of 5 after a warm-up, in-process; a 20 um film of a RIT foundation over a 0.45 grey skin, D65",
        f"radius: +-{result['radius']:.3f} linearized, +-{result['sampled']:.3f} from {DRAWS} draws; "
        f"{result['dominant']} dominates ({result['share']:.0%})",
        f"best addition: {result['best']}",
    ]
    settle = [
        f"linearized: {result['radius']:.4f} Delta E 2000 (95 %); the sd is what one report's Monte Carlo radius may "
        "be off by at that count"
    ]
    time_title = "Uncertainty of one sample's rendered colour (81 wavelengths, 6 readings): time"
    settle_title = "The Monte Carlo radius against the linearized one, by the number of draws"
    settle_header = ["draws", "mean radius over 10 seeds", "sd over seeds", "against linearized"]
    return [
        Table(time_title, ["step", "time", "target", "met"], rows, notes),
        Table(settle_title, settle_header, accuracy, settle),
    ]


def main() -> None:
    for table in tables(run()):
        table.print()


if __name__ == "__main__":
    main()
