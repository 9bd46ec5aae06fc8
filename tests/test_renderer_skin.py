"""Makeup on skin (renderer.skin) against references written here, never against numbers the code produced.

References: the skin profile and blend weights as printed in the thesis (Table 3.1, thesis eq. 3.3); conservation laws
of the blur (a normalised symmetric blur keeps a uniform image and a row's total light, and mirrors a step); closed
forms of the layer pass (a film of albedo ``a`` lit at angle theta renders as ``a E cos(theta)``; the Kelemen /
Szirmay-Kalos lobe written out below); and the continuous sum of Gaussians of Table 3.1 for the blur's size.

Scenes: an orthographic camera looks down -z at a card in the z = 0 plane (``meshes.card``, uv (0, 0) at its
bottom-left), lit by directional lights, so the view vector is +z everywhere and every card pixel sees the same
light. The skin light of a pixel is what :func:`render_skin` adds to the makeup's own reflectance (over black) and
the lobes; with no lobes and films of known R0 it is the render minus ``E cos(theta) R0``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy import optimize, special

from renderer import meshes
from renderer.layers import render_layers
from renderer.scene import DirectionalLight, OrthographicCamera, PerspectiveCamera, PointLight, Prop, Scattering, Scene
from renderer.skin import SKIN_VARIANCES_MM2, SKIN_WEIGHTS, blend_weights, render_skin
from renderer.stack import SKIN_SPECULAR, ChannelStack, LayerTable, Precomposed, Specular

# Thesis Table 3.1, as printed: variance (mm^2), W_i (R, G, B), W'_i (R, G, B).
TABLE_3_1 = (
    (0.0064, (0.2405, 0.4474, 0.6157), (1.0, 1.0, 1.0)),
    (0.0516, (0.1158, 0.3661, 0.3439), (0.3251, 0.45, 0.3583)),
    (0.2719, (0.1836, 0.1864, 0.0), (0.34, 0.1864, 0.0)),
    (2.0062, (0.46, 0.0, 0.0402), (0.46, 0.0, 0.0402)),
)
# Method notes, "Skin": F0 ~ 0.028; SKIN_SPECULAR's docstring: Beckmann roughness 0.35.
SKIN_F0, SKIN_ROUGHNESS = 0.028, 0.35

SIZE = 64
HALF = 8.0  # mm: the square image spans [-8, 8] mm in x and y
CAMERA = OrthographicCamera(half_height=HALF)
FULL_CARD = meshes.card(2 * HALF, 2 * HALF)  # fills the image
SMALL_CARD = meshes.card(9.0, 6.0)  # leaves background (or a prop) all round
RADIANCE = np.array([1.6, 1.2, 0.9])
SKIN_ALBEDO = np.array([0.62, 0.43, 0.35])
BACKGROUND = (-1.0, -1.0, -1.0)  # a value no lit surface renders


def light_at(theta_deg: float, radiance=RADIANCE, cast_shadows: bool = True) -> DirectionalLight:
    theta = np.radians(theta_deg)
    return DirectionalLight((0.0, -np.sin(theta), -np.cos(theta)), tuple(radiance), cast_shadows)


def kelemen(n, to_light, v, roughness: float, f0: float) -> float:
    """f_spec = P(H) F(H.L) / (2 (1 + L.V)); P = exp(-tan^2 a / m^2) / (pi m^2 cos^4 a); Schlick F (thesis eq. 3.15)."""
    n, l, v = (np.asarray(x, float) / np.linalg.norm(x) for x in (n, to_light, v))  # noqa: E741
    h = (l + v) / np.linalg.norm(l + v)
    cos_a = float(n @ h)
    tan2 = (1.0 - cos_a**2) / cos_a**2
    beckmann = np.exp(-tan2 / roughness**2) / (np.pi * roughness**2 * cos_a**4)
    fresnel = f0 + (1.0 - f0) * (1.0 - float(h @ l)) ** 5
    return beckmann * fresnel / (2.0 * (1.0 + float(l @ v)))


def bare_skin(theta_deg: float, lobe: bool, albedo=SKIN_ALBEDO) -> np.ndarray:
    """Closed form of bare skin on a card facing +z, seen from +z: E cos(theta) (a + pi f_spec)."""
    theta = np.radians(theta_deg)
    specular = kelemen((0, 0, 1), (0, np.sin(theta), np.cos(theta)), (0, 0, 1), SKIN_ROUGHNESS, SKIN_F0) if lobe else 0
    return RADIANCE * np.cos(theta) * (albedo + np.pi * specular)


def make_table(seed: int, channels: int = 3) -> LayerTable:
    """A smooth plausible film: R0 = 0 and T = 1 at X = 0, R0 rising and T falling with thickness."""
    rng = np.random.default_rng(seed)
    k, s = rng.uniform(5.0, 40.0, channels), rng.uniform(20.0, 80.0, channels)  # mm^-1
    x = np.array([0.0, 0.005, 0.012, 0.025, 0.05])[:, None]
    return LayerTable(x[:, 0], s * x / (1.0 + (k + s) * x), np.exp(-k * x) / (1.0 + s * x))


def skin(stack, lights, mesh=FULL_CARD, camera=CAMERA, size=(SIZE, SIZE), substrate_lobe=SKIN_SPECULAR, **kwargs):
    """The skin pass on ``stack``, with the skin's own lobe unless told otherwise."""
    scene = Scene(mesh=mesh, camera=camera, lights=lights, stack=stack, resolution=size, substrate_lobe=substrate_lobe,
                  background=BACKGROUND, **kwargs)  # fmt: skip
    return render_skin(scene)


# --- Table 3.1 -------------------------------------------------------------------------------------------------------


def test_the_profile_is_table_3_1():
    np.testing.assert_array_equal(SKIN_VARIANCES_MM2, [row[0] for row in TABLE_3_1])
    np.testing.assert_array_equal(SKIN_WEIGHTS, [row[1] for row in TABLE_3_1])
    assert SKIN_SPECULAR.f0 == pytest.approx(SKIN_F0, rel=1e-12)
    assert SKIN_SPECULAR.roughness == SKIN_ROUGHNESS


def test_blend_weights_reproduce_table_3_1_as_printed():
    """W'_i of all four rows to the printed digits. The finest printed digit is the 4th decimal, so the tolerance is
    one unit of it: thesis eq. 3.3 on the printed W_i gives 0.32501 and 0.35838 where the table prints 0.3251 and 0.3583
    (neither is the rounding of the other to 4 digits, so half a unit would be too strict for the table itself)."""
    printed = np.array([row[2] for row in TABLE_3_1])
    np.testing.assert_allclose(blend_weights(), printed, rtol=0.0, atol=1e-4)
    np.testing.assert_allclose(blend_weights([row[1] for row in TABLE_3_1]), printed, rtol=0.0, atol=1e-4)


@given(
    weights=arrays(np.float64, (4, 3), elements=st.just(0.0) | st.floats(1e-6, 1.0)),  # zeros as in Table 3.1
    blurs=arrays(np.float64, (4, 3), elements=st.floats(0.0, 10.0)),
)
def test_blending_with_eq_3_4_leaves_the_normalised_sum_of_gaussians(weights, blurs):
    """Color_out = Color_src W'_i + Color_dst (1 - W'_i) (thesis eq. 3.4), from a cleared target, gives sum W_i b_i /
    sum W."""
    assume(np.all(weights.sum(axis=0) > 0.0))
    accumulator = np.zeros(3)
    for blur, blend in zip(blurs, blend_weights(weights), strict=True):
        assert np.all((blend >= 0.0) & (blend <= 1.0))
        accumulator = blur * blend + accumulator * (1.0 - blend)
    expected = (weights * blurs).sum(axis=0) / weights.sum(axis=0)
    np.testing.assert_allclose(accumulator, expected, rtol=1e-9, atol=1e-12)


def test_bad_scattering_raises_value_error():
    for kwargs in ({"alpha": 0.0}, {"alpha": -1.0}, {"beta": -1.0}, {"gradient_clamp": -1e-3}):
        with pytest.raises(ValueError, match="scattering needs"):
            Scattering(**kwargs)


# --- Energy and the layer pass ---------------------------------------------------------------------------------------


def _lifted(z: float) -> np.ndarray:
    model = np.eye(4)
    model[2, 3] = z
    return model


def _tilted(angle_deg: float) -> np.ndarray:
    angle = np.radians(angle_deg)
    model = np.eye(4)
    model[1:3, 1:3] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    return model


@pytest.mark.parametrize("alpha", [1.0, 50.0])
@pytest.mark.parametrize("scene", ["orthographic card over a ground", "perspective tilted card"])
def test_a_uniformly_lit_card_is_unchanged_by_scattering(scene, alpha):
    """A normalised blur keeps a uniform image: everywhere on the card, edges included (taps off the skin take the
    centre's value, so neither the background nor a prop bleeds in or darkens the silhouette)."""
    film = make_table(1)
    stack = ChannelStack([film], [0.012], SKIN_ALBEDO)
    if scene.startswith("orthographic"):
        kwargs = {"mesh": SMALL_CARD, "props": [Prop(meshes.card(40.0, 40.0), (0.3, 0.5, 0.7), _lifted(-2.0))]}
        lights = [light_at(0.0)]
    else:
        camera = PerspectiveCamera(fov_y_deg=30.0, eye=(0.0, 0.0, 80.0), near=10.0, far=200.0)
        kwargs = {"mesh": meshes.card(24.0, 16.0), "camera": camera, "model": _tilted(40.0)}
        lights = [light_at(10.0)]
    lobes = {"lobes": [Specular(0.2, 1.45)]}
    plain = skin(stack, lights, scattering=None, **lobes, **kwargs)
    blurred = skin(stack, lights, scattering=Scattering(alpha=alpha), **lobes, **kwargs)
    on_card = plain[..., 0] != BACKGROUND[0]
    if "props" not in kwargs:
        # The card's silhouette is inside the image: some card pixels border the background.
        border = on_card & ~(np.roll(on_card, 1, 0) & np.roll(on_card, -1, 0) & np.roll(on_card, 1, 1))
        assert 0 < border.sum() < on_card.sum() < on_card.size
    np.testing.assert_allclose(blurred, plain, rtol=1e-5, atol=1e-6)


def _rgb_stack():
    thickness_map = np.linspace(0.0, 0.04, 5 * 7).reshape(5, 7)
    return ChannelStack([make_table(2), make_table(3)], [thickness_map, 0.008], SKIN_ALBEDO)


def _bands_stack():
    channels = 6
    to_rgb = np.random.default_rng(4).uniform(0.0, 0.35, (channels, 3))
    return ChannelStack([make_table(5, channels)], [0.017], np.linspace(0.25, 0.75, channels), to_rgb)


def _precomposed_stack():
    rng = np.random.default_rng(6)
    over_black = rng.uniform(0.05, 0.3, (4, 5, 3))
    reflectance = over_black + rng.uniform(0.1, 0.5, (4, 5, 3))
    return Precomposed(reflectance, over_black, rng.uniform(0.2, 1.0, (3, 4, 5, 3)))


@pytest.mark.parametrize(
    ("make_stack", "specular"),
    [(_rgb_stack, [Specular(0.3, 1.5), None]), (_bands_stack, [Specular(0.15, 1.4)]), (_precomposed_stack, [])],
    ids=["rgb", "bands", "precomposed"],
)
def test_without_scattering_the_skin_render_is_the_layer_pass(make_stack, specular):
    stack = make_stack()
    lights = [light_at(25.0), PointLight((3.0, 2.0, 40.0), (0.4, 0.5, 0.6), 40.0)]
    scene = Scene(
        mesh=meshes.card(12.0, 10.0), camera=CAMERA, lights=lights, stack=stack, resolution=(SIZE, SIZE),
        lobes=specular, substrate_lobe=SKIN_SPECULAR, scattering=None,
        props=[Prop(meshes.card(30.0, 30.0), (0.4, 0.4, 0.4), _lifted(-1.5))], background=BACKGROUND,
    )  # fmt: skip
    image = render_skin(scene)
    layers = render_layers(scene)
    assert np.ptp(layers[SIZE // 2]) > 1e-2  # the row crosses the card, the ground and the thickness map
    np.testing.assert_allclose(image, layers, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("scattering", [None, Scattering(alpha=3.0)], ids=["plain", "scattering"])
@pytest.mark.parametrize("lobe", [False, True], ids=["no lobe", "skin lobe"])
@pytest.mark.parametrize("theta_deg", [0.0, 35.0])
def test_without_makeup_skin_renders_as_its_albedo(theta_deg, lobe, scattering):
    image = skin(
        ChannelStack([], [], SKIN_ALBEDO), [light_at(theta_deg)], scattering=scattering,
        substrate_lobe=SKIN_SPECULAR if lobe else None,
    )  # fmt: skip
    np.testing.assert_allclose(image.reshape(-1, 3), np.tile(bare_skin(theta_deg, lobe), (SIZE * SIZE, 1)), rtol=1e-5)


@pytest.mark.parametrize("scattering", [None, Scattering(alpha=3.0)], ids=["plain", "scattering"])
def test_films_of_thickness_zero_change_nothing(scattering):
    films = [make_table(7), make_table(8)]
    assert films[0].r0[0].max() == 0.0 and films[0].t[0].min() == 1.0
    stack = ChannelStack(films, [0.0, np.zeros((3, 4))], SKIN_ALBEDO)
    image = skin(stack, [light_at(20.0)], scattering=scattering)  # with the default skin lobe, attenuated by T^2 = 1
    np.testing.assert_allclose(image.reshape(-1, 3), np.tile(bare_skin(20.0, True), (SIZE * SIZE, 1)), rtol=1e-5)


def test_an_opaque_film_hides_the_skin():
    """T = 0: no light reaches the skin and the skin's lobe is hidden; the film shows its own R0 whatever the skin."""
    r = np.array([0.45, 0.3, 0.2])
    opaque = LayerTable(0.02, r, np.zeros(3))
    theta = 30.0
    images = [
        skin(ChannelStack([opaque], [0.02], albedo), [light_at(theta)], scattering=Scattering(alpha=5.0))
        for albedo in (SKIN_ALBEDO, np.array([0.95, 0.9, 0.85]), np.zeros(3))
    ]
    expected = np.tile(r * RADIANCE * np.cos(np.radians(theta)), (SIZE * SIZE, 1))
    for image in images:
        np.testing.assert_allclose(image.reshape(-1, 3), expected, rtol=1e-5)


# --- The blur of a step ----------------------------------------------------------------------------------------------

STRIP = (128, 16)  # width, height in pixels
ALPHA = 8.0
LIT = SKIN_ALBEDO * RADIANCE  # bare skin, head-on
COVER_R0 = np.array([0.3, 0.25, 0.2])
# The film: R0 = T - 1 = 0 at X = 0, opaque (T = 0, R0 = COVER_R0) at 1 mm, linear between.
COVER = LayerTable(np.array([0.0, 1.0]), np.array([np.zeros(3), COVER_R0]), np.array([np.ones(3), np.zeros(3)]))


def total_reach_px(pixels_per_mm: float, alpha: float) -> float:
    """How far the chain of 7-tap blurs reaches: sum over the Gaussians of 3 sqrt(v_i - v_(i-1)) (mm) on screen."""
    variances = [row[0] for row in TABLE_3_1]
    return 3.0 * alpha * pixels_per_mm * float(np.sum(np.sqrt(np.diff(np.concatenate([[0.0], variances])))))


def step_render(camera, card, columns: int, alpha: float, cover_r0=COVER_R0, vertical: bool = False) -> np.ndarray:
    """The film over the left half of the card (a thickness map over uv: 1 mm on the left, 0 on the right), no lobes;
    returns the middle row's skin light divided by the bare skin's (0 under the film, 1 far from it), shape (n, 3).
    ``vertical``: the strip stands upright (``STRIP`` transposed), the film on its top half, and the middle column is
    returned from the top down."""
    cover = LayerTable(COVER.thickness_mm, np.array([np.zeros(3), cover_r0]), COVER.t)
    thickness = np.zeros((2, columns))
    thickness[:, : columns // 2] = 1.0
    size = STRIP[::-1] if vertical else STRIP
    stack = ChannelStack([cover], [thickness.T if vertical else thickness], SKIN_ALBEDO)
    scene = Scene(mesh=card, camera=camera, lights=[light_at(0.0)], stack=stack, resolution=size,
                  scattering=Scattering(alpha=alpha))  # fmt: skip
    image = render_skin(scene)
    line = (image[:, size[0] // 2] if vertical else image[size[1] // 2]).astype(float)
    covered = np.arange(len(line))[:, None] < len(line) // 2
    return (line - np.where(covered, cover_r0 * RADIANCE, 0.0)) / LIT


def orthographic_strip(pixels_per_mm: float, vertical: bool = False) -> tuple[OrthographicCamera, object]:
    """An orthographic camera and a card exactly filling the strip image at ``pixels_per_mm``."""
    width, height = (n / pixels_per_mm for n in (STRIP[::-1] if vertical else STRIP))
    return OrthographicCamera(half_height=height / 2), meshes.card(width, height)


def crossing(profile: np.ndarray, level: float) -> float:
    """Where a rising profile first reaches ``level`` (pixels, linear between pixel centres)."""
    i = int(np.nonzero(profile >= level)[0][0])
    return i - 1 + (level - profile[i - 1]) / (profile[i] - profile[i - 1])


def width_10_90(profile: np.ndarray) -> float:
    return crossing(profile, 0.9) - crossing(profile, 0.1)


def mixture_width_10_90_mm(channel: int) -> float:
    """10-90 % width (mm) of a step blurred by the continuous sum of Gaussians of Table 3.1 (normalised W_i)."""
    variances = np.array([row[0] for row in TABLE_3_1])
    weights = np.array([row[1][channel] for row in TABLE_3_1])
    weights = weights / weights.sum()

    def cdf(x: float) -> float:
        return float(np.sum(weights * 0.5 * (1.0 + special.erf(x / np.sqrt(2.0 * variances)))))

    return optimize.brentq(lambda x: cdf(x) - 0.9, -10, 10) - optimize.brentq(lambda x: cdf(x) - 0.1, -10, 10)


@pytest.mark.parametrize("vertical", [False, True], ids=["across", "along"])
def test_scattering_blurs_a_step_smoothly_red_widest_and_conserves_the_light(vertical):
    pixels_per_mm = 1.0
    camera, card = orthographic_strip(pixels_per_mm, vertical)
    light = step_render(camera, card, STRIP[0], ALPHA, vertical=vertical)  # (width, 3), lit side = 1
    width, step = STRIP[0], STRIP[0] // 2  # pixels < step are covered
    reach = total_reach_px(pixels_per_mm, ALPHA)
    assert 40.0 < reach < step - 8.0  # the blur reaches far, yet the image's ends stay beyond it
    columns = np.arange(width)
    far = np.abs(columns + 0.5 - step) > reach + 1.0
    # (a) Beyond the blur's reach both sides keep their unblurred values (0 under the film, the bare skin's beside).
    np.testing.assert_allclose(light[far & (columns < step)], 0.0, atol=1e-6)
    np.testing.assert_allclose(light[far & (columns >= step)], 1.0, rtol=1e-5)
    # ... and near the step the light really moved across it.
    assert np.all(light[step - 1] > 0.2) and np.all(light[step] < 0.8)
    # (b) Smooth: rising monotonically from the covered side to the lit, over several pixels, in no big jump.
    assert np.all(np.diff(light, axis=0) > -1e-6)
    assert np.all(np.abs(np.diff(light, axis=0)).max(axis=0) < 0.5)  # unblurred: one jump of 1
    assert np.all(((light > 0.05) & (light < 0.95)).sum(axis=0) >= 4)
    # (c) Red has the widest Gaussians (W_4 = 0.46 at 2.0062 mm^2): it spreads furthest.
    widths = [width_10_90(light[:, channel]) for channel in range(3)]
    assert widths[0] > 2.0 * widths[1] and widths[0] > 2.0 * widths[2], widths
    # (d) Conservation: what leaks under the film is what the lit side lost. A symmetric normalised blur of a step
    # mirrors it (light(step + k) + light(step - 1 - k) = 1) and so keeps the row's total skin light.
    np.testing.assert_allclose(light.sum(axis=0), width - step, rtol=1e-3)
    np.testing.assert_allclose(light[step:] + light[step - 1 :: -1], 1.0, atol=1e-4)


def test_the_covered_sides_own_reflectance_is_not_blurred():
    """The film's R0 is added after the blur: the step's skin light is the same whatever the film reflects."""
    camera, card = orthographic_strip(1.0)
    dark = step_render(camera, card, STRIP[0], ALPHA, cover_r0=np.zeros(3))
    bright = step_render(camera, card, STRIP[0], ALPHA, cover_r0=np.array([0.8, 0.7, 0.9]))
    np.testing.assert_allclose(bright, dark, atol=1e-5)


def test_the_blur_follows_the_pixels_per_mm():
    """The blur's footprint in pixels is its size in mm times the pixels per mm on the skin: an orthographic camera's
    pixels per mm, or a perspective camera's focal length over the distance (twice as far: half the footprint). In mm,
    alpha = 1 is the true size of Table 3.1's profile: the red 10-90 % width of the continuous sum of Gaussians."""
    red_mm = mixture_width_10_90_mm(0)
    orthographic = {}
    for pixels_per_mm in (1.0, 0.5):
        camera, card = orthographic_strip(pixels_per_mm)
        orthographic[pixels_per_mm] = width_10_90(step_render(camera, card, STRIP[0], ALPHA)[:, 0])
        # The 7 taps sample each Gaussian at whole deviations (variance 1.08 sigma^2), hence the 10 % tolerance.
        assert orthographic[pixels_per_mm] == pytest.approx(red_mm * ALPHA * pixels_per_mm, rel=0.1)
    assert orthographic[0.5] / orthographic[1.0] == pytest.approx(0.5, abs=0.05)
    # Perspective: focal length 100 px, so 1 px per mm at 100 mm and 0.5 at 200 mm. The card fills both views; its
    # thickness map has many columns so that the film's edge stays sharp in pixels.
    fov_y = 2.0 * np.degrees(np.arctan(0.5 * STRIP[1] / 100.0))
    perspective = {
        distance: width_10_90(
            step_render(PerspectiveCamera(fov_y_deg=fov_y, eye=(0.0, 0.0, distance)), meshes.card(600.0, 120.0), 2048,
                        ALPHA)[:, 0]
        )
        for distance in (100.0, 200.0)
    }  # fmt: skip
    assert perspective[200.0] / perspective[100.0] == pytest.approx(0.5, abs=0.05)
    assert perspective[100.0] == pytest.approx(orthographic[1.0], rel=0.05)


def test_the_skin_region_is_the_projected_sphere_grown_by_two_pixels():
    """A sphere of radius 6 mm at (3, -2, 0) seen head-on by an orthographic camera 20 mm tall on 64 px: its
    silhouette spans (3 +- 6, -2 +- 6) mm, so the box is those spans in pixels, 3.2 px a mm from the frame's centre,
    grown by 2 and clipped to the frame."""
    from renderer.skin import skin_region

    camera = OrthographicCamera(half_height=10.0)
    view_projection = camera.projection_matrix(1.0) @ camera.view_matrix()
    model = np.eye(4)
    model[:3, 3] = (3.0, -2.0, 0.0)
    region = skin_region(meshes.sphere(6.0).vertices, model, view_projection, 64, 64)
    expected = (np.floor(32 + 3.2 * -3.0) - 2, np.floor(32 + 3.2 * -8.0) - 2, np.ceil(32 + 3.2 * 9.0) + 2,
                np.ceil(32 + 3.2 * 4.0) + 2)  # fmt: skip
    assert region == tuple(int(v) for v in expected)
    assert skin_region(meshes.sphere(60.0).vertices, np.eye(4), view_projection, 64, 64) == (0, 0, 64, 64)
    behind = PerspectiveCamera(fov_y_deg=40.0, eye=(0.0, 0.0, 3.0))  # the camera inside the sphere
    perspective = behind.projection_matrix(1.0) @ behind.view_matrix()
    assert skin_region(meshes.sphere(6.0).vertices, np.eye(4), perspective, 64, 64) is None


def test_blurring_only_the_skin_region_leaves_the_frame_unchanged(monkeypatch):
    """Skin on a sphere that covers part of the frame, before a lit card: the blur limited to the sphere's box equals
    the blur over the whole frame, bit for bit."""
    import renderer.skin

    back = meshes.card(40.0, 40.0)
    back.apply_translation((0.0, 0.0, -20.0))
    scene = Scene(
        mesh=meshes.sphere(5.0),
        camera=OrthographicCamera(half_height=10.0),
        lights=[DirectionalLight(direction=(-0.3, -0.5, -1.0), radiance=(1.0, 1.0, 1.0))],
        stack=ChannelStack([], [], (0.75, 0.5, 0.4)),
        resolution=(64, 64),
        scattering=Scattering(alpha=1.0),  # the widest Gaussian reaches about 13 px, within the 32 px sphere
        props=[Prop(back, (0.5, 0.5, 0.5))],
    )
    boxed = render_skin(scene)
    monkeypatch.setattr(renderer.skin, "skin_region", lambda *args: None)
    whole = render_skin(scene)
    assert np.array_equal(boxed, whole)
    assert not np.array_equal(whole, render_skin(dataclasses.replace(scene, scattering=None)))  # the blur did blur
