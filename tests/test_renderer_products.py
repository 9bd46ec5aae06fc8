"""Procedural product meshes and mesh loading: closed solids with the analytic volume, the bounding box the parameters
ask for, unit outward normals, uv in [0, 1], and a round trip through OBJ, PLY and GLB files.

Analytic volumes (mm^3): the compact pan is a cylinder minus the powder recess, pi R^2 depth - pi (R - rim)^2 recess;
the lipstick bullet is the cylinder under the bevel plane, pi r^2 z_c (a plane over a disc averages to its height on
the axis), minus the rounded edge, 2 pi b^2 ((r - b)(1 - pi / 4) + b / 6) for a quarter-circle drop of radius b.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from lambert import lambert

from renderer import products
from renderer.scene import DirectionalLight, OrthographicCamera

BULLETS = [
    {},  # the defaults: 12 mm x 20 mm, 50 degree bevel
    {"diameter": 10.0, "length": 25.0, "bevel_angle_deg": 35.0, "segments": 48},
    {"diameter": 8.0, "length": 12.0, "bevel_angle_deg": 0.0, "tip_radius": 0.5},
    {"diameter": 14.0, "length": 30.0, "bevel_angle_deg": 60.0, "tip_radius": 2.0, "segments": 96},
]
COMPACTS = [
    {},  # the defaults: 56 mm x 4 mm, 2 mm rim
    {"diameter": 30.0, "depth": 6.0, "rim": 1.0, "segments": 64, "recess": 1.5},
]


def welded(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The mesh with vertices merged by position (seams and sharp edges joined), for topology checks."""
    return trimesh.Trimesh(mesh.vertices, mesh.faces)


def bullet_volume(diameter=12.0, length=20.0, bevel_angle_deg=50.0, tip_radius=1.0, **_) -> float:
    """Volume (mm^3) of the smooth bullet, computed here independently of the module's own helper."""
    r, b, t = diameter / 2.0, tip_radius, np.tan(np.radians(bevel_angle_deg))
    # the top peaks on +x where the quarter circle's slope tan(phi) equals the bevel's slope t
    phi = np.arctan(t)
    z_c = length - t * (r - b + b * np.sin(phi)) + b * (1.0 - np.cos(phi))
    return np.pi * r**2 * z_c - 2.0 * np.pi * b**2 * ((r - b) * (1.0 - np.pi / 4.0) + b / 6.0)


def compact_volume(diameter=56.0, depth=4.0, rim=2.0, recess=0.5, **_) -> float:
    """Volume (mm^3) of the compact pan."""
    radius = diameter / 2.0
    return np.pi * radius**2 * depth - np.pi * (radius - rim) ** 2 * recess


def check_surface(mesh: trimesh.Trimesh, outward_fraction: float) -> None:
    """Closed, consistently wound, positive volume; unit normals that agree with the winding and point away from
    the centroid for at least ``outward_fraction`` of the faces; uv for every vertex, in [0, 1]."""
    solid = welded(mesh)
    assert solid.is_watertight
    assert solid.is_winding_consistent
    assert solid.volume > 0.0
    normals = np.asarray(mesh.vertex_normals)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    # the stored (exact) normals of each face's corners lean the same way as the face's winding
    agreement = np.einsum("ij,ij->i", mesh.face_normals, normals[mesh.faces].mean(axis=1))
    assert np.all(agreement > 0.5)
    away = np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles_center - solid.center_mass)
    assert np.mean(away > 0.0) >= outward_fraction
    uv = np.asarray(mesh.visual.uv)
    assert uv.shape == (len(mesh.vertices), 2)
    assert uv.min() >= 0.0 and uv.max() <= 1.0


@pytest.mark.parametrize("params", BULLETS)
def test_lipstick_bullet_is_a_closed_solid_with_outward_normals(params):
    check_surface(products.lipstick_bullet(**params), outward_fraction=1.0)


@pytest.mark.parametrize("params", BULLETS)
def test_lipstick_bullet_volume_and_bounds_match_the_parameters(params):
    mesh = products.lipstick_bullet(**params)
    diameter, length = params.get("diameter", 12.0), params.get("length", 20.0)
    assert welded(mesh).volume == pytest.approx(bullet_volume(**params), rel=0.02)
    assert products.lipstick_bullet_volume(
        diameter, length, params.get("bevel_angle_deg", 50.0), params.get("tip_radius", 1.0)
    ) == pytest.approx(bullet_volume(**params), rel=1e-12)
    np.testing.assert_allclose(
        mesh.bounds, [[-diameter / 2, -diameter / 2, 0.0], [diameter / 2, diameter / 2, length]], atol=1e-9
    )


def test_lipstick_bullet_volume_converges_to_the_analytic_one():
    fine = products.lipstick_bullet(segments=512, rings=64)
    assert welded(fine).volume == pytest.approx(bullet_volume(), rel=1e-4)


def test_lipstick_bullet_bevel_is_slanted_at_the_bevel_angle_and_meets_the_wall_tangentially():
    angle = 40.0
    mesh = products.lipstick_bullet(bevel_angle_deg=angle, tip_radius=1.0)
    bevel = mesh.metadata["parts"]["bevel"]
    normals = np.asarray(mesh.vertex_normals)[np.unique(mesh.faces[bevel])]
    vertices = mesh.vertices[np.unique(mesh.faces[bevel])]
    # the flat part of the bevel (inside r - tip_radius) rises towards +x, so its normal leans towards -x
    flat = np.hypot(vertices[:, 0], vertices[:, 1]) < 5.0 - 1e-9
    assert flat.sum() > 64
    expected = [-np.sin(np.radians(angle)), 0.0, np.cos(np.radians(angle))]
    np.testing.assert_allclose(normals[flat], np.broadcast_to(expected, (flat.sum(), 3)), atol=1e-12)
    slope = np.linalg.lstsq(np.c_[vertices[flat, :2], np.ones(flat.sum())], vertices[flat, 2], rcond=None)[0]
    np.testing.assert_allclose(slope[:2], [np.tan(np.radians(angle)), 0.0], atol=1e-12)
    # where the bevel meets the wall its normals are horizontal (the rounding turns vertical there)
    rim = np.isclose(np.hypot(vertices[:, 0], vertices[:, 1]), 6.0)
    assert rim.sum() == 64
    np.testing.assert_allclose(normals[rim, 2], 0.0, atol=1e-12)


def test_lipstick_bullet_rejects_a_bevel_too_steep_for_its_length():
    with pytest.raises(ValueError, match="length"):
        products.lipstick_bullet(diameter=12.0, length=10.0, bevel_angle_deg=60.0)


@pytest.mark.parametrize("params", COMPACTS)
def test_compact_pan_is_a_closed_solid_with_outward_normals(params):
    # the inner wall of the recess faces the axis, so it is the one part that faces the centroid
    mesh = products.compact_pan(**params)
    check_surface(mesh, outward_fraction=0.75)
    inner = mesh.metadata["parts"]["inner_wall"]
    radial = mesh.triangles_center[inner] * [1.0, 1.0, 0.0]
    assert np.all(np.einsum("ij,ij->i", mesh.face_normals[inner], radial) < 0.0)


@pytest.mark.parametrize("params", COMPACTS)
def test_compact_pan_volume_and_bounds_match_the_parameters(params):
    mesh = products.compact_pan(**params)
    radius, depth = params.get("diameter", 56.0) / 2.0, params.get("depth", 4.0)
    assert welded(mesh).volume == pytest.approx(compact_volume(**params), rel=0.02)
    np.testing.assert_allclose(mesh.bounds, [[-radius, -radius, 0.0], [radius, radius, depth]], atol=1e-9)


@pytest.mark.parametrize("params", COMPACTS)
def test_compact_powder_top_is_a_flat_disc_whose_uv_spans_the_unit_square(params):
    mesh = products.compact_pan(**params)
    powder = np.unique(mesh.faces[mesh.metadata["parts"]["powder"]])
    radius = params.get("diameter", 56.0) / 2.0 - params.get("rim", 2.0)
    xyz, uv = mesh.vertices[powder], np.asarray(mesh.visual.uv)[powder]
    np.testing.assert_allclose(xyz[:, 2], params.get("depth", 4.0) - params.get("recess", 0.5))
    np.testing.assert_allclose(np.asarray(mesh.vertex_normals)[powder], np.broadcast_to([0.0, 0.0, 1.0], xyz.shape))
    assert np.hypot(xyz[:, 0], xyz[:, 1]).max() == pytest.approx(radius)
    # planar mapping: uv is affine in (x, y) and the disc's extremes reach 0 and 1 on both axes
    np.testing.assert_allclose(uv, 0.5 + 0.5 * xyz[:, :2] / radius, atol=1e-12)
    np.testing.assert_allclose(uv.min(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(uv.max(axis=0), 1.0, atol=1e-12)
    # the powder faces cover the whole disc (the polygon inscribed in it)
    segments = params.get("segments", 96)
    area = mesh.area_faces[mesh.metadata["parts"]["powder"]].sum()
    assert area == pytest.approx(0.5 * segments * radius**2 * np.sin(2.0 * np.pi / segments), rel=1e-9)


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".glb"])
@pytest.mark.parametrize("make", [products.lipstick_bullet, products.compact_pan])
def test_load_mesh_round_trips_exported_meshes(tmp_path, make, suffix):
    mesh = make()
    path = tmp_path / f"product{suffix}"
    mesh.export(path)
    loaded = products.load_mesh(path)
    assert isinstance(loaded, trimesh.Trimesh)
    assert len(loaded.vertices) == len(mesh.vertices)
    assert len(loaded.faces) == len(mesh.faces)
    # PLY and GLB store float32 coordinates, hence the relative tolerance
    assert loaded.area == pytest.approx(mesh.area, rel=1e-6)
    assert loaded.volume == pytest.approx(mesh.volume, rel=1e-6)
    np.testing.assert_allclose(np.linalg.norm(loaded.vertex_normals, axis=1), 1.0, atol=1e-6)
    assert np.asarray(loaded.visual.uv).shape == (len(loaded.vertices), 2)


def test_load_mesh_computes_normals_when_the_file_has_none(tmp_path):
    box = trimesh.creation.box(extents=(2.0, 3.0, 4.0))
    path = tmp_path / "box.ply"
    path.write_bytes(trimesh.exchange.ply.export_ply(box, vertex_normal=False))
    loaded = products.load_mesh(path)
    assert loaded.volume == pytest.approx(24.0)
    normals = np.asarray(loaded.vertex_normals)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)
    assert np.all(np.einsum("ij,ij->i", normals, loaded.vertices - loaded.center_mass) > 0.0)


@pytest.mark.parametrize(
    ("name", "content"),
    [
        ("empty.obj", b""),
        ("empty.ply", b""),
        ("empty.glb", b""),
        ("garbage.ply", b"\x00\xffnot a mesh at all\x01" * 20),
        ("garbage.glb", b"glTF\x02\x00\x00\x00garbage"),
        ("garbage.gltf", b"{ this is not json"),
        ("points.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"),
        ("notes.txt", b"v 0 0 0\n"),
    ],
)
def test_load_mesh_rejects_unreadable_files_naming_them(tmp_path, name, content):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(ValueError, match=name.replace(".", r"\.")):
        products.load_mesh(path)


def test_load_mesh_rejects_a_missing_file_naming_it(tmp_path):
    with pytest.raises(ValueError, match=r"absent\.obj"):
        products.load_mesh(tmp_path / "absent.obj")


def test_compact_pan_renders_head_on_as_a_disc_of_its_radius():
    radiance, albedo, size, half = np.array([2.0, 3.0, 0.5]), np.array([0.5, 0.25, 0.8]), 121, 30.0
    image = lambert(
        products.compact_pan(),
        OrthographicCamera(half_height=half),
        DirectionalLight(direction=(0.0, 0.0, -1.0), radiance=tuple(radiance), cast_shadows=False),
        tuple(albedo),
        size,
        size,
        background=(-1.0, -1.0, -1.0),
    )
    mask = np.any(image != np.float32(-1.0), axis=-1)
    measured_radius_mm = np.sqrt(mask.sum() / np.pi) * (2.0 * half / size)
    assert measured_radius_mm == pytest.approx(28.0, rel=1e-2)
    rows, columns = np.nonzero(mask)
    assert rows.mean() == pytest.approx((size - 1) / 2.0, abs=0.5)
    assert columns.mean() == pytest.approx((size - 1) / 2.0, abs=0.5)
    # seen head-on, only the powder and the rim show, both facing the light
    np.testing.assert_allclose(image[mask], np.broadcast_to(albedo * radiance, (mask.sum(), 3)), rtol=1e-5)
