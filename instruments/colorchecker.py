"""A 24-patch ColorChecker in a photo: find it and measure its patches in the linear data.

Two ways to find the chart, both ending in the same sampler (:func:`sample_quads`):

- :func:`find_colorchecker` detects a classic 24-patch ColorChecker (Classic, Classic Mini, Passport page) anywhere in
  a photo, or inside a polygon of it, with OpenCV's ``cv2.mcc`` (opencv-contrib 5.x). Detection runs on an 8-bit
  **BGR** copy (the caller passes the tone-mapped RGB copy used for the markers; it is converted here); the patch
  quadrilaterals it returns (``CChecker.getColorCharts()``: the central part of each patch, 4 corners per patch, in
  the standard patch order) are then sampled in the **linear** image. mcc's own patch statistics
  (``getChartsRGB``) are of the 8-bit copy and are never used.
- :func:`sample_colorchecker_in_slot` is the geometric path for a chart laid in a card's ``colorchecker`` slot: the
  slot is resampled in card millimetres through the card's homography (``CardLocation``), the
  chart's black body is found there (largest dark connected area, its minimum-area rectangle: the chart may be
  placed by hand, shifted and slightly turned), and the 4 x 6 patch grid of :data:`CLASSIC_MINI` is laid into that
  rectangle by fractions of its size.

Patch order is the standard one (X-Rite numbering 1-24, here indices 0-23): dark skin, light skin, ... cyan, then
the neutral row white 9.5 ... black 2, as colour-science's 'ColorChecker24 - After November 2014' and
'ColorChecker N Ohta' name them (:data:`PATCH_NAMES`). A found chart is accepted only if its neutral row reads
brighter to darker (:func:`neutral_row_descends`), which also settles a chart turned by 180 degrees.

All image coordinates are in px with OpenCV's convention (pixel (column i, row j) centred at (i, j)); card
coordinates in mm. Values are those of the linear image (dimensionless, e.g. normalized raw). Nothing here imports
``kmpipe``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from instruments.drawdown_card.layout import Region
from instruments.drawdown_card.locate import CardLocation

__all__ = [
    "CLASSIC_MINI",
    "NEUTRAL_PATCHES",
    "ORIENTATIONS",
    "PATCH_NAMES",
    "ChartGeometry",
    "ColorCheckerNotFound",
    "ColorCheckerSample",
    "find_colorchecker",
    "neutral_row_descends",
    "sample_colorchecker_in_slot",
    "sample_quads",
]

PATCH_NAMES = (
    "dark skin",
    "light skin",
    "blue sky",
    "foliage",
    "blue flower",
    "bluish green",
    "orange",
    "purplish blue",
    "moderate red",
    "purple",
    "yellow green",
    "orange yellow",
    "blue",
    "green",
    "red",
    "yellow",
    "magenta",
    "cyan",
    "white 9.5 (.05 D)",
    "neutral 8 (.23 D)",
    "neutral 6.5 (.44 D)",
    "neutral 5 (.70 D)",
    "neutral 3.5 (1.05 D)",
    "black 2 (1.5 D)",
)
"""The 24 patches in the standard order (index 0 = X-Rite patch 1), named as colour-science names them."""

NEUTRAL_PATCHES = tuple(range(18, 24))
"""Indices of the neutral row, white first."""

ORIENTATIONS = ("portrait", "portrait_ccw", "landscape", "landscape_180", "auto")
"""How the chart lies in a slot, seen on the card (x right, y down). ``landscape``: the standard reading, 4 rows of 6,
dark skin top-left; ``landscape_180``: turned half a turn (dark skin bottom-right); ``portrait``: turned 90 degrees
clockwise (dark skin top-right, the neutral column on the left, white at the top); ``portrait_ccw``: turned 90
degrees counter-clockwise (dark skin bottom-left); ``auto``: the long side of the chart found picks portrait or
landscape, the neutral row picks between the two half-turns."""


class ColorCheckerNotFound(ValueError):
    """No ColorChecker where one was looked for; the message says what was seen."""


@dataclass(frozen=True)
class ChartGeometry:
    """A 4 x 6 patch chart in its standard (landscape) reading, all in mm.

    ``long_mm`` x ``short_mm``: the chart's black body; patches of side ``patch_mm`` on a ``pitch_mm`` grid, the grid
    centred on the body. The slot sampler places patches by fractions of the body it measures, so a chart of the same
    proportions at another size is sampled correctly too.
    """

    long_mm: float
    short_mm: float
    pitch_mm: float
    patch_mm: float

    def patch_centres(self) -> np.ndarray:
        """(24, 2) patch centres (p, q) in mm from the body centre, p along the long side (right), q down."""
        col, row = np.arange(24) % 6, np.arange(24) // 6
        return np.stack([(col - 2.5) * self.pitch_mm, (row - 1.5) * self.pitch_mm], axis=-1)


CLASSIC_MINI = ChartGeometry(long_mm=83.0, short_mm=57.0, pitch_mm=13.0, patch_mm=11.0)
"""X-Rite ColorChecker Classic Mini (2.25 x 3.25 in): 11 mm patches, 2 mm black gaps (approximate: see
:class:`ChartGeometry`)."""


@dataclass(frozen=True, eq=False)
class ColorCheckerSample:
    """The 24 patches of a chart measured in a linear image, in the standard order (:data:`PATCH_NAMES`).

    ``mean`` (24, C): trimmed mean of each patch's samples (the ``trim`` fraction of the lowest and of the highest
    values of each channel dropped), in the units of the linear image; ``std`` (24, C): standard deviation of all
    samples (ddof 1); ``count`` (24,): pixels inside each sampled area (samples are one per pixel or denser, so
    this, not the number of samples, is what averages the noise); ``clipped_fraction`` (24,): fraction of a
    patch's samples whose nearest pixel is flagged in the mask passed (e.g. ``RawPhoto.saturated``; 0 without one);
    ``polygons_px`` (24, 4, 2): the sampled quadrilateral of each patch (its central part, away from the edges) in
    image px; ``centres_px`` (24, 2): their centres; ``confidence`` in [0, 1] (see the finder);
    ``method``: ``"mcc"`` or ``"slot"``.
    """

    mean: np.ndarray
    std: np.ndarray
    count: np.ndarray
    clipped_fraction: np.ndarray
    polygons_px: np.ndarray
    centres_px: np.ndarray
    confidence: float
    method: str


# ---------------------------------------------------------------------------------------------------------------
# Sampling


def sample_quads(
    linear_rgb: np.ndarray,
    quads_px: Any,
    *,
    mask: np.ndarray | None = None,
    trim: float = 0.1,
    confidence: float = 1.0,
    method: str = "",
) -> ColorCheckerSample:
    """Measure 24 quadrilaterals (24, 4, 2) px (corners in order around the quad) of a linear image (H, W, C).

    Each quad is sampled on an n x n grid (n = its longest side in px, at least 4: about one sample per pixel) by
    bilinear interpolation of its corners, the points read with bilinear interpolation (``cv2.remap``). Statistics as
    in :class:`ColorCheckerSample`. Raises ValueError if a quad leaves the image.
    """
    image = np.asarray(linear_rgb)
    if image.ndim == 2:
        image = image[..., None]
    if image.ndim != 3:
        raise ValueError(f"linear_rgb must be (H, W) or (H, W, C), got shape {image.shape}")
    quads = np.asarray(quads_px, dtype=np.float64)
    if quads.shape != (24, 4, 2):
        raise ValueError(f"expected 24 quadrilaterals (24, 4, 2), got shape {quads.shape}")
    if not 0 <= trim < 0.5:
        raise ValueError(f"trim must be at least 0 and below 0.5, got {trim!r}")
    height, width = image.shape[:2]
    if quads[..., 0].min() < 0 or quads[..., 1].min() < 0 or quads[..., 0].max() > width - 1:
        raise ValueError("a ColorChecker patch is not entirely inside the photo")
    if quads[..., 1].max() > height - 1:
        raise ValueError("a ColorChecker patch is not entirely inside the photo")
    if mask is not None and np.shape(mask) != (height, width):
        raise ValueError(f"mask has shape {np.shape(mask)}; the image is {(height, width)}")

    sides = np.linalg.norm(quads - np.roll(quads, -1, axis=1), axis=-1)  # (24, 4)
    n = max(4, math.ceil(sides.max()))
    s = (np.arange(n) + 0.5) / n
    S, T = np.meshgrid(s, s)  # (n, n): S along corner 0 -> 1, T along corner 0 -> 3
    w00, w10, w11, w01 = (1 - S) * (1 - T), S * (1 - T), S * T, (1 - S) * T
    points = (
        w00[None, ..., None] * quads[:, None, None, 0]
        + w10[None, ..., None] * quads[:, None, None, 1]
        + w11[None, ..., None] * quads[:, None, None, 2]
        + w01[None, ..., None] * quads[:, None, None, 3]
    )  # (24, n, n, 2)
    flat = points.reshape(-1, 1, 2).astype(np.float32)
    values = cv2.remap(
        np.ascontiguousarray(image, dtype=np.float32),
        flat[..., 0],
        flat[..., 1],
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    values = values.reshape(24, n, n, image.shape[2]).astype(np.float64)

    channels = image.shape[2]
    mean = np.empty((24, channels))
    std = np.empty((24, channels))
    count = np.empty(24, dtype=int)
    clipped = np.zeros(24)
    for k in range(24):
        area = cv2.contourArea(quads[k].astype(np.float32))
        used = values[k].reshape(-1, channels)
        ordered = np.sort(used, axis=0)
        cut = int(trim * len(ordered))
        mean[k] = ordered[cut : len(ordered) - cut].mean(axis=0)
        std[k] = used.std(axis=0, ddof=1)
        count[k] = max(1, round(area))
        if mask is not None:
            nearest = np.rint(points[k].reshape(-1, 2)).astype(int)
            clipped[k] = float(np.asarray(mask, dtype=bool)[nearest[:, 1], nearest[:, 0]].mean())
    return ColorCheckerSample(
        mean=mean,
        std=std,
        count=count,
        clipped_fraction=clipped,
        polygons_px=quads,
        centres_px=quads.mean(axis=1),
        confidence=float(confidence),
        method=method,
    )


def neutral_row_descends(mean: np.ndarray, clipped_fraction: np.ndarray | None = None) -> bool:
    """Whether the neutral row (:data:`NEUTRAL_PATCHES`) reads from bright to dark, as it must in the standard order.

    The sum of the channels must fall from each neutral patch to the next by at least 10 % (the neutral series
    steps by about 0.15-0.3 in optical density, i.e. 30-50 %); a pair of patches both clipped may read equal.
    """
    level = np.asarray(mean, dtype=np.float64)[list(NEUTRAL_PATCHES)].sum(axis=-1)
    clipped = np.zeros(6) if clipped_fraction is None else np.asarray(clipped_fraction)[list(NEUTRAL_PATCHES)]
    for i in range(5):
        if clipped[i] > 0 and clipped[i + 1] > 0:
            continue
        if not level[i + 1] < 0.9 * level[i]:
            return False
    return True


# ---------------------------------------------------------------------------------------------------------------
# Detection with cv2.mcc


def find_colorchecker(
    image_8bit_rgb: np.ndarray,
    linear_rgb: np.ndarray,
    *,
    search_polygon_px: Any = None,
    mask: np.ndarray | None = None,
    trim: float = 0.1,
    max_cost: float = 0.5,
) -> ColorCheckerSample | None:
    """Detect a classic 24-patch ColorChecker with ``cv2.mcc`` and measure its patches in the linear image.

    Parameters
    ----------
    image_8bit_rgb
        uint8 (h, w, 3), R, G, B: a display copy of the photo (e.g. ``tone_mapped_8bit(raw.rgb)``), used only to
        detect. It may be a different size from ``linear_rgb`` (e.g. detect on the full-size interpolated image,
        measure on half size): patch corners are scaled between the two, pixel centres kept aligned.
    linear_rgb
        (H, W, C) linear values to measure (e.g. ``RawPhoto.rgb``, dimensionless).
    search_polygon_px
        Optional (N, 2) polygon in ``image_8bit_rgb`` px (e.g. a card's colorchecker slot mapped into the photo,
        grown a little): detection runs on its bounding box with everything outside it painted mid-grey.
    mask
        Optional boolean (H, W) of flagged pixels of ``linear_rgb`` (e.g. saturated), counted per patch.
    trim
        Fraction of the lowest and of the highest samples of each channel dropped from each patch's mean.
    max_cost
        Charts with mcc's cost (its colour-matching error against the chart's reference colours; 0 is perfect)
        above this are rejected.

    Returns
    -------
    ColorCheckerSample or None
        The best chart found (``method="mcc"``, ``confidence = 1 - cost`` clipped to [0, 1]); None when mcc finds no
        chart, or the chart found fails :func:`neutral_row_descends` in the linear data (not a ColorChecker, or
        a mis-ordered detection), or lies partly outside the linear image.
    """
    image = np.asarray(image_8bit_rgb)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"find_colorchecker needs an 8-bit RGB image (h, w, 3), got {image.dtype} {image.shape}")
    linear = np.asarray(linear_rgb)
    if linear.ndim != 3:
        raise ValueError(f"linear_rgb must be (H, W, C), got shape {linear.shape}")
    bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    offset = np.zeros(2)
    if search_polygon_px is not None:
        polygon = np.asarray(search_polygon_px, dtype=np.float64).reshape(-1, 2)
        x0, y0 = np.maximum(np.floor(polygon.min(axis=0)).astype(int), 0)
        x1 = min(int(np.ceil(polygon[:, 0].max())) + 1, image.shape[1])
        y1 = min(int(np.ceil(polygon[:, 1].max())) + 1, image.shape[0])
        if x1 - x0 < 8 or y1 - y0 < 8:
            return None
        inside = np.zeros(image.shape[:2], np.uint8)
        cv2.fillPoly(inside, [np.round(polygon).astype(np.int32)], 1)
        bgr = np.where(inside[..., None] > 0, bgr, np.uint8(128))[y0:y1, x0:x1]
        bgr = np.ascontiguousarray(bgr)
        offset = np.array([x0, y0], dtype=np.float64)

    detector = cv2.mcc.CCheckerDetector_create()
    detector.setColorChartType(cv2.mcc.MCC24)
    if not detector.process(bgr, 1):
        return None
    checker = detector.getBestColorChecker()
    if checker is None:
        return None
    cost = float(checker.getCost())
    if not cost <= max_cost:
        return None
    quads = np.asarray(checker.getColorCharts(), dtype=np.float64).reshape(24, 4, 2) + offset
    scale = np.array([linear.shape[1] / image.shape[1], linear.shape[0] / image.shape[0]])
    quads = (quads + 0.5) * scale - 0.5
    try:
        sample = sample_quads(
            linear, quads, mask=mask, trim=trim, confidence=min(1.0, max(0.0, 1.0 - cost)), method="mcc"
        )
    except ValueError:
        return None
    if not neutral_row_descends(sample.mean, sample.clipped_fraction):
        return None
    return sample


# ---------------------------------------------------------------------------------------------------------------
# The geometric path: a chart in the card's slot


def sample_colorchecker_in_slot(
    linear_rgb: np.ndarray,
    card_location: CardLocation,
    region: Region,
    *,
    orientation: str = "portrait",
    geometry: ChartGeometry = CLASSIC_MINI,
    mask: np.ndarray | None = None,
    trim: float = 0.1,
    sample_fraction: float = 0.5,
    px_per_mm: float | None = None,
    size_tolerance: float = 0.12,
) -> ColorCheckerSample:
    """Measure a chart laid by hand in a card's ``colorchecker`` slot (``region``, card mm) of a linear photo.

    1. The slot is resampled on a grid in card mm, ``px_per_mm`` points per mm (default: the photo's own resolution
       there), through ``card_location`` (bilinear).
    2. Dark pixels (sum of channels below 1/4 of the slot's 90th percentile: the chart's black body and gaps, its
       dark patches) are grouped into connected areas; the largest one's outline, holes filled, is the chart body,
       and its minimum-area rectangle gives the chart's centre, sides (mm) and turn (a chart placed by hand).
       The rectangle must match ``geometry`` (long x short side) within ``size_tolerance`` (relative), and its long
       side must lie as ``orientation`` says.
    3. The patch grid of ``geometry``, scaled to the rectangle found, is laid in it as ``orientation`` says
       (:data:`ORIENTATIONS`); each patch is sampled over a square of ``sample_fraction`` of its side around its
       centre (default half: 5.5 mm of an 11 mm patch, tolerant of +-2.5 mm misplacement of the grid), mapped into
       the photo (:func:`sample_quads`).
    4. The neutral row must read bright to dark (:func:`neutral_row_descends`); with ``orientation="auto"`` the
       half-turn that passes is kept.

    ``confidence`` = 1 - (largest relative misfit of the two body sides) / ``size_tolerance``, in [0, 1].
    Raises :class:`ColorCheckerNotFound` (a ValueError) when no chart body of the right size is in the slot or the
    neutral row does not descend, ValueError for bad arguments or a slot leaving the photo.
    """
    if orientation not in ORIENTATIONS:
        raise ValueError(f"orientation must be one of {', '.join(ORIENTATIONS)}, got {orientation!r}")
    if not 0 < sample_fraction <= 1:
        raise ValueError(f"sample_fraction must be in (0, 1], got {sample_fraction!r}")
    image = np.asarray(linear_rgb, dtype=np.float64)
    if image.ndim != 3:
        raise ValueError(f"linear_rgb must be (H, W, C), got shape {image.shape}")
    slot_px = card_location.card_to_image(
        [
            [region.x_mm, region.y_mm],
            [region.x_mm + region.w_mm, region.y_mm],
            [region.x_mm + region.w_mm, region.y_mm + region.h_mm],
            [region.x_mm, region.y_mm + region.h_mm],
        ]
    )
    if px_per_mm is None:
        px_per_mm = math.sqrt(cv2.contourArea(slot_px.astype(np.float32)) / (region.w_mm * region.h_mm))
    if not (math.isfinite(px_per_mm) and px_per_mm > 0):
        raise ValueError(f"px_per_mm must be a finite number > 0, got {px_per_mm!r}")
    height, width = image.shape[:2]
    if slot_px[:, 0].min() < 0 or slot_px[:, 1].min() < 0 or slot_px[:, 0].max() > width - 1:
        raise ValueError(f"slot {region.name!r} is not entirely inside the photo")
    if slot_px[:, 1].max() > height - 1:
        raise ValueError(f"slot {region.name!r} is not entirely inside the photo")

    # 1. The slot in card mm.
    nx, ny = max(8, round(region.w_mm * px_per_mm)), max(8, round(region.h_mm * px_per_mm))
    gx = region.x_mm + (np.arange(nx) + 0.5) * (region.w_mm / nx)
    gy = region.y_mm + (np.arange(ny) + 0.5) * (region.h_mm / ny)
    grid_px = card_location.card_to_image(np.stack(np.meshgrid(gx, gy), axis=-1)).astype(np.float32)
    slot = cv2.remap(image.astype(np.float32), grid_px[..., 0], grid_px[..., 1], cv2.INTER_LINEAR)
    slot = slot.reshape(ny, nx, -1)

    # 2. The chart's body.
    level = slot.sum(axis=-1)
    dark = (level < 0.25 * np.percentile(level, 90)).astype(np.uint8)
    n_labels, labels, stats, _ = cv2.connectedComponentsWithStats(dark, connectivity=8)
    if n_labels < 2:
        raise ColorCheckerNotFound(f"no ColorChecker in slot {region.name!r}: nothing dark there")
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    contours, _ = cv2.findContours((labels == largest).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    outline = max(contours, key=cv2.contourArea).reshape(-1, 2).astype(np.float64)
    outline_mm = np.array([region.x_mm, region.y_mm]) + (outline + 0.5) * [region.w_mm / nx, region.h_mm / ny]
    (cx, cy), _, _ = cv2.minAreaRect(outline_mm.astype(np.float32))
    corners = cv2.boxPoints(cv2.minAreaRect(outline_mm.astype(np.float32))).astype(np.float64)
    edges = [corners[1] - corners[0], corners[2] - corners[1]]
    # u: the side direction nearest the card's +x, v: nearest +y (a chart is turned by less than 45 degrees).
    i_u = int(np.argmax([abs(e[0]) / np.linalg.norm(e) for e in edges]))
    u, v = edges[i_u], edges[1 - i_u]
    size_u, size_v = float(np.linalg.norm(u)), float(np.linalg.norm(v))
    u_hat = u / size_u * (1 if u[0] >= 0 else -1)
    v_hat = v / size_v * (1 if v[1] >= 0 else -1)
    # A pixel-outline rectangle is one sample wider than the body it traces.
    size_u += region.w_mm / nx
    size_v += region.h_mm / ny
    portrait = size_v > size_u
    long_side, short_side = (size_v, size_u) if portrait else (size_u, size_v)
    misfit = max(abs(long_side / geometry.long_mm - 1), abs(short_side / geometry.short_mm - 1))
    if misfit > size_tolerance:
        raise ColorCheckerNotFound(
            f"no ColorChecker in slot {region.name!r}: the largest dark area is {size_u:.1f} x {size_v:.1f} mm, "
            f"a {geometry.short_mm:g} x {geometry.long_mm:g} mm chart body was expected"
        )
    if orientation in ("portrait", "portrait_ccw") and not portrait:
        raise ColorCheckerNotFound(f"the chart in slot {region.name!r} lies landscape; orientation={orientation!r}")
    if orientation in ("landscape", "landscape_180") and portrait:
        raise ColorCheckerNotFound(f"the chart in slot {region.name!r} lies portrait; orientation={orientation!r}")
    candidates = (
        [orientation]
        if orientation != "auto"
        else (["portrait", "portrait_ccw"] if portrait else ["landscape", "landscape_180"])
    )

    # 3. The patch grid, by fractions of the body found.
    pq = geometry.patch_centres() / [geometry.long_mm, geometry.short_mm] * [long_side, short_side]  # (24, 2) mm
    scale = math.sqrt(long_side * short_side / (geometry.long_mm * geometry.short_mm))
    half = 0.5 * sample_fraction * geometry.patch_mm * scale
    square = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])  # in (u, v), clockwise on the card
    confidence = max(0.0, 1.0 - misfit / size_tolerance)
    centre = np.array([cx, cy])
    tried = []
    for name in candidates:
        p, q = pq[:, 0], pq[:, 1]
        a, b = {
            "landscape": (p, q),
            "landscape_180": (-p, -q),
            "portrait": (-q, p),
            "portrait_ccw": (q, -p),
        }[name]
        corners_mm = (
            centre
            + (a[:, None] + square[None, :, 0])[..., None] * u_hat
            + (b[:, None] + square[None, :, 1])[..., None] * v_hat
        )  # (24, 4, 2)
        quads = card_location.card_to_image(corners_mm)
        sample = sample_quads(image, quads, mask=mask, trim=trim, confidence=confidence, method="slot")
        if neutral_row_descends(sample.mean, sample.clipped_fraction):
            return sample
        tried.append(name)
    raise ColorCheckerNotFound(
        f"the chart in slot {region.name!r} does not read as a ColorChecker (orientation {', '.join(tried)}): its "
        "neutral row does not go from white to black; check how it lies in the slot"
    )
