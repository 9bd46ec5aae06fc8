"""The drawdown card's layout: its size, ArUco markers, printed areas and regions, and the rules they keep.

:class:`Layout` checks every rule of ``docs/formats.md`` ("Drawdown card layout") on construction, for a layout
built in code as for one read from a file (``kmpipe.formats.card_layout``), and raises :class:`LayoutError` naming
the table, the entry (counted from 1, in file order) and the key. :func:`default_layout` is the bundled A5 card.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import cv2
import numpy as np

ROLES = ("backing", "film", "white_reference", "colorchecker")
"""Region roles: labels for the caller, not interpreted here."""

DICTIONARIES = tuple(sorted(name for name in dir(cv2.aruco) if name.startswith("DICT_")))
"""Names of OpenCV's predefined ArUco and AprilTag dictionaries, as accepted in ``card.dictionary``."""

MAX_CARD_MM = 500.0
"""Longest side of a card (mm), checked when a layout is made: larger than any drawdown card a printer takes."""

OUTLINE_CLEARANCE_MM = 1.0
"""Extra distance (mm) a region keeps from a marker's quiet zone: room for the region's printed outline."""


#: How far inside its edges a region is sampled (mm): away from the drawdown's edges and the print's bleed.
SAMPLING_MARGIN_MM = 2.0
REGION_KEYS = ("name", "role", "x_mm", "y_mm", "w_mm", "h_mm")
"""The keys of a region; any other key of a region's table is metadata."""
_NAME = re.compile(r"[A-Za-z0-9_-]+")


class LayoutError(ValueError):
    """A card layout breaks a rule.

    ``loc`` is where: the table, the entry's index (from 0) and the key, e.g. ``("region", 4, "x_mm")`` or
    ``("marker",)``; ``message`` what is wrong. ``str()`` gives both, counting entries from 1 as every kmpipe
    message does: ``region[5].x_mm: ...``.
    """

    def __init__(self, message: str, loc: tuple[str | int, ...]) -> None:
        self.message, self.loc = message, tuple(loc)
        where = "".join(f"[{part + 1}]" if isinstance(part, int) else f".{part}" for part in self.loc).lstrip(".")
        super().__init__(f"{where}: {message}")


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
    the entry and the key.
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
        return 1.0 / (aruco_dictionary(self.dictionary).markerSize + 2)


def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """OpenCV's predefined marker dictionary called ``name`` (one of :data:`DICTIONARIES`)."""
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def overlap(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> bool:
    """Whether two boxes (x0, y0, x1, y1) share interior points (touching edges do not overlap)."""
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def keep_out(marker: Marker, quiet: float, extra_mm: float = 0.0) -> tuple[float, float, float, float]:
    """Box (x0, y0, x1, y1) in mm of a marker's square grown by its quiet zone (``quiet`` per mm of side) and
    ``extra_mm``."""
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
    """Raise :class:`LayoutError` for the first broken rule."""
    for key in ("width_mm", "height_mm"):
        value = getattr(layout, key)
        if not (_finite_positive(value) and value <= MAX_CARD_MM):
            raise LayoutError(
                f"must be a finite number > 0 and at most {MAX_CARD_MM:g} mm, got {value!r}", ("card", key)
            )
    if layout.dictionary not in DICTIONARIES:
        raise LayoutError(
            f"unknown ArUco dictionary {layout.dictionary!r}; expected one of {', '.join(DICTIONARIES)}",
            ("card", "dictionary"),
        )
    n_ids = aruco_dictionary(layout.dictionary).bytesList.shape[0]
    quiet = layout.quiet_zone_fraction()
    if len(layout.markers) < 3:
        raise LayoutError(
            f"at least 3 markers are needed (4, at the card's corners, are best); got {len(layout.markers)}",
            ("marker",),
        )
    seen_ids: dict[int, int] = {}
    for i, marker in enumerate(layout.markers):
        if not 0 <= marker.id < n_ids:
            raise LayoutError(
                f"{marker.id} is not an id of {layout.dictionary} (0 to {n_ids - 1})", ("marker", i, "id")
            )
        if marker.id in seen_ids:
            raise LayoutError(f"duplicate id {marker.id} (also marker[{seen_ids[marker.id] + 1}])", ("marker", i, "id"))
        seen_ids[marker.id] = i
        for key in ("x_mm", "y_mm"):
            if not math.isfinite(getattr(marker, key)):
                raise LayoutError(f"must be a finite number, got {getattr(marker, key)!r}", ("marker", i, key))
        if not _finite_positive(marker.size_mm):
            raise LayoutError(f"must be a finite number > 0, got {marker.size_mm!r}", ("marker", i, "size_mm"))
        box = keep_out(marker, quiet)
        if box[0] < 0 or box[1] < 0 or box[2] > layout.width_mm or box[3] > layout.height_mm:
            raise LayoutError(
                f"marker id {marker.id} (x_mm, y_mm, size_mm) and its {marker.size_mm * quiet:g} mm quiet zone "
                f"({box[0]:g}-{box[2]:g} x {box[1]:g}-{box[3]:g} mm) must lie on the "
                f"{layout.width_mm:g} x {layout.height_mm:g} mm card",
                ("marker", i, "x_mm"),
            )
        for j, other in enumerate(layout.markers[:i]):
            if overlap(box, keep_out(other, 0.0)) or overlap(keep_out(marker, 0.0), keep_out(other, quiet)):
                raise LayoutError(
                    f"marker id {marker.id} (x_mm, y_mm) overlaps marker[{j + 1}] (id {other.id}) or its quiet zone",
                    ("marker", i, "x_mm"),
                )
    for i, area in enumerate(layout.printed):
        _check_rectangle(area, ("printed", i), layout)
        if not (math.isfinite(area.gray) and 0.0 <= area.gray <= 1.0):
            raise LayoutError(
                f"must be a number from 0 (black) to 1 (paper white), got {area.gray!r}", ("printed", i, "gray")
            )
        for j, marker in enumerate(layout.markers):
            if overlap(_box(area), keep_out(marker, quiet)):
                raise LayoutError(
                    f"the area (x_mm, y_mm, w_mm, h_mm) overlaps marker[{j + 1}] (id {marker.id}) or its quiet zone",
                    ("printed", i, "x_mm"),
                )
    seen_names: dict[str, int] = {}
    for i, region in enumerate(layout.regions):
        if not isinstance(region.name, str) or not _NAME.fullmatch(region.name):
            raise LayoutError(
                f"{region.name!r} must be letters, digits, '_' or '-' (at least one)", ("region", i, "name")
            )
        if region.name in seen_names:
            raise LayoutError(
                f"duplicate name {region.name!r} (also region[{seen_names[region.name] + 1}])", ("region", i, "name")
            )
        seen_names[region.name] = i
        if region.role not in ROLES:
            raise LayoutError(
                f"region {region.name!r}: {region.role!r} is not one of {', '.join(ROLES)}", ("region", i, "role")
            )
        _check_rectangle(region, ("region", i), layout)
        for j, marker in enumerate(layout.markers):
            if overlap(_box(region), keep_out(marker, quiet, OUTLINE_CLEARANCE_MM)):
                raise LayoutError(
                    f"region {region.name!r} (x_mm, y_mm, w_mm, h_mm) overlaps marker[{j + 1}] (id {marker.id}), its "
                    f"quiet zone or the {OUTLINE_CLEARANCE_MM:g} mm around it",
                    ("region", i, "x_mm"),
                )
        for key, value in region.metadata.items():
            if key in REGION_KEYS or not isinstance(key, str) or not key:
                raise LayoutError(f"region {region.name!r}: {key!r} is not a usable metadata key", ("region", i))
            if not _plain_value(value):
                raise LayoutError(
                    f"region {region.name!r}: metadata must be a string, boolean, number or an array of them, got "
                    f"{value!r}",
                    ("region", i, key),
                )


def _check_rectangle(item: PrintedArea | Region, where: tuple[str, int], layout: Layout) -> None:
    what = f"region {item.name!r}" if isinstance(item, Region) else "the area"
    for key in ("x_mm", "y_mm"):
        if not math.isfinite(getattr(item, key)):
            raise LayoutError(f"must be a finite number, got {getattr(item, key)!r}", (*where, key))
    smallest = 2 * SAMPLING_MARGIN_MM + 1.0 if isinstance(item, Region) else 0.0
    for key in ("w_mm", "h_mm"):
        value = getattr(item, key)
        if not (_finite_positive(value) and value >= smallest):
            least = f"at least {smallest:g} mm (sampled {SAMPLING_MARGIN_MM:g} mm inside its edges)" if smallest else (
                "> 0")  # fmt: skip
            raise LayoutError(f"must be a finite number {least}, got {value!r}", (*where, key))
    x0, y0, x1, y1 = _box(item)
    if x0 < 0 or x1 > layout.width_mm:
        raise LayoutError(
            f"{what} (x_mm, w_mm) at {x0:g}-{x1:g} mm lies outside the card (0-{layout.width_mm:g} mm)",
            (*where, "x_mm"),
        )
    if y0 < 0 or y1 > layout.height_mm:
        raise LayoutError(
            f"{what} (y_mm, h_mm) at {y0:g}-{y1:g} mm lies outside the card (0-{layout.height_mm:g} mm)",
            (*where, "y_mm"),
        )


def _plain_value(value: Any) -> bool:
    if isinstance(value, list | tuple):
        return all(isinstance(v, str | bool | int | float) for v in value)
    return isinstance(value, str | bool | int | float)


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
