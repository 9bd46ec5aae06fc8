"""The video stage: a turntable's frames as an H.264 MP4 and a lossless animated WebP, each frame captioned.

Both are made from the tone-mapped sRGB frames (``frame_NNN.png``), one video frame per turntable frame, with a
caption strip *below* the image (never over the product) that labels it like the contact sheet: "product · shade"
(marked ⚠ where the frame says its material failed validation) on the first line, "illuminant · camera azimuth"
on the second, both from the frames' EXR headers (:func:`kmpipe.stages.sheet.frame_labels`). The image area holds
the PNG's codes unchanged; a frame of odd width gets one column of the caption's grey on its right, and the strip's
height makes the whole even (H.264 in 4:2:0 needs even sides).

Caption size, in pixels, for frames ``w`` wide: font ``f = max(16, round(w / 24))`` (16 px at 256 px, as on the
sheet), smaller (not under 12 px) if the longest line would not fit ``w - f``; the strip is ``2 round(1.3 f) +
2 round(0.4 f)`` high (two lines and a margin above and below), plus 1 if the total height would be odd.

Encoders (PyAV's wheel bundles FFmpeg with libx264 and libwebp; nothing is downloaded or looked up at run time):

``mp4``
    H.264 (libx264, constant quality CRF :data:`CRF`, preset :data:`PRESET`) in yuv420p, which every player opens:
    RGB to limited-range BT.709 Y'CbCr, tagged BT.709 primaries and matrix and the sRGB transfer function (what
    the codes are); ``+faststart`` so that a browser plays it while it loads. Lossy: a few 8-bit levels off.
``webp``
    Animated WebP, lossless (every pixel as in the PNG), looping forever.

Frames are streamed through the encoders one at a time, so memory does not grow with the turntable. Each file is
written atomically (:func:`kmpipe.formats.atomic_write.write_atomically`): an interrupted or failed encode leaves
no video behind, or the previous one untouched.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.atomic_write import write_atomically
from kmpipe.stages.sheet import frame_labels

#: Video formats: their FFmpeg container (muxer) and encoder.
FORMATS = {"mp4": ("mp4", "libx264"), "webp": ("webp", "libwebp_anim")}
#: Fewest frames a turntable needs for a video.
MIN_FRAMES = 2
#: libx264's constant rate factor (0 lossless .. 51; 18 is visually lossless) and speed preset.
CRF = 18
PRESET = "medium"
#: Caption font sizes (pixels): the smallest, and the size at 256 px (it grows with the frame's width).
MIN_FONT, FONT_AT_256 = 12, 16
#: Colour of the caption's second line (sRGB-encoded in [0, 1]); the first has the sheet's text colour.
SECOND_LINE_COLOUR = (0.75, 0.75, 0.75)


@dataclass(frozen=True)
class _Captions:
    """The caption strip of a video: font size and strip height (pixels)."""

    font: int
    height: int


def write_turntable_videos(
    frames: Sequence[str | Path],
    out_dir: str | Path,
    *,
    formats: Sequence[str] = ("mp4", "webp"),
    fps: int = 24,
    inputs: Sequence[Path] = (),
) -> list[Path]:
    """Write ``out_dir/turntable.mp4`` and/or ``turntable.webp`` from a turntable's frames; the files written.

    ``frames`` are the EXR files of the turntable in order (``kmpipe render``'s, labelled by their headers), each
    with its PNG beside it (the pixels used); ``fps`` frames a second (1-120). Fewer than :data:`MIN_FRAMES` frames,
    or no ``formats``, write nothing. A missing or unreadable PNG, frames of different sizes, or a video that would
    overwrite one of ``inputs`` are an InputError naming the file; the encoder failing is a RuntimeError naming the
    video, and nothing is left of it.

    >>> import pathlib, tempfile, numpy as np
    >>> from renderer.image_io import write_exr, write_png
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> for i in range(3):
    ...     write_png(folder / f"frame_{i:03d}.png", np.full((32, 32, 3), 0.2 * (i + 1)))
    ...     write_exr(folder / f"frame_{i:03d}.exr", np.full((32, 32, 3), 0.2 * (i + 1)), {"product": "Rouge",
    ...               "shade": "Berry", "camera_azimuth_deg": 120.0 * i, "illuminant": "D65"})
    >>> written = write_turntable_videos(sorted(folder.glob("frame_*.exr")), folder, fps=12)
    >>> [path.name for path in written]
    ['turntable.mp4', 'turntable.webp']
    >>> captions(sorted(folder.glob("frame_*.exr")))[1]
    ('Rouge · Berry', 'D65 · 120°')
    """
    frames, out_dir = [Path(f) for f in frames], Path(out_dir)
    chosen = list(dict.fromkeys(formats))
    unknown = [f for f in chosen if f not in FORMATS]
    if unknown:
        raise InputError(f"is not a video format kmpipe writes: {', '.join(unknown)} (it writes {', '.join(FORMATS)})",
                         field="output.video")  # fmt: skip
    if not 1 <= fps <= 120:
        raise InputError(f"must lie in 1-120 frames a second, got {fps}", field="output.fps")
    if len(frames) < MIN_FRAMES or not chosen:
        return []
    outputs = [files.output_file(out_dir / f"turntable.{f}", inputs=inputs) for f in chosen]
    lines = captions(frames)
    for kind, output in zip(chosen, outputs, strict=True):
        _encode(kind, output, _video_frames(frames, lines), fps)
    return outputs


def captions(frames: Sequence[Path]) -> list[tuple[str, str]]:
    """Each frame's caption lines: ("product · shade", "illuminant · azimuth°"), as the contact sheet labels them
    (:func:`kmpipe.stages.sheet.frame_labels`); frames without kmpipe's headers get their file names."""
    from renderer.image_io import read_header

    labels = frame_labels(frames, 1, len(frames))
    try:
        illuminant = str(read_header(frames[0]).get("illuminant", ""))
    except OSError:
        illuminant = ""
    return [(labels.rows[0], " · ".join(filter(None, (illuminant, column)))) for column in labels.columns]


def _pixels(png: Path) -> np.ndarray:
    """A frame's 8-bit sRGB codes (height, width, 3)."""
    from renderer.image_io import read_png

    try:
        codes = read_png(files.regular_file(png, "image"))
    except (OSError, ValueError) as err:
        raise InputError(f"cannot be read as an image ({err})", path=png) from None
    if codes.shape[2] < 3:
        codes = np.repeat(codes[..., :1], 3, axis=2)
    return codes[..., :3]


def _caption_strip(lines: list[tuple[str, str]], width: int) -> _Captions:
    """Font size and strip height for captions of ``lines`` under frames ``width`` px wide (module docstring)."""
    import OpenImageIO as oiio

    font = max(FONT_AT_256, round(width / 24))
    widest = max((oiio.ImageBufAlgo.text_size(text, font).width for pair in lines for text in pair if text), default=0)
    if widest > width - font:
        font = max(MIN_FONT, int(font * (width - font) / widest))
    return _Captions(font, 2 * round(1.3 * font) + 2 * round(0.4 * font))


def _strip(text: tuple[str, str], width: int, strip: _Captions) -> np.ndarray:
    """One caption strip, 8-bit sRGB codes (strip height, width, 3): two centred lines on the sheet's grey."""
    import OpenImageIO as oiio

    from renderer.contact_sheet import BACKGROUND, TEXT_COLOUR

    buf = oiio.ImageBuf(oiio.ImageSpec(width, strip.height, 3, oiio.FLOAT))
    oiio.ImageBufAlgo.fill(buf, BACKGROUND)
    margin, line = round(0.4 * strip.font), round(1.3 * strip.font)
    for k, (words, colour) in enumerate(zip(text, (TEXT_COLOUR, SECOND_LINE_COLOUR), strict=True)):
        y = margin + k * line
        box = oiio.ROI(0, width, y, y + line, 0, 1, 0, 3)
        if words and not oiio.ImageBufAlgo.render_text(
            buf,
            width // 2,
            y + line // 2,
            words,
            strip.font,
            textcolor=colour,
            alignx="center",
            aligny="center",
            roi=box,
        ):
            raise RuntimeError(f"cannot draw the caption {words!r}: {buf.geterror() or oiio.geterror()}")  # fmt: skip
    return np.rint(np.clip(buf.get_pixels(oiio.FLOAT), 0.0, 1.0) * 255.0).astype(np.uint8)


def _video_frames(frames: Sequence[Path], lines: list[tuple[str, str]]) -> Iterator[np.ndarray]:
    """Each video frame, 8-bit sRGB (even height, even width, 3): the PNG's codes, then its caption strip below,
    grey where the sides are made even. The first frame's PNG sets the size; another size is an InputError."""
    from renderer.contact_sheet import BACKGROUND

    grey = np.rint(np.asarray(BACKGROUND) * 255.0).astype(np.uint8)
    size = strip = None
    for frame, text in zip(frames, lines, strict=True):
        png = frame.with_suffix(".png")
        pixels = _pixels(png)
        height, width = pixels.shape[:2]
        if strip is None:
            size, strip = (width, height), _caption_strip(lines, width)
        elif (width, height) != size:
            raise InputError(f"is {width} x {height} px; the turntable's first frame is {size[0]} x {size[1]}: a "
                             "video's frames are all one size", path=png)  # fmt: skip
        total = height + strip.height
        image = np.empty((total + total % 2, width + width % 2, 3), np.uint8)
        image[:] = grey
        image[:height, :width] = pixels
        image[height:total] = _strip(text, image.shape[1], strip)
        yield image


def _encode(kind: str, output: Path, images: Iterator[np.ndarray], fps: int) -> None:
    """Encode ``images`` (all of one size) into ``output``, atomically, as ``kind``; the container format is named,
    since the temporary file the encoder writes ends in ``.tmp``."""
    import av
    from av.video.reformatter import VideoReformatter

    def write(temporary: Path) -> None:
        first, convert = next(images), VideoReformatter()  # one converter for every frame: set up once
        options = {"movflags": "+faststart"} if kind == "mp4" else {"loop": "0"}
        with av.open(str(temporary), mode="w", format=FORMATS[kind][0], options=options) as container:
            stream = _mp4_stream(container, fps) if kind == "mp4" else _webp_stream(container, fps)
            stream.height, stream.width = first.shape[:2]
            for image in itertools.chain([first], images):
                for packet in stream.encode(_picture(kind, image, convert)):
                    container.mux(packet)
            for packet in stream.encode():
                container.mux(packet)

    try:
        write_atomically(output, write)
    except OSError as err:  # also av's: no space left, no permission
        raise InputError(f"the video cannot be written ({err.strerror or err})", path=output) from None
    except av.error.FFmpegError as err:
        raise RuntimeError(f"{output}: the {FORMATS[kind][1]} encoder failed ({err}); nothing was written") from None


def _mp4_stream(container, fps: int):
    """An H.264 stream in yuv420p, tagged BT.709 primaries and matrix, limited range, sRGB transfer."""
    from av.video.reformatter import ColorPrimaries, ColorRange, Colorspace, ColorTrc

    stream = container.add_stream(FORMATS["mp4"][1], rate=Fraction(fps), options={"crf": str(CRF), "preset": PRESET})
    stream.pix_fmt = "yuv420p"
    context = stream.codec_context
    context.colorspace, context.color_range = Colorspace.ITU709, ColorRange.MPEG
    context.color_primaries, context.color_trc = ColorPrimaries.BT709, ColorTrc.IEC61966_2_1
    return stream


def _webp_stream(container, fps: int):
    """A lossless animated WebP stream (libwebp's fastest method: lossless either way, only the size differs)."""
    stream = container.add_stream(FORMATS["webp"][1], rate=Fraction(fps),
                                  options={"lossless": "1", "compression_level": "0", "quality": "80"})  # fmt: skip
    stream.pix_fmt = "bgra"
    return stream


def _picture(kind: str, image: np.ndarray, convert):
    """One video frame converted by ``convert`` (a VideoReformatter): Y'CbCr 4:2:0 (BT.709, limited range; accurate
    rounding) for H.264, BGRA for WebP."""
    import av
    from av.video.reformatter import ColorRange, Colorspace, Interpolation

    frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="rgb24")
    if kind == "webp":
        return convert.reformat(frame, format="bgra")
    return convert.reformat(frame, format="yuv420p", dst_colorspace=Colorspace.ITU709, dst_color_range=ColorRange.MPEG,
                            interpolation=Interpolation.BICUBIC | Interpolation.ACCURATE_RND)  # fmt: skip
