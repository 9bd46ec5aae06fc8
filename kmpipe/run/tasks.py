"""The tasks of ``kmpipe run``: what each kind of task does, as plain functions of file paths and settings (so any
executor can run them), each calling the stage functions the CLI calls."""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from kmpipe import __version__
from kmpipe.formats.atomic_write import write_text_atomically
from kmpipe.formats.files import read_text
from kmpipe.formats.recipe import Recipe, load_recipe
from kmpipe.run.folder import refuse_symlinks, remove_tree

#: The render plan of a product (kmpipe.stages.plan_file), beside its frames.
PLAN_FILE = "plan.json"


#: What a task can do: make a product's material (measure, replay or fit), validate it, plan its render, render frames
#: of its turntable, make the turntable's videos; index the line's reports, lay out its contact sheet; a skin tone's
#: row of the shade review, the review's matrix.
KINDS = ("material", "validate", "plan", "render", "video", "reports", "sheet", "tone", "review")


def task_key(*parts) -> str:
    return hashlib.sha256(json.dumps([__version__, *parts], sort_keys=True, default=str).encode()).hexdigest()


@dataclass
class Task:
    """One unit of work: what it runs (``function`` with ``args``), what it needs and what it writes.

    ``kind`` is what it does (one of :data:`KINDS`), ``name`` which one (a product's folder name, and a render
    task's frames: ``face:0-3``); its ``id`` is ``KIND:NAME`` (``KIND`` alone for the line's own tasks), the name
    of its record. ``outputs`` are the files that make it complete; ``writes`` every other path it writes or
    deletes (its folders, a session's files), both relative to the output folder.
    """

    kind: str
    name: str
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

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"a task's kind is one of {', '.join(KINDS)}, not {self.kind!r}")

    @property
    def id(self) -> str:
        return f"{self.kind}:{self.name}" if self.name else self.kind


def do_material(source: str, inputs: dict, out: str) -> dict:
    """Make a product's material.json in folder ``out``: measure or replay and fit, fit, or copy."""
    from rich.console import Console

    from kmpipe.stages.fit import fit_manifests
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
            refuse_symlinks(session)
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
    fit_manifests([manifest], target)
    return {}


def do_validate(
    material: str, out: str, illuminants: list[str], thresholds: dict, contexts: list[dict] | None = None
) -> dict:
    """Validate a fitted material (its rendered colour in the line's ``contexts``) and write its report into
    ``out``; its verdict and reasons."""
    from kmpipe.formats.thresholds import Thresholds
    from kmpipe.stages.validate import write_report
    from kmpipe.validation.material import validate_material

    report = validate_material(material, illuminants=tuple(illuminants), thresholds=Thresholds(**thresholds),
                               contexts=contexts or None)  # fmt: skip
    write_report(report, out)
    radius = None if report.uncertainty is None else round(report.uncertainty.worst.radius, 4)  # as validation.json
    return {"verdict": report.verdict, "reasons": list(report.reasons), "worst_delta_e": report.worst_delta_e,
            "colour_radius": radius}  # fmt: skip


#: The recipe last loaded in this process, by its path and the SHA-256 of its text (render tasks share it).
_LOADED: dict[tuple[str, str], Recipe] = {}


def remember_recipe(recipe: Recipe) -> Recipe:
    _LOADED.clear()
    _LOADED[(str(recipe.path), hashlib.sha256(recipe.text.encode()).hexdigest())] = recipe
    return recipe


def _recipe(path: str) -> Recipe:
    """The recipe at ``path``, loaded once per process while its text is unchanged (every render task reads it)."""
    text = read_text(path, "TOML", field="recipe")
    found = _LOADED.get((path, hashlib.sha256(text.encode()).hexdigest()))
    return found if found is not None else remember_recipe(load_recipe(path))


def _product_scene(recipe: str, product: str, materials: dict):
    """The render scene of a product of the recipe at ``recipe``, its layers made of ``materials`` (name: path)."""
    from kmpipe.formats.scene import build_scene

    loaded = _recipe(recipe)
    index = [p.name for p in loaded.info.product].index(product)
    data = loaded.scene_data(loaded.info.product[index], {name: Path(path) for name, path in materials.items()})
    return build_scene(data, loaded.path, loaded.base, loaded.scene_where(index))


def do_plan(recipe: str, product: str, materials: dict, out: str, choice: dict | None = None) -> dict:
    """Plan a product's render, with the frame settings ``kmpipe trade`` chose for it (``choice``, the fields of a
    :class:`kmpipe.stages.frame_choice.FrameChoice`, or None), and write its plan file ``out``; the chosen mode."""
    from kmpipe.stages.frame_choice import FrameChoice
    from kmpipe.stages.plan_file import plan_to_file

    Path(out).parent.mkdir(parents=True, exist_ok=True)
    measured = None if choice is None else FrameChoice(**choice)
    return {"mode": plan_to_file(_product_scene(recipe, product, materials), Path(out), measured).mode}


def do_render(recipe: str, product: str, materials: dict, plan: str, out: str, frames: list[int], header: dict) -> dict:
    """Render frames of a product's turntable into ``out`` as its plan file ``plan`` says (no planning again)."""
    from kmpipe.stages.plan_file import read_plan
    from kmpipe.stages.render import render_scene

    folder = Path(out)
    todo = [i for i in frames if not _frame_done(folder, i, header.get("task_key"))]
    if todo:
        scene = _product_scene(recipe, product, materials)
        render_scene(scene, folder, plan=read_plan(plan, scene), frames=todo, header=header, echo=lambda _: None)
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


def do_video(frames: list[str], out: str, formats: list[str], fps: int) -> dict:
    """A product's turntable videos (``turntable.mp4``, ``.webp``) in ``out`` from its ``frames`` (EXR, their PNGs
    beside them), ``fps`` frames a second."""
    from kmpipe.stages.video import write_turntable_videos

    return {"videos": [str(p) for p in write_turntable_videos(frames, out, formats=formats, fps=fps)]}


def do_reports(entries: list[tuple[str, str]], out: str, links: list[tuple[str, str]] = ()) -> dict:
    """The validation index over (validation.json, report.html) pairs, linking ``links`` (title, page)."""
    from kmpipe.stages.validate import index_reports

    return {"index": str(index_reports(entries, out, links))}


def do_sheet(rows: list[dict], out: str, header: str, columns: int, cell: int, captions: bool = False) -> dict:
    """The contact sheet: a row per product (its ``frames``), ``columns`` frames each, in cells of ``cell`` pixels
    square, labelled from the frames' headers (product and shade, a warning mark where validation failed, camera
    azimuth per column); with ``captions`` (a line of one frame per product) the products fill ``columns`` columns
    row by row, each cell captioned with its product and shade."""
    from kmpipe.stages.sheet import write_contact_sheet

    frames = [f for row in rows for f in row["frames"]]
    write_contact_sheet(frames, out, columns=columns, header=header, cell=cell, captions=captions)
    return {"sheet": out}


def do_tone(**row) -> dict:
    """A skin tone's row of the shade review (:func:`kmpipe.stages.review.review_row`)."""
    from kmpipe.stages.review import review_row

    return review_row(**row)


def do_review(**review) -> dict:
    """The shade review's matrix from its rows (:func:`kmpipe.stages.review_page.write_review`)."""
    from kmpipe.stages.review_page import write_review

    return write_review(**review)
