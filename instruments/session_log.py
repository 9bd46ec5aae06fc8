"""Byte-exact session logs of a serial instrument, written before anything is parsed.

A session log is a JSON-lines file (format: ``docs/formats.md``, "Instrument session log"). Each
connection starts with a header line; each later line is one event on the wire, stamped with ``t``, the
seconds (monotonic clock) since the connection's header was written:

- ``tx``: bytes the host wrote, logged *before* they are sent;
- ``rx``: a chunk of bytes as the port delivered it, logged and flushed *before* the caller gets it;
- ``timeout``: a read that returned nothing (``waited``: how long it blocked, in s), or, with
  ``"deadline": true``, a ``read_until`` that pyserial ended on its overall timeout while bytes were still
  trickling in;
- ``flush``: ``reset_input_buffer()``: ``data`` are the pending bytes it discarded, ``unread`` the number of
  bytes of the last ``rx`` chunk that the caller never read;
- ``close``: the host closed the port.

Bytes are JSON strings of code points U+0000-U+00FF, one per byte (ISO-8859-1), so that printable ASCII reads
as itself and every other byte is a JSON escape (``\\r``, ``\\n``, ``\\u0000``, ``\\u00ff``):
:func:`encode_bytes` and :func:`decode_bytes` convert exactly.

:class:`RecordingSerial` records a pyserial port; :func:`open_recorded` opens a URL and records it;
:func:`read_session_log` reads a log back (the ``replay://`` URL handler in :mod:`instruments.urlhandler` uses it).
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import serial
from serial.serialutil import PortNotOpenError, SerialBase, SerialException

__all__ = [
    "FORMAT_VERSION",
    "LogConnection",
    "LogEvent",
    "RecordingSerial",
    "SessionLog",
    "SessionLogError",
    "decode_bytes",
    "encode_bytes",
    "open_recorded",
    "read_session_log",
]

FORMAT_VERSION = 1
"""Value of the ``kmpipe_session_log`` key of a header line."""

EVENT_KINDS = ("tx", "rx", "timeout", "flush", "close")
"""Values of an event's ``dir`` key."""


class SessionLogError(ValueError):
    """A session log file that cannot be read or appended to; the message names the file and line."""


def encode_bytes(data: bytes) -> str:
    """Return ``data`` as a string of code points U+0000-U+00FF, one per byte (JSON then escapes the unprintable)."""
    return bytes(data).decode("latin-1")


def decode_bytes(text: str) -> bytes:
    """Return the bytes of a string written by :func:`encode_bytes`; a code point above U+00FF raises ValueError."""
    return text.encode("latin-1")


def _json_line(entry: dict[str, Any]) -> str:
    """Return ``entry`` as one line of ASCII JSON; DEL (0x7f), which JSON need not escape, is escaped too."""
    return json.dumps(entry, ensure_ascii=True).replace("\x7f", "\\u007f") + "\n"


class SessionLog:
    """One connection's session log, appended to a JSON-lines file.

    Parameters
    ----------
    path
        The log file. A new (or empty) file gets a header line; an existing log gets another header with
        ``"resumed": true``, so one file holds every connection of a session, in order. A non-empty file whose
        first line is not a session-log header raises :class:`SessionLogError`.
    port
        The port name or URL, written to the header.
    meta
        JSON-serializable metadata for the header (operator, sample, instrument serial, ...).
    fsync
        Also ``os.fsync`` after every line (survives a power cut, not only a crash of the program); every
        line is flushed to the operating system in any case.

    Attributes
    ----------
    path : pathlib.Path
    header : dict
        The header line written for this connection.
    """

    def __init__(
        self, path: str | os.PathLike[str], *, port: str, meta: dict[str, Any] | None = None, fsync: bool = False
    ) -> None:
        self.path = Path(path)
        self._fsync = fsync
        resumed = self.path.exists() and self.path.stat().st_size > 0
        if resumed:
            self._check_existing()
        self._file = self.path.open("a", encoding="ascii", newline="\n")
        self._t0 = time.monotonic()
        started = datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")
        self.header = {
            "kmpipe_session_log": FORMAT_VERSION,
            "port": port,
            "started": started,
            "resumed": resumed,
            "meta": dict(meta or {}),
        }
        if resumed and not self._ends_with_newline():
            self._file.write("\n")  # a line cut short by a crash must not swallow the new header
        self._write(self.header)

    def _check_existing(self) -> None:
        """Raise SessionLogError unless the file's first line is a session-log header."""
        with self.path.open("rb") as file:
            first = file.readline()
        try:
            header = json.loads(first)
        except ValueError:
            header = None
        if not isinstance(header, dict) or header.get("kmpipe_session_log") != FORMAT_VERSION:
            raise SessionLogError(f"{self.path}:1: not a session log (version {FORMAT_VERSION}); refusing to append")

    def _ends_with_newline(self) -> bool:
        """Whether the existing file's last byte is a line feed."""
        with self.path.open("rb") as file:
            file.seek(-1, os.SEEK_END)
            return file.read(1) == b"\n"

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called."""
        return self._file.closed

    def elapsed(self) -> float:
        """Seconds (monotonic clock) since this connection's header was written."""
        return time.monotonic() - self._t0

    def record(self, kind: str, data: bytes | None = None, **fields: Any) -> dict[str, Any]:
        """Append one event line and flush it to the operating system (and disk, with ``fsync``).

        Parameters
        ----------
        kind
            The event's ``dir``: one of ``tx``, ``rx``, ``timeout``, ``flush``, ``close``.
        data
            The event's bytes, if it has any.
        fields
            Further keys (``waited`` in s for ``timeout``, ``unread`` for ``flush``), written after ``data``.

        Returns
        -------
        dict
            The entry as written (``data`` as a string).
        """
        if kind not in EVENT_KINDS:
            raise ValueError(f"unknown session-log event {kind!r}; expected one of {', '.join(EVENT_KINDS)}")
        entry: dict[str, Any] = {"t": round(self.elapsed(), 6), "dir": kind}
        if data is not None:
            entry["data"] = encode_bytes(data)
        entry.update(fields)
        self._write(entry)
        return entry

    def _write(self, entry: dict[str, Any]) -> None:
        """Write one line and push it out of the process."""
        self._file.write(_json_line(entry))
        self._file.flush()
        if self._fsync:
            os.fsync(self._file.fileno())

    def close(self) -> None:
        """Close the file (idempotent)."""
        self._file.close()

    def __enter__(self) -> SessionLog:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


class RecordingSerial(SerialBase):
    """A pyserial port that logs every byte written and read to a :class:`SessionLog`.

    It is a :class:`serial.SerialBase`, so pyserial's own ``read_until``, ``read_all``, ``readline`` and
    ``iread_until`` run on top of the recorded :meth:`read`. Port settings (``timeout``, ``baudrate``, ...) are
    copied from the wrapped port and written back to it when changed on this object: change them here, not on
    the wrapped port. Not thread-safe; closing it closes the wrapped port and the log.

    Reads take from the wrapped port whatever it has waiting (at least ``size`` bytes, or until its timeout)
    and log that as one ``rx`` chunk before returning the first ``size`` bytes; the rest is returned by the next
    reads, so ``read_until`` (which reads one byte at a time) logs whole chunks rather than single bytes.

    Parameters
    ----------
    serial_port
        An open (or openable) pyserial port: ``serial.Serial``, ``serial.serial_for_url(...)``, any SerialBase.
    log
        The connection's log; owned by this object from now on.
    """

    def __init__(self, serial_port: SerialBase, log: SessionLog) -> None:
        self._serial = serial_port
        self._log = log
        self._buffer = bytearray()  # bytes already logged as rx but not yet returned to the caller
        self._last_read_timed_out = False
        super().__init__()
        self.apply_settings(serial_port.get_settings())
        self.port = serial_port.port
        self.is_open = serial_port.is_open

    @property
    def serial_port(self) -> SerialBase:
        """The wrapped port."""
        return self._serial

    @property
    def log(self) -> SessionLog:
        """The session log being written."""
        return self._log

    def open(self) -> None:
        """Open the wrapped port; a recording that was closed cannot be reopened (start a new SessionLog)."""
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._log.closed:
            raise SerialException(
                f"the session log {self._log.path} is closed: record the new connection with a "
                "new SessionLog (it appends a resumed header)"
            )
        if not self._serial.is_open:
            self._serial.open()
        self.is_open = True

    def close(self) -> None:
        """Log ``close``, then close the wrapped port and the log (idempotent)."""
        if not self.is_open:
            return
        self.is_open = False
        try:
            self._log.record("close")
        finally:
            self._serial.close()
            self._log.close()

    def _reconfigure_port(self) -> None:
        """Pass settings changed on this object on to the wrapped port."""
        self._serial.apply_settings(self.get_settings())

    def _update_rts_state(self) -> None:
        """Set the wrapped port's RTS line."""
        self._serial.rts = self._rts_state

    def _update_dtr_state(self) -> None:
        """Set the wrapped port's DTR line."""
        self._serial.dtr = self._dtr_state

    def _update_break_state(self) -> None:
        """Set or clear a break on the wrapped port."""
        self._serial.break_condition = self._break_state

    @property
    def cts(self) -> bool:
        """Clear To Send line of the wrapped port."""
        return self._serial.cts

    @property
    def dsr(self) -> bool:
        """Data Set Ready line of the wrapped port."""
        return self._serial.dsr

    @property
    def ri(self) -> bool:
        """Ring Indicator line of the wrapped port."""
        return self._serial.ri

    @property
    def cd(self) -> bool:
        """Carrier Detect line of the wrapped port."""
        return self._serial.cd

    @property
    def in_waiting(self) -> int:
        """Bytes that a read would return without waiting: those read but not yet returned, plus the port's."""
        if not self.is_open:
            raise PortNotOpenError()
        return len(self._buffer) + self._serial.in_waiting

    @property
    def out_waiting(self) -> int:
        """Bytes written but not yet sent by the wrapped port."""
        return self._serial.out_waiting

    def write(self, data: bytes | bytearray | memoryview) -> int | None:
        """Log ``data`` as ``tx``, then send it; returns what the wrapped port's ``write`` returns."""
        if not self.is_open:
            raise PortNotOpenError()
        data = serial.to_bytes(data)
        self._log.record("tx", data)
        return self._serial.write(data)

    def flush(self) -> None:
        """Wait until everything written has been sent (the wrapped port's ``flush``)."""
        self._serial.flush()

    def read(self, size: int = 1) -> bytes:
        """Read up to ``size`` bytes; every chunk taken from the port is logged as ``rx`` before it is returned.

        A read that returns nothing (the port's timeout expired) is logged as ``timeout`` with ``waited``, the
        seconds it blocked.
        """
        if not self.is_open:
            raise PortNotOpenError()
        if size <= 0:
            return b""
        if not self._buffer:
            started = time.monotonic()
            chunk = self._serial.read(max(size, self._serial.in_waiting))
            if not chunk:
                self._last_read_timed_out = True
                self._log.record("timeout", waited=round(time.monotonic() - started, 6))
                return b""
            waiting = self._serial.in_waiting  # what arrived while the read blocked belongs to the same chunk
            if waiting:
                chunk += self._serial.read(waiting)
            self._log.record("rx", chunk)
            self._buffer += chunk
        self._last_read_timed_out = False
        data = bytes(self._buffer[:size])
        del self._buffer[:size]
        return data

    def read_until(self, expected: bytes = serial.LF, size: int | None = None) -> bytes:
        """pyserial's ``read_until`` (through :meth:`read`); when its overall timeout ends it while bytes were
        still arriving (no read came back empty), a ``timeout`` event with ``"deadline": true`` and ``waited`` 0 s
        is logged, so that a replay ends that ``read_until`` at the same byte."""
        self._last_read_timed_out = False
        line = super().read_until(expected, size)
        complete = line.endswith(expected) or (size is not None and len(line) >= size)
        if line and not complete and not self._last_read_timed_out:
            self._log.record("timeout", waited=0.0, deadline=True)
        return line

    def reset_input_buffer(self) -> None:
        """Discard pending input, logging it first as ``flush`` (when anything was discarded).

        The wrapped port's pending bytes are read (``in_waiting`` until it is 0) rather than dropped by the
        operating system, so that no byte is lost without a trace; ``unread`` counts the bytes of the last
        ``rx`` chunk that were logged but never returned to the caller.
        """
        if not self.is_open:
            raise PortNotOpenError()
        unread = len(self._buffer)
        self._buffer.clear()
        drained = bytearray()
        while waiting := self._serial.in_waiting:
            drained += self._serial.read(waiting)
        if drained or unread:
            self._log.record("flush", bytes(drained), unread=unread)

    def reset_output_buffer(self) -> None:
        """Drop output not yet sent (the wrapped port's ``reset_output_buffer``)."""
        self._serial.reset_output_buffer()


def open_recorded(
    url: str,
    log_path: str | os.PathLike[str],
    *,
    meta: dict[str, Any] | None = None,
    fsync: bool = False,
    **kwargs: Any,
) -> RecordingSerial:
    """Open ``serial.serial_for_url(url, **kwargs)`` and record it to a :class:`SessionLog` at ``log_path``.

    ``meta`` and ``fsync`` go to the SessionLog (header metadata; fsync after every line); every other keyword
    (``timeout`` in s, ``baudrate``, ``do_not_open``, ...) goes to pyserial. The port is opened before the log
    is touched, so a port that fails to open leaves no header behind.
    """
    port = serial.serial_for_url(url, **kwargs)
    return RecordingSerial(port, SessionLog(log_path, port=url, meta=meta, fsync=fsync))


@dataclass(frozen=True)
class LogEvent:
    """One event line of a session log.

    Attributes
    ----------
    line : int
        Line number in the file (1 = first line).
    t : float
        Seconds since the connection's header was written.
    kind : str
        ``tx``, ``rx``, ``timeout``, ``flush`` or ``close`` (the line's ``dir``).
    data : bytes
        The event's bytes (empty for ``timeout`` and ``close``).
    waited : float
        For ``timeout``: seconds the read blocked (0 for a ``read_until`` deadline); otherwise 0.
    """

    line: int
    t: float
    kind: str
    data: bytes = b""
    waited: float = 0.0


@dataclass(frozen=True)
class LogConnection:
    """One connection of a session log: its header line and its events, in order.

    Attributes
    ----------
    line : int
        Line number of the header.
    header : dict
        The header as written (``port``, ``started``, ``resumed``, ``meta``, ...).
    events : tuple of LogEvent
    """

    line: int
    header: dict[str, Any]
    events: tuple[LogEvent, ...]


def _number(entry: dict[str, Any], key: str, where: str) -> float:
    """Return ``entry[key]`` as a finite number >= 0, or raise SessionLogError naming ``where``."""
    value = entry.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 <= value < float("inf"):
        raise SessionLogError(f"{where}: {key!r} must be a number >= 0, got {value!r}")
    return float(value)


def _parse_event(entry: dict[str, Any], line: int, where: str) -> LogEvent:
    """Validate one event entry."""
    kind = entry.get("dir")
    if kind not in EVENT_KINDS:
        raise SessionLogError(f"{where}: 'dir' must be one of {', '.join(EVENT_KINDS)}, got {kind!r}")
    t = _number(entry, "t", where)
    data = b""
    if kind in ("tx", "rx", "flush"):
        text = entry.get("data")
        if not isinstance(text, str):
            raise SessionLogError(f"{where}: a {kind} event needs 'data' (a string), got {text!r}")
        try:
            data = decode_bytes(text)
        except UnicodeEncodeError as err:
            raise SessionLogError(
                f"{where}: 'data' holds {text[err.start]!r}, above U+00FF (one code point is one byte)"
            ) from None
    waited = _number(entry, "waited", where) if kind == "timeout" else 0.0
    return LogEvent(line=line, t=t, kind=kind, data=data, waited=waited)


def read_session_log(path: str | os.PathLike[str]) -> list[LogConnection]:
    """Read every connection of a session log, in file order.

    Blank lines are skipped. Raises SessionLogError (naming the file and line) for a line that is not JSON, an
    event before the first header, an unknown ``dir``, or a bad ``t``, ``data`` or ``waited``.
    """
    path = Path(path)
    connections: list[LogConnection] = []
    header_line = 0
    header: dict[str, Any] | None = None
    events: list[LogEvent] = []
    with path.open(encoding="utf-8") as file:
        for number, text in enumerate(file, start=1):
            if not text.strip():
                continue
            where = f"{path}:{number}"
            try:
                entry = json.loads(text)
            except ValueError as err:
                raise SessionLogError(f"{where}: not a JSON line ({err})") from None
            if not isinstance(entry, dict):
                raise SessionLogError(f"{where}: expected a JSON object, got {type(entry).__name__}")
            if "kmpipe_session_log" in entry:
                if entry["kmpipe_session_log"] != FORMAT_VERSION:
                    raise SessionLogError(
                        f"{where}: session log version {entry['kmpipe_session_log']!r}, this "
                        f"reader knows {FORMAT_VERSION}"
                    )
                if header is not None:
                    connections.append(LogConnection(header_line, header, tuple(events)))
                header_line, header, events = number, entry, []
            elif header is None:
                raise SessionLogError(f"{where}: an event before the first header line")
            else:
                events.append(_parse_event(entry, number, where))
    if header is None:
        raise SessionLogError(f"{path}: no session-log header (an empty file?)")
    connections.append(LogConnection(header_line, header, tuple(events)))
    return connections
