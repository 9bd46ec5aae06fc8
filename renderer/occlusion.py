"""Ambient occlusion baked per vertex: how much of the sky each vertex of a static mesh sees, cosine weighted.

For a vertex at p with normal n, over ``n_directions`` directions w_i spread evenly over the sphere (a Fibonacci
lattice)::

    AO(p) = sum_i V(p, w_i) max(n.w_i, 0) / sum_i max(n.w_i, 0)

with V = 1 where nothing of the mesh (or of the other meshes that move with it, such as eyes in a head) lies between
p and infinity along w_i. V is read from a depth map of the meshes seen from w_i (a :class:`renderer.shadows.ShadowMap`
of a distant light there, ``size`` texels square): the vertex, moved 1.5 texels off the surface along n, is visible
when it is no deeper than the map there. AO is 1 on a convex mesh (nothing occludes anything), so a white Lambert
sphere in a uniform environment still renders the environment's radiance (the white furnace test); creases, the
ears and the eye sockets darken. The normalisation by the discrete cosine sum makes an unoccluded vertex exactly 1.

A floor under a product that turns (:class:`FloorOcclusion`) is baked once, with the product unturned, on a square
grid of the floor around it; a floor vertex of a frame where the product is turned by a rotation R about the
vertical takes the value at R^-1 of its position (the product's shadow on the sky turns with it). Beyond the grid,
and on a floor rising off the plane (a sweep's cove), the value goes smoothly to 1.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy import ndimage

from renderer import context
from renderer.meshes import GpuMesh, card
from renderer.scene import DirectionalLight
from renderer.shadows import MARGIN, ShadowMap, light_view_projection, read_depth, shadow_matrix

#: Directions sampled and the depth maps' size (texels), the defaults of :func:`vertex_occlusion`.
N_DIRECTIONS = 96
MAP_SIZE = 512


def sphere_directions(n: int) -> np.ndarray:
    """``n`` unit vectors (n, 3) spread evenly over the sphere: the Fibonacci lattice, z_k = 1 - (2k + 1) / n."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    azimuth = np.pi * (1.0 + 5.0**0.5) * k
    rho = np.sqrt(1.0 - z * z)
    return np.stack([rho * np.cos(azimuth), rho * np.sin(azimuth), z], axis=1)


def vertex_occlusion(
    mesh: trimesh.Trimesh, others: Sequence[trimesh.Trimesh] = (), n_directions: int = N_DIRECTIONS,
    size: int = MAP_SIZE,
) -> np.ndarray:  # fmt: skip
    """AO (n_vertices,) float32 in [0, 1] of each vertex of ``mesh`` (object space), occluded by itself and ``others``
    (in the same space), as the module docstring says. Needs no current context (it makes its own)."""
    points = np.asarray(mesh.vertices, dtype=float)
    normals = np.asarray(mesh.vertex_normals, dtype=float)
    everything = np.concatenate([points, *[np.asarray(o.vertices, float) for o in others]])
    lo, hi = everything.min(axis=0), everything.max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = float(np.max(np.linalg.norm(everything - centre, axis=1)))
    texel_mm = 2.0 * (1.0 + MARGIN) * radius / size
    lifted = np.hstack([points + 1.5 * texel_mm * normals, np.ones((len(points), 1))])
    directions = sphere_directions(n_directions)
    seen = np.zeros(len(points))
    weight_sum = np.zeros(len(points))
    with context.lock:
        context.make_current(size, size)
        gpu = [GpuMesh(m) for m in (mesh, *others)]
        try:
            with ShadowMap(size) as depth_map:
                for w in directions:
                    weight = np.maximum(normals @ w, 0.0)
                    if not weight.any():  # below every vertex's horizon (half the sphere, for a floor): no share
                        continue
                    light = DirectionalLight(tuple(-w), (1.0, 1.0, 1.0))
                    view_projection = light_view_projection(light, centre, radius)
                    depth_map.render([(g, np.eye(4)) for g in gpu], view_projection)
                    depth = read_depth(depth_map)
                    q = lifted @ shadow_matrix(view_projection).T
                    column = np.clip((q[:, 0] * size).astype(int), 0, size - 1)
                    row = np.clip(size - 1 - (q[:, 1] * size).astype(int), 0, size - 1)
                    visible = q[:, 2] <= depth[row, column]
                    seen += visible * weight
                    weight_sum += weight
        finally:
            for g in gpu:
                g.release()
    return np.divide(seen, weight_sum, out=np.ones(len(points)), where=weight_sum > 0.0).astype(np.float32)


#: Grid cells per side of a floor's baked occlusion, and the share of its half width over which the edge fades to 1.
FLOOR_CELLS = 64
FLOOR_EDGE = 0.15
#: Directions and depth-map size of a floor's bake: more directions than a mesh's (a product's disc of sky seen from
#: the floor near it is a few dozen of 96, too few for a smooth falloff), smaller maps (the floor is broad).
FLOOR_DIRECTIONS = 256
FLOOR_MAP_SIZE = 256


@dataclass(frozen=True)
class FloorOcclusion:
    """Ambient occlusion of the floor plane y = ``floor_y`` (mm) around an unturned product: ``values`` (n, n) at
    x = centre_x + extent s_j, z = centre_z + extent s_i with s = linspace(-1, 1, n) (row i, column j); it fades to
    1 over heights 0 to ``fade_mm`` above the floor."""

    centre: tuple[float, float]
    floor_y: float
    extent: float
    values: np.ndarray
    fade_mm: float

    def at(self, points: np.ndarray) -> np.ndarray:
        """AO (n,) at points (n, 3) in the unturned product's frame (mm): bilinear on the grid, with 1 - AO scaled
        by a smoothstep to 0 over the grid's outer :data:`FLOOR_EDGE` and over heights 0 to ``fade_mm``."""
        points = np.asarray(points, dtype=float)
        n = self.values.shape[0]
        s = (points[:, [0, 2]] - np.asarray(self.centre)) / self.extent  # (x, z) in [-1, 1] on the grid
        nodes = (s[:, ::-1].T + 1.0) / 2.0 * (n - 1)  # (row from z, column from x), in grid steps
        value = ndimage.map_coordinates(self.values, nodes, order=1, mode="nearest")
        edge = _smoothstep((1.0 - np.max(np.abs(s), axis=1)) / FLOOR_EDGE)
        height = _smoothstep(1.0 - (points[:, 1] - self.floor_y) / self.fade_mm)
        return (1.0 - (1.0 - value) * edge * height).astype(np.float32)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def floor_occlusion(
    product: Sequence[trimesh.Trimesh], floor_y: float, centre: tuple[float, float], extent: float, fade_mm: float,
    cells: int = FLOOR_CELLS, n_directions: int = FLOOR_DIRECTIONS, size: int = FLOOR_MAP_SIZE,
) -> FloorOcclusion:  # fmt: skip
    """Bake the occlusion of the floor plane y = ``floor_y`` by the ``product`` meshes (mm, unturned) on a grid of
    ``cells`` x ``cells`` cells spanning ``extent`` mm each way from ``centre`` = (x, z) (:func:`vertex_occlusion`
    at its vertices, the floor facing up, ``n_directions`` depth maps of ``size`` texels), fading to 1 over
    ``fade_mm`` above the floor."""
    grid = card(2.0 * extent, 2.0 * extent, cells)
    up = np.eye(4)
    up[1:3, 1:3] = [[0.0, 1.0], [-1.0, 0.0]]  # the card's +z normal turned to +y; its +y (rows) to -z
    up[:3, 3] = (centre[0], floor_y, centre[1])
    grid.apply_transform(up)
    values = vertex_occlusion(grid, list(product), n_directions, size).reshape(cells + 1, cells + 1)
    return FloorOcclusion(centre, floor_y, extent, values[::-1], fade_mm)  # rows from -z to +z
