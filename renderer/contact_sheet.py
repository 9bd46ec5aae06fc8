"""Contact sheets: rendered frames laid out in a labelled grid, as one 8-bit sRGB PNG.

A sheet is a header line across the top, a band of column labels, and one row per row label with that label on
the left and one cell per column. Every frame is fitted into its cell keeping its aspect ratio and centred there.
EXR frames hold linear values and are encoded with the sRGB transfer function; other files (PNG) hold sRGB codes
and are used as they are. Text is drawn with OpenImageIO's ``render_text`` (UTF-8, its bundled font).

Layout, in pixels, with ``m`` the margin, ``f`` the font size and ``(w, h)`` the cell size::

    width  = m + label_width + n_cols * (w + m)
    height = m + header_height + column_label_height + n_rows * (h + caption_height + m)

where ``header_height = 2 f`` when there is a header (else 0), ``column_label_height = 2 f``, ``label_width`` is the
widest row label plus ``m`` (0 when every row label is empty) and ``caption_height = 2 f`` on a sheet whose cells
carry captions of their own (drawn under each cell, cut with an ellipsis to its width; else 0).
"""

from __future__ import annotations

import concurrent.futures
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import OpenImageIO as oiio

from renderer.image_io import PNG_COMPRESSION, _write, read_exr, read_png, srgb_encode

#: Sheet background, sRGB-encoded in [0, 1]: a neutral mid-dark grey (code 77).
BACKGROUND = (0.3, 0.3, 0.3)
#: Text colour, sRGB-encoded in [0, 1].
TEXT_COLOUR = (0.95, 0.95, 0.95)
#: File name suffixes read as linear (scene-referred) images.
LINEAR_SUFFIXES = (".exr",)


class FrameError(OSError):
    """A frame file is missing or cannot be read; ``path`` names it."""

    def __init__(self, path: str | Path, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path = Path(path)
        self.reason = reason


@dataclass(frozen=True)
class SheetLayout:
    """Where everything goes on a sheet (pixels, origin top left, y down).

    Attributes
    ----------
    width, height
        Size of the whole sheet.
    n_rows, n_cols
        Grid shape.
    cell_size
        ``(w, h)`` of one cell.
    margin
        Gap around and between cells.
    header_height, column_label_height, label_width
        Height of the header band, of the column label band, and width of the row label band.
    caption_height
        Height of the caption band under each row of cells (0 without captions).
    """

    width: int
    height: int
    n_rows: int
    n_cols: int
    cell_size: tuple[int, int]
    margin: int
    header_height: int
    column_label_height: int
    label_width: int
    caption_height: int = 0

    def cell_origin(self, row: int, col: int) -> tuple[int, int]:
        """Top-left corner ``(x, y)`` of the cell in ``row``, ``col`` (0-based)."""
        w, h = self.cell_size
        x = self.margin + self.label_width + col * (w + self.margin)
        y = self.margin + self.header_height + self.column_label_height + row * (h + self.caption_height + self.margin)
        return x, y

    def cell_centre(self, row: int, col: int) -> tuple[int, int]:
        """Centre pixel ``(x, y)`` of the cell in ``row``, ``col``."""
        x, y = self.cell_origin(row, col)
        return x + self.cell_size[0] // 2, y + self.cell_size[1] // 2


def sheet_layout(
    rows: Sequence[str],
    columns: Sequence[str],
    *,
    header: str = "",
    cell_size: tuple[int, int] = (256, 256),
    margin: int = 8,
    font_size: int = 16,
    captions: bool = False,
) -> SheetLayout:
    """Compute the layout of a sheet with these labels, and a caption under each cell if ``captions`` (see the module
    docstring for the formulas)."""
    n_rows, n_cols = len(rows), len(columns)
    if n_rows < 1 or n_cols < 1:
        raise ValueError(f"a sheet needs at least one row and one column, got {n_rows} x {n_cols}")
    w, h = (int(v) for v in cell_size)
    if w < 1 or h < 1 or margin < 0 or font_size < 1:
        raise ValueError(
            f"expected a positive cell size and font size and a margin >= 0, got {cell_size}, {margin}, {font_size}"
        )
    widths = [oiio.ImageBufAlgo.text_size(label, font_size).width for label in rows if label]
    label_width = max(widths) + margin if widths else 0
    header_height = 2 * font_size if header else 0
    column_label_height = 2 * font_size
    caption_height = 2 * font_size if captions else 0
    width = margin + label_width + n_cols * (w + margin)
    height = margin + header_height + column_label_height + n_rows * (h + caption_height + margin)
    return SheetLayout(width, height, n_rows, n_cols, (w, h), margin, header_height, column_label_height, label_width,
                       caption_height)  # fmt: skip


def read_frame(path: str | Path) -> np.ndarray:
    """Read one frame as sRGB-encoded RGB float32 in [0, 1], shape (height, width, 3).

    ``.exr`` files are linear and go through the sRGB transfer function (non-finite values count as 0); any other
    file OpenImageIO reads (PNG) is taken as 8-bit sRGB codes. Grey images are repeated into RGB; alpha is dropped.

    Raises
    ------
    FrameError
        The file does not exist or cannot be read.
    """
    path = Path(path)
    if not path.is_file():
        raise FrameError(path, "does not exist" if not path.exists() else "is not a file")
    try:
        if path.suffix.lower() in LINEAR_SUFFIXES:
            linear, _ = read_exr(path)
            colour = srgb_encode(np.nan_to_num(linear, nan=0.0, posinf=1.0, neginf=0.0))
        else:
            colour = read_png(path).astype(np.float64) / 255.0
    except (OSError, ValueError) as err:  # ValueError: an image over the readers' size limits
        raise FrameError(path, f"cannot be read as an image ({err})") from None
    if colour.shape[2] < 3:
        colour = np.repeat(colour[..., :1], 3, axis=2)
    return np.ascontiguousarray(colour[..., :3], dtype=np.float32)


def _codes(encoded: np.ndarray) -> np.ndarray:
    """8-bit codes of sRGB-encoded values: ``rint(255 clip(v, 0, 1))``."""
    return np.rint(np.clip(encoded, 0.0, 1.0) * 255.0).astype(np.uint8)


def _fitted(frame: np.ndarray, cell_size: tuple[int, int]) -> np.ndarray:
    """The frame resized to fit ``cell_size`` with its aspect ratio kept, as 8-bit codes: each new pixel the mean of
    the frame over its area when shrinking (OpenCV's INTER_AREA: no aliasing, a flat region keeps its value), bicubic
    when enlarging."""
    height, width = frame.shape[:2]
    scale = min(cell_size[0] / width, cell_size[1] / height)
    new_w, new_h = max(1, round(width * scale)), max(1, round(height * scale))
    if (new_w, new_h) != (width, height):
        frame = cv2.resize(frame, (new_w, new_h), interpolation=cv2.INTER_AREA if scale < 1.0 else cv2.INTER_CUBIC)
    return _codes(frame)


def _cells(frames: Sequence[str | Path], cell_size: tuple[int, int]) -> list[np.ndarray]:
    """Each frame read (:func:`read_frame`) and fitted to its cell (:func:`_fitted`), on a thread per core (reading,
    decoding, encoding and resizing run outside Python's lock): only the cells stay in memory, not the frames. The
    first frame in order that cannot be read raises its FrameError."""
    threads = max(1, min(len(frames), len(os.sched_getaffinity(0))))
    with concurrent.futures.ThreadPoolExecutor(max_workers=threads) as pool:
        return list(pool.map(lambda path: _fitted(read_frame(path), cell_size), frames))


def _text(buf: oiio.ImageBuf, x: int, y: int, text: str, font_size: int, box: oiio.ROI, **align: str) -> None:
    """Draw ``text`` at ``(x, y)``, clipped to ``box``."""
    if text and not oiio.ImageBufAlgo.render_text(buf, x, y, text, font_size, textcolor=TEXT_COLOUR, roi=box, **align):
        raise RuntimeError(f"cannot draw the text {text!r}: {buf.geterror() or oiio.geterror()}")


def _shortened(text: str, width: int, font_size: int) -> str:
    """``text``, cut and ended with an ellipsis until it is at most ``width`` pixels wide (at ``font_size``)."""
    if not text or oiio.ImageBufAlgo.text_size(text, font_size).width <= width:
        return text
    for end in range(len(text) - 1, 0, -1):
        cut = text[:end].rstrip() + "…"
        if oiio.ImageBufAlgo.text_size(cut, font_size).width <= width:
            return cut
    return ""


def make_sheet(
    frames: Sequence[str | Path],
    *,
    rows: Sequence[str],
    columns: Sequence[str],
    grid: tuple[int, int] | None = None,
    header: str = "",
    cell_size: tuple[int, int] = (256, 256),
    margin: int = 8,
    font_size: int = 16,
    captions: Sequence[str] | None = None,
) -> oiio.ImageBuf:
    """Lay frames out in a labelled grid and return the sheet as an 8-bit sRGB RGB ImageBuf.

    Parameters
    ----------
    frames
        Image files (EXR linear, PNG sRGB), placed row-major: frame ``i`` goes to row ``i // n_cols``, column
        ``i % n_cols``. Fewer frames than cells leave the last cells empty.
    rows, columns
        Row labels (drawn left of each row) and column labels (drawn above each column); their lengths give the
        grid shape. Empty strings draw nothing.
    grid
        ``(n_rows, n_cols)``; if given it must equal ``(len(rows), len(columns))``.
    header
        One line across the top, e.g. scene, illuminant and date.
    cell_size
        ``(w, h)`` of a cell in pixels; each frame is fitted inside keeping its aspect ratio and centred.
    margin
        Gap in pixels around and between cells.
    font_size
        Text size in pixels.
    captions
        One line under each frame's cell (one per frame, cut with an ellipsis to the cell's width), or None.

    Raises
    ------
    ValueError
        Labels and grid disagree, more frames than cells, or captions not one per frame.
    FrameError
        A frame file is missing or unreadable (its path is in the error).
    """
    shape = (len(rows), len(columns))
    if grid is not None and tuple(grid) != shape:
        raise ValueError(f"grid {tuple(grid)} does not match {shape[0]} row labels and {shape[1]} column labels")
    if len(frames) > shape[0] * shape[1]:
        raise ValueError(f"{len(frames)} frames do not fit a {shape[0]} x {shape[1]} grid")
    if captions is not None and len(captions) != len(frames):
        raise ValueError(f"{len(captions)} captions for {len(frames)} frames: give one per frame")
    layout = sheet_layout(rows, columns, header=header, cell_size=cell_size, margin=margin, font_size=font_size,
                          captions=captions is not None)  # fmt: skip
    cells = _cells(frames, layout.cell_size)  # all read first: a bad file fails before any drawing

    # Laid out in 8-bit codes (a float sheet of a long line is gigabytes), the text then drawn over them.
    codes = np.empty((layout.height, layout.width, 3), np.uint8)
    codes[...] = _codes(np.asarray(BACKGROUND))
    w, h = layout.cell_size
    for i, fitted in enumerate(cells):
        x, y = layout.cell_origin(*divmod(i, layout.n_cols))
        fh, fw = fitted.shape[:2]
        x, y = x + (w - fw) // 2, y + (h - fh) // 2
        codes[y : y + fh, x : x + fw] = fitted
    sheet = oiio.ImageBuf(oiio.ImageSpec(layout.width, layout.height, 3, oiio.UINT8))
    sheet.set_pixels(oiio.ROI(0, layout.width, 0, layout.height, 0, 1, 0, 3), codes)
    del codes, cells

    m, f = layout.margin, font_size
    if header:
        box = oiio.ROI(0, layout.width, 0, m + layout.header_height, 0, 1, 0, 3)
        _text(sheet, m, m + layout.header_height // 2, header, f, box, aligny="center")
    top = m + layout.header_height
    for col, label in enumerate(columns):
        x, _ = layout.cell_origin(0, col)
        box = oiio.ROI(x, x + w, top, top + layout.column_label_height, 0, 1, 0, 3)
        _text(sheet, x + w // 2, top + layout.column_label_height // 2, label, f, box, alignx="center", aligny="center")
    for row, label in enumerate(rows):
        _, y = layout.cell_origin(row, 0)
        box = oiio.ROI(0, m + layout.label_width, y, y + h, 0, 1, 0, 3)
        _text(sheet, m, y + h // 2, label, f, box, aligny="center")
    for i, caption in enumerate(captions or ()):
        x, y = layout.cell_origin(*divmod(i, layout.n_cols))
        box = oiio.ROI(x, x + w, y + h, y + h + layout.caption_height, 0, 1, 0, 3)
        text = _shortened(caption, w, f)
        _text(sheet, x + w // 2, y + h + layout.caption_height // 2, text, f, box, alignx="center", aligny="center")

    sheet.specmod().attribute("oiio:ColorSpace", "sRGB")
    return sheet


def write_sheet(buf: oiio.ImageBuf, path: str | Path) -> None:
    """Write a sheet from :func:`make_sheet` as an 8-bit sRGB PNG, atomically (temporary file, then rename)."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: a contact sheet is written as PNG; expected a .png file name")
    spec = buf.spec()
    codes = np.asarray(buf.get_pixels(oiio.UINT8)).reshape(spec.height, spec.width, spec.nchannels)
    out_spec = oiio.ImageSpec(spec.width, spec.height, spec.nchannels, oiio.UINT8)
    out_spec.attribute("oiio:ColorSpace", "sRGB")
    out_spec.attribute("png:compressionLevel", PNG_COMPRESSION)
    _write(path, codes, out_spec)
