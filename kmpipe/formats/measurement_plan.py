"""Measurement plans (TOML) for ``kmpipe measure``: the positions of one sample's session, in order.

The format is documented in docs/formats.md ("Measurement plan"): the sample, the instrument's settings, the white
standard, the backings, the masstone(s) and the films, each read ``repeats`` times. Parsing is strict and every error
names the file, the line and the field.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator

from kmpipe.errors import InputError
from kmpipe.formats.files import name_problem, sha256
from kmpipe.formats.manifest import MeasuredThickness, Thickness, parse_measured_thickness
from kmpipe.formats.toml_input import StrictModel, read_model, toml_line


class PlanSample(StrictModel):
    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
    product: str = ""
    kind: str = ""

    @field_validator("name")
    @classmethod
    def _a_safe_name(cls, name: str) -> str:
        """The session folder is named after the sample: ``.`` or ``..`` would lead out of the plan's folder."""
        problem = name_problem(name)
        if problem is not None:
            raise ValueError(f"{problem} (the session folder is named after the sample)")
        return name


class PlanInstrument(StrictModel):
    speed: Literal["normal", "fast", "multi-normal", "multi-fast", "manual"] = "normal"
    nd: Literal["off", "on", "auto"] = "auto"
    integration: float | None = Field(default=None, gt=0)  # s: multi-integration time, or manual exposure
    observer: Literal[2, 10] = 2
    repeats: int = Field(default=1, ge=1, le=20)


class PlanWhite(StrictModel):
    certified: str = "builtin:baso4"
    repeats: int | None = Field(default=None, ge=1, le=20)


class PlanBacking(StrictModel):
    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_-]+$")


class PlanMasstone(StrictModel):
    thickness: Thickness | None = None  # e.g. "200 um"


class PlanFilm(StrictModel):
    thickness: MeasuredThickness | None = None  # e.g. "30 um" or "30 um +- 2 um"
    over: str
    name: str | None = Field(default=None, min_length=1, max_length=60, pattern=r"^[A-Za-z0-9_-]+$")  # reading name


class PlanSkin(StrictModel):
    """Bare skin measured in the session (a panel of skin tones for shade reviews): its name and body site."""

    name: str = Field(min_length=1, max_length=40, pattern=r"^[A-Za-z0-9_-]+$")
    site: str | None = Field(default=None, min_length=1, max_length=80)


class Plan(StrictModel):
    sample: PlanSample
    instrument: PlanInstrument = PlanInstrument()
    white: PlanWhite = PlanWhite()
    backing: list[PlanBacking] = Field(min_length=1)
    masstone: list[PlanMasstone] = Field(default_factory=list)
    film: list[PlanFilm] = Field(min_length=1)
    skin: list[PlanSkin] = Field(default_factory=list)


def plan_digest(path: Path) -> str:
    """SHA-256 (hex) of the plan file's bytes: what a session folder and a session log record as their plan."""
    return sha256(path, "TOML")


def load_plan(path: Path) -> Plan:
    """Read and check a measurement plan; InputError naming the file, line and field on any problem."""
    text, plan = read_model(path, "measurement plan", Plan)
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

    role: str  # white | backing | masstone | film | skin
    column: str
    prompt: str
    over: str | None = None
    thickness: str | None = None
    site: str | None = None  # of a skin reading


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
        um = parse_measured_thickness(thickness)[0] * 1000.0
        add(
            "film",
            film.name or f"film_{um:g}um_over_{film.over}",
            f"the {thickness} film over {film.over}",
            repeats,
            over=film.over,
            thickness=thickness,
        )
    for skin in plan.skin:
        where = f" ({skin.site})" if skin.site else ""
        add("skin", f"skin_{skin.name}", f"the bare skin of {skin.name}{where}", repeats, site=skin.site)
    names = [p.column for p in out]
    if len(set(names)) != len(names):
        duplicated = sorted({n for n in names if names.count(n) > 1})
        raise InputError(f"two plan entries give the same reading name {duplicated[0]!r}; use repeats instead")
    return out


def skin_readings(plan: Plan) -> dict[str, list[str]]:
    """The reading columns of each bare skin of the plan (``skin_NAME``, then ``_1``, ``_2``, ... with repeats), by
    the column its mean gets in reflectance.csv (``skin_NAME``)."""
    repeats = plan.instrument.repeats
    found = {}
    for skin in plan.skin:
        base = f"skin_{skin.name}"
        found[base] = [base] if repeats == 1 else [f"{base}_{r}" for r in range(1, repeats + 1)]
    return found
