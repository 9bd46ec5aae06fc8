"""A scene's white (renderer/scene_white.py): the luminance of a white card in the scene's light, against closed forms.

References: a card facing one light renders as that light's radiance; two lights at angle a apart, of luminances
Y1 and Y2, light a card at most sqrt(Y1^2 + Y2^2 + 2 Y1 Y2 cos a) (the length of the sum of the two vectors towards
them, each scaled by its luminance; for a < 90 degrees, where the best card sees both); a point light falls off with
the inverse square of the distance; a uniform environment of radiance L lights every card as L (the white furnace);
the sky L = c max(w.y, 0) lights a card facing up as 2c/3.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from renderer import meshes
from renderer.environment import Environment
from renderer.scene import DirectionalLight, OrthographicCamera, PointLight, Scene
from renderer.scene_white import scene_white
from renderer.stack import ChannelStack

Y = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 luminance
TARGET = (3.0, -2.0, 5.0)
CAMERA = OrthographicCamera(half_height=10.0, eye=(3.0, -2.0, 105.0), target=TARGET)


def scene(lights=(), environment=None) -> Scene:
    return Scene(mesh=meshes.sphere(5.0), stack=ChannelStack((), (), (1.0, 1.0, 1.0)), camera=CAMERA,
                 lights=list(lights), resolution=(8, 8), environment=environment)  # fmt: skip


directions = st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda v: np.linalg.norm(v) > 0.1)
radiances = st.tuples(*[st.floats(0.0, 50.0)] * 3).filter(lambda v: sum(v) > 1e-3)


@given(directions, radiances)
def test_one_light_gives_its_own_luminance(direction, radiance):
    assert scene_white(scene([DirectionalLight(direction, radiance)])) == pytest.approx(float(Y @ radiance), rel=1e-12)


@given(st.floats(0.0, 85.0), st.floats(0.05, 5.0), st.floats(0.05, 5.0))
def test_two_lights_give_the_length_of_their_summed_directions(angle_deg, first, second):
    a = np.radians(angle_deg)
    lights = [DirectionalLight((0.0, -1.0, 0.0), (first,) * 3),
              DirectionalLight((-np.sin(a), -np.cos(a), 0.0), (second,) * 3)]  # fmt: skip
    expected = np.sqrt(first**2 + second**2 + 2.0 * first * second * np.cos(a))
    assert scene_white(scene(lights)) == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize("distance", [50.0, 100.0, 400.0])
def test_a_point_light_falls_off_with_the_square_of_its_distance_from_the_target(distance):
    position = tuple(np.add(TARGET, np.array([2.0, 6.0, 3.0]) / 7.0 * distance))
    light = PointLight(position, (0.6, 0.9, 0.3), reference_distance_mm=100.0)
    assert scene_white(scene([light])) == pytest.approx(float(Y @ (0.6, 0.9, 0.3)) * (100.0 / distance) ** 2)


@pytest.mark.parametrize("intensity", [0.25, 1.0, 3.0])
def test_a_uniform_environment_lights_every_card_as_its_radiance(intensity):
    radiance = (0.7, 0.5, 0.2)
    environment = Environment(np.tile(np.array(radiance, np.float32), (16, 32, 1)), rotation_deg=40.0,
                              intensity=intensity)  # fmt: skip
    assert scene_white(scene(environment=environment)) == pytest.approx(float(Y @ radiance) * intensity, rel=1e-5)


def sky(c: float, cols: int = 128) -> np.ndarray:
    """L = c max(w.y, 0) on the equirectangular grid of renderer/environment.py (row 0 the zenith)."""
    theta = (np.arange(cols // 2) + 0.5) / (cols // 2) * np.pi
    return np.repeat(np.repeat(c * np.maximum(np.cos(theta), 0.0)[:, None], cols, axis=1)[..., None], 3, axis=2)


def test_a_cosine_sky_and_a_sun_at_the_zenith_add_up_on_a_card_facing_up():
    environment = Environment(sky(0.9).astype(np.float32))
    assert scene_white(scene(environment=environment)) == pytest.approx(2.0 * 0.9 / 3.0, rel=0.01)
    sun = DirectionalLight((0.0, -1.0, 0.0), (1.5, 1.5, 1.5))
    assert scene_white(scene([sun], environment)) == pytest.approx(1.5 + 2.0 * 0.9 / 3.0, rel=0.005)


def test_a_scene_without_light_keeps_a_positive_white():
    dark = DirectionalLight((0.0, 0.0, -1.0), (0.0, 0.0, 0.0))
    assert scene_white(scene([dark])) == 1e-6
    at_the_target = PointLight(TARGET, (1.0, 1.0, 1.0), reference_distance_mm=10.0)
    assert scene_white(scene([at_the_target], Environment(np.zeros((16, 32, 3), np.float32)))) == 1e-6
