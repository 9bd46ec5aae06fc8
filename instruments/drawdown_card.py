"""The drawdown card: a printed card with ArUco markers, located in a photo so that its regions can be sampled.

A technician draws a cosmetic film down over the black and white stripes of a printed card and photographs it
through crossed polarizers. This module describes the card (:class:`Layout`, read from and written to TOML, see
``docs/formats.md``), prints it (:func:`render_card`, :func:`write_card`), finds it in a photo
(:func:`locate_card`: ArUco markers, then a homography from card millimetres to image pixels) and measures its
regions in the linear photo (:func:`sample_region`).

Coordinates
-----------
Card coordinates are in mm from the card's top-left corner, x to the right and y down. Image coordinates are in px
with OpenCV's convention: the centre of pixel (column i, row j) is at (i, j), so a rendered card at ``px_per_mm``
maps card (x, y) mm to image (x * px_per_mm - 0.5, y * px_per_mm - 0.5) px.

Markers
-------
A marker's ``x_mm``, ``y_mm`` is the top-left corner of its black square (border included) and ``size_mm`` its side.
It is printed upright. Around the square a quiet zone one module wide (``size_mm / (bits + 2)``, e.g. 1/6 of the
side for a 4x4 dictionary) must stay white: printed areas may not enter it, regions keep a further 1 mm away (room
for their outlines), and it must lie on the card.
"""

from __future__ import annotations

import json
import math
import os
import re
import secrets
import struct
import tomllib
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import IO, Any

import cv2
import numpy as np

from instruments.regular_files import NotReadable, read_regular

ROLES = ("backing", "film", "white_reference", "colorchecker")
"""Region roles: labels for the caller, not interpreted here."""

DICTIONARIES = tuple(sorted(name for name in dir(cv2.aruco) if name.startswith("DICT_")))
"""Names of OpenCV's predefined ArUco and AprilTag dictionaries, as accepted in ``card.dictionary``."""

PRINT_DPI = 300.0
"""Resolution of the printable card written by :func:`write_card` (dots per inch)."""

MAX_CARD_MM = 500.0
"""Longest side of a card (mm), checked when a layout is made: larger than any drawdown card a printer takes."""

MAX_CARD_PIXELS = 64_000_000
"""Most pixels :func:`render_card` draws (a 500 x 500 mm card at 300 dpi is 35 million, 105 MB as 8-bit RGB)."""

MAX_LAYOUT_BYTES = 4 << 20
"""Largest layout file read (bytes)."""

OUTLINE_CLEARANCE_MM = 1.0
"""Extra distance (mm) a region keeps from a marker's quiet zone: room for the region's printed outline."""

RANSAC_THRESHOLD_PX = 3.0
"""Maximum reprojection error (px) of a marker corner counted as an inlier when the homography is fitted."""

_NAME = re.compile(r"[A-Za-z0-9_-]+")  # region names, and the keys TOML writes without quotes
#: How far inside its edges a region is sampled (mm): away from the drawdown's edges and the print's bleed.
SAMPLING_MARGIN_MM = 2.0
_CARD_KEYS = ("width_mm", "height_mm", "dictionary")
_MARKER_KEYS = ("id", "x_mm", "y_mm", "size_mm")
_PRINTED_KEYS = ("x_mm", "y_mm", "w_mm", "h_mm", "gray")
_REGION_KEYS = ("name", "role", "x_mm", "y_mm", "w_mm", "h_mm")
_TABLES = ("card", "marker", "printed", "region")
_GRAY_OUTLINE = 128  # 8-bit grey of region outlines and labels: visible on black ink and on white paper
_LABEL_HEIGHT_MM = 2.2
_OUTLINE_GAP_MM = 0.4
_OUTLINE_WIDTH_MM = 0.25


class LayoutError(ValueError):
    """A card layout breaks a rule; the message names the file (when read from one), the table and the field."""


class CardNotFound(ValueError):
    """Too few of the layout's markers were found in the photo to locate the card."""


# ---------------------------------------------------------------------------------------------------------------
# Layout model


@dataclass(frozen=True)
class Marker:
    """An ArUco marker printed on the card.

    ``id`` is the marker's id in the layout's dictionary; ``x_mm``, ``y_mm`` the top-left corner of its black
    square from the card's top-left corner (mm); ``size_mm`` the side of the black square, border included (mm).
    """

    id: int
    x_mm: float
    y_mm: float
    size_mm: float

    def corners_mm(self) -> np.ndarray:
        """Corners of the black square (4, 2) in mm, in ArUco order: top-left, top-right, bottom-right, bottom-left."""
        x, y, s = self.x_mm, self.y_mm, self.size_mm
        return np.array([[x, y], [x + s, y], [x + s, y + s], [x, y + s]], dtype=np.float64)


@dataclass(frozen=True)
class PrintedArea:
    """A rectangle printed in a uniform grey: ``gray`` 0 is black ink, 1 the paper white (mm from the card corner)."""

    x_mm: float
    y_mm: float
    w_mm: float
    h_mm: float
    gray: float


@dataclass(frozen=True)
class Region:
    """A rectangle of the card to sample (mm from the card's top-left corner).

    ``role`` is one of :data:`ROLES`; ``metadata`` holds any further keys of the TOML table (e.g. ``over``,
    ``thickness``, ``reflectance``), passed through untouched: strings, booleans, numbers or arrays of them.
    """

    name: str
    role: str
    x_mm: float
    y_mm: float
    w_mm: float
    h_mm: float
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "metadata", MappingProxyType(dict(self.metadata)))


@dataclass(frozen=True)
class Layout:
    """A drawdown card: its size (mm), marker dictionary, markers, printed areas and regions.

    Constructing a layout checks every rule of ``docs/formats.md`` and raises :class:`LayoutError` naming the table,
    index (counted from 0, in file order) and field.
    """

    width_mm: float
    height_mm: float
    dictionary: str
    markers: tuple[Marker, ...]
    regions: tuple[Region, ...]
    printed: tuple[PrintedArea, ...] = ()

    def __post_init__(self) -> None:
        for name in ("markers", "regions", "printed"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        _check_layout(self)

    def region(self, name: str) -> Region:
        """The region called ``name`` (KeyError if there is none)."""
        for region in self.regions:
            if region.name == name:
                return region
        raise KeyError(f"no region {name!r}; the layout has {', '.join(r.name for r in self.regions)}")

    def quiet_zone_fraction(self) -> float:
        """Width of the white quiet zone around each marker as a fraction of its side: one module of the dictionary."""
        return 1.0 / (_dictionary(self.dictionary).markerSize + 2)


def _dictionary(name: str) -> cv2.aruco.Dictionary:
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def _overlap(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> bool:
    """Whether two boxes (x0, y0, x1, y1) share interior points (touching edges do not overlap)."""
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _keep_out(marker: Marker, quiet: float, extra_mm: float = 0.0) -> tuple[float, float, float, float]:
    """Box (mm) of a marker's square grown by its quiet zone (``quiet`` per mm of side) and ``extra_mm``."""
    pad = marker.size_mm * quiet + extra_mm
    return (
        marker.x_mm - pad,
        marker.y_mm - pad,
        marker.x_mm + marker.size_mm + pad,
        marker.y_mm + marker.size_mm + pad,
    )


def _box(item: PrintedArea | Region) -> tuple[float, float, float, float]:
    return (item.x_mm, item.y_mm, item.x_mm + item.w_mm, item.y_mm + item.h_mm)


def _finite_positive(value: float) -> bool:
    return math.isfinite(value) and value > 0


def _check_layout(layout: Layout) -> None:
    """Raise :class:`LayoutError` for the first broken rule, naming table[index].field."""
    for key in ("width_mm", "height_mm"):
        value = getattr(layout, key)
        if not (_finite_positive(value) and value <= MAX_CARD_MM):
            raise LayoutError(f"card.{key}: must be a finite number > 0 and at most {MAX_CARD_MM:g} mm, got {value!r}")
    if layout.dictionary not in DICTIONARIES:
        raise LayoutError(
            f"card.dictionary: unknown ArUco dictionary {layout.dictionary!r}; "
            f"expected one of {', '.join(DICTIONARIES)}"
        )
    n_ids = _dictionary(layout.dictionary).bytesList.shape[0]
    quiet = layout.quiet_zone_fraction()
    if len(layout.markers) < 3:
        raise LayoutError(
            f"marker: at least 3 markers are needed (4, at the card's corners, are best); got {len(layout.markers)}"
        )
    seen_ids: dict[int, int] = {}
    for i, marker in enumerate(layout.markers):
        where = f"marker[{i}]"
        if not 0 <= marker.id < n_ids:
            raise LayoutError(f"{where}.id: {marker.id} is not an id of {layout.dictionary} (0 to {n_ids - 1})")
        if marker.id in seen_ids:
            raise LayoutError(f"{where}.id: duplicate id {marker.id} (also marker[{seen_ids[marker.id]}])")
        seen_ids[marker.id] = i
        for key in ("x_mm", "y_mm"):
            if not math.isfinite(getattr(marker, key)):
                raise LayoutError(f"{where}.{key}: must be a finite number, got {getattr(marker, key)!r}")
        if not _finite_positive(marker.size_mm):
            raise LayoutError(f"{where}.size_mm: must be a finite number > 0, got {marker.size_mm!r}")
        box = _keep_out(marker, quiet)
        if box[0] < 0 or box[1] < 0 or box[2] > layout.width_mm or box[3] > layout.height_mm:
            raise LayoutError(
                f"{where} (id {marker.id}).x_mm, y_mm, size_mm: the marker and its {marker.size_mm * quiet:g} mm quiet "
                f"zone ({box[0]:g}-{box[2]:g} x {box[1]:g}-{box[3]:g} mm) must lie on the "
                f"{layout.width_mm:g} x {layout.height_mm:g} mm card"
            )
        for j, other in enumerate(layout.markers[:i]):
            if _overlap(box, _keep_out(other, 0.0)) or _overlap(_keep_out(marker, 0.0), _keep_out(other, quiet)):
                raise LayoutError(
                    f"{where} (id {marker.id}).x_mm, y_mm: overlaps marker[{j}] (id {other.id}) or its quiet zone"
                )
    for i, area in enumerate(layout.printed):
        _check_rectangle(area, f"printed[{i}]", layout)
        if not (math.isfinite(area.gray) and 0.0 <= area.gray <= 1.0):
            raise LayoutError(
                f"printed[{i}].gray: must be a number from 0 (black) to 1 (paper white), got {area.gray!r}"
            )
        for j, marker in enumerate(layout.markers):
            if _overlap(_box(area), _keep_out(marker, quiet)):
                raise LayoutError(
                    f"printed[{i}].x_mm, y_mm, w_mm, h_mm: overlaps marker[{j}] (id {marker.id}) or its quiet zone"
                )
    seen_names: dict[str, int] = {}
    for i, region in enumerate(layout.regions):
        where = f"region[{i}]"
        if not isinstance(region.name, str) or not _NAME.fullmatch(region.name):
            raise LayoutError(f"{where}.name: {region.name!r} must be letters, digits, '_' or '-' (at least one)")
        if region.name in seen_names:
            raise LayoutError(f"{where}.name: duplicate name {region.name!r} (also region[{seen_names[region.name]}])")
        seen_names[region.name] = i
        where = f"region[{i}] ({region.name!r})"
        if region.role not in ROLES:
            raise LayoutError(f"{where}.role: {region.role!r} is not one of {', '.join(ROLES)}")
        _check_rectangle(region, where, layout)
        for j, marker in enumerate(layout.markers):
            if _overlap(_box(region), _keep_out(marker, quiet, OUTLINE_CLEARANCE_MM)):
                raise LayoutError(
                    f"{where}.x_mm, y_mm, w_mm, h_mm: overlaps marker[{j}] (id {marker.id}), its quiet zone or the "
                    f"{OUTLINE_CLEARANCE_MM:g} mm around it"
                )
        for key, value in region.metadata.items():
            if key in _REGION_KEYS or not isinstance(key, str) or not key:
                raise LayoutError(f"{where}.metadata: {key!r} is not a usable metadata key")
            if not _plain_value(value):
                raise LayoutError(
                    f"{where}.{key}: metadata must be a string, boolean, number or an array of them, got {value!r}"
                )


def _check_rectangle(item: PrintedArea | Region, where: str, layout: Layout) -> None:
    for key in ("x_mm", "y_mm"):
        if not math.isfinite(getattr(item, key)):
            raise LayoutError(f"{where}.{key}: must be a finite number, got {getattr(item, key)!r}")
    smallest = 2 * SAMPLING_MARGIN_MM + 1.0 if isinstance(item, Region) else 0.0
    for key in ("w_mm", "h_mm"):
        value = getattr(item, key)
        if not (_finite_positive(value) and value >= smallest):
            least = f"at least {smallest:g} mm (sampled {SAMPLING_MARGIN_MM:g} mm inside its edges)" if smallest else (
                "> 0")  # fmt: skip
            raise LayoutError(f"{where}.{key}: must be a finite number {least}, got {value!r}")
    x0, y0, x1, y1 = _box(item)
    if x0 < 0 or x1 > layout.width_mm:
        raise LayoutError(f"{where}.x_mm, w_mm: {x0:g}-{x1:g} mm lies outside the card (0-{layout.width_mm:g} mm)")
    if y0 < 0 or y1 > layout.height_mm:
        raise LayoutError(f"{where}.y_mm, h_mm: {y0:g}-{y1:g} mm lies outside the card (0-{layout.height_mm:g} mm)")


def _plain_value(value: Any) -> bool:
    if isinstance(value, list | tuple):
        return all(isinstance(v, str | bool | int | float) for v in value)
    return isinstance(value, str | bool | int | float)


# ---------------------------------------------------------------------------------------------------------------
# TOML I/O


def load_layout(path: str | os.PathLike) -> Layout:
    """Read a card layout from a TOML file (``docs/formats.md``, "Drawdown card layout").

    Raises :class:`LayoutError` naming the file, the table and index (from 0) and the field for every broken rule:
    unreadable or invalid TOML, unknown tables or keys, missing keys, wrong types, an unknown dictionary, fewer than
    3 markers, duplicate marker ids or region names, a marker, printed area or region outside the card, and regions
    or printed areas overlapping a marker's quiet zone.
    """
    path = Path(path)
    try:
        data = tomllib.loads(_read_layout_text(path))
    except OSError as error:
        raise LayoutError(f"{path}: cannot read the layout ({error.strerror or error})") from None
    except UnicodeDecodeError as error:
        raise LayoutError(f"{path}: not UTF-8 text ({error.reason} at byte {error.start})") from None
    except tomllib.TOMLDecodeError as error:
        raise LayoutError(f"{path}: not valid TOML ({error})") from None
    except RecursionError:
        raise LayoutError(f"{path}: not a layout: its arrays or tables are nested too deeply") from None
    try:
        return _layout_from_dict(data)
    except LayoutError as error:
        raise LayoutError(f"{path}: {error}") from None


def _read_layout_text(path: Path) -> str:
    """The text of a layout file: a regular file (never a device or a FIFO) of at most MAX_LAYOUT_BYTES bytes."""
    try:
        return read_regular(path, MAX_LAYOUT_BYTES).decode("utf-8-sig")
    except NotReadable as error:
        raise LayoutError(f"{error}; expected a layout TOML file") from None


def _layout_from_dict(data: dict[str, Any]) -> Layout:
    unknown = sorted(set(data) - set(_TABLES))
    if unknown:
        raise LayoutError(f"unknown table or key {unknown[0]!r}; expected {', '.join(_TABLES)}")
    card = data.get("card")
    if not isinstance(card, dict):
        raise LayoutError("card: a [card] table is required")
    _no_unknown_keys(card, "card", _CARD_KEYS)
    dictionary = _require(card, "card", "dictionary", str)
    markers = [
        Marker(
            id=_require(table, f"marker[{i}]", "id", int),
            x_mm=_number(table, f"marker[{i}]", "x_mm"),
            y_mm=_number(table, f"marker[{i}]", "y_mm"),
            size_mm=_number(table, f"marker[{i}]", "size_mm"),
        )
        for i, table in enumerate(_array_of_tables(data, "marker", _MARKER_KEYS))
    ]
    printed = [
        PrintedArea(*(_number(table, f"printed[{i}]", key) for key in _PRINTED_KEYS))
        for i, table in enumerate(_array_of_tables(data, "printed", _PRINTED_KEYS))
    ]
    regions = [
        Region(
            name=_require(table, f"region[{i}]", "name", str),
            role=_require(table, f"region[{i}]", "role", str),
            x_mm=_number(table, f"region[{i}]", "x_mm"),
            y_mm=_number(table, f"region[{i}]", "y_mm"),
            w_mm=_number(table, f"region[{i}]", "w_mm"),
            h_mm=_number(table, f"region[{i}]", "h_mm"),
            metadata={key: value for key, value in table.items() if key not in _REGION_KEYS},
        )
        for i, table in enumerate(_array_of_tables(data, "region", None))
    ]
    return Layout(
        width_mm=_number(card, "card", "width_mm"),
        height_mm=_number(card, "card", "height_mm"),
        dictionary=dictionary,
        markers=tuple(markers),
        regions=tuple(regions),
        printed=tuple(printed),
    )


def _array_of_tables(data: dict[str, Any], name: str, keys: tuple[str, ...] | None) -> list[dict[str, Any]]:
    """The tables of ``[[name]]`` (empty if absent), each checked for unknown keys unless ``keys`` is None."""
    tables = data.get(name, [])
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise LayoutError(f"{name}: must be an array of tables, written [[{name}]]")
    if keys is not None:
        for i, table in enumerate(tables):
            _no_unknown_keys(table, f"{name}[{i}]", keys)
    return tables


def _no_unknown_keys(table: dict[str, Any], where: str, keys: tuple[str, ...]) -> None:
    unknown = sorted(set(table) - set(keys))
    if unknown:
        raise LayoutError(f"{where}.{unknown[0]}: unknown key; expected {', '.join(keys)}")


def _require(table: dict[str, Any], where: str, key: str, kind: type) -> Any:
    if key not in table:
        raise LayoutError(f"{where}.{key}: missing (required)")
    value = table[key]
    if not isinstance(value, kind) or isinstance(value, bool):
        raise LayoutError(f"{where}.{key}: must be {'an integer' if kind is int else 'a string'}, got {value!r}")
    return value


def _number(table: dict[str, Any], where: str, key: str) -> float:
    if key not in table:
        raise LayoutError(f"{where}.{key}: missing (required)")
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise LayoutError(f"{where}.{key}: must be a finite number, got {value!r}")
    return float(value)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(int(value))
    if isinstance(value, float):
        return repr(float(value))  # Python's repr of a float (1e-05, inf, nan) is valid TOML
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")  # JSON escapes are TOML escapes
    return "[" + ", ".join(_toml_value(v) for v in value) + "]"


def _toml_key(key: str) -> str:
    return key if _NAME.fullmatch(key) else _toml_value(key)


def layout_to_toml(layout: Layout) -> str:
    """The layout as TOML text, readable by :func:`load_layout` (tables in the order card, marker, printed, region)."""
    lines = [
        "# kmpipe drawdown card layout (docs/formats.md); lengths in mm from the card's top-left corner",
        "[card]",
        f"width_mm = {_toml_value(layout.width_mm)}",
        f"height_mm = {_toml_value(layout.height_mm)}",
        f"dictionary = {_toml_value(layout.dictionary)}",
    ]
    for marker in layout.markers:
        lines += ["", "[[marker]]", *(f"{key} = {_toml_value(getattr(marker, key))}" for key in _MARKER_KEYS)]
    for area in layout.printed:
        lines += ["", "[[printed]]", *(f"{key} = {_toml_value(getattr(area, key))}" for key in _PRINTED_KEYS)]
    for region in layout.regions:
        lines += ["", "[[region]]", *(f"{key} = {_toml_value(getattr(region, key))}" for key in _REGION_KEYS)]
        lines += [f"{_toml_key(key)} = {_toml_value(value)}" for key, value in region.metadata.items()]
    return "\n".join(lines) + "\n"


def write_layout(layout: Layout, path: str | os.PathLike) -> None:
    """Write the layout as TOML to ``path`` (UTF-8), atomically: a temporary file in the same folder, then renamed."""
    text = layout_to_toml(layout).encode("utf-8")
    _atomic_write(Path(path), lambda handle: handle.write(text))


def _atomic_write(path: Path, write: Callable[[IO[bytes]], object]) -> None:
    """Call ``write`` on a new temporary file next to ``path`` (mode 0666 less the umask), fsync it, rename it to
    ``path`` and fsync the folder: readers see the old file or the complete new one, never a partial one."""
    temporary = path.with_name(f".{path.name}.{secrets.token_hex(8)}.tmp")
    descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(descriptor, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)


# ---------------------------------------------------------------------------------------------------------------
# The default card


def default_layout() -> Layout:
    """An A5-landscape card (210 x 148 mm) for one drawdown, with four 16 mm DICT_4X4_50 markers at the corners.

    - Markers 0-3 clockwise from the top-left, 4 mm from the card's edges (quiet zone 2.7 mm).
    - Left: a black stripe (printed, 10-130 x 25-71 mm) over a white stripe (paper, 10-130 x 71-117 mm). The bare
      backings are sampled in ``black`` and ``white`` (role backing, 40 x 30 mm each). The film is drawn down
      across both stripes in a band about 64-128 mm from the left edge (a 60 mm applicator fits), sampled in
      ``film_over_black`` and ``film_over_white`` (role film, metadata ``over``; 52 x 30 mm each).
    - Bottom: ``white_reference`` (40 x 20 mm of paper, role white_reference) with ``reflectance = 0.9``, typical
      of a matte printing paper; replace it by the value measured on the card stock.
    - Right: an optional ``colorchecker`` slot (role colorchecker, metadata ``optional = true``) of 66 x 96 mm,
      portrait: it takes an X-Rite ColorChecker Classic Mini (57 x 83 mm, 2.25 x 3.25 in) with room to place it by
      hand. A ColorChecker Passport (125 x 90 mm closed) does not fit beside the stripes on A5: photograph it next
      to the card, or use a larger layout.

    Every region keeps at least 6 mm from the edges of its stripe, so the default sampling margin (2 mm) and a
    slightly misplaced drawdown stay clear of the stripe edges.
    """
    markers = (
        Marker(0, 4.0, 4.0, 16.0),
        Marker(1, 190.0, 4.0, 16.0),
        Marker(2, 190.0, 128.0, 16.0),
        Marker(3, 4.0, 128.0, 16.0),
    )
    printed = (PrintedArea(10.0, 25.0, 120.0, 46.0, 0.0), PrintedArea(10.0, 71.0, 120.0, 46.0, 1.0))
    regions = (
        Region("black", "backing", 16.0, 33.0, 40.0, 30.0),
        Region("white", "backing", 16.0, 79.0, 40.0, 30.0),
        Region("film_over_black", "film", 70.0, 33.0, 52.0, 30.0, {"over": "black"}),
        Region("film_over_white", "film", 70.0, 79.0, 52.0, 30.0, {"over": "white"}),
        Region(
            "white_reference",
            "white_reference",
            30.0,
            122.0,
            40.0,
            20.0,
            {
                "reflectance": 0.9,
                "note": "typical matte printing paper; replace by the reflectance measured on this card stock",
            },
        ),
        Region(
            "colorchecker",
            "colorchecker",
            136.0,
            26.0,
            66.0,
            96.0,
            {"optional": True, "chart": "X-Rite ColorChecker Classic Mini (57 x 83 mm)"},
        ),
    )
    return Layout(210.0, 148.0, "DICT_4X4_50", markers, regions, printed)


# ---------------------------------------------------------------------------------------------------------------
# Rendering and printing


def render_card(
    layout: Layout, px_per_mm: float = 10.0, *, region_colors: Mapping[str, Any] | None = None
) -> np.ndarray:
    """The printable card as an 8-bit RGB image (H, W, 3), H = round(height_mm * px_per_mm) px.

    White paper; printed areas in their grey; regions filled with ``region_colors[name]`` (RGB, floats 0-1,
    rounded to 8 bits) where given; a thin grey outline around each region, 0.4 mm outside it, and the region's name
    above it (below it when there is no room above; left out when neither fits), so that nothing printed enters a
    sampled area; the markers (``cv2.aruco.generateImageMarker``, 1-bit border) on their white quiet zone. Edges
    fall on the nearest pixel boundary (mm * px_per_mm, rounded).
    """
    if not (math.isfinite(px_per_mm) and px_per_mm > 0):
        raise ValueError(f"px_per_mm must be a finite number > 0, got {px_per_mm!r}")
    if round(layout.width_mm * px_per_mm) * round(layout.height_mm * px_per_mm) > MAX_CARD_PIXELS:
        raise ValueError(
            f"a {layout.width_mm:g} x {layout.height_mm:g} mm card at {px_per_mm:g} px/mm exceeds {MAX_CARD_PIXELS} "
            "pixels"
        )
    colors = dict(region_colors or {})
    unknown = sorted(set(colors) - {r.name for r in layout.regions})
    if unknown:
        raise ValueError(f"region_colors names unknown regions {unknown}")

    def px(mm: float) -> int:
        return round(mm * px_per_mm)

    image = np.full((px(layout.height_mm), px(layout.width_mm), 3), 255, dtype=np.uint8)
    for area in layout.printed:
        _fill(
            image,
            px(area.x_mm),
            px(area.y_mm),
            px(area.x_mm + area.w_mm),
            px(area.y_mm + area.h_mm),
            round(area.gray * 255),
        )
    for name, rgb in colors.items():
        rgb = np.asarray(rgb, dtype=np.float64)
        if rgb.shape != (3,) or not np.all((rgb >= 0) & (rgb <= 1)):
            raise ValueError(f"region_colors[{name!r}] must be 3 numbers from 0 to 1, got {rgb.tolist()}")
        region = layout.region(name)
        value = np.round(rgb * 255).astype(np.uint8)
        _fill(
            image, px(region.x_mm), px(region.y_mm), px(region.x_mm + region.w_mm), px(region.y_mm + region.h_mm), value
        )

    gap = max(1, px(_OUTLINE_GAP_MM))
    width = max(1, px(_OUTLINE_WIDTH_MM))
    outer = gap + width
    boxes = [
        (px(r.x_mm) - outer, px(r.y_mm) - outer, px(r.x_mm + r.w_mm) + outer, px(r.y_mm + r.h_mm) + outer)
        for r in layout.regions
    ]
    quiet = layout.quiet_zone_fraction()
    keep_out = [tuple(px(v) for v in _keep_out(m, quiet)) for m in layout.markers]
    for x0, y0, x1, y1 in boxes:
        for band in (
            (x0, y0, x1, y0 + width),
            (x0, y1 - width, x1, y1),
            (x0, y0, x0 + width, y1),
            (x1 - width, y0, x1, y1),
        ):
            _fill(image, *band, _GRAY_OUTLINE)

    font = cv2.FONT_HERSHEY_SIMPLEX
    (_, unit_height), _ = cv2.getTextSize("Ag", font, 1.0, 1)
    scale = _LABEL_HEIGHT_MM * px_per_mm / unit_height
    thickness = max(1, px(_OUTLINE_WIDTH_MM))
    for region, box in zip(layout.regions, boxes, strict=True):
        (text_w, text_h), baseline = cv2.getTextSize(region.name, font, scale, thickness)
        pad = gap + thickness
        above = box[1] - pad - baseline
        below = box[3] + pad + text_h
        for y_base in (above, below):
            label = (box[0] - pad, y_base - text_h - pad, box[0] + text_w + pad, y_base + baseline + pad)
            inside = label[0] >= 0 and label[1] >= 0 and label[2] <= image.shape[1] and label[3] <= image.shape[0]
            if inside and not any(_overlap(label, other) for other in [*boxes, *keep_out]):
                cv2.putText(
                    image, region.name, (box[0], y_base), font, scale, (_GRAY_OUTLINE,) * 3, thickness, cv2.LINE_AA
                )
                break

    dictionary = _dictionary(layout.dictionary)
    for marker in layout.markers:
        x0, y0 = px(marker.x_mm), px(marker.y_mm)
        x1, y1 = px(marker.x_mm + marker.size_mm), px(marker.y_mm + marker.size_mm)
        square = cv2.aruco.generateImageMarker(dictionary, marker.id, x1 - x0, borderBits=1)
        if y1 - y0 != x1 - x0:
            square = cv2.resize(square, (x1 - x0, y1 - y0), interpolation=cv2.INTER_NEAREST)
        image[y0:y1, x0:x1] = square[..., None]
    return image


def _fill(image: np.ndarray, x0: int, y0: int, x1: int, y1: int, value: Any) -> None:
    """Paint pixels x0 <= column < x1, y0 <= row < y1 (clipped to the image)."""
    image[max(0, y0) : max(0, y1), max(0, x0) : max(0, x1)] = value


def write_card(layout: Layout, path: str | os.PathLike) -> None:
    """Write the printable card at 300 dpi, as PNG or PDF by the suffix of ``path``, atomically.

    PNG: round(width_mm / 25.4 * 300) x round(height_mm / 25.4 * 300) px, with a pHYs chunk saying 300 dpi so that
    it prints at size. PDF: one page of exactly the card's size (width_mm / 25.4 * 72 pt), the image placed
    unresampled. Print at 100 % ("actual size"); writing the layout's TOML next to it is the caller's job.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".png", ".pdf"):
        raise ValueError(f"{path}: the card is written as .png or .pdf, not {path.suffix or 'no suffix'!r}")
    image = render_card(layout, PRINT_DPI / 25.4)
    if suffix == ".png":
        ok, encoded = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        if not ok:
            raise OSError(f"{path}: OpenCV could not encode the PNG")
        data = _with_png_dpi(encoded.tobytes(), PRINT_DPI)
        _atomic_write(path, lambda handle: handle.write(data))
    else:
        from matplotlib.figure import Figure

        figure = Figure(figsize=(layout.width_mm / 25.4, layout.height_mm / 25.4), dpi=PRINT_DPI)
        axes = figure.add_axes((0.0, 0.0, 1.0, 1.0))
        axes.set_axis_off()
        axes.imshow(image, interpolation="none", aspect="auto")
        _atomic_write(
            path, lambda handle: figure.savefig(handle, format="pdf", dpi=PRINT_DPI, metadata={"CreationDate": None})
        )


def _with_png_dpi(png: bytes, dpi: float) -> bytes:
    """Insert a pHYs chunk (pixels per metre) after a PNG's first chunk, IHDR, as the PNG specification asks."""
    ihdr_end = 8 + 12 + struct.unpack(">I", png[8:12])[0]  # signature, then length, type, data and CRC of IHDR
    per_metre = round(dpi / 0.0254)
    body = b"pHYs" + struct.pack(">IIB", per_metre, per_metre, 1)
    chunk = struct.pack(">I", len(body) - 4) + body + struct.pack(">I", zlib.crc32(body))
    return png[:ihdr_end] + chunk + png[ihdr_end:]


# ---------------------------------------------------------------------------------------------------------------
# Locating the card in a photo


@dataclass(frozen=True, eq=False)
class CardLocation:
    """Where the card lies in a photo.

    ``homography`` (3, 3) maps card mm to image px (OpenCV pixel-centre convention), normalised so that
    ``homography[2, 2] == 1``. ``found_ids`` and ``missing_ids`` are the layout's marker ids seen once and not seen
    (sorted); ``duplicate_ids`` layout ids seen more than once (left out of the fit: another card in view?).
    ``reprojection_error_px`` is the RMS distance (px) between the detected marker corners and the layout's
    corners mapped by the homography, over all corners used (RANSAC outliers included, so a bad marker shows).
    """

    homography: np.ndarray
    found_ids: tuple[int, ...]
    missing_ids: tuple[int, ...]
    duplicate_ids: tuple[int, ...]
    reprojection_error_px: float

    def card_to_image(self, points_mm: Any) -> np.ndarray:
        """Map card points (..., 2) in mm to image points (..., 2) in px."""
        points = np.asarray(points_mm, dtype=np.float64)
        mapped = cv2.perspectiveTransform(points.reshape(-1, 1, 2), self.homography)
        return mapped.reshape(points.shape)


def locate_card(image: np.ndarray, layout: Layout) -> CardLocation:
    """Find the card in an 8-bit photo (gray (H, W) or RGB (H, W, 3)): detect markers, fit card mm -> image px.

    Pass a tone-mapped 8-bit copy of the linear photo. Markers are detected with ``cv2.aruco.ArucoDetector`` (the
    layout's dictionary, sub-pixel corner refinement); ids not in the layout are ignored. The homography is fitted
    by ``cv2.findHomography`` (RANSAC, 3 px threshold, then refined on the inliers) to all 4 corners of every marker
    found. Raises :class:`CardNotFound` when fewer than 2 of the layout's markers are found (8 corners: the least
    that fixes a homography).
    """
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise ValueError(f"locate_card needs an 8-bit image (a tone-mapped copy of the photo), got {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 3:
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    elif image.ndim == 2:
        gray = image
    else:
        raise ValueError(f"locate_card needs a gray (H, W) or RGB (H, W, 3) image, got shape {image.shape}")

    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(_dictionary(layout.dictionary), parameters)
    corners, ids, _ = detector.detectMarkers(gray)
    detected: dict[int, list[np.ndarray]] = {}
    for marker_corners, marker_id in zip(corners, [] if ids is None else ids.ravel(), strict=True):
        detected.setdefault(int(marker_id), []).append(marker_corners.reshape(4, 2))

    expected = sorted(m.id for m in layout.markers)
    by_id = {m.id: m for m in layout.markers}
    found = sorted(i for i in expected if len(detected.get(i, [])) == 1)
    duplicates = sorted(i for i in expected if len(detected.get(i, [])) > 1)
    missing = sorted(set(expected) - set(found) - set(duplicates))
    if len(found) < 2:
        strangers = sorted(set(detected) - set(expected))
        raise CardNotFound(
            f"card not found: {len(found)} of the layout's markers found (ids {found}); missing ids {missing}"
            + (f"; seen more than once (ambiguous) ids {duplicates}" if duplicates else "")
            + (f"; ids not in the layout ignored {strangers}" if strangers else "")
            + f". The layout expects {layout.dictionary} markers with ids {expected}; at least 2 must be visible"
        )
    card_mm = np.concatenate([by_id[i].corners_mm() for i in found])
    image_px = np.concatenate([detected[i][0] for i in found]).astype(np.float64)
    homography, _ = cv2.findHomography(card_mm, image_px, cv2.RANSAC, RANSAC_THRESHOLD_PX)
    if homography is None:
        raise CardNotFound(f"card not found: markers {found} were found but no homography fits their corners")
    homography = homography / homography[2, 2]
    projected = cv2.perspectiveTransform(card_mm.reshape(-1, 1, 2), homography).reshape(-1, 2)
    rms = float(np.sqrt(np.mean(np.sum((projected - image_px) ** 2, axis=1))))
    return CardLocation(homography, tuple(found), tuple(missing), tuple(duplicates), rms)


# ---------------------------------------------------------------------------------------------------------------
# Sampling a region of the linear photo


@dataclass(frozen=True, eq=False)
class RegionSample:
    """Statistics of one region of a linear photo (:func:`sample_region`, :func:`sample_pixels`), per channel (C,).

    ``mean``: trimmed mean; ``std``: standard deviation of all samples (ddof 1); ``count``: number of samples;
    ``masked_fraction``: fraction of samples whose nearest pixel is flagged in the mask (0 without a mask);
    ``uniformity``: (largest - smallest mean of the four quadrants) / |trimmed mean| (0 for a uniform region;
    inf when the mean is 0 and the quadrants differ); ``polygon_px`` (4, 2): corners of the sampled area in the
    image (px), clockwise from the region's top-left.
    """

    name: str
    mean: np.ndarray
    std: np.ndarray
    count: int
    masked_fraction: float
    uniformity: np.ndarray
    polygon_px: np.ndarray


def sample_region(
    linear_image: np.ndarray,
    location: CardLocation,
    region: Region,
    *,
    px_per_mm: float | None = None,
    margin_mm: float = SAMPLING_MARGIN_MM,
    trim: float = 0.1,
    mask: np.ndarray | None = None,
) -> RegionSample:
    """Measure a region of a linear photo (H, W, C) or (H, W), any channel count and numeric dtype.

    The region, shrunk by ``margin_mm`` on each side (away from its printed edges and a misplaced film), is
    sampled on a regular grid of points in card mm, ``px_per_mm`` points per mm (default: the photo's own
    resolution there, the square root of the sampled area in px² over its area in mm², so about one sample per
    pixel). Each point is mapped through ``location.homography`` and read with bilinear interpolation
    (``cv2.remap``). The mean drops the ``trim`` fraction of the lowest and of the highest values of each channel.
    ``mask`` is an optional boolean (H, W) image of flagged pixels (e.g. saturated): it is only counted (read at the
    nearest pixel), never used to drop samples. Raises ValueError if the sampled area leaves the photo.
    """
    image = np.asarray(linear_image)
    if image.ndim == 2:
        image = image[..., None]
    if image.ndim != 3:
        raise ValueError(f"linear_image must be (H, W) or (H, W, C), got shape {image.shape}")
    if not 0 <= trim < 0.5:
        raise ValueError(f"trim must be at least 0 and below 0.5, got {trim!r}")
    if not (math.isfinite(margin_mm) and margin_mm >= 0):
        raise ValueError(f"margin_mm must be a finite number >= 0, got {margin_mm!r}")
    if mask is not None and np.shape(mask) != image.shape[:2]:
        raise ValueError(f"mask has shape {np.shape(mask)}; the image is {image.shape[:2]}")
    x0, y0 = region.x_mm + margin_mm, region.y_mm + margin_mm
    w, h = region.w_mm - 2 * margin_mm, region.h_mm - 2 * margin_mm
    if w <= 0 or h <= 0:
        raise ValueError(
            f"region {region.name!r} ({region.w_mm:g} x {region.h_mm:g} mm) is empty after a {margin_mm:g} mm margin"
        )

    polygon = location.card_to_image([[x0, y0], [x0 + w, y0], [x0 + w, y0 + h], [x0, y0 + h]])
    if px_per_mm is None:
        px_per_mm = math.sqrt(cv2.contourArea(polygon.astype(np.float32)) / (w * h))
    if not (math.isfinite(px_per_mm) and px_per_mm > 0):
        raise ValueError(f"px_per_mm must be a finite number > 0, got {px_per_mm!r}")
    nx, ny = max(2, round(w * px_per_mm)), max(2, round(h * px_per_mm))
    grid_x = x0 + (np.arange(nx) + 0.5) * (w / nx)
    grid_y = y0 + (np.arange(ny) + 0.5) * (h / ny)
    points = location.card_to_image(np.stack(np.meshgrid(grid_x, grid_y), axis=-1))  # (ny, nx, 2) px

    height, width = image.shape[:2]
    low, high = np.floor(points.min(axis=(0, 1))).astype(int), np.ceil(points.max(axis=(0, 1))).astype(int)
    if low[0] < 0 or low[1] < 0 or high[0] > width - 1 or high[1] > height - 1:
        raise ValueError(f"region {region.name!r} is not entirely inside the photo (samples span {low}-{high} px)")
    crop = np.ascontiguousarray(image[low[1] : high[1] + 1, low[0] : high[0] + 1], dtype=np.float64)
    map_x = (points[..., 0] - low[0]).astype(np.float32)
    map_y = (points[..., 1] - low[1]).astype(np.float32)
    values = cv2.remap(crop, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    values = values.reshape(ny, nx, image.shape[2])

    flagged = None
    if mask is not None:
        nearest = np.rint(points).astype(int)
        flagged = np.asarray(mask, dtype=bool)[nearest[..., 1], nearest[..., 0]]
    return _statistics(region.name, values, flagged, trim, polygon)


def sample_pixels(
    pixels: np.ndarray, mask: np.ndarray | None = None, *, trim: float = 0.1, name: str = ""
) -> RegionSample:
    """The statistics of :func:`sample_region` for a block of pixels (h, w, C) or (h, w) taken as it is.

    For a rectangle of an image cut out by the caller (e.g. a region given in px for a photo without markers);
    ``mask`` is an optional boolean (h, w) block of flagged pixels. ``polygon_px`` is the block's outline in its own
    pixel coordinates, (-0.5, -0.5) to (w - 0.5, h - 0.5).
    """
    values = np.asarray(pixels, dtype=np.float64)
    if values.ndim == 2:
        values = values[..., None]
    if values.ndim != 3 or values.shape[0] < 2 or values.shape[1] < 2:
        raise ValueError(f"pixels must be (h, w) or (h, w, C) with h, w >= 2, got shape {np.shape(pixels)}")
    if not 0 <= trim < 0.5:
        raise ValueError(f"trim must be at least 0 and below 0.5, got {trim!r}")
    if mask is not None and np.shape(mask) != values.shape[:2]:
        raise ValueError(f"mask has shape {np.shape(mask)}; the pixels are {values.shape[:2]}")
    h, w = values.shape[:2]
    outline = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    return _statistics(name, values, None if mask is None else np.asarray(mask, dtype=bool), trim, outline)


def _statistics(
    name: str, values: np.ndarray, flagged: np.ndarray | None, trim: float, polygon_px: np.ndarray
) -> RegionSample:
    """Trimmed mean, standard deviation, masked fraction and quadrant uniformity of a grid of samples (ny, nx, C)."""
    ny, nx, channels = values.shape
    flat = np.sort(values.reshape(-1, channels), axis=0)
    cut = int(trim * flat.shape[0])
    mean = flat[cut : flat.shape[0] - cut].mean(axis=0)
    std = flat.std(axis=0, ddof=1)
    half_y, half_x = ny // 2, nx // 2  # with an odd count, the middle row or column belongs to no quadrant
    quadrants = np.stack(
        [
            values[:half_y, :half_x].mean(axis=(0, 1)),
            values[:half_y, nx - half_x :].mean(axis=(0, 1)),
            values[ny - half_y :, :half_x].mean(axis=(0, 1)),
            values[ny - half_y :, nx - half_x :].mean(axis=(0, 1)),
        ]
    )
    spread = quadrants.max(axis=0) - quadrants.min(axis=0)
    uniformity = np.divide(spread, np.abs(mean), out=np.where(spread > 0, np.inf, 0.0), where=mean != 0)
    masked = 0.0 if flagged is None else float(flagged.mean())
    return RegionSample(name, mean, std, nx * ny, masked, uniformity, polygon_px)


# ---------------------------------------------------------------------------------------------------------------
# Illumination across the card


def paper_illumination(
    linear_image: np.ndarray,
    location: CardLocation,
    layout: Layout,
    *,
    keep_out_mm: float = 7.0,
    cell_mm: float = 8.0,
) -> Callable[[Any], np.ndarray]:
    """Light falling on the card (vignetting, uneven lighting), estimated from its bare paper; returns a function
    mapping card points (..., 2) in mm to the paper's reading there, per channel (..., C).

    The paper is read on a 1 mm grid wherever it is bare: away from regions, printed areas and markers by
    ``keep_out_mm`` (outlines, labels and quiet zones), and inside the photo. Medians over ``cell_mm`` cells (robust
    to printed text) are fitted per channel with a quadratic surface in the photo's (x, y) by least squares (lens
    vignetting, 1 - v r^2, is quadratic there, not in card coordinates once the card is seen in perspective),
    refitted once without cells more than 3 median absolute deviations off. Dividing a region's reading by the
    surface at its centre, and the white reference's likewise, removes the light's fall-off between them. Raises
    ValueError when fewer than 12 cells of bare paper are visible.
    """
    image = np.asarray(linear_image, dtype=np.float64)
    if image.ndim == 2:
        image = image[..., None]
    blocked = [(r.x_mm, r.y_mm, r.w_mm, r.h_mm) for r in layout.regions]
    blocked += [(p.x_mm, p.y_mm, p.w_mm, p.h_mm) for p in layout.printed]
    blocked += [(m.x_mm, m.y_mm, m.size_mm, m.size_mm) for m in layout.markers]
    xs = np.arange(0.5, layout.width_mm, 1.0)
    ys = np.arange(0.5, layout.height_mm, 1.0)
    gx, gy = np.meshgrid(xs, ys)
    free = (gx > keep_out_mm / 2) & (gx < layout.width_mm - keep_out_mm / 2)
    free &= (gy > keep_out_mm / 2) & (gy < layout.height_mm - keep_out_mm / 2)
    for x, y, w, h in blocked:
        free &= ~(
            (gx > x - keep_out_mm) & (gx < x + w + keep_out_mm) & (gy > y - keep_out_mm) & (gy < y + h + keep_out_mm)
        )
    points_mm = np.stack([gx[free], gy[free]], axis=-1)
    pixels = location.card_to_image(points_mm)
    height, width = image.shape[:2]
    inside = (pixels[:, 0] >= 0) & (pixels[:, 0] <= width - 1) & (pixels[:, 1] >= 0) & (pixels[:, 1] <= height - 1)
    points_mm, pixels = points_mm[inside], pixels[inside]
    values = (
        cv2.remap(
            image.astype(np.float32),
            pixels[:, 0].astype(np.float32).reshape(-1, 1),
            pixels[:, 1].astype(np.float32).reshape(-1, 1),
            cv2.INTER_LINEAR,
        )
        .reshape(len(pixels), image.shape[2])
        .astype(np.float64)
    )

    cells = np.floor(points_mm / cell_mm).astype(int)
    keys, inverse = np.unique(cells, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    if len(keys) < 12:
        raise ValueError(f"only {len(keys)} cells of bare paper are visible: cannot estimate the light across the card")
    centres = np.array([pixels[inverse == k].mean(axis=0) for k in range(len(keys))])
    medians = np.array([np.median(values[inverse == k], axis=0) for k in range(len(keys))])

    def design(points_px: np.ndarray) -> np.ndarray:
        x = (points_px[..., 0] - width / 2) / width
        y = (points_px[..., 1] - height / 2) / height
        return np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=-1)

    A = design(centres)
    coefficients = np.linalg.lstsq(A, medians, rcond=None)[0]
    residuals = medians - A @ coefficients
    mad = np.median(np.abs(residuals - np.median(residuals, axis=0)), axis=0)
    keep = np.all(np.abs(residuals) <= 3.0 * np.maximum(mad, 1e-12) + 1e-12, axis=1)
    if keep.sum() >= 12:
        coefficients = np.linalg.lstsq(A[keep], medians[keep], rcond=None)[0]

    def light(points_mm: Any) -> np.ndarray:
        return design(location.card_to_image(points_mm)) @ coefficients

    return light
