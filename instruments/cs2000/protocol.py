"""Konica Minolta CS-2000 / CS-2000A serial protocol: pure functions, no port and no I/O.

The host side formats commands (:func:`format_command`) and parses replies (:func:`parse_reply`, :func:`check`
and the field parsers); the instrument side (the emulator) parses commands (:func:`parse_command`) and formats
replies (:func:`format_reply`, :func:`format_decimal_spectral`, :func:`format_colorimetric`). The driver owns the
port and calls these functions; nothing here blocks, sleeps or touches a file.

Reference: Konica Minolta, *CS-2000/CS-2000A Communication Specifications*, Rev. 7.00 (2020), as summarised in
``../shared/instruments/cs2000-protocol.md``; behaviour marked *inferred* there is tolerated here.

Exceptions
----------
- :class:`ProtocolError` (a ``ValueError``): the bytes do not follow the protocol (no reply code, wrong field
  count, a field that is not a number, a bad command). Nothing the instrument *meant* to say.
- :class:`CS2000Error`: the instrument answered an error code ``ERnn``; ``.busy`` tells the three codes that mean
  "measurement in progress" when they answer a command sent during a measurement.
- :class:`CalculationError` (a :class:`CS2000Error` with code ``None``): a reply was well formed and ``OK00`` but
  spectral values were calculation-error sentinels. Raised by :func:`parse_spectral_block`, with the wavelengths
  concerned and the block's values (``NaN`` at the sentinels) attached, so a caller that wants the rest has it.
  Colorimetric sentinels do not raise: :func:`parse_colorimetric` maps them to ``None``, one quantity at a time.

Calculation-error sentinels
---------------------------
The specification lists ``-9.9999e9`` (hex ``D1BA43B6``) for spectral values, Le and XYZ; ``-9.9e9`` for Lv,
lambda_d and Pe; ``-9.999`` for chromaticities; ``-9999`` for T; ``-9.9999`` for duv; and firmware 1.01.0000 sends
a bare ``0`` instead (accepted in both formats: it is not 8 hexadecimal characters). Two traps: ``D1BA43B6``
decodes to -9.999999e10, not -9.9999e9 (whose float32 is ``D0150297``); and a bare ``0`` is also a number. So a
value is a sentinel when

- its text is exactly ``0`` (firmware 1.01.0000; every documented format prints a genuine zero with a decimal
  point, e.g. ``0.0000e+0``, ``0.0000``, and a genuine T is never 0 K), or
- it is at or below the threshold of its quantity (:data:`SENTINEL_THRESHOLDS`): -1e9 for radiance, Le, XYZ,
  Lv, lambda_d and Pe; -9 for chromaticities and duv; -9000 for T. No physical value comes near these, and the
  rule covers both hex spellings and any decimal spelling (``-9.9999e9``, ``-9.9999E+09``).

Garbage before a reply
----------------------
Line noise on RS-232, a reply fragment left over after a timeout, or a NUL sent when the USB port opens can put
stray bytes before a reply code. :func:`parse_reply` finds the **last** place in the line where a reply code
(``OK`` or ``ER`` and two digits) starts and is followed by ``,`` or the end of the line, and parses from there;
the bytes before it are kept in :attr:`Reply.skipped`. The last, not the first, because a fragment of an earlier
reply (``OK00,3AA1``) may precede the real one. This is safe because no field of any CS-2000 reply can contain
``OK`` or ``ER`` followed by two digits: fields are decimal numbers (exponent ``e``/``E`` then a sign or digit),
hexadecimal (no ``K`` or ``R``), or the model name. Bytes *after* the code must be well formed.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from dataclasses import fields as dataclass_fields

import numpy as np

__all__ = [
    "BUSY_CODES",
    "COLORIMETRIC_BLOCKS",
    "COLORIMETRIC_NAMES",
    "ERROR_MEANINGS",
    "FIRMWARE_1_01_SENTINEL",
    "HEX_SENTINEL",
    "SENTINEL_THRESHOLDS",
    "SPECTRAL_BLOCKS",
    "TERMINATOR",
    "TERMINATORS",
    "WAVELENGTHS",
    "CS2000Error",
    "CalculationError",
    "Conditions",
    "Identity",
    "ProtocolError",
    "Reply",
    "check",
    "decode_float32_hex",
    "decode_float32_hex_fields",
    "encode_float32_hex",
    "format_colorimetric",
    "format_command",
    "format_decimal_spectral",
    "format_reply",
    "is_busy_code",
    "parse_colorimetric",
    "parse_command",
    "parse_conditions",
    "parse_identity",
    "parse_measure_time",
    "parse_reply",
    "parse_spectral_block",
    "sentinel_text",
    "split_line",
]

TERMINATOR = b"\r\n"
"""The terminator the driver sends; the instrument ends each reply with the terminator of its command."""

TERMINATORS = (b"\r\n", b"\r", b"\n")
"""Accepted line terminators, longest first."""

ERROR_MEANINGS: dict[str, str] = {
    "ER00": "invalid command or wrong number of parameters",
    "ER02": "measurement in progress",
    "ER05": "no user-calibration / lens / ND compensation values",
    "ER10": "over range, or flicker too large",
    "ER17": "parameter out of range (also: MEAS misuse)",
    "ER20": "no data",
    "ER30": "internal memory (flash) error",
    "ER32": "internal memory (flash) error",
    "ER34": "internal memory (flash) error",
    "ER51": "temperature abnormality",
    "ER52": "temperature abnormality",
    "ER71": "external sync missing or outside 20-200 Hz",
    "ER81": "shutter",
    "ER82": "internal ND filter mechanism",
    "ER83": "measuring-angle selector abnormal or moved",
    "ER84": "cooling fan",
    "ER99": "program abnormality",
}
"""Meaning of every error code in the specification."""

BUSY_CODES = frozenset({"ER00", "ER02", "ER17"})
"""Codes that, in answer to a command sent during a measurement, mean "measurement in progress" (ER17 and, on some
units, ER02 answer ``MEAS,1``; ER00 answers anything else; ER02 answers ``MEDR`` polls after a missed completion)."""

SPECTRAL_BLOCKS: dict[int, tuple[int, int]] = {1: (380, 479), 2: (480, 579), 3: (580, 679), 4: (680, 780)}
"""``MEDR,1,fmt,block``: inclusive wavelength range in nm of each spectral block, 1 nm apart."""

WAVELENGTHS = np.arange(380, 781, dtype=np.float64)
"""The 401 wavelengths in nm of a whole spectrum, blocks 1-4 in order."""

COLORIMETRIC_NAMES: tuple[str, ...] = (
    "Le", "Lv", "X", "Y", "Z", "x", "y", "u'", "v'", "T", "duv", "lambda_d", "Pe",
    "X_10", "Y_10", "Z_10", "x_10", "y_10", "u'_10", "v'_10", "T_10", "duv_10", "lambda_d_10", "Pe_10",
)  # fmt: skip
"""``MEDR,2,fmt,0`` order. Units: Le W sr-1 m-2; Lv, X, Y, Z cd m-2 (Y = Lv); x, y, u', v' 1; T K; duv 1
(CIE 1960 uv distance from the Planckian locus, signed); lambda_d nm (negative: complementary wavelength);
Pe %. ``_10``: the CIE 1964 10 deg observer."""

COLORIMETRIC_BLOCKS: dict[int, tuple[str, ...]] = {
    0: COLORIMETRIC_NAMES,
    1: ("X", "Y", "Z"),
    2: ("x", "y", "Lv"),
    3: ("u'", "v'", "Lv"),
    4: ("T", "duv", "Lv"),
    5: ("lambda_d", "Pe", "Lv"),
    11: ("X_10", "Y_10", "Z_10"),
    12: ("x_10", "y_10", "Lv"),
    13: ("u'_10", "v'_10", "Lv"),
    14: ("T_10", "duv_10", "Lv"),
    15: ("lambda_d_10", "Pe_10", "Lv"),
    100: ("Le",),
    101: ("Lv",),
}
"""``MEDR,2,fmt,block``: the quantities of each colorimetric block, in reply order. Blocks 12-15 carry Lv (there is
no 10 deg luminance), by analogy with blocks 2-5."""


def _base(name: str) -> str:
    """The 2 deg name of a colorimetric quantity (``"x_10"`` -> ``"x"``)."""
    return name.removesuffix("_10")


SENTINEL_THRESHOLDS: dict[str, float] = {
    "radiance": -1e9, "Le": -1e9, "X": -1e9, "Y": -1e9, "Z": -1e9, "Lv": -1e9, "lambda_d": -1e9, "Pe": -1e9,
    "x": -9.0, "y": -9.0, "u'": -9.0, "v'": -9.0, "duv": -9.0, "T": -9000.0,
}  # fmt: skip
"""A value at or below its threshold is a calculation-error sentinel (keys: ``"radiance"`` for spectra, and the
2 deg names of the colorimetric quantities; ``_10`` quantities use their 2 deg name)."""

_SENTINEL_TEXT: dict[str, str] = {
    "radiance": "-9.9999e9", "Le": "-9.9999e9", "X": "-9.9999e9", "Y": "-9.9999e9", "Z": "-9.9999e9",
    "Lv": "-9.9e9", "lambda_d": "-9.9e9", "Pe": "-9.9e9",
    "x": "-9.999", "y": "-9.999", "u'": "-9.999", "v'": "-9.999", "T": "-9999", "duv": "-9.9999",
}  # fmt: skip

HEX_SENTINEL = "D1BA43B6"
"""The hexadecimal spectral sentinel as the specification spells it (decodes to -9.999999e10)."""

FIRMWARE_1_01_SENTINEL = "0"
"""What firmware 1.01.0000 sends instead of every sentinel."""

_MNEMONIC = re.compile(r"[A-Z]{4}")
_PARAM = re.compile(r"[!-~ ]+")  # printable ASCII; commas are refused separately
_CODE = re.compile(rb"(?:OK|ER)[0-9]{2}(?=,|\Z)")
_REPLY_CODE = re.compile(r"(?:OK|ER)[0-9]{2}")
_FIELD = re.compile(r"[ -+\--~]*")  # printable ASCII without the comma
_DECIMAL = re.compile(r" *[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)? *")
_HEX8 = re.compile(r"[0-9A-Fa-f]{8}")
_DIGITS = re.compile(r"[0-9]+")
_FLOAT32_MAX = float(np.finfo(np.float32).max)


class ProtocolError(ValueError):
    """Bytes that do not follow the protocol: a line without a reply code, a wrong field count, a bad number."""


class CS2000Error(Exception):
    """The instrument answered an error code.

    Attributes
    ----------
    code : str or None
        ``"ER10"`` etc.; ``None`` for a :class:`CalculationError`.
    meaning : str
        From :data:`ERROR_MEANINGS` (``"unknown error code"`` for a code the specification does not list).
    """

    def __init__(self, code: str | None, meaning: str | None = None) -> None:
        self.code = code
        self.meaning = meaning if meaning is not None else ERROR_MEANINGS.get(code or "", "unknown error code")
        super().__init__(str(self))

    def __str__(self) -> str:
        return f"{self.code}: {self.meaning}" if self.code else self.meaning

    @property
    def busy(self) -> bool:
        """True for ER00, ER02 and ER17: "measurement in progress" when answering a command sent while measuring."""
        return is_busy_code(self.code)


class CalculationError(CS2000Error):
    """``OK00`` spectral data holding calculation-error sentinels (over range, or a failed reading).

    Attributes
    ----------
    wavelengths : tuple of int
        The wavelengths (nm) whose values were sentinels.
    values : numpy.ndarray
        The whole block in W sr-1 m-2 nm-1, ``NaN`` at the sentinels.
    """

    def __init__(self, wavelengths: Sequence[int], values: np.ndarray) -> None:
        self.wavelengths = tuple(int(w) for w in wavelengths)
        self.values = values
        super().__init__(None, f"calculation error (sentinel values) at {_ranges(self.wavelengths)} nm")


def _ranges(wavelengths: Sequence[int]) -> str:
    """``(380, 381, 382, 400)`` -> ``"380-382, 400"``."""
    parts: list[str] = []
    start = prev = wavelengths[0]
    for w in [*wavelengths[1:], None]:
        if w is not None and w == prev + 1:
            prev = w
            continue
        parts.append(f"{start}-{prev}" if prev != start else f"{start}")
        if w is not None:
            start = prev = w
    return ", ".join(parts)


def is_busy_code(code: str | None) -> bool:
    """True if ``code`` is one of :data:`BUSY_CODES`."""
    return code in BUSY_CODES


# --------------------------------------------------------------------------------------------------- host side


def _check_terminator(terminator: bytes) -> None:
    if terminator not in TERMINATORS:
        raise ValueError(f"terminator {terminator!r} is not CR, LF or CR LF")


def format_command(mnemonic: str, *params: int | str, terminator: bytes = TERMINATOR) -> bytes:
    """Encode a command line: ``format_command("MEDR", 1, 1, 1)`` -> ``b"MEDR,1,1,1\\r\\n"``.

    Parameters
    ----------
    mnemonic : str
        Four upper-case letters (``"MEAS"``).
    params : int or str
        Non-negative integers are written in decimal without padding (the instrument accepts dropped leading
        zeros); strings are written as given (e.g. ``"000033333"``) and must be printable ASCII without commas.
    terminator : bytes
        CR LF (default), CR or LF; the reply will end with the same.

    Raises
    ------
    ValueError
        For a bad mnemonic, parameter or terminator.
    """
    if not isinstance(mnemonic, str) or not _MNEMONIC.fullmatch(mnemonic):
        raise ValueError(f"command mnemonic {mnemonic!r} is not four upper-case letters")
    _check_terminator(terminator)
    parts = [mnemonic]
    for param in params:
        if isinstance(param, bool) or not isinstance(param, int | str):
            raise ValueError(f"{mnemonic} parameter {param!r} is not an integer or a string")
        if isinstance(param, int):
            if param < 0:
                raise ValueError(f"{mnemonic} parameter {param} is negative")
            text = str(param)
        else:
            text = param
        if not _PARAM.fullmatch(text) or "," in text:
            raise ValueError(f"{mnemonic} parameter {param!r} is empty, or has a comma, CR, LF or non-ASCII character")
        parts.append(text)
    return ",".join(parts).encode("ascii") + terminator


def split_line(line: bytes) -> tuple[bytes, bytes]:
    """Split one line into its body and its terminator (CR LF, CR, LF, or ``b""`` if it has none)."""
    for terminator in TERMINATORS:
        if line.endswith(terminator):
            return line[: -len(terminator)], terminator
    return line, b""


@dataclass(frozen=True)
class Reply:
    """One reply line from the instrument.

    Attributes
    ----------
    code : str
        ``"OK00"`` or ``"ERnn"``.
    fields : tuple of str
        The comma-separated fields after the code, as sent (``"CS-2000A "`` keeps its padding).
    raw : bytes
        The line exactly as received, garbage and terminator included.
    skipped : bytes
        Garbage bytes before the code (normally ``b""``).
    """

    code: str
    fields: tuple[str, ...]
    raw: bytes
    skipped: bytes = b""

    @property
    def ok(self) -> bool:
        """True for an ``OK`` code."""
        return self.code.startswith("OK")


def parse_reply(line: bytes) -> Reply:
    """Parse one reply line (with or without its CR, LF or CR LF terminator).

    Garbage before the reply code is skipped (see the module notes: the last code start wins) and kept in
    :attr:`Reply.skipped`. Does not raise for ``ERnn``: see :func:`check`.

    Raises
    ------
    ProtocolError
        No reply code in the line; or, after the code, a CR or LF, a non-ASCII or control character.
    """
    if not isinstance(line, bytes | bytearray):
        raise TypeError(f"a reply line is bytes, not {type(line).__name__}")
    raw = bytes(line)
    body, _ = split_line(raw)
    starts = [m.start() for m in _CODE.finditer(body)]
    if not starts:
        raise ProtocolError(f"no reply code (OK00 or ERnn followed by ',' or the end of the line) in {raw!r}")
    start = starts[-1]
    try:
        text = body[start:].decode("ascii")
    except UnicodeDecodeError:
        raise ProtocolError(f"non-ASCII bytes after the reply code in {raw!r}") from None
    code, *fields = text.split(",")
    bad = next((f for f in fields if not _FIELD.fullmatch(f)), None)
    if bad is not None:
        raise ProtocolError(f"field {bad!r} has a control character (CR, LF, ...) in {raw!r}")
    return Reply(code=code, fields=tuple(fields), raw=raw, skipped=body[:start])


def check(reply: Reply) -> tuple[str, ...]:
    """The reply's fields if its code is ``OK``; raise :class:`CS2000Error` for ``ERnn``."""
    if reply.ok:
        return reply.fields
    raise CS2000Error(reply.code)


@dataclass(frozen=True)
class Identity:
    """``IDDR``: model name (padding removed, ``"CS-2000A"``), variant (1 CS-2000, 2 CS-2000A), 7-digit serial."""

    model: str
    variant: int
    serial: str


def _count(fields: Sequence[str], expected: int | Iterable[int], what: str) -> None:
    allowed = (expected,) if isinstance(expected, int) else tuple(expected)
    if len(fields) not in allowed:
        want = " or ".join(str(n) for n in allowed)
        raise ProtocolError(f"{what}: expected {want} fields, got {len(fields)}: {','.join(fields)!r}")


def _integer(text: str, what: str) -> int:
    if not _DIGITS.fullmatch(text):
        raise ProtocolError(f"{what}: {text!r} is not an unsigned integer")
    return int(text)


def parse_identity(fields: Sequence[str]) -> Identity:
    """Parse the ``IDDR`` fields ``("CS-2000A ", "2", "1234567")``.

    Raises
    ------
    ProtocolError
        Not 3 fields, an empty name, a variant other than 1 or 2, or a serial number that is not 7 digits.
    """
    _count(fields, 3, "IDDR reply")
    name, variant_text, serial = fields
    model = name.strip()
    if not model:
        raise ProtocolError("IDDR reply: empty model name")
    variant = _integer(variant_text, "IDDR variant")
    if variant not in (1, 2):
        raise ProtocolError(f"IDDR reply: variant {variant} is not 1 (CS-2000) or 2 (CS-2000A)")
    if not re.fullmatch(r"[0-9]{7}", serial):
        raise ProtocolError(f"IDDR reply: serial number {serial!r} is not 7 digits")
    return Identity(model=model, variant=variant, serial=serial)


def parse_measure_time(reply: Reply) -> int:
    """The measuring time in s announced by the first reply to ``MEAS,1`` (``OK00,005`` -> 5).

    The code is checked before the time: a failing pre-measurement may answer a bare ``ERnn`` (inferred).

    Raises
    ------
    CS2000Error
        For an ``ERnn`` reply (with or without fields).
    ProtocolError
        An ``OK`` reply without exactly one unsigned-integer field.
    """
    fields = check(reply)
    _count(fields, 1, "first MEAS reply")
    return _integer(fields[0], "first MEAS reply, measuring time")


def _decimal(text: str, what: str) -> float:
    if not _DECIMAL.fullmatch(text):
        raise ProtocolError(f"{what}: {text!r} is not a decimal number")
    return float(text)


def decode_float32_hex(text: str) -> float:
    """Decode 8 hexadecimal characters of a big-endian IEEE-754 float32 (``"3F800000"`` -> 1.0), exactly.

    Raises
    ------
    ProtocolError
        Not exactly 8 hexadecimal characters.
    """
    if not _HEX8.fullmatch(text):
        raise ProtocolError(f"{text!r} is not 8 hexadecimal characters (a float32)")
    return struct.unpack(">f", bytes.fromhex(text))[0]


def decode_float32_hex_fields(fields: Sequence[str]) -> np.ndarray:
    """Vectorised :func:`decode_float32_hex`: float64 array holding the float32 values exactly."""
    bad = next((f for f in fields if not _HEX8.fullmatch(f)), None)
    if bad is not None:
        raise ProtocolError(f"{bad!r} is not 8 hexadecimal characters (a float32)")
    return np.frombuffer(bytes.fromhex("".join(fields)), dtype=">f4").astype(np.float64)


def encode_float32_hex(values: float | Iterable[float] | np.ndarray) -> list[str]:
    """Encode values as 8 upper-case hexadecimal characters each, big-endian IEEE-754 float32.

    A float32 value round-trips exactly through :func:`decode_float32_hex` (signed zero and subnormals included);
    a float64 value is rounded to the nearest float32.

    Raises
    ------
    ValueError
        A value that is NaN, infinite, or beyond the float32 range.
    """
    array = np.atleast_1d(np.asarray(values, dtype=np.float64)).ravel()
    if not np.all(np.isfinite(array)) or np.any(np.abs(array) > _FLOAT32_MAX):
        raise ValueError("values to encode as float32 must be finite and within the float32 range")
    text = array.astype(">f4").tobytes().hex().upper()
    return [text[i : i + 8] for i in range(0, len(text), 8)]


def parse_spectral_block(fields: Sequence[str], block: int, fmt: int) -> np.ndarray:
    """Spectral radiance of one ``MEDR,1,fmt,block`` reply, W sr-1 m-2 nm-1 at the block's wavelengths.

    Parameters
    ----------
    fields : sequence of str
        The reply's fields (after :func:`check`).
    block : int
        1-4 (:data:`SPECTRAL_BLOCKS`); blocks 1-3 hold 100 values, block 4 holds 101.
    fmt : int
        0: decimal text; 1: hexadecimal float32, big-endian (exact).

    Returns
    -------
    numpy.ndarray
        float64, one value per nm.

    Raises
    ------
    ProtocolError
        Wrong count for the block, or a value that is not a number of the format (or a non-finite float32).
    CalculationError
        Sentinel values (see the module notes): the error names the wavelengths and carries the block with NaN there.
    ValueError
        An unknown block or format.
    """
    if block not in SPECTRAL_BLOCKS:
        raise ValueError(f"spectral block {block} is not one of 1, 2, 3, 4")
    if fmt not in (0, 1):
        raise ValueError(f"MEDR format {fmt} is not 0 (decimal) or 1 (hexadecimal)")
    first, last = SPECTRAL_BLOCKS[block]
    _count(fields, last - first + 1, f"spectral block {block} ({first}-{last} nm)")
    old_firmware = np.array([f.strip() == FIRMWARE_1_01_SENTINEL for f in fields])
    texts = ["00000000" if old else f for f, old in zip(fields, old_firmware, strict=True)]
    if fmt == 1:
        values = decode_float32_hex_fields(texts)
        if not np.all(np.isfinite(values)):
            raise ProtocolError(f"spectral block {block}: a hexadecimal value is not a finite float32")
    else:
        values = np.array([_decimal(f, f"spectral block {block}") for f in texts])
    mask = (values <= SENTINEL_THRESHOLDS["radiance"]) | old_firmware
    if np.any(mask):
        values[mask] = np.nan
        raise CalculationError((first + np.flatnonzero(mask)).tolist(), values)
    return values


@dataclass(frozen=True)
class Conditions:
    """Measurement conditions (``MEDR,0,0,1``).

    Attributes
    ----------
    speed : int
        0 Normal, 1 Fast, 2 Multi-integration Normal, 3 Manual, 4 Multi-integration Fast.
    sync : int
        0 none, 1 internal, 2 external.
    integration_us : int
        Integration time in microseconds.
    internal_nd : int
        0 off, 1 on.
    close_up_lens : int
        0 none, else the lens fitted.
    external_nd : int
        0 none, 1 = 1/10, 2 = 1/100.
    angle : int
        Aperture: 0 = 1 deg, 1 = 0.2 deg, 2 = 0.1 deg.
    calibration_channel : int
        0 factory calibration, else the user-calibration channel.
    """

    speed: int
    sync: int
    integration_us: int
    internal_nd: int
    close_up_lens: int
    external_nd: int
    angle: int
    calibration_channel: int


def parse_conditions(fields: Sequence[str]) -> Conditions:
    """Parse the ``MEDR,0,0,1`` fields ``("0", "0", "000500000", "0", "0", "0", "0", "00")``.

    Raises
    ------
    ProtocolError
        Not 8 fields, or a field that is not an unsigned integer.
    """
    _count(fields, 8, "measurement conditions")
    names = [f.name for f in dataclass_fields(Conditions)]
    return Conditions(*(_integer(text, f"conditions, {name}") for text, name in zip(fields, names, strict=True)))


def parse_colorimetric(fields: Sequence[str], block: int, fmt: int = 0) -> dict[str, float | None]:
    """Colorimetric values of one ``MEDR,2,fmt,block`` reply, by name (:data:`COLORIMETRIC_NAMES`, units there).

    Sentinels (see the module notes) become ``None``, one quantity at a time; T is returned as a float.

    Raises
    ------
    ProtocolError
        Wrong field count for the block, or a value that is not a number of the format.
    ValueError
        An unknown block or format.
    """
    if block not in COLORIMETRIC_BLOCKS:
        raise ValueError(f"colorimetric block {block} is not one of {sorted(COLORIMETRIC_BLOCKS)}")
    if fmt not in (0, 1):
        raise ValueError(f"MEDR format {fmt} is not 0 (decimal) or 1 (hexadecimal)")
    names = COLORIMETRIC_BLOCKS[block]
    _count(fields, len(names), f"colorimetric block {block}")
    result: dict[str, float | None] = {}
    for name, text in zip(names, fields, strict=True):
        if text.strip() == FIRMWARE_1_01_SENTINEL:
            result[name] = None
            continue
        value = decode_float32_hex(text) if fmt == 1 else _decimal(text, f"colorimetric {name}")
        result[name] = None if value <= SENTINEL_THRESHOLDS[_base(name)] else value
    return result


# --------------------------------------------------------------------------------------------- instrument side


def parse_command(line: bytes) -> tuple[str, tuple[str, ...]]:
    """Split a command line (terminator optional) into its mnemonic and parameters.

    ``b"MEDR,1,0,01\\r\\n"`` -> ``("MEDR", ("1", "0", "01"))``. Parameters are returned as sent; the instrument
    reads numeric ones with ``int``, so dropped leading zeros do not matter.

    Raises
    ------
    ProtocolError
        Not ASCII, a mnemonic that is not four upper-case letters, an empty parameter or a control character.
    """
    body, _ = split_line(bytes(line))
    try:
        text = body.decode("ascii")
    except UnicodeDecodeError:
        raise ProtocolError(f"command {bytes(line)!r} is not ASCII") from None
    mnemonic, *params = text.split(",")
    if not _MNEMONIC.fullmatch(mnemonic):
        raise ProtocolError(f"command {bytes(line)!r}: {mnemonic!r} is not four upper-case letters")
    bad = next((p for p in params if not _PARAM.fullmatch(p)), None)
    if bad is not None:
        raise ProtocolError(f"command {bytes(line)!r}: parameter {bad!r} is empty or has a control character")
    return mnemonic, tuple(params)


def format_reply(code: str = "OK00", *fields: str, terminator: bytes = TERMINATOR) -> bytes:
    """Encode a reply line: ``format_reply("OK00", "005")`` -> ``b"OK00,005\\r\\n"``.

    Raises
    ------
    ValueError
        A code that is not ``OK``/``ER`` and two digits, a field with a comma, CR, LF or non-ASCII character, or
        a bad terminator.
    """
    if not _REPLY_CODE.fullmatch(code):
        raise ValueError(f"reply code {code!r} is not OK or ER and two digits")
    _check_terminator(terminator)
    bad = next((f for f in fields if not isinstance(f, str) or not _FIELD.fullmatch(f)), None)
    if bad is not None:
        raise ValueError(f"reply field {bad!r} is not printable ASCII without a comma")
    return ",".join((code, *fields)).encode("ascii") + terminator


def format_decimal_spectral(value: float) -> str:
    """Decimal text of a spectral value, Le or X, Y, Z: 4 decimals and a one-digit signed exponent (``1.2345e-3``).

    The one-digit exponent limits the range: magnitudes that round below ``1.0000e-9`` are written
    ``0.0000e+0`` (below the instrument's noise floor); magnitudes that round to ``1.0000e+10`` or more cannot be
    written and raise ``ValueError`` (the instrument reports ER10 over range instead).
    """
    value = float(value)
    if not np.isfinite(value):
        raise ValueError(f"{value} cannot be written as a decimal spectral value")
    mantissa, exponent_text = f"{value:.4e}".split("e")
    exponent = int(exponent_text)
    if exponent > 9:
        raise ValueError(f"{value} is beyond the decimal format's one-digit exponent")
    if value == 0 or exponent < -9:
        return "0.0000e+0"
    return f"{mantissa}e{exponent:+d}"


def _format_lv(value: float) -> str:
    """Lv, 6 characters: ``0.0123``, ``1.2345``, ``12.345``, ``1234.5``, ``123456``; beyond, ``1.23e6``."""
    for decimals in (4, 3, 2, 1):
        text = f"{value:.{decimals}f}"
        if len(text) <= 6:
            return text
    text = f"{value:.0f}"
    return text if len(text) <= 6 else f"{value:.2e}".replace("e+0", "e").replace("e+", "e")


def format_colorimetric(name: str, value: float | None, fmt: int = 0, *, firmware_1_01: bool = False) -> str:
    """Text of one colorimetric value as the instrument writes it in ``MEDR,2,fmt,...``.

    Decimal formats: Le, X, Y, Z as :func:`format_decimal_spectral`; Lv 6 characters wide; x, y, u', v' ``0.####``;
    T an integer; duv signed with 4 decimals; lambda_d and Pe one decimal. Hexadecimal: float32 as
    :func:`encode_float32_hex`. ``None`` is written as the quantity's sentinel (``0`` with ``firmware_1_01``).
    """
    base = _base(name)
    if base not in _SENTINEL_TEXT or base == "radiance":
        raise ValueError(f"{name!r} is not a colorimetric quantity")
    if value is None:
        if firmware_1_01:
            return FIRMWARE_1_01_SENTINEL
        text = _SENTINEL_TEXT[base]
        return encode_float32_hex(float(text))[0] if fmt == 1 else text
    if fmt == 1:
        return encode_float32_hex(value)[0]
    if base in ("Le", "X", "Y", "Z"):
        return format_decimal_spectral(value)
    if base == "Lv":
        return _format_lv(value)
    if base in ("x", "y", "u'", "v'"):
        return f"{value:.4f}"
    if base == "T":
        return f"{value:.0f}"
    if base == "duv":
        return f"{value:+.4f}"
    return f"{value:.1f}"


def sentinel_text(fmt: int, *, firmware_1_01: bool = False) -> str:
    """The spectral sentinel as the instrument writes it: ``-9.9999e9`` (decimal), ``D1BA43B6`` (hex), or ``0``."""
    if firmware_1_01:
        return FIRMWARE_1_01_SENTINEL
    return HEX_SENTINEL if fmt == 1 else _SENTINEL_TEXT["radiance"]
