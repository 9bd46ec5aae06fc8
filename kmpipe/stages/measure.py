"""A guided CS-2000 measuring session for one sample: ``kmpipe measure PLAN.toml --port URL``.

The plan (TOML, documented in docs/formats.md "Measurement plan") lists the positions to measure in order:
the white standard, each bare backing, the masstone(s) and the films, each a number of times. Every reading
is saved the moment it has been read (the radiance CSV and the session state are rewritten atomically), so an
interrupted session loses nothing and ``--resume`` continues with the first position not yet saved. At the end
the session writes reflectance (white-normalized with the mean of the white readings) and a sample manifest
that ``kmpipe fit`` and ``kmpipe validate`` accept.

A session follows one plan: session.json records the plan's SHA-256 and sample name, a recorded session log
(``--record``) carries them in its header's ``meta``, and ``--resume`` or a replay (``replay://LOG``) with another
plan is refused before anything is opened or written. Every reading's colorimetric values are checked against its
spectrum (a mismatch is a transfer error: the data are read again).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import math
import os
import sys
from pathlib import Path

import numpy as np
import serial
import tomli_w
from rich.console import Console
from rich.markup import escape

from instruments.cs2000.driver import CS2000, InstrumentTimeout, Reading
from instruments.cs2000.protocol import WAVELENGTHS, CS2000Error, ProtocolError
from instruments.session_log import SessionLogError, read_session_log
from instruments.urlhandler.protocol_replay import parse_url
from kmpipe import __version__
from kmpipe.errors import InputError
from kmpipe.formats.atomic_write import write_text_atomically
from kmpipe.formats.files import (
    output_file,
    output_folder,
    read_bytes,
    read_text,
    refuse_inputs,
    regular_file,
    same_file,
)
from kmpipe.formats.manifest import parse_measured_thickness
from kmpipe.formats.measurement_plan import (
    Plan,
    PlanFilm,
    PlanInstrument,
    Position,
    load_plan,
    plan_digest,
    positions,
    skin_readings,
)
from kmpipe.formats.spectra import SpectralTable, read_spectra_csv, write_spectra_csv
from kmpipe.formats.toml_input import field_line
from kmpipe.physics.colorimetry import cmfs
from kmpipe.physics.white import certified_reflectance, radiance_to_reflectance

#: SPMS parameters of each speed mode name (internal ND: 0 off, 1 on, 2 auto).
SPEED_MODES = {"normal": 0, "fast": 1, "multi-normal": 2, "manual": 3, "multi-fast": 4}
#: How often a reading is tried when the failure leaves the sample and the instrument as they were.
ATTEMPTS = 3
#: Version of session.json (``kmpipe_session``); version 1 did not record the plan it follows.
SESSION_FORMAT = 2
#: The files a session folder holds, in the order they are written.
SESSION_FILES = ("radiance.csv", "session.json", "reflectance.csv", "manifest.toml")
#: How far an instrument's colorimetric values may lie from those of its own spectrum (its rounding, its finer
#: internal grid): chromaticity x, y; Lv relative, with a floor in cd m-2 for the 6-character field's last digit.
XY_TOLERANCE = 0.005
LV_TOLERANCE = 0.02
LV_FLOOR = 1e-4


class Session:
    """The files of one session folder: radiance.csv, session.json, and at the end reflectance.csv and manifest.toml.

    ``plan`` is what session.json records of the plan the session follows: ``{"sample": name, "sha256": hex}``.
    """

    def __init__(self, folder: Path, plan: dict[str, str]) -> None:
        self.folder = folder
        self.radiance_path = folder / "radiance.csv"
        self.state_path = folder / "session.json"
        self.readings: dict[str, np.ndarray] = {}
        self.state: dict = {"kmpipe_session": SESSION_FORMAT, "plan": dict(plan), "readings": []}

    def damaged(self, path: Path, problem: str, line: int | None = None) -> InputError:
        """The error for a damaged session file: what is wrong, and that nothing in the folder was changed."""
        return InputError(
            f"{problem}, so the session cannot be resumed. Nothing in {self.folder} was changed (the saved readings "
            "are untouched): restore the file from a backup, or measure afresh into another folder (-o)",
            path=path,
            line=line,
        )

    def load(self, plan_path: Path, steps: list[Position]) -> None:
        """Pick up a session that was interrupted (``--resume``), reading only: InputError, before anything is
        written, for a session that follows another plan, an older session.json that does not record its plan,
        or damaged files (session.json that is not the state kmpipe writes, a listed reading missing from
        radiance.csv, a radiance.csv cut short)."""
        if not self.state_path.exists():
            return
        try:
            text = read_text(self.state_path, "session state")
        except InputError as err:
            raise self.damaged(self.state_path, err.message) from None
        try:
            state = json.loads(text)
        except ValueError as err:
            raise self.damaged(self.state_path, f"is not JSON ({getattr(err, 'msg', err)})",
                                getattr(err, "lineno", None)) from None  # fmt: skip
        if not isinstance(state, dict) or not isinstance(state.get("readings"), list):
            raise self.damaged(self.state_path, "is not a measuring session's state (an object with 'readings')")
        wanted = self.state["plan"]
        recorded = state.get("plan")
        if state.get("kmpipe_session") == 1 or "plan" not in state:
            raise InputError(
                f"was written by an older kmpipe that did not record the plan a session follows, so it cannot be "
                f"checked against {plan_path} (sample {wanted['sample']}); measure afresh into another folder (-o)",
                path=self.state_path,
                field="plan",
            )
        if state.get("kmpipe_session") != SESSION_FORMAT or not isinstance(recorded, dict):
            raise self.damaged(self.state_path, f"is not a version {SESSION_FORMAT} session state")
        if recorded != wanted:
            raise InputError(
                f"the session follows plan {str(recorded.get('sha256'))[:12]} of sample {recorded.get('sample')}, "
                f"not {plan_path} (sample {wanted['sample']}, plan {wanted['sha256'][:12]}); resume it with the "
                "plan it was started with, or measure this plan into another folder (-o)",
                path=self.state_path,
                field="plan",
            )
        known = {p.column for p in steps}
        columns = [entry.get("column") if isinstance(entry, dict) else None for entry in state["readings"]]
        for i, column in enumerate(columns, start=1):
            if column not in known or columns.index(column) != i - 1:
                raise self.damaged(self.state_path, f"reading {i} is {column!r}, not a position of the plan once")
        if not columns:
            self.state = state
            return
        try:
            table = read_spectra_csv(self.radiance_path)
            ends_whole = read_bytes(self.radiance_path, "spectral CSV").endswith(b"\n")
        except InputError as err:
            raise self.damaged(err.path or self.radiance_path, err.message, err.line) from None
        if not ends_whole or table.wavelengths is None or not np.array_equal(table.wavelengths, WAVELENGTHS):
            raise self.damaged(self.radiance_path, "is cut short or altered: expected the full 380-780 nm at 1 nm "
                                "ending in a line feed, as kmpipe writes it")  # fmt: skip
        for column in columns:
            if column not in table.columns:
                raise self.damaged(self.radiance_path, f"has no column {column!r}, a reading that session.json "
                                    "lists as saved")  # fmt: skip
        self.state = state
        for column in columns:
            self.readings[column] = np.asarray(table.column(column), dtype=np.float64)

    def save(self, position: Position, reading: Reading, instrument: dict) -> None:
        """Add one reading and rewrite both files atomically (radiance first, then the state that lists it)."""
        self.readings[position.column] = reading.radiance
        colorimetry = reading.colorimetry
        self.state["instrument"] = instrument
        self.state["readings"].append(
            {
                "column": position.column,
                "role": position.role,
                "time": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
                "measuring_seconds": reading.measuring_seconds,
                "Lv": colorimetry.get("Lv"),
                "x": colorimetry.get("x"),
                "y": colorimetry.get("y"),
                "conditions": dict(vars(reading.conditions)),
            }
        )
        self.write_radiance(instrument)
        write_text_atomically(self.state_path, json.dumps(self.state, indent=1) + "\n")

    def write_radiance(self, instrument: dict) -> None:
        columns = tuple(self.readings)
        metadata = {
            "quantity": "radiance",
            "units": "W sr-1 m-2 nm-1",
            "instrument": instrument.get("model", "Konica Minolta CS-2000"),
            "serial": instrument.get("serial", ""),
            "time": self.state["readings"][0]["time"] if self.state["readings"] else "",
            "note": f"kmpipe {__version__} measure session",
        }
        table = SpectralTable(
            np.arange(380.0, 781.0), None, columns, np.array([self.readings[c] for c in columns]), metadata
        )
        write_spectra_csv(table, self.radiance_path)


def _finish(session: Session, plan: Plan, steps: list[Position]) -> Path:
    """reflectance.csv (white-normalized with the mean of the white readings; each bare backing and each bare skin as
    the mean of its readings; every masstone and film reading as it is) and manifest.toml (without the skin: it is
    not part of the sample's fit); returns the manifest path."""
    wavelengths = np.arange(380.0, 781.0)

    def readings_of(role: str, over: str | None = None) -> list[str]:
        return [p.column for p in steps if p.role == role and (over is None or p.over == over)]

    whites = readings_of("white")
    white = np.mean([session.readings[c] for c in whites], axis=0)
    certified = certified_reflectance(plan.white.certified, wavelengths, base_dir=session.folder)

    def reflectance(radiance: np.ndarray, column: str) -> np.ndarray:
        return radiance_to_reflectance(radiance, white, certified, source=f"{session.radiance_path}:{column}")

    columns: dict[str, np.ndarray] = {}
    sample = {"name": plan.sample.name, "product": plan.sample.product, "kind": plan.sample.kind}
    measured: dict[str, list[dict[str, str]]] = {"backing": [], "masstone": [], "film": []}
    for backing in plan.backing:
        names = readings_of("backing", backing.name)
        columns[backing.name] = reflectance(np.mean([session.readings[c] for c in names], axis=0), names[0])
        measured["backing"].append({"name": backing.name, "file": "reflectance.csv", "column": backing.name})
    for p in steps:
        if p.role in ("masstone", "film"):
            columns[p.column] = reflectance(session.readings[p.column], p.column)
            entry = {"file": "reflectance.csv", "column": p.column}
            if p.role == "film":
                entry["over"] = p.over
            if p.thickness:
                entry["thickness"] = p.thickness
            measured[p.role].append(entry)
    for column, names in skin_readings(plan).items():  # skin tones for shade reviews: the mean of their readings
        columns[column] = reflectance(np.mean([session.readings[c] for c in names], axis=0), names[0])
    sites = {f"site.skin_{skin.name}": skin.site for skin in plan.skin if skin.site}
    instrument = session.state.get("instrument", {})
    metadata = {
        "quantity": "reflectance",
        "units": "1",
        "instrument": instrument.get("model", "Konica Minolta CS-2000"),
        "serial": instrument.get("serial", ""),
        "white_reference": f"mean of {', '.join(whites)} in radiance.csv x {plan.white.certified}",
        "backings": "each bare backing is the mean of its readings",
        **({"skin": "each bare skin (skin_NAME) is the mean of its readings"} if plan.skin else {}),
        **sites,
    }
    table = SpectralTable(wavelengths, None, tuple(columns), np.array(list(columns.values())), metadata)
    write_spectra_csv(table, session.folder / "reflectance.csv")
    manifest = session.folder / "manifest.toml"
    header = "# Written by kmpipe measure: reflectance.csv is radiance.csv normalized by the mean white reading.\n"
    tables = {"sample": sample} | {role: entries for role, entries in measured.items() if entries}
    write_text_atomically(manifest, header + tomli_w.dumps(tables))
    return manifest


def _speed_parameters(instrument: PlanInstrument) -> tuple[int, ...]:
    """SPMS parameters for the plan's speed mode, internal ND filter and integration time."""
    nd = {"off": 0, "on": 1, "auto": 2}[instrument.nd]
    mode = SPEED_MODES[instrument.speed]
    if instrument.speed in ("normal", "fast"):
        return (mode, nd)
    if instrument.integration is None:
        raise InputError(f"speed {instrument.speed!r} needs an integration time (s)", field="instrument.integration")
    if instrument.speed == "manual":
        if nd == 2:
            raise InputError("manual speed mode takes nd 'off' or 'on', not 'auto'", field="instrument.nd")
        microseconds = round(instrument.integration * 1e6)
        if not 5000 <= microseconds <= 120_000_000:
            raise InputError("manual integration time must lie in 0.005-120 s", field="instrument.integration")
        return (mode, microseconds, nd)
    seconds = round(instrument.integration)
    if not 1 <= seconds <= 16:
        raise InputError("multi-integration time must be 1-16 s", field="instrument.integration")
    return (mode, seconds, nd)


def colorimetry_problem(radiance: np.ndarray, colorimetry: dict[str, float | None]) -> str | None:
    """Why a reading's colorimetric block cannot have come with its spectrum (None when it can).

    ``radiance``: W sr-1 m-2 nm-1 at 380-780 nm, 1 nm; ``colorimetry``: the instrument's ``Lv`` (cd m-2), ``x``,
    ``y`` (CIE 1931 2 deg). Plausible: x, y in [0, 1] with x + y <= 1, Lv finite and >= 0. Consistent: within
    :data:`XY_TOLERANCE` of x, y and :data:`LV_TOLERANCE` (at least :data:`LV_FLOOR`) of Lv computed from the
    spectrum, X, Y, Z = 683 lm W-1 x sum L cmf dlambda (CIE 15:2018 eq. 7.1, 1 nm steps), Lv = Y. Sentinels
    (None: the instrument could not compute a value) are not checked.
    """
    lv, x, y = (colorimetry.get(k) for k in ("Lv", "x", "y"))
    for name, value in (("x", x), ("y", y)):
        if value is not None and not 0.0 <= value <= 1.0:
            return f"chromaticity {name} = {value:g} lies outside 0-1"
    if x is not None and y is not None and x + y > 1.0:
        return f"chromaticity x + y = {x + y:g} exceeds 1"
    if lv is not None and not (math.isfinite(lv) and lv >= 0.0):
        return f"Lv = {lv:g} cd/m2 is not a luminance (finite, >= 0)"
    xyz = 683.0 * np.asarray(radiance, dtype=np.float64) @ cmfs("2")[WAVELENGTHS]
    if lv is not None and abs(lv - xyz[1]) > max(LV_TOLERANCE * abs(xyz[1]), LV_FLOOR):
        return f"Lv = {lv:.6g} cd/m2, but its spectrum gives {xyz[1]:.6g} cd/m2"
    total = float(xyz.sum())
    for name, value, index in (("x", x, 0), ("y", y, 1)):
        if value is not None and total > 0 and abs(value - xyz[index] / total) > XY_TOLERANCE:
            return f"chromaticity {name} = {value:.4f}, but its spectrum gives {xyz[index] / total:.4f}"
    return None


class ImplausibleReading(Exception):
    """A reading whose colorimetric values did not match its spectrum however often it was read."""


def _read_with_retries(instrument: CS2000, progress, column: str) -> Reading:
    """One reading, tried again (at most `ATTEMPTS` times) when the failure left sample and instrument as
    they were: "busy" answers, "no data" (ER20), a reply that did not come in time (measured again), and
    colorimetric values that do not fit the spectrum (a transfer error: the data, still held by the instrument
    with the measure button disabled, are read again). Anything else (over range, hardware faults, a vanished
    port) is raised at once; ImplausibleReading when the values never fit."""
    reading: Reading | None = None
    problem = ""
    for attempt in range(1, ATTEMPTS + 1):
        try:
            if reading is None:
                reading = instrument.take_reading(progress=progress)
            else:
                reading = instrument.read_data(reading.measuring_seconds)
        except CS2000Error as err:
            if attempt == ATTEMPTS or not (err.busy or err.code == "ER20"):
                raise
            instrument.wait_until_idle(60.0)
            reading = None
            continue
        except InstrumentTimeout:
            if attempt == ATTEMPTS:
                raise
            instrument.wait_until_idle(60.0)
            reading = None
            continue
        problem = colorimetry_problem(reading.radiance, reading.colorimetry)
        if problem is None:
            return reading
    raise ImplausibleReading(
        f"reading {column}: the instrument's colorimetric values do not fit the spectrum sent with them "
        f"({problem}; read {ATTEMPTS} times)"
    )


def _replay_log(port_url: str) -> Path | None:
    """The session log a ``replay://`` port reads (checked to be a regular file), or None for another port."""
    if not port_url.lower().startswith("replay://"):
        return None
    try:
        path = Path(parse_url(port_url)[0])
    except serial.SerialException as err:
        raise InputError(str(err), field="--port") from None
    return regular_file(path, "session log", field="--port")


def check_log(log: Path, plan_path: Path, meta: dict[str, str], field: str, console: Console) -> None:
    """Refuse a session log recorded for another sample or plan (its headers' ``meta``: ``sample``,
    ``plan_sha256``); a log without them (recorded before kmpipe wrote them) is accepted with a warning."""
    try:
        connections = read_session_log(log)
    except (OSError, UnicodeDecodeError, SessionLogError) as err:
        raise InputError(f"cannot be read as a session log ({err})", path=log, field=field) from None
    unchecked = False
    for connection in connections:
        recorded = connection.header.get("meta")
        recorded = recorded if isinstance(recorded, dict) else {}
        sample, digest = recorded.get("sample"), recorded.get("plan_sha256")
        if sample is None and digest is None:
            unchecked = True
        elif sample != meta["sample"] or digest != meta["plan_sha256"]:
            raise InputError(
                f"was recorded for sample {sample} (plan sha256 {str(digest)[:12]}), not {meta['sample']} "
                f"({plan_path}, plan sha256 {meta['plan_sha256'][:12]}); use the plan it was recorded with",
                path=log,
                line=connection.line,
                field=field,
            )
    if unchecked:
        console.print(f"[yellow]warning:[/] {escape(str(log))} does not record which sample and plan it measured "
                      f"(recorded by an older kmpipe): it cannot be checked to be a recording of "
                      f"{escape(meta['sample'])}", soft_wrap=True)  # fmt: skip


def _check_outputs(folder: Path, record: Path | None, inputs: list[Path]) -> None:
    """Refuse outputs that are inputs, or each other: the session folder's files (``-o``) must not be the plan
    or the replayed log, and the ``--record`` log must be a file in an existing folder that is neither an input
    nor one of the session folder's files."""
    output_folder(folder, field="-o", create=False)
    files = [folder / name for name in SESSION_FILES]
    for path in files:
        refuse_inputs(path, inputs, field="-o")
    if record is None:
        return
    output_file(record, field="--record", inputs=inputs)
    for path in files:
        if same_file(record, path):
            raise InputError(f"is the session folder's {path.name}; the session log must be kept apart from the "
                             "session's files: choose another --record", path=record, field="--record")  # fmt: skip


def run_session(
    plan_path: Path,
    port_url: str,
    *,
    out_dir: Path | None = None,
    record: Path | None = None,
    resume: bool = False,
    interactive: bool | None = None,
    baudrate: int = 115200,
    rtscts: bool = False,
    console: Console | None = None,
) -> Path:
    """Measure every position of the plan not yet saved; returns the manifest written at the end.

    Before anything is opened or written: the outputs are checked against the inputs (``-o``, ``--record``), a
    replayed log (``replay://LOG``) and a log ``--record`` appends to must have been recorded for this plan, and a
    resumed session must follow it and be undamaged (InputError otherwise, exit status 2).

    >>> import io, kmpipe, pathlib, tempfile
    >>> from rich.console import Console
    >>> repo = pathlib.Path(kmpipe.__file__).parents[1]
    >>> plan = repo / "recipes" / "samples" / "F1" / "plan.toml"
    >>> log = repo / "recipes" / "demo" / "sessions" / "F1.jsonl"  # a recorded session: replayed byte for byte
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "F1"
    >>> quiet = Console(file=io.StringIO())
    >>> manifest = run_session(plan, f"replay://{log}", out_dir=out, interactive=False, console=quiet)
    >>> manifest.name, sorted(p.name for p in out.iterdir())
    ('manifest.toml', ['manifest.toml', 'radiance.csv', 'reflectance.csv', 'session.json'])
    """
    console = console or Console(emoji=False)
    plan = load_plan(plan_path)
    meta = {"sample": plan.sample.name, "plan_sha256": plan_digest(plan_path)}
    folder = out_dir or plan_path.parent / plan.sample.name
    replayed = _replay_log(port_url)
    _check_outputs(folder, record, [plan_path, replayed])
    session = Session(folder, {"sample": meta["sample"], "sha256": meta["plan_sha256"]})
    existing = [path for path in (session.state_path, session.radiance_path) if os.path.lexists(path)]
    if existing and not resume:
        raise InputError(
            "already holds a measuring session; run with --resume to continue it, or choose another -o", path=folder
        )
    if existing and not os.path.lexists(session.state_path):
        raise session.damaged(session.state_path, "is missing beside radiance.csv")
    if replayed is not None:
        check_log(replayed, plan_path, meta, "--port", console)
    if record is not None and os.path.lexists(record) and record.stat().st_size > 0:
        check_log(regular_file(record, "session log", field="--record"), plan_path, meta, "--record", console)
    interactive = sys.stdin.isatty() if interactive is None else interactive

    def ask_thickness(i: int, film: PlanFilm) -> str:
        while True:
            text = console.input(f"Thickness of film {i + 1} (over {film.over}), e.g. 30 um: ").strip()
            try:
                parse_measured_thickness(text)
                return text
            except ValueError as err:
                console.print(f"[red]{escape(str(err))}[/]")

    try:
        steps = positions(plan, ask_thickness if interactive else None)
    except InputError as err:
        if err.path is None and err.field:
            err.path, err.line = plan_path, field_line(plan_path, err.field)
        raise
    if resume:
        session.load(plan_path, steps)
    todo = [p for p in steps if p.column not in session.readings]
    if session.readings:
        console.print(f"resuming: {len(session.readings)} of {len(steps)} readings already saved in {folder}",
                      markup=False)  # fmt: skip
    try:
        if record is not None:
            from instruments.session_log import open_recorded

            port = open_recorded(port_url, record, meta=meta, baudrate=baudrate, rtscts=rtscts)
        else:
            port = serial.serial_for_url(port_url, baudrate=baudrate, rtscts=rtscts)
    except (serial.SerialException, OSError, ValueError) as err:
        raise InputError(f"cannot open the instrument port {port_url!r}: {err}", field="--port") from None
    instrument = CS2000(port)
    done = len(session.readings)
    try:
        output_folder(folder, field="-o")
    except InputError:
        instrument.close()
        raise
    try:
        mode = instrument.remote(True)
        identity = instrument.identity()
        info = {"model": f"Konica Minolta {identity.model}", "serial": identity.serial, "remote_mode": mode}
        console.print(f"connected: {identity.model} serial {identity.serial} on {port_url}", markup=False)
        instrument.set_measure_button(False)  # data stay readable until the next measurement
        instrument.set_speed(*_speed_parameters(plan.instrument))
        instrument.set_observer(plan.instrument.observer)
        previous_prompt = None
        for position in todo:
            prompt = position.prompt.split(" (reading")[0]
            if interactive and prompt != previous_prompt:
                console.input(f"Place [bold]{prompt}[/] under the instrument and press Enter ")
            previous_prompt = prompt
            with console.status(f"measuring {position.column} ...") as status:

                def progress(elapsed: float, announced: int, status=status, column=position.column) -> None:
                    status.update(f"measuring {column}: {elapsed:.0f} of ~{announced} s")

                reading = _read_with_retries(instrument, progress, position.column)
            session.save(position, reading, info)
            done += 1
            c = reading.colorimetry
            lv, x, y = c.get("Lv"), c.get("x"), c.get("y")
            summary = "calculation error" if None in (lv, x, y) else f"Lv {lv:.4g} cd/m2, x {x:.4f}, y {y:.4f}"
            console.print(f"  [{done}/{len(steps)}] {position.column}: {summary} ({reading.measuring_seconds} s)",
                          markup=False)  # fmt: skip
        manifest = _finish(session, plan, steps)
    except KeyboardInterrupt:
        with contextlib.suppress(Exception):  # stop a measurement in progress; the saved readings stay
            instrument.cancel()
        console.print(f"interrupted: {done} of {len(steps)} readings are saved in {folder}; --resume continues",
                      markup=False)  # fmt: skip
        raise
    except (CS2000Error, InstrumentTimeout, ImplausibleReading, ProtocolError, serial.SerialException, OSError) as err:
        raise InputError(
            f"the instrument session stopped: {err}. {done} of {len(steps)} readings are saved in {folder}; "
            "fix the cause and run the same command with --resume to measure the rest",
            path=replayed,  # a replayed session's log, which ran out or broke (None for a live port)
            field="--port",
        ) from None
    finally:
        instrument.reply_timeout = 2.0  # a silent instrument must not hold the error message back for long
        with contextlib.suppress(Exception):  # the port may be gone; the readings are already safe on disk
            instrument.set_measure_button(True)
            instrument.remote(False)
        instrument.close()
    console.print(f"wrote {session.radiance_path}, {folder / 'reflectance.csv'} and {manifest}", markup=False)
    return manifest
