"""The depth pass that lets a multisampled layer pass skip fragments hidden at every sample (renderer.visible_depth).

References, none produced by the code under test: the window depth of a plane through an orthographic camera follows
from its projection matrix (z_window = (z_ndc + 1) / 2), and across a plane tilted by theta about the vertical it
changes by (1 / (far - near)) tan(theta) per mm of x; skipping must not change a single pixel of the frame, so a
frame rendered with the skip equals the one rendered without it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from renderer import context, meshes, multisample, visible_depth
from renderer.framebuffer import Framebuffer
from renderer.layers import render_layers
from renderer.meshes import GpuMesh
from renderer.scene import DirectionalLight, OrthographicCamera, Prop, Scene
from renderer.stack import ChannelStack

SIZE = 48
CAMERA = OrthographicCamera(half_height=10.0, eye=(0.0, 0.0, 100.0), near=1.0, far=1000.0)


def _window_depth(distance_mm: float) -> float:
    """Window depth of a point ``distance_mm`` in front of CAMERA, from its projection matrix."""
    n, f = CAMERA.near, CAMERA.far
    z_ndc = (2.0 * distance_mm - (f + n)) / (f - n)
    return 0.5 * z_ndc + 0.5


def _bounds(mesh: trimesh.Trimesh) -> np.ndarray:
    """The per-pixel mean of the samples' depth bounds of ``mesh`` (a 4 x multisampled pass), top row first."""
    view_projection = CAMERA.projection_matrix(1.0) @ CAMERA.view_matrix()
    with context.lock:
        context.make_current(SIZE, SIZE)
        assert visible_depth.skips_hidden(4), "llvmpipe multisamples without testing depth first: the pass must run"
        with GpuMesh(mesh) as gpu_mesh, Framebuffer(SIZE, SIZE) as resolved:
            with visible_depth.bounds(SIZE, SIZE, 4, [(gpu_mesh, np.eye(4))], view_projection) as bounds:
                multisample.resolve(bounds, resolved)
            return resolved.read_rgba()[..., 0].astype(np.float64)


@pytest.mark.parametrize("tilt_deg", [0.0, 35.0])
def test_a_card_s_depth_bound_is_its_window_depth_plus_half_its_change_across_a_pixel(tilt_deg):
    card = meshes.card(60.0, 60.0)  # fills the frame
    card.apply_transform(trimesh.transformations.rotation_matrix(math.radians(tilt_deg), (0.0, 1.0, 0.0)))
    bound = _bounds(card)
    pixel_mm = 20.0 / SIZE
    x = (np.arange(SIZE) + 0.5) * pixel_mm - 10.0  # pixel centres, mm
    # Rotating about +y moves a point at x to depth -x sin(theta) along z, x cos(theta) across: at screen x it lies
    # 100 + x tan(theta) mm from the camera.
    t = math.tan(math.radians(tilt_deg))
    centre = np.array([_window_depth(100.0 + xi * t) for xi in x])
    half_step = 0.5 * abs(_window_depth(100.0 + pixel_mm * t) - _window_depth(100.0))
    np.testing.assert_allclose(bound, np.broadcast_to(centre + half_step, bound.shape), atol=2e-6)


def test_where_no_surface_lies_the_bound_is_the_far_plane():
    bound = _bounds(meshes.card(8.0, 8.0))
    assert np.all(bound[:4] == 1.0) and np.all(bound[:, :4] == 1.0)  # the frame's edges: nothing drawn
    assert np.all(bound[SIZE // 2 - 2 : SIZE // 2 + 2, SIZE // 2 - 2 : SIZE // 2 + 2] < 0.2)  # the card, 100 mm off


def _occluded_scene() -> Scene:
    """A sphere just in front of a tilted card and a second card behind both: every kind of hidden fragment (the
    sphere's far side, the cards behind it) and silhouettes whose pixels show two surfaces."""
    behind = meshes.card(40.0, 40.0)
    behind.apply_transform(trimesh.transformations.rotation_matrix(math.radians(50.0), (0.0, 1.0, 0.0)))
    back = meshes.card(40.0, 40.0)
    back.apply_translation((0.0, 0.0, -30.0))
    return Scene(
        mesh=meshes.sphere(6.0),
        camera=CAMERA,
        lights=[DirectionalLight(direction=(0.3, 0.4, -1.0), radiance=(1.0, 1.0, 1.0))],
        stack=ChannelStack([], [], (0.6, 0.45, 0.3)),
        resolution=(SIZE, SIZE),
        multisamples=4,
        props=[Prop(behind, (0.3, 0.5, 0.7)), Prop(back, (0.8, 0.8, 0.8))],
    )


def test_skipping_hidden_fragments_leaves_the_multisampled_frame_unchanged(monkeypatch):
    skipped = render_layers(_occluded_scene())
    monkeypatch.setattr(visible_depth, "skips_hidden", lambda samples: False)
    shaded = render_layers(_occluded_scene())
    assert np.array_equal(skipped, shaded)  # bit for bit
    values = np.unique(np.round(shaded.reshape(-1, 3), 4), axis=0)
    assert len(values) > 100  # the frame shows the sphere, both cards and their silhouettes
