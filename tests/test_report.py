"""Reports (kmpipe.validation.report): the HTML page and validation.json of one sample, and the index of a batch.

A bundled sample (F1) is fitted through the command line and validated; a small camera-channel sample is
written here and fitted with the black-white method. Pages are checked for what a technician relies on
(every figure present, decodable and of the stated size; nothing fetched from elsewhere; text escaped;
cells over the thresholds marked) and the JSON documents for what batch jobs rely on.
"""

from __future__ import annotations

import base64
import dataclasses
import json
import os
import re
import struct
from pathlib import Path

import numpy as np
import pytest

from kmpipe import cli
from kmpipe.errors import InputError
from kmpipe.formats.thresholds import Thresholds
from kmpipe.physics.kubelka_munk import reflectance_infinite, reflectance_over_background
from kmpipe.validation.findings import Finding, report_to_dict
from kmpipe.validation.html_parts import DPI
from kmpipe.validation.material import validate_material
from kmpipe.validation.report import KS_SIZE, SPECTRA_SIZE, swatch_figsize, write_index, write_sample_report
from kmpipe.validation.uncertainty_page import FIGURE_SIZE

ROOT = Path(__file__).resolve().parents[1]
F1_MANIFEST = ROOT / "recipes" / "samples" / "F1" / "manifest.toml"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
IMG = re.compile(r"<img\b[^>]*>")

# colour-science 0.4.7 warns that it aligns the CMFs and illuminants to the spectra's grid (intended);
# kmpipe.physics.colorimetry's filter for ColourWarning misses it: ColourRuntimeWarning does not derive from it.
pytestmark = pytest.mark.filterwarnings("ignore:Aligning:colour.utilities.ColourRuntimeWarning")


def fit(manifest: Path, output: Path, *options: str) -> Path:
    assert cli.main(["fit", str(manifest), "-o", str(output), *options]) == cli.EXIT_OK
    return output


@pytest.fixture(scope="module")
def f1_report(tmp_path_factory):
    material = fit(F1_MANIFEST, tmp_path_factory.mktemp("fit") / "F1.json")
    return validate_material(material, illuminants=("D65", "A"))


def attribute(tag: str, name: str) -> str:
    match = re.search(rf'\b{name}="([^"]*)"', tag)
    assert match, f"{tag[:80]} has no {name}"
    return match.group(1)


def images(page: str) -> dict[str, tuple[str, bytes]]:
    """{img id: (the tag without its data, the decoded PNG)} of a page."""
    out = {}
    for tag in IMG.findall(page):
        src = attribute(tag, "src")
        assert src.startswith("data:image/png;base64,")
        out[attribute(tag, "id")] = (tag.replace(src, ""), base64.b64decode(src.split(",", 1)[1], validate=True))
    return out


def png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == PNG_SIGNATURE and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def pixels(size_inches: tuple[float, float]) -> tuple[int, int]:
    return round(size_inches[0] * DPI), round(size_inches[1] * DPI)


def strict_json(path: Path):
    def refuse(name):
        raise AssertionError(f"{path.name} holds {name}, which is not JSON")

    return json.loads(path.read_text(encoding="utf-8"), parse_constant=refuse)


def renamed(report, name: str, *findings: Finding):
    """The report for a sample called ``name``, with the given findings instead of its own."""
    return dataclasses.replace(
        report, material=dataclasses.replace(report.material, name=name), findings=tuple(findings)
    )


# --- one sample ------------------------------------------------------------------------------------------


def test_page_embeds_every_figure_as_a_png_of_the_stated_size(f1_report, tmp_path):
    page_path = write_sample_report(f1_report, tmp_path / "F1")
    assert page_path == tmp_path / "F1" / "report.html" and page_path.is_file()
    page = page_path.read_text(encoding="utf-8")
    found = images(page)
    expected = {
        "plot-spectra": pixels(SPECTRA_SIZE),
        "plot-ks": pixels(KS_SIZE),
        "plot-swatches": pixels(swatch_figsize(len(f1_report.measurements))),
        # the rendered colour's doubt under each illuminant validated
        **{f"plot-uncertainty-{i + 1}": pixels(FIGURE_SIZE) for i in range(len(f1_report.illuminants))},
    }
    assert set(found) == set(expected)
    for element_id, (tag, data) in found.items():
        assert png_size(data) == expected[element_id]
        assert (int(attribute(tag, "width")), int(attribute(tag, "height"))) == expected[element_id]
        assert attribute(tag, "alt")
    assert sorted(os.listdir(tmp_path / "F1")) == ["report.html", "validation.json"]  # no temporary files


def test_page_needs_nothing_but_itself(f1_report, tmp_path):
    page = write_sample_report(f1_report, tmp_path).read_text(encoding="utf-8")
    text = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "data:", page)
    assert "http" not in text.lower()
    assert not re.search(r"<script|<link|<iframe|@import|url\(", text, re.IGNORECASE)
    for target in re.findall(r'(?:src|href)="([^"]*)"', text):
        assert target == "data:" or (tmp_path / target).is_file()


def test_validation_json_is_report_to_dict(f1_report, tmp_path):
    write_sample_report(f1_report, tmp_path)
    document = strict_json(tmp_path / "validation.json")
    expected = json.loads(json.dumps(report_to_dict(f1_report, html="report.html")))
    assert document == expected
    assert document["verdict"] == f1_report.verdict and document["findings"] == expected["findings"]
    assert document["report_html"] == "report.html"


def test_text_is_escaped_and_the_failing_row_marked(f1_report, tmp_path):
    first = f1_report.measurements[0]
    message = '<script>alert("x")</script> R & B'
    finding = Finding("delta_e", "fail", message, [400.0, 405.0, 410.0, 500.0], first.id)
    report = renamed(f1_report, "F1 <new> & improved", finding)
    page = write_sample_report(report, tmp_path).read_text(encoding="utf-8")
    assert "<script>" not in page and "<new>" not in page
    assert "&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt; R &amp; B" in page
    assert "F1 &lt;new&gt; &amp; improved" in page
    assert "400-410, 500 nm" in page
    assert '<span class="badge fail">fail</span>' in page
    row = re.search(rf'<tr class="(\w+)"><td>{re.escape(first.id)}</td>', page)
    assert row and row.group(1) == "fail"
    assert strict_json(tmp_path / "validation.json")["findings"][0]["message"] == message


def test_cells_over_the_thresholds_are_marked(f1_report, tmp_path):
    masstone = f1_report.measurements[0]
    value = masstone.delta_e["D65"]
    # the masstone: Delta E under D65 over fail, RMSE between warn and fail; the best fit: RMSE below warn
    below = min(f1_report.measurements, key=lambda c: c.rmse)
    thresholds = Thresholds(
        delta_e_warn=value / 3,
        delta_e_fail=value / 2,
        rmse_warn=(below.rmse + masstone.rmse) / 2,
        rmse_fail=masstone.rmse * 2,
    )
    page = write_sample_report(dataclasses.replace(f1_report, thresholds=thresholds), tmp_path).read_text(
        encoding="utf-8"
    )
    row = re.search(rf"<tr[^>]*><td>{re.escape(masstone.id)}</td>.*?</tr>", page).group(0)
    assert f'<td class="num fail">{value:.2f}</td>' in row
    assert f'<td class="num warn">{masstone.rmse:.4f}</td>' in row
    row = re.search(rf"<tr[^>]*><td>{re.escape(below.id)}</td>.*?</tr>", page).group(0)
    assert f'<td class="num pass">{below.rmse:.4f}</td>' in row


def test_rewriting_replaces_the_files_and_a_failed_write_keeps_the_old_ones(f1_report, tmp_path, monkeypatch):
    write_sample_report(f1_report, tmp_path)
    write_sample_report(renamed(f1_report, "second"), tmp_path)
    old = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert "second" in old

    def broken(*args):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken)
    with pytest.raises(InputError, match="disk full"):  # a clear message naming the file, no traceback
        write_sample_report(renamed(f1_report, "third"), tmp_path)
    assert (tmp_path / "report.html").read_text(encoding="utf-8") == old
    assert sorted(os.listdir(tmp_path)) == ["report.html", "validation.json"]


# --- the index -------------------------------------------------------------------------------------------


def test_index_lists_failing_samples_first_and_links_their_reports(f1_report, tmp_path):
    reports = [
        renamed(f1_report, "P"),
        renamed(f1_report, "W", Finding("opaque", "warn", "hides its backing", [700.0])),
        renamed(
            f1_report,
            "X",
            Finding("rmse", "warn", "a", [], f1_report.measurements[0].id),
            Finding("thickness_not_monotone", "fail", "b", [500.0]),
        ),
    ]
    entries = [(r, write_sample_report(r, tmp_path / "reports" / r.material.name)) for r in reports]
    index = write_index([(report_to_dict(r), page) for r, page in entries], tmp_path / "batch")
    assert index == tmp_path / "batch" / "index.html"
    page = index.read_text(encoding="utf-8")
    rows = re.findall(r'<tr class="(\w+)"><td>(\w+)</td>.*?<a href="([^"]+)">', page)
    assert [(verdict, name) for verdict, name, _ in rows] == [("fail", "X"), ("warn", "W"), ("pass", "P")]
    for _, name, link in rows:
        assert link == f"../reports/{name}/report.html"
        assert (index.parent / link).resolve() == (tmp_path / "reports" / name / "report.html").resolve()
    assert "http" not in page

    summary = strict_json(tmp_path / "batch" / "summary.json")
    expected = []
    for name, report in (("X", reports[2]), ("W", reports[1]), ("P", reports[0])):
        expected.append(
            {
                "sample": name,
                "product": report.material.product,
                "verdict": report.verdict,
                "worst_delta_e_2000": report.worst_delta_e,
                "reasons": report.reasons,
                "report": f"../reports/{name}/report.html",
            }
        )
    assert summary == expected
    assert summary[0]["reasons"] == ["thickness_not_monotone", "rmse"]
    assert sorted(os.listdir(tmp_path / "batch")) == ["index.html", "summary.json"]


# --- camera channels -------------------------------------------------------------------------------------


def write_channel_sample(folder: Path) -> Path:
    """A 3-channel reflectance sample (no [white]): a masstone and 10, 20 um films over black and white."""
    K, S = np.array([0.8, 2.0, 5.0]), np.array([40.0, 35.0, 30.0])
    cards = {"black": np.array([0.04, 0.04, 0.045]), "white": np.array([0.85, 0.84, 0.82])}
    columns = {"masstone": reflectance_infinite(K, S)}
    manifest = '[sample]\nname = "C1"\nproduct = "camera test"\n'
    for name in cards:
        manifest += f'\n[[backing]]\nname = "{name}"\nfile = "cards.csv"\ncolumn = "{name}"\n'
    manifest += '\n[[masstone]]\nfile = "camera.csv"\ncolumn = "masstone"\n'
    for um in (10, 20):
        for name, card in cards.items():
            columns[f"film_{um}um_over_{name}"] = reflectance_over_background(K, S, um / 1000.0, card)
            manifest += (
                f'\n[[film]]\nfile = "camera.csv"\ncolumn = "film_{um}um_over_{name}"\n'
                f'over = "{name}"\nthickness = "{um} um"\n'
            )

    def write_csv(path: Path, table: dict[str, np.ndarray]) -> None:
        lines = ["# kmpipe-spectra: 1", "# quantity: reflectance", "# units: 1", "channel," + ",".join(table)]
        lines += [f"{channel}," + ",".join(f"{v[i]:.6f}" for v in table.values()) for i, channel in enumerate("RGB")]
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")

    folder.mkdir(parents=True, exist_ok=True)
    write_csv(folder / "camera.csv", columns)
    write_csv(folder / "cards.csv", cards)
    (folder / "manifest.toml").write_text(manifest, encoding="utf-8")
    return folder / "manifest.toml"


def test_channel_material_report_has_no_swatches_or_delta_e(tmp_path):
    manifest = write_channel_sample(tmp_path / "sample")
    material = fit(manifest, tmp_path / "C1.json", "--method", "black-white")
    report = validate_material(material)
    assert not report.spectral and report.labels == ["R", "G", "B"]
    page = write_sample_report(report, tmp_path / "report").read_text(encoding="utf-8")
    found = images(page)
    assert set(found) == {"plot-spectra", "plot-ks"}
    assert png_size(found["plot-spectra"][1]) == pixels(SPECTRA_SIZE)
    assert png_size(found["plot-ks"][1]) == pixels(KS_SIZE)
    assert "Camera-channel material" in page and "ΔE00 D65" not in page
    document = strict_json(tmp_path / "report" / "validation.json")
    assert document["worst_delta_e_2000"] is None and document["illuminants"] == []
    write_index([(report_to_dict(report), tmp_path / "report" / "report.html")], tmp_path)
    assert strict_json(tmp_path / "summary.json")[0]["worst_delta_e_2000"] is None
