"""How long the emulated CS-2000 takes to measure, and whether a luminance is within its range.

Timing (instrument seconds, before the emulator's ``time_scale``)
-----------------------------------------------------------------
Pre-measurement: 1 s at Lv >= 100 cd m-2, rising by 0.5 s per decade below, at most 3 s. Measuring time NNN
(2-242 s): Normal: 2 + 16 t with auto integration time t = 5 / Lv s (5 ms-15 s); Fast: 2 + 4 t with t = 1 / Lv s;
Multi-integration Normal with S s: 2 + S n where n = ceil(100 / Lv) frames (1-15, so dark samples take longer);
Multi-integration Fast: half that; Manual with t s: 2 + 2 t. Over range (ER10 after the pre-measurement) above the
aperture's limit (5000, 125000 or 500000 cd m-2 for 1, 0.2 or 0.1 deg) times 100 with the internal ND filter (on,
or auto), or in Manual when Lv t exceeds that limit x 0.5 s.
"""

from __future__ import annotations

import math

from instruments.cs2000.protocol import Conditions

LV_LIMIT = {0: 5_000.0, 1: 125_000.0, 2: 500_000.0}
"""Highest luminance (cd m-2) measured without the ND filter, per aperture (``STSR``: 0 = 1 deg, 1 = 0.2 deg,
2 = 0.1 deg)."""
_ND_FACTOR = 100.0


def premeasure_seconds(lv: float) -> float:
    """Pre-measurement time (instrument s) at luminance ``lv`` (cd m-2, > 0):
    min(3, 1 + 0.5 max(0, log10(100 / lv)))."""
    return min(3.0, 1.0 + 0.5 * max(0.0, math.log10(100.0 / lv)))


def exposure(lv: float, speed: tuple[int, int, int], sync_mode: int, aperture: int) -> tuple[Conditions, int, bool]:
    """Conditions, measuring time (instrument s) and over range at luminance ``lv`` (cd m-2, > 0).

    ``speed`` is the ``SPMS`` setting (mode, seconds or microseconds or 0, ND setting 0 off / 1 on / 2 auto),
    ``sync_mode`` the ``SCMS`` mode and ``aperture`` the ``STSR`` value (a key of :data:`LV_LIMIT`).
    """
    mode, value, nd_setting = speed
    limit = LV_LIMIT[aperture]
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
    conditions = Conditions(mode, sync_mode, round(integration * 1e6), nd, 0, 0, aperture, 0)
    return conditions, int(min(max(math.ceil(seconds), 2), 242)), over_range
