"""Studio light through scene files (kmpipe.formats.scene_lighting, kmpipe.formats.surface_maps,
kmpipe.stages.staging): ``[environment]``, ``[backdrop]``, area lights, normal and roughness maps, end to end.

References, none produced by the code under test: the white furnace (a flat substrate of reflectance 0.5 under a film
of no thickness, in a uniform environment of radiance L at intensity s, renders 0.5 L s everywhere; a pixel no surface
covers shows L s when the environment is visible); a gradient's rows follow the smoothstep the scene format
documents; a tangent-space normal tilted by a, under a film of thickness t with fill f, shades as the tilt shrunk by
k = exp(-t / f), cos = cos a / sqrt(k^2 sin^2 a + cos^2 a); which scenes need which passes follows from the geometry
(a sphere is convex, the head is not, a sweep is a floor behind the product).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from kmpipe import cli
from kmpipe.formats.scene import load_scene, referenced_files
from kmpipe.stages.fit import fit_manifests
from kmpipe.stages.plan_file import plan_to_file, read_plan
from kmpipe.stages.render import renderer_scenes
from kmpipe.stages.render_plan import placed_bounds, plan_scene
from kmpipe.stages.staging import floor_occlusion
from renderer.image_io import read_exr, write_exr, write_map

ROOT = Path(__file__).resolve().parents[1]
SIZE = 24


@pytest.fixture(scope="module")
def material(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("material") / "F1.json"
    fit_manifests([ROOT / "recipes/samples/F1/manifest.toml"], path, method="black-white")
    return path


def write_scene(
    folder: Path,
    material: Path,
    extra: str = "",
    *,
    mesh: str = "sphere",
    base: str = "[substrate]\nreflectance = 0.5",
    thickness: str = "10 um",
    light: str = "direction = [0.3, 0.8, 0.5]",
    mode: str = "rgb",
) -> Path:
    path = folder / "scene.toml"
    path.write_text(
        f'[scene]\nname = "studio"\nmesh = "{mesh}"\nresolution = [{SIZE}, {SIZE}]\nmode = "{mode}"\n'
        f'{base}\n[[layer]]\nmaterial = "{material}"\nthickness = "{thickness}"\n[[light]]\n{light}\n'
        f'[camera]\nprojection = "orthographic"\n[output]\nantialias = 1\n{extra}\n',
        encoding="utf-8",
    )
    return path


def render(scene: Path, out: Path, *options: str) -> tuple[int, np.ndarray | None]:
    status = cli.main(["render", str(scene), "-o", str(out), *options])
    return status, (read_exr(out / "frame_000.exr")[0] if status == 0 else None)


def constant_exr(path: Path, value: float, cols: int = 64) -> None:
    write_exr(path, np.full((cols // 2, cols, 3), value, np.float32), half=False)


# 1. The white furnace, end to end.


@pytest.mark.parametrize("mode", ["rgb", "exact", "bands:6"])
@pytest.mark.parametrize("base", ["[substrate]\nreflectance = 0.5", "[skin]\nreflectance = 0.5\nspecular = false"])
def test_a_flat_substrate_in_a_uniform_environment_renders_reflectance_times_radiance(
    tmp_path, material, mode, base, capsys
):
    radiance, intensity = 0.8, 1.5
    constant_exr(tmp_path / "uniform.exr", radiance)
    scene = write_scene(
        tmp_path,
        material,
        f'[environment]\nfile = "uniform.exr"\nintensity = {intensity}\nvisible = true',
        base=base,
        thickness="0 um",
        light="direction = [0, 0, 1]\nradiance = [0, 0, 0]",
        mode=mode,
    )
    status, pixels = render(scene, tmp_path / "out")
    assert status == 0, capsys.readouterr().err
    centre, corner = pixels[SIZE // 2, SIZE // 2], pixels[0, 0]
    product = np.abs(pixels - radiance * intensity).max(axis=-1) > 1e-3  # the background is L s (visible)
    assert product.sum() > 0.3 * SIZE * SIZE
    np.testing.assert_allclose(pixels[product], 0.5 * radiance * intensity, atol=1e-4)
    np.testing.assert_allclose(corner, radiance * intensity, atol=1e-4)
    np.testing.assert_allclose(centre, 0.5 * radiance * intensity, atol=1e-4)


# 2. Bad input: exit 2, naming the file and the field.

ENVIRONMENT = '[environment]\nfile = "{}"'


def two_channel_png(path: Path) -> None:
    spec = oiio.ImageSpec(8, 8, 2, oiio.UINT8)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(np.full((8, 8, 2), 200, np.uint8)) and out.close()


def flat_normals(path: Path, size: int) -> None:
    write_map(path, np.broadcast_to([0.5, 0.5, 1.0], (size, size, 3)))


BAD = {
    "an environment that is not an image": (
        lambda d: (d / "x.hdr").write_text("not an image\n"),
        {"extra": ENVIRONMENT.format("x.hdr")},
        ["field 'environment.file'", "x.hdr", "cannot read the environment image"],
    ),
    "an environment that is not 2:1": (
        lambda d: write_exr(d / "square.exr", np.full((16, 16, 3), 0.5, np.float32)),
        {"extra": ENVIRONMENT.format("square.exr")},
        ["field 'environment.file'", "square.exr", "16 x 16", "twice as wide"],
    ),
    "a missing environment": (
        lambda d: None,
        {"extra": ENVIRONMENT.format("missing.exr")},
        ["field 'environment.file'", "missing.exr", "does not exist"],
    ),
    "a rotation that is not a number": (
        lambda d: None,
        {"extra": '[environment]\nrotation_deg = "left"'},
        ["field 'environment.rotation_deg'", "valid number"],
    ),
    "a sweep and a ground": (
        lambda d: None,
        {"extra": '[ground]\nreflectance = 0.3\n[backdrop]\nkind = "sweep"'},
        ["[ground]", "[backdrop] sweep"],
    ),
    "a normal map of two channels": (
        lambda d: two_channel_png(d / "two.png"),
        {"base": '[substrate]\nreflectance = 0.5\nnormal_map = "two.png"'},
        ["field 'substrate.normal_map'", "two.png", "2 channel"],
    ),
    "a normal map not the albedo's size": (
        lambda d: (write_map(d / "albedo.png", np.full((8, 8, 3), 0.5)), flat_normals(d / "normal.png", 16)),
        {"base": '[substrate]\nreflectance = 0.5\nalbedo_texture = "albedo.png"\nnormal_map = "normal.png"'},
        ["field 'substrate.normal_map'", "normal.png", "16 x 16", "8 x 8"],
    ),
    "a roughness map out of range": (
        lambda d: write_map(d / "rough.png", np.full((8, 8), 0.005)),
        {"base": '[skin]\nreflectance = 0.5\nroughness_map = "rough.png"'},
        ["field 'skin.roughness_map'", "rough.png", "[0.02, 2]"],
    ),
    "a normal map on a mesh without uv": (
        lambda d: (
            (d / "nouv.obj").write_text("v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n"),
            flat_normals(d / "normal.png", 8),
        ),
        {"mesh": "nouv.obj", "base": '[substrate]\nreflectance = 0.5\nnormal_map = "normal.png"'},
        ["field 'substrate.normal_map'", "nouv.obj", "no texture coordinates"],
    ),
    "an angle on a point light": (
        lambda d: None,
        {"light": 'kind = "point"\nposition = [0, 0, 500]\nangle_deg = 10'},
        ["field 'light[1]'", "angle_deg"],
    ),
    "a size on a directional light": (
        lambda d: None,
        {"light": "direction = [0, 0, 1]\nsize_mm = 10"},
        ["field 'light[1]'", "size_mm"],
    ),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_studio_input_exits_2_naming_the_file_and_the_field(tmp_path, material, case, capsys):
    prepare, fields, expected = BAD[case]
    prepare(tmp_path)
    scene = write_scene(tmp_path, material, **fields)
    assert cli.main(["render", str(scene), "-o", str(tmp_path / "out")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert str(scene) in err
    for words in expected:
        assert words in err, err
    assert not (tmp_path / "out" / "frame_000.exr").exists()


# 3. The planner.


def test_without_an_environment_there_is_no_image_based_pass_and_no_occlusion(tmp_path, material, capsys):
    scene = write_scene(tmp_path, material)
    plan = plan_scene(load_scene(scene))
    assert not plan.ambient_occlusion
    assert cli.main(["render", str(scene), "-o", str(tmp_path / "out"), "--explain"]) == 0
    assert "no image-based pass" in capsys.readouterr().out
    (frame,) = renderer_scenes(load_scene(scene), plan, [0.0])
    assert frame.environment is None and frame.occlusion is None


@pytest.mark.parametrize(
    ("mesh", "base", "occluded"),
    [
        ("sphere", "[substrate]\nreflectance = 0.5", False),
        ("head", "[skin]\nreflectance = 0.5", True),
    ],
)
def test_occlusion_is_baked_only_where_the_mesh_can_hide_the_sky_from_itself(tmp_path, material, mesh, base, occluded):
    scene = load_scene(write_scene(tmp_path, material, "[environment]\nrotation_deg = 30", mesh=mesh, base=base))
    plan = plan_scene(scene)
    assert plan.ambient_occlusion == occluded
    notes = "\n".join(plan.notes)
    assert "environment light: the built-in studio" in notes and "rotated 30 deg" in notes
    assert ("ambient occlusion: baked per vertex" in notes) == occluded
    assert ("ambient occlusion: none" in notes) != occluded
    written = plan_to_file(scene, tmp_path / "plan.json")
    read = read_plan(tmp_path / "plan.json", scene)
    assert written.ambient_occlusion == read.ambient_occlusion == occluded and read.explain() == plan.explain()


def test_the_head_bakes_occlusion_that_darkens_its_creases_and_leaves_open_skin_lit(tmp_path, material):
    """Per vertex in [0, 1]: most of the head sees most of the sky, and some of it (ears, nostrils, eye sockets,
    under the chin) sees much less."""
    scene = load_scene(write_scene(tmp_path, material, "[environment]", mesh="head", base="[skin]\nreflectance = 0.5"))
    (frame,) = renderer_scenes(scene, plan_scene(scene), [0.0])
    ao = np.asarray(frame.occlusion)
    assert ao.shape == (len(scene.mesh.vertices),) and 0.0 <= ao.min() and ao.max() <= 1.0
    assert np.median(ao) > 0.8 and np.percentile(ao, 2) < 0.6


def test_a_sweep_is_a_floor_that_a_convex_product_shadows(tmp_path, material):
    bare = plan_scene(load_scene(write_scene(tmp_path, material)))
    assert bare.shadow_lights == (False,)  # a sphere alone cannot shadow anything
    scene = load_scene(write_scene(tmp_path, material, '[backdrop]\nkind = "sweep"'))
    plan = plan_scene(scene)
    assert plan.shadow_lights == (True,) and any("backdrop sweep" in note for note in plan.notes)
    (frame,) = renderer_scenes(scene, plan, [0.0])
    assert len(frame.props) == 1 and frame.lights[0].cast_shadows


@pytest.mark.parametrize("floor", ["[ground]\nreflectance = 0.5", '[backdrop]\nkind = "sweep"'])
def test_the_floor_under_a_product_in_an_environment_sees_the_sky_the_product_leaves(tmp_path, material, floor):
    """The sphere (radius r) on a ground or a sweep: a floor vertex d from its contact point has the occlusion of a
    sphere resting on a plane, 1 - (r / sqrt(d^2 + r^2))^3, turned or not (the sphere is round), and the floor far
    away sees the whole sky; without an environment the floor has no occlusion."""
    scene = load_scene(write_scene(tmp_path, material, f"[environment]\n{floor}"))
    plan = plan_scene(scene)
    assert any("ambient occlusion: baked once on a 64 x 64 grid" in note for note in plan.notes)
    centre, radius, _ = placed_bounds(scene)
    d = np.linspace(0.0, 6.0, 121)[:, None] * radius  # along two directions on the floor from below the centre
    r = d[:, 0]
    on_floor = [centre + np.column_stack([r * np.cos(t), np.full_like(r, -radius), r * np.sin(t)]) for t in (0.4, 2.5)]
    for frame in renderer_scenes(scene, plan, [0.0, 70.0]):
        prop = frame.props[0]
        assert prop.occlusion is None and len(prop.mesh.faces) <= 80  # per pixel: a few large triangles
        for points in on_floor:
            relative = points @ prop.floor_frame[:3, :3].T + prop.floor_frame[:3, 3]
            ao = prop.floor_occlusion.at(relative)
            near = (d[:, 0] > 1.3 * radius) & (d[:, 0] < 2.5 * radius)
            expected = 1.0 - (radius / np.hypot(d[near, 0], radius)) ** 3
            np.testing.assert_allclose(ao[near], expected, atol=0.03)
            outside = d[:, 0] > 3.0 * np.sqrt(2.0) * radius  # beyond the baked square (3 radii each way)
            np.testing.assert_array_equal(ao[outside], 1.0)
    (bare,) = renderer_scenes(scene := load_scene(write_scene(tmp_path, material, floor)), plan_scene(scene), [0.0])
    assert bare.props[0].occlusion is None and bare.props[0].floor_occlusion is None


def test_a_floor_bake_is_kept_for_products_placed_alike_and_made_anew_for_another(tmp_path, material):
    """Every render task of a line's products on one mesh shares one bake of the floor (kept per process); another
    film changes nothing under the floor, another mesh or size does."""
    extra = '[environment]\n[backdrop]\nkind = "sweep"'
    first = floor_occlusion(load_scene(write_scene(tmp_path, material, extra, thickness="10 um")))
    (tmp_path / "other").mkdir()
    again = floor_occlusion(load_scene(write_scene(tmp_path / "other", material, extra, thickness="40 um")))
    assert again is first and not first.values.flags.writeable
    lipstick = floor_occlusion(load_scene(write_scene(tmp_path, material, extra, mesh="lipstick")))
    assert lipstick is not first and not np.array_equal(lipstick.values, first.values)


def test_a_gradient_backdrop_fills_the_frame_behind_the_product(tmp_path, material, capsys):
    top, bottom = np.array([0.8, 0.5, 0.2]), np.array([0.1, 0.15, 0.3])
    extra = f'[backdrop]\nkind = "gradient"\ntop = {top.tolist()}\nbottom = {bottom.tolist()}'
    status, pixels = render(write_scene(tmp_path, material, extra), tmp_path / "out")
    assert status == 0, capsys.readouterr().err
    t = (np.arange(SIZE) + 0.5) / SIZE
    expected = top + (bottom - top) * (3.0 * t**2 - 2.0 * t**3)[:, None]
    np.testing.assert_allclose(pixels[:, 0], expected, atol=1e-5)  # the sphere leaves the first column free


def test_an_area_light_reaches_the_renderer_with_its_size(tmp_path, material):
    scene = load_scene(
        write_scene(
            tmp_path, material, "[ground]\nreflectance = 0.3", light="direction = [0.3, 0.8, 0.5]\nangle_deg = 12"
        )
    )
    plan = plan_scene(scene)
    (frame,) = renderer_scenes(scene, plan, [0.0])
    assert frame.lights[0].angle_deg == 12.0
    assert frame.lights[0].softness == pytest.approx(2.0 * np.tan(np.radians(6.0)))
    assert any("soft shadows" in note and "12 deg" in note for note in plan.notes)


# Fine detail, end to end.


def test_a_normal_map_under_a_film_shades_with_its_tilt_filled_by_the_film(tmp_path, material, capsys):
    """A card facing the camera and the light, a uniform normal map tilted by a, F1 of 10 um, fill 10 um."""
    a = np.radians(40.0)
    write_map(tmp_path / "tilted.png", np.broadcast_to([(np.sin(a) + 1) / 2, 0.5, (np.cos(a) + 1) / 2], (8, 8, 3)))
    flat_normals(tmp_path / "flat.png", 8)
    frames = {}
    for name in ("none", "flat", "tilted"):
        normal = "" if name == "none" else f'normal_map = "{name}.png"\nnormal_fill = "10 um"'
        scene = write_scene(
            tmp_path,
            material,
            mesh="card",
            light="direction = [0, 0, 1]",
            base=f"[substrate]\nreflectance = 0.5\n{normal}",
        )
        status, frames[name] = render(scene, tmp_path / name)
        assert status == 0, capsys.readouterr().err
    centre = (SIZE // 2, SIZE // 2)
    np.testing.assert_allclose(frames["flat"], frames["none"], rtol=1e-4, atol=1e-6)
    # the map's 16-bit codes: the tilt they hold, to their rounding
    codes = np.rint(np.array([(np.sin(a) + 1) / 2, 0.5, (np.cos(a) + 1) / 2]) * 65535.0) / 65535.0
    d = 2.0 * codes - 1.0
    d /= np.linalg.norm(d)
    k = np.exp(-1.0)  # 10 um of film over a fill of 10 um
    expected = d[2] / np.sqrt(k**2 * (d[0] ** 2 + d[1] ** 2) + d[2] ** 2)
    np.testing.assert_allclose(frames["tilted"][centre] / frames["none"][centre], expected, rtol=1e-4)


# 4. Inputs and caching.


def test_the_environment_and_the_maps_are_inputs_of_the_scene(tmp_path, material):
    constant_exr(tmp_path / "studio.exr", 0.5)
    flat_normals(tmp_path / "normal.png", 8)
    write_map(tmp_path / "rough.png", np.full((8, 8), 0.3))
    base = '[skin]\nreflectance = 0.5\nnormal_map = "normal.png"\nroughness_map = "rough.png"'
    path = write_scene(tmp_path, material, '[environment]\nfile = "studio.exr"', base=base)
    scene = load_scene(path)
    inputs = {p.resolve() for p in scene.inputs}
    assert {(tmp_path / name).resolve() for name in ("studio.exr", "normal.png", "rough.png")} <= inputs
    assert {p.resolve() for p in referenced_files(scene.info, tmp_path)} == inputs - {
        path.resolve(),
        material.resolve(),
    }
    assert scene.environment.shape == (32, 64, 3) and np.all(scene.environment == 0.5)
    np.testing.assert_allclose(scene.roughness, 0.3, atol=1e-4)


@pytest.mark.parametrize("mode", ["rgb", "exact", "bands:6"])
def test_a_glossy_film_of_no_thickness_leaves_the_surface_as_it_was(tmp_path, material, mode, capsys):
    """A film's lobe goes with the film: a glossy film of 0 um renders exactly as the same film without a lobe (in
    the shader's modes and in exact mode, where kmpipe composes the stack), on a substrate and on skin."""
    frames = []
    for specular in ("specular = { roughness = 0.2, ior = 1.5 }", ""):
        folder = tmp_path / ("glossy" if specular else "matte")
        folder.mkdir()
        scene = write_scene(folder, material, mode=mode, thickness="0 um", extra="")
        text = scene.read_text(encoding="utf-8").replace('thickness = "0 um"\n', f'thickness = "0 um"\n{specular}\n')
        scene.write_text(text, encoding="utf-8")
        status, image = render(scene, folder / "out")
        assert status == 0
        frames.append(image)
    np.testing.assert_array_equal(frames[0], frames[1])
    assert frames[0].max() > 0.1


# Soft shadows on skin, end to end.


def test_soft_shadows_of_the_made_up_head_agree_with_hard_shadows_averaged_over_the_light(tmp_path, material):
    """The bundled head on skin, made up, over the sweep, seen from the side (the turntable at 90 degrees) under a key
    light 20 degrees wide, as ``kmpipe render`` builds it, at 4096 texels: the visibility of every pixel (the skin
    render over the render without shadows, scattering and environment off so that only the key shades) against its
    mean over 48 hard-shadowed renders with the light turned to directions spread over its disc. The occlusion agrees
    within 15 % and the pixels within 0.04 on average (here: 4.5 %, 0.017); when the sweep and the head shadowed
    themselves, 3.6 times the occlusion, 0.11 on average."""
    from renderer.skin import render_skin

    scene = load_scene(write_scene(tmp_path, material, '[backdrop]\nkind = "sweep"', mesh="head",
                                   base='[skin]\nreflectance = "colorchecker:light skin"',
                                   light="direction = [0.5, 0.6, 0.8]\nangle_deg = 20.0"))  # fmt: skip
    (frame,) = renderer_scenes(scene, plan_scene(scene), [90.0])
    frame = dataclasses.replace(frame, resolution=(128, 128), supersampling=1, multisamples=1, soft_shadow_scale=1,
                                shadow_map_size=4096, scattering=None, environment=None)  # fmt: skip
    (key,) = frame.lights

    def render(light) -> np.ndarray:
        return render_skin(dataclasses.replace(frame, lights=(light,)))[..., 1]

    def visibility(light) -> np.ndarray:
        return render(light) / np.maximum(render(dataclasses.replace(light, cast_shadows=False)), 1e-6)

    towards = -np.asarray(key.direction, dtype=float)
    towards /= np.linalg.norm(towards)
    u = np.cross(towards, (0.0, 1.0, 0.0))
    u /= np.linalg.norm(u)
    v = np.cross(towards, u)
    k = np.arange(48) + 0.5
    r, a = np.tan(np.radians(key.angle_deg) / 2.0) * np.sqrt(k / 48), k * np.pi * (3.0 - np.sqrt(5.0))
    directions = towards + r[:, None] * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * v)
    hard = [dataclasses.replace(key, direction=tuple(-d / np.linalg.norm(d)), angle_deg=0.0) for d in directions]
    averaged = np.mean([visibility(light) for light in hard], axis=0)
    soft = visibility(key)
    seen = render(dataclasses.replace(key, cast_shadows=False)) > 1e-3
    assert np.sum(1.0 - averaged[seen]) > 300.0  # the head's shadow side and its shadow on the sweep
    assert np.sum(1.0 - soft[seen]) == pytest.approx(np.sum(1.0 - averaged[seen]), rel=0.15)
    assert np.mean(np.abs(soft - averaged)[seen]) < 0.04
