"""The light falling across the drawdown card (vignetting, uneven lighting), estimated from its bare paper."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from instruments.drawdown_card.layout import Layout
from instruments.drawdown_card.locate import CardLocation


def paper_illumination(
    linear_image: np.ndarray,
    location: CardLocation,
    layout: Layout,
    *,
    keep_out_mm: float = 7.0,
    cell_mm: float = 8.0,
) -> Callable[[Any], np.ndarray]:
    """Light falling on the card (vignetting, uneven lighting), estimated from its bare paper; returns a function
    mapping card points (..., 2) in mm to the paper's reading there, per channel (..., C).

    The paper is read on a 1 mm grid wherever it is bare: away from regions, printed areas and markers by
    ``keep_out_mm`` (outlines, labels and quiet zones), and inside the photo. Medians over ``cell_mm`` cells (robust
    to printed text) are fitted per channel with a quadratic surface in the photo's (x, y) by least squares (lens
    vignetting, 1 - v r^2, is quadratic there, not in card coordinates once the card is seen in perspective),
    refitted once without cells more than 3 median absolute deviations off. Dividing a region's reading by the
    surface at its centre, and the white reference's likewise, removes the light's fall-off between them. Raises
    ValueError when fewer than 12 cells of bare paper are visible.
    """
    image = np.asarray(linear_image, dtype=np.float64)
    if image.ndim == 2:
        image = image[..., None]
    blocked = [(r.x_mm, r.y_mm, r.w_mm, r.h_mm) for r in layout.regions]
    blocked += [(p.x_mm, p.y_mm, p.w_mm, p.h_mm) for p in layout.printed]
    blocked += [(m.x_mm, m.y_mm, m.size_mm, m.size_mm) for m in layout.markers]
    xs = np.arange(0.5, layout.width_mm, 1.0)
    ys = np.arange(0.5, layout.height_mm, 1.0)
    gx, gy = np.meshgrid(xs, ys)
    free = (gx > keep_out_mm / 2) & (gx < layout.width_mm - keep_out_mm / 2)
    free &= (gy > keep_out_mm / 2) & (gy < layout.height_mm - keep_out_mm / 2)
    for x, y, w, h in blocked:
        free &= ~(
            (gx > x - keep_out_mm) & (gx < x + w + keep_out_mm) & (gy > y - keep_out_mm) & (gy < y + h + keep_out_mm)
        )
    points_mm = np.stack([gx[free], gy[free]], axis=-1)
    pixels = location.card_to_image(points_mm)
    height, width = image.shape[:2]
    inside = (pixels[:, 0] >= 0) & (pixels[:, 0] <= width - 1) & (pixels[:, 1] >= 0) & (pixels[:, 1] <= height - 1)
    points_mm, pixels = points_mm[inside], pixels[inside]
    values = (
        cv2.remap(
            image.astype(np.float32),
            pixels[:, 0].astype(np.float32).reshape(-1, 1),
            pixels[:, 1].astype(np.float32).reshape(-1, 1),
            cv2.INTER_LINEAR,
        )
        .reshape(len(pixels), image.shape[2])
        .astype(np.float64)
    )

    cells = np.floor(points_mm / cell_mm).astype(int)
    keys, inverse = np.unique(cells, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    if len(keys) < 12:
        raise ValueError(f"only {len(keys)} cells of bare paper are visible: cannot estimate the light across the card")
    centres = np.array([pixels[inverse == k].mean(axis=0) for k in range(len(keys))])
    medians = np.array([np.median(values[inverse == k], axis=0) for k in range(len(keys))])

    def design(points_px: np.ndarray) -> np.ndarray:
        x = (points_px[..., 0] - width / 2) / width
        y = (points_px[..., 1] - height / 2) / height
        return np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=-1)

    A = design(centres)
    coefficients = np.linalg.lstsq(A, medians, rcond=None)[0]
    residuals = medians - A @ coefficients
    mad = np.median(np.abs(residuals - np.median(residuals, axis=0)), axis=0)
    keep = np.all(np.abs(residuals) <= 3.0 * np.maximum(mad, 1e-12) + 1e-12, axis=1)
    if keep.sum() >= 12:
        coefficients = np.linalg.lstsq(A[keep], medians[keep], rcond=None)[0]

    def light(points_mm: Any) -> np.ndarray:
        return design(location.card_to_image(points_mm)) @ coefficients

    return light
