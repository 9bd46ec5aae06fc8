"""The render plan's file, ``plan.json``: what :func:`kmpipe.stages.render_plan.plan_scene` decided for a scene, so
that its frames are rendered from it without planning again (``kmpipe run``'s ``plan`` task writes it beside a
product's frames; its ``render`` tasks read it).

The file (docs/formats.md, "Render plan (JSON)") holds the scene it was planned for (its name, the SHA-256 of its
fields, and each layer's material with the SHA-256 of the material file), the chosen mode, the plan of the optical
tables (illuminant, observer, target, the stacks and thickness ranges planned on, every mode tried with its Delta E
2000 against exact, each material's table: its thickness axis and channels), what was dropped and why, the
scene-level choices (shadow maps and the lights that cast them, the skin's lobe and subsurface scattering) with their
notes, and the lines that ``kmpipe render --explain`` prints for the same plan. Numbers are written as Python's
``repr`` (which JSON reads back to the same float64), so a plan read back renders the same pixels as the plan it was
written from.

:func:`read_plan` reads it strictly: a file that is not a kmpipe render plan, a damaged one (a missing or unknown
field, a value of the wrong type or out of range, fields that disagree with each other or with the explanation), or
one planned for another scene is an :class:`~kmpipe.errors.InputError` naming the file and the field.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.atomic_write import write_text_atomically
from kmpipe.formats.scene import MAX_LAYERS, Scene
from kmpipe.formats.toml_input import first_validation_error, format_field
from kmpipe.physics.optical_tables import Stack, parse_mode
from kmpipe.stages.frame_choice import FrameChoice, apply_choice, scene_fingerprint
from kmpipe.stages.render_plan import MAX_SAMPLES, ModeCandidate, RenderPlan, ScenePlan, TableSize, plan_scene
from renderer.scene import MAX_SUPERSAMPLING, Scattering
from renderer.stack import MAX_CHANNELS, Specular

#: The value of the ``format`` field: kmpipe's render plan, version 1.
PLAN_FORMAT = "kmpipe-render-plan/1"


def plan_to_file(scene: Scene, path: str | Path, choice: FrameChoice | None = None) -> ScenePlan:
    """The plan stage: plan ``scene`` (:func:`~kmpipe.stages.render_plan.plan_scene`), with the frame settings
    ``kmpipe trade`` chose for it (:func:`kmpipe.stages.frame_choice.apply_choice`; None: none measured), and write
    its plan file to ``path`` (atomically); the plan.

    >>> import kmpipe, pathlib, tempfile
    >>> from kmpipe.formats.scene import load_scene
    >>> from kmpipe.stages.fit import fit_manifests
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1" / "manifest.toml"
    >>> _ = fit_manifests([F1], folder / "F1.json")
    >>> _ = (folder / "card.toml").write_text(
    ...     '[scene]\\nname = "F1"\\nmode = "rgb"\\n[substrate]\\nreflectance = 0.5\\n'
    ...     '[[layer]]\\nmaterial = "F1.json"\\nthickness = "20 um"\\n')
    >>> scene = load_scene(folder / "card.toml")
    >>> plan = plan_to_file(scene, folder / "plan.json")
    >>> again = read_plan(folder / "plan.json", scene)
    >>> again.mode, again.explain() == plan.explain()
    ('rgb', True)
    """
    plan = apply_choice(plan_scene(scene), scene, choice)
    write_plan(plan, scene, path)
    return plan


def write_plan(plan: ScenePlan, scene: Scene, path: str | Path) -> None:
    """Write ``plan``, planned for ``scene``, as a plan file at ``path`` (a temporary file, then renamed)."""
    tables = plan.tables
    layers = zip(scene.materials, scene.material_hashes, strict=True)
    document = {
        "format": PLAN_FORMAT,
        "scene": scene.name,
        "scene_sha256": scene_fingerprint(scene),
        "layers": [{"material": material.name, "sha256": sha256} for material, sha256 in layers],
        "mode": tables.mode,
        "forced": tables.forced,
        "illuminant": tables.illuminant,
        "observer": tables.observer,
        "target_dE": tables.target_dE,
        "materials": list(tables.materials),
        "stacks": [
            {"name": s.name, "layers": list(s.layers), "substrate": s.substrate.tolist()} for s in tables.stacks
        ],
        "thickness_ranges": {name: list(lo_hi) for name, lo_hi in tables.thickness_ranges.items()},
        "candidates": [dataclasses.asdict(candidate) for candidate in tables.candidates],
        "tables": [dataclasses.asdict(table) for table in tables.tables],
        "dropped": list(tables.dropped),
        "shadow_map_size": plan.shadow_map_size,
        "shadow_lights": list(plan.shadow_lights),
        "skin_lobe": None if plan.skin_lobe is None else dataclasses.asdict(plan.skin_lobe),
        "scattering": None if plan.scattering is None else dataclasses.asdict(plan.scattering),
        "ambient_occlusion": plan.ambient_occlusion,
        "antialiasing": plan.antialiasing,
        "antialias_side": plan.antialias_side,
        "notes": list(plan.notes),
        "explain": plan.explain().split("\n"),
    }
    write_text_atomically(Path(path), json.dumps(document, indent=1, allow_nan=False) + "\n")


# ------------------------------------------------------------------------------------------------------ reading ---


class _Strict(BaseModel):
    """Unknown fields refused, types exact (no number from a string, no integer from a float), finite numbers."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


_Name = Annotated[str, Field(min_length=1)]
_NonNegative = Annotated[float, Field(ge=0.0)]
_Reflectance = Annotated[float, Field(ge=0.0, le=1.0)]
_Range = Annotated[list[_NonNegative], Field(min_length=2, max_length=2)]


class _Layer(_Strict):
    material: _Name
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")


class _Stack(_Strict):
    name: str
    layers: list[str] = Field(min_length=1, max_length=MAX_LAYERS)
    substrate: list[_Reflectance] = Field(min_length=1)


class _Candidate(_Strict):
    mode: str
    max_dE: _NonNegative
    mean_dE: _NonNegative


class _Table(_Strict):
    material: _Name
    min_mm: _NonNegative
    max_mm: _NonNegative
    n_samples: int = Field(ge=1, le=MAX_SAMPLES)
    n_channels: int = Field(ge=1)
    interpolation_dE: _NonNegative


class _Lobe(_Strict):
    roughness: float = Field(gt=0.0, le=2.0)
    ior: float = Field(ge=1.0, le=4.0)


class _Scattering(_Strict):
    alpha: float = Field(gt=0.0)
    beta: _NonNegative
    gradient_clamp: _NonNegative


class _PlanFile(_Strict):
    format: Literal["kmpipe-render-plan/1"]
    scene: _Name
    scene_sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    layers: list[_Layer] = Field(min_length=1, max_length=MAX_LAYERS)
    mode: str
    forced: bool
    illuminant: _Name
    observer: _Name
    target_dE: float = Field(gt=0.0)
    materials: list[_Name] = Field(min_length=1, max_length=MAX_LAYERS)
    stacks: list[_Stack] = Field(min_length=1)
    thickness_ranges: dict[str, _Range]
    candidates: list[_Candidate] = Field(min_length=1)
    tables: list[_Table]
    dropped: list[str]
    shadow_map_size: int | None = Field(ge=64, le=8192)
    shadow_lights: list[bool] = Field(min_length=1)
    skin_lobe: _Lobe | None
    scattering: _Scattering | None
    ambient_occlusion: bool
    antialiasing: Literal["none", "multisample", "supersample"] = "supersample"  # (older plans: supersample)
    antialias_side: int | None = Field(default=None, ge=1, le=MAX_SUPERSAMPLING)  # (older plans: the scene's)
    notes: list[str]
    explain: list[str]


def read_plan(path: str | Path, scene: Scene) -> ScenePlan:
    r"""Read the plan file at ``path`` and check that it is a plan of ``scene``; the plan, as planned.

    InputError naming the file and the field when the file is not a kmpipe render plan, is damaged (see the module's
    docstring), or was planned for another scene: another scene name, other materials (by name and SHA-256, layer by
    layer), another number of lights or another wavelength grid.

    >>> import kmpipe, pathlib, tempfile
    >>> from kmpipe.formats.scene import load_scene
    >>> from kmpipe.stages.fit import fit_manifests
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> _ = fit_manifests([F1 / "manifest.toml"], folder / "F1.json", method="black-white")
    >>> for name in ("A", "B"):
    ...     _ = (folder / f"{name}.toml").write_text(f'[scene]\nname = "{name}"\nmode = "rgb"\n'
    ...         '[substrate]\nreflectance = 0.5\n[[layer]]\nmaterial = "F1.json"\nthickness = "20 um"\n')
    >>> _ = plan_to_file(load_scene(folder / "A.toml"), folder / "plan.json")
    >>> read_plan(folder / "plan.json", load_scene(folder / "A.toml")).mode
    'rgb'
    >>> try:
    ...     read_plan(folder / "plan.json", load_scene(folder / "B.toml"))  # the plan of another scene
    ... except InputError as err:
    ...     print(err.field)
    scene
    """
    path = Path(path)
    document = files.read_json(path, "JSON", "kmpipe render plan")
    if not isinstance(document, dict) or document.get("format") != PLAN_FORMAT:
        found = document.get("format") if isinstance(document, dict) else None
        raise InputError(f"not a kmpipe render plan: format is {found!r}, expected {PLAN_FORMAT!r}", path=path,
                         field="format")  # fmt: skip
    try:
        fields = _PlanFile.model_validate(document)
    except ValidationError as err:
        first = first_validation_error(err)
        message = "unknown field" if first["type"] == "extra_forbidden" else first["msg"]
        raise _damaged(path, format_field(first["loc"]), message) from None
    plan = _checked(fields, path)
    _check_scene(fields, scene, path)
    return plan


def _damaged(path: Path, field: str, message: str) -> InputError:
    return InputError(f"a damaged render plan: {message}; plan the scene again (kmpipe run does once the file is "
                      "deleted)", path=path, field=field)  # fmt: skip


def _checked(fields: _PlanFile, path: Path) -> ScenePlan:
    """The ScenePlan of validated fields, after the checks across fields (InputError naming the field)."""
    try:
        kind, n_bands = parse_mode(fields.mode)
    except ValueError as err:
        raise _damaged(path, "mode", str(err)) from None
    if kind == "bands" and n_bands > MAX_CHANNELS:
        raise _damaged(path, "mode", f"the layer pass composes at most {MAX_CHANNELS} bands")
    if fields.candidates[-1].mode != fields.mode or (fields.forced and len(fields.candidates) != 1):
        raise _damaged(path, "candidates", f"the chosen mode {fields.mode} is the last one tried (the only one when "
                       "forced)")  # fmt: skip
    used = fields.materials
    if [t.material for t in fields.tables] != used or list(fields.thickness_ranges) != used:
        raise _damaged(path, "tables", "one table and one thickness range per material in use, in its order")
    n_wavelengths = len(fields.stacks[0].substrate)
    channels = {"rgb": 3, "bands": n_bands, "exact": n_wavelengths}[kind]
    for index, table in enumerate(fields.tables, 1):
        if fields.thickness_ranges[table.material] != [table.min_mm, table.max_mm] or table.min_mm > table.max_mm:
            raise _damaged(path, f"thickness_ranges.{table.material}", "[min_mm, max_mm] of the material's table")
        if (table.n_samples == 1) != (table.min_mm == table.max_mm):
            raise _damaged(path, f"tables[{index}].n_samples", "1 exactly when the range is a single thickness")
        if table.n_channels != channels:
            raise _damaged(path, f"tables[{index}].n_channels", f"mode {fields.mode} has {channels} channels")
    for index, stack in enumerate(fields.stacks, 1):
        if len(stack.substrate) != n_wavelengths or not set(stack.layers) <= set(used):
            raise _damaged(path, f"stacks[{index}]", f"a substrate of {n_wavelengths} reflectances, materials in use")
    tables = RenderPlan(
        fields.illuminant,
        fields.observer,
        fields.target_dE,
        fields.mode,
        fields.forced,
        tuple(used),
        tuple(Stack(s.name, tuple(s.layers), np.array(s.substrate, dtype=np.float64)) for s in fields.stacks),
        {name: (lo, hi) for name, (lo, hi) in fields.thickness_ranges.items()},
        tuple(ModeCandidate(**c.model_dump()) for c in fields.candidates),
        tuple(TableSize(**t.model_dump()) for t in fields.tables),
        tuple(fields.dropped),
    )
    side = fields.antialias_side
    if side is not None and ((fields.antialiasing == "none") != (side == 1) or
                             (fields.antialiasing == "multisample" and side != 2)):  # fmt: skip
        raise _damaged(path, "antialias_side", "1 exactly without antialiasing, 2 (4 samples) with multisampling")
    lobe = None if fields.skin_lobe is None else Specular(**fields.skin_lobe.model_dump())
    scattering = None if fields.scattering is None else Scattering(**fields.scattering.model_dump())
    plan = ScenePlan(tables, fields.shadow_map_size, tuple(fields.shadow_lights), lobe, scattering, tuple(fields.notes),
                     fields.ambient_occlusion, fields.antialiasing, fields.antialias_side)  # fmt: skip
    if plan.explain() != "\n".join(fields.explain):
        raise _damaged(path, "explain", "it is not the explanation of the plan's other fields")
    return plan


#: What :func:`_check_scene` compares, by field of the plan file.
_IDENTITY = {
    "scene": "scene name",
    "layers": "materials (layer by layer, by name and by the SHA-256 of the material file)",
    "scene_sha256": "fields (mesh, substrate or skin, layers, lights, camera, ...)",
    "shadow_lights": "number of lights",
    "stacks": "wavelength grid",
}


def _check_scene(fields: _PlanFile, scene: Scene, path: Path) -> None:
    """Refuse a plan planned for another scene than ``scene``."""
    planned = {
        "scene": fields.scene,
        "layers": [(layer.material, layer.sha256) for layer in fields.layers],
        "scene_sha256": fields.scene_sha256,
        "shadow_lights": len(fields.shadow_lights),
        "stacks": len(fields.stacks[0].substrate),
    }
    actual = {
        "scene": scene.name,
        "layers": [(m.name, sha256) for m, sha256 in zip(scene.materials, scene.material_hashes, strict=True)],
        "scene_sha256": scene_fingerprint(scene),
        "shadow_lights": len(scene.info.light),
        "stacks": len(scene.wavelengths),
    }
    for field, what in _IDENTITY.items():
        if planned[field] != actual[field]:
            raise InputError(f"is the plan of another scene: its {what} differ from those of {scene.name!r} "
                             f"({scene.path}); plan the scene again (kmpipe run does once the file is deleted)",
                             path=path, field=field)  # fmt: skip
