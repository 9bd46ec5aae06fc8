"""A Konica Minolta CS-2000A emulator speaking the serial protocol, on a pseudo-terminal and/or a TCP socket.

The emulator answers the commands the pipeline uses (see :mod:`instruments.cs2000.protocol` and the protocol
summary) with the instrument's timing: ``MEAS,1`` pre-measures for 1-3 s while it reads and ignores input, answers
``OK00,NNN``, and sends the unsolicited completion ``OK00`` NNN s later. All instrument times are multiplied by
``time_scale`` (tests use 0.01); the announced NNN is not.

Physics
-------
Spectral radiance (W sr-1 m-2 nm-1, 380-780 nm at 1 nm) = illuminant relative spectral power (CIE D55 by default,
normalised to 100 at 560 nm, linearly interpolated from the CIE 5 nm table) x reflectance of the sample under the
instrument x ``gain``, times ``1 + noise * N(0, 1)`` per wavelength (seeded), rounded to float32 (what the
instrument sends in hex). Colorimetric values follow from that spectrum: Le = sum L dlambda (W sr-1 m-2);
X, Y, Z = 683 sum L xbar dlambda (cd m-2, CIE 1931 2 deg and CIE 1964 10 deg CMFs at 1 nm; Lv = Y);
x, y, u', v' from XYZ; T and duv by Ohno (2013) from CIE 1960 uv (sentinels when |duv| > 0.05 or T is outside
1000-100000 K); lambda_d and Pe (%) against the equal-energy white point (the real instrument's white point is not
documented here). Quantities that cannot be computed (a black spectrum) are sent as sentinels.

Timing (instrument seconds, before ``time_scale``)
--------------------------------------------------
Pre-measurement: 1 s at Lv >= 100 cd m-2, rising by 0.5 s per decade below, at most 3 s. Measuring time NNN
(2-242 s): Normal: 2 + 16 t with auto integration time t = 5 / Lv s (5 ms-15 s); Fast: 2 + 4 t with t = 1 / Lv s;
Multi-integration Normal with S s: 2 + S n where n = ceil(100 / Lv) frames (1-15, so dark samples take longer);
Multi-integration Fast: half that; Manual with t s: 2 + 2 t. Over range (ER10 after the pre-measurement) above the
aperture's limit (5000, 125000 or 500000 cd m-2 for 1, 0.2 or 0.1 deg) times 100 with the internal ND filter (on,
or auto), or in Manual when Lv t exceeds that limit x 0.5 s.

Faults
------
:class:`Fault` injects misbehaviour for commands that match (a mnemonic ``"MEDR"``, a command ``"MEDR,1,1,2"``,
or ``"*"``), every time or on the n-th occurrence. Wire faults (``delay``, ``chunks``, ``garbage``, ``disconnect``)
change how a reply is sent, the immediate reply or, with ``at="completion"``, the MEAS completion line. Replacement
faults answer an error instead (``busy`` ER02 and ``no_data`` ER20 at once; ``error``/``over_range`` on ``MEAS,1``
after the pre-measurement or, with ``at="completion"``, as the completion line). ``no_completion`` never sends the
completion line (``MEDR`` then answers ER02 until the measuring time has passed); ``calculation_error`` makes a
measurement's values sentinels; ``late_completion`` sends a stray ``OK00`` after the reply to ``MEAS,0``;
``colorimetry`` answers a colorimetric ``MEDR`` with some values replaced (a corrupted transfer: they no longer match
the spectrum).

The sample under the instrument
-------------------------------
A samples ``sequence`` lists what the operator puts under the instrument, in order. The operator moves on to the
next sample once a measurement has been read out (its four spectral blocks and its colorimetric values), so a
``MEAS,1`` that failed, or one whose data were not read completely, is measured again on the same sample: a retried
or a resumed reading measures the sample it is meant for, as on the real instrument.

Transports
----------
A pseudo-terminal (the slave's path in :attr:`Emulator.port`, optionally a symlink such as ``/tmp/cs2000`` so that
``serial.serial_for_url("/tmp/cs2000")`` opens it) and a TCP server on 127.0.0.1 (``socket://127.0.0.1:PORT``),
one client at a time. Both talk to the same instrument, served by one background thread. A ``disconnect`` fault
closes the TCP connection, or closes the pseudo-terminal and opens a new one, re-pointing the symlink (like a USB
re-plug that gives a new device node).
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import csv
import fcntl
import heapq
import itertools
import math
import os
import select
import signal
import socket
import struct
import sys
import termios
import threading
import time
import tomllib
import tty
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from functools import cache
from pathlib import Path
from typing import TextIO

import numpy as np

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
from instruments.regular_files import read_regular

#: Largest samples script or reflectance CSV the emulator reads (bytes).
MAX_FILE_BYTES = 64 << 20

__all__ = [
    "FAULT_KINDS",
    "Emulator",
    "Fault",
    "Measurement",
    "ScriptError",
    "colorimetry",
    "illuminant_spd",
    "load_script",
    "main",
    "read_reflectance_csv",
    "run",
]

FAULT_KINDS = (
    "delay",
    "chunks",
    "garbage",
    "disconnect",
    "busy",
    "no_data",
    "error",
    "over_range",
    "no_completion",
    "calculation_error",
    "late_completion",
    "colorimetry",
)
"""Injectable faults; see :class:`Fault`."""

_WIRE_KINDS = frozenset({"delay", "chunks", "garbage", "disconnect"})
_MEAS_KINDS = frozenset({"no_completion", "calculation_error", "late_completion"})
_REPLY_ERRORS = {"busy": "ER02", "no_data": "ER20", "over_range": "ER10", "error": None}
_MAX_COMMAND = 1024  # bytes without a terminator before the instrument discards its input buffer
_CR_WAIT = 0.05  # s: after a CR, how long to wait for an LF (CR LF) before taking CR alone as the terminator
_DRAIN_LIMIT = 0.5  # s: how long a pty disconnect waits for the host to read the partial reply first
_LV_LIMIT = {0: 5_000.0, 1: 125_000.0, 2: 500_000.0}  # cd m-2 without ND, per aperture (1, 0.2, 0.1 deg)
_ND_FACTOR = 100.0


class ScriptError(ValueError):
    """A samples script or reflectance file that cannot be used; the message names the file and the field."""


@dataclass(frozen=True)
class Fault:
    """One injected fault.

    Attributes
    ----------
    kind : str
        One of :data:`FAULT_KINDS`:
        ``delay`` (reply ``seconds`` late), ``chunks`` (reply in ``chunk_size``-byte pieces, ``seconds`` apart),
        ``garbage`` (``garbage`` bytes before the reply), ``disconnect`` (send ``fraction`` of the reply, then drop
        the link), ``busy`` (answer ER02), ``no_data`` (answer ER20), ``error`` (answer ``code``), ``over_range``
        (answer ER10), ``no_completion`` (MEAS,1: no completion line), ``calculation_error`` (MEAS,1: sentinel
        values), ``late_completion`` (MEAS,0: a stray ``OK00`` ``seconds`` after the reply), ``colorimetry``
        (MEDR,2: ``values`` sent instead of the measurement's).
    command : str
        ``"*"`` (any command), a mnemonic (``"MEDR"``), or a whole command (``"MEDR,1,1,2"``; numeric parameters
        compare as numbers).
    occurrence : int or None
        Fire on the n-th matching command only (1 = the first); ``None``: every time.
    at : str
        ``"reply"``, or ``"completion"`` for the MEAS completion line (wire faults, ``error``, ``over_range``).
    seconds : float
        Instrument seconds (scaled by ``time_scale``): the delay, the pause between chunks, the late completion.
    chunk_size : int
        Bytes per chunk.
    garbage : bytes
        Bytes sent before the reply.
    code : str
        The error code of an ``error`` fault.
    fraction : float
        Part of the reply sent before a ``disconnect`` (0-1).
    values : mapping of str to float
        For ``colorimetry``: colorimetric quantity name (:data:`~instruments.cs2000.protocol.COLORIMETRIC_NAMES`)
        -> the value sent instead (units there).
    """

    kind: str
    command: str = "*"
    occurrence: int | None = None
    at: str = "reply"
    seconds: float = 1.0
    chunk_size: int = 8
    garbage: bytes = b"\x00\xfe~#"
    code: str = "ER10"
    fraction: float = 0.5
    values: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"fault kind {self.kind!r} is not one of {', '.join(FAULT_KINDS)}")
        if self.command != "*":
            try:
                parse_command(self.command.encode("ascii"))
            except (UnicodeEncodeError, ProtocolError):
                raise ValueError(f"fault command {self.command!r} is not '*', a mnemonic or a command") from None
        if self.occurrence is not None and (isinstance(self.occurrence, bool) or self.occurrence < 1):
            raise ValueError(f"fault occurrence {self.occurrence!r} is not a positive integer")
        if self.at not in ("reply", "completion"):
            raise ValueError(f"fault 'at' {self.at!r} is not 'reply' or 'completion'")
        if self.kind in _MEAS_KINDS and self.command.split(",")[0] not in ("*", "MEAS"):
            raise ValueError(f"a {self.kind} fault applies to MEAS, not {self.command!r}")
        if self.at == "completion" and self.kind not in _WIRE_KINDS | {"error", "over_range"}:
            raise ValueError(f"a {self.kind} fault cannot apply to the completion line")
        if not (self.seconds >= 0 and self.chunk_size >= 1 and 0 <= self.fraction <= 1):
            raise ValueError("fault seconds must be >= 0, chunk_size >= 1 and fraction within 0-1")
        if self.kind == "error":
            format_reply(self.code)  # raises ValueError for a bad code
        if self.kind == "colorimetry" and self.command.split(",")[0] not in ("*", "MEDR"):
            raise ValueError(f"a colorimetry fault applies to MEDR, not {self.command!r}")
        unknown = sorted(set(self.values) - set(COLORIMETRIC_NAMES))
        if unknown or not all(isinstance(v, int | float) and math.isfinite(v) for v in self.values.values()):
            raise ValueError(f"fault values must map colorimetric names ({', '.join(COLORIMETRIC_NAMES)}) to finite "
                             f"numbers; got {dict(self.values)!r}")  # fmt: skip

    @classmethod
    def from_table(cls, table: Mapping[str, object]) -> Fault:
        """A fault from a TOML table (``garbage`` is a string whose characters are bytes 0-255)."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(table) - known)
        if unknown:
            raise ValueError(f"unknown fault key(s) {', '.join(unknown)}; expected {', '.join(sorted(known))}")
        values = dict(table)
        if isinstance(values.get("garbage"), str):
            values["garbage"] = values["garbage"].encode("latin-1")
        return cls(**values)  # type: ignore[arg-type]

    def matches(self, mnemonic: str, params: Sequence[str]) -> bool:
        """True if this fault is for the command ``mnemonic,params``."""
        if self.command == "*":
            return True
        want_mnemonic, want_params = parse_command(self.command.encode("ascii"))
        if want_mnemonic != mnemonic:
            return False
        return not want_params or [_normal(p) for p in want_params] == [_normal(p) for p in params]


def _fault_code(fault: Fault) -> str:
    """The error code a replacement fault answers."""
    return _REPLY_ERRORS[fault.kind] or fault.code


def _meas_parameter(mnemonic: str, params: Sequence[str]) -> int | None:
    """0 or 1 for ``MEAS,0`` / ``MEAS,1`` (leading zeros allowed), else None."""
    if mnemonic == "MEAS" and len(params) == 1 and params[0].isdigit() and int(params[0]) in (0, 1):
        return int(params[0])
    return None


def _normal(param: str) -> str:
    """A parameter compared as a number when it is one (``"01"`` == ``"1"``)."""
    return str(int(param)) if param.isdigit() else param


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


# ------------------------------------------------------------------------------------------------ colorimetry


@cache
def _cmfs() -> tuple[np.ndarray, np.ndarray]:
    """CIE 1931 2 deg and CIE 1964 10 deg colour-matching functions at 380-780 nm, 1 nm: two (401, 3) arrays."""
    import colour

    tables = []
    for name in ("CIE 1931 2 Degree Standard Observer", "CIE 1964 10 Degree Standard Observer"):
        cmfs = colour.MSDS_CMFS[name]
        tables.append(np.array([cmfs[w] for w in WAVELENGTHS]))
    return tables[0], tables[1]


def illuminant_spd(name: str = "D55") -> np.ndarray:
    """Relative spectral power of a CIE illuminant known to colour-science at 380-780 nm, 1 nm (linear
    interpolation of its table), normalised to 100 at 560 nm.

    Raises
    ------
    ValueError
        An unknown name, or a table that does not cover 380-780 nm.
    """
    import colour

    if name not in colour.SDS_ILLUMINANTS:
        raise ValueError(f"illuminant {name!r} is unknown; expected a CIE illuminant such as D55, D65 or A")
    sd = colour.SDS_ILLUMINANTS[name]
    if sd.wavelengths[0] > 380 or sd.wavelengths[-1] < 780:
        raise ValueError(f"illuminant {name!r} does not cover 380-780 nm")
    spd = np.interp(WAVELENGTHS, sd.wavelengths, sd.values)
    return spd * (100.0 / spd[WAVELENGTHS == 560][0])


def _chromaticity(xyz: np.ndarray, cmfs_name: str) -> dict[str, float | None]:
    """x, y, u', v', T, duv, lambda_d, Pe of one tristimulus vector (``None`` where undefined)."""
    import colour

    nothing: dict[str, float | None] = dict.fromkeys(("x", "y", "u'", "v'", "T", "duv", "lambda_d", "Pe"))
    big_x, big_y, big_z = (float(v) for v in xyz)
    total, denominator = big_x + big_y + big_z, big_x + 15 * big_y + 3 * big_z
    if min(big_x, big_y, big_z) < 0 or total <= 0 or denominator <= 0:
        return nothing
    xy = np.array([big_x / total, big_y / total])
    u, v = 4 * big_x / denominator, 6 * big_y / denominator
    result = {"x": float(xy[0]), "y": float(xy[1]), "u'": u, "v'": 1.5 * v}
    cct, duv = (float(c) for c in colour.temperature.uv_to_CCT_Ohno2013(np.array([u, v])))
    valid_cct = 1000 <= cct <= 100_000 and abs(duv) <= 0.05
    result |= {"T": cct if valid_cct else None, "duv": duv if valid_cct else None}
    white = np.array([1 / 3, 1 / 3])
    if np.hypot(*(xy - white)) < 1e-6:
        return result | {"lambda_d": None, "Pe": None}
    cmfs = colour.MSDS_CMFS[cmfs_name]
    wavelength = float(colour.dominant_wavelength(xy, white, cmfs)[0])
    purity = float(colour.excitation_purity(xy, white, cmfs)) * 100
    return result | {"lambda_d": wavelength, "Pe": purity}


def colorimetry(radiance: np.ndarray) -> dict[str, float | None]:
    """The 24 colorimetric values of a radiance spectrum (W sr-1 m-2 nm-1 at 380-780 nm, 1 nm), by name
    (:data:`~instruments.cs2000.protocol.COLORIMETRIC_NAMES`, units there); ``None`` where undefined.

    Le = sum L (1 nm steps); X, Y, Z = 683 sum L cmf (CIE 15:2018 eq. 7.1 with Km = 683 lm W-1); chromaticities,
    T and duv (Ohno 2013), dominant wavelength and excitation purity as in the module notes.
    """
    radiance = np.asarray(radiance, dtype=np.float64)
    if radiance.shape != WAVELENGTHS.shape:
        raise ValueError(f"radiance must have {WAVELENGTHS.size} values (380-780 nm, 1 nm)")
    if not np.all(np.isfinite(radiance)):
        return dict.fromkeys(COLORIMETRIC_NAMES)
    cmfs_2, cmfs_10 = _cmfs()
    xyz_2, xyz_10 = 683.0 * radiance @ cmfs_2, 683.0 * radiance @ cmfs_10
    result: dict[str, float | None] = {"Le": float(radiance.sum()), "Lv": float(xyz_2[1])}
    result |= dict(zip(("X", "Y", "Z"), map(float, xyz_2), strict=True))
    result |= _chromaticity(xyz_2, "CIE 1931 2 Degree Standard Observer")
    result |= dict(zip(("X_10", "Y_10", "Z_10"), map(float, xyz_10), strict=True))
    result |= {f"{k}_10": v for k, v in _chromaticity(xyz_10, "CIE 1964 10 Degree Standard Observer").items()}
    return {name: result[name] for name in COLORIMETRIC_NAMES}


# ------------------------------------------------------------------------------------------------- input files


def read_reflectance_csv(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """Reflectance samples from a kmpipe spectral CSV, linearly interpolated to 380-780 nm at 1 nm.

    The file has ``# key: value`` header lines (``# quantity: reflectance`` if a quantity is given), a header
    row ``wavelength_nm,name1,name2,...`` and one row per wavelength (nm, increasing, covering 380-780 nm).

    Raises
    ------
    ScriptError
        Naming the file and line: unreadable, another quantity, a bad header, a row of the wrong length, a value
        that is not a finite number, wavelengths that do not increase or do not cover 380-780 nm.
    """
    path = Path(path)
    try:
        text = read_regular(path, MAX_FILE_BYTES).decode("utf-8-sig")
    except (OSError, ValueError) as error:  # ValueError: not a regular file, too large, not UTF-8
        raise ScriptError(f"{path}: cannot read the reflectance file ({error})") from None
    header: list[str] | None = None
    rows: list[list[float]] = []
    for line_no, row in enumerate(csv.reader(text.splitlines()), start=1):
        if not row or not "".join(row).strip():
            continue
        if row[0].startswith("#"):
            key, _, value = ",".join(row).lstrip("#").partition(":")
            if header is None and key.strip() == "quantity" and value.strip() != "reflectance":
                raise ScriptError(f"{path}, line {line_no}: quantity is {value.strip()!r}; expected reflectance")
            continue
        if header is None:
            if row[0] != "wavelength_nm" or len(row) < 2 or len(set(row)) != len(row) or "" in row:
                raise ScriptError(f"{path}, line {line_no}: expected a header row 'wavelength_nm,sample,...'")
            header = row
            continue
        if len(row) != len(header):
            raise ScriptError(f"{path}, line {line_no}: {len(row)} fields; the header has {len(header)}")
        try:
            numbers = [float(cell) for cell in row]
        except ValueError:
            raise ScriptError(f"{path}, line {line_no}: a value is not a number") from None
        if not all(math.isfinite(n) for n in numbers):
            raise ScriptError(f"{path}, line {line_no}: a value is not finite")
        rows.append(numbers)
    if header is None or len(rows) < 2:
        raise ScriptError(f"{path}: no header row or fewer than 2 data rows")
    table = np.array(rows)
    wavelengths = table[:, 0]
    if np.any(np.diff(wavelengths) <= 0) or wavelengths[0] > 380 or wavelengths[-1] < 780:
        raise ScriptError(f"{path}: wavelengths must increase and cover 380-780 nm")
    return {name: np.interp(WAVELENGTHS, wavelengths, table[:, k]) for k, name in enumerate(header[1:], start=1)}


_SAMPLES_KEYS = {"file", "sequence", "illuminant", "gain", "noise", "seed", "time_scale"}
_INSTRUMENT_KEYS = {"model", "serial", "firmware"}


def load_script(path: str | os.PathLike[str]) -> dict[str, object]:
    """Read a samples script (TOML) into :class:`Emulator` keyword arguments.

    ``[samples]``: ``file`` (reflectance CSV, relative to the script), ``sequence`` (the samples put under the
    instrument in turn, the next after each measurement read out; the last stays), ``illuminant``, ``gain``,
    ``noise``, ``seed``, ``time_scale``. ``[instrument]`` (optional): ``model``, ``serial``, ``firmware``.
    ``[[faults]]`` or ``[faults.NAME]`` tables: :class:`Fault` fields. A ``.csv`` path is read as the reflectance
    file alone.

    Raises
    ------
    ScriptError
        Naming the file and the table or key at fault.
    """
    path = Path(path)
    if path.suffix.lower() == ".csv":
        return {"samples": read_reflectance_csv(path)}
    try:
        script = tomllib.loads(read_regular(path, MAX_FILE_BYTES).decode("utf-8"))
    except (OSError, ValueError, RecursionError) as error:  # ValueError: not regular, too large, not UTF-8 or TOML
        raise ScriptError(f"{path}: cannot read the samples script ({error})") from None
    unknown = sorted(set(script) - {"samples", "instrument", "faults"})
    if unknown:
        raise ScriptError(f"{path}: unknown table(s) {', '.join(unknown)}; expected samples, instrument, faults")
    samples = script.get("samples")
    if not isinstance(samples, dict) or "file" not in samples:
        raise ScriptError(f"{path}: missing [samples] table with a 'file' key")
    instrument = script.get("instrument", {})
    if not isinstance(samples["file"], str) or not isinstance(instrument, dict):
        raise ScriptError(f"{path}: [samples] file is the name of a reflectance CSV (text), and [instrument] a table")
    for table, name, known in ((samples, "samples", _SAMPLES_KEYS), (instrument, "instrument", _INSTRUMENT_KEYS)):
        extra = sorted(set(table) - known)
        if extra:
            raise ScriptError(
                f"{path}: [{name}] unknown key(s) {', '.join(extra)}; expected {', '.join(sorted(known))}"
            )
    try:
        kwargs: dict[str, object] = {"samples": read_reflectance_csv(path.parent / samples["file"])}
    except ScriptError as error:  # name the script that names the file, too
        raise ScriptError(f"{path}: [samples] file: {error}") from None
    kwargs |= {
        key: samples[key] for key in ("sequence", "illuminant", "gain", "noise", "seed", "time_scale") if key in samples
    }
    kwargs |= {{"serial": "serial_number"}.get(key, key): value for key, value in instrument.items()}
    raw_faults = script.get("faults", [])
    items = list(raw_faults.items()) if isinstance(raw_faults, dict) else list(enumerate(raw_faults, start=1))
    faults = []
    for name, table in items:
        try:
            if not isinstance(table, dict):
                raise ValueError("expected a table")
            faults.append(Fault.from_table(table))
        except (TypeError, ValueError, LookupError, OverflowError) as error:
            raise ScriptError(f"{path}: fault {name}: {error}") from None
    kwargs["faults"] = faults
    return kwargs


# -------------------------------------------------------------------------------------------------- transports


class _PtyLink:
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


class _SocketLink:
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


_Link = _PtyLink | _SocketLink


@dataclass
class _Data:
    """The instrument's stored measurement and which spectral blocks have been read since."""

    measurement: Measurement
    blocks_read: set[int] = field(default_factory=set)
    colorimetry_read: bool = False


@dataclass
class _Pending:
    """A measurement in progress."""

    link: _Link
    measurement: Measurement
    error: str | None
    faults: list[Fault]
    state: str = "premeasuring"  # then "measuring"


def _firmware_tuple(firmware: str) -> tuple[int, ...]:
    try:
        return tuple(int(part) for part in firmware.split("."))
    except ValueError:
        raise ValueError(f"firmware {firmware!r} is not dotted numbers such as 3.00.9301") from None


# ---------------------------------------------------------------------------------------------------- emulator


class Emulator:
    """A CS-2000 on a pseudo-terminal and/or a TCP port, served by a background thread.

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
    pty : bool
        Serve a pseudo-terminal.
    link : path, optional
        A symlink to create to the pseudo-terminal (implies ``pty``); removed on :meth:`stop`.
    socket_port : int, optional
        Serve TCP on 127.0.0.1 at this port (0: any free port, see :attr:`socket_port`).
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
        pty: bool = True,
        link: str | os.PathLike[str] | None = None,
        socket_port: int | None = None,
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
        if aperture not in _LV_LIMIT:
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
        self._use_pty = pty or link is not None
        self._link_path = Path(link) if link is not None else None
        self._socket_port = socket_port
        if not self._use_pty and socket_port is None:
            raise ValueError("no transport: use pty, link or socket_port")
        self._reset_settings()
        self._pty: _PtyLink | None = None
        self._server: socket.socket | None = None
        self._client: _SocketLink | None = None
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._wake_r = self._wake_w = -1
        self._timers: list[tuple[float, int, Callable[[], None]]] = []
        self._timer_ids = itertools.count()
        self._failure: BaseException | None = None

    def _reset_settings(self) -> None:
        self._remote = False
        self._button_enabled = True
        self._speed: tuple[int, int, int] = (0, 0, 2)  # mode, seconds or microseconds (0 if none), ND 0/1/2
        self._sync: tuple[int, int] = (0, 0)  # mode, frequency in 1/100 Hz
        self._observer = 0
        self._data: _Data | None = None
        self._pending: _Pending | None = None
        self._late_until = 0.0  # monotonic time until which a no_completion measurement is still "measuring"
        self._colorimetry_fault: dict[str, float] = {}  # values a colorimetry fault replaces in the current reply

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

    def start(self) -> Emulator:
        """Open the transports and start serving; returns self."""
        if self._thread is not None:
            raise RuntimeError("the emulator is already running")
        self._stopping.clear()
        self._wake_r, self._wake_w = os.pipe()
        try:
            if self._use_pty:
                self._pty = _PtyLink()
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

    @classmethod
    def from_script(cls, path: str | os.PathLike[str], **overrides: object) -> Emulator:
        """An emulator from a samples script (:func:`load_script`); ``overrides`` win over the script."""
        kwargs = load_script(path) | overrides
        try:
            return cls(**kwargs)  # type: ignore[arg-type]
        except (TypeError, ValueError, LookupError, OverflowError) as error:  # a value of the wrong type or range
            raise ScriptError(f"{path}: {error}") from None

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

    def _drop(self, link: _Link) -> None:
        """Disconnect a link: close a TCP client; close the pty and open a new one (re-pointing the symlink)."""
        if isinstance(link, _PtyLink):
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
                self._pty = _PtyLink()
                self._point_link()
            link.close()
        else:
            link.close()
            if link is self._client:
                self._client = None

    def _send(self, link: _Link, payload: bytes, faults: Sequence[Fault] = ()) -> None:
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
        self._client = _SocketLink(connection)

    def _receive(self, link: _Link) -> None:
        data = link.read()
        if not data:
            if isinstance(link, _SocketLink):
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

    # ------------------------------------------------------------------------------------------ instrument

    def _command(self, link: _Link, line: bytes, terminator: bytes) -> None:
        if self._pending is not None and self._pending.state == "premeasuring":
            return  # the instrument accepts nothing while pre-measuring
        try:
            mnemonic, params = parse_command(line)
        except ProtocolError:
            self._send(link, format_reply("ER00", terminator=terminator))
            return
        fired = self._fired(mnemonic, params)
        wire = [f for f in fired if f.kind in _WIRE_KINDS and f.at == "reply"]
        self._colorimetry_fault = {k: v for f in fired if f.kind == "colorimetry" for k, v in f.values.items()}
        meas = _meas_parameter(mnemonic, params)
        starts = meas == 1 and self._pending is None and self._remote and not self._late()
        replacement = next((f for f in fired if f.kind in _REPLY_ERRORS and f.at == "reply"), None)
        if replacement is not None and not (starts and replacement.kind in ("error", "over_range")):
            self._send(link, format_reply(_fault_code(replacement), terminator=terminator), wire)
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

    def _start_measurement(self, link: _Link, terminator: bytes, fired: list[Fault]) -> None:
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
        premeasure = min(3.0, 1.0 + 0.5 * max(0.0, math.log10(100.0 / lv)))
        conditions, measuring_time, over_range = self._exposure(lv)
        if any(f.kind == "calculation_error" for f in fired):
            radiance = np.full(WAVELENGTHS.shape, np.nan)
            colorimetric = dict.fromkeys(COLORIMETRIC_NAMES)
        radiance.setflags(write=False)
        measurement = Measurement(sample, radiance, colorimetric, conditions, measuring_time)
        start_error = next((f for f in fired if f.kind in ("error", "over_range") and f.at == "reply"), None)
        error = _fault_code(start_error) if start_error is not None else "ER10" if over_range else None
        pending = _Pending(link, measurement, error, fired)
        self._pending = pending
        self._data = None
        self._schedule(premeasure, lambda: self._premeasured(pending, terminator))

    def _exposure(self, lv: float) -> tuple[Conditions, int, bool]:
        """Conditions, measuring time (s) and over range for luminance ``lv`` (cd m-2) under the current settings."""
        mode, value, nd_setting = self._speed
        limit = _LV_LIMIT[self._aperture]
        if mode == 0:
            integration = min(max(5.0 / lv, 0.005), 15.0)
            seconds = 2 + 16 * integration
        elif mode == 1:
            integration = min(max(1.0 / lv, 0.005), 15.0)
            seconds = 2 + 4 * integration
        elif mode == 3:
            integration = value / 1e6
            seconds = 2 + 2 * integration
        else:
            frames = min(max(math.ceil(100.0 / lv), 1), 15)
            integration = min(max(5.0 / lv, 0.005), float(value))
            seconds = 2 + value * frames / (1 if mode == 2 else 2)
        nd = 1 if nd_setting == 1 or (nd_setting == 2 and lv > 0.5 * limit) else 0
        limit *= _ND_FACTOR if nd else 1.0
        over_range = lv > limit or (mode == 3 and lv * integration > 0.5 * limit)
        conditions = Conditions(mode, self._sync[0], round(integration * 1e6), nd, 0, 0, self._aperture, 0)
        return conditions, int(min(max(math.ceil(seconds), 2), 242)), over_range

    def _premeasured(self, pending: _Pending, terminator: bytes) -> None:
        if self._pending is not pending:
            return
        wire = [f for f in pending.faults if f.kind in _WIRE_KINDS and f.at == "reply"]
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
        wire = [f for f in pending.faults if f.kind in _WIRE_KINDS and f.at == "completion"]
        error = next((f for f in pending.faults if f.kind in ("error", "over_range") and f.at == "completion"), None)
        if error is not None:
            self._send(pending.link, format_reply(_fault_code(error), terminator=terminator), wire)
            return
        self._store(pending.measurement)
        self._send(pending.link, format_reply("OK00", terminator=terminator), wire)

    def _store(self, measurement: Measurement) -> None:
        self._data = _Data(measurement)
        with self._lock:
            self._measurements.append(measurement)


_COMMANDS = frozenset({"IDDR", "MSWE", "SPMS", "SPMR", "SCMS", "SCMR", "OBSS", "OBSR", "STSR", "DTCR", "MEAS", "MEDR"})
"""Commands the emulator implements besides RMTS; any other mnemonic is answered ER00."""


# ------------------------------------------------------------------------------------------------------ CLI


def run(
    link: str | os.PathLike[str] | None = None,
    samples: str | os.PathLike[str] | None = None,
    socket_port: int | None = None,
    time_scale: float | None = None,
    *,
    out: TextIO | None = None,
) -> None:
    """Serve an emulated CS-2000 until Ctrl-C (or SIGTERM): on a pseudo-terminal (with the symlink ``link``)
    and, if ``socket_port`` is given, on TCP 127.0.0.1. ``samples`` is a samples script (TOML) or a reflectance
    CSV; ``time_scale`` overrides the script's. Prints where it listens to ``out`` (default stdout).

    Raises
    ------
    ScriptError
        A samples script or file that cannot be used.
    """
    out = out or sys.stdout
    overrides: dict[str, object] = {"link": link, "socket_port": socket_port}
    if time_scale is not None:
        overrides["time_scale"] = time_scale
    emulator = Emulator.from_script(samples, **overrides) if samples else Emulator(**overrides)  # type: ignore[arg-type]
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler) if _main_thread() else None
    try:
        with emulator:
            print(f"CS-2000 emulator: serial port {emulator.port}" + (f" (link {link})" if link else ""), file=out)
            if emulator.socket_url:
                print(f"CS-2000 emulator: {emulator.socket_url}", file=out)
            print(
                f"samples: {', '.join(emulator.sample_names)}; time scale {emulator.time_scale}; Ctrl-C to stop",
                file=out,
            )
            out.flush()
            with contextlib.suppress(KeyboardInterrupt):
                while not emulator.wait(0.5):
                    pass
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m instruments.cs2000.emulator [--link PATH] [--samples FILE] [--socket PORT] [--time-scale X]``.

    Returns the exit status: 0 after Ctrl-C, 2 for bad input (a message, no traceback).
    """
    parser = argparse.ArgumentParser(prog="cs2000-emulator", description="Emulate a Konica Minolta CS-2000A.")
    parser.add_argument("--link", help="symlink to create to the pseudo-terminal, e.g. /tmp/cs2000")
    parser.add_argument("--samples", help="samples script (TOML) or reflectance CSV")
    parser.add_argument("--socket", type=int, dest="socket_port", help="also serve TCP on 127.0.0.1:PORT (0: any)")
    parser.add_argument("--time-scale", type=float, help="multiply all instrument times (e.g. 0.1)")
    args = parser.parse_args(argv)
    try:
        run(link=args.link, samples=args.samples, socket_port=args.socket_port, time_scale=args.time_scale)
    except (ScriptError, ValueError, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
