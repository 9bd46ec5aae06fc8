"""Emulator samples scripts (TOML) for ``kmpipe emulate``: what lies under the emulated CS-2000, and how it behaves.

The format is documented in ``docs/formats.md`` ("Emulator samples script"): ``[samples]`` names a reflectance CSV
(read by :func:`~kmpipe.formats.spectra.read_spectra_csv`, the one reader of the spectral CSV format) and the
sequence put under the instrument, the illuminant (resolved by
:func:`~kmpipe.physics.colorimetry.illuminant_key`, as in scenes, recipes and validation), gain, noise, seed and time
scale; ``[instrument]`` its identity; ``[[faults]]`` (or ``[faults.NAME]``) the faults to inject. Values are taken as
written (a number is not given as text, nor a string as a number). Every problem is an
:class:`~kmpipe.errors.InputError` naming the file, line and field; what is read is handed to the emulator
(:class:`instruments.cs2000.emulator.server.Emulator`) as plain values and arrays.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import ConfigDict, Field, ValidationError, field_validator

from instruments.cs2000.emulator.faults import FAULT_KINDS, Fault
from instruments.cs2000.emulator.radiometry import illuminant_spd
from instruments.cs2000.emulator.server import Emulator
from instruments.cs2000.protocol import WAVELENGTHS
from kmpipe.errors import InputError
from kmpipe.formats.files import regular_file
from kmpipe.formats.sample import named_in
from kmpipe.formats.spectra import format_number, read_spectra_csv
from kmpipe.formats.toml_input import StrictModel, format_field, input_error, read_toml, toml_line
from kmpipe.physics.colorimetry import illuminant_key


class _Table(StrictModel):
    model_config = ConfigDict(strict=True)


class SamplesTable(_Table):
    """``[samples]``; a key left out keeps the emulator's default."""

    file: str = Field(min_length=1)
    sequence: list[str] | None = None
    illuminant: str | None = None
    gain: float | None = Field(default=None, gt=0)
    noise: float | None = Field(default=None, ge=0)
    seed: int | None = Field(default=None, ge=0)
    time_scale: float | None = Field(default=None, gt=0)

    @field_validator("illuminant")
    @classmethod
    def _known_illuminant(cls, value: str | None) -> str | None:
        """colour-science's key of the illuminant (ValueError: unknown, or not covering 380-780 nm)."""
        if value is None:
            return None
        key = illuminant_key(value)
        illuminant_spd(key)
        return key


class InstrumentTable(_Table):
    """``[instrument]``: the identity the emulator reports."""

    model: Literal["CS-2000", "CS-2000A"] | None = None
    serial: str | None = None
    firmware: str | None = None

    @field_validator("serial")
    @classmethod
    def _seven_digits(cls, value: str | None) -> str | None:
        if value is not None and not re.fullmatch(r"[0-9]{7}", value):
            raise ValueError(f"a serial number is 7 digits, such as 1234567, got {value!r}")
        return value

    @field_validator("firmware")
    @classmethod
    def _dotted_numbers(cls, value: str | None) -> str | None:
        if value is not None and not re.fullmatch(r"[0-9]+(\.[0-9]+)*", value):
            raise ValueError(f"a firmware version is dotted numbers, such as 3.00.9301, got {value!r}")
        return value


class FaultTable(_Table):
    """One fault: the fields of :class:`~instruments.cs2000.emulator.faults.Fault` (``garbage`` as text whose
    characters are the bytes 0-255); a key left out keeps the fault's default."""

    kind: Literal[FAULT_KINDS]
    command: str | None = None
    occurrence: int | None = Field(default=None, ge=1)
    at: Literal["reply", "completion"] | None = None
    seconds: float | None = Field(default=None, ge=0)
    chunk_size: int | None = Field(default=None, ge=1)
    garbage: str | None = None
    code: str | None = None
    fraction: float | None = Field(default=None, ge=0, le=1)
    values: dict[str, float] | None = None

    @field_validator("garbage")
    @classmethod
    def _bytes(cls, value: str | None) -> str | None:
        if value is not None and any(ord(c) > 255 for c in value):
            raise ValueError("garbage is text whose characters are the bytes to send, \\u0000 to \\u00ff")
        return value

    def fault(self) -> Fault:
        """The fault (ValueError for fields that do not go together, e.g. a colorimetry fault on MEAS)."""
        options = self.model_dump(exclude_none=True)
        if "garbage" in options:
            options["garbage"] = options["garbage"].encode("latin-1")
        return Fault(**options)


class ScriptFile(_Table):
    samples: SamplesTable
    instrument: InstrumentTable = InstrumentTable()
    faults: list[FaultTable] = Field(default=[])


def read_reflectance_samples(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """The samples of a reflectance CSV, each linearly interpolated to the emulator's 380-780 nm at 1 nm.

    A spectral CSV (``docs/formats.md``) whose quantity, if given, is reflectance and whose wavelengths cover
    380-780 nm; returns column name -> (401,) reflectance (fraction).

    Raises
    ------
    InputError
        Naming the file (line and column where they apply): what :func:`~kmpipe.formats.spectra.read_spectra_csv`
        refuses, camera channels, another quantity, wavelengths that do not cover 380-780 nm.
    """
    table = read_spectra_csv(path)
    if table.wavelengths is None:
        raise InputError("holds camera channels; the emulator needs reflectance spectra (a wavelength_nm column)",
                         path=table.path, field="channel")  # fmt: skip
    quantity = table.metadata.get("quantity", "reflectance")
    if quantity != "reflectance":
        raise InputError(f"holds {quantity}; the emulator needs reflectance ('# quantity: reflectance')",
                         path=table.path, field="quantity")  # fmt: skip
    low, high = table.wavelengths[0], table.wavelengths[-1]
    if low > WAVELENGTHS[0] or high < WAVELENGTHS[-1]:
        raise InputError(f"its wavelengths, {format_number(low)}-{format_number(high)} nm, do not cover 380-780 nm, "
                         "what the emulated instrument measures", path=table.path, field="wavelength_nm")  # fmt: skip
    return {
        name: np.interp(WAVELENGTHS, table.wavelengths, values)
        for name, values in zip(table.columns, table.values, strict=True)
    }


def load_emulator_script(path: str | os.PathLike[str]) -> dict[str, object]:
    """The emulator settings a samples script gives (keyword arguments of
    :class:`~instruments.cs2000.emulator.server.Emulator`: ``samples``, ``faults`` and those the script sets).

    A ``.csv`` path is read as the reflectance file alone (:func:`read_reflectance_samples`). The reflectance file
    a script names is relative to the script; a problem in it is reported at that file, naming the script too.

    Raises
    ------
    InputError
        Naming the file, line and field: an unreadable or invalid script, an unknown table or key, a value of the
        wrong type or out of range, an unknown illuminant, a sequence naming a sample the reflectance file does not
        have, a fault whose fields do not go together, a broken reflectance file.
    """
    path = Path(path)
    if path.suffix.lower() == ".csv":
        return {"samples": read_reflectance_samples(path)}
    text, data = read_toml(path, "emulator samples script")
    names: list[str] = []  # the faults' names when given as [faults.NAME] tables
    if isinstance(data.get("faults"), dict):
        names = list(data["faults"])
        data = data | {"faults": list(data["faults"].values())}

    def where(loc: tuple) -> dict:
        if names and loc[:1] == ("faults",) and len(loc) > 1 and isinstance(loc[1], int):
            table, rest = f"faults.{names[loc[1]]}", loc[2:]
            return {"path": path, "line": toml_line(text, (table, *rest)), "field": format_field((table, *rest))}
        return {"path": path, "line": toml_line(text, loc), "field": format_field(loc)}

    try:
        script = ScriptFile.model_validate(data)
    except ValidationError as err:
        raise input_error(err, where) from None
    faults = []
    for i, table in enumerate(script.faults):
        try:
            faults.append(table.fault())
        except ValueError as err:
            raise InputError(str(err), **where(("faults", i))) from None
    file_where = where(("samples", "file"))
    reflectance = path.parent / script.samples.file
    try:
        regular_file(reflectance, "spectral CSV")
    except InputError as err:
        raise InputError(f"names the file {script.samples.file!r}, which {err.message} (looked for {reflectance})",
                         **file_where) from None  # fmt: skip
    try:
        samples = read_reflectance_samples(reflectance)
    except InputError as err:
        raise named_in(err, path, file_where["field"], file_where["line"]) from None
    unknown = sorted(set(script.samples.sequence or ()) - set(samples))
    if unknown:
        raise InputError(f"names unknown sample(s) {', '.join(unknown)}; {script.samples.file} has "
                         f"{', '.join(samples)}", **where(("samples", "sequence")))  # fmt: skip
    settings: dict[str, object] = {"samples": samples, "faults": faults}
    settings |= script.samples.model_dump(exclude_none=True, exclude={"file"})
    identity = script.instrument.model_dump(exclude_none=True)
    settings |= {{"serial": "serial_number"}.get(key, key): value for key, value in identity.items()}
    return settings


def emulator_from_script(path: str | os.PathLike[str], **overrides: object) -> Emulator:
    """An emulator (not started) with the settings of a samples script (:func:`load_emulator_script`);
    ``overrides`` (any :class:`~instruments.cs2000.emulator.server.Emulator` keyword) win over the script's."""
    return Emulator(**(load_emulator_script(path) | overrides))  # type: ignore[arg-type]
