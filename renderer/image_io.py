"""Image files through OpenImageIO: linear EXR with caller metadata, and 8-bit sRGB PNG.

Files are written to a temporary name in the target directory, fsynced and renamed (:mod:`renderer.atomic_write`),
so a reader never sees half a file and a crash never leaves one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from renderer.atomic_write import write_atomically

#: Header attribute values the EXR writer accepts.
AttributeValue = str | float | int

_CHANNELS = {1: ("Y",), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}
#: Largest image side (pixels) read: 8192 x 8192 x 4 channels is 1 GiB as float32, 2 GiB as float64.
MAX_IMAGE_SIDE = 8192
#: Most channels of an image read.
MAX_CHANNELS = 16


def _as_image(pixels: np.ndarray) -> np.ndarray:
    image = np.ascontiguousarray(pixels)  # OpenImageIO cannot take broadcast (zero-stride) arrays
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ValueError(f"expected an image of shape (height, width, 3 or 4), got {image.shape}")
    return image


def _write(path: Path, pixels: np.ndarray, spec: oiio.ImageSpec) -> None:
    """Write ``pixels`` with ``spec`` to ``path`` atomically (:mod:`renderer.atomic_write`: a temporary file beside
    it, fsynced, renamed onto it), in the format its suffix names."""
    spec.channelnames = _CHANNELS[spec.nchannels]

    def write(temporary: Path) -> None:
        output = oiio.ImageOutput.create(path.suffix.lstrip(".").lower())  # by format: the temporary ends in .tmp
        if output is None:
            raise OSError(f"{path}: OpenImageIO has no writer for this file type: {oiio.geterror()}")
        if not (output.open(str(temporary), spec) and output.write_image(pixels) and output.close()):
            raise OSError(f"{path}: write failed: {output.geterror()}")

    write_atomically(path, write)


def write_exr(
    path: str | Path,
    rgb: np.ndarray,
    attributes: dict[str, AttributeValue] | None = None,
    half: bool = True,
) -> None:
    """Write a linear image as OpenEXR.

    Parameters
    ----------
    path
        Output file (``.exr``).
    rgb
        Linear values (scene-referred, unclamped), shape (height, width, 3 or 4), top row first.
    attributes
        Header attributes stored as given, e.g. ``{"product": "...", "shade": "...", "camera_angle_deg": 30.0,
        "render_mode": "..."}``; values are strings or numbers (floats are stored as 32-bit floats).
    half
        Store 16-bit half floats (about 3 significant digits) if true, else 32-bit floats.
    """
    image = _as_image(rgb).astype(np.float32)
    path = Path(path)
    height, width, channels = image.shape
    spec = oiio.ImageSpec(width, height, channels, oiio.HALF if half else oiio.FLOAT)
    for name, value in (attributes or {}).items():
        if isinstance(value, bool) or not isinstance(value, str | float | int):
            raise TypeError(f"{path}: header attribute {name!r} must be a string or a number, got {type(value)}")
        spec.attribute(name, value)
    _write(path, image, spec)


def read_image(path: str | Path, pixel_type, pixels: bool = True) -> tuple[np.ndarray | None, oiio.ImageSpec]:
    """An image file's pixels (height, width, channels) as OIIO's ``pixel_type``, top row first, and its spec.

    The header is read first: an image larger than :data:`MAX_IMAGE_SIDE` on a side or with more than
    :data:`MAX_CHANNELS` channels is refused (ValueError) before any pixel is read.
    """
    source = oiio.ImageInput.open(str(path))
    if source is None:
        raise OSError(f"{path}: cannot open: {oiio.geterror()}")
    try:
        spec = source.spec()
        if not pixels:
            return None, spec
        if not (1 <= spec.width <= MAX_IMAGE_SIDE and 1 <= spec.height <= MAX_IMAGE_SIDE and spec.depth <= 1):
            raise ValueError(
                f"{path}: the image is {spec.width} x {spec.height} pixels"
                f"{f' x {spec.depth} deep' if spec.depth > 1 else ''}; at most {MAX_IMAGE_SIDE} x {MAX_IMAGE_SIDE} "
                "(a 2-D image) is read"
            )
        if not 1 <= spec.nchannels <= MAX_CHANNELS:
            raise ValueError(f"{path}: the image has {spec.nchannels} channels; at most {MAX_CHANNELS} are read")
        data = source.read_image(pixel_type)
        if data is None:
            raise OSError(f"{path}: read failed: {source.geterror()}")
    finally:
        source.close()
    return np.asarray(data).reshape(spec.height, spec.width, spec.nchannels), spec


def _attributes(spec: oiio.ImageSpec) -> dict[str, AttributeValue]:
    return {attribute.name: attribute.value for attribute in spec.extra_attribs}


def read_exr(path: str | Path) -> tuple[np.ndarray, dict[str, AttributeValue]]:
    """Read an EXR: the pixels as float32 (height, width, channels), top row first, and all header attributes."""
    pixels, spec = read_image(path, oiio.FLOAT)
    return pixels.astype(np.float32, copy=False), _attributes(spec)


def read_header(path: str | Path) -> dict[str, AttributeValue]:
    """The header attributes of an image file, without reading its pixels."""
    return _attributes(read_image(path, oiio.FLOAT, pixels=False)[1])


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1) of linear values, clipped to [0, 1] first; returns [0, 1]."""
    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


#: zlib level of the PNGs written: 3 writes a 512 x 512 frame in about a third of the time of the default 6, for files
#: about 13 % larger (the pixels are the same: PNG is lossless).
PNG_COMPRESSION = 3


def write_png(path: str | Path, rgb: np.ndarray) -> None:
    """Write linear RGB(A) as an 8-bit sRGB PNG: clip to [0, 1], sRGB-encode colour, round to 0..255.

    Alpha (a 4th channel), if present, is stored linearly.
    """
    image = _as_image(rgb).astype(np.float64)
    encoded = image.copy()
    encoded[..., :3] = srgb_encode(image[..., :3])
    encoded[..., 3:] = np.clip(image[..., 3:], 0.0, 1.0)
    codes = np.rint(encoded * 255.0).astype(np.uint8)
    height, width, channels = codes.shape
    spec = oiio.ImageSpec(width, height, channels, oiio.UINT8)
    spec.attribute("oiio:ColorSpace", "sRGB")
    spec.attribute("png:compressionLevel", PNG_COMPRESSION)
    _write(Path(path), codes, spec)


def read_png(path: str | Path) -> np.ndarray:
    """Read a PNG's 8-bit codes as uint8 (height, width, channels), top row first, without decoding sRGB."""
    return read_image(path, oiio.UINT8)[0].astype(np.uint8, copy=False)


def read_pixels(path: str | Path) -> tuple[np.ndarray, list[str]]:
    """An image file's pixels as float64 (height, width, channels), top row first, and its channel names.

    No colour decoding: integer files are normalised to [0, 1] (code / max code), float files (EXR) read as stored.
    Raises :class:`OSError` when the file cannot be read and :class:`ValueError` when it is larger than
    :data:`MAX_IMAGE_SIDE` on a side or has more than :data:`MAX_CHANNELS` channels.
    """
    pixels, spec = read_image(path, oiio.FLOAT)
    return pixels.astype(np.float64), list(spec.channelnames)


def read_channel(path: str | Path, channel: str) -> np.ndarray:
    """One channel of an image file as float64 (height, width), as :func:`read_pixels` reads it.

    ``channel`` is a channel name of the file (``R``, ``G``, ``B``, ``A``, ``Y``, ...); a one-channel file answers
    to any name. Raises :class:`OSError` when the file cannot be read and :class:`ValueError` when it has no such
    channel or is too large (see :func:`read_pixels`).
    """
    image, names = read_pixels(path)
    if image.shape[2] == 1:
        return np.ascontiguousarray(image[..., 0])
    if channel not in names:
        raise ValueError(f"{path} has no channel {channel!r} (it has {', '.join(names)})")
    return np.ascontiguousarray(image[..., names.index(channel)])


def write_map(path: str | Path, values: np.ndarray) -> None:
    """Write data in [0, 1], (height, width) or (height, width, 1, 3 or 4), as a 16-bit PNG with no sRGB encoding.

    For maps that are data, not pictures: cosmetic and thickness maps (:func:`read_channel` reads them back).
    """
    data = np.asarray(values, dtype=np.float64)
    if data.ndim == 2:
        data = data[..., np.newaxis]
    if data.ndim != 3 or data.shape[2] not in _CHANNELS or not np.all((data >= 0.0) & (data <= 1.0)):
        raise ValueError(f"expected values in [0, 1] of shape (height, width[, 1, 3 or 4]), got {data.shape}")
    codes = np.ascontiguousarray(np.rint(data * 65535.0).astype(np.uint16))
    height, width, channels = codes.shape
    _write(Path(path), codes, oiio.ImageSpec(width, height, channels, oiio.UINT16))
