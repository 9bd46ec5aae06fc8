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
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh

from renderer import context
from renderer.meshes import GpuMesh
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
                    light = DirectionalLight(tuple(-w), (1.0, 1.0, 1.0))
                    view_projection = light_view_projection(light, centre, radius)
                    depth_map.render([(g, np.eye(4)) for g in gpu], view_projection)
                    depth = read_depth(depth_map)
                    q = lifted @ shadow_matrix(view_projection).T
                    column = np.clip((q[:, 0] * size).astype(int), 0, size - 1)
                    row = np.clip(size - 1 - (q[:, 1] * size).astype(int), 0, size - 1)
                    visible = q[:, 2] <= depth[row, column]
                    weight = np.maximum(normals @ w, 0.0)
                    seen += visible * weight
                    weight_sum += weight
        finally:
            for g in gpu:
                g.release()
    return np.divide(seen, weight_sum, out=np.ones(len(points)), where=weight_sum > 0.0).astype(np.float32)
