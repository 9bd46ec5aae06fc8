"""A bare Lambert surface through the renderer's layer pass, and meshes joined from parts, for tests that check
geometry and lighting."""

from __future__ import annotations

import numpy as np
import trimesh

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


def joined(*parts: trimesh.Trimesh) -> trimesh.Trimesh:
    """One mesh of several parts, each keeping its vertex normals and uv."""
    vertices, faces, normals, uv, offset = [], [], [], [], 0
    for part in parts:
        vertices.append(part.vertices)
        faces.append(part.faces + offset)
        normals.append(part.vertex_normals)
        uv.append(part.visual.uv)
        offset += len(part.vertices)
    return trimesh.Trimesh(np.vstack(vertices), np.vstack(faces), vertex_normals=np.vstack(normals),
                           visual=trimesh.visual.TextureVisuals(uv=np.vstack(uv)), process=False)  # fmt: skip
