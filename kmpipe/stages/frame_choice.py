"""The frame settings the planner takes from measurement: antialiasing, shadow-map size and subsurface scattering as
``kmpipe trade`` chose them on a product's own frame (:func:`kmpipe.stages.trade.choose_frame_settings`).

The render mode and the thickness tables are planned on the scene's stacks (:mod:`kmpipe.stages.render_plan`): their
error against exact is within the scene's Delta E 2000 target there. What the frame adds on top (how silhouettes are
sampled, how fine the shadow map is, whether the skin's light is blurred) shows only in a frame, and gets the same
target of its own: ``kmpipe trade`` renders the product's first turntable frame with those knobs at their most exact,
then lowers them one at a time, cheapest setting first, keeping a lower setting while 95 % of the product's pixels
stay within the target of that most exact frame (the 95th percentile of the per-pixel Delta E 2000: the mean would
let a few stair-stepped silhouettes or a blocky shadow edge pass). The choice, its measured time and error, and the
scene it was measured on (:func:`scene_fingerprint`) go into ``trade.json``; ``kmpipe run`` into
the same output folder plans each product with its choice (:func:`apply_choice`): only the knobs the scene leaves to
the planner (:func:`free_knobs`) are set, and a choice measured on another version of the scene is not used (the
plan says so). ``kmpipe render SCENE --measure-settings`` makes the same choice on a scene file's first frame
(:func:`kmpipe.stages.trade.measure_frame_choice`) and renders the turntable with it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass

from kmpipe.formats.scene import Scene
from kmpipe.stages.antialiasing import renderer_fields
from kmpipe.stages.render_plan import SHADOW_MAP_SIZES, ScenePlan

#: Antialiasing settings, cheapest first: (label, method, samples a pixel per side).
ANTIALIASING = (("1 sample", "none", 1), ("4 x multisampling", "multisample", 2),
                ("2 x 2 supersampling", "supersample", 2), ("3 x 3 supersampling", "supersample", 3))  # fmt: skip
#: Antialiasing settings the choice tries: one sample a pixel is not among them. Its stair-stepped silhouettes are
#: some 3 % of a product's pixels, which no Delta E statistic over the product sees (the 95th percentile of a 384 px
#: lipstick moved by 0.05) but a viewer does; a scene that wants it says ``antialias = 1``.
CHOSEN_ANTIALIASING = tuple(label for label, _, side in ANTIALIASING if side > 1)
#: Shadow-map sizes tried (texels a side), cheapest first.
SHADOW_MAPS = (512, 1024, 2048, SHADOW_MAP_SIZES[1])
#: Subsurface scattering, cheapest first.
SCATTERING = ("off", "on")


@dataclass(frozen=True)
class FrameChoice:
    """What ``kmpipe trade`` chose for one product's frames.

    ``antialiasing`` (a label of :data:`CHOSEN_ANTIALIASING`), ``shadow_map`` (texels a side) and ``scattering``
    ("on" or "off") are None where the knob is not the planner's to choose (:func:`free_knobs`). ``mean_de`` and
    ``p95_de`` are the Delta E 2000 of the chosen frame against the frame with those knobs at their most exact, over
    the product's pixels (``p95_de`` within ``target_de``); ``reference_de`` its mean against the most exact frame of
    all (exact mode, every knob at its most exact: what the mode and the other knobs add); ``seconds`` its render
    time; ``tried``: frames rendered to choose.
    """

    scene_sha256: str
    target_de: float
    antialiasing: str | None
    shadow_map: int | None
    scattering: str | None
    seconds: float
    mean_de: float
    p95_de: float
    reference_de: float
    tried: int


def scene_fingerprint(scene: Scene) -> str:
    """SHA-256 (hex) of a scene's fields, each layer's material by the SHA-256 of its file: what tells one scene from
    another (another product of a line, another mesh, other lights), wherever its files lie."""
    fields = scene.info.model_dump(mode="json")
    for layer, sha256 in zip(fields["layer"], scene.material_hashes, strict=True):
        layer["material"] = sha256
    return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()


def free_knobs(scene: Scene, plan: ScenePlan) -> dict[str, tuple]:
    """The knobs of the scene's frames left to the planner, each with its settings cheapest first: antialiasing
    unless ``[output] antialias`` or ``antialias_method`` is given, the shadow map where shadows are cast and
    ``[scene] shadow_map`` is not given, subsurface scattering where the skin scatters and ``[skin] scattering`` is
    not given."""
    output, knobs = scene.info.output, {}
    if "antialias" not in output.model_fields_set and output.antialias_method == "auto":
        knobs["antialiasing"] = CHOSEN_ANTIALIASING
    if plan.shadow_map_size is not None and scene.info.scene.shadow_map is None:
        knobs["shadow map"] = SHADOW_MAPS
    skin = scene.info.skin
    if plan.scattering is not None and skin is not None and "scattering" not in skin.model_fields_set:
        knobs["subsurface scattering"] = SCATTERING
    return knobs


def _method_and_side(label: str) -> tuple[str, int]:
    """The antialiasing method and samples a pixel per side of an :data:`ANTIALIASING` label."""
    _, method, side = next(choice for choice in ANTIALIASING if choice[0] == label)
    return method, side


def antialiasing_fields(label: str) -> dict[str, int]:
    """``supersampling`` and ``multisamples`` of a renderer scene for an :data:`ANTIALIASING` label."""
    return renderer_fields(*_method_and_side(label))


def apply_choice(plan: ScenePlan, scene: Scene, choice: FrameChoice | None, by: str = "kmpipe trade") -> ScenePlan:
    """``plan`` with the frame settings of ``choice`` (measured ``by`` ``kmpipe trade`` on this product, or by
    ``kmpipe render --measure-settings`` on this scene) on the knobs the scene leaves to the planner, its notes saying
    so; as it is, with a note why, where the choice was measured on another version of the scene; as it is without a
    choice (the plan of a ``kmpipe render`` that does not measure)."""
    if choice is None:
        return plan
    if choice.scene_sha256 != scene_fingerprint(scene):
        return dataclasses.replace(plan, notes=(*plan.notes, "frame settings: by the planner's rules (kmpipe trade's "
                                                "choice was measured on another version of this scene: run kmpipe "
                                                "trade again)"))  # fmt: skip
    knobs = free_knobs(scene, plan)
    notes = list(plan.notes)
    changes: dict = {}
    if "antialiasing" in knobs and choice.antialiasing is not None:
        method, side = _method_and_side(choice.antialiasing)
        changes.update(antialiasing=method, antialias_side=side)
        notes = _replaced(notes, "antialiasing:", f"antialiasing: {choice.antialiasing} -- chosen by {by}")
    if "shadow map" in knobs and choice.shadow_map is not None:
        changes["shadow_map_size"] = choice.shadow_map
        old = f"{plan.shadow_map_size} x {plan.shadow_map_size} texels"
        notes = [note.replace(old, f"{choice.shadow_map} x {choice.shadow_map} texels (chosen by {by})")
                 if note.startswith("shadow maps:") else note for note in notes]  # fmt: skip
    if "subsurface scattering" in knobs and choice.scattering == "off":
        changes["scattering"] = None
        notes = _replaced(notes, "subsurface scattering:", f"subsurface scattering: off -- chosen by {by} (the frame "
                                                           "is within the target without it)")  # fmt: skip
    notes.append(
        f"frame settings: measured by {by} on this product's frame: the cheapest antialiasing, shadow map and "
        f"subsurface scattering with 95 % of the product's pixels within Delta E 2000 {choice.target_de:g} of the "
        f"frame with them at their most exact (95th percentile {choice.p95_de:.2f}, mean {choice.mean_de:.2f}; "
        f"against the most exact frame of all, mode included: mean {choice.reference_de:.2f}; {choice.seconds:.2f} s "
        f"a frame; {choice.tried} frames tried)"
    )
    return dataclasses.replace(plan, notes=tuple(notes), **changes)


def _replaced(notes: list[str], start: str, note: str) -> list[str]:
    return [note if line.startswith(start) else line for line in notes]
