"""Shadow maps (renderer.shadows) against geometry worked out here.

References: a texel ``[row, column]`` of an N x N map has its centre at ``u = (column + 0.5) / N`` and
``v = (N - 0.5 - row) / N`` (rows top first); a world point's texture coordinate and depth are ``q.xyz / q.w`` with
``q = shadow_matrix @ p``. The documented frusta give closed forms: under a directional light a point at distance
``s`` from the eye along the light has depth ``(s - h) / (2 h)`` with ``h = (1 + MARGIN) r`` and the eye ``2 h`` before
the centre; under a point light at distance ``D`` the depth is ``f (s - n) / (s (f - n))`` and the sphere's outline
is a circle of radius ``N / (2 (1 + MARGIN))`` texels. A card under a straight or tilted light casts the square
shadow found by projecting its corners along the light onto the ground.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from renderer import context, meshes, shadows
from renderer.context import GL
from renderer.framebuffer import Framebuffer
from renderer.program import Program
from renderer.scene import DirectionalLight, OrthographicCamera, PointLight

WHITE = (1.0, 1.0, 1.0)
DOWN = DirectionalLight(direction=(0.0, 0.0, -1.0), radiance=WHITE)
M = shadows.MARGIN


def translate(x: float, y: float, z: float) -> np.ndarray:
    model = np.eye(4)
    model[:3, 3] = x, y, z
    return model


def project(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(u, v, depth) of world points (n, 3) under a shadow matrix, after the perspective divide."""
    q = np.hstack([points, np.ones((len(points), 1))]) @ matrix.T
    return q[:, :3] / q[:, 3:]


def on_sphere(centre, radius: float, count: int, seed: int) -> np.ndarray:
    directions = np.random.default_rng(seed).normal(size=(count, 3))
    return np.asarray(centre, dtype=float) + radius * directions / np.linalg.norm(directions, axis=1, keepdims=True)


def texel_centres(size: int) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) of every texel centre, arrays (size, size) indexed [row, column] with row 0 at the top (v = 1)."""
    c = (np.arange(size) + 0.5) / size
    return np.broadcast_to(c[None, :], (size, size)), np.broadcast_to(c[::-1, None], (size, size))


def depth_map(mesh, model, light, centre, radius, size) -> tuple[np.ndarray, np.ndarray]:
    """Render one mesh into a shadow map; returns (depths top row first, shadow matrix)."""
    context.make_current(8, 8)
    view_projection = shadows.light_view_projection(light, centre, radius)
    with shadows.ShadowMap(size) as shadow_map, meshes.GpuMesh(mesh) as gpu_mesh:
        shadow_map.render([(gpu_mesh, model)], view_projection)
        np.testing.assert_array_equal(shadow_map.view_projection, view_projection)
        return shadows.read_depth(shadow_map), shadows.shadow_matrix(view_projection)


def test_card_under_a_straight_light_stores_its_depth_over_its_footprint_only():
    size = 64
    depth, matrix = depth_map(meshes.card(50.0, 50.0), np.eye(4), DOWN, (0.0, 0.0, 0.0), 25.0 * np.sqrt(2.0), size)
    assert depth.shape == (size, size) and depth.dtype == np.float32
    # world point under each texel centre on the plane z = 0: the map is orthographic, so invert it at two depths
    u, v = texel_centres(size)
    inverse = np.linalg.inv(matrix)
    ends = [np.stack([u, v, np.full_like(u, z), np.ones_like(u)], axis=-1) @ inverse.T for z in (0.0, 1.0)]
    a, b = ends[0][..., :3] / ends[0][..., 3:], ends[1][..., :3] / ends[1][..., 3:]
    world = a + (b - a) * (-a[..., 2:] / (b[..., 2:] - a[..., 2:]))
    extent = np.maximum(np.abs(world[..., 0]), np.abs(world[..., 1]))
    inside, outside = extent < 25.0 - 1e-3, extent > 25.0 + 1e-3
    assert inside.sum() > 0.4 * size**2 and outside.sum() > 0.1 * size**2
    expected = project(matrix, world[inside])[:, 2]
    np.testing.assert_allclose(depth[inside], expected, atol=1e-4)
    np.testing.assert_allclose(depth[inside], 0.5, atol=1e-4)  # the card lies at the centre: s = 2 h
    np.testing.assert_array_equal(depth[outside], 1.0)


def test_sphere_under_a_directional_light_gives_its_nearest_depth_and_a_disc():
    size, radius = 129, 25.0  # odd: the centre texel sits on the axis through the sphere's pole
    depth, matrix = depth_map(meshes.sphere(radius), np.eye(4), DOWN, (0.0, 0.0, 0.0), radius, size)
    (u, v, nearest), centre = project(matrix, np.array([[0.0, 0.0, radius], [0.0, 0.0, 0.0]]))
    assert (u, v) == pytest.approx((0.5, 0.5), abs=1e-12)
    assert nearest == pytest.approx(M / (2.0 * (1.0 + M)), rel=1e-9)  # s = 2 h - r
    stored = depth[size // 2, size // 2]
    assert 0.0 <= stored - nearest < 1e-3  # the polygon offset only pushes away from the light
    # outline radius in texels, from where the silhouette points land
    rim = project(matrix, np.array([[radius, 0.0, 0.0], [0.0, radius, 0.0]]))
    rim_texels = np.hypot(*(rim[:, :2] - centre[:2]).T) * size
    assert rim_texels[0] == pytest.approx(rim_texels[1], rel=1e-12)
    assert np.count_nonzero(depth < 1.0) == pytest.approx(np.pi * rim_texels[0] ** 2, rel=0.02)


def test_point_light_frames_the_sphere():
    size, radius, distance = 129, 25.0, 200.0
    light = PointLight(position=(0.0, 0.0, distance), radiance=WHITE, reference_distance_mm=100.0)
    vp = shadows.light_view_projection(light, (0.0, 0.0, 0.0), radius)
    matrix = shadows.shadow_matrix(vp)
    uvz = project(matrix, on_sphere((0.0, 0.0, 0.0), radius, 1000, seed=1))
    assert np.all((uvz[:, :2] >= 0.0) & (uvz[:, :2] <= 1.0))
    assert np.all((uvz[:, 2] > 0.0) & (uvz[:, 2] < 1.0))
    # the outline: where lines from the light touch the sphere, a circle at z = r^2 / D
    angle = np.linspace(0.0, 2.0 * np.pi, 360, endpoint=False)
    rho = radius * np.sqrt(1.0 - (radius / distance) ** 2)
    outline = np.stack([rho * np.cos(angle), rho * np.sin(angle), np.full_like(angle, radius**2 / distance)], axis=-1)
    offsets = np.hypot(*(project(matrix, outline)[:, :2] - 0.5).T)
    np.testing.assert_allclose(offsets, 0.5 / (1.0 + M), rtol=1e-9)
    depth, _ = depth_map(meshes.sphere(radius), np.eye(4), light, (0.0, 0.0, 0.0), radius, size)
    h = (1.0 + M) * radius
    near, far, s = distance - h, distance + h, distance - radius
    nearest = project(matrix, np.array([[0.0, 0.0, radius]]))[0]
    assert nearest == pytest.approx((0.5, 0.5, far * (s - near) / (s * (far - near))), rel=1e-9)
    assert 0.0 <= depth[size // 2, size // 2] - nearest[2] < 1e-3
    expected_area = np.pi * (size / (2.0 * (1.0 + M))) ** 2
    assert np.count_nonzero(depth < 1.0) == pytest.approx(expected_area, rel=0.02)


@pytest.mark.parametrize("position", [(0.0, 0.0, 10.0), (0.0, 25.0, 0.0), (3.0, -4.0, 0.0)])
def test_point_light_inside_or_on_the_sphere_is_refused(position):
    light = PointLight(position=position, radiance=WHITE, reference_distance_mm=100.0)
    with pytest.raises(ValueError, match=r"inside or on the bounding sphere.*cast_shadows=False"):
        shadows.light_view_projection(light, (0.0, 0.0, 0.0), 25.0)


@pytest.mark.parametrize("radius", [0.0, -1.0, np.inf, np.nan])
def test_bad_radius_is_refused(radius):
    with pytest.raises(ValueError, match="radius"):
        shadows.light_view_projection(DOWN, (0.0, 0.0, 0.0), radius)


@pytest.mark.parametrize(
    "direction",
    [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1), (1, 1, 1), (-1, 2, -0.5)],
)
def test_directional_light_along_any_axis_or_diagonal(direction):
    centre, radius = np.array([10.0, -20.0, 5.0]), 30.0
    matrix = shadows.shadow_matrix(
        shadows.light_view_projection(DirectionalLight(direction=direction, radiance=WHITE), centre, radius)
    )
    assert np.all(np.isfinite(matrix))
    np.testing.assert_allclose(matrix[3], [0.0, 0.0, 0.0, 1.0], atol=1e-15)  # orthographic
    d = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    towards, away = project(matrix, np.array([centre - radius * d, centre + radius * d]))
    edge = M / (2.0 * (1.0 + M))
    np.testing.assert_allclose([towards[2], away[2]], [edge, 1.0 - edge], rtol=1e-9)
    np.testing.assert_allclose([towards[:2], away[:2]], 0.5, atol=1e-12)  # both on the axis through the centre
    uvz = project(matrix, on_sphere(centre, radius, 500, seed=2))
    assert np.all((uvz >= 0.0) & (uvz <= 1.0))
    # the square just encloses the sphere: the outline reaches 0.5 / (1 + m) from the centre in every direction
    outline = np.hypot(*(uvz[:, :2] - 0.5).T)
    assert outline.max() <= 0.5 / (1.0 + M) * (1.0 + 1e-9)


unit_vector = st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda v: np.linalg.norm(v) > 0.1)


@settings(max_examples=200, deadline=None)
@given(
    kind=st.sampled_from(["directional", "point"]),
    direction=unit_vector,
    centre=st.tuples(*[st.floats(-500.0, 500.0)] * 3),
    radius=st.floats(0.1, 200.0),
    light_distance=st.floats(1.001, 50.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_every_point_of_the_sphere_lies_in_the_light_frustum(kind, direction, centre, radius, light_distance, seed):
    d = np.asarray(direction) / np.linalg.norm(direction)
    if kind == "directional":
        light = DirectionalLight(direction=tuple(d), radiance=WHITE)
    else:
        position = tuple(np.asarray(centre) - light_distance * radius * d)
        light = PointLight(position=position, radiance=WHITE, reference_distance_mm=100.0)
    matrix = shadows.shadow_matrix(shadows.light_view_projection(light, centre, radius))
    q = np.hstack([on_sphere(centre, radius, 200, seed), np.ones((200, 1))]) @ matrix.T
    assert np.all(q[:, 3] > 0.0)  # in front of the light
    uvz = q[:, :3] / q[:, 3:]
    assert np.all((uvz >= 0.0) & (uvz <= 1.0))


RECEIVER_VERT = """#version 330 core
layout(location = 0) in vec3 a_position;
uniform mat4 u_model;
uniform mat4 u_view_projection;
uniform mat4 u_shadow_matrix;
out vec4 v_shadow;
void main() {
    vec4 world = u_model * vec4(a_position, 1.0);
    v_shadow = u_shadow_matrix * world;
    gl_Position = u_view_projection * world;
}
"""
RECEIVER_FRAG = """#version 330 core
in vec4 v_shadow;
uniform sampler2DShadow u_shadow_map;
out vec4 f_colour;
void main() {
    float lit = textureProj(u_shadow_map, v_shadow);
    f_colour = vec4(lit, lit, lit, 1.0);
}
"""


@pytest.mark.parametrize(
    ("theta_deg", "ground_mm", "blocker_mm", "centre", "radius"),
    [
        (0.0, 80.0, 20.0, (0.0, 0.0, 5.0), 20.0),
        (0.0, 80.0, 60.0, (0.0, 0.0, 5.0), 20.0),
        (50.0, 60.0, 20.0, (0.0, 0.0, 0.0), 43.0),
    ],
    ids=["straight-map-smaller-than-ground", "straight-blocker-wider-than-map", "tilted-map-covers-ground"],
)
def test_sampler2dshadow_lookup_shadows_the_ground_under_a_blocker(
    tmp_path, theta_deg, ground_mm, blocker_mm, centre, radius
):
    """A square card 10 mm above a ground card: the ground is lit (1) except where the blocker's projected square and
    the map's footprint overlap; outside the map the border depth 1 reads as lit, even next to a shadowed edge."""
    theta, height, pixels = np.radians(theta_deg), 10.0, int(2 * ground_mm)
    light = DirectionalLight(direction=(0.0, -np.sin(theta), -np.cos(theta)), radiance=WHITE)
    (tmp_path / "receiver.vert").write_text(RECEIVER_VERT)
    (tmp_path / "receiver.frag").write_text(RECEIVER_FRAG)
    camera = OrthographicCamera(half_height=ground_mm / 2.0)  # looks down -z, 0.5 mm per pixel: finer than the map
    context.make_current(8, 8)
    receiver = Program(str(tmp_path / "receiver.vert"), str(tmp_path / "receiver.frag"))
    view_projection = shadows.light_view_projection(light, centre, radius)
    with (
        shadows.ShadowMap(64) as shadow_map,
        meshes.GpuMesh(meshes.card(ground_mm, ground_mm)) as ground,
        meshes.GpuMesh(meshes.card(blocker_mm, blocker_mm)) as blocker,
        Framebuffer(pixels, pixels) as target,
    ):
        shadow_map.render([(ground, np.eye(4)), (blocker, translate(0.0, 0.0, height))], view_projection)
        target.clear((-1.0, -1.0, -1.0, 0.0))
        GL.glEnable(GL.GL_DEPTH_TEST)
        receiver.use()
        receiver.set_mat4("u_model", np.eye(4))
        receiver.set_mat4("u_view_projection", camera.projection_matrix(1.0) @ camera.view_matrix())
        receiver.set_mat4("u_shadow_matrix", shadows.shadow_matrix(view_projection))
        GL.glUniform1i(GL.glGetUniformLocation(receiver.handle, "u_shadow_map"), 0)
        GL.glActiveTexture(GL.GL_TEXTURE0)
        GL.glBindTexture(GL.GL_TEXTURE_2D, shadow_map.texture)
        ground.draw()
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
        lit = target.read_rgba()[..., 0]
    receiver.release()
    x = -ground_mm / 2.0 + (np.arange(pixels) + 0.5) * 0.5
    px, py = np.meshgrid(x, -x)  # row 0 is the top (+y)
    shift = height * np.tan(theta)  # the blocker's shadow slides along -y
    half = blocker_mm / 2.0
    # the map's footprint on the ground is |x|, |y| < h for the straight light; the tilted one's is larger (stretched
    # along y) and holds the whole ground, so h bounds it from inside
    in_map = (1.0 + M) * radius - np.maximum(np.abs(px), np.abs(py))
    distance_to_edge = np.minimum(np.minimum(half - np.abs(px), half - np.abs(py + shift)), in_map)  # > 0: shadow
    texel_mm = 2.0 * (1.0 + M) * radius / 64 / np.cos(theta)  # map texels stretch along y on the tilted ground
    blur = 1.5 * texel_mm + 1.0  # PCF reaches a texel and a half; 1 mm more for the pixel grid
    shadowed, open_ground = distance_to_edge > blur, distance_to_edge < -blur
    assert shadowed.sum() > 100 and open_ground.sum() > 1000
    np.testing.assert_array_equal(lit[shadowed], 0.0)
    np.testing.assert_array_equal(lit[open_ground], 1.0)  # no self-shadowing acne, and the border reads as lit
    assert np.any((lit > 0.05) & (lit < 0.95))  # linear filtering: 2 x 2 PCF softens the shadow's edge
    if theta_deg == 0.0:
        assert np.count_nonzero(in_map < -blur) > 1000


def test_render_restores_the_callers_state():
    context.make_current(8, 8)
    with Framebuffer(4, 4) as target, shadows.ShadowMap(16) as shadow_map, meshes.GpuMesh(meshes.card(1, 1)) as card:
        target.bind()
        GL.glDisable(GL.GL_DEPTH_TEST)
        GL.glDepthFunc(GL.GL_GEQUAL)
        GL.glDepthMask(GL.GL_FALSE)
        GL.glUseProgram(0)
        shadow_map.render([(card, np.eye(4))], shadows.light_view_projection(DOWN, (0.0, 0.0, 0.0), 1.0))
        assert int(GL.glGetIntegerv(GL.GL_DRAW_FRAMEBUFFER_BINDING)) == target.fbo
        assert int(GL.glGetIntegerv(GL.GL_READ_FRAMEBUFFER_BINDING)) == target.fbo
        assert not GL.glIsEnabled(GL.GL_POLYGON_OFFSET_FILL)
        assert float(GL.glGetFloatv(GL.GL_POLYGON_OFFSET_FACTOR)) == 0.0
        assert float(GL.glGetFloatv(GL.GL_POLYGON_OFFSET_UNITS)) == 0.0
        assert not GL.glIsEnabled(GL.GL_DEPTH_TEST)
        assert int(GL.glGetIntegerv(GL.GL_DEPTH_FUNC)) == GL.GL_GEQUAL
        assert not GL.glGetBooleanv(GL.GL_DEPTH_WRITEMASK)
        assert int(GL.glGetIntegerv(GL.GL_CURRENT_PROGRAM)) == 0
        GL.glDepthFunc(GL.GL_LESS)
        GL.glDepthMask(GL.GL_TRUE)
        assert shadows.read_depth(shadow_map)[8, 8] == pytest.approx(0.5, abs=1e-6)


def test_shadow_map_size_is_checked():
    context.make_current(8, 8)
    with pytest.raises(ValueError, match="size"):
        shadows.ShadowMap(0)
