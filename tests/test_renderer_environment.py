"""Studio light in the layer pass: environment light, ambient occlusion, soft shadows, backdrops, fine detail.

References, none produced by the code under test:

* the white furnace: inside a uniform environment of radiance L a Lambert surface of albedo a reflects exactly a L
  (its irradiance is pi L wherever it faces), a Kubelka-Munk stack its composite reflectance times L;
* the Kelemen / Szirmay-Kalos lobe (thesis eq. 3.15, as ``shaders/km_layers.frag`` writes it: normalised Beckmann P,
  Schlick F, 1 / (2 (1 + l.v))) integrated here against cos(theta_l) over the light's hemisphere on a fine grid (the
  code integrates over the half vector instead);
* the irradiance of a cosine sky L(w) = c max(w.y, 0): for a normal at angle g from +y, integral of two clamped
  cosines, ``E / pi = (2 c / (3 pi)) ((pi - g) cos g + sin g)`` (checked here against scipy's dblquad too);
* the equirectangular directions and the rotation as ``renderer/environment.py``'s docstring states them, written
  out here;
* ambient occlusion of a floor point at distance d from an infinitely wide wall of height H: the wall is the wedge of
  directions between the horizon and elevation alpha = atan(H / d), seen in a cross-section as the 2-D view factor
  of a strip, (sin 90 - sin(90 - alpha)) / 2; it hides the projected solid angle (pi / 2) (1 - cos alpha) of pi, so
  AO = (1 + cos alpha) / 2;
* the penumbra of a disc-shaped light of angular diameter theta behind an edge a gap g above the floor: the lit
  fraction of the light's disc of diameter D = 2 g tan(theta / 2), a circular segment;
* a tangent-space normal (sin a, 0, cos a) on a card facing +z is the world normal (sin a, 0, cos a), so Lambert
  scales by its cosine to the light; a film of thickness t scales its tilt by k = exp(-t / fill).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import trimesh
from lambert import joined
from scipy import integrate, ndimage, optimize

from renderer import meshes
from renderer.environment import (
    LOBE_TABLE_SIZE,
    Environment,
    lobe_albedo,
    lobe_m_axis,
    prefiltered,
    studio_environment,
)
from renderer.layers import render_layers
from renderer.occlusion import FloorOcclusion, floor_occlusion, vertex_occlusion
from renderer.products import load_mesh
from renderer.scene import (
    DirectionalLight,
    GradientBackground,
    NormalMap,
    OrthographicCamera,
    PerspectiveCamera,
    PointLight,
    Prop,
    Scattering,
    Scene,
)
from renderer.skin import render_skin
from renderer.stack import LOBE_COVER_MM, ChannelStack, LayerTable, Specular

ROOT = Path(__file__).resolve().parents[1]
SIZE = 48
CAMERA = OrthographicCamera(half_height=12.0, eye=(0.0, 0.0, 100.0), near=1.0, far=300.0)
SPHERE = meshes.sphere(10.0)
CARD = meshes.card(30.0, 30.0)  # fills the frame: u along +x, v along +y, facing +z
DARK = DirectionalLight((0.0, 0.0, -1.0), (0.0, 0.0, 0.0), cast_shadows=False)  # a light that adds nothing
HEAD_ON = DirectionalLight((0.0, 0.0, -1.0), (1.0, 1.0, 1.0), cast_shadows=False)
BACKGROUND = (-1.0, -1.0, -1.0)  # marks the pixels no surface covers


def uniform(radiance: float, **options) -> Environment:
    return Environment(np.full((16, 32, 3), radiance, np.float32), **options)


def scene(**options) -> Scene:
    """A white Lambert sphere in the frame's middle, no light; ``options`` replace any field."""
    base = Scene(
        mesh=SPHERE,
        stack=ChannelStack((), (), (1.0, 1.0, 1.0)),
        camera=CAMERA,
        lights=[DARK],
        resolution=(SIZE, SIZE),
        background=BACKGROUND,
    )
    return dataclasses.replace(base, **options)


def covered(image: np.ndarray) -> np.ndarray:
    return image[..., 0] >= 0.0


def equirect_directions(cols: int, rows: int) -> np.ndarray:
    """Pixel-centre directions of an equirectangular image as renderer/environment.py's docstring defines them:
    theta from +y, phi from -z towards +x, d = (sin theta sin phi, cos theta, -sin theta cos phi)."""
    theta = (np.arange(rows) + 0.5) / rows * np.pi
    phi = (np.arange(cols) + 0.5) / cols * 2.0 * np.pi - np.pi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    return np.stack([np.sin(t) * np.sin(p), np.cos(t), -np.sin(t) * np.cos(p)], axis=-1)


def environment_of(function, cols: int = 128) -> np.ndarray:
    """An equirectangular image (cols / 2, cols, 3) whose pixels are ``function(direction)`` (grey)."""
    values = function(equirect_directions(cols, cols // 2))
    return np.repeat(values[..., None], 3, axis=2).astype(np.float32)


def kelemen_albedo(mu: float, m: float, f0: float, n_theta: int = 360, n_phi: int = 720) -> float:
    """rho(mu, m, F0) = integral over the light's hemisphere of f_spec(l, v) cos(theta_l) dw_l, midpoint rule in
    (theta_l, phi_l); f_spec = P(h) F(h.l) / (2 (1 + l.v)), P = exp(-tan^2 a / m^2) / (pi m^2 cos^4 a), Schlick F."""
    theta = (np.arange(n_theta) + 0.5) / n_theta * (np.pi / 2.0)
    phi = (np.arange(n_phi) + 0.5) / n_phi * (2.0 * np.pi)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    light = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
    view = np.array([np.sqrt(1.0 - mu * mu), 0.0, mu])
    half = light + view
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    cos_a = half[..., 2]
    beckmann = np.exp(-(1.0 - cos_a**2) / cos_a**2 / m**2) / (np.pi * m**2 * cos_a**4)
    fresnel = f0 + (1.0 - f0) * (1.0 - np.sum(half * light, axis=-1)) ** 5
    f_spec = beckmann * fresnel / (2.0 * (1.0 + light @ view))
    d_omega = np.sin(t) * (np.pi / 2.0 / n_theta) * (2.0 * np.pi / n_phi)
    return float(np.sum(f_spec * np.cos(t) * d_omega))


# 1. The white furnace.


@pytest.mark.parametrize(("albedo", "radiance", "intensity"), [(1.0, 0.7, 1.0), (0.35, 0.7, 1.0), (0.35, 0.7, 2.5)])
def test_a_lambert_sphere_in_a_uniform_environment_renders_albedo_times_radiance(albedo, radiance, intensity):
    image = render_layers(
        scene(stack=ChannelStack((), (), (albedo,) * 3), environment=uniform(radiance, intensity=intensity))
    )
    inside = covered(image)
    assert inside.sum() > 0.4 * SIZE * SIZE
    np.testing.assert_allclose(image[inside], intensity * albedo * radiance, rtol=2e-6)  # float32 rounding


def test_the_skin_pass_keeps_the_furnace_through_a_film_and_its_scattering():
    """Skin under a film (R0, T) in a uniform environment: the KM composite R0 + T^2 a / (1 - R0 a) times L, with or
    without the subsurface blur (a uniform skin light blurred stays uniform)."""
    r0, t, skin = np.array([0.2, 0.3, 0.1]), np.array([0.6, 0.5, 0.7]), np.array([0.9, 0.7, 0.5])
    stack = ChannelStack((LayerTable(0.01, r0, t),), (0.01,), skin)
    expected = 0.7 * (r0 + t**2 * skin / (1.0 - r0 * skin))
    for scattering in (None, Scattering()):
        image = render_skin(scene(stack=stack, environment=uniform(0.7), scattering=scattering))
        np.testing.assert_allclose(
            image[covered(image)], np.broadcast_to(expected, image[covered(image)].shape), rtol=2e-5
        )


# 2. The lobe albedo table.


@pytest.mark.parametrize(("m_row", "mu_column"), [(8, 31), (8, 12), (18, 22), (18, 4), (31, 31), (31, 12)])
def test_the_lobe_albedo_table_matches_a_quadrature_over_the_light_hemisphere(m_row, mu_column):
    m = lobe_m_axis()[m_row]
    mu = np.linspace(0.0, 1.0, LOBE_TABLE_SIZE[0])[mu_column]  # the table's mu nodes (its first is 1e-3)
    assert m >= 0.2  # the grid resolves the lobe
    a, b = lobe_albedo()[m_row, mu_column]
    for f0 in (0.028, 0.04, 0.25):
        assert f0 * a + b == pytest.approx(kelemen_albedo(mu, m, f0), rel=0.01)


# 3. Lobes in a uniform environment.


@pytest.mark.parametrize(("roughness", "ior"), [(0.3, 1.5), (0.2, 1.4), (0.6, 2.0)])
def test_a_substrate_lobe_in_a_uniform_environment_adds_its_albedo_times_radiance(roughness, ior):
    """At the sphere's centre (mu = 1) the lobe adds rho(1, m, F0) L to the Lambert a L; under a film of
    transmittance T (no lobe of its own) the substrate's lobe is seen through it: T^2 rho L."""
    radiance, albedo, lobe = 0.7, 0.4, Specular(roughness, ior)
    centre = (SIZE // 2, SIZE // 2)
    rho = kelemen_albedo(1.0, roughness, lobe.f0)
    bare = scene(stack=ChannelStack((), (), (albedo,) * 3), environment=uniform(radiance), resolution=(SIZE + 1,) * 2)
    without = render_layers(bare)[centre]
    with_lobe = render_layers(dataclasses.replace(bare, substrate_lobe=lobe))[centre]
    np.testing.assert_allclose(without, albedo * radiance, rtol=1e-5)
    np.testing.assert_allclose(with_lobe - without, rho * radiance, rtol=0.015)
    t = np.array([0.8, 0.5, 0.3])
    filmed = dataclasses.replace(
        bare, stack=ChannelStack((LayerTable(0.01, np.full(3, 0.1), t),), (0.01,), (albedo,) * 3)
    )
    seen = render_layers(dataclasses.replace(filmed, substrate_lobe=lobe))[centre] - render_layers(filmed)[centre]
    np.testing.assert_allclose(seen, t**2 * rho * radiance, rtol=0.015)


# 4. The irradiance prefilter.


def cosine_sky_irradiance(c: float, gamma: np.ndarray) -> np.ndarray:
    """E / pi of a normal at angle gamma from +y under L = c max(w.y, 0): (1 / pi) * integral of
    c max(w.y, 0) max(n.w, 0) dw = (2 c / (3 pi)) ((pi - gamma) cos gamma + sin gamma)."""
    return 2.0 * c / (3.0 * np.pi) * ((np.pi - gamma) * np.cos(gamma) + np.sin(gamma))


def test_the_closed_form_of_the_cosine_sky_holds():
    for gamma in (0.0, 0.7, np.pi / 2, 2.2):
        n = np.array([np.sin(gamma), np.cos(gamma), 0.0])

        def integrand(theta, phi, n=n):
            w = np.array([np.sin(theta) * np.cos(phi), np.cos(theta), np.sin(theta) * np.sin(phi)])
            return np.cos(theta) * max(float(n @ w), 0.0) * np.sin(theta)

        value, _ = integrate.dblquad(integrand, 0.0, 2.0 * np.pi, 0.0, np.pi / 2.0, epsabs=1e-10)
        assert value / np.pi == pytest.approx(cosine_sky_irradiance(1.0, gamma), rel=1e-6, abs=1e-9)


def test_the_prefiltered_irradiance_of_a_cosine_sky_matches_the_closed_form():
    c = 0.8
    maps = prefiltered(Environment(environment_of(lambda d: c * np.maximum(d[..., 1], 0.0))))
    rows, cols = maps.irradiance.shape[:2]
    gamma = np.arccos(np.clip(equirect_directions(cols, rows)[..., 1], -1.0, 1.0))  # every texel's normal
    expected = cosine_sky_irradiance(c, gamma)
    assert maps.irradiance[0, 0, 0] == pytest.approx(2.0 * c / 3.0, rel=0.01)  # next to the zenith
    horizon = maps.irradiance[rows // 2 - 1 : rows // 2 + 1, 0, 0].mean()  # bilinear between the rows around it
    assert horizon == pytest.approx(2.0 * c / (3.0 * np.pi), rel=0.02)
    np.testing.assert_allclose(maps.irradiance[..., 0], expected, rtol=0.02, atol=0.002 * c)
    np.testing.assert_array_equal(maps.irradiance[..., 0], maps.irradiance[..., 2])


# 5. Rotation.


def test_rotation_turns_the_environment_counter_clockwise_seen_from_above():
    """A bright patch around -z (the image's centre, phi = 0). Seen from above (x to the right, -z up) a turn of
    +90 degrees counter-clockwise takes -z, pointing up, to pointing left: -x. Lookups and renders agree."""
    patch = environment_of(lambda d: np.where(d[..., 2] < -np.cos(np.radians(20.0)), 5.0, 0.02))
    probes = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    for rotation, bright in ((0.0, 0), (90.0, 1), (-90.0, 2), (180.0, 3), (450.0, 1)):
        seen = Environment(patch, rotation_deg=rotation, intensity=2.0).lookup(probes)[:, 0]
        np.testing.assert_allclose(seen, np.where(np.arange(4) == bright, 10.0, 0.04), rtol=1e-5)
    # In the layer pass the sphere's side facing the patch is lit: the left half at +90, the right at -90.
    for rotation, left_brighter in ((90.0, True), (-90.0, False)):
        image = render_layers(scene(environment=Environment(patch, rotation_deg=rotation)))[..., 0]
        left, right = image[:, : SIZE // 2], image[:, SIZE // 2 :]
        assert (left[left >= 0].mean() > 5.0 * right[right >= 0].mean()) == left_brighter


# 6. Ambient occlusion.


def floor_grid(xs: np.ndarray, zs: np.ndarray) -> trimesh.Trimesh:
    """A floor in y = 0 over the grid xs x zs (mm), normals +y, with uv."""
    xx, zz = np.meshgrid(xs, zs, indexing="xy")
    vertices = np.stack([xx, np.zeros_like(xx), zz], axis=-1).reshape(-1, 3)
    n = len(xs)
    i, j = np.meshgrid(np.arange(len(zs) - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    faces = np.concatenate([np.stack([a, a + n, a + 1], -1), np.stack([a + 1, a + n, a + n + 1], -1)])
    uv = np.stack([(xx - xs[0]) / np.ptp(xs), (zz - zs[0]) / np.ptp(zs)], axis=-1).reshape(-1, 2)
    return trimesh.Trimesh(
        vertices,
        faces,
        vertex_normals=np.tile([0.0, 1.0, 0.0], (len(vertices), 1)),
        visual=trimesh.visual.TextureVisuals(uv=uv),
        process=False,
    )


def test_a_sphere_sees_the_whole_sky():
    np.testing.assert_array_equal(vertex_occlusion(SPHERE), 1.0)


def test_a_wall_hides_the_wedge_of_sky_below_its_top_edge():
    height, half_width = 10.0, 100.0  # the wall's width is 10 times the farthest distance: practically infinite
    distances = np.array([2.5, 5.0, 10.0, 20.0])
    floor = floor_grid(np.array([-4.0, 0.0, 4.0]), np.concatenate([[0.0], distances, [25.0]]))
    wall = trimesh.Trimesh(
        [[-half_width, 0.0, 0.0], [half_width, 0.0, 0.0], [half_width, height, 0.0], [-half_width, height, 0.0]],
        [[0, 1, 2], [0, 2, 3]],
        vertex_normals=np.tile([0.0, 0.0, 1.0], (4, 1)),
        visual=trimesh.visual.TextureVisuals(uv=np.zeros((4, 2))),
        process=False,
    )
    ao = vertex_occlusion(floor, [wall], n_directions=400, size=1024)
    for d in distances:
        at = np.flatnonzero((floor.vertices[:, 0] == 0.0) & (floor.vertices[:, 2] == d))[0]
        alpha = np.arctan2(height, d)
        assert ao[at] == pytest.approx((1.0 + np.cos(alpha)) / 2.0, rel=0.03), d


def test_a_sphere_resting_on_the_floor_hides_the_cap_of_sky_it_spans():
    """A sphere of radius r on the floor, seen from a floor point d from its contact: its disc of sky (angular radius
    asin(r / D), centre at elevation angle with cos = r / D from the zenith, D = sqrt(d^2 + r^2)) just touches the
    horizon, so the cosine-weighted sky it hides is (r / D)^2 (r / D): AO = 1 - (r / D)^3."""
    r = 10.0
    baked = floor_occlusion([meshes.sphere(r).apply_translation([0.0, r, 0.0])], 0.0, (0.0, 0.0), 4.0 * r, r, cells=40)
    for d in (1.2 * r, 1.6 * r, 2.0 * r, 3.0 * r):
        expected = 1.0 - (r / np.hypot(d, r)) ** 3
        for direction in ((1.0, 0.0), (0.0, -1.0), (-0.6, 0.8)):
            point = np.array([[d * direction[0], 0.0, d * direction[1]]])
            assert baked.at(point)[0] == pytest.approx(expected, abs=0.02), (d, direction)
    assert baked.at(np.array([[0.0, 0.0, 0.0]]))[0] < 0.05  # under the sphere: no sky at all


def test_a_baked_floor_is_its_grid_at_its_nodes_and_fades_to_open_sky():
    values = np.linspace(0.2, 0.9, 25).reshape(5, 5)
    floor = FloorOcclusion((10.0, -5.0), 2.0, 8.0, values, fade_mm=1.0)
    s = np.linspace(-1.0, 1.0, 5)
    # inner nodes (outside the grid's fading rim): exactly their values; row i is z, column j is x
    nodes = np.array([[10.0 + 8.0 * s[j], 2.0, -5.0 + 8.0 * s[i]] for i in (1, 2, 3) for j in (1, 2, 3)])
    np.testing.assert_allclose(floor.at(nodes), [values[i, j] for i in (1, 2, 3) for j in (1, 2, 3)], rtol=1e-6)
    beyond = np.array([[10.0 + 9.0, 2.0, -5.0], [10.0, 2.0, -5.0 - 30.0], [10.0, 2.0 + 1.0, -5.0]])  # out, above
    np.testing.assert_array_equal(floor.at(beyond), 1.0)


@pytest.mark.parametrize("turn_deg", [0.0, 35.0])
def test_a_floor_takes_its_baked_grid_per_pixel_where_it_lies_relative_to_the_product(turn_deg):
    """A white floor of two triangles in a uniform environment of radiance 1, seen from above, renders the grid's
    occlusion at each pixel centre's place in the grid's frame (FloorOcclusion.at: bilinear, the rim's fade), the
    frame turned by the product's turn."""
    rng = np.random.default_rng(7)
    baked = FloorOcclusion((1.0, -2.0), 2.0, 8.0, rng.uniform(0.2, 1.0, (9, 9)), fade_mm=1.0)
    a = np.radians(turn_deg)
    frame = np.eye(4)
    frame[[0, 0, 2, 2], [0, 2, 0, 2]] = np.cos(a), np.sin(a), -np.sin(a), np.cos(a)  # about +y
    lift = np.eye(4)
    lift[1, 3] = 2.0  # the floor at y = 2
    side = np.array([-12.0, 12.0])
    floor = Prop(floor_grid(side, side), (1.0, 1.0, 1.0), lift, floor_occlusion=baked, floor_frame=frame)
    away = np.eye(4)
    away[0, 3] = 1000.0  # the sphere out of the frame: the floor alone
    top = OrthographicCamera(half_height=12.0, eye=(0.0, 100.0, 0.0), up=(0.0, 0.0, -1.0), near=1.0, far=300.0)
    image = render_layers(scene(camera=top, model=away, props=[floor], environment=uniform(1.0)))
    centres = -12.0 + (np.arange(SIZE) + 0.5) * 24.0 / SIZE  # x along columns; z along rows (the top row at -z)
    x, z = np.meshgrid(centres, centres, indexing="xy")
    points = np.stack([x, np.full_like(x, 2.0), z], axis=-1).reshape(-1, 3)
    expected = baked.at(points @ frame[:3, :3].T).reshape(SIZE, SIZE)
    assert expected.min() < 0.3 and np.mean(expected == 1.0) > 0.2  # dark inside the grid, open sky beyond it
    np.testing.assert_allclose(image[..., 0], expected, atol=1e-5)  # float32 lookups


def test_a_card_in_cells_is_the_same_card():
    one, many = meshes.card(30.0, 20.0), meshes.card(30.0, 20.0, 8)
    assert len(many.vertices) == 81 and len(many.faces) == 128
    assert many.area == pytest.approx(one.area) == pytest.approx(600.0)
    np.testing.assert_allclose(many.vertex_normals, np.tile([0.0, 0.0, 1.0], (81, 1)))
    np.testing.assert_allclose(many.visual.uv, (many.vertices[:, :2] + [15.0, 10.0]) / [30.0, 20.0], atol=1e-12)
    assert np.all(np.cross(*(many.triangles[:, 1:] - many.triangles[:, :1]).transpose(1, 0, 2))[:, 2] > 0)


def fibonacci_directions(n: int) -> np.ndarray:
    """n unit vectors spread evenly over the sphere: z_k = 1 - (2k + 1) / n, azimuth k times the golden angle."""
    k = np.arange(n)
    z = 1.0 - (2.0 * k + 1.0) / n
    azimuth = k * np.pi * (3.0 - np.sqrt(5.0))
    rho = np.sqrt(1.0 - z * z)
    return np.stack([rho * np.cos(azimuth), rho * np.sin(azimuth), z], axis=1)


def ray_hits(triangles: np.ndarray, origin: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Whether each ray from ``origin`` along ``directions`` (k, 3) meets any of ``triangles`` (n, 3, 3): the
    Moller-Trumbore test, a hit at u, v >= 0, u + v <= 1 and distance t > 0."""
    e1, e2 = triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
    to_origin = origin - triangles[:, 0]
    q = np.cross(to_origin, e1)
    p = np.cross(directions[:, None, :], e2[None])
    det = np.einsum("kij,ij->ki", p, e1)
    inverse = 1.0 / np.where(np.abs(det) > 1e-12, det, np.inf)
    u = np.einsum("kij,ij->ki", p, to_origin) * inverse
    v = (directions @ q.T) * inverse
    t = np.sum(e2 * q, axis=1) * inverse
    return np.any((u >= 0.0) & (v >= 0.0) & (u + v <= 1.0) & (t > 1e-6), axis=1)


def test_the_heads_baked_occlusion_agrees_with_ray_casting():
    """The bundled head with its eyes, at the default settings: at sampled vertices, the cosine-weighted share of 200
    directions whose rays (from just off the surface) meet nothing, cast here against every triangle."""
    head_dir = ROOT / "recipes" / "head"
    head = load_mesh(head_dir / "head.obj")
    eyes = [load_mesh(head_dir / f"eyes_{part}.obj") for part in ("sclera", "iris", "pupil")]
    baked = vertex_occlusion(head, eyes)
    triangles = np.concatenate([np.asarray(m.vertices)[m.faces] for m in (head, *eyes)])
    directions = fibonacci_directions(200)
    points, normals = np.asarray(head.vertices), np.asarray(head.vertex_normals)
    sample = np.random.default_rng(7).choice(len(points), 16, replace=False)
    cast = []
    for i in sample:
        weight = np.maximum(directions @ normals[i], 0.0)
        open_sky = ~ray_hits(triangles, points[i] + 0.05 * normals[i], directions[weight > 0.0])
        cast.append(np.sum(weight[weight > 0.0] * open_sky) / np.sum(weight))
    assert np.ptp(cast) > 0.5  # the sample holds open skin and hidden creases
    np.testing.assert_allclose(baked[sample], cast, atol=0.1)
    assert np.mean(np.abs(baked[sample] - cast)) < 0.03


# 7. Soft shadows.


def disc_light_profile_width(diameter: float) -> float:
    """The 10-90 % width of the lit fraction behind a straight edge under a disc of ``diameter`` (mm): the disc's
    area beyond a chord at s radii from its centre, f(s) = 1 - (acos s - s sqrt(1 - s^2)) / pi."""
    lit = lambda s, level: 1.0 - (np.arccos(s) - s * np.sqrt(1.0 - s * s)) / np.pi - level  # noqa: E731
    return diameter / 2.0 * (optimize.brentq(lit, -1.0, 1.0, (0.9,)) - optimize.brentq(lit, -1.0, 1.0, (0.1,)))


def edge_profile(angle_deg: float, scale: int = 2, gap: float = 10.0,
                 size: int = 512) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The lit fraction across the shadow's edge on a floor (albedo 0.8) under a half-plane card ``gap`` mm above it
    (its edge at x = 0), light straight down, soft shadows computed in blocks of ``scale`` pixels from a shadow map of
    ``size`` texels a side; the camera looks down from just below the card (its near plane clips the card away).
    Returns x (mm) of the columns, the rows' mean lit fraction per column, and the image."""
    width, height, half = 128, 16, 16.0
    camera = OrthographicCamera(half_height=half * height / width, eye=(0.0, 0.0, gap - 0.5), near=1.0, far=50.0)
    model = np.eye(4)
    model[:3, 3] = (-20.0, 0.0, gap)
    card = Prop(meshes.card(40.0, 40.0), (0.5, 0.5, 0.5), model)
    light = DirectionalLight((0.0, 0.0, -1.0), (1.0, 1.0, 1.0), angle_deg=angle_deg)
    image = render_layers(
        Scene(
            mesh=meshes.card(60.0, 60.0),
            stack=ChannelStack((), (), (0.8,) * 3),
            camera=camera,
            lights=[light],
            resolution=(width, height),
            props=[card],
            shadow_map_size=size,
            soft_shadow_scale=scale,
        )
    )
    x = -half + (np.arange(width) + 0.5) * (2.0 * half / width)
    return x, image[..., 0].mean(axis=0) / 0.8, image


def transition(x: np.ndarray, lit: np.ndarray) -> float:
    """Width (mm) between where the (monotone envelope of the) lit fraction first reaches 10 % and 90 %."""
    envelope = np.maximum.accumulate(lit)
    return float(np.interp(0.9, envelope, x) - np.interp(0.1, envelope, x))


@pytest.mark.parametrize("scale", [1, 2])
def test_an_area_light_softens_the_shadow_edge_by_its_penumbra(scale):
    """Hard light: an edge within 3 pixels. A light of angular diameter theta: the lit fraction of its disc, of
    diameter D = g 2 tan(theta / 2) seen from the floor at the card's height, as the 10-90 % width of the edge;
    well beyond D / 2 from the edge the floor is in full light (as under the hard light) or full shadow; so whether
    the soft shadows are computed at every pixel or at half the resolution."""
    x, hard, hard_image = edge_profile(0.0)
    assert transition(x, hard) <= 3.0 * (x[1] - x[0])
    measured, expected = [], []
    for angle in (10.0, 20.0, 30.0):
        x, soft, soft_image = edge_profile(angle, scale)
        diameter = 10.0 * 2.0 * np.tan(np.radians(angle) / 2.0)
        far = np.abs(x) > diameter + 1.0  # well beyond the penumbra's D / 2 each side of the edge
        np.testing.assert_array_equal(soft_image[:, far & (x > 0)], hard_image[:, far & (x > 0)])
        np.testing.assert_array_equal(soft_image[:, far & (x < 0)], 0.0)
        measured.append(transition(x, soft))
        expected.append(disc_light_profile_width(diameter))
    assert measured[0] < measured[1] < measured[2]
    np.testing.assert_allclose(measured, expected, rtol=0.35)


def test_the_penumbra_is_the_lights_whatever_the_shadow_maps_size():
    """A card 30 mm above the floor under a light 20 degrees wide: a penumbra 10.6 mm wide, some 60 texels of a 2048
    map. Its 10-90 % width is the disc light's on a 512 and on a 2048 map alike: a finer map samples the same
    penumbra more finely, it does not narrow it."""
    diameter = 30.0 * 2.0 * np.tan(np.radians(20.0) / 2.0)
    widths = []
    for size in (512, 2048):
        x, soft, _ = edge_profile(20.0, 1, gap=30.0, size=size)
        widths.append(transition(x, soft))
    np.testing.assert_allclose(widths, disc_light_profile_width(diameter), rtol=0.3)
    assert abs(widths[1] - widths[0]) < 0.15 * widths[0]


def seen_past_sphere(oc: np.ndarray, radius: float, rays: np.ndarray, length: np.ndarray | float = np.inf
                     ) -> np.ndarray:  # fmt: skip
    """For points at ``oc`` (N x 3, mm, from the centre of a sphere of ``radius`` mm), the fraction of their ``rays``
    (unit vectors: (n, 3), the same for every point, or (N, n, 3)) that miss the sphere before ``length`` mm along
    them (a scalar or N x n), each ray tested against the sphere analytically."""
    b = oc @ rays.T if rays.ndim == 2 else np.einsum("pi,pri->pr", oc, rays)  # N x n: along each ray
    c = np.sum(oc * oc, axis=1)[:, None] - radius * radius
    near = -b - np.sqrt(np.maximum(b * b - c, 0.0))  # the first crossing's distance along the ray
    return 1.0 - np.mean((b * b > c) & (near > 0.0) & (near < length), axis=1)


def disc_spiral(n: int, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points spread evenly over a disc of ``radius`` (a Vogel spiral): their distances from the centre and
    angles."""
    k = np.arange(n) + 0.5
    return radius * np.sqrt(k / n), k * np.pi * (3.0 - np.sqrt(5.0))


def ray_cast_visibility(points: np.ndarray, centre: np.ndarray, radius: float, towards: np.ndarray,
                        angle_deg: float, n: int = 2048) -> np.ndarray:  # fmt: skip
    """The fraction of a directional light of angular diameter ``angle_deg`` (unit vector ``towards`` it) seen from
    each of ``points`` (N x 3, mm) past a sphere: ``n`` directions spread evenly over the light's disc (a Vogel
    spiral in the tangent plane, radius tan(angle / 2))."""
    u = np.cross(towards, (0.0, 1.0, 0.0) if abs(towards[1]) < 0.9 else (1.0, 0.0, 0.0))
    u /= np.linalg.norm(u)
    v = np.cross(towards, u)
    r, a = disc_spiral(n, np.tan(np.radians(angle_deg) / 2.0))
    rays = towards + r[:, None] * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * v)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    return np.concatenate([seen_past_sphere(points[start : start + 512] - centre, radius, rays)
                           for start in range(0, len(points), 512)])  # fmt: skip


def ray_cast_point_visibility(points: np.ndarray, centre: np.ndarray, radius: float, light: np.ndarray,
                              size: float, n: int = 2048) -> np.ndarray:  # fmt: skip
    """The fraction of a point light's disc of diameter ``size`` (mm) at ``light``, facing each of ``points`` (N x 3,
    mm), seen from it past a sphere: rays to ``n`` points spread evenly over the disc (a Vogel spiral)."""
    r, a = disc_spiral(n, 0.5 * size)
    seen = []
    for start in range(0, len(points), 256):
        chunk = points[start : start + 256]
        towards = light - chunk
        towards /= np.linalg.norm(towards, axis=1, keepdims=True)
        u = np.cross(towards, (0.0, 1.0, 0.0))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        v = np.cross(towards, u)
        spots = light + r[:, None, None] * (np.cos(a)[:, None, None] * u + np.sin(a)[:, None, None] * v)  # n, N, 3
        rays = np.swapaxes(spots, 0, 1) - chunk[:, None]
        length = np.linalg.norm(rays, axis=2)
        seen.append(seen_past_sphere(chunk - centre, radius, rays / length[..., None], length))
    return np.concatenate(seen)


#: The sphere over the floor of the soft-shadow tests: radius and height of its centre (mm), and half the width of
#: the floor the camera sees (mm).
BALL_RADIUS, BALL_HEIGHT, VIEW_HALF = 15.0, 35.0, 60.0


def floor_under_sphere(light, size: int, scale: int, res: int, floor: float = 300.0,
                       wall: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """A sphere 30 mm across floating 35 mm over a floor ``floor`` mm wide (with a wall behind: the scene as large as
    a backdrop makes it), lit by ``light``, a map of ``size`` texels, soft shadows in blocks of ``scale`` pixels, seen
    from above in ``res`` x ``res`` pixels: the floor's visibility (the render over the render without the sphere),
    each pixel's point on the floor (res^2 x 3, mm) and where the camera sees the floor past the sphere."""
    back = np.eye(4)
    back[:3, :3] = [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]
    back[:3, 3] = (0.0, 100.0, 100.0)
    walls = [Prop(meshes.card(300.0, 200.0), (0.5, 0.5, 0.5), back)] if wall else []
    ball = np.eye(4)
    ball[2, 3] = BALL_HEIGHT

    def render(props: list) -> np.ndarray:
        return render_layers(Scene(
            mesh=meshes.card(floor, floor), stack=ChannelStack((), (), (0.8,) * 3), resolution=(res, res),
            camera=OrthographicCamera(half_height=VIEW_HALF, eye=(0.0, 0.0, 150.0), near=1.0, far=400.0),
            lights=[light], shadow_map_size=size, props=[*props, *walls], soft_shadow_scale=scale,
        ))[..., 0]  # fmt: skip

    visibility = render([Prop(meshes.sphere(BALL_RADIUS), (0.5, 0.5, 0.5), ball)]) / render([])
    x = -VIEW_HALF + (np.arange(res) + 0.5) * (2.0 * VIEW_HALF / res)
    points = np.stack(np.broadcast_arrays(x[None, :], -x[:, None], 0.0), axis=-1).reshape(-1, 3)
    beside = (x[None, :] ** 2 + x[:, None] ** 2) > (BALL_RADIUS + 1.0) ** 2
    return visibility, points, beside


def sphere_over_floor(angle: float, size: int, scale: int, res: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`floor_under_sphere` (a wall behind) under a directional light ``angle`` degrees wide from 27 degrees
    off the vertical: the floor's visibility, the fraction of the light's disc seen past the sphere ray cast from
    each pixel's point, and where the camera sees the floor past the sphere."""
    travel = np.array([0.5, 0.0, -1.0]) / np.sqrt(1.25)
    light = DirectionalLight(tuple(travel), (1.0, 1.0, 1.0), angle_deg=angle)
    visibility, points, beside = floor_under_sphere(light, size, scale, res)
    truth = ray_cast_visibility(points, np.array([0.0, 0.0, BALL_HEIGHT]), BALL_RADIUS, -travel, angle)
    return visibility, truth.reshape(res, res), beside


def assert_agrees_with_ray_casting(visibility: np.ndarray, truth: np.ndarray, beside: np.ndarray,
                                   mean_error: float) -> None:  # fmt: skip
    """A shadow of some 300 pixels' worth whose whole occlusion (summed over the floor the camera sees past the
    sphere) agrees with ray casting within 5 %, its pixels within ``mean_error`` on average."""
    assert np.sum(1.0 - truth[beside]) > 300.0
    assert np.sum(1.0 - visibility[beside]) == pytest.approx(np.sum(1.0 - truth[beside]), rel=0.05)
    shadowed = beside & ((truth < 0.999) | (visibility < 0.999))
    assert np.mean(np.abs(visibility - truth)[shadowed]) < mean_error


@pytest.mark.parametrize(("angle", "size", "scale"),
                         [(10.0, 1024, 1), (10.0, 4096, 1), (30.0, 1024, 1), (30.0, 4096, 1), (10.0, 1024, 2),
                          (30.0, 1024, 2)])  # fmt: skip
def test_soft_shadows_agree_with_ray_casting_the_light(angle, size, scale):
    """The sphere over the floor (:func:`sphere_over_floor`), lights 10 and 30 degrees wide: the shadow's whole
    occlusion (summed over the floor the camera sees past the sphere) agrees with ray casting within 5 % on maps of
    1024 and 4096 texels, whether soft shadows are computed at every pixel or at half resolution, the pixels within
    0.1 on average: no penumbra narrowed by the map's size, no floor or wall shadowing itself."""
    assert_agrees_with_ray_casting(*sphere_over_floor(angle, size, scale, 96), mean_error=0.1)


@pytest.mark.parametrize(("size", "scale"), [(20.0, 1), (40.0, 1), (40.0, 2)])
def test_soft_shadows_of_a_point_light_agree_with_ray_casting_its_disc(size, scale):
    """The sphere over a floor 130 mm wide (:func:`floor_under_sphere`, no wall: the light must lie outside the
    scene), under a point light of diameter 20 or 40 mm, 200 mm up and 60 mm to the side (a perspective shadow map,
    penumbrae size (d_r - d_o) / d_o): the floor's visibility against the fraction of the light's disc (facing each
    floor point; 2,048 points spread over it) seen past the sphere, ray cast from each pixel's point. The whole
    occlusion agrees within 5 %, the pixels within 0.12 on average."""
    light = np.array([60.0, 0.0, 200.0])
    point_light = PointLight(tuple(light), (1.0, 1.0, 1.0), reference_distance_mm=200.0, size_mm=size)
    visibility, points, beside = floor_under_sphere(point_light, 2048, scale, 96, floor=130.0, wall=False)
    truth = ray_cast_point_visibility(points, np.array([0.0, 0.0, BALL_HEIGHT]), BALL_RADIUS, light, size)
    assert_agrees_with_ray_casting(visibility, truth.reshape(96, 96), beside, mean_error=0.12)


@pytest.mark.parametrize("scale", [1, 2])
def test_soft_shadows_are_as_smooth_as_the_light_casts_them(scale):
    """The sphere over the floor under a light 30 degrees wide, one sample a pixel: the penumbra's grain, the mean
    of |v - its 3 x 3 box mean| over the shadow, is at most twice that of the ray-cast visibility (which is smooth
    but for its curvature and 2,048 rays). The 16 taps of each disc, turned per pixel, left grain 4 (half
    resolution) to 40 (every pixel) times the light's before the soft-shadow pass's visibility was filtered along
    each surface (soft_shadow_filter.frag)."""
    visibility, truth, beside = sphere_over_floor(30.0, 1024, scale, 192)
    shadow = beside & ((truth < 0.999) | (visibility < 0.999))
    assert shadow.sum() > 3000

    def grain(v: np.ndarray) -> float:
        return float(np.mean(np.abs(v - ndimage.uniform_filter(v, 3, mode="nearest"))[shadow]))

    assert grain(visibility) <= 2.0 * grain(truth)


def test_the_soft_shadow_filter_keeps_the_penumbras_width(monkeypatch):
    """The card's edge over the floor under lights 10, 20 and 30 degrees wide, soft shadows at half resolution: with
    the filter along each surface (soft_shadow_filter.frag), the edge's 10-90 % width is within 5 % of its width
    without it (the filter reaching 0 texels), while the grain along the edge (the rows' spread about their mean
    profile) shrinks by more than 40 %."""
    import renderer.layers

    widths, grains, filtered = {}, {}, renderer.layers.SOFT_FILTER_RADIUS
    for radius in (0, filtered):
        monkeypatch.setattr(renderer.layers, "SOFT_FILTER_RADIUS", radius)
        for angle in (10.0, 20.0, 30.0):
            x, lit, image = edge_profile(angle, 2)
            widths[radius, angle] = transition(x, lit)
            grains[radius, angle] = float(np.mean(np.std(image[..., 0], axis=0)))
    for angle in (10.0, 20.0, 30.0):
        assert widths[filtered, angle] == pytest.approx(widths[0, angle], rel=0.05)
    assert grains[filtered, 30.0] < 0.6 * grains[0, 30.0]


@pytest.mark.parametrize("scale", [1, 2])
def test_a_wall_standing_on_a_floor_is_lit_to_its_foot_by_an_area_light(scale):
    """A wall 20 mm high standing on a floor, facing a light 20 degrees wide that comes from 37 degrees above the
    floor: nothing hides the light from any point of the wall, so the wall is lit as under the hard light down to its
    foot, within 2 % (the filtered lookups of lit taps there blend in a texel of the floor). The floor in front of
    the wall lies in front of the wall's plane as the shadow map sees it, and counted as a blocker: the wall's lowest
    2 mm went dark, to 0.7 of the light at its foot."""
    place = trimesh.transformations.rotation_matrix(np.radians(-90.0), (1.0, 0.0, 0.0))  # facing +y
    place[2, 3] = 10.0
    block = meshes.card(40.0, 20.0)
    camera = OrthographicCamera(half_height=14.0, eye=(0.0, 150.0, 40.0), target=(0.0, 0.0, 8.0), up=(0.0, 0.0, 1.0),
                                near=1.0, far=400.0)  # fmt: skip

    def render(angle: float) -> np.ndarray:
        light = DirectionalLight((0.0, -0.8, -0.6), (1.0, 1.0, 1.0), angle_deg=angle)
        return render_layers(Scene(
            mesh=meshes.card(200.0, 200.0), stack=ChannelStack((), (), (0.8,) * 3), camera=camera, lights=[light],
            resolution=(128, 128), shadow_map_size=2048, props=[Prop(block, (0.5, 0.5, 0.5), place)],
            soft_shadow_scale=scale,
        ))[..., 0]  # fmt: skip

    hard, soft = render(0.0), render(20.0)
    wall = np.isclose(hard, 0.5 * 0.8, atol=1e-4)  # the front wall, lit: albedo x cos, cos = 0.8
    rows = np.flatnonzero(wall.any(axis=1))
    assert wall.sum() > 2000 and rows[-1] - rows[0] > 60  # the wall, some 20 mm high, to its foot
    np.testing.assert_allclose(soft[wall], hard[wall], rtol=0.02)
    assert np.mean(soft[wall]) == pytest.approx(0.4, rel=1e-3)


@pytest.mark.parametrize("size", [1024, 4096])
def test_soft_shadows_of_the_head_over_a_sweep_agree_with_hard_shadows_averaged_over_the_light(size):
    """The bundled head over a studio sweep under a light 20 degrees wide: the visibility of every surface (the render
    over the render without shadows) against its mean over 32 hard-shadowed renders, the light turned to directions
    spread over its disc (a Vogel spiral), the accumulation a renderer does without any soft-shadow estimate. The
    whole occlusion agrees within 15 % (what the hard-edged terminator on the head and the floor's long shadow leave),
    the pixels within 0.03 on average. Before the soft shadows' discs were the map's and compared with the receiver's
    plane, the sweep and the head shadowed themselves: 4.2 times the occlusion, 0.16 on average."""
    head = load_mesh(ROOT / "recipes" / "head" / "head.obj")
    place = np.eye(4)
    place[:3, 3] = (0.0, head.bounds[0][1] - 40.0, head.bounds[0][2] - 150.0)
    sweep = Prop(meshes.sweep(1400.0, 700.0, 200.0, 900.0), (0.6, 0.6, 0.6), place)
    towards = np.array([0.5, 0.6, 0.8]) / np.sqrt(1.25)

    def render(direction: np.ndarray, angle: float, shadows: bool) -> np.ndarray:
        light = DirectionalLight(tuple(-direction), (1.0, 1.0, 1.0), angle_deg=angle, cast_shadows=shadows)
        return render_layers(Scene(
            mesh=head, stack=ChannelStack((), (), (0.8,) * 3), resolution=(128, 128), lights=[light], props=[sweep],
            camera=OrthographicCamera(half_height=260.0, eye=(-600.0, 150.0, 500.0), target=(0.0, -60.0, -60.0),
                                      far=3000.0),
            shadow_map_size=size, soft_shadow_scale=1,
        ))[..., 1]  # fmt: skip

    def visibility(direction: np.ndarray, angle: float) -> np.ndarray:
        return render(direction, angle, True) / np.maximum(render(direction, angle, False), 1e-6)

    u = np.cross(towards, (0.0, 1.0, 0.0))
    u /= np.linalg.norm(u)
    v = np.cross(towards, u)
    k = np.arange(32) + 0.5
    r, a = np.tan(np.radians(10.0)) * np.sqrt(k / 32), k * np.pi * (3.0 - np.sqrt(5.0))
    directions = towards + r[:, None] * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * v)
    averaged = np.mean([visibility(d / np.linalg.norm(d), 0.0) for d in directions], axis=0)
    soft = visibility(towards, 20.0)
    seen = render(towards, 0.0, False) > 1e-3
    assert np.sum(1.0 - averaged[seen]) > 500.0  # shadows of some 500 pixels' worth: the head's own and on the floor
    assert np.sum(1.0 - soft[seen]) == pytest.approx(np.sum(1.0 - averaged[seen]), rel=0.15)
    assert np.mean(np.abs(soft - averaged)[seen]) < 0.03


@pytest.mark.parametrize("size", [512, 2048])
def test_a_surface_at_an_angle_to_an_area_light_does_not_shadow_itself(size):
    """A card turned 50 degrees from a light 20 degrees wide, nothing else in the scene: nothing can shadow it, so
    every pixel is lit exactly as under the hard light (whose 3 x 3 taps lie within a texel). Its blocker search
    reaches some 60 texels, where the card's plane lies 1.2 texels nearer the light per texel away: compared with the
    depth at the disc's centre, those taps would count the card itself as a blocker."""
    card = meshes.card(40.0, 40.0)
    card.apply_transform(trimesh.transformations.rotation_matrix(np.radians(50.0), (1.0, 0.0, 0.0)))
    images = [render_layers(Scene(mesh=card, stack=ChannelStack((), (), (0.5, 0.5, 0.5)),
                                  camera=OrthographicCamera(half_height=16.0, eye=(0.0, 0.0, 80.0)),
                                  lights=[DirectionalLight((0.0, 0.0, -1.0), (1.0, 1.0, 1.0), angle_deg=angle)],
                                  resolution=(64, 64), shadow_map_size=size, soft_shadow_scale=1))[..., 0]
              for angle in (0.0, 20.0)]  # fmt: skip
    on_card = images[0] > 0.0
    assert on_card.mean() > 0.5
    np.testing.assert_array_equal(images[1][on_card], images[0][on_card])


def test_soft_shadows_at_half_resolution_do_not_leak_across_a_silhouette():
    """One mesh of two parallel cards 6 mm apart, the light (20 degrees wide) from the camera's side: the front card,
    turned about the view axis, shadows the back one right around its own outline, while nothing shadows the front
    card. Upsampled from half resolution, the front card's pixels stay exactly lit up to its silhouette (no shadow of
    the back card's texels leaks onto it) while the back card's pixels beside it are darker."""
    front = meshes.card(12.0, 8.0)
    front.apply_transform(trimesh.transformations.rotation_matrix(np.radians(23.0), (0.0, 0.0, 1.0)))
    front.apply_transform(trimesh.transformations.translation_matrix((0.0, 0.0, 6.0)))
    mesh = joined(front, meshes.card(30.0, 30.0))
    light = DirectionalLight((0.0, 0.0, -1.0), (1.0, 1.0, 1.0), angle_deg=20.0)
    image = render_layers(Scene(mesh=mesh, stack=ChannelStack((), (), (0.5, 0.5, 0.5)),
                                camera=OrthographicCamera(half_height=10.0, eye=(0.0, 0.0, 50.0)), lights=[light],
                                resolution=(80, 80), soft_shadow_scale=2))[..., 0]  # fmt: skip
    camera_x = (np.arange(80) + 0.5) / 80 * 20.0 - 10.0
    x, y = np.meshgrid(camera_x, -camera_x)
    turn = np.radians(-23.0)
    u, v = x * np.cos(turn) - y * np.sin(turn), x * np.sin(turn) + y * np.cos(turn)  # in the front card's frame
    on_front = (np.abs(u) < 6.0 - 0.2) & (np.abs(v) < 4.0 - 0.2)  # pixels wholly on the front card
    beside = ~on_front & (np.abs(u) < 6.0 + 0.6) & (np.abs(v) < 4.0 + 0.6) & ((np.abs(u) > 6.2) | (np.abs(v) > 4.2))
    np.testing.assert_array_equal(image[on_front], 0.5)  # lit, exactly: the light sees all of the front card
    assert image[beside].mean() < 0.45 and image[beside].min() < 0.4  # in the front card's penumbra


@pytest.mark.parametrize("scale", [0, 3, 1.5])
def test_soft_shadows_are_computed_per_pixel_or_at_half_resolution_only(scale):
    with pytest.raises(ValueError, match="blocks of 1 or 2 pixels"):
        scene(soft_shadow_scale=scale)


# 8. Backdrops.


def test_a_sweep_faces_the_camera_side_with_exact_unit_normals():
    radius, depth, height = 20.0, 50.0, 80.0
    sweep = meshes.sweep(100.0, depth, radius, height)
    p, n = np.asarray(sweep.vertices), np.asarray(sweep.vertex_normals)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    floor = np.isclose(p[:, 1], 0.0) & (p[:, 2] >= 0.0)
    wall = np.isclose(p[:, 2], -radius) & (p[:, 1] >= radius)
    cove = ~floor & ~wall
    assert floor.any() and wall.any() and cove.sum() > 10
    np.testing.assert_allclose(n[floor], np.broadcast_to([0.0, 1.0, 0.0], n[floor].shape), atol=1e-12)
    np.testing.assert_allclose(n[wall], np.broadcast_to([0.0, 0.0, 1.0], n[wall].shape), atol=1e-12)
    towards_centre = (np.array([0.0, radius, 0.0]) - p[cove] * [0.0, 1.0, 1.0]) / radius  # the cove's axis: y=R, z=0
    np.testing.assert_allclose(np.linalg.norm(towards_centre, axis=1), 1.0, atol=1e-9)  # the cove is that circle
    np.testing.assert_allclose(n[cove], towards_centre, atol=1e-9)
    assert p[:, 2].max() == pytest.approx(depth) and p[:, 1].max() == pytest.approx(height)
    corners = p[sweep.faces]
    winding = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    assert np.all(np.einsum("ij,ij->i", winding, n[sweep.faces].mean(axis=1)) > 0.0)  # front faces the camera side
    assert np.all(n @ [0.0, 1.0, 1.0] > 0.0)


def test_a_gradient_background_runs_from_top_to_bottom_by_smoothstep():
    top, bottom = np.array([0.9, 0.6, 0.3]), np.array([0.1, 0.2, 0.05])
    width, height = 40, 30
    camera = OrthographicCamera(half_height=20.0)
    image = render_layers(
        scene(
            camera=camera,
            resolution=(width, height),
            lights=[HEAD_ON],
            background=GradientBackground(tuple(top), tuple(bottom)),
        )
    )
    t = (np.arange(height) + 0.5) / height
    s = 3.0 * t**2 - 2.0 * t**3
    expected = top + (bottom - top) * s[:, None]
    for column in (0, 1, width - 1):  # the sphere covers the middle columns only
        np.testing.assert_allclose(image[:, column], expected, rtol=1e-6)
    assert np.abs(image[0, 0] - top).max() < 0.01 and np.abs(image[-1, 0] - bottom).max() < 0.01
    pixel = 2.0 * camera.half_height / height  # mm; the sphere itself, lit head-on, renders its normal's z
    x, y = (width // 2 + 0.5) * pixel - 0.5 * width * pixel, 0.5 * height * pixel - (height // 2 + 0.5) * pixel
    np.testing.assert_allclose(image[height // 2, width // 2], np.sqrt(1.0 - (x * x + y * y) / 100.0), rtol=1e-5)


def test_a_visible_environment_shows_behind_the_product_along_each_camera_ray():
    """A perspective camera off the axes; each pixel no surface covers shows the environment along its ray (a smooth
    environment written from the docstring's mapping), times the intensity."""
    shade = lambda d: 0.5 + 0.3 * d[..., 0] - 0.2 * d[..., 1] + 0.1 * d[..., 2]  # noqa: E731
    width, height, fov = 40, 30, 60.0
    camera = PerspectiveCamera(fov_y_deg=fov, eye=(30.0, 20.0, 100.0), near=1.0, far=1000.0)
    environment = Environment(environment_of(shade, 512), intensity=2.0, visible=True)
    image = render_layers(
        scene(mesh=meshes.sphere(3.0), camera=camera, resolution=(width, height), environment=environment)
    )
    forward = -np.asarray(camera.eye) / np.linalg.norm(camera.eye)
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    tan = np.tan(np.radians(fov) / 2.0)
    x = ((np.arange(width) + 0.5) / width * 2.0 - 1.0) * tan * width / height
    y = (1.0 - (np.arange(height) + 0.5) / height * 2.0) * tan
    xx, yy = np.meshgrid(x, y)
    rays = forward + xx[..., None] * right + yy[..., None] * up
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    expected = 2.0 * shade(rays)
    behind = np.abs(image[..., 0] - expected) < 1e-3
    assert behind.sum() >= width * height - 12  # all but the few pixels of the small sphere
    np.testing.assert_allclose(image[behind], np.repeat(expected[behind][:, None], 3, axis=1), atol=2e-4)


# 9. Normal maps.


def card_scene(normal_map: NormalMap | None, to_light=(0.0, 0.0, 1.0), stack: ChannelStack | None = None) -> Scene:
    light = DirectionalLight(tuple(-np.asarray(to_light, float)), (1.0, 1.0, 1.0), cast_shadows=False)
    return scene(
        mesh=CARD,
        stack=stack or ChannelStack((), (), (0.6,) * 3),
        lights=[light],
        resolution=(16, 16),
        normal_map=normal_map,
    )


def tilted(a: float, axis: int = 0, shape=(4, 4)) -> np.ndarray:
    normals = np.zeros((*shape, 3))
    normals[..., axis], normals[..., 2] = np.sin(a), np.cos(a)
    return normals


def test_a_flat_normal_map_changes_nothing():
    flat = np.zeros((4, 4, 3))
    flat[..., 2] = 1.0
    for to_light in ((0.0, 0.0, 1.0), (0.4, -0.3, 0.8)):
        plain = render_layers(card_scene(None, to_light))
        assert np.abs(render_layers(card_scene(NormalMap(flat), to_light)) - plain).max() <= 1e-6


def test_a_tilted_normal_map_tilts_the_lambert_term_along_u_and_v():
    a = np.radians(30.0)
    plain = render_layers(card_scene(None))[8, 8]
    np.testing.assert_allclose(render_layers(card_scene(NormalMap(tilted(a))))[8, 8], plain * np.cos(a), rtol=1e-5)
    # x is +u (= +x here) and y is +v (= +y): a light along the tilted normal renders as head-on, one mirrored
    # across the card's normal at cos(2 a).
    for axis in (0, 1):
        towards = np.zeros(3)
        towards[axis], towards[2] = np.sin(a), np.cos(a)
        mirrored = towards * [-1.0, -1.0, 1.0]
        normal_map = NormalMap(tilted(a, axis))
        np.testing.assert_allclose(render_layers(card_scene(normal_map, towards))[8, 8], plain, rtol=1e-5)
        np.testing.assert_allclose(
            render_layers(card_scene(normal_map, mirrored))[8, 8], plain * np.cos(2 * a), rtol=1e-5
        )


def test_a_normal_map_is_read_with_row_zero_at_the_top():
    a = np.radians(40.0)
    normals = tilted(a, shape=(8, 8))
    normals[4:] = (0.0, 0.0, 1.0)  # the bottom half (v < 1/2) flat
    image = render_layers(card_scene(NormalMap(normals)))
    plain = render_layers(card_scene(None))
    np.testing.assert_allclose(image[1, 8], plain[1, 8] * np.cos(a), rtol=1e-5)  # near the top: tilted
    np.testing.assert_allclose(image[14, 8], plain[14, 8], rtol=1e-5)  # near the bottom: flat


@pytest.mark.parametrize("thickness_mm", [0.005, 0.01, 0.02])
def test_a_film_fills_the_detail_by_its_thickness(thickness_mm):
    """The film's own reflectance cancels in the ratio of renders with and without the map."""
    a, fill = np.radians(35.0), 0.01
    table = LayerTable(np.array([0.0, 0.03]), np.array([[0.0] * 3, [0.3, 0.25, 0.2]]), np.array([[1.0] * 3, [0.6] * 3]))
    stack = ChannelStack((table,), (thickness_mm,), (0.6, 0.5, 0.4))
    k = np.exp(-thickness_mm / fill)
    expected = np.cos(a) / np.sqrt(k**2 * np.sin(a) ** 2 + np.cos(a) ** 2)
    with_map = render_layers(card_scene(NormalMap(tilted(a), thickness_mm, fill), stack=stack))[8, 8]
    without = render_layers(card_scene(None, stack=stack))[8, 8]
    np.testing.assert_allclose(with_map / without, expected, rtol=1e-5)


# 10. Lobe cover.


def test_a_film_of_no_thickness_leaves_the_substrate_and_its_lobe_as_they_were():
    table = LayerTable(np.array([0.0, 0.02]), np.array([[0.0] * 3, [0.4, 0.3, 0.2]]), np.array([[1.0] * 3, [0.5] * 3]))
    substrate, lobe = (0.5, 0.4, 0.3), Specular(0.3, 1.4)
    light = DirectionalLight((-0.3, -0.2, -1.0), (1.0, 1.0, 1.0), cast_shadows=False)
    for environment in (None, uniform(0.6), Environment(studio_environment(64))):
        bare = scene(
            stack=ChannelStack((), (), substrate), lights=[light], substrate_lobe=lobe, environment=environment
        )
        filmed = dataclasses.replace(bare, stack=ChannelStack((table,), (0.0,), substrate), lobes=[Specular(0.1, 2.0)])
        np.testing.assert_array_equal(render_layers(filmed), render_layers(bare))


@pytest.mark.parametrize("cover", [0.25, 0.5, 2.0])
def test_a_thin_films_lobe_grows_with_its_cover(cover):
    """The top film's lobe at normal light and view adds clamp(x / LOBE_COVER_MM, 0, 1) pi f_spec E."""
    thickness = cover * LOBE_COVER_MM
    table = LayerTable(np.array([0.0, 0.02]), np.array([[0.0] * 3, [0.4, 0.3, 0.2]]), np.array([[1.0] * 3, [0.5] * 3]))
    lobe = Specular(0.3, 1.5)
    plain = scene(mesh=CARD, stack=ChannelStack((table,), (thickness,), (0.5,) * 3), lights=[HEAD_ON])
    added = render_layers(dataclasses.replace(plain, lobes=[lobe]))[24, 24] - render_layers(plain)[24, 24]
    f_spec = 1.0 / (np.pi * 0.3**2) * lobe.f0 / 4.0  # h = n = l = v: tan a = 0, F = F0, 1 / (2 (1 + 1))
    np.testing.assert_allclose(added, min(cover, 1.0) * np.pi * f_spec, rtol=1e-4)


# 11. Roughness maps.


def test_a_uniform_roughness_map_is_the_lobe_of_that_roughness():
    light = DirectionalLight((-0.3, -0.2, -1.0), (1.0, 1.0, 1.0), cast_shadows=False)
    for environment in (None, Environment(studio_environment(64))):
        base = scene(lights=[light], environment=environment, stack=ChannelStack((), (), (0.3,) * 3))
        for m in (0.1, 0.45):
            by_map = dataclasses.replace(
                base, substrate_lobe=Specular(1.0, 1.45), substrate_roughness=np.full((4, 4), m)
            )
            by_lobe = dataclasses.replace(base, substrate_lobe=Specular(m, 1.45))
            assert np.abs(render_layers(by_map) - render_layers(by_lobe)).max() <= 1e-5


def test_a_roughness_map_is_read_with_row_zero_at_the_top():
    roughness = np.full((8, 8), 0.6)
    roughness[:4] = 0.15  # top half
    base = scene(mesh=CARD, lights=[HEAD_ON], resolution=(16, 16), stack=ChannelStack((), (), (0.3,) * 3))
    image = render_layers(dataclasses.replace(base, substrate_lobe=Specular(1.0), substrate_roughness=roughness))
    for m, row in ((0.15, 1), (0.6, 14)):
        np.testing.assert_allclose(
            image[row, 8], render_layers(dataclasses.replace(base, substrate_lobe=Specular(m)))[row, 8], rtol=1e-5
        )


# 12. Environment on and off.


def studio_irradiance(normal: np.ndarray) -> float:
    """E / pi of the studio environment (grey channel 0) for a normal, summed over its pixels here: the sum of
    L max(n.w, 0) Omega / pi, Omega_r = (2 pi / cols) (cos theta_top - cos theta_bottom) of the pixel's row."""
    radiance = studio_environment()[..., 0]
    rows, cols = radiance.shape
    edges = np.linspace(0.0, np.pi, rows + 1)
    solid = (2.0 * np.pi / cols) * (np.cos(edges[:-1]) - np.cos(edges[1:]))
    cosine = np.maximum(equirect_directions(cols, rows) @ normal, 0.0)
    return float(np.sum(radiance * cosine * solid[:, None]) / np.pi)


def test_without_an_environment_the_frame_is_as_before_and_with_one_the_unlit_side_is_lit():
    side = DirectionalLight((-1.0, 0.0, -0.2), (1.0, 1.0, 1.0))  # lights the sphere's +x side
    stack = ChannelStack((), (), (1.0,) * 3)
    before = Scene(mesh=SPHERE, stack=stack, camera=CAMERA, lights=[side], resolution=(SIZE, SIZE))
    off = dataclasses.replace(before, environment=None, occlusion=None, normal_map=None, substrate_roughness=None)
    plain = render_layers(before)
    np.testing.assert_array_equal(render_layers(off), plain)
    studio = render_layers(dataclasses.replace(before, environment=Environment(studio_environment())))
    unlit = (plain.sum(axis=-1) == 0.0) & covered(render_layers(dataclasses.replace(before, background=BACKGROUND)))
    assert unlit.sum() > 0.2 * SIZE * SIZE
    assert studio[unlit].min() > 0.05
    assert np.all(studio >= plain)  # the environment only adds light
    # Where the light does not reach, the white sphere shows the studio's irradiance over pi along its normal.
    pixel = 2.0 * CAMERA.half_height / SIZE
    for row, column in ((24, 6), (10, 12), (38, 12), (24, 14)):
        assert unlit[row, column]
        x, y = (column + 0.5) * pixel - CAMERA.half_height, CAMERA.half_height - (row + 0.5) * pixel
        normal = np.array([x, y, np.sqrt(100.0 - x * x - y * y)]) / 10.0
        assert studio[row, column, 0] == pytest.approx(studio_irradiance(normal), rel=0.03), (row, column)


def test_the_soft_shadow_code_is_compiled_only_into_the_program_that_needs_it():
    """``defines`` reach the shaders: the percentage-closer soft shadows (the only code that reads the shadow maps'
    raw depths and frusta) are compiled into the soft-shadow pass, whether it computes them at every pixel or at half
    resolution, never into the shading program, and nowhere without an area light (the PCSS code costs on llvmpipe
    even where no pixel takes it)."""
    from renderer import context
    from renderer.context import GL
    from renderer.program import Program

    counts = {"LAYER_COUNT": 1, "GROUP_COUNT": 1, "LIGHT_COUNT": 1, "SAMPLES": 1, "SHADOW_LIGHTS": 1}
    off = ("PRECOMPOSED", "SUBSTRATE_MAP", "ROUGHNESS_MAP", "ENVIRONMENT", "FLOOR", "ORTHOGRAPHIC", "SKIN_SPLIT",
           "THICKNESS_MAPS", "LOBES", "POINT_LIGHTS")  # fmt: skip
    switches = {**counts, **dict.fromkeys(off, 0)}
    found = {}
    with context.lock:
        context.make_current(8, 8)
        for shader in ("km_layers.frag", "light_visibility.frag"):
            for soft, scale in ((0, 1), (1, 1), (1, 2)):
                program = Program("fullscreen.vert", shader,
                                  defines={**switches, "SOFT_LIGHTS": soft, "SOFT_SHADOW_SCALE": scale})  # fmt: skip
                try:
                    found[shader, soft, scale] = GL.glGetUniformLocation(program.handle, "u_shadow_range") >= 0
                finally:
                    program.release()
    assert found == {
        ("km_layers.frag", 0, 1): False, ("km_layers.frag", 1, 1): False, ("km_layers.frag", 1, 2): False,
        ("light_visibility.frag", 0, 1): False, ("light_visibility.frag", 1, 1): True,
        ("light_visibility.frag", 1, 2): True,
    }  # fmt: skip
