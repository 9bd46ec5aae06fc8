"""Benchmark: product lines end to end with ``kmpipe run``, per executor, and fully cached re-runs.

Two lines:

- the demo line, ``recipes/demo/recipe.toml`` (sessions replayed from recorded CS-2000 logs, fits, validation,
  turntables of every product, videos, the sheet and the report index). Targets: under 2 minutes on this 2-core
  machine, a cached re-run under 3 s;
- a 16-product line (:func:`sixteen_products`: the six bundled samples fitted once, 16 products on the compact and the
  lipstick at several thicknesses, the demo's scene, 8 frames each), for the parallel speed-up: the throughput of 2
  workers against 1, a Dask local cluster against the local pool, a cached re-run against interpreter start.

Each configuration starts from an empty output folder in a fresh ``kmpipe`` process (start-up, imports and the GL
context count, as for a user); the cached re-run is a second ``kmpipe run`` on the finished folder. CPU seconds are
those of the command and every process it started (user + system); "cores busy" is CPU seconds over wall seconds.

Run alone: ``.venv/bin/python benchmarks/bench_run.py``.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import REPO, Table, best_of

RECIPE = REPO / "recipes" / "demo" / "recipe.toml"
CONFIGURATIONS = (
    ("local, 1 process", ["--workers", "1"], {}),
    ("local, 2 processes", ["--workers", "2"], {}),
    ("dask local cluster, 2 workers", ["--executor", "dask", "--workers", "2"], {}),
)
#: The 16-product line's configurations, each with the cores it may use (None: all); the last two render through
#: llvmpipe on one thread (LP_NUM_THREADS=1), to show how much of one process's rendering already runs on the second
#: core, and then on one core alone (its affinity), to show how the workers scale with the cores they are given.
ONE_THREAD = {"LP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
SCALING = (
    *((label, options, env, None) for label, options, env in CONFIGURATIONS),
    ("local, 1 process, llvmpipe on 1 thread", ["--workers", "1"], {"LP_NUM_THREADS": "1"}, None),
    ("local, 1 process on 1 core", ["--workers", "1"], ONE_THREAD, {0}),
)
TARGET_S, CACHED_TARGET_S = 120.0, 3.0
SAMPLES = ("L1", "L2", "F1", "F2", "B1", "E1")


def _kmpipe(*args: str, env: dict[str, str] | None = None, cores: set[int] | None = None) -> tuple[float, float]:
    """Wall and CPU seconds (user + system, of the command and the processes it started) of ``kmpipe ARGS``, on
    ``cores`` alone if given (the CPU affinity of the command and all it starts)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    pinned = None if cores is None else (lambda: os.sched_setaffinity(0, cores))
    done = subprocess.run([sys.executable, "-m", "kmpipe", *args], capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, preexec_fn=pinned)  # fmt: skip
    seconds = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode not in (0, 1):
        raise RuntimeError(f"kmpipe {args[0]} failed ({done.returncode}): {done.stderr[-2000:]}")
    return seconds, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _frames(out: Path) -> int:
    return len(list(out.glob("frames/*/frame_*.exr")))


def sixteen_products(folder: Path) -> Path:
    """Write a 16-product line into ``folder``: the bundled samples fitted (``kmpipe fit``), then a recipe with the
    demo line's scene (compact, sweep, soft key, environment; 384 px, 8 frames) whose products use them, on the
    compact at 20-60 um and on the lipstick at 1 mm. Returns the recipe's path."""
    for sample in SAMPLES:
        manifest = REPO / "recipes" / "samples" / sample / "manifest.toml"
        _kmpipe("fit", str(manifest), "-o", str(folder / f"{sample}.json"))
    scene = RECIPE.read_text().split("# ----- the products")[0].replace('name = "Demo line"', 'name = "16 products"')
    products = []
    for index in range(16):
        sample = SAMPLES[index % len(SAMPLES)]
        lipstick = sample.startswith("L")
        thickness = "1 mm" if lipstick else ("20 um", "30 um", "40 um", "60 um")[index % 4]
        products.append(
            f'[[product]]\nname = "Product {index + 1} {sample}"\nshade = "{sample}"\nmaterial = "{sample}.json"\n'
            + ('mesh = "lipstick"\n' if lipstick else "")
            + f'layer = [{{ material = "self", thickness = "{thickness}", specular = {{ roughness = 0.3, ior = 1.5 }} '
            "}]\n"
        )
    recipe = folder / "recipe.toml"
    recipe.write_text(scene + "\n".join(products))
    return recipe


def _demo(folder: Path) -> list[list[str]]:
    rows = []
    for label, options, env in CONFIGURATIONS:
        out = folder / label.replace(" ", "_").replace(",", "")
        seconds, _ = _kmpipe("run", str(RECIPE), "-o", str(out), *options, env=env)
        frames = _frames(out)
        cached, _ = _kmpipe("run", str(RECIPE), "-o", str(out), *options, env=env)
        rows.append([
            label, str(frames), f"{seconds:.1f}", f"{frames / seconds:.2f}", f"{cached:.2f}",
            "yes" if seconds < TARGET_S else "no", "yes" if cached < CACHED_TARGET_S else "no",
        ])  # fmt: skip
    return rows


#: What a cached ``kmpipe run`` imports before it reads its records: the command line, planning and execution, and
#: colour-science, which checking a recipe's illuminant names needs.
IMPORTS = "import kmpipe.cli, kmpipe.run.planning, kmpipe.run.execute, kmpipe.physics.colorimetry"


def _start() -> float:
    """Seconds (best of 3) that starting the interpreter and :data:`IMPORTS` take."""
    return best_of(lambda: subprocess.run([sys.executable, "-c", IMPORTS], check=True))[0]


def _scaling(folder: Path) -> tuple[list[list[str]], float, float]:
    """The 16-product line's rows, the seconds of interpreter start, and the throughput of 2 processes over that of
    1 process on 1 core."""
    recipe = sixteen_products(folder)
    start = _start()
    measured = []
    for label, options, env, cores in SCALING:
        out = folder / ("16-" + label.replace(" ", "_").replace(",", ""))
        seconds, cpu = _kmpipe("run", str(recipe), "-o", str(out), *options, env=env, cores=cores)
        cached, _ = _kmpipe("run", str(recipe), "-o", str(out), *options, env=env, cores=cores)
        measured.append((label, _frames(out), seconds, cpu, cached))
    one, pool = measured[0][2], measured[1][2]
    rows = []
    for label, frames, seconds, cpu, cached in measured:
        compared = f"{seconds / pool:.2f} x the pool's time" if "dask" in label else ""
        rows.append([label, str(frames), f"{seconds:.1f}", f"{frames / seconds:.2f}", f"{one / seconds:.2f}",
                     f"{cpu:.1f}", f"{cpu / seconds:.2f}", f"{cached:.2f}", compared])  # fmt: skip
    return rows, start, measured[-1][2] / pool


def run() -> dict:
    with tempfile.TemporaryDirectory() as folder:
        demo = _demo(Path(folder))
        scaling, start, per_core = _scaling(Path(folder))
    return {"demo": demo, "scaling": scaling, "start": start, "per_core": per_core}


def tables(rows: dict) -> list[Table]:
    return [
        Table(
            "The demo line end to end (kmpipe run recipes/demo/recipe.toml)",
            ["executor", "frames", "s", "frames/s", "cached re-run, s", "< 2 min", "cached < 3 s"],
            rows["demo"],
            [
                "each run in a fresh kmpipe process from an empty output folder: replaying and fitting every sample, "
                "validation, every product's turntable (EXR + PNG), the sheet and the report index",
            ],
        ),
        Table(
            "A 16-product line: the speed-up of workers",
            [
                "executor",
                "frames",
                "s",
                "frames/s",
                "throughput / 1 process",
                "CPU s",
                "cores busy",
                "cached re-run, s",
                "Dask against the pool",
            ],
            rows["scaling"],
            [
                "16 products (the six bundled samples, on the compact at 20-60 um and the lipstick), the demo's scene "
                "at 384 px, 8 frames each: fits given as files, plans, turntables, videos, the sheet",
                f"interpreter start and the imports a cached run needs ({IMPORTS}): {rows['start']:.2f} s of each "
                "cached re-run",
                "CPU s: user + system of the command and every process it started; cores busy = CPU s / s",
                "llvmpipe rasterizes on one thread per core: one process already renders on both cores of this "
                "machine (compare the row on 1 thread); pool and Dask workers get the cores divided among them "
                "(kmpipe.run.executors.worker_environment)",
                "the workers against the cores they are given: 2 processes on 2 cores have "
                f"{rows['per_core']:.2f} x the throughput of 1 process on 1 core (the last row)",
            ],
        ),
    ]


def main() -> None:
    for table in tables(run()):
        table.print()


if __name__ == "__main__":
    main()
