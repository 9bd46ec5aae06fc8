"""The input layer of the files people write (TOML): one strict pydantic base for their models, reading a TOML
file safely, and turning a validation error into an InputError at its file, line and field.

Every format people write (sample manifests, measurement plans, render scenes, recipes, validation thresholds) reads
through :func:`read_toml` and validates with a model derived from :class:`StrictModel`: unknown keys are refused (a
misspelt key is never silently ignored), models are frozen, and a number that is NaN or infinite is refused where
it is read.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

from kmpipe.errors import InputError
from kmpipe.formats import files


class StrictModel(BaseModel):
    """The base of every model of a file people write: unknown keys refused, frozen, finite numbers only."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def toml_line(text: str, loc: tuple) -> int | None:
    """1-based line of the field at ``loc`` (e.g. ('film', 1, 'thickness'), ('product', 0, 'layer', 2, 'material'))
    in TOML text, if found; else the line of the nearest enclosing table found.

    Tables are followed down their dotted headers (``[[product]]`` then ``[[product.layer]]`` within it), each
    index picking among the headers of that name; a key is looked for in its table before any further header.
    """
    lines = text.splitlines()
    parts = [p for p in loc if not isinstance(p, str) or p]
    start, end, prefix, best = 0, len(lines), "", None
    i = 0
    while i < len(parts) and isinstance(parts[i], str):
        name = parts[i]
        index = parts[i + 1] if i + 1 < len(parts) and isinstance(parts[i + 1], int) else None
        dotted = f"{prefix}.{name}" if prefix else name
        header = re.compile(r"^\s*\[\[?\s*" + re.escape(dotted) + r"\s*\]\]?\s*(#.*)?$")
        found, seen = None, -1
        for number in range(start, end):
            if header.match(lines[number]):
                seen += 1
                if index is None or seen == index:
                    found = number
                    break
        if found is None:  # a key of the current table (a value, an inline table or an inline array)
            key = re.compile(r"^\s*" + re.escape(str(name)) + r"\s*=")
            for number in range(start, end):
                if number > start and _HEADER.match(lines[number]) and best is not None:
                    break
                if key.match(lines[number]):
                    return number + 1
            return best
        best = found + 1
        inner = dotted + "."
        start, end = (
            found + 1,
            next(
                (
                    n
                    for n in range(found + 1, end)
                    if (m := _HEADER.match(lines[n])) and not m.group(1).startswith(inner)
                ),
                end,
            ),
        )
        prefix = dotted
        i += 1 if index is None else 2
    return best


_HEADER = re.compile(r"^\s*\[\[?\s*([^\]\s]+)")


def format_field(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part + 1}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def field_line(path: Path, field: str) -> int | None:
    """Line of a field named like 'film[2].column' or 'white.file' in a manifest file, if it can be found."""
    loc: list = []
    for part in field.split("."):
        name, _, index = part.partition("[")
        loc.append(name)
        if index:
            loc.append(int(index.rstrip("]")) - 1)
    try:
        return toml_line(files.read_text(path, "TOML"), tuple(loc))
    except (InputError, ValueError):
        return None


def read_toml(path: Path, what: str) -> tuple[str, dict]:
    """The text and the parsed TOML of a file people write (a regular UTF-8 file of at most
    ``files.LIMITS["TOML"]`` bytes); InputError naming the file (and line) otherwise. ``what`` names the file's
    role in the messages ("sample manifest")."""
    try:
        text = files.read_text(path, "TOML")
    except InputError as err:
        raise InputError(f"the {what}: {err.message}", path=path) from None
    try:
        return text, tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        match = re.search(r"line (\d+)", str(err))
        raise InputError(f"not valid TOML: {err}", path=path, line=int(match.group(1)) if match else None) from None
    except RecursionError:
        raise InputError(f"not a {what}: its arrays or tables are nested too deeply", path=path) from None


def first_validation_error(err: ValidationError) -> dict:
    """The error to report of several: a misspelt key shows up twice, as unknown and as missing; the unknown one
    says more."""
    return sorted(err.errors(), key=lambda e: e["type"] != "extra_forbidden")[0]


def input_error(err: ValidationError, where) -> InputError:
    """The InputError to raise for a pydantic error: its message, at ``where(loc)`` (path, line and field)."""
    first = first_validation_error(err)
    message = "unknown field" if first["type"] == "extra_forbidden" else first["msg"].removeprefix("Value error, ")
    return InputError(message, **where(tuple(first["loc"])))


def located_in(path: Path, text: str):
    """``where`` for :func:`input_error`: a location in the TOML ``text`` of ``path``."""
    return lambda loc: {"path": path, "line": toml_line(text, loc), "field": format_field(loc)}


#: A strict model read from a file (:func:`read_model`).
Model = TypeVar("Model", bound=StrictModel)


def read_model(path: Path, what: str, model: type[Model]) -> tuple[str, Model]:
    """The text of the TOML file ``path`` (:func:`read_toml`) and its contents validated as ``model``; a pydantic
    error becomes an InputError naming the file, the line and the field (:func:`input_error`)."""
    text, data = read_toml(path, what)
    try:
        return text, model.model_validate(data)
    except ValidationError as err:
        raise input_error(err, located_in(path, text)) from None
