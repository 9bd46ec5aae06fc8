"""Maps over a mesh's uv that a scene file names: thickness maps of films, the substrate's (skin's) albedo texture,
its tangent-space normal map (fine detail) and the skin lobe's roughness map; and the textures a user's mesh file
brings (:mod:`renderer.mesh_textures`). Each is read, checked and returned as float arrays, row 0 at v = 1; bad input
is an :class:`~kmpipe.errors.InputError` naming the file and the scene's field.

* thickness map: ``min + value (max - min)`` (mm), value an image channel in [0, 1];
* albedo texture: linear RGB in [0, 1], sRGB-decoded unless ``linear`` (EXR and HDR are linear by default);
* normal map: unit vectors n = normalize(2 c - 1) of an integer image's codes c in [0, 1] (a float image's values
  taken as the vector), x along +u, y along +v, z out of the surface (OpenGL / glTF); at least RGB, z > 0 everywhere,
  and the size of the albedo texture when the scene has both (they share one uv layout);
* roughness map: Beckmann m = value * scale, value the image's first channel in [0, 1], m in [0.02, 2].
"""

from __future__ import annotations

from pathlib import Path

import colour
import numpy as np
from pydantic import Field

from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.manifest import ThicknessOrZero, parse_thickness_mm
from kmpipe.formats.toml_input import StrictModel

#: Bounds of a roughness map's Beckmann m.
ROUGHNESS_RANGE = (0.02, 2.0)


class ThicknessMapInfo(StrictModel):
    """A thickness map: ``min`` where the image's channel is 0, ``max`` where it is 1, linear in between."""

    file: str = Field(min_length=1)
    channel: str = "R"
    min: ThicknessOrZero = "0 um"
    max: ThicknessOrZero


def image_file(base: Path, name: str, what: str, where: dict) -> tuple[Path, np.ndarray, list[str]]:
    """The image file ``base / name`` read as float64 pixels (rows, columns, channels) and its channel names."""
    from renderer.image_io import read_pixels

    path = base / name
    if not path.is_file():
        raise InputError(f"names the {what} {path}, which does not exist", **where)
    files.regular_file(path, "image", field=where["field"])
    try:
        image, names = read_pixels(path)
    except (OSError, ValueError) as err:
        raise InputError(f"cannot read the {what}: {err}", **where) from None
    return path, image, names


def albedo_texture(name: str, encoding: str | None, base: Path, where: dict) -> np.ndarray:
    """The albedo texture as linear RGB (rows, columns, 3): sRGB-decoded unless linear (EXR and HDR by default)."""
    path, image, _ = image_file(base, name, "albedo texture", where)
    if image.shape[2] < 3 or not np.all(np.isfinite(image[..., :3])) or image[..., :3].min() < 0.0:
        raise InputError(f"{path}: an albedo texture needs finite, non-negative R, G and B channels", **where)
    encoding = encoding or ("linear" if path.suffix.lower() in (".exr", ".hdr") else "srgb")
    rgb = image[..., :3]
    if encoding == "srgb":
        rgb = colour.models.eotf_sRGB(np.clip(rgb, 0.0, 1.0))
    if rgb.max() > 1.0:
        raise InputError(f"{path}: a linear albedo must lie in [0, 1], found up to {rgb.max():.3g}", **where)
    return rgb


def thickness_map(info: ThicknessMapInfo, base: Path, where: dict) -> np.ndarray:
    """A layer's thickness map in mm: min + value * (max - min), value the image channel in [0, 1]."""
    from renderer.image_io import read_channel

    image_path = base / info.file
    if not image_path.is_file():
        raise InputError(f"names the thickness map {image_path}, which does not exist", **where)
    files.regular_file(image_path, "image", field=where["field"])
    try:
        value = read_channel(image_path, info.channel)
    except (OSError, ValueError) as err:
        raise InputError(f"cannot read the thickness map: {err}", **where) from None
    if not (np.all(np.isfinite(value)) and value.min() >= 0.0 and value.max() <= 1.0):
        raise InputError(f"{image_path}: thickness map values must lie in [0, 1] (min maps to min, 1 to max)", **where)
    lo, hi = parse_thickness_mm(info.min, allow_zero=True), parse_thickness_mm(info.max, allow_zero=True)
    if not hi > lo:
        raise InputError(f"thickness_map.max ({info.max}) must exceed thickness_map.min ({info.min})", **where)
    return lo + value * (hi - lo)


def normal_map(name: str, base: Path, where: dict, size_of_albedo: tuple[int, int] | None) -> np.ndarray:
    """The tangent-space normal map as unit vectors (rows, columns, 3), as the module docstring says."""
    path, image, _ = image_file(base, name, "normal map", where)
    if image.shape[2] < 3:
        raise InputError(f"{path} has {image.shape[2]} channel(s): a tangent-space normal map is RGB (x, y, z); a "
                         "one-channel image is a height map, not a normal map", **where)  # fmt: skip
    if size_of_albedo is not None and image.shape[:2] != size_of_albedo:
        albedo = f"{size_of_albedo[1]} x {size_of_albedo[0]}"
        raise InputError(f"{path} is {image.shape[1]} x {image.shape[0]} px but the albedo texture is {albedo}: maps "
                         "of one uv layout have one size", **where)  # fmt: skip
    vectors = image[..., :3]
    if path.suffix.lower() not in (".exr", ".hdr"):
        vectors = 2.0 * vectors - 1.0
    length = np.linalg.norm(vectors, axis=2, keepdims=True)
    if not (np.all(np.isfinite(vectors)) and length.min() > 1e-6):
        raise InputError(f"{path}: a normal map's vectors must be finite and non-zero", **where)
    vectors = vectors / length
    if vectors[..., 2].min() <= 0.0:
        row, column = np.unravel_index(int(np.argmin(vectors[..., 2])), vectors.shape[:2])
        raise InputError(f"{path}: a tangent-space normal points out of the surface (z > 0); row {row}, column "
                         f"{column} does not (is it an object-space map?)", **where)  # fmt: skip
    return vectors


def roughness_map(name: str, scale: float, base: Path, where: dict) -> np.ndarray:
    """The skin lobe's Beckmann m over uv (rows, columns): the image's first channel times ``scale``."""
    path, image, _ = image_file(base, name, "roughness map", where)
    m = image[..., 0] * scale
    lo, hi = ROUGHNESS_RANGE
    if not (np.all(np.isfinite(m)) and m.min() >= lo and m.max() <= hi):
        raise InputError(f"{path}: roughness (value x roughness_scale) must lie in [{lo:g}, {hi:g}], found "
                         f"{np.nanmin(m):.3g} to {np.nanmax(m):.3g}", **where)  # fmt: skip
    return np.ascontiguousarray(m)
