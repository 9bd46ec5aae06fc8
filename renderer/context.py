"""The offscreen OpenGL context: one OSMesa core-profile context per process.

PyOpenGL chooses its platform once, when ``OpenGL.platform`` is first imported, from the environment variable
``PYOPENGL_PLATFORM``. This module therefore sets it to ``osmesa`` before importing OpenGL, and every other renderer
module takes its ``GL`` from here so that the order cannot go wrong.

The context is created on the first :func:`make_current` and lives until the process ends. A process forked after
the context exists hangs inside Mesa, so worker processes must use the ``spawn`` start method; using the context from
a forked child raises :class:`RuntimeError` instead of hanging. The one context serves one thread at a time: a pass
holds :data:`lock` from its first GL call to its last (a Dask worker may run tasks in several threads).
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading

_MISSING = (
    "the OSMesa offscreen OpenGL library could not be loaded: install the Debian package libosmesa6 "
    "(apt-get install libosmesa6) and the Python package PyOpenGL"
)

if "OpenGL.platform" in sys.modules and os.environ.get("PYOPENGL_PLATFORM") != "osmesa":
    raise RuntimeError(
        "OpenGL was imported before renderer.context with a platform other than OSMesa; "
        "import renderer modules first or set PYOPENGL_PLATFORM=osmesa before the first `import OpenGL`"
    )
os.environ["PYOPENGL_PLATFORM"] = "osmesa"

# The imports must follow the environment variable above.
try:
    import OpenGL.error
    import OpenGL.platform
    from OpenGL import GL, osmesa
except (ImportError, OSError, AttributeError) as _error:
    raise RuntimeError(_MISSING) from _error

if type(OpenGL.platform.PLATFORM).__name__ != "OSMesaPlatform":
    raise RuntimeError(f"PyOpenGL chose {type(OpenGL.platform.PLATFORM).__name__}, not OSMesa: {_MISSING}")

__all__ = ["GL", "gl_version", "lock", "make_current"]

#: Held by a rendering pass for all its GL work: the process's one context is current in one thread at a time.
lock = threading.RLock()

#: Core-profile versions tried in order, best first.
_VERSIONS = ((4, 5), (3, 3))


class _Context:
    """The process's OSMesa context and the default colour buffer it is bound to."""

    def __init__(self) -> None:
        self.pid = os.getpid()
        self.handle = None
        for major, minor in _VERSIONS:
            attributes = (ctypes.c_int * 11)(
                osmesa.OSMESA_FORMAT, osmesa.OSMESA_RGBA,
                osmesa.OSMESA_DEPTH_BITS, 24,
                osmesa.OSMESA_PROFILE, osmesa.OSMESA_CORE_PROFILE,
                osmesa.OSMESA_CONTEXT_MAJOR_VERSION, major,
                osmesa.OSMESA_CONTEXT_MINOR_VERSION, minor,
                0,
            )  # fmt: skip
            try:
                self.handle = osmesa.OSMesaCreateContextAttribs(attributes, None)
            except (OSError, AttributeError, OpenGL.error.NullFunctionError) as error:
                raise RuntimeError(_MISSING) from error
            if self.handle:
                break
        if not self.handle:
            raise RuntimeError("OSMesa could not create an OpenGL 3.3 (or newer) core-profile context")
        self.buffer = None
        self.size = (0, 0)

    def make_current(self, width: int, height: int) -> None:
        """Bind the context to a default colour buffer of ``width`` x ``height`` pixels."""
        if (width, height) != self.size:
            self.buffer = (ctypes.c_ubyte * (width * height * 4))()
            self.size = (width, height)
        if not osmesa.OSMesaMakeCurrent(self.handle, self.buffer, GL.GL_UNSIGNED_BYTE, width, height):
            raise RuntimeError(f"OSMesaMakeCurrent failed for a {width} x {height} buffer")


_context: _Context | None = None


def make_current(width: int, height: int) -> None:
    """Make the process's offscreen context current, creating it on first use.

    Parameters
    ----------
    width, height
        Size of the context's default colour buffer in pixels (at least 1). Passes render into their own
        framebuffers, so this only has to be large enough for the viewport they set.

    Raises
    ------
    RuntimeError
        If OSMesa cannot give a 3.3+ core context, or if called in a process forked after the context was created.
    """
    global _context
    if width < 1 or height < 1:
        raise ValueError(f"the context buffer must be at least 1 x 1 pixels, got {width} x {height}")
    if _context is not None and _context.pid != os.getpid():
        raise RuntimeError(
            "this process was forked after the OSMesa context was created, which hangs Mesa; "
            "start worker processes with multiprocessing.get_context('spawn')"
        )
    if _context is None:
        _context = _Context()
    _context.make_current(width, height)


def gl_version() -> tuple[int, int]:
    """The (major, minor) OpenGL version of the current context; call :func:`make_current` first."""
    return int(GL.glGetIntegerv(GL.GL_MAJOR_VERSION)), int(GL.glGetIntegerv(GL.GL_MINOR_VERSION))
