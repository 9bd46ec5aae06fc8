"""Antialiasing by supersampling (renderer.scene.supersampled) and by multisampling (renderer.multisample), and how a
scene's ``[output] antialias`` and ``antialias_method`` choose (kmpipe.stages.antialiasing).

References, none produced by the code under test: a flat card under a head-on light renders as ``albedo x radiance``
wherever it lies (Lambert at normal incidence), so with n samples a pixel a silhouette crosses can only take
``j / n`` of that value (j of its samples on the card), and a pixel inside takes it exactly; a box filter keeps
the image's mean; a disc of radius r covers pi r^2 of the image; a card of known size and uv has texels of known size.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import trimesh
from lambert import joined, lambert

from kmpipe import cli
from kmpipe.formats.scene import load_scene
from kmpipe.stages.antialiasing import uv_texel_mm
from kmpipe.stages.fit import fit_manifests
from kmpipe.stages.render_plan import plan_scene
from renderer import meshes
from renderer.environment import Environment
from renderer.image_io import read_exr
from renderer.layers import render_layers
from renderer.scene import DirectionalLight, GradientBackground, OrthographicCamera, Prop, Scattering, Scene
from renderer.skin import render_skin
from renderer.stack import ChannelStack

ALBEDO = np.array([0.6, 0.45, 0.3])
RADIANCE = np.array([1.0, 1.0, 1.0])
HEAD_ON = DirectionalLight(direction=(0.0, 0.0, -1.0), radiance=tuple(RADIANCE))


def _tilted_card(angle_deg: float = 23.0) -> trimesh.Trimesh:
    """A 12 x 8 mm card turned about the view axis, so that its edges cross the pixel grid at odd places."""
    card = meshes.card(12.0, 8.0)
    card.apply_transform(trimesh.transformations.rotation_matrix(np.radians(angle_deg), (0.0, 0.0, 1.0)))
    return card


@pytest.mark.parametrize("k", [2, 3, 4])
def test_a_pixel_takes_the_share_of_its_samples_on_the_card(k):
    camera = OrthographicCamera(half_height=10.0)
    image = lambert(_tilted_card(), camera, HEAD_ON, tuple(ALBEDO), 40, 40, supersampling=k).astype(np.float64)
    value = ALBEDO * RADIANCE
    share = image / value  # per channel: j / k^2 in every pixel, the same j in every channel
    j = np.rint(share * k * k)
    assert np.allclose(share, j / (k * k), atol=1e-6)
    assert np.all(j == j[..., :1])
    found = set(np.unique(j).astype(int))
    assert {0, k * k} <= found and len(found - {0, k * k}) >= k * k // 2  # partial coverage along the edges
    assert np.count_nonzero(j == k * k) > 0.4 * np.count_nonzero(j > 0)


def test_without_supersampling_a_pixel_is_on_the_card_or_off_it():
    image = lambert(_tilted_card(), OrthographicCamera(half_height=10.0), HEAD_ON, tuple(ALBEDO), 40, 40)
    values = {tuple(np.round(p.astype(np.float64), 6).tolist()) for p in image.reshape(-1, 3)}
    assert values == {(0.0, 0.0, 0.0), tuple(np.round(ALBEDO * RADIANCE, 6).tolist())}


def test_inside_a_flat_region_supersampling_changes_nothing_and_the_mean_is_kept():
    camera = OrthographicCamera(half_height=10.0)
    plain = lambert(meshes.card(40.0, 40.0), camera, HEAD_ON, tuple(ALBEDO), 24, 24)  # the card fills the frame
    fine = lambert(meshes.card(40.0, 40.0), camera, HEAD_ON, tuple(ALBEDO), 24, 24, supersampling=3)
    assert np.array_equal(plain, fine)  # bit for bit
    sphere = meshes.sphere(6.0)
    coarse = lambert(sphere, camera, HEAD_ON, tuple(ALBEDO), 20, 20, supersampling=2).astype(np.float64)
    detail = lambert(sphere, camera, HEAD_ON, tuple(ALBEDO), 40, 40).astype(np.float64)
    assert np.allclose(coarse.mean(axis=(0, 1)), detail.mean(axis=(0, 1)), rtol=1e-6)  # the box filter keeps light


def test_multisampled_a_pixel_takes_the_share_of_its_4_samples_on_the_card():
    camera = OrthographicCamera(half_height=10.0)
    image = lambert(_tilted_card(), camera, HEAD_ON, tuple(ALBEDO), 40, 40, multisamples=4).astype(np.float64)
    share = image / (ALBEDO * RADIANCE)
    j = np.rint(share * 4)
    assert np.allclose(share, j / 4, atol=1e-6)
    assert np.all(j == j[..., :1])
    assert set(np.unique(j).astype(int)) == {0, 1, 2, 3, 4}  # every partial coverage occurs along the edges
    plain = lambert(_tilted_card(), camera, HEAD_ON, tuple(ALBEDO), 40, 40).astype(np.float64)
    inside = j[..., 0] == 4
    assert np.array_equal(image[inside], plain[inside])  # bit for bit where the card covers the whole pixel


def _shares(image: np.ndarray, front: np.ndarray, back: np.ndarray) -> np.ndarray:
    """j (0 .. 4) with image = back + j / 4 (front - back) in every pixel and channel, asserted."""
    j = (image - back) / (front - back) * 4.0
    assert np.allclose(j, np.rint(j), atol=1e-4)
    j = np.rint(j)
    assert np.all(j == j[..., :1])
    return j[..., 0]


def test_multisampled_a_crease_of_one_mesh_takes_the_share_of_each_face():
    """A roof of two faces of one mesh meeting at a ridge (normals 60 degrees apart), turned about the view axis so
    that the ridge crosses pixels at odd places, lit from one side: each face is uniformly lit, and a pixel the ridge
    crosses takes j/4 of each, as 4 samples would."""
    faces = []
    for side in (-1.0, 1.0):
        face = meshes.card(20.0, 40.0)  # the roof fills the frame
        face.apply_transform(trimesh.transformations.translation_matrix((10.0 * side, 0.0, 0.0)))
        face.apply_transform(trimesh.transformations.rotation_matrix(np.radians(-30.0 * side), (0.0, 1.0, 0.0)))
        faces.append(face)
    roof = joined(*faces)
    roof.apply_transform(trimesh.transformations.rotation_matrix(np.radians(23.0), (0.0, 0.0, 1.0)))
    light = DirectionalLight(direction=(-0.6, 0.0, -0.8), radiance=tuple(RADIANCE), cast_shadows=False)
    camera = OrthographicCamera(half_height=8.0)
    image = lambert(roof, camera, light, tuple(ALBEDO), 40, 40, multisamples=4).astype(np.float64)
    normals = [face.vertex_normals[0] @ trimesh.transformations.rotation_matrix(np.radians(23.0), (0, 0, 1))[:3, :3].T
               for face in faces]  # fmt: skip
    lit = [ALBEDO * RADIANCE * max(float(n @ -np.array(light.direction)), 0.0) for n in normals]
    j = _shares(image, lit[0], lit[1])
    assert {1, 2, 3} <= set(np.unique(j).astype(int))  # the ridge's pixels
    assert np.count_nonzero((j > 0) & (j < 4)) < 3 * 40  # along the ridge only


def test_multisampled_a_surface_over_another_of_the_same_mesh_and_a_prop_behind_both_keep_their_shares():
    """One mesh of two parallel cards 2 mm apart (the front one turned about the view axis, its vertices half
    occluded), a prop card behind them, in a uniform environment: each surface renders albedo x L x its occlusion,
    and every pixel takes j/4 of the surfaces its samples show, though the two cards share a normal."""
    front = _tilted_card()
    front.apply_transform(trimesh.transformations.translation_matrix((0.0, 0.0, 2.0)))
    back = meshes.card(30.0, 30.0)
    mesh = joined(front, back)
    occlusion = np.r_[np.full(len(front.vertices), 0.5), np.ones(len(back.vertices))]
    prop = Prop(mesh=meshes.card(60.0, 60.0), albedo=(0.2, 0.2, 0.2),
                model=trimesh.transformations.translation_matrix((0.0, 0.0, -3.0)))  # fmt: skip
    dark = DirectionalLight(direction=(0.0, 0.0, -1.0), radiance=(0.0, 0.0, 0.0), cast_shadows=False)
    scene = Scene(mesh=mesh, stack=ChannelStack([], [], tuple(ALBEDO)), camera=OrthographicCamera(half_height=10.0),
                  lights=[dark], resolution=(40, 40), environment=Environment(np.full((16, 32, 3), 0.7, np.float32)),
                  occlusion=occlusion, props=[prop], multisamples=4)  # fmt: skip
    image = render_layers(scene).astype(np.float64)
    j = _shares(image, 0.5 * ALBEDO * 0.7, ALBEDO * 0.7)
    assert {0, 1, 2, 3, 4} <= set(np.unique(j).astype(int))
    plain = render_layers(dataclasses.replace(scene, multisamples=1)).astype(np.float64)
    assert np.array_equal(image[(j == 0) | (j == 4)], plain[(j == 0) | (j == 4)])  # one surface: bit for bit
    # The prop lies wholly behind the back card: without it the frame is the same, bit for bit.
    assert np.array_equal(render_layers(dataclasses.replace(scene, props=[])).astype(np.float64), image)


def test_more_meshes_than_the_pass_can_tell_apart_are_refused():
    props = [Prop(mesh=meshes.card(1.0, 1.0), albedo=(0.5, 0.5, 0.5))] * 8
    with pytest.raises(ValueError, match="at most 7 props"):
        lambert(_tilted_card(), OrthographicCamera(half_height=10.0), HEAD_ON, tuple(ALBEDO), 8, 8, props=props)


def test_multisampled_coverage_of_a_disc_is_its_area():
    """A flat disc (a 96-gon) of radius 7 mm in a 20 mm square frame: the image's total share of the disc's value is
    the polygon's area in pixels, to the sampling error of 4 samples along its rim."""
    radius, size = 7.0, 64
    angles = np.linspace(0.0, 2.0 * np.pi, 97)[:-1]
    rim = np.column_stack([radius * np.cos(angles), radius * np.sin(angles), np.zeros(96)])
    vertices = np.vstack([[0.0, 0.0, 0.0], rim])
    faces = np.array([[0, 1 + i, 1 + (i + 1) % 96] for i in range(96)])
    uv = trimesh.visual.TextureVisuals(uv=0.5 + vertices[:, :2] / 20.0)
    disc = trimesh.Trimesh(vertices, faces, vertex_normals=np.tile([0.0, 0.0, 1.0], (97, 1)), visual=uv, process=False)
    camera = OrthographicCamera(half_height=10.0)
    image = lambert(disc, camera, HEAD_ON, tuple(ALBEDO), size, size, multisamples=4).astype(np.float64)
    covered = (image / (ALBEDO * RADIANCE))[..., 0].sum()
    area = 0.5 * 96 * radius**2 * np.sin(2.0 * np.pi / 96) * (size / 20.0) ** 2
    rim_pixels = 2.0 * np.pi * radius * size / 20.0
    assert abs(covered - area) < 0.05 * rim_pixels  # a rim pixel is off by at most 1/8 on average
    plain = lambert(disc, camera, HEAD_ON, tuple(ALBEDO), size, size).astype(np.float64)
    assert abs(covered - area) < abs((plain / (ALBEDO * RADIANCE))[..., 0].sum() - area) + 1.0


def test_multisampled_silhouettes_blend_with_a_gradient_background_by_their_coverage():
    camera = OrthographicCamera(half_height=10.0)
    background = GradientBackground(top=(0.2, 0.3, 0.4), bottom=(0.05, 0.05, 0.1))
    image = lambert(_tilted_card(), camera, HEAD_ON, tuple(ALBEDO), 40, 40, multisamples=4,
                    background=background).astype(np.float64)  # fmt: skip
    bare = lambert(_tilted_card(), camera, HEAD_ON, tuple(ALBEDO), 40, 40, multisamples=4).astype(np.float64)
    t = (np.arange(40) + 0.5) / 40
    s = (t * t * (3.0 - 2.0 * t))[:, None, None]
    behind = np.asarray(background.top) + (np.asarray(background.bottom) - np.asarray(background.top)) * s
    cover = bare[..., :1] / (ALBEDO * RADIANCE)[0]  # the share of each pixel the card covers
    np.testing.assert_allclose(image, bare + (1.0 - cover) * behind, atol=1e-6)


def test_a_uniformly_lit_multisampled_skin_keeps_its_light_under_the_blur_at_its_silhouette():
    """Skin of one albedo facing the light everywhere: the blur of a uniform light is that light, also in the pixels
    its rim covers in part, so the blurred frame equals the unblurred one."""
    camera = OrthographicCamera(half_height=10.0)
    scene = {"mesh": _tilted_card(), "camera": camera, "lights": [HEAD_ON],
             "stack": ChannelStack([], [], tuple(ALBEDO)), "resolution": (48, 48), "multisamples": 4}  # fmt: skip
    blurred = render_skin(Scene(**scene, scattering=Scattering(alpha=1.0, beta=0.0, gradient_clamp=0.001)))
    plain = render_skin(Scene(**scene))
    share = plain[..., 0] / (ALBEDO * RADIANCE)[0]
    assert ((share > 0.1) & (share < 0.9)).sum() > 20  # the rim is partly covered
    np.testing.assert_allclose(blurred, plain, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("samples", [0, 3, 8])
def test_a_sample_count_multisampling_cannot_take_is_refused(samples):
    with pytest.raises(ValueError, match="samples a pixel"):
        lambert(_tilted_card(), OrthographicCamera(half_height=10.0), HEAD_ON, tuple(ALBEDO), 8, 8,
                multisamples=samples)  # fmt: skip


def test_a_maps_texel_size_is_the_cards_side_over_its_texels():
    card = meshes.card(30.0, 20.0)  # uv [0, 1]^2 over 30 x 20 mm
    assert uv_texel_mm(card, np.eye(4), (200, 300)) == pytest.approx(np.sqrt(600.0 / 60000.0), rel=1e-12)
    doubled = np.diag([2.0, 2.0, 2.0, 1.0])
    assert uv_texel_mm(card, doubled, (200, 300)) == pytest.approx(2.0 * np.sqrt(600.0 / 60000.0), rel=1e-12)


@pytest.fixture(scope="module")
def material(tmp_path_factory):
    path = tmp_path_factory.mktemp("material") / "F1.json"
    fit_manifests([Path(__file__).resolve().parents[1] / "recipes/samples/F1/manifest.toml"], path)
    return path


def _scene(folder: Path, material: Path, output: str = "") -> Path:
    path = folder / "scene.toml"
    path.write_text(
        f'[scene]\nname = "card"\nmesh = "sphere"\nresolution = [24, 24]\nmode = "exact"\n'
        f'[substrate]\nreflectance = 0.8\n[[layer]]\nmaterial = "{material}"\nthickness = "20 um"\n'
        f"[[light]]\ndirection = [0.4, 0.8, 0.6]\n{output}"
    )
    return path


def test_a_scene_antialiases_by_default_and_says_so(tmp_path, material, capsys):
    assert cli.main(["render", str(_scene(tmp_path, material)), "-o", str(tmp_path / "two"), "--explain"]) == 0
    out = capsys.readouterr().out
    assert "antialiasing: 4 x multisampling (antialias = 2, the default" in out
    assert "no map varies the shading inside a triangle" in out
    scene = _scene(tmp_path, material, "[output]\nantialias = 1\n")
    assert cli.main(["render", str(scene), "-o", str(tmp_path / "one"), "--explain"]) == 0
    assert "antialiasing: none" in capsys.readouterr().out
    two, header = read_exr(tmp_path / "two" / "frame_000.exr")
    one, _ = read_exr(tmp_path / "one" / "frame_000.exr")
    assert header["antialias"] == "4 x multisampling"
    covered_one, covered_two = (one > 0).any(axis=-1), (two > 0).any(axis=-1)
    assert covered_two.sum() > covered_one.sum()  # the rim's partly covered pixels
    rim = covered_two & ~covered_one
    assert two[rim].max() < two[covered_one].max()  # and they are partial
    assert np.allclose(two.mean(axis=(0, 1)), one.mean(axis=(0, 1)), rtol=0.05)  # the same light, resampled


@pytest.mark.parametrize("value", ["0", "5", "1.5", '"2x"'])
def test_an_antialias_that_is_not_1_to_4_is_exit_2_naming_the_field(tmp_path, material, capsys, value):
    scene = _scene(tmp_path, material, f"[output]\nantialias = {value}\n")
    assert cli.main(["render", str(scene), "-o", str(tmp_path / "out")]) == 2
    assert "output.antialias" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_supersampled_frame_too_large_to_render_is_exit_2_naming_the_field(tmp_path, material, capsys):
    scene = _scene(tmp_path, material, "[output]\nantialias = 3\n")
    scene.write_text(scene.read_text().replace("resolution = [24, 24]", "resolution = [4096, 2048]"))
    assert cli.main(["render", str(scene), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "output.antialias" in err and "12288 px render" in err


def test_a_scene_can_ask_for_either_method(tmp_path, material, capsys):
    scene = _scene(tmp_path, material, '[output]\nantialias_method = "supersample"\n')
    assert cli.main(["render", str(scene), "-o", str(tmp_path / "ss"), "--explain"]) == 0
    assert "antialiasing: 2 x 2 supersampling (antialias = 2, the default" in capsys.readouterr().out
    assert read_exr(tmp_path / "ss" / "frame_000.exr")[1]["antialias"] == "2 x 2 supersampling"
    scene = _scene(tmp_path, material, "[output]\nantialias = 3\n")
    assert "multisampling stops at 4 samples a pixel" in plan_scene(load_scene(scene)).explain()
    scene = _scene(tmp_path, material, '[output]\nantialias = 2\nantialias_method = "multisample"\n')
    assert "as the scene asks" in plan_scene(load_scene(scene)).explain()


def test_multisampling_more_than_4_samples_is_exit_2_naming_the_field(tmp_path, material, capsys):
    scene = _scene(tmp_path, material, '[output]\nantialias = 3\nantialias_method = "multisample"\n')
    assert cli.main(["render", str(scene), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "output.antialias_method" in err and "at most 2 x 2" in err
    assert not (tmp_path / "out").exists()


def test_the_planner_supersamples_a_map_finer_than_a_pixel(tmp_path, material):
    """The sphere at 24 px (about 1 mm a pixel) wearing a 512 x 512 thickness map (about 0.1 mm a texel): one shaded
    sample a pixel would alias the map, so the planner supersamples; at 4 x 4 texels the map is coarse: multisample."""
    import cv2

    for side, method in ((512, "supersample"), (4, "multisample")):
        ramp = np.tile(np.linspace(0, 255, side, dtype=np.uint8), (side, 1))
        cv2.imwrite(str(tmp_path / "map.png"), np.dstack([ramp, ramp, ramp]))
        scene = _scene(tmp_path, material)
        text = scene.read_text().replace('thickness = "20 um"', 'thickness_map = { file = "map.png", max = "20 um" }')
        scene.write_text(text)
        plan = plan_scene(load_scene(scene))
        assert plan.antialiasing == method
        assert ("finer than a pixel" in plan.explain()) == (method == "supersample")
