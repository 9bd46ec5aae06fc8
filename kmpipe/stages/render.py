"""``kmpipe render``: a scene file (:mod:`kmpipe.formats.scene`) to linear EXR and sRGB PNG frames.

The materials' planned optical tables (:func:`kmpipe.stages.render_plan.plan_render` on the scene's one stack, each
material over the thickness range the scene gives it) feed the renderer's Kubelka-Munk layer pass
(:mod:`renderer.layers`). In the ``rgb`` and ``bands:N`` modes the shader composes the films per channel from the
tables (at most :data:`renderer.layers.MAX_CHANNELS` bands, so the planner tries no more); in ``exact`` mode the stack
is composed here, per wavelength, once for each distinct combination of thicknesses in the scene (one for uniform
films; one per distinct texel of the thickness maps), and the shader reads the result.

The scene also decides what else a frame needs (:class:`ScenePlan`): a shadow map for each light that casts shadows,
unless nothing in the scene can shadow anything (a flat or convex product without a ground); the size of the maps;
a ground under the product.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.albedo_texture import basis_spectra, texture_weights
from kmpipe.formats.scene import Scene, load_scene
from kmpipe.physics.optical_tables import Stack, exact_stack, parse_mode, working_space
from kmpipe.stages.render_plan import RenderPlan, plan_render

#: Texels of a shadow map per pixel of the longer image side, and the bounds of the map's size.
SHADOW_TEXELS_PER_PIXEL = 2
SHADOW_MAP_SIZES = (512, 4096)
#: Ground half-size in radii of the product's bounding sphere.
GROUND_EXTENT = 4.0
#: Share of the image height the product's bounding sphere fills when the scene gives no camera distance.
FRAME_FILL = 0.8


@dataclass(frozen=True)
class ScenePlan:
    """The render plan of the optical tables plus the scene-level choices: shadows, their maps, the ground."""

    tables: RenderPlan
    shadow_map_size: int | None
    shadow_lights: tuple[bool, ...]
    notes: tuple[str, ...] = field(default=())

    @property
    def mode(self) -> str:
        return self.tables.mode

    def explain(self) -> str:
        lines = [self.tables.explain(), "Scene:"]
        lines += [f"  {note}" for note in self.notes]
        return "\n".join(lines)


def can_shadow_itself(mesh: trimesh.Trimesh) -> bool:
    """Whether some part of the mesh can hide another from a light: False for a flat or a closed convex mesh."""
    vertices = np.asarray(mesh.vertices, dtype=float)
    centred = vertices - vertices.mean(axis=0)
    extent = float(np.ptp(vertices, axis=0).max())
    flat = np.linalg.svd(centred, compute_uv=False)[-1] <= 1e-9 * max(extent, 1e-300) * math.sqrt(len(vertices))
    if flat:
        return False
    welded = trimesh.Trimesh(vertices, np.asarray(mesh.faces), process=True)  # seams duplicated for uv: merged
    return not (welded.is_watertight and welded.is_convex)


def plan_scene(scene: Scene) -> ScenePlan:
    """The scene's render plan: mode and tables, then shadows and the other per-frame work.

    A point light inside the product's bounding sphere is refused here (InputError naming its position).
    """
    from renderer.layers import MAX_CHANNELS

    materials = {m.name: m for m in scene.materials}
    ranges: dict[str, tuple[float, float]] = {}
    for index, material in enumerate(scene.materials):
        lo, hi = scene.thickness_range_mm(index)
        old = ranges.get(material.name, (lo, hi))
        ranges[material.name] = (min(old[0], lo), max(old[1], hi))
    stacks = [Stack(scene.name, tuple(m.name for m in scene.materials), scene.substrate_reflectance())]
    settings = scene.info.scene
    tables = plan_render(
        materials, stacks, ranges, settings.illuminant, settings.accuracy, settings.mode, max_bands=MAX_CHANNELS
    )
    kind, _ = parse_mode(tables.mode)
    notes = []
    if kind == "exact":
        notes.append(
            f"exact: the stack is composed per wavelength ({len(scene.wavelengths)} of them) at each distinct "
            "combination of thicknesses in the scene; no tables reach the shader"
        )
    lights = scene.info.light
    wanted = [light.shadows for light in lights]
    self_shadowing = can_shadow_itself(scene.mesh)
    size = None
    if not any(wanted):
        notes.append("shadow maps: no light casts shadows -> none made")
    elif not (self_shadowing or scene.info.ground is not None):
        notes.append(
            f"shadow maps: the {scene.info.scene.mesh} mesh is flat or convex and there is no ground, so nothing "
            "can shadow anything -> none made"
        )
        wanted = [False] * len(lights)
    else:
        longer = max(settings.resolution)
        size = settings.shadow_map or int(
            np.clip(2 ** math.ceil(math.log2(SHADOW_TEXELS_PER_PIXEL * longer)), *SHADOW_MAP_SIZES)
        )
        casters = "the product" + (" (it can shadow itself)" if self_shadowing else "")
        notes.append(
            f"shadow maps: {sum(wanted)} of {len(lights)} lights cast shadows of {casters}"
            f"{' onto the ground' if scene.info.ground is not None else ''}; {size} x {size} texels, 3 x 3 PCF"
        )
    _check_point_lights(scene, wanted)
    if scene.info.ground is None:
        notes.append("ground: none")
    lobes = [i + 1 for i, layer in enumerate(scene.info.layer) if layer.specular is not None]
    notes.append(f"specular lobes: layers {', '.join(map(str, lobes))}" if lobes else "specular lobes: none")
    notes += _skin_notes(scene)
    return ScenePlan(tables, size, tuple(wanted), tuple(notes))


def _check_point_lights(scene: Scene, shadows: list[bool]) -> None:
    """Refuse a point light inside the product's bounding sphere (on or in the product, at some turn of the
    turntable, where its inverse-square falloff has no finite value), and a shadowing one inside the scene's reach
    (its shadow map looks at the scene from outside it)."""
    centre, radius, _ = _bounds(scene)
    reach = radius * (GROUND_EXTENT * math.sqrt(2.0) if scene.info.ground is not None else 1.0)
    for index, (light, casts) in enumerate(zip(scene.info.light, shadows, strict=True)):
        if light.kind != "point":
            continue
        distance = float(np.linalg.norm(np.subtract(light.position, centre)))
        if distance <= radius:
            raise InputError(
                f"a point light must stand outside the product: more than {radius:.3g} mm (the radius of its "
                f"bounding sphere) from its centre {tuple(round(float(c), 1) for c in centre)}, got {distance:.3g} "
                "mm: move it",
                path=scene.path,
                field=f"light[{index + 1}].position",
            )
        if casts and distance <= 1.05 * reach:
            raise InputError(
                f"a point light that casts shadows must stand outside the scene (more than {1.05 * reach:.0f} mm "
                f"from its centre {tuple(round(float(c), 1) for c in centre)}, the product"
                f"{' and its ground' if scene.info.ground is not None else ''}): move it, or set shadows = false",
                path=scene.path,
                field=f"light[{index + 1}].position",
            )


def _skin_notes(scene: Scene) -> list[str]:
    skin = scene.info.skin
    if skin is None:
        return ["skin: none (the films lie on a substrate; no subsurface scattering)"]
    lobe = skin_lobe(scene)
    notes = [
        f"skin: {skin.reflectance}; its own lobe "
        + ("none" if lobe is None else f"roughness {lobe.roughness:g}, F0 {lobe.f0:.3f}")
    ]
    if skin.albedo_texture is not None:
        notes.append(f"albedo texture: {skin.albedo_texture} (spectra per texel from the skin's; modes planned on it)")
    scattering = skin_scattering(scene)
    if scattering is None:
        notes.append("subsurface scattering: off (the skin's light is not blurred)")
    else:
        notes.append(
            f"subsurface scattering: 4 Gaussians x 2 separable 7-tap passes on skin pixels, alpha {scattering.alpha:g} "
            f"(1 = the measured profile at true scale), beta {scattering.beta:g}, clamp {scattering.gradient_clamp:g}"
        )
    return notes


def layer_lobes(scene: Scene) -> list:
    """The films' specular lobes (renderer Specular or None), top first."""
    from renderer.layers import Specular

    return [None if layer.specular is None else Specular(**layer.specular.model_dump()) for layer in scene.info.layer]


def skin_lobe(scene: Scene):
    """The skin's own specular lobe (renderer Specular), or None."""
    from renderer.layers import Specular
    from renderer.skin import SKIN_SPECULAR

    specular = scene.info.skin.specular
    if specular is True:
        return SKIN_SPECULAR
    return None if specular is False else Specular(specular.roughness, specular.ior)


def skin_scattering(scene: Scene, enabled: bool = True):
    """The skin's subsurface scattering (renderer Scattering), or None when off."""
    from renderer.skin import Scattering

    scattering = scene.info.skin.scattering
    if not enabled or scattering is False:
        return None
    return Scattering() if scattering is True else Scattering(**scattering.model_dump())


def _stack_input(plan: ScenePlan, scene: Scene):
    """The layer pass's stack: a ChannelStack from the planned tables, or a Precomposed stack in exact mode.

    With an albedo texture the substrate is a per-texel mix of three basis spectra
    (:mod:`kmpipe.formats.albedo_texture`),
    reduced to the mode's channels like the films.
    """
    from renderer.layers import ChannelStack, LayerTable, Precomposed

    kind, _ = parse_mode(plan.mode)
    substrate = scene.substrate_reflectance()
    if kind == "exact":
        return Precomposed(*_precompose(scene, substrate))
    tables = plan.tables.build_tables({m.name: m for m in scene.materials})
    first = tables[scene.materials[0].name]
    reduce = first.space.matrix if kind == "rgb" else first.bands.averaging
    to_rgb = None if kind == "rgb" else first.bands.to_rgb
    substrate_map = None
    if scene.albedo is not None:
        basis = basis_spectra(substrate, first.space)
        substrate_map = (_albedo_weights(scene, scene.albedo, basis, first.space), basis @ reduce)
    layer_tables = []
    for material in scene.materials:
        table = tables[material.name]
        x = table.single_thickness_mm if table.thickness_mm is None else table.thickness_mm
        layer_tables.append(LayerTable(x, np.clip(table.R0, 0.0, 1.0), np.clip(table.T, 0.0, 1.0)))
    substrate_channels = np.clip(substrate @ reduce, 0.0, 1.0)
    return ChannelStack(layer_tables, list(scene.thicknesses_mm), substrate_channels, to_rgb, substrate_map)


def _albedo_weights(scene: Scene, albedo: np.ndarray, basis: np.ndarray, space) -> np.ndarray:
    """:func:`kmpipe.formats.albedo_texture.texture_weights`, its refusal said as bad input naming the scene's field."""
    try:
        return texture_weights(albedo, basis, space)
    except ValueError as err:
        key = "skin" if scene.info.skin is not None else "substrate"
        raise InputError(str(err), path=scene.path, field=f"{key}.albedo_texture") from None


def _on_grid(value: np.ndarray, rows: int, columns: int) -> np.ndarray:
    """A 2-D (or 2-D x channels) map resampled bilinearly to rows x columns (as it is if it has that size)."""
    import cv2

    if value.shape[:2] == (rows, columns):
        return value
    return cv2.resize(value, (columns, rows), interpolation=cv2.INTER_LINEAR)


def _precompose(scene: Scene, substrate: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact mode: reflectance and over-black reflectance (3,), attenuation (n + 1, 3), or all over the grid of the
    thickness maps and the albedo texture (see :func:`kmpipe.physics.optical_tables.exact_stack`).

    Maps of other sizes than the first are resampled to its grid (bilinear). Only distinct combinations of
    thicknesses (and albedo weights) are composed, in chunks, so a large map of few levels costs little.
    """
    space = working_space(scene.wavelengths, scene.info.scene.illuminant)
    maps = [np.asarray(x, dtype=float) for x in scene.thicknesses_mm if np.ndim(x) == 2]
    if scene.albedo is not None:
        maps.append(scene.albedo)
    if not maps:
        return exact_stack(scene.materials, list(scene.thicknesses_mm), substrate, space)
    rows, columns = maps[0].shape[:2]
    columns_of_grid = [_on_grid(np.broadcast_to(np.asarray(x, float), (rows, columns)) if np.ndim(x) == 0
                                else np.asarray(x, float), rows, columns).reshape(rows * columns, 1)
                       for x in scene.thicknesses_mm]  # fmt: skip
    n_layers = len(columns_of_grid)
    basis = None
    if scene.albedo is not None:
        basis = basis_spectra(substrate, space)
        weights = _albedo_weights(scene, _on_grid(scene.albedo, rows, columns), basis, space)
        columns_of_grid.append(weights.reshape(rows * columns, 3))
    combinations, inverse = np.unique(np.hstack(columns_of_grid), axis=0, return_inverse=True)
    reflectance = np.empty((len(combinations), 3))
    over_black = np.empty((len(combinations), 3))
    attenuation = np.empty((n_layers + 1, len(combinations), 3))
    chunk = 16384
    for start in range(0, len(combinations), chunk):
        part = combinations[start : start + chunk]
        under = substrate if basis is None else np.clip(part[:, n_layers:] @ basis, 0.0, 1.0)
        rows_done = slice(start, start + chunk)
        reflectance[rows_done], over_black[rows_done], attenuation[:, rows_done] = exact_stack(
            scene.materials, list(part[:, :n_layers].T), under, space
        )
    inverse = inverse.ravel()
    return (
        reflectance[inverse].reshape(rows, columns, 3),
        over_black[inverse].reshape(rows, columns, 3),
        attenuation[:, inverse].reshape(n_layers + 1, rows, columns, 3),
    )


def _bounds(scene: Scene) -> tuple[np.ndarray, float, float]:
    """Centre (mm) and radius (mm) of the placed mesh, and its lowest world y (mm)."""
    vertices = np.asarray(scene.mesh.vertices) @ scene.model[:3, :3].T + scene.model[:3, 3]
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    return centre, float(np.max(np.linalg.norm(vertices - centre, axis=1))), float(vertices[:, 1].min())


def camera_for(scene: Scene):
    """The scene's camera, looking at the centre of the (placed) mesh."""
    from renderer.scene import OrthographicCamera, PerspectiveCamera

    centre, radius, _ = _bounds(scene)
    info = scene.info.camera
    azimuth, elevation = math.radians(info.azimuth_deg), math.radians(info.elevation_deg)
    direction = np.array(
        [math.cos(elevation) * math.sin(azimuth), math.sin(elevation), math.cos(elevation) * math.cos(azimuth)]
    )
    distance = info.distance_mm
    if distance is None:  # the bounding sphere fills FRAME_FILL of the image height
        half_angle = math.radians(info.fov_deg) / 2.0
        distance = (
            radius / math.sin(math.atan(FRAME_FILL * math.tan(half_angle)))
            if info.projection == "perspective"
            else 3.0 * radius
        )
    eye = tuple(centre + distance * direction)
    reach = radius * (GROUND_EXTENT * math.sqrt(2.0) if scene.info.ground is not None else 1.0)
    near = max(distance - 2.0 * reach, 1e-3 * distance)
    far = distance + 2.0 * reach
    if info.projection == "orthographic":
        return OrthographicCamera(radius / FRAME_FILL, eye=eye, target=tuple(centre), near=near, far=far)
    return PerspectiveCamera(info.fov_deg, eye=eye, target=tuple(centre), near=near, far=far)


def turntable_model(scene: Scene, angle_deg: float) -> np.ndarray:
    """The product's object -> world matrix turned by ``angle_deg`` about the vertical axis through its centre.

    The turn is clockwise seen from above, so the camera's azimuth relative to the product grows with the angle.
    """
    centre, _, _ = _bounds(scene)
    turn = np.eye(4)
    c, s = math.cos(math.radians(-angle_deg)), math.sin(math.radians(-angle_deg))
    turn[0, 0], turn[0, 2], turn[2, 0], turn[2, 2] = c, s, -s, c
    shift, back = np.eye(4), np.eye(4)
    shift[:3, 3], back[:3, 3] = -centre, centre
    return back @ turn @ shift @ scene.model


def _lights(scene: Scene, plan: ScenePlan):
    from renderer.scene import DirectionalLight, PointLight

    centre, _, _ = _bounds(scene)
    lights = []
    for info, shadows in zip(scene.info.light, plan.shadow_lights, strict=True):
        if info.kind == "point":
            reference = info.reference_distance_mm or float(np.linalg.norm(np.subtract(info.position, centre)))
            lights.append(PointLight(info.position, info.radiance, reference, cast_shadows=shadows))
        else:
            towards = info.direction if info.direction is not None else (0.0, 0.0, 1.0)
            lights.append(DirectionalLight(tuple(-np.asarray(towards, float)), info.radiance, cast_shadows=shadows))
    return lights


def _ground(scene: Scene):
    """A square floor under the product (a Prop), or None."""
    from renderer.layers import Prop
    from renderer.meshes import card

    if scene.info.ground is None:
        return None
    centre, radius, bottom = _bounds(scene)
    side = 2.0 * GROUND_EXTENT * radius
    model = np.eye(4)
    model[1:3, 1:3] = [[0.0, 1.0], [-1.0, 0.0]]  # the card's +z normal turned to +y
    model[:3, 3] = (centre[0], bottom, centre[2])
    return Prop(card(side, side), (scene.info.ground.reflectance,) * 3, model)


def render_scene(
    scene: str | Path | Scene,
    out_dir: str | Path,
    *,
    explain: bool = False,
    scattering: bool = True,
    ab_scattering: bool = False,
    frames: Sequence[int] | None = None,
    header: dict[str, str] | None = None,
    echo: Callable[[str], None] = print,
    on_frame: Callable[[int, int], None] | None = None,
) -> list[Path]:
    """Render every frame of a scene file into ``out_dir`` as ``frame_NNN.exr`` (linear, float) and ``.png`` (sRGB).

    ``explain`` passes the plan's text to ``echo``; ``on_frame(i, n)`` is called after frame i of n. The PNG is
    tone mapped as the scene's ``[output]`` says; the EXR keeps the linear render. On skin, ``scattering=False``
    turns subsurface scattering off, and ``ab_scattering`` renders every frame without it as well (into
    ``no_sss/``) and lays both out on ``ab_sss.png`` (with above, without below, thesis figure 5.58). ``frames``
    renders only those frames of the turntable (indices); ``header`` adds attributes to every frame's EXR header.
    Returns the files written, EXR and PNG of each frame in order (then the A/B frames and sheet).
    """
    from renderer.layers import render_layers
    from renderer.skin import render_skin

    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    if ab_scattering and (scene.info.skin is None or skin_scattering(scene) is None):
        raise InputError(
            "--ab-sss compares renders with and without subsurface scattering: the scene needs [skin] with its "
            "scattering on",
            path=scene.path,
            field="skin.scattering",
        )
    plan = plan_scene(scene)
    if explain:
        echo(plan.explain())
    stack = _stack_input(plan, scene)
    info = scene.info
    specular = layer_lobes(scene)
    lights, camera = _lights(scene, plan), camera_for(scene)
    ground = _ground(scene)
    width, height = info.scene.resolution
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    header = {
        **(header or {}),
        "scene": scene.name,
        "product": scene.product,
        "shade": scene.shade,
        "materials": ", ".join(m.name for m in scene.materials),
        "material_sha256": ", ".join(scene.material_hashes),
        "thicknesses_mm": ", ".join(
            f"{x:g}" if np.ndim(x) == 0 else "{:g}..{:g} (map)".format(*scene.thickness_range_mm(i))
            for i, x in enumerate(scene.thicknesses_mm)
        ),
        "render_mode": plan.mode,
        "illuminant": info.scene.illuminant,
        "camera_elevation_deg": float(info.camera.elevation_deg),
        "tone_map": f"{info.output.tone_map} {info.output.exposure_ev:+g} EV (PNG only)",
    }
    on_skin = info.skin is not None
    blur = skin_scattering(scene, scattering) if on_skin else None
    header["subsurface_scattering"] = (
        "none (no skin)" if not on_skin else "off" if blur is None
        else f"alpha {blur.alpha:g}, beta {blur.beta:g}, clamp {blur.gradient_clamp:g}"
    )  # fmt: skip
    variants = [(out_dir, blur)]
    if ab_scattering:
        variants.append((files.output_folder(files.within(out_dir, "no_sss"), field="--ab-sss"), None))
    written = []
    angles = scene.turntable_angles_deg()
    chosen = range(len(angles)) if frames is None else list(frames)
    outputs = [folder / f"frame_{i:03d}.{ext}" for folder, _ in variants for i in chosen for ext in ("exr", "png")]
    for output in [*outputs, *([out_dir / "ab_sss.png"] if ab_scattering else [])]:
        files.refuse_inputs(output, scene.inputs, field="-o")
    for done, i in enumerate(chosen):
        angle = angles[i]
        common = {
            "specular": specular,
            "model": turntable_model(scene, angle),
            "props": [ground] if ground is not None else [],
            "shadow_map_size": plan.shadow_map_size or SHADOW_MAP_SIZES[0],
        }
        for folder, variant in variants:
            if on_skin:
                image = render_skin(
                    scene.mesh, camera, lights, stack, width, height,
                    scattering=variant, skin_specular=skin_lobe(scene), **common,
                )  # fmt: skip
            else:
                image = render_layers(scene.mesh, camera, lights, stack, width, height, **common)
            exr, png = folder / f"frame_{i:03d}.exr", folder / f"frame_{i:03d}.png"
            frame_header = {
                **header,
                "camera_azimuth_deg": float((info.camera.azimuth_deg + angle) % 360.0),
                "turntable_deg": float(angle),
                "frame": i,
            }
            if folder != out_dir:
                frame_header["subsurface_scattering"] = "off (A/B comparison)"
            _write_frame(exr, png, image, frame_header, info.output)
            written += [exr, png]
        if on_frame is not None:
            on_frame(done + 1, len(chosen))
    if ab_scattering:
        written.append(_ab_sheet(out_dir, scene, len(angles)))
    return written


def _write_frame(exr: Path, png: Path, image: np.ndarray, header: dict, output) -> None:
    """Write one frame as a pair: the linear EXR (32-bit float, with ``header``) and the PNG tone mapped as
    ``output`` (the scene's [output]) says.

    Each file is written atomically (renderer.image_io); the old EXR is removed first and the new one written
    last, so an exit at any moment leaves no EXR (what caches and readers look for) without its PNG. A frame with
    NaN or infinite pixels is a renderer bug: RuntimeError, and nothing is written for it.
    """
    from renderer.image_io import write_exr, write_png
    from renderer.tone_map import tone_map

    bad = int(np.count_nonzero(~np.isfinite(image)))
    if bad:
        raise RuntimeError(f"the renderer gave {bad} NaN or infinite values for {exr}; nothing was written for it")
    tone_mapped = tone_map(image, output.tone_map, output.exposure_ev)
    exr.unlink(missing_ok=True)
    write_png(png, tone_mapped)
    write_exr(exr, image, header, half=False)


def _ab_sheet(out_dir: Path, scene: Scene, frames: int) -> Path:
    """``ab_sss.png``: up to 4 frames with subsurface scattering (top row) and without (bottom row)."""
    from renderer.contact_sheet import make_sheet, write_sheet

    picks = [round(i * frames / min(frames, 4)) for i in range(min(frames, 4))]
    paths = [out_dir / f"frame_{i:03d}.exr" for i in picks] + [out_dir / "no_sss" / f"frame_{i:03d}.exr" for i in picks]
    angles = scene.turntable_angles_deg()
    columns = [f"{(scene.info.camera.azimuth_deg + angles[i]) % 360.0:g}°" for i in picks]
    sheet = make_sheet(
        paths,
        rows=["with subsurface scattering", "without"],
        columns=columns,
        grid=(2, len(picks)),
        header=f"{scene.name} · {scene.product} · {scene.shade} · {scene.info.scene.illuminant}",
    )
    path = out_dir / "ab_sss.png"
    write_sheet(sheet, path)
    return path
