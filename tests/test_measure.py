"""``kmpipe measure``: recorded sessions replayed through ``replay://``, a live session against the CS-2000 emulator
on a pseudo-terminal (then ``kmpipe fit`` and ``kmpipe validate``), an interrupted session resumed, and bad input.

References are independent of the code under test: the session folders and exit statuses that the original
runs wrote (``tests/data/sessions/*.expected``, recorded by ``tests/data/sessions/record_sessions.py``), the
emulator's ground truth (``Emulator.measurements``), and the K and S that sample F1 was simulated from
(``recipes/samples/F1/truth.json``).
"""

from __future__ import annotations

import json
import re
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest
import serial

from instruments.cs2000.emulator.faults import Fault
from instruments.cs2000.emulator.server import Emulator
from instruments.session_log import read_session_log
from kmpipe.cli import main
from kmpipe.formats.emulator_script import emulator_from_script, read_reflectance_samples
from kmpipe.formats.spectra import read_spectra_csv

ROOT = Path(__file__).resolve().parents[1]
F1 = ROOT / "recipes" / "samples" / "F1"
PLAN = F1 / "plan.toml"
SESSIONS = Path(__file__).resolve().parent / "data" / "sessions"
NAMES = (
    "complete",
    "over_range",
    "busy",
    "no_data",
    "missing_completion",
    "garbage",
    "chunks",
    "slow",
    "disconnect",
)
READINGS = 8  # positions in F1's plan
TIME_SCALE = 0.02
STOPPED = re.compile(
    r"the instrument session stopped: (?P<detail>.*)\. (?P<saved>\d+) of (?P<total>\d+) readings are saved in "
    r"(?P<folder>.*); fix the cause and run the same command with --resume to measure the rest"
)


def kmpipe(capsys, *argv: str | Path) -> tuple[int, str]:
    """Run the command line in-process; its exit status and standard error."""
    capsys.readouterr()
    status = main([str(a) for a in argv])
    return status, capsys.readouterr().err


def measure(capsys, port: str, folder: Path, *more: str | Path, plan: Path = PLAN) -> tuple[int, str]:
    return kmpipe(capsys, "measure", plan, "--port", port, "-o", folder, "--unattended", *more)


def radiance_table(path: Path):
    table = read_spectra_csv(path)
    return table, {c: np.asarray(table.column(c), dtype=np.float64) for c in table.columns}


def without_times(state: dict) -> dict:
    """session.json without the clock times of the readings."""
    return state | {"readings": [{k: v for k, v in r.items() if k != "time"} for r in state["readings"]]}


def lines_without_time(path: Path) -> list[str]:
    """A spectral CSV's lines without its ``# time:`` header (radiance.csv stamps the first reading's time)."""
    return [line for line in path.read_text(encoding="utf-8").splitlines() if not line.startswith("# time:")]


def assert_same_session_files(folder: Path, expected: Path) -> None:
    """The files a session folder holds equal those of the original run (clock times aside)."""
    wanted = sorted(p.name for p in expected.iterdir() if p.name not in ("exit_status", "message"))
    assert sorted(p.name for p in folder.iterdir() if not p.name.startswith(".")) == wanted
    got_table, got = radiance_table(folder / "radiance.csv")
    want_table, want = radiance_table(expected / "radiance.csv")
    assert list(got) == list(want)
    for column, values in want.items():
        np.testing.assert_array_equal(got[column], values, err_msg=column)  # exactly: float32 from hex
    assert {k: v for k, v in got_table.metadata.items() if k != "time"} == {
        k: v for k, v in want_table.metadata.items() if k != "time"
    }
    assert lines_without_time(folder / "radiance.csv") == lines_without_time(expected / "radiance.csv")
    state = json.loads((folder / "session.json").read_text(encoding="utf-8"))
    assert without_times(state) == without_times(json.loads((expected / "session.json").read_text(encoding="utf-8")))
    for name in ("reflectance.csv", "manifest.toml"):
        if (expected / name).exists():
            assert (folder / name).read_text(encoding="utf-8") == (expected / name).read_text(encoding="utf-8"), name


# ------------------------------------------------------------------------------------------- recorded sessions


def exchanges(name: str) -> list[tuple[bytes, list]]:
    """The log of a fixture as (bytes written, events until the next write) pairs; one connection."""
    [connection] = read_session_log(SESSIONS / f"{name}.jsonl")
    pairs: list[tuple[bytes, list]] = []
    for event in connection.events:
        if event.kind == "tx":
            pairs.append((event.data, []))
        else:
            assert pairs, "the log reads before the first write"
            pairs[-1][1].append(event)
    return pairs


def received(events) -> bytes:
    return b"".join(e.data for e in events if e.kind == "rx")


def count_tx(pairs, command: bytes) -> int:
    return sum(tx == command for tx, _ in pairs)


def test_every_fixture_exercises_its_fault():
    """Each recorded log shows on the wire the fault its name promises (so the replays below cover it)."""
    pairs = {name: exchanges(name) for name in NAMES}
    for name, log in pairs.items():  # every log starts the same way and stays in remote mode to the end
        assert [tx for tx, _ in log[:5]] == [b"RMTS,2\r\n", b"IDDR\r\n", b"MSWE,0\r\n", b"SPMS,0,2\r\n", b"OBSS,0\r\n"]
        assert b"MEAS,1\r\n" in {tx for tx, _ in log}, name
    clean = pairs["complete"]
    assert count_tx(clean, b"MEAS,1\r\n") == READINGS
    assert not any(b"ER" in received(events) for _, events in clean)
    assert [tx for tx, _ in clean[-2:]] == [b"MSWE,1\r\n", b"RMTS,0\r\n"]

    over = pairs["over_range"]
    meas = [received(events) for tx, events in over if tx == b"MEAS,1\r\n"]
    assert meas[-1] == b"ER10\r\n" and len(meas) == 5 and all(m.startswith(b"OK00,003\r\n") for m in meas[:4])

    for name, command, code in (("busy", b"MEDR,1,1,2\r\n", b"ER02\r\n"), ("no_data", b"MEDR,1,1,3\r\n", b"ER20\r\n")):
        log = pairs[name]
        failed = [i for i, (tx, events) in enumerate(log) if tx == command and received(events) == code]
        assert len(failed) == 1, name
        # then it polls until idle and measures again (the sample has not moved): one MEAS,1 more than readings
        assert log[failed[0] + 1][0] == b"MEDR,0,0,1\r\n" and log[failed[0] + 2][0] == b"MEAS,1\r\n"
        assert count_tx(log, b"MEAS,1\r\n") == READINGS + 1

    lost = pairs["missing_completion"]
    polled = [i for i, (tx, _) in enumerate(lost) if tx == b"MEDR,0,0,1\r\n" and lost[i - 1][0] == b"MEAS,1\r\n"]
    assert len(polled) == 1
    events = lost[polled[0] - 1][1]
    assert received(events) == b"OK00,003\r\n"  # the first reply only: no completion line ...
    waited = sum(e.waited for e in events if e.kind == "timeout")
    assert waited > 3  # ... after the announced 3 s (and the margin), the driver polled instead
    assert received(lost[polled[0]][1]).startswith(b"OK00,")
    assert count_tx(lost, b"MEAS,1\r\n") == READINGS

    noisy = b"".join(received(events) for _, events in pairs["garbage"])
    assert b"\x00\xfe~#OK00," in noisy and b"OK00,3AA1OK00\r\n" in noisy and b"\x00OK00,CS-2000A" in noisy

    pieces = [sum(e.kind == "rx" for e in events) for _, events in pairs["chunks"]]
    assert max(pieces) > 10  # a 906-byte block in 64-byte pieces

    slow = [
        (tx, events)
        for tx, events in pairs["slow"]
        if sum(e.kind == "timeout" for e in events) >= 2 and received(events).endswith(b"\r\n")
    ]
    assert {tx for tx, _ in slow} >= {b"IDDR\r\n", b"MEDR,1,1,4\r\n"}  # answered after reads that timed out

    cut = pairs["disconnect"]
    last_tx, events = cut[-1]
    assert last_tx == b"MEDR,1,1,2\r\n" and events[-1].kind == "close"
    partial = received(events)
    assert partial.startswith(b"OK00,") and b"\n" not in partial and 0 < len(partial) < 906


@pytest.mark.parametrize("name", NAMES)
def test_replay_gives_the_outcome_of_the_original_run(name, tmp_path, capsys, monkeypatch):
    expected = SESSIONS / f"{name}.expected"
    opened = []
    serial_for_url = serial.serial_for_url

    def recorded_port(url, *args, **kwargs):
        opened.append(serial_for_url(url, *args, **kwargs))
        return opened[-1]

    monkeypatch.setattr(serial, "serial_for_url", recorded_port)
    folder = tmp_path / "F1"
    status, err = measure(capsys, f"replay://{SESSIONS / name}.jsonl?timing=fast&strict=1", folder)

    assert status == int((expected / "exit_status").read_text(encoding="ascii"))
    [port] = opened
    port.assert_complete()  # strict replay: the driver wrote the recorded bytes, all of them, and read every reply
    assert_same_session_files(folder, expected)
    if status == 0:
        assert err == ""
        return
    recorded = STOPPED.search((expected / "message").read_text(encoding="utf-8"))
    replayed = STOPPED.search(err)
    assert recorded and replayed, err
    assert replayed["folder"] == str(folder)
    assert (replayed["saved"], replayed["total"]) == (recorded["saved"], recorded["total"])
    saved = int(replayed["saved"])
    assert 0 < saved < READINGS and not (folder / "manifest.toml").exists()
    assert len(json.loads((folder / "session.json").read_text(encoding="utf-8"))["readings"]) == saved
    # the same error; a vanished port is reported by pyserial live and by the replay at the recorded point
    assert replayed["detail"] == recorded["detail"] or all("disconnected" in m["detail"] for m in (recorded, replayed))


# -------------------------------------------------------------------------------------------------- live runs


def material_grid(material: dict) -> np.ndarray:
    return np.asarray(material["grid"]["wavelengths_nm"], dtype=np.float64)


def test_live_session_then_fit_recovers_the_truth_and_validates(tmp_path, capsys):
    folder = tmp_path / "F1"
    with emulator_from_script(F1 / "emulator.toml", time_scale=TIME_SCALE, link=tmp_path / "cs2000") as emulator:
        status, err = measure(capsys, emulator.link, folder)
        truth = emulator.measurements
    assert status == 0, err
    assert len(truth) == READINGS
    _, radiance = radiance_table(folder / "radiance.csv")
    for (column, values), measurement in zip(radiance.items(), truth, strict=True):
        np.testing.assert_array_equal(values, measurement.radiance, err_msg=column)

    material_path = tmp_path / "F1.json"
    status, err = kmpipe(capsys, "fit", folder / "manifest.toml", "-o", material_path)
    assert status == 0, err
    material = json.loads(material_path.read_text(encoding="utf-8"))
    reference = json.loads((F1 / "truth.json").read_text(encoding="utf-8"))
    grid = material_grid(material)
    for quantity, key in (("K", "K_per_mm"), ("S", "S_per_mm")):
        true = np.interp(grid, reference["wavelengths_nm"], reference[key])
        relative = np.abs(np.asarray(material[quantity]) / true - 1)
        assert np.median(relative) < 0.05, (quantity, np.median(relative))

    status, err = kmpipe(capsys, "validate", material_path, "-o", tmp_path / "report")
    assert status == 0, err
    report = json.loads((tmp_path / "report" / "validation.json").read_text(encoding="utf-8"))
    assert report["verdict"] in ("pass", "warn")


def script_settings() -> dict:
    return tomllib.loads((F1 / "emulator.toml").read_text(encoding="utf-8"))["samples"]


def test_interrupted_session_resumes_where_it_stopped(tmp_path, capsys):
    saved = 4  # the port vanishes during the 5th reading
    folder = tmp_path / "F1"
    fault = Fault("disconnect", "MEDR,1,1,2", occurrence=saved + 1)
    with emulator_from_script(F1 / "emulator.toml", time_scale=TIME_SCALE, faults=[fault]) as first:
        status, err = measure(capsys, first.port, folder)
        before = first.measurements
    assert status == 2
    stopped = STOPPED.search(err)
    assert stopped and (stopped["saved"], stopped["total"]) == (str(saved), str(READINGS)), err
    assert stopped["folder"] == str(folder)
    assert len(before) == saved + 1 and not (folder / "manifest.toml").exists()
    state = json.loads((folder / "session.json").read_text(encoding="utf-8"))
    _, interrupted = radiance_table(folder / "radiance.csv")
    assert len(state["readings"]) == saved and list(interrupted) == [r["column"] for r in state["readings"]]
    for (column, values), measurement in zip(interrupted.items(), before, strict=False):
        np.testing.assert_array_equal(values, measurement.radiance, err_msg=column)

    # a fresh instrument (after a re-plug) with the rest of the plan's samples under it, one at a time
    settings = script_settings()
    samples = read_reflectance_samples(F1 / settings["file"])
    rest = settings["sequence"][saved:]
    log = tmp_path / "resumed.jsonl"
    with Emulator(
        samples,
        sequence=rest,
        illuminant=settings["illuminant"],
        gain=settings["gain"],
        noise=settings["noise"],
        seed=2024,
        time_scale=TIME_SCALE,
    ) as second:
        status, err = measure(capsys, second.port, folder, "--resume", "--record", log)
        after = second.measurements
    assert status == 0, err
    assert len(after) == READINGS - saved  # only the readings not yet saved were measured
    [connection] = read_session_log(log)
    assert sum(e.kind == "tx" and e.data == b"MEAS,1\r\n" for e in connection.events) == READINGS - saved
    assert [m.sample for m in after] == rest

    final_state = json.loads((folder / "session.json").read_text(encoding="utf-8"))
    assert final_state["readings"][:saved] == state["readings"]  # the saved readings are kept as they were
    _, final = radiance_table(folder / "radiance.csv")
    assert len(final) == READINGS
    columns = list(final)
    for column in columns[:saved]:
        np.testing.assert_array_equal(final[column], interrupted[column], err_msg=column)
    for column, measurement in zip(columns[saved:], after, strict=True):
        np.testing.assert_array_equal(final[column], measurement.radiance, err_msg=column)

    # against an uninterrupted session of the same plan (tests/data/sessions/complete.expected, same emulator
    # script and seed): the readings taken before the interruption exactly, the rest up to the instrument noise
    uninterrupted = SESSIONS / "complete.expected"
    _, reference = radiance_table(uninterrupted / "radiance.csv")
    assert list(reference) == columns
    for column in columns[:saved]:
        np.testing.assert_array_equal(final[column], reference[column], err_msg=column)
    assert (folder / "manifest.toml").read_text(encoding="utf-8") == (uninterrupted / "manifest.toml").read_text(
        encoding="utf-8"
    )
    got = read_spectra_csv(folder / "reflectance.csv")
    want = read_spectra_csv(uninterrupted / "reflectance.csv")
    assert got.columns == want.columns
    noise = settings["noise"] * np.sqrt(2)  # relative: two independent readings of the same sample
    for column in want.columns:
        ours, theirs = np.asarray(got.column(column)), np.asarray(want.column(column))
        if column in columns[:saved]:  # the backings and the masstone: measured before the interruption
            np.testing.assert_array_equal(ours, theirs, err_msg=column)
        else:
            relative = np.abs(ours / theirs - 1)
            assert np.median(relative) < 2 * noise and relative.max() < 8 * noise, column


def test_a_noise_line_before_a_reply_does_not_crash_the_session(tmp_path, capsys):
    """Line noise that happens to hold a line feed gives a "reply" without a reply code: the session must skip
    it (exit 0), or stop with the clear error that keeps the readings (exit 2), never fail as an internal error."""
    folder = tmp_path / "F1"
    noise = Fault("garbage", "MEDR,1,1,1", occurrence=2, garbage=b"\x00\xfe\r\n")
    with emulator_from_script(F1 / "emulator.toml", time_scale=TIME_SCALE, faults=[noise]) as emulator:
        status, err = measure(capsys, emulator.port, folder)
        truth = emulator.measurements
    assert status in (0, 2), err
    _, radiance = radiance_table(folder / "radiance.csv")
    for (column, values), measurement in zip(radiance.items(), truth, strict=False):
        np.testing.assert_array_equal(values, measurement.radiance, err_msg=column)
    if status == 2:
        stopped = STOPPED.search(err)
        assert stopped and int(stopped["saved"]) == len(radiance) >= 1, err


def test_a_reading_whose_data_are_gone_is_measured_again(tmp_path, capsys):
    """ER20 (no data) on a spectral block, and on the MEDR,0,0,1 poll that follows (the data really are gone):
    the reading is tried again, as kmpipe.stages.measure promises for "no data", and the session completes."""
    folder = tmp_path / "F1"
    gone = [Fault("no_data", "MEDR,1,1,3", occurrence=4), Fault("no_data", "MEDR,0,0,1", occurrence=4)]
    with emulator_from_script(F1 / "emulator.toml", time_scale=TIME_SCALE, faults=gone) as emulator:
        status, err = measure(capsys, emulator.port, folder)
        truth = emulator.measurements
    assert status == 0, err
    assert len(truth) == READINGS + 1  # the 4th reading measured twice
    _, radiance = radiance_table(folder / "radiance.csv")
    assert len(radiance) == READINGS
    np.testing.assert_array_equal(radiance["masstone"], truth[4].radiance)


# -------------------------------------------------------------------------------------------------- bad input


def edited_plan(tmp_path: Path, old: str, new: str) -> Path:
    text = PLAN.read_text(encoding="utf-8")
    assert old in text
    path = tmp_path / "plan.toml"
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return path


@pytest.mark.parametrize(
    ("old", "new", "lines", "field"),
    [
        ("repeats = 1", "repaets = 1", (10,), "instrument.repaets"),  # a typo'd key
        ('over = "white"\nthickness = "15 um"', 'over = "grey"\nthickness = "15 um"', (28,), "film[2].over"),
        # no thickness, unattended: the [[film]] table or its first key
        ('over = "black"\nthickness = "15 um"\n', 'over = "black"\n', (23, 24), "film[1].thickness"),
    ],
    ids=["typo", "unknown-backing", "no-thickness"],
)
def test_bad_plan_names_file_line_and_field(tmp_path, capsys, old, new, lines, field):
    plan = edited_plan(tmp_path, old, new)
    folder = tmp_path / "F1"
    status, err = measure(capsys, str(tmp_path / "no-port"), folder, plan=plan)
    assert status == 2
    assert any(f"{plan}, line {line}:" in err for line in lines), err
    assert f"field '{field}'" in err, err
    assert not (folder / "session.json").exists() and not (folder / "radiance.csv").exists()


def test_a_port_that_does_not_exist(tmp_path, capsys):
    port = tmp_path / "ttyACM9"
    status, err = measure(capsys, str(port), tmp_path / "F1", "--record", tmp_path / "s.jsonl")
    assert status == 2
    assert "--port" in err and str(port) in err, err
    assert not (tmp_path / "s.jsonl").exists()  # nothing was exchanged: no log
    assert not (tmp_path / "F1" / "session.json").exists()


def test_a_folder_with_a_session_is_not_started_afresh(tmp_path, capsys):
    folder = tmp_path / "F1"
    status, _ = measure(capsys, f"replay://{SESSIONS / 'over_range.jsonl'}", folder)
    assert status == 2  # a stopped session: 4 readings
    files = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert set(files) == {"radiance.csv", "session.json"}

    status, err = measure(capsys, f"replay://{SESSIONS / 'complete.jsonl'}", folder)
    assert status == 2
    assert str(folder) in err and "--resume" in err, err
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == files


def test_replay_clock_follows_the_recording_in_fast_timing():
    """The replay port's clock (used by the driver's deadlines) is the recorded time, jumping to the next recorded
    write where the recording has nothing more to read: a lost completion line costs no real waiting."""
    import serial

    import instruments.urlhandler  # noqa: F401  (registers replay://)
    from instruments.session_log import read_session_log

    log = SESSIONS / "missing_completion.jsonl"
    events = read_session_log(log)[0].events
    port = serial.serial_for_url(f"replay://{log.resolve()}", timeout=0.05)
    first_tx = next(e for e in events if e.kind == "tx")
    port.write(first_tx.data)
    assert port.clock() == first_tx.t
    next_tx = next(e for e in events if e.kind == "tx" and e.t > first_tx.t)
    seen = []
    for _ in range(10_000):  # the first reply's chunks and timeouts, then silence until the next write
        chunk = port.read(256)
        seen.append(port.clock())
        if not chunk and port.clock() == next_tx.t:
            break
    else:
        pytest.fail("the replay clock never reached the next recorded write")
    assert seen == sorted(seen)  # never goes back
    port.close()


# ------------------------------------------------------------------------------- a session follows one plan

DEMO_SESSIONS = ROOT / "recipes" / "demo" / "sessions"


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative name -> bytes), to show that a refused command changed nothing."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def stopped(tmp_path, capsys) -> Path:
    """A session folder of F1's plan that stopped after 4 of 8 readings (the over_range recording replayed)."""
    folder = tmp_path / "F1"
    status, err = measure(capsys, f"replay://{SESSIONS / 'over_range.jsonl'}", folder)
    assert status == 2 and "4 of 8 readings are saved" in err, err
    return folder


def test_a_sample_name_that_leads_out_of_the_plan_folder_is_refused(tmp_path, capsys):
    """name = ".." without -o would make the plan folder's parent the session folder (and replace a manifest.toml
    there): refused, naming the field and its line, and nothing is written anywhere."""
    plans = tmp_path / "plans"
    plans.mkdir()
    plan = plans / "plan.toml"
    plan.write_text(PLAN.read_text(encoding="utf-8").replace('name = "F1"', 'name = ".."', 1), encoding="utf-8")
    (tmp_path / "manifest.toml").write_text("# someone else's manifest\n", encoding="utf-8")
    before = snapshot(tmp_path)
    status, err = kmpipe(capsys, "measure", plan, "--port", f"replay://{SESSIONS / 'complete.jsonl'}", "--unattended")
    assert status == 2
    assert f"{plan}, line 3:" in err and "field 'sample.name'" in err and "'..'" in err, err
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("name", ["..", ".", "a/b"])
def test_unsafe_sample_names_are_refused_by_the_plan(tmp_path, name):
    from kmpipe.errors import InputError
    from kmpipe.formats.measurement_plan import load_plan

    plan = edited_plan(tmp_path, 'name = "F1"', f"name = {json.dumps(name)}")
    with pytest.raises(InputError) as caught:
        load_plan(plan)
    assert (caught.value.path, caught.value.line, caught.value.field) == (plan, 3, "sample.name")


def copied_log(tmp_path: Path, name: str = "complete") -> Path:
    log = tmp_path / f"{name}.jsonl"
    log.write_bytes((SESSIONS / f"{name}.jsonl").read_bytes())
    return log


@pytest.mark.parametrize(
    "case", ["record-is-replay", "record-is-plan", "record-in-session", "o-is-plan", "o-holds-plan-as-file"]
)
def test_outputs_that_are_inputs_are_refused_before_anything_is_opened(tmp_path, capsys, case):
    log = copied_log(tmp_path)
    plan = tmp_path / "plan.toml"
    plan.write_bytes(PLAN.read_bytes())
    folder = tmp_path / "F1"
    record, field = {
        "record-is-replay": (tmp_path / "." / "complete.jsonl", "--record"),  # the same file, spelt otherwise
        "record-is-plan": (plan, "--record"),
        "record-in-session": (folder / "session.json", "--record"),
        "o-is-plan": (None, "-o"),
        "o-holds-plan-as-file": (None, "-o"),
    }[case]
    if case == "o-is-plan":
        folder = plan
    if case == "o-holds-plan-as-file":
        plan = tmp_path / "manifest.toml"  # a plan named like a session file, and -o its folder
        plan.write_bytes(PLAN.read_bytes())
        folder = tmp_path
    before = snapshot(tmp_path)
    more = ("--record", record) if record is not None else ()
    status, err = measure(capsys, f"replay://{log}", folder, *more, plan=plan)
    assert status == 2
    assert f"field '{field}'" in err, err
    assert snapshot(tmp_path) == before  # the log being replayed was not appended to; no folder was made


@pytest.mark.parametrize("case", ["o-is-a-file", "record-is-a-folder", "record-in-a-missing-folder"])
def test_output_paths_that_cannot_be_written(tmp_path, capsys, case):
    folder = tmp_path / "F1"
    if case == "o-is-a-file":
        folder = tmp_path / "taken.txt"
        folder.write_text("x", encoding="utf-8")
    record = {"record-is-a-folder": tmp_path, "record-in-a-missing-folder": tmp_path / "no" / "s.jsonl"}.get(case)
    field, named = ("-o", folder) if record is None else ("--record", record)
    more = ("--record", record) if record is not None else ()
    before = snapshot(tmp_path)
    status, err = measure(capsys, f"replay://{SESSIONS / 'complete.jsonl'}", folder, *more)
    assert status == 2
    assert f"{named}" in err and f"field '{field}'" in err, err
    assert snapshot(tmp_path) == before and not (tmp_path / "no").exists()


def test_a_missing_parent_of_the_session_folder_is_created(tmp_path, capsys):
    folder = tmp_path / "new" / "deeper" / "F1"
    status, err = measure(capsys, f"replay://{SESSIONS / 'complete.jsonl'}", folder)
    assert status == 0, err
    assert (folder / "manifest.toml").is_file()


def test_resume_with_another_plan_is_refused_and_changes_nothing(stopped, tmp_path, capsys):
    before = snapshot(stopped)
    digest = json.loads((stopped / "session.json").read_text(encoding="utf-8"))["plan"]["sha256"]
    other = ROOT / "recipes" / "samples" / "F2" / "plan.toml"
    edited = edited_plan(tmp_path, "repeats = 1", "repeats = 1  # the same sample, another plan")
    for plan in (other, edited):
        status, err = measure(capsys, str(tmp_path / "no-port"), stopped, "--resume", plan=plan)
        assert status == 2
        assert f"{stopped / 'session.json'}" in err and str(plan) in err, err
        assert f"follows plan {digest[:12]} of sample F1" in err, err
        assert snapshot(stopped) == before  # byte for byte


def test_resume_of_a_session_folder_without_its_plan_is_refused(stopped, tmp_path, capsys):
    """session.json of the older format (version 1, no plan recorded): refused, it cannot be checked."""
    state = json.loads((stopped / "session.json").read_text(encoding="utf-8"))
    del state["plan"]
    (stopped / "session.json").write_text(json.dumps(state | {"kmpipe_session": 1}), encoding="utf-8")
    before = snapshot(stopped)
    status, err = measure(capsys, str(tmp_path / "no-port"), stopped, "--resume")
    assert status == 2
    assert "older kmpipe" in err and "field 'plan'" in err and str(PLAN) in err, err
    assert snapshot(stopped) == before


def cut(path: Path, keep: float) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


DAMAGE = {
    "session-json-truncated": ("session.json", lambda f: cut(f / "session.json", 0.5)),
    "session-json-empty": ("session.json", lambda f: (f / "session.json").write_bytes(b"")),
    "session-json-random-bytes": (
        "session.json",
        lambda f: (f / "session.json").write_bytes(np.random.default_rng(7).bytes(512)),
    ),
    "session-json-not-a-state": ("session.json", lambda f: (f / "session.json").write_text("[1, 2]\n")),
    "reading-without-its-column": (
        "radiance.csv",
        lambda f: (f / "radiance.csv").write_text(
            (f / "radiance.csv").read_text(encoding="utf-8").replace(",white,", ",whitish,", 1), encoding="utf-8"
        ),
    ),
    "radiance-csv-truncated": ("radiance.csv", lambda f: cut(f / "radiance.csv", 0.6)),
    "radiance-csv-last-byte-cut": ("radiance.csv", lambda f: cut(f / "radiance.csv", 1 - 1e-9)),
    "radiance-csv-missing": ("session.json", lambda f: (f / "radiance.csv").unlink()),
}


@pytest.mark.parametrize("case", list(DAMAGE))
def test_resume_of_a_damaged_session_says_what_is_damaged_and_changes_nothing(stopped, tmp_path, capsys, case):
    damaged, damage = DAMAGE[case]
    damage(stopped)
    before = snapshot(stopped)
    status, err = measure(capsys, f"replay://{SESSIONS / 'complete.jsonl'}", stopped, "--resume")
    assert status == 2, err
    assert "Traceback" not in err and "internal error" not in err.lower(), err
    named = stopped / ("radiance.csv" if case == "radiance-csv-missing" else damaged)
    assert str(named) in err and "the saved readings are untouched" in err, err
    assert snapshot(stopped) == before


def test_replay_of_another_samples_log_is_refused_and_writes_nothing(tmp_path, capsys):
    folder = tmp_path / "F1"
    l1 = json.loads((DEMO_SESSIONS / "L1.jsonl").read_text(encoding="utf-8").splitlines()[0])["meta"]
    status, err = measure(capsys, f"replay://{DEMO_SESSIONS / 'L1.jsonl'}", folder)
    assert status == 2
    assert f"{DEMO_SESSIONS / 'L1.jsonl'}, line 1:" in err and "field '--port'" in err, err
    assert f"was recorded for sample L1 (plan sha256 {l1['plan_sha256'][:12]}), not F1" in err, err
    assert not folder.exists()
    # the same sample with another plan (an edited copy of F1's)
    edited = edited_plan(tmp_path, "repeats = 1", "repeats = 1  # edited")
    status, err = measure(capsys, f"replay://{SESSIONS / 'complete.jsonl'}", folder, plan=edited)
    assert status == 2 and "was recorded for sample F1" in err and str(edited) in err, err
    assert not folder.exists()


def test_a_recorded_log_names_its_sample_and_plan_and_a_log_without_them_is_replayed_with_a_warning(tmp_path, capsys):
    from kmpipe.formats.measurement_plan import plan_digest

    [connection] = read_session_log(SESSIONS / "complete.jsonl")
    assert connection.header["meta"] == {"sample": "F1", "plan_sha256": plan_digest(PLAN)}
    old = tmp_path / "old.jsonl"  # as recorded before kmpipe wrote the metadata
    lines = (SESSIONS / "complete.jsonl").read_text(encoding="utf-8").splitlines(keepends=True)
    header = json.loads(lines[0]) | {"meta": {}}
    old.write_text(json.dumps(header) + "\n" + "".join(lines[1:]), encoding="utf-8")
    capsys.readouterr()
    status = main(["measure", str(PLAN), "--port", f"replay://{old}", "-o", str(tmp_path / "F1"), "--unattended"])
    out = capsys.readouterr()
    assert status == 0, out.err
    assert "does not record which sample and plan" in out.out + out.err


def test_record_appends_only_to_a_log_of_the_same_plan(tmp_path, capsys):
    log = tmp_path / "L1.jsonl"
    log.write_bytes((DEMO_SESSIONS / "L1.jsonl").read_bytes())
    before = log.read_bytes()
    status, err = measure(capsys, f"replay://{SESSIONS / 'complete.jsonl'}", tmp_path / "F1", "--record", log)
    assert status == 2 and "recorded for sample L1" in err and "field '--record'" in err, err
    assert log.read_bytes() == before and not (tmp_path / "F1").exists()


# ------------------------------------------------------------------------- the sample under the instrument


def expected_radiance(sample: str) -> np.ndarray:
    """The emulator's documented ground truth, computed independently: CIE D55 (colour-science's table, linear
    interpolation to 1 nm, 100 at 560 nm) x the sample's reflectance (F1's emulator_reflectance.csv) x the script's
    gain, rounded to float32 (what the instrument sends in hex); the emulator's noise is off."""
    import colour

    d55 = colour.SDS_ILLUMINANTS["D55"]
    wavelengths = np.arange(380.0, 781.0)
    spd = np.interp(wavelengths, d55.wavelengths, d55.values)
    spd *= 100.0 / spd[wavelengths == 560][0]
    table = read_spectra_csv(F1 / script_settings()["file"])
    reflectance = np.interp(wavelengths, table.wavelengths, np.asarray(table.column(sample), dtype=np.float64))
    return (spd * reflectance * script_settings()["gain"]).astype(np.float32).astype(np.float64)


def assert_each_reading_is_its_sample(folder: Path) -> None:
    _, radiance = radiance_table(folder / "radiance.csv")
    for column, sample in zip(radiance, script_settings()["sequence"], strict=False):
        np.testing.assert_allclose(radiance[column], expected_radiance(sample), rtol=1e-6, err_msg=column)


def test_readings_after_faults_and_resumes_measure_the_sample_they_are_named_for(tmp_path, capsys):
    """ER51 (temperature) on the 3rd MEAS,1 and ER10 (over range) on the 6th stop the session; each --resume goes
    on with the same instrument, whose sample stays put until a reading was read out: every reading is of the
    sample it is named for, the retried ones included."""
    folder = tmp_path / "F1"
    faults = [Fault("error", "MEAS", occurrence=3, code="ER51"), Fault("over_range", "MEAS", occurrence=6)]
    with emulator_from_script(F1 / "emulator.toml", time_scale=TIME_SCALE, noise=0.0, faults=faults) as emulator:
        status, err = measure(capsys, emulator.port, folder)
        assert status == 2 and "ER51" in err and "2 of 8 readings are saved" in err, err
        assert_each_reading_is_its_sample(folder)
        status, err = measure(capsys, emulator.port, folder, "--resume")
        assert status == 2 and "ER10" in err and "4 of 8 readings are saved" in err, err
        assert_each_reading_is_its_sample(folder)
        status, err = measure(capsys, emulator.port, folder, "--resume")
        assert status == 0, err
        measured = [m.sample for m in emulator.measurements]
    assert measured == script_settings()["sequence"]  # the failed MEAS,1 completed nothing
    _, radiance = radiance_table(folder / "radiance.csv")
    assert len(radiance) == READINGS
    assert_each_reading_is_its_sample(folder)


def test_a_retried_reading_measures_the_same_sample(tmp_path, capsys):
    """ER02 on a spectral block: the reading is measured again, on the sample still under the instrument."""
    folder = tmp_path / "F1"
    busy = Fault("busy", "MEDR,1,1,2", occurrence=3)
    with emulator_from_script(F1 / "emulator.toml", time_scale=TIME_SCALE, noise=0.0, faults=[busy]) as emulator:
        status, err = measure(capsys, emulator.port, folder)
        measured = [m.sample for m in emulator.measurements]
    assert status == 0, err
    sequence = script_settings()["sequence"]
    assert measured == [*sequence[:3], sequence[2], *sequence[3:]]  # the 3rd sample twice
    assert_each_reading_is_its_sample(folder)


# ------------------------------------------------------------------------------------- colorimetric checks


def test_colorimetry_that_does_not_fit_its_spectrum_is_read_again(tmp_path, capsys):
    """x = y = 10 in the 3rd reading's colorimetric block, once: a transfer error, the data are read again (not
    measured again) and the session completes with the instrument's honest values."""
    folder = tmp_path / "F1"
    corrupt = Fault("colorimetry", "MEDR,2,0,0", occurrence=3, values={"x": 10.0, "y": 10.0})
    with emulator_from_script(F1 / "emulator.toml", time_scale=TIME_SCALE, faults=[corrupt]) as emulator:
        status, err = measure(capsys, emulator.port, folder)
        truth = emulator.measurements
    assert status == 0, err
    assert len(truth) == READINGS  # read again, not measured again
    state = json.loads((folder / "session.json").read_text(encoding="utf-8"))
    third = state["readings"][2]
    assert third["column"] == "white"
    assert abs(third["x"] - truth[2].colorimetric["x"]) < 1e-4 and abs(third["y"] - truth[2].colorimetric["y"]) < 1e-4


def test_colorimetry_that_never_fits_stops_the_session_naming_the_reading(tmp_path, capsys):
    folder = tmp_path / "F1"
    corrupt = [Fault("colorimetry", "MEDR,2,0,0", occurrence=n, values={"Lv": 1.0}) for n in (3, 4, 5)]
    with emulator_from_script(F1 / "emulator.toml", time_scale=TIME_SCALE, faults=corrupt) as emulator:
        status, err = measure(capsys, emulator.port, folder)
    assert status == 2
    stopped = STOPPED.search(err)
    assert stopped and (stopped["saved"], stopped["total"]) == ("2", str(READINGS)), err
    assert "reading white" in stopped["detail"] and "Lv = 1 cd/m2" in stopped["detail"], err
    state = json.loads((folder / "session.json").read_text(encoding="utf-8"))
    assert [r["column"] for r in state["readings"]] == ["white_standard", "black"]
    assert not (folder / "manifest.toml").exists()


@pytest.mark.parametrize(
    ("values", "problem"),
    [
        ({"x": 10.0, "y": 10.0}, "x = 10 lies outside 0-1"),
        ({"x": 0.6, "y": 0.5}, "x + y = 1.1 exceeds 1"),
        ({"Lv": -1.0}, "Lv = -1 cd/m2 is not a luminance"),
        ({"Lv": float("inf")}, "is not a luminance"),
        ({"x": 0.3}, "chromaticity x = 0.3000, but its spectrum gives"),
        ({"Lv": 1.03}, "Lv = 1.03 cd/m2, but its spectrum gives 1"),
    ],
)
def test_colorimetry_problem_checks_plausibility_and_the_spectrum(values, problem):
    import colour

    from kmpipe.stages.measure import colorimetry_problem

    cmfs = np.asarray(colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"][np.arange(380, 781)])
    radiance = np.ones(401) / (683.0 * cmfs[:, 1].sum())  # an equal-energy spectrum of 1 cd/m2: x = y = 1/3
    honest = {"Lv": 1.0, "x": 1 / 3, "y": 1 / 3}
    assert colorimetry_problem(radiance, honest) is None
    assert colorimetry_problem(radiance, honest | {"Lv": 1.015, "x": 0.337}) is None  # within the tolerances
    assert colorimetry_problem(radiance, dict.fromkeys(honest)) is None  # sentinels are not checked
    found = colorimetry_problem(radiance, honest | values)
    assert found is not None and problem in found, found


def test_kmpipe_run_refuses_to_replay_another_samples_log(tmp_path):
    """``kmpipe run`` replays a product's log through ``run_session(plan, "replay://LOG")``: the same check."""
    from kmpipe.errors import InputError
    from kmpipe.run.tasks import do_material

    with pytest.raises(InputError, match="was recorded for sample L1") as caught:
        do_material("replay", {"plan": str(PLAN), "log": str(DEMO_SESSIONS / "L1.jsonl")}, str(tmp_path / "F1"))
    assert caught.value.path == DEMO_SESSIONS / "L1.jsonl"
    assert not (tmp_path / "F1" / "material.json").exists() and not (tmp_path / "F1" / "session").exists()


def test_a_skin_panel_is_measured_like_any_reading_and_becomes_review_tones(tmp_path, capsys):
    from kmpipe.formats.skin_tones import read_tones
    from kmpipe.formats.spectra import SpectralTable, write_spectra_csv

    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN.read_text(encoding="utf-8") + '\n[[skin]]\nname = "V07"\nsite = "cheek"\n\n[[skin]]\n'
                    'name = "V08"\n', encoding="utf-8")  # fmt: skip
    samples = read_spectra_csv(F1 / "emulator_reflectance.csv")
    w = samples.wavelengths
    skins = {"skin_v07": 0.2 + 0.4 / (1.0 + np.exp(-(w - 590.0) / 25.0)), "skin_v08": 0.1 + 0.2 * (w - 380) / 400}
    columns = {c: samples.column(c) for c in samples.columns} | skins
    table = SpectralTable(w, None, tuple(columns), np.array(list(columns.values())), {"quantity": "reflectance"})
    write_spectra_csv(table, tmp_path / "reflectance.csv")
    script = script_settings() | {"file": "reflectance.csv", "noise": 0.0}
    script["sequence"] = [*script["sequence"], "skin_v07", "skin_v08"]
    (tmp_path / "emulator.toml").write_text("[samples]\n" + "".join(
        f"{k} = {json.dumps(v)}\n" for k, v in script.items()), encoding="utf-8")  # fmt: skip
    folder = tmp_path / "session"
    with emulator_from_script(tmp_path / "emulator.toml", time_scale=TIME_SCALE, link=tmp_path / "cs2000") as emulator:
        status, err = measure(capsys, emulator.link, folder, plan=plan)
    assert status == 0, err
    reflectance = read_spectra_csv(folder / "reflectance.csv")
    assert reflectance.metadata["site.skin_V07"] == "cheek" and "site.skin_V08" not in reflectance.metadata
    for name, column in (("skin_V07", "skin_v07"), ("skin_V08", "skin_v08")):
        np.testing.assert_allclose(reflectance.column(name), skins[column], rtol=1e-6)  # as the instrument sends it
    manifest = tomllib.loads((folder / "manifest.toml").read_text(encoding="utf-8"))
    assert "skin" not in manifest and len(manifest["film"]) == 4  # the sample's fit is as before
    tones = read_tones(["reflectance.csv:skin_V07"], np.arange(380.0, 781.0, 5.0), folder, {})
    assert [(t.id, t.name, t.site, t.kind) for t in tones] == [("skin-v07", "skin_V07", "cheek", "measured")]


def test_the_suggested_measurement_is_measured_as_a_plan_addition(tmp_path, capsys):
    """Measure F1, fit, validate; measure again with --add-suggested: the plan gets the suggested film (the emulator
    holds it, made from F1's truth), and the refitted material's radius shrinks as the validation predicted."""
    from kmpipe.formats.spectra import SpectralTable, write_spectra_csv
    from kmpipe.physics.kubelka_munk import reflectance_over_background

    with emulator_from_script(F1 / "emulator.toml", time_scale=TIME_SCALE, link=tmp_path / "cs2000") as emulator:
        assert measure(capsys, emulator.link, tmp_path / "F1")[0] == 0
    assert kmpipe(capsys, "fit", tmp_path / "F1" / "manifest.toml", "-o", tmp_path / "F1.json")[0] == 0
    at = ("--at", "15 um", "--over", "white", "--draws", "0")  # judged where the product is worn, both times
    assert kmpipe(capsys, "validate", tmp_path / "F1.json", "-o", tmp_path / "report", *at)[0] == 0
    report = json.loads((tmp_path / "report" / "validation.json").read_text(encoding="utf-8"))
    best = report["uncertainty"]["next_measurement"][0]
    assert best["role"] in ("film", "repeat") and best["over"] in ("black", "white")
    plan = tmp_path / "plan.toml"
    shutil.copy(PLAN, plan)
    # the emulator's samples, and the suggested film: made from the truth the others were made from, or a repeat
    script = (F1 / "emulator.toml").read_text(encoding="utf-8")
    table = read_spectra_csv(F1 / "emulator_reflectance.csv")
    truth = json.loads((F1 / "truth.json").read_text(encoding="utf-8"))
    K, S = (np.interp(table.wavelengths, truth["wavelengths_nm"], truth[q]) for q in ("K_per_mm", "S_per_mm"))
    um = float(best["thickness"].split()[0])
    added = reflectance_over_background(K, S, um / 1000.0, table.column(f"{best['over']}_card"))
    samples = SpectralTable(table.wavelengths, None, (*table.columns, "added"), np.vstack([table.values, added]),
                            table.metadata)  # fmt: skip
    write_spectra_csv(samples, tmp_path / "samples.csv")
    script = script.replace('file = "emulator_reflectance.csv"', f'file = "{tmp_path / "samples.csv"}"')
    script = script.replace('"film_30um_over_white"]', '"film_30um_over_white", "added"]')
    (tmp_path / "emulator.toml").write_text(script, encoding="utf-8")
    with emulator_from_script(tmp_path / "emulator.toml", time_scale=TIME_SCALE, link=tmp_path / "cs") as emulator:
        status, err = measure(capsys, emulator.link, tmp_path / "F1-next", "--add-suggested",
                              tmp_path / "report" / "validation.json", plan=plan)  # fmt: skip
    assert status == 0, err
    text = (tmp_path / "plan.next.toml").read_text(encoding="utf-8")
    assert text.startswith(PLAN.read_text(encoding="utf-8").rstrip("\n")) and best["line"] in text
    manifest = (tmp_path / "F1-next" / "manifest.toml").read_text(encoding="utf-8")
    assert manifest.count("[[film]]") == 5 and f'thickness = "{best["thickness"]}' in manifest
    assert kmpipe(capsys, "fit", tmp_path / "F1-next" / "manifest.toml", "-o", tmp_path / "F1-next.json")[0] == 0
    assert kmpipe(capsys, "validate", tmp_path / "F1-next.json", "-o", tmp_path / "next", *at)[0] == 0
    after = json.loads((tmp_path / "next" / "validation.json").read_text(encoding="utf-8"))
    radius = after["uncertainty"]["radius_delta_e_2000_95"]
    assert radius < best["today"] and radius == pytest.approx(best["radius"], rel=0.2)
