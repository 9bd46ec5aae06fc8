"""Shadow maps: the depth of the scene seen from a light, rendered into a square depth texture.

Lengths are in scene units (mm); matrices are row-major numpy (4, 4) arrays acting on column vectors, in the OpenGL
clip convention (NDC z in [-1, 1]), as in :mod:`renderer.scene`.

The light's frustum is fitted to a bounding sphere (centre ``c``, radius ``r``) of every shadow caster and receiver,
widened by the relative :data:`MARGIN` ``m``: ``h = (1 + m) r``. With ``d`` the unit light direction:

* directional light: an orthographic projection looking along ``d`` from ``c - 2 h d``, square of half-size ``h``,
  near ``h`` and far ``3 h``, so that a point at distance ``s`` from that eye along ``d`` has depth
  ``(s - h) / (2 h)``: the sphere occupies depths ``m / (2 (1 + m))`` to ``1 - m / (2 (1 + m))``;
* point light at ``L``, ``D = |c - L| > r``: a perspective projection from ``L`` looking at ``c``, square, with the
  tangent of its half field of view ``t = (1 + m) tan(asin(r / D)) = (1 + m) r / sqrt(D^2 - r^2)``, far
  ``f = D + h`` and near ``n = max(D - h, (D - r) / 2)`` (half the gap to the sphere when the light is closer than
  the margin); a point at distance ``s`` along the axis has depth ``f (s - n) / (s (f - n))``.

:func:`shadow_matrix` maps a world point ``p`` to the homogeneous shadow coordinate ``q = B P V p`` with
``B`` the bias taking NDC [-1, 1]^3 to [0, 1]^3; ``q.xy / q.w`` is the texture coordinate (u to the right, v up) and
``q.z / q.w`` the depth to compare with the map's, as GLSL's ``textureProj(sampler2DShadow, q)`` does. The map
compares with ``GL_LEQUAL``: a lookup returns 1 (lit) where the reference depth is at most the stored one,
bilinearly weighted over the four nearest texels (2 x 2 percentage-closer filtering). Outside [0, 1]^2 the map
reads the border depth 1, so receivers there are lit; the reference depth is not clamped (a float depth texture), so
a receiver beyond the far plane, outside the bounding sphere, compares as shadowed.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from renderer.context import GL
from renderer.meshes import GpuMesh
from renderer.program import Program, shared_program
from renderer.scene import DirectionalLight, OrthographicCamera, PerspectiveCamera, PointLight

#: Relative widening of the light's frustum beyond the bounding sphere, in size and in depth.
MARGIN = 0.01
#: glPolygonOffset factor: the depth offset in units of the primitive's largest depth slope per texel.
SLOPE_BIAS = 2.0
#: glPolygonOffset units: the constant depth offset in units of the smallest resolvable depth difference.
CONSTANT_BIAS = 4.0

#: Takes NDC [-1, 1]^3 to texture coordinates and depth in [0, 1]^3.
_BIAS = np.array(
    [
        [0.5, 0.0, 0.0, 0.5],
        [0.0, 0.5, 0.0, 0.5],
        [0.0, 0.0, 0.5, 0.5],
        [0.0, 0.0, 0.0, 1.0],
    ]
)


def _depth_program() -> Program:
    """The depth-only program."""
    return shared_program("shadow_depth.vert", "shadow_depth.frag")


def _up_for(direction: np.ndarray) -> tuple[float, float, float]:
    """The world axis least aligned with ``direction``: never parallel to it, so a valid ``look_at`` up vector."""
    up = np.zeros(3)
    up[int(np.argmin(np.abs(direction)))] = 1.0
    return tuple(up)


def light_camera(
    light: DirectionalLight | PointLight, centre: Sequence[float] | np.ndarray, radius: float
) -> OrthographicCamera | PerspectiveCamera:
    """The light's view (a camera) whose frustum encloses the sphere of ``centre`` (mm) and ``radius`` (mm).

    The sphere should bound every shadow caster and receiver; the frusta are described in the module docstring.

    Raises
    ------
    ValueError
        If the radius is not positive and finite, the centre not finite, or a point light lies inside or on the
        sphere: one 2-D map cannot cover every direction around the light.
    """
    c = np.asarray(centre, dtype=float).reshape(3)
    if not (np.all(np.isfinite(c)) and np.isfinite(radius) and radius > 0.0):
        raise ValueError(f"the bounding sphere needs a finite centre and a radius > 0 mm, got {tuple(c)} and {radius}")
    h = (1.0 + MARGIN) * radius
    if isinstance(light, DirectionalLight):
        d = -light.to_light()
        camera = OrthographicCamera(
            eye=tuple(c - 2.0 * h * d), target=tuple(c), up=_up_for(d), near=h, far=3.0 * h, half_height=h
        )
    else:
        position = np.asarray(light.position, dtype=float)
        distance = float(np.linalg.norm(c - position))
        if distance <= radius:
            raise ValueError(
                f"the point light at {tuple(position)} lies inside or on the bounding sphere of the shadow casters "
                f"and receivers (centre {tuple(c)}, radius {radius} mm, the light {distance:.6g} mm from the centre): "
                "a single 2-D shadow map cannot cover every direction; move the light out of the sphere or set "
                "cast_shadows=False"
            )
        tangent = h / np.sqrt((distance - radius) * (distance + radius))
        camera = PerspectiveCamera(
            eye=tuple(position),
            target=tuple(c),
            up=_up_for(c - position),
            near=max(distance - h, 0.5 * (distance - radius)),
            far=distance + h,
            fov_y_deg=float(np.degrees(2.0 * np.arctan(tangent))),
        )
    return camera


def light_view_projection(
    light: DirectionalLight | PointLight, centre: Sequence[float] | np.ndarray, radius: float
) -> np.ndarray:
    """The world -> light clip matrix (4, 4) of :func:`light_camera`: its frustum encloses the sphere."""
    camera = light_camera(light, centre, radius)
    return camera.projection_matrix(1.0) @ camera.view_matrix()


def shadow_matrix(view_projection: np.ndarray) -> np.ndarray:
    """World -> homogeneous shadow coordinates (4, 4): ``B @ view_projection``, with ``B`` taking NDC to [0, 1]^3.

    For a world point ``p`` (homogeneous, w = 1), ``q = shadow_matrix @ p`` gives the texture coordinate
    ``q.xy / q.w`` and the depth ``q.z / q.w`` (``q.w`` is 1 for a directional light).
    """
    return _BIAS @ np.asarray(view_projection, dtype=float)


class ShadowMap:
    """A square depth texture of ``size`` x ``size`` texels and a depth-only framebuffer rendering into it.

    The texture is ``GL_DEPTH_COMPONENT32F`` with ``GL_TEXTURE_COMPARE_MODE = GL_COMPARE_REF_TO_TEXTURE`` and
    ``GL_LEQUAL``, so bind it to a ``sampler2DShadow``; ``GL_LINEAR`` filters give 2 x 2 percentage-closer filtering;
    outside [0, 1]^2 it reads the border depth 1 (lit). A current context is needed from creation to release; use as a
    context manager (or call :meth:`release`) to free the GL objects.

    Attributes
    ----------
    size
        Width and height in texels.
    texture
        GL name of the depth texture.
    view_projection
        The world -> light clip matrix (4, 4) of the last :meth:`render`, None before the first.
    """

    def __init__(self, size: int) -> None:
        """Create the depth texture and framebuffer; ``size`` in texels."""
        limit = int(GL.glGetIntegerv(GL.GL_MAX_TEXTURE_SIZE))
        if not 1 <= size <= limit:
            raise ValueError(f"the shadow map size must lie in 1 .. {limit} texels, got {size}")
        self.size = size
        self.view_projection: np.ndarray | None = None
        self.texture = GL.glGenTextures(1)
        GL.glBindTexture(GL.GL_TEXTURE_2D, self.texture)
        GL.glTexImage2D(
            GL.GL_TEXTURE_2D, 0, GL.GL_DEPTH_COMPONENT32F, size, size, 0, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT, None
        )
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_WRAP_S, GL.GL_CLAMP_TO_BORDER)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_WRAP_T, GL.GL_CLAMP_TO_BORDER)
        GL.glTexParameterfv(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_BORDER_COLOR, np.ones(4, dtype=np.float32))
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_COMPARE_MODE, GL.GL_COMPARE_REF_TO_TEXTURE)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_COMPARE_FUNC, GL.GL_LEQUAL)
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
        previous = int(GL.glGetIntegerv(GL.GL_FRAMEBUFFER_BINDING))
        self.fbo = GL.glGenFramebuffers(1)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
        GL.glFramebufferTexture2D(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_TEXTURE_2D, self.texture, 0)
        GL.glDrawBuffer(GL.GL_NONE)
        GL.glReadBuffer(GL.GL_NONE)
        status = GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, previous)
        if status != GL.GL_FRAMEBUFFER_COMPLETE:
            self.release()
            raise RuntimeError(f"the depth-only framebuffer ({size} x {size}) is incomplete: status 0x{status:x}")

    def render(self, draws: Sequence[tuple[GpuMesh, np.ndarray]], view_projection: np.ndarray) -> None:
        """Clear the map to depth 1 and render the depth of ``draws`` seen through ``view_projection``.

        Parameters
        ----------
        draws
            ``(mesh, model)`` pairs: an uploaded mesh and its object -> world matrix (4, 4).
        view_projection
            World -> light clip matrix (4, 4), usually from :func:`light_view_projection`.

        Every triangle is drawn (no face culling: a single-sided card must cast a shadow) with
        ``glPolygonOffset(SLOPE_BIAS, CONSTANT_BIAS)`` pushing the stored depth away from the light. A lit surface
        looks its own depth up through 2 x 2 PCF, whose texels lie up to one texel from the lookup point along each
        axis, so its stored depths differ from its own by up to twice its largest depth slope per texel: the factor
        2 removes that self-shadowing ("acne"). The 4 units (about 2.4e-7 for depths in [0.5, 1)) cover the float32
        rounding of the two passes' transforms. Silhouettes seen edge-on get large offsets and may clamp to depth 1;
        they are grazing, so a shadow lost there is dark from the cosine term anyway.

        The framebuffer bindings, current program (unless it was deleted), depth test, function and write mask, and
        the polygon offset are restored afterwards. The viewport is left covering the map: setting it back is the
        caller's job (as :meth:`renderer.framebuffer.Framebuffer.bind` does).
        """
        view_projection = np.asarray(view_projection, dtype=float)
        if view_projection.shape != (4, 4) or not np.all(np.isfinite(view_projection)):
            raise ValueError(f"view_projection must be a finite (4, 4) matrix, got shape {view_projection.shape}")
        draw_fbo = int(GL.glGetIntegerv(GL.GL_DRAW_FRAMEBUFFER_BINDING))
        read_fbo = int(GL.glGetIntegerv(GL.GL_READ_FRAMEBUFFER_BINDING))
        current_program = int(GL.glGetIntegerv(GL.GL_CURRENT_PROGRAM))
        depth_test = bool(GL.glIsEnabled(GL.GL_DEPTH_TEST))
        depth_func = int(GL.glGetIntegerv(GL.GL_DEPTH_FUNC))
        depth_mask = bool(GL.glGetBooleanv(GL.GL_DEPTH_WRITEMASK))
        offset_fill = bool(GL.glIsEnabled(GL.GL_POLYGON_OFFSET_FILL))
        offset_factor = float(GL.glGetFloatv(GL.GL_POLYGON_OFFSET_FACTOR))
        offset_units = float(GL.glGetFloatv(GL.GL_POLYGON_OFFSET_UNITS))
        program = _depth_program()
        try:
            GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
            GL.glViewport(0, 0, self.size, self.size)
            GL.glDepthMask(GL.GL_TRUE)
            GL.glClearDepth(1.0)
            GL.glClear(GL.GL_DEPTH_BUFFER_BIT)
            GL.glEnable(GL.GL_DEPTH_TEST)
            GL.glDepthFunc(GL.GL_LESS)
            GL.glEnable(GL.GL_POLYGON_OFFSET_FILL)
            GL.glPolygonOffset(SLOPE_BIAS, CONSTANT_BIAS)
            program.use()
            program.set_mat4("u_view_projection", view_projection)
            for mesh, model in draws:
                program.set_mat4("u_model", np.asarray(model, dtype=float).reshape(4, 4))
                mesh.draw()
            GL.glFinish()
            self.view_projection = view_projection.copy()
        finally:
            GL.glPolygonOffset(offset_factor, offset_units)
            (GL.glEnable if offset_fill else GL.glDisable)(GL.GL_POLYGON_OFFSET_FILL)
            GL.glDepthMask(GL.GL_TRUE if depth_mask else GL.GL_FALSE)
            GL.glDepthFunc(depth_func)
            (GL.glEnable if depth_test else GL.glDisable)(GL.GL_DEPTH_TEST)
            # a program deleted while current is freed once another is used: then there is none to go back to
            GL.glUseProgram(current_program if GL.glIsProgram(current_program) else 0)
            GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, draw_fbo)
            GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, read_fbo)

    def release(self) -> None:
        """Delete the GL objects (a bound framebuffer reverts to 0 when deleted); the map cannot be used afterwards."""
        GL.glDeleteFramebuffers(1, [self.fbo])
        GL.glDeleteTextures(1, [self.texture])

    def __enter__(self) -> ShadowMap:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.release()


def read_depth(shadow_map: ShadowMap) -> np.ndarray:
    """The map's depths in [0, 1] as float32 (size, size), top row (v = 1) first; for tests and debugging.

    Texel ``[row, column]`` covers u in ``[column, column + 1] / size`` and v in
    ``[size - 1 - row, size - row] / size``.
    """
    GL.glBindTexture(GL.GL_TEXTURE_2D, shadow_map.texture)
    GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 4)
    data = GL.glGetTexImage(GL.GL_TEXTURE_2D, 0, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT)
    GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
    depth = np.asarray(data, dtype=np.float32).reshape(shadow_map.size, shadow_map.size)
    return np.ascontiguousarray(depth[::-1])
