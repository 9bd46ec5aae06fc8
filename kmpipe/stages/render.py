"""``kmpipe render``: a scene file (:mod:`kmpipe.formats.scene`) and its render plan to linear EXR and sRGB PNG frames.

The plan (:func:`kmpipe.stages.render_plan.plan_scene`, or its file read back by
:func:`kmpipe.stages.plan_file.read_plan`) gives the render mode, the optical tables, the shadow maps and the skin's
passes. :func:`renderer_scenes` turns the scene and its plan into the renderer's scenes
(:class:`renderer.scene.Scene`), one per turntable angle, which the renderer's passes draw: the Kubelka-Munk layer
pass (:func:`renderer.layers.render_layers`) or, on skin, the skin pass with subsurface scattering
(:func:`renderer.skin.render_skin`). In the ``rgb`` and ``bands:N`` modes the shader composes the films per channel
from the tables; in ``exact`` mode the stack is composed here, per wavelength, once for each distinct combination of
thicknesses in the scene (one for uniform films; one per distinct texel of the thickness maps), and the shader reads
the result (each film's lobe weighted by its cover, :data:`renderer.stack.LOBE_COVER_MM`, as the shader does).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.albedo_texture import basis_spectra, texture_weights
from kmpipe.formats.scene import Scene, load_scene
from kmpipe.physics.optical_tables import exact_stack, parse_mode, working_space
from kmpipe.stages import antialiasing, framing, staging
from kmpipe.stages.frame_choice import apply_choice
from kmpipe.stages.render_plan import SHADOW_MAP_SIZES, ScenePlan, placed_bounds, plan_scene, scene_reach
from kmpipe.stages.sheet import write_contact_sheet
from kmpipe.stages.video import write_turntable_videos
from renderer.image_io import write_exr, write_png
from renderer.layers import render_layers
from renderer.scene import DirectionalLight, OrthographicCamera, PerspectiveCamera, PointLight
from renderer.scene import Scene as RendererScene
from renderer.scene_white import scene_white
from renderer.skin import render_skin
from renderer.stack import LOBE_COVER_MM, ChannelStack, LayerTable, Precomposed, Specular
from renderer.tone_map import tone_map


def renderer_scenes(
    scene: Scene,
    plan: ScenePlan,
    angles_deg: Sequence[float],
    *,
    scattering: bool = True,
    occlusion: np.ndarray | None = None,
) -> list[RendererScene]:
    """The renderer's scene of each turntable angle (degrees) of ``scene`` rendered as ``plan`` says.

    The scenes share everything but the product's model matrix (turned about the vertical through its centre by
    the angle, clockwise seen from above): the mesh, the surface (a :class:`~renderer.stack.ChannelStack` of the
    planned tables, or a :class:`~renderer.stack.Precomposed` stack in exact mode; built once), the films' lobes,
    the lights with the plan's shadows, the camera looking at the centre of the placed mesh, a ground or a backdrop
    (:mod:`kmpipe.stages.staging`), the environment light and, where the plan says, its ambient occlusion, the skin's
    lobe and scattering from the plan (``scattering=False``: none). ``occlusion``: the mesh's ambient occlusion
    baked before (:func:`kmpipe.stages.staging.occlusion` of a scene with the same mesh, place and backdrop), or
    None to bake it here.

    >>> import kmpipe, pathlib, tempfile
    >>> from kmpipe.formats.scene import load_scene
    >>> from kmpipe.stages.fit import fit_manifests
    >>> from kmpipe.stages.render_plan import plan_scene
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1" / "manifest.toml"
    >>> _ = fit_manifests([F1], folder / "F1.json")
    >>> _ = (folder / "card.toml").write_text(
    ...     '[scene]\\nname = "F1"\\nmode = "rgb"\\n[substrate]\\nreflectance = 0.5\\n'
    ...     '[[layer]]\\nmaterial = "F1.json"\\nthickness = "20 um"\\n[turntable]\\nframes = 4\\n')
    >>> scene = load_scene(folder / "card.toml")
    >>> frames = renderer_scenes(scene, plan_scene(scene), scene.turntable_angles_deg())
    >>> len(frames), frames[0].resolution, frames[0].stack is frames[3].stack
    (4, (512, 512), True)
    """
    info = scene.info
    lobes = [None if layer.specular is None else Specular(**layer.specular.model_dump()) for layer in info.layer]
    floor = staging.floor_prop(scene)
    common = {
        "mesh": scene.mesh,
        "stack": _surface(scene, plan),
        "camera": _camera(scene),
        "lights": _lights(scene, plan),
        "resolution": info.resolution,
        "lobes": lobes,
        "substrate_lobe": plan.skin_lobe,
        "scattering": plan.scattering if scattering else None,
        "shadow_map_size": plan.shadow_map_size or SHADOW_MAP_SIZES[0],
        **antialiasing.renderer_fields(plan.antialiasing, plan.antialias(scene)),
        "background": staging.background(scene),
        "environment": staging.environment(scene),
        "occlusion": (staging.occlusion(scene) if occlusion is None else occlusion) if plan.ambient_occlusion else None,
        "normal_map": staging.normal_map(scene),
        "substrate_roughness": scene.roughness,
    }
    models = [_turntable_model(scene, angle) for angle in angles_deg]
    baked = staging.floor_occlusion(scene) if floor is not None else None
    scenes = []
    for m in models:
        floors = () if floor is None else (floor if baked is None else staging.turned_floor(scene, floor, baked, m),)
        scenes.append(RendererScene(model=m, **{**common, "props": floors + staging.eyes(scene, m)}))
    return scenes


def _surface(scene: Scene, plan: ScenePlan) -> ChannelStack | Precomposed:
    """The layer pass's stack: a ChannelStack from the planned tables, or a Precomposed stack in exact mode.

    With an albedo texture the substrate is a per-texel mix of three basis spectra
    (:mod:`kmpipe.formats.albedo_texture`), reduced to the mode's channels like the films.
    """
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
        weights = texture_weights(albedo, basis, space)
        weights.setflags(write=False)  # the same for every frame: hashed once (renderer.texture_cache.frozen)
        return weights
    except ValueError as err:
        key = "skin" if scene.info.skin is not None else "substrate"
        raise InputError(str(err), path=scene.path, field=f"{key}.albedo_texture") from None


def _on_grid(value: np.ndarray, rows: int, columns: int) -> np.ndarray:
    """A 2-D (or 2-D x channels) map resampled bilinearly to rows x columns (as it is if it has that size)."""
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
        thicknesses = list(scene.thicknesses_mm)
        reflectance, over_black, attenuation = exact_stack(scene.materials, thicknesses, substrate, space)
        cover = np.clip(np.asarray(scene.thicknesses_mm, dtype=float) / LOBE_COVER_MM, 0.0, 1.0)
        attenuation[:-1] *= cover[:, None]
        return reflectance, over_black, attenuation
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
    attenuation[:-1] *= np.clip(combinations[:, :n_layers].T / LOBE_COVER_MM, 0.0, 1.0)[..., None]  # films' cover
    return (
        reflectance[inverse].reshape(rows, columns, 3),
        over_black[inverse].reshape(rows, columns, 3),
        attenuation[:, inverse].reshape(n_layers + 1, rows, columns, 3),
    )


def _camera(scene: Scene) -> OrthographicCamera | PerspectiveCamera:
    """The scene's camera, looking at the centre of the (placed) mesh moved by the camera's ``aim_mm``."""
    centre, radius, _ = placed_bounds(scene)
    info = scene.info.camera
    centre = centre + np.asarray(info.aim_mm, dtype=float)
    azimuth, elevation = math.radians(info.azimuth_deg), math.radians(info.elevation_deg)
    direction = np.array(
        [math.cos(elevation) * math.sin(azimuth), math.sin(elevation), math.cos(elevation) * math.cos(azimuth)]
    )
    distance = framing.camera_distance_mm(info, radius)
    eye = tuple(centre + distance * direction)
    reach = scene_reach(scene)
    near = max(distance - 2.0 * reach, 1e-3 * distance)
    far = distance + 2.0 * reach
    if info.projection == "orthographic":
        return OrthographicCamera(radius / framing.FRAME_FILL, eye=eye, target=tuple(centre), near=near, far=far)
    return PerspectiveCamera(info.fov_deg, eye=eye, target=tuple(centre), near=near, far=far)


def _turntable_model(scene: Scene, angle_deg: float) -> np.ndarray:
    """The product's object -> world matrix turned by ``angle_deg`` about the vertical axis through its centre.

    The turn is clockwise seen from above, so the camera's azimuth relative to the product grows with the angle.
    """
    centre, _, _ = placed_bounds(scene)
    turn = np.eye(4)
    c, s = math.cos(math.radians(-angle_deg)), math.sin(math.radians(-angle_deg))
    turn[0, 0], turn[0, 2], turn[2, 0], turn[2, 2] = c, s, -s, c
    shift, back = np.eye(4), np.eye(4)
    shift[:3, 3], back[:3, 3] = -centre, centre
    return back @ turn @ shift @ scene.model


def _lights(scene: Scene, plan: ScenePlan) -> list[DirectionalLight | PointLight]:
    """The scene's lights, each casting shadows where the plan gives it a shadow map."""
    centre, _, _ = placed_bounds(scene)
    lights = []
    for info, shadows in zip(scene.info.light, plan.shadow_lights, strict=True):
        if info.kind == "point":
            reference = info.reference_distance_mm or float(np.linalg.norm(np.subtract(info.position, centre)))
            light = PointLight(info.position, info.radiance, reference, cast_shadows=shadows, size_mm=info.size_mm)
            lights.append(light)
        else:
            towards = tuple(-np.asarray(info.direction if info.direction is not None else (0.0, 0.0, 1.0), float))
            lights.append(DirectionalLight(towards, info.radiance, cast_shadows=shadows, angle_deg=info.angle_deg))
    return lights


def render_scene(
    scene: str | Path | Scene,
    out_dir: str | Path,
    *,
    plan: ScenePlan | None = None,
    measure_settings: bool = False,
    explain: bool = False,
    scattering: bool = True,
    ab_scattering: bool = False,
    frames: Sequence[int] | None = None,
    header: dict[str, str] | None = None,
    echo: Callable[[str], None] = print,
    on_frame: Callable[[int, int], None] | None = None,
) -> list[Path]:
    r"""Render every frame of a scene file into ``out_dir`` as ``frame_NNN.exr`` (linear, float) and ``.png`` (sRGB).

    ``plan`` renders as that plan of the scene says (e.g. its plan file read back,
    :func:`kmpipe.stages.plan_file.read_plan`) without planning again; by default the scene is planned
    (:func:`kmpipe.stages.render_plan.plan_scene`), and with ``measure_settings`` its antialiasing, shadow map and
    subsurface scattering (those it leaves to the planner) are then the cheapest whose first frame keeps 95 % of the
    product's pixels within the scene's Delta E 2000 target, measured as ``kmpipe trade`` measures a line's products
    (:func:`kmpipe.stages.trade.measure_frame_choice`). ``explain`` passes the plan's text to ``echo``; ``on_frame(i,
    n)`` is called after frame i of n. The PNG is tone mapped as the scene's ``[output]`` says; the EXR keeps the
    linear render. On skin, ``scattering=False`` turns subsurface scattering off, and ``ab_scattering`` renders every
    frame without it as well (into ``no_sss/``) and lays both out on ``ab_sss.png`` (with above, without below,
    thesis figure 5.58). ``frames`` renders only those frames of the turntable (indices); ``header`` adds attributes
    to every frame's EXR header. Returns the files written, EXR and PNG of each frame in order (then the A/B frames
    and sheet, then the turntable's videos, :func:`kmpipe.stages.video.write_turntable_videos`, when every frame
    was rendered).

    >>> import kmpipe, pathlib, tempfile, numpy as np
    >>> from kmpipe.stages.fit import fit_manifests
    >>> from renderer.image_io import read_exr
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> _ = fit_manifests([F1 / "manifest.toml"], folder / "F1.json", method="black-white")
    >>> _ = (folder / "scene.toml").write_text(
    ...     '[scene]\nname = "F1 on a card"\nmesh = "card"\nresolution = [32, 32]\n'
    ...     '[substrate]\nreflectance = 0.8\n[[layer]]\nmaterial = "F1.json"\nthickness = "30 um"\n'
    ...     '[[light]]\ndirection = [0, 0, 1]\n[camera]\nelevation_deg = 0.0\nprojection = "orthographic"\n')
    >>> written = render_scene(folder / "scene.toml", folder / "out", echo=lambda text: None)
    >>> [path.name for path in written]
    ['frame_000.exr', 'frame_000.png']
    >>> image, header = read_exr(written[0])
    >>> image.shape, header["product"], header["illuminant"], bool(np.isfinite(image).all() and image.max() > 0)
    ((32, 32, 3), 'F1 on a card', 'D65', True)
    """
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    info = scene.info
    on_skin = info.skin is not None
    if ab_scattering and not (on_skin and info.skin.scattering is not False):
        raise InputError(
            "--ab-sss compares renders with and without subsurface scattering: the scene needs [skin] with its "
            "scattering on",
            path=scene.path,
            field="skin.scattering",
        )
    if plan is None and measure_settings:
        if on_skin and (ab_scattering or not scattering):  # --ab-sss, --no-sss: scattering is set, not measured
            scene = dataclasses.replace(scene, info=info.model_copy(update={"skin": info.skin.model_copy(
                update={"scattering": info.skin.scattering if scattering else False})}))  # fmt: skip
            info = scene.info
        plan = _measured_plan(scene)
    plan = plan_scene(scene) if plan is None else plan
    if explain:
        from renderer.context import renderer_name

        echo(plan.explain())
        echo(f"OpenGL: {renderer_name()} (kmpipe --gl, KMPIPE_GL: osmesa, egl or auto)")
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
        "antialias": antialiasing.describe(plan.antialiasing, plan.antialias(scene)),
    }
    blur = plan.scattering if scattering else None
    header["subsurface_scattering"] = (
        "none (no skin)" if not on_skin else "off" if blur is None
        else f"alpha {blur.alpha:g}, beta {blur.beta:g}, clamp {blur.gradient_clamp:g}"
    )  # fmt: skip
    folders = [out_dir]
    if ab_scattering:
        folders.append(files.output_folder(files.within(out_dir, "no_sss"), field="--ab-sss"))
    angles = scene.turntable_angles_deg()
    chosen = range(len(angles)) if frames is None else list(frames)
    outputs = [folder / f"frame_{i:03d}.{ext}" for folder in folders for i in chosen for ext in ("exr", "png")]
    for output in [*outputs, *([out_dir / "ab_sss.png"] if ab_scattering else [])]:
        files.refuse_inputs(output, scene.inputs, field="-o")
    render = render_skin if on_skin else render_layers
    written = []
    scenes = renderer_scenes(scene, plan, [angles[i] for i in chosen], scattering=scattering)
    # Reinhard's white: the scene's white card (renderer.scene_white), the same for every frame under these lights.
    white = scene_white(scenes[0]) if info.output.tone_map == "reinhard" and scenes else None
    curve = f"{info.output.tone_map} {info.output.exposure_ev:+g} EV"
    header["tone_map"] = f"{curve} (PNG only)" if white is None else f"{curve}, white {white:.4g} (PNG only)"
    # A frame is written (tone mapped, encoded, fsynced) by a thread of its own while the next one renders; at most
    # one write waits, and its error surfaces here before the next frame is handed over. on_frame follows the writes.
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="kmpipe-frame-writer") as writer:
        pending: tuple[Future, int | None] | None = None  # the write in flight, and the frames done when it ends

        def finish() -> None:
            write, frames_done = pending
            write.result()
            if on_frame is not None and frames_done is not None:
                on_frame(frames_done, len(chosen))

        for done, (i, frame) in enumerate(zip(chosen, scenes, strict=True)):
            for folder in folders:
                image = render(frame if folder == out_dir else dataclasses.replace(frame, scattering=None))
                exr, png = folder / f"frame_{i:03d}.exr", folder / f"frame_{i:03d}.png"
                frame_header = {
                    **header,
                    "camera_azimuth_deg": float((info.camera.azimuth_deg + angles[i]) % 360.0),
                    "turntable_deg": float(angles[i]),
                    "frame": i,
                }
                if folder != out_dir:
                    frame_header["subsurface_scattering"] = "off (A/B comparison)"
                if pending is not None:
                    finish()
                last = folder == folders[-1]
                pending = (
                    writer.submit(_write_frame, exr, png, image, frame_header, info.output, white),
                    done + 1 if last else None,
                )
                written += [exr, png]
        if pending is not None:
            finish()
    if ab_scattering:
        written.append(_ab_sheet(out_dir, scene, len(angles)))
    if frames is None:  # the whole turntable: its videos (none for one frame, or with [output] video = [])
        exrs = [out_dir / f"frame_{i:03d}.exr" for i in chosen]
        written += write_turntable_videos(
            exrs, out_dir, formats=info.output.video, fps=info.output.fps, inputs=scene.inputs
        )
    return written


def _measured_plan(scene: Scene) -> ScenePlan:
    """The scene's plan with the frame settings measured on its first frame
    (:func:`kmpipe.stages.trade.measure_frame_choice`), its notes saying so, or that there was nothing to measure."""
    from kmpipe.stages.trade import measure_frame_choice

    plan = plan_scene(scene)
    choice = measure_frame_choice(scene, plan)
    if choice is not None:
        return apply_choice(plan, scene, choice, by="kmpipe render --measure-settings")
    note = ("frame settings: nothing to measure (--measure-settings): the scene sets its antialiasing, shadow map and "
            "subsurface scattering itself, or they do not apply to it")  # fmt: skip
    return dataclasses.replace(plan, notes=(*plan.notes, note))


def _write_frame(exr: Path, png: Path, image: np.ndarray, header: dict, output, white: float | None) -> None:
    """Write one frame as a pair: the linear EXR (32-bit float, with ``header``) and the PNG tone mapped as
    ``output`` (the scene's [output]) says, with Reinhard's ``white`` (the scene's, not the frame's).

    Each file is written atomically (renderer.image_io); the old EXR is removed first and the new one written
    last, so an exit at any moment leaves no EXR (what caches and readers look for) without its PNG. A frame with
    NaN or infinite pixels is a renderer bug: RuntimeError, and nothing is written for it.
    """
    bad = int(np.count_nonzero(~np.isfinite(image)))
    if bad:
        raise RuntimeError(f"the renderer gave {bad} NaN or infinite values for {exr}; nothing was written for it")
    tone_mapped = tone_map(image, output.tone_map, output.exposure_ev, white)
    exr.unlink(missing_ok=True)
    write_png(png, tone_mapped)
    write_exr(exr, image, header, half=False)


def _ab_sheet(out_dir: Path, scene: Scene, frames: int) -> Path:
    """``ab_sss.png``: up to 4 frames with subsurface scattering (top row) and without (bottom row), a column per
    camera angle (from the frames' headers, :func:`kmpipe.stages.sheet.frame_labels`)."""
    picks = [round(i * frames / min(frames, 4)) for i in range(min(frames, 4))]
    paths = [out_dir / f"frame_{i:03d}.exr" for i in picks] + [out_dir / "no_sss" / f"frame_{i:03d}.exr" for i in picks]
    header = f"{scene.name} · {scene.product} · {scene.shade} · {scene.info.scene.illuminant}"
    rows = ["with subsurface scattering", "without"]
    return write_contact_sheet(paths, out_dir / "ab_sss.png", columns=len(picks), row_labels=rows, header=header).path
