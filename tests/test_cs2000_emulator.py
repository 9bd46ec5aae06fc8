"""Tests of the CS-2000 emulator (instruments.cs2000.emulator), through pyserial on its pseudo-terminal and its
TCP socket: replies per the protocol summary, the two-phase MEAS, MEDR against the ground truth, data clearing,
and every injectable fault as seen on the wire; and of its samples scripts (kmpipe.formats.emulator_script)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import serial

from instruments.cs2000.emulator.faults import Fault
from instruments.cs2000.emulator.radiometry import colorimetry, illuminant_spd
from instruments.cs2000.emulator.server import Emulator
from instruments.cs2000.protocol import (
    COLORIMETRIC_BLOCKS,
    COLORIMETRIC_NAMES,
    SPECTRAL_BLOCKS,
    CalculationError,
    Conditions,
    CS2000Error,
    Identity,
    check,
    format_colorimetric,
    parse_colorimetric,
    parse_conditions,
    parse_identity,
    parse_measure_time,
    parse_reply,
    parse_spectral_block,
)
from kmpipe import cli
from kmpipe.errors import InputError
from kmpipe.formats.emulator_script import emulator_from_script, load_emulator_script

SCALE = 0.01  # emulated instrument times x 0.01: a 3 s measurement takes 30 ms
REFLECTANCE = {"white": 0.98, "black": 0.03, "dark": 5e-5, "ramp": np.linspace(0.05, 0.9, 401)}
# at gain 0.01 under D55: white about 70000 cd m-2, black about 2200, dark about 3.6 (15 multi-integration frames)


class Host:
    """The host end: pyserial on a URL, one command and its reply at a time."""

    def __init__(self, url: str, terminator: bytes = b"\r\n", timeout: float = 5.0) -> None:
        self.port = serial.serial_for_url(url, timeout=timeout)
        self.terminator = terminator

    def line(self) -> bytes:
        data = self.port.read_until(self.terminator)
        assert data.endswith(self.terminator), f"no complete line: {data!r}"
        return data

    def ask(self, command: str) -> bytes:
        self.port.write(command.encode("ascii") + self.terminator)
        return self.line()

    def fields(self, command: str) -> tuple[str, ...]:
        return check(parse_reply(self.ask(command)))

    def remote(self) -> None:
        assert self.ask("RMTS,2") == b"OK00" + self.terminator

    def measure(self) -> int:
        """MEAS,1, both replies; the announced time in s."""
        seconds = parse_measure_time(parse_reply(self.ask("MEAS,1")))
        assert self.line() == b"OK00" + self.terminator
        return seconds

    def close(self) -> None:
        self.port.close()


@pytest.fixture
def emulator(tmp_path):
    with Emulator(REFLECTANCE, time_scale=SCALE, link=tmp_path / "cs2000", socket_port=0) as emu:
        yield emu


@pytest.fixture(params=["pty", "socket"])
def host(request, emulator):
    """A host on either transport (pyserial's socket close sleeps 0.3 s, so only some tests use both)."""
    host = Host(emulator.link if request.param == "pty" else emulator.socket_url)
    yield host
    host.close()


@pytest.fixture
def pty_host(emulator):
    host = Host(emulator.link)
    yield host
    host.close()


def expected_radiance(sample: str) -> np.ndarray:
    """Ground truth without noise: D55 x reflectance x gain 0.01, rounded to float32."""
    reflectance = np.broadcast_to(REFLECTANCE[sample], (401,))
    return (illuminant_spd("D55") * reflectance * 0.01).astype(np.float32).astype(np.float64)


def read_spectrum(host: Host, fmt: int) -> np.ndarray:
    return np.concatenate([parse_spectral_block(host.fields(f"MEDR,1,{fmt},{b}"), b, fmt) for b in SPECTRAL_BLOCKS])


def test_example_exchange(host, emulator):
    assert host.ask("IDDR") == b"ER00\r\n"  # not in remote mode yet
    host.remote()
    assert host.ask("IDDR") == b"OK00,CS-2000A ,2,1234567\r\n"
    assert parse_identity(host.fields("IDDR")) == Identity("CS-2000A", 2, "1234567")
    assert host.ask("MSWE,0") == b"OK00\r\n"
    assert host.ask("SPMS,0,2") == b"OK00\r\n"
    assert host.ask("MEDR,1,1,1") == b"ER20\r\n"
    assert host.measure() == emulator.last_measurement.measuring_time
    assert len(host.fields("MEDR,1,1,1")) == 100
    assert len(host.fields("MEDR,1,0,4")) == 101
    assert len(host.fields("MEDR,2,0,1")) == 3
    conditions = parse_conditions(host.fields("MEDR,0,0,1"))
    assert conditions == emulator.last_measurement.conditions
    assert host.ask("SPMS,5") == b"ER17\r\n"
    assert host.ask("FOO") == b"ER00\r\n"
    assert host.ask("RMTS,0") == b"OK00\r\n"
    assert host.ask("IDDR") == b"ER00\r\n"


def test_settings_commands(pty_host):
    pty_host.remote()
    assert pty_host.fields("SPMR") == ("0", "2")
    assert pty_host.ask("SPMS,3,33333") == b"OK00\r\n"
    assert pty_host.fields("SPMR") == ("3", "000033333", "1")
    assert pty_host.ask("SPMS,2,5,2") == b"OK00\r\n"
    assert pty_host.fields("SPMR") == ("2", "05", "2")
    assert pty_host.ask("SPMS,2,17") == b"ER17\r\n"
    assert pty_host.ask("SPMS,3,4999,0") == b"ER17\r\n"
    assert pty_host.ask("SPMS,0,1,1") == b"ER00\r\n"
    assert pty_host.ask("SCMS,1,06000") == b"OK00\r\n"
    assert pty_host.fields("SCMR") == ("1", "06000")
    assert pty_host.ask("SCMS,1,1999") == b"ER17\r\n"
    assert pty_host.ask("SCMS,2") == b"OK00\r\n"
    assert pty_host.fields("SCMR") == ("2",)
    assert pty_host.ask("OBSS,1") == b"OK00\r\n"
    assert pty_host.fields("OBSR") == ("1",)
    assert pty_host.ask("OBSS,2") == b"ER17\r\n"
    assert pty_host.fields("STSR") == ("0",)
    assert pty_host.fields("DTCR") == ("20190401", "093000")
    assert pty_host.ask("MSWE") == b"ER00\r\n"
    assert pty_host.ask("MEAS,0") == b"ER17\r\n"  # nothing to cancel
    assert pty_host.ask("medr,1,1,1") == b"ER00\r\n"


def test_rmts_2_needs_firmware_3_00_9301():
    with Emulator(REFLECTANCE, time_scale=SCALE, firmware="3.00.9300") as emu:
        host = Host(emu.port)
        assert host.ask("RMTS,2") == b"ER17\r\n"
        assert host.ask("RMTS,1") == b"OK00\r\n"
        assert host.ask("IDDR") == b"OK00,CS-2000A ,2,1234567\r\n"
        host.close()


@pytest.mark.parametrize("terminator", [b"\r", b"\n", b"\r\n"])
def test_replies_use_the_command_terminator(emulator, terminator):
    host = Host(emulator.port, terminator)
    assert host.ask("RMTS,1") == b"OK00" + terminator
    assert host.ask("IDDR") == b"OK00,CS-2000A ,2,1234567" + terminator
    seconds = parse_measure_time(parse_reply(host.ask("MEAS,1")))
    assert seconds >= 2
    assert host.line() == b"OK00" + terminator
    host.close()


def test_two_phase_measurement_and_busy_answers(host, emulator):
    host.remote()
    emulator.under_instrument = "dark"
    assert host.ask("SPMS,2,2") == b"OK00\r\n"  # dark sample, multi-integration: 2 + 2 x 15 = 32 s
    first = parse_reply(host.ask("MEAS,1"))
    seconds = parse_measure_time(first)
    assert first.raw == b"OK00,032\r\n"
    with pytest.raises(CS2000Error) as in_progress:
        check(parse_reply(host.ask("IDDR")))
    assert in_progress.value.code == "ER00" and in_progress.value.busy
    assert host.ask("MEDR,1,1,1") == b"ER00\r\n"
    assert host.ask("MEAS,1") == b"ER17\r\n"
    assert host.line() == b"OK00\r\n"  # the unsolicited completion
    measurement = emulator.last_measurement
    assert (measurement.sample, measurement.measuring_time) == ("dark", seconds)
    assert host.ask("IDDR").startswith(b"OK00,")


def test_cancel_during_measurement(pty_host, emulator):
    pty_host.remote()
    emulator.under_instrument = "dark"
    pty_host.ask("SPMS,2,16")
    assert parse_measure_time(parse_reply(pty_host.ask("MEAS,1"))) == 242
    assert pty_host.ask("MEAS,0") == b"OK00\r\n"
    assert pty_host.ask("MEDR,0,0,1") == b"ER20\r\n"
    assert emulator.measurements == []


def test_measuring_time_follows_speed_mode_and_luminance(emulator):
    host = Host(emulator.port)
    host.remote()
    times = {}
    for speed in ("0,2", "1,2", "2,2", "4,2"):
        host.ask(f"SPMS,{speed}")
        for sample in ("white", "dark"):
            emulator.under_instrument = sample
            times[speed, sample] = host.measure()
    assert times["0,2", "white"] == 3  # 2 s + 16 x 5 ms auto integration
    assert times["0,2", "dark"] == 25  # 2 s + 16 x 5 / 3.6 s
    assert (times["2,2", "white"], times["2,2", "dark"]) == (4, 32)  # 1 and 15 frames of 2 s
    assert times["4,2", "dark"] == 17
    assert all(2 <= t <= 242 for t in times.values())
    conditions = emulator.last_measurement.conditions
    assert (conditions.speed, conditions.internal_nd) == (4, 0)
    host.close()


def test_hex_spectrum_is_the_ground_truth_exactly(host, emulator):
    host.remote()
    host.ask("MSWE,0")
    for sample in ("white", "ramp"):
        emulator.under_instrument = sample
        host.measure()
        spectrum = read_spectrum(host, 1)
        np.testing.assert_array_equal(spectrum, emulator.last_measurement.radiance)
        np.testing.assert_array_equal(spectrum, expected_radiance(sample))


def test_decimal_spectrum_to_printed_precision(pty_host, emulator):
    pty_host.remote()
    pty_host.ask("MSWE,0")
    emulator.under_instrument = "ramp"
    pty_host.measure()
    truth = emulator.last_measurement.radiance
    decimal = read_spectrum(pty_host, 0)
    half_unit = 0.5 * 10.0 ** (np.floor(np.log10(np.abs(truth))) - 4)
    assert np.all(np.abs(decimal - truth) <= half_unit * (1 + 1e-9))
    assert not np.array_equal(decimal, truth)  # 5 significant digits, not float32's


def test_colorimetric_values(pty_host, emulator):
    pty_host.remote()
    pty_host.ask("MSWE,0")
    pty_host.measure()
    truth = emulator.last_measurement.colorimetric
    hex_values = parse_colorimetric(pty_host.fields("MEDR,2,1,0"), 0, 1)
    assert hex_values == {n: float(np.float32(truth[n])) for n in COLORIMETRIC_NAMES}
    resolution = {"Lv": 0.5, "x": 5e-5, "y": 5e-5, "u'": 5e-5, "v'": 5e-5, "T": 0.5, "duv": 5e-5, "lambda_d": 0.05}
    for block, names in COLORIMETRIC_BLOCKS.items():
        fields = pty_host.fields(f"MEDR,2,0,{block}")
        assert list(fields) == [format_colorimetric(n, truth[n]) for n in names]
        parsed = parse_colorimetric(fields, block)
        for n in names:
            tolerance = resolution.get(n.removesuffix("_10"), 0.05 if n.startswith("Pe") else 5e-5 * abs(truth[n]))
            assert abs(parsed[n] - truth[n]) <= tolerance * (1 + 1e-9), n
    # physics: D55 on a flat 0.98 white: Lv = Y = 683 sum(L ybar) ~ 70000 cd m-2 at 0.01 gain; CCT of D55
    assert truth["Lv"] == truth["Y"]
    assert 60_000 < truth["Lv"] < 80_000
    assert truth["x"] == pytest.approx(truth["X"] / (truth["X"] + truth["Y"] + truth["Z"]))
    assert truth["T"] == pytest.approx(5503, abs=15)
    assert truth["Le"] == pytest.approx(emulator.last_measurement.radiance.sum())


def test_colorimetry_of_a_black_spectrum_is_sentinels():
    values = colorimetry(np.zeros(401))
    assert values["Le"] == 0.0 and values["X"] == 0.0
    assert all(values[n] is None for n in ("x", "y", "u'", "v'", "T", "duv", "lambda_d", "Pe"))


def test_no_data_before_measuring_and_clearing_with_the_button_enabled(pty_host):
    pty_host.remote()
    assert pty_host.ask("MEDR,1,1,1") == b"ER20\r\n"
    assert pty_host.ask("MEDR,2,0,0") == b"ER20\r\n"
    # panel button enabled (the power-on state): reading all four spectral blocks clears the data
    pty_host.measure()
    assert len(pty_host.fields("MEDR,0,0,1")) == 8  # conditions do not clear
    pty_host.fields("MEDR,1,1,1")
    pty_host.fields("MEDR,1,1,1")  # a re-read before all four are read is still answered
    for block in (2, 3, 4):
        pty_host.fields(f"MEDR,1,1,{block}")
    assert pty_host.ask("MEDR,1,1,1") == b"ER20\r\n"
    # ... and any colorimetric block clears it
    pty_host.measure()
    pty_host.fields("MEDR,2,0,101")
    assert pty_host.ask("MEDR,1,1,1") == b"ER20\r\n"
    # with the button disabled the data stays
    assert pty_host.ask("MSWE,0") == b"OK00\r\n"
    pty_host.measure()
    for _ in range(2):
        read_spectrum(pty_host, 1)
        pty_host.fields("MEDR,2,0,0")
    assert len(pty_host.fields("MEDR,1,0,01")) == 100  # leading zeros dropped or not


def test_sequence_seeded_noise_and_script(tmp_path):
    csv = tmp_path / "reflectance.csv"
    csv.write_text(
        "# kmpipe-spectra: 1\n# quantity: reflectance\n# units: 1\nwavelength_nm,baso4,black\n"
        "380,0.95,0.03\n580,0.98,0.04\n780,0.98,0.05\n"
    )
    script = tmp_path / "samples.toml"
    script.write_text(
        '[samples]\nfile = "reflectance.csv"\nsequence = ["baso4", "black", "baso4", "black"]\n'
        'illuminant = "D55"\ngain = 0.01\nnoise = 0.003\nseed = 1\ntime_scale = 0.01\n'
        '[instrument]\nserial = "7654321"\n'
        '[[faults]]\nkind = "garbage"\ncommand = "IDDR"\noccurrence = 2\ngarbage = "\\u0000\\u00ff"\n'
    )
    runs = []
    for _ in range(2):
        with emulator_from_script(script) as emu:
            host = Host(emu.port)
            host.remote()
            assert host.ask("IDDR") == b"OK00,CS-2000A ,2,7654321\r\n"
            assert host.ask("IDDR") == b"\x00\xffOK00,CS-2000A ,2,7654321\r\n"
            assert host.ask("MSWE,0") == b"OK00\r\n"  # the data stay readable after the spectrum
            for _ in range(5):  # each measurement read out: the operator moves on to the next sample
                host.measure()
                read_spectrum(host, 1)
                host.fields("MEDR,2,0,0")
            runs.append(emu.measurements)
            host.close()
    assert [m.sample for m in runs[0]] == ["baso4", "black", "baso4", "black", "black"]  # the last one stays
    for first, second in zip(*runs, strict=True):
        np.testing.assert_array_equal(first.radiance, second.radiance)  # seeded
    reflectance = np.interp(np.arange(380, 781), [380, 580, 780], [0.95, 0.98, 0.98])
    clean = illuminant_spd("D55") * reflectance * 0.01
    relative = runs[0][0].radiance / clean - 1
    assert 0.002 < relative.std() < 0.004  # noise = 0.003


def test_the_sample_stays_until_its_measurement_was_read_out():
    """A failed MEAS,1 (ER51, ER10) or a measurement read only in part is measured again on the same sample: the
    sequence moves on only after the four spectral blocks and the colorimetric values were read."""
    faults = [Fault("error", "MEAS", occurrence=2, code="ER51"), Fault("over_range", "MEAS", occurrence=3)]
    samples = {"a": 0.2, "b": 0.5, "c": 0.8}
    with Emulator(samples, sequence=["a", "b", "c"], time_scale=0.01, faults=faults) as emu:
        host = Host(emu.port)
        host.remote()
        assert host.ask("MSWE,0") == b"OK00\r\n"
        host.measure()  # a, read out
        read_spectrum(host, 1)
        host.fields("MEDR,2,0,0")
        for code in (b"ER51\r\n", b"ER10\r\n"):  # b fails twice
            host.port.write(b"MEAS,1\r\n")
            assert host.line() == code
        host.measure()  # b, only the spectrum read: the operator has not moved on
        read_spectrum(host, 1)
        host.measure()  # b again, read out
        read_spectrum(host, 1)
        host.fields("MEDR,2,0,101")
        host.measure()  # c
        host.close()
        assert [m.sample for m in emu.measurements] == ["a", "b", "b", "c"]
        assert emu.under_instrument == "c"


def test_a_colorimetry_fault_replaces_the_values_sent():
    fault = Fault("colorimetry", "MEDR,2,0,0", occurrence=1, values={"x": 10.0, "y": 10.0})
    with Emulator({"w": 0.9}, time_scale=0.01, faults=[fault]) as emu:
        host = Host(emu.port)
        host.remote()
        assert host.ask("MSWE,0") == b"OK00\r\n"
        host.measure()
        corrupted = parse_colorimetric(host.fields("MEDR,2,0,0"), 0)
        honest = parse_colorimetric(host.fields("MEDR,2,0,0"), 0)
        truth = emu.last_measurement.colorimetric
        host.close()
    assert (corrupted["x"], corrupted["y"]) == (10.0, 10.0) and corrupted["Lv"] == honest["Lv"]
    assert abs(honest["x"] - truth["x"]) < 1e-4 and abs(honest["y"] - truth["y"]) < 1e-4
    with pytest.raises(ValueError, match="colorimetric names"):
        Fault("colorimetry", "MEDR", values={"q": 1.0})
    with pytest.raises(ValueError, match="applies to MEDR"):
        Fault("colorimetry", "MEAS", values={"x": 1.0})


def test_bad_scripts_are_refused_with_the_file_named(tmp_path):
    script = tmp_path / "samples.toml"
    script.write_text('[samples]\nfile = "missing.csv"\n')
    with pytest.raises(InputError, match=r"line 2: field 'samples\.file': names the file 'missing\.csv', which does"):
        load_emulator_script(script)
    (tmp_path / "r.csv").write_text("wavelength_nm,a\n400,0.5\n700,0.5\n")
    script.write_text('[samples]\nfile = "r.csv"\n')
    with pytest.raises(InputError, match=r"r\.csv: field 'wavelength_nm': .*cover 380-780 nm.*samples\.toml, line 2"):
        load_emulator_script(script)
    (tmp_path / "r.csv").write_text("wavelength_nm,a\n380,0.5\n780,0.5\n")
    script.write_text('[samples]\nfile = "r.csv"\nsequence = ["b"]\n')
    with pytest.raises(InputError, match=r"line 3: field 'samples\.sequence': names unknown sample"):
        emulator_from_script(script)
    script.write_text('[samples]\nfile = "r.csv"\n[faults.slow]\nkind = "delay"\ncommand = "IDDR"\nseconds = 2\n')
    assert load_emulator_script(script)["faults"] == [Fault("delay", "IDDR", seconds=2)]
    script.write_text('[samples]\nfile = "r.csv"\n[faults.slow]\nkind = "delay"\nseconds = -1\n')
    with pytest.raises(InputError, match=r"line 5: field 'faults\.slow\.seconds'"):
        load_emulator_script(script)
    script.write_text('[samples]\nfile = "r.csv"\n[[faults]]\nkind = "explode"\n')
    with pytest.raises(InputError, match=r"line 4: field 'faults\[1\]\.kind': Input should be 'delay'"):
        load_emulator_script(script)
    script.write_text('[samples]\nfile = "r.csv"\n[[faults]]\nkind = "colorimetry"\ncommand = "MEAS"\n')
    with pytest.raises(InputError, match=r"line 3: field 'faults\[1\]': a colorimetry fault applies to MEDR"):
        load_emulator_script(script)
    script.write_text('[samples]\nfile = "r.csv"\ngain = "0.01"\n')  # values as written: no text for a number
    with pytest.raises(InputError, match=r"line 3: field 'samples\.gain'"):
        load_emulator_script(script)
    assert cli.main(["emulate", "--samples", str(tmp_path / "nothing.toml"), "--link", str(tmp_path / "l")]) == 2


@pytest.mark.parametrize(
    ("name", "key"), [("D55", "D55"), ("d65", "D65"), ("F11", "FL11"), ("FL2", "FL2"), ("LED-B3", "LED-B3")]
)
def test_a_script_takes_the_illuminant_names_scenes_and_recipes_take(tmp_path, name, key):
    """The one resolver of illuminant names (kmpipe.physics.colorimetry.illuminant_key): F11 is FL11, case does
    not matter; the emulator's radiance is that illuminant's colour-science table."""
    (tmp_path / "r.csv").write_text("wavelength_nm,a\n380,0.5\n780,0.5\n")
    (tmp_path / "s.toml").write_text(f'[samples]\nfile = "r.csv"\nilluminant = "{name}"\n')
    assert load_emulator_script(tmp_path / "s.toml")["illuminant"] == key
    import colour

    table = colour.SDS_ILLUMINANTS[key]
    relative = np.interp(np.arange(380, 781), table.wavelengths, table.values)
    np.testing.assert_allclose(illuminant_spd(key), relative * 100 / relative[180], rtol=1e-12)


@pytest.mark.parametrize("name", ["F99", "FL", "sunlight", "ISO 7589 Photoflood"])
def test_a_script_refuses_an_unknown_illuminant_naming_the_field(tmp_path, name):
    (tmp_path / "r.csv").write_text("wavelength_nm,a\n380,0.5\n780,0.5\n")
    (tmp_path / "s.toml").write_text(f'[samples]\nfile = "r.csv"\nilluminant = "{name}"\n')
    with pytest.raises(InputError) as err:
        load_emulator_script(tmp_path / "s.toml")
    assert (err.value.path, err.value.line, err.value.field) == (tmp_path / "s.toml", 3, "samples.illuminant")


# ------------------------------------------------------------------------------------------------------ faults


def faulty(*faults: Fault, **kwargs) -> Emulator:
    return Emulator(REFLECTANCE, time_scale=SCALE, socket_port=0, faults=faults, **kwargs)


@pytest.mark.parametrize("transport", ["pty", "socket"])
def test_slow_reply(transport):
    with faulty(Fault("delay", "IDDR", seconds=50)) as emu:  # 50 instrument seconds = 0.5 s
        host = Host(emu.port if transport == "pty" else emu.socket_url, timeout=0.1)
        host.remote()
        host.port.write(b"IDDR\r\n")
        assert host.port.read_until(b"\r\n") == b""
        host.port.timeout = 5
        assert host.line() == b"OK00,CS-2000A ,2,1234567\r\n"
        host.close()


def test_reply_in_chunks():
    with faulty(Fault("chunks", "MEDR,1,1,1", chunk_size=64, seconds=2)) as emu:
        host = Host(emu.socket_url)
        host.remote()
        host.ask("MSWE,0")
        host.measure()
        assert len(host.ask("MEDR,1,1,2")) == 906  # an unaffected block: 5 + 100 x 9 - 1 + 2 bytes
        raw = socket.create_connection(("127.0.0.1", emu.socket_port))  # replaces the pyserial connection
        raw.sendall(b"MEDR,1,1,1\r\n")
        pieces = []
        while not b"".join(pieces).endswith(b"\r\n"):
            pieces.append(raw.recv(4096))
        raw.close()
        reply = b"".join(pieces)
        np.testing.assert_array_equal(
            parse_spectral_block(check(parse_reply(reply)), 1, 1), emu.last_measurement.radiance[:100]
        )
        assert len(pieces) > 2 and max(map(len, pieces)) <= 64


def test_garbage_before_a_reply_is_skipped_by_the_parser():
    with faulty(Fault("garbage", "MEAS", garbage=b"\x00\xfe~")) as emu:
        host = Host(emu.port)
        host.remote()
        first = host.ask("MEAS,1")
        assert first.startswith(b"\x00\xfe~OK00,")
        assert parse_reply(first).skipped == b"\x00\xfe~"
        assert parse_measure_time(parse_reply(first)) == 3
        assert host.line() == b"OK00\r\n"
        host.close()


def test_over_range_on_meas_and_natural_over_range():
    with faulty(Fault("over_range", "MEAS", occurrence=1)) as emu:
        host = Host(emu.port)
        host.remote()
        first = parse_reply(host.ask("MEAS,1"))
        assert first.raw == b"ER10\r\n"
        with pytest.raises(CS2000Error, match="ER10: over range"):
            parse_measure_time(first)
        assert host.ask("MEDR,1,1,1") == b"ER20\r\n"
        assert host.measure() == 3  # the fault fired once
        # a white at 70000 cd m-2 with the internal ND filter off is over the 5000 cd m-2 range
        assert host.ask("SPMS,0,0") == b"OK00\r\n"
        assert host.ask("MEAS,1") == b"ER10\r\n"
        emu.under_instrument = "black"
        assert host.measure() >= 2
        host.close()


def test_error_at_completion():
    with faulty(Fault("error", "MEAS", at="completion", code="ER71")) as emu:
        host = Host(emu.port)
        host.remote()
        assert parse_measure_time(parse_reply(host.ask("MEAS,1"))) == 3
        with pytest.raises(CS2000Error, match="ER71: external sync"):
            check(parse_reply(host.line()))
        assert host.ask("MEDR,0,0,1") == b"ER20\r\n"
        host.close()


def test_busy_and_no_data_faults():
    with faulty(Fault("busy", "IDDR", occurrence=1), Fault("no_data", "MEDR,1,1,3")) as emu:
        host = Host(emu.port)
        host.remote()
        with pytest.raises(CS2000Error) as busy:
            check(parse_reply(host.ask("IDDR")))
        assert busy.value.code == "ER02" and busy.value.busy
        assert host.ask("IDDR").startswith(b"OK00,")
        host.ask("MSWE,0")
        host.measure()
        assert len(host.fields("MEDR,1,1,2")) == 100
        assert host.ask("MEDR,1,1,03") == b"ER20\r\n"
        assert len(host.fields("MEDR,1,1,4")) == 101
        host.close()


def test_missing_completion_then_poll_medr():
    with faulty(Fault("no_completion", "MEAS")) as emu:
        emu.under_instrument = "dark"
        host = Host(emu.port, timeout=0.2)
        host.remote()
        host.ask("SPMS,2,4")  # 2 + 4 x 15 s = 62 s: 0.62 s here
        seconds = parse_measure_time(parse_reply(host.ask("MEAS,1")))
        assert seconds == 62
        assert host.port.read_until(b"\r\n") == b""  # the completion line does not come
        answers = []
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            answers.append(host.ask("MEDR,0,0,1"))
            if answers[-1] != b"ER02\r\n":
                break
            time.sleep(0.1)
        assert answers[0] == b"ER02\r\n"
        assert parse_conditions(check(parse_reply(answers[-1]))) == emu.last_measurement.conditions
        assert host.port.read(10) == b""  # still no stray completion line
        host.close()


def test_disconnect_in_a_spectral_block_over_socket():
    with faulty(Fault("disconnect", "MEDR,1,1,2", occurrence=1)) as emu:
        host = Host(emu.socket_url)
        host.remote()
        host.ask("MSWE,0")
        host.measure()
        host.fields("MEDR,1,1,1")
        host.port.write(b"MEDR,1,1,2\r\n")
        assert host.port.read(100).startswith(b"OK00,")  # half of the 906-byte reply was sent ...
        with pytest.raises(serial.SerialException):
            host.port.read_until(b"\r\n")  # ... then the connection closed
        host.close()
        again = Host(emu.socket_url)  # the instrument is still there
        assert len(again.fields("MEDR,1,1,2")) == 100
        again.close()


def test_disconnect_in_a_spectral_block_over_the_pty(tmp_path):
    link = tmp_path / "cs2000"
    with faulty(Fault("disconnect", "MEDR", occurrence=2), link=link) as emu:
        old_port = emu.port
        host = Host(str(link))
        host.remote()
        host.ask("MSWE,0")
        host.measure()
        host.fields("MEDR,1,1,1")
        host.port.write(b"MEDR,1,1,2\r\n")
        assert host.port.read(100).startswith(b"OK00,")
        with pytest.raises(serial.SerialException):
            host.port.read_until(b"\r\n")
        host.close()
        assert emu.port != old_port and os.readlink(link) == emu.port  # a new device node, like a USB re-plug
        again = Host(str(link))
        np.testing.assert_array_equal(read_spectrum(again, 1), emu.last_measurement.radiance)
        again.close()
    assert not os.path.lexists(link)


@pytest.mark.parametrize(("firmware", "sentinel"), [("3.00.9301", "D1BA43B6"), ("1.01.0000", "0")])
def test_calculation_error_sentinels(firmware, sentinel):
    with faulty(Fault("calculation_error", "MEAS"), firmware=firmware) as emu:
        host = Host(emu.port)
        assert host.ask("RMTS,1") == b"OK00\r\n"
        host.ask("MSWE,0")
        host.measure()
        fields = host.fields("MEDR,1,1,4")
        assert set(fields) == {sentinel}
        with pytest.raises(CalculationError) as error:
            parse_spectral_block(fields, 4, 1)
        assert error.value.wavelengths == tuple(range(680, 781))
        assert parse_colorimetric(host.fields("MEDR,2,0,0"), 0) == dict.fromkeys(COLORIMETRIC_NAMES)
        assert parse_conditions(host.fields("MEDR,0,0,1")).speed == 0
        host.close()


def test_late_completion_after_cancel():
    with faulty(Fault("late_completion", "MEAS", seconds=10)) as emu:
        emu.under_instrument = "dark"
        host = Host(emu.port)
        host.remote()
        host.ask("SPMS,2,16")
        parse_measure_time(parse_reply(host.ask("MEAS,1")))
        assert host.ask("MEAS,0") == b"OK00\r\n"
        assert host.line() == b"OK00\r\n"  # the stray line a driver must drain
        assert host.ask("MEDR,1,1,1") == b"ER20\r\n"
        host.close()


def test_fault_validation():
    with pytest.raises(ValueError, match="fault kind"):
        Fault("meltdown")
    with pytest.raises(ValueError, match="not '\\*', a mnemonic or a command"):
        Fault("delay", "medr")
    with pytest.raises(ValueError, match="cannot apply to the completion"):
        Fault("busy", "MEAS", at="completion")
    with pytest.raises(ValueError, match="occurrence"):
        Fault("busy", occurrence=0)
    assert Fault("busy", "MEDR,1,1,01").matches("MEDR", ("1", "1", "1"))
    assert not Fault("busy", "MEDR,1,1,1").matches("MEDR", ("1", "1", "2"))
    assert Fault("busy", "MEDR").matches("MEDR", ("2", "0", "0"))


# ---------------------------------------------------------------------------------------------------- lifecycle


def test_symlink_lifecycle(tmp_path):
    link = tmp_path / "cs2000"
    link.symlink_to("/nonexistent/stale")  # left by a crashed run: replaced
    emu = Emulator(REFLECTANCE, link=link).start()
    assert os.readlink(link) == emu.port
    emu.stop()
    assert not os.path.lexists(link)
    regular = tmp_path / "file"
    regular.write_text("keep me")
    with pytest.raises(FileExistsError):
        Emulator(REFLECTANCE, link=regular).start()
    assert regular.read_text() == "keep me"


def test_command_line_runs_until_interrupted(tmp_path):
    """``kmpipe emulate``, the emulator's one command line, serves until Ctrl-C and exits 0, removing its link."""
    link = tmp_path / "cs2000"
    root = Path(__file__).resolve().parents[1]
    script = root / "recipes" / "samples" / "F1" / "emulator.toml"
    # Ctrl-C as at a terminal: a test run started in the background by a shell without job control ignores SIGINT,
    # and its children would inherit that.
    process = subprocess.Popen(
        [sys.executable, "-m", "kmpipe", "emulate", "--samples", str(script), "--link", str(link), "--time-scale",
         "0.01"],
        stdout=subprocess.PIPE,
        text=True,
        cwd=root,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    try:
        assert f"(link {link})" in process.stdout.readline()
        host = Host(str(link))
        host.remote()
        assert host.measure() == 3
        host.close()
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=10) == 0
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        process.stdout.close()
    assert not os.path.lexists(link)


def test_manual_integration_conditions_and_aperture():
    with Emulator(REFLECTANCE, time_scale=SCALE, aperture=2) as emu:
        host = Host(emu.port)
        host.remote()
        assert host.fields("STSR") == ("2",)
        host.ask("SPMS,3,100000,0")
        host.ask("SCMS,1,6000")
        emu.under_instrument = "black"
        assert host.measure() == 3  # 2 s + 2 x 0.1 s
        assert parse_conditions(host.fields("MEDR,0,0,1")) == Conditions(3, 1, 100000, 0, 0, 0, 2, 0)
        # a white at 70000 cd m-2 is within the 0.1 deg range (500000 cd m-2) but saturates a 5 s manual integration
        # (limit: range x 0.5 s)
        host.ask("SPMS,3,5000000,0")
        emu.under_instrument = "white"
        assert host.ask("MEAS,1") == b"ER10\r\n"
        host.close()
