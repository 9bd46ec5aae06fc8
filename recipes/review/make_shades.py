"""Regenerate the shade range of the review example: SIMULATED drawdowns of eight foundation shades.

The range runs from a porcelain to an espresso shade, as a brand's foundation line does; each shade is a Duncan
mixture of real pigments from the RIT Artist Paint Spectral Database (titanium white, Hansa yellow, cadmium orange,
pyrrole red, bone black; ``recipes/samples/simulated_drawdowns.py``), its amounts chosen so that its masstone lies at
a CIELAB colour along the skin-tone range (L* 80 to 38 under D65), and scaled so that the amounts sum to 1.8 (a
15 um film hides most, not all, of what lies under it). Each shade's readings are simulated exactly as the bundled
samples' are (``recipes/samples/simulate_samples.py``: CS-2000 radiance under D55, black and white cards, 15 and
30 um films, the Kimera repeats' noise), so that ``kmpipe run`` fits them like any sample.

Run from the repository root: ``.venv/bin/python recipes/review/make_shades.py``. Deterministic (fixed seeds).
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "samples"))

from simulate_samples import PER_MM, WAVELENGTHS, write_sample  # noqa: E402
from simulated_drawdowns import rit_pigments  # noqa: E402

#: Amounts of each shade's pigments besides titanium white (1.0), before scaling to TOTAL.
SHADES = {  # Hansa: HansaYellowOpaque
    "V110": ("Porcelain", {"Hansa": 0.193, "CadmiumOrange": 0.337, "PyrroleRed": 0.026, "BoneBlack": 0.221}),
    "V120": ("Ivory", {"Hansa": 0.188, "CadmiumOrange": 0.678, "PyrroleRed": 0.004, "BoneBlack": 0.609}),
    "V130": ("Sand", {"Hansa": 0.178, "CadmiumOrange": 1.146, "PyrroleRed": 0.013, "BoneBlack": 1.236}),
    "V140": ("Honey", {"Hansa": 0.514, "CadmiumOrange": 1.099, "PyrroleRed": 0.418, "BoneBlack": 1.865}),
    "V150": ("Caramel", {"Hansa": 0.977, "CadmiumOrange": 1.177, "PyrroleRed": 1.097, "BoneBlack": 3.213}),
    "V160": ("Chestnut", {"Hansa": 1.188, "CadmiumOrange": 2.408, "PyrroleRed": 1.964, "BoneBlack": 6.699}),
    "V170": ("Mocha", {"Hansa": 1.009, "CadmiumOrange": 5.302, "PyrroleRed": 3.973, "BoneBlack": 15.933}),
    "V180": ("Espresso", {"Hansa": 0.998, "CadmiumOrange": 11.2, "PyrroleRed": 12.271, "BoneBlack": 50.474}),
}
#: Full names of the pigments SHADES abbreviates.
PIGMENTS = {"Hansa": "HansaYellowOpaque"}
#: Sum of each shade's amounts (titanium white included).
TOTAL = 1.8


def main() -> None:
    pigments = rit_pigments().on(WAVELENGTHS)
    for index, (name, (shade, others)) in enumerate(SHADES.items()):
        amounts = {"TitaniumWhite": 1.0, **{PIGMENTS.get(k, k): v for k, v in others.items()}}
        scale = TOTAL / sum(amounts.values())
        mix = {pigment: round(amount * scale, 6) for pigment, amount in amounts.items()}
        spec = {"product": f"Skin Veil foundation {name[1:]} {shade} (simulated)", "kind": "foundation", "mix": mix,
                "thicknesses_um": (15, 30)}  # fmt: skip
        K, S = pigments.mixture(mix, PER_MM)
        write_sample(HERE / "shades" / name, name, spec, K, S, 2000 + index)


if __name__ == "__main__":
    main()
