"""A first, minimal pass: one mesh, one directional light, uniform albedo, Lambert shading, no shadows."""

from __future__ import annotations

import numpy as np
import trimesh

from renderer import context
from renderer.context import GL
from renderer.framebuffer import Framebuffer
from renderer.meshes import GpuMesh
from renderer.program import Program
from renderer.scene import Camera, DirectionalLight

_program: Program | None = None


def _lambert_program() -> Program:
    """The Lambert program, compiled once per process (the context is one per process)."""
    global _program
    if _program is None:
        _program = Program("lambert.vert", "lambert.frag")
    return _program


def render(
    mesh: trimesh.Trimesh,
    camera: Camera,
    light: DirectionalLight,
    albedo: tuple[float, float, float],
    width: int,
    height: int,
    model: np.ndarray | None = None,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> np.ndarray:
    """Render ``mesh`` with Lambert shading into a float image.

    Parameters
    ----------
    mesh
        Triangle mesh in mm with per-vertex normals and uv (see :mod:`renderer.meshes`).
    camera
        Orthographic or perspective camera; its aspect ratio is ``width / height``.
    light
        Directional light; a pixel renders as ``albedo * light.radiance * max(cos theta, 0)``.
    albedo
        Diffuse albedo, linear RGB in [0, 1].
    width, height
        Image size in pixels.
    model
        Object -> world matrix (4, 4); identity if omitted.
    background
        Linear RGB of pixels the mesh does not cover (any float, unclamped).

    Returns
    -------
    np.ndarray
        Linear RGB, float32, shape (height, width, 3), top row first.
    """
    model = np.eye(4) if model is None else np.asarray(model, dtype=float)
    view_projection = camera.projection_matrix(width / height) @ camera.view_matrix()
    context.make_current(width, height)
    program = _lambert_program()
    with Framebuffer(width, height) as target, GpuMesh(mesh) as gpu_mesh:
        target.clear((*background, 0.0))
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthFunc(GL.GL_LESS)
        program.use()
        program.set_mat4("u_model", model)
        program.set_mat4("u_view_projection", view_projection)
        program.set_mat3("u_normal_matrix", np.linalg.inv(model[:3, :3]).T)
        program.set_vec3("u_albedo", albedo)
        program.set_vec3("u_light_radiance", light.radiance)
        program.set_vec3("u_to_light", light.to_light())
        gpu_mesh.draw()
        GL.glFinish()
        return target.read_rgba()[..., :3]
