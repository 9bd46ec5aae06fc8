"""Executing a planned ``kmpipe run``: tasks in dependency order on an executor, each recorded as it finishes."""

from __future__ import annotations

import collections
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from kmpipe.errors import InputError
from kmpipe.formats.atomic_write import write_text_atomically
from kmpipe.formats.files import within
from kmpipe.run.executors import call_task, check_executor, make_executor
from kmpipe.run.folder import clean_temporaries, locked
from kmpipe.run.planning import RunPlan, blocked_by_validation, failed_validations, mark_cached, record_path
from kmpipe.run.tasks import Task


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
    r"""Run every task of ``plan`` that is not cached, each after what it needs; records each one as it finishes.

    Holds the output folder's lock throughout (:func:`locked`; ``wait``: wait for another run to finish rather than
    refuse), deletes the temporary files of killed writes, and looks again at what is cached (another run may have
    finished tasks since planning). ``on_task(task, finished, total)`` is called as each task ends (run, failed or
    skipped).

    >>> import kmpipe, pathlib, tempfile
    >>> from kmpipe.run.planning import plan_run
    >>> from kmpipe.stages.fit import fit_manifests
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> line = pathlib.Path(tempfile.mkdtemp())
    >>> _ = fit_manifests([F1 / "manifest.toml"], line / "F1.json", method="black-white")
    >>> _ = (line / "recipe.toml").write_text(
    ...     '[line]\nname = "One compact"\n[scene]\nmesh = "compact"\nresolution = [24, 24]\n'
    ...     '[substrate]\nreflectance = 0.8\n[[light]]\ndirection = [0.4, 0.8, 0.6]\n[turntable]\nframes = 2\n'
    ...     '[[product]]\nname = "Foundation F1"\nmaterial = "F1.json"\n'
    ...     'layer = [{ material = "self", thickness = "40 um" }]\n')
    >>> summary = execute(plan_run(line / "recipe.toml", line / "out"))
    >>> summary.ran, summary.frames, summary.sheet.name, summary.failed
    (5, 2, 'sheet.png', [])
    >>> execute(plan_run(line / "recipe.toml", line / "out")).ran  # everything cached now
    0
    """
    started = time.perf_counter()
    check_executor(executor, workers, scheduler)
    with locked(plan.out_dir, wait=wait):
        clean_temporaries(plan)
        mark_cached(plan)
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

    pool = make_executor(executor, workers, scheduler)
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
    return not blocked_by_validation(plan, task)


def _record(plan: RunPlan, task: Task) -> None:
    """Write the record of a task that has just finished (into the output folder, never out of it)."""
    path = within(plan.out_dir, record_path(Path(), task.id), field="-o")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"the folder of the task records cannot be made ({err.strerror or err})", path=path.parent,
                         field="-o") from None  # fmt: skip
    record = {"key": task.key, "outputs": list(task.outputs), "result": task.result}
    write_text_atomically(path, json.dumps(record, indent=1) + "\n")


def _arguments(plan: RunPlan, task: Task) -> dict:
    """The task's arguments, completed with what only earlier tasks could tell (verdicts, surviving rows)."""
    args = dict(task.args)
    if task.kind == "render":
        failed = [plan.tasks[d].product for d in failed_validations(plan, task)]
        args["header"] = {"validation": "fail: " + ", ".join(failed) + " (rendered with --keep-going)"} if failed else {
            "validation": "pass or warn"}  # fmt: skip
        args["header"]["task_key"] = task.key  # a frame on disk with this key is not rendered again
        radii = [
            (plan.tasks[d].product, plan.tasks[d].result.get("colour_radius"))
            for d in task.deps
            if plan.tasks[d].kind == "validate" and plan.tasks[d].result.get("colour_radius") is not None
        ]
        if radii:  # the rendered colour's 95 % Delta E 2000 radius (kmpipe.validation.uncertainty)
            args["header"]["colour_uncertainty"] = (f"±{radii[0][1]:.2f}" if len(radii) == 1 else
                                                    ", ".join(f"{name} ±{r:.2f}" for name, r in radii))  # fmt: skip
    if task.kind == "reports":
        done = {plan.out_dir / plan.tasks[d].outputs[0] for d in task.deps if plan.tasks[d].state in ("cached", "run")}
        args["entries"] = [entry for entry in task.args["entries"] if Path(entry[0]) in done]
    if task.kind == "sheet":
        args["rows"] = [row for row in task.args["rows"] if all(plan.tasks[c].state in ("cached", "run")
                                                                  for c in row["chunks"])]  # fmt: skip
    return args


def _summary(plan: RunPlan, seconds: float) -> RunSummary:
    tasks = plan.tasks.values()
    verdicts = {t.product: t.result.get("verdict", "?") for t in tasks if t.kind == "validate"}
    frames = sum(len(t.args["frames"]) for t in tasks if t.kind == "render" and t.state in ("run", "cached"))
    sheet = next(
        (plan.out_dir / t.outputs[0] for t in tasks if t.kind == "sheet" and t.state in ("run", "cached")), None
    )
    reports = next((plan.out_dir / t.outputs[0] for t in tasks if t.kind == "reports" and t.state in ("run", "cached")),
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
