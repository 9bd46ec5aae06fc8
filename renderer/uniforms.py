"""The layer program's uniforms and texture units (``shaders/km_layers.frag``): lights and their shadows, the view, the
lobes, the environment light and the mesh's fine detail (normal map, film thickness, substrate roughness).

Texture units: tables 0-3, thickness maps 4-7, the precomposed array 8, shadow maps 9-12, the substrate map 13, the
environment's irradiance 14, specular levels 15 and lobe table 16, the shadow maps' raw depths 17-20 (read through a
sampler object that does not compare), the normal map 21, the films' total thickness 22, the substrate's roughness 23,
a floor's occlusion grid 24, the samples' depth bounds of renderer.visible_depth 25.
Every sampler has a unit of its own (GL forbids samplers of different types on one unit, even unused ones).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from renderer.context import GL
from renderer.environment import LOBE_M_RANGE, SPECULAR_LEVELS, lobe_albedo, prefiltered
from renderer.occlusion import FLOOR_EDGE, FloorOcclusion
from renderer.program import Program
from renderer.scene import FILL_MM, MAX_LIGHTS, Camera, Light, NormalMap, OrthographicCamera, PointLight
from renderer.stack import LOBE_COVER_MM, MAX_LAYERS, Specular
from renderer.textures import array_texture, float_texture, map_texels

COMPOSITE_UNIT = 2 * MAX_LAYERS
SHADOW_UNIT = COMPOSITE_UNIT + 1
SUBSTRATE_UNIT = SHADOW_UNIT + MAX_LIGHTS
ENV_UNIT = SUBSTRATE_UNIT + 1
SHADOW_DEPTH_UNIT = ENV_UNIT + 3
DETAIL_UNIT = SHADOW_DEPTH_UNIT + MAX_LIGHTS
FLOOR_UNIT = DETAIL_UNIT + 3
VISIBLE_UNIT = FLOOR_UNIT + 1
LAST_UNIT = VISIBLE_UNIT


def environment_textures(environment) -> list[int]:
    """Upload the environment's prefiltered irradiance, specular levels and the lobe albedo table (three textures)."""
    maps = prefiltered(environment)

    def texels(image: np.ndarray) -> np.ndarray:
        out = np.zeros((*image.shape[:-1], 4), dtype=np.float32)
        out[..., : image.shape[-1]] = image
        return out

    irradiance = float_texture(texels(maps.irradiance[::-1]), linear=True, wrap_s=True)
    specular = array_texture(texels(maps.specular[:, ::-1]), wrap_s=True)
    lobe = float_texture(texels(lobe_albedo()), linear=True)
    return [irradiance, specular, lobe]


def set_environment(program: Program, environment, textures: Sequence[int]) -> None:
    """The environment's uniforms and textures (units ENV_UNIT ..), or u_env_on = 0."""
    GL.glUniform1i(program.location("u_env_on"), int(environment is not None))
    for offset, name in enumerate(("u_env_irradiance", "u_env_specular", "u_env_lobe")):
        GL.glUniform1i(program.location(name), ENV_UNIT + offset)
    if environment is None:
        return
    levels = np.zeros(8, dtype=np.float32)
    levels[: len(SPECULAR_LEVELS)] = [m for m, _ in SPECULAR_LEVELS]
    GL.glUniform1i(program.location("u_env_level_count"), len(SPECULAR_LEVELS))
    GL.glUniform1fv(program.location("u_env_level_m"), 8, levels)
    GL.glUniform2f(program.location("u_env_lobe_range"), *np.sqrt(LOBE_M_RANGE))
    GL.glUniform1f(program.location("u_env_intensity"), environment.intensity)
    program.set_mat3("u_env_rotation", environment.world_to_environment())
    for offset, (target, texture) in enumerate(
        zip((GL.GL_TEXTURE_2D, GL.GL_TEXTURE_2D_ARRAY, GL.GL_TEXTURE_2D), textures, strict=True)
    ):
        GL.glActiveTexture(GL.GL_TEXTURE0 + ENV_UNIT + offset)
        GL.glBindTexture(target, texture)
    GL.glActiveTexture(GL.GL_TEXTURE0)  # textures created later bind to unit 0, which the stack rebinds


def detail_textures(normal_map: NormalMap | None, roughness: np.ndarray | None) -> list[int]:
    """The normal map, the films' total thickness and the substrate's roughness as textures (0 where absent)."""
    textures = [0, 0, 0]
    if normal_map is not None:
        film = np.asarray(normal_map.film_thickness_mm, dtype=float)
        textures[0] = float_texture(map_texels(normal_map.normals), linear=True)
        textures[1] = float_texture(map_texels(film if film.ndim == 2 else np.full((1, 1), film)), linear=True)
    if roughness is not None:
        m = np.asarray(roughness, dtype=float)
        if m.ndim != 2 or not (np.all(np.isfinite(m)) and 0.0 < m.min() and m.max() <= 2.0):
            raise ValueError("the substrate's roughness map must be a 2-D map of Beckmann m in (0, 2]")
        textures[2] = float_texture(map_texels(m), linear=True)
    return textures


def set_detail(program: Program, normal_map: NormalMap | None, textures: Sequence[int]) -> None:
    """Uniforms and textures of the mesh's fine detail and the substrate's roughness map (units DETAIL_UNIT ..)."""
    GL.glUniform1i(program.location("u_use_normal_map"), int(normal_map is not None))
    GL.glUniform1i(program.location("u_use_roughness_map"), int(textures[2] != 0))
    GL.glUniform1f(program.location("u_fill_mm"), FILL_MM if normal_map is None else normal_map.fill_mm)
    GL.glUniform1f(program.location("u_lobe_cover_mm"), LOBE_COVER_MM)
    for offset, (name, texture) in enumerate(zip(("u_normal_map", "u_film_total", "u_roughness_map"), textures,
                                                 strict=True)):  # fmt: skip
        GL.glUniform1i(program.location(name), DETAIL_UNIT + offset)
        GL.glActiveTexture(GL.GL_TEXTURE0 + DETAIL_UNIT + offset)
        GL.glBindTexture(GL.GL_TEXTURE_2D, texture)
    GL.glActiveTexture(GL.GL_TEXTURE0)


def set_lights(
    program: Program,
    lights: Sequence[Light],
    casts: np.ndarray,
    shadow_matrices: np.ndarray,
    ranges: np.ndarray,
    soft_shadows: bool,
) -> None:
    """The lights' uniforms; the areas' sizes and the shadow frusta's ranges only in the soft-shadow program."""
    is_point = np.zeros(MAX_LIGHTS, dtype=np.int32)
    vectors = np.zeros((MAX_LIGHTS, 3))
    radiance = np.zeros((MAX_LIGHTS, 3))
    reference = np.ones(MAX_LIGHTS)
    softness = np.zeros(MAX_LIGHTS)
    for index, light in enumerate(lights):
        radiance[index] = light.radiance
        softness[index] = light.softness
        if isinstance(light, PointLight):
            is_point[index], vectors[index], reference[index] = 1, light.position, light.reference_distance_mm
        else:
            vectors[index] = light.to_light()
    GL.glUniform1iv(program.location("u_light_is_point"), MAX_LIGHTS, is_point)
    GL.glUniform3fv(program.location("u_light_vector"), MAX_LIGHTS, vectors.astype(np.float32))
    GL.glUniform3fv(program.location("u_light_radiance"), MAX_LIGHTS, radiance.astype(np.float32))
    GL.glUniform1fv(program.location("u_light_reference"), MAX_LIGHTS, reference.astype(np.float32))
    GL.glUniform1iv(program.location("u_light_shadow"), MAX_LIGHTS, casts)
    if soft_shadows:
        GL.glUniform1fv(program.location("u_light_softness"), MAX_LIGHTS, softness.astype(np.float32))
        GL.glUniform2fv(program.location("u_shadow_range"), MAX_LIGHTS, ranges.astype(np.float32))
    GL.glUniformMatrix4fv(
        program.location("u_shadow_matrix"), MAX_LIGHTS, GL.GL_TRUE, shadow_matrices.astype(np.float32)
    )


def set_view(program: Program, camera: Camera) -> None:
    """The view direction: constant (towards the camera) for an orthographic camera, else from the eye position."""
    orthographic = isinstance(camera, OrthographicCamera)
    GL.glUniform1i(program.location("u_orthographic"), int(orthographic))
    if orthographic:
        program.set_vec3("u_view_vector", np.linalg.inv(camera.view_matrix())[:3, 2])
    else:
        program.set_vec3("u_view_vector", camera.eye)


def set_specular(program: Program, lobes: Sequence[Specular | None]) -> None:
    """Lobes of the films bottom-up (slots 0 .. MAX_LAYERS - 1) and of the substrate (slot MAX_LAYERS)."""
    slots = MAX_LAYERS + 1
    on = np.zeros(slots, dtype=np.int32)
    roughness = np.ones(slots)
    f0 = np.zeros(slots)
    for index, lobe in enumerate(lobes):
        if lobe is not None:
            on[index], roughness[index], f0[index] = 1, lobe.roughness, lobe.f0
    GL.glUniform1i(program.location("u_any_specular"), int(on.any()))
    GL.glUniform1iv(program.location("u_specular_on"), slots, on)
    GL.glUniform1fv(program.location("u_roughness"), slots, roughness.astype(np.float32))
    GL.glUniform1fv(program.location("u_f0"), slots, f0.astype(np.float32))


def set_floor(program: Program, floor: FloorOcclusion | None, frame: np.ndarray | None) -> None:
    """A floor's baked occlusion grid (unit FLOOR_UNIT) and its place (``frame``: world -> the grid's frame, identity
    if None), or u_floor_on = 0."""
    GL.glUniform1i(program.location("u_floor_on"), int(floor is not None))
    GL.glUniform1i(program.location("u_floor"), FLOOR_UNIT)
    texture = 0
    if floor is not None:
        values = np.asarray(floor.values, dtype=float)
        # one channel; texel row i: z_i (no flip: the grid's rows run along +z as t does)
        texture = float_texture(values.astype(np.float32)[..., None], linear=True)
        program.set_mat4("u_floor_frame", np.eye(4) if frame is None else np.asarray(frame, dtype=float))
        GL.glUniform4f(program.location("u_floor_grid"), *floor.centre, floor.extent, values.shape[0])
        GL.glUniform3f(program.location("u_floor_fade"), floor.floor_y, floor.fade_mm, FLOOR_EDGE)
    GL.glActiveTexture(GL.GL_TEXTURE0 + FLOOR_UNIT)
    GL.glBindTexture(GL.GL_TEXTURE_2D, texture)
    GL.glActiveTexture(GL.GL_TEXTURE0)


def set_visible(program: Program, bounds: int, samples: int) -> None:
    """The samples' depth bounds of :func:`renderer.visible_depth.bounds` (unit VISIBLE_UNIT), or none (0): then
    every fragment is shaded."""
    GL.glUniform1i(program.location("u_visible_on"), int(bounds != 0))
    GL.glUniform1i(program.location("u_visible_depth"), VISIBLE_UNIT)
    GL.glUniform1i(program.location("u_visible_samples"), samples)
    GL.glActiveTexture(GL.GL_TEXTURE0 + VISIBLE_UNIT)
    GL.glBindTexture(GL.GL_TEXTURE_2D_MULTISAMPLE, bounds)
    GL.glActiveTexture(GL.GL_TEXTURE0)
