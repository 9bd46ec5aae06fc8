"""Synthetic DNG files for the RAW photo tests (a test-support module, not a test module).

:func:`write_dng` writes a CFA DNG with tifffile that LibRaw decodes: the tags DNG 1.4 asks for (DNGVersion,
UniqueCameraModel, ColorMatrix1, CalibrationIlluminant1), the CFA tags without which LibRaw finds no colour
layout (CFARepeatPatternDim, CFAPattern, CFAPlaneColor), the levels (BlackLevel, WhiteLevel), Make and Model, and an
AsShotNeutral that is deliberately *not* neutral, so a reader that applied the camera white balance shows it.
Values are linear: a float value ``v`` in [0, 1] is stored as ``round(black + v * (white - black))`` DN.

LibRaw refuses images under 22 photosites on a side; 32 x 48 and up are used here.
Nothing here imports ``kmpipe`` or ``instruments``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import tifffile

COLOR_CODES = {"R": 0, "G": 1, "B": 2, "C": 3, "M": 4, "Y": 5}
"""DNG CFAPlaneColor codes of the filter colours a pattern string may use."""

XTRANS = "".join(("GGRGGB", "GGBGGR", "BRGRBG", "GGBGGR", "GGRGGB", "RBGBRG"))
"""A Fujifilm X-Trans 6x6 layout, row by row."""

_IDENTITY_SRATIONAL = (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1)
_D65 = 21  # EXIF LightSource code of CalibrationIlluminant1


def mosaic(rgb: np.ndarray, pattern: str = "RGGB") -> np.ndarray:
    """Return the (H, W) CFA samples of a full-resolution linear (H, W, 3) image through a 2x2 Bayer ``pattern``.

    ``pattern`` lists the filter colours of the 2x2 cell in reading order (``"RGGB"``, ``"BGGR"``, ...); the
    sample at each photosite is that pixel's value in the photosite's colour.
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or len(pattern) != 4 or sorted(pattern) != ["B", "G", "G", "R"]:
        raise ValueError(f"expected an (H, W, 3) image and a 2x2 R, G, B pattern, got {rgb.shape} and {pattern!r}")
    samples = np.empty(rgb.shape[:2])
    for k, letter in enumerate(pattern):
        i, j = divmod(k, 2)
        samples[i::2, j::2] = rgb[i::2, j::2, "RGB".index(letter)]
    return samples


def write_dng(
    path: str | os.PathLike[str],
    values: np.ndarray,
    *,
    pattern: str | None = "RGGB",
    black_level: int | Sequence[int] = 512,
    white_level: int = 16383,
    camera: str = "kmpipe synthetic",
    as_shot_neutral: Sequence[float] = (0.5, 1.0, 0.75),
    orientation: int = 1,
    active_area: Sequence[int] | None = None,
) -> Path:
    """Write a one-channel CFA DNG (PhotometricInterpretation 32803) and return its path.

    Parameters
    ----------
    values
        (H, W) CFA samples: floats in [0, 1] (linear, 1 = white level), quantized to DN as
        ``round(black + v * (white - black))`` with the black level of each sample's position; or integers,
        written as they are (DN).
    pattern
        Filter colours of the repeating cell in reading order, n*n letters from :data:`COLOR_CODES`: ``"RGGB"``,
        ``"CMYG"``, :data:`XTRANS`. None writes no CFA tags (the trap the notes warn about).
    black_level
        One level (DN), or four for the 2x2 positions in reading order (BlackLevelRepeatDim 2x2).
    white_level
        WhiteLevel (DN).
    camera
        UniqueCameraModel; split at its first space into Make and Model.
    as_shot_neutral
        AsShotNeutral (camera R, G, B of a neutral); the camera white balance is its reciprocal.
    orientation
        TIFF Orientation (1 = as stored, 3 = 180 degrees, 6 = 90 degrees clockwise, ...).
    active_area
        DNG ActiveArea (top, left, bottom, right) in photosites, or None for the whole image.
    """
    path = Path(path)
    blacks = np.atleast_1d(np.asarray(black_level, dtype=np.int64))
    if blacks.shape not in ((1,), (4,)):
        raise ValueError(f"black_level must be one level or four, got {black_level!r}")
    values = np.asarray(values)
    if values.ndim != 2:
        raise ValueError(f"expected (H, W) CFA samples, got shape {values.shape}")
    if np.issubdtype(values.dtype, np.integer):
        if values.min() < 0 or values.max() > 65535:
            raise ValueError("integer samples must fit in 16 bits")
        stored = values.astype(np.uint16)
    else:
        if not (np.all(np.isfinite(values)) and values.min() >= 0.0 and values.max() <= 1.0):
            raise ValueError("float samples must be linear values in [0, 1]")
        cell = blacks.reshape(2, 2) if blacks.size == 4 else np.full((2, 2), blacks[0])
        height, width = values.shape
        black_map = np.tile(cell, ((height + 1) // 2, (width + 1) // 2))[:height, :width]
        stored = np.round(black_map + values * (white_level - black_map)).astype(np.uint16)

    make, _, model = camera.partition(" ")
    tags: list[tuple] = [
        (271, "s", 0, make),
        (272, "s", 0, model or make),
        (274, "H", 1, orientation),
        (50706, "B", 4, (1, 4, 0, 0)),
        (50708, "s", 0, camera),
        (50717, "H", 1, white_level),
        (50721, "2i", 9, _IDENTITY_SRATIONAL),
        (50728, "2I", 3, _rationals(as_shot_neutral)),
        (50778, "H", 1, _D65),
    ]
    if blacks.size == 4:
        tags += [(50713, "H", 2, (2, 2)), (50714, "H", 4, tuple(int(b) for b in blacks))]
    else:
        tags.append((50714, "H", 1, int(blacks[0])))
    if pattern is not None:
        side = round(len(pattern) ** 0.5)
        if side * side != len(pattern) or not set(pattern) <= set(COLOR_CODES):
            raise ValueError(f"pattern must be n*n letters from {''.join(COLOR_CODES)}, got {pattern!r}")
        planes = sorted(set(pattern), key=COLOR_CODES.__getitem__)
        tags += [
            (33421, "H", 2, (side, side)),
            (33422, "B", len(pattern), bytes(planes.index(letter) for letter in pattern)),
            (50710, "B", len(planes), bytes(COLOR_CODES[letter] for letter in planes)),
        ]
    if active_area is not None:
        tags.append((50829, "I", 4, tuple(active_area)))
    tifffile.imwrite(path, stored, photometric=32803, subfiletype=0, extratags=tags, metadata=None)
    return path


def write_linear_dng(path: str | os.PathLike[str], rgb: np.ndarray, *, white_level: int = 16383) -> Path:
    """Write an already demosaiced ("linear") 3-channel DNG (PhotometricInterpretation 34892) and return its path.

    ``rgb`` is (H, W, 3) linear in [0, 1], stored as ``round(v * white)`` DN with a black level of 0.
    """
    path = Path(path)
    stored = np.round(np.asarray(rgb, dtype=np.float64) * white_level).astype(np.uint16)
    tags = [
        (271, "s", 0, "kmpipe"),
        (272, "s", 0, "linear"),
        (50706, "B", 4, (1, 4, 0, 0)),
        (50708, "s", 0, "kmpipe linear"),
        (50714, "H", 1, 0),
        (50717, "H", 1, white_level),
        (50721, "2i", 9, _IDENTITY_SRATIONAL),
        (50778, "H", 1, _D65),
    ]
    tifffile.imwrite(path, stored, photometric=34892, subfiletype=0, extratags=tags, metadata=None)
    return path


def write_jpeg(path: str | os.PathLike[str]) -> Path:
    """Write a small valid JPEG (a colour gradient, 64 x 48) and return its path."""
    path = Path(path)
    ramp = np.linspace(0, 255, 64, dtype=np.uint8)
    image = np.stack(np.broadcast_arrays(ramp[None, :], ramp[:48, None], np.uint8(128)), axis=-1)
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(image))
    if not ok:
        raise RuntimeError("OpenCV could not encode a JPEG")
    path.write_bytes(data.tobytes())
    return path


def write_truncated_dng(path: str | os.PathLike[str], keep: float) -> Path:
    """Write a valid 32 x 48 RGGB DNG, cut it after the first ``keep`` (fraction, 0..1) of its bytes; return path."""
    path = write_dng(path, np.full((32, 48), 0.5))
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])
    return path


def _rationals(numbers: Sequence[float]) -> tuple[int, ...]:
    """Return numerator, denominator pairs (denominator 10**6) for TIFF RATIONAL values."""
    return tuple(int(part) for x in numbers for part in (round(x * 1_000_000), 1_000_000))
