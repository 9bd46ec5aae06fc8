"""The lines ``kmpipe render --explain`` prints about a scene's per-frame work beyond its tables (what
:func:`kmpipe.stages.render_plan.plan_scene` decided and why): backdrop, fine detail, environment light
and ambient occlusion, the skin's lobe and scattering."""

from __future__ import annotations

from kmpipe.formats.scene import Scene
from kmpipe.formats.scene_lighting import FLOOR_EXTENT
from renderer.occlusion import FLOOR_CELLS, FLOOR_DIRECTIONS
from renderer.scene import Scattering
from renderer.stack import Specular


def detail_note(scene: Scene) -> str:
    """The mesh's fine detail and the skin lobe's roughness map, or that there are none."""
    if scene.normal_map is None:
        detail = "fine detail: none (no normal map)"
    else:
        rows, columns = scene.normal_map.shape[:2]
        detail = (f"fine detail: a {columns} x {rows} tangent-space normal map, smoothed under the films by "
                  f"exp(-thickness / {scene.info.base.normal_fill})")  # fmt: skip
    if scene.roughness is not None:
        detail += f"; the skin lobe's roughness from a map ({scene.roughness.min():.2f} to {scene.roughness.max():.2f})"
    return detail


def backdrop_note(scene: Scene) -> str:
    backdrop = scene.info.backdrop
    if backdrop is None:
        return "backdrop: " + ("none (a ground under the product, black behind it)" if scene.info.ground is not None
                               else "none (no ground; black behind the product)")  # fmt: skip
    if backdrop.kind == "sweep":
        return "backdrop: a seamless sweep (floor curving into a wall behind the product), shadows fall on it"
    return "backdrop: a vertical gradient behind the product (no floor)"


def environment_notes(scene: Scene, self_shadowing: bool, floor: str | None) -> list[str]:
    """The environment light and its ambient occlusion (the mesh's; the ``floor``'s, "ground" or "backdrop sweep",
    where there is one), or why there is none."""
    from renderer.environment import IRRADIANCE_SIZE, SPECULAR_LEVELS

    info = scene.info.environment
    if info is None:
        return ["environment light: none (no [environment]) -> no image-based pass, no ambient occlusion"]
    source = info.file or "the built-in studio (softboxes over a neutral dome)"
    notes = [
        f"environment light: {source}, rotated {info.rotation_deg:g} deg, intensity {info.intensity:g}; diffuse from "
        f"its irradiance ({IRRADIANCE_SIZE[0]} x {IRRADIANCE_SIZE[1]} map), lobes from {len(SPECULAR_LEVELS)} "
        f"prefiltered levels{'; shown behind the product' if info.visible else ''}"
    ]
    if self_shadowing:
        notes.append("ambient occlusion: baked per vertex (96 directions): the mesh can hide itself from the sky")
    else:
        notes.append(f"ambient occlusion: none (the {scene.info.scene.mesh} mesh is flat or convex)")
    if floor is not None:
        notes.append(f"the {floor}'s ambient occlusion: baked once on a {FLOOR_CELLS} x {FLOOR_CELLS} grid "
                     f"{FLOOR_EXTENT:g} radii each way under the product ({FLOOR_DIRECTIONS} directions), turned "
                     "with it each frame: the product hides the floor around it from the sky")  # fmt: skip
    return notes


def skin_notes(scene: Scene, lobe: Specular | None, scattering: Scattering | None) -> list[str]:
    skin = scene.info.skin
    if skin is None:
        return ["skin: none (the films lie on a substrate; no subsurface scattering)"]
    notes = [
        f"skin: {skin.reflectance}; its own lobe "
        + ("none" if lobe is None else f"roughness {lobe.roughness:g}, F0 {lobe.f0:.3f}")
    ]
    if skin.albedo_texture is not None:
        notes.append(f"albedo texture: {skin.albedo_texture} (spectra per texel from the skin's; modes planned on it)")
    if scattering is None:
        notes.append("subsurface scattering: off (the skin's light is not blurred)")
    else:
        notes.append(
            f"subsurface scattering: 4 Gaussians x 2 separable 7-tap passes on skin pixels, alpha {scattering.alpha:g} "
            f"(1 = the measured profile at true scale), beta {scattering.beta:g}, clamp {scattering.gradient_clamp:g}"
        )
    return notes
