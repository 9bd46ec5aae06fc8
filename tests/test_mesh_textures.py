"""Textured mesh files (renderer.mesh_textures): glTF 2.0 / GLB and OBJ + MTL with base colour, normal and occlusion
maps, round trips to known values, the bundled head as a GLB, and bad input refused naming the file and the slot.

The glTF files are written by trimesh's own exporter (an independent writer), edited in their JSON where a test needs
a parameter trimesh does not export (normalTexture.scale, occlusionTexture.strength) or a broken file. References:
colour-science's sRGB EOTF for the base colour; the glTF 2.0 formulas for the normal (normalize((2c - 1) * (s, s, 1)))
and the occlusion (1 + strength (ao - 1)); codes 0 and 255 decode exactly to -1 and 1, so a normal map of those codes
has the exact unit vectors (+-s, +-s, 1) / sqrt(2 s^2 + 1); trimesh's uv_to_color for which texel a uv addresses.
"""

from __future__ import annotations

import base64
import importlib.util
import json
import re
from pathlib import Path

import colour
import cv2
import numpy as np
import PIL.Image
import pytest
import trimesh

from renderer.image_io import write_exr
from renderer.mesh_textures import MeshTextures, load_mesh_textures, texture_files

HEAD = Path(__file__).resolve().parents[1] / "recipes" / "head"
_spec = importlib.util.spec_from_file_location("make_head_gltf", HEAD / "make_head_gltf.py")
make_head_gltf = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(make_head_gltf)

BASE = np.array([[[10, 200, 30], [255, 0, 128], [64, 64, 64]], [[0, 0, 0], [250, 240, 230], [1, 2, 3]]], np.uint8)
NORMAL = np.array([[[255, 0, 255], [0, 255, 255]], [[255, 255, 255], [0, 0, 255]]], np.uint8)
SIGNS = np.array([[[1, -1], [-1, 1]], [[1, 1], [-1, -1]]], float)  # the x, y signs NORMAL's codes decode to
OCCLUSION = np.array([[[0, 9, 9], [51, 200, 0]], [[204, 0, 77], [255, 13, 13]]], np.uint8)  # R: ao; G, B: ignored
FACTOR = np.array([51, 102, 255, 255], np.uint8)  # trimesh exports uint8 colours as code / 255: 0.2, 0.4, 1, 1


def decoded_base(codes: np.ndarray, factor=(1.0, 1.0, 1.0)) -> np.ndarray:
    """The linear RGB of sRGB codes (colour-science's EOTF) times a factor."""
    return colour.models.eotf_sRGB(codes / float(np.iinfo(codes.dtype).max)) * np.asarray(factor)


def exact_normal(scale: float) -> np.ndarray:
    """NORMAL decoded: (+-scale, +-scale, 1) / sqrt(2 scale^2 + 1)."""
    xy = SIGNS * scale
    return np.concatenate([xy, np.ones((2, 2, 1))], axis=2) / np.sqrt(2.0 * scale**2 + 1.0)


def quad(material=None) -> trimesh.Trimesh:
    """A 10 mm card in z = 0 with uv over [0, 1]^2 (v up), textured with ``material`` if given."""
    vertices = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 10.0, 0.0], [0.0, 10.0, 0.0]])
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    return trimesh.Trimesh(vertices, [[0, 1, 2], [0, 2, 3]], visual=visual, process=False)


def material(base=BASE, normal=NORMAL, occlusion=OCCLUSION, factor=FACTOR) -> trimesh.visual.material.PBRMaterial:
    images = {
        name: None if codes is None else PIL.Image.fromarray(codes)
        for name, codes in (("baseColorTexture", base), ("normalTexture", normal), ("occlusionTexture", occlusion))
    }
    return trimesh.visual.material.PBRMaterial(baseColorFactor=factor, **images)


def write_gltf(folder: Path, edit=None, mesh: trimesh.Trimesh | None = None) -> Path:
    """``folder/model.gltf`` and its buffers as trimesh exports ``mesh`` (default: the textured quad), its JSON
    passed through ``edit(document)`` first."""
    files = (mesh or quad(material())).export(file_type="gltf")
    document = json.loads(files.pop("model.gltf"))
    if edit:
        edit(document)
    for name, data in files.items():
        (folder / name).write_bytes(data)
    (folder / "model.gltf").write_text(json.dumps(document))
    return folder / "model.gltf"


def png(codes: np.ndarray) -> bytes:
    """PNG bytes of RGB(A) or grey codes (cv2 stores colour as BGR)."""
    image = codes[..., ::-1] if codes.ndim == 3 else codes
    return cv2.imencode(".png", np.ascontiguousarray(image))[1].tobytes()


def test_glb_round_trip_decodes_every_map_as_gltf_specifies(tmp_path):
    path = tmp_path / "quad.glb"
    path.write_bytes(quad(material()).export(file_type="glb"))
    mesh, textures = load_mesh_textures(path)
    np.testing.assert_allclose(textures.base_colour, decoded_base(BASE, FACTOR[:3] / 255.0), atol=1e-6)
    np.testing.assert_allclose(textures.normal, exact_normal(1.0), atol=1e-6)
    np.testing.assert_allclose(textures.occlusion, OCCLUSION[..., 0] / 255.0, atol=1e-6)
    assert textures.base_colour.dtype == textures.normal.dtype == textures.occlusion.dtype == np.float32
    assert not textures.base_colour.flags.writeable
    # row 0 is v = 1: the texel each vertex's uv addresses, as trimesh samples it, is the one decoded there
    rows, columns = BASE.shape[:2]
    uv = mesh.visual.uv
    row, column = np.rint((1.0 - uv[:, 1]) * (rows - 1)).astype(int), np.rint(uv[:, 0] * (columns - 1)).astype(int)
    sampled = trimesh.visual.color.uv_to_color(uv, PIL.Image.fromarray(BASE))[:, :3]
    np.testing.assert_allclose(textures.base_colour[row, column], decoded_base(sampled, FACTOR[:3] / 255.0), atol=1e-6)
    assert texture_files(path) == []


def test_gltf_normal_scale_occlusion_strength_and_base_colour_factor(tmp_path):
    def edit(document):
        document["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] = [0.5, 0.25, 1.0, 0.3]
        document["materials"][0]["normalTexture"]["scale"] = 0.5
        document["materials"][0]["occlusionTexture"]["strength"] = 0.25

    _, textures = load_mesh_textures(write_gltf(tmp_path, edit))
    np.testing.assert_allclose(textures.base_colour, decoded_base(BASE, (0.5, 0.25, 1.0)), atol=1e-6)
    np.testing.assert_allclose(textures.normal, exact_normal(0.5), atol=1e-6)
    np.testing.assert_allclose(textures.occlusion, 1.0 + 0.25 * (OCCLUSION[..., 0] / 255.0 - 1.0), atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(textures.normal, axis=2), 1.0, atol=1e-6)


def test_a_mid_grey_normal_code_decodes_as_the_formula(tmp_path):
    codes = np.array([[[128, 64, 200]]], np.uint8)
    _, textures = load_mesh_textures(write_gltf(tmp_path, mesh=quad(material(normal=codes))))
    vector = 2.0 * codes[0, 0] / 255.0 - 1.0
    np.testing.assert_allclose(textures.normal[0, 0], vector / np.linalg.norm(vector), atol=1e-6)


def test_gltf_images_from_a_data_uri_and_an_external_file(tmp_path):
    def edit(document):
        document["images"][0] = {"uri": "data:image/png;base64," + base64.b64encode(png(BASE[:1])).decode()}
        document["images"][1] = {"uri": "normal%20map.png"}

    (tmp_path / "normal map.png").write_bytes(png(NORMAL[::-1]))
    path = write_gltf(tmp_path, edit)
    _, textures = load_mesh_textures(path)
    np.testing.assert_allclose(textures.base_colour, decoded_base(BASE[:1], FACTOR[:3] / 255.0), atol=1e-6)
    np.testing.assert_allclose(textures.normal, exact_normal(1.0)[::-1], atol=1e-6)
    listed = texture_files(path)
    assert tmp_path / "normal map.png" in listed
    assert all(file.is_file() for file in listed) and len(listed) == len(set(listed))


def test_a_mesh_without_a_material_or_a_ply_has_no_textures(tmp_path):
    for name in ("plain.glb", "plain.ply"):
        path = tmp_path / name
        path.write_bytes(trimesh.Trimesh(quad().vertices, quad().faces).export(file_type=name.split(".")[1]))
        assert load_mesh_textures(path)[1] == MeshTextures()


OBJ = """mtllib quad.mtl
v 0 0 0
v 10 0 0
v 10 10 0
v 0 10 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
usemtl skin
f 1/1/1 2/2/1 3/3/1
f 1/1/1 3/3/1 4/4/1
"""


def write_obj(folder: Path, mtl: str, obj: str = OBJ) -> Path:
    (folder / "quad.obj").write_text(obj)
    (folder / "quad.mtl").write_text(mtl)
    return folder / "quad.obj"


def test_obj_mtl_round_trip_with_options_skipped(tmp_path):
    (tmp_path / "albedo.png").write_bytes(png(BASE))
    (tmp_path / "maps").mkdir()
    (tmp_path / "maps" / "normal.png").write_bytes(png(NORMAL))
    mtl = "newmtl skin\nKd 0.8 0.8 0.8\nmap_Kd -blendu on -o 0 0 0 albedo.png\nmap_Bump -bm 1.0 maps\\normal.png\n"
    path = write_obj(tmp_path, mtl)
    _, textures = load_mesh_textures(path)
    np.testing.assert_allclose(textures.base_colour, decoded_base(BASE), atol=1e-6)
    np.testing.assert_allclose(textures.normal, exact_normal(1.0), atol=1e-6)
    assert textures.occlusion is None
    assert texture_files(path) == [tmp_path / "quad.mtl", tmp_path / "albedo.png", tmp_path / "maps" / "normal.png"]
    # trimesh's own OBJ loader reads the same map_Kd image at the same uv (it skips a map_Kd with options)
    path = write_obj(tmp_path, "newmtl skin\nmap_Kd albedo.png\n")
    mesh, plain = load_mesh_textures(path)
    loaded = trimesh.load(path, process=False)
    np.testing.assert_allclose(plain.base_colour, decoded_base(np.asarray(loaded.visual.material.image)), atol=1e-6)
    np.testing.assert_array_equal(mesh.visual.uv, loaded.visual.uv)


def test_obj_norm_is_preferred_over_a_bump_height_map(tmp_path):
    (tmp_path / "height.png").write_bytes(png(np.full((2, 2), 100, np.uint8)))
    (tmp_path / "normal.png").write_bytes(png(NORMAL))
    path = write_obj(tmp_path, "newmtl skin\nbump height.png\nnorm normal.png\n")
    _, textures = load_mesh_textures(path)
    assert textures.base_colour is None
    np.testing.assert_allclose(textures.normal, exact_normal(1.0), atol=1e-6)


def test_a_float_albedo_is_linear_and_an_obj_without_usemtl_uses_its_one_textured_material(tmp_path):
    pixels = np.array([[[0.25, 0.5, 0.75], [0.0, 1.0, 0.125]]])  # exact in half floats
    write_exr(tmp_path / "albedo.exr", pixels)
    obj = OBJ.replace("usemtl skin\n", "")
    path = write_obj(tmp_path, "newmtl plain\nKd 1 0 0\nnewmtl skin\nmap_Kd albedo.exr\n", obj)
    _, textures = load_mesh_textures(path)
    np.testing.assert_array_equal(textures.base_colour, pixels.astype(np.float32))
    pixels[0, 1, 1] = 1.5  # the only value out of range
    write_exr(tmp_path / "albedo.exr", pixels)
    with pytest.raises(
        ValueError, match=r"its map_Kd .*albedo\.exr has a value outside \[0, 1\] .* at row 0, column 1"
    ):
        load_mesh_textures(path)


def test_bundled_head_as_glb_round_trip(tmp_path):
    path = make_head_gltf.make_head_gltf(tmp_path)
    mesh, textures = load_mesh_textures(path)
    statements = {}
    for line in (HEAD / "head.obj").read_text().splitlines():
        keyword, *values = line.split()
        statements.setdefault(keyword, []).append(values)
    vertices = np.array(statements["v"], float)
    uv = np.array(statements["vt"], float)
    faces = np.array([[int(corner.split("/")[0]) - 1 for corner in face] for face in statements["f"]])
    np.testing.assert_array_equal(mesh.vertices, vertices.astype(np.float32))
    np.testing.assert_allclose(mesh.visual.uv, uv, atol=1e-6)
    np.testing.assert_array_equal(mesh.faces, faces)

    albedo, normal = make_head_gltf.texture_sources()
    codes = cv2.imread(str(albedo), cv2.IMREAD_UNCHANGED)[..., 2::-1]
    np.testing.assert_allclose(textures.base_colour, decoded_base(codes), atol=1e-6)
    if normal is None:  # the flat map the script makes while the head has no normal map of its own
        codes = np.array([[[128, 128, 255]]], np.uint8)
    else:
        codes = cv2.imread(str(normal), cv2.IMREAD_UNCHANGED)[..., 2::-1]
    vectors = 2.0 * codes / float(np.iinfo(codes.dtype).max) - 1.0
    np.testing.assert_allclose(textures.normal, vectors / np.linalg.norm(vectors, axis=2, keepdims=True), atol=1e-6)
    assert textures.occlusion is None


# --- bad input -----------------------------------------------------------------------------------------------------


def test_gltf_textures_without_texture_coordinates(tmp_path):
    def edit(document):
        del document["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"]

    path = write_gltf(tmp_path, edit)
    message = f"{path}: has a baseColorTexture but no texture coordinates (TEXCOORD_0)"
    with pytest.raises(ValueError, match=f"^{re.escape(message)}$"):
        load_mesh_textures(path)


def test_obj_map_without_texture_coordinates(tmp_path):
    (tmp_path / "albedo.png").write_bytes(png(BASE))
    obj = "\n".join(line for line in OBJ.splitlines() if not line.startswith(("vt", "f")))
    path = write_obj(tmp_path, "newmtl skin\nmap_Kd albedo.png\n", obj + "\nf 1//1 2//1 3//1\nf 1//1 3//1 4//1\n")
    with pytest.raises(ValueError, match=r"quad\.obj: has a map_Kd but no texture coordinates \(vt\)"):
        load_mesh_textures(path)


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (None, "no such file"),
        (b"this is not an image", "cannot be read as an image"),
        (png(np.random.default_rng(1).integers(0, 256, (64, 64, 3), dtype=np.uint8))[:300], "cannot be read"),
    ],
    ids=["missing", "not-an-image", "truncated"],
)
def test_a_broken_gltf_texture_file_names_the_file_and_slot(tmp_path, content, reason):
    def edit(document):
        document["images"][1] = {"uri": "normal.png"}

    if content is not None:
        (tmp_path / "normal.png").write_bytes(content)
    path = write_gltf(tmp_path, edit)
    with pytest.raises(ValueError, match=f"^{path}: its normalTexture {tmp_path / 'normal.png'}: {reason}"):
        load_mesh_textures(path)


def test_a_corrupt_embedded_image_names_where_it_is(tmp_path):
    def edit(document):
        document["images"][0] = {"uri": "data:image/png;base64," + base64.b64encode(b"garbage").decode()}

    path = write_gltf(tmp_path, edit)
    with pytest.raises(ValueError, match=r"its baseColorTexture image 0 \(a data: URI\): cannot be read as an image"):
        load_mesh_textures(path)


def test_a_two_channel_normal_map(tmp_path):
    def edit(document):
        document["images"][1] = {"uri": "normal.png"}

    PIL.Image.fromarray(NORMAL[..., :2], "LA").save(tmp_path / "normal.png")
    path = write_gltf(tmp_path, edit)
    with pytest.raises(ValueError, match=r"its normalTexture .*normal\.png has 2 channels; a tangent-space normal map"):
        load_mesh_textures(path)


def test_a_one_channel_bump_map_is_not_a_normal_map(tmp_path):
    (tmp_path / "height.png").write_bytes(png(np.full((2, 2), 100, np.uint8)))
    path = write_obj(tmp_path, "newmtl skin\nmap_Bump height.png\n")
    with pytest.raises(ValueError, match=r"its map_Bump .*height\.png has 1 channel; .*a bump \(height\) map"):
        load_mesh_textures(path)


@pytest.mark.parametrize("value", [0.5, np.nan], ids=["zero", "nan"])
def test_a_zero_or_nan_normal(tmp_path, value):
    pixels = np.full((3, 4, 3), 0.75)
    pixels[1, 2] = value  # 2 * 0.5 - 1 = 0: the zero vector
    write_exr(tmp_path / "normal.exr", pixels)
    path = write_obj(tmp_path, "newmtl skin\nnorm normal.exr\n")
    with pytest.raises(ValueError, match=r"its norm .*normal\.exr has a zero or non-finite normal at row 1, column 2"):
        load_mesh_textures(path)


def test_missing_obj_map_and_mtl(tmp_path):
    path = write_obj(tmp_path, "newmtl skin\nmap_Kd albedo.png\n")
    with pytest.raises(ValueError, match=f"^{path}: its map_Kd {tmp_path / 'albedo.png'}: no such file$"):
        load_mesh_textures(path)
    (tmp_path / "quad.mtl").unlink()
    with pytest.raises(ValueError, match=r"quad\.mtl: no such material \(MTL\) file"):
        load_mesh_textures(path)
    assert texture_files(path) == [tmp_path / "quad.mtl"]


def test_an_unknown_map_option_names_the_mtl_line(tmp_path):
    path = write_obj(tmp_path, "newmtl skin\n\nmap_Kd -zoom 2 albedo.png\n")
    with pytest.raises(ValueError, match=r"quad\.mtl:3: map_Kd has an unknown option '-zoom'"):
        load_mesh_textures(path)


def test_parts_with_different_materials_are_refused(tmp_path):
    path = tmp_path / "two.glb"
    other = quad(material(base=BASE[::-1]))
    other.apply_translation([20.0, 0.0, 0.0])
    path.write_bytes(trimesh.Scene([quad(material()), other]).export(file_type="glb"))
    with pytest.raises(ValueError, match=r"its primitives use 2 materials \(0, 1\); .* share one material"):
        load_mesh_textures(path)
    (tmp_path / "a.png").write_bytes(png(BASE))
    (tmp_path / "b.png").write_bytes(png(BASE[::-1]))
    obj = OBJ.replace("f 1/1/1 3/3/1 4/4/1", "usemtl lips\nf 1/1/1 3/3/1 4/4/1")
    path = write_obj(tmp_path, "newmtl skin\nmap_Kd a.png\nnewmtl lips\nmap_Kd b.png\n", obj)
    with pytest.raises(
        ValueError,
        match=r"quad\.obj: it uses 2 materials \(skin, lips\), some with texture maps; .* share one material",
    ):
        load_mesh_textures(path)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            lambda material: material["pbrMetallicRoughness"].update(baseColorFactor=[2.0, 0.0, 0.0, 1.0]),
            r"materials\[0\]\.pbrMetallicRoughness\.baseColorFactor must be in \[0, 1\], got 2\.0",
        ),
        (lambda material: material["normalTexture"].update(scale="x"), r"normalTexture\.scale must be a finite number"),
        (lambda material: material["occlusionTexture"].update(strength=1.5), r"occlusionTexture\.strength must be in"),
        (lambda material: material["normalTexture"].update(texCoord=1), r"normalTexture uses TEXCOORD_1"),
    ],
    ids=["factor", "scale", "strength", "texcoord"],
)
def test_bad_gltf_material_parameters_name_the_field(tmp_path, edit, message):
    path = write_gltf(tmp_path, lambda document: edit(document["materials"][0]))
    with pytest.raises(ValueError, match=message):
        load_mesh_textures(path)
