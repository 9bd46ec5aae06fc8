"""``kmpipe run``: every stage a recipe needs, as a graph of cached tasks, in one process, a process pool or Dask.

Tasks (``id``: what it writes under the output folder):

- ``material:P`` (products with a source): measure the sample on the CS-2000 at the recipe's port (live; recorded
  byte for byte into ``products/P/session.jsonl``; a session cut short is resumed by the next run) or replay a
  recorded session, into ``products/P/session/``, and fit it; or fit the manifest; or copy the material file; writes
  ``products/P/material.json``. A live measurement is keyed by its plan and port, so it is measured once;
- ``validate:P`` (materials fitted from measurements): ``reports/P/report.html`` and ``validation.json``;
- ``render:P:A-B`` (products with layers): frames A..B of the turntable into ``frames/P/``, a few frames a task so
  that several workers share a product; waits for the materials its layers use and for their validation: a material
  that failed validation is not rendered unless ``keep_going`` (then its frames say so in their header);
- ``reports``: ``reports/index.html`` and ``summary.json`` over every validated product;
- ``sheet``: the contact sheet, a row per rendered product and a column per angle.

Caching. Every task has a key, the SHA-256 of what determines its result: its kind and settings, the content of the
input files it reads, the keys of the tasks it depends on, and kmpipe's version. When a task finishes, a record of its
key and outputs goes to ``.kmpipe/tasks/`` (written last, atomically). A task whose record holds its current key
and whose outputs all exist is not run again: a second run does nothing, and changing one product's data changes the
keys of exactly that product's tasks (and of the line's sheet and index). Every file is written under a temporary
name and renamed, so a run killed at any moment leaves finished files or none, and the next run resumes.

Executors: ``local`` runs tasks in this process (``workers`` = 1) or in a pool of spawned processes; ``dask`` sends
them to a Dask distributed scheduler (``scheduler`` address) or to a local Dask cluster of ``workers`` processes. Task
functions are plain module functions of file paths and settings; the output folder must be visible to every worker
(a shared file system). Results are identical whichever executor ran them: the same code renders each frame.
"""

from __future__ import annotations

import concurrent.futures
import datetime
import hashlib
import json
import multiprocessing
import os
import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from kmpipe import __version__
from kmpipe.atomic_write import write_text_atomically
from kmpipe.errors import InputError
from kmpipe.recipe import Recipe, inside, load_recipe, slug
from kmpipe.sample import file_sha256

#: Frames of a product rendered by one task.
FRAMES_PER_TASK = 4
#: Where task records live, under the output folder.
RECORDS = Path(".kmpipe") / "tasks"


def _key(*parts) -> str:
    return hashlib.sha256(json.dumps([__version__, *parts], sort_keys=True, default=str).encode()).hexdigest()


@dataclass
class Task:
    """One unit of work: what it runs (``function`` with ``args``), what it needs and what it writes."""

    id: str
    product: str | None
    deps: tuple[str, ...]
    key: str
    outputs: tuple[str, ...]
    function: Callable[..., dict]
    args: dict
    state: str = "pending"  # pending | cached | run | skipped | failed
    reason: str = ""
    result: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------------------------------- the tasks ---


def do_material(source: str, inputs: dict, out: str) -> dict:
    """Make a product's material.json in folder ``out``: measure or replay and fit, fit, or copy."""
    import dataclasses

    from rich.console import Console

    from kmpipe.fitting import fit_sample, provenance
    from kmpipe.material import write_material
    from kmpipe.measure import run_session
    from kmpipe.sample import load_sample

    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / "material.json"
    if source == "material":
        temporary = folder / ".material.json.tmp"
        shutil.copyfile(inputs["material"], temporary)
        os.replace(temporary, target)
        return {}
    if source in ("measure", "replay"):
        session = folder / "session"
        quiet = Console(file=open(os.devnull, "w"), force_terminal=False)  # noqa: SIM115 (closed with the console)
        if source == "replay":
            shutil.rmtree(session, ignore_errors=True)  # a replay starts from the recording's first byte
            port, record, resume = f"replay://{inputs['log']}", None, False
        else:  # a live session cut short keeps its readings: measure only the rest
            resume = (session / "session.json").exists()
            record = folder / ("session-resumed.jsonl" if resume else "session.jsonl")
            port = inputs["port"]
        try:
            manifest = run_session(
                Path(inputs["plan"]), port, out_dir=session, record=record, resume=resume, interactive=False,
                baudrate=inputs.get("baudrate", 115200), console=quiet,
            )  # fmt: skip
        finally:
            quiet.file.close()
    else:
        manifest = Path(inputs["manifest"])
    sample = load_sample(manifest)
    material = fit_sample(sample)
    write_material(dataclasses.replace(material, provenance=provenance(sample, target)), target)
    return {}


def do_validate(material: str, out: str, illuminants: list[str], thresholds: dict) -> dict:
    """Validate a fitted material and write its report into ``out``; its verdict and reasons."""
    from kmpipe.report import write_sample_report
    from kmpipe.validation import Thresholds, validate_material

    report = validate_material(material, illuminants=tuple(illuminants), thresholds=Thresholds(**thresholds))
    write_sample_report(report, Path(out))
    return {"verdict": report.verdict, "reasons": list(report.reasons), "worst_delta_e": report.worst_delta_e}


def do_render(recipe: str, product: str, materials: dict, out: str, frames: list[int], header: dict) -> dict:
    """Render frames of a product's turntable into ``out``."""
    from kmpipe.recipe import load_recipe
    from kmpipe.render import render_scene
    from kmpipe.scene import build_scene

    loaded = load_recipe(recipe)
    index = [p.name for p in loaded.info.product].index(product)
    data = loaded.scene_data(loaded.info.product[index], {name: Path(path) for name, path in materials.items()})
    scene = build_scene(data, loaded.path, loaded.base, loaded.scene_where(index))
    written = render_scene(scene, Path(out), frames=frames, header=header, echo=lambda _: None)
    return {"frames": [str(p) for p in written if p.suffix == ".exr"]}


def do_reports(entries: list[tuple[str, str]], out: str) -> dict:
    """The validation index over (validation.json, report.html) pairs."""
    from kmpipe.report import write_index

    documents = [(json.loads(Path(doc).read_text(encoding="utf-8")), Path(page)) for doc, page in entries]
    return {"index": str(write_index(documents, Path(out)))}


def do_sheet(products: list[dict], out: str, header: str, columns: list[str]) -> dict:
    """The contact sheet: a row per product (its ``label`` and ``frames``), a column per angle."""
    from renderer.contact_sheet import make_sheet, write_sheet

    frames = [Path(f) for p in products for f in p["frames"]]
    labels = [p["label"] for p in products]
    sheet = make_sheet(frames, rows=labels, columns=columns, grid=(len(labels), len(columns)), header=header)
    write_sheet(sheet, Path(out))
    return {"sheet": out}


# ------------------------------------------------------------------------------------------------------ planning ---


@dataclass
class RunPlan:
    """The graph of a recipe's tasks for one output folder, with what is cached."""

    recipe: Recipe
    out_dir: Path
    tasks: dict[str, Task]
    keep_going: bool

    def explain(self) -> str:
        lines = [f"Run plan of {self.recipe.info.line.name} ({self.recipe.path}) into {self.out_dir}:"]
        for task in self.tasks.values():
            state = {"pending": "will run", "cached": "cached", "skipped": "skipped"}.get(task.state, task.state)
            lines.append(f"  {task.id:<40} {state}{f' ({task.reason})' if task.reason else ''}")
        counts = {s: sum(t.state == s for t in self.tasks.values()) for s in ("pending", "cached", "skipped")}
        lines.append(f"{counts['pending']} to run, {counts['cached']} cached, {counts['skipped']} skipped")
        return "\n".join(lines)


def _record_path(out_dir: Path, task_id: str) -> Path:
    return out_dir / RECORDS / (task_id.replace(":", "__") + ".json")


def _cached(out_dir: Path, task: Task) -> dict | None:
    """The recorded result of ``task`` if its record holds its key and its outputs exist."""
    try:
        record = json.loads(_record_path(out_dir, task.id).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if record.get("key") != task.key or not all((out_dir / o).exists() for o in task.outputs):
        return None
    return record.get("result", {})


def plan_run(
    recipe_path: str | Path, out_dir: str | Path, *, only: Sequence[str] = (), keep_going: bool = False
) -> RunPlan:
    """The task graph of a recipe: keys from file contents and settings, cached tasks marked."""
    recipe = load_recipe(recipe_path)
    out_dir = Path(out_dir).absolute()  # tasks may run in other processes, in other folders
    info = recipe.info
    names = [p.name for p in info.product]
    unknown = [n for n in only if n not in names]
    if unknown:
        raise InputError(f"names no product of the recipe: {', '.join(unknown)} (it has {', '.join(names)})",
                         field="--only")  # fmt: skip
    wanted = set(only) or set(names)
    # A product needs the materials of the products in its stack.
    for name in list(wanted):
        for layer in recipe.product(name).layer:
            if layer.get("material") not in (None, "self"):
                wanted.add(layer["material"])
    outputs = info.outputs
    frames_dir = inside(out_dir, outputs.frames, recipe.where(("outputs", "frames")))
    reports_dir = inside(out_dir, outputs.reports, recipe.where(("outputs", "reports")))
    tasks: dict[str, Task] = {}

    def add(task: Task) -> Task:
        tasks[task.id] = task
        return task

    def rel(path: Path) -> str:
        return os.path.relpath(path, out_dir)

    material_key: dict[str, str] = {}
    for product in info.product:
        if product.name not in wanted or product.source is None:
            continue
        folder = out_dir / "products" / slug(product.name)
        base = recipe.base
        settings: dict = {}
        if product.source == "measure":
            inputs = {"plan": base / product.measure.plan}
            settings = {"port": product.measure.port, "baudrate": product.measure.baudrate}
        elif product.source == "replay":
            inputs = {"log": base / product.replay.log, "plan": base / product.replay.plan}
        elif product.source == "fit":
            inputs = {"manifest": base / product.fit, **_manifest_inputs(base / product.fit)}
        else:
            inputs = {"material": base / product.material}
        hashes = {name: file_sha256(Path(path)) for name, path in inputs.items()}
        key = _key("material", product.source, hashes, settings)
        material_key[product.name] = key
        paths = {k: str(v) for k, v in inputs.items() if k in ("log", "plan", "manifest", "material")}
        add(Task(f"material:{slug(product.name)}", product.name, (), key, (rel(folder / "material.json"),),
                 do_material, {"source": product.source, "out": str(folder), "inputs": {**paths, **settings}}))
        if product.source != "material":
            thresholds = {k: getattr(recipe.thresholds, k) for k in recipe.thresholds.__dataclass_fields__}
            report = reports_dir / slug(product.name)
            add(Task(f"validate:{slug(product.name)}", product.name, (f"material:{slug(product.name)}",),
                     _key("validate", key, info.validation.illuminants, thresholds),
                     (rel(report / "validation.json"), rel(report / "report.html")), do_validate,
                     {"material": str(folder / "material.json"), "out": str(report),
                      "illuminants": info.validation.illuminants, "thresholds": thresholds}))  # fmt: skip

    rows = []
    for product in info.product:
        if not product.layer or product.name not in (set(only) or set(names)):
            continue
        owners = [product.name if layer.get("material") == "self" else layer["material"] for layer in product.layer]
        materials = {o: str(out_dir / "products" / slug(o) / "material.json") for o in owners}
        data = recipe.scene_data(product, {o: Path(slug(o)) for o in owners})  # paths out of the key: names
        files = _scene_files(recipe, data)
        frame_count = (data.get("turntable") or {}).get("frames", 1)
        deps = tuple(dict.fromkeys(f"material:{slug(o)}" for o in owners))
        checks = tuple(f"validate:{slug(o)}" for o in dict.fromkeys(owners) if f"validate:{slug(o)}" in tasks)
        upstream = [material_key[o] for o in owners] + [tasks[c].key for c in checks]
        folder = frames_dir / slug(product.name)
        chunks = []
        for start in range(0, frame_count, FRAMES_PER_TASK):
            frames = list(range(start, min(start + FRAMES_PER_TASK, frame_count)))
            key = _key("render", data, files, upstream, frames, keep_going)
            task_id = f"render:{slug(product.name)}:{frames[0]}-{frames[-1]}"
            produced = tuple(rel(folder / f"frame_{i:03d}.{ext}") for i in frames for ext in ("exr", "png"))
            add(Task(task_id, product.name, deps + checks, key, produced, do_render,
                     {"recipe": str(recipe.path), "product": product.name, "materials": materials,
                      "out": str(folder), "frames": frames, "header": {}}))  # fmt: skip
            chunks.append(task_id)
        rows.append((product.name, product.shade or product.name, chunks, folder, frame_count))

    validations = [t for t in tasks.values() if t.id.startswith("validate:")]
    if validations:
        entries = [(str(out_dir / t.outputs[0]), str(out_dir / t.outputs[1])) for t in validations]
        add(Task("reports", None, tuple(t.id for t in validations), _key("reports", [t.key for t in validations]),
                 (rel(reports_dir / "index.html"),), do_reports, {"entries": entries, "out": str(reports_dir)}))
    if outputs.sheet is not None and rows:
        sheet = inside(out_dir, outputs.sheet, recipe.where(("outputs", "sheet")))
        count = min(outputs.sheet_columns, min(n for *_, n in rows))
        picks = [round(k * rows[0][4] / count) for k in range(count)]  # angles of the first product's turntable
        azimuth = float((recipe.info.scene.get("camera") or {}).get("azimuth_deg", 0.0))
        columns = [f"{(azimuth + 360.0 * i / rows[0][4]) % 360.0:g}°" for i in picks]
        products = [
            {"label": name if shade == name else f"{name} · {shade}", "chunks": chunks,
             "frames": [str(folder / f"frame_{round(k * n / count):03d}.exr") for k in range(count)]}
            for name, shade, chunks, folder, n in rows
        ]  # fmt: skip
        header = f"{info.line.name} · {info.line.illuminant}"
        dated = f"{header} · {datetime.date.today().isoformat()}"  # the date the sheet is made, not part of its key
        add(Task("sheet", None, tuple(c for p in products for c in p["chunks"]),
                 _key("sheet", [tasks[c].key for p in products for c in p["chunks"]], columns, header),
                 (rel(sheet),), do_sheet,
                 {"products": products, "out": str(sheet), "header": dated, "columns": columns}))  # fmt: skip

    plan = RunPlan(recipe, out_dir, tasks, keep_going)
    for task in tasks.values():
        result = _cached(out_dir, task)
        if result is not None:
            task.state, task.result = "cached", result
    for task in tasks.values():  # a verdict already known: a failed material's renders are skipped now
        if task.state == "pending" and all(tasks[d].state == "cached" for d in task.deps if d.startswith("validate:")):
            _blocked_by_validation(plan, task)
    return plan


def _manifest_inputs(manifest: Path) -> dict[str, Path]:
    """The files a manifest's fit reads besides the manifest (its measurement CSVs), by name."""
    from kmpipe.sample import load_sample

    return {f"input:{i}": Path(p) for i, p in enumerate(load_sample(manifest).inputs)}


def _scene_files(recipe: Recipe, data: dict) -> dict[str, str]:
    """SHA-256 of the files a product's scene reads besides materials: maps, textures, a mesh file, a CSV."""
    from kmpipe.scene import BUILTIN_MESHES

    paths = [layer["thickness_map"]["file"] for layer in data["layer"] if isinstance(layer.get("thickness_map"), dict)]
    for key in ("substrate", "skin"):
        table = data.get(key) or {}
        if table.get("albedo_texture"):
            paths.append(table["albedo_texture"])
        if isinstance(table.get("reflectance"), str) and ".csv" in table["reflectance"].lower():
            paths.append(table["reflectance"].split(":")[0])
    mesh = data.get("scene", {}).get("mesh", "card")
    if mesh not in BUILTIN_MESHES:
        paths.append(mesh)
    return {p: file_sha256(recipe.base / p) for p in paths if (recipe.base / p).is_file()}


# ----------------------------------------------------------------------------------------------------- executing ---


def call_task(function: Callable[..., dict], kwargs: dict) -> dict:
    """Run a task function; a bad input comes back as data (an InputError's fields do not survive pickling)."""
    try:
        return function(**kwargs)
    except InputError as err:
        return {"input_error": {"message": err.message, "path": None if err.path is None else str(err.path),
                                "line": err.line, "field": err.field}}  # fmt: skip


class _InProcess:
    """Runs each task at once, in this process (its GL context is this process's)."""

    def submit(self, function, *args):
        future: concurrent.futures.Future = concurrent.futures.Future()
        try:
            future.set_result(function(*args))
        except Exception as err:  # handed to the caller through the future
            future.set_exception(err)
        return future

    @staticmethod
    def wait(futures):
        return concurrent.futures.wait(futures, return_when=concurrent.futures.FIRST_COMPLETED)

    def close(self) -> None:
        pass


class _Pool(_InProcess):
    """A pool of spawned worker processes (a fork after a GL context exists hangs)."""

    def __init__(self, workers: int) -> None:
        context = multiprocessing.get_context("spawn")
        self.pool = concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=context)

    def submit(self, function, *args):
        return self.pool.submit(function, *args)

    def close(self) -> None:
        self.pool.shutdown()


class _Dask:
    """A Dask distributed client: of the scheduler at ``address``, or of a local cluster of ``workers`` processes."""

    def __init__(self, address: str | None, workers: int) -> None:
        from distributed import Client, LocalCluster

        self.cluster = None
        if address is None:
            self.cluster = LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
            )
            address = self.cluster.scheduler_address
        try:
            self.client = Client(address, timeout=10)
        except OSError as err:
            raise InputError(f"cannot reach the Dask scheduler at {address}: {err}", field="--scheduler") from None

    def submit(self, function, *args):
        return self.client.submit(function, *args, pure=False)

    @staticmethod
    def wait(futures):
        from distributed import wait

        return wait(futures, return_when="FIRST_COMPLETED")

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def _executor(kind: str, workers: int, scheduler: str | None):
    if kind == "dask":
        return _Dask(scheduler, workers)
    if scheduler is not None:
        raise InputError("--scheduler needs --executor dask", field="--scheduler")
    return _InProcess() if workers <= 1 else _Pool(workers)


@dataclass
class RunSummary:
    products: int
    frames: int
    seconds: float
    ran: int
    cached: int
    skipped: int
    failed: list[str]
    verdicts: dict[str, str]
    sheet: Path | None
    reports: Path | None


def execute(
    plan: RunPlan,
    *,
    executor: str = "local",
    workers: int = 1,
    scheduler: str | None = None,
    on_task: Callable[[Task, int, int], None] | None = None,
) -> RunSummary:
    """Run every task of ``plan`` that is not cached, each after what it needs; records each one that finishes."""
    started = time.perf_counter()
    tasks = plan.tasks
    todo = [t for t in tasks.values() if t.state == "pending"]
    total, finished = len(todo), 0
    pool = _executor(executor, workers, scheduler) if todo else None
    running: dict = {}
    try:
        while any(t.state == "pending" for t in tasks.values()) or running:
            for task in tasks.values():
                if task.state != "pending" or task.id in running.values():
                    continue
                states = [tasks[d].state for d in task.deps]
                if task.product is None:  # the line's sheet and index: of what finished, if anything did
                    if any(s == "pending" for s in states):
                        continue
                    if states and not any(s in ("cached", "run") for s in states):
                        task.state, task.reason = "skipped", "nothing it lays out finished"
                        continue
                    running[pool.submit(call_task, task.function, _arguments(plan, task))] = task.id
                elif any(s in ("skipped", "failed") for s in states):
                    task.state, task.reason = "skipped", "a task it needs did not finish"
                elif all(s in ("cached", "run") for s in states):
                    if _blocked_by_validation(plan, task):
                        continue
                    running[pool.submit(call_task, task.function, _arguments(plan, task))] = task.id
            if not running:
                continue
            done, _ = pool.wait(list(running))
            for future in done:
                task = tasks[running.pop(future)]
                result = future.result()
                if "input_error" in result:
                    task.state, task.result = "failed", result["input_error"]
                    task.reason = result["input_error"]["message"]
                else:
                    task.state, task.result = "run", result
                    record = {"key": task.key, "outputs": list(task.outputs), "result": result}
                    path = _record_path(plan.out_dir, task.id)
                    path.parent.mkdir(parents=True, exist_ok=True)
                    write_text_atomically(path, json.dumps(record, indent=1) + "\n")
                finished += 1
                if on_task is not None:
                    on_task(task, finished, total)
    finally:
        if pool is not None:
            pool.close()
    return _summary(plan, time.perf_counter() - started)


def _blocked_by_validation(plan: RunPlan, task: Task) -> bool:
    """Skip a render whose materials failed validation (unless keep_going); True when it was skipped."""
    if not task.id.startswith("render:"):
        return False
    failed = [d for d in task.deps if d.startswith("validate:") and plan.tasks[d].result.get("verdict") == "fail"]
    if failed and not plan.keep_going:
        names = ", ".join(plan.tasks[d].product for d in failed)
        task.state, task.reason = "skipped", f"validation of {names} failed (--keep-going renders it anyway)"
        return True
    return False


def _arguments(plan: RunPlan, task: Task) -> dict:
    """The task's arguments, completed with what only earlier tasks could tell (verdicts, surviving rows)."""
    args = dict(task.args)
    if task.id.startswith("render:"):
        failed = [plan.tasks[d].product for d in task.deps
                  if d.startswith("validate:") and plan.tasks[d].result.get("verdict") == "fail"]  # fmt: skip
        args["header"] = {"validation": "fail: " + ", ".join(failed) + " (rendered with --keep-going)"} if failed else {
            "validation": "pass or warn"}  # fmt: skip
    if task.id == "reports":
        done = {plan.out_dir / plan.tasks[d].outputs[0] for d in task.deps if plan.tasks[d].state in ("cached", "run")}
        args["entries"] = [entry for entry in task.args["entries"] if Path(entry[0]) in done]
    if task.id == "sheet":
        args["products"] = [
            {**p, "label": ("⚠ " if any(_failed_validation(plan, c) for c in p["chunks"]) else "") + p["label"]}
            for p in task.args["products"]
            if all(plan.tasks[c].state in ("cached", "run") for c in p["chunks"])
        ]
    return args


def _failed_validation(plan: RunPlan, render_id: str) -> bool:
    return any(d.startswith("validate:") and plan.tasks[d].result.get("verdict") == "fail"
               for d in plan.tasks[render_id].deps)  # fmt: skip


def _summary(plan: RunPlan, seconds: float) -> RunSummary:
    tasks = plan.tasks.values()
    verdicts = {t.product: t.result.get("verdict", "?") for t in tasks if t.id.startswith("validate:")}
    frames = sum(len(t.args["frames"]) for t in tasks if t.id.startswith("render:") and t.state in ("run", "cached"))
    sheet = next((plan.out_dir / t.outputs[0] for t in tasks if t.id == "sheet" and t.state in ("run", "cached")), None)
    reports = next((plan.out_dir / t.outputs[0] for t in tasks if t.id == "reports" and t.state in ("run", "cached")),
                   None)  # fmt: skip
    return RunSummary(
        products=len({t.product for t in tasks if t.product is not None}),
        frames=frames,
        seconds=seconds,
        ran=sum(t.state == "run" for t in tasks),
        cached=sum(t.state == "cached" for t in tasks),
        skipped=sum(t.state == "skipped" for t in tasks),
        failed=[f"{t.id}: {t.reason}" for t in tasks if t.state == "failed"],
        verdicts=verdicts,
        sheet=sheet,
        reports=reports,
    )
