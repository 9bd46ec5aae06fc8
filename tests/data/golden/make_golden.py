"""Regenerate the golden images: ``.venv/bin/python tests/data/golden/make_golden.py`` (from the repository root).

Writes ``wedge.png`` (the wedge scene's thickness map), fits the sample materials into a temporary folder, renders
each scene (``<scene>.toml`` here) and copies its EXR frames to ``<scene>_NNN.exr`` here. tests/test_golden_images.py
imports :func:`stage` and :func:`render` from this file, so the test and the goldens render the scenes the same way.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

GOLDEN = Path(__file__).resolve().parent
REPO = GOLDEN.parents[2]
SCENES = ("compact", "lipstick", "wedge", "face")
#: Scenes rendered with and without subsurface scattering (kmpipe render --ab-sss): frame 000 with, 001 without.
AB_SCENES = ("face",)
MATERIALS = ("F1", "F2", "B1", "L1", "L2")
#: The wedge's thickness map: a left-to-right ramp, 16-bit, WEDGE_SIZE = (width, height).
WEDGE_SIZE = (64, 8)


def write_wedge(path: Path) -> None:
    """A one-channel 16-bit PNG: 0 in column 0 rising linearly to 65535 in the last column, the same in every row."""
    import cv2

    width, height = WEDGE_SIZE
    ramp = np.round(np.linspace(0.0, 65535.0, width)).astype(np.uint16)
    if not cv2.imwrite(str(path), np.tile(ramp, (height, 1))):
        raise OSError(f"cannot write {path}")


def stage(folder: Path) -> Path:
    """Fit the sample materials into ``folder/materials`` and copy the scene files, wedge.png and the head's
    cosmetic map (recipes/scenes/head_makeup.png) beside them."""
    from kmpipe import cli

    (folder / "materials").mkdir(parents=True, exist_ok=True)
    for name in MATERIALS:
        manifest = REPO / "recipes" / "samples" / name / "manifest.toml"
        if cli.main(["fit", str(manifest), "-o", str(folder / "materials" / f"{name}.json")]) != 0:
            raise RuntimeError(f"kmpipe fit {manifest} failed")
    sources = [*(GOLDEN / f"{scene}.toml" for scene in SCENES), GOLDEN / "wedge.png"]
    for source in [*sources, REPO / "recipes" / "scenes" / "head_makeup.png"]:
        shutil.copy(source, folder / source.name)
    return folder


def render(staged: Path, scene: str, out_dir: Path) -> list[Path]:
    """Render ``scene`` from a :func:`stage` folder into ``out_dir``; its EXR frames in order."""
    from kmpipe.stages.render import render_scene

    written = render_scene(staged / f"{scene}.toml", out_dir, ab_scattering=scene in AB_SCENES, echo=lambda _: None)
    return [p for p in written if p.suffix == ".exr"]


def golden_paths(scene: str) -> list[Path]:
    return sorted(GOLDEN.glob(f"{scene}_[0-9][0-9][0-9].exr"))


def main() -> int:
    write_wedge(GOLDEN / "wedge.png")
    with tempfile.TemporaryDirectory() as tmp:
        staged = stage(Path(tmp) / "scenes")
        for scene in SCENES:
            for old in golden_paths(scene):
                old.unlink()
            for i, frame in enumerate(render(staged, scene, Path(tmp) / "out" / scene)):
                target = GOLDEN / f"{scene}_{i:03d}.exr"
                shutil.copyfile(frame, target)
                print(f"wrote {target.relative_to(REPO)}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    sys.exit(main())
