"""The Kubelka-Munk layer pass: the GL pass that renders a :class:`renderer.scene.Scene`, a mesh shaded by a stack of
up to four films over a substrate (:mod:`renderer.stack`), with lights and shadows.

The fragment shader (``shaders/km_layers.frag``) looks each film's optical table up at the film's thickness,
interpolating linearly between samples and clamping at the ends, and composes the films bottom-up onto the substrate
reflectance ``Rg`` with the layer equation (thesis eq. 3.14, printed with T2 where R2 belongs; films are symmetric, so
the reflectance from below equals ``R0``)::

    Rg <- R0 + T^2 Rg / (1 - R0 Rg)

per channel: linear RGB, or spectral bands (up to :data:`~renderer.stack.MAX_CHANNELS`) converted once with the
stack's ``to_rgb`` matrix; a precomposed stack's linear RGB is read as it is. Each lobe (thesis eq. 3.15) is
attenuated by the films above it. A pixel renders as

    sum over lights of  E * visibility * max(cos theta, 0) * (R_rgb + pi * sum_i A_i f_spec,i)

with ``E`` the light's radiance, the value a white Lambert surface facing the light renders to (as in
a bare Lambert surface); ``km_layers.frag`` gives every term. Lights that cast shadows get a shadow map
(:mod:`renderer.shadows`) covering the mesh and the props, filtered with 3 x 3 PCF taps.

The pass is deferred: the meshes are first drawn into surface attributes (``shaders/surface_attributes.frag``: per
sample, what the nearest surface holds at the pixel's centre), multisampled when the scene asks for it; then each
mesh is shaded once over the frame (``shaders/km_layers.frag``), only at the pixels where some sample shows it (a
stencil bit per mesh, set by ``shaders/surface_cover.frag``), each group of samples showing one smooth surface shaded
once. A pixel is shaded as often as it shows distinct surfaces, however many triangles were drawn over it: hidden
surfaces and the triangles' edges inside a surface cost nothing (llvmpipe shades a whole block of pixels for every
triangle that touches it, and, multisampling, every fragment before its depth test).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh

from renderer import context, multisample
from renderer.background import fill_background
from renderer.context import GL
from renderer.framebuffer import Framebuffer, pooled
from renderer.meshes import GpuMesh
from renderer.program import Program, shared_program
from renderer.scene import MAX_LIGHTS, Light, OrthographicCamera, Scene, supersampled
from renderer.shadows import MARGIN, ShadowMap, light_camera, shadow_matrix
from renderer.stack import MAX_LAYERS, ChannelStack
from renderer.stack_uniforms import bind_channel_stack, bind_precomposed, channel_uniforms, composite_texels
from renderer.texture_cache import cache as texture_cache
from renderer.textures import array_texture, raw_depth_sampler
from renderer.uniforms import (
    ATTRIBUTE_TARGETS,
    COMPOSITE_UNIT,
    LAST_UNIT,
    SHADOW_DEPTH_UNIT,
    SHADOW_UNIT,
    SOFT_PASS_TARGETS,
    SOFT_TARGETS,
    SUBSTRATE_UNIT,
    detail_textures,
    environment_textures,
    light_switches,
    lobe_switch,
    set_attributes,
    set_environment,
    set_fine_detail,
    set_floor,
    set_lights,
    set_roughness,
    set_shadow_lookup,
    set_soft_shadows,
    set_specular,
    set_view,
)

#: Most meshes in one pass (the product and its props): one stencil bit each.
MAX_MESHES = 8
#: Texels each way the soft-shadow filter reaches at most (soft_shadow_filter.frag).
SOFT_FILTER_RADIUS = 3


def _shading_program(switches: dict[str, int]) -> Program:
    """The shading program with these counts and switches compiled in (km_layers.frag lists them): each combination
    its own program, compiled once per process (llvmpipe runs the code of a branch no pixel takes under an empty
    mask, and indexes arrays in memory in a loop it cannot unroll)."""
    return shared_program("fullscreen.vert", "km_layers.frag", defines=dict(sorted(switches.items())))


def _check_lights(lights: Sequence[Light]) -> None:
    if not 1 <= len(lights) <= MAX_LIGHTS:
        raise ValueError(f"between 1 and {MAX_LIGHTS} lights are needed, got {len(lights)}")


def _world_bounds(draws: Sequence[tuple[trimesh.Trimesh, np.ndarray]]) -> tuple[np.ndarray, float]:
    """Centre (mm) and radius (mm) of a sphere around every mesh, placed by its model matrix."""
    points = np.concatenate([np.asarray(mesh.vertices) @ model[:3, :3].T + model[:3, 3] for mesh, model in draws])
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = 0.5 * (lo + hi)
    return centre, float(np.max(np.linalg.norm(points - centre, axis=1)))


def render_layers(scene: Scene) -> np.ndarray:
    """Render ``scene``: its mesh covered by its Kubelka-Munk stack of films, and its props, into a float image.

    Every field of the :class:`~renderer.scene.Scene` is used but ``scattering`` (the skin pass's,
    :func:`renderer.skin.render_skin`); ``supersampling`` through :func:`renderer.scene.supersampled`.

    Returns
    -------
    np.ndarray
        Linear RGB, float32, shape (height, width, 3), top row first.
    """
    return supersampled(_render_layers, scene)


def _render_layers(scene: Scene) -> np.ndarray:
    with context.lock, SurfacePass(scene) as surface_pass, pooled(*scene.resolution) as target:
        surface_pass.draw(target, split=False)
        return fill_background(target.read_rgba(), scene)


class SurfacePass:
    """The layer pass's GL resources for one frame of a scene: meshes, tables, shadow maps; :meth:`draw` renders into
    a target.

    A context manager; the resources are freed on exit. Refuses (ValueError) a scene the pass cannot draw: no light
    or more than :data:`MAX_LIGHTS`, lobes not one per film, a prop's albedo outside [0, 1], more than
    :data:`MAX_MESHES` meshes, a sample count multisampling cannot take, a stack beyond the pass's limits.
    """

    def __init__(self, scene: Scene) -> None:
        stack, width, height = scene.stack, *scene.resolution
        _check_lights(scene.lights)
        lobes = list(scene.lobes) or [None] * stack.n_layers
        if len(lobes) != stack.n_layers:
            raise ValueError(f"one specular entry per layer is needed: {stack.n_layers} layers, {len(lobes)} entries")
        self.lobes_bottom_up = [*lobes[::-1], *[None] * (MAX_LAYERS - len(lobes)), scene.substrate_lobe]
        self.stack = stack
        self.channel = channel_uniforms(stack) if isinstance(stack, ChannelStack) else None
        self.composite_texels = None if self.channel is not None else composite_texels(stack)
        self.model = np.eye(4) if scene.model is None else np.asarray(scene.model, dtype=float)
        self.props = list(scene.props)
        for prop in self.props:
            albedo = np.asarray(prop.albedo, dtype=float)
            if albedo.shape != (3,) or not (np.all(np.isfinite(albedo)) and 0.0 <= albedo.min() <= albedo.max() <= 1.0):
                raise ValueError(f"a prop's albedo must be linear RGB in [0, 1], got {prop.albedo}")
        self.draws = [(scene.mesh, self.model)] + [
            (p.mesh, np.eye(4) if p.model is None else np.asarray(p.model, float)) for p in self.props
        ]
        if len(self.draws) > MAX_MESHES:
            raise ValueError(f"at most {MAX_MESHES - 1} props can be drawn with the product, got {len(self.props)}")
        self.camera, self.lights = scene.camera, list(scene.lights)
        self.view_projection = self.camera.projection_matrix(width / height) @ self.camera.view_matrix()
        self.shadow_map_size = scene.shadow_map_size
        self.environment, self.occlusion = scene.environment, scene.occlusion
        self.normal_map, self.substrate_roughness = scene.normal_map, scene.substrate_roughness
        context.make_current(width, height)
        self.samples = scene.multisamples
        multisample.check_samples(self.samples)
        self.soft_shadows = any(light.cast_shadows and light.softness > 0.0 for light in self.lights)
        self.soft_shadow_scale = scene.soft_shadow_scale
        shared = {
            **light_switches(self.lights),
            "SAMPLES": self.samples,
            "SOFT_SHADOW_SCALE": self.soft_shadow_scale,
            "ENVIRONMENT": int(self.environment is not None),
            "ORTHOGRAPHIC": int(isinstance(self.camera, OrthographicCamera)),
        }
        channel = self.channel
        maps = [] if channel is None else channel["maps"]
        self.product_switches = {
            **shared,
            **lobe_switch(self.lobes_bottom_up),
            "LAYER_COUNT": stack.n_layers,
            "GROUP_COUNT": 1 if channel is None else -(-channel["substrate"].size // 4),
            "THICKNESS_MAPS": sum(1 << index for index, values in enumerate(maps) if values is not None),
            "PRECOMPOSED": int(channel is None),
            "SUBSTRATE_MAP": int(channel is not None and channel["substrate_map"] is not None),
            "ROUGHNESS_MAP": int(self.substrate_roughness is not None),
            "FLOOR": 0,
        }
        self.props_switches = [  # bare Lambert substrates in RGB: no films, no lobes
            {**shared, "LOBES": 0, "LAYER_COUNT": 0, "GROUP_COUNT": 1, "THICKNESS_MAPS": 0, "PRECOMPOSED": 0,
             "SUBSTRATE_MAP": 0, "ROUGHNESS_MAP": 0, "FLOOR": int(prop.floor_occlusion is not None), "SKIN_SPLIT": 0}
            for prop in self.props
        ]  # fmt: skip
        self.composite = 0
        texture_cache.new_frame()  # nothing this pass binds is evicted while it draws
        self.raw_depth_sampler = raw_depth_sampler()
        self.shadow_maps: list[ShadowMap] = []
        self.gpu_meshes: list[GpuMesh] = []
        self.gpu_draws: list[tuple[GpuMesh, np.ndarray]] = []  # each uploaded mesh with its model matrix
        try:
            self._prepare()
        except BaseException:
            self.release()
            raise

    def _prepare(self) -> None:
        occlusions = [self.occlusion, *(prop.occlusion for prop in self.props)]
        self.gpu_meshes = [GpuMesh(m, ao) for (m, _), ao in zip(self.draws, occlusions, strict=True)]
        self.gpu_draws = [(gpu, model) for gpu, (_, model) in zip(self.gpu_meshes, self.draws, strict=True)]
        centre, radius = _world_bounds(self.draws)
        self.shadow_matrices = np.tile(np.eye(4), (MAX_LIGHTS, 1, 1))
        self.shadow_ranges = np.ones((MAX_LIGHTS, 2))
        self.casts = np.zeros(MAX_LIGHTS, dtype=np.int32)
        self.shadow_texel_mm = 2.0 * (1.0 + MARGIN) * radius / self.shadow_map_size  # the map spans the sphere
        for index, light in enumerate(self.lights):
            if light.cast_shadows:
                self.shadow_maps.append(ShadowMap(self.shadow_map_size))
                frustum = light_camera(light, centre, radius)
                light_matrix = frustum.projection_matrix(1.0) @ frustum.view_matrix()
                self.shadow_ranges[index] = (frustum.near, frustum.far)
                self.shadow_maps[-1].render(self.gpu_draws, light_matrix)
                self.shadow_matrices[index] = shadow_matrix(light_matrix)
                self.casts[index] = 1
        if self.composite_texels is not None:
            self.composite = array_texture(self.composite_texels)
        self.environment_textures = [] if self.environment is None else environment_textures(self.environment)
        self.detail_textures = detail_textures(self.normal_map, self.substrate_roughness)

    def draw(self, target: Framebuffer, *, split: bool) -> None:
        """Shade the mesh and the props into ``target`` (single-sampled, cleared here; its alpha: the share of each
        pixel's samples a surface shows).

        ``split``: the skin pass's three outputs (km_layers.frag), the mesh being skin; else one colour output.
        """
        width, height = target.width, target.height
        with pooled(width, height, ATTRIBUTE_TARGETS, self.samples) as attributes:
            self._draw_attributes(attributes)
            target.bind()
            for index in range(len(target.colours)):
                GL.glClearBufferfv(GL.GL_COLOR, index, np.zeros(4, dtype=np.float32))
            GL.glClearBufferiv(GL.GL_STENCIL, 0, np.zeros(1, dtype=np.int32))
            vao = GL.glGenVertexArrays(1)
            GL.glBindVertexArray(vao)
            try:
                self._cover(attributes)
                if self.soft_shadows:
                    size = (-(-width // self.soft_shadow_scale), -(-height // self.soft_shadow_scale))
                    with (pooled(*size, SOFT_PASS_TARGETS) as soft, pooled(*size) as across,
                          pooled(*size, SOFT_TARGETS) as filtered):  # fmt: skip
                        self._soft_shadows(attributes, soft, height)
                        _filter_soft_shadows(soft, soft.colours[0], 0, across)
                        _filter_soft_shadows(soft, across.colours[0], 1, filtered)
                        target.bind()
                        self._shade(attributes, split, filtered.colours)
                else:
                    self._shade(attributes, split, None)
                GL.glFinish()
            finally:
                GL.glDisable(GL.GL_STENCIL_TEST)
                GL.glDisable(GL.GL_BLEND)
                GL.glStencilMask(0xFF)
                GL.glColorMask(GL.GL_TRUE, GL.GL_TRUE, GL.GL_TRUE, GL.GL_TRUE)
                GL.glBindVertexArray(0)
                GL.glDeleteVertexArrays(1, [vao])
                _unbind_units()

    def _draw_attributes(self, attributes: Framebuffer) -> None:
        """Draw every mesh's surface attributes (surface_attributes.frag) into ``attributes``: mesh index -1 where none.
        Only the index is cleared: the rest of a sample is read only where it names a mesh."""
        attributes.bind()
        GL.glClearBufferfv(GL.GL_COLOR, 2, np.asarray((0.0, 0.0, 0.0, -1.0), dtype=np.float32))
        GL.glClear(GL.GL_DEPTH_BUFFER_BIT)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthFunc(GL.GL_LESS)
        try:
            for index, (gpu_mesh, model) in enumerate(self.gpu_draws):
                normal_map = self.normal_map if index == 0 else None
                program = shared_program("km_layers.vert", "surface_attributes.frag",
                                         defines={"NORMAL_MAP": int(normal_map is not None)})  # fmt: skip
                program.use()
                program.set_mat4("u_view_projection", self.view_projection)
                program.set_mat4("u_view", self.camera.view_matrix())
                GL.glUniform1f(program.location("u_object"), float(index))
                set_fine_detail(program, normal_map, self.detail_textures)
                _draw(program, gpu_mesh, model)
        finally:
            GL.glDisable(GL.GL_DEPTH_TEST)

    def _cover(self, attributes: Framebuffer) -> None:
        """Set stencil bit i of every pixel where some sample shows mesh i (surface_cover.frag)."""
        program = shared_program("fullscreen.vert", "surface_cover.frag", defines={"SAMPLES": self.samples})
        program.use()
        set_attributes(program, attributes.colours, self.samples, read=(2,))
        GL.glColorMask(GL.GL_FALSE, GL.GL_FALSE, GL.GL_FALSE, GL.GL_FALSE)
        GL.glEnable(GL.GL_STENCIL_TEST)
        GL.glStencilFunc(GL.GL_ALWAYS, 0xFF, 0xFF)
        GL.glStencilOp(GL.GL_KEEP, GL.GL_KEEP, GL.GL_REPLACE)
        for index in range(len(self.gpu_draws)):
            GL.glStencilMask(1 << index)
            GL.glUniform1f(program.location("u_object"), float(index))
            GL.glDrawArrays(GL.GL_TRIANGLES, 0, 3)
        GL.glStencilMask(0)
        GL.glColorMask(GL.GL_TRUE, GL.GL_TRUE, GL.GL_TRUE, GL.GL_TRUE)

    def _soft_shadows(self, attributes: Framebuffer, soft: Framebuffer, height: int) -> None:
        """The area lights' visibility at 1 / scale of the resolution into ``soft`` (light_visibility.frag), of a frame
        ``height`` pixels high."""
        names = ("SAMPLES", "SOFT_SHADOW_SCALE", "LIGHT_COUNT", "POINT_LIGHTS", "SOFT_LIGHTS", "ORTHOGRAPHIC")
        switches = {name: self.product_switches[name] for name in names}
        program = shared_program("fullscreen.vert", "light_visibility.frag", defines=switches)
        program.use()
        set_attributes(program, attributes.colours, self.samples, read=(0, 1, 2))
        GL.glUniform2f(program.location("u_footprint"), *_footprint(self.camera, height))
        set_view(program, self.camera)
        self._bind_shadows(program)
        GL.glDisable(GL.GL_STENCIL_TEST)
        soft.bind()
        GL.glDrawArrays(GL.GL_TRIANGLES, 0, 3)
        GL.glEnable(GL.GL_STENCIL_TEST)

    def _shade(self, attributes: Framebuffer, split: bool, soft: list[int] | None) -> None:
        """Shade each mesh over the pixels its stencil bit marks, adding (blending) into the bound target; ``soft``:
        the soft-shadow pass's filtered targets, or None (no soft shadows)."""
        GL.glEnable(GL.GL_BLEND)
        GL.glBlendFunc(GL.GL_ONE, GL.GL_ONE)
        # The product (or the skin).
        program = self._use(_shading_program({**self.product_switches, "SKIN_SPLIT": int(split)}), attributes, soft)
        if self.channel is not None:
            bind_channel_stack(program, self.channel)
        else:
            bind_precomposed(self.composite)
        set_specular(program, self.lobes_bottom_up)
        set_roughness(program, self.detail_textures)
        _shade_mesh(program, 0)
        # The props: bare Lambert substrates in RGB.
        for index, (prop, switches) in enumerate(zip(self.props, self.props_switches, strict=True), start=1):
            program = self._use(_shading_program(switches), attributes, soft)
            set_specular(program, [])
            bind_channel_stack(program, channel_uniforms(ChannelStack((), (), prop.albedo)))
            set_floor(program, prop.floor_occlusion, prop.floor_frame)
            _shade_mesh(program, index)

    def _use(self, program: Program, attributes: Framebuffer, soft: list[int] | None) -> Program:
        """Make ``program`` current with everything its meshes share: the attributes, the soft-shadow pass's targets
        (if any), view, lights, shadow maps, environment and the texture units of the tables and maps."""
        program.use()
        set_attributes(program, attributes.colours, self.samples)
        if soft is not None:
            set_soft_shadows(program, soft)
        GL.glUniform2f(program.location("u_footprint"), *_footprint(self.camera, attributes.height))
        set_lights(program, self.lights)
        self._bind_shadows(program)
        set_view(program, self.camera)
        GL.glActiveTexture(GL.GL_TEXTURE0)  # textures created later bind to unit 0, which the stack rebinds
        for index in range(MAX_LAYERS):
            GL.glUniform1i(program.location(f"u_table{index}"), index)
            GL.glUniform1i(program.location(f"u_map{index}"), MAX_LAYERS + index)
        GL.glUniform1i(program.location("u_composite"), COMPOSITE_UNIT)
        GL.glUniform1i(program.location("u_substrate_map"), SUBSTRATE_UNIT)
        set_environment(program, self.environment, self.environment_textures)
        return program

    def _bind_shadows(self, program: Program) -> None:
        """The uniforms and textures of shaders/shadow_lookup.glsl: the lights and their shadow maps."""
        set_shadow_lookup(program, self.lights, self.shadow_matrices, self.shadow_ranges, self.shadow_texel_mm)
        shadow_textures = iter(shadow_map.texture for shadow_map in self.shadow_maps)
        for index in range(MAX_LIGHTS):
            texture = next(shadow_textures) if self.casts[index] else 0
            for unit, name in ((SHADOW_UNIT + index, "u_shadow"), (SHADOW_DEPTH_UNIT + index, "u_shadow_depth")):
                if name == "u_shadow_depth" and not self.soft_shadows:
                    continue  # only the soft-shadow program reads the raw depths
                GL.glUniform1i(program.location(f"{name}{index}"), unit)
                GL.glActiveTexture(GL.GL_TEXTURE0 + unit)
                GL.glBindTexture(GL.GL_TEXTURE_2D, texture)
            GL.glBindSampler(SHADOW_DEPTH_UNIT + index, self.raw_depth_sampler)
        GL.glActiveTexture(GL.GL_TEXTURE0)

    def release(self) -> None:
        """Free the meshes, shadow maps and the sampler (the textures stay in :mod:`renderer.texture_cache`)."""
        if self.raw_depth_sampler:
            GL.glDeleteSamplers(1, [self.raw_depth_sampler])
            self.raw_depth_sampler = 0
        for item in [*self.shadow_maps, *self.gpu_meshes]:
            item.release()
        self.shadow_maps, self.gpu_meshes, self.gpu_draws = [], [], []

    def __enter__(self) -> SurfacePass:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.release()


def _unbind_units() -> None:
    for unit_index in range(LAST_UNIT + 1):
        GL.glActiveTexture(GL.GL_TEXTURE0 + unit_index)
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
        GL.glBindTexture(GL.GL_TEXTURE_2D_ARRAY, 0)
        GL.glBindTexture(GL.GL_TEXTURE_2D_MULTISAMPLE, 0)
        GL.glBindSampler(unit_index, 0)
    GL.glActiveTexture(GL.GL_TEXTURE0)


def _filter_soft_shadows(soft: Framebuffer, visibility: int, axis: int, filtered: Framebuffer) -> None:
    """The visibility texture ``visibility`` filtered along ``axis`` (0: x, 1: y) on each surface
    (soft_shadow_filter.frag), the surfaces from the soft-shadow pass's targets ``soft``, into ``filtered``: the
    visibility, and the plane where it has a second target (what the shading pass reads)."""
    defines = {"RADIUS": SOFT_FILTER_RADIUS, "AXIS": axis}
    program = shared_program("fullscreen.vert", "soft_shadow_filter.frag", defines=defines)
    program.use()
    textures = (visibility, *soft.colours[1:])
    for unit, (name, texture) in enumerate(zip(("u_visibility", "u_plane", "u_reach"), textures, strict=True)):
        GL.glUniform1i(program.location(name), unit)
        GL.glActiveTexture(GL.GL_TEXTURE0 + unit)
        GL.glBindTexture(GL.GL_TEXTURE_2D, texture)
    GL.glActiveTexture(GL.GL_TEXTURE0)
    GL.glDisable(GL.GL_STENCIL_TEST)
    filtered.bind()
    GL.glDrawArrays(GL.GL_TRIANGLES, 0, 3)
    GL.glEnable(GL.GL_STENCIL_TEST)


def _shade_mesh(program: Program, index: int) -> None:
    """Shade mesh ``index`` over the whole frame, where its stencil bit is set."""
    GL.glStencilFunc(GL.GL_EQUAL, 1 << index, 1 << index)
    GL.glUniform1f(program.location("u_object"), float(index))
    GL.glDrawArrays(GL.GL_TRIANGLES, 0, 3)


def _footprint(camera, height: int) -> tuple[float, float]:
    """A pixel's size (mm) at view depth d as (x, y) with size = x + y d: the orthographic camera's constant, or the
    perspective camera's angle a pixel subtends."""
    if isinstance(camera, OrthographicCamera):
        return 2.0 * camera.half_height / height, 0.0
    return 0.0, 2.0 * float(np.tan(np.radians(camera.fov_y_deg) / 2.0)) / height


def _draw(program: Program, gpu_mesh: GpuMesh, model: np.ndarray) -> None:
    program.set_mat4("u_model", model)
    program.set_mat3("u_normal_matrix", np.linalg.inv(model[:3, :3]).T)
    gpu_mesh.draw()
