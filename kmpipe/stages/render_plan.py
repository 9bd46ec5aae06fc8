"""Render plan: which optical tables a scene needs, in which render mode, and how large.

The plan lists the materials, stacks and thickness ranges (mm) in use; picks the cheapest render mode, in the
order rgb, bands:3, bands:6, bands:9, ... (N below the number of wavelengths), exact, whose largest Delta E 2000
against the exact spectral result on the scene's own stacks (:func:`kmpipe.physics.optical_tables.mode_error`) is within
the accuracy target; sizes each thickness axis so that linear interpolation adds at most
:data:`INTERPOLATION_FRACTION` of the target; and drops what the scene does not need.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import colour
import numpy as np

from kmpipe.physics.optical_tables import (
    FilmCoefficients,
    OpticalTable,
    Stack,
    band_partition,
    composite,
    mode_error,
    parse_mode,
    working_space,
)

#: Delta E 2000 target (worst case over the scene's stacks) when the caller gives none; about 1/2 of a just noticeable
#: difference, so a studio can composite renders of one shade next to each other without seeing the mode.
DEFAULT_TARGET_DE = 0.5
#: Share of the target that thickness interpolation may use (the rest is left to the mode).
INTERPOLATION_FRACTION = 0.25
#: Largest thickness axis the planner will propose (2^8 + 1 samples).
MAX_SAMPLES = 257


@dataclass(frozen=True)
class ModeCandidate:
    """A render mode and its measured Delta E 2000 against exact over the scene's stacks and probe thicknesses."""

    mode: str
    max_dE: float
    mean_dE: float


@dataclass(frozen=True)
class TableSize:
    """Thickness axis of one material's table: ``n_samples`` uniform samples over [min_mm, max_mm] (1: no axis).

    ``interpolation_dE`` is the largest Delta E 2000 between linear interpolation in the table and the same mode
    evaluated at the thickness itself, measured at every eighth of each interval of the table (0 without an axis).
    """

    material: str
    min_mm: float
    max_mm: float
    n_samples: int
    n_channels: int
    interpolation_dE: float

    @property
    def thicknesses_mm(self) -> np.ndarray:
        return np.linspace(self.min_mm, self.max_mm, self.n_samples)


@dataclass(frozen=True)
class RenderPlan:
    """What :func:`plan_render` decided; ``explain()`` prints it."""

    illuminant: str
    observer: str
    target_dE: float
    mode: str
    forced: bool
    materials: tuple[str, ...]
    stacks: tuple[Stack, ...]
    thickness_ranges: dict[str, tuple[float, float]]
    candidates: tuple[ModeCandidate, ...]
    tables: tuple[TableSize, ...]
    dropped: tuple[str, ...]

    def build_tables(self, materials: Mapping[str, FilmCoefficients]) -> dict[str, OpticalTable]:
        """The planned :class:`OpticalTable` of every material in use."""
        space = working_space(materials[self.materials[0]].wavelengths, self.illuminant, self.observer)
        kind, n_bands = parse_mode(self.mode)
        bands = band_partition(space.wavelengths, n_bands, space=space) if kind == "bands" else None
        return {
            t.material: OpticalTable.build(materials[t.material], t.thicknesses_mm, self.mode, space, bands)
            for t in self.tables
        }

    def explain(self) -> str:
        """The plan as text: materials, stacks, ranges, candidates with their errors, table sizes, what was dropped."""
        lines = [
            f"Render plan under {self.illuminant} (observer {self.observer} deg), "
            f"target Delta E 2000 <= {self.target_dE:g}"
        ]
        lines.append("Materials: " + ", ".join(self.materials))
        lines.append("Stacks (top first):")
        lines += [f"  {s.name}: {' / '.join(s.layers)} / substrate" for s in self.stacks]
        lines.append("Thickness ranges (mm):")
        lines += [f"  {name}: {lo:g} .. {hi:g}" for name, (lo, hi) in self.thickness_ranges.items()]
        lines.append("Modes (Delta E 2000 against exact on the scene's stacks: max, mean):")
        for c in self.candidates:
            verdict = "meets target" if c.max_dE <= self.target_dE else "misses target"
            mark = "  <- chosen" if c.mode == self.mode else ""
            lines.append(f"  {c.mode:>9}: max {c.max_dE:.3f}, mean {c.mean_dE:.3f} ({verdict}){mark}")
        if self.forced:
            lines.append(f"  mode {self.mode} was requested; no other mode was evaluated")
        else:
            lines.append(f"  modes after {self.mode} were not evaluated: a cheaper mode met the target")
        lines.append("Tables:")
        for t in self.tables:
            axis = f"{t.n_samples} thickness samples" if t.n_samples > 1 else "no thickness axis"
            lines.append(
                f"  {t.material}: {axis} x {t.n_channels} channels x (R0, T), "
                f"interpolation Delta E 2000 <= {t.interpolation_dE:.3f}"
            )
        lines.append("Dropped:" if self.dropped else "Dropped: nothing")
        lines += [f"  {d}" for d in self.dropped]
        return "\n".join(lines)


def candidate_modes(n_wavelengths: int, max_bands: int | None = None) -> list[str]:
    """rgb, bands:3, bands:6, ... (N < n_wavelengths and N <= max_bands), exact: cheapest first."""
    top = n_wavelengths - 1 if max_bands is None else min(n_wavelengths - 1, max_bands)
    return ["rgb", *(f"bands:{n}" for n in range(3, top + 1, 3)), "exact"]


def _interpolation_error(material: FilmCoefficients, lo: float, hi: float, n: int, substrates, mode, space, bands):
    """Largest Delta E 2000 of linear interpolation on n uniform samples, at every eighth of every interval.

    The film is checked alone over each substrate it lies on (nothing above it to hide its error).
    """
    axis = np.linspace(lo, hi, n)
    midpoints = (axis[:-1, None] + np.diff(axis)[:, None] * np.arange(1, 8) / 8).ravel()
    table = OpticalTable.build(material, axis, mode, space, bands)
    at_midpoints = OpticalTable.build(material, midpoints, mode, space, bands)
    worst = 0.0
    for substrate in substrates:
        interpolated = composite([table], [midpoints], substrate, mode)
        direct = composite([at_midpoints], [midpoints], substrate, mode)
        dE = colour.delta_E(space.to_Lab(interpolated), space.to_Lab(direct), method="CIE 2000")
        worst = max(worst, float(np.max(dE)))
    return worst


def plan_render(
    scene_materials: Mapping[str, FilmCoefficients],
    stacks: Sequence[Stack],
    thickness_ranges: Mapping[str, tuple[float, float]],
    illuminant: str = "D65",
    accuracy_target_dE: float | None = None,
    mode: str | None = None,
    observer: str = "2",
    max_bands: int | None = None,
) -> RenderPlan:
    """Plan the optical tables of a scene.

    Parameters
    ----------
    scene_materials
        Materials by name (K, S per mm on one wavelength grid).
    stacks
        The scene's stacks; materials in no stack, stacks without layers and repeated stacks (same layers and
        substrate) get no tables and are listed as dropped.
    thickness_ranges
        (min, max) film thickness per material, mm; min == max is a single thickness: no thickness axis.
    accuracy_target_dE
        Largest Delta E 2000 allowed against exact (default :data:`DEFAULT_TARGET_DE`).
    mode
        Force a render mode ("rgb", "bands:N", "exact"); its error is still measured and reported.
    max_bands
        Most bands a ``bands:N`` candidate may have (a renderer's channel limit); exact follows the last one.
    """
    target = DEFAULT_TARGET_DE if accuracy_target_dE is None else float(accuracy_target_dE)
    dropped = []
    kept: list[Stack] = []
    for stack in stacks:
        twin = next(
            (k for k in kept if k.layers == stack.layers and np.array_equal(k.substrate, stack.substrate)), None
        )
        if not stack.layers:
            dropped.append(f"stack {stack.name}: no layers (bare substrate) -> no tables")
        elif twin is not None:
            dropped.append(f"stack {stack.name}: same layers and substrate as {twin.name} -> measured once")
        else:
            kept.append(stack)
    if not kept:
        raise ValueError("the scene has no stack with layers: nothing to plan")
    used = tuple(dict.fromkeys(name for stack in kept for name in stack.layers))
    for name in used:
        if name not in scene_materials or name not in thickness_ranges:
            raise ValueError(f"material {name!r} is used by a stack but has no coefficients or no thickness range")
    dropped += [f"material {name}: not in any stack -> no table" for name in scene_materials if name not in used]
    dropped += [
        f"thickness range of {name}: material not used -> ignored" for name in thickness_ranges if name not in used
    ]
    ranges = {name: (float(thickness_ranges[name][0]), float(thickness_ranges[name][1])) for name in used}
    dropped += [
        f"material {name}: single thickness {lo:g} mm -> no thickness axis"
        for name, (lo, hi) in ranges.items()
        if lo == hi
    ]

    space = working_space(scene_materials[used[0]].wavelengths, illuminant, observer)
    candidates = []
    for candidate in [mode] if mode is not None else candidate_modes(len(space.wavelengths), max_bands):
        errors = mode_error(kept, candidate, scene_materials, ranges, illuminant, observer)
        candidates.append(ModeCandidate(candidate, float(errors.max()), float(errors.mean())))
        if candidates[-1].max_dE <= target:
            break
    chosen = candidates[-1].mode

    kind, n_bands = parse_mode(chosen)
    bands = band_partition(space.wavelengths, n_bands, space=space) if kind == "bands" else None
    n_channels = {"rgb": 3, "bands": n_bands, "exact": len(space.wavelengths)}[kind]
    tables = []
    for name in used:
        lo, hi = ranges[name]
        n, error = 1, 0.0
        if hi > lo:
            substrates = [s.substrate for s in kept if name in s.layers]
            n = 2
            error = _interpolation_error(scene_materials[name], lo, hi, n, substrates, chosen, space, bands)
            while error > INTERPOLATION_FRACTION * target and n < MAX_SAMPLES:
                n = 2 * n - 1
                error = _interpolation_error(scene_materials[name], lo, hi, n, substrates, chosen, space, bands)
        tables.append(TableSize(name, lo, hi, n, n_channels, error))
    return RenderPlan(
        illuminant,
        observer,
        target,
        chosen,
        mode is not None,
        used,
        tuple(kept),
        ranges,
        tuple(candidates),
        tuple(tables),
        tuple(dropped),
    )
