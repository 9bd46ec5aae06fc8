"""The textures of a user's mesh file: base colour, tangent-space normal and ambient-occlusion maps of its material.

A head scan comes as glTF 2.0 (``.gltf`` with its buffers and images, or ``.glb``) whose material has a
``baseColorTexture``, ``normalTexture`` and ``occlusionTexture``, or as an OBJ whose MTL gives ``map_Kd`` (albedo) and
``norm`` / ``map_Bump`` / ``bump`` (read as a tangent-space normal map). :func:`load_mesh_textures` loads the mesh
as :func:`renderer.products.load_mesh` does and decodes those maps into :class:`MeshTextures`, plain float32 arrays:

- base colour: linear RGB in [0, 1], ``eotf_sRGB(code) * baseColorFactor.rgb`` (an integer image is sRGB-coded, as
  glTF specifies and as OBJ albedo maps are painted; a floating-point image, EXR say, is taken as linear); alpha and
  the MTL's ``Kd`` are not applied;
- normal: unit vectors in the tangent frame (x along +u, y along +v, z out of the surface; the OpenGL / glTF
  convention), ``n = normalize((2 c_x - 1) s, (2 c_y - 1) s, 2 c_z - 1)`` with ``c`` the codes in [0, 1] and ``s``
  glTF's ``normalTexture.scale`` (1 for an OBJ; MTL options such as ``-bm`` are skipped);
- occlusion: glTF's ``1 + strength (ao - 1)`` with ``ao`` the image's first (R) channel, linear, in [0, 1].

Every image keeps its own size; row 0 is the image's top, which is v = 1 in ``mesh.visual.uv`` (trimesh gives glTF
uv flipped to the OBJ convention, origin at the bottom left), the convention of the renderer's other maps: the GL
upload flips it. Only texture coordinate set 0 is read; a glTF ``texCoord`` other than 0 or a ``KHR_texture_transform``
is refused, as is a mesh whose parts have different materials (trimesh would pack them into one atlas).

Errors are :class:`ValueError` naming the mesh file, the texture slot and the texture's file (or where in the glTF
it is embedded), so that a caller can report bad input: textures but no texture coordinates, a missing, unreadable or
oversized image, a normal map of fewer than 3 channels or with a zero or non-finite vector.
"""

from __future__ import annotations

import base64
import binascii
import json
import math
import mmap
import re
import struct
import tempfile
import urllib.parse
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import trimesh

from renderer.image_io import read_image
from renderer.products import MAX_GLTF_JSON_BYTES, load_mesh

#: Largest texture image file read (bytes), as for kmpipe's images.
MAX_TEXTURE_BYTES = 512 << 20
#: Largest ``.glb`` (bytes) whose embedded images are read.
MAX_GLB_BYTES = 512 << 20
#: Largest MTL file read (bytes).
MAX_MTL_BYTES = 64 << 20
#: Shortest encoded normal (2 c - 1, after the scale) taken as a direction; shorter ones are refused.
MIN_NORMAL_LENGTH = 1e-6

_GLB_MAGIC, _GLB_JSON, _GLB_BIN = b"glTF", 0x4E4F534A, 0x004E4942
_GLTF_SLOTS = ("baseColorTexture", "normalTexture", "occlusionTexture")
#: MTL map options and how many arguments each takes (-o, -s, -t take 1 to 3 numbers).
_MTL_OPTIONS = {
    "-blendu": 1,
    "-blendv": 1,
    "-bm": 1,
    "-boost": 1,
    "-cc": 1,
    "-clamp": 1,
    "-imfchan": 1,
    "-mm": 2,
    "-texres": 1,
    "-type": 1,
    "-o": 3,
    "-s": 3,
    "-t": 3,
}
_MTL_NORMAL_KEYWORDS = ("norm", "map_bump", "bump")  # in order of preference: norm names a normal map explicitly
_OBJ_STATEMENT = re.compile(rb"^[ \t]*(mtllib|usemtl)[ \t]+([^\r\n]*\S)", re.MULTILINE)


@dataclass(frozen=True)
class MeshTextures:
    """The decoded textures of a mesh's material (read-only float32 arrays, row 0 = the image's top = v = 1).

    Attributes
    ----------
    base_colour
        Linear RGB albedo in [0, 1], (rows, columns, 3), or None without a base colour texture.
    normal
        Tangent-space unit normals (x along +u, y along +v, z out of the surface), (rows, columns, 3), or None.
    occlusion
        Ambient occlusion in [0, 1] (1 = unoccluded), (rows, columns), or None.
    """

    base_colour: np.ndarray | None = None
    normal: np.ndarray | None = None
    occlusion: np.ndarray | None = None


@dataclass(frozen=True)
class _Image:
    """Where a texture's image is: a file, or bytes embedded in the mesh file (``label`` says where)."""

    slot: str
    label: str
    file: Path | None = None
    data: bytes | None = None


@dataclass(frozen=True)
class _Material:
    """The textured slots of a material, the parameters that scale them and the name of its uv set."""

    uv_name: str
    base: _Image | None = None
    base_factor: tuple[float, float, float] = (1.0, 1.0, 1.0)
    normal: _Image | None = None
    normal_scale: float = 1.0
    occlusion: _Image | None = None
    occlusion_strength: float = 1.0


def load_mesh_textures(path: str | Path) -> tuple[trimesh.Trimesh, MeshTextures]:
    """Load a mesh file with the textures of its material.

    The mesh is :func:`renderer.products.load_mesh`'s (its checks, normals and uv); the textures are those of the
    one material its parts share, decoded as the module docstring says. A PLY, or a file whose material has no
    textures, gives an empty :class:`MeshTextures`.

    Raises
    ------
    ValueError
        Naming the file (and the texture slot and image): what :func:`renderer.products.load_mesh` refuses; textures
        but no (or non-finite) texture coordinates; a missing, unreadable or oversized image; a base colour or
        occlusion outside [0, 1] or not finite; a normal map of fewer than 3 channels or with a zero or non-finite
        vector; a glTF material that is malformed or uses another uv set or a texture transform; parts with
        different materials; an OBJ whose MTL is missing or malformed.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    material = None
    if path.is_file():  # else load_mesh names what is wrong with the path
        material = (
            _gltf_material(path) if suffix in (".gltf", ".glb") else _obj_material(path) if suffix == ".obj" else None
        )
    if material is None:
        return load_mesh(path), MeshTextures()
    # the textures before the mesh: trimesh's glTF loader also opens the images and would fail naming the mesh alone
    textures = MeshTextures(
        base_colour=None if material.base is None else _base_colour(path, material.base, material.base_factor),
        normal=None if material.normal is None else _normal(path, material.normal, material.normal_scale),
        occlusion=None
        if material.occlusion is None
        else _occlusion(path, material.occlusion, material.occlusion_strength),
    )
    mesh = load_mesh(path)
    first = next(image for image in (material.base, material.normal, material.occlusion) if image is not None)
    uv = getattr(mesh.visual, "uv", None)
    if uv is None or len(uv) != len(mesh.vertices):
        raise ValueError(f"{path}: has a {first.slot} but no texture coordinates ({material.uv_name})")
    if not np.all(np.isfinite(uv)):
        raise ValueError(f"{path}: its texture coordinates ({material.uv_name}) are not all finite")
    return mesh, textures


def texture_files(path: str | Path) -> list[Path]:
    """The files other than ``path`` itself that :func:`load_mesh_textures` may read for its textures, for a cache
    of renders to hash: an OBJ's MTL files (named by ``mtllib``) and every map their materials name; a glTF's or
    GLB's external buffers and images (relative URIs; ``data:`` URIs are in the file). Missing files are listed too;
    an unreadable MTL or glTF lists what could be read (loading it then fails, naming it)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".obj":
        found: list[Path] = []
        try:
            libraries, _ = _obj_statements(path)
        except (OSError, ValueError):
            return found
        for library in libraries:
            found.append(library)
            try:
                materials = _mtl_materials(library)
            except (OSError, ValueError):
                continue
            found += [image.file for slots in materials.values() for image in slots.values()]
        return list(dict.fromkeys(found))
    if suffix in (".gltf", ".glb"):
        try:
            document, _ = _gltf_document(path)
        except (OSError, ValueError):
            return []
        entries = [*document.get("buffers", []), *document.get("images", [])]
        uris = [entry.get("uri") for entry in entries if isinstance(entry, dict)]
        external = [uri for uri in uris if isinstance(uri, str) and uri and not uri.startswith("data:")]
        return list(dict.fromkeys(path.parent / urllib.parse.unquote(uri) for uri in external))
    return []


# --- decoding ------------------------------------------------------------------------------------------------------


def _srgb_decode(codes: np.ndarray) -> np.ndarray:
    """The sRGB EOTF (IEC 61966-2-1): ``c / 12.92`` for ``c <= 0.04045``, else ``((c + 0.055) / 1.055) ^ 2.4``;
    codes in [0, 1] to linear values in [0, 1], in the codes' float type."""
    c = np.asarray(codes)
    return np.where(c <= 0.04045, c / 12.92, np.power((np.maximum(c, 0.04045) + 0.055) / 1.055, 2.4))


def _pixels(path: Path, image: _Image) -> tuple[np.ndarray, bool]:
    """The image's pixels (rows, columns, channels) as float32, integer codes scaled to [0, 1], row 0 the top, and
    whether the file stores floating-point values."""
    where = f"{path}: its {image.slot} {image.label}"
    if image.file is not None:
        if not image.file.exists():
            raise ValueError(f"{where}: no such file")
        if not image.file.is_file():
            raise ValueError(f"{where}: not a regular file")
        if image.file.stat().st_size > MAX_TEXTURE_BYTES:
            raise ValueError(f"{where}: the file is larger than {MAX_TEXTURE_BYTES >> 20} MiB")
        pixels, spec = _read_image(image.file, where)
    else:
        with tempfile.TemporaryDirectory() as folder:  # OpenImageIO reads files, not bytes
            embedded = Path(folder) / "texture"
            embedded.write_bytes(image.data)
            pixels, spec = _read_image(embedded, where)
    is_float = spec.format.basetype in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE)
    return pixels, is_float


def _read_image(file: Path, where: str) -> tuple[np.ndarray, oiio.ImageSpec]:
    """:func:`renderer.image_io.read_image` of ``file`` (its size limits), its errors as ValueError after ``where``."""
    try:
        return read_image(file, oiio.FLOAT)
    except (OSError, ValueError) as error:
        reason = str(error).replace(f"{file}: ", "").replace(str(file), "the image")
        raise ValueError(f"{where}: cannot be read as an image: {reason}") from error


def _frozen(values: np.ndarray) -> np.ndarray:
    values = np.ascontiguousarray(values, dtype=np.float32)
    values.setflags(write=False)
    return values


def _check_range(path: Path, image: _Image, values: np.ndarray) -> None:
    """Refuse floating-point pixels that are not finite or outside [0, 1] (integer codes always are inside)."""
    bad = ~(np.isfinite(values) & (values >= 0.0) & (values <= 1.0))
    if np.any(bad):
        row, column = np.argwhere(bad)[0][:2]
        raise ValueError(
            f"{path}: its {image.slot} {image.label} has a value outside [0, 1] or not finite at row {row}, "
            f"column {column}: {values[row, column]}"
        )


def _base_colour(path: Path, image: _Image, factor: tuple[float, float, float]) -> np.ndarray:
    """Linear RGB (rows, columns, 3): ``eotf_sRGB(c) * factor`` of an integer image, ``c * factor`` of a float one;
    a one- or two-channel (grey) image gives grey."""
    pixels, is_float = _pixels(path, image)
    rgb = pixels[..., :3] if pixels.shape[2] >= 3 else np.repeat(pixels[..., :1], 3, axis=2)
    if is_float:
        _check_range(path, image, rgb)
    linear = rgb if is_float else _srgb_decode(rgb)
    return _frozen(linear * np.asarray(factor, dtype=np.float32))


def _normal(path: Path, image: _Image, scale: float) -> np.ndarray:
    """Unit tangent-space normals (rows, columns, 3): ``normalize((2 c_x - 1) scale, (2 c_y - 1) scale, 2 c_z - 1)``."""
    pixels, _ = _pixels(path, image)
    channels = pixels.shape[2]
    if channels < 3:
        raise ValueError(
            f"{path}: its {image.slot} {image.label} has {channels} channel{'s' * (channels != 1)}; a tangent-space "
            "normal map has 3 (x, y, z as R, G, B); a one-channel image is a bump (height) map, not a normal map"
        )
    vectors = 2.0 * pixels[..., :3] - 1.0
    vectors[..., :2] *= scale
    length = np.linalg.norm(vectors, axis=2)
    bad = ~(np.isfinite(length) & (length >= MIN_NORMAL_LENGTH))
    if np.any(bad):
        row, column = np.argwhere(bad)[0]
        raise ValueError(
            f"{path}: its {image.slot} {image.label} has a zero or non-finite normal at row {row}, column {column} "
            f"(codes {pixels[row, column, :3]})"
        )
    return _frozen(vectors / length[..., np.newaxis])


def _occlusion(path: Path, image: _Image, strength: float) -> np.ndarray:
    """Ambient occlusion (rows, columns): ``1 + strength (ao - 1)``, ``ao`` the first (R) channel."""
    pixels, is_float = _pixels(path, image)
    ao = pixels[..., 0]
    if is_float:
        _check_range(path, image, ao)
    return _frozen(1.0 + strength * (ao - 1.0))


# --- glTF ----------------------------------------------------------------------------------------------------------


def _gltf_document(path: Path) -> tuple[dict, bytes | None]:
    """A ``.gltf``'s JSON, or a ``.glb``'s JSON chunk and binary chunk (None without one)."""
    limit = MAX_GLB_BYTES if path.suffix.lower() == ".glb" else MAX_GLTF_JSON_BYTES
    if path.stat().st_size > limit:
        raise ValueError(f"{path}: larger than {limit >> 20} MiB; its textures are not read")
    content, binary = path.read_bytes(), None
    if path.suffix.lower() == ".glb":
        if len(content) < 20 or content[:4] != _GLB_MAGIC:
            raise ValueError(f"{path}: not a binary glTF (GLB) file")
        chunks, offset = {}, 12
        while offset + 8 <= len(content):
            length, kind = struct.unpack_from("<II", content, offset)
            chunks.setdefault(kind, content[offset + 8 : offset + 8 + length])
            offset += 8 + length
        if _GLB_JSON not in chunks:
            raise ValueError(f"{path}: the GLB has no JSON chunk")
        content, binary = chunks[_GLB_JSON], chunks.get(_GLB_BIN)
    try:
        document = json.loads(content.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: cannot read the glTF JSON: {error}") from error
    if not isinstance(document, dict):
        raise ValueError(f"{path}: the glTF JSON is not an object")
    return document, binary


def _data_uri(uri: str, where: str) -> bytes:
    """The bytes of a base64 ``data:`` URI; a ValueError starting ``where`` if it is not one."""
    header, _, payload = uri.partition(",")
    try:
        if not header.endswith(";base64"):
            raise binascii.Error("not base64-encoded")
        return base64.b64decode(payload, validate=True)
    except binascii.Error as error:
        raise ValueError(f"{where}: its data: URI cannot be decoded: {error}") from error


def _gltf_image(path: Path, document: dict, binary: bytes | None, slot: str, source: int) -> _Image:
    """Where image ``source`` of the document is: its file, or its bytes (a data: URI or a buffer view)."""
    entry = document["images"][source]
    uri = entry.get("uri")
    if isinstance(uri, str) and uri.startswith("data:"):
        label = f"image {source} (a data: URI)"
        return _Image(slot, label, data=_data_uri(uri, f"{path}: its {slot} {label}"))
    if isinstance(uri, str):
        file = path.parent / urllib.parse.unquote(uri)
        return _Image(slot, str(file), file=file)
    index = entry["bufferView"]
    view = document["bufferViews"][index]
    buffer = document["buffers"][view["buffer"]]
    label = f"image {source} (bufferView {index})"
    buffer_uri = buffer.get("uri")
    if buffer_uri is None:
        if binary is None:
            raise ValueError(f"{path}: its {slot} {label} is in a buffer without data")
        data = binary
    elif buffer_uri.startswith("data:"):
        data = _data_uri(buffer_uri, f"{path}: its {slot} {label}, in buffer {view['buffer']},")
    else:
        file = path.parent / urllib.parse.unquote(buffer_uri)
        if not file.is_file() or file.stat().st_size > MAX_GLB_BYTES:
            raise ValueError(f"{path}: its {slot} {label} is in {file}, which is missing or too large")
        data = file.read_bytes()
    start = int(_number(path, f"bufferViews[{index}].byteOffset", view.get("byteOffset", 0), 0))
    length = int(_number(path, f"bufferViews[{index}].byteLength", view["byteLength"], 1))
    if start + length > len(data):
        raise ValueError(f"{path}: its {slot} {label} lies outside its buffer ({len(data)} bytes)")
    return _Image(slot, label, data=data[start : start + length])


def _number(path: Path, where: str, value, low: float = -math.inf, high: float = math.inf) -> float:
    """``value`` as a float if it is a finite JSON number in [low, high]; else a ValueError naming ``where``."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{path}: {where} must be a finite number, got {value!r}")
    if not low <= value <= high:
        raise ValueError(f"{path}: {where} must be in [{low:g}, {high:g}], got {value!r}")
    return float(value)


def _gltf_material(path: Path) -> _Material | None:
    """The textured material that every primitive of the glTF's nodes shares, or None if none has textures."""
    document, binary = _gltf_document(path)
    try:
        meshes = [document["meshes"][node["mesh"]] for node in document.get("nodes", []) if "mesh" in node]
        primitives = [primitive for mesh in meshes for primitive in mesh["primitives"]]
        used = list(dict.fromkeys(primitive.get("material") for primitive in primitives))
        materials = [(index, document["materials"][index]) for index in used if index is not None]
        textured = [
            (index, material)
            for index, material in materials
            if any(slot in {**material, **material.get("pbrMetallicRoughness", {})} for slot in _GLTF_SLOTS)
        ]
        if not textured:
            return None
        index, material = textured[0]
        if len(used) > 1:
            listed = ", ".join("none" if used_index is None else str(used_index) for used_index in used)
            raise ValueError(
                f"{path}: its primitives use {len(used)} materials ({listed}); textures are read from a mesh whose "
                "parts share one material"
            )
        pbr = material.get("pbrMetallicRoughness", {})
        where = f"materials[{index}]"
        found = {}
        for slot, info in (
            ("baseColorTexture", pbr.get("baseColorTexture")),
            ("normalTexture", material.get("normalTexture")),
            ("occlusionTexture", material.get("occlusionTexture")),
        ):
            if info is None:
                continue
            if info.get("texCoord", 0) != 0:
                raise ValueError(f"{path}: its {slot} uses TEXCOORD_{info['texCoord']}; only TEXCOORD_0 is read")
            if "KHR_texture_transform" in info.get("extensions", {}):
                raise ValueError(f"{path}: its {slot} has a KHR_texture_transform, which is not supported")
            texture = document["textures"][info["index"]]
            source = texture.get("source", texture.get("extensions", {}).get("EXT_texture_webp", {}).get("source"))
            if source is None:
                raise ValueError(f"{path}: its {slot} (texture {info['index']}) has no image source it can read")
            found[slot] = (_gltf_image(path, document, binary, slot, source), info)
        if any("TEXCOORD_0" not in primitive.get("attributes", {}) for primitive in primitives):
            raise ValueError(f"{path}: has a {next(iter(found))} but no texture coordinates (TEXCOORD_0)")
        factor = pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0])
        if not isinstance(factor, list) or len(factor) != 4:
            raise ValueError(f"{path}: {where}.pbrMetallicRoughness.baseColorFactor must be 4 numbers, got {factor!r}")
        rgb = [_number(path, f"{where}.pbrMetallicRoughness.baseColorFactor", value, 0.0, 1.0) for value in factor]
        scale = found["normalTexture"][1].get("scale", 1.0) if "normalTexture" in found else 1.0
        strength = found["occlusionTexture"][1].get("strength", 1.0) if "occlusionTexture" in found else 1.0
        return _Material(
            uv_name="TEXCOORD_0",
            base=found.get("baseColorTexture", (None,))[0],
            base_factor=(rgb[0], rgb[1], rgb[2]),
            normal=found.get("normalTexture", (None,))[0],
            normal_scale=_number(path, f"{where}.normalTexture.scale", scale),
            occlusion=found.get("occlusionTexture", (None,))[0],
            occlusion_strength=_number(path, f"{where}.occlusionTexture.strength", strength, 0.0, 1.0),
        )
    except (KeyError, IndexError, TypeError, AttributeError) as error:
        raise ValueError(f"{path}: malformed glTF material, texture or image entry: {error!r}") from error


# --- OBJ and MTL ---------------------------------------------------------------------------------------------------


def _obj_statements(path: Path) -> tuple[list[Path], list[str]]:
    """The MTL files an OBJ names (``mtllib``, relative to its folder) and the materials it uses (``usemtl``), in
    order of first appearance."""
    libraries: list[Path] = []
    used: list[str] = []
    with path.open("rb") as file, mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ) as content:
        for match in _OBJ_STATEMENT.finditer(content):
            keyword, rest = match.group(1), match.group(2).decode("utf-8", errors="replace").strip()
            if keyword == b"usemtl":
                used.append(rest)
            else:  # several names, or one name with spaces
                names = [rest] if (path.parent / rest.replace("\\", "/")).is_file() else rest.split()
                libraries += [path.parent / name.replace("\\", "/") for name in names]
    return list(dict.fromkeys(libraries)), list(dict.fromkeys(used))


def _map_file(mtl: Path, number: int, keyword: str, statement: str) -> Path:
    """The image file of a map statement's arguments (options such as ``-bm 1.0`` skipped), relative to the MTL."""
    tokens = list(re.finditer(r"\S+", statement))
    position = 0
    while position < len(tokens) and tokens[position].group().startswith("-"):
        option = tokens[position].group().lower()
        if option not in _MTL_OPTIONS:
            raise ValueError(f"{mtl}:{number}: {keyword} has an unknown option {tokens[position].group()!r}")
        position += 1
        if option in ("-o", "-s", "-t"):  # 1 to 3 numbers
            for _ in range(3):
                if position < len(tokens) and re.fullmatch(r"[-+]?[\d.]+(e[-+]?\d+)?", tokens[position].group(), re.I):
                    position += 1
        else:
            position += _MTL_OPTIONS[option]
    if position >= len(tokens):
        raise ValueError(f"{mtl}:{number}: {keyword} names no image file")
    return mtl.parent / statement[tokens[position].start() :].strip().replace("\\", "/")


def _mtl_materials(mtl: Path) -> dict[str, dict[str, _Image]]:
    """Per material of an MTL file, its albedo (``map_Kd``) and normal map (``norm``, else ``map_Bump`` / ``bump``)
    as images keyed ``"base"`` and ``"normal"``."""
    if not mtl.is_file():
        raise ValueError(f"{mtl}: no such material (MTL) file")
    if mtl.stat().st_size > MAX_MTL_BYTES:
        raise ValueError(f"{mtl}: larger than {MAX_MTL_BYTES >> 20} MiB")
    materials: dict[str, dict[str, tuple[int, _Image]]] = {}
    current = None
    for number, line in enumerate(mtl.read_text(encoding="utf-8", errors="replace").splitlines(), start=1):
        written, _, rest = line.strip().replace("\t", " ").partition(" ")
        keyword = written.lower()
        if keyword == "newmtl":
            current = materials.setdefault(rest.strip(), {})
        elif current is not None and keyword in ("map_kd", *_MTL_NORMAL_KEYWORDS):
            file = _map_file(mtl, number, written, rest)
            image = _Image(written, str(file), file=file)
            slot, rank = ("base", 0) if keyword == "map_kd" else ("normal", _MTL_NORMAL_KEYWORDS.index(keyword))
            if slot not in current or rank < current[slot][0]:
                current[slot] = (rank, image)
    return {name: {slot: image for slot, (_, image) in slots.items()} for name, slots in materials.items()}


def _obj_material(path: Path) -> _Material | None:
    """The material an OBJ uses (``usemtl``) if it has texture maps; if the OBJ names none, the one material of its
    MTLs that has maps; else None. Several materials with maps are refused (trimesh splits the mesh by material and
    packs their uv into one atlas)."""
    libraries, used = _obj_statements(path)
    defined: dict[str, dict[str, _Image]] = {}
    for library in libraries:
        for name, slots in _mtl_materials(library).items():
            defined.setdefault(name, slots)
    names = used or [name for name, slots in defined.items() if slots]
    if not any(defined.get(name) for name in names):
        return None
    if len(names) > 1:
        raise ValueError(
            f"{path}: it {'uses' if used else 'names no material (usemtl) and its MTLs have'} {len(names)} materials "
            f"({', '.join(names)}), some with texture maps; textures are read from a mesh whose parts share one "
            "material"
        )
    slots = defined[names[0]]
    return _Material(uv_name="vt", base=slots.get("base"), normal=slots.get("normal"))
