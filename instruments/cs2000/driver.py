"""Driver for the Konica Minolta CS-2000 / CS-2000A over a serial port (USB CDC-ACM, RS-232, or any pyserial URL).

A thin layer over :mod:`instruments.cs2000.protocol`: it owns the port, reads replies up to the terminator
under an overall deadline (keeping any bytes after the terminator for the next reply), discards stale input
before each command, and runs the two-phase measurement. Every byte can be recorded (see
:mod:`instruments.session_log`) before it is parsed, so a reply is never lost to a parsing error.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import serial

import instruments.urlhandler  # noqa: F401  (registers replay:// for serial_for_url)
from instruments.cs2000 import protocol
from instruments.cs2000.protocol import CS2000Error, Reply

#: Deadlines (s) from the protocol summary: any reply 10 s (20 s at 600 baud), the first MEAS reply 20 s,
#: completion the announced time plus a margin.
REPLY_TIMEOUT = 10.0
FIRST_REPLY_TIMEOUT = 20.0
COMPLETION_MARGIN = 10.0
#: Port read timeout (s): the granularity at which deadlines and progress are checked.
POLL = 0.05


class InstrumentTimeout(Exception):
    """No complete reply before the deadline; carries the command and the bytes received so far."""

    def __init__(self, command: bytes, received: bytes, seconds: float) -> None:
        shown = command.strip().decode("ascii", "replace")
        super().__init__(f"no complete reply to {shown} within {seconds:g} s (received {received!r})")
        self.command = command
        self.received = received


@dataclass(frozen=True)
class Reading:
    """One measurement: spectral radiance at 380-780 nm every 1 nm (W sr-1 m-2 nm-1) and what came with it."""

    wavelengths: np.ndarray  # nm
    radiance: np.ndarray
    colorimetry: dict[str, float | None]
    conditions: protocol.Conditions
    measuring_seconds: int  # as announced by the instrument


class CS2000:
    """A CS-2000 on an open pyserial port. Use :meth:`open` to make one from a device path or URL."""

    def __init__(self, port: serial.SerialBase, *, reply_timeout: float = REPLY_TIMEOUT) -> None:
        self.port = port
        self.port.timeout = POLL
        # A replayed port keeps the recording's time (deadlines pass as they did, without waiting for them).
        self._clock = getattr(port, "clock", time.monotonic)
        self._sleep = getattr(port, "sleep", time.sleep)
        self.reply_timeout = reply_timeout
        self._pending = b""  # bytes received after the last terminator

    @classmethod
    def open(cls, url: str, *, baudrate: int = 115200, rtscts: bool = False, **kwargs) -> CS2000:
        """Open ``url`` (a device such as /dev/ttyACM0, socket://HOST:PORT, replay://LOG ...) at 8N1."""
        port = serial.serial_for_url(url, baudrate=baudrate, rtscts=rtscts, timeout=POLL, **kwargs)
        return cls(port)

    def close(self) -> None:
        self.port.close()

    def __enter__(self) -> CS2000:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- bytes -------------------------------------------------------------------------------------------

    def _read_line(self, seconds: float, command: bytes, tick: Callable[[], None] | None = None) -> bytes:
        """The next non-empty reply line, waiting at most ``seconds`` overall however the bytes trickle in.

        Commands are sent with CR LF, so replies end with CR LF: a line ends at LF. Bytes after it stay
        pending for the next reply (the second line of MEAS may arrive right behind the first).
        """
        deadline = self._clock() + seconds
        while True:
            end = self._pending.find(b"\n")
            if end >= 0:
                line, self._pending = self._pending[: end + 1], self._pending[end + 1 :]
                if line.strip():
                    return line
                continue
            if self._clock() > deadline:
                raise InstrumentTimeout(command, self._pending, seconds)
            chunk = self.port.read(max(1, self.port.in_waiting))
            if chunk:
                self._pending += chunk
            elif tick is not None:
                tick()

    def _read_reply(self, seconds: float, command: bytes, tick: Callable[[], None] | None = None) -> Reply:
        """The next line that is a reply (starts with a reply code, after any garbage), within ``seconds``.

        Lines that hold no reply code at all (line noise ending in a line feed) are skipped, not taken as the
        answer: the instrument's real reply is still to come.
        """
        deadline = self._clock() + seconds
        while True:
            line = self._read_line(max(deadline - self._clock(), 0.0), command, tick)
            try:
                return protocol.parse_reply(line)
            except protocol.ProtocolError:
                continue

    def _discard_stale(self) -> None:
        """Drop input left from earlier exchanges (a late completion line, noise) before a new command."""
        self._pending = b""
        self.port.reset_input_buffer()

    def query(self, mnemonic: str, *params, timeout: float | None = None) -> Reply:
        """Send one command and return its parsed reply (an ERnn reply is returned, not raised)."""
        command = protocol.format_command(mnemonic, *params)
        self._discard_stale()
        self.port.write(command)
        self.port.flush()
        return self._read_reply(timeout or self.reply_timeout, command)

    def command(self, mnemonic: str, *params, timeout: float | None = None) -> tuple[str, ...]:
        """Send one command; its fields, or CS2000Error for an ERnn reply."""
        return protocol.check(self.query(mnemonic, *params, timeout=timeout))

    # --- settings ----------------------------------------------------------------------------------------

    def remote(self, on: bool = True) -> int:
        """Remote mode on (RMTS,2, which does not write settings to flash; RMTS,1 on older firmware) or off.

        Returns the mode set (2, 1 or 0).
        """
        if not on:
            self.command("RMTS", 0)
            return 0
        reply = self.query("RMTS", 2)
        if reply.code == "OK00":
            return 2
        self.command("RMTS", 1)
        return 1

    def identity(self) -> protocol.Identity:
        return protocol.parse_identity(self.command("IDDR"))

    def set_measure_button(self, enabled: bool) -> None:
        """Enable or disable the front-panel measure button (disabled: data stay readable until the next MEAS)."""
        self.command("MSWE", 1 if enabled else 0)

    def set_speed(self, mode: int, *params: int) -> None:
        """SPMS: 0 Normal, 1 Fast, 2 Multi-integration Normal, 3 Manual, 4 Multi-integration Fast (see the protocol)."""
        self.command("SPMS", mode, *params)

    def speed(self) -> tuple[str, ...]:
        return self.command("SPMR")

    def set_sync(self, mode: int, frequency_centihertz: int | None = None) -> None:
        """SCMS: 0 none, 1 internal at frequency/100 Hz (2000-20000), 2 external."""
        self.command("SCMS", mode, *(() if frequency_centihertz is None else (f"{frequency_centihertz:05d}",)))

    def set_observer(self, degrees: int) -> None:
        """OBSS: CIE 1931 2 deg or CIE 1964 10 deg (colorimetric values only)."""
        if degrees not in (2, 10):
            raise ValueError("observer must be 2 or 10 degrees")
        self.command("OBSS", 0 if degrees == 2 else 1)

    # --- measuring ---------------------------------------------------------------------------------------

    def measure(
        self,
        *,
        progress: Callable[[float, int], None] | None = None,
        first_timeout: float = FIRST_REPLY_TIMEOUT,
        margin: float = COMPLETION_MARGIN,
    ) -> int:
        """Take one measurement; return the measuring time the instrument announced (s).

        MEAS,1 is answered twice: ``OK00,NNN`` after the pre-measurement (up to ~10 s), then ``OK00`` (or an
        error) about NNN s later. If the completion line does not arrive by NNN + ``margin`` s, the driver
        polls MEDR,0,0,1 until it stops answering "busy" rather than sending MEAS,1 again. ``progress(elapsed,
        announced)`` is called while waiting. An error in either phase raises CS2000Error.
        """
        command = protocol.format_command("MEAS", 1)
        self._discard_stale()
        self.port.write(command)
        self.port.flush()
        started = self._clock()
        first = self._read_reply(first_timeout, command)
        announced = protocol.parse_measure_time(first)
        tick = None if progress is None else (lambda: progress(self._clock() - started, announced))
        try:
            completion = self._read_reply(announced + margin, command, tick)
        except InstrumentTimeout:
            self.wait_until_idle(REPLY_TIMEOUT + margin)
            return announced
        protocol.check(completion)
        return announced

    def wait_until_idle(self, seconds: float) -> None:
        """Poll MEDR,0,0,1 until the instrument no longer answers "busy" (the completion line was lost).

        ER20 (no data) also means idle: nothing is being measured, there is just nothing to read.
        """
        deadline = self._clock() + seconds
        while True:
            reply = self.query("MEDR", 0, 0, 1)
            if reply.code in ("OK00", "ER20"):
                return
            error = CS2000Error(reply.code)
            if not error.busy:
                raise error
            if self._clock() > deadline:
                raise InstrumentTimeout(b"MEDR,0,0,1", b"", seconds)
            self._sleep(0.5)

    def cancel(self) -> None:
        """MEAS,0: stop a measurement; a late completion line may still come, so the input is drained."""
        self.port.write(protocol.format_command("MEAS", 0))
        self.port.flush()
        self._sleep(0.2)
        self._discard_stale()

    def read_spectrum(self) -> np.ndarray:
        """The last measurement's spectral radiance, 401 values at 380-780 nm (hex float32, full precision)."""
        blocks = [
            protocol.parse_spectral_block(self.command("MEDR", 1, 1, block), block, 1)
            for block in sorted(protocol.SPECTRAL_BLOCKS)
        ]
        return np.concatenate(blocks)

    def read_colorimetry(self) -> dict[str, float | None]:
        """The last measurement's colorimetric values (Le, Lv, X, Y, Z, x, y, ... and the 10 deg set)."""
        return protocol.parse_colorimetric(self.command("MEDR", 2, 0, 0), 0)

    def read_conditions(self) -> protocol.Conditions:
        return protocol.parse_conditions(self.command("MEDR", 0, 0, 1))

    def read_data(self, measuring_seconds: int) -> Reading:
        """Read the last measurement's spectrum, colorimetry and conditions (again, after a transfer that went
        wrong: with the measure button disabled the data stay until the next measurement).

        ``measuring_seconds`` is the time the instrument announced for that measurement (s), kept in the Reading.
        """
        radiance = self.read_spectrum()
        return Reading(
            wavelengths=np.arange(380.0, 781.0),
            radiance=radiance,
            colorimetry=self.read_colorimetry(),
            conditions=self.read_conditions(),
            measuring_seconds=measuring_seconds,
        )

    def take_reading(self, *, progress: Callable[[float, int], None] | None = None) -> Reading:
        """Measure, then read spectrum, colorimetry and conditions (needs the measure button disabled)."""
        return self.read_data(self.measure(progress=progress))
