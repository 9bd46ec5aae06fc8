"""``kmpipe trade``: a line's speed/accuracy trade (:mod:`kmpipe.stages.trade`) on its own products.

The line's materials are made as ``kmpipe run`` makes them (the same tasks, cached in the same output folder, so a
line already run is not fitted again); then each product with layers is measured, its frame settings are chosen for
its scene's target (:func:`kmpipe.stages.trade.choose_frame_settings`), and the files of
:mod:`kmpipe.stages.trade_files` are written into ``OUT_DIR/trade/``, where ``kmpipe run`` into the same output
folder finds the choices (:mod:`kmpipe.stages.frame_choice`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from kmpipe.errors import InputError
from kmpipe.formats.material import read_material
from kmpipe.formats.recipe import slug
from kmpipe.run.execute import execute
from kmpipe.run.folder import PRODUCTS, TRADE
from kmpipe.run.planning import RunPlan, plan_run
from kmpipe.stages.frame_choice import FrameChoice
from kmpipe.stages.trade import Aggregate, Setting, aggregate, cheapest_within, rebuild_for, target_of, trade_product
from kmpipe.stages.trade_files import write_trade


@dataclass(frozen=True)
class TradeResult:
    line: str
    target: float
    settings: list[Setting]
    rows: list[Aggregate]
    chosen: dict[str, Aggregate]
    choices: dict[str, FrameChoice]
    files: list[Path]


def _manifest(material_path: Path) -> Path | None:
    """The manifest a material was fitted from (its provenance), or None (a material given as a file)."""
    manifest = read_material(material_path).provenance.get("manifest")
    return None if not manifest else (material_path.parent / manifest).resolve()


def trade_line(recipe_path: str | Path, out_dir: str | Path, *, only: Sequence[str] = (), wait: bool = False,
               echo: Callable[[str], None] = print) -> TradeResult:  # fmt: skip
    """Measure the trade of the recipe's products (``only`` those named) into ``out_dir`` (module docstring)."""
    plan = plan_run(recipe_path, out_dir, only=only)
    recipe, out_dir = plan.recipe, plan.out_dir
    materials = RunPlan(recipe, out_dir, {i: t for i, t in plan.tasks.items() if t.kind == "material"}, False)
    summary = execute(materials, wait=wait)
    if summary.failed:
        raise InputError(f"the materials of {', '.join(summary.failed)} could not be made (kmpipe run says why)",
                         path=recipe.path)  # fmt: skip
    settings, scenes, choices = [], [], {}
    wanted = set(only) or {p.name for p in recipe.info.product}
    for index, product in enumerate(recipe.info.product):
        if product.name not in wanted or not product.layer:
            continue
        owners = [product.name if layer.get("material") == "self" else layer["material"] for layer in product.layer]
        paths = {o: out_dir / PRODUCTS / slug(o) / "material.json" for o in dict.fromkeys(owners)}
        rebuild = rebuild_for(recipe, index)
        scene = rebuild(paths)
        scenes.append(scene)
        echo(f"trade: {product.name}")
        measured, choice = trade_product(product.name, scene, rebuild, {o: _manifest(p) for o, p in paths.items()},
                                         target_of([scene]))  # fmt: skip
        settings += measured
        if choice is not None:
            choices[product.name] = choice
    if not scenes:
        raise InputError("has no product with layers to render", path=recipe.path, field="product")
    rows = aggregate(settings)
    target = target_of(scenes)
    chosen = cheapest_within(rows, target)
    folder = out_dir / TRADE
    folder.mkdir(parents=True, exist_ok=True)
    files = write_trade(folder, recipe.info.line.name, target, settings, rows, chosen, choices)
    return TradeResult(recipe.info.line.name, target, settings, rows, chosen, choices, files)
