"""Cross-polarized RAW photos of a drawdown card to per-channel reflectance: ``kmpipe ingest-raw``.

Each photo is decoded to linear camera RGB (:mod:`instruments.raw_photo`), the card is found by its ArUco
markers and rectified (:mod:`instruments.drawdown_card`), and every region of the layout is sampled away from its
edges with a trimmed mean. Reflectance per channel = region / white reference patch x the patch's reflectance x
``polarization_factor``. The white patch lies in the same photo behind the same crossed polarizers, so both lose
the same half of their diffuse light and the factor is 1; the thesis (section 4.2) doubles picked colours because
it has no such reference: use 2 when the reference value was taken without the analyzer. Several photos of the
same card become repeats, so their spread is the noise floor that ``kmpipe validate`` uses.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from instruments.colorchecker import ColorCheckerNotFound, find_colorchecker, sample_colorchecker_in_slot
from instruments.drawdown_card.flat_field import paper_illumination
from instruments.drawdown_card.layout import Layout, Region
from instruments.drawdown_card.locate import CardNotFound, locate_card
from instruments.drawdown_card.sampling import sample_pixels, sample_region
from instruments.raw_photo import RawPhotoError, read_raw, tone_mapped_8bit
from kmpipe.errors import InputError
from kmpipe.formats.atomic_write import write_text_atomically
from kmpipe.formats.card_layout import load_card_layout
from kmpipe.formats.files import output_folder, refuse_inputs, regular_file, safe_name
from kmpipe.formats.manifest import parse_thickness_mm
from kmpipe.formats.spectra import SpectralTable, write_spectra_csv
from kmpipe.physics.colorimetry import white_XYZ
from kmpipe.physics.colour_correction import fit_camera_to_XYZ

#: Largest fraction of a region's pixels that may be clipped (at the sensor's white level).
MAX_CLIPPED = 0.001
#: A white reference below this (fraction of the white level, brightest channel) is underexposed.
MIN_WHITE_LEVEL = 0.05
#: Largest difference between a region's quadrant means, relative to its mean: above it, uneven light or film.
MAX_NONUNIFORMITY = 0.08
#: Largest standard deviation of a region's pixels relative to their mean: above it, a highlight or a blemish.
MAX_VARIATION = 0.05
CHANNELS = ("R", "G", "B")


@dataclass(frozen=True)
class PhotoRegions:
    """Per-region trimmed-mean linear camera RGB of one photo (light fall-off removed), and its ColorChecker."""

    photo: Path
    camera: str
    values: dict[str, np.ndarray]  # region name -> (3,)
    chart: np.ndarray | None = None  # (24, 3) patch means on the same scale, when a chart was found
    chart_clipped: np.ndarray | None = None  # (24,) fraction of clipped pixels per patch
    chart_method: str = ""


def _find_chart(raw, location, layout: Layout, light):
    """The ColorChecker in the layout's colorchecker slot: cv2.mcc on a display copy, else the slot's geometry.

    Returns (means (24, 3) divided by the light at each patch, clipped fractions, method) or None.
    """
    slots = [r for r in layout.regions if r.role == "colorchecker"]
    if not slots:
        return None
    slot = slots[0]
    grow = 3.0
    corners = [
        [slot.x_mm - grow, slot.y_mm - grow],
        [slot.x_mm + slot.w_mm + grow, slot.y_mm - grow],
        [slot.x_mm + slot.w_mm + grow, slot.y_mm + slot.h_mm + grow],
        [slot.x_mm - grow, slot.y_mm + slot.h_mm + grow],
    ]
    sample = find_colorchecker(
        tone_mapped_8bit(raw.rgb), raw.rgb, search_polygon_px=location.card_to_image(corners), mask=raw.saturated
    )
    if sample is None:
        try:
            sample = sample_colorchecker_in_slot(raw.rgb, location, slot, orientation="auto", mask=raw.saturated)
        except (ColorCheckerNotFound, ValueError):
            return None
    centres_mm = cv2.perspectiveTransform(
        np.asarray(sample.centres_px, dtype=np.float64).reshape(-1, 1, 2), np.linalg.inv(location.homography)
    ).reshape(-1, 2)
    return sample.mean / light(centres_mm), np.asarray(sample.clipped_fraction), sample.method


def _roi_region(text: str) -> Region:
    """NAME=x,y,w,h (pixels of the decoded image) as a Region in 'mm' where 1 mm = 1 pixel."""
    match = re.fullmatch(r"([A-Za-z0-9_-]+)=(\d+),(\d+),(\d+),(\d+)", text.strip())
    if not match:
        raise InputError(f"expected NAME=x,y,w,h in pixels, got {text!r}", field="--roi")
    name, *numbers = match.groups()
    x, y, w, h = (float(v) for v in numbers)
    return Region(name=name, role="", x_mm=x, y_mm=y, w_mm=w, h_mm=h)


def _measure_photo(photo: Path, layout: Layout, rois: list[Region], layout_path: Path) -> PhotoRegions:
    """Trimmed means of every region of one photo, corrected for the light's fall-off across the card.

    A region's problem names the photo and the layout that places the region (either may be at fault)."""
    try:
        raw = read_raw(photo)
    except RawPhotoError as err:
        raise InputError(str(err)) from None
    location = light = None
    if not rois:
        try:
            location = locate_card(tone_mapped_8bit(raw.rgb), layout)
        except CardNotFound as err:
            raise InputError(f"{err} (use --roi NAME=x,y,w,h for photos without markers)", path=photo) from None
        try:
            light = paper_illumination(raw.rgb, location, layout)
        except ValueError as err:
            raise InputError(str(err), path=photo) from None
    values = {}
    for region in rois or layout.regions:
        if region.role == "colorchecker":
            continue
        where = f"{layout_path.name} places it; check the photo and the layout"
        try:
            sample = (
                sample_region(raw.rgb, location, region, mask=raw.saturated) if location else _sample_roi(raw, region)
            )
        except ValueError as err:
            raise InputError(f"{err} ({where})", path=photo) from None
        if sample.masked_fraction > MAX_CLIPPED:
            raise InputError(
                f"region {region.name!r} is clipped in {sample.masked_fraction:.1%} of its pixels: lower the exposure",
                path=photo,
            )
        variation = np.max(np.asarray(sample.std) / np.maximum(np.abs(sample.mean), 1e-12))
        if np.max(sample.uniformity) > MAX_NONUNIFORMITY or variation > MAX_VARIATION:
            raise InputError(
                f"region {region.name!r} is uneven (quadrants differ by {np.max(sample.uniformity):.0%}, pixels vary "
                f"by {variation:.0%}): a specular highlight (are the polarizers crossed?), uneven light or film, or "
                f"a region off its patch ({where})",
                path=photo,
            )
        value = np.asarray(sample.mean, dtype=np.float64)
        if region.role == "white_reference" and np.max(value) < MIN_WHITE_LEVEL:
            raise InputError(
                f"the white reference reads {np.max(value):.1%} of the sensor's range: underexposed, increase the "
                "exposure",
                path=photo,
            )
        if light is not None:
            centre = [region.x_mm + region.w_mm / 2, region.y_mm + region.h_mm / 2]
            value = value / light(centre)
        values[region.name] = value
    chart = _find_chart(raw, location, layout, light) if location is not None else None
    if chart is None:
        return PhotoRegions(photo=photo, camera=raw.camera, values=values)
    means, clipped, method = chart
    return PhotoRegions(photo, raw.camera, values, chart=means, chart_clipped=clipped, chart_method=method)


def _sample_roi(raw, region: Region):
    """Sample an axis-aligned pixel rectangle (for --roi) with the same statistics as a card region."""
    x, y, w, h = (round(v) for v in (region.x_mm, region.y_mm, region.w_mm, region.h_mm))
    height, width = raw.rgb.shape[:2]
    if x < 0 or y < 0 or x + w > width or y + h > height or w < 4 or h < 4:
        raise InputError(f"--roi {region.name} lies outside the {width} x {height} image", field="--roi")
    return sample_pixels(raw.rgb[y : y + h, x : x + w], raw.saturated[y : y + h, x : x + w], name=region.name)


def _toml_string(text: str) -> str:
    """``text`` as a TOML basic string (JSON's escapes are TOML's)."""
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")


def ingest_raw(
    photos: list[Path],
    layout_path: Path,
    out_dir: Path,
    *,
    rois: list[str] = (),
    name: str | None = None,
    thickness: str | None = None,
    polarization_factor: float = 1.0,
) -> Path:
    r"""The ingest-raw stage: cross-polarized RAW photos of a drawdown card to reflectance.csv (3 channels, one
    column per region and photo) and manifest.toml in ``out_dir`` (an existing folder); returns the manifest.

    Each photo must be a regular file (a FIFO or a device is refused before it is opened) and no output may be one
    of the inputs. InputError naming the photo, the region or the field for anything the photos cannot give.

    >>> import pathlib, tempfile
    >>> from instruments.drawdown_card.layout import default_layout
    >>> from kmpipe.formats.card_layout import write_card_layout
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> write_card_layout(default_layout(), folder / "card.layout.toml")
    >>> _ = (folder / "photo.dng").write_bytes(b"II*\x00 not a raw photo")
    >>> try:
    ...     ingest_raw([folder / "photo.dng"], folder / "card.layout.toml", folder)
    ... except InputError as err:
    ...     print(err)  # doctest: +ELLIPSIS
    /.../photo.dng: LibRaw cannot decode it (...); expected a camera RAW file with a 2x2 Bayer colour filter array ...
    """
    out_dir = output_folder(out_dir, create=False)
    if name is not None:
        safe_name(name, field="--name")
    for photo in photos:  # rawpy would read a FIFO or a device
        regular_file(photo, "RAW photo")
    for output in ("reflectance.csv", "manifest.toml"):
        refuse_inputs(out_dir / output, [*photos, layout_path])
    layout = load_card_layout(layout_path)
    roi_regions = [_roi_region(text) for text in rois]
    if roi_regions:
        by_name = {r.name: r for r in layout.regions}
        unknown = [r.name for r in roi_regions if r.name not in by_name]
        if unknown:
            raise InputError(f"names region {unknown[0]!r}, which the layout does not have", field="--roi")
        roi_regions = [
            Region(**{**vars(by_name[r.name]), **{k: getattr(r, k) for k in ("x_mm", "y_mm", "w_mm", "h_mm")}})
            for r in roi_regions
        ]
    measured = [_measure_photo(photo, layout, roi_regions, Path(layout_path)) for photo in photos]
    white = [r for r in layout.regions if r.role == "white_reference"]
    if not white:
        raise InputError('has no region with role = "white_reference" to normalize by', path=layout_path)
    reference = white[0]
    reference_reflectance = float(reference.metadata.get("reflectance", 0.9))

    def camera_reflectance(photo: PhotoRegions, values: np.ndarray) -> np.ndarray:
        return values / photo.values[reference.name] * reference_reflectance * polarization_factor

    # A ColorChecker in any photo: fit camera RGB -> XYZ on the charts (reflectance scale, averaged over the photos)
    # and give every region as X/Xn, Y/Yn, Z/Zn (relative to the perfect white): device-independent channels.
    charted = [p for p in measured if p.chart is not None]
    fit = white = None
    channels, description = (
        CHANNELS,
        f"linear camera RGB of {measured[0].camera} (no white balance), not device-independent",
    )
    if charted:
        chart = np.mean([camera_reflectance(p, p.chart) for p in charted], axis=0)
        clipped = np.max([p.chart_clipped for p in charted], axis=0)
        fit = fit_camera_to_XYZ(chart, illuminant="D65", observer="2", clipped_fraction=clipped)
        white = white_XYZ(np.arange(380.0, 781.0, 5.0), "D65", "2")
        channels = ("X", "Y", "Z")
        description = (
            f"CIE XYZ relative to the perfect white (X/Xn, Y/Yn, Z/Zn; CIE 1931 2 deg, D65) from the camera RGB of "
            f"{measured[0].camera} through a ColorChecker fit ({charted[0].chart_method}, {len(charted)} photo(s), "
            f"mean Delta E 2000 {fit.mean_delta_E:.2f}, max {fit.max_delta_E:.2f})"
        )

    def reflectance(photo: PhotoRegions, region: str) -> np.ndarray:
        rgb = camera_reflectance(photo, photo.values[region])
        return rgb if fit is None else fit.apply(rgb) / white

    sample_name = safe_name(name or Path(out_dir).resolve().name, field="--name")
    columns: dict[str, np.ndarray] = {}
    sources: dict[str, list[Path]] = {}  # the photos each column comes from
    lines = [
        "# Written by kmpipe ingest-raw: camera-RGB reflectance of the card's regions.",
        "[sample]",
        f"name = {_toml_string(sample_name)}",
        "",
    ]
    for region in layout.regions:
        if region.role == "backing":
            columns[region.name] = np.mean([reflectance(p, region.name) for p in measured], axis=0)
            sources[region.name] = [p.photo for p in measured]
            lines += [
                "[[backing]]",
                f"name = {_toml_string(region.name)}",
                'file = "reflectance.csv"',
                f"column = {_toml_string(region.name)}",
                "",
            ]
    for region in layout.regions:
        if region.role != "film":
            continue
        for i, photo in enumerate(measured, 1):
            column = region.name if len(measured) == 1 else f"{region.name}_{i}"
            columns[column] = reflectance(photo, region.name)
            sources[column] = [photo.photo]
            over = region.metadata.get("over")
            film_thickness = region.metadata.get("thickness", thickness)
            if over is None or film_thickness is None:
                raise InputError(
                    f"film region {region.name!r} needs 'over' (a backing region) and a thickness: add "
                    'thickness = "30 um" to it in the layout, or pass --thickness',
                    path=layout_path,
                )
            try:
                parse_thickness_mm(str(film_thickness))
            except ValueError as err:
                raise InputError(str(err), field="--thickness") from None
            lines += [
                "[[film]]",
                'file = "reflectance.csv"',
                f"column = {_toml_string(column)}",
                f"over = {_toml_string(str(over))}",
                f"thickness = {_toml_string(str(film_thickness))}",
                "",
            ]
    metadata = {
        "quantity": "reflectance",
        "units": "1",
        "channels": description,
        "white_reference": f"region {reference.name} x {reference_reflectance:g}",
        "polarization_factor": f"{polarization_factor:g}",
        "photos": ", ".join(p.photo.name for p in measured),
    }
    table = SpectralTable(None, channels, tuple(columns), np.array(list(columns.values())), metadata)
    try:
        table.validate_values()
    except InputError as err:  # the reflectance of a region is impossible: name the photos it was read from
        photos = sources.get(err.field or "", [p.photo for p in measured])
        raise InputError(
            f"{err.message}. Region {err.field!r} of {', '.join(p.name for p in photos)} reads a reflectance no "
            "card has: a damaged or badly exposed RAW, or a layout whose regions miss the card; nothing was written",
            path=photos[0] if len(photos) == 1 else None,
            field=err.field,
        ) from None
    out_dir.mkdir(parents=True, exist_ok=True)
    write_spectra_csv(table, out_dir / "reflectance.csv")
    manifest = out_dir / "manifest.toml"
    write_text_atomically(manifest, "\n".join(lines))
    return manifest
