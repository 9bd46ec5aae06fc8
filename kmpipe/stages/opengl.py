"""Which OpenGL platform a command renders through (``kmpipe --gl``, a recipe's ``[line] gl``): OSMesa on the CPU,
EGL on a GPU, or ``auto`` (:mod:`renderer.gl_platform`). The choice goes into the environment, where the renderer
reads it when it first loads OpenGL, in this process and in the worker processes it spawns."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from kmpipe.errors import InputError
from renderer.gl_platform import CHOICE_VARIABLE, CHOICES, choose


def use_gl(choice: str, *, field: str, path: str | Path | None = None) -> None:
    """Render through ``choice`` (one of :data:`renderer.gl_platform.CHOICES`) from here on; InputError naming
    ``field`` (of ``path``) for another value, or when this process already renders through another platform
    (OpenGL's platform is fixed once loaded: run the command in a fresh process)."""
    if choice not in CHOICES:
        raise InputError(f"expected one of {', '.join(CHOICES)}, got {choice!r}", path=path, field=field)
    loaded = sys.modules.get("renderer.context")
    if loaded is not None and loaded.PLATFORM != choose(choice):
        raise InputError(
            f"{choice!r} renders through {choose(choice)}, but this process already renders through "
            f"{loaded.PLATFORM} (OpenGL's platform is fixed once loaded): run kmpipe in a fresh process",
            path=path,
            field=field,
        )
    os.environ[CHOICE_VARIABLE] = choice
