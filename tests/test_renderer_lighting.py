"""Lights, specular lobes, shadows and precomposed stacks in the layer pass, against references written here.

An orthographic camera looks down -z at cards in z = const planes, so the view vector is +z everywhere and every
pixel's world position follows from its row and column. References: the Kelemen / Szirmay-Kalos lobe with a
normalised Beckmann distribution and Schlick's Fresnel (thesis eq. 3.15), written out below; the inverse-square law;
shadow geometry by similar triangles.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import integrate

from renderer import meshes
from renderer.layers import render_layers
from renderer.scene import DirectionalLight, OrthographicCamera, PointLight, Prop, Scene
from renderer.stack import ChannelStack, LayerTable, Precomposed, Specular

SIZE = 64
HALF = 10.0  # mm: the image spans [-10, 10] mm in x and y
CAMERA = OrthographicCamera(half_height=HALF, eye=(0.0, 0.0, 100.0), near=1.0, far=300.0)
CARD = meshes.card(2 * HALF, 2 * HALF)  # fills the image
BACKGROUND = (-1.0, -1.0, -1.0)


def pixel_xy() -> tuple[np.ndarray, np.ndarray]:
    """World x, y (mm) of every pixel centre, row 0 at the top."""
    centres = -HALF + (np.arange(SIZE) + 0.5) * (2 * HALF / SIZE)
    return np.meshgrid(centres, centres[::-1])


def kelemen(n, to_light, v, roughness: float, f0: float) -> float:
    """f_spec = P(H) F(H.L) / (2 (1 + L.V)); P = exp(-tan^2 a / m^2) / (pi m^2 cos^4 a); Schlick F."""
    n, l, v = (np.asarray(x, float) / np.linalg.norm(x) for x in (n, to_light, v))  # noqa: E741
    h = (l + v) / np.linalg.norm(l + v)
    cos_a = float(n @ h)
    tan2 = (1.0 - cos_a**2) / cos_a**2
    beckmann = np.exp(-tan2 / roughness**2) / (np.pi * roughness**2 * cos_a**4)
    fresnel = f0 + (1.0 - f0) * (1.0 - float(h @ l)) ** 5
    return beckmann * fresnel / (2.0 * (1.0 + float(l @ v)))


def plain_table(r0, t) -> LayerTable:
    return LayerTable(0.01, np.asarray(r0, float), np.asarray(t, float))


def render(stack, lights, **kwargs):
    scene = Scene(mesh=CARD, camera=CAMERA, lights=lights, stack=stack, resolution=(SIZE, SIZE), background=BACKGROUND)
    return render_layers(dataclasses.replace(scene, **kwargs))


@pytest.mark.parametrize("theta_deg", [0.0, 20.0, 50.0])
@pytest.mark.parametrize(("roughness", "ior"), [(0.3, 1.5), (0.12, 1.4), (0.6, 2.0)])
def test_a_single_lobe_matches_kelemen_with_beckmann_and_schlick(theta_deg, roughness, ior):
    theta = np.radians(theta_deg)
    to_light = np.array([0.0, np.sin(theta), np.cos(theta)])
    radiance = np.array([1.5, 1.0, 0.5])
    table = plain_table([0.2, 0.3, 0.4], [0.5, 0.4, 0.3])
    substrate = np.array([0.5, 0.5, 0.5])
    stack = ChannelStack([table], [0.01], substrate)
    image = render(stack, [DirectionalLight(tuple(-to_light), tuple(radiance))], lobes=[Specular(roughness, ior)])
    r = table.r0 + table.t**2 * substrate / (1.0 - table.r0 * substrate)
    f0 = ((ior - 1.0) / (ior + 1.0)) ** 2
    lobe = kelemen((0, 0, 1), to_light, (0, 0, 1), roughness, f0)
    expected = radiance * np.cos(theta) * (r + np.pi * lobe)
    np.testing.assert_allclose(image[SIZE // 2, SIZE // 2], expected, rtol=1e-4)


def test_a_lower_lobe_is_attenuated_by_the_films_above_it():
    top = plain_table([0.1, 0.2, 0.3], [0.8, 0.6, 0.4])
    bottom = plain_table([0.3, 0.3, 0.3], [0.5, 0.5, 0.5])
    substrate = np.array([0.4, 0.4, 0.4])
    stack = ChannelStack([top, bottom], [0.01, 0.01], substrate)
    light = DirectionalLight((0.0, 0.0, -1.0), (1.0, 1.0, 1.0))
    lobe = Specular(0.25, 1.5)
    with_lobe = render(stack, [light], lobes=[None, lobe])
    without = render(stack, [light])
    specular = with_lobe[SIZE // 2, SIZE // 2] - without[SIZE // 2, SIZE // 2]
    expected = np.pi * kelemen((0, 0, 1), (0, 0, 1), (0, 0, 1), 0.25, 0.04) * top.t**2
    np.testing.assert_allclose(specular, expected, rtol=1e-4)


def test_the_lobe_reflects_at_most_its_fresnel_fraction():
    """Directional albedo of the normalised lobe, integral of f cos(theta_v) over the hemisphere, stays <= F(0)."""
    for roughness in (0.1, 0.3, 0.6):
        for theta_l in np.radians([0.0, 30.0, 60.0]):
            light = (np.sin(theta_l), 0.0, np.cos(theta_l))

            def integrand(phi, theta_v, light=light, roughness=roughness):
                view = (np.sin(theta_v) * np.cos(phi), np.sin(theta_v) * np.sin(phi), np.cos(theta_v))
                return kelemen((0, 0, 1), light, view, roughness, 0.04) * np.cos(theta_v) * np.sin(theta_v)

            albedo, _ = integrate.dblquad(integrand, 0.0, np.pi / 2, 0.0, 2 * np.pi, epsabs=1e-6)
            fresnel_max = 0.04 + 0.96 * (1.0 - np.cos(theta_l)) ** 5
            assert 0.0 < albedo <= max(fresnel_max, 0.04) * 1.05


def test_two_lights_add():
    stack = ChannelStack([plain_table([0.2, 0.3, 0.4], [0.5, 0.4, 0.3])], [0.01], np.full(3, 0.6))
    a = DirectionalLight((0.0, -0.5, -1.0), (1.0, 0.5, 0.2))
    b = DirectionalLight((0.3, 0.2, -1.0), (0.1, 0.4, 0.9))
    both = render(stack, [a, b])
    np.testing.assert_allclose(both, render(stack, [a]) + render(stack, [b]), rtol=1e-5, atol=1e-6)


def test_a_point_light_falls_off_with_the_inverse_square_and_cosine():
    height, reference = 30.0, 25.0
    radiance = np.array([2.0, 1.0, 0.5])
    light = PointLight((0.0, 0.0, height), tuple(radiance), reference)
    substrate = np.array([0.3, 0.5, 0.7])
    image = render(ChannelStack([], [], substrate), [light])
    x, y = pixel_xy()
    distance = np.sqrt(x**2 + y**2 + height**2)
    expected = substrate * radiance * (reference / distance[..., None]) ** 2 * (height / distance[..., None])
    np.testing.assert_allclose(image, expected, rtol=1e-4)


def test_a_card_over_a_ground_casts_its_shadow_where_similar_triangles_put_it():
    """A 6 x 6 mm card 8 mm above the ground, light from 45 degrees in x: the shadow is the card moved 8 mm in -x."""
    lift, side = 8.0, 6.0
    model = np.eye(4)
    model[2, 3] = lift
    ground = Prop(meshes.card(4 * HALF, 4 * HALF), (0.5, 0.5, 0.5))
    to_light = np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0)
    light = DirectionalLight(tuple(-to_light), (1.0, 1.0, 1.0))
    stack = ChannelStack([], [], np.full(3, 0.8))
    card = {"mesh": meshes.card(side, side), "camera": CAMERA, "stack": stack, "resolution": (SIZE, SIZE)}
    image = render_layers(Scene(lights=[light], model=model, props=[ground], shadow_map_size=2048, **card))
    x, y = pixel_xy()
    on_card = (np.abs(x) < side / 2 - 0.5) & (np.abs(y) < side / 2 - 0.5)
    shadow = (np.abs(x + lift) < side / 2 - 0.5) & (np.abs(y) < side / 2 - 0.5)
    lit_ground = ~on_card & ~shadow & ((np.abs(x + lift) > side / 2 + 0.8) | (np.abs(y) > side / 2 + 0.8))
    lit_ground &= (np.abs(x) > side / 2 + 0.5) | (np.abs(y) > side / 2 + 0.5)
    cos45 = 1.0 / np.sqrt(2.0)
    np.testing.assert_allclose(image[on_card], 0.8 * cos45, rtol=1e-4)
    np.testing.assert_allclose(image[shadow], 0.0, atol=1e-6)
    np.testing.assert_allclose(image[lit_ground], 0.5 * cos45, rtol=1e-4)
    # Without shadows the same ground is lit everywhere.
    unshadowed = DirectionalLight(tuple(-to_light), (1.0, 1.0, 1.0), cast_shadows=False)
    open_image = render_layers(Scene(lights=[unshadowed], model=model, props=[ground], **card))
    np.testing.assert_allclose(open_image[shadow], 0.5 * cos45, rtol=1e-4)


def test_precomposed_maps_are_read_over_uv_with_row_zero_at_the_top():
    reflectance = np.zeros((2, 2, 3))
    reflectance[0] = (0.9, 0.1, 0.1)  # top half
    reflectance[1] = (0.1, 0.1, 0.9)  # bottom half
    attenuation = np.ones((2, 2, 2, 3))
    light = DirectionalLight((0.0, 0.0, -1.0), (1.0, 1.0, 1.0))
    image = render(Precomposed(reflectance, np.zeros_like(reflectance), attenuation), [light])
    # Bilinear between the two texel centres (v = 0.25 and 0.75); beyond them the edge value.
    np.testing.assert_allclose(image[2, SIZE // 2], (0.9, 0.1, 0.1), rtol=1e-5)
    np.testing.assert_allclose(image[SIZE - 3, SIZE // 2], (0.1, 0.1, 0.9), rtol=1e-5)
    uniform = render(Precomposed(np.array([0.3, 0.4, 0.5]), np.zeros(3), np.ones((3, 3))), [light])
    np.testing.assert_allclose(uniform, np.broadcast_to([0.3, 0.4, 0.5], uniform.shape), rtol=1e-6)


def test_bad_lights_and_lobes_raise_value_error():
    stack = ChannelStack([], [], np.full(3, 0.5))
    light = DirectionalLight((0.0, 0.0, -1.0), (1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="lights"):
        render(stack, [])
    with pytest.raises(ValueError, match="lights"):
        render(stack, [light] * 5)
    with pytest.raises(ValueError, match="specular"):
        render(ChannelStack([plain_table([0.1] * 3, [0.5] * 3)], [0.01], np.full(3, 0.5)), [light], lobes=[None] * 2)
    with pytest.raises(ValueError, match="roughness"):
        Specular(0.0)
    with pytest.raises(ValueError, match="reference distance"):
        PointLight((0.0, 0.0, 1.0), (1.0, 1.0, 1.0), 0.0)
    with pytest.raises(ValueError, match="precomposed"):
        render(Precomposed(np.ones((2, 2, 3)), np.ones((2, 2, 3)), np.ones((2, 3, 3, 3))), [light])
