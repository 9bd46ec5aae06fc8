"""A user's textured head scan, end to end: the bundled head written as a glTF (GLB) with its albedo and normal map as
``baseColorTexture`` and ``normalTexture`` (recipes/head/make_head_gltf.py) renders as the bundled head does with the
same maps named in the scene file (two independent routes to the same pixels), and a scan with broken textures is
refused with exit status 2 naming the mesh file and the texture.
"""

from __future__ import annotations

import importlib.util
import json
import struct
from pathlib import Path

import numpy as np
import pytest

from kmpipe import cli
from kmpipe.formats.scene import load_scene
from kmpipe.formats.surface_maps import albedo_texture, normal_map
from kmpipe.stages.fit import fit_manifests
from renderer.image_io import read_exr

ROOT = Path(__file__).resolve().parents[1]
HEAD = ROOT / "recipes" / "head"
_spec = importlib.util.spec_from_file_location("make_head_gltf", HEAD / "make_head_gltf.py")
make_head_gltf = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(make_head_gltf)


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("scan")
    fit_manifests([ROOT / "recipes/samples/F1/manifest.toml"], folder / "F1.json", method="black-white")
    make_head_gltf.make_head_gltf(folder)
    return folder


def _scene(folder: Path, mesh: str, maps: str) -> Path:
    path = folder / f"{Path(mesh).stem}.toml"
    path.write_text(
        f'[scene]\nname = "scan"\nmesh = "{mesh}"\nresolution = [40, 40]\nmode = "rgb"\n'
        f'[skin]\nreflectance = "colorchecker:light skin"\nscattering = false\n{maps}\n'
        '[[layer]]\nmaterial = "F1.json"\nthickness = "0 um"\n'
        "[[light]]\ndirection = [0.3, 0.4, 1.0]\nshadows = false\n"
        "[camera]\nelevation_deg = 5.0\n[output]\nantialias = 1\n",
        encoding="utf-8",
    )
    return path


def test_the_scans_textures_stand_in_for_the_maps_a_scene_would_name(folder):
    scan = load_scene(_scene(folder, "head_textured.glb", ""))
    where = {"field": "test"}
    albedo = albedo_texture(str(HEAD / "head_albedo.png"), None, folder, where)
    normals = normal_map(str(HEAD / "head_normal.png"), folder, where, albedo.shape[:2])
    np.testing.assert_allclose(scan.albedo, albedo, atol=1e-6)  # sRGB-decoded base colour = the albedo texture
    np.testing.assert_allclose(scan.normal_map, normals, atol=1e-6)
    assert {p.name for p in scan.inputs} >= {"head_textured.glb", "F1.json"}


def test_a_textured_scan_renders_as_the_head_with_its_maps_named(folder, capsys):
    maps = f'albedo_texture = "{HEAD / "head_albedo.png"}"\nnormal_map = "{HEAD / "head_normal.png"}"'
    frames = []
    for mesh, extra in (("head_textured.glb", ""), (str(HEAD / "head.obj"), maps)):
        out = folder / f"out_{Path(mesh).stem}"
        assert cli.main(["render", str(_scene(folder, mesh, extra)), "-o", str(out)]) == 0
        frames.append(read_exr(out / "frame_000.exr")[0])
    scan, named = frames
    assert scan.max() > 0.1
    # The same mesh, uv and maps: the same pixels (float32 rounding of the GLB's vertices and normals aside).
    np.testing.assert_allclose(scan, named, atol=2e-3)
    assert float(np.mean(np.abs(scan - named))) < 1e-4


def _broken_glb(source: Path, target: Path) -> None:
    """The scan with its normal texture's image pointing at a file that does not exist."""
    data = source.read_bytes()
    length = struct.unpack_from("<I", data, 12)[0]
    document = json.loads(data[20 : 20 + length])
    normal = document["materials"][0]["normalTexture"]["index"]
    image = document["images"][document["textures"][normal]["source"]]
    image.pop("bufferView", None)
    image.pop("mimeType", None)
    image["uri"] = "missing_normal.png"
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    binary = data[20 + length :]
    header = struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(text) + len(binary))
    target.write_bytes(header + struct.pack("<I4s", len(text), b"JSON") + text + binary)


def test_a_scan_with_a_missing_texture_is_refused_naming_it(folder, capsys):
    _broken_glb(folder / "head_textured.glb", folder / "broken.glb")
    assert cli.main(["render", str(_scene(folder, "broken.glb", "")), "-o", str(folder / "out_broken")]) == 2
    message = capsys.readouterr().err
    assert "broken.glb" in message and "missing_normal.png" in message and "normalTexture" in message
    assert "Traceback" not in message
