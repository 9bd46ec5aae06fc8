"""The layer pass's uniforms and texture units (``shaders/km_layers.frag`` and ``shaders/surface_attributes.frag``):
lights and their shadows, the view, the lobes, the environment light, the mesh's fine detail (normal map, film
thickness, substrate roughness) and the surface attributes the shading reads.

Texture units: tables 0-3, thickness maps 4-7, the precomposed array 8, shadow maps 9-12, the substrate map 13, the
environment's irradiance 14, specular levels 15 and lobe table 16, the shadow maps' raw depths 17-20 (read through a
sampler object that does not compare), the normal map 21, the films' total thickness 22, the substrate's roughness 23,
a floor's occlusion grid 24, the surface attributes 25-28, the soft-shadow pass's targets 29-30.
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
ATTRIBUTE_UNIT = FLOOR_UNIT + 1
#: Targets of the surface attributes (surface_attributes.frag), of the soft-shadow pass (light_visibility.frag) and
#: of its filter (soft_shadow_filter.frag), which the shading pass reads.
ATTRIBUTE_TARGETS = 4
SOFT_PASS_TARGETS = 3
SOFT_TARGETS = 2
SOFT_UNIT = ATTRIBUTE_UNIT + ATTRIBUTE_TARGETS
LAST_UNIT = SOFT_UNIT + SOFT_TARGETS - 1


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
    """The environment's uniforms and textures (units ENV_UNIT ..), for a program with ENVIRONMENT (else nothing)."""
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


def set_fine_detail(program: Program, normal_map: NormalMap | None, textures: Sequence[int]) -> None:
    """The normal map and films' total thickness (units DETAIL_UNIT, DETAIL_UNIT + 1) of the attribute program with
    NORMAL_MAP, or none."""
    GL.glUniform1f(program.location("u_fill_mm"), FILL_MM if normal_map is None else normal_map.fill_mm)
    for offset, name in enumerate(("u_normal_map", "u_film_total")):
        GL.glUniform1i(program.location(name), DETAIL_UNIT + offset)
        GL.glActiveTexture(GL.GL_TEXTURE0 + DETAIL_UNIT + offset)
        GL.glBindTexture(GL.GL_TEXTURE_2D, textures[offset] if normal_map is not None else 0)
    GL.glActiveTexture(GL.GL_TEXTURE0)


def set_roughness(program: Program, textures: Sequence[int]) -> None:
    """The shading program's substrate roughness map (unit DETAIL_UNIT + 2, read with ROUGHNESS_MAP; none where
    ``textures[2]`` is 0) and the films' lobe cover."""
    GL.glUniform1f(program.location("u_lobe_cover_mm"), LOBE_COVER_MM)
    GL.glUniform1i(program.location("u_roughness_map"), DETAIL_UNIT + 2)
    GL.glActiveTexture(GL.GL_TEXTURE0 + DETAIL_UNIT + 2)
    GL.glBindTexture(GL.GL_TEXTURE_2D, textures[2])
    GL.glActiveTexture(GL.GL_TEXTURE0)


def set_lights(program: Program, lights: Sequence[Light]) -> None:
    """The shading program's lights' radiance and a point light's reference distance."""
    radiance = np.zeros((MAX_LIGHTS, 3))
    reference = np.ones(MAX_LIGHTS)
    for index, light in enumerate(lights):
        radiance[index] = light.radiance
        if isinstance(light, PointLight):
            reference[index] = light.reference_distance_mm
    GL.glUniform3fv(program.location("u_light_radiance"), MAX_LIGHTS, radiance.astype(np.float32))
    GL.glUniform1fv(program.location("u_light_reference"), MAX_LIGHTS, reference.astype(np.float32))


def set_shadow_lookup(
    program: Program, lights: Sequence[Light], shadow_matrices: np.ndarray, ranges: np.ndarray, texel_mm: float
) -> None:
    """The uniforms of ``shaders/shadow_lookup.glsl``: where the lights are, their shadow maps' frusta (``ranges``:
    near and far, mm) and matrices, a texel's size (mm) and the area lights' sizes (their kinds are compiled in:
    :func:`light_switches`)."""
    vectors = np.zeros((MAX_LIGHTS, 3))
    softness = np.zeros(MAX_LIGHTS)
    for index, light in enumerate(lights):
        softness[index] = light.softness
        vectors[index] = light.position if isinstance(light, PointLight) else light.to_light()
    GL.glUniform3fv(program.location("u_light_vector"), MAX_LIGHTS, vectors.astype(np.float32))
    GL.glUniform1fv(program.location("u_light_softness"), MAX_LIGHTS, softness.astype(np.float32))
    GL.glUniform2fv(program.location("u_shadow_range"), MAX_LIGHTS, ranges.astype(np.float32))
    GL.glUniform1fv(program.location("u_shadow_texel"), MAX_LIGHTS, np.full(MAX_LIGHTS, texel_mm, np.float32))
    GL.glUniformMatrix4fv(
        program.location("u_shadow_matrix"), MAX_LIGHTS, GL.GL_TRUE, shadow_matrices.astype(np.float32)
    )


def light_switches(lights: Sequence[Light]) -> dict[str, int]:
    """The shading program's LIGHT_COUNT and bit masks of the lights that are points (POINT_LIGHTS), that look their
    shadow map up (SHADOW_LIGHTS) and whose shadows are soft (SOFT_LIGHTS: an area light casting shadows)."""
    masks = {"POINT_LIGHTS": 0, "SHADOW_LIGHTS": 0, "SOFT_LIGHTS": 0}
    for index, light in enumerate(lights):
        masks["POINT_LIGHTS"] |= int(isinstance(light, PointLight)) << index
        masks["SHADOW_LIGHTS"] |= int(light.cast_shadows) << index
        masks["SOFT_LIGHTS"] |= int(light.cast_shadows and light.softness > 0.0) << index
    return {"LIGHT_COUNT": len(lights), **masks}


def set_view(program: Program, camera: Camera) -> None:
    """The view direction: constant (towards the camera) for an orthographic camera (ORTHOGRAPHIC), else from the eye
    position."""
    if isinstance(camera, OrthographicCamera):
        program.set_vec3("u_view_vector", np.linalg.inv(camera.view_matrix())[:3, 2])
    else:
        program.set_vec3("u_view_vector", camera.eye)


def set_specular(program: Program, lobes: Sequence[Specular | None]) -> None:
    """Lobes of the films bottom-up (slots 0 .. MAX_LAYERS - 1) and of the substrate (slot MAX_LAYERS); which are on is
    compiled in (:func:`lobe_switch`)."""
    slots = MAX_LAYERS + 1
    roughness = np.ones(slots)
    f0 = np.zeros(slots)
    for index, lobe in enumerate(lobes):
        if lobe is not None:
            roughness[index], f0[index] = lobe.roughness, lobe.f0
    GL.glUniform1fv(program.location("u_roughness"), slots, roughness.astype(np.float32))
    GL.glUniform1fv(program.location("u_f0"), slots, f0.astype(np.float32))


def lobe_switch(lobes: Sequence[Specular | None]) -> dict[str, int]:
    """The shading program's LOBES: bit k set where slot k (:func:`set_specular`) has a lobe."""
    return {"LOBES": sum(1 << index for index, lobe in enumerate(lobes) if lobe is not None)}


def set_floor(program: Program, floor: FloorOcclusion | None, frame: np.ndarray | None) -> None:
    """A floor's baked occlusion grid (unit FLOOR_UNIT) and its place (``frame``: world -> the grid's frame, identity
    if None), for a program with FLOOR; or none."""
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


def set_attributes(program: Program, textures: Sequence[int], samples: int, read: Sequence[int] = (0, 1, 2, 3)) -> None:
    """The surface attributes' targets (units ATTRIBUTE_UNIT ..), multisample textures where ``samples`` > 1; the
    program reads the targets ``read``."""
    kind = GL.GL_TEXTURE_2D_MULTISAMPLE if samples > 1 else GL.GL_TEXTURE_2D
    for index, texture in enumerate(textures):
        if index in read:
            GL.glUniform1i(program.location(f"u_attributes{index}"), ATTRIBUTE_UNIT + index)
        GL.glActiveTexture(GL.GL_TEXTURE0 + ATTRIBUTE_UNIT + index)
        GL.glBindTexture(kind, texture)
    GL.glActiveTexture(GL.GL_TEXTURE0)


def set_soft_shadows(program: Program, textures: Sequence[int]) -> None:
    """The soft-shadow pass's targets (units SOFT_UNIT ..) for the shading program to upsample."""
    for index, (name, texture) in enumerate(zip(("u_soft_visibility", "u_soft_plane"), textures, strict=True)):
        GL.glUniform1i(program.location(name), SOFT_UNIT + index)
        GL.glActiveTexture(GL.GL_TEXTURE0 + SOFT_UNIT + index)
        GL.glBindTexture(GL.GL_TEXTURE_2D, texture)
    GL.glActiveTexture(GL.GL_TEXTURE0)
