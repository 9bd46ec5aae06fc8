"""Recipe files (TOML) for ``kmpipe run``: a product line, where its materials come from, and how to render it.

A recipe names the line (illuminant, accuracy or render mode), the validation thresholds, the scene every product is
rendered in (the tables of a scene file, :mod:`kmpipe.formats.scene`, at the top level: ``[scene]`` without name,
product and shade, ``[substrate]`` or ``[skin]``, ``[[light]]``, ``[ground]`` or ``[backdrop]``, ``[environment]``,
``[camera]``, ``[turntable]``, ``[output]``;
no ``[[layer]]``), the products and the outputs. Each product has a name, a shade, where its material comes from (a
CS-2000 session to measure live and fit, a recorded session to replay and fit, measurements to fit, or a material
file; or none, for a look made of other products' materials), its layer stack (top first; ``material`` is ``"self"``
or another product's name) and optional overrides of the template's mesh, substrate or skin.

Nothing in a recipe is executed: it is data. Input paths are relative to the recipe's folder and only read; every
output goes under the run's output folder, and an output path that would leave it is refused. Every problem is an
:class:`~kmpipe.errors.InputError` naming the file, line and field.
"""

from __future__ import annotations

import copy
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationError, field_validator, model_validator

from kmpipe.errors import InputError
from kmpipe.formats.files import UNLIMITED, regular_file
from kmpipe.formats.scene import MAX_LAYERS, RenderSettings, SceneFile
from kmpipe.formats.thresholds import Thresholds
from kmpipe.formats.toml_input import StrictModel, input_error, located_in, read_model, toml_line
from kmpipe.physics.colorimetry import illuminant_key, is_spd_file, register_illuminant

#: The material of the product itself, in its layer stack.
SELF = "self"
#: Where a product's material can come from.
SOURCES = ("measure", "replay", "fit", "material")


class LineInfo(RenderSettings):
    name: str = Field(min_length=1)
    gl: Literal["auto", "osmesa", "egl"] | None = None  # the OpenGL platform (kmpipe.stages.opengl); None: as set


class ValidationInfo(StrictModel):
    illuminants: list[str] = Field(default=["D65"], min_length=1)
    delta_e_warn: float | None = None
    delta_e_fail: float | None = None
    rmse_warn: float | None = None
    rmse_fail: float | None = None
    uncertainty_warn: float | None = None  # the rendered colour's 95 % radius, Delta E 2000
    uncertainty_fail: float | None = None

    @field_validator("illuminants")
    @classmethod
    def _known_illuminants(cls, names: list[str]) -> list[str]:
        for name in names:
            illuminant_key(name)  # the one resolver: refused here, before any product is measured or fitted
        return names


def _illuminant_id(name: str) -> str:
    """An illuminant's identity: its CIE key (ValueError if unknown), or an SPD file's name as written (the file is
    read when the recipe is loaded)."""
    return name if is_spd_file(name) else illuminant_key(name)


class ReviewInfo(StrictModel):
    """``[review]``: the shade review (kmpipe.stages.review): foundations (product names of the line, each worn at the
    thickness of its own layer), skin tones (kmpipe.formats.skin_tones), illuminants, the reference illuminant among
    them and the Delta E 2000 under which a pair matches."""

    foundations: list[str] = Field(min_length=1)
    tones: list[str] = Field(default=["builtin"], min_length=1)
    illuminants: list[str] = Field(default=["D65", "A", "FL11"], min_length=1, max_length=8)
    reference: str = "D65"
    thickness: str | None = None  # worn thickness of every foundation (default: each product's own layer's)
    match_delta_e: float = Field(default=2.0, gt=0.0, le=50.0)
    tile: int = Field(default=256, ge=64, le=1024)

    @field_validator("illuminants")
    @classmethod
    def _known_illuminants(cls, names: list[str]) -> list[str]:
        if len({_illuminant_id(n) for n in names}) != len(names):
            raise ValueError(f"illuminants are listed once each, got {', '.join(names)}")
        return names

    @model_validator(mode="after")
    def _reference_among_them(self) -> ReviewInfo:
        if _illuminant_id(self.reference) not in [_illuminant_id(n) for n in self.illuminants]:
            raise ValueError(f"the reference illuminant {self.reference!r} must be one of the illuminants "
                             f"({', '.join(self.illuminants)})")  # fmt: skip
        return self


class ReplaySource(StrictModel):
    log: str = Field(min_length=1)
    plan: str = Field(min_length=1)


class MeasureSource(StrictModel):
    plan: str = Field(min_length=1)
    port: str = Field(min_length=1)
    baudrate: int = Field(default=115200, gt=0, le=4_000_000)


class ProductInfo(StrictModel):
    name: str = Field(min_length=1, max_length=80)
    shade: str | None = None
    measure: MeasureSource | None = None
    replay: ReplaySource | None = None
    fit: str | None = None
    material: str | None = None
    mesh: str | None = None
    substrate: dict[str, Any] | None = None
    skin: dict[str, Any] | None = None
    layer: list[dict[str, Any]] = Field(default=[], max_length=MAX_LAYERS)

    @field_validator("name")
    @classmethod
    def _plain_name(cls, value: str) -> str:
        if value.strip() != value or value.lower() == SELF or any(c in value for c in "/\\\0"):
            raise ValueError(f"a product name is plain text without slashes, not {SELF!r}, got {value!r}")
        return value

    @model_validator(mode="after")
    def _one_source(self) -> ProductInfo:
        given = [k for k in SOURCES if getattr(self, k) is not None]
        if len(given) > 1:
            raise ValueError(f"give one source of the material ({', '.join(SOURCES)}), not {' and '.join(given)}")
        if not given and not self.layer:
            raise ValueError(f"a product needs a source of its material ({', '.join(SOURCES)}) or a layer stack")
        return self

    @property
    def source(self) -> str | None:
        return next((k for k in SOURCES if getattr(self, k) is not None), None)


class OutputsInfo(StrictModel):
    frames: str = Field(default="frames", min_length=1)
    reports: str = Field(default="reports", min_length=1)
    sheet: str | None = "sheet.png"
    sheet_columns: int = Field(default=4, ge=1, le=36)
    review: str = Field(default="review", min_length=1)

    @field_validator("sheet")
    @classmethod
    def _png(cls, value: str | None) -> str | None:
        if value is not None and (not value.lower().endswith(".png") or Path(value).name.lower() == ".png"):
            raise ValueError(f"the contact sheet is a PNG file: expected a name ending in .png, got {value!r}")
        return value


#: Scene-file tables a recipe holds at its top level, for every product.
SCENE_TABLES = (
    "scene", "substrate", "skin", "light", "ground", "backdrop", "environment", "camera", "turntable", "output",
)  # fmt: skip


class RecipeFile(StrictModel):
    line: LineInfo
    validation: ValidationInfo = ValidationInfo()
    scene: dict[str, Any] = Field(default_factory=dict)
    substrate: dict[str, Any] | None = None
    skin: dict[str, Any] | None = None
    light: list[dict[str, Any]] | None = None
    ground: dict[str, Any] | None = None
    backdrop: dict[str, Any] | None = None
    environment: dict[str, Any] | None = None
    camera: dict[str, Any] | None = None
    turntable: dict[str, Any] | None = None
    output: dict[str, Any] | None = None
    product: list[ProductInfo] = Field(min_length=1)
    outputs: OutputsInfo = OutputsInfo()
    review: ReviewInfo | None = None

    def template(self) -> dict:
        """The scene-file tables the recipe gives every product."""
        return {key: getattr(self, key) for key in SCENE_TABLES if getattr(self, key) is not None}

    @model_validator(mode="after")
    def _distinct_products(self) -> RecipeFile:
        names = [p.name for p in self.product]
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise ValueError(f"product names must differ; repeated: {', '.join(repeated)}")
        slugs = [slug(n) for n in names]
        clashing = sorted({n for n, s in zip(names, slugs, strict=True) if slugs.count(s) > 1})
        if clashing:
            raise ValueError(f"product names that make the same folder name: {', '.join(clashing)}")
        return self


def slug(name: str) -> str:
    """A product's folder name: lower case letters, digits and dashes (never empty, never '.' or '..')."""
    text = re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-")
    return text or "product"


@dataclass(frozen=True)
class Recipe:
    """A checked recipe: its file, text and fields, with every input file resolved."""

    path: Path
    text: str
    info: RecipeFile
    thresholds: Thresholds

    @property
    def base(self) -> Path:
        return self.path.parent

    def where(self, loc: tuple) -> dict:
        """InputError's path, line and field for a location in the recipe."""
        return located_in(self.path, self.text)(loc)

    def product(self, name: str) -> ProductInfo:
        return next(p for p in self.info.product if p.name == name)

    def scene_data(self, product: ProductInfo, materials: dict[str, Path]) -> dict:
        """The scene-file data of one product: the template, its overrides, its layers with material paths.

        ``materials`` maps product names to their material files (absolute paths).
        """
        data = copy.deepcopy(self.info.template())
        info = self.info.line
        data.setdefault("scene", {})
        data["scene"].update(name=info.name, product=product.name, shade=product.shade or product.name)
        data["scene"].setdefault("illuminant", info.illuminant)
        if info.accuracy is not None:
            data["scene"]["accuracy"] = info.accuracy
        if info.mode is not None:
            data["scene"]["mode"] = info.mode
        if product.mesh is not None:
            data["scene"]["mesh"] = product.mesh
        for key in ("substrate", "skin"):
            if getattr(product, key) is not None:
                data.pop("substrate", None)
                data.pop("skin", None)
        for key in ("substrate", "skin"):
            if getattr(product, key) is not None:
                data[key] = copy.deepcopy(getattr(product, key))
        data["layer"] = []
        for layer in product.layer:
            entry = copy.deepcopy(layer)
            owner = product.name if entry.get("material") == SELF else entry.get("material")
            entry["material"] = str(materials[owner])
            data["layer"].append(entry)
        return data

    def scene_where(self, index: int):
        """Locator for a product's composed scene: its layers and overrides are the product's, the rest the
        recipe's own tables (named as in a scene file)."""

        def where(loc: tuple) -> dict:
            loc = tuple(loc)
            product = self.info.product[index]
            if loc and loc[0] == "layer":
                return self.where(("product", index, *loc))
            if loc and loc[0] in ("substrate", "skin") and getattr(product, loc[0]) is not None:
                return self.where(("product", index, *loc))
            if loc[:2] == ("scene", "mesh") and product.mesh is not None:
                return self.where(("product", index, "mesh"))
            if not loc or loc[0] == "__root__":
                return self.where(("product", index))
            return self.where(loc)

        return where


def inside(out_dir: Path, relative: str, where: dict) -> Path:
    """``out_dir / relative`` with its ``.`` and ``..`` taken out, refused (InputError at ``where``) if ``relative``
    is absolute or climbs out of ``out_dir``. This is the recipe's text; symlinks in the output folder are checked
    where the run writes (:mod:`kmpipe.run.planning`)."""
    normal = os.path.normpath(relative)
    if Path(relative).is_absolute() or normal == os.pardir or normal.startswith(os.pardir + os.sep):
        raise InputError(f"{relative!r} would write outside the output folder; give a path inside it", **where)
    return out_dir / normal


def load_recipe(path: str | Path) -> Recipe:
    """Read and check a recipe: fields, product references, input files and each product's scene.

    >>> import kmpipe, pathlib
    >>> recipe = load_recipe(pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "demo" / "recipe.toml")
    >>> [(product.name, product.source) for product in recipe.info.product][:2]
    [('Lipstick Classic Red', 'replay'), ('Lipstick Berry', 'replay')]
    """
    path = Path(path)
    text, info = read_model(path, "recipe", RecipeFile)
    recipe = Recipe(path, text, info, _thresholds(info.validation, path, text))
    _check_template(recipe)
    names = {p.name for p in info.product}
    for i, product in enumerate(info.product):
        for source, key in ((product.fit, "fit"), (product.material, "material")):
            if source is not None:
                _existing(recipe, source, ("product", i, key))
        if product.replay is not None:
            _existing(recipe, product.replay.log, ("product", i, "replay", "log"))
            _existing(recipe, product.replay.plan, ("product", i, "replay", "plan"))
        if product.measure is not None:
            _existing(recipe, product.measure.plan, ("product", i, "measure", "plan"))
        for j, layer in enumerate(product.layer):
            owner = layer.get("material")
            if not isinstance(owner, str):
                raise InputError(f"expected 'self' or the name of a product of the recipe (text), got {owner!r}",
                                 **recipe.where(("product", i, "layer", j, "material")))  # fmt: skip
            if owner == SELF and product.source is None:
                raise InputError("names 'self', but the product has no material of its own", **recipe.where(
                    ("product", i, "layer", j, "material")))  # fmt: skip
            if owner != SELF and owner not in names:
                raise InputError(
                    f"names {owner!r}: expected 'self' or the name of a product of the recipe "
                    f"({', '.join(sorted(names))})",
                    **recipe.where(("product", i, "layer", j, "material")),
                )
            if owner != SELF and recipe.product(owner).source is None:
                raise InputError(f"names {owner!r}, a product without a material of its own", **recipe.where(
                    ("product", i, "layer", j, "material")))  # fmt: skip
        if product.layer:
            _check_product_scene(recipe, i)
    if info.review is not None:
        _check_review(recipe)
    for key in ("frames", "reports", "sheet", "review"):
        value = getattr(info.outputs, key)
        if value is not None:
            inside(Path("."), value, recipe.where(("outputs", key)))
    return recipe


def review_foundations(recipe: Recipe) -> list[tuple[str, str, float]]:
    """The review's foundations: (product, shade, thickness in mm), the thickness that of the product's own layer
    (its ``thickness``, or a thickness map's ``max``)."""
    from kmpipe.formats.manifest import parse_thickness_mm

    found = []
    for i, name in enumerate(recipe.info.review.foundations):
        at = recipe.where(("review", "foundations", i))
        if name not in {p.name for p in recipe.info.product}:
            raise InputError(f"names {name!r}, which is not a product of the recipe", **at)
        product = recipe.product(name)
        own = [layer for layer in product.layer if layer.get("material") == SELF]
        if product.source is None or not own:
            raise InputError(f"names {name!r}, which has no material of its own in its layer stack: a foundation "
                             "of the review needs both (its thickness is its own layer's)", **at)  # fmt: skip
        layer = own[0]
        given = recipe.info.review.thickness or (
            layer.get("thickness")
            if layer.get("thickness") is not None
            else (layer.get("thickness_map") or {}).get("max")
        )
        try:
            thickness = parse_thickness_mm(given, allow_zero=False)
        except (InputError, TypeError, ValueError):
            raise InputError(f"{name!r}: its own layer gives no thickness the review can wear it at (a thickness, or "
                             "a thickness map's max, above 0)", **at) from None  # fmt: skip
        found.append((name, product.shade or name, thickness))
    names = [f[0] for f in found]
    if len(set(names)) != len(names):
        raise InputError("lists a foundation twice", **recipe.where(("review", "foundations")))
    return found


def review_illuminant_files(recipe: Recipe) -> dict[str, tuple[Path, str | None]]:
    """The review's illuminants that are SPD files (``FILE.csv[:COLUMN]``, relative to the recipe): name -> (path,
    column)."""
    found = {}
    for name in recipe.info.review.illuminants:
        if is_spd_file(name):
            file, _, column = name.partition(":")
            found[name] = (recipe.base / file, column or None)
    return found


def _check_review(recipe: Recipe) -> None:
    """[review]: known foundations with their thickness; tone sources that exist (their spectra are read by the
    review's tasks, on the materials' grid)."""
    if recipe.info.review.thickness is not None:
        from kmpipe.formats.manifest import parse_thickness_mm

        try:
            parse_thickness_mm(recipe.info.review.thickness, allow_zero=False)
        except (InputError, ValueError) as err:
            raise InputError(getattr(err, "message", str(err)), **recipe.where(("review", "thickness"))) from None
    review_foundations(recipe)
    for name, (path, column) in review_illuminant_files(recipe).items():
        i = recipe.info.review.illuminants.index(name)
        if not path.is_file():
            raise InputError(
                f"names the SPD file {path}, which does not exist", **recipe.where(("review", "illuminants", i))
            )
        register_illuminant(name, path, column)
    from kmpipe.formats.skin_tones import source_kind

    for i, source in enumerate(recipe.info.review.tones):
        kind, rest = source_kind(source, recipe.where(("review", "tones", i)))
        if kind != "builtin":
            _existing(recipe, rest.partition(":")[0] if kind == "csv" else rest, ("review", "tones", i))


def _thresholds(info: ValidationInfo, path: Path, text: str) -> Thresholds:
    values = info.model_dump(exclude={"illuminants"})
    try:
        return Thresholds().updated(**values)
    except InputError as err:
        field = f"validation.{err.field}" if err.field else "validation"
        raise InputError(err.message, path=path, line=toml_line(text, ("validation", err.field)), field=field) from None


def _existing(recipe: Recipe, relative: str, loc: tuple) -> Path:
    target = recipe.base / relative
    try:
        regular_file(target, "input", limit=UNLIMITED)  # the reader applies its format's limit
    except InputError as err:
        raise InputError(f"names {target}, which {err.message.split(';')[0]}", **recipe.where(loc)) from None
    return target


def _check_template(recipe: Recipe) -> None:
    """[scene] holds what a scene file's does, but the name, product and shade: the line and products give those."""
    for key in ("name", "product", "shade"):
        if key in recipe.info.scene:
            raise InputError(f"scene.{key} comes from [line] and the products; remove it",
                             **recipe.where(("scene", key)))  # fmt: skip


def _check_product_scene(recipe: Recipe, index: int) -> None:
    """Validate a product's composed scene as a scene file (materials stand in by name; files exist later)."""
    product = recipe.info.product[index]
    owners = {product.name, *(layer["material"] for layer in product.layer)} - {SELF}
    stand_ins = {name: Path(f"{slug(name)}.json") for name in owners}
    data = recipe.scene_data(product, stand_ins)
    try:
        SceneFile.model_validate(data)
    except ValidationError as err:
        raise input_error(err, recipe.scene_where(index)) from None
    where = recipe.scene_where(index)
    for j, layer in enumerate(product.layer):
        mapping = layer.get("thickness_map")
        if isinstance(mapping, dict) and "file" in mapping:
            _existing(recipe, mapping["file"], ("product", index, "layer", j, "thickness_map"))
    for key in ("substrate", "skin"):
        table = data.get(key) or {}
        if table.get("albedo_texture"):
            target = recipe.base / table["albedo_texture"]
            if not target.is_file():
                raise InputError(f"names {target}, which does not exist", **where((key, "albedo_texture")))


#: Most render contexts in which one material's rendered colour is validated.
MAX_CONTEXTS = 4


def render_contexts(recipe: Recipe, material: str) -> list[dict]:
    """Where the material of product ``material`` is rendered in the line: each layer made of it with a uniform
    thickness, over its product's substrate or skin (a context of :func:`kmpipe.validation.material.validate_material`:
    ``label``, ``thickness_mm``, ``over``, ``base``), at most :data:`MAX_CONTEXTS`, each once."""
    from kmpipe.formats.manifest import parse_thickness_mm
    from kmpipe.formats.scene import SkinInfo

    found: dict[tuple, dict] = {}
    for product in recipe.info.product:
        for layer in product.layer:
            named = product.name if layer.get("material") == SELF else layer.get("material")
            if named != material or not isinstance(layer.get("thickness"), str):
                continue
            data = recipe.scene_data(product, {p.name: Path(p.name) for p in recipe.info.product})
            base = data.get("substrate") or data.get("skin") or {}
            over = base.get("reflectance", SkinInfo.model_fields["reflectance"].default)
            thickness = parse_thickness_mm(layer["thickness"], allow_zero=True)
            key = (thickness, str(over))
            if key not in found and thickness > 0.0 and len(found) < MAX_CONTEXTS:
                found[key] = {"label": f"{product.name}: {layer['thickness']} over {over}", "thickness_mm": thickness,
                              "over": over, "base": str(recipe.base), "field": f"product {product.name!r}"}  # fmt: skip
    return list(found.values())
