"""Makeup on skin: the skin pass, screen-space subsurface scattering, and the cosmetic pass (thesis sections 3.2, 3.4).

Model. The makeup films lie on the skin, which is their substrate. Per channel, with R the stack's reflectance over the
skin albedo a, R_b its reflectance over black (what the films reflect by themselves) and E v cos(theta) the light
arriving (:mod:`renderer.layers`), the Kubelka-Munk composition of the films over the skin splits exactly into

    E v cos(theta) R  =  E v cos(theta) R_b  +  E v cos(theta) (R - R_b)

where ``R - R_b = T^2 a / (1 - R_b' a)`` (one film; the stack's in general) is the light that went down through the
makeup, into the skin, and back out through the makeup, with the interreflections between skin and films. The skin
pass writes that second term, the skin's light, into its own float target (with the view depth and a skin mask);
subsurface scattering blurs it; the cosmetic pass adds the first term, the makeup's own reflectance, and the specular
lobes of every film and of the skin (the skin's seen through all films, A = product of T^2). Energy is consistent by
construction: without the blur the sum is the layer pass's result to rounding, so a film of thickness 0 or no makeup
shows bare skin, and an opaque film (T = 0) sends no light to the skin at all. Blurring the light after its way back
up through the films (instead of between its ways down and up) is the approximation: it differs only where the makeup
changes within the scattering distance of skin (about a millimetre), at a product's edge.

Subsurface scattering (Jimenez et al. 2009, as in the thesis): the sum of Gaussians of Table 3.1 (variances v_i in mm^2,
RGB weights W_i) applied as a chain of separable 7-tap blurs (``shaders/sss_blur.frag``), blur i widening the previous
result by sqrt(v_i - v_(i-1)); each result is alpha-blended (thesis eq. 3.4) into an accumulator with the weights W'_i =
W_i / sum_(j <= i) W_j (thesis eq. 3.3, :func:`blend_weights`), which leaves sum_i W_i blur_i / sum_j W_j. Only skin
pixels are blurred and only skin pixels feed a blur.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from renderer import context
from renderer.background import fill_background
from renderer.context import GL
from renderer.framebuffer import Framebuffer, pooled
from renderer.layers import SurfacePass
from renderer.program import Program, shared_program
from renderer.scene import Camera, OrthographicCamera, Scattering, Scene, supersampled

#: Variances (mm^2) of the four Gaussians of the skin profile (thesis Table 3.1, Jimenez et al. 2009).
SKIN_VARIANCES_MM2 = (0.0064, 0.0516, 0.2719, 2.0062)
#: Their RGB weights W_i (Table 3.1).
SKIN_WEIGHTS = ((0.2405, 0.4474, 0.6157), (0.1158, 0.3661, 0.3439), (0.1836, 0.1864, 0.0), (0.4600, 0.0, 0.0402))


def blend_weights(weights: Sequence[Sequence[float]] = SKIN_WEIGHTS) -> np.ndarray:
    """Alpha-blend weights W'_i = W_i / sum_(j <= i) W_j (thesis eq. 3.3), shape (n, 3); 0 where the sum is 0."""
    w = np.asarray(weights, dtype=float)
    cumulative = np.cumsum(w, axis=0)
    return np.divide(w, cumulative, out=np.zeros_like(w), where=cumulative > 0.0)


def _blur_program() -> Program:
    return shared_program("fullscreen.vert", "sss_blur.frag")


def _camera_scale(camera: Camera, height: int) -> tuple[float, bool]:
    """Pixels per mm at 1 m (perspective) or pixels per mm (orthographic), and whether the camera is orthographic."""
    if isinstance(camera, OrthographicCamera):
        return height / (2.0 * camera.half_height), True
    focal_pixels = 0.5 * height / np.tan(np.radians(camera.fov_y_deg) / 2.0)
    return focal_pixels / 1000.0, False


def skin_region(
    mesh_vertices: np.ndarray, model: np.ndarray, view_projection: np.ndarray, width: int, height: int
) -> tuple[int, int, int, int] | None:
    """The pixels the skin can cover: the box (x0, y0, x1, y1), GL window pixels from the bottom left, end exclusive,
    around the projected vertices of the skin mesh, grown by 2 pixels and clipped to the frame; None (the whole frame)
    when a vertex lies behind the camera. A triangle projects inside the box of its corners, so no skin pixel, nor
    any sample of one, lies outside it."""
    corners = np.c_[np.asarray(mesh_vertices, dtype=float), np.ones(len(mesh_vertices))] @ (view_projection @ model).T
    if not np.all(corners[:, 3] > 0.0):
        return None
    ndc = corners[:, :2] / corners[:, 3:]
    low = np.floor((ndc.min(axis=0) * 0.5 + 0.5) * (width, height)) - 2
    high = np.ceil((ndc.max(axis=0) * 0.5 + 0.5) * (width, height)) + 2
    x0, y0 = np.clip(low, 0, (width, height)).astype(int)
    x1, y1 = np.clip(high, 0, (width, height)).astype(int)
    return int(x0), int(y0), int(x1), int(y1)


def scatter(
    skin: Framebuffer, camera: Camera, scattering: Scattering, region: tuple[int, int, int, int] | None = None
) -> np.ndarray:
    """Blur the skin light (target 1 of ``skin``, the skin pass) with the skin profile; linear RGB (h, w, 3).

    ``region`` (:func:`skin_region`) limits the blur's passes to the pixels the skin can cover (a scissor box): every
    pixel outside it holds no skin light, which the blur would carry through as 0, and reads 0 here as well; None
    blurs the whole frame.
    """
    width, height = skin.width, skin.height
    program = _blur_program()
    scale, orthographic = _camera_scale(camera, height)
    weights = blend_weights()
    widening = np.sqrt(np.diff(np.concatenate([[0.0], SKIN_VARIANCES_MM2])))
    vao = GL.glGenVertexArrays(1)
    try:
        with pooled(width, height) as across, pooled(width, height, targets=2) as along:
            along.clear((0.0, 0.0, 0.0, 0.0))
            across.clear((0.0, 0.0, 0.0, 0.0))  # outside the region: 0, as the blur of no skin light
            if region is not None:
                GL.glEnable(GL.GL_SCISSOR_TEST)
                GL.glScissor(region[0], region[1], region[2] - region[0], region[3] - region[1])
            GL.glDisable(GL.GL_DEPTH_TEST)
            GL.glBindVertexArray(vao)
            program.use()
            GL.glUniform1i(GL.glGetUniformLocation(program.handle, "u_source"), 0)
            GL.glUniform1i(GL.glGetUniformLocation(program.handle, "u_depth"), 1)
            GL.glUniform2f(GL.glGetUniformLocation(program.handle, "u_pixel"), 1.0 / width, 1.0 / height)
            for name, value in (("u_alpha", scattering.alpha), ("u_beta", scattering.beta),
                                ("u_clamp", scattering.gradient_clamp), ("u_scale", scale)):  # fmt: skip
                GL.glUniform1f(GL.glGetUniformLocation(program.handle, name), value)
            GL.glUniform1i(GL.glGetUniformLocation(program.handle, "u_orthographic"), int(orthographic))
            GL.glActiveTexture(GL.GL_TEXTURE1)
            GL.glBindTexture(GL.GL_TEXTURE_2D, skin.colours[2])
            source = skin.colours[1]
            for step, blend in zip(widening, weights, strict=True):
                GL.glUniform1f(GL.glGetUniformLocation(program.handle, "u_width"), step)
                # Across: source -> across; along: across -> along[0] (the next source) and, blended, along[1].
                for target, direction, texture in ((across, (1.0, 0.0), source), (along, (0.0, 1.0), across.colour)):
                    target.bind()
                    GL.glUniform2f(GL.glGetUniformLocation(program.handle, "u_direction"), *direction)
                    GL.glActiveTexture(GL.GL_TEXTURE0)
                    GL.glBindTexture(GL.GL_TEXTURE_2D, texture)
                    if target is along:
                        GL.glEnablei(GL.GL_BLEND, 1)
                        GL.glBlendFunci(1, GL.GL_CONSTANT_COLOR, GL.GL_ONE_MINUS_CONSTANT_COLOR)
                        GL.glBlendColor(*blend, 1.0)
                    GL.glDrawArrays(GL.GL_TRIANGLES, 0, 3)
                    GL.glDisablei(GL.GL_BLEND, 1)
                source = along.colours[0]
            GL.glFinish()
            GL.glDisable(GL.GL_SCISSOR_TEST)
            return along.read_rgba(1)[..., :3]
    finally:
        GL.glDisable(GL.GL_SCISSOR_TEST)
        GL.glBindVertexArray(0)
        GL.glActiveTexture(GL.GL_TEXTURE1)
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
        GL.glActiveTexture(GL.GL_TEXTURE0)
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
        GL.glDeleteVertexArrays(1, [vao])


def render_skin(scene: Scene) -> np.ndarray:
    """Render a skin mesh wearing a makeup stack (its substrate is the skin's albedo) into linear RGB (h, w, 3).

    The scene as :func:`renderer.layers.render_layers` takes it, with ``substrate_lobe`` the skin's own lobe
    (:data:`renderer.stack.SKIN_SPECULAR` for measured skin) and ``scattering`` the subsurface blur (None: no blur,
    the result equals the layer pass's to rounding). Supersampled as :func:`renderer.scene.supersampled` says: the
    blur runs on the fine image, its reach in mm the same.
    """
    return supersampled(_render_skin, scene)


def _render_skin(scene: Scene) -> np.ndarray:
    width, height = scene.resolution
    with context.lock, SurfacePass(scene) as surface_pass, pooled(width, height, targets=3) as target:
        surface_pass.draw(target, split=True)
        surface = fill_background(target.read_rgba(0), scene)
        if scene.scattering is None:
            return surface + target.read_rgba(1)[..., :3]
        region = skin_region(scene.mesh.vertices, surface_pass.model, surface_pass.view_projection, width, height)
        return surface + scatter(target, scene.camera, scene.scattering, region)
