"""Scene description as plain data, with no GL: cameras, lights, props, skin scattering, and the :class:`Scene` that
holds one frame's worth of them for the passes (:func:`renderer.layers.render_layers`,
:func:`renderer.skin.render_skin`), as pyrender hands its Scene to its renderer.

Positions and lengths are in scene units (mm); directions are world-space vectors (normalised on use). Matrices are
row-major numpy (4, 4) arrays acting on column vectors, in the OpenGL clip-space convention (NDC z in [-1, 1]).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
import trimesh

from renderer.environment import Environment
from renderer.stack import ChannelStack, Precomposed, Specular

if TYPE_CHECKING:  # (renderer.occlusion imports this module)
    from renderer.occlusion import FloorOcclusion

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
    (W m^-2 at normal incidence), pass ``E / pi``. ``angle_deg`` is the light's angular diameter (an area light seen
    from the scene, such as a softbox): its shadows get penumbrae of ``2 tan(angle / 2)`` mm per mm between occluder
    and receiver (0: hard).
    """

    direction: Vec3
    radiance: Vec3
    cast_shadows: bool = True
    angle_deg: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.angle_deg < 180.0:
            raise ValueError(f"a directional light's angular diameter is 0 to 180 degrees, got {self.angle_deg}")

    @property
    def softness(self) -> float:
        """Penumbra width (mm) per mm between occluder and receiver: 2 tan(angle / 2)."""
        return 2.0 * float(np.tan(np.radians(self.angle_deg) / 2.0))

    def to_light(self) -> np.ndarray:
        """Unit vector (3,) from a surface towards the light."""
        return -_unit(self.direction, "the light direction")


@dataclass(frozen=True)
class PointLight:
    """An isotropic light at ``position`` (mm), falling off with the inverse square of the distance.

    ``radiance`` is linear RGB at ``reference_distance_mm``: a white Lambert surface facing the light from that
    distance renders as ``radiance``; at distance d it renders as ``radiance * (reference_distance_mm / d)^2 *
    cos(theta)``. ``size_mm`` is the emitter's diameter: its shadows get penumbrae of ``size (d_r - d_o) / d_o``
    (d_o, d_r the occluder's and the receiver's distances from the light; 0: hard).
    """

    position: Vec3
    radiance: Vec3
    reference_distance_mm: float
    cast_shadows: bool = True
    size_mm: float = 0.0

    def __post_init__(self) -> None:
        if not (np.all(np.isfinite(self.position)) and self.reference_distance_mm > 0.0 and self.size_mm >= 0.0):
            raise ValueError(
                f"a point light needs a finite position, a reference distance > 0 mm and a size >= 0 mm, got "
                f"{self.position}, {self.reference_distance_mm} and {self.size_mm}"
            )

    @property
    def softness(self) -> float:
        """The emitter's diameter (mm)."""
        return float(self.size_mm)


Light = DirectionalLight | PointLight


@dataclass(frozen=True)
class Prop:
    """A plain diffuse object beside the product (a floor, a stand): Lambert ``albedo`` (linear RGB in [0, 1]).

    It receives light and shadows and casts shadows; ``model`` is its object -> world matrix (identity if None);
    ``occlusion`` its ambient occlusion per vertex in [0, 1], darkening the environment's light (None: 1). A floor
    under the product takes its occlusion per pixel from a baked grid instead (``floor_occlusion``, looked up at
    ``floor_frame`` times the world position: the product unturned; identity if None), so that a few large triangles
    carry it.
    """

    mesh: trimesh.Trimesh
    albedo: tuple[float, float, float]
    model: np.ndarray | None = None
    occlusion: np.ndarray | None = None
    floor_occlusion: FloorOcclusion | None = None
    floor_frame: np.ndarray | None = None


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


@dataclass(frozen=True)
class GradientBackground:
    """A background that fades vertically from ``top`` (the image's top row) to ``bottom`` (linear RGB), smoothly
    (smoothstep in the row's height), as a studio's graded paper seen behind the product."""

    top: Vec3
    bottom: Vec3


#: Film thickness (mm) that smooths a normal map's detail by 1/e (:class:`NormalMap`): fine lines of skin are tens of
#: micrometres deep, and a foundation of about that thickness fills them (thesis figure 3.20).
FILL_MM = 0.01


@dataclass(frozen=True)
class NormalMap:
    """Fine surface detail of the mesh (pores, fine lines) over its uv, smoothed where films lie over it.

    ``normals``: tangent-space unit vectors (rows, columns, 3), row 0 at v = 1, x along +u, y along +v, z out of the
    surface (the OpenGL / glTF convention). ``film_thickness_mm``: the films' total thickness over uv (a 2-D map, row 0
    at v = 1, or a number); the detail's tilt is scaled by exp(-thickness / ``fill_mm``).
    """

    normals: np.ndarray
    film_thickness_mm: np.ndarray | float = 0.0
    fill_mm: float = FILL_MM

    def __post_init__(self) -> None:
        normals = np.asarray(self.normals, dtype=float)
        if normals.ndim != 3 or normals.shape[2] != 3 or min(normals.shape[:2]) < 1:
            raise ValueError(f"a normal map needs (rows, columns, 3) vectors, got shape {normals.shape}")
        if not (np.all(np.isfinite(normals)) and normals[..., 2].min() > 0.0):
            raise ValueError("a normal map's vectors must be finite and point out of the surface (z > 0)")
        film = np.asarray(self.film_thickness_mm, dtype=float)
        if film.ndim not in (0, 2) or not (np.all(np.isfinite(film)) and film.min() >= 0.0 and self.fill_mm > 0.0):
            raise ValueError("a normal map's film thickness must be a number or a 2-D map >= 0 mm, fill_mm > 0")


#: The block sizes (pixels a side) in which soft shadows may be computed (:attr:`Scene.soft_shadow_scale`).
SOFT_SHADOW_SCALES = (1, 2)
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
        What pixels no surface covers show: linear RGB (any float, unclamped) or a :class:`GradientBackground`;
        a visible ``environment`` takes its place.
    environment
        Light from an equirectangular environment (:class:`renderer.environment.Environment`) on every surface,
        through the films and into the skin like a light's, or None.
    normal_map
        Fine detail of ``mesh`` over its uv (:class:`NormalMap`), used by every pass that shades it; None: none.
    substrate_roughness
        The substrate lobe's Beckmann roughness over uv (rows, columns), row 0 at v = 1, instead of its own; None.
    occlusion
        Ambient occlusion of each vertex of ``mesh`` in [0, 1] (:func:`renderer.occlusion.vertex_occlusion`),
        darkening the environment's light; None: 1 everywhere.
    supersampling
        Samples per pixel along each side (1 to :data:`MAX_SUPERSAMPLING`): the frame is rendered at ``resolution``
        times this and box-filtered down (:func:`supersampled`), so silhouettes get partial coverage while a region of
        one value keeps that value exactly. 1: one sample per pixel.
    multisamples
        Coverage samples per pixel of the surface pass (:mod:`renderer.multisample`: 1, 2 or 4): silhouettes get
        partial coverage as with supersampling, for about the shading cost of one sample a pixel. 1: none.
    soft_shadow_scale
        Pixels per side of the blocks in which area lights' soft shadows are computed (:data:`SOFT_SHADOW_SCALES`):
        2 computes them at half the frame's resolution (about a quarter of their cost), 1 at every pixel; either way
        they are filtered along each surface (which removes their sampling noise) and upsampled to the frame.
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
    background: tuple[float, float, float] | GradientBackground = (0.0, 0.0, 0.0)
    environment: Environment | None = None
    occlusion: np.ndarray | None = None
    normal_map: NormalMap | None = None
    substrate_roughness: np.ndarray | None = None
    supersampling: int = 1
    multisamples: int = 1
    soft_shadow_scale: int = 2

    def __post_init__(self) -> None:
        if self.soft_shadow_scale not in SOFT_SHADOW_SCALES:
            raise ValueError(
                f"soft shadows are computed in blocks of 1 or 2 pixels a side, got {self.soft_shadow_scale!r}"
            )


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
