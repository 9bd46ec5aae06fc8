"""Writes head_makeup.png beside this file: the procedural cosmetic map of the built-in head mesh.

Red marks the foundation, green the blush, blue the lipstick (renderer.cosmetic_maps.head_makeup), 0 to 1 as the
share of each film's maximum thickness; a 16-bit PNG stored linearly.
Run: .venv/bin/python recipes/scenes/make_head_map.py
"""

from pathlib import Path

from renderer.cosmetic_maps import head_makeup
from renderer.image_io import write_map

if __name__ == "__main__":
    out = Path(__file__).resolve().parent / "head_makeup.png"
    write_map(out, head_makeup(512, 512))
    print(f"wrote {out}")
