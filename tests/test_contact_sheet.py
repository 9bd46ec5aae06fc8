"""Contact sheets: layout, colours of EXR and PNG frames, drawn labels, and the ``kmpipe sheet`` command."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest

from kmpipe.cli import main
from renderer.contact_sheet import (
    BACKGROUND,
    FrameError,
    make_sheet,
    sheet_layout,
    write_sheet,
)
from renderer.image_io import read_png, write_exr, write_png

CELL, MARGIN, FONT = (48, 40), 6, 14
ROWS = ["D65", "Teinte n°3 — Rosé"]
COLUMNS = ["0°", "30°", "60°"]
HEADER = "scène visage — D65 — 2024-05-01"
BACKGROUND_CODE = round(BACKGROUND[0] * 255)

#: (file name, linear value written, expected 8-bit sRGB code at the cell centre).
FRAMES = [
    ("a.exr", (0.5, 0.5, 0.5), (188, 188, 188)),
    ("b.exr", (1.0, 0.0, 0.0), (255, 0, 0)),
    ("c.exr", (0.0, 0.25, 1.0), (0, 137, 255)),
    ("d.png", (0.0, 1.0, 0.0), (0, 255, 0)),
    ("e.png", (0.25, 0.25, 0.0), (137, 137, 0)),
    ("f.png", (0.05, 0.05, 0.05), (63, 63, 63)),
]


@pytest.fixture
def frames(tmp_path):
    """Six solid frames of different aspect ratios: three linear EXR, three sRGB PNG."""
    paths = []
    for i, (name, linear, _) in enumerate(FRAMES):
        shape = (30, 50, 3) if i % 2 else (64, 32, 3)
        path = tmp_path / name
        (write_exr if name.endswith(".exr") else write_png)(path, np.full(shape, linear))
        paths.append(path)
    return paths


def _pixels(buf: oiio.ImageBuf) -> np.ndarray:
    spec = buf.spec()
    return np.asarray(buf.get_pixels(oiio.UINT8)).reshape(spec.height, spec.width, spec.nchannels)


def _drawn(region: np.ndarray) -> int:
    """How many pixels of ``region`` differ from the background."""
    return int(np.count_nonzero(np.any(region != BACKGROUND_CODE, axis=-1)))


@pytest.fixture
def sheet(frames):
    buf = make_sheet(
        frames, rows=ROWS, columns=COLUMNS, grid=(2, 3), header=HEADER, cell_size=CELL, margin=MARGIN, font_size=FONT
    )
    layout = sheet_layout(ROWS, COLUMNS, header=HEADER, cell_size=CELL, margin=MARGIN, font_size=FONT)
    return buf, layout


def test_sheet_size_follows_the_documented_layout(sheet):
    buf, layout = sheet
    spec = buf.spec()
    assert (spec.nchannels, spec.format) == (3, oiio.TypeDesc(oiio.UINT8))
    label_width = oiio.ImageBufAlgo.text_size(ROWS[1], FONT).width + MARGIN  # the wider row label
    assert layout.label_width == label_width
    assert (spec.width, spec.height) == (
        MARGIN + label_width + 3 * (CELL[0] + MARGIN),
        MARGIN + 2 * FONT + 2 * FONT + 2 * (CELL[1] + MARGIN),
    )


def test_cell_centres_hold_the_frame_colours_exr_srgb_encoded(sheet):
    buf, layout = sheet
    pixels = _pixels(buf)
    for i, (_, _, expected) in enumerate(FRAMES):
        x, y = layout.cell_centre(*divmod(i, 3))
        assert tuple(pixels[y, x]) == expected, FRAMES[i][0]


def test_frames_keep_their_aspect_ratio_on_the_background(sheet):
    buf, layout = sheet
    pixels = _pixels(buf)
    # frame a is 32 x 64 (portrait): fitted to 20 x 40 in a 48 x 40 cell, grey bars left and right
    x, y = layout.cell_origin(0, 0)
    cell = pixels[y : y + CELL[1], x : x + CELL[0]]
    covered = np.all(cell == 188, axis=-1)
    assert np.count_nonzero(covered.any(axis=0)) == pytest.approx(20, abs=1)
    assert covered.any(axis=1).all()
    assert np.all(cell[:, :10] == BACKGROUND_CODE)


def test_a_frame_shrunk_into_its_cell_takes_the_mean_of_each_pixel_area(tmp_path):
    """Stripes one pixel wide (codes 0 and 255) shrunk 4 times are a uniform 127.5 (the mean of every 4 x 4 block),
    not stripes aliased to a beat."""
    stripes = np.zeros((160, 160, 3))
    stripes[:, 1::2] = 1.0
    write_png(tmp_path / "stripes.png", stripes)
    buf = make_sheet([tmp_path / "stripes.png"], rows=[""], columns=[""], cell_size=(40, 40), margin=MARGIN)
    x, y = sheet_layout([""], [""], cell_size=(40, 40), margin=MARGIN).cell_origin(0, 0)
    cell = _pixels(buf)[y : y + 40, x : x + 40]
    assert set(np.unique(cell)) <= {127, 128}


def test_labels_and_header_are_drawn(sheet):
    buf, layout = sheet
    pixels = _pixels(buf)
    header = pixels[: MARGIN + layout.header_height]
    assert _drawn(header) > 50
    top = MARGIN + layout.header_height
    for col in range(3):
        x, _ = layout.cell_origin(0, col)
        band = pixels[top : top + layout.column_label_height, x : x + CELL[0]]
        assert _drawn(band) > 10, COLUMNS[col]
    for row in range(2):
        _, y = layout.cell_origin(row, 0)
        band = pixels[y : y + CELL[1], : MARGIN + layout.label_width]
        assert _drawn(band) > 20, ROWS[row]


def test_longer_utf8_label_draws_more_ink(frames):
    def ink(label: str) -> int:
        buf = make_sheet(frames[:1], rows=[label], columns=[""], cell_size=CELL, margin=MARGIN, font_size=FONT)
        return _drawn(_pixels(buf)[:, : MARGIN + sheet_layout([label], [""], font_size=FONT).label_width])

    assert ink("Teinte n°3 — Rosé") > ink("Teinte n") > 0


def test_empty_cells_and_blank_labels_stay_background(frames):
    buf = make_sheet(frames[:1], rows=["", ""], columns=["", ""], cell_size=CELL, margin=MARGIN, font_size=FONT)
    layout = sheet_layout(["", ""], ["", ""], cell_size=CELL, margin=MARGIN, font_size=FONT)
    pixels = _pixels(buf)
    assert (layout.label_width, layout.header_height) == (0, 0)
    assert pixels.shape == (MARGIN + 2 * FONT + 2 * (CELL[1] + MARGIN), MARGIN + 2 * (CELL[0] + MARGIN), 3)
    x, y = layout.cell_origin(0, 1)
    assert _drawn(pixels[y:, x:]) == 0
    assert _drawn(pixels[: layout.cell_origin(0, 0)[1]]) == 0


def test_make_sheet_refuses_a_mismatched_grid_and_too_many_frames(frames):
    with pytest.raises(ValueError, match=r"grid \(3, 2\)"):
        make_sheet(frames, rows=ROWS, columns=COLUMNS, grid=(3, 2))
    with pytest.raises(ValueError, match="6 frames do not fit a 1 x 3 grid"):
        make_sheet(frames, rows=["x"], columns=COLUMNS)


def test_missing_and_unreadable_frames_raise_naming_the_file(frames, tmp_path):
    missing = tmp_path / "gone.exr"
    with pytest.raises(FrameError, match=r"gone\.exr: does not exist") as caught:
        make_sheet([frames[0], missing], rows=["r"], columns=["a", "b"])
    assert caught.value.path == missing
    junk = tmp_path / "junk.png"
    junk.write_text("not an image")
    with pytest.raises(FrameError, match=r"junk\.png: cannot be read"):
        make_sheet([junk], rows=["r"], columns=["a"])


def test_write_sheet_round_trips_the_pixels_and_leaves_no_temporary(sheet, tmp_path):
    buf, _ = sheet
    out = tmp_path / "sheets" / "sheet.png"
    out.parent.mkdir()
    write_sheet(buf, out)
    np.testing.assert_array_equal(read_png(out), _pixels(buf))
    assert [p.name for p in out.parent.iterdir()] == ["sheet.png"]
    with pytest.raises(ValueError, match=r"expected a \.png"):
        write_sheet(buf, tmp_path / "sheet.jpg")


def test_cli_writes_a_sheet(frames, tmp_path, capsys):
    out = tmp_path / "sheet.png"
    status = main(
        [
            "sheet",
            *map(str, frames),
            "-o",
            str(out),
            "--columns",
            "3",
            "--row-labels",
            ",".join(ROWS),
            "--column-labels",
            ",".join(COLUMNS),
            "--header",
            HEADER,
        ]
    )
    assert status == 0
    assert "wrote the sheet" in capsys.readouterr().out
    pixels = read_png(out)
    layout = sheet_layout(ROWS, COLUMNS, header=HEADER)
    assert pixels.shape == (layout.height, layout.width, 3)
    for i, (_, _, expected) in enumerate(FRAMES):
        x, y = layout.cell_centre(*divmod(i, 3))
        assert tuple(pixels[y, x]) == expected


def test_cli_default_labels_are_file_stems(frames, tmp_path):
    out = tmp_path / "sheet.png"
    assert main(["sheet", *map(str, frames[:4]), "-o", str(out), "--columns", "2"]) == 0
    layout = sheet_layout(["a", "c"], ["a", "b"])
    assert read_png(out).shape == (layout.height, layout.width, 3)


def test_cli_missing_frame_exits_2_naming_it(frames, tmp_path, capsys):
    missing = tmp_path / "nowhere" / "lost_frame.exr"
    status = main(["sheet", str(frames[0]), str(missing), "-o", str(tmp_path / "sheet.png")])
    assert status == 2
    err = capsys.readouterr().err
    assert "lost_frame.exr" in err and "does not exist" in err
    assert not (tmp_path / "sheet.png").exists()


def test_cli_unreadable_frame_and_wrong_label_count_exit_2(frames, tmp_path, capsys):
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"\x89PNG broken")
    assert main(["sheet", str(junk), "-o", str(tmp_path / "s.png")]) == 2
    assert "junk.png" in capsys.readouterr().err
    status = main(["sheet", *map(str, frames), "-o", str(tmp_path / "s.png"), "--columns", "3", "--row-labels", "x"])
    assert status == 2
    assert "--row-labels" in capsys.readouterr().err


def test_captions_go_under_their_own_cells(frames):
    captions = ["Rouge · Berry", "", "Velvet · 02"]
    buf = make_sheet(frames[:3], rows=[""], columns=["", "", ""], cell_size=CELL, margin=MARGIN, font_size=FONT,
                     captions=captions)  # fmt: skip
    layout = sheet_layout([""], ["", "", ""], cell_size=CELL, margin=MARGIN, font_size=FONT, captions=True)
    pixels = _pixels(buf)
    assert layout.caption_height == 2 * FONT
    assert pixels.shape == (MARGIN + 2 * FONT + CELL[1] + 2 * FONT + MARGIN, MARGIN + 3 * (CELL[0] + MARGIN), 3)
    for col, caption in enumerate(captions):
        x, y = layout.cell_origin(0, col)
        band = pixels[y + CELL[1] : y + CELL[1] + layout.caption_height, x : x + CELL[0]]
        assert (_drawn(band) > 10) == bool(caption), caption
    with pytest.raises(ValueError, match="2 captions for 3 frames"):
        make_sheet(frames[:3], rows=[""], columns=["", "", ""], captions=captions[:2])


def test_a_sheet_of_one_frame_per_product_captions_each_cell(tmp_path):
    from kmpipe.stages.sheet import write_contact_sheet

    paths = []
    for i, (product, shade) in enumerate([("Rouge", "Berry"), ("Velvet", "02"), ("Glow", "Glow")]):
        paths.append(tmp_path / f"{i}.exr")
        write_exr(paths[-1], np.full((16, 16, 3), 0.3), {"product": product, "shade": shade,
                  "camera_azimuth_deg": 0.0, "scene": "s", "illuminant": "D65"})  # fmt: skip
    written = write_contact_sheet(paths, tmp_path / "sheet.png", columns=2, cell=CELL[0], captions=True)
    assert written.grid == (2, 2)
    layout = sheet_layout(["", ""], ["", ""], header="s · D65 · x", cell_size=(CELL[0],) * 2, captions=True)
    assert written.size == (layout.width, layout.height)
    pixels = read_png(written.path)
    assert _drawn(pixels[:, : layout.cell_origin(0, 0)[0]]) == 0  # no row labels
    for i in range(3):
        x, y = layout.cell_origin(*divmod(i, 2))
        assert _drawn(pixels[y + CELL[0] : y + CELL[0] + layout.caption_height, x : x + CELL[0]]) > 10
