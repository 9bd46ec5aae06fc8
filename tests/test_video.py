"""Turntable videos (kmpipe.stages.video, ``kmpipe render``, ``kmpipe run``): an H.264 MP4 and a lossless animated
WebP of the tone-mapped frames, each frame captioned below the image.

What is expected comes from independent facts: the videos are decoded back by other code than wrote them where one
exists (the WebP by Pillow; the MP4 by FFmpeg's H.264 decoder), the frames they must hold are the PNGs read by
Pillow, the captions are what the scene file says (product, shade, illuminant, 360 / frames degrees a frame).
"""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np
import pytest
from PIL import Image, ImageSequence

from kmpipe import cli
from kmpipe.errors import InputError
from kmpipe.run.execute import execute
from kmpipe.run.planning import plan_run
from kmpipe.stages import video
from kmpipe.stages.video import captions, write_turntable_videos

REPO = Path(__file__).resolve().parent.parent
WIDTH, HEIGHT, FRAMES = 31, 23, 3  # odd sides: the video pads them to even


@pytest.fixture(scope="module")
def material(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("material") / "L1.json"
    assert cli.main(["fit", str(REPO / "recipes/samples/L1/manifest.toml"), "-o", str(path)]) == 0
    return path


def write_scene(folder: Path, material: Path, *, frames: int = FRAMES, output: str = "") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "scene.toml"
    path.write_text(
        f'[scene]\nname = "Bullet"\nproduct = "Rouge"\nshade = "Berry"\nilluminant = "D65"\nmesh = "lipstick"\n'
        f"resolution = [{WIDTH}, {HEIGHT}]\n[substrate]\nreflectance = 0.8\n"
        f'[[layer]]\nmaterial = "{material}"\nthickness = "1 mm"\n'
        f"[[light]]\ndirection = [0.6, 0.5, 0.6]\n[camera]\nelevation_deg = 20.0\n"
        f"[turntable]\nframes = {frames}\n[output]\n{output}\n",
        encoding="utf-8",
    )
    return path


def render(scene: Path, out: Path, capsys=None) -> int:
    status = cli.main(["render", str(scene), "-o", str(out)])
    if capsys is not None:
        capsys.readouterr()
    return status


@pytest.fixture(scope="module")
def rendered(tmp_path_factory, material) -> Path:
    """A 3-frame turntable rendered by ``kmpipe render`` with the default [output]: its output folder."""
    folder = tmp_path_factory.mktemp("turntable")
    assert render(write_scene(folder, material), folder / "out") == cli.EXIT_OK
    return folder / "out"


def png(out: Path, i: int) -> np.ndarray:
    with Image.open(out / f"frame_{i:03d}.png") as image:
        return np.asarray(image.convert("RGB"), dtype=np.int16)


def webp_frames(path: Path) -> tuple[list[np.ndarray], dict, list[int]]:
    """The WebP's frames (RGB), its info and each frame's duration (ms), decoded by Pillow."""
    with Image.open(path) as image:
        assert image.format == "WEBP" and image.is_animated
        frames, durations = [], []
        for frame in ImageSequence.Iterator(image):
            frames.append(np.asarray(frame.convert("RGB"), dtype=np.int16))
            durations.append(frame.info["duration"])
        return frames, dict(image.info), durations


def lasting(durations: list[int], fps: int) -> bool:
    """True when every frame lasts 1 / fps s (WebP durations are whole milliseconds)."""
    return all(abs(d - 1000 / fps) <= 1 for d in durations)


def mp4_frames(path: Path) -> tuple[list[np.ndarray], av.video.stream.VideoStream]:
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = [frame.to_ndarray(format="rgb24").astype(np.int16) for frame in container.decode(stream)]
        return frames, stream


def test_kmpipe_render_writes_both_videos_of_a_turntable(rendered):
    assert {p.name for p in rendered.iterdir()} == {f"frame_{i:03d}.{e}" for i in range(FRAMES) for e in ("exr", "png")
                                                    } | {"turntable.mp4", "turntable.webp"}  # fmt: skip


def test_the_webp_holds_every_frame_exactly_and_loops(rendered):
    frames, info, durations = webp_frames(rendered / "turntable.webp")
    assert len(frames) == FRAMES
    assert info["loop"] == 0  # forever
    assert lasting(durations, 24)  # by default
    height, width = frames[0].shape[:2]
    assert width == WIDTH + 1 and height % 2 == 0 and height > HEIGHT  # even sides, a caption strip below
    for i, frame in enumerate(frames):
        assert np.array_equal(frame[:HEIGHT, :WIDTH], png(rendered, i)), i  # lossless: the PNG's codes
        assert (frame[:HEIGHT, WIDTH] == frame[-1, 0]).all()  # the padding column: the strip's grey
    strips = [frame[HEIGHT:] for frame in frames]
    assert all(strip.max() >= 200 for strip in strips)  # light text on the grey strip
    assert not np.array_equal(strips[0], strips[1])  # each frame's own angle


def test_the_mp4_is_h264_in_yuv420p_close_to_the_frames(rendered):
    frames, stream = mp4_frames(rendered / "turntable.mp4")
    assert stream.codec_context.name == "h264" and stream.codec_context.pix_fmt == "yuv420p"
    assert stream.average_rate == 24
    assert len(frames) == FRAMES
    webp, _, _ = webp_frames(rendered / "turntable.webp")
    assert frames[0].shape == webp[0].shape  # the same picture size as the WebP's
    for i, frame in enumerate(frames):
        difference = np.abs(frame[:HEIGHT, :WIDTH] - png(rendered, i))
        assert difference.mean() < 4.0, (i, difference.mean())  # lossy 4:2:0, a few 8-bit levels at most


def test_captions_say_product_shade_illuminant_and_angle(rendered):
    assert captions([rendered / f"frame_{i:03d}.exr" for i in range(FRAMES)]) == [
        ("Rouge · Berry", "D65 · 0°"), ("Rouge · Berry", "D65 · 120°"), ("Rouge · Berry", "D65 · 240°")]  # fmt: skip


def test_fps_and_formats_come_from_the_scene(tmp_path, material, capsys):
    out = tmp_path / "out"
    assert render(write_scene(tmp_path, material, output='video = ["webp"]\nfps = 8'), out, capsys) == cli.EXIT_OK
    assert not (out / "turntable.mp4").exists()
    _, _, durations = webp_frames(out / "turntable.webp")
    assert lasting(durations, 8)


@pytest.mark.parametrize(("frames", "output"), [(FRAMES, "video = []"), (1, "")], ids=["video-off", "one-frame"])
def test_no_video_without_formats_or_for_one_frame(tmp_path, material, capsys, frames, output):
    out = tmp_path / "out"
    assert render(write_scene(tmp_path, material, frames=frames, output=output), out, capsys) == cli.EXIT_OK
    assert sorted(p.name for p in out.iterdir()) == [
        f"frame_{i:03d}.{e}" for i in range(frames) for e in ("exr", "png")
    ]


@pytest.mark.parametrize(("output", "field", "line"), [("fps = 0", "output.fps", "fps = 0"),
                                                        ('video = ["avi"]', "output.video", "avi")])  # fmt: skip
def test_bad_video_settings_exit_2_naming_the_field(tmp_path, material, capsys, output, field, line):
    scene = write_scene(tmp_path, material, output=output)
    capsys.readouterr()
    assert render(scene, tmp_path / "out") == cli.EXIT_BAD_INPUT
    err = " ".join(capsys.readouterr().err.split())
    number = next(n for n, text in enumerate(scene.read_text().splitlines(), 1) if line in text)
    assert f"{scene}, line {number}: field '{field}" in err
    assert not (tmp_path / "out").exists()


def test_an_interrupted_write_leaves_no_video(rendered, tmp_path, monkeypatch):
    for path in rendered.glob("frame_*"):
        (tmp_path / path.name).write_bytes(path.read_bytes())
    (tmp_path / "turntable.webp").write_bytes(b"the previous video")
    real, calls = video._picture, []

    def interrupted(kind, image, convert):
        calls.append(kind)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(kind, image, convert)

    monkeypatch.setattr(video, "_picture", interrupted)
    exrs = [tmp_path / f"frame_{i:03d}.exr" for i in range(FRAMES)]
    for formats in (["mp4"], ["webp"]):
        calls.clear()
        with pytest.raises(KeyboardInterrupt):
            write_turntable_videos(exrs, tmp_path, formats=formats)
    assert not (tmp_path / "turntable.mp4").exists()
    assert (tmp_path / "turntable.webp").read_bytes() == b"the previous video"
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary file left


def test_an_encoder_failure_names_the_video_and_leaves_none(rendered, tmp_path, monkeypatch):
    for path in rendered.glob("frame_*"):
        (tmp_path / path.name).write_bytes(path.read_bytes())
    monkeypatch.setattr(video, "PRESET", "no-such-preset")  # libx264 refuses to open
    with pytest.raises(RuntimeError, match=r"turntable\.mp4"):
        write_turntable_videos([tmp_path / f"frame_{i:03d}.exr" for i in range(FRAMES)], tmp_path, formats=["mp4"])
    assert sorted(p.name for p in tmp_path.iterdir() if "turntable" in p.name) == []


def test_a_missing_frame_is_bad_input_naming_it(rendered, tmp_path):
    for path in rendered.glob("frame_00[01].*"):
        (tmp_path / path.name).write_bytes(path.read_bytes())
    (tmp_path / "frame_002.exr").write_bytes((rendered / "frame_002.exr").read_bytes())
    with pytest.raises(InputError) as raised:
        write_turntable_videos([tmp_path / f"frame_{i:03d}.exr" for i in range(FRAMES)], tmp_path)
    assert raised.value.path == tmp_path / "frame_002.png"
    assert not list(tmp_path.glob("*turntable*"))


RECIPE = """\
[line]
name = "Video line"
[scene]
mesh = "lipstick"
resolution = [16, 16]
[substrate]
reflectance = 0.8
[[light]]
direction = [0.6, 0.5, 0.6]
[turntable]
frames = 2
[output]
fps = 12

[[product]]
name = "Rouge A"
material = "L1.json"
layer = [{ material = "self", thickness = "1 mm" }]

[[product]]
name = "Rouge B"
material = "L1.json"
layer = [{ material = "self", thickness = "0.2 mm" }]
"""


def test_kmpipe_run_writes_each_products_videos_once(tmp_path, material):
    (tmp_path / "L1.json").write_bytes(material.read_bytes())
    recipe = tmp_path / "recipe.toml"
    recipe.write_text(RECIPE, encoding="utf-8")
    out = tmp_path / "out"
    first = plan_run(recipe, out)
    videos = {t.id: t for t in first.tasks.values() if t.kind == "video"}
    assert set(videos) == {"video:rouge-a", "video:rouge-b"}
    assert set(videos["video:rouge-a"].deps) >= {"render:rouge-a:0-1"}
    assert execute(first).failed == []
    for product in ("rouge-a", "rouge-b"):
        frames, _, durations = webp_frames(out / "frames" / product / "turntable.webp")
        assert len(frames) == 2 and lasting(durations, 12)
        assert np.array_equal(frames[1][:16, :16], png(out / "frames" / product, 1))
        assert len(mp4_frames(out / "frames" / product / "turntable.mp4")[0]) == 2
    again = plan_run(recipe, out)
    assert {t.state for t in again.tasks.values()} == {"cached"}
    assert execute(again).ran == 0
    # Another frame rate: only the videos are made again.
    recipe.write_text(RECIPE.replace("fps = 12", "fps = 6"), encoding="utf-8")
    changed = plan_run(recipe, out)
    execute(changed)
    assert {t.id for t in changed.tasks.values() if t.state == "run"} == set(videos)
    assert lasting(webp_frames(out / "frames" / "rouge-a" / "turntable.webp")[2], 6)
