"""A guided CS-2000 measuring session for one sample: ``kmpipe measure PLAN.toml --port URL``.

The plan (TOML, documented in docs/formats.md "Measurement plan") lists the positions to measure in order:
the white standard, each bare backing, the masstone(s) and the films, each a number of times. Every reading
is saved the moment it has been read (the radiance CSV and the session state are rewritten atomically), so an
interrupted session loses nothing and ``--resume`` continues with the first position not yet saved. At the end
the session writes reflectance (white-normalized with the mean of the white readings) and a sample manifest
that ``kmpipe fit`` and ``kmpipe validate`` accept.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import serial
from pydantic import BaseModel, ConfigDict, Field, ValidationError
from rich.console import Console

from instruments.cs2000.driver import CS2000, InstrumentTimeout, Reading
from instruments.cs2000.protocol import CS2000Error, ProtocolError
from kmpipe import __version__
from kmpipe.atomic_write import write_text_atomically
from kmpipe.errors import InputError
from kmpipe.manifest import (
    Thickness,
    field_line,
    input_error,
    located_in,
    parse_thickness_mm,
    read_toml,
    toml_line,
)
from kmpipe.spectra import SpectralTable, read_spectra_csv, write_spectra_csv
from kmpipe.white import certified_reflectance, radiance_to_reflectance

#: SPMS parameters of each speed mode name (internal ND: 0 off, 1 on, 2 auto).
SPEED_MODES = {"normal": 0, "fast": 1, "multi-normal": 2, "manual": 3, "multi-fast": 4}
#: How often a reading is tried when the failure leaves the sample and the instrument as they were.
ATTEMPTS = 3


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class PlanSample(_Strict):
    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
    product: str = ""
    kind: str = ""


class PlanInstrument(_Strict):
    speed: Literal["normal", "fast", "multi-normal", "multi-fast", "manual"] = "normal"
    nd: Literal["off", "on", "auto"] = "auto"
    integration: float | None = Field(default=None, gt=0)  # s: multi-integration time, or manual exposure
    observer: Literal[2, 10] = 2
    repeats: int = Field(default=1, ge=1, le=20)


class PlanWhite(_Strict):
    certified: str = "builtin:baso4"
    repeats: int | None = Field(default=None, ge=1, le=20)


class PlanBacking(_Strict):
    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_-]+$")


class _WithThickness(_Strict):
    thickness: Thickness | None = None  # e.g. "30 um"


class PlanMasstone(_WithThickness):
    pass


class PlanFilm(_WithThickness):
    over: str


class Plan(_Strict):
    sample: PlanSample
    instrument: PlanInstrument = PlanInstrument()
    white: PlanWhite = PlanWhite()
    backing: list[PlanBacking] = Field(min_length=1)
    masstone: list[PlanMasstone] = Field(default_factory=list)
    film: list[PlanFilm] = Field(min_length=1)


def load_plan(path: Path) -> Plan:
    """Read and check a measurement plan; InputError naming the file, line and field on any problem."""
    text, data = read_toml(path, "measurement plan")
    try:
        plan = Plan.model_validate(data)
    except ValidationError as err:
        raise input_error(err, located_in(path, text)) from None
    names = [b.name for b in plan.backing]
    for i, film in enumerate(plan.film):
        if film.over not in names:
            raise InputError(
                f"names backing {film.over!r}; the plan's backings are {', '.join(names)}",
                path=path,
                line=toml_line(text, ("film", i, "over")),
                field=f"film[{i + 1}].over",
            )
    return plan


@dataclass(frozen=True)
class Position:
    """One thing to put under the instrument: what it is, its column name, and its manifest entry."""

    role: str  # white | backing | masstone | film
    column: str
    prompt: str
    over: str | None = None
    thickness: str | None = None


def positions(plan: Plan, thickness_of=None) -> list[Position]:
    """Every reading of the session in order, repeats included (column names end in _1, _2, ... then)."""
    out: list[Position] = []

    def add(role, base, prompt, repeats, **extra):
        for r in range(1, repeats + 1):
            column = base if repeats == 1 else f"{base}_{r}"
            suffix = "" if repeats == 1 else f" (reading {r} of {repeats})"
            out.append(Position(role, column, prompt + suffix, **extra))

    repeats = plan.instrument.repeats
    add("white", "white_standard", "the white standard", plan.white.repeats or repeats)
    for backing in plan.backing:
        add("backing", backing.name, f"the bare {backing.name} backing", repeats, over=backing.name)
    for i, masstone in enumerate(plan.masstone):
        base = "masstone" if len(plan.masstone) == 1 else f"masstone{i + 1}"
        add("masstone", base, "the masstone (opaque layer)", repeats, thickness=masstone.thickness)
    for i, film in enumerate(plan.film):
        thickness = film.thickness or (thickness_of(i, film) if thickness_of else None)
        if thickness is None:
            raise InputError(
                "has no thickness; give it in the plan for an unattended session", field=f"film[{i + 1}].thickness"
            )
        um = parse_thickness_mm(thickness) * 1000.0
        add(
            "film",
            f"film_{um:g}um_over_{film.over}",
            f"the {thickness} film over {film.over}",
            repeats,
            over=film.over,
            thickness=thickness,
        )
    names = [p.column for p in out]
    if len(set(names)) != len(names):
        duplicated = sorted({n for n in names if names.count(n) > 1})
        raise InputError(f"two plan entries give the same reading name {duplicated[0]!r}; use repeats instead")
    return out


class Session:
    """The files of one session folder: radiance.csv, session.json, and at the end reflectance.csv and manifest.toml."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.radiance_path = folder / "radiance.csv"
        self.state_path = folder / "session.json"
        self.readings: dict[str, np.ndarray] = {}
        self.state: dict = {"kmpipe_session": 1, "readings": []}

    def load(self) -> None:
        """Pick up a session that was interrupted (``--resume``)."""
        if not self.state_path.exists():
            return
        self.state = json.loads(self.state_path.read_text(encoding="utf-8"))
        table = read_spectra_csv(self.radiance_path)
        for entry in self.state["readings"]:
            self.readings[entry["column"]] = np.asarray(table.column(entry["column"]), dtype=np.float64)

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
    """reflectance.csv (white-normalized with the mean of the white readings; each bare backing as the mean of
    its readings; every masstone and film reading as it is) and manifest.toml; returns the manifest path."""
    wavelengths = np.arange(380.0, 781.0)

    def readings_of(role: str, over: str | None = None) -> list[str]:
        return [p.column for p in steps if p.role == role and (over is None or p.over == over)]

    whites = readings_of("white")
    white = np.mean([session.readings[c] for c in whites], axis=0)
    certified = certified_reflectance(plan.white.certified, wavelengths, base_dir=session.folder)

    def reflectance(radiance: np.ndarray, column: str) -> np.ndarray:
        return radiance_to_reflectance(radiance, white, certified, source=f"{session.radiance_path}:{column}")

    columns: dict[str, np.ndarray] = {}
    lines = [
        "# Written by kmpipe measure: reflectance.csv is radiance.csv normalized by the mean white reading.",
        "[sample]",
        f"name = {json.dumps(plan.sample.name)}",
        f"product = {json.dumps(plan.sample.product)}",
        f"kind = {json.dumps(plan.sample.kind)}",
        "",
    ]
    for backing in plan.backing:
        names = readings_of("backing", backing.name)
        columns[backing.name] = reflectance(np.mean([session.readings[c] for c in names], axis=0), names[0])
        lines += [
            "[[backing]]",
            f'name = "{backing.name}"',
            'file = "reflectance.csv"',
            f'column = "{backing.name}"',
            "",
        ]
    for p in steps:
        if p.role in ("masstone", "film"):
            columns[p.column] = reflectance(session.readings[p.column], p.column)
            lines += [f"[[{p.role}]]", 'file = "reflectance.csv"', f'column = "{p.column}"']
            if p.role == "film":
                lines.append(f'over = "{p.over}"')
            if p.thickness:
                lines.append(f'thickness = "{p.thickness}"')
            lines.append("")
    instrument = session.state.get("instrument", {})
    metadata = {
        "quantity": "reflectance",
        "units": "1",
        "instrument": instrument.get("model", "Konica Minolta CS-2000"),
        "serial": instrument.get("serial", ""),
        "white_reference": f"mean of {', '.join(whites)} in radiance.csv x {plan.white.certified}",
        "backings": "each bare backing is the mean of its readings",
    }
    table = SpectralTable(wavelengths, None, tuple(columns), np.array(list(columns.values())), metadata)
    write_spectra_csv(table, session.folder / "reflectance.csv")
    manifest = session.folder / "manifest.toml"
    write_text_atomically(manifest, "\n".join(lines))
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


def _read_with_retries(instrument: CS2000, progress) -> Reading:
    """One reading, tried again (at most `ATTEMPTS` times) when the failure left sample and instrument as
    they were: "busy" answers, "no data" (ER20), a reply that did not come in time. Anything else (over range,
    hardware faults, a vanished port) is raised at once."""
    for attempt in range(1, ATTEMPTS + 1):
        try:
            return instrument.take_reading(progress=progress)
        except CS2000Error as err:
            if attempt == ATTEMPTS or not (err.busy or err.code == "ER20"):
                raise
            instrument.wait_until_idle(60.0)
        except InstrumentTimeout:
            if attempt == ATTEMPTS:
                raise
            instrument.wait_until_idle(60.0)
    raise AssertionError("unreachable")  # the loop returns or raises


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
    """Measure every position of the plan not yet saved; returns the manifest written at the end."""
    console = console or Console()
    plan = load_plan(plan_path)
    folder = out_dir or plan_path.parent / plan.sample.name
    session = Session(folder)
    if session.state_path.exists() and not resume:
        raise InputError(
            "already holds a measuring session; run with --resume to continue it, or choose another -o", path=folder
        )
    if resume:
        session.load()
    interactive = sys.stdin.isatty() if interactive is None else interactive

    def ask_thickness(i: int, film: PlanFilm) -> str:
        while True:
            text = console.input(f"Thickness of film {i + 1} (over {film.over}), e.g. 30 um: ").strip()
            try:
                parse_thickness_mm(text)
                return text
            except ValueError as err:
                console.print(f"[red]{err}[/]")

    try:
        steps = positions(plan, ask_thickness if interactive else None)
    except InputError as err:
        if err.path is None and err.field:
            err.path, err.line = plan_path, field_line(plan_path, err.field)
        raise
    todo = [p for p in steps if p.column not in session.readings]
    if session.readings:
        console.print(f"resuming: {len(session.readings)} of {len(steps)} readings already saved in {folder}")
    try:
        if record is not None:
            from instruments.session_log import open_recorded

            record.parent.mkdir(parents=True, exist_ok=True)
            port = open_recorded(port_url, record, baudrate=baudrate, rtscts=rtscts)
        else:
            port = serial.serial_for_url(port_url, baudrate=baudrate, rtscts=rtscts)
    except (serial.SerialException, OSError, ValueError) as err:
        raise InputError(f"cannot open the instrument port {port_url!r}: {err}", field="--port") from None
    instrument = CS2000(port)
    done = len(session.readings)
    folder.mkdir(parents=True, exist_ok=True)
    try:
        mode = instrument.remote(True)
        identity = instrument.identity()
        info = {"model": f"Konica Minolta {identity.model}", "serial": identity.serial, "remote_mode": mode}
        console.print(f"connected: {identity.model} serial {identity.serial} on {port_url}")
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

                reading = _read_with_retries(instrument, progress)
            session.save(position, reading, info)
            done += 1
            c = reading.colorimetry
            lv, x, y = c.get("Lv"), c.get("x"), c.get("y")
            summary = "calculation error" if None in (lv, x, y) else f"Lv {lv:.4g} cd/m2, x {x:.4f}, y {y:.4f}"
            console.print(f"  [{done}/{len(steps)}] {position.column}: {summary} ({reading.measuring_seconds} s)")
        manifest = _finish(session, plan, steps)
    except KeyboardInterrupt:
        with contextlib.suppress(Exception):  # stop a measurement in progress; the saved readings stay
            instrument.cancel()
        console.print(f"interrupted: {done} of {len(steps)} readings are saved in {folder}; --resume continues")
        raise
    except (CS2000Error, InstrumentTimeout, ProtocolError, serial.SerialException, OSError) as err:
        raise InputError(
            f"the instrument session stopped: {err}. {done} of {len(steps)} readings are saved in {folder}; "
            "fix the cause and run the same command with --resume to measure the rest",
            field="--port",
        ) from None
    finally:
        instrument.reply_timeout = 2.0  # a silent instrument must not hold the error message back for long
        with contextlib.suppress(Exception):  # the port may be gone; the readings are already safe on disk
            instrument.set_measure_button(True)
            instrument.remote(False)
        instrument.close()
    console.print(f"wrote {session.radiance_path}, {folder / 'reflectance.csv'} and {manifest}")
    return manifest
