"""Scene files (TOML) for ``kmpipe render``: one stack of films over a substrate on a mesh, lights and a camera.

A scene file names the mesh (a built-in shape or a mesh file), the films top first (kmpipe material files, each with
a uniform thickness or a thickness map, and optionally a specular lobe), the substrate (a product's base) or the skin
(a substrate that scatters light beneath its surface, with a lobe of its own), up to four
directional or point lights (:mod:`kmpipe.formats.scene_lighting`: their sizes, an environment light, a ground or a
backdrop), a camera and, optionally, a turntable. Paths are
relative to the scene file. Every problem is an :class:`~kmpipe.errors.InputError` naming the file, line and field.

Camera: world +y is up. The camera looks at the centre of the mesh's bounding box from ``distance_mm`` away (by
default just far enough for the mesh's bounding sphere to fill 80 % of the image height), from
the direction given by ``azimuth_deg`` (about +y, 0 is +z, 90 is +x) and ``elevation_deg`` (above the horizontal
plane). The built-in card faces +z, so azimuth 0 and elevation 0 see it head-on; the lipstick and compact stand
upright (their +z axis turned to world +y). A turntable turns the product about the vertical axis through its
centre, by 360 / frames degrees a frame; camera, lights and ground stay put, as on a real turntable.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import colour
import numpy as np
import trimesh
from pydantic import Field, ValidationError, field_validator, model_validator

from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.manifest import Thickness, ThicknessOrZero, parse_thickness_mm
from kmpipe.formats.material import Material, read_material
from kmpipe.formats.scene_lighting import (
    MAX_DISTANCE_MM,
    BackdropInfo,
    EnvironmentInfo,
    GroundInfo,
    LightInfo,
    environment_radiance,
)
from kmpipe.formats.surface_maps import ThicknessMapInfo, albedo_texture, normal_map, roughness_map, thickness_map
from kmpipe.formats.toml_input import StrictModel, input_error, located_in, read_toml
from kmpipe.physics.colorimetry import illuminant_key
from kmpipe.physics.optical_tables import parse_mode
from renderer.scene import MAX_RENDER_SIDE, MAX_SUPERSAMPLING

#: Most films in one stack (the layer pass's limit, renderer.stack.MAX_LAYERS).
MAX_LAYERS = 4
#: Most lights in one scene (renderer.scene.MAX_LIGHTS).
MAX_LIGHTS = 4
#: Built-in meshes by name.
BUILTIN_MESHES = ("card", "sphere", "lipstick", "compact", "head", "cylinder")
#: The bundled head (``mesh = "head"``): MakeHuman's CC0 head and neck with its uv and eyes (recipes/head/README.md).
HEAD_DIR = Path(__file__).resolve().parents[2] / "recipes" / "head"
COLORCHECKER = "ColorChecker N Ohta"
#: Frame size (width, height in pixels) when a scene gives none: a look on skin, and a packshot (a product alone).
SKIN_RESOLUTION = (1024, 1024)
PACKSHOT_RESOLUTION = (512, 512)
#: Largest image side (pixels). A frame costs about 200 bytes a pixel on llvmpipe (several RGBA32F targets of 16
#: bytes, the depth buffer, the read-back and the float64 copies of tone mapping and writing): ~3.4 GB at
#: 4096 x 4096, four times that at 8192 x 8192.
MAX_RESOLUTION = 4096
_PIXELS = Annotated[int, Field(ge=1, le=MAX_RESOLUTION)]


class RenderSettings(StrictModel):
    """The illuminant and the render planner's accuracy target or forced mode (a scene's, or a product line's)."""

    illuminant: str = "D65"
    accuracy: float | None = Field(default=None, gt=0.0)
    mode: str | None = None

    @field_validator("illuminant")
    @classmethod
    def _known_illuminant(cls, value: str) -> str:
        illuminant_key(value)  # the one resolver: what validation accepts, a scene accepts
        return value

    @field_validator("mode")
    @classmethod
    def _known_mode(cls, value: str | None) -> str | None:
        """'rgb', 'exact' or 'bands:N' with N at most the layer pass's channels (renderer.stack.MAX_CHANNELS)."""
        from renderer.stack import MAX_CHANNELS

        if value is not None:
            kind, n_bands = parse_mode(value)
            if kind == "bands" and n_bands > MAX_CHANNELS:
                raise ValueError(
                    f"mode {value} has more bands than the layer pass composes ({MAX_CHANNELS}): use bands:N with "
                    f"N <= {MAX_CHANNELS}, or exact"
                )
        return value


class SceneInfo(RenderSettings):
    name: str = Field(min_length=1)
    product: str | None = None
    shade: str | None = None
    mesh: str = Field(default="card", min_length=1)
    resolution: tuple[_PIXELS, _PIXELS] | None = None  # None: SKIN_RESOLUTION on skin, else PACKSHOT_RESOLUTION
    shadow_map: int | None = Field(default=None, ge=64, le=8192)


class SubstrateInfo(StrictModel):
    reflectance: float | str
    albedo_texture: str | None = None
    albedo_encoding: Literal["srgb", "linear"] | None = None
    normal_map: str | None = Field(default=None, min_length=1)  # tangent-space fine detail over uv
    normal_fill: Thickness = "10 um"  # film thickness that smooths the detail by 1/e

    @field_validator("reflectance")
    @classmethod
    def _known_reflectance(cls, value: float | str) -> float | str:
        if isinstance(value, str):
            kind, _, name = value.partition(":")
            if kind == "colorchecker" and name not in colour.SDS_COLOURCHECKERS[COLORCHECKER]:
                raise ValueError(
                    f"{name!r} is not a patch of {COLORCHECKER} (e.g. 'colorchecker:light skin', 'dark skin')"
                )
            if kind != "colorchecker" and not value.partition(":")[0].lower().endswith(".csv"):
                raise ValueError(
                    "expected a number in [0, 1], 'colorchecker:NAME' (a patch of "
                    f"{COLORCHECKER}) or a spectral CSV file 'FILE.csv[:COLUMN]', got {value!r}"
                )
        elif not (math.isfinite(value) and 0.0 <= value <= 1.0):
            raise ValueError(f"a flat reflectance must lie in [0, 1], got {value}")
        return value


class SpecularInfo(StrictModel):
    roughness: float = Field(gt=0.0, le=2.0)
    ior: float = Field(default=1.5, ge=1.0, le=4.0)


class ScatteringInfo(StrictModel):
    alpha: float = Field(default=1.0, gt=0.0, le=1000.0)
    beta: float = Field(default=800.0, ge=0.0, le=1e6)
    gradient_clamp: float = Field(default=0.001, ge=0.0, le=1.0)  # metres of depth per pixel


class SkinInfo(SubstrateInfo):
    """Skin as the films' substrate: its reflectance, its own lobe (True: the default), its scattering."""

    reflectance: float | str = "colorchecker:light skin"
    specular: SpecularInfo | bool = True
    scattering: ScatteringInfo | bool = True
    roughness_map: str | None = Field(default=None, min_length=1)  # the skin lobe's Beckmann m over uv ...
    roughness_scale: float = Field(default=1.0, gt=0.0, le=2.0)  # ... m = value (0 to 1) * roughness_scale


class LayerInfo(StrictModel):
    material: str = Field(min_length=1)
    thickness: ThicknessOrZero | None = None
    thickness_map: ThicknessMapInfo | None = None
    specular: SpecularInfo | None = None

    @model_validator(mode="after")
    def _one_thickness(self) -> LayerInfo:
        if (self.thickness is None) == (self.thickness_map is None):
            raise ValueError("give either thickness or thickness_map")
        return self


#: Samples per pixel side when a scene's [output] gives no ``antialias``: 2 x 2 (4 samples a pixel), clean silhouettes.
DEFAULT_ANTIALIAS = 2


class OutputInfo(StrictModel):
    tone_map: Literal["none", "reinhard", "aces"] = "none"
    exposure_ev: float = Field(default=0.0, ge=-20.0, le=20.0)
    antialias: int = Field(default=DEFAULT_ANTIALIAS, ge=1, le=MAX_SUPERSAMPLING)  # samples per pixel side
    # how they are taken (kmpipe.stages.antialiasing): the planner's choice, or multisampling or supersampling
    antialias_method: Literal["auto", "multisample", "supersample"] = "auto"
    video: list[Literal["mp4", "webp"]] = Field(default=["mp4", "webp"])  # turntable videos (kmpipe.stages.video)
    fps: int = Field(default=24, ge=1, le=120)  # frames per second of the videos


_AIM = Annotated[float, Field(ge=-MAX_DISTANCE_MM, le=MAX_DISTANCE_MM)]


class CameraInfo(StrictModel):
    azimuth_deg: float = Field(default=0.0, ge=-360.0, le=360.0)
    elevation_deg: float = Field(default=0.0, gt=-90.0, lt=90.0)
    distance_mm: float | None = Field(default=None, gt=0.0, le=MAX_DISTANCE_MM)
    projection: Literal["perspective", "orthographic"] = "perspective"
    fov_deg: float = Field(default=30.0, gt=0.0, lt=180.0)
    # the point looked at, from the centre of the placed mesh (mm, world axes: x right, y up, z to the front)
    aim_mm: tuple[_AIM, _AIM, _AIM] = (0.0, 0.0, 0.0)


class TurntableInfo(StrictModel):
    frames: int = Field(ge=1, le=3600)


class SceneFile(StrictModel):
    scene: SceneInfo
    substrate: SubstrateInfo | None = None
    skin: SkinInfo | None = None
    layer: list[LayerInfo] = Field(min_length=1, max_length=MAX_LAYERS)
    light: list[LightInfo] = Field(default=[LightInfo()], min_length=1, max_length=MAX_LIGHTS)
    ground: GroundInfo | None = None
    backdrop: BackdropInfo | None = None
    environment: EnvironmentInfo | None = None
    camera: CameraInfo = CameraInfo()
    turntable: TurntableInfo | None = None
    output: OutputInfo = OutputInfo()

    @model_validator(mode="after")
    def _one_substrate(self) -> SceneFile:
        if (self.substrate is None) == (self.skin is None):
            raise ValueError("give either [substrate] (a product's base) or [skin] (makeup on skin), not both")
        return self

    @property
    def resolution(self) -> tuple[int, int]:
        """The frames' size (width, height) in pixels: the scene's, or the default for a look on skin or a packshot."""
        return default_resolution(self.scene.resolution, self.skin is not None)

    @property
    def base(self) -> SubstrateInfo:
        """What the films lie on: the substrate or the skin."""
        return self.skin if self.skin is not None else self.substrate


def default_resolution(given, on_skin: bool) -> tuple[int, int]:
    """``given`` (width, height) or, if None, :data:`SKIN_RESOLUTION` on skin and :data:`PACKSHOT_RESOLUTION` else."""
    if given is not None:
        return tuple(given)
    return SKIN_RESOLUTION if on_skin else PACKSHOT_RESOLUTION


@dataclass(frozen=True)
class Scene:
    """A checked scene: its file, the parsed fields, the materials (top first) and the mesh.

    ``thicknesses_mm`` holds, per layer (top first), a number (uniform thickness, mm) or a 2-D array (a thickness
    map over the mesh's uv, mm, row 0 at v = 1). ``material_hashes`` are the SHA-256 of the material files.
    ``substrate`` is the spectral reflectance of the substrate or skin on the materials' wavelength grid;
    ``albedo`` its albedo texture, linear RGB (rows, columns, 3) over uv (row 0 at v = 1), or None;
    ``environment`` the environment's equirectangular radiance (:mod:`kmpipe.formats.scene_lighting`), or None;
    ``normal_map`` tangent-space unit vectors (rows, columns, 3), ``roughness`` the skin lobe's Beckmann m (rows,
    columns) and ``occlusion_map`` a mesh file's ambient occlusion (rows, columns), over uv, or None
    (:mod:`kmpipe.formats.surface_maps`). A mesh file's own base colour and normal map stand in for an albedo
    texture and a normal map the scene does not name. The arrays are made read-only: a scene's maps never change,
    which lets the renderer hash each once however many frames use it (:func:`renderer.texture_cache.frozen`).
    """

    path: Path
    info: SceneFile
    materials: tuple[Material, ...]
    thicknesses_mm: tuple[float | np.ndarray, ...]
    material_hashes: tuple[str, ...]
    substrate: np.ndarray
    albedo: np.ndarray | None
    mesh: trimesh.Trimesh
    model: np.ndarray
    inputs: tuple[Path, ...] = ()  # every file the scene reads: the scene, materials, maps, textures, mesh, CSVs
    environment: np.ndarray | None = None
    normal_map: np.ndarray | None = None
    roughness: np.ndarray | None = None
    occlusion_map: np.ndarray | None = None

    def __post_init__(self) -> None:
        maps = (*self.thicknesses_mm, self.substrate, self.albedo, self.environment, self.normal_map, self.roughness,
                self.occlusion_map)  # fmt: skip
        for values in maps:
            if isinstance(values, np.ndarray):
                values.setflags(write=False)

    @property
    def name(self) -> str:
        return self.info.scene.name

    @property
    def wavelengths(self) -> np.ndarray:
        return self.materials[0].wavelengths

    @property
    def product(self) -> str:
        return self.info.scene.product or self.name

    @property
    def shade(self) -> str:
        return self.info.scene.shade or ", ".join(m.name for m in self.materials)

    def turntable_angles_deg(self) -> list[float]:
        """The product's turn in every frame: 360 i / frames on a turntable, else one frame at 0."""
        frames = self.info.turntable.frames if self.info.turntable is not None else 1
        return [360.0 * i / frames for i in range(frames)]

    def thickness_range_mm(self, layer: int) -> tuple[float, float]:
        """(min, max) thickness (mm) of one layer (top first) over the scene."""
        value = np.asarray(self.thicknesses_mm[layer], dtype=float)
        return float(value.min()), float(value.max())

    def substrate_reflectance(self) -> np.ndarray:
        """Spectral reflectance of the substrate (or skin) on the materials' wavelength grid."""
        return self.substrate


def resolve_reflectance(value: float | str, wavelengths: np.ndarray, base: Path, where: dict) -> np.ndarray:
    """A flat reflectance, a ColorChecker patch or a spectral CSV column, on ``wavelengths`` (nm)."""
    from kmpipe.formats.spectra import read_spectra_csv
    from kmpipe.formats.spectral_grid import resample

    if not isinstance(value, str):
        return np.full(len(wavelengths), float(value))
    kind, _, name = value.partition(":")
    if kind == "colorchecker":
        sd = colour.SDS_COLOURCHECKERS[COLORCHECKER][name]
        return np.interp(wavelengths, sd.wavelengths, sd.values)
    csv_path = base / kind
    if not csv_path.is_file():
        raise InputError(f"names the spectral CSV {csv_path}, which does not exist", **where)
    table = read_spectra_csv(csv_path)
    if table.wavelengths is None:
        raise InputError(f"{csv_path} holds camera channels; a reflectance spectrum is needed", **where)
    column = name or table.columns[0]
    if column not in table.columns:
        raise InputError(f"{csv_path} has no column {column!r} (it has {', '.join(table.columns)})", **where)
    if table.wavelengths[0] > wavelengths[0] or table.wavelengths[-1] < wavelengths[-1]:
        raise InputError(
            f"{csv_path} covers {table.wavelengths[0]:g}-{table.wavelengths[-1]:g} nm; the materials need "
            f"{wavelengths[0]:g}-{wavelengths[-1]:g} nm",
            **where,
        )
    values = resample(table, wavelengths).values[table.columns.index(column)]
    if not (np.all(np.isfinite(values)) and values.min() >= 0.0 and values.max() <= 1.0):
        raise InputError(f"{csv_path}, column {column!r}: a reflectance must lie in [0, 1]", **where)
    return values


def _upright() -> np.ndarray:
    """Model matrix turning a product's +z axis to world +y (a -90 degree rotation about x)."""
    model = np.eye(4)
    model[1:3, 1:3] = [[0.0, 1.0], [-1.0, 0.0]]
    return model


def _mesh(name: str, base: Path, where: dict) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A built-in mesh by name, or the mesh file ``base / name`` (a regular file within the mesh size limit)."""
    from renderer import meshes, products

    if name == "card":
        return meshes.card(50.0, 50.0), np.eye(4)
    if name == "sphere":
        return meshes.sphere(25.0), np.eye(4)
    if name == "lipstick":
        return products.lipstick_bullet(), _upright()
    if name == "compact":
        return products.compact_pan(), _upright()
    if name == "head":
        if not (HEAD_DIR / "head.obj").is_file():
            raise InputError(f"the bundled head {HEAD_DIR}/head.obj is missing: run {HEAD_DIR}/make_head.py", **where)
        return products.load_mesh(HEAD_DIR / "head.obj"), np.eye(4)
    if name == "cylinder":
        return meshes.cylinder(40.0, 120.0), np.eye(4)
    path = base / name
    if path.exists():  # a missing file is load_mesh's ValueError, which lists the built-in meshes
        files.regular_file(path, "mesh", **where)
    return products.load_mesh(path), np.eye(4)


def _mesh_and_textures(name: str, base: Path, where: dict):
    """The mesh and its model matrix (:func:`_mesh`) and, for a mesh file, the textures its material brings
    (:func:`renderer.mesh_textures.load_mesh_textures`; empty for a built-in mesh)."""
    from renderer.mesh_textures import MeshTextures, load_mesh_textures

    if name in BUILTIN_MESHES or not (base / name).is_file():
        return (*_mesh(name, base, where), MeshTextures())
    files.regular_file(base / name, "mesh", **where)
    mesh, textures = load_mesh_textures(base / name)
    return mesh, np.eye(4), textures


#: Where a field of a scene is, for error messages: loc (as pydantic gives it) -> InputError's path, line, field.
Locator = Callable[[tuple], dict]


def load_scene(path: str | Path) -> Scene:
    r"""Read and check a scene file, its materials and its mesh; InputError naming the file, line and field.

    >>> import kmpipe, pathlib, tempfile
    >>> from kmpipe.stages.fit import fit_manifests
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> _ = fit_manifests([F1 / "manifest.toml"], folder / "F1.json", method="black-white")
    >>> _ = (folder / "scene.toml").write_text(
    ...     '[scene]\nname = "F1 on a card"\nmesh = "card"\nresolution = [64, 64]\n'
    ...     '[substrate]\nreflectance = 0.8\n'
    ...     '[[layer]]\nmaterial = "F1.json"\nthickness = "30 um"\n'
    ...     '[[light]]\ndirection = [0, 0, 1]\n')
    >>> scene = load_scene(folder / "scene.toml")
    >>> scene.name, [m.name for m in scene.materials], scene.thicknesses_mm, [p.name for p in scene.inputs]
    ('F1 on a card', ['F1'], (0.03,), ['scene.toml', 'F1.json'])
    """
    path = Path(path)
    text, data = read_toml(path, "scene file")
    return build_scene(data, path, path.parent, located_in(path, text))


def build_scene(data: dict, path: Path, base: Path, where: Locator) -> Scene:
    """Check scene data (a parsed scene file, or one a recipe composed) and load its materials, maps and mesh.

    Relative paths are resolved against ``base``; ``path`` names the scene in the frames' headers; ``where`` turns
    a field's location into the file, line and field an InputError names.
    """
    try:
        info = SceneFile.model_validate(data)
    except ValidationError as err:
        raise input_error(err, where) from None
    if info.ground is not None and info.backdrop is not None and info.backdrop.kind == "sweep":
        raise InputError("a sweep backdrop has its own floor: give [ground] or a [backdrop] sweep, not both",
                         **where(("backdrop", "kind")))  # fmt: skip
    if info.output.antialias_method == "multisample" and info.output.antialias > 2:
        raise InputError(f"is multisample, which takes at most 2 x 2 samples a pixel, but antialias is "
                         f"{info.output.antialias}: use antialias = 2, or antialias_method = \"supersample\"",
                         **where(("output", "antialias_method")))  # fmt: skip
    side, samples = max(info.resolution), info.output.antialias
    if side * samples > MAX_RENDER_SIDE:
        raise InputError(f"is {samples}: {samples} x {samples} samples per pixel of a {side} px frame make a "
                         f"{side * samples} px render, above the {MAX_RENDER_SIDE} px a render may be; use fewer",
                         **where(("output", "antialias")))  # fmt: skip

    materials, thicknesses, hashes, sources = [], [], [], {}
    for i, layer in enumerate(info.layer):
        at = where(("layer", i, "material"))
        material_path = base / layer.material
        if not material_path.is_file():
            what = "does not exist" if not material_path.exists() else "is not a file"
            raise InputError(f"names the material file {material_path}, which {what}", **at)
        material = read_material(material_path)
        if material.wavelengths is None:
            raise InputError(f"{material_path} holds camera channels; rendering needs spectral K and S", **at)
        previous = sources.setdefault(material.name, material_path.resolve())
        if previous != material_path.resolve():
            raise InputError(f"{material_path} and {previous} both hold a material named {material.name!r}", **at)
        if materials and not np.array_equal(material.wavelengths, materials[0].wavelengths):
            raise InputError(
                f"{material_path} is on another wavelength grid than {info.layer[0].material}; fit them on one grid",
                **at,
            )
        materials.append(material)
        hashes.append(files.sha256(material_path, "material"))
        if layer.thickness is not None:
            thicknesses.append(parse_thickness_mm(layer.thickness, allow_zero=True))
        else:
            thicknesses.append(thickness_map(layer.thickness_map, base, where(("layer", i, "thickness_map"))))

    try:
        mesh, model, textures = _mesh_and_textures(info.scene.mesh, base, {"field": where(("scene", "mesh"))["field"]})
    except ValueError as err:
        raise InputError(
            f"{err} (expected one of {', '.join(BUILTIN_MESHES)} or a mesh file)", **where(("scene", "mesh"))
        ) from None
    _check_mode(info.scene, len(materials[0].wavelengths), where(("scene", "mode")))
    key = "skin" if info.skin is not None else "substrate"
    uv = getattr(mesh.visual, "uv", None)
    if uv is None or len(uv) != len(mesh.vertices):
        mapped = [("layer", i, "thickness_map") for i, layer in enumerate(info.layer) if layer.thickness_map]
        mapped += [(key, name) for name in ("albedo_texture", "normal_map", "roughness_map")
                   if getattr(info.base, name, None) is not None]  # fmt: skip
        if mapped:
            raise InputError(
                f"the mesh {info.scene.mesh} has no texture coordinates (uv), which thickness maps, albedo "
                "textures, normal and roughness maps need; give a mesh with uv or uniform thicknesses",
                **where(mapped[0]),
            )
        mesh = mesh.copy()
        mesh.visual = trimesh.visual.TextureVisuals(uv=np.zeros((len(mesh.vertices), 2)))  # uniform films: unused
    substrate = resolve_reflectance(info.base.reflectance, materials[0].wavelengths, base, where((key, "reflectance")))
    albedo, normals, roughness = textures.base_colour, textures.normal, None
    if info.base.albedo_texture is not None:
        albedo = albedo_texture(info.base.albedo_texture, info.base.albedo_encoding, base,
                                where((key, "albedo_texture")))  # fmt: skip
    if info.base.normal_map is not None:
        size = None if info.base.albedo_texture is None else albedo.shape[:2]
        normals = normal_map(info.base.normal_map, base, where((key, "normal_map")), size)
    if info.skin is not None and info.skin.roughness_map is not None:
        roughness = roughness_map(
            info.skin.roughness_map, info.skin.roughness_scale, base, where((key, "roughness_map"))
        )
    environment = None
    if info.environment is not None:
        environment = environment_radiance(info.environment, base, where(("environment", "file")))
    return Scene(path, info, tuple(materials), tuple(thicknesses), tuple(hashes), substrate, albedo, mesh, model,
                 _inputs(info, path, base), environment, normals, roughness, textures.occlusion)  # fmt: skip


def _inputs(info: SceneFile, path: Path, base: Path) -> tuple[Path, ...]:
    """The files a checked scene reads (so that no output is written over one of them)."""
    return (path, *(base / layer.material for layer in info.layer), *referenced_files(info, base))


def referenced_files(info: SceneFile, base: Path) -> list[Path]:
    """The files a scene reads besides its materials, relative names resolved against ``base``: thickness maps, a
    mesh file (and a glTF's buffers and images, :func:`renderer.products.mesh_files`, an OBJ's MTL and its maps,
    :func:`renderer.mesh_textures.texture_files`), an albedo texture, normal and roughness maps, a reflectance CSV,
    an environment image (what a render's cache key must hash)."""
    from renderer.mesh_textures import texture_files
    from renderer.products import mesh_files

    found = [base / layer.thickness_map.file for layer in info.layer if layer.thickness_map is not None]
    if info.scene.mesh not in BUILTIN_MESHES:
        found += mesh_files(base / info.scene.mesh)
    if info.scene.mesh not in BUILTIN_MESHES:
        found += [file for file in texture_files(base / info.scene.mesh) if file not in found]
    found += [base / name for name in (info.base.albedo_texture, info.base.normal_map,
                                       getattr(info.base, "roughness_map", None)) if name is not None]  # fmt: skip
    if isinstance(info.base.reflectance, str) and not info.base.reflectance.startswith("colorchecker:"):
        found.append(base / info.base.reflectance.partition(":")[0])
    if info.environment is not None and info.environment.file is not None:
        found.append(base / info.environment.file)
    return found


def _check_mode(settings: RenderSettings, n_wavelengths: int, where: dict) -> None:
    """A forced ``bands:N`` needs at least N wavelengths in the materials' grid."""
    if settings.mode is not None:
        kind, n_bands = parse_mode(settings.mode)
        if kind == "bands" and n_bands > n_wavelengths:
            raise InputError(
                f"mode {settings.mode} asks for more bands than the materials have wavelengths ({n_wavelengths})",
                **where,
            )
