"""Tests of the CS-2000 protocol layer (instruments.cs2000.protocol): the summary's example exchange, formats,
sentinels, error codes and malformed input."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from instruments.cs2000.protocol import (
    COLORIMETRIC_BLOCKS,
    COLORIMETRIC_NAMES,
    ERROR_MEANINGS,
    SPECTRAL_BLOCKS,
    CalculationError,
    Conditions,
    CS2000Error,
    Identity,
    ProtocolError,
    Reply,
    check,
    decode_float32_hex,
    decode_float32_hex_fields,
    encode_float32_hex,
    format_colorimetric,
    format_command,
    format_decimal_spectral,
    format_reply,
    parse_colorimetric,
    parse_command,
    parse_conditions,
    parse_identity,
    parse_measure_time,
    parse_reply,
    parse_spectral_block,
    sentinel_text,
)

# The summary's example exchange: (command as the driver formats it, its bytes, the reply line).
EXCHANGE = [
    (("RMTS", 2), b"RMTS,2\r\n", b"OK00\r\n"),
    (("IDDR",), b"IDDR\r\n", b"OK00,CS-2000A ,2,1234567\r\n"),
    (("MSWE", 0), b"MSWE,0\r\n", b"OK00\r\n"),
    (("SPMS", 0, 2), b"SPMS,0,2\r\n", b"OK00\r\n"),
    (("MEDR", 1, 1, 1), b"MEDR,1,1,1\r\n", b"ER20\r\n"),
    (("MEAS", 1), b"MEAS,1\r\n", b"OK00,005\r\n"),
    (("MEDR", 2, 0, 1), b"MEDR,2,0,1\r\n", b"OK00,9.5047e+1,1.0000e+2,1.0888e+2\r\n"),
    (("MEDR", 0, 0, 1), b"MEDR,0,0,1\r\n", b"OK00,0,0,000500000,0,0,0,0,00\r\n"),
    (("SPMS", 5), b"SPMS,5\r\n", b"ER17\r\n"),
    (("RMTS", 0), b"RMTS,0\r\n", b"OK00\r\n"),
]


@pytest.mark.parametrize(("command", "wire", "_reply"), EXCHANGE)
def test_commands_format_as_in_the_example(command, wire, _reply):
    assert format_command(*command) == wire
    assert parse_command(wire) == (command[0], tuple(str(p) for p in command[1:]))


@pytest.mark.parametrize("terminator", [b"\r\n", b"\r", b"\n"])
def test_command_terminators_and_reply_terminators(terminator):
    assert format_command("MEDR", 1, 0, "01", terminator=terminator) == b"MEDR,1,0,01" + terminator
    assert parse_command(b"MEDR,1,0,01" + terminator) == ("MEDR", ("1", "0", "01"))
    reply = parse_reply(b"OK00,005" + terminator)
    assert (reply.code, reply.fields) == ("OK00", ("005",))
    assert format_reply("OK00", "005", terminator=terminator) == b"OK00,005" + terminator


def test_every_reply_of_the_example_parses():
    replies = {wire: parse_reply(line) for _, wire, line in EXCHANGE}
    assert all(r.raw.endswith(b"\r\n") and r.skipped == b"" for r in replies.values())
    assert check(replies[b"RMTS,2\r\n"]) == ()
    assert parse_identity(check(replies[b"IDDR\r\n"])) == Identity("CS-2000A", 2, "1234567")
    assert replies[b"IDDR\r\n"].fields[0] == "CS-2000A "
    assert parse_measure_time(replies[b"MEAS,1\r\n"]) == 5
    assert parse_colorimetric(check(replies[b"MEDR,2,0,1\r\n"]), 1) == {"X": 95.047, "Y": 100.0, "Z": 108.88}
    assert parse_conditions(check(replies[b"MEDR,0,0,1\r\n"])) == Conditions(0, 0, 500000, 0, 0, 0, 0, 0)
    with pytest.raises(CS2000Error) as no_data:
        check(replies[b"MEDR,1,1,1\r\n"])
    assert (no_data.value.code, str(no_data.value)) == ("ER20", "ER20: no data")
    with pytest.raises(CS2000Error, match=r"^ER17: parameter out of range"):
        check(replies[b"SPMS,5\r\n"])
    # the completion line and the reply to an unknown command
    assert parse_reply(b"OK00\r\n") == Reply("OK00", (), b"OK00\r\n")
    assert parse_reply(b"ER00\r\n").code == "ER00"
    assert not parse_reply(b"ER00\r\n").ok


def test_hex_spectral_block_of_the_example():
    values = np.linspace(1.0e-3, 2.0e-3, 100, dtype=np.float32)
    line = format_reply("OK00", *encode_float32_hex(values))
    assert line.startswith(b"OK00,3A83126F,")  # 1e-3 as float32
    radiance = parse_spectral_block(check(parse_reply(line)), 1, 1)
    assert radiance.dtype == np.float64
    np.testing.assert_array_equal(radiance, values.astype(np.float64))
    assert decode_float32_hex("3AA1CEF2") == struct.unpack(">f", bytes.fromhex("3AA1CEF2"))[0]


def test_decimal_spectral_block_4_has_101_values():
    values = np.geomspace(1e-9, 9.9e9, 101)
    fields = [format_decimal_spectral(v) for v in values]
    radiance = parse_spectral_block(fields, 4, 0)
    # 4 decimals of the mantissa: within half a unit of the last printed digit
    ulp = 10.0 ** (np.floor(np.log10(values)) - 4)
    assert np.all(np.abs(radiance - values) <= 0.5 * ulp * (1 + 1e-9))
    with pytest.raises(ProtocolError, match="expected 101 fields, got 100"):
        parse_spectral_block(fields[:100], 4, 0)
    with pytest.raises(ProtocolError, match="expected 100 fields, got 101"):
        parse_spectral_block(fields, 1, 0)


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (1.2345e-3, "1.2345e-3"),
        (95.047, "9.5047e+1"),
        (100.0, "1.0000e+2"),
        (108.88, "1.0888e+2"),
        (0.0, "0.0000e+0"),
        (-3.0e-5, "-3.0000e-5"),
        (9.99996e-1, "1.0000e+0"),  # rounding carries into the exponent
        (1e-12, "0.0000e+0"),  # below the one-digit exponent
    ],
)
def test_decimal_spectral_format(value, text):
    assert format_decimal_spectral(value) == text


def test_decimal_spectral_format_refuses_what_it_cannot_write():
    for value in (1e10, math.inf, math.nan):
        with pytest.raises(ValueError):
            format_decimal_spectral(value)


@given(st.floats(width=32, allow_nan=False, allow_infinity=False, allow_subnormal=True))
def test_hex_float32_round_trip_is_exact(value):
    (text,) = encode_float32_hex(value)
    assert len(text) == 8 and text == text.upper()
    decoded = decode_float32_hex(text)
    assert decoded == value
    assert math.copysign(1.0, decoded) == math.copysign(1.0, value)  # signed zero survives
    assert text == struct.pack(">f", value).hex().upper()


@given(st.lists(st.floats(width=32, allow_nan=False, allow_infinity=False), min_size=1, max_size=50))
def test_hex_float32_fields_round_trip_is_exact(values):
    np.testing.assert_array_equal(decode_float32_hex_fields(encode_float32_hex(values)), np.array(values))


def test_hex_encoding_refuses_non_float32_values():
    assert encode_float32_hex([0.0, 1.0, 5e-45]) == ["00000000", "3F800000", "00000004"]
    for bad in (math.nan, math.inf, 1e39):
        with pytest.raises(ValueError):
            encode_float32_hex([1.0, bad])
    for text in ("3F80000", "3F8000000", "3F80000G", " 3F80000"):
        with pytest.raises(ProtocolError, match="8 hexadecimal characters"):
            decode_float32_hex(text)


@pytest.mark.parametrize("fmt", [0, 1])
@pytest.mark.parametrize("firmware_1_01", [False, True])
def test_spectral_sentinels_raise_naming_the_wavelengths(fmt, firmware_1_01):
    values = np.full(100, 0.25)  # exact in both formats
    fields = encode_float32_hex(values) if fmt else [format_decimal_spectral(v) for v in values]
    for i in (0, 1, 2, 40):  # 580, 581, 582, 620 nm in block 3
        fields[i] = sentinel_text(fmt, firmware_1_01=firmware_1_01)
    with pytest.raises(CalculationError) as error:
        parse_spectral_block(fields, 3, fmt)
    assert error.value.wavelengths == (580, 581, 582, 620)
    assert str(error.value) == "calculation error (sentinel values) at 580-582, 620 nm"
    assert error.value.code is None and not error.value.busy
    assert np.isnan(error.value.values[[0, 1, 2, 40]]).all()
    np.testing.assert_array_equal(np.delete(error.value.values, [0, 1, 2, 40]), np.delete(values, [0, 1, 2, 40]))


@pytest.mark.parametrize(
    "text",
    [
        "-9.9999e9",
        "-9.9999E+09",
        "-9.9999e+9",
        "D1BA43B6",  # as the summary spells it: decodes to -9.999999e10
        "D0150297",  # float32(-9.9999e9)
        "d1ba43b6",
    ],
)
def test_spectral_sentinel_spellings(text):
    fmt = 0 if "e" in text.lower() and "." in text else 1
    fields = ["3A83126F" if fmt else "1.0000e-3"] * 100
    fields[99] = text
    with pytest.raises(CalculationError) as error:
        parse_spectral_block(fields, 2, fmt)
    assert error.value.wavelengths == (579,)


def test_hex_zero_and_decimal_zero_are_not_sentinels():
    # firmware 1.01.0000's sentinel is a bare "0"; a genuine zero is "0.0000e+0" (decimal) or "00000000" (hex)
    assert parse_spectral_block(["0.0000e+0"] * 100, 1, 0).tolist() == [0.0] * 100
    assert parse_spectral_block(["00000000"] * 100, 1, 1).tolist() == [0.0] * 100


def test_colorimetric_block_0_with_every_sentinel():
    sentinels = {
        "Le": "-9.9999e9", "Lv": "-9.9e9", "X": "-9.9999e9", "Y": "-9.9999e9", "Z": "-9.9999e9",
        "x": "-9.999", "y": "-9.999", "u'": "-9.999", "v'": "-9.999", "T": "-9999", "duv": "-9.9999",
        "lambda_d": "-9.9e9", "Pe": "-9.9e9",
    }  # fmt: skip
    fields = [sentinels[name.removesuffix("_10")] for name in COLORIMETRIC_NAMES]
    assert parse_colorimetric(fields, 0) == dict.fromkeys(COLORIMETRIC_NAMES)
    assert parse_colorimetric(["0"] * 24, 0) == dict.fromkeys(COLORIMETRIC_NAMES)  # firmware 1.01.0000
    assert parse_colorimetric(["0"] * 24, 0, 1) == dict.fromkeys(COLORIMETRIC_NAMES)
    assert [format_colorimetric(n, None) for n in COLORIMETRIC_NAMES] == fields
    hex_fields = [format_colorimetric(n, None, 1) for n in COLORIMETRIC_NAMES]
    assert parse_colorimetric(hex_fields, 0, 1) == dict.fromkeys(COLORIMETRIC_NAMES)


def test_colorimetric_values_round_trip_to_printed_precision():
    values = {
        "Le": 0.48213, "Lv": 152.31, "X": 145.23, "Y": 152.31, "Z": 160.77, "x": 0.31812, "y": 0.33361,
        "u'": 0.19893, "v'": 0.46936, "T": 6204.4, "duv": -0.00213, "lambda_d": -531.26, "Pe": 2.341,
    }  # fmt: skip
    values |= {f"{k}_10": v for k, v in values.items() if k not in ("Le", "Lv")}
    fields = [format_colorimetric(name, values[name]) for name in COLORIMETRIC_NAMES]
    assert fields[:13] == [
        "4.8213e-1", "152.31", "1.4523e+2", "1.5231e+2", "1.6077e+2", "0.3181", "0.3336", "0.1989", "0.4694",
        "6204", "-0.0021", "-531.3", "2.3",
    ]  # fmt: skip
    parsed = parse_colorimetric(format_reply("OK00", *fields).decode().strip().split(",")[1:], 0)
    resolution = {"x": 5e-5, "y": 5e-5, "u'": 5e-5, "v'": 5e-5, "duv": 5e-5, "T": 0.5, "lambda_d": 0.05, "Pe": 0.05}
    for name, value in values.items():
        base = name.removesuffix("_10")
        tolerance = resolution.get(base, abs(value) * 5e-5)
        assert abs(parsed[name] - value) <= tolerance * (1 + 1e-9), name
    hex_parsed = parse_colorimetric([format_colorimetric(n, values[n], 1) for n in COLORIMETRIC_NAMES], 0, 1)
    assert hex_parsed == {n: float(np.float32(values[n])) for n in COLORIMETRIC_NAMES}


@pytest.mark.parametrize(("block", "names"), sorted(COLORIMETRIC_BLOCKS.items()))
def test_colorimetric_blocks_check_their_counts(block, names):
    assert list(parse_colorimetric(["1.0"] * len(names), block)) == list(names)
    with pytest.raises(ProtocolError, match=f"colorimetric block {block}: expected {len(names)} fields"):
        parse_colorimetric(["1.0"] * (len(names) + 1), block)


def test_lv_is_six_characters_wide():
    assert [format_colorimetric("Lv", v) for v in (0.0123, 1.2345, 12.345, 123.45, 1234.5, 123456.0)] == [
        "0.0123", "1.2345", "12.345", "123.45", "1234.5", "123456",
    ]  # fmt: skip


@pytest.mark.parametrize("code", sorted(ERROR_MEANINGS))
def test_each_error_code_maps_to_its_meaning(code):
    reply = parse_reply(format_reply(code))
    with pytest.raises(CS2000Error) as error:
        check(reply)
    assert error.value.code == code
    assert error.value.meaning == ERROR_MEANINGS[code]
    assert str(error.value) == f"{code}: {ERROR_MEANINGS[code]}"
    assert error.value.busy == (code in ("ER00", "ER02", "ER17"))


def test_error_meanings_cover_the_summary_table():
    assert sorted(ERROR_MEANINGS) == [
        "ER00", "ER02", "ER05", "ER10", "ER17", "ER20", "ER30", "ER32", "ER34",
        "ER51", "ER52", "ER71", "ER81", "ER82", "ER83", "ER84", "ER99",
    ]  # fmt: skip
    assert ERROR_MEANINGS["ER10"] == "over range, or flicker too large"
    assert str(CS2000Error("ER42")) == "ER42: unknown error code"


def test_first_meas_reply_error_is_raised_before_the_time():
    with pytest.raises(CS2000Error, match=r"^ER10: over range"):
        parse_measure_time(parse_reply(b"ER10\r\n"))
    with pytest.raises(CS2000Error, match=r"^ER10"):
        parse_measure_time(parse_reply(b"ER10,005\r\n"))
    assert parse_measure_time(parse_reply(b"OK00,242\r\n")) == 242
    with pytest.raises(ProtocolError, match="expected 1 fields, got 0"):
        parse_measure_time(parse_reply(b"OK00\r\n"))
    with pytest.raises(ProtocolError, match="not an unsigned integer"):
        parse_measure_time(parse_reply(b"OK00,5s\r\n"))


@pytest.mark.parametrize(
    ("line", "skipped"),
    [
        (b"\x00OK00,005\r\n", b"\x00"),
        (b"\xff\xfe~#OK00,005\r\n", b"\xff\xfe~#"),
        (b"OK00,3AA1OK00,005\r\n", b"OK00,3AA1"),  # fragment of an earlier reply
        (b"ER0OK00,005\n", b"ER0"),
        (b"noise\r\nOK00,005\r", b"noise\r\n"),
        (b"ER00OK00,005", b"ER00"),
    ],
)
def test_garbage_before_a_reply_is_tolerated(line, skipped):
    reply = parse_reply(line)
    assert (reply.code, reply.fields, reply.skipped, reply.raw) == ("OK00", ("005",), skipped, line)


@pytest.mark.parametrize(
    ("line", "message"),
    [
        (b"", "no reply code"),
        (b"\r\n", "no reply code"),
        (b"HELLO\r\n", "no reply code"),
        (b"OK0\r\n", "no reply code"),
        (b"OK005\r\n", "no reply code"),
        (b"ok00\r\n", "no reply code"),
        (b"OK00,12\x0034\r\n", "control character"),
        (b"OK00,1\r2\r\n", "control character"),
        (b"OK00,\xe9\r\n", "non-ASCII"),
    ],
)
def test_malformed_replies_raise_a_clear_error(line, message):
    with pytest.raises(ProtocolError, match=message):
        parse_reply(line)


def test_malformed_fields_raise_a_clear_error():
    with pytest.raises(ProtocolError, match="IDDR reply: expected 3 fields, got 2"):
        parse_identity(["CS-2000A ", "2"])
    with pytest.raises(ProtocolError, match="variant 3"):
        parse_identity(["CS-2000A ", "3", "1234567"])
    with pytest.raises(ProtocolError, match="not 7 digits"):
        parse_identity(["CS-2000A ", "2", "123456"])
    with pytest.raises(ProtocolError, match="conditions, integration_us: 'x' is not an unsigned integer"):
        parse_conditions(["0", "0", "x", "0", "0", "0", "0", "00"])
    with pytest.raises(ProtocolError, match="'nan' is not a decimal number"):
        parse_spectral_block(["nan"] * 100, 1, 0)
    with pytest.raises(ProtocolError, match="not a finite float32"):
        parse_spectral_block(["7FC00000"] * 100, 1, 1)
    with pytest.raises(ValueError, match="spectral block 5"):
        parse_spectral_block([], 5, 1)
    assert sorted(SPECTRAL_BLOCKS) == [1, 2, 3, 4]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("meas", 1), "four upper-case letters"),
        (("MEASURE", 1), "four upper-case letters"),
        (("MEAS", "1,2"), "comma"),
        (("MEAS", "1\r"), "comma, CR, LF"),
        (("MEAS", ""), "empty"),
        (("MEAS", -1), "negative"),
        (("MEAS", True), "not an integer"),
        (("MEAS", 1.0), "not an integer"),
    ],
)
def test_bad_commands_are_refused(args, message):
    with pytest.raises(ValueError, match=message):
        format_command(*args)


@pytest.mark.parametrize("line", [b"meas,1\r\n", b"MEAS,,1\r\n", b"MEAS,\x011\r\n", b"ME\xffS\r\n", b"\r\n"])
def test_instrument_side_refuses_bad_command_lines(line):
    with pytest.raises(ProtocolError):
        parse_command(line)


def test_reply_formatting_refuses_bad_fields():
    with pytest.raises(ValueError):
        format_reply("OK00", "1,2")
    with pytest.raises(ValueError):
        format_reply("OKAY")
    with pytest.raises(ValueError):
        format_reply("OK00", terminator=b"\n\r")
