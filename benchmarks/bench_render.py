"""Benchmark: turntable rendering speed per render mode and resolution, with each mode's Delta E 2000 against exact.

One product (sample F1, fitted from recipes/samples/F1, 20 um of foundation over ColorChecker light skin) on the
compact pan mesh over a ground, a specular lobe, a shadowing directional light and a point fill light, a 36-frame
turntable, written as EXR and PNG like ``kmpipe render`` does (a warm-up frame first,
so context creation and shader compilation are left out), one sample a pixel and no videos: this table measures the
render modes (antialiasing, the environment and the backdrop are bench_look's). Target from the issue: 36 frames at
512 x 512 in under 10 s on this 2-core machine.

Run alone: ``.venv/bin/python benchmarks/bench_render.py``.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from common import REPO, Table

from kmpipe.cli import main as kmpipe_main
from kmpipe.formats.scene import load_scene
from kmpipe.stages.render import render_scene
from kmpipe.stages.render_plan import plan_scene

FRAMES = 36
MODES = ("rgb", "bands:6", "bands:12", "exact")
SIZES = (512, 1024)

SCENE = """[scene]
name = "benchmark"
illuminant = "D65"
mesh = "compact"
resolution = [{size}, {size}]
mode = "{mode}"

[substrate]
reflectance = "colorchecker:light skin"

[[layer]]
material = "F1.json"
thickness = "20 um"
specular = {{ roughness = 0.3, ior = 1.5 }}

[[light]]
direction = [0.3, 0.5, 1.0]

[[light]]
kind = "point"
position = [-150.0, 80.0, 120.0]
radiance = [0.3, 0.3, 0.35]
shadows = false

[ground]
reflectance = 0.4

[camera]
elevation_deg = 35.0
distance_mm = 180

[output]
antialias = 1
video = []

[turntable]
frames = {frames}
"""


def run() -> list[list[str]]:
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        status = kmpipe_main(["fit", str(REPO / "recipes/samples/F1/manifest.toml"), "-o", str(folder / "F1.json")])
        if status != 0:
            raise RuntimeError("fitting the benchmark's material failed")
        warm = folder / "warm.toml"
        warm.write_text(SCENE.format(size=64, mode="rgb", frames=1), encoding="utf-8")
        render_scene(warm, folder / "warm", echo=lambda _: None)
        for mode in MODES:
            for size in SIZES:
                scene = folder / f"{mode.replace(':', '')}_{size}.toml"
                scene.write_text(SCENE.format(size=size, mode=mode, frames=FRAMES), encoding="utf-8")
                loaded = load_scene(scene)
                plan = plan_scene(loaded)
                chosen = next(c for c in plan.tables.candidates if c.mode == plan.mode)
                start = time.perf_counter()
                render_scene(loaded, folder / scene.stem, plan=plan, echo=lambda _: None)
                seconds = time.perf_counter() - start
                rows.append(
                    [
                        mode,
                        f"{size} x {size}",
                        f"{seconds:.2f}",
                        f"{FRAMES / seconds:.1f}",
                        f"{chosen.max_dE:.3f}",
                        "yes" if size != 512 or seconds < 10.0 else "no",
                    ]
                )
    return rows


def tables(rows: list[list[str]]) -> list[Table]:
    return [
        Table(
            f"Turntable rendering: {FRAMES} frames of F1 on the compact pan (EXR + PNG written per frame)",
            ["mode", "resolution", "s", "frames/s", "dE00 vs exact (this scene)", "512 target (< 10 s) met"],
            rows,
            [
                "llvmpipe (OSMesa) on the CPU; times include writing both files per frame",
                "Delta E 2000 of the mode against exact on the scene's own stack, as the planner measures it",
            ],
        )
    ]


def main() -> None:
    for table in tables(run()):
        table.print()


if __name__ == "__main__":
    main()
