"""What the emulated CS-2000 measures: the radiance of the sample under it and its colorimetric values.

Spectral radiance (W sr-1 m-2 nm-1, 380-780 nm at 1 nm) = illuminant relative spectral power (CIE D55 by default,
normalised to 100 at 560 nm, linearly interpolated from the CIE 5 nm table) x reflectance of the sample under the
instrument x ``gain`` (thesis eq. 4.3 run backwards), times ``1 + noise * N(0, 1)`` per wavelength (seeded), rounded
to float32 (what the instrument sends in hex); :mod:`instruments.cs2000.emulator.instrument` forms it from
:func:`illuminant_spd`.
Colorimetric values follow from that spectrum (:func:`colorimetry`): Le = sum L dlambda (W sr-1 m-2);
X, Y, Z = 683 sum L xbar dlambda (cd m-2, CIE 1931 2 deg and CIE 1964 10 deg CMFs at 1 nm; Lv = Y);
x, y, u', v' from XYZ; T and duv by Ohno (2013) from CIE 1960 uv (sentinels when |duv| > 0.05 or T is outside
1000-100000 K); lambda_d and Pe (%) against the equal-energy white point (the real instrument's white point is not
documented here). Quantities that cannot be computed (a black spectrum) are sent as sentinels.
"""

from __future__ import annotations

from functools import cache

import numpy as np

from instruments.cs2000.protocol import COLORIMETRIC_NAMES, WAVELENGTHS


@cache
def _cmfs() -> tuple[np.ndarray, np.ndarray]:
    """CIE 1931 2 deg and CIE 1964 10 deg colour-matching functions at 380-780 nm, 1 nm: two (401, 3) arrays."""
    import colour

    tables = []
    for name in ("CIE 1931 2 Degree Standard Observer", "CIE 1964 10 Degree Standard Observer"):
        cmfs = colour.MSDS_CMFS[name]
        tables.append(np.array([cmfs[w] for w in WAVELENGTHS]))
    return tables[0], tables[1]


def illuminant_spd(name: str = "D55") -> np.ndarray:
    """Relative spectral power of a CIE illuminant at 380-780 nm, 1 nm (linear interpolation of its table),
    normalised to 100 at 560 nm.

    ``name`` is a key of ``colour.SDS_ILLUMINANTS`` as spelt there ("D55", "FL11", "LED-B3"); kmpipe resolves the
    names people write (case, F11 for FL11) with ``kmpipe.physics.colorimetry.illuminant_key`` first.

    Raises
    ------
    ValueError
        An unknown key, or a table that does not cover 380-780 nm.
    """
    import colour

    if name not in colour.SDS_ILLUMINANTS:
        raise ValueError(f"illuminant {name!r} is unknown; expected a CIE illuminant such as D55, D65 or A")
    sd = colour.SDS_ILLUMINANTS[name]
    if sd.wavelengths[0] > 380 or sd.wavelengths[-1] < 780:
        raise ValueError(f"illuminant {name!r} does not cover 380-780 nm")
    spd = np.interp(WAVELENGTHS, sd.wavelengths, sd.values)
    return spd * (100.0 / spd[WAVELENGTHS == 560][0])


def _chromaticity(xyz: np.ndarray, cmfs_name: str) -> dict[str, float | None]:
    """x, y, u', v', T, duv, lambda_d, Pe of one tristimulus vector (``None`` where undefined)."""
    import colour

    nothing: dict[str, float | None] = dict.fromkeys(("x", "y", "u'", "v'", "T", "duv", "lambda_d", "Pe"))
    big_x, big_y, big_z = (float(v) for v in xyz)
    total, denominator = big_x + big_y + big_z, big_x + 15 * big_y + 3 * big_z
    if min(big_x, big_y, big_z) < 0 or total <= 0 or denominator <= 0:
        return nothing
    xy = np.array([big_x / total, big_y / total])
    u, v = 4 * big_x / denominator, 6 * big_y / denominator
    result = {"x": float(xy[0]), "y": float(xy[1]), "u'": u, "v'": 1.5 * v}
    cct, duv = (float(c) for c in colour.temperature.uv_to_CCT_Ohno2013(np.array([u, v])))
    valid_cct = 1000 <= cct <= 100_000 and abs(duv) <= 0.05
    result |= {"T": cct if valid_cct else None, "duv": duv if valid_cct else None}
    white = np.array([1 / 3, 1 / 3])
    if np.hypot(*(xy - white)) < 1e-6:
        return result | {"lambda_d": None, "Pe": None}
    cmfs = colour.MSDS_CMFS[cmfs_name]
    wavelength = float(colour.dominant_wavelength(xy, white, cmfs)[0])
    purity = float(colour.excitation_purity(xy, white, cmfs)) * 100
    return result | {"lambda_d": wavelength, "Pe": purity}


def colorimetry(radiance: np.ndarray) -> dict[str, float | None]:
    """The 24 colorimetric values of a radiance spectrum (W sr-1 m-2 nm-1 at 380-780 nm, 1 nm), by name
    (:data:`~instruments.cs2000.protocol.COLORIMETRIC_NAMES`, units there); ``None`` where undefined.

    Le = sum L (1 nm steps); X, Y, Z = 683 sum L cmf (CIE 15:2018 eq. 7.1 with Km = 683 lm W-1); chromaticities,
    T and duv (Ohno 2013), dominant wavelength and excitation purity as in the module notes.
    """
    radiance = np.asarray(radiance, dtype=np.float64)
    if radiance.shape != WAVELENGTHS.shape:
        raise ValueError(f"radiance must have {WAVELENGTHS.size} values (380-780 nm, 1 nm)")
    if not np.all(np.isfinite(radiance)):
        return dict.fromkeys(COLORIMETRIC_NAMES)
    cmfs_2, cmfs_10 = _cmfs()
    xyz_2, xyz_10 = 683.0 * radiance @ cmfs_2, 683.0 * radiance @ cmfs_10
    result: dict[str, float | None] = {"Le": float(radiance.sum()), "Lv": float(xyz_2[1])}
    result |= dict(zip(("X", "Y", "Z"), map(float, xyz_2), strict=True))
    result |= _chromaticity(xyz_2, "CIE 1931 2 Degree Standard Observer")
    result |= dict(zip(("X_10", "Y_10", "Z_10"), map(float, xyz_10), strict=True))
    result |= {f"{k}_10": v for k, v in _chromaticity(xyz_10, "CIE 1964 10 Degree Standard Observer").items()}
    return {name: result[name] for name in COLORIMETRIC_NAMES}
