"""Writes head_textured.glb: the bundled head (head.obj) as a binary glTF 2.0 with its albedo and normal map.

The head scan a user would bring, made from the bundled head, for testing the textured-mesh path
(renderer.mesh_textures): one mesh, one primitive (POSITION, NORMAL and TEXCOORD_0 as head.obj has them, mm; uint32
triangle indices in head.obj's order), one material: baseColorTexture = head_albedo.png (else, while that map does not
exist, recipes/scenes/head_makeup.png), normalTexture = head_normal.png (else a flat 1 x 1 normal map, codes 128, 128,
255), metallicFactor 0. The PNGs are embedded byte for byte (no re-encoding: a 16-bit map stays 16-bit), which is
why the file is written here rather than through trimesh's exporter (it re-encodes images through Pillow, 8 bits).
glTF's uv origin is the image's top left, so v is stored as 1 - v.

Run: .venv/bin/python recipes/head/make_head_gltf.py [FOLDER]   (default /tmp; writes FOLDER/head_textured.glb)
"""

from __future__ import annotations

import argparse
import json
import struct
from pathlib import Path

import cv2
import numpy as np

from renderer.atomic_write import write_atomically
from renderer.products import load_mesh

HEAD = Path(__file__).resolve().parent
ALBEDO, NORMAL = HEAD / "head_albedo.png", HEAD / "head_normal.png"
FALLBACK_ALBEDO = HEAD.parent / "scenes" / "head_makeup.png"
NAME = "head_textured.glb"
#: Codes of a flat tangent-space normal ((0, 0, 1) to 8-bit precision): the normal map while head_normal.png is missing.
FLAT_NORMAL_RGB = (128, 128, 255)
_PNG_MAGIC, _JPEG_MAGIC = b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff"
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_FLOAT, _UNSIGNED_INT = 5126, 5125


def texture_sources() -> tuple[Path, Path | None]:
    """The albedo and normal map PNGs the glTF embeds: the head's own maps where they exist, else the head's
    cosmetic map for the albedo and None for the normal map (a flat one is made)."""
    albedo = ALBEDO if ALBEDO.is_file() else FALLBACK_ALBEDO
    return albedo, NORMAL if NORMAL.is_file() else None


def _mime(data: bytes, name: str) -> str:
    """The glTF mimeType of PNG or JPEG bytes (the two image types glTF 2.0 allows)."""
    if data.startswith(_PNG_MAGIC):
        return "image/png"
    if data.startswith(_JPEG_MAGIC):
        return "image/jpeg"
    raise ValueError(f"{name}: not a PNG or JPEG file; glTF 2.0 embeds only those")


def head_glb(albedo_png: bytes, normal_png: bytes) -> bytes:
    """The GLB bytes of head.obj with ``albedo_png`` as its baseColorTexture and ``normal_png`` as its normalTexture
    (PNG or JPEG bytes, embedded as given)."""
    mesh = load_mesh(HEAD / "head.obj")
    uv = np.asarray(mesh.visual.uv, dtype=np.float64)
    arrays = [
        np.ascontiguousarray(mesh.faces, dtype=np.uint32),
        np.ascontiguousarray(mesh.vertices, dtype=np.float32),
        np.ascontiguousarray(mesh.vertex_normals, dtype=np.float32),
        np.ascontiguousarray(np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1), dtype=np.float32),
    ]
    blobs = [array.tobytes() for array in arrays] + [albedo_png, normal_png]
    views, binary = [], b""
    for blob in blobs:  # every view starts on a 4-byte boundary
        binary += b"\0" * (-len(binary) % 4)
        views.append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(blob)})
        binary += blob
    binary += b"\0" * (-len(binary) % 4)
    for view, target in zip(
        views[:4], (_ELEMENT_ARRAY_BUFFER, _ARRAY_BUFFER, _ARRAY_BUFFER, _ARRAY_BUFFER), strict=True
    ):
        view["target"] = target  # the images' views have no target
    vertices = arrays[1]
    accessors = [
        {"bufferView": 0, "componentType": _UNSIGNED_INT, "count": arrays[0].size, "type": "SCALAR"},
        {
            "bufferView": 1,
            "componentType": _FLOAT,
            "count": len(vertices),
            "type": "VEC3",
            "min": vertices.min(axis=0).tolist(),
            "max": vertices.max(axis=0).tolist(),
        },
        {"bufferView": 2, "componentType": _FLOAT, "count": len(vertices), "type": "VEC3"},
        {"bufferView": 3, "componentType": _FLOAT, "count": len(vertices), "type": "VEC2"},
    ]
    document = {
        "asset": {"version": "2.0", "generator": "kmpipe recipes/head/make_head_gltf.py"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "head"}],
        "meshes": [
            {
                "name": "head",
                "primitives": [
                    {
                        "attributes": {"POSITION": 1, "NORMAL": 2, "TEXCOORD_0": 3},
                        "indices": 0,
                        "material": 0,
                        "mode": 4,
                    }
                ],
            }
        ],
        "materials": [
            {
                "name": "skin",
                "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0.0},
                "normalTexture": {"index": 1},
            }
        ],
        "textures": [{"source": 0}, {"source": 1}],
        "images": [
            {"bufferView": 4, "mimeType": _mime(albedo_png, "the albedo")},
            {"bufferView": 5, "mimeType": _mime(normal_png, "the normal map")},
        ],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(binary)}],
    }
    text = json.dumps(document, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def make_head_gltf(folder: str | Path = "/tmp") -> Path:
    """Write ``folder/head_textured.glb`` (atomically) from the head and :func:`texture_sources`; return its path."""
    albedo, normal = texture_sources()
    flat = np.array([[FLAT_NORMAL_RGB[::-1]]], np.uint8)  # cv2 writes BGR
    normal_png = normal.read_bytes() if normal else cv2.imencode(".png", flat)[1].tobytes()
    glb = head_glb(albedo.read_bytes(), normal_png)
    path = Path(folder) / NAME
    write_atomically(path, lambda temporary: temporary.write_bytes(glb))
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", nargs="?", default="/tmp", help="where to write head_textured.glb (default /tmp)")
    print(make_head_gltf(parser.parse_args().folder))


if __name__ == "__main__":
    main()
