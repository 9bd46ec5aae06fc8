"""The process's one OSMesa context, shared by threads (a Dask worker may run render tasks in several): passes take
turns (renderer.context.lock), and every image equals the one rendered alone."""

from __future__ import annotations

import threading

import numpy as np

from renderer import meshes
from renderer.layers import render_layers
from renderer.scene import DirectionalLight, OrthographicCamera, Scattering, Scene
from renderer.skin import render_skin
from renderer.stack import SKIN_SPECULAR, ChannelStack


def test_threads_rendering_at_once_get_the_images_they_would_alone():
    camera = OrthographicCamera(10.0)
    light = DirectionalLight((0.3, -0.2, -1.0), (1.0, 1.0, 1.0))
    sphere = {"mesh": meshes.sphere(8.0), "camera": camera, "lights": [light]}
    layers = Scene(stack=ChannelStack([], [], [0.5, 0.4, 0.3]), resolution=(48, 48), **sphere)
    skin = Scene(
        stack=ChannelStack([], [], [0.6, 0.4, 0.3]),
        resolution=(40, 40),
        substrate_lobe=SKIN_SPECULAR,
        scattering=Scattering(),
        **sphere,
    )
    jobs = [lambda: render_layers(layers), lambda: render_skin(skin)]
    alone = [job() for job in jobs]
    results: list[tuple[int, np.ndarray]] = []

    def work(index: int) -> None:
        for _ in range(4):
            results.append((index, jobs[index]()))

    threads = [threading.Thread(target=work, args=(i % 2,)) for i in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(results) == 16
    for index, image in results:
        np.testing.assert_array_equal(image, alone[index])
