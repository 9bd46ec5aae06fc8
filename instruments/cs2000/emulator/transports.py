"""The ends of the links a host talks to the emulated CS-2000 over: a pseudo-terminal and a TCP connection.

A pseudo-terminal (:class:`PtyLink`: the host opens its slave's :attr:`~PtyLink.path`) passes bytes unchanged both
ways and loses what the host does not read, as a serial line does. A TCP connection (:class:`SocketLink`) is one
client of the emulator's server on 127.0.0.1. Both keep the bytes received but not yet taken as a command in
``inbuf``; :mod:`instruments.cs2000.emulator.server` serves them.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import socket
import struct
import termios
import tty


class PtyLink:
    """The instrument end of a pseudo-terminal (raw mode); the host opens :attr:`path`."""

    def __init__(self) -> None:
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no CR/LF translation: bytes pass unchanged both ways
        os.set_blocking(self.master, False)  # a host that does not read loses bytes, as on a serial line
        self.path = os.ttyname(self._slave)
        self.inbuf = bytearray()
        self.closed = False

    def fileno(self) -> int:
        return self.master

    def read(self) -> bytes:
        try:
            return os.read(self.master, 4096)
        except OSError:
            return b""

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        with contextlib.suppress(BlockingIOError):
            while view:
                view = view[os.write(self.master, view) :]

    def unread(self) -> int:
        """Bytes sent that the host has not read yet."""
        return struct.unpack("i", fcntl.ioctl(self._slave, termios.FIONREAD, b"\0\0\0\0"))[0]

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            os.close(self.master)
            os.close(self._slave)


class SocketLink:
    """One TCP client of the emulator's server."""

    def __init__(self, connection: socket.socket) -> None:
        self.connection = connection
        self.inbuf = bytearray()
        self.closed = False

    def fileno(self) -> int:
        return self.connection.fileno()

    def read(self) -> bytes:
        try:
            return self.connection.recv(4096)
        except OSError:
            return b""

    def write(self, data: bytes) -> None:
        self.connection.sendall(data)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            with contextlib.suppress(OSError):
                self.connection.shutdown(socket.SHUT_RDWR)
            self.connection.close()


Link = PtyLink | SocketLink
"""Either end."""
