"""What to measure next: the one added measurement that would shrink a film's rendered-colour radius the most.

An added reading c (a film of thickness X_c over a backing, a masstone, or a repeat of a reading already made) with
model slopes j_c = (dR_c/dK, dR_c/dS) at each wavelength extends the fit's information and every source of its
budget (:mod:`kmpipe.physics.fit_covariance`) without refitting, since K and S hardly move:

    H += j_c j_c^T,   noise block += sigma_c^2 j_c j_c^T,   backing column += j_c dR_c/dG sigma_b,
    thickness vector += j_c dR_c/dX u   (a repeat: its film's u; a new drawdown: a new vector of its own u_c),
    white vector += j_c (R_c - G dR_c/dG) u_w / R_w,

and the radius is recomputed from the extended budget (:func:`kmpipe.physics.colour_uncertainty.colour_doubt`).
sigma_c is the median noise of the readings over the same backing (a repeat: that reading's); a film of a thickness
already measured is that drawdown (the budget groups films by thickness), so it shares its thickness error; a new
thickness is a new drawdown with u_c the sample's median relative thickness uncertainty times X_c (0 where the
manifest states none).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from kmpipe.physics.fit_covariance import Budget, Doubts, _interleave, block_diagonal, sensitivity

#: Thinnest and thickest new film suggested (mm).
FILM_RANGE_MM = (0.002, 0.2)


@dataclass(frozen=True)
class Candidate:
    """A measurement the lab could add: a film over a backing, a masstone, or a repeat of reading ``repeat_of``."""

    role: str  # "film" | "masstone" | "repeat"
    over: str | None
    thickness_mm: float  # inf for a masstone
    repeat_of: int | None = None
    thickness_u_mm: float = 0.0  # its standard uncertainty: the drawdown's, or the sample's relative one

    def describe(self) -> str:
        """'add a 45 um film over black', 'add a masstone', 'repeat the 30 um film over white'."""
        if self.role == "masstone":
            return "add a masstone (an opaque layer)"
        film = f"the {self.thickness_mm * 1000:g} um film over {self.over}"
        if self.role == "repeat":
            return "repeat the masstone reading" if self.over is None else f"repeat the reading of {film}"
        return f"add a {self.thickness_mm * 1000:g} um film over {self.over}"


def candidates(doubts: Doubts, thickness: np.ndarray) -> list[Candidate]:
    """A measured drawdown read over a backing it was not read over; new drawdowns half as thick as the thinnest and
    twice as thick as the thickest, over each backing; a masstone where there is none; a repeat of each distinct
    reading."""
    X = np.asarray(thickness, dtype=np.float64)
    films = sorted({float(x) for x in X[np.isfinite(X)]})
    read = {(int(b), float(x)) for b, x in zip(doubts.backing, X, strict=True)}
    stated = np.isfinite(X) & (doubts.thickness_u > 0.0)
    relative = float(np.median(doubts.thickness_u[stated] / X[stated])) if stated.any() else 0.0

    def u_of(x: float) -> float:
        same = X == x
        return float(np.max(doubts.thickness_u[same])) if same.any() else relative * x

    out: list[Candidate] = []
    for x in films:
        out += [Candidate("film", name, x, thickness_u_mm=u_of(x)) for b, name in enumerate(doubts.backing_names)
                if (b, x) not in read]  # fmt: skip
    if films:
        for x in sorted({round(films[0] / 2.0, 6), round(films[-1] * 2.0, 6)} - set(films)):
            if FILM_RANGE_MM[0] <= x <= FILM_RANGE_MM[1]:
                out += [Candidate("film", name, x, thickness_u_mm=u_of(x)) for name in doubts.backing_names]
    if not np.any(~np.isfinite(X)):
        out.append(Candidate("masstone", None, math.inf))
    seen = set()
    for i, x in enumerate(X):
        over = doubts.backing_names[doubts.backing[i]] if doubts.backing[i] >= 0 else None
        if (over, float(x)) not in seen:
            seen.add((over, float(x)))
            out.append(Candidate("repeat", over, float(x), i, u_of(float(x)) if np.isfinite(x) else 0.0))
    return out


def extended(budget: Budget, candidate: Candidate, doubts: Doubts, thickness: np.ndarray, saunderson=None) -> Budget:
    """The budget with ``candidate`` added (module docstring)."""
    X = np.asarray(thickness, dtype=np.float64)
    b = -1 if candidate.over is None else doubts.backing_names.index(candidate.over)
    G = np.zeros((1, budget.K.size)) if b < 0 else np.minimum(doubts.backing_readings[b], 1.0)[None, :]
    sens = sensitivity(budget.K, budget.S, np.array([candidate.thickness_mm]), G, saunderson)
    j = np.stack([sens.dK[0], sens.dS[0]], axis=-1)  # (n, 2)
    same = doubts.backing == b
    if candidate.role == "repeat":
        sigma = doubts.sigma[candidate.repeat_of]
    else:
        sigma = np.median(doubts.sigma[same if same.any() else slice(None)], axis=0)
    outer = j[:, :, None] * j[:, None, :]
    blocks = dict(budget.blocks)
    blocks["reading noise"] = blocks.get("reading noise", 0.0) + sigma[:, None, None] ** 2 * outer
    columns = dict(budget.columns)
    source = f"backing {candidate.over}"
    if b >= 0 and source in columns:
        columns[source] = columns[source] + j * (sens.dG[0] * doubts.backing_sigma[b])[:, None]
    vectors = dict(budget.vectors)
    if math.isfinite(candidate.thickness_mm):
        same_film = np.flatnonzero(X == candidate.thickness_mm)
        u = candidate.thickness_u_mm
        if same_film.size:  # a repeat, or the drawdown read over another backing: its thickness error
            d = doubts.drawdown[same_film[0]]
            source = f"thickness {doubts.drawdown_names[d]}" if d < len(doubts.drawdown_names) else None
        else:
            source = f"thickness new {candidate.thickness_mm * 1000:g} um"
        if u > 0.0 and source is not None:
            vectors[source] = vectors.get(source, 0.0) + _interleave(*(j * (sens.dX[0] * u)[:, None]).T)
    if doubts.white_u is not None and "white standard" in vectors:
        shift = (sens.R[0] - sens.dG[0] * G[0]) * doubts.white_u
        vectors["white standard"] = vectors["white standard"] + _interleave(*(j * shift[:, None]).T)
    kinds = dict(budget.kinds)
    kinds.setdefault("reading noise", "noise")
    kinds.update({name: "thickness" for name in vectors if name.startswith("thickness")})
    return replace(budget, H=budget.H + block_diagonal(outer), blocks=blocks, columns=columns, vectors=vectors,
                   kinds=kinds)  # fmt: skip


@dataclass(frozen=True)
class Suggestion:
    """An added measurement and the radius it would leave (Delta E 2000, 95 %), against today's."""

    candidate: Candidate
    radius: float
    today: float

    def line(self) -> str:
        """'add a 45 um film over black: +-0.90 -> +-0.30'."""
        return f"{self.candidate.describe()}: +-{self.today:.2f} -> +-{self.radius:.2f}"


def rank(
    budget: Budget,
    doubts: Doubts,
    thickness: np.ndarray,
    radius_of: Callable[[Budget], float],
    saunderson=None,
) -> list[Suggestion]:
    """Every candidate with the radius ``radius_of`` its extended budget gives, smallest first."""
    today = radius_of(budget)
    found = [Suggestion(c, radius_of(extended(budget, c, doubts, thickness, saunderson)), today)
             for c in candidates(doubts, thickness)]  # fmt: skip
    return sorted(found, key=lambda s: s.radius)
