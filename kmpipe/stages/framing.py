"""Where the camera stands and how large a pixel is on the product.

Without ``[camera] distance_mm`` a perspective camera stands where the product's bounding sphere (radius r) fills
:data:`FRAME_FILL` of the image height: d = r / sin(atan(FRAME_FILL tan(fov / 2))); an orthographic one at 3 r,
its half height r / FRAME_FILL. A pixel of a frame H pixels high spans, at the product's centre,
2 d tan(fov / 2) / H mm (perspective) or 2 (r / FRAME_FILL) / H mm (orthographic).
"""

from __future__ import annotations

import math

from kmpipe.formats.scene import CameraInfo

#: Share of the image height the product's bounding sphere fills when the scene gives no camera distance.
FRAME_FILL = 0.8


def camera_distance_mm(camera: CameraInfo, radius_mm: float) -> float:
    """The camera's distance (mm) from the product's centre: the scene's, or framed as the module says."""
    if camera.distance_mm is not None:
        return camera.distance_mm
    if camera.projection == "orthographic":
        return 3.0 * radius_mm
    half_angle = math.radians(camera.fov_deg) / 2.0
    return radius_mm / math.sin(math.atan(FRAME_FILL * math.tan(half_angle)))


def pixel_mm(camera: CameraInfo, radius_mm: float, height_px: int) -> float:
    """Size (mm) of one pixel at the product's centre, for a frame ``height_px`` pixels high."""
    if camera.projection == "orthographic":
        return 2.0 * radius_mm / FRAME_FILL / height_px
    distance = camera_distance_mm(camera, radius_mm)
    return 2.0 * distance * math.tan(math.radians(camera.fov_deg) / 2.0) / height_px
