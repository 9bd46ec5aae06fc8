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
key and outputs goes to ``.kmpipe/tasks/`` (written atomically, as soon as that task finishes, whichever executor ran
it). A task whose record holds its current key and whose outputs all exist is not run again: a second run does
nothing, and changing one product's data changes the keys of exactly that product's tasks (and of the line's sheet
and index). Every file is written under a temporary name and renamed, so a run killed at any moment leaves finished
files or none, and the next run resumes, first deleting the hidden temporary files a killed write left (kmpipe's own
temporary names only, see :data:`TEMPORARY`).

Safety. Every path the run writes or deletes is resolved and must lie inside the output folder: at planning (a
symlink under the output folder leading out of it is refused, naming the path) and again in the task, right before it
writes (a symlink made meanwhile is refused too); a session folder is deleted without following symlinks. The outputs
of one run never collide: a recipe whose ``[outputs]`` make two tasks write the same file, or put the frames, reports,
products and records folders inside one another, is refused at planning, naming the field. One run at a time writes
an output folder: :func:`execute` holds ``.kmpipe/lock`` (:func:`locked`, an ``flock`` released by the kernel when the
process ends, however it ends); another run is refused naming the holder (pid, host, since when), or waits for it.
Planning (``--dry-run``) takes no lock and writes nothing.

Executors: ``local`` runs tasks in this process (``workers`` = 1) or in a pool of spawned processes; ``dask`` sends
them to a Dask distributed scheduler (``scheduler`` address) or to a local Dask cluster of ``workers`` processes. Task
functions are plain module functions of file paths and settings; the output folder must be visible to every worker
(a shared file system). Results are identical whichever executor ran them: the same code renders each frame. At most
a few tasks per worker are handed out at a time, so that the work of scheduling grows linearly with the line.
"""

from __future__ import annotations

import collections
import concurrent.futures
import contextlib
import datetime
import fcntl
import hashlib
import json
import math
import multiprocessing
import os
import re
import shutil
import socket
import stat
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from kmpipe import __version__
from kmpipe.errors import InputError
from kmpipe.formats.atomic_write import write_text_atomically
from kmpipe.formats.files import is_regular, read_text, sha256, within
from kmpipe.formats.recipe import Recipe, inside, load_recipe, slug

#: Frames of a product rendered by one task.
FRAMES_PER_TASK = 4
#: kmpipe's own folder under the output folder: task records and the lock.
STATE = Path(".kmpipe")
#: Where task records live, under the output folder.
RECORDS = STATE / "tasks"
#: The lock of the output folder: held by the run writing it, with its pid, host and start time inside.
LOCK = STATE / "lock"
#: Where the products' materials and sessions live, under the output folder.
PRODUCTS = Path("products")
#: Names of the temporary files kmpipe's writers make beside their targets (deleted at the start of a run):
#: kmpipe.formats.atomic_write's ``.NAME.<16 hex>.tmp`` and renderer.image_io's ``.STEM.<8 of a-z 0-9 _>.exr`` /
#: ``.png``
#: (mkstemp).
TEMPORARY = re.compile(r"\..+\.[0-9a-f]{16}\.tmp|\..+\.[a-z0-9_]{8}\.(?:exr|png)")


#: Largest contact sheet in pixels: a long line's sheet has cells smaller than 256 px to stay under it (a sheet takes
#: about 40 bytes a pixel while it is made: 2.6 GB).
SHEET_PIXELS = 64_000_000
#: Largest total of frame pixels a contact sheet reads (all at once, 12 bytes a pixel: 3.6 GB); a line whose sheet
#: would read more is refused at planning.
SHEET_FRAME_PIXELS = 300_000_000


def _key(*parts) -> str:
    return hashlib.sha256(json.dumps([__version__, *parts], sort_keys=True, default=str).encode()).hexdigest()


@dataclass
class Task:
    """One unit of work: what it runs (``function`` with ``args``), what it needs and what it writes.

    ``outputs`` are the files that make it complete; ``writes`` every other path it writes or deletes (its folders,
    a session's files), both relative to the output folder.
    """

    id: str
    product: str | None
    deps: tuple[str, ...]
    key: str
    outputs: tuple[str, ...]
    function: Callable[..., dict]
    args: dict
    writes: tuple[str, ...] = ()
    state: str = "pending"  # pending | cached | run | skipped | failed
    reason: str = ""
    result: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------------------------------- the tasks ---


def do_material(source: str, inputs: dict, out: str) -> dict:
    """Make a product's material.json in folder ``out``: measure or replay and fit, fit, or copy."""
    import dataclasses

    from rich.console import Console

    from kmpipe.formats.material import write_material
    from kmpipe.formats.sample import load_sample
    from kmpipe.stages.fit import fit_sample, provenance
    from kmpipe.stages.measure import run_session

    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / "material.json"
    if source == "material":
        write_text_atomically(target, read_text(inputs["material"], "material"))
        return {}
    if source in ("measure", "replay"):
        session = folder / "session"
        quiet = Console(file=open(os.devnull, "w"), force_terminal=False)  # noqa: SIM115 (closed with the console)
        if source == "replay":
            remove_tree(session)  # a replay starts from the recording's first byte
            port, record, resume = f"replay://{inputs['log']}", None, False
        else:  # a live session cut short keeps its readings: measure only the rest
            _refuse_symlinks(session)
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


def remove_tree(path: Path) -> None:
    """Delete ``path`` (a folder and everything in it, a file or a symlink) without following any symlink."""
    try:
        info = os.lstat(path)
    except FileNotFoundError:
        return
    if stat.S_ISDIR(info.st_mode):
        shutil.rmtree(path)  # removes symlinks inside as links (shutil.rmtree.avoids_symlink_attacks on Linux)
    else:
        os.unlink(path)


def _refuse_symlinks(folder: Path) -> None:
    """Refuse a session folder that holds a symlink (its files are written again, and must stay where they are)."""
    for top, folders, files in os.walk(folder):
        for name in folders + files:
            if os.path.islink(os.path.join(top, name)):
                raise InputError("is a symlink inside a session folder; kmpipe writes a session's files only in "
                                 "its own folder: remove it", path=Path(top, name))  # fmt: skip


def do_validate(material: str, out: str, illuminants: list[str], thresholds: dict) -> dict:
    """Validate a fitted material and write its report into ``out``; its verdict and reasons."""
    from kmpipe.validation.checks import Thresholds, validate_material
    from kmpipe.validation.report import write_sample_report

    report = validate_material(material, illuminants=tuple(illuminants), thresholds=Thresholds(**thresholds))
    write_sample_report(report, Path(out))
    return {"verdict": report.verdict, "reasons": list(report.reasons), "worst_delta_e": report.worst_delta_e}


#: The recipe last loaded in this process, by its path and the SHA-256 of its text (render tasks share it).
_LOADED: dict[tuple[str, str], Recipe] = {}


def _remember(recipe: Recipe) -> Recipe:
    _LOADED.clear()
    _LOADED[(str(recipe.path), hashlib.sha256(recipe.text.encode()).hexdigest())] = recipe
    return recipe


def _recipe(path: str) -> Recipe:
    """The recipe at ``path``, loaded once per process while its text is unchanged (every render task reads it)."""
    text = read_text(path, "TOML", field="recipe")
    found = _LOADED.get((path, hashlib.sha256(text.encode()).hexdigest()))
    return found if found is not None else _remember(load_recipe(path))


def do_render(recipe: str, product: str, materials: dict, out: str, frames: list[int], header: dict) -> dict:
    """Render frames of a product's turntable into ``out``."""
    from kmpipe.formats.scene import build_scene
    from kmpipe.stages.render import render_scene

    folder = Path(out)
    todo = [i for i in frames if not _frame_done(folder, i, header.get("task_key"))]
    if todo:
        loaded = _recipe(recipe)
        index = [p.name for p in loaded.info.product].index(product)
        data = loaded.scene_data(loaded.info.product[index], {name: Path(path) for name, path in materials.items()})
        scene = build_scene(data, loaded.path, loaded.base, loaded.scene_where(index))
        render_scene(scene, folder, frames=todo, header=header, echo=lambda _: None)
    return {"frames": [str(folder / f"frame_{i:03d}.exr") for i in frames]}


def _frame_done(folder: Path, frame: int, key: str | None) -> bool:
    """True when frame ``frame`` of a render task of ``key`` is already on disk, complete: a run killed inside a
    task keeps the frames it finished. The EXR is renamed into place after its PNG and carries the task's key."""
    from renderer.image_io import read_header

    exr, png = folder / f"frame_{frame:03d}.exr", folder / f"frame_{frame:03d}.png"
    if key is None or not (exr.is_file() and png.is_file()):
        return False
    try:
        return read_header(exr).get("task_key") == key
    except (OSError, ValueError):
        return False


def do_reports(entries: list[tuple[str, str]], out: str) -> dict:
    """The validation index over (validation.json, report.html) pairs."""
    from kmpipe.validation.report import write_index

    documents = [(json.loads(read_text(doc, "JSON")), Path(page)) for doc, page in entries]
    return {"index": str(write_index(documents, Path(out)))}


def do_sheet(products: list[dict], out: str, header: str, columns: list[str], cell: int = 256) -> dict:
    """The contact sheet: a row per product (its ``label`` and ``frames``), a column per angle, in cells of ``cell``
    pixels square."""
    from renderer.contact_sheet import make_sheet, write_sheet

    frames = [Path(f) for p in products for f in p["frames"]]
    labels = [p["label"] for p in products]
    sheet = make_sheet(frames, rows=labels, columns=columns, grid=(len(labels), len(columns)), header=header,
                       cell_size=(cell, cell))  # fmt: skip
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

    def folders(self) -> list[Path]:
        """The folders the run writes into (products, records, frames, reports), under the output folder."""
        outputs = self.recipe.info.outputs
        return [self.out_dir / PRODUCTS, self.out_dir / STATE, self.out_dir / outputs.frames,
                self.out_dir / outputs.reports]  # fmt: skip


def _record_path(out_dir: Path, task_id: str) -> Path:
    return out_dir / RECORDS / (task_id.replace(":", "__") + ".json")


def _cached(out_dir: Path, task: Task) -> dict | None:
    """The recorded result of ``task`` if its record holds its key and its outputs exist; a record that cannot be
    read (damaged, not a regular file) means "not cached"."""
    try:
        record = json.loads(read_text(_record_path(out_dir, task.id), "JSON"))
    except (InputError, ValueError):
        return None
    if not isinstance(record, dict) or record.get("key") != task.key:
        return None
    if not all((out_dir / o).exists() for o in task.outputs):
        return None
    result = record.get("result", {})
    return result if isinstance(result, dict) else None


class _Claims:
    """Every path of a run's tasks, resolved: refused if it leads outside the output folder, exists as what it is
    not (a folder where a file goes), or collides with another task's: the same file, a file where a folder goes, a
    file inside a folder that is another's own, folders of the layout (products, records, frames, reports) inside one
    another. ``field`` names the recipe field that placed a path (None: the fixed layout, products and records)."""

    def __init__(self, recipe: Recipe, root: Path) -> None:
        self.recipe, self.root = recipe, root
        self.files: dict[Path, str] = {}  # resolved path: the task writing it
        self.folders: dict[Path, str] = {}  # resolved path: whose it is
        self.own: dict[Path, str] = {}  # folders holding only what their owner writes
        self.layout: dict[Path, tuple[str, str | None]] = {}  # the layout's folders: (what, field)

    def _refuse(self, relative: str | Path, other: str, field: str | None) -> None:
        if field is None:
            raise InputError(f"collides with {other}", path=self.root / relative, field="-o")
        raise InputError(f"{str(relative)!r} collides with {other}: the outputs of one run must not overlap; give "
                         "another path", **self.recipe.where(tuple(field.split("."))))  # fmt: skip

    def _above(self, target: Path) -> Iterator[Path]:
        """The folders between ``target`` and the output folder (both excluded)."""
        for parent in target.parents:
            if parent == self.root:
                return
            yield parent

    def top(self, relative: str | Path, what: str, field: str | None, *, own: bool = False) -> None:
        """A folder of the output folder's layout: not the output folder, not in, nor holding, another one."""
        target = within(self.root, relative, field="-o")
        if target == self.root:
            self._refuse(relative, f"the output folder {self.root} itself, which holds the others", field)
        for other, (name, other_field) in self.layout.items():
            if target == other or target.is_relative_to(other) or other.is_relative_to(target):
                self._refuse(relative, f"{name}{f' ({other_field})' if other_field else ''}, {other}", field)
        self.layout[target] = (what, field)
        self.folder(relative, what, field, own=own)

    def folder(self, relative: str | Path, whose: str, field: str | None, *, own: bool = False) -> None:
        """A folder that ``whose`` writes into (``own``: holding nothing else)."""
        target = within(self.root, relative, field="-o")
        if os.path.lexists(target) and not target.is_dir():
            raise InputError("exists and is not a folder; kmpipe writes a folder there", path=target, field="-o")
        for place in (target, *self._above(target)):
            if place in self.files:
                self._refuse(relative, f"the output of {self.files[place]}, {place}, a file", field)
        self.folders.setdefault(target, whose)
        if own:
            self.own[target] = whose

    def file(self, relative: str | Path, task: str, whose: str, field: str | None) -> None:
        """A file that ``task`` writes, into folders of ``whose``."""
        target = within(self.root, relative, field="-o")
        if target.is_dir():
            raise InputError("is a folder; kmpipe writes a file there", path=target, field="-o")
        if target in self.files:
            self._refuse(relative, f"an output of {self.files[target]}, {target}", field)
        if target in self.folders:
            self._refuse(relative, f"the folder of {self.folders[target]}, {target}", field)
        for parent in self._above(target):
            if parent in self.files:
                self._refuse(relative, f"the output of {self.files[parent]}, {parent}, a file", field)
            if self.own.get(parent, whose) != whose:
                self._refuse(relative, f"the folder of {self.own[parent]}, {parent}", field)
        self.files[target] = task

    def task(self, task: Task, whose: str, field: str | None) -> Task:
        """Claim a task's outputs (placed by ``field``) and its record."""
        for path in task.outputs:
            self.file(path, task.id, whose, field)
        self.file(_record_path(Path(), task.id), task.id, RECORDS_OWNER, None)
        return task


#: Whose the records folder is.
RECORDS_OWNER = "kmpipe's task records and lock"


def plan_run(
    recipe_path: str | Path, out_dir: str | Path, *, only: Sequence[str] = (), keep_going: bool = False
) -> RunPlan:
    """The task graph of a recipe: keys from file contents and settings, cached tasks marked.

    Every path the tasks write is checked (see :class:`_Claims`): inside the output folder, resolved, and no two
    tasks' outputs colliding. Nothing is written.
    """
    recipe = _remember(load_recipe(recipe_path))
    out_dir = Path(out_dir).absolute()  # tasks may run in other processes, in other folders
    info = recipe.info
    names = [p.name for p in info.product]
    by_name = {p.name: p for p in info.product}
    unknown = [n for n in only if n not in by_name]
    if unknown:
        raise InputError(f"names no product of the recipe: {', '.join(unknown)} (it has {', '.join(names)})",
                         field="--only")  # fmt: skip
    wanted = set(only) or set(names)
    # A product needs the materials of the products in its stack.
    for name in list(wanted):
        for layer in by_name[name].layer:
            if layer.get("material") not in (None, "self"):
                wanted.add(layer["material"])
    outputs = info.outputs
    frames_dir = inside(out_dir, outputs.frames, recipe.where(("outputs", "frames")))
    reports_dir = inside(out_dir, outputs.reports, recipe.where(("outputs", "reports")))
    claims = _Claims(recipe, out_dir.resolve())
    claims.top(PRODUCTS, "the products folder", None)
    claims.top(STATE, RECORDS_OWNER, None, own=True)
    claims.file(LOCK, "the lock", RECORDS_OWNER, None)
    claims.top(outputs.reports, "the reports folder", "outputs.reports")
    claims.top(outputs.frames, "the frames folder", "outputs.frames")
    tasks: dict[str, Task] = {}
    hashes: dict[Path, str] = {}  # of the input files, each read once however many products share it

    def add(task: Task, whose: str, field: str | None) -> Task:
        tasks[task.id] = claims.task(task, whose, field)
        return task

    def rel(path: Path) -> str:
        return os.path.relpath(path, out_dir)

    def hashed(path: Path) -> str:  # each input file hashed once per plan
        if path not in hashes:
            hashes[path] = sha256(path)
        return hashes[path]

    material_key: dict[str, str] = {}
    for product in info.product:
        if product.name not in wanted or product.source is None:
            continue
        folder = out_dir / PRODUCTS / slug(product.name)
        whose = f"the material of {product.name}"
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
        folders = [folder] + ([folder / "session"] if product.source in ("measure", "replay") else [])
        written = [folder / "session.jsonl", folder / "session-resumed.jsonl"] if product.source == "measure" else []
        for path in folders:
            claims.folder(rel(path), whose, None, own=True)
        for path in written:
            claims.file(rel(path), f"material:{slug(product.name)}", whose, None)
        key = _key("material", product.source, {name: hashed(Path(p)) for name, p in inputs.items()}, settings)
        material_key[product.name] = key
        paths = {k: str(v) for k, v in inputs.items() if k in ("log", "plan", "manifest", "material")}
        add(Task(f"material:{slug(product.name)}", product.name, (), key, (rel(folder / "material.json"),),
                 do_material, {"source": product.source, "out": str(folder), "inputs": {**paths, **settings}},
                 tuple(rel(p) for p in folders + written)), whose, None)  # fmt: skip
        if product.source != "material":
            thresholds = {k: getattr(recipe.thresholds, k) for k in recipe.thresholds.__dataclass_fields__}
            report = reports_dir / slug(product.name)
            whose = f"the report of {product.name}"
            claims.folder(rel(report), whose, "outputs.reports", own=True)
            add(Task(f"validate:{slug(product.name)}", product.name, (f"material:{slug(product.name)}",),
                     _key("validate", key, info.validation.illuminants, thresholds),
                     (rel(report / "validation.json"), rel(report / "report.html")), do_validate,
                     {"material": str(folder / "material.json"), "out": str(report),
                      "illuminants": info.validation.illuminants, "thresholds": thresholds},
                     (rel(report),)), whose, "outputs.reports")  # fmt: skip

    rows = []
    for product in info.product:
        if not product.layer or product.name not in (set(only) or set(names)):
            continue
        owners = [product.name if layer.get("material") == "self" else layer["material"] for layer in product.layer]
        materials = {o: str(out_dir / PRODUCTS / slug(o) / "material.json") for o in owners}
        data = recipe.scene_data(product, {o: Path(slug(o)) for o in owners})  # paths out of the key: names
        files = _scene_files(recipe, data, hashed)
        frame_count = (data.get("turntable") or {}).get("frames", 1)
        deps = tuple(dict.fromkeys(f"material:{slug(o)}" for o in owners))
        checks = tuple(f"validate:{slug(o)}" for o in dict.fromkeys(owners) if f"validate:{slug(o)}" in tasks)
        upstream = [material_key[o] for o in owners] + [tasks[c].key for c in checks]
        folder = frames_dir / slug(product.name)
        whose = f"the frames of {product.name}"
        claims.folder(rel(folder), whose, "outputs.frames", own=True)
        chunks = []
        for start in range(0, frame_count, FRAMES_PER_TASK):
            frames = list(range(start, min(start + FRAMES_PER_TASK, frame_count)))
            key = _key("render", data, files, upstream, frames, keep_going)
            task_id = f"render:{slug(product.name)}:{frames[0]}-{frames[-1]}"
            produced = tuple(rel(folder / f"frame_{i:03d}.{ext}") for i in frames for ext in ("exr", "png"))
            add(Task(task_id, product.name, deps + checks, key, produced, do_render,
                     {"recipe": str(recipe.path), "product": product.name, "materials": materials,
                      "out": str(folder), "frames": frames, "header": {}}, (rel(folder),)),
                whose, "outputs.frames")  # fmt: skip
            chunks.append(task_id)
        width, height = (data.get("scene") or {}).get("resolution") or (256, 256)
        rows.append((product.name, product.shade or product.name, chunks, folder, frame_count, width * height))

    validations = [t for t in tasks.values() if t.id.startswith("validate:")]
    if validations:
        entries = [(str(out_dir / t.outputs[0]), str(out_dir / t.outputs[1])) for t in validations]
        add(Task("reports", None, tuple(t.id for t in validations), _key("reports", [t.key for t in validations]),
                 (rel(reports_dir / "index.html"),), do_reports, {"entries": entries, "out": str(reports_dir)},
                 (rel(reports_dir / "summary.json"),)), "the index of the reports", "outputs.reports")  # fmt: skip
        claims.file(rel(reports_dir / "summary.json"), "reports", "the index of the reports", "outputs.reports")
    if outputs.sheet is not None and rows:
        sheet = inside(out_dir, outputs.sheet, recipe.where(("outputs", "sheet")))
        count = min(outputs.sheet_columns, min(row[4] for row in rows))
        cell = _sheet_cell(recipe, count, [row[5] for row in rows])
        picks = [round(k * rows[0][4] / count) for k in range(count)]  # angles of the first product's turntable
        azimuth = float((recipe.info.scene.get("camera") or {}).get("azimuth_deg", 0.0))
        columns = [f"{(azimuth + 360.0 * i / rows[0][4]) % 360.0:g}°" for i in picks]
        products = [
            {"label": name if shade == name else f"{name} · {shade}", "chunks": chunks,
             "frames": [str(folder / f"frame_{round(k * n / count):03d}.exr") for k in range(count)]}
            for name, shade, chunks, folder, n, _ in rows
        ]  # fmt: skip
        header = f"{info.line.name} · {info.line.illuminant}"
        dated = f"{header} · {datetime.date.today().isoformat()}"  # the date the sheet is made, not part of its key
        add(Task("sheet", None, tuple(c for p in products for c in p["chunks"]),
                 _key("sheet", [tasks[c].key for p in products for c in p["chunks"]], columns, header, cell),
                 (rel(sheet),), do_sheet,
                 {"products": products, "out": str(sheet), "header": dated, "columns": columns, "cell": cell}),
            "the contact sheet", "outputs.sheet")  # fmt: skip

    plan = RunPlan(recipe, out_dir, tasks, keep_going)
    _mark_cached(plan)
    return plan


def _sheet_cell(recipe: Recipe, columns: int, frame_pixels: list[int]) -> int:
    """The side of the contact sheet's cells: 256 px, less for a line so long that the sheet would pass
    :data:`SHEET_PIXELS`; refused (InputError at ``outputs.sheet``) if the cells would be under 16 px or the frames the
    sheet reads pass :data:`SHEET_FRAME_PIXELS` (every one is in memory while the sheet is made)."""
    cells = columns * len(frame_pixels)
    cell = min(256, math.isqrt(SHEET_PIXELS // cells) - 8)  # cells and the 8 px margins between them
    reads = columns * sum(frame_pixels)
    if cell < 16 or reads > SHEET_FRAME_PIXELS:
        raise InputError(
            f"a contact sheet of {len(frame_pixels)} products by {columns} angles is larger than kmpipe makes: at "
            f"most {SHEET_PIXELS // 10**6} million pixels, in cells of 16 px or more, from at most "
            f"{SHEET_FRAME_PIXELS // 10**6} million pixels of frames (this one reads {reads // 10**6} million); give "
            "fewer outputs.sheet_columns, a smaller scene.resolution, or run part of the line with --only",
            **recipe.where(("outputs", "sheet")),
        )
    return cell


def _mark_cached(plan: RunPlan) -> None:
    """Mark the pending tasks whose record holds their key and whose outputs exist as cached; skip the renders of a
    material whose failed verdict is already known."""
    pending = [t for t in plan.tasks.values() if t.state == "pending"]
    for task in pending:
        result = _cached(plan.out_dir, task)
        if result is not None:
            task.state, task.result = "cached", result
    for task in pending:
        if task.state == "pending" and all(plan.tasks[d].state == "cached" for d in task.deps
                                           if d.startswith("validate:")):  # fmt: skip
            _blocked_by_validation(plan, task)


def _manifest_inputs(manifest: Path) -> dict[str, Path]:
    """The files a manifest's fit reads besides the manifest (its measurement CSVs), by name."""
    from kmpipe.formats.sample import load_sample

    return {f"input:{i}": Path(p) for i, p in enumerate(load_sample(manifest).inputs)}


def _scene_files(recipe: Recipe, data: dict, hashed: Callable[[Path], str]) -> dict[str, str]:
    """SHA-256 of the files a product's scene reads besides materials
    (:func:`kmpipe.formats.scene.referenced_files`), by
    their path relative to the recipe."""
    from kmpipe.formats.scene import SceneFile, referenced_files

    paths = referenced_files(SceneFile.model_validate(data), recipe.base)  # checked when the recipe was loaded
    return {os.path.relpath(p, recipe.base): hashed(p) for p in paths if is_regular(p)}


# ----------------------------------------------------------------------------------------------------- executing ---


def call_task(function: Callable[..., dict], kwargs: dict, root: str | None = None, paths: Sequence[str] = ()) -> dict:
    """Run a task function; a bad input comes back as data (an InputError's fields do not survive pickling).

    ``paths`` (under the output folder ``root``) are checked again first, where the task runs, right before it
    writes: a symlink made since planning that leads out of the output folder is refused.
    """
    try:
        for path in paths:
            within(Path(root), path, field="-o")
        return function(**kwargs)
    except InputError as err:
        return {"input_error": {"message": err.message, "path": None if err.path is None else str(err.path),
                                "line": err.line, "field": err.field}}  # fmt: skip


class _InProcess:
    """Runs tasks in this process (its GL context is this process's), one each time it is waited on, so that each
    task is recorded before the next one starts."""

    #: Tasks handed out at a time.
    capacity = 1

    def __init__(self) -> None:
        self.queue: collections.deque = collections.deque()

    def submit(self, function, *args):
        future: concurrent.futures.Future = concurrent.futures.Future()
        self.queue.append((future, function, args))
        return future

    def wait(self, futures):
        """Run the first task submitted (``futures`` holds it); it is done."""
        future, function, args = self.queue.popleft()
        try:
            future.set_result(function(*args))
        except Exception as err:  # handed to the caller through the future
            future.set_exception(err)
        return {future}, set(futures) - {future}

    def close(self) -> None:
        self.queue.clear()


class _Pool:
    """A pool of spawned worker processes (a fork after a GL context exists hangs)."""

    def __init__(self, workers: int) -> None:
        context = multiprocessing.get_context("spawn")
        self.pool = concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=context)
        self.capacity = 2 * workers

    def submit(self, function, *args):
        return self.pool.submit(function, *args)

    @staticmethod
    def wait(futures):
        return concurrent.futures.wait(futures, return_when=concurrent.futures.FIRST_COMPLETED)

    def close(self) -> None:
        self.pool.shutdown()


class _Dask:
    """A Dask distributed client: of the scheduler at ``address``, or of a local cluster of ``workers`` processes."""

    def __init__(self, address: str | None, workers: int) -> None:
        from distributed import Client, LocalCluster

        self.cluster = None
        if address is None:
            self.cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
        try:
            self.client = Client(address or self.cluster.scheduler_address, timeout=10)
        except Exception as err:  # whatever Dask raises, the address is what to fix
            if self.cluster is not None:
                self.cluster.close()
            raise InputError(f"cannot connect to the Dask scheduler at {address or 'the local cluster'}: "
                             f"{type(err).__name__}: {err}", field="--scheduler") from None  # fmt: skip
        self.capacity = 2 * max(workers, sum(self.client.nthreads().values()))

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


#: Addresses of a Dask scheduler: tcp://HOST:PORT, tls://HOST:PORT, HOST:PORT (tcp), inproc://...; HOST a name, an
#: IPv4 address or an [IPv6] address.
SCHEDULER = re.compile(
    r"(?:(?:tcp|tls)://)?(?:\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9](?:[A-Za-z0-9.-]*[A-Za-z0-9])?):(?P<port>[0-9]{1,5})"
    r"|inproc://[^\s/]+(?:/[^\s/]+)*"
)


def check_executor(kind: str, workers: int, scheduler: str | None) -> None:
    """Refuse an executor, a number of workers or a scheduler address that cannot work (InputError naming it)."""
    if kind not in ("local", "dask"):
        raise InputError(f"is {kind!r}; expected local or dask", field="--executor")
    if workers < 1:
        raise InputError(f"is {workers}; expected at least 1 worker", field="--workers")
    if scheduler is None:
        return
    if kind != "dask":
        raise InputError("--scheduler needs --executor dask", field="--scheduler")
    found = SCHEDULER.fullmatch(scheduler)
    if found is None or (found["port"] is not None and not 0 < int(found["port"]) < 65536):
        raise InputError(f"is {scheduler!r}; expected the address of a Dask scheduler: tcp://HOST:PORT, "
                         "tls://HOST:PORT, HOST:PORT or inproc://...", field="--scheduler")  # fmt: skip


def _executor(kind: str, workers: int, scheduler: str | None):
    if kind == "dask":
        return _Dask(scheduler, workers)
    return _InProcess() if workers <= 1 else _Pool(workers)


# -------------------------------------------------------------------------------------------- the output folder ---


@contextlib.contextmanager
def locked(out_dir: str | Path, *, wait: bool = False) -> Iterator[Path]:
    """Hold the lock of an output folder (``.kmpipe/lock``, created with the folder if need be) while in the block.

    The lock is an ``flock`` on the open file, which holds the holder's pid, host and start time (JSON). Another
    holder is refused (InputError naming it: pid, host, since when) unless ``wait``, which waits until it lets go.
    The lock goes on any exit of the block, and with the process, however it ends: a lock file left by a process
    that died holds no lock.
    """
    out_dir = Path(out_dir).absolute()
    path = within(out_dir, LOCK, field="-o")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        descriptor = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, 0o666)
    except OSError as err:
        raise InputError(f"the lock of the output folder cannot be made ({err.strerror or err})", path=path,
                         field="-o") from None  # fmt: skip
    try:
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            raise InputError("is not a regular file; kmpipe's lock of the output folder is", path=path, field="-o")
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            raise InputError(f"the output folder is being written by another kmpipe run ({_holder(descriptor)}); "
                             "wait until it has finished and run again, or run with --wait", path=path,
                             field="-o") from None  # fmt: skip
        holder = {"pid": os.getpid(), "host": socket.gethostname(),
                  "since": datetime.datetime.now().astimezone().isoformat(timespec="seconds")}  # fmt: skip
        os.ftruncate(descriptor, 0)
        os.pwrite(descriptor, (json.dumps(holder) + "\n").encode(), 0)
        try:
            yield path
        finally:
            os.ftruncate(descriptor, 0)  # let go: no holder to name
            fcntl.flock(descriptor, fcntl.LOCK_UN)
    finally:
        os.close(descriptor)


def _holder(descriptor: int) -> str:
    """Who holds a lock, as its file says (it may be still writing it)."""
    try:
        holder = json.loads(os.pread(descriptor, 4096, 0))
        return f"pid {int(holder['pid'])} on {holder['host']}, since {holder['since']}"
    except (OSError, ValueError, TypeError, KeyError):
        return "its pid, host and start time are not written yet"


def clean_temporaries(plan: RunPlan) -> list[Path]:
    """Delete the temporary files that killed writes left in the run's folders (names matching :data:`TEMPORARY`,
    regular files only, never following a symlink); the files deleted. For a run that holds the lock."""
    removed = []
    sheet = next((Path(t.outputs[0]) for t in plan.tasks.values() if t.id == "sheet"), None)
    places = [(folder, True) for folder in plan.folders()]
    if sheet is not None:
        places.append((plan.out_dir / sheet.parent, False))
    for folder, deep in places:
        if not within(plan.out_dir, folder, field="-o").is_dir():
            continue
        for top, folders, files, descriptor in os.fwalk(folder, follow_symlinks=False):  # a symlink is not entered
            for name in filter(TEMPORARY.fullmatch, files):
                with contextlib.suppress(FileNotFoundError):
                    if stat.S_ISREG(os.stat(name, dir_fd=descriptor, follow_symlinks=False).st_mode):
                        os.unlink(name, dir_fd=descriptor)
                        removed.append(Path(top, name))
            if not deep:
                folders.clear()
    return removed


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
    wait: bool = False,
) -> RunSummary:
    """Run every task of ``plan`` that is not cached, each after what it needs; records each one as it finishes.

    Holds the output folder's lock throughout (:func:`locked`; ``wait``: wait for another run to finish rather than
    refuse), deletes the temporary files of killed writes, and looks again at what is cached (another run may have
    finished tasks since planning). ``on_task(task, finished, total)`` is called as each task ends (run, failed or
    skipped).
    """
    started = time.perf_counter()
    check_executor(executor, workers, scheduler)
    with locked(plan.out_dir, wait=wait):
        clean_temporaries(plan)
        _mark_cached(plan)
        _run(plan, executor, workers, scheduler, on_task)
    return _summary(plan, time.perf_counter() - started)


FINAL = ("cached", "run", "skipped", "failed")


def _run(plan: RunPlan, executor: str, workers: int, scheduler: str | None,
         on_task: Callable[[Task, int, int], None] | None) -> None:  # fmt: skip
    """Hand out the pending tasks of ``plan`` as what they need ends, a few per worker at a time."""
    tasks = plan.tasks
    todo = [t for t in tasks.values() if t.state == "pending"]
    if not todo:
        return
    waiting = {t.id: sum(tasks[d].state not in FINAL for d in t.deps) for t in todo}
    dependents: dict[str, list[str]] = collections.defaultdict(list)
    for task in todo:
        for dep in task.deps:
            dependents[dep].append(task.id)
    ready = collections.deque(t for t in todo if waiting[t.id] == 0)
    root = str(plan.out_dir)
    total, finished = len(todo), 0
    running: dict = {}

    def ended(task: Task) -> None:
        nonlocal finished
        finished += 1
        if on_task is not None:
            on_task(task, finished, total)
        for other in dependents[task.id]:
            waiting[other] -= 1
            if waiting[other] == 0:
                ready.append(tasks[other])

    pool = _executor(executor, workers, scheduler)
    try:
        while ready or running:
            while ready and len(running) < pool.capacity:
                task = ready.popleft()
                if _decide(plan, task):
                    paths = [*task.outputs, *task.writes]
                    running[pool.submit(call_task, task.function, _arguments(plan, task), root, paths)] = task
                else:
                    ended(task)
            if not running:
                continue
            done, _ = pool.wait(list(running))
            for future in done:
                task = running.pop(future)
                result = future.result()
                if "input_error" in result:
                    task.state, task.result = "failed", result["input_error"]
                    task.reason = str(InputError(**result["input_error"]))
                else:
                    task.state, task.result = "run", result
                    _record(plan, task)
                ended(task)
    finally:
        pool.close()


def _decide(plan: RunPlan, task: Task) -> bool:
    """True if ``task``, whose dependencies have ended, is to run; else it is skipped (and says why)."""
    states = [plan.tasks[d].state for d in task.deps]
    if task.product is None:  # the line's sheet and index: of what finished, if anything did
        if states and not any(s in ("cached", "run") for s in states):
            task.state, task.reason = "skipped", "nothing it lays out finished"
            return False
        return True
    if any(s in ("skipped", "failed") for s in states):
        task.state, task.reason = "skipped", "a task it needs did not finish"
        return False
    return not _blocked_by_validation(plan, task)


def _record(plan: RunPlan, task: Task) -> None:
    """Write the record of a task that has just finished (into the output folder, never out of it)."""
    path = within(plan.out_dir, _record_path(Path(), task.id), field="-o")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"the folder of the task records cannot be made ({err.strerror or err})", path=path.parent,
                         field="-o") from None  # fmt: skip
    record = {"key": task.key, "outputs": list(task.outputs), "result": task.result}
    write_text_atomically(path, json.dumps(record, indent=1) + "\n")


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
        args["header"]["task_key"] = task.key  # a frame on disk with this key is not rendered again
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
