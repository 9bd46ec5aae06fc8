"""Camera RAW photos as linear camera RGB, for radiometric measurement.

:func:`read_raw` decodes a RAW file with rawpy (LibRaw) and returns a :class:`RawPhoto` whose ``rgb`` is
proportional to the light on each photosite: no gamma, no white balance, no colour matrix, no brightness or
maximum adjustment, no clipping, no flip.

Decode path
-----------
LibRaw is used only to *unpack* the file (decompression, linearization curves, masked borders, metadata). The
image is then built here from the visible CFA samples (``raw_image_visible``, copied while the file is open,
because it is a view into LibRaw's memory), the colour of each position in a 2x2 CFA cell and the black and
white levels:

1. every sample is normalized with the black level of its own colour (DNG spec, "Mapping Raw Values to Linear
   Reference Values"): ``v = (raw - black[c]) / (white - black[c])``, so black reads 0 and the white level
   reads 1 in every channel. Values below 0 (read noise around black) and above 1 are kept, so that averages
   over a patch stay unbiased;
2. ``half_size=True`` (the default, for measurement): each 2x2 cell becomes one pixel holding its R sample, the
   mean of its two G samples and its B sample. Nothing is interpolated, so every value is a measured one.
   A trailing odd row or column (an incomplete cell) is dropped;
3. ``half_size=False``: full resolution by bilinear interpolation of the normalized samples (each site keeps
   its own sample; a missing G is the mean of the 4 edge neighbours, a missing R or B the mean of the 2 or 4
   nearest same-colour samples; at the border, of those that exist). Linear in the data, exact on flat and
   linearly graded fields, but interpolated: use it for locating things, and half size for measuring.

Why not LibRaw's ``postprocess``: with every option set for radiometry (``gamma=(1, 1)``,
``no_auto_bright=True``, ``user_wb=[1, 1, 1, 1]``, ``output_color=raw``, ``adjust_maximum_thr=0``,
``user_flip=0``) it agrees with step 2 on ordinary files, but it quantizes to 16 bits, clips at black and white,
scales every channel by ``white - min(black)`` instead of each channel's own range, and each forgotten option
silently changes the numbers (the default ``adjust_maximum_thr`` reads 0.5 grey as 0.625 when the frame's
brightest sample is at 0.8; leaving ``user_wb`` unset applies a daylight balance). Building the image from the
samples has none of these options to forget.

The image stays in sensor orientation: the camera's orientation tag is ignored, so a fixture on the copy stand
is at the same pixels whichever way the camera reports it was held.

Only 2x2 Bayer sensors with R, G, B filters are accepted; X-Trans, four-colour (CMYG, RGBE), monochrome and
already demosaiced ("linear") RAW files raise :class:`RawPhotoError`, as does anything LibRaw cannot decode.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rawpy
from scipy import ndimage

__all__ = ["SATURATION_MARGIN", "RawPhoto", "RawPhotoError", "read_raw", "tone_mapped_8bit"]

SATURATION_MARGIN = 0.01
"""A raw sample at or above ``1 - SATURATION_MARGIN`` of its normalized range counts as saturated.

As a fraction of ``white - black`` (1 % is about 160 DN for a 14-bit sensor): real sensors can clip a little
below the white level LibRaw reports, and a measurement patch has no business being that close to white.
"""

_EXPECTED = "expected a camera RAW file with a 2x2 Bayer colour filter array (R, G, B)"

_RED_BLUE_KERNEL = np.array([[1.0, 2.0, 1.0], [2.0, 4.0, 2.0], [1.0, 2.0, 1.0]])
"""Bilinear weights for R and B: on a Bayer mosaic the 3x3 window holds the site itself or 2 or 4 neighbours."""

_GREEN_KERNEL = np.array([[0.0, 1.0, 0.0], [1.0, 4.0, 1.0], [0.0, 1.0, 0.0]])
"""Bilinear weights for G: the site itself, or its 4 edge neighbours (diagonal G samples are left out)."""

_TIFF_MAKE, _TIFF_MODEL, _TIFF_ASCII = 271, 272, 2


class RawPhotoError(ValueError):
    """A file that is not a camera RAW this module can measure from; the one-line message names the file."""


@dataclass(frozen=True, eq=False)
class RawPhoto:
    """A decoded RAW photo: linear camera RGB and what is needed to trust it.

    The arrays are read-only.

    Attributes
    ----------
    rgb
        float64 (H, W, 3), linear camera RGB (R, G, B in the sensor's own primaries, not white balanced), scaled
        so that each channel's black level is 0 and the white level is 1 (dimensionless). Slightly negative
        values (noise around black) are kept.
    saturated
        bool (H, W): True where any raw sample that contributed to the pixel is within
        :data:`SATURATION_MARGIN` of the white level. Such pixels are not measurements.
    camera
        Make and model from the file's TIFF header (DNG, CR2, NEF, ARW, ORF, RW2, PEF, ...), e.g.
        ``"Canon EOS R5"``; empty for RAW formats without one (CR3, RAF).
    raw_pattern
        uint8 (2, 2): LibRaw colour index (into ``color_desc``) of each position of the 2x2 CFA cell at the top
        left of the visible area; the cell that the half-size pixels are made of.
    color_desc
        LibRaw's colour letters for the indices, ``b"RGBG"`` for every accepted file (index 3 is the second G).
    black_level
        Black level of each LibRaw colour index 0..3, in raw DN (data numbers).
    white_level
        White (saturation) level, in raw DN.
    path
        The file that was read.
    """

    rgb: np.ndarray
    saturated: np.ndarray
    camera: str
    raw_pattern: np.ndarray
    color_desc: bytes
    black_level: tuple[int, int, int, int]
    white_level: int
    path: Path

    @property
    def cfa(self) -> str:
        """The 2x2 CFA cell as four letters in reading order, e.g. ``"RGGB"``."""
        return "".join(chr(self.color_desc[c]) for c in self.raw_pattern.flat)


def read_raw(path: str | os.PathLike[str], *, half_size: bool = True) -> RawPhoto:
    """Read a camera RAW file as linear camera RGB (see the module docstring for exactly what is done).

    Parameters
    ----------
    path
        A RAW file that LibRaw decodes (DNG, CR2, CR3, NEF, ARW, ...) from a Bayer R, G, B sensor.
    half_size
        True: one pixel per 2x2 CFA cell, every value measured, (H // 2, W // 2) for a visible area of H x W
        photosites. False: H x W by bilinear interpolation.

    Returns
    -------
    RawPhoto

    Raises
    ------
    RawPhotoError
        The file is missing, is not a RAW file, is truncated or corrupt, or is not from a 2x2 R, G, B Bayer
        sensor (X-Trans, CMYG, monochrome, linear DNG).
    """
    path = Path(path)
    if not path.is_file():
        raise _error(path, "not a file" if path.exists() else "file not found")
    try:
        with rawpy.imread(os.fspath(path)) as raw:
            if raw.raw_type is not rawpy.RawType.Flat:
                raise _error(path, "LibRaw decodes it as an RGB image (linear DNG, Foveon or sRAW), not a CFA mosaic")
            samples = np.array(raw.raw_image_visible, dtype=np.uint16)  # a copy: the view dies with `raw`
            pattern = raw.raw_pattern
            sizes = raw.sizes
            cell = np.array(
                [[raw.raw_color(sizes.top_margin + i, sizes.left_margin + j) for j in range(2)] for i in range(2)],
                dtype=np.uint8,
            )
            color_desc = bytes(raw.color_desc)
            black_level = tuple(int(b) for b in raw.black_level_per_channel)
            white_level = int(raw.white_level)
    except rawpy.LibRawError as err:
        message = err.args[0].decode(errors="replace") if err.args and isinstance(err.args[0], bytes) else str(err)
        raise _error(path, f"LibRaw cannot decode it ({type(err).__name__}: {message})") from None
    except NotImplementedError as err:  # rawpy's raw_pattern for a CFA layout it has no name for
        raise _error(path, f"unsupported colour filter layout ({err})") from None

    channels = _bayer_channels(path, pattern, cell, color_desc)
    if white_level <= max(black_level):
        raise _error(path, f"white level {white_level} DN is not above the black levels {black_level} DN")
    normalized = _normalized(samples, cell, black_level, white_level)
    clipped = normalized >= 1.0 - SATURATION_MARGIN
    if half_size:
        rgb, saturated = _bin_cells(normalized, clipped, channels)
    else:
        rgb, saturated = _bilinear(normalized, clipped, channels)
    rgb.flags.writeable = False
    saturated.flags.writeable = False
    cell.flags.writeable = False
    return RawPhoto(
        rgb=rgb,
        saturated=saturated,
        camera=_camera_name(path),
        raw_pattern=cell,
        color_desc=color_desc,
        black_level=black_level,
        white_level=white_level,
        path=path,
    )


def tone_mapped_8bit(rgb: np.ndarray, *, percentile: float = 99.0) -> np.ndarray:
    """Return an 8-bit display copy of linear RGB for finding markers and charts. Never measure on it.

    Each channel is divided by its own ``percentile``-th percentile over the image (so that value becomes
    white; this also roughly neutralizes the green-heavy camera RGB), clipped to [0, 1] and encoded with the
    sRGB transfer function (IEC 61966-2-1). Per-image and nonlinear: the same patch gets different codes in
    different photos. Channel order stays R, G, B (OpenCV's colour functions expect B, G, R).

    Parameters
    ----------
    rgb
        (H, W, 3) finite linear values, e.g. :attr:`RawPhoto.rgb` (dimensionless).
    percentile
        In (0, 100]: the percentile of each channel that maps to 255.

    Returns
    -------
    numpy.ndarray
        uint8 (H, W, 3), a new array.
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {rgb.shape}")
    if not 0.0 < percentile <= 100.0:
        raise ValueError(f"percentile must be in (0, 100], got {percentile}")
    if not np.all(np.isfinite(rgb)):
        raise ValueError("the image has non-finite values")
    white = np.percentile(rgb.reshape(-1, 3), percentile, axis=0)
    linear = np.clip(rgb / np.where(white > 0.0, white, 1.0), 0.0, 1.0)
    encoded = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1.0 / 2.4) - 0.055)
    return np.round(encoded * 255.0).astype(np.uint8)


def _error(path: Path, what: str) -> RawPhotoError:
    """Return the one-line error for ``path``: what is wrong, then what was expected."""
    return RawPhotoError(f"{path}: {what}; {_EXPECTED}")


def _bayer_channels(path: Path, pattern: np.ndarray, cell: np.ndarray, color_desc: bytes) -> np.ndarray:
    """Return the RGB channel (0, 1, 2) of each position of the 2x2 cell, or raise if it is not R, G, B Bayer."""
    if pattern.shape == (1, 1):
        raise _error(path, "it has no colour filter pattern (a monochrome sensor, or a DNG without CFAPattern)")
    if pattern.shape != (2, 2):
        n_rows, n_cols = pattern.shape
        raise _error(path, f"its colour filter pattern repeats every {n_rows}x{n_cols} photosites (X-Trans or other)")
    letters = "".join(chr(color_desc[c]) if c < len(color_desc) else "?" for c in cell.flat)
    bayer = sorted(letters) == ["B", "G", "G", "R"] and (letters[0] == letters[3] or letters[1] == letters[2])
    if not bayer:
        raise _error(path, f"its 2x2 colour filter cell is {letters!r} (colours {color_desc!r})")
    return np.array(["RGB".index(letter) for letter in letters]).reshape(2, 2)


def _normalized(samples: np.ndarray, cell: np.ndarray, black_level: tuple[int, ...], white_level: int) -> np.ndarray:
    """Return float64 ``(raw - black[c]) / (white - black[c])`` for every sample, c its LibRaw colour index."""
    normalized = samples.astype(np.float64)
    for i in range(2):
        for j in range(2):
            black = black_level[cell[i, j]]
            normalized[i::2, j::2] -= black
            normalized[i::2, j::2] /= white_level - black
    return normalized


def _bin_cells(normalized: np.ndarray, clipped: np.ndarray, channels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (rgb, saturated) with one pixel per complete 2x2 cell: R, mean of the two G, B; any sample clipped."""
    height, width = normalized.shape[0] // 2, normalized.shape[1] // 2
    rgb = np.zeros((height, width, 3))
    saturated = np.zeros((height, width), dtype=bool)
    for i in range(2):
        for j in range(2):
            rgb[..., channels[i, j]] += normalized[i : 2 * height : 2, j : 2 * width : 2]
            saturated |= clipped[i : 2 * height : 2, j : 2 * width : 2]
    rgb[..., 1] /= 2.0
    return rgb, saturated


def _bilinear(normalized: np.ndarray, clipped: np.ndarray, channels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (rgb, saturated) at full resolution by normalized bilinear interpolation of each channel's samples.

    A pixel is saturated when a clipped sample has a nonzero weight in any of its three channels.
    """
    rgb = np.empty((*normalized.shape, 3))
    saturated = np.zeros(normalized.shape, dtype=bool)
    for channel in range(3):
        here = np.zeros(normalized.shape)
        for i, j in zip(*np.nonzero(channels == channel), strict=True):
            here[i::2, j::2] = 1.0
        kernel = _GREEN_KERNEL if channel == 1 else _RED_BLUE_KERNEL
        weights = ndimage.correlate(here, kernel, mode="constant")
        rgb[..., channel] = ndimage.correlate(normalized * here, kernel, mode="constant") / weights
        saturated |= ndimage.correlate(clipped * here, kernel, mode="constant") > 0.0
    return rgb, saturated


def _camera_name(path: Path) -> str:
    """Return "Make Model" from the first IFD of a TIFF-based RAW file, or "" if it has none.

    rawpy does not expose LibRaw's make and model, and this is all the EXIF this module needs.
    """
    try:
        with path.open("rb") as file:
            header = file.read(8)
            order = {b"II": "<", b"MM": ">"}.get(header[:2])
            if order is None:
                return ""
            file.seek(struct.unpack(order + "I", header[4:8])[0])
            (count,) = struct.unpack(order + "H", file.read(2))
            entries = file.read(12 * count)
            text = {}
            for k in range(count):
                tag, kind, length, value = struct.unpack(order + "HHI4s", entries[12 * k : 12 * k + 12])
                if tag in (_TIFF_MAKE, _TIFF_MODEL) and kind == _TIFF_ASCII:
                    if length > 4:
                        file.seek(struct.unpack(order + "I", value)[0])
                        value = file.read(length)
                    name = value[:length].split(b"\0")[0].decode("latin-1")
                    text[tag] = "".join(c if c.isprintable() else "?" for c in name).strip()[:64]  # untrusted bytes
    except (OSError, struct.error):
        return ""
    make, model = text.get(_TIFF_MAKE, ""), text.get(_TIFF_MODEL, "")
    return model if model.startswith(make) else f"{make} {model}".strip()
