"""The Kubelka-Munk layer pass (renderer.layers) against numpy references written here, independently of the shader.

A 20 x 10 mm card faces the camera and the light head-on in a 64 x 64 orthographic image, so every card pixel
renders as ``(R @ to_rgb) * E`` with ``R`` the stack's reflectance: each film's ``R0`` and ``T`` interpolated
linearly at its thickness (mm), then composed bottom-up onto the substrate, ``Rg <- R0 + T^2 Rg / (1 - R0 Rg)``
(thesis eq. 3.14).
"""

from __future__ import annotations

import numpy as np
import pytest

from renderer import meshes
from renderer.layers import render_layers
from renderer.scene import DirectionalLight, OrthographicCamera, Scene
from renderer.stack import MAX_LAYERS, ChannelStack, LayerTable

SIZE = 64
RADIANCE = np.array([2.0, 3.0, 0.5])
BACKGROUND = (-1.0, -1.0, -1.0)  # a value no lit surface can produce
HEAD_ON = DirectionalLight(direction=(0.0, 0.0, -1.0), radiance=tuple(RADIANCE))
CAMERA = OrthographicCamera(half_height=10.0)
CARD = meshes.card(20.0, 10.0)  # spans all 64 columns and rows 16 .. 47; uv (0, 0) at the bottom-left
THICKNESS_MM = np.array([0.0, 0.005, 0.012, 0.025, 0.05])  # unevenly spaced samples


def make_table(seed: int, channels: int = 3) -> LayerTable:
    """A smooth, physically plausible table (R0 + T <= 1, R0 rising and T falling with thickness)."""
    rng = np.random.default_rng(seed)
    k = rng.uniform(5.0, 40.0, channels)  # mm^-1
    s = rng.uniform(20.0, 80.0, channels)  # mm^-1
    x = THICKNESS_MM[:, None]
    r0 = s * x / (1.0 + (k + s) * x)
    t = np.exp(-k * x) / (1.0 + s * x)
    return LayerTable(THICKNESS_MM, r0, t)


def reference(tables, thicknesses_mm, substrate, to_rgb=None) -> np.ndarray:
    """Reference RGB reflectance of a stack (tables top first) at uniform thicknesses: np.interp, then the
    recurrence from the substrate up."""
    ground = np.asarray(substrate, dtype=float)
    for table, x in reversed(list(zip(tables, thicknesses_mm, strict=True))):
        xs = np.atleast_1d(table.thickness_mm)
        r0_table, t_table = np.atleast_2d(table.r0), np.atleast_2d(table.t)
        r0 = np.array([np.interp(x, xs, r0_table[:, c]) for c in range(ground.size)])
        t = np.array([np.interp(x, xs, t_table[:, c]) for c in range(ground.size)])
        ground = r0 + t**2 * ground / (1.0 - r0 * ground)
    return ground if to_rgb is None else ground @ to_rgb


def card_mask() -> np.ndarray:
    """Pixels covered by the card: rows whose centre lies within |y| < 5 mm."""
    y = 10.0 - (np.arange(SIZE) + 0.5) * (20.0 / SIZE)
    return np.broadcast_to((np.abs(y) < 5.0)[:, None], (SIZE, SIZE))


def card_scene(stack, light=HEAD_ON) -> Scene:
    return Scene(mesh=CARD, camera=CAMERA, lights=[light], stack=stack, resolution=(SIZE, SIZE), background=BACKGROUND)


def render(tables, thicknesses, substrate, to_rgb=None, light=HEAD_ON) -> np.ndarray:
    return render_layers(card_scene(ChannelStack(tables, thicknesses, substrate, to_rgb), light))


def assert_card_equals(image: np.ndarray, rgb: np.ndarray, mask: np.ndarray | None = None) -> None:
    inside = card_mask()
    region = inside if mask is None else inside & mask
    assert region.sum() > 0
    np.testing.assert_allclose(image[region], np.broadcast_to(rgb, (region.sum(), 3)), rtol=1e-5)
    np.testing.assert_array_equal(image[~inside], np.float32(-1.0))


def test_one_layer_between_samples_equals_interpolated_composite():
    table = make_table(1)
    substrate = np.array([0.6, 0.45, 0.3])
    x = 0.0185  # between the samples 0.012 and 0.025 mm
    image = render([table], [x], substrate)
    assert image.shape == (SIZE, SIZE, 3)
    assert image.dtype == np.float32
    r0 = np.array([np.interp(x, THICKNESS_MM, table.r0[:, c]) for c in range(3)])
    t = np.array([np.interp(x, THICKNESS_MM, table.t[:, c]) for c in range(3)])
    assert_card_equals(image, (r0 + t**2 * substrate / (1.0 - r0 * substrate)) * RADIANCE)


@pytest.mark.parametrize("x", [0.0, 0.005, 0.05, -0.01, 0.2])
def test_thickness_at_samples_and_beyond_the_ends_clamps(x):
    table = make_table(2)
    substrate = np.array([0.2, 0.5, 0.7])
    clamped = np.clip(x, THICKNESS_MM[0], THICKNESS_MM[-1])
    assert_card_equals(render([table], [x], substrate), reference([table], [clamped], substrate) * RADIANCE)


@pytest.mark.parametrize("count", [2, 3, MAX_LAYERS])
def test_stacks_equal_the_bottom_up_recurrence(count):
    tables = [make_table(10 + i) for i in range(count)]
    thicknesses = [0.003, 0.021, 0.04, 0.0075][:count]
    substrate = np.array([0.7, 0.5, 0.35])
    expected = reference(tables, thicknesses, substrate) * RADIANCE
    assert_card_equals(render(tables, thicknesses, substrate), expected)


def test_layer_order_is_top_first():
    tables = [make_table(20), make_table(21)]
    substrate = np.array([0.7, 0.5, 0.35])
    forward = render(tables, [0.01, 0.03], substrate)
    swapped = render(tables[::-1], [0.03, 0.01], substrate)
    assert_card_equals(forward, reference(tables, [0.01, 0.03], substrate) * RADIANCE)
    assert np.abs(forward[card_mask()] - swapped[card_mask()]).max() > 1e-3


def test_a_single_thickness_table_needs_no_thickness_axis():
    table = LayerTable(0.02, np.array([0.3, 0.2, 0.1]), np.array([0.5, 0.6, 0.7]))
    substrate = np.array([0.4, 0.4, 0.4])
    expected = (table.r0 + table.t**2 * substrate / (1.0 - table.r0 * substrate)) * RADIANCE
    for x in (0.0, 0.02, 1.0):  # one sample: every thickness takes its value
        assert_card_equals(render([table], [x], substrate), expected)


def test_thickness_zero_shows_the_substrate_unchanged():
    table = make_table(3)  # R0 = 0 and T = 1 at X = 0
    assert table.r0[0].max() == 0.0 and table.t[0].min() == 1.0
    substrate = np.array([0.61, 0.37, 0.12])
    assert_card_equals(render([table, table], [0.0, 0.0], substrate), substrate * RADIANCE)
    assert_card_equals(render([], [], substrate), substrate * RADIANCE)


@pytest.mark.parametrize("substrate", [0.0, 0.5, 1.0])
def test_a_thick_white_non_absorbing_layer_approaches_but_never_exceeds_e(substrate):
    s = 100.0  # mm^-1, K = 0: R0 = S X / (1 + S X), T = 1 / (1 + S X)
    x = np.array([0.0, 0.1, 1.0, 10.0, 100.0])
    white = LayerTable(
        x, np.repeat((s * x / (1.0 + s * x))[:, None], 3, 1), np.repeat((1.0 / (1.0 + s * x))[:, None], 3, 1)
    )
    for thickness in (0.05, 5.0, 100.0, 1000.0):
        image = render([white], [thickness], np.full(3, substrate))[card_mask()]
        assert np.all(image <= RADIANCE * (1.0 + 1e-6))
    assert np.all(image >= RADIANCE * 0.999)


def test_thickness_map_left_thin_right_thick():
    table = make_table(4)
    substrate = np.array([0.55, 0.35, 0.25])
    thin, thick = 0.004, 0.037
    thickness_map = np.full((8, SIZE), thin)
    thickness_map[:, SIZE // 2 :] = thick  # column 0 at u = 0: the left edge of the card
    image = render([table], [thickness_map], substrate)
    columns = np.arange(SIZE)[None, :]
    away_from_edge = np.broadcast_to(np.abs(columns + 0.5 - SIZE / 2) > 2.0, (SIZE, SIZE))
    left = away_from_edge & (columns < SIZE // 2)
    right = away_from_edge & (columns >= SIZE // 2)
    assert_card_equals(image, reference([table], [thin], substrate) * RADIANCE, left)
    assert_card_equals(image, reference([table], [thick], substrate) * RADIANCE, right)
    assert np.abs(image[32, 5] - image[32, 60]).max() > 1e-2


def test_thickness_map_row_zero_is_the_top():
    table = make_table(5)
    substrate = np.array([0.5, 0.5, 0.5])
    thickness_map = np.full((32, 4), 0.045)
    thickness_map[:16] = 0.002  # the top half of the map (rows 0 .. 15) at v > 0.5
    uniform_layer = make_table(6)
    image = render([table, uniform_layer], [thickness_map, 0.01], substrate)  # the map on the top layer
    rows = np.arange(SIZE)[:, None]
    top = np.broadcast_to(rows < 30, (SIZE, SIZE))  # the card spans rows 16 .. 47, its middle at 32
    bottom = np.broadcast_to(rows >= 34, (SIZE, SIZE))
    assert_card_equals(image, reference([table, uniform_layer], [0.002, 0.01], substrate) * RADIANCE, top)
    assert_card_equals(image, reference([table, uniform_layer], [0.045, 0.01], substrate) * RADIANCE, bottom)


def test_bands_mode_composes_per_band_then_converts_to_rgb():
    channels = 6
    tables = [make_table(30, channels), make_table(31, channels)]
    substrate = np.linspace(0.2, 0.8, channels)
    to_rgb = np.random.default_rng(7).uniform(0.0, 0.4, (channels, 3))
    thicknesses = [0.009, 0.03]
    expected = reference(tables, thicknesses, substrate, to_rgb) * RADIANCE
    assert_card_equals(render(tables, thicknesses, substrate, to_rgb=to_rgb), expected)


@pytest.mark.parametrize("theta_deg", [30.0, 75.0])
def test_tilting_the_light_scales_by_cos_theta(theta_deg):
    theta = np.radians(theta_deg)
    light = DirectionalLight(direction=(0.0, -np.sin(theta), -np.cos(theta)), radiance=tuple(RADIANCE))
    table = make_table(8)
    substrate = np.array([0.3, 0.6, 0.9])
    image = render([table], [0.02], substrate, light=light)
    expected = reference([table], [0.02], substrate) * RADIANCE * np.cos(theta)
    assert_card_equals(image, expected)


def test_bad_input_raises_value_error():
    table = make_table(9)
    with pytest.raises(ValueError, match="one thickness per layer"):
        render([table], [], [0.5, 0.5, 0.5])
    with pytest.raises(ValueError, match="to_rgb"):
        render([make_table(9, 6)], [0.01], np.full(6, 0.5))
    with pytest.raises(ValueError, match="channels"):
        render([make_table(9, 6)], [0.01], np.full(3, 0.5))
    with pytest.raises(ValueError, match="at most"):
        render([table] * (MAX_LAYERS + 1), [0.01] * (MAX_LAYERS + 1), [0.5, 0.5, 0.5])
    with pytest.raises(ValueError, match="increasing"):
        render([LayerTable(THICKNESS_MM[::-1], table.r0, table.t)], [0.01], [0.5, 0.5, 0.5])


def test_every_layer_reads_its_own_thickness_map():
    """Three layers, each with a map of its own (left/right, top/bottom, uniform-valued): each quadrant composes the
    thicknesses its maps give it."""
    tables = [make_table(40), make_table(41), make_table(42)]
    substrate = np.array([0.6, 0.4, 0.3])
    left_right = np.full((8, 8), 0.003)
    left_right[:, 4:] = 0.04
    top_bottom = np.full((8, 8), 0.035)
    top_bottom[4:] = 0.006  # the bottom half of the map (rows 4 .. 7) at v < 0.5
    constant = np.full((4, 4), 0.02)
    image = render(tables, [left_right, top_bottom, constant], substrate)
    rows, columns = np.arange(SIZE)[:, None], np.arange(SIZE)[None, :]
    for (lr, tb), region in (
        ((0.003, 0.035), (rows < 28) & (columns < 28)),
        ((0.04, 0.035), (rows < 28) & (columns >= 36)),
        ((0.003, 0.006), (rows >= 36) & (columns < 28)),
        ((0.04, 0.006), (rows >= 36) & (columns >= 36)),
    ):
        expected = reference(tables, [lr, tb, 0.02], substrate) * RADIANCE
        assert_card_equals(image, expected, np.broadcast_to(region, (SIZE, SIZE)))


def test_a_substrate_map_mixes_the_basis_per_uv_and_clamps():
    """Left half: the first basis reflectance; right half: half the second plus the third (clamped to [0, 1])."""
    table = make_table(43)
    basis = np.array([[0.2, 0.3, 0.4], [0.9, 0.8, 0.1], [0.6, 0.5, 0.2]])
    weights = np.zeros((4, 8, 3))
    weights[:, :4] = (1.0, 0.0, 0.0)
    weights[:, 4:] = (0.0, 0.5, 1.0)
    stack = ChannelStack([table], [0.01], np.full(3, 0.5), substrate_map=(weights, basis))
    image = render_layers(card_scene(stack))
    columns = np.arange(SIZE)[None, :]
    left = np.broadcast_to(columns < 24, (SIZE, SIZE))
    right = np.broadcast_to(columns >= 40, (SIZE, SIZE))
    assert_card_equals(image, reference([table], [0.01], basis[0]) * RADIANCE, left)
    right_substrate = np.clip(0.5 * basis[1] + basis[2], 0.0, 1.0)  # (1.05, 0.9, 0.25) -> red clamped to 1
    assert_card_equals(image, reference([table], [0.01], right_substrate) * RADIANCE, right)


EVEN_MM = np.linspace(0.0, 0.048, 17)  # evenly spaced: the shader finds the segment from the spacing


@pytest.mark.parametrize("x", [0.0, 0.003, 0.006, 0.0165, np.nextafter(0.018, 0.0), 0.018, 0.0479, 0.048, -0.002, 0.09])
def test_an_evenly_spaced_table_interpolates_as_np_interp(x):
    """Samples on an even axis (the planner's tables), looked up at samples, a hair below one, between them and
    beyond the ends: the linear interpolation of np.interp, the segment found exactly as a search would."""
    k, s = np.array([8.0, 20.0, 35.0]), np.array([30.0, 55.0, 70.0])
    axis = EVEN_MM[:, None]
    table = LayerTable(EVEN_MM, s * axis / (1.0 + (k + s) * axis), np.exp(-k * axis) / (1.0 + s * axis))
    substrate = np.array([0.55, 0.4, 0.3])
    assert_card_equals(render([table], [x], substrate), reference([table], [x], substrate) * RADIANCE)
