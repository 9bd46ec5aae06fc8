"""The drawdown card: layout TOML, printing, locating the card in a warped photo, sampling its regions."""

import math
import re
import struct

import cv2
import numpy as np
import OpenImageIO as oiio
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from instruments.drawdown_card.layout import Layout, LayoutError, Marker, Region, default_layout
from instruments.drawdown_card.locate import CardLocation, CardNotFound, locate_card
from instruments.drawdown_card.printing import render_card, write_card
from instruments.drawdown_card.sampling import sample_pixels, sample_region
from kmpipe import cli
from kmpipe.errors import InputError
from kmpipe.formats.card_layout import load_card_layout, write_card_layout

PPM = 6.0  # px per mm of the cards rendered here
CANVAS = 1700  # side (px) of the simulated photo: holds the card at any rotation at scales up to 1
BACKGROUND = 70  # 8-bit grey of the table around the card
LAYOUT = default_layout()
CARD = render_card(LAYOUT, PPM)
RENDER_MM_TO_PX = np.array([[PPM, 0, -0.5], [0, PPM, -0.5], [0, 0, 1.0]])  # card mm -> rendered px (pixel centres)
CARD_CORNERS_MM = np.array([[0, 0], [LAYOUT.width_mm, 0], [LAYOUT.width_mm, LAYOUT.height_mm], [0, LAYOUT.height_mm]])


def apply(homography, points):
    """Map points (N, 2) through a homography."""
    return cv2.perspectiveTransform(np.asarray(points, dtype=np.float64).reshape(-1, 1, 2), homography).reshape(-1, 2)


def random_warp(seed):
    """A random rotation (any angle), scale (0.5-1), shift and perspective of the rendered card onto the canvas.

    Returns the rendered-px -> canvas-px homography.
    """
    rng = np.random.default_rng(seed)
    h, w = CARD.shape[:2]
    source = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    angle, scale = rng.uniform(-math.pi, math.pi), rng.uniform(0.5, 1.0)
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    target = (source - [w / 2, h / 2]) @ rotation.T * scale + CANVAS / 2 + rng.uniform(-40, 40, 2)
    target += rng.uniform(-0.05, 0.05, (4, 2)) * w * scale  # perspective: each corner moved independently
    assert target.min() > 0 and target.max() < CANVAS - 1
    return cv2.getPerspectiveTransform(source.astype(np.float32), target.astype(np.float32))


def photograph(card, warp, border=BACKGROUND):
    """The card image warped onto the canvas (bilinear), the way a camera would see it."""
    return cv2.warpPerspective(card, warp, (CANVAS, CANVAS), flags=cv2.INTER_LINEAR, borderValue=(border,) * 3)


def cover_marker(photo, warp, marker):
    """Paint over a marker and its quiet zone in a photo, with the table's grey."""
    pad = marker.size_mm / 6
    corners = Marker(marker.id, marker.x_mm - pad, marker.y_mm - pad, marker.size_mm + 2 * pad).corners_mm()
    polygon = apply(warp @ RENDER_MM_TO_PX, corners)
    cv2.fillConvexPoly(photo, np.round(polygon).astype(np.int32), (BACKGROUND,) * 3)


def corner_error_px(location, truth):
    """Largest distance (px) between the card corners mapped by the located and by the true homography."""
    return float(
        np.max(np.linalg.norm(location.card_to_image(CARD_CORNERS_MM) - apply(truth, CARD_CORNERS_MM), axis=1))
    )


# ---------------------------------------------------------------------------------------------------------------
# Layout and TOML


def test_default_layout_is_an_a5_card_with_the_documented_regions():
    assert (LAYOUT.width_mm, LAYOUT.height_mm) == (210.0, 148.0)
    assert sorted(m.id for m in LAYOUT.markers) == [0, 1, 2, 3]
    roles = {r.name: r.role for r in LAYOUT.regions}
    assert roles == {
        "black": "backing",
        "white": "backing",
        "film_over_black": "film",
        "film_over_white": "film",
        "white_reference": "white_reference",
        "colorchecker": "colorchecker",
    }
    assert LAYOUT.region("film_over_black").metadata["over"] == "black"
    assert LAYOUT.region("film_over_white").metadata["over"] == "white"
    assert LAYOUT.region("white_reference").metadata["reflectance"] == pytest.approx(0.9)
    checker = LAYOUT.region("colorchecker")
    assert checker.w_mm >= 57 + 4 and checker.h_mm >= 83 + 4  # a ColorChecker Classic Mini with room around it


def test_layout_round_trips_through_toml(tmp_path):
    path = tmp_path / "card.toml"
    write_card_layout(LAYOUT, path)
    assert load_card_layout(path) == LAYOUT
    assert [p.name for p in tmp_path.iterdir()] == ["card.toml"]  # no temporary file left behind


@settings(max_examples=60, deadline=None)
@given(
    metadata=st.dictionaries(
        st.text(min_size=1).filter(lambda key: key not in ("name", "role", "x_mm", "y_mm", "w_mm", "h_mm")),
        st.one_of(
            st.text(),
            st.booleans(),
            st.integers(-(2**63), 2**63 - 1),
            st.floats(allow_nan=False),
            st.lists(st.one_of(st.text(max_size=5), st.integers(-9, 9)), max_size=3),
        ),
        max_size=4,
    )
)
def test_region_metadata_passes_through_toml_untouched(tmp_path_factory, metadata):
    region = Region("film", "film", 30.0, 30.0, 40.0, 30.0, metadata)
    markers = (Marker(0, 5, 5, 18), Marker(1, 177, 5, 18), Marker(2, 5, 117, 18))
    layout = Layout(200.0, 140.0, "DICT_5X5_100", markers, (region,))
    path = tmp_path_factory.mktemp("metadata") / "card.toml"
    write_card_layout(layout, path)
    loaded = load_card_layout(path)
    assert loaded == layout
    assert dict(loaded.regions[0].metadata) == metadata


def test_a_layout_as_people_write_it_reads(tmp_path):
    """The documented form, arrays of tables written out ([[marker]]), reads as the layout it describes."""
    path = tmp_path / "card.toml"
    path.write_text(HAND_WRITTEN, encoding="utf-8")
    assert load_card_layout(path) == LAYOUT


def _toml_value(value):
    return repr(value).lower() if isinstance(value, bool) else f'"{value}"' if isinstance(value, str) else repr(value)


def _hand_written(layout):
    """The layout in the form docs/formats.md shows, one key per line and [[...]] for every entry."""
    blocks = [f"[card]\nwidth_mm = {layout.width_mm!r}\nheight_mm = {layout.height_mm!r}\n"
              f'dictionary = "{layout.dictionary}"\n']  # fmt: skip
    for table, entries in (("marker", layout.markers), ("printed", layout.printed), ("region", layout.regions)):
        for entry in entries:
            values = {k: v for k, v in vars(entry).items() if k != "metadata"} | dict(getattr(entry, "metadata", {}))
            blocks.append(f"[[{table}]]\n" + "".join(f"{k} = {_toml_value(v)}\n" for k, v in values.items()))
    return "\n".join(blocks)


def edit(text, old, new):
    assert old in text, old
    return text.replace(old, new, 1)


def drop_markers(text, *ids):
    blocks = text.split("\n\n")
    return "\n\n".join(b for b in blocks if not any(b.startswith(f"[[marker]]\nid = {i}\n") for i in ids))


HAND_WRITTEN = _hand_written(LAYOUT)
#: A broken layout -> the field named (entries counted from 1) and the line's text, or None where there is no line
BAD_LAYOUTS = {
    "unknown card key": (
        edit(HAND_WRITTEN, 'dictionary = "DICT_4X4_50"', 'dictionary = "DICT_4X4_50"\ncolour = "red"'),
        "card.colour",
        'colour = "red"',
    ),
    "unknown marker key": (
        edit(HAND_WRITTEN, "size_mm = 16.0", "size_mm = 16.0\nrotation = 90"),
        "marker[1].rotation",
        "rotation = 90",
    ),
    "unknown printed key": (edit(HAND_WRITTEN, "gray = 0.0", "gray = 0.0\nink = 'K'"), "printed[1].ink", "ink = 'K'"),
    "unknown table": (HAND_WRITTEN + "\n[extra]\na = 1\n", "extra", "[extra]"),
    "unknown dictionary": (edit(HAND_WRITTEN, "DICT_4X4_50", "DICT_4X4_51"), "card.dictionary", 'dictionary = "DICT'),
    "too few markers": (drop_markers(HAND_WRITTEN, 2, 3), "marker", "[[marker]]"),
    "duplicate id": (edit(HAND_WRITTEN, "id = 3", "id = 0"), "marker[4].id", "id = 0"),
    "id outside the dictionary": (edit(HAND_WRITTEN, "id = 3", "id = 50"), "marker[4].id", "id = 50"),
    "marker off the card": (edit(HAND_WRITTEN, "x_mm = 190.0", "x_mm = 193.0"), "marker[2].x_mm", "x_mm = 193.0"),
    "duplicate name": (edit(HAND_WRITTEN, 'name = "white"', 'name = "black"'), "region[2].name", 'name = "black"'),
    "bad name": (edit(HAND_WRITTEN, 'name = "white"', 'name = "white card"'), "region[2].name", 'name = "white card"'),
    "bad role": (edit(HAND_WRITTEN, 'role = "backing"', 'role = "substrate"'), "region[1].role", 'role = "substrate"'),
    "region outside the card": (edit(HAND_WRITTEN, "x_mm = 136.0", "x_mm = 150.0"), "region[6].x_mm", "x_mm = 150.0"),
    "region over a marker": (edit(HAND_WRITTEN, "x_mm = 30.0", "x_mm = 20.0"), "region[5].x_mm", "x_mm = 20.0"),
    "printed area over a marker": (edit(HAND_WRITTEN, "y_mm = 25.0", "y_mm = 20.0"), "printed[1].x_mm", "x_mm = 10.0"),
    "printed grey out of range": (edit(HAND_WRITTEN, "gray = 0.0", "gray = 2.0"), "printed[1].gray", "gray = 2.0"),
    "missing field": (edit(HAND_WRITTEN, "h_mm = 30.0\n", ""), "region[1].h_mm", "[[region]]"),
    "wrong type": (edit(HAND_WRITTEN, "size_mm = 16.0", 'size_mm = "16"'), "marker[1].size_mm", 'size_mm = "16"'),
    "zero size": (edit(HAND_WRITTEN, "w_mm = 40.0", "w_mm = 0"), "region[1].w_mm", "w_mm = 0"),
    "card table missing": (HAND_WRITTEN.replace("[card]", "[cards]"), "cards", "[cards]"),
    "nested metadata": (edit(HAND_WRITTEN, 'over = "black"', "over = { a = 1 }"), "region[3].over", "over = { a = 1 }"),
    "invalid TOML": (HAND_WRITTEN + "\nx = = 1\n", None, "x = = 1"),
}


@pytest.mark.parametrize("case", BAD_LAYOUTS)
def test_bad_layout_is_refused_naming_file_line_and_field(tmp_path, case):
    text, field, line_text = BAD_LAYOUTS[case]
    path = tmp_path / "my_card.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as error:
        load_card_layout(path)
    assert (error.value.path, error.value.field) == (path, field)
    assert line_text in text.splitlines()[error.value.line - 1]
    assert str(error.value).startswith(f"{path}, line {error.value.line}: ")


def test_a_bad_layout_exits_2_with_a_message_naming_the_field(tmp_path, capsys):
    path = tmp_path / "card.toml"
    path.write_text(edit(HAND_WRITTEN, "id = 3", "id = 0"), encoding="utf-8")
    assert cli.main(["card", "--layout", str(path), "-o", str(tmp_path / "card.png")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert f"{path}, line" in err and "field 'marker[4].id': duplicate id 0 (also marker[1])" in err
    assert not (tmp_path / "card.png").exists()


def test_missing_layout_file_is_refused_naming_it(tmp_path):
    with pytest.raises(InputError, match="does not exist") as error:
        load_card_layout(tmp_path / "nowhere.toml")
    assert error.value.path == tmp_path / "nowhere.toml"


def test_layout_built_in_code_is_checked_too():
    markers = (Marker(0, 5, 5, 18), Marker(1, 177, 5, 18), Marker(2, 5, 117, 18))
    with pytest.raises(
        LayoutError, match=r"^region\[1\]\.x_mm: region 'a' \(x_mm, y_mm, w_mm, h_mm\) overlaps marker\[1\]"
    ):
        Layout(200.0, 140.0, "DICT_4X4_50", markers, (Region("a", "film", 20, 20, 30, 30),))
    with pytest.raises(LayoutError, match=r"^region\[1\]: region 'a': 'x_mm' is not a usable metadata key") as error:
        Layout(200.0, 140.0, "DICT_4X4_50", markers, (Region("a", "film", 40, 40, 30, 30, {"x_mm": 1.0}),))
    assert error.value.loc == ("region", 0)


# ---------------------------------------------------------------------------------------------------------------
# Rendering and printing


def region_pixels(image, region, ppm=PPM):
    """The pixels of a rendered card that fall inside a region."""
    x0, y0 = round(region.x_mm * ppm), round(region.y_mm * ppm)
    return image[y0 : round((region.y_mm + region.h_mm) * ppm), x0 : round((region.x_mm + region.w_mm) * ppm)]


def test_render_card_prints_stripes_and_nothing_inside_the_regions():
    assert CARD.shape == (round(148 * PPM), round(210 * PPM), 3) and CARD.dtype == np.uint8
    for name, value in [("black", 0), ("film_over_black", 0), ("white", 255), ("film_over_white", 255)]:
        assert np.all(region_pixels(CARD, LAYOUT.region(name)) == value), name
    assert np.all(region_pixels(CARD, LAYOUT.region("colorchecker")) == 255)
    above_black = CARD[round(27 * PPM) : round(33 * PPM), round(16 * PPM) : round(56 * PPM)]
    assert np.any(above_black > 0)  # outline and label printed on the black stripe, outside the region


def test_render_card_paints_region_colors():
    colors = {"black": (0.2, 0.4, 0.6), "white_reference": (1.0, 0.5, 0.0)}
    image = render_card(LAYOUT, 4.0, region_colors=colors)
    for name, rgb in colors.items():
        assert np.all(region_pixels(image, LAYOUT.region(name), 4.0) == np.round(np.array(rgb) * 255)), name
    with pytest.raises(ValueError, match="unknown regions"):
        render_card(LAYOUT, 4.0, region_colors={"grey": (0.5, 0.5, 0.5)})


def test_write_card_png_at_300_dpi(tmp_path):
    path = tmp_path / "card.png"
    write_card(LAYOUT, path)
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert image.shape == (round(148 / 25.4 * 300), round(210 / 25.4 * 300), 3) == (1748, 2480, 3)
    assert np.array_equal(cv2.cvtColor(image, cv2.COLOR_BGR2RGB), render_card(LAYOUT, 300 / 25.4))
    data = path.read_bytes()
    x_per_metre, y_per_metre, unit = struct.unpack(">IIB", data[data.index(b"pHYs") + 4 :][:9])
    assert (x_per_metre, y_per_metre, unit) == (11811, 11811, 1)  # pixels per metre: 300 / 0.0254 = 11811.02
    spec = oiio.ImageInput.open(str(path)).spec()
    assert spec.getattribute("XResolution") == pytest.approx(300.0, abs=0.01)
    assert spec.getattribute("YResolution") == pytest.approx(300.0, abs=0.01)
    assert spec.getattribute("ResolutionUnit") in ("in", "inch")
    assert [p.name for p in tmp_path.iterdir()] == ["card.png"]


def test_write_card_pdf_page_is_the_card_size(tmp_path):
    path = tmp_path / "card.pdf"
    write_card(LAYOUT, path)
    data = path.read_bytes()
    assert data.startswith(b"%PDF")
    boxes = re.findall(rb"/MediaBox\s*\[\s*0\s+0\s+([\d.]+)\s+([\d.]+)\s*\]", data)
    assert len(boxes) == 1
    width_pt, height_pt = (float(v) for v in boxes[0])
    assert width_pt == pytest.approx(210 / 25.4 * 72, abs=0.01)
    assert height_pt == pytest.approx(148 / 25.4 * 72, abs=0.01)
    assert [p.name for p in tmp_path.iterdir()] == ["card.pdf"]


def test_write_card_refuses_other_formats(tmp_path):
    with pytest.raises(ValueError, match=r"\.png or \.pdf"):
        write_card(LAYOUT, tmp_path / "card.jpg")


# ---------------------------------------------------------------------------------------------------------------
# Locating the card


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_locate_card_recovers_the_homography(seed):
    warp = random_warp(seed)
    photo = cv2.GaussianBlur(photograph(CARD, warp), (0, 0), 0.7)  # a slightly soft lens
    location = locate_card(photo, LAYOUT)
    assert location.found_ids == (0, 1, 2, 3)
    assert location.missing_ids == () and location.duplicate_ids == ()
    assert location.reprojection_error_px < 0.5
    assert corner_error_px(location, warp @ RENDER_MM_TO_PX) < 0.5
    gray = locate_card(cv2.cvtColor(photo, cv2.COLOR_RGB2GRAY), LAYOUT)
    assert corner_error_px(gray, warp @ RENDER_MM_TO_PX) < 0.5


@pytest.mark.parametrize("covered", [0, 1, 2, 3])
def test_locate_card_with_a_marker_covered_reports_it_missing(covered):
    warp = random_warp(5 + covered)
    photo = photograph(CARD, warp)
    cover_marker(photo, warp, LAYOUT.markers[covered])
    location = locate_card(photo, LAYOUT)
    assert location.missing_ids == (covered,)
    assert location.found_ids == tuple(i for i in range(4) if i != covered)
    # three markers fix the perspective less well than four: the card's corners (extrapolated) move by up to a
    # few px, but every region corner stays within 1 mm of the truth, half the default sampling margin
    truth = warp @ RENDER_MM_TO_PX
    assert corner_error_px(location, truth) < 3.0
    for region in LAYOUT.regions:
        x0, y0, x1, y1 = region.x_mm, region.y_mm, region.x_mm + region.w_mm, region.y_mm + region.h_mm
        corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
        one_mm_px = min(
            np.linalg.norm(apply(truth, corners + step) - apply(truth, corners), axis=1).min()
            for step in ([1, 0], [0, 1])
        )
        error = np.linalg.norm(location.card_to_image(corners) - apply(truth, corners), axis=1)
        assert np.all(error < one_mm_px), region.name


def test_locate_card_ignores_markers_not_in_the_layout():
    card = CARD.copy()
    x0, y0, side = round(150 * PPM), round(40 * PPM), round(20 * PPM)  # id 7 lying in the colorchecker slot
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    card[y0 : y0 + side, x0 : x0 + side] = cv2.aruco.generateImageMarker(dictionary, 7, side)[..., None]
    warp = random_warp(6)
    location = locate_card(photograph(card, warp), LAYOUT)
    assert location.found_ids == (0, 1, 2, 3)
    assert corner_error_px(location, warp @ RENDER_MM_TO_PX) < 0.5


def test_locate_card_with_one_marker_left_raises_naming_the_ids():
    warp = random_warp(7)
    photo = photograph(CARD, warp)
    for marker in LAYOUT.markers[1:]:
        cover_marker(photo, warp, marker)
    with pytest.raises(CardNotFound) as error:
        locate_card(photo, LAYOUT)
    message = str(error.value)
    assert "ids [0]" in message
    assert "missing ids [1, 2, 3]" in message
    assert "DICT_4X4_50 markers with ids [0, 1, 2, 3]" in message


def test_locate_card_needs_an_8_bit_image():
    with pytest.raises(ValueError, match="8-bit"):
        locate_card(CARD.astype(np.float32) / 255, LAYOUT)


# ---------------------------------------------------------------------------------------------------------------
# Sampling regions


PAINT = {  # known linear values, on the 8-bit grid so that the printed card holds them exactly
    "black": np.array([10, 12, 14]) / 255,
    "white": np.array([230, 225, 220]) / 255,
    "film_over_black": np.array([90, 70, 60]) / 255,
    "film_over_white": np.array([180, 140, 120]) / 255,
    "white_reference": np.array([240, 240, 241]) / 255,
}


@pytest.fixture(scope="module")
def painted_photo():
    """A card with known region values, warped into a float photo, and its location found on an 8-bit copy."""
    warp = random_warp(11)
    card = render_card(LAYOUT, PPM, region_colors=PAINT)
    linear = photograph(card.astype(np.float32) / 255, warp, border=BACKGROUND / 255)
    location = locate_card(photograph(card, warp), LAYOUT)
    return linear, location, warp


def test_sample_region_returns_the_painted_values(painted_photo):
    linear, location, _ = painted_photo
    for name, value in PAINT.items():
        sample = sample_region(linear, location, LAYOUT.region(name))
        assert sample.name == name
        np.testing.assert_allclose(sample.mean, value, atol=1e-3)
        assert np.all(sample.uniformity < 1e-3)
        assert np.all(sample.std < 1e-3)
        assert sample.masked_fraction == 0.0
        assert sample.count > 0.5 * (LAYOUT.region(name).w_mm - 4) * (LAYOUT.region(name).h_mm - 4)


def test_sample_region_any_channel_count(painted_photo):
    linear, location, _ = painted_photo
    five = np.dstack([linear, 0.5 * linear[..., :2]]).astype(np.float64)
    region = LAYOUT.region("film_over_white")
    sample = sample_region(five, location, region)
    value = PAINT["film_over_white"]
    np.testing.assert_allclose(sample.mean, [*value, *(0.5 * value[:2])], atol=1e-3)
    assert sample.uniformity.shape == sample.std.shape == (5,)
    single = sample_region(linear[..., 1], location, region)
    np.testing.assert_allclose(single.mean, value[1:2], atol=1e-3)


def test_sample_region_shows_a_highlight_as_non_uniformity(painted_photo):
    linear, location, warp = painted_photo
    region = LAYOUT.region("film_over_white")
    centre_mm = (region.x_mm + region.w_mm / 4, region.y_mm + region.h_mm / 4)  # centre of the top-left quadrant
    cx, cy = apply(warp @ RENDER_MM_TO_PX, [centre_mm])[0]
    rows, columns = np.mgrid[: linear.shape[0], : linear.shape[1]]
    spot = 0.5 * np.exp(-((columns - cx) ** 2 + (rows - cy) ** 2) / (2 * 15.0**2))
    highlighted = linear + spot[..., None].astype(np.float32)
    sample = sample_region(highlighted, location, region)
    assert np.all(sample.uniformity > 0.1)
    assert np.all(sample.mean > PAINT["film_over_white"])  # the spot covers more than the trimmed 10 %
    untouched = sample_region(highlighted, location, LAYOUT.region("film_over_black"))
    assert np.all(untouched.uniformity < 1e-3)


def test_sample_region_counts_masked_pixels():
    card = render_card(LAYOUT, PPM, region_colors=PAINT).astype(np.float64) / 255
    exact = CardLocation(RENDER_MM_TO_PX, (0, 1, 2, 3), (), (), 0.0)  # samples fall on pixel centres
    region = LAYOUT.region("black")  # 16-56 x 33-63 mm; with the 2 mm margin columns 108-323, rows 210-365 px
    mask = np.zeros(card.shape[:2], dtype=bool)
    mask[:, :216] = True  # the left half of the sampled columns
    sample = sample_region(card, exact, region, mask=mask)
    assert sample.count == 216 * 156
    assert sample.masked_fraction == 0.5
    np.testing.assert_allclose(sample.mean, PAINT["black"], atol=1e-12)
    np.testing.assert_allclose(sample.polygon_px, [[107.5, 209.5], [323.5, 209.5], [323.5, 365.5], [107.5, 365.5]])
    assert sample_region(card, exact, LAYOUT.region("film_over_black"), mask=mask).masked_fraction == 0.0
    assert sample_region(card, exact, region, mask=mask, px_per_mm=3.0).count == 108 * 78


def test_sample_region_refuses_a_region_off_the_photo_or_emptied_by_the_margin(painted_photo):
    linear, location, _ = painted_photo
    shifted = CardLocation(
        location.homography + np.array([[0, 0, CANVAS], [0, 0, 0], [0, 0, 0]]), (0, 1, 2, 3), (), (), 0.0
    )
    with pytest.raises(ValueError, match="not entirely inside the photo"):
        sample_region(linear, shifted, LAYOUT.region("black"))
    with pytest.raises(ValueError, match="empty after a 20 mm margin"):
        sample_region(linear, location, LAYOUT.region("black"), margin_mm=20.0)


def test_sample_pixels_statistics_of_a_block():
    block = np.full((10, 8, 2), [0.2, 0.4])
    block[0, 0] = [5.0, 5.0]  # one outlier: trimmed away from the mean, seen in the std and the top-left quadrant
    mask = np.zeros((10, 8), dtype=bool)
    mask[:, :2] = True
    sample = sample_pixels(block, mask, trim=0.1, name="roi")
    assert sample.name == "roi" and sample.count == 80
    np.testing.assert_allclose(sample.mean, [0.2, 0.4], atol=1e-15)
    np.testing.assert_allclose(sample.std, np.std(block.reshape(-1, 2), axis=0, ddof=1))
    np.testing.assert_allclose(sample.uniformity, (np.array([5.0, 5.0]) - [0.2, 0.4]) / 20 / [0.2, 0.4])
    assert sample.masked_fraction == 0.25
    np.testing.assert_allclose(sample.polygon_px, [[-0.5, -0.5], [7.5, -0.5], [7.5, 9.5], [-0.5, 9.5]])
    dark = sample_pixels(np.zeros((4, 4)))
    assert dark.masked_fraction == 0.0 and dark.uniformity.tolist() == [0.0]
