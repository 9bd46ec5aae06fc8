"""The README's demo command, end to end: emulated CS-2000 session, fits, validation reports, renders, a sheet."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_demo_measures_fits_validates_and_renders(tmp_path):
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
    materials = sorted(p.stem for p in (out / "materials").glob("*.json"))
    assert materials == ["B1", "F1", "F2", "L1", "L2"]
    summary = json.loads((out / "reports" / "summary.json").read_text(encoding="utf-8"))
    assert {entry["sample"]: entry["verdict"] for entry in summary}["F1"] == "pass"
    assert (out / "reports" / "index.html").exists()
    # Rendering: 8 turntable frames per product, their headers, and a sheet of 4 rows x 4 columns.
    from renderer.contact_sheet import sheet_layout
    from renderer.image_io import read_header, read_png

    for scene, shade in (("F1_compact", "F1"), ("B1_compact", "B1"), ("L1_lipstick", "L1"), ("face", "F1 + B1 + L1")):
        frames = sorted((out / "render" / scene).glob("frame_*.exr"))
        assert len(frames) == 8 and len(list((out / "render" / scene).glob("frame_*.png"))) == 8
        header = read_header(frames[2])
        assert header["shade"] == shade and header["camera_azimuth_deg"] == 90.0
    layout = sheet_layout(
        ["Foundation compact · F1", "Blush compact · B1", "Lipstick · L1", "Full face · F1 + B1 + L1"],
        ["0°", "90°", "180°", "270°"],
        header="Demo line · D65 · date",  # the layout depends on whether there is a header, not on its text
    )
    assert read_png(out / "sheet.png").shape == (layout.height, layout.width, 3)
    assert read_header(out / "render" / "face" / "frame_000.exr")["subsurface_scattering"].startswith("alpha 1")
    assert len(list((out / "render" / "face" / "no_sss").glob("frame_*.exr"))) == 8
    assert (out / "render" / "face" / "ab_sss.png").is_file()
