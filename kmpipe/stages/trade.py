"""The speed/accuracy trade of a product line, measured on its own products (``kmpipe trade``).

For each product, one frame (the turntable's first) is rendered as the planner plans it (measured once: it is also
every knob's planned setting), then with one knob at a time set otherwise, and at the most exact setting of every
knob at once (the reference): exact render mode, 3 x 3 supersampling, soft shadows at every pixel, the largest
shadow map, the environment at its full size, subsurface scattering on, the materials as fitted. For each setting:
the time of its frame (the render alone, after a warm-up; what it adds before the frame, a refit or an environment's
prefilter, counted where the knob moves it) and the Delta E 2000 of each of the product's pixels against the
reference (linear sRGB -> XYZ -> CIELAB, D65), its mean and 95th percentile, and the mean against the planned frame.
The product's pixels are those the product itself covers, found by rendering it alone.

The knobs (:data:`KNOBS`), each reported "not applicable" where it cannot change the product's frame (no skin: no
subsurface scattering; no area light: no soft-shadow sampling; one thickness: no thickness axis; no environment;
a material given as a file: no refit):

- ``mode``: the render mode (rgb, bands:N, exact) forced;
- ``thickness samples``: the samples of the thickness tables (a map's films), halved or doubled from the plan's;
- ``antialiasing``: 1 sample, 4 x multisampling, 2 x 2 or 3 x 3 supersampling;
- ``soft shadows``: at half the resolution or at every pixel;
- ``shadow map``: texels a side;
- ``subsurface scattering``: on or off;
- ``environment``: the environment map's width (its prefilter's cost goes with it);
- ``resolution``: half the frame's (compared with the reference box-filtered to that size);
- ``fit``: the materials refitted on a 10 or 20 nm grid, or by the closed-form black-white method (the refit's time).

The Pareto front is over the settings of every knob with the times and errors summed (times) and averaged (mean
Delta E) over the products: the settings no other beats on both. ``trade.csv``, ``trade.json`` and ``trade.png``
(time against Delta E, the front drawn) are written into the output folder (docs/formats.md, "Trade").
"""

from __future__ import annotations

import dataclasses
import functools
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import colour
import numpy as np

from kmpipe.formats.scene import Scene, build_scene
from kmpipe.physics.colorimetry import delta_E_2000
from kmpipe.stages.frame_choice import (
    ANTIALIASING,
    SHADOW_MAPS,
    FrameChoice,
    antialiasing_fields,
    free_knobs,
    scene_fingerprint,
)
from kmpipe.stages.render_plan import DEFAULT_TARGET_DE, SHADOW_MAP_SIZES, ScenePlan, parse_mode, plan_scene

#: The knobs, in the order the tables list them.
KNOBS = ("planned", "mode", "thickness samples", "antialiasing", "soft shadows", "shadow map",
         "subsurface scattering", "environment", "resolution", "fit")  # fmt: skip
#: Environment widths (pixels) tried.
ENVIRONMENT_WIDTHS = (64, 128)
#: Refits tried: (label, grid, method).
REFITS = (("10 nm grid", "380:780:10", None), ("20 nm grid", "380:780:20", None), ("black-white", None, "black-white"))


@dataclass(frozen=True)
class Setting:
    """One measured setting of one product: ``seconds`` None where the knob does not apply (``note`` says why)."""

    product: str
    knob: str
    value: str
    seconds: float | None
    mean_de: float | None
    p95_de: float | None
    planned: bool = False
    note: str = ""
    shift_de: float | None = None  # mean Delta E 2000 against the frame as planned: what this setting alone moves


def _lab(image: np.ndarray) -> np.ndarray:
    """CIELAB (D65, 2 degrees) of linear sRGB."""
    xyz = colour.RGB_to_XYZ(np.clip(image, 0.0, None), colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False)
    return colour.XYZ_to_Lab(xyz, colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])


def _box(image: np.ndarray, k: int) -> np.ndarray:
    """``image`` box-filtered by k x k blocks (its sides cut to multiples of k)."""
    h, w = (image.shape[0] // k) * k, (image.shape[1] // k) * k
    return image[:h, :w].reshape(h // k, k, w // k, k, -1).mean(axis=(1, 3))


def delta_e_stats(image: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """Mean and 95th percentile of the per-pixel Delta E 2000 between two linear sRGB frames over ``mask``."""
    d = delta_E_2000(_lab(image[mask]), _lab(reference[mask]))
    return float(np.mean(d)), float(np.percentile(d, 95))


class _Product:
    """One product's scene, its planned frame and reference, and how to render variants of it; ``rebuild(paths)``
    gives its scene with materials from other files (name: path), None where none can be (a scene file); ``plan``
    the scene's plan where the caller has it (planned here otherwise)."""

    def __init__(self, name: str, scene: Scene, rebuild: Callable[[dict], Scene] | None,
                 plan: ScenePlan | None = None) -> None:  # fmt: skip
        from kmpipe.stages.render import renderer_scenes
        from renderer.layers import render_layers
        from renderer.skin import render_skin

        self.name, self.scene, self.rebuild = name, scene, rebuild
        self.on_skin = scene.info.skin is not None
        self._render = render_skin if self.on_skin else render_layers
        self._scenes = renderer_scenes
        self.plan = plan_scene(scene) if plan is None else plan
        [self.frame] = renderer_scenes(scene, self.plan, [0.0])
        exact_scene = _with_mode(scene, "exact")
        [exact] = renderer_scenes(exact_scene, plan_scene(exact_scene), [0.0], occlusion=self.frame.occlusion)
        self.reference = self.render(dataclasses.replace(
            exact, supersampling=3, multisamples=1, soft_shadow_scale=1, shadow_map_size=SHADOW_MAP_SIZES[1]
        ))[1]  # fmt: skip
        alone = dataclasses.replace(exact, props=(), background=(0.0, 0.0, 0.0), supersampling=1, multisamples=1)
        self.mask = self.render(alone)[1].max(axis=-1) > 0.0

    @functools.cached_property
    def _planned(self) -> tuple[float, np.ndarray, tuple[float, float]]:
        """The planned frame's seconds, image and (mean, 95th percentile) Delta E 2000 against the reference, rendered
        when first asked for (choosing frame settings alone does not need it)."""
        seconds, image = self.render(self.frame)
        return seconds, image, delta_e_stats(image, self.reference, self.mask)

    @property
    def planned_seconds(self) -> float:
        return self._planned[0]

    @property
    def planned(self) -> np.ndarray:
        return self._planned[1]

    @property
    def planned_de(self) -> tuple[float, float]:
        return self._planned[2]

    def render(self, frame) -> tuple[float, np.ndarray]:
        """(seconds of a render after a warm-up one, the image)."""
        self._render(frame)
        start = time.perf_counter()
        image = self._render(frame)
        return time.perf_counter() - start, image

    def render_once(self, frame) -> np.ndarray:
        """The image of one render, untimed."""
        return self._render(frame)

    def frame_of(self, scene: Scene, plan: ScenePlan | None = None):
        plan = plan_scene(scene) if plan is None else plan
        [frame] = self._scenes(scene, plan, [0.0], occlusion=self.frame.occlusion)
        return frame

    def measure(self, knob: str, value: str, frame, extra_s: float = 0.0, planned: bool = False) -> Setting:
        seconds, image = self.render(frame)
        mean, p95 = delta_e_stats(image, self.reference, self.mask)
        shift = delta_e_stats(image, self.planned, self.mask)[0]
        return Setting(self.name, knob, value, seconds + extra_s, mean, p95, planned, shift_de=shift)

    def as_planned(self, knob: str, value: str, note: str = "") -> Setting:
        """The knob's setting that is the plan's: the planned frame, measured once for every knob."""
        return Setting(self.name, knob, value, self.planned_seconds, *self.planned_de, True, note, shift_de=0.0)

    def either(self, knob: str, value: str, planned: bool, frame) -> Setting:
        """:meth:`as_planned` where ``planned``, else ``frame`` measured."""
        return self.as_planned(knob, value) if planned else self.measure(knob, value, frame)

    def not_applicable(self, knob: str, why: str) -> Setting:
        return Setting(self.name, knob, "-", None, None, None, note=f"not applicable: {why}")


def _with_mode(scene: Scene, mode: str) -> Scene:
    settings = scene.info.scene.model_copy(update={"mode": mode})
    return dataclasses.replace(scene, info=scene.info.model_copy(update={"scene": settings}))


def _modes(product: _Product) -> list[Setting]:
    out = []
    for candidate in ("rgb", "bands:3", "bands:6", "bands:9", "bands:12", "exact"):
        scene = _with_mode(product.scene, candidate)
        kind, bands = parse_mode(candidate)
        if kind == "bands" and bands > len(scene.wavelengths):
            continue
        out.append(product.measure("mode", candidate, product.frame_of(scene), planned=candidate == product.plan.mode))
    return out


def _thickness_samples(product: _Product) -> list[Setting]:
    tables = product.plan.tables.tables
    if parse_mode(product.plan.mode)[0] == "exact":
        return [product.not_applicable("thickness samples", "exact mode composes each frame without tables")]
    if not any(table.n_samples > 1 for table in tables):
        return [product.not_applicable("thickness samples", "every film has one thickness")]
    out = []
    for label, factor in (("half the plan's", 0.5), ("the plan's", 1.0), ("twice the plan's", 2.0)):
        resized = tuple(
            dataclasses.replace(table, n_samples=max(2, round((table.n_samples - 1) * factor) + 1))
            if table.n_samples > 1 else table
            for table in tables
        )  # fmt: skip
        plan = dataclasses.replace(product.plan, tables=dataclasses.replace(product.plan.tables, tables=resized))
        counts = "/".join(str(t.n_samples) for t in resized if t.n_samples > 1)
        if factor == 1.0:
            out.append(product.as_planned("thickness samples", label, note=f"samples: {counts}"))
            continue
        setting = product.measure("thickness samples", label, product.frame_of(product.scene, plan))
        out.append(dataclasses.replace(setting, note=f"samples: {counts}"))
    return out


def _antialiasing(product: _Product) -> list[Setting]:
    frame = product.frame
    planned = {"supersampling": frame.supersampling, "multisamples": frame.multisamples}
    return [product.either("antialiasing", label, antialiasing_fields(label) == planned,
                           dataclasses.replace(frame, **antialiasing_fields(label)))
            for label, _, _ in ANTIALIASING]  # fmt: skip


def _soft_shadows(product: _Product) -> list[Setting]:
    frame = product.frame
    if not any(light.cast_shadows and light.softness > 0.0 for light in frame.lights):
        return [product.not_applicable("soft shadows", "no area light casts shadows")]
    return [product.either("soft shadows", label, scale == frame.soft_shadow_scale,
                           dataclasses.replace(frame, soft_shadow_scale=scale))
            for label, scale in (("at half resolution", 2), ("at every pixel", 1))]  # fmt: skip


def _shadow_map(product: _Product) -> list[Setting]:
    frame = product.frame
    if not any(light.cast_shadows for light in frame.lights):
        return [product.not_applicable("shadow map", "no light casts shadows")]
    sizes = sorted({*SHADOW_MAPS, frame.shadow_map_size})
    return [product.either("shadow map", f"{size} texels", size == frame.shadow_map_size,
                           dataclasses.replace(frame, shadow_map_size=size)) for size in sizes]  # fmt: skip


def _scattering(product: _Product) -> list[Setting]:
    frame = product.frame
    if not product.on_skin or frame.scattering is None:
        return [product.not_applicable("subsurface scattering", "no skin (or its scattering is off)")]
    return [product.as_planned("subsurface scattering", "on"),
            product.measure("subsurface scattering", "off", dataclasses.replace(frame, scattering=None))]  # fmt: skip


def _environment(product: _Product) -> list[Setting]:
    from renderer import environment as module

    frame = product.frame
    if frame.environment is None:
        return [product.not_applicable("environment", "no environment light")]
    full = frame.environment
    out = []
    for width in ENVIRONMENT_WIDTHS:
        if width >= full.radiance.shape[1]:
            continue
        k = full.radiance.shape[1] // width
        radiance = _box(np.asarray(full.radiance, np.float64), k).astype(np.float32)
        smaller = dataclasses.replace(full, radiance=radiance)
        start = time.perf_counter()
        module.prefiltered(smaller)
        prefilter = time.perf_counter() - start
        out.append(product.measure("environment", f"{radiance.shape[1]} x {radiance.shape[0]} px",
                                   dataclasses.replace(frame, environment=smaller), prefilter))  # fmt: skip
    rows, columns = full.radiance.shape[:2]
    return [*out, product.as_planned("environment", f"{columns} x {rows} px")]


def _resolution(product: _Product) -> list[Setting]:
    frame = product.frame
    width, height = frame.resolution
    half = dataclasses.replace(frame, resolution=(width // 2, height // 2))
    seconds, image = product.render(half)
    reference = _box(product.reference, 2)
    mask = _box(product.mask[..., None].astype(float), 2)[..., 0] >= 1.0
    image = image[: reference.shape[0], : reference.shape[1]]
    mean, p95 = delta_e_stats(image, reference, mask)
    shift = delta_e_stats(image, _box(product.planned, 2), mask)[0]
    full = product.as_planned("resolution", "full", note=f"{width} x {height}")
    note = f"{width // 2} x {height // 2}, against the frames box-filtered to that size"
    return [full, Setting(product.name, "resolution", "half", seconds, mean, p95, note=note, shift_de=shift)]


def _refits(product: _Product, manifests: dict[str, Path | None]) -> list[Setting]:
    from kmpipe.stages.fit import fit_manifests

    if not manifests or any(path is None for path in manifests.values()):
        return [product.not_applicable("fit", "a material is given as a file: nothing to refit")]
    out = [product.as_planned("fit", "as fitted (planned)")]
    with tempfile.TemporaryDirectory(prefix="kmpipe-trade-") as folder:
        for label, grid, method in REFITS:
            start = time.perf_counter()
            paths = {}
            for name, manifest in manifests.items():
                target = Path(folder) / label.replace(" ", "_") / f"{name}.json"
                target.parent.mkdir(parents=True, exist_ok=True)
                fit_manifests([manifest], target, grid=grid, method=method)
                paths[name] = target
            fitting = time.perf_counter() - start
            out.append(product.measure("fit", label, product.frame_of(product.rebuild(paths)), fitting))
    return out


def _with_settings(product: _Product, settings: dict):
    """The product's planned frame with the frame settings ``settings`` (knob: setting, :func:`free_knobs`)."""
    frame = product.frame
    if "antialiasing" in settings:
        frame = dataclasses.replace(frame, **antialiasing_fields(settings["antialiasing"]))
    if "shadow map" in settings:
        frame = dataclasses.replace(frame, shadow_map_size=settings["shadow map"])
    if settings.get("subsurface scattering") == "off":
        frame = dataclasses.replace(frame, scattering=None)
    return frame


def choose_frame_settings(product: _Product, target: float) -> FrameChoice | None:
    """The cheapest antialiasing, shadow map and subsurface scattering of the product's frame within ``target``
    (:mod:`kmpipe.stages.frame_choice`), or None when the scene leaves none of them to the planner.

    From the most exact setting of every free knob (the frame's other knobs as planned), each knob in turn
    (antialiasing first: the most exact one makes every other frame dearer) is lowered to its cheapest setting whose
    frame keeps 95 % of the product's pixels within ``target`` (Delta E 2000) of that most exact frame, trying the
    cheapest first; what is kept stays for the knobs after it.
    """
    knobs = free_knobs(product.scene, product.plan)
    if not knobs:
        return None
    current = {knob: options[-1] for knob, options in knobs.items()}
    best = product.render_once(_with_settings(product, current))
    tried = 1
    for knob, options in knobs.items():
        for option in options[:-1]:  # the most exact is where it stands
            candidate = {**current, knob: option}
            tried += 1
            if delta_e_stats(product.render_once(_with_settings(product, candidate)), best, product.mask)[1] <= target:
                current = candidate
                break
    seconds, image = product.render(_with_settings(product, current))
    mean, p95 = delta_e_stats(image, best, product.mask)
    reference = delta_e_stats(image, product.reference, product.mask)[0]
    return FrameChoice(scene_fingerprint(product.scene), target, current.get("antialiasing"), current.get("shadow map"),
                       current.get("subsurface scattering"), seconds, mean, p95, reference, tried)  # fmt: skip


def measure_frame_choice(scene: Scene, plan: ScenePlan) -> FrameChoice | None:
    """The frame settings of a scene file (planned as ``plan``) chosen on its own first frame for its own target
    (:func:`target_of`, :func:`choose_frame_settings`), as ``kmpipe trade`` chooses them for a line's product: what
    ``kmpipe render --measure-settings`` renders with. None, with nothing rendered, where the scene sets every one of
    them."""
    if not free_knobs(scene, plan):
        return None
    return choose_frame_settings(_Product(scene.name, scene, None, plan), target_of([scene]))


def trade_product(name: str, scene: Scene, rebuild: Callable[[dict], Scene], manifests: dict[str, Path | None],
                  target: float) -> tuple[list[Setting], FrameChoice | None]:  # fmt: skip
    """Every knob's settings for one product (module docstring), and the frame settings chosen for ``target``
    (:func:`choose_frame_settings`); ``rebuild(paths)`` gives its scene with materials from other files (name:
    path), ``manifests`` each material's manifest (None: given as a file)."""
    product = _Product(name, scene, rebuild)
    planned = product.as_planned("planned", "as planned", note=_planned_label(product))
    exact = dataclasses.replace(product.frame_of(_with_mode(scene, "exact")), supersampling=3, multisamples=1,
                                soft_shadow_scale=1, shadow_map_size=SHADOW_MAP_SIZES[1])  # fmt: skip
    settings = [planned, product.measure("planned", "the reference (most exact)", exact)]
    for knob in (_modes, _thickness_samples, _antialiasing, _soft_shadows, _shadow_map, _scattering, _environment,
                 _resolution):  # fmt: skip
        settings += knob(product)
    settings += _refits(product, manifests)
    return settings, choose_frame_settings(product, target)


def _planned_label(product: _Product) -> str:
    frame = product.frame
    aa = {(1, 1): "1 sample", (1, 4): "4 x multisampling"}.get(
        (frame.supersampling, frame.multisamples), f"{frame.supersampling} x {frame.supersampling} supersampling"
    )
    return f"{product.plan.mode}, {aa}, shadow map {frame.shadow_map_size}"


@dataclass(frozen=True)
class Aggregate:
    """A setting over the products it applies to: total seconds, mean of the products' mean Delta E, worst 95th
    percentile, and whether it is on the Pareto front."""

    knob: str
    value: str
    products: int
    seconds: float
    mean_de: float
    p95_de: float
    planned: bool
    shift_de: float
    front: bool = False


def aggregate(settings: Sequence[Setting]) -> list[Aggregate]:
    """The settings summed over products (see :class:`Aggregate`), the Pareto front marked among the settings that
    apply to every product: no other is both faster and closer to the reference (by mean Delta E)."""
    groups: dict[tuple[str, str], list[Setting]] = {}
    for s in settings:
        if s.seconds is not None:
            groups.setdefault((s.knob, s.value), []).append(s)
    rows = []
    for (knob, value), members in groups.items():
        mean, shift = (float(np.mean([getattr(m, name) for m in members])) for name in ("mean_de", "shift_de"))
        rows.append(Aggregate(knob, value, len(members), sum(m.seconds for m in members), mean,
                              max(m.p95_de for m in members), all(m.planned for m in members), shift))  # fmt: skip
    everyone = max((r.products for r in rows), default=0)
    whole = [r for r in rows if r.products == everyone]

    def beaten(r: Aggregate) -> bool:
        return any(
            o.seconds <= r.seconds and o.mean_de <= r.mean_de and (o.seconds, o.mean_de) != (r.seconds, r.mean_de)
            for o in whole
        )

    return [dataclasses.replace(r, front=r.products == everyone and not beaten(r)) for r in rows]


def target_of(scenes: Sequence[Scene]) -> float:
    """The line's Delta E 2000 target: its scenes' accuracy (the tightest), else the planner's default."""
    targets = [s.info.scene.accuracy for s in scenes if s.info.scene.accuracy is not None]
    return min(targets) if targets else DEFAULT_TARGET_DE


def cheapest_within(rows: Sequence[Aggregate], target: float) -> dict[str, Aggregate]:
    """Per knob, the fastest setting whose mean Delta E 2000 is within ``target``."""
    best: dict[str, Aggregate] = {}
    for row in rows:
        if row.knob == "planned" or row.mean_de > target:
            continue
        if row.knob not in best or row.seconds < best[row.knob].seconds:
            best[row.knob] = row
    return best


def rebuild_for(recipe, index: int) -> Callable[[dict], Scene]:
    """``rebuild(paths)``: the scene of product ``index`` of a loaded recipe with its layers' materials from
    ``paths`` (product name: material file)."""
    product = recipe.info.product[index]

    def rebuild(paths: dict) -> Scene:
        data = recipe.scene_data(product, {name: Path(path) for name, path in paths.items()})
        return build_scene(data, recipe.path, recipe.base, recipe.scene_where(index))

    return rebuild
