"""Simulated drawdown samples for the tests: RIT pigment mixtures on the card of the bundled samples, written as files.

Pigments, Duncan mixtures and the card's black and white backings are those the bundled example samples were made
of (``recipes/samples/simulated_drawdowns.py``, shared with ``simulate_samples.py`` and the benchmarks). What a
film over the card reads comes from kmpipe's own forward model (:mod:`kmpipe.physics.kubelka_munk`, itself checked
against 50-digit arithmetic in test_kubelka_munk.py): use :func:`simulate_sample` only where that model is not
what is under test (fits, validation, the CLI); tests of the forward model or of the inversions simulate through
``mp_reference`` instead.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kmpipe.formats.spectra import SpectralTable, write_spectra_csv
from kmpipe.physics.kubelka_munk import reflectance_infinite, reflectance_over_background
from kmpipe.physics.saunderson import saunderson_forward

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "recipes" / "samples"))
from simulated_drawdowns import cards, rit_pigments, shared_data  # noqa: E402

__all__ = [
    "FOUNDATION",
    "LIPSTICK",
    "PER_MM",
    "REFLECTANCE",
    "Simulated",
    "cards",
    "rit_mixture",
    "rit_pigments",
    "shared_data",
    "simulate_sample",
    "write_sample",
]

#: The RIT table's K and S are relative (titanium white S = 1); x60 gives per-mm values typical of a foundation,
#: as in the bundled samples.
PER_MM = 60.0
#: The mixture of the bundled sample F1 (a liquid foundation) and of L1 (a lipstick), amounts of RIT paints.
FOUNDATION = {
    "TitaniumWhite": 1.0,
    "HansaYellowOpaque": 0.3,
    "CadmiumOrange": 0.25,
    "PyrroleRed": 0.05,
    "BoneBlack": 0.25,
}
LIPSTICK = {"PyrroleRed": 1.0, "QuinacridoneMagenta": 0.15, "TitaniumWhite": 0.05}
#: Metadata of every simulated reflectance CSV.
REFLECTANCE = {"quantity": "reflectance", "units": "1", "note": "SIMULATED by tests/simulation.py"}


def rit_mixture(
    amounts: Mapping[str, float], per_mm: float = PER_MM, wavelengths=None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(wavelengths nm, K 1/mm, S 1/mm) of a Duncan mixture of RIT paints, K = per_mm sum_i c_i K_i (S alike).

    On the table's own grid (380-750 nm every 10 nm) unless ``wavelengths`` is given (linear interpolation, the end
    values held beyond the table).
    """
    table = rit_pigments() if wavelengths is None else rit_pigments().on(wavelengths)
    K, S = table.mixture(amounts, per_mm)
    return table.wavelengths, K, S


@dataclass
class Simulated:
    """A sample as written: its manifest, the card and reading columns, and what each reading is.

    ``entries``: one dict per reading, in the order written: ``role`` ("masstone" or "film"), ``column``, ``over``
    (the backing's name; None for a masstone) and ``thickness_mm`` (inf for a masstone).
    """

    manifest: Path
    wavelengths: np.ndarray
    cards: dict[str, np.ndarray]
    columns: dict[str, np.ndarray]
    entries: list[dict] = field(default_factory=list)

    @property
    def folder(self) -> Path:
        return self.manifest.parent

    def group(self, role: str, over: str | None = None, um: float | None = None) -> list[str]:
        """The columns of the readings of one role over one backing (and of one thickness in um, if given)."""
        return [
            e["column"]
            for e in self.entries
            if e["role"] == role and e["over"] == over and (um is None or math.isclose(e["thickness_mm"], um / 1000.0))
        ]


def write_sample(
    folder: Path,
    wavelengths,
    card_values: Mapping[str, np.ndarray],
    columns: Mapping[str, np.ndarray],
    entries: Sequence[dict],
    *,
    name: str = "T",
    fit_table: str = "",
    masstone_thickness: str | None = None,
) -> Simulated:
    """``cards.csv``, ``readings.csv`` and ``manifest.toml`` (reflectance, no ``[white]``) in ``folder`` (made).

    ``fit_table``: TOML text put after ``[sample]`` (e.g. a ``[fit]`` table); ``masstone_thickness``: a thickness
    declared on every masstone (e.g. "40 um"), none by default.
    """
    folder.mkdir(parents=True, exist_ok=True)
    write_spectra_csv(
        SpectralTable(wavelengths, None, tuple(card_values), np.array(list(card_values.values())), REFLECTANCE),
        folder / "cards.csv",
    )
    write_spectra_csv(
        SpectralTable(wavelengths, None, tuple(columns), np.array(list(columns.values())), REFLECTANCE),
        folder / "readings.csv",
    )
    text = f'# SIMULATED by tests/simulation.py\n[sample]\nname = "{name}"\nproduct = "simulated"\nkind = "test"\n\n'
    text += fit_table
    for card in card_values:
        text += f'\n[[backing]]\nname = "{card}"\nfile = "cards.csv"\ncolumn = "{card}"\n'
    for e in entries:
        if e["role"] == "masstone":
            text += f'\n[[masstone]]\nfile = "readings.csv"\ncolumn = "{e["column"]}"\n'
            if masstone_thickness is not None:
                text += f'thickness = "{masstone_thickness}"\n'
    for e in entries:
        if e["role"] == "film":
            text += (
                f'\n[[film]]\nfile = "readings.csv"\ncolumn = "{e["column"]}"\nover = "{e["over"]}"\n'
                f'thickness = "{e["thickness_mm"] * 1000:g} um"\n'
            )
    manifest = folder / "manifest.toml"
    manifest.write_text(text, encoding="utf-8")
    return Simulated(manifest, np.asarray(wavelengths), dict(card_values), dict(columns), list(entries))


def simulate_sample(
    folder: Path,
    wavelengths,
    K,
    S,
    *,
    thicknesses_um: Sequence[float] = (15, 30),
    overs: Sequence[str] = ("black", "white"),
    repeats: int = 1,
    masstones: int = 1,
    saunderson: tuple[float, float] | None = None,
    noise: float = 0.0,
    rng: np.random.Generator | int = 0,
    edit: Callable[[dict[str, np.ndarray], np.ndarray], None] | None = None,
    name: str = "T",
    fit_table: str = "",
    masstone_thickness: str | None = None,
) -> Simulated:
    """A sample of K, S (1/mm) on the card :func:`cards`, written by :func:`write_sample` (which takes ``name``,
    ``fit_table`` and ``masstone_thickness``).

    Readings, in this order: ``masstones`` masstones (R_inf), then for each thickness (um) and each backing in
    ``overs`` ``repeats`` films over it; columns ``masstone_1``, ..., ``film_15um_black_1``, .... They are KM
    reflectances (:func:`kmpipe.physics.kubelka_munk.reflectance_over_background`); with ``saunderson`` (k1, k2)
    the surface reflection is added to the films, the masstones and the cards alike; then Gaussian noise of
    standard deviation ``noise`` (drawn from ``rng``: a generator, or the seed of a new one) is added to the films
    and masstones, column by column (the cards stay noise-free: a fit takes them as known);
    ``edit(columns, wavelengths)`` may then change readings in place (the fault under test).
    """
    card_values = cards(wavelengths)
    columns, entries = {}, []
    for r in range(masstones):
        columns[f"masstone_{r + 1}"] = reflectance_infinite(K, S)
        entries.append({"role": "masstone", "column": f"masstone_{r + 1}", "over": None, "thickness_mm": math.inf})
    for um in thicknesses_um:
        for over in overs:
            for r in range(repeats):
                column = f"film_{um:g}um_{over}_{r + 1}"
                columns[column] = reflectance_over_background(K, S, um / 1000.0, card_values[over])
                entries.append({"role": "film", "column": column, "over": over, "thickness_mm": um / 1000.0})
    if saunderson is not None:
        columns = {k: saunderson_forward(v, *saunderson) for k, v in columns.items()}
        card_values = {k: saunderson_forward(v, *saunderson) for k, v in card_values.items()}
    if noise:
        rng = np.random.default_rng(rng)  # a Generator comes back as it is
        columns = {k: v + rng.normal(0.0, noise, v.shape) for k, v in columns.items()}
    if edit is not None:
        edit(columns, np.asarray(wavelengths))
    return write_sample(
        folder,
        wavelengths,
        card_values,
        columns,
        entries,
        name=name,
        fit_table=fit_table,
        masstone_thickness=masstone_thickness,
    )
