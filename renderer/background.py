"""What a frame shows where no surface is: a flat colour, a vertical gradient, or the environment behind the camera's
rays.

The passes leave alpha 0 where no surface is and 1 where one covers the pixel;
:func:`fill_background` then adds what is behind, weighted by 1 - alpha, to the pixels not wholly covered (alpha 0:
nothing covers them; between 0 and 1: a multisampled silhouette, :mod:`renderer.multisample`). A gradient's row y of
h (0 at the top) takes ``top + (bottom - top) s(t)``, t = (y + 1/2) / h, s(t) = 3 t^2 - 2 t^3; a visible environment
the radiance along each pixel centre's camera ray (:meth:`renderer.environment.Environment.lookup`). Under
supersampling the fill runs on the fine image, so a silhouette's pixels blend the surface with what is behind it.
"""

from __future__ import annotations

import numpy as np

from renderer.scene import GradientBackground, Scene


def camera_rays(scene: Scene) -> np.ndarray:
    """World-space unit directions (height, width, 3) of the camera rays through the pixel centres, top row first."""
    width, height = scene.resolution
    camera = scene.camera
    inverse = np.linalg.inv(camera.projection_matrix(width / height) @ camera.view_matrix())
    x = (np.arange(width) + 0.5) / width * 2.0 - 1.0
    y = 1.0 - (np.arange(height) + 0.5) / height * 2.0
    xx, yy = np.meshgrid(x, y)
    ends = []
    for z in (-1.0, 1.0):
        clip = np.stack([xx, yy, np.full_like(xx, z), np.ones_like(xx)], axis=-1) @ inverse.T
        ends.append(clip[..., :3] / clip[..., 3:])
    rays = ends[1] - ends[0]
    return rays / np.linalg.norm(rays, axis=-1, keepdims=True)


def fill_background(rgba: np.ndarray, scene: Scene) -> np.ndarray:
    """The frame's linear RGB (h, w, 3) from its RGBA read-back, the pixels of alpha < 1 filled as the module says."""
    rgb = rgba[..., :3]
    environment = scene.environment
    shown = environment is not None and environment.visible
    gradient = isinstance(scene.background, GradientBackground)
    flat = np.zeros(3) if shown or gradient else np.asarray(scene.background, dtype=float)
    if not (shown or gradient or flat.any()):
        return rgb
    cover = rgba[..., 3]
    empty = cover < 1.0  # (a multisampled silhouette: partly covered)
    if not empty.any():
        return rgb
    if shown:
        behind = environment.lookup(camera_rays(scene))
    elif gradient:
        height = rgba.shape[0]
        t = (np.arange(height) + 0.5) / height
        s = (t * t * (3.0 - 2.0 * t))[:, None, None]
        top, bottom = (np.asarray(c, dtype=float) for c in (scene.background.top, scene.background.bottom))
        behind = np.broadcast_to(top + (bottom - top) * s, rgb.shape)
    else:
        behind = np.broadcast_to(flat, rgb.shape)
    out = rgb.copy()
    out[empty] = rgb[empty] + (1.0 - cover[empty, None]) * behind[empty]
    return out
