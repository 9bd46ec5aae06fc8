"""Pieces of the self-contained report pages: tables and figures embedded as PNG."""

from __future__ import annotations

import base64
import html
import io

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

DPI = 100


def table(header: list[str], rows: list[str]) -> str:
    """An HTML table of ``header`` cells (HTML) and ``rows`` (each a whole ``<tr>``)."""
    head = "".join(f"<th>{h}</th>" for h in header)
    return f"<table>\n<tr>{head}</tr>\n" + "\n".join(rows) + "\n</table>"


def png_img(fig: Figure, element_id: str, alt: str) -> str:
    """The figure as an ``<img>`` with the PNG embedded (no Software tag, so the bytes are reproducible)."""
    FigureCanvasAgg(fig)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI, metadata={"Software": None})
    width, height = (round(v * DPI) for v in fig.get_size_inches())
    data = base64.b64encode(buffer.getvalue()).decode("ascii")
    return (
        f'<img id="{element_id}" alt="{html.escape(alt)}" width="{width}" height="{height}" '
        f'src="data:image/png;base64,{data}">'
    )
