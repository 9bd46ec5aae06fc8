"""The offscreen OpenGL context: one core-profile context per process, through OSMesa or EGL.

Two platforms give the renderer a context without a window; the shaders are the same on both:

- **OSMesa** (``libosmesa6``): Mesa's llvmpipe on the CPU, on any machine.
- **EGL** (``libegl1``, ``libopengl0``): a GPU's driver (NVIDIA, Mesa's radeonsi/iris), the context made on the EGL
  device itself with no display or window (``EGL_EXT_platform_device``); on a machine with no GPU, Mesa's llvmpipe
  through EGL's surfaceless platform (``EGL_MESA_platform_surfaceless``), which is how EGL is tested here.

The environment variable ``KMPIPE_GL`` chooses (:mod:`renderer.gl_platform`): ``osmesa``, ``egl`` or ``auto`` (the
default: EGL where EGL lists a hardware device, one whose extensions do not say ``EGL_MESA_device_software``, else
OSMesa); ``KMPIPE_EGL_DEVICE`` which hardware device (0, 1, ...). ``kmpipe --gl`` and a recipe's ``[line] gl`` set
it for the process and the workers it spawns.

PyOpenGL chooses its platform once, when ``OpenGL.platform`` is first imported, from ``PYOPENGL_PLATFORM``. This
module therefore decides and sets it before importing OpenGL, and every other renderer module takes its ``GL`` from
here so that the order cannot go wrong.

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

from renderer.gl_platform import CHOICE_VARIABLE, DEVICE_VARIABLE, choose, is_hardware

_MISSING = {
    "osmesa": "the OSMesa offscreen OpenGL library could not be loaded: install the Debian package libosmesa6 "
    "(apt-get install libosmesa6) and the Python package PyOpenGL",
    "egl": "EGL could not give an OpenGL context: install the Debian packages libegl1, libegl-mesa0 and libopengl0 "
    "(or the GPU vendor's driver with its EGL library) and the Python package PyOpenGL",
}


try:
    PLATFORM = choose(os.environ.get(CHOICE_VARIABLE, "auto"))
except ValueError as _error:
    raise RuntimeError(str(_error)) from None

if "OpenGL.platform" in sys.modules and os.environ.get("PYOPENGL_PLATFORM") != PLATFORM:
    raise RuntimeError(
        f"OpenGL was imported before renderer.context with a platform other than {PLATFORM}; import renderer "
        f"modules first or set PYOPENGL_PLATFORM={PLATFORM} before the first `import OpenGL`"
    )
os.environ["PYOPENGL_PLATFORM"] = PLATFORM

# The imports must follow the environment variable above.
try:
    import OpenGL.error
    import OpenGL.platform
    from OpenGL import GL

    if PLATFORM == "osmesa":
        from OpenGL import osmesa
    else:
        from OpenGL import EGL
        from OpenGL.EGL.EXT.device_base import eglQueryDevicesEXT, eglQueryDeviceStringEXT
        from OpenGL.EGL.EXT.platform_base import eglGetPlatformDisplayEXT
except (ImportError, OSError, AttributeError) as _error:
    raise RuntimeError(_MISSING[PLATFORM]) from _error

_EXPECTED = {"osmesa": "OSMesaPlatform", "egl": "EGLPlatform"}[PLATFORM]
if type(OpenGL.platform.PLATFORM).__name__ != _EXPECTED:
    raise RuntimeError(
        f"PyOpenGL chose {type(OpenGL.platform.PLATFORM).__name__}, not {_EXPECTED}: {_MISSING[PLATFORM]}"
    )

__all__ = ["GL", "PLATFORM", "gl_version", "lock", "make_current", "renderer_name"]

#: Held by a rendering pass for all its GL work: the process's one context is current in one thread at a time.
lock = threading.RLock()

#: Core-profile versions tried in order, best first.
_VERSIONS = ((4, 5), (3, 3))


class _OSMesaContext:
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
                raise RuntimeError(_MISSING["osmesa"]) from error
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


#: EGL_PLATFORM_DEVICE_EXT and EGL_PLATFORM_SURFACELESS_MESA.
_DEVICE_PLATFORM, _SURFACELESS_PLATFORM = 0x313F, 0x31DD


class _EGLContext:
    """The process's EGL context with no surface (every pass draws into its own framebuffers): on the first hardware
    EGL device, else on Mesa's surfaceless platform."""

    def __init__(self) -> None:
        self.pid = os.getpid()
        try:
            self.display = self._display()
            major, minor = EGL.EGLint(), EGL.EGLint()
            if not (self.display and EGL.eglInitialize(self.display, ctypes.byref(major), ctypes.byref(minor))):
                raise RuntimeError(f"EGL could not initialise a display: {_MISSING['egl']}")
            EGL.eglBindAPI(EGL.EGL_OPENGL_API)
            self.context = None
            for major_version, minor_version in _VERSIONS:
                attributes = (EGL.EGLint * 7)(
                    EGL.EGL_CONTEXT_MAJOR_VERSION, major_version,
                    EGL.EGL_CONTEXT_MINOR_VERSION, minor_version,
                    EGL.EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL.EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT,
                    EGL.EGL_NONE,
                )  # fmt: skip
                context = EGL.eglCreateContext(self.display, EGL.EGLConfig(), EGL.EGL_NO_CONTEXT, attributes)
                if context:
                    self.context = context
                    break
        except (OSError, AttributeError, OpenGL.error.Error) as error:
            raise RuntimeError(f"{_MISSING['egl']} ({error})") from error
        if not self.context:
            raise RuntimeError("EGL could not create an OpenGL 3.3 (or newer) core-profile context without a surface")

    @staticmethod
    def _display():
        """The display of hardware device ``KMPIPE_EGL_DEVICE`` (default 0), else Mesa's surfaceless platform."""
        count = EGL.EGLint(0)
        hardware = []
        if eglQueryDevicesEXT(0, None, ctypes.byref(count)) and count.value > 0:
            devices = (EGL.EGLDeviceEXT * count.value)()
            eglQueryDevicesEXT(count.value, devices, ctypes.byref(count))
            for device in devices[: count.value]:
                extensions = (eglQueryDeviceStringEXT(device, EGL.EGL_EXTENSIONS) or b"").decode(errors="replace")
                if is_hardware(extensions):
                    hardware.append(device)
        wanted = os.environ.get(DEVICE_VARIABLE, "0")
        if not hardware:
            return eglGetPlatformDisplayEXT(_SURFACELESS_PLATFORM, EGL.EGL_DEFAULT_DISPLAY, None)
        if not (wanted.isdigit() and int(wanted) < len(hardware)):
            raise RuntimeError(f"{DEVICE_VARIABLE}={wanted!r}: expected 0 to {len(hardware) - 1}, the hardware EGL "
                               f"devices of this machine")  # fmt: skip
        return eglGetPlatformDisplayEXT(_DEVICE_PLATFORM, hardware[int(wanted)], None)

    def make_current(self, width: int, height: int) -> None:
        """Make the context current (no surface: ``width`` and ``height`` are the passes' own)."""
        if not EGL.eglMakeCurrent(self.display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, self.context):
            raise RuntimeError("eglMakeCurrent failed for the renderer's context")


_context: _OSMesaContext | _EGLContext | None = None


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
        If the platform cannot give a 3.3+ core context, or if called in a process forked after the context was
        created.
    """
    global _context
    if width < 1 or height < 1:
        raise ValueError(f"the context buffer must be at least 1 x 1 pixels, got {width} x {height}")
    if _context is not None and _context.pid != os.getpid():
        raise RuntimeError(
            "this process was forked after the OpenGL context was created, which hangs Mesa; "
            "start worker processes with multiprocessing.get_context('spawn')"
        )
    if _context is None:
        _context = _OSMesaContext() if PLATFORM == "osmesa" else _EGLContext()
    _context.make_current(width, height)


def gl_version() -> tuple[int, int]:
    """The (major, minor) OpenGL version of the current context; call :func:`make_current` first."""
    return int(GL.glGetIntegerv(GL.GL_MAJOR_VERSION)), int(GL.glGetIntegerv(GL.GL_MINOR_VERSION))


def renderer_name() -> str:
    """The platform and the GL renderer it gives, e.g. ``OSMesa: llvmpipe (LLVM 15.0.6, 256 bits)``; makes the
    context current if it is not yet."""
    make_current(1, 1)
    name = (GL.glGetString(GL.GL_RENDERER) or b"").decode(errors="replace")
    return f"{'OSMesa' if PLATFORM == 'osmesa' else 'EGL'}: {name}"
