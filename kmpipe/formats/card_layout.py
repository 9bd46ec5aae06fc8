"""Drawdown card layouts (TOML): where the markers, printed areas and sampled regions lie on a printed card.

The format is documented in ``docs/formats.md`` ("Drawdown card layout"). The file is read through the TOML input
layer (:mod:`kmpipe.formats.toml_input`) and its tables and keys checked by pydantic (unknown tables and keys
refused, except in ``[[region]]`` where any other key is metadata; values taken as written: a number is not given
as text); the card's rules (markers in their dictionary and on the card, quiet zones kept clear, ...) are the
layout's own (:class:`instruments.drawdown_card.layout.Layout`). Every problem is an
:class:`~kmpipe.errors.InputError` naming the file, line and field. Layouts are written with tomli-w.
"""

from __future__ import annotations

import os
from pathlib import Path

import tomli_w
from pydantic import ConfigDict, Field

from instruments.drawdown_card.layout import Layout, LayoutError, Marker, PrintedArea, Region
from kmpipe.errors import InputError
from kmpipe.formats.atomic_write import write_text_atomically
from kmpipe.formats.toml_input import (
    StrictModel,
    format_field,
    read_model,
    toml_line,
)

_HEADER = "# kmpipe drawdown card layout (docs/formats.md); lengths in mm from the card's top-left corner\n"


class _Table(StrictModel):
    model_config = ConfigDict(strict=True)


class CardTable(_Table):
    width_mm: float
    height_mm: float
    dictionary: str


class MarkerTable(_Table):
    id: int
    x_mm: float
    y_mm: float
    size_mm: float


class PrintedTable(_Table):
    x_mm: float
    y_mm: float
    w_mm: float
    h_mm: float
    gray: float


class RegionTable(_Table):
    """A region; every key but these is its metadata (checked by the layout)."""

    model_config = ConfigDict(extra="allow")
    name: str
    role: str
    x_mm: float
    y_mm: float
    w_mm: float
    h_mm: float


class LayoutFile(_Table):
    card: CardTable
    marker: list[MarkerTable] = Field(default=[])
    printed: list[PrintedTable] = Field(default=[])
    region: list[RegionTable] = Field(default=[])


def load_card_layout(path: str | os.PathLike[str]) -> Layout:
    """Read a card layout from a TOML file.

    Raises
    ------
    InputError
        Naming the file, line and field (entries counted from 1, e.g. ``region[5].x_mm``): an unreadable or invalid
        file, an unknown table or key, a missing key, a value of the wrong type, and every rule of the layout (an
        unknown dictionary, fewer than 3 markers, duplicate ids or names, a marker, printed area or region off the
        card, a printed area or region over a marker's quiet zone, ...).
    """
    path = Path(path)
    text, info = read_model(path, "card layout", LayoutFile)
    try:
        return Layout(
            width_mm=info.card.width_mm,
            height_mm=info.card.height_mm,
            dictionary=info.card.dictionary,
            markers=tuple(Marker(**m.model_dump()) for m in info.marker),
            regions=tuple(
                Region(**r.model_dump(exclude=set(r.model_extra)), metadata=r.model_extra) for r in info.region
            ),
            printed=tuple(PrintedArea(**p.model_dump()) for p in info.printed),
        )
    except LayoutError as err:
        raise InputError(err.message, path=path, line=toml_line(text, err.loc), field=format_field(err.loc)) from None


def card_layout_toml(layout: Layout) -> str:
    """The layout as TOML text (tomli-w), readable by :func:`load_card_layout`."""
    data: dict = {"card": {"width_mm": layout.width_mm, "height_mm": layout.height_mm, "dictionary": layout.dictionary}}
    tables = {
        "marker": [{"id": m.id, "x_mm": m.x_mm, "y_mm": m.y_mm, "size_mm": m.size_mm} for m in layout.markers],
        "printed": [
            {"x_mm": p.x_mm, "y_mm": p.y_mm, "w_mm": p.w_mm, "h_mm": p.h_mm, "gray": p.gray} for p in layout.printed
        ],
        "region": [
            {"name": r.name, "role": r.role, "x_mm": r.x_mm, "y_mm": r.y_mm, "w_mm": r.w_mm, "h_mm": r.h_mm}
            | dict(r.metadata)
            for r in layout.regions
        ],
    }
    data |= {name: entries for name, entries in tables.items() if entries}
    return _HEADER + tomli_w.dumps(data)


def write_card_layout(layout: Layout, path: str | os.PathLike[str]) -> None:
    """Write the layout as TOML (:func:`card_layout_toml`) to ``path``, atomically (InputError if it cannot)."""
    write_text_atomically(path, card_layout_toml(layout))
