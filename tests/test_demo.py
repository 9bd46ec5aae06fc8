"""The README's demo command, end to end: a live emulated CS-2000 session, the demo product line (replayed sessions,
fits, validation, turntables, sheet, report index) run twice (the second time fully cached), the trade of two of its
products and a third run that plans them with it, an A/B render and the shade review of a foundation range."""

from __future__ import annotations

import json
import os
import subprocess
import tomllib
from pathlib import Path

from kmpipe.formats.recipe import slug

ROOT = Path(__file__).resolve().parents[1]


def test_the_demo_measures_runs_the_line_and_renders(tmp_path):
    from renderer.contact_sheet import sheet_layout
    from renderer.image_io import read_header, read_png

    out = tmp_path / "demo"
    done = subprocess.run(
        ["bash", str(ROOT / "scripts" / "demo")],
        env={**os.environ, "KMPIPE_DEMO_OUT": str(out)},
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    session = out / "session" / "F1"
    assert {"radiance.csv", "reflectance.csv", "manifest.toml", "session.json"} <= {p.name for p in session.iterdir()}
    log_lines = (out / "session" / "F1.jsonl").read_text(encoding="utf-8").splitlines()
    assert json.loads(log_lines[0])["kmpipe_session_log"] == 1 and len(log_lines) > 50
    assert (out / "session" / "F1.json").is_file()

    recipe = tomllib.loads((ROOT / "recipes" / "demo" / "recipe.toml").read_text(encoding="utf-8"))
    products = recipe["product"]
    frames = recipe["turntable"]["frames"]
    line = out / "line"
    assert len(list(line.glob("products/*/material.json"))) == sum("replay" in p for p in products)
    assert len(list(line.glob("frames/*/frame_*.exr"))) == frames * len(products)
    summary = json.loads((line / "reports" / "summary.json").read_text(encoding="utf-8"))
    assert {entry["verdict"] for entry in summary} <= {"pass", "warn"}
    assert (line / "reports" / "index.html").is_file()
    # The second run ran nothing.
    assert "0 tasks run" in done.stdout.split("every task is cached")[1]
    # The trade on two products, then a third run: their plans take the frame settings it chose, the others' keep
    # the planner's rules.
    trade = json.loads((line / "trade" / "trade.json").read_text(encoding="utf-8"))
    assert set(trade["frame_settings"]) == {"Lipstick Classic Red", "Foundation Natural Beige"}
    for product in products:
        plan = json.loads((line / "frames" / slug(product["name"]) / "plan.json").read_text(encoding="utf-8"))
        chosen = any("chosen by kmpipe trade" in note for note in plan["notes"])
        assert chosen == (product["name"] in trade["frame_settings"]), product["name"]

    # The sheet: a row per product, four angles.
    # (each validated product's label ends with its rendered colour's 95 % uncertainty, from its validation.json)
    def doubt(product: dict) -> str:
        report = line / "reports" / slug(product["name"]) / "validation.json"
        if not report.is_file():
            return ""
        return f" ±{json.loads(report.read_text(encoding='utf-8'))['uncertainty']['radius_delta_e_2000_95']:.2f}"

    labels = [f"{p['name']} · {p['shade']}{doubt(p)}" for p in products]
    layout = sheet_layout(labels, ["0°", "90°", "180°", "270°"], header="Demo line · D65")
    assert read_png(line / "sheet.png").shape == (layout.height, layout.width, 3)
    header = read_header(next(line.glob("frames/the-look/frame_002.exr")))
    assert header["camera_azimuth_deg"] == 90.0 and header["subsurface_scattering"].startswith("alpha 1")
    # The A/B render of the look.
    face = tomllib.loads((ROOT / "recipes" / "scenes" / "face.toml").read_text(encoding="utf-8"))
    assert len(list((out / "face" / "render" / "no_sss").glob("frame_*.exr"))) == face["turntable"]["frames"]
    assert (out / "face" / "render" / "ab_sss.png").is_file()
    # The shade review: every shade of the range on every built-in tone under each light, all of it on the page.
    review = tomllib.loads((ROOT / "recipes" / "review" / "recipe.toml").read_text(encoding="utf-8"))["review"]
    document = json.loads((out / "review" / "review" / "review.json").read_text(encoding="utf-8"))
    assert len(document["tones"]) == 8 and document["illuminants"] == review["illuminants"]
    assert all(len(row["cells"]) == len(review["foundations"]) for row in document["tones"])
    page = (out / "review" / "review" / "review.html").read_text(encoding="utf-8")
    assert page.count("<tr>") >= len(document["tones"]) and (out / "review" / "review" / "review.png").is_file()
