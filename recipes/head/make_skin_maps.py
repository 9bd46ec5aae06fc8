"""Writes head_albedo.png, head_normal.png and head_roughness.png beside this file: skin maps of the bundled head.

All three are 1024 x 1024 texels over the head's uv (row 0 at v = 1, like recipes/scenes/head_makeup.png). Each texel
is painted as a function of the 3-D point of the head it covers (mm, +y up, the face towards +z; head_texels.py), so
nothing jumps at the uv seams; the regions come from the head's landmarks (landmarks.json) and its own geometry.

- head_albedo.png, 8-bit sRGB: the skin's albedo for ``[skin] albedo_texture``. Multiplicative tints around the mean
  colour, scaled so that the mean of linear RGB over the face's texels is ColorChecker "light skin" under D65 in
  linear sRGB (:func:`light_skin`): the measured skin spectrum, re-weighted per texel by
  kmpipe/formats/albedo_texture.py, stays itself on average. Tints: redder cheekbones, nose tip and ears; lips
  redder and darker (make_head_map.py's lipstick outline, a 0.8 mm soft vermilion border, a darker mouth line);
  brows, an arc above each eye drawn hair by hair, darker and browner; a paler scalp above the hairline; 3 % RMS of
  low-frequency luminance and 1 % of redness mottling from blurred random 3-D grids (cells 2 and 3 mm, Gaussian sd
  2.5 and 3 cells: smooth at 5-9 mm on the head, whatever the uv).
- head_normal.png, 8-bit RGB, linear codes: the tangent-space normal n = 2 rgb / 255 - 1 (+x along increasing u, +y
  along increasing v, +z out of the surface: OpenGL / glTF) of a height field h (mm) of fine detail: pores, forehead
  lines, crow's feet, soft nasolabial folds, vertical lip wrinkles and a faint micro-relief between them.
  n = normalize(-dh/ds_u, -dh/ds_v, 1), the slopes along the surface's u and v directions in mm per mm (central
  differences of h, a function of the 3-D point, over +-0.25 mm along each; the directions and the mm per texel are
  the derivatives of the texels' points in uv, :func:`head_texels.texel_frames`). RMS tilt over the face about 2.3
  deg, at most 16 deg. Flat (128, 128, 255) outside the islands.
- head_roughness.png, 8-bit grey: the skin lobe's Beckmann roughness m = value / 255 (bare skin 0.35, T-zone 0.28,
  lips 0.20, scalp and neck 0.40, soft transitions).

Resolution: the face's texels are about 1 mm (0.8 to 1.6 mm; the head holds a fifth of the uv square), so a pore
(0.1-0.3 mm) is far below a texel. Each pore is drawn at the map's limit, a Gaussian pit of sd
sqrt(r^2 + (0.6 texel)^2) for a pore of radius r, and its depth is set by the tilt its wall reaches (7 deg on the
nose's tip to 2.5 deg on the neck), not by a real pore's depth, which a texel would average away. Lines and brow
hairs are likewise no narrower than 0.5-0.6 texel.

Deterministic (seed SEED): a rerun writes byte-identical files (compare their SHA-256 with README.md's).
Run: .venv/bin/python recipes/head/make_skin_maps.py
"""

from __future__ import annotations

import json
from pathlib import Path

import colour
import cv2
import numpy as np
from head_texels import hairline_mm, lip_outline, mouth, smoothstep, texel_frames, texel_points
from scipy.ndimage import gaussian_filter, map_coordinates
from scipy.spatial import cKDTree

from renderer.image_io import write_png
from renderer.products import load_mesh

HEAD = Path(__file__).resolve().parent
SIZE = 1024
SEED = 14
DILATE_TEXELS = 4
"""How far (texels) the islands' albedo and roughness are carried outward, so bilinear sampling at their borders
never reaches the fill."""
ROUGHNESS_SCALE = 1.0
"""Beckmann m of code 255 in head_roughness.png (m = code / 255 * ROUGHNESS_SCALE)."""


def light_skin() -> np.ndarray:
    """ColorChecker "light skin" (N Ohta) as linear sRGB in [0, 1]: XYZ under D65 (CIE 1931 2 deg) / 100 to sRGB."""
    sd = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]["light skin"]
    xyz = colour.sd_to_XYZ(sd, illuminant=colour.SDS_ILLUMINANTS["D65"])
    return colour.XYZ_to_sRGB(xyz / 100.0, apply_cctf_encoding=False)


class Head:
    """The head's texels and their 3-D points, with the landmarks and soft region masks (0 to 1) over them."""

    def __init__(self, mesh, marks: dict, size: int):
        self.mesh, self.marks = mesh, marks
        self.points, self.covered, triangle = texel_points(mesh, size)
        self.du, self.dv = texel_frames(mesh, size, triangle)
        x, y, z = (self.points[..., i] for i in range(3))
        self.x, self.y, self.z = x, y, z
        self.eye_x, self.eye_y = marks["joint-l-eye"][0], marks["joint-l-eye"][1]
        self.lid_y = marks["joint-l-upperlid"][1]
        self.azimuth = np.degrees(np.arctan2(x, z - marks["joint-head"][2]))  # about the head's vertical axis
        self.texel_mm = np.maximum(np.linalg.norm(self.du, axis=-1), np.linalg.norm(self.dv, axis=-1))
        self.texel_area = np.linalg.norm(np.cross(self.du, self.dv), axis=-1)  # mm^2
        self.lips_edge = lip_outline(self.points, mesh)
        self.mouth_line, _, _ = mouth(mesh)
        midline = mesh.vertices[np.abs(mesh.vertices[:, 0]) < 0.5]
        self.tip = midline[np.argmax(midline[:, 2])]  # the nose's tip

    def hairline(self) -> np.ndarray:
        """The hairline's height (mm) at each texel (:func:`head_texels.hairline_mm`)."""
        return hairline_mm(self.azimuth)

    def jaw(self) -> np.ndarray:
        """The jaw line's height (mm), rising towards the ears (as make_head_map.py's foundation), level behind them
        (|azimuth| over 70 deg)."""
        return self.marks["joint-jaw"][1] + 12.0 + 40.0 * (np.minimum(np.abs(self.azimuth), 70.0) / 70.0) ** 2

    def scalp(self) -> np.ndarray:
        return smoothstep(-4.0, 6.0, self.y - self.hairline())

    def neck(self) -> np.ndarray:
        return 1.0 - smoothstep(-8.0, 4.0, self.y - self.jaw())

    def face(self) -> np.ndarray:
        """The face: in front (|azimuth| < 40 deg fading to 50), below the hairline, above the jaw line."""
        front = 1.0 - smoothstep(40.0, 50.0, np.abs(self.azimuth))
        return front * (1.0 - self.scalp()) * (1.0 - self.neck())

    def lips(self, soft_mm: float) -> np.ndarray:
        """The lips: 1 inside the lipstick's outline, falling to 0 over +-soft_mm across it."""
        return 1.0 - smoothstep(-soft_mm, soft_mm, self.lips_edge)

    def cheeks(self) -> np.ndarray:
        """Over each cheekbone: 28 mm below and 14 mm outside the eye (the blush's place), a Gaussian (sd 16 x 11 mm)
        stretched up and out towards the temple."""
        total = np.zeros_like(self.x)
        for side in (-1.0, 1.0):
            dx, dy = side * self.x - (self.eye_x + 12.0), self.y - (self.eye_y - 26.0)
            along, across = 0.8 * dx + 0.6 * dy, -0.6 * dx + 0.8 * dy
            total += np.exp(-0.5 * ((along / 16.0) ** 2 + (across / 11.0) ** 2)) * (side * self.x > 0)
        return total * smoothstep(30.0, 60.0, self.z)

    def nose_tip(self) -> np.ndarray:
        """Around the nose's tip (the midline's most forward point) and its wings: a Gaussian of sd 10 x 6 mm."""
        r2 = (self.x / 10.0) ** 2 + ((self.y - self.tip[1] + 1.0) / 6.0) ** 2
        return np.exp(-0.5 * r2) * smoothstep(self.tip[2] - 30.0, self.tip[2] - 15.0, self.z)

    def nose(self) -> np.ndarray:
        """The nose from its bridge between the eyes to its tip, |x| under 9 mm fading to 15, standing out of the
        face."""
        _, tip_y, tip_z = self.tip
        across = 1.0 - smoothstep(9.0, 15.0, np.abs(self.x))
        along = smoothstep(tip_y - 12.0, tip_y - 6.0, self.y) * (1.0 - smoothstep(self.lid_y - 4.0, self.lid_y, self.y))
        return across * along * smoothstep(tip_z - 32.0, tip_z - 24.0, self.z)

    def forehead(self) -> np.ndarray:
        """The forehead: above the brows, below the hairline, in front."""
        above_brows = smoothstep(self.lid_y + 8.0, self.lid_y + 16.0, self.y)
        return above_brows * (1.0 - self.scalp()) * (1.0 - smoothstep(30.0, 42.0, np.abs(self.azimuth)))

    def ears(self) -> np.ndarray:
        """Each ear: an ellipsoid around it (centre |x| 82, y -5, z -17 mm; semi-axes 10 x 30 x 20 mm), soft."""
        r2 = ((np.abs(self.x) - 82.0) / 10.0) ** 2 + ((self.y + 5.0) / 30.0) ** 2 + ((self.z + 17.0) / 20.0) ** 2
        return 1.0 - smoothstep(0.6, 1.0, r2)


def blurred_noise(points: np.ndarray, rng: np.random.Generator, cell_mm: float, sd_cells: float) -> np.ndarray:
    """Smooth 3-D noise at the points (..., 3), unit RMS over them: a grid of standard normal values every cell_mm
    over the head's box, blurred by a Gaussian of sd sd_cells, sampled trilinearly."""
    lo = points.reshape(-1, 3).min(axis=0) - 4.0 * cell_mm
    shape = np.ceil((points.reshape(-1, 3).max(axis=0) + 4.0 * cell_mm - lo) / cell_mm).astype(int) + 1
    grid = gaussian_filter(rng.standard_normal(shape), sd_cells, mode="wrap")
    coords = ((points.reshape(-1, 3) - lo) / cell_mm).T
    values = map_coordinates(grid, coords, order=1).reshape(points.shape[:-1])
    return values / np.sqrt(np.mean(values**2))


def brow_shape(s: np.ndarray, lid_y: float) -> tuple[np.ndarray, np.ndarray]:
    """A brow's centre line height (mm) and half-width (mm) at s along it (0 its inner end at |x| 13 mm, 1 its tail
    at |x| 55 mm): lid + 4 mm at the head, rising 4 mm to a peak two thirds out, lid + 4.8 mm at the tail; 4.5 mm
    half-width tapering to 1.5 mm."""
    t = np.clip(s, 0.0, 1.0)
    centre = lid_y + 4.0 + 4.0 * np.sin(np.pi * np.clip(t / 1.3, 0.0, 1.0) ** 1.1) - 2.0 * t**3
    return centre, 4.5 - 3.0 * t


BROW_HAIRS = 360
"""Hairs per brow."""
HAIR_MM = 0.14
"""A brow hair's apparent width (mm): a hair (about 0.08 mm) and the shadow it casts on the skin."""


def brow_cover(head: Head, rng: np.random.Generator) -> np.ndarray:
    """How much of each texel the brows' hairs cover, 0 to 1: BROW_HAIRS strokes per brow, drawn in the face's front
    projection, their cover combined as 1 - prod(1 - c_i).

    A hair's root lies in the brow's band (:func:`brow_shape`), denser in its body than at its head and tail; it
    grows 4 to 8 mm (shorter at the head) at 55 deg over the horizontal at the brow's head flattening to 0 at its
    tail, lower hairs 18 deg steeper and upper ones 18 deg flatter (they meet along the middle), +-8 deg at random;
    it tapers from root to tip. A hair is far finer than a texel, so its stroke is a Gaussian line of sd
    max(0.3 mm, 0.5 texel) whose cover keeps the hair's area: c = HAIR_MM / (sd sqrt(2 pi)) at its root.
    """
    log_clear = np.zeros(head.x.shape)
    width = np.maximum(0.3, 0.5 * head.texel_mm)
    for side in (-1.0, 1.0):
        near = (
            head.covered & (side * head.x > 5.0) & (side * head.x < 62.0) & (np.abs(head.y - head.lid_y - 6.0) < 12.0)
        )
        near &= head.z > 40.0
        px, py, sd = side * head.x[near], head.y[near], width[near]
        s = rng.beta(1.6, 1.3, size=BROW_HAIRS) * 1.06 - 0.03
        centre, half_width = brow_shape(s, head.lid_y)
        across = rng.uniform(-0.95, 0.95, size=BROW_HAIRS)  # of the half-width, below (-) or above the centre
        root = np.stack([13.0 + 42.0 * s, centre + across * half_width], axis=-1)
        angle = np.radians(
            55.0 - 55.0 * np.clip(s, 0.0, 1.0) ** 0.6 - 18.0 * across + rng.uniform(-8.0, 8.0, BROW_HAIRS)
        )
        length = rng.uniform(4.0, 8.0, size=BROW_HAIRS) * (0.6 + 0.4 * np.clip(s / 0.3, 0.0, 1.0))
        direction = np.stack([np.cos(angle), np.sin(angle)], axis=-1)
        rel_x, rel_y = px[:, None] - root[:, 0], py[:, None] - root[:, 1]  # (texels, hairs)
        t = np.clip((rel_x * direction[:, 0] + rel_y * direction[:, 1]) / length, 0.0, 1.0)
        dx, dy = rel_x - t * length * direction[:, 0], rel_y - t * length * direction[:, 1]
        root_cover = HAIR_MM / (sd[:, None] * np.sqrt(2.0 * np.pi))
        cover = root_cover * (1.0 - 0.5 * t) * np.exp(-0.5 * (dx * dx + dy * dy) / sd[:, None] ** 2)
        log_clear[near] += np.log1p(-np.clip(cover, 0.0, 0.95)).sum(axis=1)
    return 1.0 - np.exp(log_clear)


def tint(head: Head, rng: np.random.Generator) -> np.ndarray:
    """The multiplicative tint (size, size, 3) of linear RGB over the mean skin colour, before normalising."""

    def toward(factor, mask):
        return 1.0 + (np.asarray(factor) - 1.0) * mask[..., None]

    lips = head.lips(0.4)
    mouth_line = np.exp(-0.5 * ((head.y - head.mouth_line) / 1.2) ** 2) * lips
    luminance = (
        1.0 + 0.024 * blurred_noise(head.points, rng, 3.0, 3.0) + 0.015 * blurred_noise(head.points, rng, 2.0, 2.5)
    )
    redness = 0.012 * blurred_noise(head.points, rng, 3.0, 3.0)
    result = luminance[..., None] * np.stack([1.0 + redness, 1.0 - 0.6 * redness, 1.0 - 0.6 * redness], axis=-1)
    result *= toward([1.05, 0.92, 0.93], head.cheeks())
    result *= toward([1.04, 0.91, 0.92], head.nose_tip())
    result *= toward([1.04, 0.90, 0.91], head.ears())
    result *= toward([1.04, 1.05, 1.06], head.scalp())
    result *= toward([0.90, 0.56, 0.62], lips)
    result *= toward([0.80, 0.75, 0.78], mouth_line)
    result *= toward([0.16, 0.15, 0.12], brow_cover(head, rng))
    return result


def dilate(values: np.ndarray, covered: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Carry values (size, size, channels) outward from the covered texels, one ring per step: each newly reached
    texel takes the mean of its covered 8-neighbours. Returns the values and the grown coverage."""
    values, covered = values.copy(), covered.copy()
    for _ in range(steps):
        padded_values = np.pad(values * covered[..., None], ((1, 1), (1, 1), (0, 0)))
        padded_cover = np.pad(covered.astype(float), 1)
        total, count = np.zeros_like(values), np.zeros(covered.shape)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                rows, cols = slice(1 + dy, 1 + dy + covered.shape[0]), slice(1 + dx, 1 + dx + covered.shape[1])
                total += padded_values[rows, cols]
                count += padded_cover[rows, cols]
        reached = ~covered & (count > 0)
        values[reached] = total[reached] / count[reached, None]
        covered = covered | reached
    return values, covered


def albedo(head: Head, rng: np.random.Generator) -> np.ndarray:
    """Linear RGB albedo (size, size, 3): the tints, each channel scaled so its mean over the face's texels is
    light skin's; uncovered texels are the dilated islands' colour, then the face's mean."""
    target = light_skin()
    tints = tint(head, rng)
    face = (head.face() > 0.5) & head.covered
    rgb = tints * (target / tints[face].mean(axis=0))
    rgb, reached = dilate(rgb, head.covered, DILATE_TEXELS)
    rgb[~reached] = target
    return rgb


def pores(head: Head, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pore centres (n, 3) mm, pit sds (n,) mm and depths (n,) mm, drawn texel by texel in proportion to the area
    each texel covers times the pore density there, each jittered uniformly within its texel.

    Per region (density per mm^2, pore radius r mm, wall tilt deg): the nose's tip and wings 0.16, 0.15, 7; cheeks
    0.11, 0.12, 5.5; elsewhere 0.06, 0.10, 4; forehead 0.05, 0.08, 4; neck and scalp 0.025, 0.05, 2.5. The pit's sd is
    sqrt(r^2 + (0.6 texel)^2), its depth d = tan(tilt) sd / exp(-1/2) (the steepest slope of a Gaussian pit
    -d exp(-r^2 / 2 sd^2) is d exp(-1/2) / sd), times a log-normal factor (sd 0.3).
    """
    regions = [  # later regions override earlier ones where their masks reach
        (head.forehead(), (0.05, 0.08, 4.0)),
        (np.clip(head.cheeks() * 1.6, 0.0, 1.0), (0.11, 0.12, 5.5)),
        (head.nose_tip(), (0.16, 0.15, 7.0)),
        (np.maximum(head.scalp(), head.neck()), (0.025, 0.05, 2.5)),
    ]
    density, radius, tilt = (np.full(head.x.shape, value) for value in (0.06, 0.10, 4.0))
    for mask, (d, r, t) in regions:
        density += (d - density) * mask
        radius += (r - radius) * mask
        tilt += (t - tilt) * mask
    density *= 1.0 - head.lips(0.6)  # no pores on the lips
    expected = np.where(head.covered, density * head.texel_area, 0.0)
    chosen = rng.uniform(size=expected.shape) < expected
    jitter = rng.uniform(-0.5, 0.5, size=(*expected.shape, 2))
    centres = head.points + jitter[..., :1] * head.du + jitter[..., 1:] * head.dv
    sd = np.sqrt(radius**2 + (0.6 * head.texel_mm) ** 2)
    depth = np.tan(np.radians(tilt)) * sd / np.exp(-0.5) * rng.lognormal(0.0, 0.3, size=expected.shape)
    return centres[chosen], sd[chosen], depth[chosen]


MICRO_TILT_DEG = 1.0
"""The RMS tilt of the skin's micro-relief between the pores and lines."""


def micro_waves(rng: np.random.Generator, count: int = 48) -> tuple[np.ndarray, np.ndarray, float]:
    """The skin's micro-relief as a sum of 3-D cosines a sum_i cos(k_i . p + phase_i): wave vectors (count, 3) in
    random directions with wavelengths 2.5 to 5 mm (2.5 texels and more), phases, and the amplitude a (mm).

    Over random directions the surface keeps 2/3 of |k|^2, so the tilt's RMS is a sqrt(sum_i |k_i|^2 / 3) (each
    cosine's slope has mean square a^2 |k_t|^2 / 2); a makes it MICRO_TILT_DEG."""
    direction = rng.standard_normal((count, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    k = direction * (2.0 * np.pi / rng.uniform(2.5, 5.0, size=(count, 1)))
    amplitude = np.tan(np.radians(MICRO_TILT_DEG)) / np.sqrt((k**2).sum() / 3.0)
    return k, rng.uniform(0.0, 2.0 * np.pi, size=count), amplitude


def groove(distance: np.ndarray, width: np.ndarray, tilt_deg: float) -> np.ndarray:
    """A groove's depth (mm, negative) at a distance (mm) from its line: -d exp(-distance^2 / 2 width^2), d set so
    that its wall's steepest slope is tilt_deg."""
    return -np.tan(np.radians(tilt_deg)) * width / np.exp(-0.5) * np.exp(-0.5 * (distance / width) ** 2)


def polyline_distance(x: np.ndarray, y: np.ndarray, curve: np.ndarray) -> np.ndarray:
    """The distance (mm) from points (x, y) to a densely sampled curve (n, 2) in the face's front projection."""
    return cKDTree(curve).query(np.stack([x, y], axis=-1))[0]


def bezier(p0, p1, p2, samples: int = 400) -> np.ndarray:
    """Points (samples, 2) along the quadratic Bezier curve p0, p1, p2."""
    t = np.linspace(0.0, 1.0, samples)[:, None]
    return (1 - t) ** 2 * np.asarray(p0) + 2 * (1 - t) * t * np.asarray(p1) + t**2 * np.asarray(p2)


class Relief:
    """The skin's fine relief h (mm) near the covered texels: called with points (n, 3), one near each covered texel
    in the order of ``head.points[head.covered]``; the regions' soft masks and the widths' texel limit are the
    texel's own (constant over the small steps the slopes are taken over)."""

    def __init__(self, head: Head, rng: np.random.Generator):
        self.head, covered = head, head.covered
        self.centres, self.sd, self.depth = pores(head, rng)
        self.tree = cKDTree(self.centres)
        self.limit = 0.6 * head.texel_mm[covered]  # the narrowest width (sd, mm) a texel holds without aliasing
        self.forehead = head.forehead()[covered]
        self.front = smoothstep(40.0, 60.0, head.z)[covered]
        self.lips = (1.0 - smoothstep(-1.0, 0.0, head.lips_edge))[covered]
        self.lip_grooves = np.cumsum(rng.uniform(2.2, 3.4, size=40)) - 60.0  # x (mm) of the lips' wrinkles
        self.lip_groove_depth = rng.uniform(0.5, 1.0, size=40)
        self.forehead_phases = rng.uniform(0.0, 2.0 * np.pi, size=(3, 2))
        self.crow_angles = np.radians([-38.0, -18.0, 2.0, 22.0]) + rng.uniform(-0.08, 0.08, size=4)
        self.waves, self.wave_phases, self.wave_amplitude = micro_waves(rng)
        self.bare = 1.0 - self.lips  # the lips have their own wrinkles

    def pits(self, p: np.ndarray) -> np.ndarray:
        """The pores: the sum of -depth exp(-r^2 / 2 sd^2) over the pores within 3 sd_max of each point."""
        pairs = cKDTree(p).sparse_distance_matrix(self.tree, 3.0 * self.sd.max(), output_type="ndarray")
        i, j, r = pairs["i"], pairs["j"], pairs["v"]
        h = np.zeros(len(p))
        np.add.at(h, i, -self.depth[j] * np.exp(-0.5 * (r / self.sd[j]) ** 2))
        return h

    def lines(self, p: np.ndarray) -> np.ndarray:
        """Grooves (:func:`groove`) drawn in the face's front projection (x, y):

        - forehead lines: three, 26, 35 and 44 mm above the lids, gently waved (1.2 mm) and bowed up 2.5 mm at
          |x| = 40 mm, fading out at |x| 30-46 mm and in strength along their length; tilt 4.5, 3.8, 3.1 deg;
        - crow's feet: four rays 3 to 17 mm from each eye's outer corner (16 mm outside the eye's centre), at -38, -18,
          2 and 22 deg (+-5), tilt 4 deg;
        - nasolabial folds: from beside the nose's wing (|x| 16, y -24 mm) curving down and out to (32, -62), sd 2.2
          mm (soft), tilt 4 deg;
        - lip wrinkles: vertical grooves 2.2 to 3.4 mm apart, fanning out 15 % towards the lips' outline, deepest
          between the mouth line and the outline, tilt up to 7 deg.
        """
        head = self.head
        x, y = p[:, 0], p[:, 1]
        h = np.zeros(len(p))
        for k, (base, (phase_a, phase_b)) in enumerate(zip((26.0, 35.0, 44.0), self.forehead_phases, strict=True)):
            centre = head.lid_y + base + 1.2 * np.sin(x / 22.0 + phase_a) + 2.5 * (x / 40.0) ** 2
            strength = (0.6 + 0.4 * np.sin(x / 9.0 + phase_b)) * (1.0 - smoothstep(30.0, 46.0, np.abs(x)))
            h += groove(y - centre, np.maximum(0.8, self.limit), 4.5 - 0.7 * k) * strength * self.forehead
        corner_x, corner_y = head.eye_x + 16.0, head.eye_y + 1.0
        fold = bezier((16.0, -24.0), (27.0, -36.0), (32.0, -62.0))
        for side in (-1.0, 1.0):
            dx, dy = side * x - corner_x, y - corner_y
            radius, angle = np.hypot(dx, dy), np.arctan2(dy, dx)
            reach = smoothstep(3.0, 6.0, radius) * (1.0 - smoothstep(11.0, 17.0, radius)) * (side * x > 0)
            for a in self.crow_angles:
                off = radius * np.sin(angle - a)
                h += groove(off, np.maximum(0.5, self.limit), 4.0) * reach * (np.cos(angle - a) > 0) * self.front
            distance = polyline_distance(side * x, y, fold)
            along = smoothstep(-60.0, -52.0, y) * (1.0 - smoothstep(-30.0, -24.0, y))
            h += groove(distance, np.maximum(2.2, self.limit), 4.0) * along * (side * x > 0) * self.front
        height = np.clip(np.abs(y - head.mouth_line) / 6.0, 0.0, 1.0)
        along_lip = smoothstep(0.05, 0.3, height) * (1.0 - smoothstep(0.75, 1.0, height))
        fan = x * (1.0 + 0.15 * height)  # the wrinkles fan out a little away from the mouth line
        nearest = np.abs(fan[:, None] - self.lip_grooves).argmin(axis=-1)
        off = fan - self.lip_grooves[nearest]
        h += groove(off, np.maximum(0.45, self.limit), 7.0) * self.lip_groove_depth[nearest] * self.lips * along_lip
        return h

    def micro(self, p: np.ndarray) -> np.ndarray:
        """The micro-relief (:func:`micro_waves`), off the lips."""
        return self.wave_amplitude * np.cos(p @ self.waves.T + self.wave_phases).sum(axis=1) * self.bare

    def __call__(self, p: np.ndarray) -> np.ndarray:
        return self.pits(p) + self.lines(p) + self.micro(p)


def tangent_normals(head: Head, relief: Relief, step_mm: float = 0.25) -> np.ndarray:
    """Tangent-space normals (size, size, 3): n = normalize(-dh/ds_u, -dh/ds_v, 1), the slopes of h along the unit
    u and v directions of the surface by central differences over +-step_mm; (0, 0, 1) outside the islands."""
    normals = np.zeros((*head.covered.shape, 3))
    normals[..., 2] = 1.0
    p = head.points[head.covered]
    for axis, direction in enumerate((head.du, head.dv)):
        unit = direction[head.covered] / np.linalg.norm(direction[head.covered], axis=-1, keepdims=True)
        ahead, behind = relief(p + step_mm * unit), relief(p - step_mm * unit)
        normals[head.covered, axis] = -(ahead - behind) / (2.0 * step_mm)
    return normals / np.linalg.norm(normals, axis=-1, keepdims=True)


def roughness(head: Head) -> np.ndarray:
    """The skin lobe's Beckmann m (size, size): 0.35, the T-zone (the forehead's middle and the nose) 0.28, the lips
    0.20, scalp and neck 0.40; islands dilated, 0.35 beyond."""
    m = np.full(head.x.shape, 0.35)
    t_zone = np.maximum(head.forehead() * (1.0 - smoothstep(16.0, 30.0, np.abs(head.x))), head.nose())
    m += (0.28 - m) * np.maximum(t_zone, head.nose_tip())
    m += (0.40 - m) * np.maximum(head.scalp(), head.neck())
    m += (0.20 - m) * head.lips(1.0)
    values, reached = dilate(m[..., None], head.covered, DILATE_TEXELS)
    values[~reached] = 0.35
    return values[..., 0]


def encode_normals(normals: np.ndarray, covered: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """8-bit codes of n (size, size, 3): code = floor(127.5 (n + 1) + u), u uniform in [0, 1) (unbiased: the mean
    code is 127.5 (n + 1), so slopes near zero do not all round one way); outside the islands (128, 128, 255)."""
    codes = np.floor(127.5 * (normals + 1.0) + rng.uniform(size=normals.shape))
    codes = np.clip(codes, 0, 255).astype(np.uint8)
    codes[~covered] = (128, 128, 255)
    return codes


def main() -> None:
    rng = np.random.default_rng(SEED)
    head = Head(load_mesh(HEAD / "head.obj"), json.loads((HEAD / "landmarks.json").read_text()), SIZE)
    write_png(HEAD / "head_albedo.png", albedo(head, rng))
    normal_codes = encode_normals(tangent_normals(head, Relief(head, rng)), head.covered, rng)
    cv2.imwrite(str(HEAD / "head_normal.png"), normal_codes[..., ::-1])  # OpenCV writes BGR
    cv2.imwrite(str(HEAD / "head_roughness.png"), np.rint(roughness(head) / ROUGHNESS_SCALE * 255.0).astype(np.uint8))
    print(f"wrote {HEAD}/head_albedo.png, head_normal.png and head_roughness.png")


if __name__ == "__main__":
    main()
