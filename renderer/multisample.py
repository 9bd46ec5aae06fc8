"""Multisample antialiasing: the layer pass's surface attributes (:mod:`renderer.layers`) drawn with ``samples`` (2 or
4) coverage and depth samples a pixel at fixed positions, each holding what the nearest triangle shows there at the
pixel's centre.

The shading pass then shades each pixel once per distinct surface its samples show and weights each by its share
of the samples, so a pixel that one surface covers keeps that surface's value exactly and a pixel a silhouette
crosses takes the share of its samples on each side: the same antialiasing of edges as
:func:`renderer.scene.supersampled` at ``samples`` samples a pixel, for about the shading cost of one sample a pixel
(texture and shading detail inside a triangle is not antialiased).
"""

from __future__ import annotations

from renderer.context import GL

#: The sample counts a pass can be multisampled with (the share of a pixel's samples is then exact in float).
SAMPLE_COUNTS = (1, 2, 4)


def check_samples(samples: int) -> None:
    """ValueError unless ``samples`` is one of :data:`SAMPLE_COUNTS` and this GL can multisample float targets so."""
    if samples not in SAMPLE_COUNTS:
        raise ValueError(f"multisampling takes {', '.join(map(str, SAMPLE_COUNTS))} samples a pixel, got {samples!r}")
    most = min(int(GL.glGetIntegerv(GL.GL_MAX_SAMPLES)), int(GL.glGetIntegerv(GL.GL_MAX_COLOR_TEXTURE_SAMPLES)))
    if samples > most:
        raise ValueError(f"this OpenGL multisamples float targets with at most {most} samples a pixel, not {samples}")
