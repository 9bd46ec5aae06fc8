"""``kmpipe render``: a scene file (:mod:`kmpipe.scene`) to linear EXR and sRGB PNG frames.

The materials' planned optical tables (:func:`kmpipe.render_plan.plan_render` on the scene's one stack, each
material at its single thickness) feed the renderer's Kubelka-Munk layer pass (:mod:`renderer.layers`). The layer
pass composes at most :data:`renderer.layers.MAX_CHANNELS` channels: a planned mode with more (``exact``, or
``bands:N`` with N larger) is replaced by ``bands:M``, M = min(number of wavelengths, MAX_CHANNELS); with M equal to
the number of wavelengths every band is one wavelength, which is the exact spectral composition. When M is smaller
and the accuracy target is not met, the scene is refused.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from kmpipe.errors import InputError
from kmpipe.optical_tables import OpticalTable, Stack, parse_mode
from kmpipe.render_plan import RenderPlan, plan_render
from kmpipe.scene import Scene, load_scene


def _channels(mode: str, n_wavelengths: int) -> int:
    kind, n_bands = parse_mode(mode)
    return {"rgb": 3, "bands": n_bands, "exact": n_wavelengths}[kind]


def plan_scene(scene: Scene) -> tuple[RenderPlan, str | None]:
    """The render plan of the scene, in a mode the layer pass can render, and a note when the mode was replaced."""
    from renderer.layers import MAX_CHANNELS

    materials = {m.name: m for m in scene.materials}
    ranges: dict[str, tuple[float, float]] = {}
    for material, thickness in zip(scene.materials, scene.thicknesses_mm, strict=True):
        lo, hi = ranges.get(material.name, (thickness, thickness))
        ranges[material.name] = (min(lo, thickness), max(hi, thickness))
    stacks = [Stack(scene.name, tuple(m.name for m in scene.materials), scene.substrate_reflectance())]
    settings = scene.info.scene
    plan = plan_render(materials, stacks, ranges, settings.illuminant, settings.accuracy, settings.mode)
    n_wavelengths = len(scene.wavelengths)
    if _channels(plan.mode, n_wavelengths) <= MAX_CHANNELS:
        return plan, None
    replacement = f"bands:{min(n_wavelengths, MAX_CHANNELS)}"
    forced = plan_render(materials, stacks, ranges, settings.illuminant, plan.target_dE, replacement)
    error = forced.candidates[-1].max_dE
    if error > forced.target_dE:
        raise InputError(
            f"the planned mode {plan.mode} has more channels than the layer pass renders ({MAX_CHANNELS}); "
            f"{replacement} misses the accuracy target (Delta E 2000 {error:.3f} > {forced.target_dE:g}): "
            "raise scene.accuracy or set scene.mode",
            path=scene.path,
            field="scene.accuracy",
        )
    note = (
        f"planned mode {plan.mode} has more than {MAX_CHANNELS} channels (the layer pass's limit): "
        f"rendering in {replacement} (max Delta E 2000 {error:.3f} against exact)"
    )
    return forced, note


def layer_inputs(plan: RenderPlan, scene: Scene):
    """The layer pass's inputs: LayerTables (top first), substrate per channel and to_rgb (None in rgb mode)."""
    from renderer.layers import LayerTable

    tables: dict[str, OpticalTable] = plan.build_tables({m.name: m for m in scene.materials})
    first = tables[scene.materials[0].name]
    kind, _ = parse_mode(plan.mode)
    substrate = scene.substrate_reflectance()
    if kind == "rgb":
        substrate_channels, to_rgb = np.clip(substrate @ first.space.matrix, 0.0, 1.0), None
    else:  # bands (exact never reaches here: plan_scene replaces it)
        substrate_channels, to_rgb = substrate @ first.bands.averaging, first.bands.to_rgb
    layer_tables = []
    for material in scene.materials:
        table = tables[material.name]
        x = table.single_thickness_mm if table.thickness_mm is None else table.thickness_mm
        layer_tables.append(LayerTable(x, np.clip(table.R0, 0.0, 1.0), np.clip(table.T, 0.0, 1.0)))
    return layer_tables, np.clip(substrate_channels, 0.0, 1.0), to_rgb


def camera_for(scene: Scene, azimuth_deg: float):
    """The scene's camera at ``azimuth_deg``, looking at the centre of the (placed) mesh."""
    from renderer.scene import OrthographicCamera, PerspectiveCamera

    vertices = np.asarray(scene.mesh.vertices) @ scene.model[:3, :3].T + scene.model[:3, 3]
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    radius = float(np.max(np.linalg.norm(vertices - centre, axis=1)))
    info = scene.info.camera
    azimuth, elevation = math.radians(azimuth_deg), math.radians(info.elevation_deg)
    direction = np.array(
        [math.cos(elevation) * math.sin(azimuth), math.sin(elevation), math.cos(elevation) * math.cos(azimuth)]
    )
    eye = tuple(centre + info.distance_mm * direction)
    near = max(info.distance_mm - 2.0 * radius, 1e-3 * info.distance_mm)
    far = info.distance_mm + 2.0 * radius
    if info.projection == "orthographic":
        return OrthographicCamera(1.1 * radius, eye=eye, target=tuple(centre), near=near, far=far)
    return PerspectiveCamera(info.fov_deg, eye=eye, target=tuple(centre), near=near, far=far)


def render_scene(
    scene_path: str | Path,
    out_dir: str | Path,
    *,
    explain: bool = False,
    echo: Callable[[str], None] = print,
    on_frame: Callable[[int, int], None] | None = None,
) -> list[Path]:
    """Render every frame of a scene file into ``out_dir`` as ``frame_NNN.exr`` (linear, float) and ``.png`` (sRGB).

    ``explain`` passes the render plan's text to ``echo``; ``on_frame(i, n)`` is called after frame i of n.
    Returns the files written, EXR and PNG of each frame in order.
    """
    from renderer.image_io import write_exr, write_png
    from renderer.layers import render_layers
    from renderer.scene import DirectionalLight

    scene = load_scene(scene_path)
    plan, note = plan_scene(scene)
    if explain:
        echo(plan.explain())
        if note:
            echo(note)
    layer_tables, substrate, to_rgb = layer_inputs(plan, scene)
    info = scene.info
    light = DirectionalLight(tuple(-np.asarray(info.light.direction, dtype=float)), info.light.radiance)
    width, height = info.scene.resolution
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    header = {
        "scene": scene.name,
        "materials": ", ".join(m.name for m in scene.materials),
        "thicknesses_mm": ", ".join(f"{x:g}" for x in scene.thicknesses_mm),
        "render_mode": plan.mode,
        "illuminant": info.scene.illuminant,
        "camera_elevation_deg": float(info.camera.elevation_deg),
    }
    written = []
    azimuths = scene.frame_azimuths_deg()
    for i, azimuth in enumerate(azimuths):
        image = render_layers(
            scene.mesh,
            camera_for(scene, azimuth),
            light,
            layer_tables,
            list(scene.thicknesses_mm),
            substrate,
            width,
            height,
            to_rgb=to_rgb,
            model=scene.model,
        )
        exr, png = out_dir / f"frame_{i:03d}.exr", out_dir / f"frame_{i:03d}.png"
        write_exr(exr, image, {**header, "camera_azimuth_deg": float(azimuth), "frame": i}, half=False)
        write_png(png, image)
        written += [exr, png]
        if on_frame is not None:
            on_frame(i + 1, len(azimuths))
    return written
