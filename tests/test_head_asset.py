"""The bundled head (recipes/head): its provenance, geometry and uv, its eyes, and the cosmetic map over its uv."""

import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pytest

from renderer.image_io import read_channel
from renderer.products import load_mesh

HEAD = Path(__file__).resolve().parents[1] / "recipes" / "head"
MAP = HEAD.parent / "scenes" / "head_makeup.png"
FILES = ("head.obj", "eyes_sclera.obj", "eyes_iris.obj", "eyes_pupil.obj", "landmarks.json", "LICENSE.md")


@pytest.fixture(scope="module")
def head():
    return load_mesh(HEAD / "head.obj")


def test_vendored_files_match_their_recorded_sha256():
    readme = (HEAD / "README.md").read_text()
    for name in FILES:
        recorded = re.search(rf"\| `{re.escape(name)}` \| `([0-9a-f]{{64}})` \|", readme)
        assert recorded is not None, name
        assert hashlib.sha256((HEAD / name).read_bytes()).hexdigest() == recorded.group(1), name
    assert "CC0 1.0 Universal" in (HEAD / "LICENSE.md").read_text()


def test_head_is_a_manifold_mm_scaled_region_with_uv_in_the_unit_square(head):
    height = np.ptp(head.vertices[:, 1])
    assert 200.0 <= height <= 300.0  # head and neck, mm
    uv = head.visual.uv
    assert uv.shape == (len(head.vertices), 2) and uv.min() >= 0.0 and uv.max() <= 1.0
    _, welded = np.unique(head.vertices.round(3), axis=0, return_inverse=True)
    edges = np.sort(welded.ravel()[head.faces][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    assert uses.max() == 2  # manifold: no edge is shared by three triangles
    assert (uses == 1).sum() < 0.01 * len(uses)  # open only at the neck's cut
    p = head.vertices[head.faces]
    assert np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).min() > 1e-3  # mm^2


def test_uv_islands_do_not_overlap(head):
    import cv2

    size = 2048
    count = np.zeros((size, size), np.int32)
    for tri in head.faces:
        canvas = np.zeros((size, size), np.uint8)
        corners = np.rint(head.visual.uv[tri] * 16 * size).astype(np.int32)
        cv2.fillPoly(canvas, [corners], 1, lineType=cv2.LINE_8, shift=4)
        count += canvas
    uv = head.visual.uv[head.faces]
    a, b = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    total = np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum() / 2.0  # the triangles' uv areas
    assert total <= (count > 0).mean()  # the triangles' areas add up to no more than the area they cover


def test_eyes_are_separate_and_inside_the_head(head):
    low, high = head.bounds
    for part in ("sclera", "iris", "pupil"):
        eye = load_mesh(HEAD / f"eyes_{part}.obj")
        assert np.all(eye.bounds[0] > low) and np.all(eye.bounds[1] < high)
        assert np.all(np.abs(eye.vertices[:, 0]) > 15.0)  # two eyes, one each side of the midline


def test_cosmetic_map_is_on_the_face_and_lipstick_on_the_mouth(head):
    foundation, blush, lips = (read_channel(MAP, c) for c in "RGB")
    rows, columns = foundation.shape
    uv = head.visual.uv
    texel = np.clip((uv * [columns, rows]).astype(int), 0, [columns - 1, rows - 1])
    at = lambda channel: channel[rows - 1 - texel[:, 1], texel[:, 0]]  # noqa: E731
    back = head.vertices[:, 2] < -50.0  # the back of the head
    for channel in (foundation, blush, lips):
        assert at(channel)[back].max() == 0.0
    assert at(foundation)[(head.vertices[:, 2] > 80.0) & (np.abs(head.vertices[:, 1]) < 20.0)].mean() > 0.9
    marks = json.loads((HEAD / "landmarks.json").read_text())
    painted = head.vertices[at(lips) > 0.5]
    assert len(painted) > 20
    assert np.abs(painted[:, 0]).max() < 30.0 and np.all(painted[:, 2] > 70.0)  # the mouth: narrow, at the front
    assert np.all(painted[:, 1] < marks["joint-l-lowerlid"][1] - 40.0)  # well below the eyes
    assert np.all(painted[:, 1] > marks["joint-jaw"][1])  # above the chin


def test_eyeshadow_is_on_the_upper_lids_between_the_lashes_and_the_brows(head):
    """Where head_eyeshadow.png holds half its thickness or more, the head's vertices are upper-lid skin: above the
    eye's opening (the eye landmark + 3 mm, the lash line), below the brow ridge (+ 16 mm), within about an eye's
    width of the eye, at the front of the face; and it covers the lid over the eye's centre on both sides."""
    shadow = read_channel(HEAD.parent / "scenes" / "head_eyeshadow.png", "R")
    rows, columns = shadow.shape
    texel = np.clip((head.visual.uv * [columns, rows]).astype(int), 0, [columns - 1, rows - 1])
    value = shadow[rows - 1 - texel[:, 1], texel[:, 0]]
    eye_x, eye_y, _ = json.loads((HEAD / "landmarks.json").read_text())["joint-l-eye"]
    painted = head.vertices[value >= 0.5]
    assert len(painted) > 20
    x, y, z = painted.T
    assert np.all((y > eye_y + 2.0) & (y < eye_y + 16.0))
    assert np.all((np.abs(x) > eye_x - 16.0) & (np.abs(x) < eye_x + 20.0)) and np.all(z > 45.0)  # outer corner ~47
    for side in (-1.0, 1.0):
        lid = (np.abs(head.vertices[:, 0] - side * eye_x) < 4.0) & (np.abs(head.vertices[:, 1] - eye_y - 6.0) < 2.0)
        lid &= (head.vertices[:, 2] > 60.0) & (head.vertex_normals[:, 2] > 0.5)  # the lid's outer, facing skin
        assert lid.any() and value[lid].min() > 0.8
    assert value[head.vertices[:, 1] < eye_y].max() == 0.0  # none below the eyes
