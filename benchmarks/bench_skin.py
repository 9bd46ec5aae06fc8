"""Benchmark: makeup on skin, the cost of subsurface scattering against the rest of the frame.

Two scenes at 512 and 1024 square, each frame rendered with and without scattering (the difference is the cost of
the eight blur passes and their accumulation):

- "head (masked)": the demo's face (recipes/scenes/face.toml): the built-in head wearing F1, B1, E1 and L1 through
  the cosmetic maps (four layers with thickness maps, bands mode as planned), a shadowing key light and a point fill
  light; skin covers about a third of the frame, and only skin pixels are blurred;
- "skin fills the frame": the same head seen from 16 cm, a close-up of the face in which every pixel is skin and is
  blurred: what a blur of the full frame costs.

Frames are rendered in-process, kmpipe's plan and renderer scene of each (kmpipe.stages.render.renderer_scenes)
drawn by renderer.skin.render_skin (no file writing), after a warm-up frame; the median of REPEATS. Target from the
issue: a full frame with skin, three makeup layers, shadows and SSS at 512 x 512 in under 0.3 s on this 2-core
machine.

Run alone: ``.venv/bin/python benchmarks/bench_skin.py``.
"""

from __future__ import annotations

import re
import tempfile
import time
from pathlib import Path

import numpy as np
from common import Table, stage_face

from kmpipe.formats.scene import load_scene
from kmpipe.stages.render import renderer_scenes
from kmpipe.stages.render_plan import plan_scene
from renderer.skin import render_skin

SIZES = (512, 1024)
REPEATS = 5
TARGET_S = 0.3


def _time(render) -> float:
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        render()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def _scenes(folder: Path) -> dict[str, Path]:
    face = stage_face(folder)
    # this table measures the blur: one sample a pixel, no environment or backdrop (bench_look has the full look)
    face = re.sub(r"\[(environment|backdrop)\][^\[]*", "", face).replace("[output]", "[output]\nantialias = 1")
    close_up = face.replace("distance_mm = 780.0", "distance_mm = 160.0")
    scenes = {}
    for label, text in (("head (masked)", face), ("skin fills the frame", close_up)):
        for size in SIZES:
            path = folder / f"{label.split()[0]}_{size}.toml"
            path.write_text(text.replace("resolution = [512, 512]", f"resolution = [{size}, {size}]"), encoding="utf-8")
            scenes[f"{label}|{size}"] = path
    return scenes


def _measure(path: Path) -> tuple[float, float, float, str]:
    """Skin share of the frame, median seconds per frame with and without scattering, and the planned mode."""
    scene = load_scene(path)
    plan = plan_scene(scene)
    [with_sss] = renderer_scenes(scene, plan, [0.0])
    [without] = renderer_scenes(scene, plan, [0.0], scattering=False)
    skin_share = float(np.mean(render_skin(with_sss).sum(axis=-1) > 0.0))  # the warm-up frame: shaders, context size
    return skin_share, _time(lambda: render_skin(with_sss)), _time(lambda: render_skin(without)), plan.mode


def run() -> list[list[str]]:
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        (Path(folder) / "face").mkdir()
        for key, path in _scenes(Path(folder) / "face").items():
            label, size = key.split("|")
            skin_share, with_sss, without, mode = _measure(path)
            cost = with_sss - without
            met = ("yes" if with_sss < TARGET_S else "no") if size == "512" else "-"
            rows.append([
                label, f"{size} x {size}", f"{skin_share:.0%}", f"{without * 1e3:.0f}", f"{cost * 1e3:.0f}",
                f"{with_sss * 1e3:.0f}", f"{cost / with_sss:.0%}", mode, met,
            ])  # fmt: skip
    return rows


def tables(rows: list[list[str]]) -> list[Table]:
    return [
        Table(
            "Makeup on skin: subsurface scattering against the rest of the frame (F1 + B1 + E1 + L1, cosmetic maps)",
            [
                "scene",
                "resolution",
                "covered pixels",
                "frame without SSS, ms",
                "SSS passes, ms",
                "frame with SSS, ms",
                "SSS share",
                "mode",
                "512 target (< 0.3 s) met",
            ],
            rows,
            [
                "llvmpipe (OSMesa) on the CPU; median of 5 frames after a warm-up; times include shadow maps, the "
                "skin pass, reading the targets back and summing them (no file writing)",
                "SSS passes: 4 Gaussians x (horizontal + vertical) 7-tap blurs with the accumulation, restricted to "
                "skin pixels; 'skin fills the frame' is what blurring every pixel costs",
            ],
        )
    ]


def main() -> None:
    for table in tables(run()):
        table.print()


if __name__ == "__main__":
    main()
