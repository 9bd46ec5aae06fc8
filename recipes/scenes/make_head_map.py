"""Writes head_makeup.png and head_eyeshadow.png beside this file: cosmetic maps of the bundled head over its uv.

Each texel of the head's uv islands gets the point of the head it covers (the triangles' positions, mm, interpolated
in uv); the makeup is a function of that point, shaped from the head's own geometry and its landmarks
(recipes/head/landmarks.json, MakeHuman's joint cubes): in head_makeup.png red the foundation, green the blush,
blue the lipstick; head_eyeshadow.png (one channel) the eyeshadow; 0 to 1 as the share of each film's maximum
thickness; zero off the face. 16-bit PNGs stored linearly (renderer.image_io.write_map).

- foundation: the front of the face, |azimuth| about the head's vertical axis under 55 deg fading to 75 deg, up to
  a hairline 25 to 55 mm above the eyes (a 30 mm fade), down to a jaw line that rises towards the ears (12 mm fade);
- blush: on each cheekbone, 28 mm below and 14 mm outside the eye, a Gaussian stretched (sd 20 mm x 10 mm) up and
  out towards the temple;
- lipstick: the lips, between the mouth line and an upper and a lower lip outline (a Cupid's bow in the upper),
  with a crisp 0.6 mm edge; the mouth line and lips' heights from the midline profile (the lips' two forward peaks);
- eyeshadow: the upper lids above the lid landmarks, fading up to the brow (sd 6 mm) and out (sd 15 mm).
Run: .venv/bin/python recipes/scenes/make_head_map.py
"""

import json
from pathlib import Path

import numpy as np

from renderer.image_io import write_map
from renderer.products import load_mesh

HEAD = Path(__file__).resolve().parents[1] / "head"
SIZE = 1024


def smoothstep(lo, hi, x):
    """0 below lo, 1 above hi, 3t^2 - 2t^3 between."""
    t = np.clip((x - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def texel_points(mesh, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The head's point (mm) at each texel's centre (size, size, 3) and where the uv islands cover (size, size)."""
    uv = mesh.visual.uv * size - 0.5  # texel centres at integers; row 0 is v = 1 (the image's top)
    uv[:, 1] = size - 1 - uv[:, 1]
    points, covered = np.zeros((size, size, 3)), np.zeros((size, size), bool)
    for tri in mesh.faces:
        corners = uv[tri]
        lo, hi = np.floor(corners.min(axis=0)).astype(int), np.ceil(corners.max(axis=0)).astype(int) + 1
        xs, ys = np.meshgrid(np.arange(max(lo[0], 0), min(hi[0], size)), np.arange(max(lo[1], 0), min(hi[1], size)))
        (ax, ay), (bx, by), (cx, cy) = corners
        area = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
        if area == 0:
            continue
        w1 = ((xs - ax) * (cy - ay) - (cx - ax) * (ys - ay)) / area
        w2 = ((bx - ax) * (ys - ay) - (xs - ax) * (by - ay)) / area
        w0 = 1.0 - w1 - w2
        inside = (w0 >= -0.02) & (w1 >= -0.02) & (w2 >= -0.02)  # a little over the edges: no gaps at the seams
        p = mesh.vertices[tri]
        points[ys[inside], xs[inside]] = w0[inside, None] * p[0] + w1[inside, None] * p[1] + w2[inside, None] * p[2]
        covered[ys[inside], xs[inside]] = True
    return points, covered


def mouth(mesh) -> tuple[float, float, float]:
    """The mouth line's height and the upper and lower lips' forward peaks (y, mm) from the midline profile."""
    midline = mesh.vertices[np.abs(mesh.vertices[:, 0]) < 0.5]
    below_nose = midline[(midline[:, 1] < -38.0) & (midline[:, 1] > -80.0)]
    upper = below_nose[np.argmax(below_nose[:, 2])]
    lower_side = below_nose[below_nose[:, 1] < upper[1] - 6.0]
    lower = lower_side[np.argmax(lower_side[:, 2])]
    return (upper[1] + lower[1]) / 2.0, upper[1], lower[1]


def makeup(points: np.ndarray, mesh, marks: dict) -> np.ndarray:
    """Foundation, blush, lipstick and eyeshadow (size, size, 4) in [0, 1] at the given head points (mm)."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    eye_x, eye_y = marks["joint-l-eye"][0], marks["joint-l-eye"][1]
    azimuth = np.degrees(np.arctan2(x, z - marks["joint-head"][2]))
    jaw = marks["joint-jaw"][1] + 12.0 + 40.0 * (azimuth / 70.0) ** 2  # the jaw line rises towards the ears
    foundation = (1.0 - smoothstep(55.0, 75.0, np.abs(azimuth))) * (1.0 - smoothstep(eye_y + 25.0, eye_y + 55.0, y))
    foundation *= smoothstep(jaw - 6.0, jaw + 6.0, y)
    blush = np.zeros_like(x)
    for side in (-1.0, 1.0):  # along (0.8, 0.6): up and out towards the temple; across it
        dx, dy = side * x - (eye_x + 14.0), y - (eye_y - 28.0)
        along, across = 0.8 * dx + 0.6 * dy, -0.6 * dx + 0.8 * dy
        blush += (
            np.exp(-0.5 * ((along / 20.0) ** 2 + (across / 10.0) ** 2)) * (side * x > 0) * smoothstep(30.0, 60.0, z)
        )
    line, upper, lower = mouth(mesh)
    half_width = 25.0
    across = np.clip(np.abs(x) / half_width, 0.0, 1.0)
    bow = 1.5 * np.exp(-((x / 5.0) ** 2))  # the Cupid's bow: a dip at the middle of the upper lip
    top = (upper - line + 4.0) * np.sqrt(1.0 - across**2) ** 0.7 - bow
    bottom = (line - lower + 5.0) * np.sqrt(1.0 - across**2) ** 0.6
    height = np.where(y > line, top, bottom)
    edge = np.abs(y - line) - height  # mm outside the outline (negative inside)
    lips = (1.0 - smoothstep(-0.3, 0.3, edge)) * (np.abs(x) < half_width) * (z > 75.0)
    lid_y = marks["joint-l-upperlid"][1]
    shadow = np.zeros_like(x)
    for side in (-1.0, 1.0):
        dx, dy = side * x - eye_x - 3.0, y - lid_y
        shadow += np.exp(-0.5 * (dx / 15.0) ** 2 - 0.5 * (np.clip(dy, 0.0, None) / 6.0) ** 2) * (side * x > 0)
        shadow *= np.where(side * x > 0, smoothstep(-4.0, 0.0, dy), 1.0) * (z > 60.0)
    return np.clip(np.stack([foundation, blush, lips, shadow], axis=-1), 0.0, 1.0)


if __name__ == "__main__":
    head = load_mesh(HEAD / "head.obj")
    points, covered = texel_points(head, SIZE)
    values = makeup(points, head, json.loads((HEAD / "landmarks.json").read_text())) * covered[..., None]
    out = Path(__file__).resolve().parent
    write_map(out / "head_makeup.png", values[..., :3])
    write_map(out / "head_eyeshadow.png", values[..., 3])
    print(f"wrote {out}/head_makeup.png and head_eyeshadow.png")
