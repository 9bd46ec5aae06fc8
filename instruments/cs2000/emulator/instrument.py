"""The emulated CS-2000's state machine: its settings, the sample under it, measuring, and its replies.

:class:`Instrument` takes a command line and answers it as the instrument would; it sends and schedules through
two methods its server provides (:class:`~instruments.cs2000.emulator.server.Emulator`), so it knows no transport.

Measuring takes the time :mod:`instruments.cs2000.emulator.timing` gives for the sample's luminance and the
settings. (About 500 lines: one short handler per command, all on the one state they share.)

The sample under the instrument
-------------------------------
A samples ``sequence`` lists what the operator puts under the instrument, in order. The operator moves on to the
next sample once a measurement has been read out (its four spectral blocks and its colorimetric values), so a
``MEAS,1`` that failed, or one whose data were not read completely, is measured again on the same sample: a retried
or a resumed reading measures the sample it is meant for, as on the real instrument.
"""

from __future__ import annotations

import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from instruments.cs2000.emulator.faults import REPLY_ERRORS, WIRE_KINDS, Fault
from instruments.cs2000.emulator.radiometry import colorimetry, illuminant_spd
from instruments.cs2000.emulator.timing import LV_LIMIT, exposure, premeasure_seconds
from instruments.cs2000.emulator.transports import Link
from instruments.cs2000.protocol import (
    COLORIMETRIC_BLOCKS,
    COLORIMETRIC_NAMES,
    SPECTRAL_BLOCKS,
    WAVELENGTHS,
    Conditions,
    ProtocolError,
    encode_float32_hex,
    format_colorimetric,
    format_decimal_spectral,
    format_reply,
    parse_command,
    sentinel_text,
)


@dataclass(frozen=True)
class Measurement:
    """One completed measurement: the ground truth behind the instrument's MEDR replies.

    Attributes
    ----------
    sample : str
        The sample that was under the instrument.
    radiance : numpy.ndarray
        401 float32 values (held as float64) in W sr-1 m-2 nm-1, 380-780 nm; ``NaN`` for a ``calculation_error``.
    colorimetric : dict
        :data:`~instruments.cs2000.protocol.COLORIMETRIC_NAMES` -> value (units there), ``None`` for a sentinel.
    conditions : Conditions
        What ``MEDR,0,0,1`` answers.
    measuring_time : int
        Announced measuring time in instrument seconds (the NNN of ``OK00,NNN``).
    """

    sample: str
    radiance: np.ndarray
    colorimetric: dict[str, float | None]
    conditions: Conditions
    measuring_time: int


def _meas_parameter(mnemonic: str, params: Sequence[str]) -> int | None:
    """0 or 1 for ``MEAS,0`` / ``MEAS,1`` (leading zeros allowed), else None."""
    if mnemonic == "MEAS" and len(params) == 1 and params[0].isdigit() and int(params[0]) in (0, 1):
        return int(params[0])
    return None


@dataclass
class _Data:
    """The instrument's stored measurement and which spectral blocks have been read since."""

    measurement: Measurement
    blocks_read: set[int] = field(default_factory=set)
    colorimetry_read: bool = False


@dataclass
class _Pending:
    """A measurement in progress."""

    link: Link
    measurement: Measurement
    error: str | None
    faults: list[Fault]
    state: str = "premeasuring"  # then "measuring"


def _firmware_tuple(firmware: str) -> tuple[int, ...]:
    try:
        return tuple(int(part) for part in firmware.split("."))
    except ValueError:
        raise ValueError(f"firmware {firmware!r} is not dotted numbers such as 3.00.9301") from None


class Instrument(ABC):
    """The state of an emulated CS-2000 and its answers to commands, over links its server owns.

    A server (:class:`~instruments.cs2000.emulator.server.Emulator`) hands each command line it receives to
    :meth:`_command` and provides :meth:`_send` (write a reply, applying wire faults) and :meth:`_schedule` (run an
    action later, in instrument seconds).

    Parameters
    ----------
    samples : mapping of str to array, optional
        Reflectance (fraction) of each sample at 380-780 nm, 1 nm (401 values). Default: ``{"white": 0.98}``.
    sequence : sequence of str
        The samples put under the instrument in turn: the next one once a measurement has been read out (its
        four spectral blocks and its colorimetric values), so a failed or unread measurement is repeated on the
        same sample; the last one stays. Default: the first sample throughout. Setting :attr:`under_instrument`
        discards what is left of it.
    illuminant : str or array
        A CIE illuminant name (:func:`illuminant_spd`) or 401 relative spectral powers.
    gain : float
        W sr-1 m-2 nm-1 per unit of relative spectral power (D55 and gain 0.01: a perfect white gives about
        1 W sr-1 m-2 nm-1 at 560 nm, about 70000 cd m-2).
    noise : float
        Relative standard deviation of the Gaussian noise on each spectral value.
    seed : int, optional
        Seed of the noise.
    faults : iterable of Fault
    time_scale : float
        Multiplies every instrument time (pre-measurement, measuring time, fault delays).
    model, serial_number, firmware : str
        Identity; ``RMTS,2`` is refused (ER17) below firmware 3.00.9301, and firmware 1.01.0000 sends ``0``
        for sentinels.
    aperture : int
        Measuring angle (``STSR``): 0 = 1 deg, 1 = 0.2 deg, 2 = 0.1 deg; sets the luminance range.

    Raises
    ------
    ValueError
        A value out of its range, a sequence naming an unknown sample.
    """

    def __init__(
        self,
        samples: Mapping[str, np.ndarray | Sequence[float] | float] | None = None,
        *,
        sequence: Sequence[str] = (),
        illuminant: str | np.ndarray = "D55",
        gain: float = 0.01,
        noise: float = 0.0,
        seed: int | None = None,
        faults: Iterable[Fault] = (),
        time_scale: float = 1.0,
        model: str = "CS-2000A",
        serial_number: str = "1234567",
        firmware: str = "3.00.9301",
        aperture: int = 0,
    ) -> None:
        samples = {"white": 0.98} if samples is None else samples
        if not samples:
            raise ValueError("at least one sample is needed")
        self._samples: dict[str, np.ndarray] = {}
        for name, reflectance in samples.items():
            array = np.asarray(reflectance, dtype=np.float64)
            if array.shape not in ((), WAVELENGTHS.shape) or not np.all(np.isfinite(array)):
                raise ValueError(f"sample {name!r}: expected a finite number or {WAVELENGTHS.size} (380-780 nm, 1 nm)")
            self._samples[name] = np.broadcast_to(array, WAVELENGTHS.shape).copy()
        unknown = sorted(set(sequence) - set(self._samples))
        if unknown:
            raise ValueError(
                f"sequence names unknown sample(s) {', '.join(unknown)}; known: {', '.join(self._samples)}"
            )
        self._spd = illuminant_spd(illuminant) if isinstance(illuminant, str) else np.asarray(illuminant, float)
        if self._spd.shape != WAVELENGTHS.shape:
            raise ValueError(f"illuminant must have {WAVELENGTHS.size} values (380-780 nm, 1 nm)")
        if not (gain > 0 and noise >= 0 and time_scale > 0):
            raise ValueError("gain and time_scale must be > 0 and noise >= 0")
        if model not in ("CS-2000", "CS-2000A") or len(serial_number) != 7 or not serial_number.isdigit():
            raise ValueError("model must be CS-2000 or CS-2000A and the serial number 7 digits")
        self.gain, self.noise, self.time_scale = float(gain), float(noise), float(time_scale)
        self.model, self.serial_number, self.firmware = model, serial_number, firmware
        self._firmware = _firmware_tuple(firmware)
        if aperture not in LV_LIMIT:
            raise ValueError(f"aperture {aperture!r} is not 0 (1 deg), 1 (0.2 deg) or 2 (0.1 deg)")
        self._aperture = aperture
        self.faults = list(faults)
        self._fault_counts = [0] * len(self.faults)
        self._rng = np.random.default_rng(seed)
        self._sequence = deque(sequence[1:])  # the samples still to come, after the one under the instrument
        self._under = sequence[0] if sequence else next(iter(self._samples))
        self._moved_on = False  # the last measurement was read out: the next MEAS,1 measures the next sample
        self._lock = threading.Lock()
        self._measurements: list[Measurement] = []
        self._remote = False
        self._button_enabled = True
        self._speed: tuple[int, int, int] = (0, 0, 2)  # mode, seconds or microseconds (0 if none), ND 0/1/2
        self._sync: tuple[int, int] = (0, 0)  # mode, frequency in 1/100 Hz
        self._observer = 0
        self._data: _Data | None = None
        self._pending: _Pending | None = None
        self._late_until = 0.0  # monotonic time until which a no_completion measurement is still "measuring"
        self._colorimetry_fault: dict[str, float] = {}  # values a colorimetry fault replaces in the current reply

    @abstractmethod
    def _send(self, link: Link, payload: bytes, faults: Sequence[Fault] = ()) -> None:
        """Write ``payload`` to ``link``, applying the wire faults among ``faults``."""

    @abstractmethod
    def _schedule(self, seconds: float, action: Callable[[], None]) -> None:
        """Call ``action`` (on the serving thread) ``seconds`` instrument seconds from now."""

    @property
    def sample_names(self) -> tuple[str, ...]:
        """The samples that can be put under the instrument."""
        return tuple(self._samples)

    @property
    def under_instrument(self) -> str:
        """Name of the sample under the instrument; setting it discards the rest of the sequence."""
        with self._lock:
            return self._under

    @under_instrument.setter
    def under_instrument(self, name: str) -> None:
        if name not in self._samples:
            raise ValueError(f"unknown sample {name!r}; known: {', '.join(self._samples)}")
        with self._lock:
            self._under = name
            self._sequence.clear()
            self._moved_on = False

    @property
    def measurements(self) -> list[Measurement]:
        """The completed measurements so far, oldest first."""
        with self._lock:
            return list(self._measurements)

    @property
    def last_measurement(self) -> Measurement | None:
        """The latest completed measurement, or None."""
        with self._lock:
            return self._measurements[-1] if self._measurements else None

    # ------------------------------------------------------------------------------------------- commands

    def _command(self, link: Link, line: bytes, terminator: bytes) -> None:
        if self._pending is not None and self._pending.state == "premeasuring":
            return  # the instrument accepts nothing while pre-measuring
        try:
            mnemonic, params = parse_command(line)
        except ProtocolError:
            self._send(link, format_reply("ER00", terminator=terminator))
            return
        fired = self._fired(mnemonic, params)
        wire = [f for f in fired if f.kind in WIRE_KINDS and f.at == "reply"]
        self._colorimetry_fault = {k: v for f in fired if f.kind == "colorimetry" for k, v in f.values.items()}
        meas = _meas_parameter(mnemonic, params)
        starts = meas == 1 and self._pending is None and self._remote and not self._late()
        replacement = next((f for f in fired if f.kind in REPLY_ERRORS and f.at == "reply"), None)
        if replacement is not None and not (starts and replacement.kind in ("error", "over_range")):
            self._send(link, format_reply(replacement.error_code, terminator=terminator), wire)
            return
        if starts:
            self._start_measurement(link, terminator, fired)
            return
        code, fields = self._answer(mnemonic, params)
        self._send(link, format_reply(code, *fields, terminator=terminator), wire)
        late = next((f for f in fired if f.kind == "late_completion"), None)
        if late is not None and meas == 0 and code == "OK00":
            self._schedule(late.seconds, lambda: self._send(link, format_reply("OK00", terminator=terminator)))

    def _fired(self, mnemonic: str, params: tuple[str, ...]) -> list[Fault]:
        fired = []
        for index, fault in enumerate(self.faults):
            if fault.matches(mnemonic, params):
                self._fault_counts[index] += 1
                if fault.occurrence is None or fault.occurrence == self._fault_counts[index]:
                    fired.append(fault)
        return fired

    def _late(self) -> bool:
        """True while a measurement whose completion line was lost is still running."""
        return time.monotonic() < self._late_until

    def _answer(self, mnemonic: str, params: tuple[str, ...]) -> tuple[str, tuple[str, ...]]:
        """The reply (code, fields) to every command but an accepted MEAS,1."""
        if self._pending is not None or self._late():
            meas = _meas_parameter(mnemonic, params)
            if meas == 0:
                self._pending, self._late_until, self._data = None, 0.0, None
                return "OK00", ()
            if meas == 1:
                return "ER17", ()
            return ("ER02" if mnemonic == "MEDR" and self._late() else "ER00"), ()
        if mnemonic == "RMTS":
            return self._rmts(params)
        if not self._remote:
            return "ER00", ()
        handler = getattr(self, f"_{mnemonic.lower()}", None)
        if handler is None or mnemonic not in _COMMANDS:
            return "ER00", ()
        if not all(p.isdigit() for p in params):
            return "ER00", ()
        return handler(tuple(int(p) for p in params))

    def _rmts(self, params: tuple[str, ...]) -> tuple[str, tuple[str, ...]]:
        if len(params) != 1 or not params[0].isdigit():
            return "ER00", ()
        mode = int(params[0])
        if mode not in (0, 1, 2) or (mode == 2 and self._firmware < (3, 0, 9301)):
            return "ER17", ()
        self._remote = mode != 0
        return "OK00", ()

    def _iddr(self, params: tuple[int, ...]) -> tuple[str, tuple[str, ...]]:
        if params:
            return "ER00", ()
        return "OK00", (f"{self.model:<9}", "2" if self.model == "CS-2000A" else "1", self.serial_number)

    def _mswe(self, params: tuple[int, ...]) -> tuple[str, tuple[str, ...]]:
        if len(params) != 1:
            return "ER00", ()
        if params[0] not in (0, 1):
            return "ER17", ()
        self._button_enabled = params[0] == 1
        return "OK00", ()

    def _spms(self, params: tuple[int, ...]) -> tuple[str, tuple[str, ...]]:
        if not params:
            return "ER00", ()
        mode, rest = params[0], params[1:]
        if mode not in (0, 1, 2, 3, 4):
            return "ER17", ()
        if mode in (0, 1):
            if len(rest) > 1:
                return "ER00", ()
            nd = rest[0] if rest else self._speed[2]
            if nd not in (0, 1, 2):
                return "ER17", ()
            self._speed = (mode, 0, nd)
            return "OK00", ()
        if len(rest) not in (1, 2):
            return "ER00", ()
        low, high, nds = (1, 16, (0, 1, 2)) if mode in (2, 4) else (5000, 120_000_000, (0, 1))
        nd = rest[1] if len(rest) == 2 else min(self._speed[2], max(nds))
        if not low <= rest[0] <= high or nd not in nds:
            return "ER17", ()
        self._speed = (mode, rest[0], nd)
        return "OK00", ()

    def _spmr(self, params: tuple[int, ...]) -> tuple[str, tuple[str, ...]]:
        if params:
            return "ER00", ()
        mode, value, nd = self._speed
        if mode in (0, 1):
            return "OK00", (str(mode), str(nd))
        return "OK00", (str(mode), f"{value:09d}" if mode == 3 else f"{value:02d}", str(nd))

    def _scms(self, params: tuple[int, ...]) -> tuple[str, tuple[str, ...]]:
        if not params or len(params) != (2 if params[0] == 1 else 1):
            return "ER00", ()
        if params[0] not in (0, 1, 2) or (params[0] == 1 and not 2000 <= params[1] <= 20000):
            return "ER17", ()
        self._sync = (params[0], params[1] if params[0] == 1 else 0)
        return "OK00", ()

    def _scmr(self, params: tuple[int, ...]) -> tuple[str, tuple[str, ...]]:
        if params:
            return "ER00", ()
        mode, frequency = self._sync
        return "OK00", (str(mode), f"{frequency:05d}") if mode == 1 else (str(mode),)

    def _obss(self, params: tuple[int, ...]) -> tuple[str, tuple[str, ...]]:
        if len(params) != 1:
            return "ER00", ()
        if params[0] not in (0, 1):
            return "ER17", ()
        self._observer = params[0]
        return "OK00", ()

    def _obsr(self, params: tuple[int, ...]) -> tuple[str, tuple[str, ...]]:
        return ("ER00", ()) if params else ("OK00", (str(self._observer),))

    def _stsr(self, params: tuple[int, ...]) -> tuple[str, tuple[str, ...]]:
        return ("ER00", ()) if params else ("OK00", (str(self._aperture),))

    def _dtcr(self, params: tuple[int, ...]) -> tuple[str, tuple[str, ...]]:
        return ("ER00", ()) if params else ("OK00", ("20190401", "093000"))

    def _meas(self, params: tuple[int, ...]) -> tuple[str, tuple[str, ...]]:
        """MEAS when no measurement starts: ``MEAS,0`` with nothing to cancel, or a bad parameter, is misuse."""
        return ("ER00", ()) if len(params) != 1 else ("ER17", ())

    def _medr(self, params: tuple[int, ...]) -> tuple[str, tuple[str, ...]]:
        if len(params) != 3:
            return "ER00", ()
        mode, fmt, block = params
        valid_blocks = {0: {1}, 1: set(SPECTRAL_BLOCKS), 2: set(COLORIMETRIC_BLOCKS)}
        if mode not in valid_blocks or fmt not in (0, 1) or block not in valid_blocks[mode]:
            return "ER17", ()
        if self._data is None:
            return "ER20", ()
        measurement = self._data.measurement
        old_firmware = self._firmware[:2] == (1, 1)
        if mode == 0:
            c = measurement.conditions
            values = (
                c.speed,
                c.sync,
                f"{c.integration_us:09d}",
                c.internal_nd,
                c.close_up_lens,
                c.external_nd,
                c.angle,
            )
            return "OK00", (*map(str, values), f"{c.calibration_channel:02d}")
        if mode == 1:
            first, last = SPECTRAL_BLOCKS[block]
            values = measurement.radiance[first - 380 : last - 379]
            if np.all(np.isfinite(values)):
                texts = encode_float32_hex(values) if fmt == 1 else [format_decimal_spectral(v) for v in values]
            else:
                texts = [sentinel_text(fmt, firmware_1_01=old_firmware)] * values.size
            self._data.blocks_read.add(block)
            self._note_read_out(self._data)
            if self._button_enabled and self._data.blocks_read >= set(SPECTRAL_BLOCKS):
                self._data = None
            return "OK00", tuple(texts)
        colorimetric = measurement.colorimetric | self._colorimetry_fault
        texts = [
            format_colorimetric(n, colorimetric[n], fmt, firmware_1_01=old_firmware) for n in COLORIMETRIC_BLOCKS[block]
        ]
        self._data.colorimetry_read = True
        self._note_read_out(self._data)
        if self._button_enabled:
            self._data = None
        return "OK00", tuple(texts)

    def _note_read_out(self, data: _Data) -> None:
        """The operator moves on once a measurement's four spectral blocks and its colorimetric values were read."""
        if data.colorimetry_read and data.blocks_read >= set(SPECTRAL_BLOCKS):
            with self._lock:
                self._moved_on = True

    # ------------------------------------------------------------------------------------------ measuring

    def _start_measurement(self, link: Link, terminator: bytes, fired: list[Fault]) -> None:
        with self._lock:
            if self._moved_on and self._sequence:
                self._under = self._sequence.popleft()
            self._moved_on = False
            sample = self._under
        radiance = self._spd * self._samples[sample] * self.gain
        if self.noise:
            radiance = radiance * (1 + self.noise * self._rng.standard_normal(radiance.shape))
        radiance = radiance.astype(np.float32).astype(np.float64)
        colorimetric = colorimetry(radiance)
        lv = max(colorimetric["Lv"] or 0.0, 1e-6)
        conditions, measuring_time, over_range = exposure(lv, self._speed, self._sync[0], self._aperture)
        if any(f.kind == "calculation_error" for f in fired):
            radiance = np.full(WAVELENGTHS.shape, np.nan)
            colorimetric = dict.fromkeys(COLORIMETRIC_NAMES)
        radiance.setflags(write=False)
        measurement = Measurement(sample, radiance, colorimetric, conditions, measuring_time)
        start_error = next((f for f in fired if f.kind in ("error", "over_range") and f.at == "reply"), None)
        error = start_error.error_code if start_error is not None else "ER10" if over_range else None
        pending = _Pending(link, measurement, error, fired)
        self._pending = pending
        self._data = None
        self._schedule(premeasure_seconds(lv), lambda: self._premeasured(pending, terminator))

    def _premeasured(self, pending: _Pending, terminator: bytes) -> None:
        if self._pending is not pending:
            return
        wire = [f for f in pending.faults if f.kind in WIRE_KINDS and f.at == "reply"]
        if pending.error is not None:
            self._pending = None
            self._send(pending.link, format_reply(pending.error, terminator=terminator), wire)
            return
        pending.state = "measuring"
        seconds = pending.measurement.measuring_time
        self._send(pending.link, format_reply("OK00", f"{seconds:03d}", terminator=terminator), wire)
        if any(f.kind == "no_completion" for f in pending.faults):
            self._pending = None
            self._late_until = time.monotonic() + seconds * self.time_scale
            self._store(pending.measurement)
            return
        self._schedule(seconds, lambda: self._complete(pending, terminator))

    def _complete(self, pending: _Pending, terminator: bytes) -> None:
        if self._pending is not pending:
            return  # cancelled
        self._pending = None
        wire = [f for f in pending.faults if f.kind in WIRE_KINDS and f.at == "completion"]
        error = next((f for f in pending.faults if f.kind in ("error", "over_range") and f.at == "completion"), None)
        if error is not None:
            self._send(pending.link, format_reply(error.error_code, terminator=terminator), wire)
            return
        self._store(pending.measurement)
        self._send(pending.link, format_reply("OK00", terminator=terminator), wire)

    def _store(self, measurement: Measurement) -> None:
        self._data = _Data(measurement)
        with self._lock:
            self._measurements.append(measurement)


_COMMANDS = frozenset({"IDDR", "MSWE", "SPMS", "SPMR", "SCMS", "SCMR", "OBSS", "OBSR", "STSR", "DTCR", "MEAS", "MEDR"})
"""Commands the emulator implements besides RMTS; any other mnemonic is answered ER00."""
