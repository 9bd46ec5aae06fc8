"""``replay://`` pyserial URL handler: plays a recorded session log back to a driver, byte for byte.

URL: ``replay://PATH[?timing=fast|real][&strict=1|0][&connection=N]`` (after ``import instruments.urlhandler``)

- ``PATH`` is everything between ``replay://`` and ``?``: ``replay:///tmp/s.jsonl`` is the absolute path
  ``/tmp/s.jsonl``, ``replay://tests/data/s.jsonl`` is relative to the current directory. Percent escapes are
  decoded (write ``?`` as ``%3F``, ``#`` as ``%23``, ``%`` as ``%25``).
- ``timing=fast`` (default) never sleeps. ``timing=real`` makes each recorded ``rx`` chunk arrive as long after
  the write it follows as it did when recorded, makes a recorded ``timeout`` block for its ``waited`` seconds,
  and makes a read that the recording has no answer for block for the port's ``timeout``.
- ``strict=1`` (default) raises :class:`ReplayMismatch` when the driver writes other bytes than the recording
  has, or reads where the recording discarded input; ``strict=0`` warns (:class:`ReplayWarning`) and goes on.
- ``connection=N`` replays only the file's connection N (0 = the first header). Without it, the connections
  are replayed in file order: closing the port and opening it again moves to the next one.

What the driver sees:

- ``write(data)`` is compared with the recorded ``tx`` bytes as one byte stream, so a write may cover several
  recorded writes or part of one. After a mismatch, a non-strict replay skips the rest of the recorded write
  in which the difference lies (a driver that writes one command per call stays in step).
- ``read(size)`` returns the recorded ``rx`` bytes in order, at most the rest of the current recorded chunk per
  call. An ``rx`` chunk can only be read once the driver has written every ``tx`` byte recorded before it;
  until then a read returns ``b""``, as the instrument would have kept silent (a read without a timeout would
  block forever and raises :class:`ReplayMismatch` instead). A recorded ``timeout`` makes the read return
  ``b""``. Reading at a recorded ``close`` or past the end of the connection raises ``SerialException``
  ("disconnected"), as a vanished USB device does.
- ``in_waiting`` is the rest of the current chunk (or of the pending input a recorded ``flush`` discards); with
  ``timing=real``, 0 until the chunk is due.
- ``reset_input_buffer()`` drops the rest of a partly read chunk and consumes a recorded ``flush`` if one is next.
- :meth:`Serial.done` and :meth:`Serial.assert_complete` tell whether the driver did everything it did when
  the session was recorded (every byte written and read, every timeout, flush and close replayed).
"""

from __future__ import annotations

import time
import urllib.parse
import warnings
from pathlib import Path
from typing import Any

import serial
from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from instruments.session_log import LogConnection, LogEvent, SessionLogError, read_session_log

__all__ = ["ReplayMismatch", "ReplayWarning", "Serial", "parse_url"]

_URL_FORM = '"replay://PATH[?timing=fast|real][&strict=1|0][&connection=N]"'
_BOOLEANS = {"1": True, "true": True, "yes": True, "0": False, "false": False, "no": False}


class ReplayMismatch(SerialException):
    """The driver did something else than the recorded session shows (strict replay)."""


class ReplayWarning(UserWarning):
    """A mismatch that a non-strict replay went on after."""


def parse_url(url: str) -> tuple[str, str, bool, int | None]:
    """The parts of a ``replay://`` URL: the log's path, ``timing``, ``strict`` and ``connection`` (None: all).

    Raises
    ------
    serial.SerialException
        Another scheme, no path, a ``#`` in the path, or an unknown option or value.
    """
    parts = urllib.parse.urlsplit(url)
    if parts.scheme.lower() != "replay":
        raise SerialException(f"expected {_URL_FORM}, got {url!r}")
    if parts.fragment:
        raise SerialException(f"{url!r}: a '#' in the path must be written %23")
    path = urllib.parse.unquote(parts.netloc + parts.path)
    if not path:
        raise SerialException(f"{url!r} names no file; expected {_URL_FORM}")
    timing, strict, selected = "fast", True, None
    for key, value in urllib.parse.parse_qsl(parts.query, keep_blank_values=True):
        if key == "timing" and value in ("fast", "real"):
            timing = value
        elif key == "strict" and value.lower() in _BOOLEANS:
            strict = _BOOLEANS[value.lower()]
        elif key == "connection" and value.isdigit():
            selected = int(value)
        else:
            raise SerialException(f"{url!r}: bad option {key}={value!r}; expected {_URL_FORM}")
    return path, timing, strict, selected


class _Cursor:
    """How far one recorded connection has been replayed.

    ``tx`` are the connection's writes, ``rx`` every other event (rx, timeout, flush, close) in order;
    ``tx_off`` and ``rx_off`` count the bytes already used of the current entry. The anchor pairs the recorded
    time of the last completed write (s since the header) with the clock reading when the driver completed it.
    """

    def __init__(self, connection: LogConnection) -> None:
        self.connection = connection
        self.tx = [event for event in connection.events if event.kind == "tx"]
        self.rx = [event for event in connection.events if event.kind != "tx"]
        self.tx_i = self.tx_off = self.rx_i = self.rx_off = 0
        self.opened = False
        self.anchor_t = 0.0
        self.anchor_clock = 0.0

    def start(self, clock: float) -> None:
        """Mark the connection opened at ``clock`` (s, monotonic)."""
        self.opened = True
        self.anchor_clock = clock

    def next_rx(self) -> LogEvent | None:
        """The next event the driver's reads face, or None at the end of the connection."""
        return self.rx[self.rx_i] if self.rx_i < len(self.rx) else None

    def next_tx_line(self) -> int | None:
        """Line of the next recorded write not yet fully written, or None when all are."""
        return self.tx[self.tx_i].line if self.tx_i < len(self.tx) else None

    def available(self, event: LogEvent) -> bool:
        """Whether every write recorded before ``event`` has been written."""
        line = self.next_tx_line()
        return line is None or line > event.line

    def tx_span(self, size: int) -> tuple[bytes, list[int]]:
        """The next ``size`` recorded tx bytes (fewer at the end) and, per byte, its line, without consuming."""
        span, lines = bytearray(), []
        i, offset = self.tx_i, self.tx_off
        while len(span) < size and i < len(self.tx):
            part = self.tx[i].data[offset : offset + size - len(span)]
            span += part
            lines += [self.tx[i].line] * len(part)
            i, offset = i + 1, 0
        return bytes(span), lines

    def consume_tx(self, size: int, clock: float) -> None:
        """Consume ``size`` recorded tx bytes (written at ``clock``)."""
        while size and self.tx_i < len(self.tx):
            step = min(size, len(self.tx[self.tx_i].data) - self.tx_off)
            self.tx_off += step
            size -= step
            if self.tx_off == len(self.tx[self.tx_i].data):
                self.finish_tx_entry(clock)

    def finish_tx_entry(self, clock: float) -> None:
        """Skip the rest of the current recorded write and re-anchor the timing on it."""
        self.anchor_t, self.anchor_clock = self.tx[self.tx_i].t, clock
        self.tx_i += 1
        self.tx_off = 0

    def take(self, size: int) -> bytes:
        """Return up to ``size`` bytes of the current rx (or flush) entry and advance."""
        event = self.rx[self.rx_i]
        data = event.data[self.rx_off : self.rx_off + size]
        self.rx_off += len(data)
        if self.rx_off == len(event.data):
            self.rx_i += 1
            self.rx_off = 0
        return data

    def drop_partial(self) -> None:
        """Discard the rest of a partly read chunk (the input a real port would still hold)."""
        if self.rx_off:
            self.rx_i += 1
            self.rx_off = 0

    def due(self, event: LogEvent) -> float:
        """Clock reading (s) at which ``event`` happens in real timing."""
        return self.anchor_clock + event.t - self.anchor_t

    def leftovers(self) -> list[str]:
        """What the driver has not replayed yet, one phrase per kind."""
        where = f"connection at line {self.connection.line}"
        if not self.opened:
            return [f"{where} never opened"]
        items = []
        if self.tx_i < len(self.tx):
            event = self.tx[self.tx_i]
            items.append(
                f"{where}: {len(self.tx) - self.tx_i} write(s) not made, the first at line {event.line}: "
                f"{event.data[self.tx_off :]!r}"
            )
        if self.rx_i < len(self.rx):
            event = self.rx[self.rx_i]
            shown = f" {event.data[self.rx_off :]!r}" if event.data else ""
            items.append(
                f"{where}: {len(self.rx) - self.rx_i} event(s) not replayed, the first at line "
                f"{event.line}: {event.kind}{shown}"
            )
        return items


class Serial(SerialBase):
    """A serial port that replays a session log written by :class:`instruments.session_log.RecordingSerial`.

    Create it with ``serial.serial_for_url("replay://PATH?...", timeout=...)``; see the module docstring for
    the URL and what reads and writes do. Port settings are accepted and ignored.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._loaded_url: str | None = None
        self._path = Path()
        self._timing = "fast"
        self._strict = True
        self._cursors: list[_Cursor] = []
        self._next = 0
        self._cursor: _Cursor | None = None
        super().__init__(*args, **kwargs)

    # -- URL and file --------------------------------------------------------------------------------------

    def _load(self, url: str) -> None:
        """Parse ``url`` and read its session log."""
        path, timing, strict, selected = parse_url(url)
        try:
            connections = read_session_log(path)
        except OSError as err:
            raise SerialException(f"cannot read the session log {path}: {err.strerror or err}") from err
        except SessionLogError as err:
            raise SerialException(str(err)) from err
        if selected is not None:
            if selected >= len(connections):
                raise SerialException(
                    f"{path} holds {len(connections)} connection(s), numbered from 0: "
                    f"connection={selected} does not exist"
                )
            connections = [connections[selected]]
        self._loaded_url, self._path, self._timing, self._strict = url, Path(path), timing, strict
        self._cursors = [_Cursor(connection) for connection in connections]
        self._next = 0
        self._cursor = None
        self._virtual = 0.0

    @property
    def header(self) -> dict[str, Any]:
        """Header line of the connection being replayed (``port``, ``started``, ``meta``, ...)."""
        if self._cursor is None:
            raise PortNotOpenError()
        return self._cursor.connection.header

    # -- open, close, settings -----------------------------------------------------------------------------

    def open(self) -> None:
        """Load the log (on the first open, or after the URL changed) and start its next connection."""
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        if self._port != self._loaded_url:
            self._load(self._port)
        if self._next >= len(self._cursors):
            raise SerialException(f"{self._path}: every recorded connection has been replayed already")
        self._virtual = 0.0
        self._cursor = self._cursors[self._next]
        self._next += 1
        self._cursor.start(time.monotonic())
        self.is_open = True

    def close(self) -> None:
        """Close the port, consuming the recorded ``close`` if the driver has reached it (idempotent)."""
        if not self.is_open:
            return
        self.is_open = False
        cursor = self._cursor
        cursor.drop_partial()
        event = cursor.next_rx()
        if event is not None and event.kind == "close" and cursor.available(event):
            cursor.rx_i += 1

    def _reconfigure_port(self) -> None:
        """Settings have no effect on a replay."""

    def _update_rts_state(self) -> None:
        """Modem lines have no effect on a replay."""

    def _update_dtr_state(self) -> None:
        """Modem lines have no effect on a replay."""

    def _update_break_state(self) -> None:
        """A break has no effect on a replay."""

    # -- completeness --------------------------------------------------------------------------------------

    def _leftovers(self) -> list[str]:
        """What has not been replayed yet, over every connection in scope."""
        if not self._cursors:
            return ["the port was never opened"]
        return [item for cursor in self._cursors for item in cursor.leftovers()]

    def done(self) -> bool:
        """Whether the whole recording (every connection in scope) has been replayed."""
        return not self._leftovers()

    def assert_complete(self) -> None:
        """Raise AssertionError, listing what is left, unless :meth:`done`."""
        leftovers = self._leftovers()
        if leftovers:
            raise AssertionError(f"replay of {self._loaded_url or self._port} incomplete: " + "; ".join(leftovers))

    # -- data ----------------------------------------------------------------------------------------------

    def _mismatch(self, message: str) -> None:
        """Raise ReplayMismatch (strict) or warn."""
        if self._strict:
            raise ReplayMismatch(message)
        warnings.warn(f"{message}; going on (strict=0)", ReplayWarning, stacklevel=3)

    def write(self, data: bytes | bytearray | memoryview) -> int:
        """Check ``data`` against the recorded writes; returns ``len(data)``."""
        if not self.is_open:
            raise PortNotOpenError()
        data = serial.to_bytes(data)
        cursor = self._cursor
        expected, lines = cursor.tx_span(len(data))
        if expected == data:
            cursor.consume_tx(len(data), time.monotonic())
            return len(data)
        first = next((i for i, (a, b) in enumerate(zip(expected, data, strict=False)) if a != b), len(expected))
        where = (
            f"{self._path}:{lines[first]}"
            if first < len(lines)
            else f"{self._path}: after the last recorded write of the connection at line {cursor.connection.line}"
        )
        self._mismatch(
            f"replay mismatch at {where}: the driver wrote {data!r}, the recording has {expected!r} "
            f"(first difference at byte {first})"
        )
        cursor.consume_tx(first, time.monotonic())
        if cursor.next_tx_line() is not None:
            cursor.finish_tx_entry(time.monotonic())
        return len(data)

    def clock(self) -> float:
        """Seconds on the recording's clock, for a driver's deadlines (``time.monotonic`` in real timing).

        In fast timing it is the recorded time of the last event replayed, and where the recording has nothing
        more to read before the driver's next write, the time of that write: the original driver waited until
        then, so its deadline has passed on this clock too, without the replay waiting for it.
        """
        if self._timing == "real" or self._cursor is None:
            return time.monotonic()
        return max(self._virtual, self._cursor.anchor_t)

    def sleep(self, seconds: float) -> None:
        """A driver's pause: real in real timing, none in fast timing (the recorded events carry the time)."""
        if self._timing == "real":
            time.sleep(seconds)

    def _sleep_until(self, clock: float) -> None:
        """Sleep until the monotonic clock reads ``clock`` (s)."""
        delay = clock - time.monotonic()
        if delay > 0:
            time.sleep(delay)

    def _silence(self, cursor: _Cursor, event: LogEvent | None) -> bytes:
        """A read that the recording has nothing for at this point: a timeout, or the end of the device."""
        line = cursor.next_tx_line()
        if line is not None:  # to the next recorded write; already there (a log out of order): the timeout passes
            written = cursor.tx[cursor.tx_i].t
            self._virtual = written if written > self._virtual else self._virtual + max(self._timeout or 0.0, 1e-3)
        if line is None:
            raise SerialException(
                f"disconnected: the recording {self._path} (connection at line "
                f"{cursor.connection.line}) ends here, and the driver reads on"
            )
        if self._timeout is None:
            raise ReplayMismatch(
                f"{self._path}:{line}: the driver reads without a timeout (it would block "
                "forever), but the recording has nothing to read before this write"
            )
        if self._timing == "real":
            time.sleep(self._timeout)
        return b""

    def read(self, size: int = 1) -> bytes:
        """Return up to ``size`` recorded bytes (at most the rest of the current chunk), or ``b""`` on a timeout."""
        if not self.is_open:
            raise PortNotOpenError()
        if size <= 0:
            return b""
        cursor = self._cursor
        while True:
            event = cursor.next_rx()
            if event is None or not cursor.available(event):
                return self._silence(cursor, event)
            self._virtual = max(self._virtual, event.t)
            if event.kind == "rx":
                if self._timing == "real" and not cursor.rx_off:
                    self._sleep_until(cursor.due(event))
                return cursor.take(size)
            if event.kind == "timeout":
                cursor.rx_i += 1
                if self._timing == "real" and event.waited:
                    time.sleep(event.waited)
                return b""
            if event.kind == "close":
                raise SerialException(
                    f"disconnected: the recording closes the port at {self._path}:{event.line}, and the driver reads on"
                )
            self._mismatch(
                f"replay mismatch at {self._path}:{event.line}: the recording discards {event.data!r} "
                "with reset_input_buffer() here, but the driver reads"
            )
            if event.data:
                return cursor.take(size)
            cursor.rx_i += 1

    @property
    def in_waiting(self) -> int:
        """Bytes a read would return at once: the rest of the current chunk (0 before it is due, in real timing)."""
        if not self.is_open:
            raise PortNotOpenError()
        cursor = self._cursor
        event = cursor.next_rx()
        if event is None or event.kind not in ("rx", "flush") or not cursor.available(event):
            return 0
        if self._timing == "real" and event.kind == "rx" and not cursor.rx_off and cursor.due(event) > time.monotonic():
            return 0
        return len(event.data) - cursor.rx_off

    def reset_input_buffer(self) -> None:
        """Drop the rest of a partly read chunk, and consume the recorded ``flush`` if it is next."""
        if not self.is_open:
            raise PortNotOpenError()
        cursor = self._cursor
        cursor.drop_partial()
        event = cursor.next_rx()
        if event is not None and event.kind == "flush" and cursor.available(event):
            cursor.rx_i += 1

    def reset_output_buffer(self) -> None:
        """Nothing is ever waiting to be sent."""

    def flush(self) -> None:
        """Nothing is ever waiting to be sent."""

    @property
    def out_waiting(self) -> int:
        """Bytes written but not yet sent: always 0, writes complete at once."""
        return 0
