"""The limits of a validation verdict and the sensitivity of its checks (docs/formats.md, "Validation thresholds")."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from pathlib import Path

from kmpipe.errors import InputError
from kmpipe.formats.toml_input import read_toml


@dataclass(frozen=True)
class Thresholds:
    """Limits of the verdict; set on the command line or in a TOML file's ``[thresholds]`` table."""

    delta_e_warn: float = 1.0  # Delta E 2000
    delta_e_fail: float = 2.0
    rmse_warn: float = 0.01  # reflectance
    rmse_fail: float = 0.02
    relative_stderr: float = 0.25  # standard error / value, for poor_conditioning
    ks_min: float = 1e-4  # K/S below: extreme (R_inf above ~0.986)
    ks_max: float = 200.0  # K/S above: extreme (R_inf below ~0.0025)
    noise_factor: float = 3.0  # residual_above_noise: residual / repeat spread; also the sigma multiple of checks
    runs_z: float = 3.5  # structured_residuals: |z| of the Wald-Wolfowitz runs test
    uncertainty_warn: float = 1.0  # colour_uncertainty: the rendered colour's 95 % radius, Delta E 2000
    uncertainty_fail: float = 2.0

    @classmethod
    def from_toml(cls, path: Path) -> Thresholds:
        """Read ``[thresholds]`` from a TOML file (read as :func:`kmpipe.formats.toml_input.read_toml` reads: a
        regular file within the TOML size limit); InputError naming the field on a bad value."""
        _, data = read_toml(Path(path), "validation config")
        extra = sorted(set(data) - {"thresholds"})
        if extra:
            raise InputError("unknown table or key; the file holds one [thresholds] table", path=path, field=extra[0])
        table = data.get("thresholds")
        if not isinstance(table, dict):
            raise InputError("expected a [thresholds] table", path=path, field="thresholds")
        return cls().updated(_source=path, **table)

    def updated(self, _source: Path | None = None, **values) -> Thresholds:
        """A copy with the given (non-None) values, each checked: a known name, a positive finite number,
        warn levels at most the fail levels, ks_min below ks_max. ``_source``: the config file, for messages."""
        known = {f.name for f in fields(self)}
        prefix = "thresholds." if _source is not None else ""
        given = {}
        for key, value in values.items():
            if value is None:
                continue
            if key not in known:
                raise InputError(
                    f"unknown threshold; expected one of {', '.join(sorted(known))}", path=_source, field=prefix + key
                )
            if isinstance(value, bool) or not isinstance(value, int | float) or not (0.0 < value < math.inf):
                raise InputError(f"expected a positive number, got {value!r}", path=_source, field=prefix + key)
            given[key] = float(value)
        out = replace(self, **given)
        for low, high in (
            ("delta_e_warn", "delta_e_fail"),
            ("rmse_warn", "rmse_fail"),
            ("ks_min", "ks_max"),
            ("uncertainty_warn", "uncertainty_fail"),
        ):
            if getattr(out, low) > getattr(out, high):
                raise InputError(
                    f"{low} ({getattr(out, low):g}) exceeds {high} ({getattr(out, high):g})",
                    path=_source,
                    field=prefix + low,
                )
        return out
