"""The ``kmpipe`` command line: one subcommand per pipeline stage.

Exit status: 0 success, 1 a check failed, 2 bad input (a one-paragraph message, no traceback unless
``--debug``), 70 an internal error (a bug: please report it with the ``--debug`` traceback).
"""

from __future__ import annotations

import argparse
import errno
import sys
import traceback
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from kmpipe import __version__
from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.manifest import MAX_SMOOTHNESS, METHODS, parse_grid
from kmpipe.physics.flags import Flag
from kmpipe.stages.opengl import use_gl
from renderer.gl_platform import CHOICES as GL_CHOICES

EXIT_OK, EXIT_CHECK_FAILED, EXIT_BAD_INPUT, EXIT_INTERNAL = 0, 1, 2, 70
#: Errors of the user's file system, not of kmpipe: a path named too long, a loop of links, no permission, a full
#: or read-only disk. Anywhere they arise they are bad input (exit 2) naming the path.
USER_FILE_SYSTEM_ERRORS = {errno.ENAMETOOLONG, errno.ELOOP, errno.EACCES, errno.EPERM, errno.ENOSPC, errno.EROFS,
                           errno.EDQUOT}  # fmt: skip

#: Wavelengths (nm) shown in the summary table of ``kmpipe fit``.
SUMMARY_WAVELENGTHS = (450.0, 550.0, 650.0)


def _saunderson_arg(text: str) -> tuple[float, float]:
    try:
        k1, k2 = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected K1,K2 such as 0.04,0.6, got {text!r}") from None
    if not (0.0 <= k1 < 1.0 and 0.0 <= k2 < 1.0):
        raise argparse.ArgumentTypeError(f"Saunderson constants must lie in [0, 1), got {text!r}")
    return k1, k2


def _number_arg(low: float, high: float, *, low_included: bool, what: str):
    """An argparse type: a number in (low, high) (or [low, high) with ``low_included``), else a clear message."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not ((low <= value if low_included else low < value) and value < high):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return value

    return parse


_noise_arg = _number_arg(0.0, 0.5, low_included=False, what="a standard deviation of reflectance in (0, 0.5)")
_smoothness_arg = _number_arg(0.0, MAX_SMOOTHNESS, low_included=True, what=f"a number in [0, {MAX_SMOOTHNESS:g})")
_positive_arg = _number_arg(0.0, float("inf"), low_included=False, what="a positive number")


def _thickness_arg(text: str) -> float:
    from kmpipe.formats.manifest import parse_thickness_mm

    try:
        return parse_thickness_mm(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _draws_arg(text: str) -> int:
    if not text.isdigit() or int(text) > 100_000:
        raise argparse.ArgumentTypeError(f"expected a whole number of draws from 0 to 100000, got {text!r}")
    return int(text)


def _grid_arg(text: str) -> str:
    try:
        parse_grid(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None
    return text


def _summary_table(materials: list[tuple[Path, object]]) -> Table:
    from kmpipe.formats.material import Material

    first: Material = materials[0][1]
    spectral = first.wavelengths is not None
    table = Table(title="Fitted materials", title_justify="left")
    table.add_column("sample")
    table.add_column("method")
    labels = SUMMARY_WAVELENGTHS if spectral else tuple(first.channels)
    for label in labels:
        table.add_column(f"K/S {label:.0f}" if spectral else f"K/S {label}", justify="right")
    table.add_column("S 550 (1/mm)" if spectral else f"S {labels[1]} (1/mm)", justify="right")
    table.add_column("worst RMSE", justify="right")
    table.add_column("flags")
    for _, material in materials:
        ks = material.ks_ratio
        cells = []
        for label in labels:
            i = int(np.argmin(np.abs(material.wavelengths - label))) if spectral else material.channels.index(label)
            cells.append(f"{ks[i]:.3g}")
        j = int(np.argmin(np.abs(material.wavelengths - 550.0))) if spectral else 1
        worst = max(m.rmse for m in material.measurements)
        counts = [
            f"{f.name.lower()} x{int(np.count_nonzero(material.flags & f))}" for f in Flag if np.any(material.flags & f)
        ]
        table.add_row(
            escape(material.name),
            escape(material.method),
            *cells,
            f"{material.S[j]:.3g}",
            f"{worst:.1e}",
            ", ".join(counts) or "none",
        )
    return table


def _cmd_fit(args: argparse.Namespace, console: Console) -> int:
    from kmpipe.stages.fit import fit_manifests

    written = fit_manifests(
        args.manifest,
        args.output,
        grid=args.grid,
        method=args.method,
        saunderson=args.saunderson,
        smoothness=args.smoothness,
        noise=args.noise,
    )
    console.print(_summary_table(written))
    for path, material in written:
        console.print(
            f"wrote {path}  ({material.name}: {material.method}, {len(material.labels)} "
            f"{'wavelengths' if material.wavelengths is not None else 'channels'})",
            highlight=False,
            markup=False,
        )
    return EXIT_OK


def _cmd_ingest(args: argparse.Namespace, console: Console) -> int:
    from kmpipe.stages.ingest import ingest

    table = ingest(
        args.radiance, args.output, white=args.white, certified=args.certified, dark=args.dark, grid=args.grid
    )
    grid = table.wavelengths
    console.print(
        f"wrote {len(table.columns)} reflectance spectra ({grid[0]:g}-{grid[-1]:g} nm) to {args.output}", markup=False
    )
    return EXIT_OK


def _cmd_validate(args: argparse.Namespace, console: Console) -> int:
    from kmpipe.stages.validate import validate_materials

    result = validate_materials(
        args.material,
        manifest=args.manifest,
        illuminants=[name.strip() for name in args.illuminant.split(",") if name.strip()],
        observer=args.observer,
        config=args.config,
        overrides={
            "delta_e_warn": args.delta_e_warn,
            "delta_e_fail": args.delta_e_fail,
            "rmse_warn": args.rmse_warn,
            "rmse_fail": args.rmse_fail,
            "uncertainty_warn": args.uncertainty_warn,
            "uncertainty_fail": args.uncertainty_fail,
        },
        output=args.output,
        context=None if args.at is None and args.over is None else {"thickness_mm": args.at, "over": args.over},
        draws=args.draws,
    )

    table = Table(title="Validation", title_justify="left")
    for column, justify in (
        ("sample", "left"),
        ("verdict", "left"),
        ("worst ΔE00", "right"),
        ("colour ±ΔE00 (95 %)", "right"),
        ("reasons", "left"),
    ):
        table.add_column(column, justify=justify)
    colours = {"pass": "green", "warn": "yellow", "fail": "red"}
    for entry in result.entries:
        report, worst = entry.report, entry.report.worst_delta_e
        table.add_row(
            escape(report.material.name),
            f"[{colours[report.verdict]}]{report.verdict}[/]",
            "n/a" if worst is None else f"{worst:.2f}",
            "n/a" if report.uncertainty is None else f"{report.uncertainty.worst.radius:.2f}",
            escape(", ".join(report.reasons)) or "none",
        )
    for broken in result.broken:
        table.add_row(escape(broken.path.name), "[red]error[/]", "", escape(broken.error.message))
    console.print(table)
    if len(result.materials) == 1:
        doubt = result.entries[0].report.uncertainty if result.entries else None
        if doubt is not None:
            from kmpipe.validation.uncertainty import headline, suggestion_line

            console.print(headline(doubt.worst), highlight=False, markup=False)
            console.print(f"what to measure next: {suggestion_line(doubt)}", highlight=False, markup=False)
        console.print(f"report: {result.entries[0].page}", highlight=False, markup=False)
    elif result.index is not None:
        console.print(f"index of {len(result.entries)} reports: {result.index}", highlight=False, markup=False)
    if result.broken:
        errors = Console(stderr=True, emoji=False)
        for broken in result.broken:
            errors.print(
                f"[bold red]kmpipe validate: error:[/] {escape(str(broken.error))}", highlight=False, soft_wrap=True
            )
        return EXIT_BAD_INPUT
    return EXIT_CHECK_FAILED if result.failed else EXIT_OK


def _cmd_measure(args: argparse.Namespace, console: Console) -> int:
    from kmpipe.stages.measure import run_session

    interactive = False if args.unattended else None
    plan, out_dir = args.plan, args.output
    if args.add_suggested is not None:
        from kmpipe.formats.measurement_plan import load_plan
        from kmpipe.stages.plan_addition import add_suggestion

        plan, line = add_suggestion(args.plan, args.add_suggested)
        out_dir = out_dir or plan.parent / f"{load_plan(plan).sample.name}-next"
        console.print(f"measuring {plan} (the plan and {line}) into {out_dir}", highlight=False, markup=False)
    run_session(
        plan,
        args.port,
        out_dir=out_dir,
        record=args.record,
        resume=args.resume,
        interactive=interactive,
        baudrate=args.baudrate,
        rtscts=args.rtscts,
        console=console,
    )
    return EXIT_OK


def _cmd_emulate(args: argparse.Namespace, console: Console) -> int:
    """Serve the emulator of the samples script until Ctrl-C or SIGTERM (exit 0)."""
    from kmpipe.stages.emulate import serve_emulator

    def echo(line: str) -> None:
        console.print(line, highlight=False, markup=False, soft_wrap=True)
        console.file.flush()

    serve_emulator(args.samples, link=args.link, socket_port=args.socket, time_scale=args.time_scale, echo=echo)
    return EXIT_OK


def _cmd_card(args: argparse.Namespace, console: Console) -> int:
    from kmpipe.stages.card import write_card_files

    written = write_card_files(args.output, args.layout)
    if written.layout is not None:
        console.print(f"wrote the layout {written.layout} (kmpipe ingest-raw reads it)", highlight=False, markup=False)
    console.print(f"wrote the card {written.card}: print it at 100 % scale", highlight=False, markup=False)
    return EXIT_OK


def _cmd_ingest_raw(args: argparse.Namespace, console: Console) -> int:
    from kmpipe.stages.ingest_raw import ingest_raw

    manifest = ingest_raw(
        args.photos,
        args.layout,
        args.output,
        rois=args.roi or [],
        name=args.name,
        thickness=args.thickness,
        polarization_factor=args.polarization_factor,
    )
    console.print(f"wrote {args.output / 'reflectance.csv'} and {manifest}", highlight=False, markup=False)
    return EXIT_OK


def _labels_arg(text: str) -> list[str]:
    return [label.strip() for label in text.split(",")]


def _cmd_sheet(args: argparse.Namespace, console: Console) -> int:
    from kmpipe.stages.sheet import write_contact_sheet

    sheet = write_contact_sheet(
        args.frames,
        args.output,
        columns=args.columns,
        row_labels=args.row_labels,
        column_labels=args.column_labels,
        header=args.header,
    )
    (n_rows, n_cols), (width, height) = sheet.grid, sheet.size
    console.print(
        f"wrote the sheet {args.output} ({n_rows} x {n_cols} frames, {width} x {height} px)",
        highlight=False,
        markup=False,
    )
    return EXIT_OK


def _progress(console: Console):
    """A transient progress bar: description, bar, done of total, time elapsed."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    return Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
        console=console, transient=True,
    )  # fmt: skip


def _cmd_render(args: argparse.Namespace, console: Console) -> int:
    from kmpipe.stages.render import render_scene

    files.output_folder(args.output, create=False)
    with _progress(console) as progress:
        first = "measuring frame settings" if args.measure_settings else "rendering frames"
        task = progress.add_task(first, total=None)

        def on_frame(done: int, total: int) -> None:
            progress.update(task, completed=done, total=total, description="rendering frames")

        written = render_scene(
            args.scene,
            args.output,
            explain=args.explain,
            measure_settings=args.measure_settings,
            scattering=not args.no_sss,
            ab_scattering=args.ab_sss,
            echo=lambda text: console.print(text, highlight=False, markup=False, soft_wrap=True),
            on_frame=on_frame,
        )
    frames = [path for path in written if path.suffix == ".exr" and path.parent == args.output]
    console.print(f"wrote {len(frames)} frames (EXR and PNG) to {args.output}", highlight=False, markup=False)
    if args.ab_sss:
        console.print(f"wrote the A/B sheet {args.output / 'ab_sss.png'} (frames without SSS in no_sss/)", markup=False)
    videos = [str(path) for path in written if path.suffix in (".mp4", ".webp")]
    if videos:
        console.print(f"wrote the turntable videos {', '.join(videos)}", highlight=False, markup=False, soft_wrap=True)
    return EXIT_OK


def _recipe_gl(recipe, args: argparse.Namespace) -> None:
    """The recipe's ``[line] gl``, unless ``--gl`` chose."""
    if args.gl is None and recipe.info.line.gl is not None:
        use_gl(recipe.info.line.gl, path=recipe.path, field="line.gl")


def _execute(plan, args: argparse.Namespace, console: Console, label: str):
    """Run a planned graph of tasks as the command's options say, with a progress bar named ``label``."""
    from kmpipe.run.execute import execute

    with _progress(console) as progress:
        bar = progress.add_task(label, total=None)

        def on_task(task, done: int, total: int) -> None:
            progress.update(bar, completed=done, total=total, description=f"{label} (last: {task.id})")

        return execute(plan, executor=args.executor, workers=args.workers, scheduler=args.scheduler,
                       on_task=on_task, wait=args.wait)  # fmt: skip


def _cmd_run(args: argparse.Namespace, console: Console) -> int:
    from kmpipe.run.planning import plan_run

    out_dir = files.output_folder(args.output or args.recipe.parent / "out", create=False)
    plan = plan_run(args.recipe, out_dir, only=args.only or (), keep_going=args.keep_going)
    _recipe_gl(plan.recipe, args)
    if args.dry_run:
        console.print(plan.explain(), highlight=False, markup=False, soft_wrap=True)
        return EXIT_OK
    summary = _execute(plan, args, console, "tasks")
    table = Table(title=f"kmpipe run: {escape(plan.recipe.info.line.name)}", title_justify="left")
    for column in ("product", "validation", "frames"):
        table.add_column(column)
    rendered: dict[str, int] = {}
    for task in plan.tasks.values():
        if task.kind == "render" and task.state in ("run", "cached"):
            rendered[task.product] = rendered.get(task.product, 0) + len(task.args["frames"])
    colours = {"pass": "green", "warn": "yellow", "fail": "red"}
    for product in plan.recipe.info.product:
        verdict = summary.verdicts.get(product.name)
        shown = "—" if verdict is None else f"[{colours.get(verdict, 'white')}]{verdict}[/]"
        skipped = [t.reason for t in plan.tasks.values() if t.product == product.name and t.state == "skipped"]
        frames = str(rendered.get(product.name, 0)) + (f" (skipped: {escape(skipped[0])})" if skipped else "")
        table.add_row(escape(product.name), shown, frames)
    console.print(table)
    console.print(
        f"{summary.products} products, {summary.frames} frames in {summary.seconds:.1f} s: {summary.ran} tasks run, "
        f"{summary.cached} cached, {summary.skipped} skipped, {len(summary.failed)} failed",
        highlight=False,
        soft_wrap=True,
    )
    if summary.sheet is not None:
        console.print(f"contact sheet: {summary.sheet}", highlight=False, markup=False, soft_wrap=True)
    if args.explain:
        for task in plan.tasks.values():
            if task.kind == "plan" and task.state in ("run", "cached"):
                lines = files.read_json(out_dir / task.outputs[0], "JSON", "kmpipe render plan")["explain"]
                console.print(f"\nRender plan of {task.product}:", highlight=False, markup=False)
                console.print("\n".join(lines), highlight=False, markup=False, soft_wrap=True)
    if summary.reports is not None:
        console.print(f"validation reports: {summary.reports}", highlight=False, markup=False, soft_wrap=True)
    if summary.failed:
        errors = Console(stderr=True, emoji=False)
        for line in summary.failed:
            errors.print(f"[bold red]kmpipe run: error:[/] {escape(line)}", highlight=False, soft_wrap=True)
        return EXIT_BAD_INPUT
    return EXIT_CHECK_FAILED if summary.skipped or "fail" in summary.verdicts.values() else EXIT_OK


def _cmd_review(args: argparse.Namespace, console: Console) -> int:
    from kmpipe.run.planning import plan_run

    out_dir = files.output_folder(args.output or args.recipe.parent / "out", create=False)
    plan = plan_run(args.recipe, out_dir, review_only=True)
    _recipe_gl(plan.recipe, args)
    if args.dry_run:
        console.print(plan.explain(), highlight=False, markup=False, soft_wrap=True)
        return EXIT_OK
    summary = _execute(plan, args, console, "review")
    review = plan.tasks["review"]
    console.print(
        f"{sum(t.kind == 'tone' for t in plan.tasks.values())} skin tones x "
        f"{len(plan.recipe.info.review.foundations)} foundations x {len(plan.recipe.info.review.illuminants)} "
        f"illuminants in {summary.seconds:.1f} s: {summary.ran} tasks run, {summary.cached} cached",
        highlight=False,
        soft_wrap=True,
    )
    if summary.failed:
        errors = Console(stderr=True, emoji=False)
        for line in summary.failed:
            errors.print(f"[bold red]kmpipe review: error:[/] {escape(line)}", highlight=False, soft_wrap=True)
        return EXIT_BAD_INPUT
    console.print(f"shade review: {out_dir / review.outputs[3]}", highlight=False, markup=False, soft_wrap=True)
    breaks = review.result.get("breaks", 0)
    if breaks:
        console.print(f"{breaks} matches break under another light (listed in the review)", highlight=False)
    return EXIT_OK


def _cmd_trade(args: argparse.Namespace, console: Console) -> int:
    from kmpipe.formats.recipe import load_recipe
    from kmpipe.run.trade import trade_line

    out_dir = files.output_folder(args.output or args.recipe.parent / "out", create=False)
    _recipe_gl(load_recipe(args.recipe), args)
    with _progress(console) as progress:
        bar = progress.add_task("trade", total=None)
        result = trade_line(args.recipe, out_dir, only=args.only or (), wait=args.wait,
                            echo=lambda text: progress.update(bar, description=text))  # fmt: skip
    table = Table(title=f"kmpipe trade: {escape(result.line)} (one frame of each product; target ΔE00 "
                        f"{result.target:g})", title_justify="left")  # fmt: skip
    for column, justify in (
        ("knob", "left"),
        ("setting", "left"),
        ("products", "right"),
        ("s", "right"),
        ("ΔE00 mean", "right"),
        ("ΔE00 p95", "right"),
        ("vs planned", "right"),
        ("", "left"),
    ):
        table.add_column(column, justify=justify, no_wrap=True)  # fmt: skip
    for row in result.rows:
        marks = ", ".join(m for m, on in (("planned", row.planned), ("front", row.front)) if on)
        table.add_row(escape(row.knob), escape(row.value), str(row.products), f"{row.seconds:.2f}",
                      f"{row.mean_de:.3f}", f"{row.p95_de:.3f}", f"{row.shift_de:.3f}", marks)  # fmt: skip
    wide = Console(emoji=False, width=max(console.width, 150))
    wide.print(table)
    wide.print("ΔE00 mean and p95: per pixel of the products, against the most exact setting; vs planned: the mean "
               "against the frames as planned (what the setting alone changes)", highlight=False)  # fmt: skip
    missing = sorted({s.knob for s in result.settings if s.seconds is None} - {r.knob for r in result.rows})
    if missing:
        console.print(f"not applicable to this line: {', '.join(missing)}", highlight=False)
    planned = next(r for r in result.rows if r.knob == "planned" and r.planned)
    verdict = "within" if planned.mean_de <= result.target else "above"
    wide.print(f"as planned: {planned.seconds:.2f} s for {planned.products} frames, mean ΔE00 {planned.mean_de:.3f} "
               f"against the most exact setting, {verdict} the target {result.target:g}", highlight=False)  # fmt: skip
    closest = min((r for r in result.rows if r.knob != "planned"), key=lambda r: r.mean_de, default=None)
    if closest is not None and closest.mean_de < planned.mean_de:
        wide.print(f"closest to it with one knob changed: {closest.knob} = {closest.value} (mean ΔE00 "
                      f"{closest.mean_de:.3f}, {closest.seconds:.2f} s)", highlight=False, markup=False)  # fmt: skip
    for knob, row in result.chosen.items():
        chosen = next((r.value for r in result.rows if r.knob == knob and r.planned), None)
        verdict = "as planned" if chosen == row.value else f"planned: {chosen}"
        console.print(f"cheapest within ΔE00 {result.target:g}: {knob} = {row.value} ({verdict})", highlight=False,
                      markup=False)  # fmt: skip
    for product, choice in result.choices.items():
        settings = ", ".join(f"{knob} {value}" for knob, value in (
            ("antialiasing", choice.antialiasing), ("shadow map", choice.shadow_map),
            ("subsurface scattering", choice.scattering)) if value is not None)  # fmt: skip
        console.print(f"frame settings for {product}: {settings} (ΔE00 p95 {choice.p95_de:.3f} against them at their "
                      f"most exact; mean {choice.reference_de:.3f} against the reference; {choice.seconds:.2f} s)",
                      highlight=False, markup=False)  # fmt: skip
    console.print(f"wrote {', '.join(str(path) for path in result.files)}; kmpipe run into {out_dir} plans each "
                  "product's frames with its frame settings", highlight=False, markup=False,
                  soft_wrap=True)  # fmt: skip
    return EXIT_OK


def _graph_options(command: argparse.ArgumentParser) -> None:
    """The options of a command that runs a recipe's graph of tasks (``run``, ``review``)."""
    command.add_argument("-o", "--output", type=Path, help="output folder (default: out/ beside the recipe)")
    command.add_argument("--dry-run", action="store_true", help="print what would run, what is cached and skipped")
    command.add_argument("--executor", choices=("local", "dask"), default="local", help="where tasks run")
    command.add_argument("--scheduler", metavar="ADDRESS", help="a Dask scheduler, e.g. tcp://HOST:8786 (with dask)")
    command.add_argument(
        "--workers", type=int, default=1, choices=range(1, 65), metavar="N",
        help="processes (local: a pool when N > 1; dask: local cluster size); default 1",
    )  # fmt: skip
    command.add_argument(
        "--wait",
        action="store_true",
        help="wait for another kmpipe run on the same output folder to finish (default: exit 2 naming it)",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="kmpipe",
        description="Measurements of cosmetic films to Kubelka-Munk materials and render assets.",
        epilog="Exit status: 0 success, 1 a check failed, 2 bad input, 70 internal error.",
    )
    parser.add_argument("--version", action="version", version=f"kmpipe {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the traceback of any error")
    parser.add_argument(
        "--gl", choices=GL_CHOICES, help="render through OSMesa (CPU), EGL (a GPU) or auto (EGL where a GPU is; the "
        "default, or a recipe's [line] gl)",
    )  # fmt: skip
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    fit = commands.add_parser(
        "fit",
        help="fit Kubelka-Munk K and S of a sample from its measurements",
        description="Fit K and S (per mm) of one sample, or of several (one output each), from a sample "
        "manifest (TOML; see docs/formats.md) and write MATERIAL.json.",
    )
    fit.add_argument("manifest", nargs="+", type=Path, help="sample manifest(s), TOML")
    fit.add_argument("-o", "--output", type=Path, required=True, help="MATERIAL.json, or a folder for several samples")
    fit.add_argument("--method", choices=METHODS, help="inversion method (default: the manifest's, else lsq)")
    fit.add_argument(
        "--saunderson", type=_saunderson_arg, metavar="K1,K2", help="model surface reflection, e.g. 0.04,0.6"
    )
    fit.add_argument(
        "--grid", type=_grid_arg, metavar="START:STOP:STEP", help="fit on this grid in nm, e.g. 400:700:10"
    )
    fit.add_argument(
        "--smoothness",
        type=_smoothness_arg,
        help="lsq: second-difference penalty across wavelength (e.g. 1e-6)",
    )
    fit.add_argument("--noise", type=_noise_arg, help="noise standard deviation of the readings, for standard errors")
    fit.set_defaults(run=_cmd_fit)

    ingest = commands.add_parser(
        "ingest",
        help="turn radiance spectra into reflectance with a white standard",
        description="R = (L - L_dark) / (L_white - L_dark) x certified reflectance of the white standard.",
    )
    ingest.add_argument("radiance", type=Path, help="spectral CSV holding radiance")
    ingest.add_argument("--white", required=True, metavar="FILE:COLUMN", help="radiance of the white standard")
    ingest.add_argument(
        "--certified",
        default="builtin:baso4",
        metavar="SPEC",
        help="builtin:baso4 (default) or FILE[:COLUMN]",
    )
    ingest.add_argument("--dark", metavar="FILE:COLUMN", help="dark reading to subtract")
    ingest.add_argument("--grid", type=_grid_arg, metavar="START:STOP:STEP", help="resample onto this grid (nm)")
    ingest.add_argument("-o", "--output", type=Path, required=True, help="reflectance CSV to write")
    ingest.set_defaults(run=_cmd_ingest)

    validate = commands.add_parser(
        "validate",
        help="check fitted materials against their measurements and write reports",
        description="Predict every measurement from K and S, report residuals and Delta E 2000, run the checks "
        "(docs/formats.md lists them) and give a verdict per sample. Exit status 0 when every sample passes or "
        "warns, 1 when one fails, 2 on bad input.",
    )
    validate.add_argument("material", type=Path, help="MATERIAL.json, or a folder of them (a product line)")
    validate.add_argument("--manifest", type=Path, help="the sample manifest (default: the one in the provenance)")
    validate.add_argument("--illuminant", default="D65", metavar="LIST", help="e.g. D65,D55,A,F11 (default D65)")
    validate.add_argument("--observer", choices=("2", "10"), default="2", help="CIE 1931 2 deg or 1964 10 deg")
    validate.add_argument(
        "-o", "--output", type=Path, help="report folder (default: reports/SAMPLE/ beside the material)"
    )
    validate.add_argument("--config", type=Path, help="TOML file with a [thresholds] table")
    for name, what in (
        ("--delta-e-warn", "Delta E 2000 above which a measurement warns (default 1)"),
        ("--delta-e-fail", "Delta E 2000 above which a measurement fails (default 2)"),
        ("--rmse-warn", "spectral RMSE above which a measurement warns (default 0.01)"),
        ("--rmse-fail", "spectral RMSE above which a measurement fails (default 0.02)"),
        ("--uncertainty-warn", "rendered colour's 95 %% radius (Delta E 2000) above which a sample warns (default 1)"),
        ("--uncertainty-fail", "rendered colour's 95 %% radius (Delta E 2000) above which a sample fails (default 2)"),
    ):
        validate.add_argument(name, type=_positive_arg, metavar="X", help=what)
    validate.add_argument("--at", type=_thickness_arg, metavar="THICKNESS",
                          help="judge the rendered colour of a film this thick, e.g. '15 um' (default: the median "
                          "measured film)")  # fmt: skip
    validate.add_argument("--over", metavar="SUBSTRATE",
                          help="... over this: a backing of the sample, a reflectance 0-1, 'colorchecker:NAME' or "
                          "FILE.csv[:COLUMN] (default: the lightest backing)")  # fmt: skip
    validate.add_argument(
        "--draws",
        type=_draws_arg,
        default=1000,
        metavar="N",
        help="Monte Carlo draws that check the linearized radius (default 1000; 0: none)",
    )
    validate.set_defaults(run=_cmd_validate)

    measure = commands.add_parser(
        "measure",
        help="measure a sample with a Konica Minolta CS-2000 (guided session)",
        description="Measure the white standard, the backings, the masstone and the films of one sample as a plan "
        "(TOML; docs/formats.md) lists them. Prompts the technician when run at a terminal, runs unattended "
        "otherwise. Each reading is saved as soon as it is read; an interrupted session continues with --resume. "
        "Writes radiance.csv, reflectance.csv and a manifest that kmpipe fit accepts.",
    )
    measure.add_argument("plan", type=Path, help="measurement plan, TOML")
    measure.add_argument(
        "--port", required=True, help="/dev/ttyACM0, /dev/ttyUSB0, socket://HOST:PORT, replay://LOG ..."
    )
    measure.add_argument("-o", "--output", type=Path, help="session folder (default: SAMPLE/ beside the plan)")
    measure.add_argument(
        "--record",
        type=Path,
        metavar="LOG",
        help="append every byte exchanged to this session log (its folder must exist; an existing log must be a "
        "recording of the same plan)",
    )
    measure.add_argument("--resume", action="store_true", help="continue an interrupted session in the folder")
    measure.add_argument("--add-suggested", type=Path, metavar="VALIDATION.json",
                         help="add the measurement that validation found would shrink the rendered colour's "
                         "uncertainty most: writes PLAN.next.toml and measures it (default -o: "
                         "SAMPLE-next/)")  # fmt: skip
    measure.add_argument("--unattended", action="store_true", help="never prompt (the default when not at a terminal)")
    measure.add_argument("--baudrate", type=int, default=115200, help="RS-232 only (USB ignores it); default 115200")
    measure.add_argument("--rtscts", action="store_true", help="RTS/CTS flow control (the CS-2000's RS-232 default)")
    measure.set_defaults(run=_cmd_measure)

    emulate = commands.add_parser(
        "emulate",
        help="run a CS-2000 emulator on a pseudo-terminal (and a TCP port) to try kmpipe measure without hardware",
    )
    emulate.add_argument("--link", type=Path, default=Path("/tmp/cs2000"), help="device path to create (symlink)")
    emulate.add_argument("--samples", type=Path, required=True, help="TOML naming the reflectance CSV and sequence")
    emulate.add_argument("--socket", type=int, metavar="PORT", help="also listen on socket://127.0.0.1:PORT")
    emulate.add_argument(
        "--time-scale", type=_positive_arg, help="multiply instrument times (e.g. 0.1; default: the script's, else 1)"
    )
    emulate.set_defaults(run=_cmd_emulate)

    card = commands.add_parser(
        "card", help="write a printable drawdown card (black and white backings, white patch, ArUco markers)"
    )
    card.add_argument("-o", "--output", type=Path, required=True, help="CARD.pdf or CARD.png")
    card.add_argument("--layout", type=Path, help="layout TOML (default: the built-in layout, written beside the card)")
    card.set_defaults(run=_cmd_card)

    ingest_raw = commands.add_parser(
        "ingest-raw",
        help="cross-polarized RAW photos of a drawdown card to per-channel reflectance and a sample manifest",
    )
    ingest_raw.add_argument("photos", nargs="+", type=Path, help="RAW photos (DNG, CR2, NEF, ARW ...) of one card")
    ingest_raw.add_argument("--layout", type=Path, required=True, help="the card's layout TOML")
    ingest_raw.add_argument("-o", "--output", type=Path, required=True, help="sample folder to write")
    ingest_raw.add_argument("--roi", action="append", metavar="NAME=x,y,w,h", help="a region in pixels (no markers)")
    ingest_raw.add_argument("--name", help="sample name (default: the output folder's name)")
    ingest_raw.add_argument("--thickness", help="film thickness, e.g. '30 um', for film regions that do not give one")
    ingest_raw.add_argument(
        "--polarization-factor",
        type=_positive_arg,
        default=1.0,
        help="analyzer transmission of the reference over that of the sample (1: white patch in the same photo)",
    )
    ingest_raw.set_defaults(run=_cmd_ingest_raw)

    sheet = commands.add_parser(
        "sheet",
        help="lay rendered frames (EXR, PNG) out in a labelled contact sheet (PNG)",
        description="Frames fill the grid row-major; EXR frames are linear and sRGB-encoded, PNG frames are used "
        "as they are. Frames from kmpipe render label themselves: product and shade per row, camera angle per "
        "column, scene, illuminant and date on top. Other frames' labels default to file stems: of the first "
        "row's frames for the columns, of each row's first frame for the rows.",
    )
    sheet.add_argument("frames", nargs="+", type=Path, help="frames, EXR (linear) or PNG (sRGB)")
    sheet.add_argument("-o", "--output", type=Path, required=True, help="SHEET.png")
    sheet.add_argument(
        "--columns",
        type=int,
        choices=range(1, 1000),
        metavar="N",
        help="frames per row (default: all, at most 4)",
    )
    sheet.add_argument("--row-labels", type=_labels_arg, metavar="A,B,..", help="one label per row")
    sheet.add_argument("--column-labels", type=_labels_arg, metavar="X,Y,..", help="one label per column")
    sheet.add_argument("--header", help="a line across the top (default for kmpipe frames: scene, illuminant, date)")
    sheet.set_defaults(run=_cmd_sheet)

    render = commands.add_parser(
        "render",
        help="render a scene (TOML: mesh, films, substrate, light, camera) to EXR and PNG frames",
        description="Plan the optical tables of the scene's films, render each frame (a turntable when the scene "
        "has one) with the Kubelka-Munk layer pass and write frame_NNN.exr (linear) and frame_NNN.png (sRGB).",
    )
    render.add_argument("scene", type=Path, help="scene file, TOML (docs in kmpipe/formats/scene.py)")
    render.add_argument("-o", "--output", type=Path, required=True, help="folder for the frames")
    render.add_argument("--explain", action="store_true", help="print the render plan: modes tried, chosen, tables")
    render.add_argument(
        "--measure-settings",
        action="store_true",
        help="choose antialiasing, shadow map and subsurface scattering (those the scene leaves to the planner) by "
        "measuring, as kmpipe trade does: the cheapest whose first frame keeps 95 %% of the product's pixels within "
        "the scene's Delta E 2000 target of the most exact one (a few frames rendered first; --explain says what "
        "was chosen)",
    )
    render.add_argument("--no-sss", action="store_true", help="on skin: no subsurface scattering")
    render.add_argument(
        "--ab-sss",
        action="store_true",
        help="on skin: also render every frame without subsurface scattering (OUT_DIR/no_sss/) and lay both out "
        "on OUT_DIR/ab_sss.png",
    )
    render.set_defaults(run=_cmd_render)

    run = commands.add_parser(
        "run",
        help="run a product line's recipe: replay or fit, validate, render turntables, sheets; cached, resumable",
        description="Runs every stage the recipe needs as a graph of tasks cached by the content of their inputs: "
        "a second run does nothing, a changed product re-runs that product's tasks, a killed run resumes. Exit "
        "status 0: done; 1: a product failed validation (not rendered unless --keep-going) or a task was skipped; 2: "
        "bad input.",
    )
    run.add_argument("recipe", type=Path, help="recipe file, TOML (docs/formats.md)")
    _graph_options(run)
    run.add_argument("--only", nargs="+", metavar="PRODUCT", help="these products (and the materials they use)")
    run.add_argument("--keep-going", action="store_true", help="render products that failed validation, marked")
    run.add_argument(
        "--explain",
        action="store_true",
        help="print each product's render plan after the run: modes, tables, shadows, antialiasing, subsurface "
        "scattering, and whether kmpipe trade chose them",
    )
    run.set_defaults(run=_cmd_run)

    review = commands.add_parser(
        "review",
        help="the shade review of a recipe's [review]: every foundation on every skin tone under every illuminant",
        description="Renders each foundation of [review] worn on each skin tone (built-in chart and complexion "
        "samples, the lab's panel, any reflectance CSV) under each illuminant, with coverage, match and the best shade "
        "per tone beside each tile, and the matches that break under another light (metamerism); writes review.png, "
        "review.csv, review.json and review.html under the output folder's review/. Cached like kmpipe run (a new "
        "tone renders only its row). Exit status 0: done; 2: bad input.",
    )
    review.add_argument("recipe", type=Path, help="recipe file with a [review] table, TOML (docs/formats.md)")
    _graph_options(review)
    review.set_defaults(run=_cmd_review)

    trade = commands.add_parser(
        "trade",
        help="the speed/accuracy trade on a line's own products: every knob's time and Delta E 2000",
        description="Renders one frame of each product of the line as planned, with one knob at a time set "
        "otherwise (render mode, thickness table samples, antialiasing, soft shadows, shadow map, subsurface "
        "scattering, environment map size, resolution, the materials' fit), and at the most exact setting of "
        "all; prints each setting's time and its Delta E 2000 against that reference over the product's pixels, "
        "the Pareto front, and what the planner chose against the cheapest setting within the line's target; writes "
        "trade.csv, trade.json and trade.png under the output folder's trade/. The materials are made (or found "
        "cached) as kmpipe run makes them. Exit status 0: done; 2: bad input.",
    )
    trade.add_argument("recipe", type=Path, help="recipe file, TOML (docs/formats.md)")
    trade.add_argument("-o", "--output", type=Path, help="output folder (default: out/ beside the recipe)")
    trade.add_argument("--only", nargs="+", metavar="PRODUCT", help="measure only these products")
    trade.add_argument("--wait", action="store_true", help="wait for another run on the same output folder to end")
    trade.set_defaults(run=_cmd_trade)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    console = Console(emoji=False)  # user text: ":x:" is not an emoji
    errors = Console(stderr=True, emoji=False)
    try:
        if args.gl is not None:
            use_gl(args.gl, field="--gl")
        return args.run(args, console)
    except InputError as err:
        if args.debug:
            traceback.print_exc()
        errors.print(f"[bold red]kmpipe {args.command}: error:[/] {escape(str(err))}", highlight=False, soft_wrap=True)
        return EXIT_BAD_INPUT
    except OSError as err:
        if err.filename is None or err.errno not in USER_FILE_SYSTEM_ERRORS:  # kmpipe's own doing: a bug
            return _internal_error(args, errors, err)
        if args.debug:
            traceback.print_exc()
        where = InputError(f"cannot be used ({err.strerror or err})", path=err.filename)
        errors.print(f"[bold red]kmpipe {args.command}: error:[/] {escape(str(where))}", highlight=False,
                     soft_wrap=True)  # fmt: skip
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        errors.print("kmpipe: interrupted; files already written are complete, nothing half-written was left.")
        return 130
    except Exception as err:  # a bug, not bad input
        return _internal_error(args, errors, err)


def _internal_error(args: argparse.Namespace, errors: Console, err: Exception) -> int:
    if args.debug:
        traceback.print_exc()
    errors.print(
        f"[bold red]kmpipe {args.command}: internal error:[/] {type(err).__name__}: {escape(str(err))}\n"
        "This is a bug in kmpipe. Run again with --debug for the traceback and report it.",
        highlight=False,
    )
    return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
