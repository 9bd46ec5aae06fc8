"""Golden images: three small scenes (tests/data/golden/*.toml, 96 x 96) re-rendered and compared with the EXR frames
stored beside them, by pixel statistics. Never by checksum: OpenImageIO stamps DateTime into every file, and another
machine's llvmpipe or BLAS may change the last bits. Regenerate with ``.venv/bin/python
tests/data/golden/make_golden.py`` after an intended change of the renderer or the planner, and look at the frames.

Together the scenes exercise what the renderer does: "compact" (F1 with a lobe, the planned default mode, a ground,
a shadowing directional light and an unshadowed point light, a 2-frame turntable), "lipstick" (two layers, exact mode,
a lobe on the top layer, shadows on the ground) and "wedge" (a thickness map over a ColorChecker patch, bands:12,
orthographic camera).

Tolerances (:func:`differences`), for an image ``a`` against its golden ``g``:

- same shape;
- per-channel mean: ``|mean(a) - mean(g)| <= 1 % of mean(g) + 1e-4``. A re-render on one machine is bit-identical;
  across machines the float order of llvmpipe, the material fit's last digits and a shadow-map texel at an edge move
  a mean by far less than 1e-3 relative. A light 3 % brighter moves it by ~2 % and must fail (tested below);
- 99th percentile of ``|a - g|`` below 2 % of the golden's 99th-percentile value: up to 1 % of the values (a
  silhouette or shadow edge moved by a pixel) may differ freely, all others must agree to 2 % of a bright pixel;
- at most 0.5 % of the pixels (46 of 9216) differ by more than 5 % of the golden's maximum in some channel: a
  structural change (a moved shadow, a missing lobe) touches more than that, rounding never does.

Independent of the goldens: pixels whose camera ray misses the product and the ground (the convex hull of their
projected vertices, grown by a pixel) are exactly the background, 0; the wedge's card follows the Kubelka-Munk
reflectance of F2 over dark skin along the map's gradient (monotonically, in the direction KM predicts, to 0.005);
the lipstick's ground is dark in its shadow and 0.4 cos(theta) where the light reaches it.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import cv2
import numpy as np
import pytest

from kmpipe.formats.material import read_material
from kmpipe.formats.scene import Scene, load_scene
from kmpipe.physics.optical_tables import exact_rgb, working_space
from kmpipe.stages.render import renderer_scenes
from kmpipe.stages.render_plan import GROUND_EXTENT, plan_scene
from renderer.image_io import read_exr

GOLDEN = Path(__file__).resolve().parent / "data" / "golden"
_spec = importlib.util.spec_from_file_location("make_golden", GOLDEN / "make_golden.py")
make_golden = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(make_golden)

MEAN_RELATIVE, MEAN_FLOOR = 0.01, 1e-4
P99_SHARE = 0.02
OUTLIER_LEVEL, OUTLIER_SHARE = 0.05, 0.005


def differences(image: np.ndarray, golden: np.ndarray) -> list[str]:
    """What is wrong with ``image`` against ``golden`` by the module's tolerances (empty: it matches)."""
    if image.shape != golden.shape:
        return [f"shape {image.shape} != golden {golden.shape}"]
    problems = []
    mean, expected = image.mean(axis=(0, 1)), golden.mean(axis=(0, 1))
    if np.any(np.abs(mean - expected) > MEAN_RELATIVE * np.abs(expected) + MEAN_FLOOR):
        problems.append(f"channel means {np.round(mean, 5)} != golden {np.round(expected, 5)} (1 %)")
    error = np.abs(image.astype(np.float64) - golden)
    p99, limit = np.percentile(error, 99), P99_SHARE * np.percentile(golden, 99)
    if p99 > limit:
        problems.append(f"99th percentile of |difference| {p99:.4g} > {limit:.4g}")
    outliers = np.mean(np.any(error > OUTLIER_LEVEL * golden.max(), axis=-1))
    if outliers > OUTLIER_SHARE:
        problems.append(f"{outliers:.2%} of the pixels differ by more than {OUTLIER_LEVEL:.0%} of the maximum")
    return problems


@pytest.fixture(scope="module")
def staged(tmp_path_factory) -> Path:
    """The scene files and wedge.png beside freshly fitted materials/ (one fit per material for the module)."""
    return make_golden.stage(tmp_path_factory.mktemp("golden"))


@pytest.fixture(scope="module")
def renders(staged, tmp_path_factory) -> dict[str, list[np.ndarray]]:
    out = tmp_path_factory.mktemp("renders")
    return {s: [read_exr(p)[0] for p in make_golden.render(staged, s, out / s)] for s in make_golden.SCENES}


def goldens(scene: str) -> list[tuple[np.ndarray, dict]]:
    return [read_exr(path) for path in make_golden.golden_paths(scene)]


def framed(scene: Scene, turntable_deg: float = 0.0):
    """The renderer's scene of ``scene`` turned by ``turntable_deg``, as kmpipe renders it: its camera and model."""
    return renderer_scenes(scene, plan_scene(scene), [turntable_deg])[0]


def to_pixels(scene: Scene, points) -> np.ndarray:
    """(column, row) image coordinates (pixel centres at + 0.5, row 0 at the top) of world points (mm)."""
    width, height = scene.info.scene.resolution
    camera = framed(scene).camera
    points = np.asarray(points, dtype=float)
    clip = np.c_[points, np.ones(len(points))] @ (camera.projection_matrix(width / height) @ camera.view_matrix()).T
    assert np.all(clip[:, 3] > 0), "a point behind the camera"
    ndc = clip[:, :2] / clip[:, 3:]
    return np.c_[(ndc[:, 0] + 1.0) / 2.0 * width, (1.0 - ndc[:, 1]) / 2.0 * height]


def placed_vertices(scene: Scene, model: np.ndarray) -> np.ndarray:
    return np.asarray(scene.mesh.vertices) @ model[:3, :3].T + model[:3, 3]


def empty_pixels(scene: Scene, turntable_deg: float) -> np.ndarray:
    """Pixels no surface can cover: outside the projected hull of the turned mesh and the ground, grown by a pixel."""
    points = [placed_vertices(scene, framed(scene, turntable_deg).model)]
    if (
        scene.info.ground is not None
    ):  # as kmpipe.stages.render places it: a square of GROUND_EXTENT radii under the product
        still = placed_vertices(scene, scene.model)
        centre = 0.5 * (still.min(axis=0) + still.max(axis=0))
        half = GROUND_EXTENT * np.max(np.linalg.norm(still - centre, axis=1))
        floor = still[:, 1].min()
        points.append([(centre[0] + x * half, floor, centre[2] + z * half) for x in (-1, 1) for z in (-1, 1)])
    hull = cv2.convexHull(np.round(to_pixels(scene, np.concatenate(points)) * 16).astype(np.int32))
    width, height = scene.info.scene.resolution
    covered = cv2.fillConvexPoly(np.zeros((height, width), np.uint8), hull, 1, shift=4)
    return cv2.dilate(covered, np.ones((3, 3), np.uint8)) == 0


def patch(image: np.ndarray, pixel) -> np.ndarray:
    """Mean of the 3 x 3 pixels around image coordinates (column, row)."""
    column, row = (int(v) for v in pixel)
    return image[row - 1 : row + 2, column - 1 : column + 2].reshape(-1, image.shape[-1]).mean(axis=0)


@pytest.mark.parametrize("scene", make_golden.SCENES)
def test_render_matches_golden(renders, scene):
    stored = goldens(scene)
    assert len(renders[scene]) == len(stored) > 0
    for i, (image, (golden, _)) in enumerate(zip(renders[scene], stored, strict=True)):
        assert not differences(image, golden), f"{scene} frame {i}: {differences(image, golden)}"


@pytest.mark.parametrize(
    ("scene", "mode"), [("compact", None), ("lipstick", "exact"), ("wedge", "bands:12"), ("face", None)]
)
def test_golden_headers(staged, scene, mode):
    loaded = load_scene(staged / f"{scene}.toml")
    mode = mode or plan_scene(loaded).mode  # the planner's default choice, which the golden must still match
    angles = loaded.turntable_angles_deg() * (2 if scene in make_golden.AB_SCENES else 1)  # with, then without SSS
    for i, (golden, header) in enumerate(goldens(scene)):
        assert golden.shape == (96, 96, 3)
        assert header["render_mode"] == mode, f"{scene}: golden made in {header['render_mode']}; regenerate it"
        assert header["product"] == loaded.product and header["shade"] == loaded.shade
        hashes = header["material_sha256"].split(", ")
        assert len(hashes) == len(loaded.materials) and all(len(h) == 64 for h in hashes)
        assert header["camera_azimuth_deg"] == pytest.approx((loaded.info.camera.azimuth_deg + angles[i]) % 360.0)


@pytest.mark.parametrize("scene", make_golden.SCENES)
def test_uncovered_pixels_are_background(staged, renders, scene):
    loaded = load_scene(staged / f"{scene}.toml")
    for i, turn in enumerate(loaded.turntable_angles_deg()):
        empty = empty_pixels(loaded, turn)
        assert empty.mean() > 0.05, "the check needs some empty image"
        assert empty[0, 0], "the top-left corner is empty"
        for image in (renders[scene][i], goldens(scene)[i][0]):
            assert np.all(image[empty] == 0.0)


def test_wedge_follows_kubelka_munk_along_the_map(staged, renders):
    scene = load_scene(staged / "wedge.toml")
    material = read_material(staged / "materials" / "F2.json")
    space = working_space(material.wavelengths, scene.info.scene.illuminant)
    lo, hi = scene.thickness_range_mm(0)
    # The card (u from 0 at its left edge to 1 at its right) faces the camera and the light (radiance 1) head-on,
    # so a pixel is the stack's reflectance at the map's thickness there: the ramp of n texels (0 .. 1, centres at
    # (i + 0.5) / n) sampled linearly, clamped at the ends.
    left, right = to_pixels(scene, [(-25.0, 0.0, 0.0), (25.0, 0.0, 0.0)])[:, 0]
    columns = np.arange(int(np.ceil(left)) + 2, int(right) - 2)
    n = np.shape(scene.thicknesses_mm[0])[1]
    ramp = np.clip(((columns + 0.5 - left) / (right - left) * n - 0.5) / (n - 1), 0.0, 1.0)
    predicted = exact_rgb([material], [lo + ramp * (hi - lo)], scene.substrate_reflectance(), space)
    direction = np.sign(predicted[-1] - predicted[0])
    assert np.all(direction == 1.0), "F2 is lighter than dark skin: thicker films are brighter"
    for image in (renders["wedge"][0], goldens("wedge")[0][0]):
        row = image[image.shape[0] // 2, columns].astype(np.float64)
        assert np.all(direction * np.diff(row, axis=0) >= -1e-4), "not monotonic along the gradient"
        np.testing.assert_allclose(row, predicted, atol=0.005)  # bands:12 and the table


def test_lipstick_ground_is_dark_in_the_shadow_and_lambertian_in_the_light(staged, renders):
    scene = load_scene(staged / "lipstick.toml")
    light = scene.info.light[0]
    towards = np.asarray(light.direction) / np.linalg.norm(light.direction)
    vertices = placed_vertices(scene, scene.model)
    base = np.array([0.0, vertices[:, 1].min(), 0.0]) + 0.5 * (vertices.min(axis=0) + vertices.max(axis=0)) * [1, 0, 1]
    height = 0.5 * np.ptp(vertices[:, 1])
    shadowed = base + height * (np.array([0.0, 1.0, 0.0]) - towards / towards[1])  # where the axis's middle falls
    sideways = towards * [1.0, 0.0, 1.0]
    lit = base + 15.0 * sideways / np.linalg.norm(sideways)  # on the light's side, in front of the bullet
    lambert = scene.info.ground.reflectance * towards[1] * np.asarray(light.radiance)
    for image in (renders["lipstick"][0], goldens("lipstick")[0][0]):
        in_shadow, in_light = (patch(image, p) for p in to_pixels(scene, [shadowed, lit]))
        np.testing.assert_allclose(in_light, lambert, rtol=0.02)
        assert np.all(in_shadow < 0.2 * in_light)


def test_comparison_rejects_a_3_percent_brighter_light(staged, tmp_path):
    text = (staged / "compact.toml").read_text(encoding="utf-8")
    assert text.count("radiance = [1.0, 1.0, 1.0]") == 1
    brighter = staged / "compact_brighter.toml"  # beside materials/, which the scene names relatively
    brighter.write_text(text.replace("radiance = [1.0, 1.0, 1.0]", "radiance = [1.03, 1.03, 1.03]"), encoding="utf-8")
    from kmpipe.stages.render import render_scene

    frames = [p for p in render_scene(brighter, tmp_path, echo=lambda _: None) if p.suffix == ".exr"]
    for frame, (golden, _) in zip(frames, goldens("compact"), strict=True):
        assert differences(read_exr(frame)[0], golden), "a 3 % brighter key light passed as the golden"


def test_face_scattering_moves_skin_light_without_making_or_losing_it(staged, renders):
    """With and without subsurface scattering (goldens and fresh renders): the blur visibly changes the skin, but
    the image's total light agrees to 1 % (the blur redistributes the skin's light; weights sum to 1)."""
    scene = load_scene(staged / "face.toml")
    for with_sss, without in ((renders["face"][0], renders["face"][1]), (goldens("face")[0][0], goldens("face")[1][0])):
        assert np.abs(with_sss - without).max() > 0.01
        np.testing.assert_allclose(with_sss.sum(axis=(0, 1)), without.sum(axis=(0, 1)), rtol=0.01)
    headers = [header for _, header in goldens("face")]
    assert headers[0]["subsurface_scattering"].startswith("alpha 8")
    assert headers[1]["subsurface_scattering"].startswith("off")
    # The lips (the cosmetic map's lipstick ellipse at u = 0.5, v = 0.31) are red: L1 over the foundation.
    from renderer.meshes import head

    mesh = head()
    uv = np.asarray(mesh.visual.uv)
    lips = np.asarray(mesh.vertices)[np.argmin(np.hypot(uv[:, 0] - 0.5, uv[:, 1] - 0.31))]
    red, green, blue = patch(renders["face"][1], to_pixels(scene, [lips])[0])
    assert red > 2.0 * green and red > 2.0 * blue
