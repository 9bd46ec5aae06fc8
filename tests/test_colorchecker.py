"""Finding a ColorChecker on a drawdown card photo and fitting a camera RGB -> XYZ matrix to it.

The photos (tests/card_photo.py, ``Scene(colorchecker=True)``) hold a synthetic ColorChecker Classic Mini in the
card's ``colorchecker`` slot whose patches are the camera RGB of a camera with the known matrix TRUE_CAMERA_MATRIX
(XYZ = camera_rgb @ M.T exactly: a Luther camera), photographed in perspective, rotated, vignetted, with 0.2 % pixel
noise, RGGB mosaic -> DNG -> read_raw (half size, about 3 px per card mm, so a patch's sampled centre, 5.5 mm square,
is about 250 pixels).

Tolerances. The camera is exactly linear in XYZ, so the fit's only errors come from the measurement: 0.2 % noise
over ~250 pixels is ~1.3e-4 relative per patch mean, and the flat field (a quadratic fitted to the bare paper,
matching the synthetic vignetting 1 - v r^2 exactly) adds a few 1e-4. A relative error e in a patch's XYZ is at
most about 100 e / 3 * 2 ~ 0.1 Delta E 2000 at e = 1e-3 for a mid grey (L* changes by ~ 116 / 3 * e * (Y/Yn)^(1/3)),
and least as much for the chromatic patches. So the fitted colours must be well within the brief's bounds
(mean < 0.5, max < 1.5 Delta E 2000 at 0.2 % noise): we assert mean < 0.1, max < 0.3, and the matrix within 0.5 %
of the truth (relative to its largest element).
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
from card_photo import CHART_CAMERA_RGB, TRUE_CAMERA_MATRIX, Scene, photograph

from instruments.colorchecker import (
    PATCH_NAMES,
    ColorCheckerNotFound,
    find_colorchecker,
    neutral_row_descends,
    sample_colorchecker_in_slot,
)
from instruments.drawdown_card.flat_field import paper_illumination
from instruments.drawdown_card.layout import Region, default_layout
from instruments.drawdown_card.locate import locate_card
from instruments.drawdown_card.sampling import sample_region
from instruments.raw_photo import read_raw, tone_mapped_8bit
from kmpipe.physics.colour_correction import fit_camera_to_XYZ, reference_XYZ

SCENE = Scene(
    backings={"black": np.array([0.040, 0.035, 0.030]), "white": np.array([0.86, 0.84, 0.80])},
    K=np.array([8.0, 15.0, 30.0]),
    S=np.array([60.0, 55.0, 50.0]),
    colorchecker=True,
    colorchecker_offset_mm=(2.5, -3.0),  # placed by hand: off centre and a little turned in the slot
    colorchecker_angle_deg=3.0,
)
LAYOUT = default_layout()
SLOT = LAYOUT.region("colorchecker")


def shot(tmp_path, scene: Scene, name: str = "photo", seed: int = 0):
    path = tmp_path / f"{name}.dng"
    photograph(LAYOUT, scene, path, seed=seed)
    raw = read_raw(path)
    display = tone_mapped_8bit(raw.rgb)
    return raw, display, locate_card(display, LAYOUT)


def slot_polygon_px(location, grow_mm: float = 3.0) -> np.ndarray:
    x0, y0 = SLOT.x_mm - grow_mm, SLOT.y_mm - grow_mm
    x1, y1 = SLOT.x_mm + SLOT.w_mm + grow_mm, SLOT.y_mm + SLOT.h_mm + grow_mm
    return location.card_to_image([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])


def reflectance_scale(sample, raw, location) -> np.ndarray:
    """Patch means flat-fielded by the paper's light and put on the reflectance scale by the white reference."""
    light = paper_illumination(raw.rgb, location, LAYOUT)
    centres_mm = cv2.perspectiveTransform(
        sample.centres_px.reshape(-1, 1, 2), np.linalg.inv(location.homography)
    ).reshape(-1, 2)
    white = LAYOUT.region("white_reference")
    white_reading = sample_region(raw.rgb, location, white).mean / light(
        [white.x_mm + white.w_mm / 2, white.y_mm + white.h_mm / 2]
    )
    return sample.mean / light(centres_mm) * (white.metadata["reflectance"] / white_reading)


@pytest.fixture(scope="module")
def photo(tmp_path_factory):
    return shot(tmp_path_factory.mktemp("chart"), SCENE)


def assert_fit_recovers_the_camera(rgb, clipped_fraction=None):
    fit = fit_camera_to_XYZ(rgb, clipped_fraction=clipped_fraction)
    assert fit.mean_delta_E < 0.1 and fit.max_delta_E < 0.3, (fit.mean_delta_E, fit.max_delta_E)
    assert np.abs(fit.matrix - TRUE_CAMERA_MATRIX).max() < 5e-3 * np.abs(TRUE_CAMERA_MATRIX).max(), fit.matrix
    np.testing.assert_allclose(fit.apply(rgb), reference_XYZ(), rtol=0.01, atol=0.1)
    return fit


def test_slot_path_samples_the_patches_and_the_fit_recovers_the_camera(photo):
    raw, _, location = photo
    sample = sample_colorchecker_in_slot(raw.rgb, location, SLOT, mask=raw.saturated)
    assert sample.method == "slot" and sample.confidence > 0.8
    assert sample.mean.shape == (24, 3) and sample.polygons_px.shape == (24, 4, 2) and sample.count.min() > 150
    assert not sample.clipped_fraction.any()
    rgb = reflectance_scale(sample, raw, location)
    np.testing.assert_allclose(rgb, CHART_CAMERA_RGB, rtol=2e-3)
    # Away from the patch edges: the spread within a patch is the pixel noise (0.2 % of the signal), not a mix.
    assert np.all(sample.std / sample.mean < 0.01)
    assert_fit_recovers_the_camera(rgb)


def test_mcc_detects_the_chart_in_the_standard_order(photo):
    raw, display, location = photo
    slot = sample_colorchecker_in_slot(raw.rgb, location, SLOT)
    for search in (None, slot_polygon_px(location)):
        sample = find_colorchecker(display, raw.rgb, search_polygon_px=search, mask=raw.saturated)
        assert sample is not None and sample.method == "mcc" and sample.confidence > 0.9
        # The same patches as the slot path, in the same (standard) order.
        assert np.max(np.linalg.norm(sample.centres_px - slot.centres_px, axis=-1)) < 3.0  # px, of 33 px patches
        np.testing.assert_allclose(sample.mean, slot.mean, rtol=2e-3)
        assert_fit_recovers_the_camera(reflectance_scale(sample, raw, location))


def test_mcc_on_a_full_size_display_copy_measures_the_half_size_data(photo, tmp_path):
    raw, _, _ = photo
    path = tmp_path / "full.dng"
    photograph(LAYOUT, SCENE, path, seed=0)
    full = read_raw(path, half_size=False)
    sample_full = find_colorchecker(tone_mapped_8bit(full.rgb), raw.rgb)
    sample_half = find_colorchecker(tone_mapped_8bit(raw.rgb), raw.rgb)
    assert sample_full is not None and sample_half is not None
    assert np.max(np.linalg.norm(sample_full.centres_px - sample_half.centres_px, axis=-1)) < 2.0
    np.testing.assert_allclose(sample_full.mean, sample_half.mean, rtol=2e-3)


def test_a_chart_turned_half_a_turn_is_read_in_the_standard_order(tmp_path):
    raw, display, location = shot(tmp_path, replace(SCENE, colorchecker_angle_deg=182.0))
    sample = sample_colorchecker_in_slot(raw.rgb, location, SLOT, orientation="auto")
    np.testing.assert_allclose(reflectance_scale(sample, raw, location), CHART_CAMERA_RGB, rtol=3e-3)
    with pytest.raises(ColorCheckerNotFound, match="neutral row"):
        sample_colorchecker_in_slot(raw.rgb, location, SLOT, orientation="portrait")
    with pytest.raises(ColorCheckerNotFound, match="lies portrait"):
        sample_colorchecker_in_slot(raw.rgb, location, SLOT, orientation="landscape")
    mcc = find_colorchecker(display, raw.rgb)
    assert mcc is not None
    np.testing.assert_allclose(mcc.mean, sample.mean, rtol=3e-3)


def test_no_chart_gives_none_or_a_clear_error(tmp_path):
    raw, display, location = shot(tmp_path, replace(SCENE, colorchecker=False))
    assert find_colorchecker(display, raw.rgb) is None
    assert find_colorchecker(display, raw.rgb, search_polygon_px=slot_polygon_px(location)) is None
    with pytest.raises(ColorCheckerNotFound, match="no ColorChecker in slot 'colorchecker'"):
        sample_colorchecker_in_slot(raw.rgb, location, SLOT)
    # Something dark of the wrong size (the black stripe, 66 x 46 mm of it here) is not taken for a chart either.
    probe = Region("probe", "colorchecker", 12.0, 20.0, 66.0, 96.0)
    with pytest.raises(ColorCheckerNotFound, match=r"57 x 83 mm chart body was expected"):
        sample_colorchecker_in_slot(raw.rgb, location, probe)


def test_clipped_patches_are_reported_and_left_out_of_the_fit(tmp_path):
    # Exposure 1.3 with even light: the white patch (0.9) reads 1.17 of full scale and clips; the next brightest
    # patches (yellow 0.66, neutral 8 0.59) stay below 0.9. The paper clips too, so no flat field is needed or used.
    exposure = 1.3
    raw, display, location = shot(tmp_path, replace(SCENE, exposure=exposure, vignetting=0.0))
    for sample in (
        sample_colorchecker_in_slot(raw.rgb, location, SLOT, mask=raw.saturated),
        find_colorchecker(display, raw.rgb, mask=raw.saturated),
    ):
        assert sample is not None
        assert sample.clipped_fraction[18] > 0.9 and not np.delete(sample.clipped_fraction, 18).any()
        fit = fit_camera_to_XYZ(sample.mean, clipped_fraction=sample.clipped_fraction)
        assert fit.excluded == (18,) and not fit.used[18] and fit.white_patch == 19  # neutral 8 sets the scale
        assert fit.mean_delta_E < 0.1 and fit.max_delta_E < 0.3
        assert fit.delta_E[18] > 1.0  # the clipped white, evaluated but not fitted, is off
        np.testing.assert_allclose(fit.matrix * exposure, TRUE_CAMERA_MATRIX, atol=5e-3 * 112)
        # Fitted with the clipped patch in, the colours are visibly worse.
        assert fit_camera_to_XYZ(sample.mean).max_delta_E > 3 * fit.max_delta_E


def test_fit_on_exact_data_and_its_checks():
    XYZ = reference_XYZ()
    assert XYZ.shape == (24, 3) and 85 < XYZ[18, 1] < 92 and XYZ[23, 1] < 4  # white 9.5 and black 2, Y in %
    rgb = 0.37 * XYZ @ np.linalg.inv(TRUE_CAMERA_MATRIX).T  # any exposure
    fit = fit_camera_to_XYZ(rgb)
    np.testing.assert_allclose(fit.matrix, TRUE_CAMERA_MATRIX / 0.37, rtol=1e-9)
    assert fit.max_delta_E < 1e-6 and fit.excluded == () and fit.white_patch == 18
    np.testing.assert_allclose(fit.apply(rgb.reshape(4, 6, 3)), XYZ.reshape(4, 6, 3), rtol=1e-9)
    # Another illuminant has its own targets: the D65 camera data no longer fit exactly.
    assert fit_camera_to_XYZ(rgb, illuminant="A").max_delta_E > 0.1
    with pytest.raises(ValueError, match=r"\(24, 3\)"):
        fit_camera_to_XYZ(rgb[:18])
    with pytest.raises(ValueError, match="at least 6"):
        fit_camera_to_XYZ(rgb, weights=np.r_[np.ones(5), np.zeros(19)])
    with pytest.raises(ValueError, match="patch number"):
        fit_camera_to_XYZ(rgb, white_patch=0)
    assert len(PATCH_NAMES) == 24
    assert neutral_row_descends(rgb) and not neutral_row_descends(rgb[::-1])
