"""What stands and shines around the product in a render (:mod:`kmpipe.formats.scene_lighting`): the ground or the
backdrop, the bundled head's eyes, the environment light and the ambient occlusion that darkens it, the mesh's fine
detail (its normal map, smoothed under the films).

Sizes are in radii r of the product's bounding sphere (as placed, :func:`kmpipe.stages.render_plan.placed_bounds`):
the ground is a square of :data:`~kmpipe.stages.render_plan.GROUND_EXTENT` r each way from the product's centre; a
sweep (:func:`renderer.meshes.sweep`) is :data:`SWEEP_SIZE` wide and deep, its cove starting 1.2 r behind the
product's centre, turned to face the camera's azimuth (it stands still while the turntable turns the product).
"""

from __future__ import annotations

import functools
import hashlib
import math

import cv2
import numpy as np

from kmpipe.formats.manifest import parse_thickness_mm
from kmpipe.formats.scene import HEAD_DIR, Scene
from kmpipe.formats.scene_lighting import FLOOR_EXTENT, GRADIENT, SWEEP_REFLECTANCE
from kmpipe.stages.render_plan import GROUND_EXTENT, placed_bounds
from renderer.environment import Environment
from renderer.meshes import card, sweep
from renderer.occlusion import FloorOcclusion, vertex_occlusion
from renderer.occlusion import floor_occlusion as bake_floor
from renderer.products import load_mesh
from renderer.scene import GradientBackground, NormalMap, Prop

#: A sweep in radii of the product: (width, floor depth in front of the product's centre, gap behind it to the cove,
#: cove radius, wall height above the floor).
SWEEP_SIZE = (12.0, 5.0, 1.2, 2.0, 8.0)
#: Height above the floor, in radii of the product, over which a sweep's occlusion fades to 1 as its cove rises.
FLOOR_FADE = 0.25
#: The bundled head's eyes: (file in kmpipe.formats.scene.HEAD_DIR, linear-RGB Lambert albedo), drawn as props.
EYES = (("eyes_sclera.obj", (0.62, 0.58, 0.54)), ("eyes_iris.obj", (0.11, 0.06, 0.03)),
        ("eyes_pupil.obj", (0.01, 0.01, 0.01)))  # fmt: skip


def floor_prop(scene: Scene) -> Prop | None:
    """The ground (a square card) or the backdrop's sweep under and behind the product, or None."""
    centre, radius, bottom = placed_bounds(scene)
    backdrop = scene.info.backdrop
    if scene.info.ground is not None:
        side = 2.0 * GROUND_EXTENT * radius
        model = np.eye(4)
        model[1:3, 1:3] = [[0.0, 1.0], [-1.0, 0.0]]  # the card's +z normal turned to +y
        model[:3, 3] = (centre[0], bottom, centre[2])
        return Prop(card(side, side), (scene.info.ground.reflectance,) * 3, model)
    if backdrop is None or backdrop.kind != "sweep":
        return None
    width, depth, gap, cove, height = (radius * f for f in SWEEP_SIZE)
    mesh = sweep(width, depth + gap, cove, height, n_across=1)  # flat across: one column of quads
    azimuth = math.radians(scene.info.camera.azimuth_deg)
    c, s = math.cos(azimuth), math.sin(azimuth)
    model = np.eye(4)
    model[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]  # its +z turned towards the camera
    model[:3, 3] = np.array([centre[0], bottom, centre[2]]) - gap * model[:3, 2]
    reflectance = SWEEP_REFLECTANCE if backdrop.reflectance is None else backdrop.reflectance
    return Prop(mesh, (reflectance,) * 3, model)


def background(scene: Scene) -> tuple[float, float, float] | GradientBackground:
    """Black, or the backdrop's gradient (its colours, or :data:`~kmpipe.formats.scene_lighting.GRADIENT`)."""
    backdrop = scene.info.backdrop
    if backdrop is None or backdrop.kind != "gradient":
        return (0.0, 0.0, 0.0)
    return GradientBackground(backdrop.top or GRADIENT[0], backdrop.bottom or GRADIENT[1])


def environment(scene: Scene) -> Environment | None:
    """The scene's environment light, or None."""
    info = scene.info.environment
    if info is None:
        return None
    return Environment(scene.environment, info.rotation_deg, info.intensity, info.visible)


@functools.cache
def _eye_meshes() -> tuple:
    """The bundled head's eye meshes, read once per process (every turntable angle and the AO bake share them)."""
    return tuple(load_mesh(HEAD_DIR / name) for name, _ in EYES)


def eyes(scene: Scene, model: np.ndarray) -> tuple[Prop, ...]:
    """The bundled head's eyes (sclera, iris, pupil) turned with it by ``model``; none on any other mesh."""
    if scene.info.scene.mesh != "head":
        return ()
    return tuple(Prop(mesh, albedo, model) for mesh, (_, albedo) in zip(_eye_meshes(), EYES, strict=True))


#: Bakes kept per process (:func:`occlusion`, :func:`floor_occlusion`), the oldest dropped first.
KEPT_BAKES = 8
_bakes: dict[bytes, object] = {}


def _kept(meshes, settings: tuple, bake):
    """``bake()``, kept per process for meshes of the same vertices, normals and faces and the same ``settings``."""
    digest = hashlib.sha1(repr(settings).encode(), usedforsecurity=False)
    for mesh in meshes:
        for values in (mesh.vertices, mesh.vertex_normals, mesh.faces):
            digest.update(np.ascontiguousarray(values).tobytes())
    key = digest.digest()
    if key not in _bakes:
        while len(_bakes) >= KEPT_BAKES:
            _bakes.pop(next(iter(_bakes)))
        _bakes[key] = bake()
    return _bakes[key]


def _frozen(values: np.ndarray) -> np.ndarray:
    values.setflags(write=False)
    return values


def occlusion(scene: Scene) -> np.ndarray:
    """Ambient occlusion per vertex of the scene's mesh (:func:`renderer.occlusion.vertex_occlusion`), occluded by
    itself and what turns with it (the bundled head's eyes), times a mesh file's own occlusion map at each vertex's
    uv (bilinear). The bake is in the mesh's own frame: it is kept per process for meshes of the same vertices,
    normals and faces (every row of a shade review, every product of a line on the bundled head)."""
    others = [prop.mesh for prop in eyes(scene, np.eye(4))]
    baked = _kept([scene.mesh, *others], ("mesh",), lambda: _frozen(vertex_occlusion(scene.mesh, others)))
    if scene.occlusion_map is None:
        return baked
    return baked * np.clip(at_uv(scene.occlusion_map, np.asarray(scene.mesh.visual.uv)), 0.0, 1.0)


def floor_occlusion(scene: Scene) -> FloorOcclusion | None:
    """The ambient occlusion of the floor (the scene's ground or sweep, :func:`floor_prop`) by the unturned product
    and its eyes, within :data:`~kmpipe.formats.scene_lighting.FLOOR_EXTENT` radii of its centre; None without an
    environment light (the only light it darkens). Kept per process for products placed alike (every render task of
    a line's products of one mesh)."""
    if scene.info.environment is None:
        return None
    centre, radius, bottom = placed_bounds(scene)
    floor = (bottom, (float(centre[0]), float(centre[2])), FLOOR_EXTENT * radius, FLOOR_FADE * radius)
    others = [prop.mesh for prop in eyes(scene, np.eye(4))]

    def bake() -> FloorOcclusion:  # the meshes placed only when a bake is needed
        placed = [mesh.copy().apply_transform(scene.model) for mesh in (scene.mesh, *others)]
        baked = bake_floor(placed, *floor)
        _frozen(baked.values)
        return baked

    return _kept([scene.mesh, *others], ("floor", scene.model.tobytes(), *floor), bake)


def turned_floor(scene: Scene, floor: Prop, baked: FloorOcclusion, model: np.ndarray) -> Prop:
    """The floor prop of a frame whose product stands at ``model`` (its turntable matrix), each pixel of it taking the
    baked occlusion at its place relative to the product unturned: model_0 model^-1 applied to it."""
    unturn = scene.model @ np.linalg.inv(model)
    return Prop(floor.mesh, floor.albedo, floor.model, floor_occlusion=baked, floor_frame=unturn)


def at_uv(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples (n,) of a 2-D map (rows, columns; row 0 at v = 1) at texture coordinates ``uv`` (n, 2)."""
    rows, columns = image.shape
    x = np.clip(uv[:, 0] * columns - 0.5, 0.0, columns - 1.0)
    y = np.clip((1.0 - uv[:, 1]) * rows - 0.5, 0.0, rows - 1.0)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, columns - 1), np.minimum(y0 + 1, rows - 1)
    fx, fy = x - x0, y - y0
    top = image[y0, x0] * (1.0 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1.0 - fx) + image[y1, x1] * fx
    return top * (1.0 - fy) + bottom * fy


def normal_map(scene: Scene) -> NormalMap | None:
    """The scene's normal map with the films' total thickness over its grid (each thickness map resampled to it,
    bilinear) and its fill thickness, or None."""
    if scene.normal_map is None:
        return None
    rows, columns = scene.normal_map.shape[:2]
    total = 0.0  # a number while every film is uniform, else a map over the normal map's grid
    for thickness in scene.thicknesses_mm:
        value = np.asarray(thickness, dtype=float)
        if value.ndim == 2 and value.shape != (rows, columns):
            value = cv2.resize(value, (columns, rows), interpolation=cv2.INTER_LINEAR)
        total = total + value
    if isinstance(total, np.ndarray) and total.ndim == 2:
        total.setflags(write=False)  # the same for every frame: hashed once (renderer.texture_cache.frozen)
    fill = parse_thickness_mm(scene.info.base.normal_fill)
    return NormalMap(scene.normal_map, float(total) if np.ndim(total) == 0 else total, fill)
