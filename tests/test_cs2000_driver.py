"""The CS-2000 driver (instruments.cs2000.driver) against the emulator on a real pseudo-terminal.

References: the emulator's ground truth (``Emulator.last_measurement``: float32 radiance, colorimetric values,
conditions, announced time) and, for what happened on the wire, a session log recorded under the driver
(``instruments.session_log.open_recorded``).
"""

from __future__ import annotations

import numpy as np
import pytest

from instruments.cs2000.driver import CS2000, InstrumentTimeout
from instruments.cs2000.emulator.faults import Fault
from instruments.cs2000.emulator.server import Emulator
from instruments.cs2000.protocol import (
    COLORIMETRIC_NAMES,
    SPECTRAL_BLOCKS,
    WAVELENGTHS,
    CS2000Error,
    check,
    parse_spectral_block,
)
from instruments.session_log import open_recorded, read_session_log

SCALE = 0.01  # emulated instrument seconds x 0.01
SAMPLES = {"white": 0.98, "black": 0.03, "dark": 5e-5, "ramp": np.linspace(0.05, 0.9, 401)}
# at the default gain under D55: white about 70000 cd m-2, dark about 3.6 cd m-2


def emulator(*faults: Fault, sample: str = "ramp", **kwargs) -> Emulator:
    kwargs = {"time_scale": SCALE, "noise": 0.01, "seed": 5} | kwargs
    emu = Emulator(SAMPLES, faults=faults, **kwargs)
    emu.under_instrument = sample
    return emu


class Wire:
    """A driver on the emulator's pseudo-terminal whose every byte is logged, for looking at the exchange."""

    def __init__(self, emu: Emulator, log_path) -> None:
        self.log_path = log_path
        self.driver = CS2000(open_recorded(emu.port, log_path, timeout=0.05))

    def pairs(self) -> list[tuple[bytes, list]]:
        """(bytes written, events until the next write), in order."""
        [connection] = read_session_log(self.log_path)
        out: list[tuple[bytes, list]] = []
        for event in connection.events:
            if event.kind == "tx":
                out.append((event.data, []))
            elif out:
                out[-1][1].append(event)
        return out

    def replies(self, command: bytes) -> list[bytes]:
        """What arrived after each write of ``command``."""
        return [b"".join(e.data for e in events if e.kind == "rx") for tx, events in self.pairs() if tx == command]


@pytest.fixture
def wire(tmp_path):
    """Make a Wire on an emulator with the given faults: ``wire(*faults, sample=..., firmware=...)``."""
    made = []

    def make(*faults: Fault, **kwargs) -> tuple[Emulator, Wire]:
        emu = emulator(*faults, **kwargs).start()
        made.append(emu)
        w = Wire(emu, tmp_path / f"session{len(made)}.jsonl")
        made.append(w.driver)
        return emu, w

    yield make
    for item in reversed(made):
        if isinstance(item, CS2000):
            item.close()
        else:
            item.stop()


def ready(driver: CS2000) -> None:
    """Remote mode with the measure button disabled (data stay readable until the next MEAS)."""
    assert driver.remote(True) == 2
    driver.set_measure_button(False)


def block_slice(block: int) -> slice:
    first, last = SPECTRAL_BLOCKS[block]
    return slice(first - 380, last - 379)


def test_read_spectrum_is_the_ground_truth_exactly(wire):
    emu, w = wire()
    driver = w.driver
    ready(driver)
    assert driver.identity().serial == emu.serial_number
    for sample in ("ramp", "black"):
        emu.under_instrument = sample
        driver.measure()
        radiance = driver.read_spectrum()
        truth = emu.last_measurement.radiance
        assert radiance.shape == WAVELENGTHS.shape
        np.testing.assert_array_equal(radiance, truth)  # hex float32: every bit
        np.testing.assert_array_equal(radiance.astype(np.float32).astype(np.float64), radiance)
    assert w.replies(b"MEDR,1,1,1\r\n")[0].startswith(b"OK00,")  # hexadecimal blocks were asked for


def test_decimal_block_parses_to_the_printed_precision(wire):
    emu, w = wire()
    driver = w.driver
    ready(driver)
    driver.measure()
    truth = emu.last_measurement.radiance
    for block in SPECTRAL_BLOCKS:
        values = parse_spectral_block(check(driver.query("MEDR", 1, 0, block)), block, 0)
        expected = truth[block_slice(block)]
        # the instrument prints 4 decimals and a one-digit exponent (1.2345e-1)
        np.testing.assert_array_equal(values, [float(f"{v:.4e}") for v in expected])
        assert np.max(np.abs(values / expected - 1)) <= 5.0001e-5
    np.testing.assert_array_equal(driver.read_spectrum(), truth)  # reading again: the data are kept (MSWE,0)


def test_measure_returns_the_announced_time(wire):
    emu, w = wire(sample="dark")
    driver = w.driver
    ready(driver)
    driver.set_speed(2, 4)  # multi-integration, 4 s x 15 frames for a dark sample: 62 s announced (0.62 s here)
    calls = []
    announced = driver.measure(progress=lambda elapsed, seconds: calls.append(seconds))
    assert announced == emu.last_measurement.measuring_time == 62
    assert calls and set(calls) == {62}
    assert w.replies(b"MEAS,1\r\n") == [b"OK00,062\r\nOK00\r\n"]
    emu.under_instrument = "white"
    driver.set_speed(0, 2)
    assert driver.measure() == emu.last_measurement.measuring_time


def test_missing_completion_is_handled_by_polling_even_when_busy(wire):
    # no completion line; the first poll is answered "busy"
    emu, w = wire(Fault("no_completion", "MEAS"), Fault("busy", "MEDR,0,0,1", occurrence=1))
    driver = w.driver
    ready(driver)
    assert driver.measure(margin=0.1) == emu.last_measurement.measuring_time
    assert w.replies(b"MEAS,1\r\n") == [b"OK00,003\r\n"]
    polls = w.replies(b"MEDR,0,0,1\r\n")
    assert polls[0] == b"ER02\r\n" and polls[1].startswith(b"OK00,")
    assert [tx for tx, _ in w.pairs()].count(b"MEAS,1\r\n") == 1  # never sent MEAS,1 again
    np.testing.assert_array_equal(driver.read_spectrum(), emu.last_measurement.radiance)
    assert driver.read_conditions() == emu.last_measurement.conditions


def test_polling_tolerates_the_instrument_still_measuring(wire):
    emu, w = wire(Fault("no_completion", "MEAS"), sample="dark")
    driver = w.driver
    ready(driver)
    driver.set_speed(2, 4)  # 62 s: still measuring (0.62 s here) when polled right after the first reply
    assert driver.query("MEAS", 1).fields == ("062",)
    driver.wait_until_idle(10.0)
    polls = w.replies(b"MEDR,0,0,1\r\n")
    assert polls[0] == b"ER02\r\n" and polls[-1].startswith(b"OK00,")
    assert set(polls[:-1]) == {b"ER02\r\n"}
    np.testing.assert_array_equal(driver.read_spectrum(), emu.last_measurement.radiance)


def test_cancel_drains_a_late_completion_line(wire):
    emu, w = wire(Fault("late_completion", "MEAS", seconds=2), sample="dark")  # 20 ms after the reply
    driver = w.driver
    ready(driver)
    driver.set_speed(2, 16)  # 242 s: long enough to cancel
    assert driver.query("MEAS", 1).fields == ("242",)
    driver.cancel()
    assert driver.port.in_waiting == 0
    [cancel] = [events for tx, events in w.pairs() if tx == b"MEAS,0\r\n"]
    drained = b"".join(e.data for e in cancel if e.kind in ("rx", "flush"))
    assert drained == b"OK00\r\nOK00\r\n"  # the reply to MEAS,0 and the stray completion, both discarded
    assert driver.query("MEDR", 1, 1, 1).code == "ER20"  # the measurement was cancelled: no data
    assert emu.measurements == []
    emu.under_instrument = "white"
    driver.set_speed(0, 2)
    assert driver.measure() == emu.last_measurement.measuring_time  # and the next measurement runs normally


@pytest.mark.parametrize(("firmware", "mode"), [("3.00.0100", 1), ("2.10.0000", 1), ("3.00.9301", 2), ("3.10.0000", 2)])
def test_remote_falls_back_to_rmts_1_on_old_firmware(wire, firmware, mode):
    _, w = wire(firmware=firmware)
    driver = w.driver
    assert driver.remote(True) == mode
    expected = [b"RMTS,2\r\n", b"RMTS,1\r\n"] if mode == 1 else [b"RMTS,2\r\n"]
    assert [tx for tx, _ in w.pairs()] == expected
    if mode == 1:
        assert w.replies(b"RMTS,2\r\n") == [b"ER17\r\n"]
    assert driver.identity().model == "CS-2000A"  # remote mode is on
    assert driver.remote(False) == 0
    assert driver.query("IDDR").code == "ER00"  # and off again


def tolerance(name: str) -> dict:
    """Printed precision of a colorimetric value (protocol summary): T an integer, lambda_d and Pe one decimal,
    chromaticities and duv 4 decimals, Le, X, Y, Z 5 significant digits, Lv 6 characters."""
    base = name.removesuffix("_10")
    if base == "T":
        return {"abs": 0.5}
    if base in ("lambda_d", "Pe"):
        return {"abs": 0.05 + 1e-9}
    if base in ("x", "y", "u'", "v'", "duv"):
        return {"abs": 5e-5 + 1e-12}
    return {"rel": 5.0001e-5, "abs": 5e-5}


@pytest.mark.parametrize("sample", ["ramp", "white", "black"])
def test_colorimetry_and_conditions_parse(wire, sample):
    emu, w = wire(sample=sample)
    driver = w.driver
    ready(driver)
    driver.measure()
    colorimetry = driver.read_colorimetry()
    truth = emu.last_measurement.colorimetric
    assert tuple(colorimetry) == COLORIMETRIC_NAMES
    for name in COLORIMETRIC_NAMES:
        if truth[name] is None:
            assert colorimetry[name] is None, name
        else:
            assert colorimetry[name] == pytest.approx(truth[name], **tolerance(name)), name
    assert colorimetry["Lv"] == pytest.approx(colorimetry["Y"], rel=1e-4)
    assert driver.read_conditions() == emu.last_measurement.conditions
    assert driver.read_conditions().speed == 0  # Normal


def test_garbage_chunked_and_slow_replies_are_read_correctly(wire):
    emu, w = wire(
        Fault("garbage", "MEDR,1,1,1"),  # NUL, 0xFE, '~#' before the reply
        Fault("garbage", "MEDR,1,1,2", garbage=b"OK00,3AA1"),  # a fragment of an earlier reply
        Fault("chunks", "MEDR,1,1,3", chunk_size=7, seconds=0.2),  # 130 pieces 2 ms apart
        Fault("delay", "MEDR,1,1,4", seconds=25),  # 0.25 s: beyond the 0.05 s port timeout, within the deadline
        Fault("chunks", "MEAS", chunk_size=2, seconds=0.5),
        Fault("garbage", "MEAS", at="completion", garbage=b"\x00\xff"),
        Fault("delay", "MEAS", at="completion", seconds=10),
    )
    driver = w.driver
    ready(driver)
    assert driver.measure() == emu.last_measurement.measuring_time
    np.testing.assert_array_equal(driver.read_spectrum(), emu.last_measurement.radiance)
    pairs = dict(w.pairs())
    assert sum(e.kind == "rx" for e in pairs[b"MEDR,1,1,3\r\n"]) > 20
    assert sum(e.kind == "timeout" for e in pairs[b"MEDR,1,1,4\r\n"]) >= 2
    assert w.replies(b"MEDR,1,1,1\r\n")[0].startswith(b"\x00\xfe~#OK00,")
    assert w.replies(b"MEAS,1\r\n")[0].endswith(b"\x00\xffOK00\r\n")
    assert driver.read_conditions() == emu.last_measurement.conditions  # nothing left over between replies


def test_error_replies_raise_cs2000error_with_code_and_meaning(wire):
    emu, w = wire(
        Fault("error", "IDDR", code="ER51", occurrence=1),
        Fault("error", "IDDR", code="ER42", occurrence=2),
        Fault("over_range", "MEAS", occurrence=1),
        Fault("error", "MEAS", at="completion", code="ER71", occurrence=2),
    )
    driver = w.driver
    ready(driver)
    with pytest.raises(CS2000Error) as error:
        driver.identity()
    assert (error.value.code, error.value.meaning) == ("ER51", "temperature abnormality")
    assert str(error.value) == "ER51: temperature abnormality" and not error.value.busy
    with pytest.raises(CS2000Error) as error:
        driver.identity()
    assert (error.value.code, error.value.meaning) == ("ER42", "unknown error code")
    with pytest.raises(CS2000Error) as error:
        driver.set_speed(5)
    assert error.value.code == "ER17" and "parameter out of range" in error.value.meaning
    with pytest.raises(CS2000Error) as error:
        driver.measure()  # over range after the pre-measurement: a bare ER10, no time field
    assert (error.value.code, error.value.meaning) == ("ER10", "over range, or flicker too large")
    with pytest.raises(CS2000Error) as error:
        driver.measure()  # the completion line is the error
    assert error.value.code == "ER71" and "external sync" in error.value.meaning
    with pytest.raises(CS2000Error) as error:
        driver.read_spectrum()
    assert error.value.code == "ER20" and error.value.meaning == "no data"
    assert driver.measure() == emu.last_measurement.measuring_time  # the instrument goes on working
    np.testing.assert_array_equal(driver.read_spectrum(), emu.last_measurement.radiance)


def test_a_reply_later_than_the_deadline_raises_instrument_timeout(tmp_path):
    with emulator(Fault("delay", "IDDR", seconds=100)) as emu:  # 1 s late
        driver = CS2000.open(emu.port)
        driver.reply_timeout = 0.3
        try:
            assert driver.remote(True) == 2
            with pytest.raises(InstrumentTimeout, match="no complete reply to IDDR"):
                driver.identity()
        finally:
            driver.close()
