"""Regenerate the bundled example samples: SIMULATED drawdown measurements of cosmetic films.

No public set of cosmetic drawdowns over black and white backings exists, so the examples are simulated (pigments,
mixtures and cards from ``simulated_drawdowns.py`` beside this file, which the benchmarks and tests share):

- K and S of each product are Duncan mixtures (K = sum c_i K_i, S = sum c_i S_i) of real pigments from the
  RIT Artist Paint Spectral Database (``shared/data/pigments/rit_golden_acrylic_ks.csv``), interpolated to
  1 nm; that table's S is relative, so both are scaled by ``PER_MM`` to plausible per-mm values (a 20 um
  foundation film hides about half of a black backing, as real medium-coverage foundations do).
- Readings are what a CS-2000 at 1 nm would record under CIE D55: radiance = D55 x reflectance x gain
  (thesis eq. 4.3, the light scaled by the gain), plus a dark offset, with noise of the size the Kimera paint
  repeats show (``shared/data/paints``: about 0.6 % of the reading, repeat to repeat).
- Backings are a black card (~0.035) and a white card (~0.78-0.86) with gentle spectral slopes.

Each sample also gets what it takes to measure it again with the CS-2000 emulator (``kmpipe emulate``): the
reflectance of everything the technician puts under the instrument (``emulator_reflectance.csv``), the samples
script that orders it as the plan does (``emulator.toml``) and the measurement plan (``plan.toml``).

Run from the repository root: ``.venv/bin/python recipes/samples/simulate_samples.py``. The output is
deterministic (fixed seeds); the true K and S are written beside each sample as ``truth.json``.
"""

from __future__ import annotations

import json
from pathlib import Path

import colour
import numpy as np
from simulated_drawdowns import cards, rit_pigments

from kmpipe.formats.spectra import SpectralTable, write_spectra_csv
from kmpipe.formats.spectral_grid import uniform_grid
from kmpipe.physics.joint_fit import predict_readings
from kmpipe.physics.white import baso4_typical

HERE = Path(__file__).resolve().parent
WAVELENGTHS = uniform_grid(380, 780, 1)
PER_MM = 60.0  # relative RIT units -> 1/mm
GAIN = 0.0105  # W sr-1 m-2 nm-1 per unit of relative D55 power (D55 ~100 at 560 nm) and unit reflectance
DARK = 2.0e-6  # dark offset, W sr-1 m-2 nm-1
RELATIVE_NOISE = 0.006  # Kimera repeat spread: ~0.6 % of the reading
ABSOLUTE_NOISE = 1.0e-6  # W sr-1 m-2 nm-1

SAMPLES = {
    "F1": {
        "product": "Liquid foundation, Natural Beige (simulated)",
        "kind": "foundation",
        "mix": {
            "TitaniumWhite": 1.0,
            "HansaYellowOpaque": 0.3,
            "CadmiumOrange": 0.25,
            "PyrroleRed": 0.05,
            "BoneBlack": 0.25,
        },
        "thicknesses_um": (15, 30),
    },
    "F2": {
        "product": "Liquid foundation, Warm Sand (simulated)",
        "kind": "foundation",
        "mix": {
            "TitaniumWhite": 1.0,
            "HansaYellowOpaque": 0.45,
            "CadmiumOrange": 0.45,
            "PyrroleRed": 0.12,
            "BoneBlack": 0.6,
        },
        "thicknesses_um": (15, 30),
    },
    "B1": {
        "product": "Cream blush, Rose (simulated)",
        "kind": "blush",
        "mix": {"TitaniumWhite": 1.0, "QuinacridoneRed": 0.25, "CadmiumOrange": 0.03},
        "thicknesses_um": (10, 20),
    },
    "L1": {
        "product": "Lipstick, Classic Red (simulated)",
        "kind": "lipstick",
        "mix": {"PyrroleRed": 1.0, "QuinacridoneMagenta": 0.15, "TitaniumWhite": 0.05},
        "thicknesses_um": (10, 20),
    },
    "L2": {
        "product": "Lipstick, Berry (simulated)",
        "kind": "lipstick",
        "mix": {"QuinacridoneMagenta": 1.0, "DioxazinePurple": 0.1, "PyrroleRed": 0.3},
        "thicknesses_um": (10, 20),
    },
    "E1": {
        "product": "Eyeshadow, Lilac Plum (simulated)",
        "kind": "eyeshadow",
        "mix": {"TitaniumWhite": 1.0, "DioxazinePurple": 0.5, "QuinacridoneMagenta": 0.35, "BoneBlack": 0.8},
        "thicknesses_um": (8, 16),
    },
}


def header(sample: str, what: str, serial: str) -> dict[str, str]:
    return {
        "quantity": "radiance",
        "units": "W sr-1 m-2 nm-1",
        "instrument": "Konica Minolta CS-2000A (SIMULATED)",
        "serial": serial,
        "illuminant": "CIE D55",
        "geometry": "0:45, 1 deg aperture",
        "time": "2026-11-20T10:00:00Z",
        "note": f"SIMULATED data for sample {sample}: {what}; made by recipes/samples/simulate_samples.py",
    }


def write_emulator_files(folder: Path, name: str, spec: dict, backings: dict, K: np.ndarray, S: np.ndarray) -> None:
    """plan.toml, emulator.toml and emulator_reflectance.csv for measuring this sample with the emulator."""
    columns = {"baso4": baso4_typical(WAVELENGTHS), "black_card": backings["black"], "white_card": backings["white"]}
    columns["masstone"] = predict_readings(K, S, np.array([np.inf]), np.zeros((1, WAVELENGTHS.size)))[0]
    sequence = ["baso4", "black_card", "white_card", "masstone"]
    films = []
    for um in spec["thicknesses_um"]:
        for over in ("black", "white"):
            column = f"film_{um}um_over_{over}"
            columns[column] = predict_readings(K, S, np.array([um / 1000.0]), backings[over][None, :])[0]
            sequence.append(column)
            films.append(f'[[film]]\nover = "{over}"\nthickness = "{um} um"\n')
    metadata = {
        "quantity": "reflectance",
        "units": "1",
        "note": f"SIMULATED reflectance for the emulator, sample {name}",
    }
    table = SpectralTable(WAVELENGTHS, None, tuple(columns), np.array(list(columns.values())), metadata)
    write_spectra_csv(table, folder / "emulator_reflectance.csv")
    (folder / "emulator.toml").write_text(
        "# kmpipe emulate --samples emulator.toml: what lies under the instrument at each MEAS of plan.toml.\n"
        f'[samples]\nfile = "emulator_reflectance.csv"\nsequence = {json.dumps(sequence)}\n'
        f'illuminant = "D55"\ngain = 0.0105\nnoise = {RELATIVE_NOISE}\nseed = {sum(map(ord, name))}\n',
        encoding="utf-8",
    )
    (folder / "plan.toml").write_text(
        "# kmpipe measure plan.toml --port /dev/ttyACM0 (or the emulator's link): one reading per position.\n"
        f'[sample]\nname = "{name}"\nproduct = "{spec["product"]}"\nkind = "{spec["kind"]}"\n\n'
        '[instrument]\nspeed = "normal"\nnd = "auto"\nrepeats = 1\n\n[white]\ncertified = "builtin:baso4"\n\n'
        '[[backing]]\nname = "black"\n\n[[backing]]\nname = "white"\n\n'
        "[[masstone]]  # as thick as it takes to hide the backing: no thickness declared\n\n" + "\n".join(films),
        encoding="utf-8",
    )


def write_sample(folder: Path, name: str, spec: dict, K: np.ndarray, S: np.ndarray, seed: int) -> None:
    """A simulated sample in ``folder``: its readings (white, backings, masstone and films), manifest, truth and the
    emulator's files, from K and S (1/mm, on WAVELENGTHS), noise drawn with ``seed``."""
    rng = np.random.default_rng(seed)
    d55 = colour.SDS_ILLUMINANTS["D55"].copy().align(colour.SpectralShape(380, 780, 1)).values
    light = GAIN * d55
    backings = cards(WAVELENGTHS)

    def measure(reflectance: np.ndarray) -> np.ndarray:
        signal = light * reflectance
        noise = rng.normal(0.0, 1.0, signal.shape) * (RELATIVE_NOISE * signal + ABSOLUTE_NOISE)
        return signal + DARK + noise

    folder.mkdir(exist_ok=True)
    serial = "1234567"
    white = measure(baso4_typical(WAVELENGTHS))
    dark = DARK + rng.normal(0.0, ABSOLUTE_NOISE / 4, WAVELENGTHS.shape)
    write_spectra_csv(
        SpectralTable(
            WAVELENGTHS,
            None,
            ("baso4", "dark"),
            np.array([white, np.abs(dark)]),
            header(name, "BaSO4 white standard and a dark reading", serial),
        ),
        folder / "white.csv",
    )
    write_spectra_csv(
        SpectralTable(
            WAVELENGTHS,
            None,
            ("black", "white"),
            np.array([measure(backings["black"]), measure(backings["white"])]),
            header(name, "bare black and white backings of the drawdown card", serial),
        ),
        folder / "backings.csv",
    )
    columns, thickness, grounds = ["masstone"], [np.inf], [np.zeros_like(WAVELENGTHS)]
    for um in spec["thicknesses_um"]:
        for over in ("black", "white"):
            columns.append(f"film_{um}um_over_{over}")
            thickness.append(um / 1000.0)
            grounds.append(backings[over])
    reflectance = predict_readings(K, S, np.array(thickness), np.array(grounds))
    write_spectra_csv(
        SpectralTable(
            WAVELENGTHS,
            None,
            tuple(columns),
            np.array([measure(r) for r in reflectance]),
            header(name, f"{spec['product']}: masstone and drawdowns", serial),
        ),
        folder / f"{name}.csv",
    )
    films = "\n".join(
        f'[[film]]\nfile = "{name}.csv"\ncolumn = "{c}"\n'
        f'over = "{c.rsplit("_", 1)[1]}"\nthickness = "{c.split("_")[1][:-2]} um"\n'
        for c in columns[1:]
    )
    (folder / "manifest.toml").write_text(
        f"# SIMULATED example sample (see simulate_samples.py): CS-2000 radiance under D55.\n"
        f'[sample]\nname = "{name}"\nproduct = "{spec["product"]}"\nkind = "{spec["kind"]}"\n\n'
        f'[white]\nfile = "white.csv"\ncolumn = "baso4"\ncertified = "builtin:baso4"\n'
        f'dark = {{ file = "white.csv", column = "dark" }}\n\n'
        f'[fit]\nmethod = "lsq"\ngrid = "380:780:5"\n\n'
        f'[[backing]]\nname = "black"\nfile = "backings.csv"\ncolumn = "black"\n\n'
        f'[[backing]]\nname = "white"\nfile = "backings.csv"\ncolumn = "white"\n\n'
        f'[[masstone]]\nfile = "{name}.csv"\ncolumn = "masstone"\n\n{films}',
        encoding="utf-8",
    )
    (folder / "truth.json").write_text(
        json.dumps(
            {
                "note": "SIMULATED: the K and S the measurements were generated from",
                "mix": spec["mix"],
                "wavelengths_nm": WAVELENGTHS.tolist(),
                "K_per_mm": K.tolist(),
                "S_per_mm": S.tolist(),
            },
            indent=1,
        )
        + "\n",
        encoding="utf-8",
    )
    write_emulator_files(folder, name, spec, backings, K, S)
    print(f"wrote {folder}")


def main() -> None:
    pigments = rit_pigments().on(WAVELENGTHS)
    for index, (name, spec) in enumerate(SAMPLES.items()):
        K, S = pigments.mixture(spec["mix"], PER_MM)
        write_sample(HERE / name, name, spec, K, S, 1000 + index)


if __name__ == "__main__":
    main()
