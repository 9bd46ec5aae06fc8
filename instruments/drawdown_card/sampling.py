"""Measuring a region of the drawdown card in a linear photo: trimmed mean, spread, masked fraction, uniformity."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from instruments.drawdown_card.layout import SAMPLING_MARGIN_MM, Region
from instruments.drawdown_card.locate import CardLocation


@dataclass(frozen=True, eq=False)
class RegionSample:
    """Statistics of one region of a linear photo (:func:`sample_region`, :func:`sample_pixels`), per channel (C,).

    ``mean``: trimmed mean; ``std``: standard deviation of all samples (ddof 1); ``count``: number of samples;
    ``masked_fraction``: fraction of samples whose nearest pixel is flagged in the mask (0 without a mask);
    ``uniformity``: (largest - smallest mean of the four quadrants) / |trimmed mean| (0 for a uniform region;
    inf when the mean is 0 and the quadrants differ); ``polygon_px`` (4, 2): corners of the sampled area in the
    image (px), clockwise from the region's top-left.
    """

    name: str
    mean: np.ndarray
    std: np.ndarray
    count: int
    masked_fraction: float
    uniformity: np.ndarray
    polygon_px: np.ndarray


def sample_region(
    linear_image: np.ndarray,
    location: CardLocation,
    region: Region,
    *,
    px_per_mm: float | None = None,
    margin_mm: float = SAMPLING_MARGIN_MM,
    trim: float = 0.1,
    mask: np.ndarray | None = None,
) -> RegionSample:
    """Measure a region of a linear photo (H, W, C) or (H, W), any channel count and numeric dtype.

    The region, shrunk by ``margin_mm`` on each side (away from its printed edges and a misplaced film), is
    sampled on a regular grid of points in card mm, ``px_per_mm`` points per mm (default: the photo's own
    resolution there, the square root of the sampled area in px² over its area in mm², so about one sample per
    pixel). Each point is mapped through ``location.homography`` and read with bilinear interpolation
    (``cv2.remap``). The mean drops the ``trim`` fraction of the lowest and of the highest values of each channel.
    ``mask`` is an optional boolean (H, W) image of flagged pixels (e.g. saturated): it is only counted (read at the
    nearest pixel), never used to drop samples. Raises ValueError if the sampled area leaves the photo.
    """
    image = np.asarray(linear_image)
    if image.ndim == 2:
        image = image[..., None]
    if image.ndim != 3:
        raise ValueError(f"linear_image must be (H, W) or (H, W, C), got shape {image.shape}")
    if not 0 <= trim < 0.5:
        raise ValueError(f"trim must be at least 0 and below 0.5, got {trim!r}")
    if not (math.isfinite(margin_mm) and margin_mm >= 0):
        raise ValueError(f"margin_mm must be a finite number >= 0, got {margin_mm!r}")
    if mask is not None and np.shape(mask) != image.shape[:2]:
        raise ValueError(f"mask has shape {np.shape(mask)}; the image is {image.shape[:2]}")
    x0, y0 = region.x_mm + margin_mm, region.y_mm + margin_mm
    w, h = region.w_mm - 2 * margin_mm, region.h_mm - 2 * margin_mm
    if w <= 0 or h <= 0:
        raise ValueError(
            f"region {region.name!r} ({region.w_mm:g} x {region.h_mm:g} mm) is empty after a {margin_mm:g} mm margin"
        )

    polygon = location.card_to_image([[x0, y0], [x0 + w, y0], [x0 + w, y0 + h], [x0, y0 + h]])
    if px_per_mm is None:
        px_per_mm = math.sqrt(cv2.contourArea(polygon.astype(np.float32)) / (w * h))
    if not (math.isfinite(px_per_mm) and px_per_mm > 0):
        raise ValueError(f"px_per_mm must be a finite number > 0, got {px_per_mm!r}")
    nx, ny = max(2, round(w * px_per_mm)), max(2, round(h * px_per_mm))
    grid_x = x0 + (np.arange(nx) + 0.5) * (w / nx)
    grid_y = y0 + (np.arange(ny) + 0.5) * (h / ny)
    points = location.card_to_image(np.stack(np.meshgrid(grid_x, grid_y), axis=-1))  # (ny, nx, 2) px

    height, width = image.shape[:2]
    low, high = np.floor(points.min(axis=(0, 1))).astype(int), np.ceil(points.max(axis=(0, 1))).astype(int)
    if low[0] < 0 or low[1] < 0 or high[0] > width - 1 or high[1] > height - 1:
        raise ValueError(f"region {region.name!r} is not entirely inside the photo (samples span {low}-{high} px)")
    crop = np.ascontiguousarray(image[low[1] : high[1] + 1, low[0] : high[0] + 1], dtype=np.float64)
    map_x = (points[..., 0] - low[0]).astype(np.float32)
    map_y = (points[..., 1] - low[1]).astype(np.float32)
    values = cv2.remap(crop, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    values = values.reshape(ny, nx, image.shape[2])

    flagged = None
    if mask is not None:
        nearest = np.rint(points).astype(int)
        flagged = np.asarray(mask, dtype=bool)[nearest[..., 1], nearest[..., 0]]
    return _statistics(region.name, values, flagged, trim, polygon)


def sample_pixels(
    pixels: np.ndarray, mask: np.ndarray | None = None, *, trim: float = 0.1, name: str = ""
) -> RegionSample:
    """The statistics of :func:`sample_region` for a block of pixels (h, w, C) or (h, w) taken as it is.

    For a rectangle of an image cut out by the caller (e.g. a region given in px for a photo without markers);
    ``mask`` is an optional boolean (h, w) block of flagged pixels. ``polygon_px`` is the block's outline in its own
    pixel coordinates, (-0.5, -0.5) to (w - 0.5, h - 0.5).
    """
    values = np.asarray(pixels, dtype=np.float64)
    if values.ndim == 2:
        values = values[..., None]
    if values.ndim != 3 or values.shape[0] < 2 or values.shape[1] < 2:
        raise ValueError(f"pixels must be (h, w) or (h, w, C) with h, w >= 2, got shape {np.shape(pixels)}")
    if not 0 <= trim < 0.5:
        raise ValueError(f"trim must be at least 0 and below 0.5, got {trim!r}")
    if mask is not None and np.shape(mask) != values.shape[:2]:
        raise ValueError(f"mask has shape {np.shape(mask)}; the pixels are {values.shape[:2]}")
    h, w = values.shape[:2]
    outline = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    return _statistics(name, values, None if mask is None else np.asarray(mask, dtype=bool), trim, outline)


def _statistics(
    name: str, values: np.ndarray, flagged: np.ndarray | None, trim: float, polygon_px: np.ndarray
) -> RegionSample:
    """Trimmed mean, standard deviation, masked fraction and quadrant uniformity of a grid of samples (ny, nx, C)."""
    ny, nx, channels = values.shape
    flat = np.sort(values.reshape(-1, channels), axis=0)
    cut = int(trim * flat.shape[0])
    mean = flat[cut : flat.shape[0] - cut].mean(axis=0)
    std = flat.std(axis=0, ddof=1)
    half_y, half_x = ny // 2, nx // 2  # with an odd count, the middle row or column belongs to no quadrant
    quadrants = np.stack(
        [
            values[:half_y, :half_x].mean(axis=(0, 1)),
            values[:half_y, nx - half_x :].mean(axis=(0, 1)),
            values[ny - half_y :, :half_x].mean(axis=(0, 1)),
            values[ny - half_y :, nx - half_x :].mean(axis=(0, 1)),
        ]
    )
    spread = quadrants.max(axis=0) - quadrants.min(axis=0)
    uniformity = np.divide(spread, np.abs(mean), out=np.where(spread > 0, np.inf, 0.0), where=mean != 0)
    masked = 0.0 if flagged is None else float(flagged.mean())
    return RegionSample(name, mean, std, nx * ny, masked, uniformity, polygon_px)
