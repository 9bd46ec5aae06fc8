"""The sheet stage: rendered frames laid out on a labelled contact sheet (``kmpipe sheet``, ``kmpipe run``).

Labels come from the frames themselves: an EXR that ``kmpipe render`` wrote names its product, shade, camera azimuth,
scene and illuminant in its header (docs/formats.md, "Frames"), so a sheet of such frames labels itself.
"""

from __future__ import annotations

import datetime
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from kmpipe.errors import InputError
from kmpipe.formats import files

#: Side (px) of a sheet's square cells unless the caller chooses.
CELL_PIXELS = 256
#: Put before the row label of a product whose frames say it failed validation (rendered with ``--keep-going``).
FAILED_MARK = "⚠ "


@dataclass(frozen=True)
class SheetLabels:
    """Labels of a sheet: one per row (drawn left), one per column (drawn above), a header line, and one per frame
    (the caption a sheet of one frame per product draws under each cell)."""

    rows: list[str]
    columns: list[str]
    header: str
    cells: list[str]


@dataclass(frozen=True)
class SheetWritten:
    """A written sheet: its file, its grid of frames (rows, columns) and its size in pixels (width, height)."""

    path: Path
    grid: tuple[int, int]
    size: tuple[int, int]


def frame_headers(frames: Sequence[Path]) -> list[dict]:
    """Each frame's EXR header ({} for another file, or one that cannot be read: the sheet names it when it reads
    the pixels)."""
    from renderer.image_io import read_header

    headers = []
    for path in frames:
        try:
            headers.append(read_header(path) if path.suffix.lower() == ".exr" else {})
        except OSError:
            headers.append({})
    return headers


def shown_image(frame: Path, header: dict) -> Path:
    """The image a sheet shows for ``frame``: the PNG that ``kmpipe render`` wrote beside its EXR (tone mapped as
    the scene's ``[output]`` says, as the frame's videos and a studio's viewers show it; the EXR's header then names
    its ``tone_map``), else the frame itself (an EXR is then sRGB encoded without a tone curve)."""
    png = frame.with_suffix(".png")
    return png if "tone_map" in header and png.is_file() else frame


def frame_labels(
    frames: Sequence[Path], n_rows: int, n_cols: int, headers: Sequence[dict] | None = None
) -> SheetLabels:
    """Row and column labels and header of a sheet of ``frames`` (row-major) in ``n_rows`` x ``n_cols`` cells.

    Frames that ``kmpipe render`` wrote (EXR with ``product`` and ``camera_azimuth_deg`` attributes) give
    "product · shade" per row and per frame (the product alone when the shade is its name; followed by the rendered
    colour's 95 % uncertainty, ``±0.21``, where the frame's ``colour_uncertainty`` attribute gives one; marked with
    :data:`FAILED_MARK` when the frame's ``validation`` attribute says it failed), the camera's azimuth in degrees per
    column (from the first row) and "scene · illuminant · today's date" across the top; any other frames give their
    file stems and no header. ``headers``: the frames' headers, if read already (:func:`frame_headers`).
    """
    headers = frame_headers(frames) if headers is None else headers
    if not all("product" in h and "camera_azimuth_deg" in h for h in headers):
        rows = [frames[r * n_cols].stem for r in range(n_rows)]
        return SheetLabels(rows, [p.stem for p in frames[:n_cols]], "", [p.stem for p in frames])

    def row_label(h: dict) -> str:
        name = h["product"] if h["shade"] in ("", h["product"]) else f"{h['product']} · {h['shade']}"
        if str(h.get("colour_uncertainty", "")).startswith("±"):  # one material's: short enough for a label
            name += f" {h['colour_uncertainty']}"
        return FAILED_MARK + name if str(h.get("validation", "")).startswith("fail") else name

    rows = [row_label(headers[r * n_cols]) for r in range(n_rows)]
    columns = [f"{float(h['camera_azimuth_deg']):g}°" for h in headers[:n_cols]]
    scenes = ", ".join(dict.fromkeys(str(h.get("scene", "")) for h in headers))
    illuminants = ", ".join(dict.fromkeys(str(h.get("illuminant", "")) for h in headers))
    header = f"{scenes} · {illuminants} · {datetime.date.today().isoformat()}"
    return SheetLabels(rows, columns, header, [row_label(h) for h in headers])


def write_contact_sheet(
    frames: Sequence[str | Path],
    output: str | Path,
    *,
    columns: int | None = None,
    row_labels: Sequence[str] | None = None,
    column_labels: Sequence[str] | None = None,
    header: str | None = None,
    cell: int = CELL_PIXELS,
    captions: bool = False,
) -> SheetWritten:
    """Lay ``frames`` (EXR, linear, encoded to sRGB; or PNG) out row-major in ``columns`` columns (default: up to 4)
    and write the sheet to ``output`` (PNG) in cells ``cell`` px square. A frame ``kmpipe render`` wrote is shown as
    its tone-mapped PNG (:func:`shown_image`).

    Labels and header left None come from the frames (:func:`frame_labels`); given labels must match the grid
    (InputError naming ``--row-labels`` or ``--column-labels``). With ``captions`` every cell is labelled under it
    with its own frame's product and shade, and rows and columns are not labelled unless given (a sheet of one
    frame per product). A frame that cannot be read is an InputError naming it, and nothing is written.

    >>> import tempfile, pathlib, numpy as np
    >>> from renderer.image_io import write_exr
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> frames = [folder / f"frame_{i:03d}.exr" for i in range(2)]
    >>> for i, frame in enumerate(frames):
    ...     write_exr(frame, np.full((32, 32, 3), 0.2 * (i + 1)), {"product": "Rouge", "shade": "Berry",
    ...               "camera_azimuth_deg": 180.0 * i, "scene": "bullet", "illuminant": "D65"})
    >>> sheet = write_contact_sheet(frames, folder / "sheet.png", cell=64)
    >>> sheet.grid, sheet.path.name
    ((1, 2), 'sheet.png')
    >>> labels = frame_labels(frames, 1, 2)
    >>> labels.rows, labels.columns, labels.header.startswith("bullet · D65 · ")
    (['Rouge · Berry'], ['0°', '180°'], True)
    """
    from renderer.contact_sheet import FrameError, make_sheet, write_sheet

    frames, output = [Path(f) for f in frames], Path(output)
    files.output_file(output, suffixes=(".png",), inputs=frames)
    n_cols = columns or min(len(frames), 4)
    n_rows = -(-len(frames) // n_cols)
    for path in frames:
        files.regular_file(path, "image")
    headers = frame_headers(frames)
    labels = frame_labels(frames, n_rows, n_cols, headers)
    default_columns, default_rows = ([""] * n_cols, [""] * n_rows) if captions else (labels.columns, labels.rows)
    chosen_columns = list(column_labels) if column_labels is not None else default_columns
    chosen_rows = list(row_labels) if row_labels is not None else default_rows
    for option, given, wanted in (("--column-labels", chosen_columns, n_cols), ("--row-labels", chosen_rows, n_rows)):
        if len(given) != wanted:
            raise InputError(
                f"gives {len(given)} labels; {len(frames)} frames in {n_cols} columns need {wanted}", field=option
            )
    try:
        sheet = make_sheet(
            [shown_image(path, header) for path, header in zip(frames, headers, strict=True)],
            rows=chosen_rows,
            columns=chosen_columns,
            grid=(n_rows, n_cols),
            header=labels.header if header is None else header,
            cell_size=(cell, cell),
            captions=labels.cells if captions else None,
        )
    except FrameError as err:
        raise InputError(err.reason, path=err.path) from None
    write_sheet(sheet, output)
    spec = sheet.spec()
    return SheetWritten(output, (n_rows, n_cols), (spec.width, spec.height))
