"""Record the CS-2000 session logs that tests/test_measure.py replays, and the outcome of each run.

Run from the repository root::

    .venv/bin/python tests/data/sessions/record_sessions.py            # every scenario
    .venv/bin/python tests/data/sessions/record_sessions.py busy slow  # some of them

Each scenario starts the CS-2000 emulator on a pseudo-terminal with sample F1's script
(``recipes/samples/F1/emulator.toml``: its sequence, noise and seed, so the spectra are the same on every run)
at a small time scale, plus the scenario's injected faults, and runs in-process

    kmpipe measure recipes/samples/F1/plan.toml --port <pty> --record <NAME>.jsonl -o <folder> --unattended

It writes, next to this script:

- ``NAME.jsonl``: the session log (every byte exchanged);
- ``NAME.expected/``: the files the session folder held at the end (``radiance.csv``, ``session.json``, and
  ``reflectance.csv`` and ``manifest.toml`` when the session completed), ``exit_status`` (the command's exit
  status) and, when the command printed an error, ``message`` (its standard error, with the session folder's
  path written ``{folder}``).

The script checks each outcome (exit status, readings saved, radiance equal to the emulator's ground truth)
and refuses to write fixtures for a run that did not go as the scenario says. The slowest scenario is
``missing_completion`` (about 13 s: the driver waits the announced time plus its 10 s margin before polling).
"""

from __future__ import annotations

import contextlib
import io
import json
import shutil
import sys
import tempfile
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
sys.path.insert(0, str(ROOT))  # run as a script: import kmpipe and instruments from this checkout

from instruments.cs2000.emulator.faults import Fault  # noqa: E402
from instruments.cs2000.emulator.instrument import Measurement  # noqa: E402
from kmpipe.cli import main  # noqa: E402
from kmpipe.formats.emulator_script import emulator_from_script  # noqa: E402
from kmpipe.formats.spectra import read_spectra_csv  # noqa: E402

PLAN = ROOT / "recipes" / "samples" / "F1" / "plan.toml"
SCRIPT = ROOT / "recipes" / "samples" / "F1" / "emulator.toml"
TIME_SCALE = 0.01  # 1 instrument second = 10 ms: a reading takes about 40 ms
READINGS = 8  # positions in F1's plan
SESSION_FILES = ("radiance.csv", "session.json", "reflectance.csv", "manifest.toml")


@dataclass(frozen=True)
class Scenario:
    """One recorded session: the faults injected and the outcome the run must have."""

    faults: tuple[Fault, ...]
    exit_status: int = 0
    saved: int = READINGS  # readings on disk at the end
    measurements: int = READINGS  # MEAS,1 the emulator completed
    note: str = ""


SCENARIOS: dict[str, Scenario] = {
    "complete": Scenario((), note="no fault"),
    "over_range": Scenario(
        (Fault("over_range", "MEAS", occurrence=5),),
        exit_status=2,
        saved=4,
        measurements=4,
        note="ER10 after the 5th MEAS,1's pre-measurement: the session stops, 4 readings kept",
    ),
    "busy": Scenario(
        (Fault("busy", "MEDR,1,1,2", occurrence=3),),
        measurements=READINGS + 1,
        note="ER02 on the 3rd reading's second spectral block: polled, measured again, completes",
    ),
    "no_data": Scenario(
        (Fault("no_data", "MEDR,1,1,3", occurrence=4),),
        measurements=READINGS + 1,
        note="ER20 on the 4th reading's third spectral block: polled, measured again, completes",
    ),
    "missing_completion": Scenario(
        (Fault("no_completion", "MEAS", occurrence=3),),
        note="the 3rd MEAS,1 never sends its completion line: the driver polls MEDR,0,0,1, completes",
    ),
    "garbage": Scenario(
        (
            Fault("garbage", "MEDR,1,1,1", occurrence=2),  # NUL, 0xFE, '~#' before the reply
            Fault("garbage", "MEAS", at="completion", occurrence=3, garbage=b"OK00,3AA1"),  # a reply fragment
            Fault("garbage", "IDDR", garbage=b"\x00"),  # a NUL as a USB port opens
        ),
        note="stray bytes before three replies: skipped by the parser, completes",
    ),
    "chunks": Scenario(
        (
            Fault("chunks", "MEDR,1,1,3", occurrence=2, chunk_size=64, seconds=0.5),
            Fault("chunks", "MEAS", occurrence=6, chunk_size=3, seconds=0.5),
        ),
        note="a spectral block and a first MEAS reply in small pieces 5 ms apart: completes",
    ),
    "slow": Scenario(
        (
            Fault("delay", "MEDR,1,1,4", occurrence=3, seconds=30),
            Fault("delay", "IDDR", seconds=20),
        ),
        note="two replies 0.2-0.3 s late, beyond the 0.05 s port read timeout, within the 10 s deadline: completes",
    ),
    "disconnect": Scenario(
        (Fault("disconnect", "MEDR,1,1,2", occurrence=6, fraction=0.5),),
        exit_status=2,
        saved=5,
        measurements=6,
        note="the port vanishes halfway through the 6th reading's second spectral block: 5 readings kept",
    ),
}


def record(name: str, scenario: Scenario) -> None:
    """Run one scenario, check its outcome and write NAME.jsonl and NAME.expected/."""
    log = HERE / f"{name}.jsonl"
    expected = HERE / f"{name}.expected"
    with tempfile.TemporaryDirectory(prefix=f"kmpipe-{name}-") as tmp:
        folder = Path(tmp) / "F1"
        new_log = Path(tmp) / "session.jsonl"
        stderr = io.StringIO()
        started = time.monotonic()
        with emulator_from_script(SCRIPT, time_scale=TIME_SCALE, faults=scenario.faults) as emulator:
            argv = ["measure", str(PLAN), "--port", emulator.port, "--record", str(new_log), "-o", str(folder)]
            with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):  # progress lines
                status = main([*argv, "--unattended"])
            truth = emulator.measurements
        seconds = time.monotonic() - started
        message = stderr.getvalue().replace(str(folder), "{folder}")
        check(name, scenario, status, folder, truth, message)
        log.unlink(missing_ok=True)
        shutil.copyfile(new_log, log)
        shutil.rmtree(expected, ignore_errors=True)
        expected.mkdir()
        for file_name in SESSION_FILES:
            if (folder / file_name).exists():
                shutil.copyfile(folder / file_name, expected / file_name)
        (expected / "exit_status").write_text(f"{status}\n", encoding="ascii")
        if message:
            (expected / "message").write_text(message, encoding="utf-8")
    size = log.stat().st_size + sum(f.stat().st_size for f in expected.iterdir())
    print(f"{name}: exit {status}, {scenario.saved} readings, {seconds:.1f} s, {size / 1024:.0f} KiB ({scenario.note})")


def check(name: str, scenario: Scenario, status: int, folder: Path, truth: list[Measurement], message: str) -> None:
    """Raise SystemExit unless the run had the scenario's outcome."""
    sequence = tomllib.loads(SCRIPT.read_text(encoding="utf-8"))["samples"]["sequence"]
    problems = []
    if status != scenario.exit_status:
        problems.append(f"exit status {status}, expected {scenario.exit_status}: {message.strip()}")
    if len(truth) != scenario.measurements:
        problems.append(f"the emulator made {len(truth)} measurements, expected {scenario.measurements}")
    state = json.loads((folder / "session.json").read_text(encoding="utf-8"))
    columns = [reading["column"] for reading in state["readings"]]
    if len(columns) != scenario.saved:
        problems.append(f"{len(columns)} readings in session.json, expected {scenario.saved}")
    table = read_spectra_csv(folder / "radiance.csv")
    if tuple(table.columns) != tuple(columns):
        problems.append(f"radiance.csv columns {table.columns} differ from session.json's {columns}")
    # every saved reading is one of the emulator's measurements, in order (a retried reading is measured again),
    # of the sample the plan names for it (the script's sequence follows the plan's positions)
    measured = iter(truth)
    for column, sample in zip(columns, sequence, strict=False):
        values = np.asarray(table.column(column), dtype=np.float64)
        match = next((m for m in measured if np.array_equal(values, m.radiance)), None)
        if match is None:
            problems.append(f"radiance of {column} is not one of the emulator's measurements (in order)")
        elif match.sample != sample:
            problems.append(f"{column} measured sample {match.sample}, not {sample}")
    completed = (folder / "manifest.toml").exists()
    if completed != (scenario.exit_status == 0):
        problems.append(f"manifest.toml {'written' if completed else 'missing'} with exit status {status}")
    if scenario.exit_status and f"{scenario.saved} of {READINGS} readings are saved" not in message:
        problems.append(f"the error does not name the readings saved: {message.strip()}")
    if problems:
        raise SystemExit(f"{name}: not recorded:\n  " + "\n  ".join(problems))


def main_script(names: list[str]) -> int:
    unknown = sorted(set(names) - set(SCENARIOS))
    if unknown:
        print(f"unknown scenario(s) {', '.join(unknown)}; known: {', '.join(SCENARIOS)}", file=sys.stderr)
        return 2
    for name in names or SCENARIOS:
        record(name, SCENARIOS[name])
    return 0


if __name__ == "__main__":
    raise SystemExit(main_script(sys.argv[1:]))
