"""Finding the drawdown card in a photo: its ArUco markers, then a homography from card mm to image px."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from instruments.drawdown_card.layout import Layout, aruco_dictionary

RANSAC_THRESHOLD_PX = 3.0
"""Maximum reprojection error (px) of a marker corner counted as an inlier when the homography is fitted."""


class CardNotFound(ValueError):
    """Too few of the layout's markers were found in the photo to locate the card."""


@dataclass(frozen=True, eq=False)
class CardLocation:
    """Where the card lies in a photo.

    ``homography`` (3, 3) maps card mm to image px (OpenCV pixel-centre convention), normalised so that
    ``homography[2, 2] == 1``. ``found_ids`` and ``missing_ids`` are the layout's marker ids seen once and not seen
    (sorted); ``duplicate_ids`` layout ids seen more than once (left out of the fit: another card in view?).
    ``reprojection_error_px`` is the RMS distance (px) between the detected marker corners and the layout's
    corners mapped by the homography, over all corners used (RANSAC outliers included, so a bad marker shows).
    """

    homography: np.ndarray
    found_ids: tuple[int, ...]
    missing_ids: tuple[int, ...]
    duplicate_ids: tuple[int, ...]
    reprojection_error_px: float

    def card_to_image(self, points_mm: Any) -> np.ndarray:
        """Map card points (..., 2) in mm to image points (..., 2) in px."""
        points = np.asarray(points_mm, dtype=np.float64)
        mapped = cv2.perspectiveTransform(points.reshape(-1, 1, 2), self.homography)
        return mapped.reshape(points.shape)


def locate_card(image: np.ndarray, layout: Layout) -> CardLocation:
    """Find the card in an 8-bit photo (gray (H, W) or RGB (H, W, 3)): detect markers, fit card mm -> image px.

    Pass a tone-mapped 8-bit copy of the linear photo. Markers are detected with ``cv2.aruco.ArucoDetector`` (the
    layout's dictionary, sub-pixel corner refinement); ids not in the layout are ignored. The homography is fitted
    by ``cv2.findHomography`` (RANSAC, 3 px threshold, then refined on the inliers) to all 4 corners of every marker
    found. Raises :class:`CardNotFound` when fewer than 2 of the layout's markers are found (8 corners: the least
    that fixes a homography).
    """
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise ValueError(f"locate_card needs an 8-bit image (a tone-mapped copy of the photo), got {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 3:
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    elif image.ndim == 2:
        gray = image
    else:
        raise ValueError(f"locate_card needs a gray (H, W) or RGB (H, W, 3) image, got shape {image.shape}")

    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(aruco_dictionary(layout.dictionary), parameters)
    corners, ids, _ = detector.detectMarkers(gray)
    detected: dict[int, list[np.ndarray]] = {}
    for marker_corners, marker_id in zip(corners, [] if ids is None else ids.ravel(), strict=True):
        detected.setdefault(int(marker_id), []).append(marker_corners.reshape(4, 2))

    expected = sorted(m.id for m in layout.markers)
    by_id = {m.id: m for m in layout.markers}
    found = sorted(i for i in expected if len(detected.get(i, [])) == 1)
    duplicates = sorted(i for i in expected if len(detected.get(i, [])) > 1)
    missing = sorted(set(expected) - set(found) - set(duplicates))
    if len(found) < 2:
        strangers = sorted(set(detected) - set(expected))
        raise CardNotFound(
            f"card not found: {len(found)} of the layout's markers found (ids {found}); missing ids {missing}"
            + (f"; seen more than once (ambiguous) ids {duplicates}" if duplicates else "")
            + (f"; ids not in the layout ignored {strangers}" if strangers else "")
            + f". The layout expects {layout.dictionary} markers with ids {expected}; at least 2 must be visible"
        )
    card_mm = np.concatenate([by_id[i].corners_mm() for i in found])
    image_px = np.concatenate([detected[i][0] for i in found]).astype(np.float64)
    homography, _ = cv2.findHomography(card_mm, image_px, cv2.RANSAC, RANSAC_THRESHOLD_PX)
    if homography is None:
        raise CardNotFound(f"card not found: markers {found} were found but no homography fits their corners")
    homography = homography / homography[2, 2]
    projected = cv2.perspectiveTransform(card_mm.reshape(-1, 1, 2), homography).reshape(-1, 2)
    rms = float(np.sqrt(np.mean(np.sum((projected - image_px) ** 2, axis=1))))
    return CardLocation(homography, tuple(found), tuple(missing), tuple(duplicates), rms)
