"""Benchmark: ``kmpipe trade`` on the demo line (recipes/demo/recipe.toml), the line's own speed/accuracy table.

One fresh ``kmpipe trade`` process from an empty output folder (the materials replayed and fitted, then one frame of
each of the 7 products rendered per setting, docs/formats.md "Trade"); its wall time (issue 17: under 5 minutes)
and its ``line_settings`` as a table: each knob's settings over the products it applies to, their summed time,
the mean and worst 95th-percentile Delta E 2000 against the most exact setting, the mean against the frames as
planned, the planner's choice and the Pareto front; then the frame settings it chose for each product (what
``kmpipe run`` into the same folder plans with) against the frames planned by the rules.

Run alone: ``.venv/bin/python benchmarks/bench_trade.py``.
"""

from __future__ import annotations

import json
import subprocess
import tempfile
import time
from pathlib import Path

from common import REPO, Table

TARGET_S = 300.0


def run() -> dict:
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        subprocess.run([str(REPO / ".venv" / "bin" / "kmpipe"), "trade", str(REPO / "recipes" / "demo" / "recipe.toml"),
                        "-o", folder], check=True, capture_output=True)  # fmt: skip
        seconds = time.perf_counter() - start
        doc = json.loads((Path(folder) / "trade" / "trade.json").read_text(encoding="utf-8"))
    return {"seconds": seconds, "doc": doc}


def tables(result: dict) -> list[Table]:
    doc = result["doc"]
    rows = []
    for r in doc["line_settings"]:
        marks = ", ".join(m for m, on in (("planned", r["planned"]), ("Pareto front", r["front"])) if on)
        rows.append([r["knob"], r["value"], str(r["products"]), f"{r['seconds']:.2f}", f"{r['mean_de']:.3f}",
                     f"{r['p95_de']:.3f}", f"{r['shift_de']:.3f}", marks])  # fmt: skip
    skipped = sorted({s["knob"] for s in doc["settings"] if s["seconds"] is None}
                     - {r["knob"] for r in doc["line_settings"]})  # fmt: skip
    cheapest = ", ".join(f"{k} = {v}" for k, v in doc["cheapest_within_target"].items()) or "none"
    planned = {s["product"]: s for s in doc["settings"] if s["knob"] == "planned" and s["value"] == "as planned"}
    choices = []
    for product, c in doc["frame_settings"].items():
        rules = planned[product]
        settings = ", ".join(str(v) for v in (c["antialiasing"], c["shadow_map"] and f"{c['shadow_map']} texels",
                                              c["scattering"] and f"SSS {c['scattering']}") if v)  # fmt: skip
        choices.append([product, settings, str(c["tried"]), f"{c['seconds']:.3f}", f"{c['p95_de']:.3f}",
                        f"{c['reference_de']:.3f}", f"{rules['seconds']:.3f}", f"{rules['mean_de']:.3f}"])  # fmt: skip
    return [
        Table(
            f"kmpipe trade on the demo line ({result['seconds']:.0f} s end to end, target < {TARGET_S:.0f} s: "
            f"{'met' if result['seconds'] < TARGET_S else 'not met'})",
            ["knob", "setting", "products", "s (summed)", "dE00 mean", "dE00 p95", "dE00 vs planned", ""],
            rows,
            [
                "one frame (the turntable's first) of each product with layers, rendered as planned, with one knob "
                "changed, and at the most exact setting of every knob (the reference); s: the render after a "
                "warm-up (plus a refit's or prefilter's time where the knob moves it), summed over the products",
                "dE00 per pixel of the products against the reference (mean, worst 95th percentile); vs planned: "
                "the mean against the frames as planned",
                f"not applicable on this line: {', '.join(skipped) or 'none'}; cheapest within the target "
                f"dE00 {doc['target_delta_e']:g}: {cheapest}",
            ],
        ),
        Table(
            "The frame settings kmpipe trade chose for kmpipe run's plans (antialiasing, shadow map, SSS)",
            [
                "product",
                "chosen",
                "frames tried",
                "s a frame",
                "dE00 p95 vs these knobs' most exact",
                "dE00 mean vs reference",
                "by the rules: s",
                "by the rules: dE00 mean vs reference",
            ],
            choices,
            [
                "from the most exact setting of each knob the scene leaves to the planner, each lowered in turn to "
                "its cheapest setting whose frame keeps 95 % of the product's pixels within the target of the frame "
                "with these knobs at their most exact; vs reference: the mean against the most exact frame of all "
                "(exact mode, 3 x 3 supersampling, per-pixel soft shadows, 4096 texels, SSS on)",
                "by the rules: the frame the planner plans without a trade (the 'as planned' row of the table above)",
            ],
        ),
    ]


def main() -> None:
    for table in tables(run()):
        table.print()


if __name__ == "__main__":
    main()
