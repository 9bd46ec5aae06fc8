"""RAW photos as linear camera RGB (instruments.raw_photo), proved on synthetic DNG files of known linear values.

Every fixture is written by ``dng_fixtures`` from linear values; a value ``v`` is stored as
``round(black + v * (white - black))`` DN, so a correct reader returns ``v`` to within half a DN step.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import rawpy
from dng_fixtures import (
    XTRANS,
    mosaic,
    write_dng,
    write_jpeg,
    write_linear_dng,
    write_truncated_dng,
)

from instruments.raw_photo import SATURATION_MARGIN, RawPhoto, RawPhotoError, read_raw, tone_mapped_8bit

BLACK, WHITE = 512, 16383
STEP = 1.0 / (WHITE - BLACK)  # one DN in normalized units
TOL = STEP / 2 + 1e-12  # rounding to the nearest DN
FLAT = np.array([0.2, 0.5, 0.35])  # linear R, G, B
BAYER = ["RGGB", "BGGR", "GRBG", "GBRG"]
SHAPE = (32, 48)  # photosites; LibRaw refuses fewer than 22 on a side

# postprocess options that make LibRaw radiometric (shared/method/notes.md), at half size
RADIOMETRIC = {
    "gamma": (1, 1),
    "no_auto_bright": True,
    "output_bps": 16,
    "use_camera_wb": False,
    "use_auto_wb": False,
    "user_wb": [1, 1, 1, 1],
    "output_color": rawpy.ColorSpace.raw,
    "adjust_maximum_thr": 0.0,
    "user_flip": 0,
    "half_size": True,
}


def flat_image(shape=SHAPE, rgb=FLAT) -> np.ndarray:
    """Return a full-resolution (H, W, 3) linear image of one colour."""
    return np.broadcast_to(np.asarray(rgb, dtype=float), (*shape, 3)).copy()


def libraw_indices(pattern: str) -> list[list[int]]:
    """Return LibRaw's colour indices for a Bayer cell (b"RGBG"): R 0, B 2, G 1 in the row of R, G 3 in that of B."""
    rows = [pattern[:2], pattern[2:]]
    return [[{"R": 0, "B": 2}.get(letter, 1 if "R" in row else 3) for letter in row] for row in rows]


def dn(value: float, black: int = BLACK) -> int:
    """Return the DN a linear value is stored as."""
    return round(black + value * (WHITE - black))


# ---------------------------------------------------------------- values and CFA patterns


@pytest.mark.parametrize("half_size", [True, False], ids=["half", "full"])
@pytest.mark.parametrize("pattern", BAYER)
def test_a_flat_field_reads_back_its_linear_values_for_every_bayer_pattern(tmp_path, pattern, half_size):
    path = write_dng(tmp_path / f"{pattern}.dng", mosaic(flat_image(), pattern), pattern=pattern)

    photo = read_raw(path, half_size=half_size)

    expected_shape = (16, 24, 3) if half_size else (32, 48, 3)
    assert photo.rgb.shape == expected_shape
    assert photo.rgb.dtype == np.float64
    assert np.all(np.abs(photo.rgb - FLAT) <= TOL)
    assert photo.cfa == pattern
    assert photo.raw_pattern.tolist() == libraw_indices(pattern)
    assert photo.color_desc == b"RGBG"
    assert photo.black_level == (BLACK,) * 4
    assert photo.white_level == WHITE
    assert photo.camera == "kmpipe synthetic"
    assert photo.path == path
    assert photo.saturated.shape == expected_shape[:2]
    assert not photo.saturated.any()


def test_a_wrong_cfa_pattern_tag_permutes_the_channels_and_the_checks_see_it(tmp_path):
    """Samples laid out RGGB but tagged BGGR: R and B come back swapped, and so does the reported cell."""
    path = write_dng(tmp_path / "mislabelled.dng", mosaic(flat_image(), "RGGB"), pattern="BGGR")

    photo = read_raw(path)

    assert np.all(np.abs(photo.rgb - FLAT[[2, 1, 0]]) <= TOL)
    assert not np.allclose(photo.rgb, FLAT, atol=10 * STEP)  # the flat-field test above would fail
    assert photo.cfa == "BGGR"  # and so would its pattern check


def test_a_dng_without_cfa_pattern_is_rejected_not_decoded_wrongly(tmp_path):
    path = write_dng(tmp_path / "no_cfa.dng", mosaic(flat_image()), pattern=None)

    with pytest.raises(RawPhotoError, match="no colour filter pattern"):
        read_raw(path)


@pytest.mark.parametrize("half_size", [True, False], ids=["half", "full"])
def test_half_grey_reads_half_without_white_balance_or_rescaling(tmp_path, half_size):
    """0.5 grey with a 0.8 patch (LibRaw's default adjust_maximum_thr would read 0.5 as 0.625) and a strongly
    non-neutral AsShotNeutral (a camera white balance would make R, G, B unequal)."""
    linear = flat_image(rgb=(0.5, 0.5, 0.5))
    linear[:8, :8] = 0.8
    path = write_dng(tmp_path / "grey.dng", mosaic(linear), as_shot_neutral=(0.4, 1.0, 0.6))

    photo = read_raw(path, half_size=half_size)

    assert np.all(np.abs(photo.rgb[12:, 12:] - 0.5) <= TOL)  # away from the patch (rows and columns 0-7)
    assert np.all(np.abs(photo.rgb[:3, :3] - 0.8) <= TOL)


def test_the_grey_fixture_trips_the_libraw_traps_that_read_raw_avoids(tmp_path):
    """The fixture of the test above is sensitive: LibRaw's postprocess gets it wrong unless every option is set."""
    linear = flat_image(rgb=(0.5, 0.5, 0.5))
    linear[:8, :8] = 0.8
    path = write_dng(tmp_path / "grey.dng", mosaic(linear), as_shot_neutral=(0.4, 1.0, 0.6))
    default_maximum = {k: v for k, v in RADIOMETRIC.items() if k != "adjust_maximum_thr"}
    default_balance = {k: v for k, v in RADIOMETRIC.items() if k != "user_wb"}

    with rawpy.imread(str(path)) as raw:
        rescaled = raw.postprocess(**default_maximum)[10, 10] / 65535
    with rawpy.imread(str(path)) as raw:
        balanced = raw.postprocess(**default_balance)[10, 10] / 65535

    assert np.allclose(rescaled, 0.625, atol=1e-4)
    assert np.ptp(balanced) > 0.02
    assert np.all(np.abs(read_raw(path).rgb[10, 10] - 0.5) <= TOL)


@pytest.mark.parametrize("pattern", BAYER)
def test_agrees_with_libraw_postprocess_given_every_radiometric_option(tmp_path, pattern):
    """An independent decoder: LibRaw's own half-size output, with the notes' options, matches to 16-bit steps."""
    rng = np.random.default_rng(7)
    linear = rng.uniform(0.0, 0.9, (*SHAPE, 3))
    path = write_dng(tmp_path / "noise.dng", mosaic(linear, pattern), pattern=pattern)

    with rawpy.imread(str(path)) as raw:
        libraw = raw.postprocess(**RADIOMETRIC) / 65535

    assert np.all(np.abs(read_raw(path).rgb - libraw) <= 1 / 65535 + STEP)


def test_black_levels_are_subtracted_per_colour(tmp_path):
    """BlackLevel per 2x2 position (R, G1, G2, B = 500, 510, 540, 560 DN): each sample loses its own colour's black."""
    path = write_dng(tmp_path / "blacks.dng", mosaic(flat_image()), black_level=(500, 510, 540, 560))

    photo = read_raw(path)

    assert photo.black_level == (500, 510, 560, 540)  # by LibRaw colour index: R, G, B, second G
    assert np.all(np.abs(photo.rgb - FLAT) <= TOL)


# ---------------------------------------------------------------- geometry


def ramps(shape) -> np.ndarray:
    """Return a linear image whose R grows left to right, G top to bottom, B along the diagonal."""
    rows, cols = np.indices(shape, dtype=float)
    height, width = shape
    return np.stack(
        [0.1 + 0.8 * cols / (width - 1), 0.3 + 0.4 * rows / (height - 1), 0.2 + 0.5 * (rows + cols) / (height + width)],
        axis=-1,
    )


@pytest.mark.parametrize("orientation", [1, 3, 6, 8])
@pytest.mark.parametrize("shape", [(32, 48), (33, 49)])
def test_half_size_keeps_one_pixel_per_cell_in_sensor_orientation(tmp_path, shape, orientation):
    """Pixel (y, x) is cell (y, x): R, mean of the two G, B of photosites (2y..2y+1, 2x..2x+1); an odd last row
    and column are dropped; the Orientation tag (1 as stored, 3 rotated 180, 6 and 8 rotated 90) is ignored."""
    samples = mosaic(ramps(shape))
    path = write_dng(tmp_path / "ramps.dng", samples, orientation=orientation)
    stored = (np.round(BLACK + samples * (WHITE - BLACK)) - BLACK) / (WHITE - BLACK)

    photo = read_raw(path)

    height, width = shape[0] // 2, shape[1] // 2
    assert photo.rgb.shape == (height, width, 3)
    cells = stored[: 2 * height, : 2 * width]
    np.testing.assert_allclose(photo.rgb[..., 0], cells[0::2, 0::2], rtol=0, atol=1e-12)
    np.testing.assert_allclose(photo.rgb[..., 1], (cells[0::2, 1::2] + cells[1::2, 0::2]) / 2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(photo.rgb[..., 2], cells[1::2, 1::2], rtol=0, atol=1e-12)
    assert np.all(np.diff(photo.rgb[..., 0], axis=1) > 0)  # R grows to the right: not mirrored or rotated
    assert np.all(np.diff(photo.rgb[..., 1], axis=0) > 0)  # G grows downwards: not flipped


def test_full_size_interpolates_linear_ramps_exactly_and_keeps_every_sample(tmp_path):
    linear = ramps((33, 49))
    samples = mosaic(linear, "GBRG")
    path = write_dng(tmp_path / "ramps.dng", samples, pattern="GBRG", orientation=6)
    stored = (np.round(BLACK + samples * (WHITE - BLACK)) - BLACK) / (WHITE - BLACK)

    photo = read_raw(path, half_size=False)

    assert photo.rgb.shape == (33, 49, 3)
    assert np.all(np.abs(photo.rgb[1:-1, 1:-1] - linear[1:-1, 1:-1]) <= TOL)  # mean of rounded samples
    np.testing.assert_allclose(mosaic(photo.rgb, "GBRG"), stored, rtol=0, atol=1e-12)  # sites keep their samples


@pytest.mark.parametrize(
    ("border", "shape", "cfa"),
    [(2, (16, 24, 3), "RGGB"), (1, (15, 23, 3), "BGGR")],
    ids=["even border", "odd border"],
)
def test_masked_photosites_outside_the_active_area_are_not_used(tmp_path, border, shape, cfa):
    """A border at the white level around an RGGB flat field, outside the DNG ActiveArea (to which the DNG spec
    anchors CFAPattern). LibRaw widens an odd border to an even one, so that visible area starts on a B."""
    samples = np.ones((32 + 2 * border, 48 + 2 * border))
    samples[border:-border, border:-border] = mosaic(flat_image((32, 48)))
    path = write_dng(tmp_path / "masked.dng", samples, active_area=(border, border, 32 + border, 48 + border))

    photo = read_raw(path)

    assert photo.rgb.shape == shape
    assert np.all(np.abs(photo.rgb - FLAT) <= TOL)
    assert not photo.saturated.any()
    assert photo.cfa == cfa


# ---------------------------------------------------------------- saturation


def saturation_fixture(tmp_path):
    """Grey 0.5 (RGGB) with an R sample at the white level at (10, 20), a G sample within the margin at (5, 6)
    and a B sample just outside it at (21, 31)."""
    samples = mosaic(flat_image(rgb=(0.5, 0.5, 0.5)))
    samples[10, 20] = 1.0
    samples[5, 6] = 1.0 - SATURATION_MARGIN / 2
    samples[21, 31] = 1.0 - 2 * SATURATION_MARGIN
    return write_dng(tmp_path / "saturated.dng", samples)


def test_a_cell_with_a_sample_at_or_near_the_white_level_is_flagged(tmp_path):
    photo = read_raw(saturation_fixture(tmp_path))

    assert sorted(zip(*np.nonzero(photo.saturated), strict=True)) == [(2, 3), (5, 10)]
    assert photo.rgb[5, 10, 0] == 1.0  # the white level reads 1, not clipped or rescaled
    assert abs(photo.rgb[10, 15, 2] - (1.0 - 2 * SATURATION_MARGIN)) <= TOL  # measured, not flagged


def test_at_full_size_every_pixel_interpolated_from_a_clipped_sample_is_flagged(tmp_path):
    photo = read_raw(saturation_fixture(tmp_path), half_size=False)

    expected = np.zeros(SHAPE, dtype=bool)
    expected[9:12, 19:22] = True  # R at (10, 20) reaches its 3x3 neighbourhood
    expected[5, 5:8] = expected[4:7, 6] = True  # G at (5, 6) reaches its 4 edge neighbours only
    np.testing.assert_array_equal(photo.saturated, expected)


# ---------------------------------------------------------------- files that are not Bayer RAW


def text_file(path):
    path.write_text("wavelength_nm,reflectance\n380,0.1\n")
    return path


def empty_file(path):
    path.write_bytes(b"")
    return path


NOT_RAW = {
    "jpeg": lambda d: write_jpeg(d / "photo.jpg"),
    "text": lambda d: text_file(d / "spectra.dng"),
    "empty": lambda d: empty_file(d / "empty.dng"),
    "dng cut in its header": lambda d: write_truncated_dng(d / "cut.dng", 0.002),
    "dng cut in its tags": lambda d: write_truncated_dng(d / "cut.dng", 0.05),
    "dng cut in its pixels": lambda d: write_truncated_dng(d / "cut.dng", 0.5),
    "dng missing its last bytes": lambda d: write_truncated_dng(d / "cut.dng", 0.999),
    "missing file": lambda d: d / "absent.dng",
    "directory": lambda d: d,
}


@pytest.mark.parametrize("make", NOT_RAW.values(), ids=NOT_RAW.keys())
def test_a_file_that_is_not_a_raw_photo_raises_one_line_naming_it(tmp_path, make):
    path = make(tmp_path)

    with pytest.raises(RawPhotoError) as caught:
        read_raw(path)

    message = str(caught.value)
    assert isinstance(caught.value, ValueError)
    assert message.startswith(f"{path}: ")
    assert message.endswith("expected a camera RAW file with a 2x2 Bayer colour filter array (R, G, B)")
    assert "\n" not in message


NOT_BAYER = {
    "x-trans": (lambda d: write_dng(d / "xtrans.dng", np.full((36, 48), 0.5), pattern=XTRANS), "repeats every 6x6"),
    "cmyg": (lambda d: write_dng(d / "cmyg.dng", np.full(SHAPE, 0.5), pattern="CMYG"), "colour filter cell is"),
    "linear dng": (lambda d: write_linear_dng(d / "linear.dng", flat_image()), "decodes it as an RGB image"),
}


@pytest.mark.parametrize(("make", "reason"), NOT_BAYER.values(), ids=NOT_BAYER.keys())
def test_raw_files_that_are_not_rgb_bayer_are_rejected(tmp_path, make, reason):
    path = make(tmp_path)

    with pytest.raises(RawPhotoError, match=reason) as caught:
        read_raw(path)

    assert str(caught.value).startswith(f"{path}: ")


# ---------------------------------------------------------------- the photo object and the display copy


def test_a_photo_cannot_be_changed(tmp_path):
    photo = read_raw(str(write_dng(tmp_path / "flat.dng", mosaic(flat_image()))))

    assert isinstance(photo, RawPhoto)
    with pytest.raises(dataclasses.FrozenInstanceError):
        photo.rgb = np.zeros(3)
    for array in (photo.rgb, photo.saturated, photo.raw_pattern):
        with pytest.raises(ValueError, match="read-only"):
            array[0, 0] = 0


def test_the_display_copy_is_8_bit_srgb_encoded_per_channel_and_leaves_the_data_alone(tmp_path):
    linear = flat_image((32, 48))
    linear[:, :24] = (0.1, 0.25, 0.175)  # half the frame at half the light
    photo = read_raw(write_dng(tmp_path / "two.dng", mosaic(linear)))
    before = photo.rgb.copy()

    display = tone_mapped_8bit(photo.rgb)

    assert display.dtype == np.uint8
    assert display.shape == photo.rgb.shape
    assert np.all(display[:, 12:] == 255)  # each channel's 99th percentile is the bright half: white
    assert np.all(display[:, :12] == 188)  # half of it: sRGB-encoded 0.5 is 0.7354, 187.5 -> 188
    np.testing.assert_array_equal(photo.rgb, before)


@pytest.mark.parametrize(
    ("image", "percentile", "match"),
    [
        (np.zeros((4, 4)), 99.0, "shape"),
        (np.zeros((4, 4, 4)), 99.0, "shape"),
        (np.zeros((4, 4, 3)), 0.0, "percentile"),
        (np.full((4, 4, 3), np.nan), 99.0, "non-finite"),
    ],
)
def test_the_display_copy_rejects_what_is_not_an_rgb_image(image, percentile, match):
    with pytest.raises(ValueError, match=match):
        tone_mapped_8bit(image, percentile=percentile)


def test_the_display_copy_of_a_black_image_is_black():
    assert np.all(tone_mapped_8bit(np.zeros((4, 4, 3))) == 0)
