"""Writes head_makeup.png and head_eyeshadow.png beside this file: cosmetic maps of the bundled head over its uv.

Each texel of the head's uv islands gets the point of the head it covers (the triangles' positions, mm, interpolated
in uv); the makeup is a function of that point, shaped from the head's own geometry and its landmarks
(recipes/head/landmarks.json, MakeHuman's joint cubes): in head_makeup.png red the foundation, green the blush,
blue the lipstick; head_eyeshadow.png (one channel) the eyeshadow; 0 to 1 as the share of each film's maximum
thickness; zero off the face. 16-bit PNGs stored linearly (renderer.image_io.write_map).

- foundation: the front of the face, |azimuth| about the head's vertical axis under 55 deg fading to 75 deg, up to
  the head's hairline (head_texels.hairline_mm, where the skin maps' paler scalp begins: full to 8 mm below it, none
  2 mm above it, so that no band of bare forehead shows between the film and the scalp), down to a jaw line that
  rises towards the ears (12 mm fade);
- blush: on each cheekbone, 28 mm below and 14 mm outside the eye, a Gaussian stretched (sd 20 mm x 10 mm) up and
  out towards the temple;
- lipstick: the lips, between the mouth line and an upper and a lower lip outline (a Cupid's bow in the upper),
  with a crisp 0.6 mm edge; the mouth line and lips' heights from the midline profile (the lips' two forward peaks);
- eyeshadow: the upper lids, from the lash line (a 1.5 mm edge) full for 4 mm and fading out by 12 mm above it (below
  the brow ridge, rising towards the temple), fading in from the inner corner and out 10 to 20 mm outside the eye.
Run: .venv/bin/python recipes/scenes/make_head_map.py
"""

import json
import sys
from pathlib import Path

import numpy as np

from renderer.image_io import write_map
from renderer.products import load_mesh

HEAD = Path(__file__).resolve().parents[1] / "head"
sys.path.insert(0, str(HEAD))
from head_texels import hairline_mm, lip_outline, smoothstep, texel_points  # noqa: E402  (the head's uv rasteriser, lip outline)

SIZE = 1024
#: Height (mm) of the lash line, the top of the eye's opening, above the eye's landmark (the bundled head's lids: the
#: opening spans -3 to +3 mm about it, the upper lid's skin +3 to +14 mm, the brow ridge above).
LASH_ABOVE_EYE = 3.0


def makeup(points: np.ndarray, mesh, marks: dict) -> np.ndarray:
    """Foundation, blush, lipstick and eyeshadow (size, size, 4) in [0, 1] at the given head points (mm)."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    eye_x, eye_y = marks["joint-l-eye"][0], marks["joint-l-eye"][1]
    azimuth = np.degrees(np.arctan2(x, z - marks["joint-head"][2]))
    jaw = marks["joint-jaw"][1] + 12.0 + 40.0 * (azimuth / 70.0) ** 2  # the jaw line rises towards the ears
    hairline = hairline_mm(azimuth)
    foundation = (1.0 - smoothstep(55.0, 75.0, np.abs(azimuth))) * (1.0 - smoothstep(hairline - 8.0, hairline + 2.0, y))
    foundation *= smoothstep(jaw - 6.0, jaw + 6.0, y)
    blush = np.zeros_like(x)
    for side in (-1.0, 1.0):  # along (0.8, 0.6): up and out towards the temple; across it
        dx, dy = side * x - (eye_x + 14.0), y - (eye_y - 28.0)
        along, across = 0.8 * dx + 0.6 * dy, -0.6 * dx + 0.8 * dy
        blush += (
            np.exp(-0.5 * ((along / 20.0) ** 2 + (across / 10.0) ** 2)) * (side * x > 0) * smoothstep(30.0, 60.0, z)
        )
    lips = 1.0 - smoothstep(-0.3, 0.3, lip_outline(points, mesh))  # the outline shared with the skin maps
    lash = eye_y + LASH_ABOVE_EYE
    shadow = np.zeros_like(x)
    for side in (-1.0, 1.0):
        dx, dy = side * x - eye_x - 2.0, y - lash
        wing = 0.15 * np.clip(dx, 0.0, None)  # the top edge rises towards the temple
        rise = smoothstep(-0.5, 1.0, dy) * (1.0 - smoothstep(4.0 + wing, 12.0 + wing, dy))
        across = smoothstep(-17.0, -9.0, dx) * (1.0 - smoothstep(10.0, 20.0, dx))  # inner corner to outer
        shadow += rise * across * (side * x > 0)
    shadow *= smoothstep(40.0, 55.0, z)  # the front of the face (the lids lie at z ~ 76 mm)
    return np.clip(np.stack([foundation, blush, lips, shadow], axis=-1), 0.0, 1.0)


if __name__ == "__main__":
    head = load_mesh(HEAD / "head.obj")
    points, covered, _ = texel_points(head, SIZE)
    values = makeup(points, head, json.loads((HEAD / "landmarks.json").read_text())) * covered[..., None]
    out = Path(__file__).resolve().parent
    write_map(out / "head_makeup.png", values[..., :3])
    write_map(out / "head_eyeshadow.png", values[..., 3])
    print(f"wrote {out}/head_makeup.png and head_eyeshadow.png")
