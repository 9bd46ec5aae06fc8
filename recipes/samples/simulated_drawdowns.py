"""What simulated drawdowns are made of: real pigment K and S, Duncan mixtures, and a black and a white card.

The one implementation for everything in this repository that simulates drawdown measurements: the bundled example
samples (``simulate_samples.py`` beside this file), the benchmarks (``benchmarks/common.py``) and the tests
(``tests/simulation.py``). It sits beside the samples it made, whose files must stay byte for byte what it gives;
the benchmarks and the tests put this folder on ``sys.path`` to import it (neither may import the other). It imports
nothing of kmpipe: what a film over these cards reads comes from kmpipe's forward model, in the callers.

- Pigments: the RIT Artist Paint Spectral Database's K and S of 19 Golden Heavy Body acrylics,
  ``pigments/rit_golden_acrylic_ks.csv`` in the shared data folder (two rows per paint, K and S, 380-750 nm every
  10 nm; fitted with Saunderson k1 = 0.03, k2 = 0.65). Both are on a relative scale (titanium white S = 1): a
  caller multiplies them by a factor it reads as per mm.
- Mixtures follow Duncan's rule: K = f sum_i c_i K_i, S = f sum_i c_i S_i (c_i the amounts, not normalised; f the
  factor to 1/mm).
- Cards: black ~0.035 and white ~0.78-0.86 (reflectance, fraction), with gentle spectral slopes.
"""

from __future__ import annotations

import csv
import functools
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: The environment variable that names the shared data folder (the one holding ``pigments/`` and ``paints/``) when
#: it is not ``shared/data`` beside the repository root.
SHARED_DATA_VARIABLE = "KMPIPE_SHARED_DATA"
REPOSITORY = Path(__file__).resolve().parents[2]
RIT_TABLE = Path("pigments") / "rit_golden_acrylic_ks.csv"


def shared_data() -> Path:
    """The shared data folder: ``$KMPIPE_SHARED_DATA`` when set, else ``../shared/data`` from the repository root.

    Raises
    ------
    FileNotFoundError
        The folder does not exist; the message names the folder looked for and the variable that moves it.
    """
    configured = os.environ.get(SHARED_DATA_VARIABLE)
    folder = Path(configured) if configured else REPOSITORY.parent / "shared" / "data"
    if not folder.is_dir():
        origin = f"${SHARED_DATA_VARIABLE} = {configured!r}" if configured else f"beside the repository {REPOSITORY}"
        raise FileNotFoundError(
            f"the shared data folder {folder} ({origin}) does not exist: it holds the real pigment and paint "
            f"measurements (pigments/, paints/, see its README.md) that simulated samples are made of; set "
            f"{SHARED_DATA_VARIABLE} to the folder that holds them"
        )
    return folder


@dataclass(frozen=True)
class Pigments:
    """K and S of paints in relative units (titanium white S = 1), each shape (n_wavelengths,), in the table's order.

    ``wavelengths``: the grid in nm.
    """

    wavelengths: np.ndarray
    K: Mapping[str, np.ndarray]
    S: Mapping[str, np.ndarray]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.K)

    def on(self, wavelengths, kind: str = "linear") -> Pigments:
        """The same paints on ``wavelengths`` (nm), the first and last values held beyond the table (to 780 nm).

        ``kind`` "linear" interpolates linearly (``np.interp``); "pchip" uses a monotone cubic (scipy's
        PchipInterpolator), which has no kinks at the table's wavelengths: for comparisons where a spectrum that is
        exactly piecewise linear on the 10 nm grid would flatter 10 nm sampling.
        """
        w = np.clip(np.asarray(wavelengths, dtype=np.float64), self.wavelengths[0], self.wavelengths[-1])
        if kind == "linear":

            def interpolate(values):
                return np.interp(w, self.wavelengths, values)
        elif kind == "pchip":
            from scipy.interpolate import PchipInterpolator

            def interpolate(values):
                return PchipInterpolator(self.wavelengths, values)(w)
        else:
            raise ValueError(f"unknown interpolation {kind!r}; expected 'linear' or 'pchip'")
        K = {name: interpolate(values) for name, values in self.K.items()}
        S = {name: interpolate(values) for name, values in self.S.items()}
        return Pigments(np.asarray(wavelengths, dtype=np.float64), K, S)

    def mixture(self, amounts: Mapping[str, float], per_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """K and S in 1/mm of a Duncan mixture: K = per_mm sum_i c_i K_i, S = per_mm sum_i c_i S_i.

        ``amounts``: {paint name: c_i}, not normalised; ``per_mm``: the factor that makes the relative units 1/mm.
        """
        K = per_mm * sum(c * self.K[name] for name, c in amounts.items())
        S = per_mm * sum(c * self.S[name] for name, c in amounts.items())
        return K, S


@functools.cache
def rit_pigments() -> Pigments:
    """The RIT table (see the module docstring) on its own grid, 380-750 nm every 10 nm; arrays read-only."""
    with open(shared_data() / RIT_TABLE, encoding="utf-8") as handle:
        rows = [row for row in csv.reader(handle) if row and not row[0].startswith("#")]
    header, body = rows[0], rows[1:]
    if header[:3] != ["pigment", "colour_index", "quantity"]:
        raise ValueError(f"{RIT_TABLE}: expected the columns pigment, colour_index, quantity, then wavelengths")
    wavelengths = np.array([float(v) for v in header[3:]])
    coefficients: dict[str, dict[str, np.ndarray]] = {"K": {}, "S": {}}
    for name, _, quantity, *values in body:
        array = np.array([float(v) for v in values])
        array.flags.writeable = False
        coefficients[quantity][name] = array
    if coefficients["K"].keys() != coefficients["S"].keys():
        raise ValueError(f"{RIT_TABLE}: every paint needs one K and one S row")
    wavelengths.flags.writeable = False
    return Pigments(wavelengths, coefficients["K"], coefficients["S"])


def cards(wavelengths) -> dict[str, np.ndarray]:
    """Reflectance (fraction) of the card's two backings at ``wavelengths`` (nm), x = (wavelength - 380) / 400:

    black = 0.035 + 0.006 x (0.035 at 380 nm to 0.041 at 780 nm),
    white = 0.78 + 0.08 (1 - exp(-(wavelength - 380) / 60)) (0.78 at 380 nm, 0.86 from about 600 nm).
    """
    w = np.asarray(wavelengths, dtype=np.float64)
    x = (w - 380.0) / 400.0
    return {"black": 0.035 + 0.006 * x, "white": 0.78 + 0.08 * (1.0 - np.exp(-(w - 380.0) / 60.0))}
