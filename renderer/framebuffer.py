"""A float framebuffer object: one or more RGBA32F colour textures and a 24-bit depth and 8-bit stencil attachment,
single-sampled or multisampled, and a pool of idle ones that passes reuse: on llvmpipe a
new 1024 x 1024 framebuffer of three targets, multisampled 4 x, costs about 0.15 s (the first touch of its 200 MB),
every frame again."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from renderer.context import GL


class Framebuffer:
    """An offscreen render target of ``width`` x ``height`` pixels holding linear float RGBA in ``targets`` colour
    attachments (fragment outputs at locations 0 .. targets - 1), sampled linearly and clamped at the edges; with
    ``samples`` > 1 the attachments are multisample textures of that many samples per pixel (a shader reads them
    with texelFetch; :meth:`read_rgba` cannot).

    Use as a context manager (or call :meth:`release`) to free the GL objects. The current context must stay the
    same from creation to release.
    """

    def __init__(self, width: int, height: int, targets: int = 1, samples: int = 1) -> None:
        """Create the colour textures, depth-stencil renderbuffer and FBO; sizes in pixels, ``samples`` per pixel."""
        self.width = width
        self.height = height
        self.samples = samples
        kind = GL.GL_TEXTURE_2D_MULTISAMPLE if samples > 1 else GL.GL_TEXTURE_2D
        self.colours = [int(t) for t in np.atleast_1d(GL.glGenTextures(targets))]
        for colour in self.colours:
            GL.glBindTexture(kind, colour)
            if samples > 1:  # fixed sample locations, the same in every attachment
                GL.glTexImage2DMultisample(kind, samples, GL.GL_RGBA32F, width, height, GL.GL_TRUE)
                continue
            GL.glTexImage2D(kind, 0, GL.GL_RGBA32F, width, height, 0, GL.GL_RGBA, GL.GL_FLOAT, None)
            for parameter, value in (
                (GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR),
                (GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR),
                (GL.GL_TEXTURE_WRAP_S, GL.GL_CLAMP_TO_EDGE),
                (GL.GL_TEXTURE_WRAP_T, GL.GL_CLAMP_TO_EDGE),
            ):
                GL.glTexParameteri(kind, parameter, value)
        GL.glBindTexture(kind, 0)
        self.colour = self.colours[0]
        self.depth = GL.glGenRenderbuffers(1)
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self.depth)
        GL.glRenderbufferStorageMultisample(GL.GL_RENDERBUFFER, samples if samples > 1 else 0,
                                            GL.GL_DEPTH24_STENCIL8, width, height)  # fmt: skip
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, 0)
        self.fbo = GL.glGenFramebuffers(1)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
        for index, colour in enumerate(self.colours):
            GL.glFramebufferTexture2D(GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0 + index, kind, colour, 0)
        GL.glDrawBuffers(targets, [GL.GL_COLOR_ATTACHMENT0 + index for index in range(targets)])
        GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_STENCIL_ATTACHMENT, GL.GL_RENDERBUFFER, self.depth)
        status = GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, 0)
        if status != GL.GL_FRAMEBUFFER_COMPLETE:
            self.release()
            raise RuntimeError(f"the RGBA32F framebuffer ({width} x {height}, {samples} samples a pixel) is "
                               f"incomplete: status 0x{status:x}")  # fmt: skip

    def bind(self) -> None:
        """Make this the draw and read target and set the viewport to cover it."""
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
        GL.glViewport(0, 0, self.width, self.height)

    def clear(self, rgba: tuple[float, float, float, float]) -> None:
        """Bind, fill every colour target with linear ``rgba`` (any float, unclamped) and the depth with 1 (far)."""
        self.bind()
        GL.glClearColor(*rgba)
        GL.glClearDepth(1.0)
        GL.glClear(GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT)

    def read_rgba(self, target: int = 0) -> np.ndarray:
        """Colour target ``target`` as a float32 array of shape (height, width, 4), top row first.

        GL stores rows bottom-up; the rows are flipped so that row 0 is the top of the image.
        """
        if self.samples > 1:
            raise ValueError("a multisampled framebuffer cannot be read back as it is")
        self.bind()
        GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT0 + target)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 4)
        data = GL.glReadPixels(0, 0, self.width, self.height, GL.GL_RGBA, GL.GL_FLOAT)
        pixels = np.asarray(data, dtype=np.float32).reshape(self.height, self.width, 4)
        return np.ascontiguousarray(pixels[::-1])

    def release(self) -> None:
        """Delete the GL objects; the framebuffer cannot be used afterwards."""
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, 0)
        GL.glDeleteFramebuffers(1, [self.fbo])
        GL.glDeleteRenderbuffers(1, [self.depth])
        GL.glDeleteTextures(len(self.colours), self.colours)

    def __enter__(self) -> Framebuffer:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.release()


#: Most bytes of idle framebuffers :func:`pooled` keeps for reuse.
POOL_BYTES = 1 << 30
_idle: list[Framebuffer] = []  # least recently given back first


def _bytes(framebuffer: Framebuffer) -> int:
    """Bytes of a framebuffer's attachments: RGBA32F colours and a 24-bit depth with 8-bit stencil per sample."""
    return framebuffer.width * framebuffer.height * framebuffer.samples * (16 * len(framebuffer.colours) + 4)


@contextmanager
def pooled(width: int, height: int, targets: int = 1, samples: int = 1) -> Iterator[Framebuffer]:
    """A :class:`Framebuffer` of this size and layout for the block: an idle one from the pool, or a new one; given
    back to the pool when the block ends. It holds what its last user left: clear or overwrite what you read.

    The pool keeps at most :data:`POOL_BYTES` of idle framebuffers, releasing the least recently used past that.
    """
    key = (width, height, targets, samples)
    found = [f for f in _idle if (f.width, f.height, len(f.colours), f.samples) == key]
    framebuffer = found[-1] if found else Framebuffer(width, height, targets, samples)
    if found:
        _idle.remove(framebuffer)
    try:
        yield framebuffer
    finally:
        _idle.append(framebuffer)
        while sum(_bytes(f) for f in _idle) > POOL_BYTES:
            _idle.pop(0).release()
