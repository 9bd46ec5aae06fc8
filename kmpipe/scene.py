"""Scene files (TOML) for ``kmpipe render``: one stack of films over a substrate on a mesh, a light and a camera.

A scene file names the mesh (a built-in shape or a mesh file), the films top first (kmpipe material files and a
thickness each), the substrate reflectance, a directional light, a camera orbiting the mesh and, optionally, a
turntable. Paths are relative to the scene file. Every problem is an :class:`~kmpipe.errors.InputError` naming the
file, line and field.

Camera: world +y is up. The camera looks at the centre of the mesh's bounding box from ``distance_mm`` away, from
the direction given by ``azimuth_deg`` (about +y, 0 is +z, 90 is +x) and ``elevation_deg`` (above the horizontal
plane). The built-in card faces +z, so azimuth 0 and elevation 0 see it head-on; the lipstick and compact stand
upright (their +z axis turned to world +y).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import colour
import numpy as np
import trimesh
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from kmpipe.errors import InputError
from kmpipe.manifest import Thickness, first_validation_error, format_field, parse_thickness_mm, read_toml, toml_line
from kmpipe.material import Material, read_material
from kmpipe.optical_tables import parse_mode

#: Most films in one stack (the layer pass's limit, renderer.layers.MAX_LAYERS).
MAX_LAYERS = 4
#: Built-in meshes by name.
BUILTIN_MESHES = ("card", "sphere", "lipstick", "compact")
COLORCHECKER = "ColorChecker N Ohta"
_PIXELS = Annotated[int, Field(ge=1, le=8192)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class SceneInfo(_Strict):
    name: str = Field(min_length=1)
    illuminant: str = "D65"
    mesh: str = Field(default="card", min_length=1)
    resolution: tuple[_PIXELS, _PIXELS] = (256, 256)
    accuracy: float | None = Field(default=None, gt=0.0)
    mode: str | None = None

    @field_validator("illuminant")
    @classmethod
    def _known_illuminant(cls, value: str) -> str:
        if value not in colour.SDS_ILLUMINANTS:
            raise ValueError(f"unknown illuminant {value!r}; e.g. D65, D50, A, F11")
        return value

    @field_validator("mode")
    @classmethod
    def _known_mode(cls, value: str | None) -> str | None:
        if value is not None:
            parse_mode(value)
        return value


class SubstrateInfo(_Strict):
    reflectance: float | str

    @field_validator("reflectance")
    @classmethod
    def _known_reflectance(cls, value: float | str) -> float | str:
        if isinstance(value, str):
            kind, _, name = value.partition(":")
            if kind != "colorchecker" or name not in colour.SDS_COLOURCHECKERS[COLORCHECKER]:
                raise ValueError(
                    f"expected a number in [0, 1] or 'colorchecker:NAME' (a patch of {COLORCHECKER}, "
                    f"e.g. 'colorchecker:light skin'), got {value!r}"
                )
        elif not (math.isfinite(value) and 0.0 <= value <= 1.0):
            raise ValueError(f"a flat reflectance must lie in [0, 1], got {value}")
        return value


class LayerInfo(_Strict):
    material: str = Field(min_length=1)
    thickness: Thickness


class LightInfo(_Strict):
    direction: tuple[float, float, float] = (0.0, 0.0, 1.0)
    radiance: tuple[
        Annotated[float, Field(ge=0.0)], Annotated[float, Field(ge=0.0)], Annotated[float, Field(ge=0.0)]
    ] = (1.0, 1.0, 1.0)

    @field_validator("direction")
    @classmethod
    def _non_zero(cls, value: tuple[float, float, float]) -> tuple[float, float, float]:
        if not (all(math.isfinite(v) for v in value) and any(v != 0.0 for v in value)):
            raise ValueError("the direction towards the light must be a finite, non-zero vector")
        return value


class CameraInfo(_Strict):
    azimuth_deg: float = 0.0
    elevation_deg: float = Field(default=0.0, gt=-90.0, lt=90.0)
    distance_mm: float = Field(default=200.0, gt=0.0)
    projection: Literal["perspective", "orthographic"] = "perspective"
    fov_deg: float = Field(default=30.0, gt=0.0, lt=180.0)


class TurntableInfo(_Strict):
    frames: int = Field(ge=1, le=3600)


class SceneFile(_Strict):
    scene: SceneInfo
    substrate: SubstrateInfo
    layer: list[LayerInfo] = Field(min_length=1, max_length=MAX_LAYERS)
    light: LightInfo = LightInfo()
    camera: CameraInfo = CameraInfo()
    turntable: TurntableInfo | None = None


@dataclass(frozen=True)
class Scene:
    """A checked scene: its file, the parsed fields, the materials (top first) and the mesh."""

    path: Path
    info: SceneFile
    materials: tuple[Material, ...]
    thicknesses_mm: tuple[float, ...]
    mesh: trimesh.Trimesh
    model: np.ndarray

    @property
    def name(self) -> str:
        return self.info.scene.name

    @property
    def wavelengths(self) -> np.ndarray:
        return self.materials[0].wavelengths

    def frame_azimuths_deg(self) -> list[float]:
        """Camera azimuth of every frame: the camera's, plus 360 i / frames on a turntable."""
        frames = self.info.turntable.frames if self.info.turntable is not None else 1
        return [(self.info.camera.azimuth_deg + 360.0 * i / frames) % 360.0 for i in range(frames)]

    def substrate_reflectance(self) -> np.ndarray:
        """Spectral reflectance of the substrate on the materials' wavelength grid."""
        value = self.info.substrate.reflectance
        wavelengths = self.wavelengths
        if isinstance(value, str):
            sd = colour.SDS_COLOURCHECKERS[COLORCHECKER][value.partition(":")[2]]
            return np.interp(wavelengths, sd.wavelengths, sd.values)
        return np.full(len(wavelengths), float(value))


def _upright() -> np.ndarray:
    """Model matrix turning a product's +z axis to world +y (a -90 degree rotation about x)."""
    model = np.eye(4)
    model[1:3, 1:3] = [[0.0, 1.0], [-1.0, 0.0]]
    return model


def _mesh(name: str, base: Path) -> tuple[trimesh.Trimesh, np.ndarray]:
    from renderer import meshes, products

    if name == "card":
        return meshes.card(50.0, 50.0), np.eye(4)
    if name == "sphere":
        return meshes.sphere(25.0), np.eye(4)
    if name == "lipstick":
        return products.lipstick_bullet(), _upright()
    if name == "compact":
        return products.compact_pan(), _upright()
    return products.load_mesh(base / name), np.eye(4)


def load_scene(path: str | Path) -> Scene:
    """Read and check a scene file, its materials and its mesh; InputError naming the file, line and field."""
    path = Path(path)
    text, data = read_toml(path, "scene file")
    try:
        info = SceneFile.model_validate(data)
    except ValidationError as err:
        first = first_validation_error(err)
        loc = tuple(first["loc"])
        message = "unknown field" if first["type"] == "extra_forbidden" else first["msg"].removeprefix("Value error, ")
        raise InputError(message, path=path, line=toml_line(text, loc), field=format_field(loc)) from None

    base = path.parent
    materials, thicknesses, sources = [], [], {}
    for i, layer in enumerate(info.layer):
        where = {"path": path, "line": toml_line(text, ("layer", i, "material")), "field": f"layer[{i + 1}].material"}
        material_path = base / layer.material
        if not material_path.is_file():
            what = "does not exist" if not material_path.exists() else "is not a file"
            raise InputError(f"names the material file {material_path}, which {what}", **where)
        material = read_material(material_path)
        if material.wavelengths is None:
            raise InputError(f"{material_path} holds camera channels; rendering needs spectral K and S", **where)
        previous = sources.setdefault(material.name, material_path.resolve())
        if previous != material_path.resolve():
            raise InputError(f"{material_path} and {previous} both hold a material named {material.name!r}", **where)
        if materials and not np.array_equal(material.wavelengths, materials[0].wavelengths):
            raise InputError(
                f"{material_path} is on another wavelength grid than {info.layer[0].material}; fit them on one grid",
                **where,
            )
        materials.append(material)
        thicknesses.append(parse_thickness_mm(layer.thickness))

    try:
        mesh, model = _mesh(info.scene.mesh, base)
    except ValueError as err:
        raise InputError(
            f"{err} (expected one of {', '.join(BUILTIN_MESHES)} or a mesh file)",
            path=path,
            line=toml_line(text, ("scene", "mesh")),
            field="scene.mesh",
        ) from None
    return Scene(path, info, tuple(materials), tuple(thicknesses), mesh, model)
