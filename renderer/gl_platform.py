"""Which OpenGL platform the renderer uses in a process (:mod:`renderer.context` says how each gives a context),
decided without importing OpenGL, so that it can be chosen before the first import fixes it."""

from __future__ import annotations

import ctypes

#: The values ``KMPIPE_GL`` may take.
CHOICES = ("auto", "osmesa", "egl")
#: The environment variable that chooses the platform.
CHOICE_VARIABLE = "KMPIPE_GL"
#: The environment variable that picks which hardware EGL device (0, 1, ... in EGL's order) a process renders on: one
#: GPU per worker on a machine with several.
DEVICE_VARIABLE = "KMPIPE_EGL_DEVICE"


def is_hardware(extensions: str) -> bool:
    """Whether an EGL device of these extensions (its EGL_EXTENSIONS string) is hardware: Mesa marks its software
    device ``EGL_MESA_device_software``."""
    return "EGL_MESA_device_software" not in extensions.split()


def hardware_devices() -> list[str]:
    """The EGL devices that are hardware (their extension strings; Mesa's software device left out), read through
    libEGL with ctypes before any platform is chosen; empty where libEGL or device enumeration is missing."""
    try:
        egl = ctypes.CDLL("libEGL.so.1")
    except OSError:
        return []
    address = egl.eglGetProcAddress
    address.restype, address.argtypes = ctypes.c_void_p, [ctypes.c_char_p]
    count_devices, describe = address(b"eglQueryDevicesEXT"), address(b"eglQueryDeviceStringEXT")
    if not (count_devices and describe):
        return []
    query = ctypes.CFUNCTYPE(ctypes.c_uint, ctypes.c_int, ctypes.POINTER(ctypes.c_void_p),
                             ctypes.POINTER(ctypes.c_int))(count_devices)  # fmt: skip
    string = ctypes.CFUNCTYPE(ctypes.c_char_p, ctypes.c_void_p, ctypes.c_int)(describe)
    count = ctypes.c_int(0)
    if not query(0, None, ctypes.byref(count)) or count.value <= 0:
        return []
    devices = (ctypes.c_void_p * count.value)()
    if not query(count.value, devices, ctypes.byref(count)):
        return []
    found = [
        (string(device, 0x3055) or b"").decode(errors="replace") for device in devices[: count.value]
    ]  # EXTENSIONS
    return [names for names in found if is_hardware(names)]


def choose(choice: str, hardware: bool | None = None) -> str:
    """The platform (``osmesa`` or ``egl``) for a ``KMPIPE_GL`` value; ``auto`` takes EGL where there is a hardware
    device (``hardware``; None: :func:`hardware_devices` asked). ValueError for a value not in :data:`CHOICES`."""
    if choice not in CHOICES:
        raise ValueError(f"{CHOICE_VARIABLE} must be one of {', '.join(CHOICES)}, got {choice!r}")
    if choice != "auto":
        return choice
    if hardware is None:
        hardware = bool(hardware_devices())
    return "egl" if hardware else "osmesa"
