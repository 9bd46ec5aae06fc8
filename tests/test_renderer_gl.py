"""The OSMesa renderer foundation: context, float framebuffer, shaders, meshes, the Lambert pass and image files.

Scenes are small (tens of pixels to 129 x 129) so that the whole module runs in a few seconds on llvmpipe. Expected
values come from the closed forms: a Lambert surface of albedo a lit at angle theta by a light of radiance E renders
as a * E * cos(theta); a sphere of radius R projects to a disc of radius R (orthographic) or of
f * tan(asin(R / d)) (perspective, distance d, focal f in pixels).
"""

from __future__ import annotations

import multiprocessing

import numpy as np
import pytest
from lambert import lambert

from renderer import context, image_io, meshes
from renderer.program import Program, ShaderError
from renderer.scene import DirectionalLight, OrthographicCamera, PerspectiveCamera

ALBEDO = np.array([0.5, 0.25, 0.8])
RADIANCE = np.array([2.0, 3.0, 0.5])
BACKGROUND = (-1.0, -1.0, -1.0)  # a value no lit surface can produce
HEAD_ON = DirectionalLight(direction=(0.0, 0.0, -1.0), radiance=tuple(RADIANCE))


def pixel_centres(size: int, half_extent: float) -> np.ndarray:
    """World coordinates (mm) of pixel centres along one axis of an orthographic image spanning +-half_extent."""
    return -half_extent + (np.arange(size) + 0.5) * (2.0 * half_extent / size)


def covered(image: np.ndarray) -> np.ndarray:
    """Mask of pixels the mesh covers (anything but the background sentinel)."""
    return np.any(image != np.float32(BACKGROUND[0]), axis=-1)


def render_card(albedo: tuple[float, float, float]) -> np.ndarray:
    """A 20 x 10 mm card head-on in a 64 x 64 orthographic image; module level so spawn workers can import it."""
    return lambert(
        meshes.card(20.0, 10.0), OrthographicCamera(half_height=10.0), HEAD_ON, albedo, 64, 64, background=BACKGROUND
    )


def test_context_is_core_33_or_newer():
    context.make_current(8, 8)
    assert context.gl_version() >= (3, 3)
    profile = context.GL.glGetIntegerv(context.GL.GL_CONTEXT_PROFILE_MASK)
    assert profile & context.GL.GL_CONTEXT_CORE_PROFILE_BIT


def test_card_head_on_renders_albedo_times_radiance_over_the_card_only():
    image = render_card(tuple(ALBEDO))
    assert image.shape == (64, 64, 3)
    assert image.dtype == np.float32
    y = -pixel_centres(64, 10.0)  # row 0 is the top (+y)
    inside = np.broadcast_to((np.abs(y) < 5.0)[:, None], (64, 64))
    np.testing.assert_allclose(image[inside], np.broadcast_to(ALBEDO * RADIANCE, (inside.sum(), 3)), rtol=1e-6)
    np.testing.assert_array_equal(image[~inside], np.float32(-1.0))


@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0, 85.0])
def test_tilting_the_light_scales_by_cos_theta(theta_deg):
    theta = np.radians(theta_deg)
    light = DirectionalLight(direction=(0.0, -np.sin(theta), -np.cos(theta)), radiance=tuple(RADIANCE))
    image = lambert(meshes.card(20.0, 20.0), OrthographicCamera(half_height=10.0), light, tuple(ALBEDO), 16, 16)
    np.testing.assert_allclose(image, np.broadcast_to(ALBEDO * RADIANCE * np.cos(theta), image.shape), rtol=1e-5)


def test_light_from_behind_renders_black():
    light = DirectionalLight(direction=(0.0, 0.0, 1.0), radiance=tuple(RADIANCE))
    image = lambert(meshes.card(20.0, 20.0), OrthographicCamera(10.0), light, tuple(ALBEDO), 16, 16)
    np.testing.assert_array_equal(image, 0.0)


def test_rows_are_top_first():
    top_half = np.eye(4)
    top_half[1, 3] = 5.0  # a 20 x 10 card moved up by 5 mm covers y in [0, 10]: the top half of the view
    image = lambert(
        meshes.card(20.0, 10.0),
        OrthographicCamera(half_height=10.0),
        HEAD_ON,
        tuple(ALBEDO),
        32,
        32,
        model=top_half,
        background=BACKGROUND,
    )
    mask = covered(image)
    assert mask[:16].all()
    assert not mask[16:].any()


def test_sphere_centre_and_shading_follow_lambert():
    radius, half_height, size = 8.0, 10.0, 129
    image = lambert(
        meshes.sphere(radius),
        OrthographicCamera(half_height=half_height),
        HEAD_ON,
        tuple(ALBEDO),
        size,
        size,
        background=BACKGROUND,
    )
    centre = size // 2  # with an odd size the centre pixel sits on the axis, facing the light
    np.testing.assert_allclose(image[centre, centre], ALBEDO * RADIANCE, rtol=1e-5)
    x = pixel_centres(size, half_height)
    rho = np.hypot(x[None, :], x[:, None]) / radius
    inner = rho < 0.9
    expected = (ALBEDO * RADIANCE) * np.sqrt(1.0 - rho[inner] ** 2)[:, None]
    # the facets lie inside the true sphere, so a pixel sees a normal from slightly further out (< 0.5 %)
    np.testing.assert_allclose(image[inner], expected, rtol=5e-3)


@pytest.mark.parametrize(
    ("camera", "expected_radius_px"),
    [
        (OrthographicCamera(half_height=10.0), 8.0 / 10.0 * 64.5),
        (PerspectiveCamera(fov_y_deg=20.0), 64.5 * np.tan(np.arcsin(8.0 / 100.0)) / np.tan(np.radians(10.0))),
    ],
    ids=["orthographic", "perspective"],
)
def test_sphere_silhouette_radius_matches_the_projection(camera, expected_radius_px):
    image = lambert(meshes.sphere(8.0), camera, HEAD_ON, tuple(ALBEDO), 129, 129, background=BACKGROUND)
    mask = covered(image)
    measured_radius_px = np.sqrt(mask.sum() / np.pi)
    assert measured_radius_px == pytest.approx(expected_radius_px, rel=5e-3)
    rows, cols = np.nonzero(mask)
    assert rows.mean() == pytest.approx(64.0, abs=0.05)
    assert cols.mean() == pytest.approx(64.0, abs=0.05)


def test_broken_shader_names_the_file_and_the_log(tmp_path):
    broken = tmp_path / "broken.frag"
    broken.write_text("#version 330 core\nout vec4 c;\nvoid main() { c = undefined_thing; }\n")
    context.make_current(8, 8)
    with pytest.raises(ShaderError, match=r"broken\.frag: compile failed:\n.*undefined_thing"):
        Program("km_layers.vert", str(broken))


@pytest.mark.parametrize("half", [True, False])
def test_exr_round_trip_keeps_linear_values_and_header(tmp_path, half):
    rng = np.random.default_rng(7)
    linear = (rng.random((9, 13, 3)) * 20.0 - 2.0).astype(np.float32)
    if half:
        linear = linear.astype(np.float16).astype(np.float32)  # values a half float holds exactly
    header = {"product": "Velvet Matte", "shade": "320 Ivory", "camera_angle_deg": 30.5, "render_mode": "flat"}
    path = tmp_path / "frame.exr"
    image_io.write_exr(path, linear, header, half=half)
    pixels, attributes = image_io.read_exr(path)
    np.testing.assert_array_equal(pixels, linear)
    assert {name: attributes[name] for name in header} == header
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame.exr"]  # no temporary file left behind


def test_exr_rejects_attribute_of_other_type(tmp_path):
    with pytest.raises(TypeError, match="angles"):
        image_io.write_exr(tmp_path / "x.exr", np.zeros((2, 2, 3)), {"angles": [1.0, 2.0]})


def test_png_holds_srgb_encoded_codes(tmp_path):
    linear = np.array([[[0.5, 0.0, 1.0], [0.18, 0.001, 2.0], [-1.0, 0.0031308, 0.214]]])
    path = tmp_path / "sheet.png"
    image_io.write_png(path, linear)
    expected = np.array([[[188, 0, 255], [118, 3, 255], [0, 10, 127]]], dtype=np.uint8)
    np.testing.assert_array_equal(image_io.read_png(path), expected)


def test_rendered_frame_survives_exr_and_png(tmp_path):
    image = render_card((0.2, 0.2, 0.2))
    image_io.write_exr(tmp_path / "card.exr", image, {"render_mode": "flat"}, half=False)
    image_io.write_png(tmp_path / "card.png", np.clip(image, 0.0, None))
    np.testing.assert_array_equal(image_io.read_exr(tmp_path / "card.exr")[0], image)
    png = image_io.read_png(tmp_path / "card.png")
    assert png[32, 32].tolist() == np.rint(255 * image_io.srgb_encode(0.2 * RADIANCE)).astype(int).tolist()
    assert png[0, 0].tolist() == [0, 0, 0]


def test_spawn_pool_workers_render():
    context.make_current(8, 8)  # the parent holds a context, as in a real run; spawn must not inherit it
    albedos = [(0.1, 0.2, 0.3), (0.4, 0.5, 0.6)]
    with multiprocessing.get_context("spawn").Pool(2) as pool:
        images = pool.map(render_card, albedos)
    for albedo, image in zip(albedos, images, strict=True):
        np.testing.assert_allclose(image[32, 32], np.multiply(albedo, RADIANCE), rtol=1e-6)
        np.testing.assert_array_equal(image[0, 0], np.float32(-1.0))


def test_exr_accepts_a_broadcast_image(tmp_path):
    """A frame made with np.broadcast_to (zero strides) is written like a contiguous one."""
    colour = np.array([0.5, 0.25, 1.0], dtype=np.float32)
    path = tmp_path / "flat.exr"
    image_io.write_exr(path, np.broadcast_to(colour, (4, 5, 3)), {})
    pixels, _ = image_io.read_exr(path)
    assert pixels.shape == (4, 5, 3) and np.array_equal(pixels, np.broadcast_to(colour, (4, 5, 3)))


@pytest.mark.parametrize("channels", [1, 2, 3, 4])
def test_a_float_texture_keeps_its_channels_and_values(channels):
    """A map of C channels becomes a C-channel float32 texture (read back from GL) holding its texels as uploaded, the
    rows flipped so that the map's first row lies at t = 1."""
    from renderer.context import GL
    from renderer.textures import float_texture, map_texels

    values = np.random.default_rng(channels).random((5, 7, channels))
    with context.lock:
        context.make_current(8, 8)
        texture = float_texture(map_texels(values[..., 0] if channels == 1 else values), linear=True)
        GL.glBindTexture(GL.GL_TEXTURE_2D, texture)
        assert GL.glGetTexLevelParameteriv(GL.GL_TEXTURE_2D, 0, GL.GL_TEXTURE_INTERNAL_FORMAT) == {
            1: GL.GL_R32F, 2: GL.GL_RG32F, 3: GL.GL_RGB32F, 4: GL.GL_RGBA32F}[channels]  # fmt: skip
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 4)
        stored = np.frombuffer(GL.glGetTexImage(GL.GL_TEXTURE_2D, 0, GL.GL_RGBA, GL.GL_FLOAT), np.float32)
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
    stored = stored.reshape(5, 7, 4)
    np.testing.assert_array_equal(stored[..., :channels], values[::-1].astype(np.float32))
    assert np.all(stored[..., channels:3] == 0.0)  # a missing colour channel reads as 0 ...
    if channels < 4:
        assert np.all(stored[..., 3] == 1.0)  # ... and a missing alpha as 1


def test_a_float_texture_of_five_channels_is_refused():
    from renderer.textures import float_texture

    with context.lock:
        context.make_current(8, 8)
        with pytest.raises(ValueError, match="1 to 4 channels"):
            float_texture(np.zeros((2, 2, 5), np.float32), linear=True)


def test_a_frozen_map_is_hashed_once_and_a_changed_one_gets_a_texture_of_its_own(monkeypatch):
    """The texture cache finds textures by content: a map changed in place (writeable) gets a new texture holding
    the new values; a frozen map (read-only, as kmpipe's scenes hold theirs) is flipped and hashed once however often
    it is asked for, and gives the same texture each time."""
    from renderer import texture_cache
    from renderer.context import GL
    from renderer.textures import float_texture, map_texels

    hashed = []
    digest = texture_cache._digest
    monkeypatch.setattr(texture_cache, "_digest", lambda texels: hashed.append(texels.shape) or digest(texels))
    rng = np.random.default_rng(7)
    with context.lock:
        context.make_current(8, 8)
        live = rng.random((6, 9))
        first = float_texture(map_texels(live), linear=True)
        live[2, 3] += 1.0
        second = float_texture(map_texels(live), linear=True)
        GL.glBindTexture(GL.GL_TEXTURE_2D, second)
        stored = np.frombuffer(GL.glGetTexImage(GL.GL_TEXTURE_2D, 0, GL.GL_RED, GL.GL_FLOAT), np.float32)
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
        assert second != first and stored.reshape(6, 9)[::-1][2, 3] == np.float32(live[2, 3])
        assert len(hashed) == 2
        still = rng.random((5, 4, 3))
        still.setflags(write=False)
        assert texture_cache.frozen(still) and not texture_cache.frozen(live)
        view = live[::2]
        view.setflags(write=False)
        assert not texture_cache.frozen(view)  # read-only, but a view of memory that can change
        textures = {float_texture(map_texels(still), linear=True) for _ in range(5)}
    assert len(textures) == 1 and len(hashed) == 3
