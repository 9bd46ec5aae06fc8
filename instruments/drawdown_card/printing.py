"""The printable drawdown card: :func:`render_card` draws it, :func:`write_card` writes it as PNG or PDF at 300 dpi."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import OpenImageIO as oiio

from instruments.atomic_write import write_atomically
from instruments.drawdown_card.layout import Layout, aruco_dictionary, keep_out, overlap

PRINT_DPI = 300.0
"""Resolution of the printable card written by :func:`write_card` (dots per inch)."""

MAX_CARD_PIXELS = 64_000_000
"""Most pixels :func:`render_card` draws (a 500 x 500 mm card at 300 dpi is 35 million, 105 MB as 8-bit RGB)."""

_GRAY_OUTLINE = 128  # 8-bit grey of region outlines and labels: visible on black ink and on white paper
_LABEL_HEIGHT_MM = 2.2
_OUTLINE_GAP_MM = 0.4
_OUTLINE_WIDTH_MM = 0.25


def render_card(
    layout: Layout, px_per_mm: float = 10.0, *, region_colors: Mapping[str, Any] | None = None
) -> np.ndarray:
    """The printable card as an 8-bit RGB image (H, W, 3), H = round(height_mm * px_per_mm) px.

    White paper; printed areas in their grey; regions filled with ``region_colors[name]`` (RGB, floats 0-1,
    rounded to 8 bits) where given; a thin grey outline around each region, 0.4 mm outside it, and the region's name
    above it (below it when there is no room above; left out when neither fits), so that nothing printed enters a
    sampled area; the markers (``cv2.aruco.generateImageMarker``, 1-bit border) on their white quiet zone. Edges
    fall on the nearest pixel boundary (mm * px_per_mm, rounded).
    """
    if not (math.isfinite(px_per_mm) and px_per_mm > 0):
        raise ValueError(f"px_per_mm must be a finite number > 0, got {px_per_mm!r}")
    if round(layout.width_mm * px_per_mm) * round(layout.height_mm * px_per_mm) > MAX_CARD_PIXELS:
        raise ValueError(
            f"a {layout.width_mm:g} x {layout.height_mm:g} mm card at {px_per_mm:g} px/mm exceeds {MAX_CARD_PIXELS} "
            "pixels"
        )
    colors = dict(region_colors or {})
    unknown = sorted(set(colors) - {r.name for r in layout.regions})
    if unknown:
        raise ValueError(f"region_colors names unknown regions {unknown}")

    def px(mm: float) -> int:
        return round(mm * px_per_mm)

    image = np.full((px(layout.height_mm), px(layout.width_mm), 3), 255, dtype=np.uint8)
    for area in layout.printed:
        _fill(
            image,
            px(area.x_mm),
            px(area.y_mm),
            px(area.x_mm + area.w_mm),
            px(area.y_mm + area.h_mm),
            round(area.gray * 255),
        )
    for name, rgb in colors.items():
        rgb = np.asarray(rgb, dtype=np.float64)
        if rgb.shape != (3,) or not np.all((rgb >= 0) & (rgb <= 1)):
            raise ValueError(f"region_colors[{name!r}] must be 3 numbers from 0 to 1, got {rgb.tolist()}")
        region = layout.region(name)
        value = np.round(rgb * 255).astype(np.uint8)
        _fill(
            image, px(region.x_mm), px(region.y_mm), px(region.x_mm + region.w_mm), px(region.y_mm + region.h_mm), value
        )

    gap = max(1, px(_OUTLINE_GAP_MM))
    width = max(1, px(_OUTLINE_WIDTH_MM))
    outer = gap + width
    boxes = [
        (px(r.x_mm) - outer, px(r.y_mm) - outer, px(r.x_mm + r.w_mm) + outer, px(r.y_mm + r.h_mm) + outer)
        for r in layout.regions
    ]
    quiet = layout.quiet_zone_fraction()
    quiet_zones = [tuple(px(v) for v in keep_out(m, quiet)) for m in layout.markers]
    for x0, y0, x1, y1 in boxes:
        for band in (
            (x0, y0, x1, y0 + width),
            (x0, y1 - width, x1, y1),
            (x0, y0, x0 + width, y1),
            (x1 - width, y0, x1, y1),
        ):
            _fill(image, *band, _GRAY_OUTLINE)

    font = cv2.FONT_HERSHEY_SIMPLEX
    (_, unit_height), _ = cv2.getTextSize("Ag", font, 1.0, 1)
    scale = _LABEL_HEIGHT_MM * px_per_mm / unit_height
    thickness = max(1, px(_OUTLINE_WIDTH_MM))
    for region, box in zip(layout.regions, boxes, strict=True):
        (text_w, text_h), baseline = cv2.getTextSize(region.name, font, scale, thickness)
        pad = gap + thickness
        above = box[1] - pad - baseline
        below = box[3] + pad + text_h
        for y_base in (above, below):
            label = (box[0] - pad, y_base - text_h - pad, box[0] + text_w + pad, y_base + baseline + pad)
            inside = label[0] >= 0 and label[1] >= 0 and label[2] <= image.shape[1] and label[3] <= image.shape[0]
            if inside and not any(overlap(label, other) for other in [*boxes, *quiet_zones]):
                cv2.putText(
                    image, region.name, (box[0], y_base), font, scale, (_GRAY_OUTLINE,) * 3, thickness, cv2.LINE_AA
                )
                break

    dictionary = aruco_dictionary(layout.dictionary)
    for marker in layout.markers:
        x0, y0 = px(marker.x_mm), px(marker.y_mm)
        x1, y1 = px(marker.x_mm + marker.size_mm), px(marker.y_mm + marker.size_mm)
        square = cv2.aruco.generateImageMarker(dictionary, marker.id, x1 - x0, borderBits=1)
        if y1 - y0 != x1 - x0:
            square = cv2.resize(square, (x1 - x0, y1 - y0), interpolation=cv2.INTER_NEAREST)
        image[y0:y1, x0:x1] = square[..., None]
    return image


def _fill(image: np.ndarray, x0: int, y0: int, x1: int, y1: int, value: Any) -> None:
    """Paint pixels x0 <= column < x1, y0 <= row < y1 (clipped to the image)."""
    image[max(0, y0) : max(0, y1), max(0, x0) : max(0, x1)] = value


def write_card(layout: Layout, path: str | os.PathLike) -> None:
    """Write the printable card at 300 dpi, as PNG or PDF by the suffix of ``path``, atomically.

    PNG: round(width_mm / 25.4 * 300) x round(height_mm / 25.4 * 300) px, its print resolution (300 dots per inch,
    the PNG's pHYs chunk) set through OpenImageIO's ``XResolution``, ``YResolution`` and ``ResolutionUnit``, so
    that it prints at size. PDF: one page of exactly the card's size (width_mm / 25.4 * 72 pt), the image placed
    unresampled. Print at 100 % ("actual size"); writing the layout's TOML next to it is the caller's job.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".png", ".pdf"):
        raise ValueError(f"{path}: the card is written as .png or .pdf, not {path.suffix or 'no suffix'!r}")
    image = render_card(layout, PRINT_DPI / 25.4)
    if suffix == ".png":
        write_atomically(path, lambda temporary: _write_png(image, temporary))
    else:
        from matplotlib.figure import Figure

        figure = Figure(figsize=(layout.width_mm / 25.4, layout.height_mm / 25.4), dpi=PRINT_DPI)
        axes = figure.add_axes((0.0, 0.0, 1.0, 1.0))
        axes.set_axis_off()
        axes.imshow(image, interpolation="none", aspect="auto")
        write_atomically(
            path,
            lambda temporary: figure.savefig(temporary, format="pdf", dpi=PRINT_DPI, metadata={"CreationDate": None}),
        )


def _write_png(image: np.ndarray, path: Path) -> None:
    """An 8-bit RGB image (H, W, 3) as a PNG at :data:`PRINT_DPI` dots per inch (OpenImageIO)."""
    height, width = image.shape[:2]
    spec = oiio.ImageSpec(width, height, 3, oiio.UINT8)
    spec.attribute("XResolution", PRINT_DPI)
    spec.attribute("YResolution", PRINT_DPI)
    spec.attribute("ResolutionUnit", "in")
    output = oiio.ImageOutput.create("png")
    if output is None:
        raise OSError(f"{path}: OpenImageIO cannot write PNG ({oiio.geterror()})")
    if not output.open(str(path), spec):
        raise OSError(f"{path}: OpenImageIO cannot write the card ({output.geterror()})")
    written = output.write_image(np.ascontiguousarray(image))
    if not output.close() or not written:
        raise OSError(f"{path}: OpenImageIO cannot write the card ({output.geterror()})")
