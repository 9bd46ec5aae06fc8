"""``kmpipe render``: a scene file to EXR and PNG frames, checked against numpy predictions of the optical tables.

The card faces the camera and the light head-on, so its centre pixel is the stack's reflectance (composed in the
planned mode by kmpipe.physics.optical_tables.composite) times the light's radiance.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from kmpipe import cli
from kmpipe.errors import InputError
from kmpipe.formats.material import read_material
from kmpipe.formats.scene import load_scene
from kmpipe.physics.optical_tables import composite
from kmpipe.stages.render_plan import plan_scene
from renderer.image_io import read_exr, read_png, srgb_encode

REPO = Path(__file__).resolve().parent.parent
RADIANCE = (0.8, 1.0, 0.6)
SIZE = 32


@pytest.fixture(scope="module")
def material_file(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("material")
    out = folder / "F1.json"
    assert cli.main(["fit", str(REPO / "recipes/samples/F1/manifest.toml"), "-o", str(out)]) == 0
    return out


def write_scene(folder: Path, material: Path, extra: str = "", *, mode_line: str = "accuracy = 0.5") -> Path:
    text = f"""[scene]
name = "F1 on a card"
illuminant = "D65"
mesh = "card"
resolution = [{SIZE}, {SIZE}]
{mode_line}

[substrate]
reflectance = 0.5

[[layer]]
material = "{material}"
thickness = "20 um"

[[light]]
direction = [0, 0, 1]
radiance = [{", ".join(map(str, RADIANCE))}]

[camera]
azimuth_deg = 0.0
elevation_deg = 0.0
distance_mm = 200
projection = "orthographic"
{extra}"""
    path = folder / "scene.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize("mode_line", ["accuracy = 0.5", 'mode = "bands:6"', 'mode = "rgb"'])
def test_card_centre_pixel_matches_the_planned_composite(tmp_path, material_file, mode_line, capsys):
    scene_path = write_scene(tmp_path, material_file, mode_line=mode_line)
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 0
    capsys.readouterr()
    scene = load_scene(scene_path)
    plan = plan_scene(scene)
    material = read_material(material_file)
    table = plan.tables.build_tables({material.name: material})[material.name]
    expected = composite([table], [0.02], np.full(len(material.wavelengths), 0.5), plan.mode) * np.array(RADIANCE)

    pixels, header = read_exr(tmp_path / "out" / "frame_000.exr")
    assert pixels.shape == (SIZE, SIZE, 3)
    centre = pixels[SIZE // 2, SIZE // 2]
    np.testing.assert_allclose(centre, expected, atol=1e-4)
    assert header["render_mode"] == plan.mode
    assert header["scene"] == "F1 on a card"
    assert header["materials"] == material.name
    assert header["thicknesses_mm"] == "0.02"
    assert header["illuminant"] == "D65"
    assert header["camera_azimuth_deg"] == pytest.approx(0.0)
    assert header["camera_elevation_deg"] == pytest.approx(0.0)

    png = read_png(tmp_path / "out" / "frame_000.png")
    assert png.shape == (SIZE, SIZE, 3)
    encoded = srgb_encode(pixels.astype(np.float64)) * 255.0
    assert np.max(np.abs(png.astype(np.float64) - encoded)) <= 1.0
    assert np.max(np.abs(png[SIZE // 2, SIZE // 2] - srgb_encode(expected) * 255.0)) <= 1.0


def test_forced_mode_is_used(tmp_path, material_file):
    scene_path = write_scene(tmp_path, material_file, mode_line='mode = "bands:6"')
    assert plan_scene(load_scene(scene_path)).mode == "bands:6"


def test_turntable_writes_frames_with_their_azimuths(tmp_path, material_file, capsys):
    scene_path = write_scene(tmp_path, material_file, "\n[turntable]\nframes = 4\n")
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 0
    capsys.readouterr()
    for i, azimuth in enumerate([0.0, 90.0, 180.0, 270.0]):
        _, header = read_exr(tmp_path / "out" / f"frame_{i:03d}.exr")
        assert header["camera_azimuth_deg"] == pytest.approx(azimuth)
        assert header["frame"] == i
        assert (tmp_path / "out" / f"frame_{i:03d}.png").is_file()
    assert not (tmp_path / "out" / "frame_004.exr").exists()
    # Seen edge-on at 90 degrees the card covers (almost) nothing; at 180 its back faces the camera.
    front, _ = read_exr(tmp_path / "out" / "frame_000.exr")
    side, _ = read_exr(tmp_path / "out" / "frame_001.exr")
    assert front[SIZE // 2, SIZE // 2].max() > 0.05
    assert side.mean() < front.mean()


def test_explain_prints_the_chosen_mode(tmp_path, material_file, capsys):
    scene_path = write_scene(tmp_path, material_file, mode_line='mode = "rgb"')
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out"), "--explain"]) == 0
    out = capsys.readouterr().out
    assert "Render plan under D65" in out
    chosen = re.findall(r"^ +(\S+): max .*<- chosen$", out, re.M)
    assert chosen == ["rgb"] and "mode rgb was requested" in out


def test_explain_shows_the_cheapest_mode_that_meets_the_target_chosen(tmp_path, material_file, capsys):
    """Unforced, the plan tries modes cheapest first and marks the first whose max Delta E meets the target."""
    scene_path = write_scene(tmp_path, material_file, mode_line="accuracy = 0.5")
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out"), "--explain"]) == 0
    out = capsys.readouterr().out
    rows = re.findall(r"^ +(\S+): max ([\d.]+), mean [\d.]+ \((meets|misses) target\)(  <- chosen)?$", out, re.M)
    assert rows, out
    *cheaper, last = rows
    assert all(float(m) > 0.5 and verdict == "misses" and not mark for _, m, verdict, mark in cheaper)
    assert float(last[1]) <= 0.5 and last[2] == "meets" and last[3]


def km_reflectance(K, S, X, Rg):
    """The textbook KM reflectance of a film over a ground (Kubelka 1948), written out here for the test."""
    a = 1.0 + K / S
    b = np.sqrt(a**2 - 1.0)
    coth = 1.0 / np.tanh(b * S * X)
    return (1.0 - Rg * (a - b * coth)) / (a - Rg + b * coth)


def test_exact_mode_renders_the_km_prediction_in_srgb(tmp_path, material_file, capsys):
    """A uniform film on a card head-on renders to KM's reflectance through colour-science's sRGB, within 1/255."""
    import colour

    scene_path = write_scene(tmp_path, material_file, mode_line='mode = "exact"')
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out"), "--explain"]) == 0
    assert "composed per wavelength" in capsys.readouterr().out
    material = read_material(material_file)
    R = km_reflectance(material.K, material.S, 0.02, 0.5)
    sd = colour.SpectralDistribution(dict(zip(material.wavelengths, R, strict=True)))
    illuminant = colour.SDS_ILLUMINANTS["D65"]
    with colour.utilities.suppress_warnings(colour_runtime_warnings=True):
        XYZ = colour.sd_to_XYZ(sd, illuminant=illuminant, method="Integration") / 100.0
    expected = colour.XYZ_to_RGB(XYZ, "sRGB", apply_cctf_encoding=False) * np.array(RADIANCE)

    pixels, header = read_exr(tmp_path / "out" / "frame_000.exr")
    assert header["render_mode"] == "exact"
    np.testing.assert_allclose(pixels[SIZE // 2, SIZE // 2], expected, rtol=2e-3)
    png = read_png(tmp_path / "out" / "frame_000.png").astype(np.float64)
    assert np.max(np.abs(png[SIZE // 2, SIZE // 2] - srgb_encode(expected) * 255.0)) <= 1.0


def test_unknown_key_exits_2_naming_file_line_and_field(tmp_path, material_file, capsys):
    scene_path = write_scene(tmp_path, material_file, "fov = 20\n")
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert f"{scene_path}, line 24" in err
    assert "field 'camera.fov'" in err and "unknown field" in err
    assert not (tmp_path / "out").exists()


def test_missing_material_exits_2_naming_file_line_and_field(tmp_path, material_file, capsys):
    scene_path = write_scene(tmp_path, Path("missing.json"))
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert f"{scene_path}, line 12" in err
    assert "field 'layer[1].material'" in err and "missing.json" in err and "does not exist" in err


def test_bad_value_exits_2(tmp_path, material_file, capsys):
    scene_path = write_scene(tmp_path, material_file)
    scene_path.write_text(scene_path.read_text().replace('"20 um"', '"20"'), encoding="utf-8")
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert f"{scene_path}, line 13" in err and "field 'layer[1].thickness'" in err


def test_frames_carry_product_shade_and_material_hashes(tmp_path, material_file, capsys):
    import hashlib

    scene_path = write_scene(tmp_path, material_file)
    text = scene_path.read_text().replace(
        'name = "F1 on a card"', 'name = "F1 on a card"\nproduct = "Velvet"\nshade = "Ivory 01"'
    )
    scene_path.write_text(text, encoding="utf-8")
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 0
    capsys.readouterr()
    _, header = read_exr(tmp_path / "out" / "frame_000.exr")
    assert header["product"] == "Velvet" and header["shade"] == "Ivory 01"
    assert header["material_sha256"] == hashlib.sha256(material_file.read_bytes()).hexdigest()
    assert header["turntable_deg"] == pytest.approx(0.0)


def write_map(path: Path, values: np.ndarray) -> None:
    import OpenImageIO as oiio

    spec = oiio.ImageSpec(values.shape[1], values.shape[0], 1, oiio.UINT16)
    out = oiio.ImageOutput.create(str(path))
    codes = np.rint(values[..., None] * 65535).astype(np.uint16)  # (rows, columns, 1): OIIO misreads a 2-D array
    assert out.open(str(path), spec) and out.write_image(codes) and out.close()


def test_a_thickness_map_renders_each_side_at_its_thickness_in_exact_mode(tmp_path, material_file, capsys):
    import colour

    values = np.zeros((4, 8))
    values[:, 4:] = 1.0  # left half at min, right half at max (column 0 is u = 0, the card's left edge)
    write_map(tmp_path / "wedge.png", values)
    scene_path = write_scene(tmp_path, material_file, mode_line='mode = "exact"')
    text = scene_path.read_text().replace(
        'thickness = "20 um"', 'thickness_map = { file = "wedge.png", min = "5 um", max = "40 um" }'
    )
    scene_path.write_text(text, encoding="utf-8")
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 0
    capsys.readouterr()
    pixels, header = read_exr(tmp_path / "out" / "frame_000.exr")
    assert header["thicknesses_mm"] == "0.005..0.04 (map)"
    material = read_material(material_file)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    illuminant = colour.SDS_ILLUMINANTS["D65"]
    for column, thickness in ((8, 0.005), (23, 0.04)):  # the card spans columns 6 .. 25; u = 0.14 and 0.87
        R = km_reflectance(material.K, material.S, thickness, 0.5)
        sd = colour.SpectralDistribution(dict(zip(material.wavelengths, R, strict=True)))
        with colour.utilities.suppress_warnings(colour_runtime_warnings=True):
            XYZ = colour.sd_to_XYZ(sd, cmfs=cmfs, illuminant=illuminant, method="Integration") / 100.0
        expected = colour.XYZ_to_RGB(XYZ, "sRGB", apply_cctf_encoding=False) * np.array(RADIANCE)
        np.testing.assert_allclose(pixels[SIZE // 2, column], expected, rtol=2e-3)


def test_a_missing_thickness_map_and_a_point_light_without_position_exit_2(tmp_path, material_file, capsys):
    scene_path = write_scene(tmp_path, material_file)
    text = scene_path.read_text().replace(
        'thickness = "20 um"', 'thickness_map = { file = "nowhere.png", max = "9 um" }'
    )
    scene_path.write_text(text, encoding="utf-8")
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "nowhere.png" in err and "layer[1]" in err and "line 13" in err
    scene_path = write_scene(tmp_path, material_file, '\n[[light]]\nkind = "point"\nradiance = [1, 1, 1]\n')
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "point light has a position" in err and "light[2]" in err


def test_the_plan_drops_shadow_maps_when_nothing_can_shadow_and_sizes_them_otherwise(tmp_path, material_file, capsys):
    scene_path = write_scene(tmp_path, material_file)
    assert "nothing can shadow anything -> none made" in plan_scene(load_scene(scene_path)).explain()
    scene_path = write_scene(tmp_path, material_file, "\n[ground]\nreflectance = 0.3\n")
    plan = plan_scene(load_scene(scene_path))
    assert plan.shadow_map_size == 512  # 2 x 32 px, raised to the smallest map
    assert "1 of 1 lights cast shadows" in plan.explain()
    text = (
        scene_path.read_text()
        .replace('mesh = "card"', 'mesh = "compact"')
        .replace("[[light]]", "[[light]]\nshadows = false")
    )
    scene_path.write_text(text, encoding="utf-8")
    assert "no light casts shadows -> none made" in plan_scene(load_scene(scene_path)).explain()


def test_tone_mapping_changes_the_png_not_the_exr(tmp_path, material_file, capsys):
    plain = write_scene(tmp_path, material_file)
    assert cli.main(["render", str(plain), "-o", str(tmp_path / "plain")]) == 0
    mapped = (
        write_scene(tmp_path / "mapped", material_file, '\n[output]\ntone_map = "reinhard"\nexposure_ev = 1.0\n')
        if (tmp_path / "mapped").mkdir() is None
        else None
    )
    assert cli.main(["render", str(mapped), "-o", str(tmp_path / "mapped_out")]) == 0
    capsys.readouterr()
    a, _ = read_exr(tmp_path / "plain" / "frame_000.exr")
    b, header = read_exr(tmp_path / "mapped_out" / "frame_000.exr")
    np.testing.assert_array_equal(a, b)
    assert header["tone_map"].startswith("reinhard +1 EV")
    assert np.any(read_png(tmp_path / "plain" / "frame_000.png") != read_png(tmp_path / "mapped_out" / "frame_000.png"))


def test_a_sheet_of_rendered_frames_labels_itself_from_their_headers(tmp_path, material_file, capsys):
    from kmpipe.stages.sheet import frame_labels

    scene_path = write_scene(tmp_path, material_file, "\n[turntable]\nframes = 2\n")
    scene_path.write_text(scene_path.read_text().replace("[scene]\n", '[scene]\nproduct = "Velvet"\nshade = "Ivory"\n'))
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 0
    frames = [tmp_path / "out" / f"frame_{i:03d}.exr" for i in range(2)]
    labels = frame_labels(frames, 1, 2)
    assert labels.rows == ["Velvet · Ivory"] and labels.columns == ["0°", "180°"]
    assert labels.header.startswith("F1 on a card · D65 · ")
    assert cli.main(["sheet", *map(str, frames), "-o", str(tmp_path / "sheet.png")]) == 0
    assert read_png(tmp_path / "sheet.png").shape[1] > 2 * SIZE


def test_rendered_rgb_and_bands_stay_within_their_planned_delta_e_of_rendered_exact(tmp_path, material_file, capsys):
    """The planner's Delta E of each mode (measured on tables) holds for the rendered pixels against exact."""
    import colour

    from kmpipe.physics.optical_tables import working_space

    centres = {}
    for mode in ("rgb", "bands:6", "bands:9", "exact"):
        folder = tmp_path / mode.replace(":", "")
        folder.mkdir()
        scene_path = write_scene(folder, material_file, mode_line=f'mode = "{mode}"')
        assert cli.main(["render", str(scene_path), "-o", str(folder / "out")]) == 0
        pixels, _ = read_exr(folder / "out" / "frame_000.exr")
        centres[mode] = (pixels[SIZE // 2, SIZE // 2] / np.array(RADIANCE), plan_scene(load_scene(scene_path)))
    capsys.readouterr()
    space = working_space(read_material(material_file).wavelengths, "D65")
    exact = space.to_Lab(centres["exact"][0])
    for mode in ("rgb", "bands:6", "bands:9"):
        rgb, plan = centres[mode]
        planned = plan.tables.candidates[-1].max_dE
        measured = float(colour.delta_E(space.to_Lab(rgb), exact, method="CIE 2000"))
        assert measured == pytest.approx(planned, abs=0.01)  # float32 pixels: a hundredth of a unit


def skin_scene(folder: Path, material: Path, mode: str, texture: np.ndarray | None) -> Path:
    """The card scene on light skin (no lobe, no scattering) under a film of 0 um, optionally with a texture."""
    from renderer.image_io import write_exr

    scene_path = write_scene(folder, material, mode_line=f'mode = "{mode}"')
    text = scene_path.read_text().replace('thickness = "20 um"', 'thickness = "0 um"')
    skin = '[skin]\nreflectance = "colorchecker:light skin"\nspecular = false\nscattering = false\n'
    if texture is not None:
        write_exr(folder / "albedo.exr", texture, {}, half=False)
        skin += 'albedo_texture = "albedo.exr"\n'
    scene_path.write_text(text.replace("[substrate]\nreflectance = 0.5\n", skin), encoding="utf-8")
    return scene_path


def render_centre_row(scene_path: Path, out: Path) -> np.ndarray:
    assert cli.main(["render", str(scene_path), "-o", str(out)]) == 0
    return read_exr(out / "frame_000.exr")[0][SIZE // 2]


@pytest.mark.parametrize("mode", ["rgb", "bands:6", "exact"])
def test_bare_skin_with_an_albedo_texture_renders_the_texture(tmp_path, material_file, mode, capsys):
    """A texture of two colours on bare skin: in rgb and exact each half renders its colour exactly (the spectra
    built from the skin's reproduce the texture's RGB); in every mode a texel of the skin's own colour renders as
    the untextured skin does."""
    (tmp_path / "plain").mkdir()
    plain = render_centre_row(skin_scene(tmp_path / "plain", material_file, mode, None), tmp_path / "plain" / "out")
    skin_rgb = plain[16] / np.array(RADIANCE)  # the untextured skin, as this mode renders it
    texture = np.zeros((4, 8, 3))
    texture[:, 4:] = (0.22, 0.30, 0.45)
    if mode == "bands:6":  # the skin's colour in the working space, from its spectrum (the mode's own error aside)
        from kmpipe.physics.optical_tables import working_space

        material = read_material(material_file)
        substrate = load_scene(skin_scene(tmp_path, material_file, mode, None)).substrate
        texture[:, :4] = substrate @ working_space(material.wavelengths, "D65").matrix
    else:
        texture[:, :4] = skin_rgb
    row = render_centre_row(skin_scene(tmp_path, material_file, mode, texture), tmp_path / "out")
    capsys.readouterr()
    np.testing.assert_allclose(row[8], plain[8], rtol=1e-5)  # the skin's own colour: k = (1, 1, 1)
    if mode != "bands:6":
        np.testing.assert_allclose(row[23], texture[0, 7] * np.array(RADIANCE), rtol=2e-3)


def test_a_missing_albedo_texture_exits_2(tmp_path, material_file, capsys):
    scene_path = write_scene(tmp_path, material_file)
    text = scene_path.read_text().replace("reflectance = 0.5", 'reflectance = 0.5\nalbedo_texture = "no.png"')
    scene_path.write_text(text, encoding="utf-8")
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "no.png" in err and "substrate.albedo_texture" in err


def test_an_albedo_texture_on_a_black_substrate_exits_2(tmp_path, material_file, capsys):
    """Nothing can tint a black spectrum: the texture is refused naming the field, not an internal error."""
    from renderer.image_io import write_exr

    write_exr(tmp_path / "albedo.exr", np.full((2, 2, 3), 0.3), {}, half=False)
    scene_path = write_scene(tmp_path, material_file)
    text = scene_path.read_text().replace("reflectance = 0.5", 'reflectance = 0.0\nalbedo_texture = "albedo.exr"')
    scene_path.write_text(text, encoding="utf-8")
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "substrate.albedo_texture" in err and "black" in err


def test_a_shadowing_point_light_inside_the_scene_exits_2(tmp_path, material_file, capsys):
    light = '\n[[light]]\nkind = "point"\nposition = [0.0, 0.0, 60.0]\n'  # outside the card, over its ground
    scene_path = write_scene(tmp_path, material_file, light + "\n[ground]\nreflectance = 0.3\n")
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "light[2].position" in err and "shadows = false" in err
    scene_path.write_text(scene_path.read_text().replace(light, light + "shadows = false\n"), encoding="utf-8")
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 0


def test_a_mesh_file_without_uv_renders_uniform_films_and_refuses_maps(tmp_path, material_file, capsys):
    import trimesh

    box = trimesh.creation.box((30.0, 30.0, 30.0))
    box.export(tmp_path / "box.ply")
    scene_path = write_scene(tmp_path, material_file)
    scene_path.write_text(scene_path.read_text().replace('mesh = "card"', 'mesh = "box.ply"'), encoding="utf-8")
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 0
    write_map(tmp_path / "map.png", np.ones((2, 2)))
    text = scene_path.read_text().replace('thickness = "20 um"', 'thickness_map = { file = "map.png", max = "9 um" }')
    scene_path.write_text(text, encoding="utf-8")
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "no texture coordinates" in err and "layer[1].thickness_map" in err


# --- hostile values in scenes and recipes: exit 2 naming the file and field, never exit 70 ------------------


def _render_status(tmp_path, scene_path, capsys) -> str:
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "scene.toml" in err and "Traceback" not in err
    assert not (tmp_path / "out" / "frame_000.exr").exists()
    return err


@pytest.mark.parametrize(
    ("extra", "field"),
    [
        ("[output]\nexposure_ev = nan\n", "output.exposure_ev"),
        ("\n[[light]]\ndirection = [0, 0, 1]\nradiance = [1e308, 1, 1]\n", "light[2].radiance"),
        ("\n[[light]]\ndirection = [0, 0, 1e-30]\n", "light[2]"),
        ("\n[[light]]\nkind = \"point\"\nposition = [0, 0, inf]\n", "light[2].position"),
        ("\n[[light]]\nkind = \"point\"\nposition = [0, 0, 0]\nshadows = true\n", "light[2].position"),
        ("\n[[light]]\nkind = \"point\"\nposition = [0, 0, 500]\nreference_distance_mm = 1e300\n",
         "light[2].reference_distance_mm"),
    ],
)  # fmt: skip
def test_a_hostile_light_or_output_value_exits_2(tmp_path, material_file, capsys, extra, field):
    err = _render_status(tmp_path, write_scene(tmp_path, material_file, extra), capsys)
    assert f"'{field}" in err


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ("azimuth_deg = 0.0", "azimuth_deg = nan", "camera.azimuth_deg"),
        ("distance_mm = 200", "distance_mm = inf", "camera.distance_mm"),
        ("distance_mm = 200", "distance_mm = 1e300", "camera.distance_mm"),
        (f"resolution = [{SIZE}, {SIZE}]", "resolution = [8192, 8192]", "scene.resolution"),
        ("accuracy = 0.5", 'mode = "bands:33"', "scene.mode"),
        ("accuracy = 0.5", "accuracy = inf", "scene.accuracy"),
    ],
)
def test_a_hostile_scene_or_camera_value_exits_2(tmp_path, material_file, capsys, old, new, field):
    path = write_scene(tmp_path, material_file)
    path.write_text(path.read_text(encoding="utf-8").replace(old, new), encoding="utf-8")
    err = _render_status(tmp_path, path, capsys)
    assert f"'{field}" in err


@pytest.mark.parametrize(
    ("obj", "words"),
    [
        ("v 0 0 0\nv 1e-30 0 0\nv 0 1e-30 0\nf 1 2 3\n", "mm across"),
        ("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "no area"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nv 6 5 5\nv 7 5 5\nf 1 2 3\nf 4 5 6\n", "has no normal"),
    ],
    ids=["1e-30 mm", "zero area", "one degenerate face"],
)
def test_a_degenerate_mesh_file_exits_2_naming_it(tmp_path, material_file, capsys, obj, words):
    (tmp_path / "tiny.obj").write_text(obj, encoding="utf-8")
    path = write_scene(tmp_path, material_file)
    path.write_text(path.read_text(encoding="utf-8").replace('mesh = "card"', 'mesh = "tiny.obj"'), encoding="utf-8")
    err = _render_status(tmp_path, path, capsys)
    assert "'scene.mesh'" in err and "tiny.obj" in err and words in err


def test_a_thickness_map_larger_than_the_limit_is_refused_from_its_header(tmp_path, material_file, capsys, monkeypatch):
    """A map over renderer.image_io.MAX_IMAGE_SIDE (8192) is refused from its header; here the limit is lowered to
    16 so that the test needs no 20000 x 20000 image, and reading the pixels would fail the test."""
    import renderer.image_io as image_io
    from renderer.image_io import write_map

    write_map(tmp_path / "map.png", np.full((32, 32), 0.5))
    monkeypatch.setattr(image_io, "MAX_IMAGE_SIDE", 16)
    monkeypatch.setattr(image_io.oiio.ImageInput, "read_image", lambda *a: pytest.fail("pixels were read"))
    path = write_scene(tmp_path, material_file)
    text = path.read_text(encoding="utf-8").replace(
        'thickness = "20 um"', '[layer.thickness_map]\nfile = "map.png"\nmax = "30 um"'
    )
    path.write_text(text, encoding="utf-8")
    err = _render_status(tmp_path, path, capsys)
    assert "'layer[1].thickness_map'" in err and "32 x 32" in err and "16 x 16" in err


def test_a_recipe_mode_is_checked_as_a_scene_mode_is(tmp_path, material_file):
    from kmpipe.formats.recipe import load_recipe

    path = tmp_path / "recipe.toml"
    path.write_text(
        f'[line]\nname = "L"\nmode = "bands:99"\n\n[[product]]\nname = "P"\nmaterial = "{material_file}"\n',
        encoding="utf-8",
    )
    with pytest.raises(InputError) as err:
        load_recipe(path)
    assert (err.value.path, err.value.field, err.value.line) == (path, "line.mode", 3)
    assert "32" in err.value.message


def test_the_scene_mode_limit_is_the_layer_pass_channel_count():
    from kmpipe.formats.scene import RenderSettings
    from renderer.stack import MAX_CHANNELS

    assert RenderSettings(mode=f"bands:{MAX_CHANNELS}").mode == f"bands:{MAX_CHANNELS}"
    with pytest.raises(ValueError, match=f"N <= {MAX_CHANNELS}"):
        RenderSettings(mode=f"bands:{MAX_CHANNELS + 1}")


# --- frames: EXR and PNG written as a pair, never a non-finite frame -----------------------------------------


def test_a_render_writes_exr_and_png_pairs_only(tmp_path, material_file, capsys):
    scene_path = write_scene(tmp_path, material_file, "[turntable]\nframes = 2\n")
    assert cli.main(["render", str(scene_path), "-o", str(tmp_path / "out")]) == 0
    capsys.readouterr()
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert names == ["frame_000.exr", "frame_000.png", "frame_001.exr", "frame_001.png", "turntable.mp4",
                     "turntable.webp"]  # fmt: skip


def test_a_frame_with_nan_pixels_is_an_internal_error_and_writes_nothing(tmp_path, material_file, monkeypatch):
    from kmpipe.stages import render

    monkeypatch.setattr(render, "render_layers", lambda scene: np.full((SIZE, SIZE, 3), np.nan))
    with pytest.raises(RuntimeError, match="NaN or infinite"):
        render.render_scene(write_scene(tmp_path, material_file), tmp_path / "out", echo=lambda text: None)
    assert list((tmp_path / "out").iterdir()) == []


def test_progress_is_reported_once_a_frame_is_on_disk_in_order(tmp_path, material_file):
    """Frames are written by a thread while the next renders: on_frame(i, n) must still come after frame i's files
    exist, once per frame and in order."""
    from kmpipe.stages.render import render_scene

    out = tmp_path / "out"
    seen = []

    def on_frame(done: int, total: int) -> None:
        on_disk = all((out / f"frame_{i:03d}.{ext}").is_file() for i in range(done) for ext in ("exr", "png"))
        seen.append((done, total, on_disk))

    scene = write_scene(tmp_path, material_file, "[turntable]\nframes = 3\n[output]\nvideo = []\n")
    written = render_scene(scene, out, echo=lambda text: None, on_frame=on_frame)
    assert seen == [(1, 3, True), (2, 3, True), (3, 3, True)]
    assert all(path.is_file() for path in written) and len(written) == 6


def test_an_exit_between_the_renames_leaves_no_exr_without_its_png(tmp_path, material_file, monkeypatch):
    import renderer.atomic_write
    from kmpipe.stages.render import render_scene

    scene = load_scene(write_scene(tmp_path, material_file))
    out = tmp_path / "out"
    render_scene(scene, out, echo=lambda text: None)
    real = renderer.atomic_write.os.replace

    def fail_on_exr(source, target):
        if Path(target) == out / "frame_000.exr":  # the EXR's rename, after the PNG's
            raise KeyboardInterrupt
        real(source, target)

    monkeypatch.setattr(renderer.atomic_write.os, "replace", fail_on_exr)
    with pytest.raises(KeyboardInterrupt):
        render_scene(scene, out, echo=lambda text: None)
    assert sorted(p.name for p in out.iterdir()) == ["frame_000.png"]


def test_more_bands_than_the_materials_wavelengths_exits_2(tmp_path, material_file, capsys):
    import dataclasses

    from kmpipe.formats.material import write_material

    full = read_material(material_file)
    measurements = tuple(dataclasses.replace(m, residuals=m.residuals[:4]) for m in full.measurements)
    cut = {"wavelengths": full.wavelengths[:4], "K": full.K[:4], "S": full.S[:4], "flags": full.flags[:4],
           "K_stderr": None, "S_stderr": None, "measurements": measurements, "budget": None}  # fmt: skip
    write_material(dataclasses.replace(full, **cut), tmp_path / "four.json")
    path = write_scene(tmp_path, tmp_path / "four.json", mode_line='mode = "bands:5"')
    err = _render_status(tmp_path, path, capsys)
    assert "'scene.mode'" in err and "(4)" in err


@pytest.mark.parametrize(
    ("name", "key"),
    [("F11", "FL11"), ("f11", "FL11"), ("FL11", "FL11"), ("F3.1", "FL3.1"), ("LED-B3", "LED-B3"), ("d65", "D65")],
)
def test_scenes_recipes_and_validation_resolve_illuminants_alike(name, key):
    """One resolver: what validation accepts (CIE names, F for colour-science's FL), a scene or recipe accepts."""
    import colour

    from kmpipe.formats.scene import RenderSettings
    from kmpipe.physics.colorimetry import illuminant_sd

    assert RenderSettings(illuminant=name).illuminant == name
    assert illuminant_sd(name) is colour.SDS_ILLUMINANTS[key]


def test_an_unknown_illuminant_is_refused_alike_and_the_message_suggests_only_known_ones():
    import re

    import colour
    from pydantic import ValidationError

    from kmpipe.errors import InputError
    from kmpipe.formats.scene import RenderSettings
    from kmpipe.physics.colorimetry import illuminant_key, illuminant_sd

    with pytest.raises(ValidationError, match="unknown illuminant 'X99'"):
        RenderSettings(illuminant="X99")
    with pytest.raises(InputError, match="unknown illuminant 'X99'") as refused:
        illuminant_sd("X99")
    suggested = re.findall(r"[A-Z]+[\w.-]*\d\w*|\bA\b", refused.value.message.split(";")[1])
    assert suggested and all(illuminant_key(s) in colour.SDS_ILLUMINANTS for s in suggested)


def test_the_camera_aims_at_the_mesh_centre_moved_by_aim_mm(tmp_path, material_file):
    from kmpipe.stages.render import renderer_scenes

    centred = load_scene(write_scene(tmp_path, material_file))
    [plain] = renderer_scenes(centred, plan_scene(centred), [0.0])
    aimed = load_scene(write_scene(tmp_path, material_file, "aim_mm = [12.0, -5.0, 3.0]\n"))
    [moved] = renderer_scenes(aimed, plan_scene(aimed), [0.0])
    offset = np.array([12.0, -5.0, 3.0])
    np.testing.assert_allclose(np.subtract(moved.camera.target, plain.camera.target), offset, atol=1e-9)
    np.testing.assert_allclose(np.subtract(moved.camera.eye, plain.camera.eye), offset, atol=1e-9)  # same direction
    path = write_scene(tmp_path, material_file, "aim_mm = [1.0, 2.0]\n")
    with pytest.raises(InputError) as err:
        load_scene(path)
    assert err.value.field.startswith("camera.aim_mm")


def test_reinhard_maps_every_frame_of_a_turntable_with_the_scenes_white_card(tmp_path, material_file, capsys):
    """The curve's white is the luminance of a white card facing the scene's one light (its radiance's luminance),
    not each frame's brightest pixel: the backdrop, the same linear value in every frame, is the same PNG code in
    every frame while the card turning away changes what is brightest."""
    extra = '\n[backdrop]\nkind = "gradient"\n[turntable]\nframes = 3\n[output]\ntone_map = "reinhard"\n'
    assert cli.main(["render", str(write_scene(tmp_path, material_file, extra)), "-o", str(tmp_path / "out")]) == 0
    capsys.readouterr()
    white = float(np.dot([0.2126, 0.7152, 0.0722], RADIANCE))
    brightest, backdrops = [], []
    for i in range(3):
        linear, header = read_exr(tmp_path / "out" / f"frame_{i:03d}.exr")
        assert header["tone_map"] == f"reinhard +0 EV, white {white:.4g} (PNG only)"
        luminance = linear @ [0.2126, 0.7152, 0.0722]
        scale = np.where(luminance > 0.0, (1.0 + luminance / white**2) / (1.0 + luminance), 1.0)
        expected = np.rint(srgb_encode(np.clip(linear * scale[..., None], 0.0, 1.0)) * 255.0)
        png = read_png(tmp_path / "out" / f"frame_{i:03d}.png").astype(float)
        assert np.abs(png - expected).max() <= 1.0
        brightest.append(luminance.max())
        backdrops.append(png[0, 0])
    assert max(brightest) > 1.5 * min(brightest)  # a per-frame white would map the backdrop differently
    np.testing.assert_array_equal(backdrops[0], backdrops[1])
    np.testing.assert_array_equal(backdrops[0], backdrops[2])


def test_a_sheet_shows_rendered_frames_as_their_tone_mapped_pngs(tmp_path, material_file, capsys):
    """The sheet shows what the frames' PNGs and videos show: a cell as large as the frame is the frame's PNG code for
    code, not its EXR sRGB encoded without the scene's tone curve (the two differ here)."""
    from kmpipe.stages.sheet import frame_labels, write_contact_sheet
    from renderer.contact_sheet import sheet_layout

    extra = '\n[turntable]\nframes = 2\n[output]\ntone_map = "reinhard"\nexposure_ev = 1.0\n'
    assert cli.main(["render", str(write_scene(tmp_path, material_file, extra)), "-o", str(tmp_path / "out")]) == 0
    capsys.readouterr()
    frames = [tmp_path / "out" / f"frame_{i:03d}.exr" for i in range(2)]
    written = write_contact_sheet(frames, tmp_path / "sheet.png", cell=SIZE, header="")
    sheet = read_png(written.path)
    labels = frame_labels(frames, 1, 2)
    layout = sheet_layout(labels.rows, labels.columns, cell_size=(SIZE, SIZE))
    for column, frame in enumerate(frames):
        x, y = layout.cell_origin(0, column)
        png = read_png(frame.with_suffix(".png"))
        np.testing.assert_array_equal(sheet[y : y + SIZE, x : x + SIZE], png)
    linear, _ = read_exr(frames[0])
    untoned = np.rint(srgb_encode(np.clip(linear, 0.0, 1.0)) * 255.0)
    assert np.abs(untoned - read_png(frames[0].with_suffix(".png"))).max() > 20
