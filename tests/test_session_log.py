"""Session logs: recording a serial conversation byte for byte, and replaying it through ``replay://``."""

import json
import os
import select
import threading
import time

import pytest
import serial
from serial.serialutil import SerialBase, SerialException

import instruments.urlhandler
from instruments.session_log import (
    RecordingSerial,
    SessionLog,
    SessionLogError,
    decode_bytes,
    encode_bytes,
    open_recorded,
    read_session_log,
)
from instruments.urlhandler import protocol_replay
from instruments.urlhandler.protocol_replay import ReplayMismatch, ReplayWarning

BINARY = bytes(range(256))
STALE = b"OK00\r\n"  # a late completion line, discarded before the next command


class PtyInstrument:
    """A scripted instrument on the master side of a pseudo-terminal; the host opens ``port_name``.

    Script steps, run in order by a thread: ``("expect", bytes)`` reads exactly those bytes from the host,
    ``("send", bytes)`` answers, ``("cue", n)`` waits until the host has called :meth:`cue` n + 1 times.
    """

    def __init__(self, script):
        self.master, self._slave = os.openpty()
        self.port_name = os.ttyname(self._slave)
        self.errors = []
        self._script = script
        self._cues = [threading.Event() for step in script if step[0] == "cue"]
        self._cued = 0
        self._thread = threading.Thread(target=self._run, daemon=True)

    def cue(self):
        """Let the instrument go on past its next ``cue`` step."""
        self._cues[self._cued].set()
        self._cued += 1

    def _read_exactly(self, size):
        data = b""
        while len(data) < size:
            ready, _, _ = select.select([self.master], [], [], 5.0)
            if not ready:
                raise TimeoutError(f"the host sent only {data!r}")
            data += os.read(self.master, size - len(data))
        return data

    def _run(self):
        try:
            for action, value in self._script:
                if action == "expect":
                    got = self._read_exactly(len(value))
                    if got != value:
                        self.errors.append(f"expected {value!r}, got {got!r}")
                elif action == "send":
                    os.write(self.master, value)
                elif not self._cues[value].wait(5.0):
                    self.errors.append(f"cue {value} never came")
        except (OSError, TimeoutError) as err:
            self.errors.append(repr(err))

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc_info):
        self._thread.join(5.0)
        os.close(self.master)
        os.close(self._slave)


SCRIPT = [
    ("expect", b"RMTS,2\r\n"),
    ("send", b"OK00\r\n"),
    ("expect", b"MEDR,1,1,1\r\n"),
    ("send", b"OK00,3AA1"),
    ("cue", 0),
    ("send", b"CEF2\r\n"),
    ("expect", b"FOO\r\n"),  # no answer: the host's read times out
    ("expect", b"MEAS,0\r\n"),
    ("send", b"OK00\r\n"),
    ("cue", 1),
    ("send", STALE),
    ("expect", BINARY),
    ("send", BINARY[::-1]),
    ("expect", b"RMTS,0\r\n"),
    ("send", b"OK00\r\n"),
]
EXPECTED_REPLIES = [b"OK00\r\n", b"OK00,3AA1", b"CEF2\r\n", b"", b"OK00\r\n", BINARY[::-1], b"OK00\r\n"]


def conversation(port, cue, medr=b"MEDR,1,1,1\r\n"):
    """A driver's session with the scripted instrument; returns what every read returned.

    ``cue`` lets the live instrument send its next part (a no-op in a replay); ``medr`` is the block request.
    """
    replies = []
    port.write(b"RMTS,2\r\n")
    replies.append(port.read_until(b"\r\n"))
    port.write(medr)
    replies.append(port.read(9))  # the first part of a reply that arrives in two chunks
    cue()
    replies.append(port.read_until(b"\r\n"))
    port.write(b"FOO\r\n")
    port.timeout = 0.1
    replies.append(port.read(4))  # the instrument keeps silent
    port.timeout = 2.0
    port.write(b"MEAS,0\r\n")
    replies.append(port.read_until(b"\r\n"))
    cue()
    deadline = time.monotonic() + 5.0
    while port.in_waiting < len(STALE) and time.monotonic() < deadline:
        time.sleep(0.005)
    port.reset_input_buffer()
    port.write(BINARY)
    replies.append(port.read(len(BINARY)))
    port.write(b"RMTS,0\r\n")
    replies.append(port.read_until(b"\r\n"))
    port.close()
    return replies


def no_cue():
    """Nothing to cue in a replay."""


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """(log path, replies) of the conversation recorded against the pty instrument."""
    log_path = tmp_path_factory.mktemp("session") / "session.jsonl"
    with PtyInstrument(SCRIPT) as instrument:
        port = open_recorded(instrument.port_name, log_path, meta={"sample": "demo"}, timeout=2.0)
        replies = conversation(port, instrument.cue)
    assert instrument.errors == []
    return log_path, replies


def replay(log_path, options="", timeout=2.0):
    return serial.serial_for_url(f"replay://{log_path}{options}", timeout=timeout)


def follow(port, events):
    """Do what a recorded connection shows, checking that every read returns exactly one recorded chunk."""
    for event in events:
        if event.kind == "tx":
            assert port.write(event.data) == len(event.data)
        elif event.kind == "rx":
            assert port.in_waiting == len(event.data)
            assert port.read(4096) == event.data
        elif event.kind == "timeout":
            assert port.read(4096) == b""
        elif event.kind == "flush":
            assert port.in_waiting == len(event.data)
            port.reset_input_buffer()
        else:
            port.close()


def handwritten(path, *events):
    """Write a session log with one connection and the given event entries."""
    header = {
        "kmpipe_session_log": 1,
        "port": "loop://",
        "started": "2025-01-01T00:00:00.000Z",
        "resumed": False,
        "meta": {},
    }
    path.write_text("".join(json.dumps(entry) + "\n" for entry in (header, *events)), encoding="ascii")
    return path


# -- recording -------------------------------------------------------------------------------------------------


def test_recording_passes_the_replies_through(recorded):
    _, replies = recorded
    assert replies == EXPECTED_REPLIES


def test_log_holds_every_byte_and_event_in_order(recorded):
    log_path, _ = recorded
    [connection] = read_session_log(log_path)
    assert connection.line == 1
    assert connection.header["kmpipe_session_log"] == 1
    assert connection.header["resumed"] is False
    assert connection.header["meta"] == {"sample": "demo"}
    assert connection.header["started"].endswith("Z")
    events = connection.events
    kinds = [event.kind for event in events]
    assert kinds.count("timeout") == 1 and kinds.count("flush") == 1 and kinds[-1] == "close"
    assert b"".join(e.data for e in events if e.kind == "tx") == (
        b"RMTS,2\r\nMEDR,1,1,1\r\nFOO\r\nMEAS,0\r\n" + BINARY + b"RMTS,0\r\n"
    )
    assert b"".join(e.data for e in events if e.kind == "rx") == b"".join(EXPECTED_REPLIES)
    assert b"OK00,3AA1" in [e.data for e in events if e.kind == "rx"]  # the first chunk of the split reply
    timeout = events[kinds.index("timeout")]
    assert events[kinds.index("timeout") - 1].data == b"FOO\r\n"
    assert timeout.waited > 0.05  # it blocked for the 0.1 s port timeout
    assert events[kinds.index("flush")].data == STALE
    assert [e.t for e in events] == sorted(e.t for e in events)
    flush_line = log_path.read_text(encoding="ascii").splitlines()[events[kinds.index("flush")].line - 1]
    assert json.loads(flush_line) == {
        "t": pytest.approx(events[kinds.index("flush")].t),
        "dir": "flush",
        "data": "OK00\r\n",
        "unread": 0,
    }


def test_log_lines_are_readable_ascii_and_exact_for_all_bytes(tmp_path):
    path = tmp_path / "bytes.jsonl"
    with SessionLog(path, port="loop://") as log:
        log.record("rx", BINARY)
        log.record("tx", b"IDDR\r\n")
    text = path.read_text(encoding="ascii")
    lines = text.splitlines()
    assert all(" " <= char <= "~" for char in text.replace("\n", ""))
    assert "\\u0000" in lines[1] and "\\u007f" in lines[1] and "\\u00ff" in lines[1]
    assert '"data": "IDDR\\r\\n"' in lines[2]
    [connection] = read_session_log(path)
    assert [e.data for e in connection.events] == [BINARY, b"IDDR\r\n"]
    assert decode_bytes(encode_bytes(BINARY)) == BINARY


def test_bytes_are_on_disk_before_they_are_sent_or_returned(tmp_path):
    path = tmp_path / "loop.jsonl"

    def last_entry():
        return json.loads(path.read_text(encoding="ascii").splitlines()[-1])

    port = open_recorded("loop://", path, timeout=0.5)
    original_write = port.serial_port.write
    seen_at_send = []
    port.serial_port.write = lambda data: seen_at_send.append(last_entry()) or original_write(data)
    port.write(b"PING\r\n")
    assert seen_at_send == [{"t": pytest.approx(seen_at_send[0]["t"]), "dir": "tx", "data": "PING\r\n"}]
    assert port.read_until(b"\r\n") == b"PING\r\n"
    assert last_entry()["dir"] == "rx" and last_entry()["data"] == "PING\r\n"
    port.close()
    assert last_entry()["dir"] == "close"
    assert port.log.closed


def test_settings_changed_on_the_recorder_reach_the_port(tmp_path):
    port = open_recorded("loop://", tmp_path / "s.jsonl", timeout=0.5)
    assert port.timeout == 0.5 and port.port == "loop://"
    port.timeout = 0.1
    port.baudrate = 115200
    assert (port.serial_port.timeout, port.serial_port.baudrate) == (0.1, 115200)
    port.close()
    with pytest.raises(SerialException, match="new SessionLog"):
        port.open()


def test_modem_lines_and_output_calls_reach_the_port(tmp_path):
    port = open_recorded("loop://", tmp_path / "s.jsonl", timeout=0.5)
    loop = port.serial_port
    port.rts = False
    port.dtr = False
    port.break_condition = True
    assert (loop.rts, loop.dtr, loop.break_condition) == (False, False, True)
    assert (port.cts, port.dsr, port.ri, port.cd) == (loop.cts, loop.dsr, loop.ri, loop.cd)
    port.write(b"X")
    port.flush()
    port.reset_output_buffer()
    assert port.out_waiting == 0
    port.close()


def test_fsync_option_syncs_every_line(tmp_path, monkeypatch):
    synced = []
    monkeypatch.setattr(os, "fsync", synced.append)
    with SessionLog(tmp_path / "s.jsonl", port="loop://", fsync=True) as log:
        log.record("tx", b"A")
    assert len(synced) == 2  # the header and the event


def test_flush_logs_unread_bytes_and_replays_them(tmp_path):
    path = tmp_path / "unread.jsonl"
    port = open_recorded("loop://", path, timeout=0.5)
    port.write(b"AB\nCD\n")
    assert port.read_until(b"\n") == b"AB\n"  # "CD\n" came in the same chunk and stays unread
    assert port.in_waiting == 3
    port.reset_input_buffer()
    assert port.in_waiting == 0
    port.close()
    [connection] = read_session_log(path)
    assert [(e.kind, e.data) for e in connection.events] == [
        ("tx", b"AB\nCD\n"),
        ("rx", b"AB\nCD\n"),
        ("flush", b""),
        ("close", b""),
    ]
    assert json.loads(path.read_text(encoding="ascii").splitlines()[3])["unread"] == 3
    again = replay(path)
    again.write(b"AB\nCD\n")
    assert again.read_until(b"\n") == b"AB\n"
    assert again.in_waiting == 3
    again.reset_input_buffer()
    again.close()
    assert again.done()


class TrickleInstrument(SerialBase):
    """A slow link: answers every write with ``reply``, one byte per read, each byte taking 0.1 s of ``clock``."""

    def __init__(self, reply, clock, **kwargs):
        self._reply, self._clock, self._pending = reply, clock, b""
        super().__init__(port="trickle", **kwargs)

    def open(self):
        self.is_open = True

    def close(self):
        self.is_open = False

    def _reconfigure_port(self):
        """No settings."""

    @property
    def in_waiting(self):
        return 0  # nothing has fully arrived until the next read waits for it

    def write(self, data):
        self._pending += self._reply
        return len(data)

    def read(self, size=1):
        if not self._pending:
            return b""
        self._clock.now += 0.1
        data, self._pending = self._pending[:1], self._pending[1:]
        return data


class FakeClock:
    """A monotonic clock that only moves when something sleeps (or is told to)."""

    def __init__(self):
        self.now = 1000.0
        self.sleeps = []

    def monotonic(self):
        return self.now

    def sleep(self, seconds):
        self.sleeps.append(seconds)
        self.now += seconds


def test_read_until_deadline_is_recorded_and_replayed(tmp_path, monkeypatch):
    clock = FakeClock()
    monkeypatch.setattr(serial.serialutil.Timeout, "TIME", staticmethod(clock.monotonic))
    path = tmp_path / "trickle.jsonl"
    port = RecordingSerial(TrickleInstrument(b"OK00,123\r\n", clock, timeout=0.35), SessionLog(path, port="trickle"))
    port.write(b"SPMR\r\n")
    parts = [port.read_until(b"\r\n") for _ in range(3)]
    assert parts == [b"OK00", b",123", b"\r\n"]  # pyserial's 0.35 s deadline cut the line after 4 bytes
    port.close()
    [connection] = read_session_log(path)
    deadlines = [e for e in connection.events if e.kind == "timeout"]
    assert [e.waited for e in deadlines] == [0.0, 0.0]
    assert all(json.loads(path.read_text(encoding="ascii").splitlines()[e.line - 1])["deadline"] for e in deadlines)
    monkeypatch.undo()
    again = replay(path)
    again.write(b"SPMR\r\n")
    assert [again.read_until(b"\r\n") for _ in range(3)] == parts
    again.close()
    again.assert_complete()


# -- replay ----------------------------------------------------------------------------------------------------


def test_replay_gives_the_driver_the_same_replies(recorded):
    log_path, replies = recorded
    port = replay(log_path)
    assert port.header["meta"] == {"sample": "demo"}
    assert conversation(port, no_cue) == replies
    assert port.done()
    port.assert_complete()


def test_replay_reads_come_back_in_the_recorded_chunks(recorded):
    log_path, _ = recorded
    [connection] = read_session_log(log_path)
    port = replay(log_path)
    follow(port, connection.events)
    assert port.done()


def test_fast_replay_never_sleeps(recorded, monkeypatch):
    log_path, _ = recorded

    def forbidden(seconds):
        raise AssertionError(f"slept {seconds} s")

    monkeypatch.setattr(time, "sleep", forbidden)
    port = replay(log_path, "?timing=fast")
    assert conversation(port, no_cue) == EXPECTED_REPLIES
    port.assert_complete()


def test_real_timing_sleeps_the_recorded_gaps(tmp_path, monkeypatch):
    path = handwritten(
        tmp_path / "gaps.jsonl",
        {"t": 0.1, "dir": "tx", "data": "MEAS,1\r\n"},
        {"t": 0.6, "dir": "rx", "data": "OK00,"},
        {"t": 0.9, "dir": "rx", "data": "005\r\n"},
        {"t": 1.9, "dir": "timeout", "waited": 1.0},
        {"t": 2.0, "dir": "tx", "data": "MEDR,2,0,1\r\n"},
        {"t": 2.25, "dir": "rx", "data": "OK00,1\r\n"},
        {"t": 2.5, "dir": "close"},
    )
    clock = FakeClock()
    monkeypatch.setattr(protocol_replay, "time", clock)
    port = replay(path, "?timing=real", timeout=0.2)
    assert port.read(10) == b""  # nothing arrives before the command: the port's 0.2 s timeout
    port.write(b"MEAS,1\r\n")
    assert port.in_waiting == 0  # the reply is due 0.5 s after the command
    assert port.read_until(b"\r\n") == b"OK00,005\r\n"
    assert port.read(10) == b""
    clock.now += 0.05  # the driver works for 0.05 s before its next command
    port.write(b"MEDR,2,0,1\r\n")
    clock.now += 0.3  # ... and 0.3 s before it reads: the reply is already there
    assert port.in_waiting == 8
    assert port.read(10) == b"OK00,1\r\n"
    port.close()
    port.assert_complete()
    assert clock.sleeps == pytest.approx([0.2, 0.5, 0.3, 1.0])
    assert sum(clock.sleeps[1:]) == pytest.approx((0.6 - 0.1) + (0.9 - 0.6) + 1.0)


def test_strict_replay_names_the_line_and_both_byte_strings(recorded):
    log_path, _ = recorded
    [connection] = read_session_log(log_path)
    medr = next(e for e in connection.events if e.data == b"MEDR,1,1,1\r\n")
    port = replay(log_path)
    with pytest.raises(ReplayMismatch) as caught:
        conversation(port, no_cue, medr=b"MEDR,1,1,2\r\n")
    message = str(caught.value)
    assert f"{log_path}:{medr.line}" in message
    assert repr(b"MEDR,1,1,2\r\n") in message and repr(b"MEDR,1,1,1\r\n") in message
    assert "byte 9" in message
    assert not port.done()


def test_non_strict_replay_warns_and_goes_on(recorded):
    log_path, replies = recorded
    port = replay(log_path, "?strict=0")
    with pytest.warns(ReplayWarning, match=r"MEDR,1,1,2"):
        assert conversation(port, no_cue, medr=b"MEDR,1,1,2\r\n") == replies
    port.assert_complete()


def test_a_write_may_span_or_split_recorded_writes(recorded):
    log_path, _ = recorded
    port = replay(log_path)
    port.write(b"RMTS")
    port.write(b",2\r\nMEDR,1,1,")  # the end of one recorded write and most of the next
    assert port.read(100) == b"OK00\r\n"
    assert port.read(100) == b""  # the block reply is recorded after the whole MEDR command
    port.write(b"1\r\n")
    assert port.read(100) == b"OK00,3AA1"


def test_read_before_the_write_times_out(recorded):
    log_path, _ = recorded
    port = replay(log_path)
    assert port.read(6) == b""
    port.timeout = None
    with pytest.raises(ReplayMismatch, match="block forever"):
        port.read(6)


def test_reading_where_the_recording_flushed(tmp_path):
    path = handwritten(
        tmp_path / "stale.jsonl",
        {"t": 0.1, "dir": "tx", "data": "MEAS,0\r\n"},
        {"t": 0.2, "dir": "flush", "data": "OK00\r\n", "unread": 0},
        {"t": 0.3, "dir": "tx", "data": "IDDR\r\n"},
    )
    strict = replay(path)
    strict.write(b"MEAS,0\r\n")
    with pytest.raises(ReplayMismatch, match=r"stale.jsonl:3: .*discards b'OK00\\r\\n'"):
        strict.read(6)
    lenient = replay(path, "?strict=0")
    lenient.write(b"MEAS,0\r\n")
    with pytest.warns(ReplayWarning, match="reset_input_buffer"):
        assert lenient.read(6) == b"OK00\r\n"  # the bytes were on the wire
    lenient.write(b"IDDR\r\n")
    lenient.close()
    assert lenient.done()  # a connection cut off without a close line


def test_reading_past_the_recording_is_a_disconnect(recorded, tmp_path):
    log_path, _ = recorded
    [connection] = read_session_log(log_path)
    port = replay(log_path)
    follow(port, connection.events[:-1])
    with pytest.raises(SerialException, match=r"disconnected: .*closes the port"):
        port.read(1)
    cut = handwritten(tmp_path / "cut.jsonl", {"t": 0.1, "dir": "tx", "data": "IDDR\r\n"})
    port = replay(cut)
    port.write(b"IDDR\r\n")
    with pytest.raises(SerialException, match=r"disconnected: .*ends here"):
        port.read(1)


def test_incomplete_replay_says_what_is_left(recorded):
    log_path, _ = recorded
    [connection] = read_session_log(log_path)
    port = replay(log_path)
    port.write(b"RMTS,2\r\n")
    port.close()
    assert not port.done()
    with pytest.raises(AssertionError, match=rf"line {connection.events[1].line}: rx b'OK00\\r\\n'"):
        port.assert_complete()
    with pytest.raises(SerialException, match="replayed already"):
        port.open()


def test_resumed_sessions_are_replayed_in_order_or_one_by_one(tmp_path):
    path = tmp_path / "two.jsonl"
    for message in (b"FIRST\n", b"SECOND\n"):
        port = open_recorded("loop://", path, meta={"try": message.decode().strip()}, timeout=0.5)
        port.write(message)
        assert port.read_until(b"\n") == message
        port.close()
    first, second = read_session_log(path)
    assert (first.header["resumed"], second.header["resumed"]) == (False, True)
    assert second.header["meta"] == {"try": "SECOND"}

    both = replay(path)
    for message in (b"FIRST\n", b"SECOND\n"):
        if not both.is_open:
            both.open()
        both.write(message)
        assert both.read_until(b"\n") == message
        both.close()
    assert both.done()

    only = replay(path, "?connection=1")
    assert only.header["meta"] == {"try": "SECOND"}
    with pytest.raises(ReplayMismatch, match=r"two.jsonl:\d+: the driver wrote b'FIRST\\n'"):
        only.write(b"FIRST\n")


def test_recorder_and_replay_refuse_a_closed_port(tmp_path):
    path = tmp_path / "later.jsonl"
    port = open_recorded("loop://", path, timeout=0.5, do_not_open=True)
    assert not port.is_open
    with pytest.raises(serial.PortNotOpenError):
        port.write(b"X")
    port.open()
    with pytest.raises(SerialException, match="already open"):
        port.open()
    assert port.read(0) == b""
    port.close()
    assert [e.kind for e in read_session_log(path)[0].events] == ["close"]
    again = serial.serial_for_url(f"replay://{path}", do_not_open=True)
    assert not again.done()
    with pytest.raises(AssertionError, match="never opened"):
        again.assert_complete()
    with pytest.raises(serial.PortNotOpenError):
        again.read(1)
    again.open()
    assert again.in_waiting == 0  # the next event is the close
    again.close()
    again.assert_complete()


def test_writing_past_the_recording_is_a_mismatch(tmp_path):
    path = handwritten(tmp_path / "short.jsonl", {"t": 0.1, "dir": "tx", "data": "IDDR\r\n"})
    port = replay(path)
    with pytest.raises(ReplayMismatch, match=r"after the last recorded write .*b'IDDR\\r\\nRMTS,0\\r\\n'"):
        port.write(b"IDDR\r\nRMTS,0\r\n")
    lenient = replay(path, "?strict=false")
    with pytest.warns(ReplayWarning, match="first difference at byte 6"):
        lenient.write(b"IDDR\r\nRMTS,0\r\n")
    assert lenient.done()


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ('{"t": 0.1, "dir": "sideways", "data": ""}', "'dir' must be one of"),
        ('{"t": -1, "dir": "close"}', "'t' must be a number >= 0"),
        ('{"t": 0.1, "dir": "timeout"}', "'waited' must be a number >= 0"),
        ('{"t": 0.1, "dir": "rx", "data": 65}', "needs 'data'"),
        ('{"t": 0.1, "dir": "rx", "data": "\\u20ac"}', "above U\\+00FF"),
        ("[1, 2]", "expected a JSON object"),
        ('{"kmpipe_session_log": 2}', "version 2"),
    ],
)
def test_bad_log_lines_are_named(tmp_path, line, message):
    path = handwritten(tmp_path / "bad.jsonl")
    with path.open("a", encoding="ascii") as file:
        file.write("\n" + line + "\n")  # a blank line is skipped: the bad line is line 3
    with pytest.raises(SessionLogError, match=rf"bad\.jsonl:3: .*{message}"):
        read_session_log(path)


def test_a_log_must_start_with_a_header(tmp_path):
    path = tmp_path / "headless.jsonl"
    path.write_text('{"t": 0.1, "dir": "close"}\n', encoding="ascii")
    with pytest.raises(SessionLogError, match=r"headless\.jsonl:1: an event before the first header"):
        read_session_log(path)
    path.write_text("", encoding="ascii")
    with pytest.raises(SessionLogError, match="no session-log header"):
        read_session_log(path)


def test_appending_to_a_file_that_is_not_a_log_is_refused(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("not a log\n")
    with pytest.raises(SessionLogError, match=r"notes\.txt:1: not a session log"):
        SessionLog(path, port="loop://")
    assert path.read_text() == "not a log\n"


def test_resuming_after_a_line_cut_short_starts_on_a_new_line(tmp_path):
    path = handwritten(tmp_path / "cut.jsonl")
    with path.open("a", encoding="ascii") as file:
        file.write('{"t": 0.1, "dir": "rx", "da')  # a crash in the middle of a line
    SessionLog(path, port="loop://").close()
    lines = path.read_text(encoding="ascii").splitlines()
    assert json.loads(lines[-1])["resumed"] is True
    with pytest.raises(SerialException, match=r"cut.jsonl:2: not a JSON line"):
        replay(path)


def test_replay_urls(recorded, tmp_path, monkeypatch):
    log_path, _ = recorded
    monkeypatch.chdir(log_path.parent.parent)
    relative = f"{log_path.parent.name}/{log_path.name}"
    assert str(log_path).startswith("/")  # replay:///abs/path is absolute, replay://dir/file relative
    assert serial.serial_for_url(f"replay://{relative}", timeout=1).header == replay(log_path).header
    assert serial.serial_for_url(f"replay://{log_path}?timing=real&strict=0&connection=0").is_open
    for bad, message in [
        (f"replay://{log_path}?speed=2", "bad option speed='2'"),
        (f"replay://{log_path}?timing=slow", "bad option timing='slow'"),
        (f"replay://{log_path}?connection=1", "1 connection"),
        (f"replay://{tmp_path}/missing.jsonl", "cannot read the session log"),
        ("replay://", "names no file"),
    ]:
        with pytest.raises(SerialException, match=message):
            serial.serial_for_url(bad)


def test_parse_url_gives_the_log_and_the_options():
    from instruments.urlhandler.protocol_replay import parse_url

    assert parse_url("replay:///tmp/a%3Fb.jsonl") == ("/tmp/a?b.jsonl", "fast", True, None)
    assert parse_url("replay://logs/s.jsonl?timing=real&strict=0&connection=2") == ("logs/s.jsonl", "real", False, 2)
    with pytest.raises(SerialException, match="expected"):
        parse_url("socket://localhost:1")


def test_replay_accepts_settings_and_modem_lines(recorded):
    log_path, _ = recorded
    port = replay(log_path)
    port.baudrate = 115200
    port.rts = False
    port.dtr = False
    port.break_condition = True
    port.flush()
    port.reset_output_buffer()
    assert port.out_waiting == 0
    assert port.write(b"RMTS,2\r\n") == 8


def test_register_is_idempotent():
    instruments.urlhandler.register()
    instruments.urlhandler.register()
    assert serial.protocol_handler_packages.count("instruments.urlhandler") == 1
