"""Which foundation shade suits which skin tone, and whether a match made in daylight holds under other light.

A foundation of K and S (1/mm) worn at thickness X (mm) over skin of reflectance R_g gives the made-up skin's
reflectance by Kubelka-Munk (thesis eq. 3.14, :func:`kmpipe.physics.kubelka_munk.reflectance_over_background`);
its masstone (the film so thick that the skin no longer shows) is R_inf = 1 + K/S - sqrt((K/S)^2 + 2 K/S). Colours
are CIELAB under each illuminant relative to that illuminant's perfect white (CIE 15: no adaptation between the
pair's members, both are seen under the same light), colour differences Delta E 2000 (CIE 142-2001):

- coverage = Delta E 2000(bare skin, made-up skin): how much the film changes the skin; 0 at X = 0 and
  Delta E 2000(bare skin, masstone) for an opaque film;
- match = Delta E 2000(masstone, bare skin): how far the shade itself lies from the tone, whatever the thickness
  (the colour the made-up skin tends to as the film builds); the best-matching shade of a tone has the smallest;
- metamerism index of a pair that matches (Delta E 2000 <= a threshold) under the reference illuminant: its
  Delta E 2000 under each other illuminant (CIE 15:2018, ISO 18314-4 style, without a correction of the reference
  mismatch); the match breaks where that index passes the threshold.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kmpipe.physics.colorimetry import delta_E_2000, reflectance_to_Lab
from kmpipe.physics.kubelka_munk import reflectance_infinite, reflectance_over_background


def made_up(K, S, thickness_mm: float, skin) -> np.ndarray:
    """Reflectance of skin ``skin`` under a film of K, S (1/mm) ``thickness_mm`` thick, per wavelength."""
    K, S, skin = (np.asarray(a, dtype=float) for a in (K, S, skin))
    return reflectance_over_background(K, S, np.full_like(K, float(thickness_mm)), skin)


def masstone(K, S) -> np.ndarray:
    """R_inf of the film, per wavelength."""
    return reflectance_infinite(np.asarray(K, dtype=float), np.asarray(S, dtype=float))


def pair_delta_e(first, second, wavelengths, illuminants, observer: str = "2") -> np.ndarray:
    """Delta E 2000 between two reflectance spectra (..., n) under each illuminant, shape (len(illuminants), ...)."""
    return np.stack([
        delta_E_2000(reflectance_to_Lab(first, wavelengths, name, observer),
                     reflectance_to_Lab(second, wavelengths, name, observer))
        for name in illuminants
    ])  # fmt: skip


def shift_words(lab: np.ndarray, reference: np.ndarray) -> str:
    """How colour ``lab`` differs from ``reference`` in words, its largest CIELAB differences first: "pinker",
    "greener", "yellower", "bluer", "lighter", "darker" (each named when it is at least a third of the largest)."""
    d = np.asarray(lab, dtype=float) - np.asarray(reference, dtype=float)
    names = [("lighter", "darker"), ("pinker", "greener"), ("yellower", "bluer")]
    largest = float(np.max(np.abs(d)))
    if largest == 0.0:
        return "the same"
    ranked = sorted(range(3), key=lambda i: -abs(d[i]))
    return " and ".join(names[i][0 if d[i] > 0 else 1] for i in ranked if abs(d[i]) >= largest / 3.0)


@dataclass(frozen=True)
class Ranking:
    """The best and second-best shades (indices) by match, and the margin between them (Delta E 2000); second and
    margin are None for a line of one shade."""

    best: int
    second: int | None
    margin: float | None


def rank_shades(match: np.ndarray) -> Ranking:
    """Rank shades by their match Delta E (1-D, one per shade) to a tone; ties go to the first listed."""
    order = np.argsort(np.asarray(match, dtype=float), kind="stable")
    if order.size == 1:
        return Ranking(int(order[0]), None, None)
    return Ranking(int(order[0]), int(order[1]), float(match[order[1]] - match[order[0]]))


def broken_matches(delta_e: np.ndarray, reference: int, threshold: float) -> np.ndarray:
    """For pairs' Delta E (illuminants, ...) that match under illuminant ``reference`` (<= threshold): True under each
    illuminant where the match breaks (> threshold); False everywhere for a pair that does not match there."""
    delta_e = np.asarray(delta_e, dtype=float)
    matched = delta_e[reference] <= threshold
    return (delta_e > threshold) & matched[None, ...]
