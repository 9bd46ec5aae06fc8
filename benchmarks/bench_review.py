"""Benchmark: the shade review of 10 foundation shades x 8 skin tones x 3 illuminants, tiles 256 x 256, end to end.

The shades are the eight of ``recipes/review/`` and the bundled foundations F1 and F2, each fitted from its
simulated drawdowns (lsq, 5 nm); the tones the eight built-in chart and complexion samples; the illuminants D65, A
and F11. ``kmpipe review`` runs in a fresh process from an empty output folder (interpreter start, fits,
validations, 8 rows of 10 x 3 + 3 tiles, the sheet, CSV, JSON and page), with 1 and with 2 worker processes, and
again on the finished folder (everything cached). Target (issue 15): under 60 s end to end, a cached re-run under 2 s.

Run alone: ``.venv/bin/python benchmarks/bench_review.py``.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
import time
from pathlib import Path

from common import REPO, Table

TARGET_S = 60.0
CACHED_TARGET_S = 2.0
SHADES = ("V110", "V120", "V130", "V140", "V150", "V160", "V170", "V180")


def _recipe(folder: Path) -> Path:
    products = []
    for name in SHADES:
        shutil.copytree(REPO / "recipes" / "review" / "shades" / name, folder / name)
    for name in ("F1", "F2"):
        shutil.copytree(REPO / "recipes" / "samples" / name, folder / name)
    for name in (*SHADES, "F1", "F2"):
        products.append(f'[[product]]\nname = "{name}"\nfit = "{name}/manifest.toml"\n'
                        'layer = [{ material = "self", thickness = "15 um" }]\n')  # fmt: skip
    names = ", ".join(f'"{n}"' for n in (*SHADES, "F1", "F2"))
    text = ('[line]\nname = "Benchmark range"\n[scene]\nmesh = "compact"\n[substrate]\nreflectance = 0.8\n'
            '[[light]]\ndirection = [0.4, 0.8, 0.6]\n' + "\n".join(products) +
            f'\n[review]\nfoundations = [{names}]\ntones = ["builtin"]\nilluminants = ["D65", "A", "F11"]\n'
            'tile = 256\n')  # fmt: skip
    path = folder / "recipe.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _review(recipe: Path, out: Path, workers: int) -> float:
    start = time.perf_counter()
    subprocess.run([str(REPO / ".venv" / "bin" / "kmpipe"), "review", str(recipe), "-o", str(out), "--workers",
                    str(workers)], check=True, capture_output=True)  # fmt: skip
    return time.perf_counter() - start


def run() -> list[list[str]]:
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        recipe = _recipe(Path(folder))
        for workers in (1, 2):
            out = Path(folder) / f"out{workers}"
            seconds = _review(recipe, out, workers)
            cached = _review(recipe, out, workers)
            tiles = len(list(out.glob("review/tones/*/*.png")))
            rows.append([f"local, {workers} process{'es' if workers > 1 else ''}", str(tiles), f"{seconds:.1f}",
                         f"{tiles / seconds:.1f}", f"{cached:.2f}", "yes" if seconds < TARGET_S else "no",
                         "yes" if cached < CACHED_TARGET_S else "no"])  # fmt: skip
    return rows


def tables(rows: list[list[str]]) -> list[Table]:
    return [
        Table(
            "The shade review: 10 shades x 8 skin tones x 3 illuminants, tiles 256 x 256 (kmpipe review)",
            ["executor", "tiles", "s", "tiles/s", "cached re-run, s", "< 60 s", "cached < 2 s"],
            rows,
            [
                "each run a fresh kmpipe process from an empty output folder: 10 fits and validations, 8 rows "
                "(10 x 3 worn tiles and 3 bare ones each), the sheet, CSV, JSON and page; then the same command again",
                "tiles: the bundled head's cheek, subsurface scattering, a soft key and the studio environment, "
                "1 sample a pixel (shown at half size or less), rendered as planned; llvmpipe (OSMesa) on the CPU",
            ],
        )
    ]


def main() -> None:
    for table in tables(run()):
        table.print()


if __name__ == "__main__":
    main()
