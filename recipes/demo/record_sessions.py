"""Record the CS-2000 session logs that the demo line (``recipe.toml``) replays: one per bundled sample.

Run from the repository root::

    .venv/bin/python recipes/demo/record_sessions.py          # every sample: F1 F2 B1 E1 L1 L2
    .venv/bin/python recipes/demo/record_sessions.py F1 B1    # some of them

For each sample S it starts the CS-2000 emulator on a pseudo-terminal with the sample's script
(``recipes/samples/S/emulator.toml``: its sequence, noise and seed, so the spectra are the same on every run) at a
small time scale, without faults, and runs in-process

    kmpipe measure recipes/samples/S/plan.toml --port <pty> --record <log> -o <folder> --unattended

It writes ``sessions/S.jsonl`` next to this script: the session log (every byte exchanged), which ``kmpipe run``
replays and fits. A log is written only if the session completed (exit status 0, ``reflectance.csv`` written, one
reading per position of the plan); otherwise the script stops and leaves the old log alone.

These logs are recordings of the EMULATED instrument (``instruments/cs2000/emulator/``) measuring SIMULATED
samples (``recipes/samples/simulate_samples.py`` writes their reflectances), not of a real CS-2000 or real cosmetics.
"""

from __future__ import annotations

import contextlib
import io
import json
import shutil
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT))  # run as a script: import kmpipe and instruments from this checkout

from kmpipe.cli import main  # noqa: E402
from kmpipe.formats.emulator_script import emulator_from_script  # noqa: E402

SAMPLES = ("F1", "F2", "B1", "E1", "L1", "L2")
TIME_SCALE = 0.01  # 1 instrument second = 10 ms


def record(sample: str) -> None:
    """Measure one sample on the emulator; check the session completed; write sessions/SAMPLE.jsonl."""
    plan = ROOT / "recipes" / "samples" / sample / "plan.toml"
    script = ROOT / "recipes" / "samples" / sample / "emulator.toml"
    with tempfile.TemporaryDirectory(prefix=f"kmpipe-demo-{sample}-") as tmp:
        folder, new_log = Path(tmp) / sample, Path(tmp) / "session.jsonl"
        stderr = io.StringIO()
        with emulator_from_script(script, time_scale=TIME_SCALE) as emulator:
            argv = ["measure", str(plan), "--port", emulator.port, "--record", str(new_log), "-o", str(folder)]
            with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
                status = main([*argv, "--unattended"])
            measured = len(emulator.measurements)
        readings = len(json.loads((folder / "session.json").read_text(encoding="utf-8"))["readings"])
        if status != 0 or not (folder / "reflectance.csv").is_file() or readings != measured:
            raise SystemExit(f"{sample}: not recorded (exit status {status}, {readings} readings saved of "
                             f"{measured} measured, reflectance.csv "
                             f"{'written' if (folder / 'reflectance.csv').is_file() else 'missing'}):\n"
                             f"{stderr.getvalue().strip()}")  # fmt: skip
        log = HERE / "sessions" / f"{sample}.jsonl"
        log.parent.mkdir(exist_ok=True)
        shutil.copyfile(new_log, log)
    print(f"{sample}: {readings} readings, {log.relative_to(ROOT)} ({log.stat().st_size / 1024:.0f} KiB)")


if __name__ == "__main__":
    unknown = sorted(set(sys.argv[1:]) - set(SAMPLES))
    if unknown:
        raise SystemExit(f"unknown sample(s) {', '.join(unknown)}; known: {', '.join(SAMPLES)}")
    for name in sys.argv[1:] or SAMPLES:
        record(name)
