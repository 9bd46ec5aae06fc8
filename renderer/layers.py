"""The Kubelka-Munk layer pass: a mesh shaded by a stack of up to four films composited over a substrate.

The renderer knows nothing of K and S: each film comes as an optical table, its reflectance ``R0`` (over a black
backing) and transmittance ``T`` sampled at a series of thicknesses (mm), per channel. The fragment shader
(``shaders/km_layers.frag``) looks both up at the film's thickness, interpolating linearly between samples and
clamping at the ends, and composes the films bottom-up onto the substrate reflectance ``Rg`` with the layer equation
(thesis eqs. 3.13, 3.14; films are symmetric, so the reflectance from below equals ``R0``)::

    Rg <- R0 + T^2 Rg / (1 - R0 Rg)

Channels are either linear RGB (3) or spectral bands (up to :data:`MAX_CHANNELS`), composed per band and converted
once with a (bands, 3) ``to_rgb`` matrix. A pixel renders as ``(R @ to_rgb) * E * max(cos theta, 0)`` with ``E`` the
light's radiance, the value a white Lambert surface facing the light renders to (as in :mod:`renderer.render_flat`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import trimesh

from renderer import context
from renderer.context import GL
from renderer.framebuffer import Framebuffer
from renderer.meshes import GpuMesh
from renderer.program import Program
from renderer.scene import Camera, DirectionalLight

#: Most films in one stack.
MAX_LAYERS = 4
#: Most channels (bands) per table; the shader works on groups of four.
MAX_CHANNELS = 32

_program: Program | None = None


@dataclass(frozen=True)
class LayerTable:
    """The optical table of one film: reflectance and transmittance against thickness, per channel.

    Attributes
    ----------
    thickness_mm
        Strictly increasing film thicknesses (mm), shape (n_thickness,), or a scalar for a single thickness.
    r0
        Reflectance of the film over a black backing, in [0, 1], shape (n_thickness, C), or (C,) with a scalar
        ``thickness_mm``.
    t
        Transmittance of the film (one pass, diffuse), in [0, 1], same shape as ``r0``.
    """

    thickness_mm: np.ndarray | float
    r0: np.ndarray
    t: np.ndarray

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Validated float64 ``(thickness_mm (n,), r0 (n, C), t (n, C))``; raises :class:`ValueError` on bad input."""
        x = np.asarray(self.thickness_mm, dtype=float)
        r0 = np.asarray(self.r0, dtype=float)
        t = np.asarray(self.t, dtype=float)
        if x.ndim == 0:
            x, r0, t = x.reshape(1), r0[np.newaxis], t[np.newaxis]
        if x.ndim != 1 or x.size < 1:
            raise ValueError(f"thickness_mm must be a scalar or a non-empty 1-D array, got shape {x.shape}")
        if r0.ndim != 2 or r0.shape[0] != x.size or t.shape != r0.shape:
            raise ValueError(
                f"r0 and t must both have shape (n_thickness, C) = ({x.size}, C), got {r0.shape} and {t.shape}"
            )
        if not (np.all(np.isfinite(x)) and np.all(np.diff(x) > 0.0)):
            raise ValueError("thickness_mm must be finite and strictly increasing")
        for name, values in (("r0", r0), ("t", t)):
            if not (np.all(np.isfinite(values)) and values.min() >= 0.0 and values.max() <= 1.0):
                raise ValueError(f"{name} must lie in [0, 1]")
        return x, r0, t


def _layers_program() -> Program:
    """The layer program, compiled once per process (the context is one per process)."""
    global _program
    if _program is None:
        _program = Program("km_layers.vert", "km_layers.frag")
    return _program


def _location(program: Program, name: str) -> int:
    location = GL.glGetUniformLocation(program.handle, name)
    if location < 0:
        raise RuntimeError(f"km_layers.frag: no active uniform named {name!r}")
    return location


def _float_texture(data: np.ndarray, linear: bool) -> int:
    """Upload ``data`` (rows, columns, 4) float as an RGBA32F texture, row 0 at t = 0; clamped at the edges."""
    rows, columns = data.shape[:2]
    texture = GL.glGenTextures(1)
    GL.glBindTexture(GL.GL_TEXTURE_2D, texture)
    GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 4)
    GL.glTexImage2D(
        GL.GL_TEXTURE_2D, 0, GL.GL_RGBA32F, columns, rows, 0, GL.GL_RGBA, GL.GL_FLOAT,
        np.ascontiguousarray(data, dtype=np.float32),
    )  # fmt: skip
    filtering = GL.GL_LINEAR if linear else GL.GL_NEAREST
    GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MIN_FILTER, filtering)
    GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAG_FILTER, filtering)
    GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_WRAP_S, GL.GL_CLAMP_TO_EDGE)
    GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_WRAP_T, GL.GL_CLAMP_TO_EDGE)
    GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
    return texture


def _table_texels(x: np.ndarray, r0: np.ndarray, t: np.ndarray, groups: int) -> np.ndarray:
    """Texels (2 groups + 1, n, 4) of one table in the layout documented in km_layers.frag."""
    n, channels = r0.shape
    texels = np.zeros((2 * groups + 1, n, 4))
    padded = np.zeros((2, n, 4 * groups))
    padded[0, :, :channels], padded[1, :, :channels] = r0, t
    texels[: 2 * groups] = padded.reshape(2, n, groups, 4).transpose(0, 2, 1, 3).reshape(2 * groups, n, 4)
    texels[2 * groups, :, 0] = x
    return texels


def render_layers(
    mesh: trimesh.Trimesh,
    camera: Camera,
    light: DirectionalLight,
    tables: Sequence[LayerTable],
    thicknesses: Sequence[float | np.ndarray],
    substrate: Sequence[float] | np.ndarray,
    width: int,
    height: int,
    *,
    to_rgb: np.ndarray | None = None,
    model: np.ndarray | None = None,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> np.ndarray:
    """Render ``mesh`` covered by a Kubelka-Munk stack of films over a substrate into a float image.

    Parameters
    ----------
    mesh
        Triangle mesh in mm with per-vertex normals and uv (see :mod:`renderer.meshes`).
    camera
        Orthographic or perspective camera; its aspect ratio is ``width / height``.
    light
        Directional light; a pixel renders as ``(R @ to_rgb) * light.radiance * max(cos theta, 0)`` with ``R`` the
        stack's reflectance per channel.
    tables
        Optical tables of 0 to :data:`MAX_LAYERS` films, top first (``tables[0]`` is the layer the light meets first,
        the last lies on the substrate; the order of kmpipe's stacks). All have the same number of channels C (3 for
        rgb, up to :data:`MAX_CHANNELS` bands). They are composed from the bottom up.
    thicknesses
        One per film, in mm: a number (uniform thickness) or a 2-D array (rows, columns) mapped over the mesh's uv,
        row 0 at v = 1 (the top, as in an image) and column 0 at u = 0, bilinearly filtered between texel centres.
        Thicknesses outside a table's range take the value at the nearer end.
    substrate
        Albedo of the substrate per channel, in [0, 1], shape (C,).
    width, height
        Image size in pixels.
    to_rgb
        (C, 3) matrix converting per-channel reflectance to linear RGB (bands mode); if omitted C must be 3 and the
        channels are linear RGB.
    model
        Object -> world matrix (4, 4); identity if omitted.
    background
        Linear RGB of pixels the mesh does not cover (any float, unclamped).

    Returns
    -------
    np.ndarray
        Linear RGB, float32, shape (height, width, 3), top row first.
    """
    if len(tables) > MAX_LAYERS:
        raise ValueError(f"at most {MAX_LAYERS} layers can be composited, got {len(tables)}")
    if len(thicknesses) != len(tables):
        raise ValueError(f"one thickness per layer is needed: {len(tables)} tables, {len(thicknesses)} thicknesses")
    # From here on bottom-up, the order of the composition: index 0 lies on the substrate.
    tables, thicknesses = list(tables)[::-1], list(thicknesses)[::-1]
    substrate = np.asarray(substrate, dtype=float)
    if substrate.ndim != 1 or not 1 <= substrate.size <= MAX_CHANNELS:
        raise ValueError(f"substrate must have shape (C,) with 1 <= C <= {MAX_CHANNELS}, got {substrate.shape}")
    channels = substrate.size
    if not (np.all(np.isfinite(substrate)) and substrate.min() >= 0.0 and substrate.max() <= 1.0):
        raise ValueError("substrate albedo must lie in [0, 1]")
    if to_rgb is None:
        if channels != 3:
            raise ValueError(f"{channels} channels need a ({channels}, 3) to_rgb matrix")
        to_rgb = np.eye(3)
    to_rgb = np.asarray(to_rgb, dtype=float)
    if to_rgb.shape != (channels, 3):
        raise ValueError(f"to_rgb must have shape ({channels}, 3), got {to_rgb.shape}")
    arrays = [table.arrays() for table in tables]
    for index, (_, r0, _) in enumerate(arrays):
        if r0.shape[1] != channels:
            raise ValueError(
                f"layer {len(tables) - 1 - index} (top first): the table has {r0.shape[1]} channels, "
                f"the substrate {channels}"
            )
    maps: list[np.ndarray | None] = []
    uniform = np.zeros(MAX_LAYERS)
    for index, thickness in enumerate(thicknesses):
        value = np.asarray(thickness, dtype=float)
        if value.ndim not in (0, 2) or value.size < 1 or not np.all(np.isfinite(value)):
            raise ValueError(
                f"layer {len(tables) - 1 - index} (top first): thickness must be a finite number or a 2-D map (mm)"
            )
        if value.ndim == 0:
            uniform[index] = value
            maps.append(None)
        else:
            maps.append(value)

    groups = -(-channels // 4)
    substrate_groups = np.zeros(4 * (MAX_CHANNELS // 4))
    substrate_groups[:channels] = substrate
    to_rgb_rows = np.zeros((MAX_CHANNELS, 3))
    to_rgb_rows[:channels] = to_rgb
    sample_count = np.ones(MAX_LAYERS, dtype=np.int32)
    use_map = np.zeros(MAX_LAYERS, dtype=np.int32)
    for index, (x, _, _) in enumerate(arrays):
        sample_count[index] = x.size
        use_map[index] = maps[index] is not None

    model = np.eye(4) if model is None else np.asarray(model, dtype=float)
    view_projection = camera.projection_matrix(width / height) @ camera.view_matrix()
    context.make_current(width, height)
    program = _layers_program()
    textures: list[int] = []
    try:
        for x, r0, t in arrays:
            textures.append(_float_texture(_table_texels(x, r0, t, groups), linear=False))
        table_textures = textures + [0] * (MAX_LAYERS - len(textures))
        map_textures = []
        for thickness_map in [*maps, *[None] * (MAX_LAYERS - len(maps))]:
            if thickness_map is None:
                map_textures.append(0)
            else:
                texels = np.zeros((*thickness_map.shape, 4))
                texels[..., 0] = thickness_map[::-1]  # row 0 of the map is the top (v = 1)
                textures.append(_float_texture(texels, linear=True))
                map_textures.append(textures[-1])
        with Framebuffer(width, height) as target, GpuMesh(mesh) as gpu_mesh:
            target.clear((*background, 0.0))
            GL.glEnable(GL.GL_DEPTH_TEST)
            GL.glDepthFunc(GL.GL_LESS)
            program.use()
            program.set_mat4("u_model", model)
            program.set_mat4("u_view_projection", view_projection)
            program.set_mat3("u_normal_matrix", np.linalg.inv(model[:3, :3]).T)
            program.set_vec3("u_light_radiance", light.radiance)
            program.set_vec3("u_to_light", light.to_light())
            GL.glUniform1i(_location(program, "u_layer_count"), len(arrays))
            GL.glUniform1i(_location(program, "u_group_count"), groups)
            GL.glUniform1iv(_location(program, "u_sample_count"), MAX_LAYERS, sample_count)
            GL.glUniform1iv(_location(program, "u_use_map"), MAX_LAYERS, use_map)
            GL.glUniform1fv(_location(program, "u_thickness"), MAX_LAYERS, uniform.astype(np.float32))
            GL.glUniform4fv(_location(program, "u_substrate"), MAX_CHANNELS // 4, substrate_groups.astype(np.float32))
            GL.glUniform3fv(_location(program, "u_to_rgb"), MAX_CHANNELS, to_rgb_rows.astype(np.float32))
            for index in range(MAX_LAYERS):
                for unit, (name, texture) in enumerate(
                    ((f"u_table{index}", table_textures[index]), (f"u_map{index}", map_textures[index]))
                ):
                    unit_index = 2 * index + unit
                    GL.glUniform1i(_location(program, name), unit_index)
                    GL.glActiveTexture(GL.GL_TEXTURE0 + unit_index)
                    GL.glBindTexture(GL.GL_TEXTURE_2D, texture)
            gpu_mesh.draw()
            GL.glFinish()
            image = target.read_rgba()[..., :3]
        return image
    finally:
        for unit_index in range(2 * MAX_LAYERS):
            GL.glActiveTexture(GL.GL_TEXTURE0 + unit_index)
            GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
        GL.glActiveTexture(GL.GL_TEXTURE0)
        if textures:
            GL.glDeleteTextures(len(textures), textures)
