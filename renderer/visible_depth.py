"""What each sample of a multisampled pass shows, as a depth bound, so that the layer pass shades only fragments that
some sample can show.

llvmpipe tests depth before shading when it draws one sample a pixel, but when multisampling it shades every
fragment a triangle covers and tests depth per sample afterwards: the sweep behind the head and the back of the head
are shaded and then thrown away. This depth pass draws the same meshes with the layer pass's vertex shader (so the
same window depths) and a one-line fragment shader (``shaders/visible_depth.frag``) that writes, into every sample
the winning fragment covers, an upper bound on that fragment's window depth anywhere in its pixel::

    b = z + 0.5 fwidth(z)

(a triangle's window depth is linear in x and y and every sample lies within half a pixel of the centre on each
axis). The layer shader then skips a fragment whose nearest depth in its pixel, ``z - 0.5 fwidth(z)``, lies beyond
the largest ``b`` of its pixel's samples by more than 1e-6: the depth test would discard it at every sample, so the
frame is the same. What the skip saves is the shading's loops and texture lookups (the soft shadows' 32 taps above
all): llvmpipe still runs a skipped branch's straight-line code under an empty mask, so a hidden fragment costs
about half a shaded one rather than nothing.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import numpy as np

from renderer.context import GL
from renderer.framebuffer import Framebuffer, pooled
from renderer.meshes import GpuMesh
from renderer.program import shared_program


def skips_hidden(samples: int) -> bool:
    """True where the depth pass pays: a multisampled pass on llvmpipe (a GPU tests depth before shading)."""
    return samples > 1 and b"llvmpipe" in (GL.glGetString(GL.GL_RENDERER) or b"")


@contextmanager
def bounds(
    width: int, height: int, samples: int, draws: Sequence[tuple[GpuMesh, np.ndarray]], view_projection: np.ndarray
) -> Iterator[Framebuffer | None]:
    """A multisampled framebuffer holding the depth bound of every sample (in red) of ``draws`` (mesh, model
    matrix) seen through ``view_projection``, for the block; None where :func:`skips_hidden` is false."""
    if not skips_hidden(samples):
        yield None
        return
    program = shared_program("km_layers.vert", "visible_depth.frag")
    with pooled(width, height, 1, samples) as framebuffer:
        framebuffer.clear((1.0, 1.0, 1.0, 1.0))  # no surface: the far plane
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthFunc(GL.GL_LESS)
        program.use()
        program.set_mat4("u_view_projection", view_projection)
        for mesh, model in draws:
            program.set_mat4("u_model", model)
            mesh.draw()
        yield framebuffer
