"""Scene description: cameras and lights as plain data, with no GL.

Positions and lengths are in scene units (mm); directions are world-space vectors (normalised on use). Matrices are
row-major numpy (4, 4) arrays acting on column vectors, in the OpenGL clip-space convention (NDC z in [-1, 1]).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

Vec3 = tuple[float, float, float]


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
