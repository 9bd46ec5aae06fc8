"""Image-based light: an equirectangular environment of radiance around the scene, prefiltered for the layer pass.

Directions. World +y is up. A pixel of an equirectangular image of ``rows`` x ``cols`` (row 0 at the top) looks along
the polar angle theta from +y and the azimuth phi from -z towards +x (the image's centre looks along -z, the way the
default camera looks, so it is what stands behind the product)::

    d = (sin theta sin phi, cos theta, -sin theta cos phi),  u = 1/2 + phi / (2 pi),  v = 1 - theta / pi

and covers the exact solid angle ``Omega_r = (2 pi / cols) (cos theta_top - cos theta_bottom)`` of its row (the
pixels sum to 4 pi to rounding). :attr:`Environment.rotation_deg` turns the environment about +y (counter-clockwise
seen from above); ``intensity`` scales it.

Prefiltering (once per environment image, :func:`prefiltered`). With L(w) the radiance and the sums over the pixels
of a copy of the image area-averaged to the map's own size (:data:`IRRADIANCE_SIZE`; each specular level's size in
:data:`SPECULAR_LEVELS`, then resized to :data:`SPECULAR_SIZE`):

* diffuse: the irradiance over pi of each normal n, ``E(n) / pi = sum L max(n.w, 0) Omega / sum max(n.w, 0) Omega``
  (normalised by the discrete cosine integral, so that a uniform environment of radiance L gives exactly L: a white
  Lambert surface inside it renders L, the white furnace test, and one of albedo a renders a L);
* specular: for each Beckmann roughness m > 0 of :data:`SPECULAR_LEVELS`, the radiance around the mirror direction r
  weighted by the lobe's shape, ``L_m(r) = sum L K_m(w.r) Omega / sum K_m(w.r) Omega`` with
  ``K_m = exp(-tan^2(b/2) / m^2) / cos^5(b/2)`` (b the angle from r: the Beckmann distribution of the half vector at
  b/2, with the Jacobian of reflection), so a uniform environment gives L again.

A lobe's reflected radiance is then the split sum ``rho(mu, m, F0) L_m(r)`` with rho the Kelemen/Szirmay-Kalos lobe's
directional albedo (:func:`lobe_albedo`): the lobe of ``shaders/km_layers.frag`` integrated against a uniform
environment, exactly (to quadrature), so a uniform environment renders the lobe as ``rho L``.
"""

from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass

import cv2
import numpy as np

#: Size (columns, rows) of the specular maps the shader reads (each level resized to it, bilinear).
SPECULAR_SIZE = (128, 64)
#: Size (columns, rows) of the prefiltered irradiance map (from the image area-averaged to the same size).
IRRADIANCE_SIZE = (64, 32)
#: Beckmann roughness m of the specular levels and the size (columns, rows) each is prefiltered at, from the image
#: area-averaged to that size: pixels under about a third of the lobe's angular width. Level 0 (m = 0) is the image
#: itself at SPECULAR_SIZE (a mirror); the shader interpolates in m between levels and clamps at the last.
SPECULAR_LEVELS = ((0.0, (128, 64)), (0.1, (64, 32)), (0.2, (64, 32)), (0.35, (64, 32)), (0.6, (32, 16)),
                   (1.0, (32, 16)), (2.0, (32, 16)))  # fmt: skip
#: Grid of the lobe albedo table: mu = cos(view angle) in [0, 1], and m in [LOBE_M_RANGE] (uniform in sqrt(m)).
LOBE_TABLE_SIZE = (32, 32)
LOBE_M_RANGE = (0.02, 2.0)
#: Largest radiance of an environment pixel accepted (linear RGB).
MAX_RADIANCE = 1e6


@dataclass(frozen=True, eq=False)
class Environment:
    """An equirectangular environment: ``radiance`` linear RGB (rows, cols, 3), rows = cols / 2 (any size from 8 x 4),
    row 0 the zenith; turned by ``rotation_deg`` about +y and scaled by ``intensity``. ``visible``: pixels no surface
    covers show it (else the scene's background)."""

    radiance: np.ndarray
    rotation_deg: float = 0.0
    intensity: float = 1.0
    visible: bool = False

    def __post_init__(self) -> None:
        image = np.asarray(self.radiance)
        if image.ndim != 3 or image.shape[2] != 3 or image.shape[1] < 8 or image.shape[1] != 2 * image.shape[0]:
            raise ValueError(f"an equirectangular environment needs (rows, 2 rows, 3) pixels, got {image.shape}")
        if not (np.all(np.isfinite(image)) and image.min() >= 0.0 and image.max() <= MAX_RADIANCE):
            raise ValueError(f"environment radiance must be finite, >= 0 and <= {MAX_RADIANCE:g}")
        if not (np.isfinite(self.rotation_deg) and np.isfinite(self.intensity) and self.intensity >= 0.0):
            raise ValueError(f"rotation and intensity must be finite and intensity >= 0, got {self.rotation_deg}, "
                             f"{self.intensity}")  # fmt: skip

    def world_to_environment(self) -> np.ndarray:
        """The (3, 3) rotation taking a world direction to the image's frame: a turn of -rotation about +y."""
        a = np.radians(-self.rotation_deg)
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])

    def lookup(self, directions: np.ndarray) -> np.ndarray:
        """Radiance (..., 3) seen along world ``directions`` (..., 3), bilinear, intensity applied (the background)."""
        d = np.asarray(directions, float) @ self.world_to_environment().T
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        rows, cols = self.radiance.shape[:2]
        phi = np.arctan2(d[..., 0], -d[..., 2])
        theta = np.arccos(np.clip(d[..., 1], -1.0, 1.0))
        x = ((0.5 + phi / (2.0 * np.pi)) * cols - 0.5).astype(np.float32)
        y = (theta / np.pi * rows - 0.5).astype(np.float32)
        image = np.asarray(self.radiance, np.float32)
        wrapped = np.concatenate([image[:, -1:], image, image[:, :1]], axis=1)  # the seam at phi = +-pi wraps
        out = cv2.remap(wrapped, x + 1.0, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return out.reshape(*d.shape[:-1], 3) * self.intensity


def pixel_directions(cols: int, rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions (rows, cols, 3) of the pixel centres and their exact solid angles (rows, cols), sr."""
    theta_edges = np.linspace(0.0, np.pi, rows + 1)
    theta = 0.5 * (theta_edges[:-1] + theta_edges[1:])
    phi = (np.arange(cols) + 0.5) / cols * 2.0 * np.pi - np.pi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    directions = np.stack([np.sin(t) * np.sin(p), np.cos(t), -np.sin(t) * np.cos(p)], axis=-1)
    solid = (2.0 * np.pi / cols) * (np.cos(theta_edges[:-1]) - np.cos(theta_edges[1:]))
    return directions, np.broadcast_to(solid[:, None], (rows, cols)).copy()


def _resized(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The image at ``size`` (columns, rows): area-averaged when smaller, bilinear when larger, float64."""
    if image.shape[1::-1] == size:
        return image.astype(np.float64)
    shrink = size[0] < image.shape[1]
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR).astype(np.float64)


def _convolve(image: np.ndarray, size: tuple[int, int], kernel) -> np.ndarray:
    """sum L K Omega / sum K Omega over the pixels of the image at ``size``, for each of its own pixel directions;
    kernel(cosine) -> weight."""
    source = _resized(image, size)
    directions, solid = pixel_directions(*size)
    directions, solid = directions.reshape(-1, 3), solid.reshape(-1)
    radiance = source.reshape(-1, 3)
    result = np.empty((len(directions), 3))
    for start in range(0, len(directions), 1024):
        weights = kernel(np.clip(directions[start : start + 1024] @ directions.T, -1.0, 1.0)) * solid
        result[start : start + 1024] = (weights @ radiance) / weights.sum(axis=1, keepdims=True)
    return result.reshape(size[1], size[0], 3)


def _specular_kernel(m: float):
    def kernel(cosine: np.ndarray) -> np.ndarray:
        c = np.sqrt(np.clip(0.5 * (1.0 + cosine), 1e-12, 1.0))  # cos(b / 2)
        tan2 = (1.0 - c * c) / (c * c)
        return np.exp(-tan2 / (m * m)) / c**5

    return kernel


@dataclass(frozen=True)
class Prefiltered:
    """An environment's prefiltered maps: ``irradiance`` E/pi (rows, cols, 3) and ``specular`` (levels, rows, cols,
    3), each equirectangular as the source (row 0 the zenith), intensity and rotation not applied."""

    irradiance: np.ndarray
    specular: np.ndarray


_cache: dict[str, Prefiltered] = {}


def prefiltered(environment: Environment) -> Prefiltered:
    """The diffuse and specular prefilters of the environment's image (module docstring), cached by its content."""
    image = np.ascontiguousarray(environment.radiance, dtype=np.float32)
    key = hashlib.sha256(image.tobytes()).hexdigest() + str(image.shape)
    if key not in _cache:
        irradiance = _convolve(image, IRRADIANCE_SIZE, lambda cosine: np.maximum(cosine, 0.0))
        levels = [
            _resized(image, size) if m == 0.0 else _resized(_convolve(image, size, _specular_kernel(m)), SPECULAR_SIZE)
            for m, size in SPECULAR_LEVELS
        ]
        specular = np.stack(levels)
        if len(_cache) > 8:
            _cache.clear()
        _cache[key] = Prefiltered(irradiance.astype(np.float32), specular.astype(np.float32))
    return _cache[key]


def lobe_m_axis() -> np.ndarray:
    """The roughness values (LOBE_TABLE_SIZE[1]) of the lobe table's rows: uniform in sqrt(m) over LOBE_M_RANGE."""
    lo, hi = np.sqrt(LOBE_M_RANGE)
    return np.linspace(lo, hi, LOBE_TABLE_SIZE[1]) ** 2


@functools.cache
def lobe_albedo() -> np.ndarray:
    """The Kelemen/Szirmay-Kalos lobe's directional albedo as ``rho = F0 a + b``: (m rows, mu columns, 2) = (a, b).

    rho(mu, m, F0) = integral over the hemisphere of f_spec(l, v) cos(theta_l) dw_l, f_spec as km_layers.frag gives
    it, with Schlick's F = F0 (1 - (1 - c)^5) + (1 - c)^5 (c = h.l). In half-vector coordinates
    (dw_l = 4 (v.h) dw_h and 1 + l.v = 2 (v.h)^2) the integrand is P(h) F cos(theta_l) / (v.h) dw_h, with P the
    normalised Beckmann distribution; integrated on tan(theta_h) = m t, t in [0, 5] (128 points) by 96 azimuths.
    """
    mu = np.linspace(0.0, 1.0, LOBE_TABLE_SIZE[0])
    mu[0] = 1e-3
    table = np.zeros((LOBE_TABLE_SIZE[1], LOBE_TABLE_SIZE[0], 2))
    t = (np.arange(128) + 0.5) / 128 * 5.0
    phi = (np.arange(96) + 0.5) / 96 * 2.0 * np.pi
    for i, m in enumerate(lobe_m_axis()):
        theta_h = np.arctan(m * t)
        d_theta = m / (1.0 + (m * t) ** 2) * (5.0 / 128)
        th, ph = np.meshgrid(theta_h, phi, indexing="ij")
        h = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
        cos_h = np.cos(th)
        density = np.exp(-((m * t[:, None]) ** 2) / (m * m)) / (np.pi * m * m * cos_h**4)
        d_omega = np.sin(th) * d_theta[:, None] * (2.0 * np.pi / 96)
        for j, mu_v in enumerate(mu):
            v = np.array([np.sqrt(1.0 - mu_v * mu_v), 0.0, mu_v])
            vh = h @ v
            l_z = 2.0 * vh * h[..., 2] - mu_v
            valid = (vh > 0.0) & (l_z > 0.0)
            c5 = (1.0 - np.clip(vh, 0.0, 1.0)) ** 5
            base = np.where(valid, density * l_z / np.where(valid, vh, 1.0) * d_omega, 0.0)
            table[i, j] = (np.sum(base * (1.0 - c5)), np.sum(base * c5))
    return table


def studio_environment(cols: int = 256) -> np.ndarray:
    """A procedural photo studio, linear RGB (cols / 2, cols, 3): a neutral grey dome over a darker floor, a large
    key softbox up to the camera's left, a fill softbox to its right, a strip light overhead and a rim light behind.

    Radiance: dome 0.30 at the zenith to 0.18 at the horizon, fading to the floor's 0.06 by 10 degrees below it; key
    2.4, fill 0.9, top strip 1.5, rim 1.8 (their edges fade over 2 degrees). A white Lambert surface renders (E / pi)
    about 0.52 facing the key, 0.54 facing up and 0.39 facing the camera.
    """
    rows = cols // 2
    directions, _ = pixel_directions(cols, rows)
    elevation = np.degrees(np.arcsin(np.clip(directions[..., 1], -1.0, 1.0)))
    azimuth = np.degrees(np.arctan2(directions[..., 0], directions[..., 2]))  # 0 towards the camera (+z), 90 at +x
    sky = 0.18 + 0.12 * np.sin(np.radians(np.maximum(elevation, 0.0)))
    below = np.clip(-elevation / 10.0, 0.0, 1.0)  # the floor: from the horizon's 0.18 down to 0.06 by -10 degrees
    dome = np.where(elevation >= 0.0, sky, 0.18 + (0.06 - 0.18) * below * below * (3.0 - 2.0 * below))
    radiance = np.repeat(dome[..., None], 3, axis=2) * np.array([1.0, 0.99, 0.97])

    def box(centre_azimuth, centre_elevation, width, height):
        da = (azimuth - centre_azimuth + 180.0) % 360.0 - 180.0
        de = elevation - centre_elevation
        edge = lambda x, half: np.clip((half - np.abs(x)) / 2.0 + 0.5, 0.0, 1.0)  # noqa: E731
        return edge(da * np.cos(np.radians(centre_elevation)), width / 2.0) * edge(de, height / 2.0)

    for (az, el, w, h), value in (
        ((-40.0, 30.0, 40.0, 34.0), 2.4),   # key: camera left, above
        ((55.0, 10.0, 30.0, 44.0), 0.9),    # fill: camera right
        ((0.0, 75.0, 70.0, 10.0), 1.5),     # strip overhead
        ((165.0, 25.0, 20.0, 50.0), 1.8),   # rim: behind, to the right
    ):  # fmt: skip
        mask = box(az, el, w, h)
        radiance = radiance * (1.0 - mask[..., None]) + value * mask[..., None]
    return radiance.astype(np.float32)
