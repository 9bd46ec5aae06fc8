"""The emulated CS-2000 served on a pseudo-terminal and/or a TCP socket: :class:`Emulator`.

A pseudo-terminal (the slave's path in :attr:`Emulator.port`, optionally a symlink such as ``/tmp/cs2000`` so that
``serial.serial_for_url("/tmp/cs2000")`` opens it) and a TCP server on 127.0.0.1 (``socket://127.0.0.1:PORT``),
one client at a time. Both talk to the same instrument, served by one background thread that also runs the
instrument's timers. A ``disconnect`` fault closes the TCP connection, or closes the pseudo-terminal and opens a new
one, re-pointing the symlink (like a USB re-plug that gives a new device node).
"""

from __future__ import annotations

import atexit
import contextlib
import heapq
import itertools
import os
import select
import socket
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from instruments.cs2000.emulator.faults import Fault
from instruments.cs2000.emulator.instrument import Instrument
from instruments.cs2000.emulator.transports import Link, PtyLink, SocketLink

_MAX_COMMAND = 1024  # bytes without a terminator before the instrument discards its input buffer
_CR_WAIT = 0.05  # s: after a CR, how long to wait for an LF (CR LF) before taking CR alone as the terminator
_DRAIN_LIMIT = 0.5  # s: how long a pty disconnect waits for the host to read the partial reply first


class Emulator(Instrument):
    """A CS-2000 on a pseudo-terminal and/or a TCP port, served by a background thread.

    Parameters
    ----------
    samples : mapping of str to array, optional
        Reflectance (fraction) of each sample at 380-780 nm, 1 nm (401 values). Default: ``{"white": 0.98}``.
    pty : bool
        Serve a pseudo-terminal.
    link : path, optional
        A symlink to create to the pseudo-terminal (implies ``pty``); removed on :meth:`stop`.
    socket_port : int, optional
        Serve TCP on 127.0.0.1 at this port (0: any free port, see :attr:`socket_port`).
    **settings
        The instrument's: ``sequence``, ``illuminant``, ``gain``, ``noise``, ``seed``, ``faults``, ``time_scale``,
        ``model``, ``serial_number``, ``firmware``, ``aperture`` (see
        :class:`~instruments.cs2000.emulator.instrument.Instrument`).

    Raises
    ------
    ValueError
        No transport, or a setting out of its range.
    """

    def __init__(
        self,
        samples: Mapping[str, np.ndarray | Sequence[float] | float] | None = None,
        *,
        pty: bool = True,
        link: str | os.PathLike[str] | None = None,
        socket_port: int | None = None,
        **settings: object,
    ) -> None:
        super().__init__(samples, **settings)  # type: ignore[arg-type]
        self._use_pty = pty or link is not None
        self._link_path = Path(link) if link is not None else None
        self._socket_port = socket_port
        if not self._use_pty and socket_port is None:
            raise ValueError("no transport: use pty, link or socket_port")
        self._pty: PtyLink | None = None
        self._server: socket.socket | None = None
        self._client: SocketLink | None = None
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._wake_r = self._wake_w = -1
        self._timers: list[tuple[float, int, Callable[[], None]]] = []
        self._timer_ids = itertools.count()
        self._failure: BaseException | None = None

    # --------------------------------------------------------------------------------------------- public API

    @property
    def port(self) -> str | None:
        """The pseudo-terminal's device path (changes after a ``disconnect`` fault), or None."""
        return self._pty.path if self._pty else None

    @property
    def link(self) -> str | None:
        """The symlink to the pseudo-terminal, or None."""
        return str(self._link_path) if self._link_path else None

    @property
    def url(self) -> str:
        """What to pass to ``serial.serial_for_url``: the symlink, the pty path, or the socket URL."""
        return self.link or self.port or self.socket_url  # type: ignore[return-value]

    @property
    def socket_port(self) -> int | None:
        """The TCP port served on 127.0.0.1, or None."""
        return self._server.getsockname()[1] if self._server else None

    @property
    def socket_url(self) -> str | None:
        """``socket://127.0.0.1:PORT`` or None."""
        return f"socket://127.0.0.1:{self.socket_port}" if self._server else None

    def start(self) -> Emulator:
        """Open the transports and start serving; returns self."""
        if self._thread is not None:
            raise RuntimeError("the emulator is already running")
        self._stopping.clear()
        self._wake_r, self._wake_w = os.pipe()
        try:
            if self._use_pty:
                self._pty = PtyLink()
                self._point_link()
            if self._socket_port is not None:
                self._server = socket.create_server(("127.0.0.1", self._socket_port))
        except BaseException:
            self._close_transports()
            raise
        atexit.register(self.stop)
        self._thread = threading.Thread(target=self._serve, name="cs2000-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving, close the transports and remove the symlink. Re-raises a failure of the serving thread."""
        atexit.unregister(self.stop)
        if self._thread is not None:
            self._stopping.set()
            os.write(self._wake_w, b"x")
            self._thread.join()
            self._thread = None
        self._close_transports()
        failure, self._failure = self._failure, None
        if failure is not None:
            raise RuntimeError("the CS-2000 emulator's thread failed") from failure

    def wait(self, timeout: float | None = None) -> bool:
        """Block until the serving thread ends (it does on :meth:`stop` or a failure); False on timeout."""
        thread = self._thread
        if thread is not None:
            thread.join(timeout)
            return not thread.is_alive()
        return True

    def __enter__(self) -> Emulator:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    # ------------------------------------------------------------------------------------------ transports

    def _point_link(self) -> None:
        """Create or re-point the symlink to the current pty, atomically."""
        if self._link_path is None or self._pty is None:
            return
        if self._link_path.exists() and not self._link_path.is_symlink():
            raise FileExistsError(f"{self._link_path} exists and is not a symlink; not replacing it")
        temporary = self._link_path.with_name(f".{self._link_path.name}.{os.getpid()}.tmp")
        with contextlib.suppress(FileNotFoundError):
            temporary.unlink()
        temporary.symlink_to(self._pty.path)
        os.replace(temporary, self._link_path)

    def _close_transports(self) -> None:
        link, pty = self._link_path, self._pty
        if link is not None and pty is not None and link.is_symlink() and os.readlink(link) == pty.path:
            link.unlink()
        for link in (self._pty, self._client):
            if link is not None:
                link.close()
        if self._server is not None:
            self._server.close()
        self._pty = self._client = self._server = None
        for fd in (self._wake_r, self._wake_w):
            if fd >= 0:
                os.close(fd)
        self._wake_r = self._wake_w = -1

    def _drop(self, link: Link) -> None:
        """Disconnect a link: close a TCP client; close the pty and open a new one (re-pointing the symlink)."""
        if isinstance(link, PtyLink):
            # closing the master discards what the host has not read: wait until the bytes have reached the host's
            # side (the pty moves them asynchronously, so the queue may look empty at first) and been read
            deadline, arrived = time.monotonic() + _DRAIN_LIMIT, False
            while time.monotonic() < deadline and not self._stopping.is_set():
                unread = link.unread()
                if not unread and arrived:
                    break
                arrived = arrived or unread > 0
                time.sleep(0.005)
            if link is self._pty:  # the new node is in place before the host can notice the old one is gone
                self._pty = PtyLink()
                self._point_link()
            link.close()
        else:
            link.close()
            if link is self._client:
                self._client = None

    def _send(self, link: Link, payload: bytes, faults: Sequence[Fault] = ()) -> None:
        """Write a reply, applying wire faults."""
        if link.closed:
            return
        for fault in faults:
            if fault.kind == "garbage":
                payload = fault.garbage + payload
        self._sleep(sum(f.seconds for f in faults if f.kind == "delay"))
        cut = min((int(len(payload) * f.fraction) for f in faults if f.kind == "disconnect"), default=None)
        chunking = [f for f in faults if f.kind == "chunks"]
        data = payload if cut is None else payload[:cut]
        try:
            if chunking:
                size, pause = chunking[0].chunk_size, chunking[0].seconds
                for start in range(0, len(data), size):
                    if start:
                        self._sleep(pause)
                    link.write(data[start : start + size])
            else:
                link.write(data)
        except OSError:
            self._drop(link)
            return
        if cut is not None:
            self._drop(link)

    def _sleep(self, seconds: float) -> None:
        if seconds > 0:
            self._stopping.wait(seconds * self.time_scale)

    def _serve(self) -> None:
        try:
            while not self._stopping.is_set():
                links = [link for link in (self._pty, self._client) if link is not None and not link.closed]
                readers: list = [self._wake_r, *links] + ([self._server] if self._server else [])
                timeout = max(0.0, self._timers[0][0] - time.monotonic()) if self._timers else None
                ready, _, _ = select.select(readers, [], [], timeout)
                if self._stopping.is_set():
                    break
                for item in ready:
                    if item is self._server:
                        self._accept()
                    elif item in links and not item.closed:
                        self._receive(item)
                while self._timers and self._timers[0][0] <= time.monotonic() and not self._stopping.is_set():
                    heapq.heappop(self._timers)[2]()
        except BaseException as error:  # reported by stop()
            self._failure = error

    def _accept(self) -> None:
        assert self._server is not None
        connection, _ = self._server.accept()
        if self._client is not None:
            self._client.close()  # one host at a time: a new connection replaces the old one
        self._client = SocketLink(connection)

    def _receive(self, link: Link) -> None:
        data = link.read()
        if not data:
            if isinstance(link, SocketLink):
                self._drop(link)
            return
        link.inbuf += data
        while not link.closed:
            buffer = link.inbuf
            ends = [i for i in (buffer.find(b"\r"), buffer.find(b"\n")) if i >= 0]
            if not ends:
                if len(buffer) > _MAX_COMMAND:
                    buffer.clear()
                return
            end = min(ends)
            if buffer[end : end + 1] == b"\r" and end + 1 == len(buffer):
                ready, _, _ = select.select([link], [], [], _CR_WAIT)  # is an LF following the CR?
                more = link.read() if ready else b""
                buffer += more
            terminator = b"\r\n" if buffer[end : end + 2] == b"\r\n" else buffer[end : end + 1]
            line = bytes(buffer[:end])
            del buffer[: end + len(terminator)]
            self._command(link, line, bytes(terminator))

    def _schedule(self, seconds: float, action: Callable[[], None]) -> None:
        heapq.heappush(self._timers, (time.monotonic() + seconds * self.time_scale, next(self._timer_ids), action))
