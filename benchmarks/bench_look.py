"""Benchmark: the full look on the bundled head, what each pass costs and how much each option changes the frame.

The scene is the demo's face (recipes/scenes/face.toml) at 1024 x 1024: the bundled head with its skin albedo
texture, normal map and roughness map, F1 + B1 + E1 + L1 through the cosmetic maps (four mapped layers, the
planned mode), subsurface scattering, the built-in studio environment with baked ambient occlusion (the head's and
the sweep's), a key area light (20 degrees, soft shadows) and a point fill, 4 samples a pixel as the planner takes
them (4 x multisampling: the maps' texels are coarser than a pixel). Each option is then turned off (or the
antialiasing changed) one at a time; for each: the median time of a frame (rendered in-process, kmpipe's renderer
scene drawn by renderer.skin.render_skin, no file writing, after a warm-up; the settings timed round-robin) and the
Delta E 2000 of the frame against the most exact setting (everything on, 3 x 3 supersampling, soft shadows computed at
every pixel), per pixel over the whole frame (the head and the backdrop; linear sRGB -> XYZ -> CIELAB, D65; mean and
95th percentile). The once-per-scene costs (planning, the environment's prefilters, the ambient occlusion bake) are
timed apart.

Second table: a 36-frame 512 x 512 packshot turntable (F1 on the compact pan with the studio environment, a sweep
backdrop, a soft key light and 4 samples a pixel, multisampled as planned or supersampled) through ``kmpipe render``,
files written; target <= 10 s.

Run alone: ``.venv/bin/python benchmarks/bench_look.py``.
"""

from __future__ import annotations

import dataclasses
import subprocess
import tempfile
import time
from pathlib import Path

import colour
import numpy as np
from common import REPO, Table, stage_face

from kmpipe.formats.scene import load_scene
from kmpipe.stages.render import renderer_scenes
from kmpipe.stages.render_plan import plan_scene
from renderer import environment as environment_module
from renderer.skin import render_skin

SIZE = 1024
REPEATS = 3
TARGET_S = 1.0
TURNTABLE_TARGET_S = 10.0
FULL = "full look (4 x multisampling, as planned)"


def _median_times(renders: dict) -> dict[str, tuple[float, np.ndarray]]:
    """Median time and image of each render, timed round-robin (every variant once per round, REPEATS rounds after a
    warm-up round) so that the machine's drift over the run falls on every variant alike."""
    images = {label: render() for label, render in renders.items()}  # warm-up: shaders, context size, textures
    times: dict[str, list[float]] = {label: [] for label in renders}
    for _ in range(REPEATS):
        for label, render in renders.items():
            start = time.perf_counter()
            images[label] = render()
            times[label].append(time.perf_counter() - start)
    return {label: (float(np.median(times[label])), images[label]) for label in renders}


def _lab(image: np.ndarray) -> np.ndarray:
    xyz = colour.RGB_to_XYZ(np.clip(image, 0.0, None), colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False)
    return colour.XYZ_to_Lab(xyz, colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])


def _delta_e(image: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """Mean and 95th percentile of the per-pixel Delta E 2000 between two frames (linear sRGB)."""
    d = colour.delta_E(_lab(image), _lab(reference), method="CIE 2000")
    return float(np.mean(d)), float(np.percentile(d, 95))


def _folder(folder: Path) -> Path:
    """The face scene at SIZE px with its materials and maps laid out as the demo lays them out."""
    text = stage_face(folder / "face").replace("resolution = [512, 512]", f"resolution = [{SIZE}, {SIZE}]")
    path = folder / "face" / "face.toml"
    path.write_text(text, encoding="utf-8")
    return path


def look_rows(folder: Path) -> tuple[list[list[str]], list[list[str]]]:
    path = _folder(folder)
    start = time.perf_counter()
    scene = load_scene(path)
    plan = plan_scene(scene)
    planned = time.perf_counter() - start
    environment_module._cache.clear()
    start = time.perf_counter()
    environment_module.prefiltered(environment_module.Environment(scene.environment))
    prefilter = time.perf_counter() - start
    start = time.perf_counter()
    [full] = renderer_scenes(scene, plan, [0.0])  # bakes the ambient occlusion
    built = time.perf_counter() - start
    hard = [
        dataclasses.replace(light, angle_deg=0.0) if hasattr(light, "angle_deg") else light for light in full.lights
    ]
    assert (full.multisamples, full.supersampling) == (4, 1), "the planner no longer multisamples the full look"
    variants = {
        FULL: full,
        "2 x 2 supersampling instead": dataclasses.replace(full, supersampling=2, multisamples=1),
        "3 x 3 supersampling, soft shadows at every pixel (the reference)": dataclasses.replace(
            full, supersampling=3, multisamples=1, soft_shadow_scale=1
        ),
        "1 sample a pixel": dataclasses.replace(full, multisamples=1),
        "soft shadows at every pixel, not at half resolution": dataclasses.replace(full, soft_shadow_scale=1),
        "no normal map": dataclasses.replace(full, normal_map=None),
        "no roughness map": dataclasses.replace(full, substrate_roughness=None),
        "no ambient occlusion": dataclasses.replace(full, occlusion=None),
        "no environment light": dataclasses.replace(full, environment=None, occlusion=None),
        "hard shadows (no area light)": dataclasses.replace(full, lights=hard),
        "no subsurface scattering": dataclasses.replace(full, scattering=None),
    }
    # Supersampled frames need framebuffers large enough to push the multisampled ones out of the renderer's pool:
    # timed round-robin with the others, each frame after them would pay for new ones. They are timed apart.
    multisampled = {label: s for label, s in variants.items() if s.supersampling == 1}
    supersampled = {label: s for label, s in variants.items() if s.supersampling > 1}
    timed = {}
    for group in (multisampled, supersampled):
        timed |= _median_times({label: lambda s=s: render_skin(s) for label, s in group.items()})
    timed = {label: timed[label] for label in variants}
    reference = timed["3 x 3 supersampling, soft shadows at every pixel (the reference)"][1]
    full_time = timed[FULL][0]
    rows = []
    for label, (seconds, image) in timed.items():
        mean, p95 = _delta_e(image, reference)
        share = "-" if label == FULL else f"{(full_time - seconds) * 1e3:+.0f}"
        met = ("yes" if seconds <= TARGET_S else "no") if label == FULL else "-"
        rows.append([label, f"{seconds:.2f}", share, f"{mean:.2f}", f"{p95:.2f}", met])
    once = [
        ["load the scene and plan it", f"{planned:.2f}"],
        ["prefilter the environment (irradiance + 7 specular levels)", f"{prefilter:.2f}"],
        ["build the renderer scene (ambient occlusion bake, 96 directions)", f"{built:.2f}"],
    ]
    return rows, once


PACKSHOT = """[scene]
name = "F1 packshot"
mesh = "compact"
resolution = [512, 512]
[substrate]
reflectance = 0.8
[[layer]]
material = "materials/F1.json"
thickness = "40 um"
specular = { roughness = 0.45, ior = 1.5 }
[[light]]
direction = [0.4, 0.8, 0.6]
radiance = [0.7, 0.7, 0.7]
angle_deg = 20.0
[environment]
intensity = 0.8
[backdrop]
kind = "sweep"
reflectance = 0.5
[camera]
elevation_deg = 30.0
[turntable]
frames = 36
[output]
tone_map = "reinhard"
antialias = 2
video = []
"""


def turntable_rows(folder: Path) -> list[list[str]]:
    path = folder / "face" / "packshot.toml"
    path.write_text(PACKSHOT, encoding="utf-8")
    rows = []
    for label, text in (("environment + sweep + soft key, 4 x multisampling (planned)", PACKSHOT),
                        ("the same, 2 x 2 supersampling", PACKSHOT.replace("antialias = 2", 'antialias = 2\n'
                                                                           'antialias_method = "supersample"')),
                        ("no environment, no backdrop, hard key, 1 sample",
                         PACKSHOT.replace("[environment]\nintensity = 0.8\n", "").replace(
                             "[backdrop]\nkind = \"sweep\"\nreflectance = 0.5\n", "").replace(
                             "angle_deg = 20.0\n", "").replace("antialias = 2", "antialias = 1"))):  # fmt: skip
        path.write_text(text, encoding="utf-8")
        start = time.perf_counter()
        subprocess.run([str(REPO / ".venv" / "bin" / "kmpipe"), "render", str(path), "-o", str(folder / "out")],
                       check=True, capture_output=True)  # fmt: skip
        seconds = time.perf_counter() - start
        rows.append([label, f"{seconds:.1f}", f"{36 / seconds:.1f}", "yes" if seconds <= TURNTABLE_TARGET_S else "no"])
    return rows


def run() -> dict:
    with tempfile.TemporaryDirectory() as folder:
        rows, once = look_rows(Path(folder))
        return {"look": rows, "once": once, "turntable": turntable_rows(Path(folder))}


def tables(result: dict) -> list[Table]:
    return [
        Table(
            f"The full look on the bundled head at {SIZE} x {SIZE}: time per frame and what each option changes",
            ["setting", "s per frame", "saves, ms", "dE00 vs reference, mean", "dE00, 95th pct", "target (<= 1 s) met"],
            result["look"],
            [
                "full look: skin albedo texture + normal map + roughness map, F1 + B1 + E1 + L1 mapped, subsurface "
                "scattering, the studio environment with baked ambient occlusion, a 20 degree key (soft shadows) and a "
                "point fill, 4 x multisampling (as planned); each other row changes one thing",
                "median of 3 frames after a warm-up, the settings timed in turn (one frame each per round; the "
                "supersampled two apart), in-process (renderer.skin.render_skin), no file writing; "
                "llvmpipe (OSMesa) on the CPU",
                "dE00 per pixel against everything on at 3 x 3 supersampling with soft shadows at every pixel, over "
                "the whole frame (head and sweep)",
            ],
        ),
        Table(
            "The full look: once-per-scene work (not per frame)",
            ["step", "s"],
            result["once"],
            ["the prefilters are cached per environment image in a process; the bake per mesh and scene"],
        ),
        Table(
            "A 36-frame 512 x 512 packshot turntable (F1 on the compact pan, kmpipe render, EXR + PNG per frame)",
            ["setting", "s", "frames/s", "target (<= 10 s) met"],
            result["turntable"],
            ["wall time of the command, interpreter start and planning included"],
        ),
    ]


def main() -> None:
    for table in tables(run()):
        table.print()


if __name__ == "__main__":
    main()
