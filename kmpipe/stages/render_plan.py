"""The render plan stage: which optical tables a scene needs, in which render mode, and what else its frames need.

:func:`plan_render` lists the materials, stacks and thickness ranges (mm) in use; picks the cheapest render mode, in
the order rgb, bands:3, bands:6, bands:9, ... (N below the number of wavelengths), exact, whose largest Delta E 2000
against the exact spectral result on the scene's own stacks (:func:`kmpipe.physics.optical_tables.mode_error`) is
within the accuracy target; sizes each thickness axis so that linear interpolation adds at most
:data:`INTERPOLATION_FRACTION` of the target; and drops what the scene does not need. :func:`plan_scene` plans a
render scene (:mod:`kmpipe.formats.scene`) that way, on its one stack (at most
:data:`renderer.stack.MAX_CHANNELS` bands, what the layer pass composes), and decides the rest of its frames
(:class:`ScenePlan`): a shadow map for each light that casts shadows, unless nothing in the scene can shadow
anything (a flat or convex product without a ground); the size of the maps; the skin's lobe and its subsurface
scattering, or none. Its plan file is :mod:`kmpipe.stages.plan_file`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import colour
import numpy as np
import trimesh

from kmpipe.errors import InputError
from kmpipe.formats.scene import Scene
from kmpipe.physics.optical_tables import (
    FilmCoefficients,
    OpticalTable,
    Stack,
    band_partition,
    composite,
    mode_error,
    parse_mode,
    working_space,
)
from kmpipe.stages import plan_notes
from kmpipe.stages.antialiasing import Method, plan_antialiasing
from renderer.scene import Scattering
from renderer.stack import MAX_CHANNELS, SKIN_SPECULAR, Specular

#: Delta E 2000 target (worst case over the scene's stacks) when the caller gives none; about 1/2 of a just noticeable
#: difference, so a studio can composite renders of one shade next to each other without seeing the mode.
DEFAULT_TARGET_DE = 0.5
#: Share of the target that thickness interpolation may use (the rest is left to the mode).
INTERPOLATION_FRACTION = 0.25
#: Largest thickness axis the planner will propose (2^8 + 1 samples).
MAX_SAMPLES = 257
#: Texels of a shadow map per pixel of the longer image side, and the bounds of the map's size.
SHADOW_TEXELS_PER_PIXEL = 2
SHADOW_MAP_SIZES = (512, 4096)
#: Ground half-size in radii of the product's bounding sphere.
GROUND_EXTENT = 4.0


@dataclass(frozen=True)
class ModeCandidate:
    """A render mode and its measured Delta E 2000 against exact over the scene's stacks and probe thicknesses."""

    mode: str
    max_dE: float
    mean_dE: float


@dataclass(frozen=True)
class TableSize:
    """Thickness axis of one material's table: ``n_samples`` uniform samples over [min_mm, max_mm] (1: no axis).

    ``interpolation_dE`` is the largest Delta E 2000 between linear interpolation in the table and the same mode
    evaluated at the thickness itself, measured at every eighth of each interval of the table (0 without an axis).
    """

    material: str
    min_mm: float
    max_mm: float
    n_samples: int
    n_channels: int
    interpolation_dE: float

    @property
    def thicknesses_mm(self) -> np.ndarray:
        return np.linspace(self.min_mm, self.max_mm, self.n_samples)


@dataclass(frozen=True)
class RenderPlan:
    """What :func:`plan_render` decided; ``explain()`` prints it."""

    illuminant: str
    observer: str
    target_dE: float
    mode: str
    forced: bool
    materials: tuple[str, ...]
    stacks: tuple[Stack, ...]
    thickness_ranges: dict[str, tuple[float, float]]
    candidates: tuple[ModeCandidate, ...]
    tables: tuple[TableSize, ...]
    dropped: tuple[str, ...]

    def build_tables(self, materials: Mapping[str, FilmCoefficients]) -> dict[str, OpticalTable]:
        """The planned :class:`OpticalTable` of every material in use."""
        space = working_space(materials[self.materials[0]].wavelengths, self.illuminant, self.observer)
        kind, n_bands = parse_mode(self.mode)
        bands = band_partition(space.wavelengths, n_bands, space=space) if kind == "bands" else None
        return {
            t.material: OpticalTable.build(materials[t.material], t.thicknesses_mm, self.mode, space, bands)
            for t in self.tables
        }

    def explain(self) -> str:
        """The plan as text: materials, stacks, ranges, candidates with their errors, table sizes, what was dropped."""
        lines = [
            f"Render plan under {self.illuminant} (observer {self.observer} deg), "
            f"target Delta E 2000 <= {self.target_dE:g}"
        ]
        lines.append("Materials: " + ", ".join(self.materials))
        lines.append("Stacks (top first):")
        lines += [f"  {s.name}: {' / '.join(s.layers)} / substrate" for s in self.stacks]
        lines.append("Thickness ranges (mm):")
        lines += [f"  {name}: {lo:g} .. {hi:g}" for name, (lo, hi) in self.thickness_ranges.items()]
        lines.append("Modes (Delta E 2000 against exact on the scene's stacks: max, mean):")
        for c in self.candidates:
            verdict = "meets target" if c.max_dE <= self.target_dE else "misses target"
            mark = "  <- chosen" if c.mode == self.mode else ""
            lines.append(f"  {c.mode:>9}: max {c.max_dE:.3f}, mean {c.mean_dE:.3f} ({verdict}){mark}")
        if self.forced:
            lines.append(f"  mode {self.mode} was requested; no other mode was evaluated")
        else:
            lines.append(f"  modes after {self.mode} were not evaluated: a cheaper mode met the target")
        lines.append("Tables:")
        for t in self.tables:
            axis = f"{t.n_samples} thickness samples" if t.n_samples > 1 else "no thickness axis"
            lines.append(
                f"  {t.material}: {axis} x {t.n_channels} channels x (R0, T), "
                f"interpolation Delta E 2000 <= {t.interpolation_dE:.3f}"
            )
        lines.append("Dropped:" if self.dropped else "Dropped: nothing")
        lines += [f"  {d}" for d in self.dropped]
        return "\n".join(lines)


def candidate_modes(n_wavelengths: int, max_bands: int | None = None) -> list[str]:
    """rgb, bands:3, bands:6, ... (N < n_wavelengths and N <= max_bands), exact: cheapest first."""
    top = n_wavelengths - 1 if max_bands is None else min(n_wavelengths - 1, max_bands)
    return ["rgb", *(f"bands:{n}" for n in range(3, top + 1, 3)), "exact"]


def _interpolation_error(material: FilmCoefficients, lo: float, hi: float, n: int, substrates, mode, space, bands):
    """Largest Delta E 2000 of linear interpolation on n uniform samples, at every eighth of every interval.

    The film is checked alone over each substrate it lies on (nothing above it to hide its error).
    """
    axis = np.linspace(lo, hi, n)
    midpoints = (axis[:-1, None] + np.diff(axis)[:, None] * np.arange(1, 8) / 8).ravel()
    table = OpticalTable.build(material, axis, mode, space, bands)
    at_midpoints = OpticalTable.build(material, midpoints, mode, space, bands)
    worst = 0.0
    for substrate in substrates:
        interpolated = composite([table], [midpoints], substrate, mode)
        direct = composite([at_midpoints], [midpoints], substrate, mode)
        dE = colour.delta_E(space.to_Lab(interpolated), space.to_Lab(direct), method="CIE 2000")
        worst = max(worst, float(np.max(dE)))
    return worst


def plan_render(
    scene_materials: Mapping[str, FilmCoefficients],
    stacks: Sequence[Stack],
    thickness_ranges: Mapping[str, tuple[float, float]],
    illuminant: str = "D65",
    accuracy_target_dE: float | None = None,
    mode: str | None = None,
    observer: str = "2",
    max_bands: int | None = None,
) -> RenderPlan:
    """Plan the optical tables of a scene.

    Parameters
    ----------
    scene_materials
        Materials by name (K, S per mm on one wavelength grid).
    stacks
        The scene's stacks; materials in no stack, stacks without layers and repeated stacks (same layers and
        substrate) get no tables and are listed as dropped.
    thickness_ranges
        (min, max) film thickness per material, mm; min == max is a single thickness: no thickness axis.
    accuracy_target_dE
        Largest Delta E 2000 allowed against exact (default :data:`DEFAULT_TARGET_DE`).
    mode
        Force a render mode ("rgb", "bands:N", "exact"); its error is still measured and reported.
    max_bands
        Most bands a ``bands:N`` candidate may have (a renderer's channel limit); exact follows the last one.
    """
    target = DEFAULT_TARGET_DE if accuracy_target_dE is None else float(accuracy_target_dE)
    dropped = []
    kept: list[Stack] = []
    for stack in stacks:
        twin = next(
            (k for k in kept if k.layers == stack.layers and np.array_equal(k.substrate, stack.substrate)), None
        )
        if not stack.layers:
            dropped.append(f"stack {stack.name}: no layers (bare substrate) -> no tables")
        elif twin is not None:
            dropped.append(f"stack {stack.name}: same layers and substrate as {twin.name} -> measured once")
        else:
            kept.append(stack)
    if not kept:
        raise ValueError("the scene has no stack with layers: nothing to plan")
    used = tuple(dict.fromkeys(name for stack in kept for name in stack.layers))
    for name in used:
        if name not in scene_materials or name not in thickness_ranges:
            raise ValueError(f"material {name!r} is used by a stack but has no coefficients or no thickness range")
    dropped += [f"material {name}: not in any stack -> no table" for name in scene_materials if name not in used]
    dropped += [
        f"thickness range of {name}: material not used -> ignored" for name in thickness_ranges if name not in used
    ]
    ranges = {name: (float(thickness_ranges[name][0]), float(thickness_ranges[name][1])) for name in used}
    dropped += [
        f"material {name}: single thickness {lo:g} mm -> no thickness axis"
        for name, (lo, hi) in ranges.items()
        if lo == hi
    ]

    space = working_space(scene_materials[used[0]].wavelengths, illuminant, observer)
    candidates = []
    for candidate in [mode] if mode is not None else candidate_modes(len(space.wavelengths), max_bands):
        errors = mode_error(kept, candidate, scene_materials, ranges, illuminant, observer)
        candidates.append(ModeCandidate(candidate, float(errors.max()), float(errors.mean())))
        if candidates[-1].max_dE <= target:
            break
    chosen = candidates[-1].mode

    kind, n_bands = parse_mode(chosen)
    bands = band_partition(space.wavelengths, n_bands, space=space) if kind == "bands" else None
    n_channels = {"rgb": 3, "bands": n_bands, "exact": len(space.wavelengths)}[kind]
    tables = []
    for name in used:
        lo, hi = ranges[name]
        n, error = 1, 0.0
        if hi > lo:
            substrates = [s.substrate for s in kept if name in s.layers]
            n = 2
            error = _interpolation_error(scene_materials[name], lo, hi, n, substrates, chosen, space, bands)
            while error > INTERPOLATION_FRACTION * target and n < MAX_SAMPLES:
                n = 2 * n - 1
                error = _interpolation_error(scene_materials[name], lo, hi, n, substrates, chosen, space, bands)
        tables.append(TableSize(name, lo, hi, n, n_channels, error))
    return RenderPlan(
        illuminant,
        observer,
        target,
        chosen,
        mode is not None,
        used,
        tuple(kept),
        ranges,
        tuple(candidates),
        tuple(tables),
        tuple(dropped),
    )


@dataclass(frozen=True)
class ScenePlan:
    """The render plan of a scene: its optical tables, then the scene-level choices: shadows and their maps, the skin's
    passes.

    Attributes
    ----------
    tables
        The plan of the optical tables (:func:`plan_render`).
    shadow_map_size
        Texels per side of each shadow map, or None when no map is made.
    shadow_lights
        Whether each light of the scene (in its order) gets a shadow map.
    skin_lobe
        The skin's own specular lobe, or None (no lobe, or no skin).
    scattering
        The skin's subsurface scattering, or None (off, or no skin).
    notes
        What the plan decided beyond the tables and why, one line each (see :meth:`explain`).
    ambient_occlusion
        Whether the mesh's ambient occlusion is baked (:mod:`renderer.occlusion`) to darken the environment's light.
    antialiasing
        How the frames take their ``[output] antialias`` samples: "none", "multisample" or "supersample"
        (:mod:`kmpipe.stages.antialiasing`).
    antialias_side
        Samples a pixel per side (k: k x k) where the plan sets them (a choice measured by ``kmpipe trade``,
        :mod:`kmpipe.stages.frame_choice`); None: the scene's ``[output] antialias``.
    """

    tables: RenderPlan
    shadow_map_size: int | None
    shadow_lights: tuple[bool, ...]
    skin_lobe: Specular | None = None
    scattering: Scattering | None = None
    notes: tuple[str, ...] = field(default=())
    ambient_occlusion: bool = False
    antialiasing: Method = "supersample"
    antialias_side: int | None = None

    @property
    def mode(self) -> str:
        return self.tables.mode

    def antialias(self, scene: Scene) -> int:
        """Samples a pixel per side the frames take: the plan's, else the scene's ``[output] antialias``."""
        return self.antialias_side or scene.info.output.antialias

    def explain(self) -> str:
        """What ``kmpipe render --explain`` prints: the tables' plan (:meth:`RenderPlan.explain`), then the notes."""
        lines = [self.tables.explain(), "Scene:"]
        lines += [f"  {note}" for note in self.notes]
        return "\n".join(lines)


def placed_bounds(scene: Scene) -> tuple[np.ndarray, float, float]:
    """Centre (mm) and radius (mm) of the bounding sphere of the scene's mesh as placed by its model matrix (centred on
    its bounding box), and its lowest world y (mm)."""
    vertices = np.asarray(scene.mesh.vertices) @ scene.model[:3, :3].T + scene.model[:3, 3]
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    return centre, float(np.max(np.linalg.norm(vertices - centre, axis=1))), float(vertices[:, 1].min())


#: Reach (radii of the product's bounding sphere) of a backdrop's sweep from the product's centre
#: (kmpipe.stages.staging.SWEEP_SIZE: half its width, its floor in front, its wall's height).
SWEEP_REACH = 10.0


def scene_reach(scene: Scene) -> float:
    """Radius (mm) about the product's centre that holds everything drawn: the product, its ground or backdrop."""
    _, radius, _ = placed_bounds(scene)
    backdrop = scene.info.backdrop
    if backdrop is not None and backdrop.kind == "sweep":
        return radius * SWEEP_REACH
    return radius * (GROUND_EXTENT * math.sqrt(2.0) if scene.info.ground is not None else 1.0)


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
    r"""The scene's render plan: mode and tables, then shadows, the skin's passes and the other per-frame work.

    A point light inside the product's bounding sphere is refused here (InputError naming its position).

    >>> import kmpipe, pathlib, tempfile
    >>> from kmpipe.formats.scene import load_scene
    >>> from kmpipe.stages.fit import fit_manifests
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> _ = fit_manifests([F1 / "manifest.toml"], folder / "F1.json", method="black-white")
    >>> _ = (folder / "card.toml").write_text(
    ...     '[scene]\nname = "F1"\naccuracy = 0.5\n[substrate]\nreflectance = 0.5\n'
    ...     '[[layer]]\nmaterial = "F1.json"\nthickness = "20 um"\n')
    >>> plan = plan_scene(load_scene(folder / "card.toml"))
    >>> chosen = next(c for c in plan.tables.candidates if c.mode == plan.mode)  # the cheapest within the target
    >>> bool(chosen.max_dE <= 0.5), plan.mode in [c.mode for c in plan.tables.candidates]
    (True, True)
    """
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
    floor = "ground" if scene.info.ground is not None else None
    if scene.info.backdrop is not None and scene.info.backdrop.kind == "sweep":
        floor = "backdrop sweep"
    wanted = [light.shadows for light in lights]
    self_shadowing = can_shadow_itself(scene.mesh)
    size = None
    if not any(wanted):
        notes.append("shadow maps: no light casts shadows -> none made")
    elif not (self_shadowing or floor is not None):
        notes.append(
            f"shadow maps: the {scene.info.scene.mesh} mesh is flat or convex and there is no ground or sweep, so "
            "nothing can shadow anything -> none made"
        )
        wanted = [False] * len(lights)
    else:
        longer = max(scene.info.resolution)
        size = settings.shadow_map or int(
            np.clip(2 ** math.ceil(math.log2(SHADOW_TEXELS_PER_PIXEL * longer)), *SHADOW_MAP_SIZES)
        )
        casters = "the product" + (" (it can shadow itself)" if self_shadowing else "")
        notes.append(
            f"shadow maps: {sum(wanted)} of {len(lights)} lights cast shadows of {casters}"
            f"{f' onto the {floor}' if floor else ''}; {size} x {size} texels, 3 x 3 PCF"
        )
        soft = [f"{i + 1} ({f'{light.angle_deg:g} deg' if light.kind == 'directional' else f'{light.size_mm:g} mm'})"
                for i, light in enumerate(lights) if wanted[i] and (light.angle_deg or light.size_mm)]  # fmt: skip
        if soft:
            notes.append(f"soft shadows (area lights: percentage-closer soft shadows, 16 + 16 taps, at half the "
                         f"resolution, filtered and upsampled along each surface): lights "
                         f"{', '.join(soft)}")  # fmt: skip
    _check_point_lights(scene, wanted)
    notes.append(plan_notes.backdrop_note(scene))
    notes.append(plan_notes.detail_note(scene))
    occluded = scene.info.environment is not None and self_shadowing
    notes += plan_notes.environment_notes(scene, self_shadowing, floor)
    lobes = [i + 1 for i, layer in enumerate(scene.info.layer) if layer.specular is not None]
    notes.append(f"specular lobes: layers {', '.join(map(str, lobes))}" if lobes else "specular lobes: none")
    antialiasing = plan_antialiasing(scene, placed_bounds(scene)[1])
    notes.append(antialiasing.note)
    skin_lobe, scattering = _skin_lobe(scene), _skin_scattering(scene)
    notes += plan_notes.skin_notes(scene, skin_lobe, scattering)
    return ScenePlan(tables, size, tuple(wanted), skin_lobe, scattering, tuple(notes), occluded, antialiasing.method)


def _check_point_lights(scene: Scene, shadows: list[bool]) -> None:
    """Refuse a point light inside the product's bounding sphere (on or in the product, at some turn of the
    turntable, where its inverse-square falloff has no finite value), and a shadowing one inside the scene's reach
    (its shadow map looks at the scene from outside it)."""
    centre, radius, _ = placed_bounds(scene)
    reach = scene_reach(scene)
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
                f"{' and its ground or backdrop' if reach > radius else ''}): move it, or set shadows = false",
                path=scene.path,
                field=f"light[{index + 1}].position",
            )


def _skin_lobe(scene: Scene) -> Specular | None:
    """The skin's own specular lobe (its default: :data:`renderer.stack.SKIN_SPECULAR`), or None."""
    specular = None if scene.info.skin is None else scene.info.skin.specular
    if specular is True:
        return SKIN_SPECULAR
    return None if specular is None or specular is False else Specular(specular.roughness, specular.ior)


def _skin_scattering(scene: Scene) -> Scattering | None:
    """The skin's subsurface scattering, or None when it is off (or there is no skin)."""
    scattering = None if scene.info.skin is None else scene.info.skin.scattering
    if scattering is None or scattering is False:
        return None
    return Scattering() if scattering is True else Scattering(**scattering.model_dump())
