"""Procedural product meshes (lipstick bullet, pressed-powder compact pan) and loading of product meshes from files.

All meshes follow the conventions of :mod:`renderer.meshes`: plain :class:`trimesh.Trimesh` objects in mm with
exact per-vertex normals (``mesh.vertex_normals``, outward) and per-vertex texture coordinates in [0, 1]
(``mesh.visual.uv``), ready for :class:`renderer.meshes.GpuMesh`. Vertices are duplicated along sharp edges and uv
seams so that normals and uv can be exact per part; the surfaces are nevertheless closed: welding the vertices by
position (``trimesh.Trimesh(mesh.vertices, mesh.faces)``) gives a watertight, consistently wound solid.

Each procedural mesh records the faces of its parts in ``mesh.metadata["parts"]`` (name -> face indices), for
example the powder surface of a compact, so that a material or a cosmetic map can be assigned per part.
"""

from __future__ import annotations

import json
import urllib.parse
from pathlib import Path

import numpy as np
import trimesh

#: File types :func:`load_mesh` accepts (by extension, lower case).
MESH_SUFFIXES = (".obj", ".ply", ".gltf", ".glb")
#: Largest ``.gltf`` JSON whose external files :func:`mesh_files` lists (larger ones list the file alone).
MAX_GLTF_JSON_BYTES = 64 << 20
#: Smallest and largest extent (mm, the longest side of the bounding box) of a mesh :func:`load_mesh` accepts.
MESH_EXTENT_MM = (1e-3, 1e5)
#: Smallest total triangle area of a loaded mesh, as a fraction of its extent squared (0 for all-degenerate faces).
MIN_AREA_FRACTION = 1e-9


class _Builder:
    """Collects parts (vertices, normals, uv, faces) and assembles one mesh."""

    def __init__(self) -> None:
        self.vertices: list[np.ndarray] = []
        self.normals: list[np.ndarray] = []
        self.uv: list[np.ndarray] = []
        self.faces: list[np.ndarray] = []
        self.parts: dict[str, np.ndarray] = {}
        self._n_vertices = 0
        self._n_faces = 0

    def add_grid(
        self,
        name: str,
        positions: np.ndarray,
        normals: np.ndarray,
        uv: np.ndarray,
        wrap: bool,
        collapsed_first_row: bool = False,
        flip: bool = False,
    ) -> None:
        """Add a (rows, columns) grid of vertices joined by quads between consecutive rows and columns.

        With rows running outwards (or upwards) and columns counter-clockwise about +z, the triangles face +z (or
        outwards from the axis); ``flip`` reverses them. ``wrap`` joins the last column to the first;
        ``collapsed_first_row`` marks row 0 as a single point repeated (a fan centre), whose degenerate triangles
        are dropped.
        """
        rows, columns = positions.shape[:2]
        n_quads_j = columns if wrap else columns - 1
        i, j = np.meshgrid(np.arange(rows - 1), np.arange(n_quads_j), indexing="ij")
        j1 = (j + 1) % columns
        v00, v01 = i * columns + j, i * columns + j1
        v10, v11 = v00 + columns, v01 + columns
        first = np.stack([v00, v10, v11], axis=-1).reshape(-1, 3)
        second = np.stack([v00, v11, v01], axis=-1)
        if collapsed_first_row:
            second = second[1:]
        faces = np.concatenate([first, second.reshape(-1, 3)])
        if flip:
            faces = faces[:, ::-1]
        self.vertices.append(positions.reshape(-1, 3))
        self.normals.append(normals.reshape(-1, 3))
        self.uv.append(uv.reshape(-1, 2))
        self.faces.append(faces + self._n_vertices)
        self.parts[name] = np.arange(self._n_faces, self._n_faces + len(faces))
        self._n_vertices += rows * columns
        self._n_faces += len(faces)

    def mesh(self) -> trimesh.Trimesh:
        """The assembled mesh, normals and uv attached, parts in ``metadata["parts"]``."""
        normals = np.concatenate(self.normals)
        normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
        mesh = trimesh.Trimesh(
            np.concatenate(self.vertices),
            np.concatenate(self.faces),
            vertex_normals=normals,
            visual=trimesh.visual.TextureVisuals(uv=np.clip(np.concatenate(self.uv), 0.0, 1.0)),
            process=False,
        )
        mesh.metadata["parts"] = dict(self.parts)
        return mesh


def _angles(segments: int, seam: bool) -> np.ndarray:
    """Azimuths (rad) of ``segments`` columns from +x towards +y, plus the closing 2 pi column if ``seam``."""
    return np.linspace(0.0, 2.0 * np.pi, segments + 1) if seam else np.arange(segments) * (2.0 * np.pi / segments)


def _disc(builder: _Builder, name: str, radii: np.ndarray, z: float, segments: int, uv_radius: float, up: bool):
    """Add a flat disc or annulus at height ``z`` (mm) through the rings ``radii`` (mm, increasing), facing +z if
    ``up`` else -z, uv planar: (x, y) in [-uv_radius, uv_radius] maps to [0, 1]."""
    theta = _angles(segments, seam=False)
    rho = radii[:, None] * np.ones_like(theta)
    x, y = rho * np.cos(theta), rho * np.sin(theta)
    positions = np.stack([x, y, np.full_like(x, z)], axis=-1)
    normals = np.broadcast_to([0.0, 0.0, 1.0 if up else -1.0], positions.shape)
    uv = np.stack([0.5 + 0.5 * x / uv_radius, 0.5 + 0.5 * y / uv_radius], axis=-1)
    builder.add_grid(name, positions, normals, uv, wrap=True, collapsed_first_row=radii[0] == 0.0, flip=not up)


def _wall(builder: _Builder, name: str, radius: float, z_bottom, z_top, segments: int, height: float, inward: bool):
    """Add a vertical cylindrical wall of ``radius`` (mm) between ``z_bottom`` and ``z_top`` (mm, scalars or
    per-column arrays of ``segments + 1``), normals radial (inwards if ``inward``), uv = (azimuth / 2 pi, z /
    height)."""
    theta = _angles(segments, seam=True)
    z = np.stack(np.broadcast_arrays(z_bottom * np.ones_like(theta), z_top * np.ones_like(theta)))
    x, y = radius * np.cos(theta) * np.ones_like(z), radius * np.sin(theta) * np.ones_like(z)
    positions = np.stack([x, y, z], axis=-1)
    sign = -1.0 if inward else 1.0
    normals = sign * np.stack([np.cos(theta), np.sin(theta), np.zeros_like(theta)], axis=-1) * np.ones((2, 1, 1))
    uv = np.stack([theta / (2.0 * np.pi) * np.ones_like(z), z / height], axis=-1)
    builder.add_grid(name, positions, normals, uv, wrap=False, flip=not inward)


def lipstick_bullet(
    diameter: float = 12.0,
    length: float = 20.0,
    bevel_angle_deg: float = 50.0,
    segments: int = 64,
    tip_radius: float = 1.0,
    rings: int = 8,
) -> trimesh.Trimesh:
    """A lipstick bullet: a cylinder of ``diameter`` (mm) standing on the z = 0 plane, its axis on +z, cut by a
    slanted plane with a rounded edge, closed at the base.

    The bevel face rises towards +x at ``bevel_angle_deg`` (degrees) from the horizontal (0 is a flat top). Its
    edge with the side wall is rounded over ``tip_radius`` (mm): within ``tip_radius`` of the rim the top surface
    drops below the plane along a quarter circle in the radial-vertical section (drop = ``tip_radius`` at the rim,
    where the surface turns vertical and meets the wall tangentially). The plane is placed so that the highest point
    of the bullet is at z = ``length`` (mm). ``segments`` is the number of facets around the axis, ``rings`` the
    number of rings across the rounded band (the flat part of the bevel gets as many).

    Volume (mm^3), exact for the smooth solid: ``pi r^2 z_c - 2 pi b^2 ((r - b)(1 - pi / 4) + b / 6)`` with
    ``r = diameter / 2``, ``b = tip_radius`` and ``z_c`` the height of the plane on the axis.

    Parts: ``"bevel"`` (the rounded slanted top), ``"side"``, ``"base"``. uv: planar over the xy disc for the bevel
    and base; (azimuth / 2 pi, z / length) on the side.
    """
    r, b = diameter / 2.0, tip_radius
    if not (diameter > 0.0 and length > 0.0 and 0.0 < tip_radius < r):
        raise ValueError(
            f"need diameter > 0, length > 0 and 0 < tip_radius < diameter / 2, got {diameter}, {length}, {tip_radius}"
        )
    if not 0.0 <= bevel_angle_deg < 90.0 or segments < 3 or rings < 1:
        raise ValueError(
            f"need 0 <= bevel_angle_deg < 90, segments >= 3, rings >= 1, got {bevel_angle_deg}, {segments}, {rings}"
        )
    t = np.tan(np.radians(bevel_angle_deg))
    # the top surface h(x, y) = z_c + t x - drop(rho) peaks on +x where the rounding's slope equals the bevel's
    phi_peak = np.arctan(t)
    z_c = length - t * (r - b + b * np.sin(phi_peak)) + b * (1.0 - np.cos(phi_peak))
    if z_c - t * r - b <= 0.0:
        raise ValueError(
            f"a {bevel_angle_deg} degree bevel on a {diameter} mm bullet needs length > "
            f"{length - z_c + t * r + b:.3f} mm, got {length}"
        )

    builder = _Builder()
    theta = _angles(segments, seam=False)
    # rings over the top: the flat bevel from the centre to r - b, then the rounding, parametrized by phi in
    # [0, pi / 2] (rho = r - b + b sin phi, drop = b (1 - cos phi)); phi_peak is included so that the peak is a vertex
    rho_flat = np.linspace(0.0, r - b, rings + 1)
    phi = np.union1d(np.linspace(0.0, np.pi / 2.0, rings + 1)[1:], [phi_peak] if phi_peak > 0.0 else [])
    rho = np.concatenate([rho_flat, r - b + b * np.sin(phi)])[:, None]
    sin_phi = np.concatenate([np.zeros_like(rho_flat), np.sin(phi)])[:, None]
    cos_phi = np.concatenate([np.ones_like(rho_flat), np.cos(phi)])[:, None]
    x, y = rho * np.cos(theta), rho * np.sin(theta)
    z = z_c + t * x - b * (1.0 - cos_phi)
    z[-1] = z_c + t * r * np.cos(theta) - b  # the rim, computed as the side wall's top edge below
    # normal of the height field: (-h_x, -h_y, 1) scaled by cos phi, which stays finite where the surface turns
    # vertical: h_x = t - tan(phi) cos(theta), h_y = -tan(phi) sin(theta)
    normals = np.stack(
        np.broadcast_arrays(-t * cos_phi + sin_phi * np.cos(theta), sin_phi * np.sin(theta), cos_phi), axis=-1
    )
    positions = np.stack([x, y, z], axis=-1)
    uv = np.stack([0.5 + 0.5 * x / r, 0.5 + 0.5 * y / r], axis=-1)
    builder.add_grid("bevel", positions, normals, uv, wrap=True, collapsed_first_row=True)
    side_theta = _angles(segments, seam=True)
    _wall(builder, "side", r, 0.0, z_c + t * r * np.cos(side_theta) - b, segments, length, inward=False)
    _disc(builder, "base", np.array([0.0, r]), 0.0, segments, r, up=False)
    return builder.mesh()


def lipstick_bullet_volume(
    diameter: float = 12.0, length: float = 20.0, bevel_angle_deg: float = 50.0, tip_radius: float = 1.0
) -> float:
    """The exact volume (mm^3) of the smooth solid that :func:`lipstick_bullet` tessellates (see its docstring)."""
    r, b = diameter / 2.0, tip_radius
    t = np.tan(np.radians(bevel_angle_deg))
    phi_peak = np.arctan(t)
    z_c = length - t * (r - b + b * np.sin(phi_peak)) + b * (1.0 - np.cos(phi_peak))
    return float(np.pi * r**2 * z_c - 2.0 * np.pi * b * b * ((r - b) * (1.0 - np.pi / 4.0) + b / 6.0))


def compact_pan(
    diameter: float = 56.0,
    depth: float = 4.0,
    rim: float = 2.0,
    segments: int = 96,
    recess: float = 0.5,
    rings: int = 4,
) -> trimesh.Trimesh:
    """A pressed-powder compact pan: a shallow cylinder of ``diameter`` and ``depth`` (mm) standing on z = 0, its
    axis on +z, with a flat powder top inside a raised rim.

    The powder surface is a disc of radius ``diameter / 2 - rim`` (mm) at z = ``depth - recess``; the rim is the
    annulus of width ``rim`` (mm) at z = ``depth``, joined to the powder by an inner wall of height ``recess`` (mm);
    an outer wall and a flat base close the solid. ``segments`` facets around the axis; ``rings`` concentric rings
    on the powder disc.

    Volume (mm^3): ``pi R^2 depth - pi (R - rim)^2 recess`` with ``R = diameter / 2``.

    Parts: ``"powder"`` (uv planar: the disc's bounding square maps to [0, 1]^2, so a square cosmetic map covers the
    disc), ``"inner_wall"``, ``"rim"``, ``"outer_wall"``, ``"base"`` (uv planar over the full diameter on the rim and
    base; (azimuth / 2 pi, z / depth) on the walls).
    """
    big_r = diameter / 2.0
    small_r = big_r - rim
    if not (diameter > 0.0 and depth > 0.0 and 0.0 < rim < big_r and 0.0 < recess < depth):
        raise ValueError(
            f"need diameter > 0, 0 < rim < diameter / 2 and 0 < recess < depth, got {diameter}, {rim}, "
            f"{recess}, {depth}"
        )
    if segments < 3 or rings < 1:
        raise ValueError(f"need segments >= 3 and rings >= 1, got {segments}, {rings}")
    builder = _Builder()
    floor = depth - recess
    _disc(builder, "powder", np.linspace(0.0, small_r, rings + 1), floor, segments, small_r, up=True)
    _wall(builder, "inner_wall", small_r, floor, depth, segments, depth, inward=True)
    _disc(builder, "rim", np.array([small_r, big_r]), depth, segments, big_r, up=True)
    _wall(builder, "outer_wall", big_r, 0.0, depth, segments, depth, inward=False)
    _disc(builder, "base", np.array([0.0, big_r]), 0.0, segments, big_r, up=False)
    return builder.mesh()


def mesh_files(path: str | Path) -> list[Path]:
    """Every file :func:`load_mesh` reads for the mesh file ``path``: the file itself and, for a ``.gltf``, the
    buffers and images its JSON names by relative URI (embedded ``data:`` URIs are in the file). What a cache of
    renders must hash; unreadable JSON gives the file alone (loading it then fails, naming it)."""
    path = Path(path)
    found = [path]
    if path.suffix.lower() == ".gltf" and path.is_file() and path.stat().st_size <= MAX_GLTF_JSON_BYTES:
        try:
            document = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return found
        for entry in [*document.get("buffers", []), *document.get("images", [])] if isinstance(document, dict) else []:
            uri = entry.get("uri") if isinstance(entry, dict) else None
            if isinstance(uri, str) and uri and not uri.startswith("data:"):
                found.append(path.parent / urllib.parse.unquote(uri))
    return found


def _flattened(scene: trimesh.Scene) -> trimesh.Trimesh | None:
    """The scene's triangle meshes in world coordinates as one mesh, in node order, keeping each part's own vertex
    normals (turned by the inverse transpose of its node's transform) and, when every part has them, its uv; None when
    it holds no triangle mesh. (trimesh's own concatenation recomputes the normals.)"""
    parts = []
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        geometry = scene.geometry[name]
        if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces):
            parts.append((geometry, np.asarray(transform, dtype=float)))
    if not parts:
        return None
    vertices, normals, faces, uvs = [], [], [], []
    offset = 0
    for geometry, transform in parts:
        vertices.append(trimesh.transform_points(geometry.vertices, transform))
        turned = np.asarray(geometry.vertex_normals, dtype=float) @ np.linalg.inv(transform[:3, :3])
        normals.append(turned / np.maximum(np.linalg.norm(turned, axis=1, keepdims=True), 1e-300))
        faces.append(np.asarray(geometry.faces) + offset)
        uvs.append(getattr(geometry.visual, "uv", None))
        offset += len(geometry.vertices)
    visual = None
    if all(uv is not None and len(uv) == len(g.vertices) for uv, (g, _) in zip(uvs, parts, strict=True)):
        visual = trimesh.visual.TextureVisuals(uv=np.concatenate(uvs))
    return trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), vertex_normals=np.concatenate(normals),
                           visual=visual, process=False)  # fmt: skip


def load_mesh(path: str | Path) -> trimesh.Trimesh:
    """Load a product mesh (mm) from an OBJ, PLY, glTF or GLB file as one :class:`trimesh.Trimesh`.

    A scene (several meshes, node transforms) is flattened into one mesh in world coordinates. Vertex order is
    kept (no merging); per-vertex normals are read from the file or, if it has none, computed from the faces;
    texture coordinates are kept in ``mesh.visual.uv`` when the file has them.

    Raises
    ------
    ValueError
        Naming the file, if it does not exist, has an unsupported extension, cannot be parsed or holds no triangles,
        if it is smaller or larger than :data:`MESH_EXTENT_MM`, if its triangles have no area, or if a vertex of a
        triangle has a zero or non-finite normal.
    """
    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(f"{path}: unsupported mesh file type {path.suffix!r}, expected one of {MESH_SUFFIXES}")
    if not path.is_file():
        raise ValueError(f"{path}: no such mesh file")
    try:  # an OBJ's materials (its .mtl and their textures) are not read: only geometry and uv are used
        options = {"skip_materials": True} if path.suffix.lower() == ".obj" else {}
        loaded = trimesh.load(str(path), process=False, maintain_order=True, **options)
        if isinstance(loaded, trimesh.Scene):  # several meshes, node transforms: one mesh in world coordinates
            loaded = _flattened(loaded)
    except Exception as error:  # trimesh's loaders raise many types for malformed files
        raise ValueError(f"{path}: cannot read a mesh: {error}") from error
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0 or len(loaded.vertices) == 0:
        raise ValueError(f"{path}: the file holds no triangles")
    if not np.all(np.isfinite(loaded.vertices)):
        raise ValueError(f"{path}: the mesh has non-finite vertex coordinates")
    if loaded.faces.min() < 0 or loaded.faces.max() >= len(loaded.vertices):
        raise ValueError(f"{path}: a face names a vertex the file does not have")
    extent = float(np.ptp(loaded.vertices, axis=0).max())
    if not MESH_EXTENT_MM[0] <= extent <= MESH_EXTENT_MM[1]:
        raise ValueError(
            f"{path}: the mesh is {extent:.3g} mm across; a product mesh (mm) is {MESH_EXTENT_MM[0]:g} to "
            f"{MESH_EXTENT_MM[1]:g} mm across"
        )
    if not float(loaded.area) > MIN_AREA_FRACTION * extent * extent:
        raise ValueError(f"{path}: the mesh's triangles have no area (all its faces are degenerate)")
    normals = np.asarray(loaded.vertex_normals)  # read from the file, else computed from the faces (and cached)
    if normals.shape != loaded.vertices.shape:
        raise ValueError(f"{path}: cannot compute vertex normals")
    used = np.unique(loaded.faces)
    length = np.linalg.norm(normals[used], axis=1)
    if not np.all(np.isfinite(length) & (length > 1e-6)):
        vertex = int(used[np.flatnonzero(~(np.isfinite(length) & (length > 1e-6)))[0]])
        raise ValueError(
            f"{path}: vertex {vertex} has no normal (zero or not finite: its faces are degenerate, or the file's "
            "normal is zero); shading it would give NaN"
        )
    return loaded
