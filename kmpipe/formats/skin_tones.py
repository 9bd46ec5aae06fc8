"""Skin tones for shade reviews: reflectance spectra of skin, built in or measured by the lab, with what a reviewer
needs to tell them apart (name, body site, CIELAB and the ITA angle).

Sources, as ``[review] tones`` lists them:

- ``"builtin"``: the chart and complexion samples colour-science ships (:data:`BUILTIN`): the four skin-tone patches
  of the PMC (preferred memory colour) chart, CIE test colour samples 13 (CIE 1995) and 15 (CIE 2024, a Japanese
  complexion), and the ColorChecker's "light skin" and "dark skin" (BabelColor average). They are chart patches and
  complexion samples, not measurements of people, and are named so. The PMC patches cover 400-700 nm and the
  ColorChecker 380-730 nm: outside that, their end values are carried on (constant extrapolation, CIE 15's practice
  and what scenes do with ColorChecker patches); every other source must cover the materials' grid.
- ``"builtin:ID"``: one of them (``builtin:tcs13``).
- ``"FILE.csv"`` or ``"FILE.csv:COLUMN"``: every column (or one) of a spectral CSV of ``quantity: reflectance``
  (docs/formats.md), each column a tone named after it; ``site.COLUMN: cheek`` header lines give body sites.
- ``"FILE.toml"``: a panel file, ``[[tone]]`` tables with ``name``, ``spectrum = "FILE.csv[:COLUMN]"`` and optional
  ``site`` and ``id``.

Every spectrum is resampled to the grid it is used on (never extrapolated but as said above) and must lie in
[0, 1]. The ITA (individual typology angle) is ITA = atan2(L* - 50, b*) in degrees, from CIELAB under D65 for the
CIE 1964 10 degree observer (Chardon et al. 1991): above 55 very light, 41-55 light, 28-41 intermediate, 10-28 tan,
-30-10 brown, below -30 dark.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import colour
import numpy as np
from pydantic import Field

from kmpipe.errors import InputError
from kmpipe.formats.toml_input import StrictModel, read_model

#: The built-in tones: id -> (name, colour-science dataset, dataset key, patch, what it is).
BUILTIN = {
    "pmc-1": ("PMC skin patch 1", "PMC", "Caucasian", "chart patch"),
    "pmc-2": ("PMC skin patch 2", "PMC", "Oriental", "chart patch"),
    "pmc-3": ("PMC skin patch 3", "PMC", "South Asian", "chart patch"),
    "pmc-4": ("PMC skin patch 4", "PMC", "African", "chart patch"),
    "tcs13": ("CIE TCS13 (complexion)", "CIE 1995", "TCS13", "complexion sample"),
    "tcs15": ("CIE TCS15 (Japanese complexion)", "CIE 2024", "TCS15", "complexion sample"),
    "cc-light-skin": ("ColorChecker light skin", "BabelColor Average", "light skin", "chart patch"),
    "cc-dark-skin": ("ColorChecker dark skin", "BabelColor Average", "dark skin", "chart patch"),
}
#: ITA classes (Chardon et al. 1991), lower bound in degrees and name.
ITA_CLASSES = ((55.0, "very light"), (41.0, "light"), (28.0, "intermediate"), (10.0, "tan"), (-30.0, "brown"),
               (-math.inf, "dark"))  # fmt: skip


@dataclass(frozen=True)
class SkinTone:
    """A skin tone's reflectance on a grid. ``id``: a file-safe name (unique in a review); ``kind``: "chart patch",
    "complexion sample" or "measured"; ``source``: where it came from (for the report)."""

    id: str
    name: str
    kind: str
    source: str
    site: str | None
    wavelengths: np.ndarray  # nm
    reflectance: np.ndarray  # fraction, on ``wavelengths``

    @property
    def lab(self) -> np.ndarray:
        """CIELAB under D65, CIE 1964 10 degree observer (the ITA's convention)."""
        from kmpipe.physics.colorimetry import reflectance_to_Lab

        return reflectance_to_Lab(self.reflectance, self.wavelengths, "D65", "10")

    @property
    def ita_deg(self) -> float:
        """ITA = atan2(L* - 50, b*) in degrees."""
        L, _, b = self.lab
        return math.degrees(math.atan2(L - 50.0, b))

    @property
    def ita_class(self) -> str:
        ita = self.ita_deg
        return next(name for bound, name in ITA_CLASSES if ita > bound)


def tone_id(name: str) -> str:
    """A tone's file-safe id from its name: lower case letters, digits and dashes."""
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-") or "tone"


def _builtin(key: str, wavelengths: np.ndarray | None) -> SkinTone:
    name, dataset, patch, kind = BUILTIN[key]
    if dataset in colour.SDS_COLOURCHECKERS:
        sd = colour.SDS_COLOURCHECKERS[dataset][patch]
        source = f"colour-science SDS_COLOURCHECKERS['{dataset}']['{patch}']"
    else:
        sd = colour.quality.SDS_TCS[dataset][patch]
        source = f"colour-science SDS_TCS['{dataset}']['{patch}']"
    if wavelengths is None:
        wavelengths = np.asarray(sd.wavelengths, dtype=float)
    values = np.interp(wavelengths, sd.wavelengths, sd.values)  # constant beyond the ends, as said above
    return SkinTone(key, name, kind, source, None, wavelengths, np.clip(values, 0.0, 1.0))


class _PanelTone(StrictModel):
    name: str = Field(min_length=1, max_length=80)
    id: str | None = Field(default=None, min_length=1, max_length=40, pattern=r"^[a-z0-9][a-z0-9-]*$")
    site: str | None = Field(default=None, min_length=1, max_length=80)
    spectrum: str = Field(min_length=1)


class _Panel(StrictModel):
    tone: list[_PanelTone] = Field(min_length=1)


def _csv_tones(path: Path, column: str | None, wavelengths: np.ndarray | None, where: dict) -> list[SkinTone]:
    """The tones of a reflectance CSV (every column, or ``column``), resampled to ``wavelengths`` (None: as read)."""
    from kmpipe.formats.spectra import read_spectra_csv
    from kmpipe.formats.spectral_grid import resample

    if not path.is_file():
        raise InputError(f"names the skin spectra {path}, which does not exist", **where)
    table = read_spectra_csv(path)
    if table.wavelengths is None or table.quantity != "reflectance":
        raise InputError("skin tones are reflectance spectra ('# quantity: reflectance' over wavelengths in nm)",
                         path=path, field="quantity")  # fmt: skip
    table.validate_values()
    if column is not None and column not in table.columns:
        raise InputError(f"no column {column!r}; the file has {', '.join(table.columns)}", path=path, field=column)
    if table.values.max() > 1.0:
        k, i = np.unravel_index(int(np.argmax(table.values)), table.values.shape)
        raise InputError(
            f"reflectance {table.values[k, i]:g} at {table.sample_labels[i]} nm is above 1: a skin reflectance is a "
            "fraction of the white standard's",
            path=path,
            field=table.columns[k],
        )
    lo, hi = float(table.wavelengths[0]), float(table.wavelengths[-1])
    if wavelengths is None:
        wavelengths, values = table.wavelengths, table
    elif lo > wavelengths[0] + 1e-9 or hi < wavelengths[-1] - 1e-9:
        raise InputError(f"covers {lo:g}-{hi:g} nm; the review needs {wavelengths[0]:g}-{wavelengths[-1]:g} nm "
                         "(the materials' grid): measure the whole range", path=path, field="wavelength")  # fmt: skip
    else:
        values = resample(table, wavelengths)
    tones = []
    for name in [column] if column is not None else table.columns:
        site = table.metadata.get(f"site.{name}")
        tones.append(SkinTone(tone_id(name), name, "measured", f"{path.name}:{name}", site, wavelengths,
                              np.asarray(values.column(name), dtype=float)))  # fmt: skip
    return tones


def source_kind(source: str, where: dict) -> tuple[str, str]:
    """What a tone source is, ``("builtin", ID or "")``, ``("csv", "FILE.csv[:COLUMN]")`` or ``("panel",
    "FILE.toml")``; InputError (at ``where``) for an unknown source or built-in id."""
    kind, _, rest = source.partition(":")
    if kind == "builtin":
        if rest and rest not in BUILTIN:
            raise InputError(f"no built-in skin tone {rest!r}; there are {', '.join(BUILTIN)}", **where)
        return "builtin", rest
    if kind.lower().endswith(".csv"):
        return "csv", source
    if source.lower().endswith(".toml"):
        return "panel", source
    raise InputError(f"unknown skin-tone source {source!r}: expected 'builtin', 'builtin:ID', 'FILE.csv', "
                     "'FILE.csv:COLUMN' or a panel 'FILE.toml'", **where)  # fmt: skip


def _refuse_repeated(ids: list[str], where: dict) -> None:
    repeated = sorted({i for i in ids if ids.count(i) > 1})
    if repeated:
        raise InputError(f"two skin tones share the id {', '.join(repeated)}: give them different names", **where)


def read_tones(sources: list[str], wavelengths: np.ndarray | None, base: Path, where: dict) -> list[SkinTone]:
    """The tones the ``sources`` name (see the module), on ``wavelengths`` (nm; None: each on its own grid), paths
    relative to ``base``; InputError naming the file or field for a source that is unknown, missing, off the grid,
    negative or above 1, and for two tones with one id."""
    wavelengths = None if wavelengths is None else np.asarray(wavelengths, dtype=float)
    tones: list[SkinTone] = []
    for source in sources:
        kind, rest = source_kind(source, where)
        if kind == "builtin":
            tones += [_builtin(k, wavelengths) for k in ([rest] if rest else BUILTIN)]
        elif kind == "csv":
            file, _, column = rest.partition(":")
            tones += _csv_tones(base / file, column or None, wavelengths, where)
        else:
            path = base / source
            if not path.is_file():
                raise InputError(f"names the skin-tone panel {path}, which does not exist", **where)
            _, panel = read_model(path, "a skin-tone panel", _Panel)
            for i, entry in enumerate(panel.tone):
                file, _, column = entry.spectrum.partition(":")
                at = {"path": path, "field": f"tone[{i + 1}].spectrum"}  # 1-based, as every field
                if not column:
                    raise InputError("give the column: spectrum = 'FILE.csv:COLUMN'", **at)
                [tone] = _csv_tones(path.parent / file, column, wavelengths, at)
                tones.append(SkinTone(entry.id or tone_id(entry.name), entry.name, "measured", tone.source,
                                      entry.site, tone.wavelengths, tone.reflectance))  # fmt: skip
    _refuse_repeated([t.id for t in tones], where)
    if not tones:
        raise InputError("no skin tone: give at least one source", **where)
    return tones


def tone_digests(sources: list[str], base: Path, where: dict) -> list[tuple[str, str, str]]:
    """(source, tone id, SHA-256 of the tone's name, site and spectrum as read) of every tone the ``sources`` name,
    in order: what a review row depends on, so that a changed or added tone re-runs only its own row."""
    import hashlib

    found = []
    for source in sources:
        for tone in read_tones([source], None, base, where):
            digest = hashlib.sha256(repr((tone.id, tone.name, tone.site, tone.kind)).encode())
            digest.update(np.ascontiguousarray(tone.wavelengths, dtype="<f8").tobytes())
            digest.update(np.ascontiguousarray(tone.reflectance, dtype="<f8").tobytes())
            found.append((source, tone.id, digest.hexdigest()))
    _refuse_repeated([f[1] for f in found], where)
    return found
