"""The shade review's matrix from its rows (:mod:`kmpipe.stages.review`): ``review.json`` and ``review.csv`` (the
numbers), ``review.png`` (a labelled sheet: a row per tone, for each illuminant the bare skin then every shade) and
``review.html`` (the same as a table whose columns sort, each cell its tile, swatch and numbers, and the matches
that break under another light). Formats: docs/formats.md, "Shade reviews"."""

from __future__ import annotations

import csv
import html
import io
import json
from pathlib import Path

import numpy as np

from kmpipe.formats.atomic_write import write_text_atomically
from kmpipe.physics.colorimetry import delta_E_2000
from kmpipe.physics.shade_match import shift_words

FORMAT = "kmpipe-review/1"
#: Side (px) of the sheet's cells.
SHEET_CELL = 160
CSV_COLUMNS = ("tone_id", "tone", "kind", "site", "ita_deg", "ita_class", "product", "shade", "thickness_mm",
               "illuminant", "coverage_delta_e", "match_delta_e", "best_shade", "worn_match_breaks",
               "shade_match_breaks", "made_up_srgb", "shift", "uncertainty_delta_e_95")  # fmt: skip


def _breaks(rows: list[dict], reference: str, threshold: float) -> list[dict]:
    """The matches under the reference that break under another illuminant: what, where, by how much. Per tone, a
    foundation worn against the bare skin (``worn``) and its masstone against the tone (``shade``); once for the line,
    two shades' masstones against each other (``shades``: two shades a counter would take for one in daylight)."""
    found = []
    for row in rows:
        for cell in row["cells"]:
            ref = cell["illuminants"][reference]
            for ill, values in cell["illuminants"].items():
                for kind, key in (("worn", "coverage_delta_e"), ("shade", "match_delta_e")):
                    if values[f"{kind}_match_breaks"]:
                        found.append({"tone": row["tone"]["name"], "shade": cell["shade"], "pair": kind,
                                      "illuminant": ill, "reference_delta_e": ref[key], "delta_e": values[key],
                                      "shift": values["shift"]})  # fmt: skip
    cells = rows[0]["cells"]  # masstones do not depend on the tone
    for i, first in enumerate(cells):
        for second in cells[i + 1 :]:
            lab = {
                ill: (np.asarray(first["illuminants"][ill]["masstone_lab"]), np.asarray(values["masstone_lab"]))
                for ill, values in second["illuminants"].items()
            }
            delta = {ill: float(delta_E_2000(a, b)) for ill, (a, b) in lab.items()}
            if delta[reference] > threshold:
                continue
            for ill, value in delta.items():
                if value > threshold:
                    found.append({"tone": "", "shade": f"{first['shade']} / {second['shade']}", "pair": "shades",
                                  "illuminant": ill, "reference_delta_e": round(delta[reference], 3),
                                  "delta_e": round(value, 3), "shift": shift_words(*lab[ill])})  # fmt: skip
    return found


def _doubt(values: dict) -> str:
    """' · ±0.3' (the made-up colour's 95 % radius, Delta E 2000) for a page's cell; '' without a budget."""
    radius = values.get("uncertainty_delta_e")
    return "" if radius is None else f' · <span title="95 % uncertainty of the made-up colour">±{radius:.1f}</span>'


def _csv(rows: list[dict]) -> str:
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for row in rows:
        tone = row["tone"]
        for cell in row["cells"]:
            for ill, v in cell["illuminants"].items():
                writer.writerow([tone["id"], tone["name"], tone["kind"], tone["site"] or "", tone["ita_deg"],
                                 tone["ita_class"], cell["product"], cell["shade"], cell["thickness_mm"], ill,
                                 v["coverage_delta_e"], v["match_delta_e"], row["best"], v["worn_match_breaks"],
                                 v["shade_match_breaks"], v["made_up_srgb"], v["shift"],
                                 "" if v.get("uncertainty_delta_e") is None else v["uncertainty_delta_e"]])  # fmt: skip
    return text.getvalue()


def _sheet(rows: list[dict], folders: list[Path], illuminants: list[str], header: str, out: Path) -> None:
    from renderer.contact_sheet import make_sheet, write_sheet

    frames, captions = [], []
    shades = [c["shade"] for c in rows[0]["cells"]]
    for row, folder in zip(rows, folders, strict=True):
        for ill in illuminants:
            frames.append(folder / row["bare"][ill]["tile"])
            captions.append(f"bare · ITA {row['tone']['ita_deg']:.0f}°")
            for cell in row["cells"]:
                v = cell["illuminants"][ill]
                mark = " best" if cell["shade"] == row["best"] else ""
                mark += " breaks" if v["worn_match_breaks"] or v["shade_match_breaks"] else ""
                frames.append(folder / v["tile"])
                doubt = "" if v.get("uncertainty_delta_e") is None else f" ±{v['uncertainty_delta_e']:.1f}"
                captions.append(f"cov {v['coverage_delta_e']:.1f} / {v['match_delta_e']:.1f}{doubt}{mark}")
    columns = [f"{ill} · {name}" for ill in illuminants for name in ["bare", *shades]]
    legend = (
        "under each shade: cov (Delta E 2000, bare vs made-up) / match (Delta E 2000, shade vs tone) ±the "
        "made-up colour's 95 % uncertainty"
    )
    sheet = make_sheet(frames, rows=[r["tone"]["name"] for r in rows], columns=columns, header=f"{header} · {legend}",
                       cell_size=(SHEET_CELL, SHEET_CELL), font_size=13, captions=captions)  # fmt: skip
    write_sheet(sheet, out)


_SCRIPT = """
const matrix = document.getElementById('matrix'), shades = +matrix.dataset.shades, groups = +matrix.dataset.groups;
for (const td of matrix.querySelectorAll('td.tone')) td.addEventListener('click', () => {
  // this tone's best shades first, within each illuminant's columns
  const row = td.parentElement;
  for (let g = 0; g < groups; g++) {
    const start = 3 + g * (shades + 1) + 1, order = [...Array(shades).keys()].map(i => start + i);
    order.sort((a, b) => +row.cells[a].dataset.value - +row.cells[b].dataset.value);
    for (const r of matrix.rows) {
      const cells = order.map(i => r.cells[i]), after = r.cells[start + shades] || null;
      cells.forEach(c => r.insertBefore(c, after));
    }
  }
});
for (const th of document.querySelectorAll('th[data-sort]')) th.addEventListener('click', () => {
  const table = th.closest('table'), body = table.tBodies[0], k = th.cellIndex;
  const up = th.dataset.dir !== 'up'; th.dataset.dir = up ? 'up' : 'down';
  const value = r => { const c = r.cells[k]; const v = c.dataset.value ?? c.textContent; return isNaN(+v) ? v : +v; };
  [...body.rows].sort((a, b) => (value(a) > value(b) ? 1 : value(a) < value(b) ? -1 : 0) * (up ? 1 : -1))
    .forEach(r => body.appendChild(r));
});
"""
_STYLE = """
body { font: 14px system-ui, sans-serif; margin: 24px; color: #222; }
table { border-collapse: collapse; margin-bottom: 24px; } td, th { border: 1px solid #ccc; padding: 4px 6px; }
th[data-sort] { cursor: pointer; background: #f3f3f3; } th[data-sort]:hover { background: #e4e4e4; }
td.tone { cursor: pointer; }
td.cell { text-align: center; vertical-align: top; font-size: 12px; } td.cell img { width: 128px; display: block; }
.swatch { display: inline-block; width: 14px; height: 14px; border: 1px solid #888; vertical-align: middle; }
.best { box-shadow: inset 0 0 0 3px #2a7; } .broken { color: #b30; font-weight: 600; }
"""


def _html(document: dict, folders: list[str]) -> str:
    e = html.escape
    rows, illuminants, reference = document["tones"], document["illuminants"], document["reference"]
    shades = document["shades"]
    head = "".join(f'<th data-sort="1">{e(ill)} · {e(s)}</th>' for ill in illuminants for s in ["bare", *shades])
    body = []
    for row, folder in zip(rows, folders, strict=True):
        tone = row["tone"]
        site = ", " + e(tone["site"]) if tone["site"] else ""
        cells = [f'<td class="tone" title="click: this tone\'s best shades first">{e(tone["name"])}<br><small>'
                 f'{e(tone["kind"])}{site}</small></td>', f'<td data-value="{tone["ita_deg"]}">{tone["ita_deg"]:.1f}° '
                 f'<small>{e(tone["ita_class"])}</small></td>',
                 f'<td>{e(row["best"])}<br><small>then {e(row["second"] or "-")}, by '
                 f'{row["margin_delta_e"] if row["margin_delta_e"] is not None else "-"}'
                 f'{" (within the uncertainty)" if row.get("margin_within_uncertainty") else ""}'
                 "</small></td>"]  # fmt: skip
        for ill in illuminants:
            bare = row["bare"][ill]
            cells.append(f'<td class="cell" data-value="{tone["ita_deg"]}"><img src="{folder}/{e(bare["tile"])}" '
                         f'alt="bare skin under {e(ill)}"><span class="swatch" style="background:{bare["srgb"]}">'
                         '</span> bare</td>')  # fmt: skip
            for cell in row["cells"]:
                v = cell["illuminants"][ill]
                best = " best" if cell["shade"] == row["best"] else ""
                broken = v["worn_match_breaks"] or v["shade_match_breaks"]
                note = f'<br><span class="broken">match breaks: {e(v["shift"])}</span>' if broken else ""
                cells.append(f'<td class="cell{best}" data-value="{v["match_delta_e"]}"><img src="{folder}/'
                             f'{e(v["tile"])}" alt="{e(cell["shade"])} on {e(tone["name"])} under {e(ill)}">'
                             f'<span class="swatch" style="background:{v["made_up_srgb"]}"></span> '
                             f'cov {v["coverage_delta_e"]:.1f} · match {v["match_delta_e"]:.1f}{_doubt(v)}{note}'
                             "</td>")  # fmt: skip
        body.append("<tr>" + "".join(cells) + "</tr>")
    breaks = document["breaks"]
    break_rows = "".join(
        f"<tr><td>{e(b['tone'])}</td><td>{e(b['shade'])}</td><td>{e(b['pair'])}</td><td>{e(b['illuminant'])}</td>"
        f"<td>{b['reference_delta_e']:.2f}</td><td>{b['delta_e']:.2f}</td><td>{e(b['shift'])}</td></tr>"
        for b in breaks
    )
    threshold = document["match_delta_e"]
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{e(document["line"])}: shade review</title>
<style>{_STYLE}</style></head><body>
<h1>{e(document["line"])}: shade review</h1>
<p>Each foundation at its usual thickness on each skin tone, under {", ".join(map(e, illuminants))} (tiles and
swatches adapted to D65 as a viewer adapted to each light sees them). <b>cov</b>: Delta E 2000 between bare and
made-up skin; <b>match</b>: Delta E 2000 between the shade's masstone and the bare tone (the best shade of each tone
is outlined, ranked under {e(reference)}). A match (Delta E 2000 &le; {threshold:g} under {e(reference)}) that passes
{threshold:g} under another light is marked. Click a column's head to sort the tones by it, a tone to put its best
shades first.</p>
<table id="matrix" data-shades="{len(shades)}" data-groups="{len(illuminants)}"><thead><tr><th data-sort="1">tone</th>
<th data-sort="1">ITA</th><th data-sort="1">best shade</th>{head}</tr>
</thead><tbody>{"".join(body)}</tbody></table>
<h2>Matches that break under another light</h2>
{
        f'''<table><thead><tr><th data-sort="1">tone</th><th data-sort="1">shade</th><th data-sort="1">pair</th>
<th data-sort="1">illuminant</th><th data-sort="1">Delta E under {e(reference)}</th><th data-sort="1">Delta E</th>
<th>how it looks</th></tr></thead><tbody>{break_rows}</tbody></table>'''
        if breaks
        else f"<p>None: no pair that matches under {e(reference)} parts by more than {threshold:g} under another "
        "light.</p>"
    }
<p><a href="review.csv">review.csv</a> · <a href="review.json">review.json</a> ·
<a href="review.png">review.png</a></p>
<script>{_SCRIPT}</script></body></html>
"""


def write_review(rows: list[str], out: str, line: str, illuminants: list[str], reference: str, threshold: float,
                 header: str) -> dict:  # fmt: skip
    """The review's files in folder ``out`` from its rows' ``row.json`` files (in tone order)."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    loaded = [json.loads(Path(r).read_text(encoding="utf-8")) for r in rows]
    folders = [Path(r).parent for r in rows]
    relative = [Path(f).relative_to(folder).as_posix() for f in folders]
    document = {
        "format": FORMAT,
        "line": line,
        "illuminants": illuminants,
        "reference": reference,
        "match_delta_e": threshold,
        "shades": [c["shade"] for c in loaded[0]["cells"]],
        "tones": loaded,
        "breaks": _breaks(loaded, reference, threshold),
    }
    write_text_atomically(folder / "review.json", json.dumps(document, indent=1) + "\n")
    write_text_atomically(folder / "review.csv", _csv(loaded))
    _sheet(loaded, folders, illuminants, header, folder / "review.png")
    write_text_atomically(folder / "review.html", _html(document, relative))
    return {"html": str(folder / "review.html"), "breaks": len(document["breaks"])}
