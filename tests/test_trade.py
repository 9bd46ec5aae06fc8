"""``kmpipe trade``: the speed/accuracy trade of a line measured on its own products (kmpipe.stages.trade,
kmpipe.run.trade).

References: the most exact setting against itself is Delta E 0 (a frame equals itself); a frame against itself as
planned is 0 in "vs planned"; colour-science's own CIEDE2000 for the per-pixel statistics; the Pareto front checked
by its definition against every row; a knob that cannot change a product's frame (no skin: no scattering; no
environment; no area light) is reported not applicable, never measured.
"""

from __future__ import annotations

import csv
import json

import colour
import numpy as np
import pytest
from test_run import make_line

from kmpipe.cli import main
from kmpipe.run.trade import trade_line
from kmpipe.stages.trade import KNOBS, Setting, aggregate, cheapest_within, delta_e_stats

pytestmark = pytest.mark.filterwarnings("ignore:Aligning:colour.utilities.ColourRuntimeWarning")


@pytest.fixture(scope="module")
def traded(tmp_path_factory):
    folder = tmp_path_factory.mktemp("trade")
    recipe = make_line(folder / "line")
    return folder, recipe, trade_line(recipe, folder / "out", echo=lambda _: None)


def test_every_product_gets_every_knob_measured_or_said_not_applicable(traded):
    _, _, result = traded
    products = {s.product for s in result.settings}
    assert products == {"Foundation F1", "Lipstick L1", "Face"}  # the products with layers; B1 has none
    for product in products:
        knobs = {s.knob for s in result.settings if s.product == product}
        assert knobs == set(KNOBS), product
    for s in result.settings:
        if s.seconds is None:
            assert s.note.startswith("not applicable") and s.mean_de is None
        else:
            assert s.seconds > 0.0 and np.isfinite(s.mean_de) and s.p95_de >= 0.0


def test_the_most_exact_setting_is_delta_e_0_against_itself_and_the_plan_0_against_the_plan(traded):
    _, _, result = traded
    for s in result.settings:
        if s.knob == "planned" and s.value.startswith("the reference"):
            assert s.mean_de == 0.0 and s.p95_de == 0.0
        if s.knob == "planned" and s.value == "as planned":
            assert s.shift_de == 0.0 and s.planned


def test_knobs_that_cannot_change_a_frame_are_not_applicable(traded):
    _, _, result = traded

    def said(product, knob):
        return [s for s in result.settings if s.product == product and s.knob == knob]

    for product in ("Foundation F1", "Lipstick L1"):  # no skin
        [s] = said(product, "subsurface scattering")
        assert s.seconds is None and "no skin" in s.note
        [s] = said(product, "thickness samples")  # uniform films
        assert s.seconds is None and "one thickness" in s.note
    for product in ("Foundation F1", "Lipstick L1", "Face"):  # no environment, no area light
        assert said(product, "environment")[0].seconds is None
        assert said(product, "soft shadows")[0].seconds is None
    assert {s.value for s in said("Face", "subsurface scattering")} == {"on", "off"}
    assert len(said("Face", "thickness samples")) == 3  # the cosmetic map's films


def test_the_per_pixel_statistics_are_colour_sciences_ciede2000():
    rng = np.random.default_rng(3)
    a, b = rng.random((6, 7, 3)) * 0.8, rng.random((6, 7, 3)) * 0.8
    mask = rng.random((6, 7)) > 0.3
    lab = [
        colour.XYZ_to_Lab(
            colour.RGB_to_XYZ(x[mask], colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False),
            colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"],
        )
        for x in (a, b)
    ]
    expected = colour.delta_E(lab[0], lab[1], method="CIE 2000")  # fmt: skip
    mean, p95 = delta_e_stats(a, b, mask)
    assert mean == pytest.approx(expected.mean(), rel=1e-12)
    assert p95 == pytest.approx(np.percentile(expected, 95), rel=1e-12)


def test_the_pareto_front_holds_exactly_the_settings_no_other_beats():
    rng = np.random.default_rng(11)
    settings = [Setting(p, f"k{i % 3}", f"v{i}", float(t), float(d), float(d), planned=i == 0, shift_de=0.0)
                for i, (t, d) in enumerate(rng.random((25, 2))) for p in ("A", "B")]  # fmt: skip
    settings.append(Setting("A", "k9", "only A", 0.0, 0.0, 0.0, shift_de=0.0))  # best, but on one product only
    rows = aggregate(settings)
    whole = [r for r in rows if r.products == 2]
    for r in whole:
        beaten = any(o.seconds <= r.seconds and o.mean_de <= r.mean_de and (o.seconds, o.mean_de) != (r.seconds,
                     r.mean_de) for o in whole)  # fmt: skip
        assert r.front == (not beaten)
    assert any(r.front for r in whole) and not next(r for r in rows if r.value == "only A").front
    chosen = cheapest_within(rows, 0.5)
    for knob, row in chosen.items():
        assert row.mean_de <= 0.5
        assert all(o.seconds >= row.seconds for o in rows if o.knob == knob and o.mean_de <= 0.5)


def test_the_files_hold_the_measurements(traded):
    folder, _, result = traded
    trade = folder / "out" / "trade"
    with open(trade / "trade.csv", encoding="utf-8", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == len(result.settings)
    assert {r["knob"] for r in rows} == set(KNOBS)
    doc = json.loads((trade / "trade.json").read_text(encoding="utf-8"))
    assert doc["target_delta_e"] == result.target == 0.5
    assert len(doc["settings"]) == len(result.settings) and len(doc["line_settings"]) == len(result.rows)
    assert (trade / "trade.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_command_prints_the_table_and_refuses_an_unknown_product(traded, capsys):
    folder, recipe, _ = traded
    assert main(["trade", str(recipe), "-o", str(folder / "out"), "--only", "Lipstick L1"]) == 0
    out = capsys.readouterr().out
    assert "kmpipe trade: Test line" in out and "the reference (most exact)" in out and "as planned:" in out
    assert main(["trade", str(recipe), "-o", str(folder / "out"), "--only", "Nothing"]) == 2
    assert "--only" in capsys.readouterr().err
