"""The files of ``kmpipe trade`` (:mod:`kmpipe.stages.trade`): ``trade.csv`` (every product's settings),
``trade.json`` (the same, the line's settings summed over products with the Pareto front, the planner's choice
against the cheapest setting within the target, and each product's frame settings chosen for its target) and
``trade.png`` (time against Delta E 2000, the front drawn); docs/formats.md, "Trade". Each is written atomically.
:func:`read_frame_choices` reads the frame settings back, strictly, for ``kmpipe run``'s plans."""

from __future__ import annotations

import csv
import io
import json
import textwrap
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Annotated, Literal

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.atomic_write import write_atomically, write_text_atomically
from kmpipe.formats.toml_input import first_validation_error, format_field
from kmpipe.stages.frame_choice import CHOSEN_ANTIALIASING, SCATTERING, SHADOW_MAPS, FrameChoice
from kmpipe.stages.trade import KNOBS, Aggregate, Setting

#: Columns of trade.csv, in order.
COLUMNS = ("product", "knob", "value", "seconds", "mean_de", "p95_de", "shift_de", "planned", "note")


def _number(value: float | None, digits: int) -> str:
    return "" if value is None else f"{value:.{digits}g}"


def trade_csv(settings: Sequence[Setting]) -> str:
    """trade.csv: a row per product and setting, times in s, Delta E 2000 against the reference (mean, 95th
    percentile) and against the frame as planned (mean), empty where the knob does not apply."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(COLUMNS)
    for s in settings:
        writer.writerow([s.product, s.knob, s.value, _number(s.seconds, 4), _number(s.mean_de, 4),
                         _number(s.p95_de, 4), _number(s.shift_de, 4), "yes" if s.planned else "", s.note])  # fmt: skip
    return out.getvalue()


def trade_json(line: str, target: float, settings: Sequence[Setting], rows: Sequence[Aggregate],
               chosen: dict[str, Aggregate], choices: dict[str, FrameChoice]) -> str:  # fmt: skip
    """trade.json (docs/formats.md, "Trade")."""
    doc = {
        "line": line,
        "target_delta_e": target,
        "settings": [asdict(s) for s in settings],
        "line_settings": [asdict(r) for r in rows],
        "cheapest_within_target": {knob: row.value for knob, row in chosen.items()},
        "planned": {r.knob: r.value for r in rows if r.planned and r.knob not in ("planned",)},
        "frame_settings": {product: asdict(choice) for product, choice in choices.items()},
    }
    return json.dumps(doc, indent=1, allow_nan=False) + "\n"


def trade_figure(line: str, target: float, rows: Sequence[Aggregate], choices: dict[str, FrameChoice]) -> bytes:
    """trade.png: each setting that applies to every product (time summed over them against mean Delta E 2000),
    coloured by knob, the planner's ringed, the Pareto front joined and numbered (named under the plot, those on one
    spot under one number), the target drawn; and, where every product has frame settings chosen, the frames
    ``kmpipe run`` then plans (their times summed, their mean Delta E against the reference averaged) as a star."""
    everyone = max((r.products for r in rows), default=0)
    shown = [r for r in rows if r.products == everyone]
    fig = Figure(figsize=(10.0, 7.0), layout="constrained")
    FigureCanvasAgg(fig)
    ax, notes = fig.subplots(2, 1, height_ratios=(5.0, 1.0))
    for index, knob in enumerate(KNOBS):
        points = [r for r in shown if r.knob == knob]
        if points:
            ax.scatter([r.mean_de for r in points], [r.seconds for r in points], color=f"C{index % 10}", label=knob,
                       s=30, zorder=3)  # fmt: skip
    planned = [r for r in shown if r.planned]
    ax.scatter([r.mean_de for r in planned], [r.seconds for r in planned], s=140, facecolors="none",
               edgecolors="black", linewidths=1.2, label="as the planner chose", zorder=4)  # fmt: skip
    if choices and len(choices) == everyone:
        seconds = sum(c.seconds for c in choices.values())
        error = sum(c.reference_de for c in choices.values()) / len(choices)
        ax.scatter([error], [seconds], marker="*", s=220, color="#c62828", edgecolors="black", linewidths=0.6,
                   label="kmpipe run's plans (the trade's choice)", zorder=5)  # fmt: skip
    front = sorted((r for r in shown if r.front), key=lambda r: r.mean_de)
    ax.plot([r.mean_de for r in front], [r.seconds for r in front], "-", color="0.3", linewidth=1, zorder=2,
            label="Pareto front")  # fmt: skip
    ax.axvline(target, color="#c62828", linestyle="--", linewidth=1, label=f"target ΔE00 {target:g}")
    ax.set_xscale("symlog", linthresh=0.01)
    ax.set_xlim(left=0.0)
    ax.set_ylim(bottom=0.0)
    # The front's settings numbered on the plot and named under it, those that land on one spot under one number.
    fig.canvas.draw()
    listing = ["The Pareto front (no other setting is both faster and closer to the reference):"]
    for number, group in enumerate(_huddles(front, ax), start=1):
        ax.annotate(str(number), (group[0].mean_de, group[0].seconds), fontsize=8, fontweight="bold", xytext=(5, 4),
                    textcoords="offset points")  # fmt: skip
        names = "; ".join(f"{r.knob}: {r.value}" for r in group)
        listing += textwrap.wrap(f"{number}. {names} ({group[0].seconds:.3g} s, ΔE00 {group[0].mean_de:.3g})",
                                 width=150, subsequent_indent="    ")  # fmt: skip
    notes.axis("off")
    notes.text(0.0, 1.0, "\n".join(listing), va="top", ha="left", fontsize=8, transform=notes.transAxes)
    ax.set_xlabel("mean ΔE00 against the most exact setting, over the products' pixels")
    ax.set_ylabel(f"seconds (a frame of each of the {everyone} products, summed)")
    ax.set_title(f"{line}: speed against accuracy, one knob at a time (the rest: trade.csv)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, metadata={"Software": None})
    return buffer.getvalue()


#: Front points closer than this on the plot (pixels) share a number.
HUDDLE_PX = 12.0


def _huddles(front: Sequence[Aggregate], ax) -> list[list[Aggregate]]:
    """The front's points (in order of Delta E) in runs that lie within :data:`HUDDLE_PX` of the run's first point
    as ``ax`` draws them."""
    groups: list[list[Aggregate]] = []
    for r in front:
        x, y = ax.transData.transform((r.mean_de, r.seconds))
        if groups:
            x0, y0 = ax.transData.transform((groups[-1][0].mean_de, groups[-1][0].seconds))
            if (x - x0) ** 2 + (y - y0) ** 2 <= HUDDLE_PX**2:
                groups[-1].append(r)
                continue
        groups.append([r])
    return groups


def write_trade(out_dir: Path, line: str, target: float, settings: Sequence[Setting], rows: Sequence[Aggregate],
                chosen: dict[str, Aggregate], choices: dict[str, FrameChoice]) -> list[Path]:  # fmt: skip
    """Write trade.csv, trade.json and trade.png into ``out_dir``; their paths."""
    paths = [out_dir / "trade.csv", out_dir / "trade.json", out_dir / "trade.png"]
    write_text_atomically(paths[0], trade_csv(settings))
    write_text_atomically(paths[1], trade_json(line, target, settings, rows, chosen, choices))
    figure = trade_figure(line, target, rows, choices)
    write_atomically(paths[2], lambda temporary: temporary.write_bytes(figure))
    return paths


_NonNegative = Annotated[float, Field(ge=0.0)]


class _Choice(BaseModel):
    """A product's frame settings in trade.json: types exact, unknown fields refused, numbers finite."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

    scene_sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    target_de: float = Field(gt=0.0)
    antialiasing: Literal[CHOSEN_ANTIALIASING] | None  # type: ignore[valid-type]
    shadow_map: Literal[SHADOW_MAPS] | None  # type: ignore[valid-type]
    scattering: Literal[SCATTERING] | None  # type: ignore[valid-type]
    seconds: _NonNegative
    mean_de: _NonNegative
    p95_de: _NonNegative
    reference_de: _NonNegative
    tried: int = Field(ge=1)


def read_frame_choices(path: Path) -> dict[str, FrameChoice]:
    """The frame settings of trade.json (product name: choice); {} where it names none. InputError naming the file
    and the field for a file that is not a trade or a damaged entry."""
    document = files.read_json(path, "JSON", "kmpipe trade.json")
    if not isinstance(document, dict) or not isinstance(document.get("frame_settings", {}), dict):
        raise InputError("not a kmpipe trade.json: expected an object with a frame_settings object", path=path,
                         field="frame_settings")  # fmt: skip
    choices = {}
    for product, entry in document.get("frame_settings", {}).items():
        try:
            choices[product] = FrameChoice(**_Choice.model_validate(entry).model_dump())
        except ValidationError as err:
            first = first_validation_error(err)
            message = "unknown field" if first["type"] == "extra_forbidden" else first["msg"]
            field = format_field(("frame_settings", product, *first["loc"]))
            raise InputError(f"a damaged trade.json: {message}; run kmpipe trade again, or delete the file",
                             path=path, field=field) from None  # fmt: skip
    return choices
