"""Procedural meshes (trimesh) and their upload to GL vertex arrays.

Meshes are plain :class:`trimesh.Trimesh` objects in scene units (mm) with per-vertex normals and texture
coordinates (``mesh.visual.uv``); :func:`upload` turns one into a :class:`GpuMesh` whose vertex array holds
positions at attribute location 0, normals at 1, uv at 2 and ambient occlusion at 3.
"""

from __future__ import annotations

import ctypes

import numpy as np
import trimesh

from renderer.context import GL


def card(width: float, height: float, cells: int = 1) -> trimesh.Trimesh:
    """A flat drawdown card: a ``width`` x ``height`` rectangle (mm) centred at the origin in the z = 0 plane, in
    ``cells`` x ``cells`` quads (more carry a per-vertex quantity finely, such as a floor's ambient occlusion).

    The front faces +z (counter-clockwise seen from +z); uv (0, 0) is the bottom-left (-x, -y) corner.
    """
    s = np.linspace(0.0, 1.0, cells + 1)
    uu, vv = np.meshgrid(s, s, indexing="xy")
    uv = np.column_stack([uu.ravel(), vv.ravel()])
    vertices = np.column_stack([(uv[:, 0] - 0.5) * width, (uv[:, 1] - 0.5) * height, np.zeros(len(uv))])
    corner = (np.arange(cells)[:, None] * (cells + 1) + np.arange(cells)[None, :]).ravel()
    right, up = corner + 1, corner + cells + 1
    faces = np.concatenate([np.column_stack([corner, right, up + 1]), np.column_stack([corner, up + 1, up])])
    normals = np.tile([0.0, 0.0, 1.0], (len(uv), 1))
    return trimesh.Trimesh(
        vertices, faces, vertex_normals=normals, visual=trimesh.visual.TextureVisuals(uv=uv), process=False
    )


def sphere(radius: float, n_latitude: int = 48, n_longitude: int = 96) -> trimesh.Trimesh:
    """A UV sphere "swatch" of ``radius`` (mm) centred at the origin, poles on the z axis.

    ``n_latitude`` bands from the +z pole (v = 1) to the -z pole (v = 0) and ``n_longitude`` segments around z
    (u = azimuth / 2 pi from +x towards +y). The seam and pole vertices are duplicated so that uv is continuous per
    triangle; normals are the exact radial directions.
    """
    if n_latitude < 2 or n_longitude < 3:
        raise ValueError(f"a sphere needs n_latitude >= 2 and n_longitude >= 3, got {n_latitude}, {n_longitude}")
    polar = np.linspace(0.0, np.pi, n_latitude + 1)
    azimuth = np.linspace(0.0, 2.0 * np.pi, n_longitude + 1)
    p, a = np.meshgrid(polar, azimuth, indexing="ij")
    normals = np.stack([np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)], axis=-1).reshape(-1, 3)
    uv = np.stack([a / (2.0 * np.pi), 1.0 - p / np.pi], axis=-1).reshape(-1, 2)
    row = n_longitude + 1
    i, j = np.meshgrid(np.arange(n_latitude), np.arange(n_longitude), indexing="ij")
    v00 = (i * row + j).ravel()
    v01, v10, v11 = v00 + 1, v00 + row, v00 + row + 1
    upper = np.stack([v00, v10, v11], axis=-1)[i.ravel() < n_latitude - 1]  # degenerate in the -z pole band
    lower = np.stack([v00, v11, v01], axis=-1)[i.ravel() > 0]  # degenerate in the +z pole band
    faces = np.concatenate([upper, lower])
    return trimesh.Trimesh(
        radius * normals, faces, vertex_normals=normals, visual=trimesh.visual.TextureVisuals(uv=uv), process=False
    )


class GpuMesh:
    """A mesh in GL buffers: an interleaved float32 vertex buffer (position, normal, uv, ambient occlusion) and a
    uint32 index buffer.

    Use as a context manager (or call :meth:`release`) to free the buffers in the same context.
    """

    def __init__(self, mesh: trimesh.Trimesh, occlusion: np.ndarray | None = None) -> None:
        """Upload ``mesh``; it needs per-vertex normals and ``mesh.visual.uv``. ``occlusion``: per-vertex ambient
        occlusion in [0, 1] (:mod:`renderer.occlusion`; None: 1, nothing occluded)."""
        uv = getattr(mesh.visual, "uv", None)
        if uv is None or len(uv) != len(mesh.vertices):
            raise ValueError("the mesh has no per-vertex texture coordinates (mesh.visual.uv)")
        ao = np.ones(len(mesh.vertices)) if occlusion is None else np.asarray(occlusion, dtype=float).reshape(-1)
        if ao.shape != (len(mesh.vertices),) or not (np.all(np.isfinite(ao)) and 0.0 <= ao.min() <= ao.max() <= 1.0):
            raise ValueError(f"occlusion needs one value in [0, 1] per vertex ({len(mesh.vertices)})")
        vertices = np.hstack([mesh.vertices, mesh.vertex_normals, uv, ao[:, None]]).astype(np.float32)
        indices = np.ascontiguousarray(mesh.faces, dtype=np.uint32)
        self.index_count = indices.size
        self.vao = GL.glGenVertexArrays(1)
        self.vbo, self.ebo = GL.glGenBuffers(2)
        GL.glBindVertexArray(self.vao)
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, self.vbo)
        GL.glBufferData(GL.GL_ARRAY_BUFFER, vertices.nbytes, vertices, GL.GL_STATIC_DRAW)
        GL.glBindBuffer(GL.GL_ELEMENT_ARRAY_BUFFER, self.ebo)
        GL.glBufferData(GL.GL_ELEMENT_ARRAY_BUFFER, indices.nbytes, indices, GL.GL_STATIC_DRAW)
        stride = vertices.shape[1] * vertices.itemsize
        for location, (offset, size) in enumerate(((0, 3), (3, 3), (6, 2), (8, 1))):
            GL.glEnableVertexAttribArray(location)
            GL.glVertexAttribPointer(
                location, size, GL.GL_FLOAT, GL.GL_FALSE, stride, ctypes.c_void_p(offset * vertices.itemsize)
            )
        GL.glBindVertexArray(0)

    def draw(self) -> None:
        """Draw the triangles with the current program."""
        GL.glBindVertexArray(self.vao)
        GL.glDrawElements(GL.GL_TRIANGLES, self.index_count, GL.GL_UNSIGNED_INT, None)
        GL.glBindVertexArray(0)

    def release(self) -> None:
        """Delete the vertex array and buffers."""
        GL.glDeleteVertexArrays(1, [self.vao])
        GL.glDeleteBuffers(2, [self.vbo, self.ebo])

    def __enter__(self) -> GpuMesh:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.release()


def _surface_of_revolution(radius_at, n_polar: int, n_azimuth: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, faces and uv of a closed surface around the +y axis: ``radius_at(polar, azimuth)`` gives the point.

    ``polar`` runs from 0 (top, +y, v = 1) to pi (bottom, v = 0); ``azimuth`` from -pi to pi with 0 facing +z
    (u = 0.5 at the front, the seam at the back). Seam and pole vertices are duplicated so uv is continuous per
    triangle; faces are counter-clockwise seen from outside.
    """
    polar = np.linspace(0.0, np.pi, n_polar + 1)
    azimuth = np.linspace(-np.pi, np.pi, n_azimuth + 1)
    p, a = np.meshgrid(polar, azimuth, indexing="ij")
    vertices = radius_at(p, a).reshape(-1, 3)
    uv = np.stack([0.5 + a / (2.0 * np.pi), 1.0 - p / np.pi], axis=-1).reshape(-1, 2)
    row = n_azimuth + 1
    i, j = np.meshgrid(np.arange(n_polar), np.arange(n_azimuth), indexing="ij")
    v00 = (i * row + j).ravel()
    v01, v10, v11 = v00 + 1, v00 + row, v00 + row + 1
    upper = np.stack([v00, v11, v01], axis=-1)[i.ravel() > 0]  # degenerate at the top pole
    lower = np.stack([v00, v10, v11], axis=-1)[i.ravel() < n_polar - 1]  # degenerate at the bottom pole
    return vertices, np.concatenate([upper, lower]), uv


def _smooth_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals, averaged over vertices at the same position (so the uv seam is invisible)."""
    triangles = vertices[faces]
    face_normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    _, group = np.unique(np.round(vertices, 9), axis=0, return_inverse=True)
    group = group.ravel()
    sums = np.zeros((group.max() + 1, 3))
    for corner in range(3):
        np.add.at(sums, group[faces[:, corner]], face_normals)
    normals = sums[group]
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def head(scale: float = 1.0, n_polar: int = 96, n_azimuth: int = 128) -> trimesh.Trimesh:
    """A procedural head-like shape (mm): an ellipsoid 150 wide, 220 tall, 190 deep, with a nose and a chin.

    Upright along +y, facing +z, centred at the origin. uv: u = 0.5 at the front (the nose), v = 0.5 at the eyes'
    height; the face spans about u 0.33 .. 0.67, v 0.28 .. 0.7. ``scale``
    multiplies every length.
    """

    def point(polar, azimuth):
        direction = np.stack([np.sin(polar) * np.sin(azimuth), np.cos(polar), np.sin(polar) * np.cos(azimuth)], axis=-1)
        radii = np.array([75.0, 110.0, 95.0])
        surface = direction * radii
        front = np.clip(direction[..., 2], 0.0, None)
        # Nose: a ridge below the eyes on the midline; chin: a bump low on the front.
        nose = 22.0 * np.exp(-((azimuth / 0.10) ** 2) - (((polar - 1.72) / 0.16) ** 2))
        chin = 8.0 * np.exp(-((azimuth / 0.35) ** 2) - (((polar - 2.35) / 0.15) ** 2))
        return surface + ((nose + chin) * front)[..., None] * direction

    vertices, faces, uv = _surface_of_revolution(point, n_polar, n_azimuth)
    vertices = scale * vertices
    return trimesh.Trimesh(
        vertices, faces, vertex_normals=_smooth_normals(vertices, faces),
        visual=trimesh.visual.TextureVisuals(uv=uv), process=False,
    )  # fmt: skip


def cylinder(radius: float, height: float, n_azimuth: int = 128, n_height: int = 16) -> trimesh.Trimesh:
    """An open cylinder (mm) around +y, centred at the origin: u around (0.5 at +z), v along +y (0 at the bottom)."""
    azimuth = np.linspace(-np.pi, np.pi, n_azimuth + 1)
    y = np.linspace(-height / 2.0, height / 2.0, n_height + 1)
    yy, aa = np.meshgrid(y, azimuth, indexing="ij")
    normals = np.stack([np.sin(aa), np.zeros_like(aa), np.cos(aa)], axis=-1).reshape(-1, 3)
    vertices = (radius * normals.reshape((*yy.shape, 3)) + np.stack([0 * yy, yy, 0 * yy], -1)).reshape(-1, 3)
    uv = np.stack([0.5 + aa / (2.0 * np.pi), (yy + height / 2.0) / height], axis=-1).reshape(-1, 2)
    row = n_azimuth + 1
    i, j = np.meshgrid(np.arange(n_height), np.arange(n_azimuth), indexing="ij")
    v00 = (i * row + j).ravel()
    faces = np.concatenate([np.stack([v00, v00 + 1, v00 + row + 1], -1), np.stack([v00, v00 + row + 1, v00 + row], -1)])
    return trimesh.Trimesh(
        vertices, faces, vertex_normals=normals, visual=trimesh.visual.TextureVisuals(uv=uv), process=False
    )


def sweep(
    width: float, floor_depth: float, cove_radius: float, wall_height: float, n_cove: int = 32, n_floor: int = 1,
    n_across: int = 32,
) -> trimesh.Trimesh:  # fmt: skip
    """A photo studio's seamless paper sweep (a cyclorama), in mm: a floor that curves up into a wall.

    In its own frame (+y up, the camera towards +z): the floor at y = 0 from z = ``floor_depth`` to z = 0, a quarter
    circle of ``cove_radius`` R about (y, z) = (R, 0) up to (R, -R), then the wall at z = -R up to y =
    ``wall_height``; ``width`` along x, centred on x = 0; ``n_floor`` rows of quads on the floor, ``n_cove`` on the
    cove, ``n_across`` columns. Normals face the camera side (up on the floor, +z on the
    wall, towards the circle's centre on the cove), exact per vertex; uv = (x / width + 1/2, arc length / total).
    """
    if not (width > 0.0 and floor_depth > 0.0 and cove_radius > 0.0 and wall_height > cove_radius):
        raise ValueError("a sweep needs width, floor depth and cove radius > 0 and a wall higher than the cove")
    t = np.linspace(0.0, np.pi / 2.0, n_cove + 1)
    floor = np.linspace(floor_depth, 0.0, n_floor + 1)[:-1]
    z = np.concatenate([floor, -cove_radius * np.sin(t), [-cove_radius]])
    y = np.concatenate([np.zeros(n_floor), cove_radius * (1.0 - np.cos(t)), [wall_height]])
    normal_z = np.concatenate([np.zeros(n_floor), np.sin(t), [1.0]])
    normal_y = np.concatenate([np.ones(n_floor), np.cos(t), [0.0]])
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(z), np.diff(y)))])
    x = np.linspace(-width / 2.0, width / 2.0, n_across + 1)
    xx, row = np.meshgrid(x, np.arange(len(z)), indexing="xy")
    vertices = np.stack([xx, y[row], z[row]], axis=-1).reshape(-1, 3)
    normals = np.stack([np.zeros_like(xx), normal_y[row], normal_z[row]], axis=-1).reshape(-1, 3)
    uv = np.stack([xx / width + 0.5, arc[row] / arc[-1]], axis=-1).reshape(-1, 2)
    columns = len(x)
    i, j = np.meshgrid(np.arange(len(z) - 1), np.arange(columns - 1), indexing="ij")
    v00 = (i * columns + j).ravel()
    v01, v10, v11 = v00 + 1, v00 + columns, v00 + columns + 1
    faces = np.concatenate([np.stack([v00, v01, v11], axis=-1), np.stack([v00, v11, v10], axis=-1)])
    corners = vertices[faces]
    facing = np.einsum("ij,ij->i", np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                       normals[faces[:, 0]])  # fmt: skip
    faces[facing < 0.0] = faces[facing < 0.0][:, ::-1]
    return trimesh.Trimesh(
        vertices, faces, vertex_normals=normals, visual=trimesh.visual.TextureVisuals(uv=uv), process=False
    )
