"""kmpipe card and kmpipe ingest-raw on synthetic cross-polarized RAW photos of a drawdown card.

The photos (tests/card_photo.py) show a card of known backing reflectances and a film of known per-channel K and S,
in perspective, rotated, with vignetting, sensor noise and an RGGB mosaic, written as DNG files.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from card_photo import Scene, photograph, region_reflectances
from dng_fixtures import write_jpeg

from instruments.drawdown_card.layout import default_layout
from kmpipe.cli import main
from kmpipe.formats.card_layout import load_card_layout, write_card_layout
from kmpipe.formats.material import read_material
from kmpipe.formats.spectra import read_spectra_csv

SCENE = Scene(
    backings={"black": np.array([0.040, 0.035, 0.030]), "white": np.array([0.86, 0.84, 0.80])},
    K=np.array([8.0, 15.0, 30.0]),
    S=np.array([60.0, 55.0, 50.0]),
)


def run(capsys, *args) -> tuple[int, str, str]:
    status = main([str(a) for a in args])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


@pytest.fixture(scope="module")
def card(tmp_path_factory):
    folder = tmp_path_factory.mktemp("card")
    layout = default_layout()
    write_card_layout(layout, folder / "layout.toml")
    photos = [folder / f"photo{i}.dng" for i in range(3)]
    for seed, photo in enumerate(photos):
        photograph(layout, replace(SCENE, angle_deg=5.0 + 4 * seed), photo, seed=seed)
    return folder, layout, photos


def test_ingest_gives_the_card_reflectances_and_fit_gives_back_k_and_s(card, tmp_path, capsys):
    folder, layout, photos = card
    out = tmp_path / "F9"
    status, _, err = run(
        capsys, "ingest-raw", *photos, "--layout", folder / "layout.toml", "-o", out, "--thickness", "30 um"
    )
    assert status == 0, err
    table = read_spectra_csv(out / "reflectance.csv")
    assert table.channels == ("R", "G", "B") and "camera RGB" in table.metadata["channels"]
    truth = region_reflectances(layout, SCENE)
    # Each photo is its own repeat of every film; the backings are averaged over the photos.
    for column in table.columns:
        region = column.rsplit("_", 1)[0] if column[-1].isdigit() else column
        np.testing.assert_allclose(table.column(column), truth[region], rtol=3e-3)
    assert sum(c.startswith("film_over_black") for c in table.columns) == 3
    # Pixel noise 0.2 % averaged over thousands of pixels leaves errors ~1e-4 in reflectance; the black/white
    # inversion of a 30 um film amplifies them about tenfold, so K and S must come back within 1 %.
    for method in ("black-white", "lsq"):
        material_path = tmp_path / f"{method}.json"
        status, _, err = run(capsys, "fit", out / "manifest.toml", "-o", material_path, "--method", method)
        assert status == 0, err
        material = read_material(material_path)
        assert material.channels == ("R", "G", "B")
        np.testing.assert_allclose(material.K, SCENE.K, rtol=0.01)
        np.testing.assert_allclose(material.S, SCENE.S, rtol=0.01)
    status, _, err = run(capsys, "validate", tmp_path / "lsq.json", "-o", tmp_path / "report")
    assert status == 0, err


def test_regions_given_by_hand_match_the_markers(card, tmp_path, capsys):
    """--roi (photos without markers): the same regions given in pixels read as the card mode reads them."""
    folder, layout, _ = card
    photo = tmp_path / "straight.dng"
    H = photograph(layout, replace(SCENE, angle_deg=0.0, tilt=0.0, vignetting=0.0), photo)
    rois = []
    for region in layout.regions:
        if region.role in ("backing", "film", "white_reference"):
            x0, y0 = region.x_mm + 3, region.y_mm + 3
            corners = np.array([[x0, y0, 1.0], [x0 + region.w_mm - 6, y0 + region.h_mm - 6, 1.0]]) @ H.T
            (ax, ay), (bx, by) = corners[:, :2] / corners[:, 2:] / 2  # the decoded photo is half size
            rois += ["--roi", f"{region.name}={int(ax)},{int(ay)},{int(bx - ax)},{int(by - ay)}"]
    status, _, err = run(
        capsys,
        "ingest-raw",
        photo,
        "--layout",
        folder / "layout.toml",
        "-o",
        tmp_path / "roi",
        "--thickness",
        "30 um",
        *rois,
    )
    assert status == 0, err
    by_hand = read_spectra_csv(tmp_path / "roi" / "reflectance.csv")
    truth = region_reflectances(layout, SCENE)
    for column in by_hand.columns:
        np.testing.assert_allclose(by_hand.column(column), truth[column], rtol=3e-3)


@pytest.mark.parametrize(
    ("scene", "expected"),
    [
        (replace(SCENE, exposure=1.6), "clipped"),
        (replace(SCENE, highlight="film_over_black"), "uneven"),
        (replace(SCENE, exposure=0.02), "underexposed"),
    ],
    ids=["clipped", "highlight", "underexposed"],
)
def test_bad_photos_are_refused_by_name_and_nothing_is_written(card, tmp_path, capsys, scene, expected):
    folder, layout, _ = card
    photo = tmp_path / "bad.dng"
    photograph(layout, scene, photo)
    out = tmp_path / "out"
    status, _, err = run(
        capsys, "ingest-raw", photo, "--layout", folder / "layout.toml", "-o", out, "--thickness", "30 um"
    )
    assert status == 2
    assert expected in err and "bad.dng" in err and "Traceback" not in err
    assert not (out / "reflectance.csv").exists() and not (out / "manifest.toml").exists()


def test_markers_hidden_and_files_that_are_not_raw(card, tmp_path, capsys):
    folder, layout, _ = card
    # One marker hidden: the other three locate the card.
    photo = tmp_path / "three.dng"
    photograph(layout, replace(SCENE, hide_marker=layout.markers[0].id), photo)
    status, _, err = run(
        capsys, "ingest-raw", photo, "--layout", folder / "layout.toml", "-o", tmp_path / "a", "--thickness", "30 um"
    )
    assert status == 0, err
    # A JPEG is not a RAW photo.
    jpeg = write_jpeg(tmp_path / "photo.jpg")
    status, _, err = run(capsys, "ingest-raw", jpeg, "--layout", folder / "layout.toml", "-o", tmp_path / "b")
    assert status == 2 and "photo.jpg" in err and "RAW" in err
    assert not (tmp_path / "b").exists()


def test_a_card_whose_markers_are_all_hidden_but_one_is_not_found(card, tmp_path, capsys, monkeypatch):
    folder, layout, _ = card
    photo = tmp_path / "one.dng"
    hidden = [m.id for m in layout.markers[1:]]
    import card_photo

    original = card_photo.linear_card

    def hide_all(layout_, scene):
        image = original(layout_, scene)
        for marker in layout_.markers:
            if marker.id in hidden:
                x0, y0 = round(marker.x_mm * card_photo.PX_PER_MM), round(marker.y_mm * card_photo.PX_PER_MM)
                size = round(marker.size_mm * card_photo.PX_PER_MM)
                image[y0 : y0 + size, x0 : x0 + size] = 0.85
        return image

    monkeypatch.setattr(card_photo, "linear_card", hide_all)
    photograph(layout, SCENE, photo)
    status, _, err = run(capsys, "ingest-raw", photo, "--layout", folder / "layout.toml", "-o", tmp_path / "c")
    assert status == 2 and "one.dng" in err and "--roi" in err


def test_card_command_writes_a_printable_card_and_its_layout(tmp_path, capsys):
    status, _, err = run(capsys, "card", "-o", tmp_path / "card.pdf")
    assert status == 0, err
    assert (tmp_path / "card.pdf").read_bytes().startswith(b"%PDF")
    layout = load_card_layout(tmp_path / "card.layout.toml")
    assert layout == default_layout()
    status, _, err = run(capsys, "card", "-o", tmp_path / "card.png", "--layout", tmp_path / "card.layout.toml")
    assert status == 0, err
    assert (tmp_path / "card.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    status, _, err = run(capsys, "card", "-o", tmp_path / "card.svg")
    assert status == 2 and "png or .pdf" in err


def test_a_colorchecker_in_the_photo_gives_device_independent_channels(tmp_path, capsys):
    """With the chart in its slot, regions come out as X/Xn, Y/Yn, Z/Zn: the synthetic camera's true matrix maps
    the regions' camera reflectance to XYZ, so the expected values are known independently of the fit."""
    from card_photo import TRUE_CAMERA_MATRIX

    from kmpipe.physics.colorimetry import white_XYZ

    layout = default_layout()
    write_card_layout(layout, tmp_path / "layout.toml")
    photo = tmp_path / "chart.dng"
    photograph(layout, replace(SCENE, colorchecker=True), photo)
    status, _, err = run(
        capsys, "ingest-raw", photo, "--layout", tmp_path / "layout.toml", "-o", tmp_path / "x", "--thickness", "30 um"
    )
    assert status == 0, err
    table = read_spectra_csv(tmp_path / "x" / "reflectance.csv")
    assert table.channels == ("X", "Y", "Z") and "ColorChecker" in table.metadata["channels"]
    white = white_XYZ(np.arange(380.0, 781.0, 5.0), "D65", "2")
    truth = region_reflectances(layout, SCENE)
    for column in table.columns:
        expected = TRUE_CAMERA_MATRIX @ truth[column] / white
        np.testing.assert_allclose(table.column(column), expected, rtol=5e-3)
