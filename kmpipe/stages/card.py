"""The card stage: a printable drawdown card and its layout (``kmpipe card``).

The card (PDF or PNG at 300 dpi, :mod:`instruments.drawdown_card.printing`) carries the black and white backings, the
white reference patch, ArUco markers and the ColorChecker slot where its layout puts them; the layout TOML
(:mod:`kmpipe.formats.card_layout`) is what ``kmpipe ingest-raw`` reads to find them again in a photo.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.card_layout import card_layout_toml, load_card_layout, write_card_layout


@dataclass(frozen=True)
class CardWritten:
    """The card written, and the layout file written beside it (None when the card was drawn from a given layout,
    or the layout beside it already held the same layout)."""

    card: Path
    layout: Path | None


def write_card_files(output: str | Path, layout: str | Path | None = None) -> CardWritten:
    """Draw the card of the layout file ``layout`` (default: the built-in layout) into ``output`` (.pdf or .png).

    With the built-in layout, its TOML is written beside the card (``CARD.layout.toml``) unless a file there already
    holds the same layout; a file there holding another layout (an edited one) is never replaced: InputError, and
    nothing is written.

    >>> import pathlib, tempfile
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> written = write_card_files(folder / "card.png")
    >>> written.card.name, written.layout.name, load_card_layout(written.layout).width_mm > 0
    ('card.png', 'card.layout.toml', True)
    >>> write_card_files(folder / "card.pdf", folder / "card.layout.toml").layout is None  # drawn from the layout
    True
    """
    from instruments.drawdown_card.layout import default_layout
    from instruments.drawdown_card.printing import write_card

    output = files.output_file(Path(output), suffixes=(".png", ".pdf"), inputs=[layout])
    written_layout = None
    if layout is not None:
        card_layout = load_card_layout(layout)
    else:
        card_layout = default_layout()
        layout_path = files.output_file(output.with_suffix(".layout.toml"), field="-o")
        if not layout_path.exists():
            write_card_layout(card_layout, layout_path)
            written_layout = layout_path
        elif not _holds(layout_path, card_layout):
            raise InputError(
                "exists and differs from the built-in layout (edited?); kmpipe does not replace it: draw the card "
                f"from it with --layout {layout_path}, or remove it to start from the built-in layout",
                path=layout_path,
                field="-o",
            )
    write_card(card_layout, output)
    return CardWritten(output, written_layout)


def _holds(path: Path, layout) -> bool:
    """Whether the layout file ``path`` holds ``layout``: the same text, or (written by another version, or with
    comments added) a file that reads as the same layout."""
    if files.read_text(path, "TOML") == card_layout_toml(layout):
        return True
    try:
        return load_card_layout(path) == layout
    except InputError:
        return False
