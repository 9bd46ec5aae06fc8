"""Planning ``kmpipe run``: a recipe as a graph of tasks with content keys, what is cached, and where each task may
write (every path resolved inside the output folder, no two tasks colliding)."""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from kmpipe.errors import InputError
from kmpipe.formats.files import is_regular, read_text, sha256, within
from kmpipe.formats.recipe import Recipe, inside, load_recipe, render_contexts, slug
from kmpipe.run.folder import LOCK, PRODUCTS, RECORDS, RECORDS_OWNER, STATE, TRADE
from kmpipe.run.tasks import (
    PLAN_FILE,
    Task,
    do_material,
    do_plan,
    do_render,
    do_reports,
    do_review,
    do_sheet,
    do_tone,
    do_validate,
    do_video,
    remember_recipe,
    task_key,
)

#: Frames of a product rendered by one task.
FRAMES_PER_TASK = 4


#: Largest contact sheet in pixels: a long line's sheet has cells smaller than 256 px to stay under it (a sheet takes
#: about 20 bytes a pixel while it is made: 1.3 GB).
SHEET_PIXELS = 64_000_000
#: Largest total of frame pixels a contact sheet reads (a frame per core at a time, each let go once fitted to its
#: cell); a line whose sheet would read more is refused at planning.
SHEET_FRAME_PIXELS = 300_000_000


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


def _frame_choices(out_dir: Path) -> dict:
    """The frame settings ``kmpipe trade`` chose for the line's products in this output folder (product: choice,
    :mod:`kmpipe.stages.frame_choice`); {} where it has not been run."""
    path = out_dir / TRADE / "trade.json"
    if not os.path.lexists(path):
        return {}
    from kmpipe.stages.trade_files import read_frame_choices

    return read_frame_choices(within(out_dir, path, field="-o"))


def record_path(out_dir: Path, task_id: str) -> Path:
    return out_dir / RECORDS / (task_id.replace(":", "__") + ".json")


def cached_result(out_dir: Path, task: Task) -> dict | None:
    """The recorded result of ``task`` if its record holds its key and its outputs exist; a record that cannot be
    read (damaged, not a regular file) means "not cached"."""
    try:
        record = json.loads(read_text(record_path(out_dir, task.id), "JSON"))
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
        self.file(record_path(Path(), task.id), task.id, RECORDS_OWNER, None)
        return task


def plan_run(
    recipe_path: str | Path,
    out_dir: str | Path,
    *,
    only: Sequence[str] = (),
    keep_going: bool = False,
    review_only: bool = False,
) -> RunPlan:
    """The task graph of a recipe: keys from file contents and settings, cached tasks marked.

    ``review_only`` (``kmpipe review``): the shade review of ``[review]`` and the materials it needs, no turntables.

    Every path the tasks write is checked (see :class:`_Claims`): inside the output folder, resolved, and no two
    tasks' outputs colliding. Nothing is written.

    >>> import collections, kmpipe, pathlib, tempfile
    >>> recipe = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "demo" / "recipe.toml"
    >>> plan = plan_run(recipe, pathlib.Path(tempfile.mkdtemp()))  # nothing is written: the graph and what is cached
    >>> sorted(collections.Counter(task.kind for task in plan.tasks.values()).items())
    [('material', 6), ('plan', 7), ('render', 14), ('reports', 1), ('sheet', 1), ('validate', 6), ('video', 7)]
    >>> {task.state for task in plan.tasks.values()}
    {'pending'}
    """
    from kmpipe.formats.scene import OutputInfo, default_resolution
    from kmpipe.stages.video import MIN_FRAMES

    recipe = remember_recipe(load_recipe(recipe_path))
    out_dir = Path(out_dir).absolute()  # tasks may run in other processes, in other folders
    info = recipe.info
    names = [p.name for p in info.product]
    by_name = {p.name: p for p in info.product}
    unknown = [n for n in only if n not in by_name]
    if unknown:
        raise InputError(f"names no product of the recipe: {', '.join(unknown)} (it has {', '.join(names)})",
                         field="--only")  # fmt: skip
    if review_only and info.review is None:
        raise InputError("has no [review] table: give its foundations (products of the line), tones and illuminants",
                         path=recipe.path, field="review")  # fmt: skip
    wanted = set(only) or set(names)
    if review_only:
        wanted = set(info.review.foundations)
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
        key = task_key("material", product.source, {name: hashed(Path(p)) for name, p in inputs.items()}, settings)
        material_key[product.name] = key
        paths = {k: str(v) for k, v in inputs.items() if k in ("log", "plan", "manifest", "material")}
        add(Task("material", slug(product.name), product.name, (), key, (rel(folder / "material.json"),),
                 do_material, {"source": product.source, "out": str(folder), "inputs": {**paths, **settings}},
                 tuple(rel(p) for p in folders + written)), whose, None)  # fmt: skip
        if product.source != "material":
            thresholds = {k: getattr(recipe.thresholds, k) for k in recipe.thresholds.__dataclass_fields__}
            report = reports_dir / slug(product.name)
            whose = f"the report of {product.name}"
            claims.folder(rel(report), whose, "outputs.reports", own=True)
            contexts = render_contexts(recipe, product.name)
            add(Task("validate", slug(product.name), product.name, (f"material:{slug(product.name)}",),
                     task_key("validate", key, info.validation.illuminants, thresholds,
                              [(c["thickness_mm"], c["over"]) for c in contexts], _files_of(recipe, contexts, hashed)),
                     (rel(report / "validation.json"), rel(report / "report.html")), do_validate,
                     {"material": str(folder / "material.json"), "out": str(report),
                      "illuminants": info.validation.illuminants, "thresholds": thresholds, "contexts": contexts},
                     (rel(report),)), whose, "outputs.reports")  # fmt: skip

    rows = []
    choices = _frame_choices(out_dir)
    for product in info.product:
        if review_only or not product.layer or product.name not in (set(only) or set(names)):
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
        # The plan: keyed by what the renders read, written once beside the frames; every render task reads it.
        plan_id, plan_file = f"plan:{slug(product.name)}", folder / PLAN_FILE
        choice = choices.get(product.name)  # the frame settings kmpipe trade measured for it, if it did
        choice = None if choice is None else dataclasses.asdict(choice)
        plan_key = task_key("plan", _without_videos(data), files, upstream, choice)
        scene_args = {"recipe": str(recipe.path), "product": product.name, "materials": materials}
        add(Task("plan", slug(product.name), product.name, deps + checks, plan_key, (rel(plan_file),),
                 do_plan, {**scene_args, "out": str(plan_file), "choice": choice}, (rel(folder),)), whose,
            "outputs.frames")  # fmt: skip
        chunks = []
        for start in range(0, frame_count, FRAMES_PER_TASK):
            frames = list(range(start, min(start + FRAMES_PER_TASK, frame_count)))
            key = task_key("render", plan_key, frames, keep_going)
            task = Task(
                "render",
                f"{slug(product.name)}:{frames[0]}-{frames[-1]}",
                product.name,
                (*deps, *checks, plan_id),
                key,
                tuple(rel(folder / f"frame_{i:03d}.{ext}") for i in frames for ext in ("exr", "png")),
                do_render,
                {**scene_args, "plan": str(plan_file), "out": str(folder), "frames": frames, "header": {}},
                (rel(folder),),
            )
            add(task, whose, "outputs.frames")
            chunks.append(task.id)
        video = OutputInfo.model_validate(data.get("output") or {})  # checked when the recipe was loaded
        formats = list(dict.fromkeys(video.video))
        if frame_count >= MIN_FRAMES and formats:  # the turntable's videos, once all its frames are rendered
            add(Task("video", slug(product.name), product.name, (*checks, *chunks),
                     task_key("video", [tasks[c].key for c in chunks], formats, video.fps),
                     tuple(rel(folder / f"turntable.{f}") for f in formats), do_video,
                     {"frames": [str(folder / f"frame_{i:03d}.exr") for i in range(frame_count)], "out": str(folder),
                      "formats": formats, "fps": video.fps}), whose, "outputs.frames")  # fmt: skip
        width, height = default_resolution((data.get("scene") or {}).get("resolution"), data.get("skin") is not None)
        rows.append((product.name, product.shade or product.name, chunks, folder, frame_count, width * height))

    validations = [t for t in tasks.values() if t.kind == "validate"]
    if validations:
        entries = [(str(out_dir / t.outputs[0]), str(out_dir / t.outputs[1])) for t in validations]
        links = []
        if info.review is not None and (review_only or not only):
            page = inside(out_dir, outputs.review, recipe.where(("outputs", "review"))) / "review.html"
            links = [("Shade review: every foundation on every skin tone, under every light", str(page))]
        add(Task("reports", "", None, tuple(t.id for t in validations),
                 task_key("reports", [t.key for t in validations], links), (rel(reports_dir / "index.html"),),
                 do_reports, {"entries": entries, "out": str(reports_dir), "links": links},
                 (rel(reports_dir / "summary.json"),)),
            "the index of the reports", "outputs.reports")  # fmt: skip
        claims.file(rel(reports_dir / "summary.json"), "reports", "the index of the reports", "outputs.reports")
    if outputs.sheet is not None and rows:
        sheet = inside(out_dir, outputs.sheet, recipe.where(("outputs", "sheet")))
        stills = len(rows) > 1 and max(row[4] for row in rows) == 1  # one frame each: products fill the columns
        count = min(outputs.sheet_columns, len(rows) if stills else min(row[4] for row in rows))
        pixels = [row[5] for row in rows]  # of one frame of each product
        reads = sum(pixels) if stills else count * sum(pixels)
        cell = _sheet_cell(recipe, count, -(-len(rows) // count) if stills else len(rows), reads)
        # each product's turntable sampled at `count` evenly spaced frames; labels come from the frames' headers
        picked = [{"chunks": row[2], "frames": [str(row[3] / f"frame_{round(k * row[4] / count):03d}.exr")
                                                for k in range(1 if stills else count)]} for row in rows]  # fmt: skip
        chunks = [c for row in rows for c in row[2]]
        header = f"{info.line.name} · {info.line.illuminant}"
        dated = f"{header} · {datetime.date.today().isoformat()}"  # the date the sheet is made, not part of its key
        add(Task("sheet", "", None, tuple(chunks),
                 task_key("sheet", [tasks[c].key for c in chunks], count, header, cell, stills), (rel(sheet),),
                 do_sheet, {"rows": picked, "out": str(sheet), "header": dated, "columns": count, "cell": cell,
                            "captions": stills}),
            "the contact sheet", "outputs.sheet")  # fmt: skip

    if info.review is not None and (review_only or not only):
        _plan_review(recipe, out_dir, claims, add, material_key, rel)
    plan = RunPlan(recipe, out_dir, tasks, keep_going)
    mark_cached(plan)
    return plan


def _plan_review(recipe: Recipe, out_dir: Path, claims: _Claims, add, material_key: dict, rel) -> None:
    """The shade review's tasks: a row per skin tone (keyed by the tone's own spectrum, so that a new tone renders
    only its row), then the matrix."""
    from kmpipe.formats.recipe import review_foundations, review_illuminant_files
    from kmpipe.formats.skin_tones import tone_digests

    review = recipe.info.review
    folder = inside(out_dir, recipe.info.outputs.review, recipe.where(("outputs", "review")))
    claims.top(rel(folder), "the review folder", "outputs.review")
    foundations = [{"name": name, "shade": shade, "material": str(out_dir / PRODUCTS / slug(name) / "material.json"),
                    "thickness_mm": thickness} for name, shade, thickness in review_foundations(recipe)]  # fmt: skip
    deps = tuple(f"material:{slug(f['name'])}" for f in foundations)
    upstream = [material_key[f["name"]] for f in foundations]
    spd_files = review_illuminant_files(recipe)
    spds = {name: sha256(path) for name, (path, _) in spd_files.items()}  # an edited SPD file re-runs every row
    settings = [[f["shade"], f["thickness_mm"]] for f in foundations], review.illuminants, review.reference, spds
    rows, keys = [], []
    for source, tone, digest in tone_digests(review.tones, recipe.base, recipe.where(("review", "tones"))):
        out = folder / "tones" / tone
        claims.folder(rel(out), f"the review's row of {tone}", "outputs.review", own=True)
        key = task_key("tone", digest, upstream, settings, review.match_delta_e, review.tile)
        add(Task("tone", tone, None, deps, key, (rel(out / "row.json"),), do_tone,
                 {"tone_source": source, "tone_id": tone, "base": str(recipe.base), "foundations": foundations,
                  "illuminants": review.illuminants, "reference": review.reference,
                  "threshold": review.match_delta_e, "out": str(out), "tile": review.tile,
                  "illuminant_files": {n: (str(p), c) for n, (p, c) in spd_files.items()}},
                 (rel(out),)), f"the review's row of {tone}", "outputs.review")  # fmt: skip
        rows.append(str(out / "row.json"))
        keys.append(key)
    files = [folder / f"review.{ext}" for ext in ("json", "csv", "png", "html")]
    header = f"{recipe.info.line.name} · shade review · {datetime.date.today().isoformat()}"
    add(Task("review", "", None, tuple(f"tone:{Path(r).parent.name}" for r in rows), task_key("review", keys),
             tuple(rel(f) for f in files), do_review,
             {"rows": rows, "out": str(folder), "line": recipe.info.line.name, "illuminants": review.illuminants,
              "reference": review.reference, "threshold": review.match_delta_e, "header": header}),
        "the shade review", "outputs.review")  # fmt: skip


def _sheet_cell(recipe: Recipe, columns: int, sheet_rows: int, reads: int) -> int:
    """The side of the contact sheet's cells (``sheet_rows`` rows of ``columns``): 256 px, less for a line so long
    that the sheet would pass :data:`SHEET_PIXELS`; refused (InputError at ``outputs.sheet``) if the cells would be
    under 16 px or the frames the sheet reads (``reads`` pixels) pass :data:`SHEET_FRAME_PIXELS`."""
    cell = min(256, math.isqrt(SHEET_PIXELS // (columns * sheet_rows)) - 8)  # cells and the 8 px margins between them
    if cell < 16 or reads > SHEET_FRAME_PIXELS:
        raise InputError(
            f"a contact sheet of {sheet_rows} rows by {columns} columns is larger than kmpipe makes: at "
            f"most {SHEET_PIXELS // 10**6} million pixels, in cells of 16 px or more, from at most "
            f"{SHEET_FRAME_PIXELS // 10**6} million pixels of frames (this one reads {reads // 10**6} million); give "
            "fewer outputs.sheet_columns, a smaller scene.resolution, or run part of the line with --only",
            **recipe.where(("outputs", "sheet")),
        )
    return cell


def mark_cached(plan: RunPlan) -> None:
    """Mark the pending tasks whose record holds their key and whose outputs exist as cached; skip the renders of a
    material whose failed verdict is already known."""
    pending = [t for t in plan.tasks.values() if t.state == "pending"]
    for task in pending:
        result = cached_result(plan.out_dir, task)
        if result is not None:
            task.state, task.result = "cached", result
    for task in pending:
        if task.state == "pending" and all(plan.tasks[d].state == "cached" for d in task.deps
                                           if plan.tasks[d].kind == "validate"):  # fmt: skip
            blocked_by_validation(plan, task)


def _without_videos(data: dict) -> dict:
    """A product's scene data less the videos' settings (``[output] video, fps``), which key its video task only:
    another frame rate makes the videos again, not the frames."""
    if "output" not in data:
        return data
    output = {k: v for k, v in data["output"].items() if k not in ("video", "fps")}
    return {**data, "output": output}


def _manifest_inputs(manifest: Path) -> dict[str, Path]:
    """The files a manifest's fit reads (the manifest, its measurement CSVs, a certificate), by name; no data read."""
    from kmpipe.formats.manifest import manifest_files

    return {f"input:{i}": p for i, p in enumerate(manifest_files(manifest))}


def _scene_files(recipe: Recipe, data: dict, hashed: Callable[[Path], str]) -> dict[str, str]:
    """SHA-256 of the files a product's scene reads besides materials
    (:func:`kmpipe.formats.scene.referenced_files`), by
    their path relative to the recipe."""
    from kmpipe.formats.scene import SceneFile, referenced_files

    paths = referenced_files(SceneFile.model_validate(data), recipe.base)  # checked when the recipe was loaded
    return {os.path.relpath(p, recipe.base): hashed(p) for p in paths if is_regular(p)}


def _files_of(recipe: Recipe, contexts: list[dict], hashed: Callable[[Path], str]) -> dict[str, str]:
    """SHA-256 of the spectral CSVs the render contexts of a validation read, by their path relative to the recipe."""
    files = [str(c["over"]).partition(":")[0] for c in contexts]
    paths = [recipe.base / f for f in files if f.lower().endswith(".csv")]
    return {os.path.relpath(p, recipe.base): hashed(p) for p in paths if is_regular(p)}


def blocked_by_validation(plan: RunPlan, task: Task) -> bool:
    """Skip the plan, the renders and the videos of a product whose materials failed validation (unless keep_going);
    True when it was skipped."""
    if task.kind not in ("plan", "render", "video"):
        return False
    failed = failed_validations(plan, task)
    if failed and not plan.keep_going:
        names = ", ".join(plan.tasks[d].product for d in failed)
        task.state, task.reason = "skipped", f"validation of {names} failed (--keep-going renders it anyway)"
        return True
    return False


def failed_validations(plan: RunPlan, task: Task) -> list[str]:
    """The validate tasks among ``task``'s dependencies whose verdict is fail."""
    checks = [plan.tasks[d] for d in task.deps if plan.tasks[d].kind == "validate"]
    return [check.id for check in checks if check.result.get("verdict") == "fail"]
