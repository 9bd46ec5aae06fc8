"""Procedural cosmetic maps: where each product lies on a mesh's uv square and how much of it (thesis figure 3.14).

A cosmetic map is an RGB image over uv (row 0 at v = 1, column 0 at u = 0) with one channel per product, each in
[0, 1]: red the foundation, green the blush, blue the lipstick. A scene turns a channel into a film thickness
(0 -> the film's min, 1 -> its max). These maps fit :func:`renderer.meshes.head`; a user's head scan comes with a
painted map of the same layout instead.
"""

from __future__ import annotations

import numpy as np

#: Channels of a cosmetic map.
CHANNELS = {"foundation": 0, "blush": 1, "lipstick": 2}


def _uv_grid(rows: int, columns: int) -> tuple[np.ndarray, np.ndarray]:
    """u and v at the texel centres, shape (rows, columns), row 0 at the top (v near 1)."""
    u = (np.arange(columns) + 0.5) / columns
    v = 1.0 - (np.arange(rows) + 0.5) / rows
    return np.meshgrid(u, v)


def _smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def head_makeup(rows: int = 512, columns: int = 512) -> np.ndarray:
    """The cosmetic map of :func:`renderer.meshes.head`: float (rows, columns, 3) in [0, 1].

    Foundation: the face, an ellipse at u = 0.5, v = 0.47 (half-axes 0.15 x 0.2), full inside and fading over its
    outer fifth;
    blush: a soft Gaussian on each cheek (u = 0.5 +- 0.085, v = 0.44, standard deviations 0.03 x 0.04); lipstick:
    the lips, an ellipse at u = 0.5, v = 0.31 (half-axes 0.045 x 0.016) with an edge of 0.004.
    """
    u, v = _uv_grid(rows, columns)
    face_radius = np.sqrt(((u - 0.5) / 0.15) ** 2 + ((v - 0.47) / 0.2) ** 2)
    face = 1.0 - _smoothstep(0.8, 1.0, face_radius)
    cheeks = sum(np.exp(-0.5 * (((u - c) / 0.03) ** 2 + ((v - 0.44) / 0.04) ** 2)) for c in (0.415, 0.585))
    lips_radius = np.sqrt(((u - 0.5) / 0.045) ** 2 + ((v - 0.31) / 0.016) ** 2)
    lips = 1.0 - _smoothstep(1.0 - 0.004 / 0.016, 1.0, lips_radius)
    return np.clip(np.stack([face, cheeks, lips], axis=-1), 0.0, 1.0)
