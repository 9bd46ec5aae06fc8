"""Synthetic cross-polarized RAW photos of a drawdown card, for the ingest-raw tests (test support).

The card of a layout is rendered in linear light (paper and backings at known reflectances, films from their
per-channel K and S over those backings by the Kubelka-Munk forward model), seen in perspective and rotated,
lit with vignetting, exposed, given photon and read noise, mosaicked to a Bayer pattern and written as a DNG.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import colour
import cv2
import numpy as np
from dng_fixtures import mosaic, write_dng

from instruments.drawdown_card.layout import Layout
from instruments.drawdown_card.printing import render_card
from kmpipe.formats.manifest import parse_thickness_mm
from kmpipe.physics.colorimetry import reflectance_to_XYZ
from kmpipe.physics.kubelka_munk import reflectance_over_background

PX_PER_MM = 6.0

# A synthetic ColorChecker Classic Mini for the ``colorchecker`` slot. The chart body is 57 x 83 mm (portrait) of
# black (CHART_BLACK), with 11 mm patches on a 13 mm pitch (2 mm black gaps, 3.5 mm black border). The standard
# chart reads in 4 rows of 6 (dark skin top-left, black bottom-right) when landscape; here it is turned 90 degrees
# clockwise into the portrait slot, so dark skin is at the top-right and the neutral row is the left column, white at
# the top. Patch colours are the linear camera RGB of a camera whose camera RGB -> XYZ matrix is TRUE_CAMERA_MATRIX:
# camera_rgb = XYZ @ inv(TRUE_CAMERA_MATRIX).T, XYZ of the 'ColorChecker N Ohta' spectra under D65 (CIE 1931 2 deg,
# 5 nm, Y = 100 for the perfect white), the scale chosen so that the white patch's largest channel is 0.9.
CHART_BODY_MM = (57.0, 83.0)  # width, height of the portrait chart
CHART_PITCH_MM = 13.0
CHART_PATCH_MM = 11.0
CHART_BLACK = 0.03  # linear camera RGB of the black body and gaps


def _chart_reference_XYZ() -> np.ndarray:
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    wavelengths = np.arange(380.0, 781.0, 5.0)
    spectra = np.array([sd.copy().align(colour.SpectralShape(380, 780, 5)).values for sd in sds.values()])
    return reflectance_to_XYZ(spectra, wavelengths, "D65", "2")  # (24, 3)


def _true_camera_matrix() -> np.ndarray:
    # Camera sensitivities as mixtures of the CMFs (camera RGB = XYZ @ C.T): broad, overlapping, as real sensors are.
    C = np.array([[0.80, 0.35, -0.10], [-0.25, 1.10, 0.12], [0.05, -0.15, 0.95]])
    white = _chart_reference_XYZ()[18] @ C.T
    C = C * (0.9 / white.max())
    return np.linalg.inv(C)


TRUE_CAMERA_MATRIX = _true_camera_matrix()
"""(3, 3) camera RGB -> XYZ (Y = 100 scale) of the synthetic camera: XYZ = camera_rgb @ TRUE_CAMERA_MATRIX.T."""

CHART_CAMERA_RGB = _chart_reference_XYZ() @ np.linalg.inv(TRUE_CAMERA_MATRIX).T
"""(24, 3) linear camera RGB (reflectance scale) of the chart's patches in the standard order, dark skin first."""


@dataclass(frozen=True)
class Scene:
    """What is on the card (reflectance per channel, linear) and how it is photographed."""

    backings: dict[str, np.ndarray]  # backing region name -> (3,) reflectance
    K: np.ndarray  # (3,) per mm
    S: np.ndarray  # (3,) per mm
    thickness: str = "30 um"  # of film regions whose layout entry gives none
    white_reference: float = 0.9
    exposure: float = 0.6  # sensor fraction of full scale for a perfect white at the image centre
    angle_deg: float = 8.0
    tilt: float = 0.12  # perspective strength
    vignetting: float = 0.15  # fractional fall-off at the image corners
    noise: float = 0.002  # relative photon-like noise per pixel
    highlight: str | None = None  # region name that gets a specular highlight (polarizers not crossed)
    hide_marker: int | None = None
    colorchecker: bool = False  # paint the synthetic ColorChecker (CHART_CAMERA_RGB) into the ``colorchecker`` slot
    colorchecker_offset_mm: tuple[float, float] = (0.0, 0.0)  # chart centre from the slot centre (placed by hand)
    colorchecker_angle_deg: float = 0.0  # chart rotation in the slot, clockwise on the card


def paint_colorchecker(card: np.ndarray, layout: Layout, scene: Scene) -> None:
    """Paint the synthetic chart into ``card`` (H, W, 3 at PX_PER_MM), centred on the colorchecker slot + offset."""
    slot = next(r for r in layout.regions if r.role == "colorchecker")
    cx = slot.x_mm + slot.w_mm / 2 + scene.colorchecker_offset_mm[0]
    cy = slot.y_mm + slot.h_mm / 2 + scene.colorchecker_offset_mm[1]
    yy, xx = np.mgrid[0 : card.shape[0], 0 : card.shape[1]]
    x, y = (xx + 0.5) / PX_PER_MM - cx, (yy + 0.5) / PX_PER_MM - cy  # pixel centres, mm from the chart centre
    a = np.deg2rad(scene.colorchecker_angle_deg)
    u, v = np.cos(a) * x + np.sin(a) * y, -np.sin(a) * x + np.cos(a) * y  # chart-local portrait coordinates
    w, h = CHART_BODY_MM
    body = (np.abs(u) <= w / 2) & (np.abs(v) <= h / 2)
    card[body] = CHART_BLACK
    # Portrait (u right, v down) -> landscape reading (p right, q down), turning the chart back counter-clockwise.
    p, q = v, -u
    gap = CHART_PITCH_MM - CHART_PATCH_MM
    border_p, border_q = (h - (6 * CHART_PITCH_MM - gap)) / 2, (w - (4 * CHART_PITCH_MM - gap)) / 2
    for index, rgb in enumerate(CHART_CAMERA_RGB):
        row, col = divmod(index, 6)
        p0 = -h / 2 + border_p + col * CHART_PITCH_MM
        q0 = -w / 2 + border_q + row * CHART_PITCH_MM
        inside = body & (p >= p0) & (p < p0 + CHART_PATCH_MM) & (q >= q0) & (q < q0 + CHART_PATCH_MM)
        card[inside] = rgb


def region_reflectances(layout: Layout, scene: Scene) -> dict[str, np.ndarray]:
    """Reflectance of every sampled region: backings as given, films by KM over their backing, the white patch."""
    out = {}
    for region in layout.regions:
        if region.role == "backing":
            out[region.name] = scene.backings[region.name]
        elif region.role == "film":
            X = parse_thickness_mm(str(region.metadata.get("thickness", scene.thickness)))
            out[region.name] = reflectance_over_background(scene.K, scene.S, X, scene.backings[region.metadata["over"]])
        elif region.role == "white_reference":
            out[region.name] = np.full(3, scene.white_reference)
    return out


def linear_card(layout: Layout, scene: Scene) -> np.ndarray:
    """(H, W, 3) linear reflectance image of the card at PX_PER_MM."""
    printed = render_card(layout, PX_PER_MM).astype(np.float64) / 255.0
    card = np.where(printed > 0.5, 0.85, 0.04)  # paper and ink, away from the regions
    for name, value in region_reflectances(layout, scene).items():
        region = next(r for r in layout.regions if r.name == name)
        x0, y0 = round(region.x_mm * PX_PER_MM), round(region.y_mm * PX_PER_MM)
        x1, y1 = round((region.x_mm + region.w_mm) * PX_PER_MM), round((region.y_mm + region.h_mm) * PX_PER_MM)
        card[y0:y1, x0:x1] = value
        if name == scene.highlight:
            yy, xx = np.mgrid[y0:y1, x0:x1]
            cy, cx, r = (y0 + y1) / 2, (x0 + x1) / 2, min(x1 - x0, y1 - y0) / 4
            card[y0:y1, x0:x1] += 0.6 * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * r * r))[..., None]
    if scene.hide_marker is not None:
        marker = next(m for m in layout.markers if m.id == scene.hide_marker)
        x0, y0 = round(marker.x_mm * PX_PER_MM), round(marker.y_mm * PX_PER_MM)
        size = round(marker.size_mm * PX_PER_MM)
        card[y0 : y0 + size, x0 : x0 + size] = 0.85
    if scene.colorchecker:
        paint_colorchecker(card, layout, scene)
    return card


def photograph(layout: Layout, scene: Scene, path: Path, *, size=(1200, 1600), seed: int = 0) -> np.ndarray:
    """Write a DNG of the card as a camera would see it; returns the card-mm -> image-px homography (full size)."""
    rng = np.random.default_rng(seed)
    card = linear_card(layout, scene)
    h, w = size
    ch, cw = card.shape[:2]
    scale = 0.8 * min(w / cw, h / ch)
    corners = np.array([[0, 0], [cw, 0], [cw, ch], [0, ch]], dtype=np.float64)
    centred = (corners - [cw / 2, ch / 2]) * scale
    a = np.deg2rad(scene.angle_deg)
    rotation = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    placed = centred @ rotation.T
    placed[:, 0] *= 1.0 + scene.tilt * (placed[:, 1] / (h / 2))  # keystone: wider at the bottom
    placed += [w / 2, h / 2]
    H = cv2.getPerspectiveTransform(corners.astype(np.float32), placed.astype(np.float32))
    image = cv2.warpPerspective(card.astype(np.float32), H, (w, h), flags=cv2.INTER_AREA, borderValue=(0.2, 0.2, 0.2))
    yy, xx = np.mgrid[0:h, 0:w]
    r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    light = scene.exposure * (1.0 - scene.vignetting * r2)
    signal = image.astype(np.float64) * light[..., None]
    signal *= 1.0 + scene.noise * rng.standard_normal(signal.shape)
    write_dng(path, np.clip(mosaic(signal, "RGGB"), 0.0, 1.0), pattern="RGGB")
    return H @ np.diag([PX_PER_MM, PX_PER_MM, 1.0])
