"""The emulate stage: a CS-2000 emulator serving a samples script until stopped (``kmpipe emulate``).

The emulator (:mod:`instruments.cs2000.emulator`) answers the instrument's protocol on a pseudo-terminal (and a TCP
port): the radiance of the sample under it is D55 (or the script's illuminant) x its reflectance, with realistic
timing and the script's injectable faults; its samples script is read by :mod:`kmpipe.formats.emulator_script`.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable
from pathlib import Path

from kmpipe.errors import InputError
from kmpipe.formats.emulator_script import emulator_from_script


def serve_emulator(
    samples: str | Path,
    *,
    link: str | Path,
    socket_port: int | None = None,
    time_scale: float | None = None,
    echo: Callable[[str], None] = print,
    stop: threading.Event | None = None,
) -> None:
    """Serve the emulator of the samples script ``samples`` on a pseudo-terminal linked at ``link`` (and on
    ``socket://127.0.0.1:socket_port``; 0: any free port) until Ctrl-C, SIGTERM or ``stop`` is set.

    ``time_scale`` multiplies the instrument's times (default: the script's, else 1). ``echo`` receives the lines
    that say where it listens. InputError naming ``--socket`` or ``--link`` when it cannot listen there.

    >>> import kmpipe, pathlib, tempfile, threading
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> stop, lines = threading.Event(), []
    >>> stop.set()  # serve, then stop at the first look
    >>> link = pathlib.Path(tempfile.mkdtemp()) / "cs2000"
    >>> serve_emulator(F1 / "emulator.toml", link=link, echo=lines.append, stop=stop)
    >>> lines[0].startswith("CS-2000 emulator: serial port /dev/pts/"), lines[1].startswith("samples: baso4, ")
    (True, True)
    """
    if socket_port is not None and not 0 <= socket_port <= 65535:
        raise InputError(f"a TCP port is 0 (any free port) to 65535, got {socket_port}", field="--socket")
    overrides: dict[str, object] = {"link": Path(link), "socket_port": socket_port}
    if time_scale is not None:
        overrides["time_scale"] = time_scale
    emulator = emulator_from_script(samples, **overrides)
    on_main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler) if on_main_thread else None
    try:
        with emulator:
            echo(f"CS-2000 emulator: serial port {emulator.port} (link {emulator.link})")
            if emulator.socket_url:
                echo(f"CS-2000 emulator: {emulator.socket_url}")
            echo(f"samples: {', '.join(emulator.sample_names)}; time scale {emulator.time_scale}; Ctrl-C to stop")
            with contextlib.suppress(KeyboardInterrupt):
                while not emulator.wait(0.5) and not (stop is not None and stop.is_set()):
                    pass
    except FileExistsError:
        raise InputError("exists and is not an emulator link; choose another path", path=Path(link),
                         field="--link") from None  # fmt: skip
    except OSError as err:
        raise InputError(f"the emulator cannot listen: {err}", field="--socket" if socket_port else "--link") from None
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
