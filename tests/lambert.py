"""A bare Lambert surface through the renderer's layer pass, for tests that check geometry and lighting."""

from __future__ import annotations

from renderer.layers import render_layers
from renderer.scene import Scene
from renderer.stack import ChannelStack


def lambert(mesh, camera, light, albedo, width, height, **options):
    """A bare Lambert surface of ``albedo`` (linear RGB): the layer pass with no films."""
    scene = Scene(
        mesh=mesh,
        camera=camera,
        lights=[light],
        stack=ChannelStack([], [], albedo),
        resolution=(width, height),
        **options,
    )
    return render_layers(scene)
