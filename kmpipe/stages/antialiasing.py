"""How a scene's frames are antialiased (``[output] antialias`` and ``antialias_method``), as the planner decides.

``antialias = k`` asks for k x k samples a pixel. Two ways to take them:

- multisampling (:mod:`renderer.multisample`): k^2 coverage samples a pixel, shaded once a pixel and surface. It
  antialiases silhouettes and every edge between surfaces for about the cost of one shaded sample a pixel, but not
  what varies inside a triangle; here it stops at 4 samples (k = 2).
- supersampling (:func:`renderer.scene.supersampled`): the frame rendered k times larger and box-filtered, every
  sample shaded: it also averages the shading's own detail (and the soft shadows' per-pixel sampling noise), at about
  k^2 the cost.

Both keep a region of one value exactly that value. With ``antialias_method = "auto"`` (the default) the planner
multisamples unless the shading varies faster than the pixels: a map over the mesh's uv (albedo texture, normal map,
roughness map, occlusion map, thickness map) whose texels are smaller than a pixel on the product, where one shaded
sample a pixel would alias, or more than 4 samples asked for. A map of w x h texels over a mesh of surface area A
(mm^2, as placed) and uv area a has texels of sqrt(A / (a w h)) mm; a pixel's size is
:func:`kmpipe.stages.framing.pixel_mm`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
import trimesh

from kmpipe.formats.scene import Scene
from kmpipe.stages.framing import pixel_mm

#: Most samples a pixel multisampling takes (what OpenGL guarantees for float targets).
MULTISAMPLE_LIMIT = 4

Method = Literal["none", "multisample", "supersample"]


@dataclass(frozen=True)
class Antialiasing:
    """The planned antialiasing: how the ``[output] antialias`` samples are taken, and the plan's note on it."""

    method: Method
    note: str


def renderer_fields(method: str, side: int) -> dict[str, int]:
    """``supersampling`` and ``multisamples`` of a :class:`renderer.scene.Scene` taking side x side samples a pixel
    by ``method``."""
    return {"supersampling": side if method == "supersample" else 1,
            "multisamples": side * side if method == "multisample" else 1}  # fmt: skip


def describe(method: str, side: int) -> str:
    """A frame header's words for the antialiasing: "4 x multisampling", "2 x 2 supersampling" or "none"."""
    if method == "multisample":
        return f"{side * side} x multisampling"
    return "none" if method == "none" else f"{side} x {side} supersampling"


def uv_texel_mm(mesh: trimesh.Trimesh, model: np.ndarray, shape: tuple[int, int]) -> float | None:
    """Mean size (mm) of a texel of a (rows, columns) map over the mesh's uv as placed by ``model``; None when the mesh
    has no uv or its uv covers no area."""
    uv = getattr(mesh.visual, "uv", None)
    if uv is None or len(uv) != len(mesh.vertices):
        return None
    faces = np.asarray(mesh.faces)
    placed = np.asarray(mesh.vertices, dtype=float) @ np.asarray(model, dtype=float)[:3, :3].T
    area = float(trimesh.triangles.area(placed[faces]).sum())
    corners = np.asarray(uv, dtype=float)[faces]
    edges = corners[:, 1:] - corners[:, :1]
    uv_area = float(0.5 * np.abs(edges[:, 0, 0] * edges[:, 1, 1] - edges[:, 0, 1] * edges[:, 1, 0]).sum())
    if uv_area <= 0.0 or area <= 0.0:
        return None
    return math.sqrt(area / (uv_area * shape[0] * shape[1]))


def _maps(scene: Scene) -> list[tuple[str, tuple[int, int]]]:
    """(name, (rows, columns)) of every map the scene lays over the mesh's uv."""
    maps = [(name, np.shape(value)[:2]) for name, value in (
        ("albedo texture", scene.albedo), ("normal map", scene.normal_map), ("roughness map", scene.roughness),
        ("occlusion map", scene.occlusion_map)) if value is not None]  # fmt: skip
    maps += [(f"layer {i + 1}'s thickness map", np.shape(x)[:2]) for i, x in enumerate(scene.thicknesses_mm)
             if np.ndim(x) == 2]  # fmt: skip
    return maps


def plan_antialiasing(scene: Scene, radius_mm: float) -> Antialiasing:
    """The scene's antialiasing and why (module docstring); ``radius_mm`` the placed product's bounding radius."""
    output = scene.info.output
    side, asked = output.antialias, output.antialias_method
    if side == 1:
        return Antialiasing("none", "antialiasing: none (antialias = 1: one sample per pixel, silhouettes are "
                                       "stair-stepped)")  # fmt: skip
    samples = side * side
    default = "" if "antialias" in output.model_fields_set else ", the default"
    multisample = (f"antialiasing: {samples} x multisampling (antialias = {side}{default}: {samples} coverage samples "
                   "a pixel shaded once a pixel, so silhouettes get partial coverage for about the cost of one sample; "
                   "flat regions keep their exact values)")  # fmt: skip
    width, height = scene.info.resolution
    supersample = (f"antialiasing: {side} x {side} supersampling (antialias = {side}{default}: {samples} shaded "
                   f"samples a pixel, rendered at {width * side} x {height * side} and box-filtered; flat regions "
                   "keep their exact values)")  # fmt: skip
    if asked == "multisample":
        return Antialiasing("multisample", multisample + " -- as the scene asks (antialias_method)")
    if asked == "supersample":
        return Antialiasing("supersample", supersample + " -- as the scene asks (antialias_method)")
    if samples > MULTISAMPLE_LIMIT:
        return Antialiasing("supersample", f"{supersample} -- multisampling stops at {MULTISAMPLE_LIMIT} "
                                                 "samples a pixel")  # fmt: skip
    pixel = pixel_mm(scene.info.camera, radius_mm, height)
    texels = [(uv_texel_mm(scene.mesh, scene.model, shape), name) for name, shape in _maps(scene)]
    texels = [(size, name) for size, name in texels if size is not None]
    if texels:
        finest, name = min(texels)
        if finest < pixel:
            return Antialiasing("supersample", f"{supersample} -- the {name}'s texels ({finest:.2g} mm) are "
                                                     f"finer than a pixel ({pixel:.2g} mm on the product): shading "
                                                     "once a pixel would alias them")  # fmt: skip
        why = (f"the finest map (the {name}, {finest:.2g} mm a texel) is coarser than a pixel ({pixel:.2g} mm on the "
               "product), so one shaded sample a pixel does not alias it")  # fmt: skip
    else:
        why = "no map varies the shading inside a triangle"
    if any(light.shadows and (light.angle_deg or light.size_mm) for light in scene.info.light):
        why += "; the soft shadows' per-pixel sampling noise is left as it is (supersampling would average it)"
    return Antialiasing("multisample", f"{multisample} -- {why}")
