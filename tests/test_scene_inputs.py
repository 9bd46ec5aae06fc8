"""The files a scene reads are the files its renders' cache sees (kmpipe.formats.scene, kmpipe.run).

A scene lists every file it read (``Scene.inputs``); ``kmpipe run`` hashes the same list, from the scene's fields, to
decide what to render again. The first test records every file the Python process opens while a scene with every
file-reading field loads (an audit hook sees each ``open``), so a new file-reading field that is not listed fails
here; the second touches one product's albedo texture and checks that exactly that product's renders run again.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from kmpipe.formats.recipe import load_recipe
from kmpipe.formats.scene import load_scene, referenced_files
from kmpipe.run.execute import execute
from kmpipe.run.planning import plan_run
from kmpipe.stages.fit import fit_manifests
from renderer.image_io import write_exr, write_map

ROOT = Path(__file__).resolve().parents[1]
F1 = ROOT / "recipes" / "samples" / "F1" / "manifest.toml"

#: Files opened while the hook is on (a list so the hook, once added for the process, can be turned off).
_OPENED: list[list[Path]] = []


def _audit(event: str, args: tuple) -> None:
    if event == "open" and _OPENED and isinstance(args[0], (str, bytes, Path)):
        _OPENED[-1].append(Path(args[0].decode() if isinstance(args[0], bytes) else args[0]).resolve())


sys.addaudithook(_audit)


@pytest.fixture(scope="module")
def material(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("material")
    fit_manifests([F1], folder / "F1.json", method="black-white")
    return folder / "F1.json"


def _every_file_field(folder: Path, material: Path, mesh: str) -> Path:
    """A scene using every field that reads a file: a material, a thickness map, a mesh file (``mesh``: an OBJ, which
    trimesh writes with a material library and texture, or a glTF with external buffers), an albedo texture, a normal
    map, a reflectance CSV and an environment image; returns its path."""
    u, v = np.mgrid[0:8, 0:8] / 7.0
    write_map(folder / "map.png", np.stack([u, v, u * v], axis=-1))
    write_map(folder / "albedo.png", np.stack([0.6 + 0.2 * u, 0.5 * np.ones_like(u), 0.4 + 0.1 * v], axis=-1))
    write_map(folder / "normal.png", np.stack([0.5 + 0.1 * u, 0.5 * np.ones_like(u), np.ones_like(u)], axis=-1))
    write_exr(folder / "sky.exr", np.full((8, 16, 3), 0.5, np.float32), {})
    box = trimesh.creation.box(extents=(40.0, 40.0, 40.0))
    uv = (box.vertices[:, :2] - box.vertices[:, :2].min(axis=0)) / 40.0
    box.visual = trimesh.visual.TextureVisuals(uv=uv)
    box.export(folder / mesh)
    wavelengths = np.arange(380, 781, 5)
    rows = "".join(f"{w},{0.3 + 0.4 * (w - 380) / 400:.6f}\n" for w in wavelengths)
    (folder / "base.csv").write_text(f"# quantity: reflectance\n# units: 1\nwavelength_nm,base\n{rows}")
    scene = folder / "scene.toml"
    scene.write_text(f"""[scene]
name = "every file"
illuminant = "D65"
mesh = "{mesh}"
resolution = [32, 32]

[substrate]
reflectance = "base.csv:base"
albedo_texture = "albedo.png"
normal_map = "normal.png"

[environment]
file = "sky.exr"

[[layer]]
material = "{material}"
thickness_map = {{ file = "map.png", channel = "R", max = "30 um" }}

[[light]]
direction = [0, 0, 1]
""")
    return scene


@pytest.mark.parametrize("mesh", ["box.obj", "box.gltf"])
def test_a_scene_lists_every_file_it_opens_and_the_cache_lists_the_same(tmp_path, material, mesh):
    scene_path = _every_file_field(tmp_path, material, mesh)
    _OPENED.append([])
    try:
        scene = load_scene(scene_path)
    finally:
        opened = set(_OPENED.pop())
    inputs = {p.resolve() for p in scene.inputs}
    mine = {p for p in opened if tmp_path in p.parents or p == material.resolve()}
    buffers = {p.name for p in tmp_path.glob("*.bin")}  # a glTF's external buffers (an OBJ has none)
    assert (len(buffers) > 0) == mesh.endswith(".gltf")
    library = {"material.mtl", "material_0.png"} if mesh.endswith(".obj") else set()  # an OBJ's MTL and its map
    names = {"scene.toml", "F1.json", "map.png", "albedo.png", "normal.png", "sky.exr", mesh, "base.csv", *buffers}
    names |= library
    assert {p.name for p in inputs} == names  # each file-reading field is listed ...
    assert mine <= inputs, f"opened but not listed: {sorted(mine - inputs)}"  # ... and nothing read is missing
    # the files run's cache key hashes: every input but the scene file itself and the materials (hashed by task)
    assert {p.resolve() for p in referenced_files(scene.info, tmp_path)} == inputs - {
        scene_path.resolve(),
        material.resolve(),
    }


RECIPE = """\
[line]
name = "Albedo line"
illuminant = "D65"

[scene]
mesh = "sphere"
resolution = [24, 24]
[substrate]
reflectance = 0.7
[[light]]
direction = [0.3, 0.8, 0.5]
[turntable]
frames = 2

[[product]]
name = "Textured"
material = "F1.json"
substrate = { reflectance = 0.7, albedo_texture = "albedo.png" }
layer = [{ material = "self", thickness = "20 um" }]

[[product]]
name = "Plain"
material = "F1.json"
layer = [{ material = "self", thickness = "20 um" }]
"""


def test_touching_a_file_one_product_reads_renders_exactly_that_product_again(tmp_path, material):
    (tmp_path / "F1.json").write_bytes(material.read_bytes())
    u, v = np.mgrid[0:8, 0:8] / 7.0
    write_map(tmp_path / "albedo.png", np.stack([0.5 + 0.3 * u, 0.5 * np.ones_like(u), 0.5 * v + 0.2], axis=-1))
    recipe = tmp_path / "recipe.toml"
    recipe.write_text(RECIPE)
    load_recipe(recipe)
    out = tmp_path / "out"
    first = plan_run(recipe, out)
    execute(first)
    renders = {t.id for t in first.tasks.values() if t.kind == "render"}
    assert {t.product for t in first.tasks.values() if t.kind == "render"} == {"Textured", "Plain"}

    again = plan_run(recipe, out)
    assert {t.state for t in again.tasks.values()} == {"cached"}

    write_map(tmp_path / "albedo.png", np.stack([0.6 + 0.2 * u, 0.4 * np.ones_like(u), 0.5 * v + 0.2], axis=-1))
    changed = plan_run(recipe, out)
    execute(changed)
    ran = {t.id for t in changed.tasks.values() if t.state == "run"}
    kinds = ("plan", "render", "video")
    textured = {t.id for t in changed.tasks.values() if t.product == "Textured" and t.kind in kinds}
    assert textured & renders and ran == textured | {"sheet"}  # its plan, renders and video, and the sheet
