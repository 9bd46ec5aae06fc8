"""Antialiasing by supersampling (renderer.scene.supersampled, a scene's ``[output] antialias``).

References, none produced by the code under test: a flat card under a head-on light renders as ``albedo x radiance``
wherever it lies (Lambert at normal incidence), so with k x k samples a pixel a silhouette crosses can only take
``j / k^2`` of that value (j of its samples on the card), and a pixel inside takes it exactly; and a box filter keeps
the image's mean.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from lambert import lambert

from kmpipe import cli
from kmpipe.stages.fit import fit_manifests
from renderer import meshes
from renderer.image_io import read_exr
from renderer.scene import DirectionalLight, OrthographicCamera

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
    assert "antialiasing: 2 x 2 supersampling (4 samples per pixel" in capsys.readouterr().out
    scene = _scene(tmp_path, material, "[output]\nantialias = 1\n")
    assert cli.main(["render", str(scene), "-o", str(tmp_path / "one"), "--explain"]) == 0
    assert "antialiasing: none" in capsys.readouterr().out
    two, header = read_exr(tmp_path / "two" / "frame_000.exr")
    one, _ = read_exr(tmp_path / "one" / "frame_000.exr")
    assert header["antialias"] == "2 x 2 supersampling"
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
