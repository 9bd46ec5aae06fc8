"""Faults the CS-2000 emulator injects: :class:`Fault`.

A fault applies to the commands that match it (a mnemonic ``"MEDR"``, a command ``"MEDR,1,1,2"``, or ``"*"``),
every time or on the n-th occurrence. Wire faults (``delay``, ``chunks``, ``garbage``, ``disconnect``) change how a
reply is sent, the immediate reply or, with ``at="completion"``, the MEAS completion line. Replacement faults answer
an error instead (``busy`` ER02 and ``no_data`` ER20 at once; ``error``/``over_range`` on ``MEAS,1`` after the
pre-measurement or, with ``at="completion"``, as the completion line). ``no_completion`` never sends the completion
line (``MEDR`` then answers ER02 until the measuring time has passed); ``calculation_error`` makes a measurement's
values sentinels; ``late_completion`` sends a stray ``OK00`` after the reply to ``MEAS,0``; ``colorimetry`` answers a
colorimetric ``MEDR`` with some values replaced (a corrupted transfer: they no longer match the spectrum).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from instruments.cs2000.protocol import COLORIMETRIC_NAMES, ProtocolError, format_reply, parse_command

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

WIRE_KINDS = frozenset({"delay", "chunks", "garbage", "disconnect"})
"""Faults that change how a reply is sent."""
REPLY_ERRORS = {"busy": "ER02", "no_data": "ER20", "over_range": "ER10", "error": None}
"""Replacement faults and the error code each answers (``error``: the fault's own ``code``)."""
_MEAS_KINDS = frozenset({"no_completion", "calculation_error", "late_completion"})


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

    Raises
    ------
    ValueError
        On construction, for a field out of its range or fields that do not go together, naming them.
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
        if self.at == "completion" and self.kind not in WIRE_KINDS | {"error", "over_range"}:
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

    @property
    def error_code(self) -> str:
        """The error code a replacement fault (:data:`REPLY_ERRORS`) answers."""
        return REPLY_ERRORS[self.kind] or self.code

    def matches(self, mnemonic: str, params: Sequence[str]) -> bool:
        """True if this fault is for the command ``mnemonic,params``."""
        if self.command == "*":
            return True
        want_mnemonic, want_params = parse_command(self.command.encode("ascii"))
        if want_mnemonic != mnemonic:
            return False
        return not want_params or [_normal(p) for p in want_params] == [_normal(p) for p in params]


def _normal(param: str) -> str:
    """A parameter compared as a number when it is one (``"01"`` == ``"1"``)."""
    return str(int(param)) if param.isdigit() else param
