"""Multisample antialiasing: a pass drawn into a multisampled framebuffer, then resolved to one value per pixel.

Each pixel holds ``samples`` (2 or 4) coverage and depth samples at fixed positions; the fragment shader runs once
per pixel and triangle (at the pixel's centre), its result written to the samples the triangle covers. The resolve
(``shaders/msaa_resolve.frag``) averages each pixel's samples in a fixed order, so a pixel that one surface covers
keeps that surface's value exactly and a pixel a silhouette crosses takes the share of its samples on each side:
the same antialiasing of edges as :func:`renderer.scene.supersampled` at ``samples`` samples a pixel, for about the
shading cost of one sample a pixel (texture and shading detail inside a triangle is not antialiased; on llvmpipe the
layer pass first draws depth bounds, :mod:`renderer.visible_depth`, to shade only what some sample shows).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from renderer.context import GL
from renderer.framebuffer import Framebuffer, pooled
from renderer.program import Program, shared_program

#: The sample counts a pass can be multisampled with (the resolve averages a power of two exactly).
SAMPLE_COUNTS = (1, 2, 4)
#: Most colour attachments one resolve handles.
MAX_TARGETS = 3


def _program() -> Program:
    return shared_program("fullscreen.vert", "msaa_resolve.frag")


def check_samples(samples: int) -> None:
    """ValueError unless ``samples`` is one of :data:`SAMPLE_COUNTS` and this GL can multisample float targets so."""
    if samples not in SAMPLE_COUNTS:
        raise ValueError(f"multisampling takes {', '.join(map(str, SAMPLE_COUNTS))} samples a pixel, got {samples!r}")
    most = min(int(GL.glGetIntegerv(GL.GL_MAX_SAMPLES)), int(GL.glGetIntegerv(GL.GL_MAX_COLOR_TEXTURE_SAMPLES)))
    if samples > most:
        raise ValueError(f"this OpenGL multisamples float targets with at most {most} samples a pixel, not {samples}")


def resolve(source: Framebuffer, target: Framebuffer) -> None:
    """Write the per-pixel mean of each of ``source``'s multisampled attachments into ``target``'s, attachment by
    attachment (same size, same number of attachments); leaves ``target`` bound."""
    targets = len(source.colours)
    if (source.width, source.height) != (target.width, target.height) or len(target.colours) != targets:
        raise ValueError("a resolve needs a target of the source's size and number of attachments")
    if targets > MAX_TARGETS:
        raise ValueError(f"a resolve handles at most {MAX_TARGETS} attachments, got {targets}")
    program = _program()
    vao = GL.glGenVertexArrays(1)
    try:
        target.bind()
        GL.glDisable(GL.GL_DEPTH_TEST)
        GL.glDisable(GL.GL_BLEND)
        GL.glBindVertexArray(vao)
        program.use()
        GL.glUniform1i(program.location("u_samples"), source.samples)
        GL.glUniform1i(program.location("u_targets"), targets)
        for unit in range(MAX_TARGETS):
            GL.glUniform1i(program.location(f"u_source{unit}"), unit)
            GL.glActiveTexture(GL.GL_TEXTURE0 + unit)
            GL.glBindTexture(GL.GL_TEXTURE_2D_MULTISAMPLE, source.colours[min(unit, targets - 1)])
        GL.glDrawArrays(GL.GL_TRIANGLES, 0, 3)
    finally:
        GL.glBindVertexArray(0)
        for unit in range(MAX_TARGETS):
            GL.glActiveTexture(GL.GL_TEXTURE0 + unit)
            GL.glBindTexture(GL.GL_TEXTURE_2D_MULTISAMPLE, 0)
        GL.glActiveTexture(GL.GL_TEXTURE0)
        GL.glDeleteVertexArrays(1, [vao])


@contextmanager
def canvas(target: Framebuffer, samples: int) -> Iterator[Framebuffer]:
    """The framebuffer to draw a pass into: ``target`` itself for 1 sample a pixel, else a multisampled one of its size
    and attachments, resolved into ``target`` when the block ends without an error."""
    if samples == 1:
        yield target
        return
    check_samples(samples)
    with pooled(target.width, target.height, len(target.colours), samples) as multisampled:
        yield multisampled
        resolve(multisampled, target)
