"""Scene description as plain data, with no GL: cameras, lights, props, skin scattering, and the :class:`Scene` that
holds one frame's worth of them for the passes (:func:`renderer.layers.render_layers`,
:func:`renderer.skin.render_skin`), as pyrender hands its Scene to its renderer.

Positions and lengths are in scene units (mm); directions are world-space vectors (normalised on use). Matrices are
row-major numpy (4, 4) arrays acting on column vectors, in the OpenGL clip-space convention (NDC z in [-1, 1]).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import trimesh

from renderer.stack import ChannelStack, Precomposed, Specular

Vec3 = tuple[float, float, float]
#: Most lights in one scene (as ``shaders/km_layers.frag`` defines it).
MAX_LIGHTS = 4


def _unit(vector: Vec3 | np.ndarray, what: str) -> np.ndarray:
    v = np.asarray(vector, dtype=float).reshape(3)
    length = np.linalg.norm(v)
    if not length > 0.0:
        raise ValueError(f"{what} must be a non-zero vector, got {tuple(v)}")
    return v / length


def look_at(eye: Vec3, target: Vec3, up: Vec3) -> np.ndarray:
    """The world -> camera (view) matrix for a camera at ``eye`` (mm) looking at ``target`` (mm).

    The camera looks down its -z axis with +y as close to ``up`` as the view direction allows.
    """
    forward = _unit(np.subtract(target, eye), "target - eye")
    right = np.cross(forward, _unit(up, "up"))
    right = _unit(right, "up x view direction (up is parallel to the view direction)")
    true_up = np.cross(right, forward)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = right, true_up, -forward
    view[:3, 3] = -view[:3, :3] @ np.asarray(eye, dtype=float)
    return view


@dataclass(frozen=True, kw_only=True)
class _Pose:
    """Where a camera is (mm) and where it looks; ``near`` and ``far`` are distances (mm) along the view direction."""

    eye: Vec3 = (0.0, 0.0, 100.0)
    target: Vec3 = (0.0, 0.0, 0.0)
    up: Vec3 = (0.0, 1.0, 0.0)
    near: float = 1.0
    far: float = 1000.0

    def view_matrix(self) -> np.ndarray:
        """World -> camera matrix (4, 4)."""
        return look_at(self.eye, self.target, self.up)


@dataclass(frozen=True)
class OrthographicCamera(_Pose):
    """A parallel projection: the image spans ``2 * half_height`` mm vertically, ``aspect`` times that horizontally.

    ``near`` and ``far`` are distances (mm) from ``eye`` along the view direction.
    """

    half_height: float

    def projection_matrix(self, aspect: float) -> np.ndarray:
        """Camera -> clip matrix (4, 4) for an image of ``aspect`` = width / height (pixels)."""
        top, right = self.half_height, self.half_height * aspect
        n, f = self.near, self.far
        return np.array(
            [
                [1.0 / right, 0.0, 0.0, 0.0],
                [0.0, 1.0 / top, 0.0, 0.0],
                [0.0, 0.0, -2.0 / (f - n), -(f + n) / (f - n)],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )


@dataclass(frozen=True)
class PerspectiveCamera(_Pose):
    """A pinhole camera with a vertical field of view ``fov_y_deg`` (degrees); ``near``/``far`` in mm (> 0)."""

    fov_y_deg: float

    def projection_matrix(self, aspect: float) -> np.ndarray:
        """Camera -> clip matrix (4, 4) for an image of ``aspect`` = width / height (pixels)."""
        focal = 1.0 / np.tan(np.radians(self.fov_y_deg) / 2.0)
        n, f = self.near, self.far
        return np.array(
            [
                [focal / aspect, 0.0, 0.0, 0.0],
                [0.0, focal, 0.0, 0.0],
                [0.0, 0.0, (f + n) / (n - f), 2.0 * f * n / (n - f)],
                [0.0, 0.0, -1.0, 0.0],
            ]
        )


Camera = OrthographicCamera | PerspectiveCamera


@dataclass(frozen=True)
class DirectionalLight:
    """A distant light travelling along ``direction`` (world space, from the light towards the scene).

    ``radiance`` is linear RGB and sets the scale of the render: a surface of albedo ``a`` at angle theta to the
    light renders as ``a * radiance * cos(theta)``. For a physical reflected radiance from an irradiance ``E``
    (W m^-2 at normal incidence), pass ``E / pi``.
    """

    direction: Vec3
    radiance: Vec3
    cast_shadows: bool = True

    def to_light(self) -> np.ndarray:
        """Unit vector (3,) from a surface towards the light."""
        return -_unit(self.direction, "the light direction")


@dataclass(frozen=True)
class PointLight:
    """An isotropic light at ``position`` (mm), falling off with the inverse square of the distance.

    ``radiance`` is linear RGB at ``reference_distance_mm``: a white Lambert surface facing the light from that
    distance renders as ``radiance``; at distance d it renders as ``radiance * (reference_distance_mm / d)^2 *
    cos(theta)``.
    """

    position: Vec3
    radiance: Vec3
    reference_distance_mm: float
    cast_shadows: bool = True

    def __post_init__(self) -> None:
        if not (np.all(np.isfinite(self.position)) and self.reference_distance_mm > 0.0):
            raise ValueError(
                f"a point light needs a finite position and a reference distance > 0 mm, got {self.position} "
                f"and {self.reference_distance_mm}"
            )


Light = DirectionalLight | PointLight


@dataclass(frozen=True)
class Prop:
    """A plain diffuse object beside the product (a floor, a stand): Lambert ``albedo`` (linear RGB in [0, 1]).

    It receives light and shadows and casts shadows; ``model`` is its object -> world matrix (identity if None).
    """

    mesh: trimesh.Trimesh
    albedo: tuple[float, float, float]
    model: np.ndarray | None = None


@dataclass(frozen=True)
class Scattering:
    """Parameters of the skin's subsurface blur (:mod:`renderer.skin`): thesis eq. 3.1 and thesis eq. 3.2 with the
    thesis's correction and clamp.

    ``alpha`` is the global level as a scale of the measured profile (1: its true size on screen; the thesis's 12 to
    40 are in its own scene units and resolution, which a renderer in mm cannot share); ``beta`` the correction for
    the depth gradient and ``gradient_clamp`` the largest gradient used (metres of depth per pixel).
    """

    alpha: float = 1.0
    beta: float = 800.0
    gradient_clamp: float = 0.001

    def __post_init__(self) -> None:
        if not (self.alpha > 0.0 and self.beta >= 0.0 and self.gradient_clamp >= 0.0):
            raise ValueError(
                f"scattering needs alpha > 0, beta >= 0 and gradient_clamp >= 0, got {self.alpha}, {self.beta}, "
                f"{self.gradient_clamp}"
            )


#: Most samples per pixel side (4: 16 samples a pixel).
MAX_SUPERSAMPLING = 4
#: Largest side (pixels) of a supersampled render: the GL framebuffers' limit here.
MAX_RENDER_SIDE = 8192


@dataclass(frozen=True, kw_only=True)
class Scene:
    """One frame to render: a mesh wearing a stack of films, its lights, camera and props, and the output size.

    Attributes
    ----------
    mesh
        Triangle mesh in mm with per-vertex normals and uv (see :mod:`renderer.meshes`): the product, or the skin.
    stack
        The films over the substrate: a :class:`~renderer.stack.ChannelStack` composed in the shader or a
        :class:`~renderer.stack.Precomposed` stack.
    camera
        Orthographic or perspective camera; its aspect ratio is ``resolution[0] / resolution[1]``.
    lights
        1 to :data:`MAX_LIGHTS` directional or point lights; those with ``cast_shadows`` get a shadow
        map of ``shadow_map_size`` texels square covering the mesh and the props.
    resolution
        Image size in pixels, (width, height).
    lobes
        The films' specular lobes, top first, one per film (None: no lobe), or empty for no lobes at all.
    substrate_lobe
        A lobe of the substrate's own surface, seen through every film (skin's: :data:`renderer.stack.SKIN_SPECULAR`).
    scattering
        The skin's subsurface blur (:func:`renderer.skin.render_skin` only; None: no blur).
    model
        Object -> world matrix (4, 4) of ``mesh`` (a turntable's turn); identity if None.
    props
        Diffuse objects beside the mesh (:class:`Prop`), such as a ground.
    shadow_map_size
        Texels per side of each shadow map.
    background
        Linear RGB of pixels no surface covers (any float, unclamped).
    supersampling
        Samples per pixel along each side (1 to :data:`MAX_SUPERSAMPLING`): the frame is rendered at ``resolution``
        times this and box-filtered down (:func:`supersampled`), so silhouettes get partial coverage while a region of
        one value keeps that value exactly. 1: one sample per pixel.
    """

    mesh: trimesh.Trimesh
    stack: ChannelStack | Precomposed
    camera: Camera
    lights: Sequence[Light]
    resolution: tuple[int, int]
    lobes: Sequence[Specular | None] = ()
    substrate_lobe: Specular | None = None
    scattering: Scattering | None = None
    model: np.ndarray | None = None
    props: Sequence[Prop] = ()
    shadow_map_size: int = 1024
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    supersampling: int = 1


def supersampled(render: Callable[[Scene], np.ndarray], scene: Scene) -> np.ndarray:
    """``render(scene)`` at ``scene.supersampling`` samples per pixel side, box-filtered to ``scene.resolution``.

    The image is rendered at (w k, h k) pixels and each k x k block averaged in float64: pixel = (1 / k^2) sum of its
    samples. A block of equal samples averages to exactly that value (the sum of k^2 <= 16 equal float32 values is
    exact in float64, and so is its division when it is back in float32), so flat regions render as without
    supersampling; a pixel a silhouette crosses takes the share of its samples on each side. ValueError when the
    supersampled frame would pass :data:`MAX_RENDER_SIDE` or ``supersampling`` is not 1 to :data:`MAX_SUPERSAMPLING`.
    """
    k = scene.supersampling
    if not (isinstance(k, int) and 1 <= k <= MAX_SUPERSAMPLING):
        raise ValueError(f"supersampling is 1 to {MAX_SUPERSAMPLING} samples per pixel side, got {k!r}")
    if k == 1:
        return render(scene)
    width, height = scene.resolution
    if max(width, height) * k > MAX_RENDER_SIDE:
        raise ValueError(f"a {width} x {height} frame at {k} x {k} samples per pixel is larger than the "
                         f"{MAX_RENDER_SIDE} px a render may be; use fewer samples")  # fmt: skip
    fine = render(replace(scene, resolution=(width * k, height * k), supersampling=1))
    blocks = fine.reshape(height, k, width, k, fine.shape[-1]).astype(np.float64)
    return blocks.mean(axis=(1, 3)).astype(np.float32)
