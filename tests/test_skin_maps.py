"""The bundled head's skin maps (recipes/head: head_albedo.png, head_normal.png, head_roughness.png), as committed.

Regions are found without the script's own geometry: points placed from the landmarks (landmarks.json) go to the
texel of the face's vertex nearest to them in front view (its uv), and the lips and the face are where the committed
cosmetic map (recipes/scenes/head_makeup.png, another script's) puts the lipstick and the foundation.
"""

import hashlib
import json
import re
from pathlib import Path

import colour
import numpy as np
import pytest

from renderer.image_io import read_channel, read_png
from renderer.products import load_mesh

HEAD = Path(__file__).resolve().parents[1] / "recipes" / "head"
MAKEUP = HEAD.parent / "scenes" / "head_makeup.png"
SIZE = 1024
MAPS = ("head_albedo.png", "head_normal.png", "head_roughness.png")


@pytest.fixture(scope="module")
def head():
    return load_mesh(HEAD / "head.obj")


@pytest.fixture(scope="module")
def marks():
    return json.loads((HEAD / "landmarks.json").read_text())


@pytest.fixture(scope="module")
def albedo():
    """Linear RGB (SIZE, SIZE, 3) decoded from the 8-bit sRGB file."""
    return colour.models.eotf_sRGB(read_png(HEAD / "head_albedo.png") / 255.0)


@pytest.fixture(scope="module")
def normals():
    """Tangent-space normals (SIZE, SIZE, 3) decoded as n = 2 rgb / 255 - 1."""
    return 2.0 * read_png(HEAD / "head_normal.png") / 255.0 - 1.0


@pytest.fixture(scope="module")
def roughness():
    """Beckmann m (SIZE, SIZE) = value / 255."""
    return read_png(HEAD / "head_roughness.png")[..., 0] / 255.0


@pytest.fixture(scope="module")
def lips():
    return read_channel(MAKEUP, "B") > 0.9


@pytest.fixture(scope="module")
def face():
    return read_channel(MAKEUP, "R") > 0.5


def light_skin_linear_srgb() -> np.ndarray:
    sd = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]["light skin"]
    xyz = colour.sd_to_XYZ(sd, illuminant=colour.SDS_ILLUMINANTS["D65"])
    return colour.XYZ_to_sRGB(xyz / 100.0, apply_cctf_encoding=False)


def disc(head, x: float, y: float, radius: int) -> np.ndarray:
    """The texels within ``radius`` of the texel of the face's vertex nearest to (x, y) in front view (of the
    vertices facing forward in front of z = 40 mm)."""
    front = np.flatnonzero((head.vertices[:, 2] > 40.0) & (head.vertex_normals[:, 2] > 0.0))
    nearest = front[np.argmin(np.hypot(head.vertices[front, 0] - x, head.vertices[front, 1] - y))]
    u, v = head.visual.uv[nearest]
    column, row = u * SIZE - 0.5, (1.0 - v) * SIZE - 0.5
    rows, columns = np.mgrid[:SIZE, :SIZE]
    return np.hypot(rows - row, columns - column) <= radius


def redness(rgb: np.ndarray) -> float:
    mean = rgb.mean(axis=0)
    return mean[0] / mean[1]


def luminance(rgb: np.ndarray) -> float:
    return float(rgb.mean(axis=0) @ [0.2126, 0.7152, 0.0722])


def cheeks(head, marks) -> np.ndarray:
    eye_x, eye_y = marks["joint-l-eye"][:2]
    return disc(head, eye_x + 12.0, eye_y - 26.0, 4) | disc(head, -eye_x - 12.0, eye_y - 26.0, 4)


def forehead(head, marks) -> np.ndarray:
    return disc(head, 0.0, marks["joint-l-upperlid"][1] + 30.0, 4)


def test_maps_are_1024_square_with_the_documented_channels_and_recorded_sha256():
    readme = (HEAD / "README.md").read_text()
    for name, channels in zip(MAPS, (3, 3, 1), strict=True):
        assert read_png(HEAD / name).shape == (SIZE, SIZE, channels), name
        recorded = re.search(rf"\| `{re.escape(name)}` \| `([0-9a-f]{{64}})` \|", readme)
        assert recorded is not None, name
        assert hashlib.sha256((HEAD / name).read_bytes()).hexdigest() == recorded.group(1), name


def test_albedo_averages_to_light_skin_over_the_face_and_fills_with_it(albedo, face):
    target = light_skin_linear_srgb()
    np.testing.assert_allclose(albedo[face].mean(axis=0), target, rtol=0.02)
    corner = read_png(HEAD / "head_albedo.png")[0, 0]  # no island reaches the uv square's corner
    assert np.all(np.abs(corner.astype(int) - np.rint(255.0 * colour.cctf_encoding(target))) <= 1)


def test_lips_are_redder_than_cheeks_and_cheeks_redder_than_forehead(head, marks, albedo, lips):
    lip, cheek, bare = (
        redness(albedo[lips]),
        redness(albedo[cheeks(head, marks)]),
        redness(albedo[forehead(head, marks)]),
    )
    assert lip > 1.3 * cheek
    assert luminance(albedo[lips]) < luminance(albedo[cheeks(head, marks)])  # darker, too
    assert cheek > 1.04 * bare


def test_brows_are_darker_than_the_forehead(head, marks, albedo):
    lid_x, lid_y = marks["joint-l-upperlid"][:2]
    for side in (-1.0, 1.0):
        brow = disc(head, side * (lid_x + 5.0), lid_y + 7.0, 2)
        assert luminance(albedo[brow]) < 0.8 * luminance(albedo[forehead(head, marks)])


def test_normal_map_is_unit_outward_unbiased_and_modest(normals, face):
    length = np.linalg.norm(normals, axis=-1)
    assert np.all(np.abs(length - 1.0) < 0.02)  # 8-bit codes: within a code of unit length
    assert normals[..., 2].min() > np.cos(np.radians(25.0))  # never tilted past 25 deg (~20 by design)
    tilt = np.degrees(np.arccos(np.clip(normals[face][:, 2] / length[face], -1.0, 1.0)))
    assert 1.0 < np.sqrt(np.mean(tilt**2)) < 5.0  # RMS tilt over the face, deg: skin, not orange peel
    assert np.all(np.abs(normals[face][:, :2].mean(axis=0)) < 0.005)  # no tilt on average (0.3 deg)
    assert np.all(read_png(HEAD / "head_normal.png")[0, 0] == (128, 128, 255))  # flat off the islands


def test_normal_map_has_detail_where_the_face_is(normals, face):
    tilt = np.degrees(np.arccos(np.clip(normals[..., 2], -1.0, 1.0)))
    assert np.mean(tilt[face] > 2.0) > 0.1  # pores and lines over the face, not a flat map


def test_roughness_is_in_range_and_lips_are_smoother_than_cheeks(head, marks, roughness, lips):
    assert 0.1 <= roughness.min() and roughness.max() <= 0.6
    cheek = roughness[cheeks(head, marks)].mean()
    assert roughness[lips].mean() < cheek - 0.1
    assert roughness[forehead(head, marks)].mean() < cheek  # the T-zone is shinier
