"""Colour of reflectance spectra under a CIE illuminant, through colour-science.

CIE 1931 2 deg (default) or CIE 1964 10 deg observer; tristimulus values by colour-science's
integration (ASTM E308-style weighting on the spectra's own grid: colour aligns the CMFs and the
illuminant to it), CIELAB relative to the perfect reflecting diffuser under the same illuminant on the
same grid (so a spectrum limited to 400-700 nm is compared with a white limited the same way), Delta E
2000 (CIE 142-2001), and sRGB (IEC 61966-2-1) after CAT02 adaptation from the illuminant's white to D65,
for swatches. Arrays: reflectance with wavelength last.
"""

from __future__ import annotations

import re
import warnings

import colour
import numpy as np

from kmpipe.errors import InputError

OBSERVERS = {
    "2": "CIE 1931 2 Degree Standard Observer",
    "10": "CIE 1964 10 Degree Standard Observer",
}


#: Illuminants read from a user's spectral power distribution file in this process (:func:`register_illuminant`).
_FILES: dict[str, colour.SpectralDistribution] = {}
#: The range an illuminant's SPD file must cover (nm): where the colour-matching functions are tabulated in CIE 15.
SPD_RANGE = (380.0, 780.0)


def is_spd_file(name: str) -> bool:
    """Whether an illuminant name names a spectral power distribution file, ``FILE.csv`` or ``FILE.csv:COLUMN``."""
    return str(name).partition(":")[0].lower().endswith(".csv")


def register_illuminant(name: str, path, column: str | None = None) -> None:
    """Read the relative spectral power distribution of a light from a spectral CSV (``quantity: radiance``, any
    scale; every column, or ``column``, the first if not given) and make it the illuminant called ``name`` in this
    process, for every function here and the renderer. It must cover 380-780 nm (CIE 15's range of the colour-
    matching functions), be >= 0 and not all 0; InputError naming the file otherwise."""
    from kmpipe.formats.spectra import read_spectra_csv

    table = read_spectra_csv(path)
    if table.wavelengths is None or table.metadata.get("quantity") != "radiance":
        raise InputError("an illuminant's SPD is a spectrum of '# quantity: radiance' (relative power, any scale)",
                         path=path, field="quantity")  # fmt: skip
    table.validate_values()
    values = table.column(column or table.columns[0])
    lo, hi = float(table.wavelengths[0]), float(table.wavelengths[-1])
    if lo > SPD_RANGE[0] or hi < SPD_RANGE[1]:
        raise InputError(f"covers {lo:g}-{hi:g} nm; an illuminant's SPD must cover {SPD_RANGE[0]:g}-"
                         f"{SPD_RANGE[1]:g} nm", path=path, field="wavelength")  # fmt: skip
    if not np.any(values > 0):
        raise InputError("the SPD is 0 everywhere: no light", path=path, field=column or table.columns[0])
    for key in [k for k in _WEIGHTS if k[1] == str(name)]:  # weights of an earlier file of that name
        del _WEIGHTS[key]
    _FILES[str(name)] = colour.SpectralDistribution(  # interpolated linearly, as colour-science's own illuminants
        dict(zip(table.wavelengths, values, strict=True)), name=str(name), interpolator=colour.LinearInterpolator
    )


def illuminant_key(name: str) -> str:
    """colour-science's key of the CIE illuminant ``name``, the one resolver of illuminant names for scenes, recipes
    and validation: case-insensitive; the CIE's F1 ... F12 and F3.1 ... F3.15 are colour-science's FL1 ... (and FL
    names work too); LED-B1 ... LED-V2 (CIE 15:2018), A, B, C, D50 ... D75, E, ISO 7589 names; or the name of a
    user's SPD file registered in this process (:func:`register_illuminant`), as it was registered.

    Raises
    ------
    ValueError
        The name is not an illuminant colour-science knows; the message gives examples that are.
    """
    if str(name) in _FILES:
        return str(name)
    upper = str(name).strip().upper()
    if re.fullmatch(r"F\d+(\.\d+)?", upper):
        upper = "FL" + upper[1:]
    key = {k.upper(): k for k in colour.SDS_ILLUMINANTS}.get(upper)
    if key is None:
        raise ValueError(f"unknown illuminant {name!r}; expected a CIE illuminant such as A, D50, D65, F2, F11 or "
                         "LED-B3")  # fmt: skip
    return key


def illuminant_sd(name: str) -> colour.SpectralDistribution:
    """The CIE illuminant called ``name`` (see :func:`illuminant_key`)."""
    try:
        key = illuminant_key(name)
        return _FILES[key] if key in _FILES else colour.SDS_ILLUMINANTS[key]
    except ValueError as err:
        raise InputError(str(err), field="--illuminant") from None


def cmfs(observer: str) -> colour.MultiSpectralDistributions:
    """The CIE colour-matching functions of the ``observer`` ("2": CIE 1931, "10": CIE 1964), from colour-science."""
    if observer not in OBSERVERS:
        raise InputError(f"observer must be 2 or 10 (degrees), got {observer!r}", field="--observer")
    return colour.MSDS_CMFS[OBSERVERS[observer]]


#: XYZ weights per (grid, illuminant, observer) in this process (:func:`xyz_weights`).
_WEIGHTS: dict[tuple[bytes, str, str], np.ndarray] = {}


def xyz_weights(wavelengths, illuminant: str = "D65", observer: str = "2") -> np.ndarray:
    """The weights W (n_wavelengths x 3) with XYZ = R @ W (Y = 100 for the perfect white) on a grid: colour-science's
    integration (``colour.msds_to_XYZ(method="Integration")``) of the grid's unit impulses, which is exact because the
    integration is linear in R. Computed once per grid, illuminant and observer in a process (read-only)."""
    wavelengths = np.ascontiguousarray(wavelengths, dtype=np.float64)
    key = (wavelengths.tobytes(), str(illuminant), str(observer))
    found = _WEIGHTS.get(key)
    if found is None:
        msds = colour.MultiSpectralDistributions(np.eye(len(wavelengths)), wavelengths)
        with warnings.catch_warnings():
            # colour warns that it aligns the CMFs and illuminant to the spectra's shape: that is intended.
            warnings.simplefilter("ignore", colour.utilities.ColourWarning)
            warnings.simplefilter("ignore", colour.utilities.ColourRuntimeWarning)
            XYZ = colour.msds_to_XYZ(
                msds, cmfs=cmfs(observer), illuminant=illuminant_sd(illuminant), method="Integration"
            )
        found = np.asarray(XYZ, dtype=np.float64).reshape(len(wavelengths), 3)
        found.setflags(write=False)
        _WEIGHTS[key] = found
    return found


def reflectance_to_XYZ(reflectance, wavelengths, illuminant: str = "D65", observer: str = "2") -> np.ndarray:
    """Tristimulus values (Y = 100 for the perfect white) of reflectance spectra, shape (..., 3).

    X = k sum R(l) S(l) xbar(l), k = 100 / sum S(l) ybar(l) (ASTM E308 weighting), by
    ``colour.msds_to_XYZ(method="Integration")`` on the spectra's grid (through :func:`xyz_weights`). This is thesis
    eq. A.1, thesis eq. A.2 and thesis eq. A.3 weighted by the illuminant S(l): the thesis integrates R(l) xbar(l)
    alone (illuminant E, unnormalised).
    """
    R = np.asarray(reflectance, dtype=np.float64)
    return R @ xyz_weights(wavelengths, illuminant, observer)


def white_XYZ(wavelengths, illuminant: str = "D65", observer: str = "2") -> np.ndarray:
    """XYZ of the perfect reflecting diffuser on the same grid (the CIELAB reference white)."""
    return reflectance_to_XYZ(np.ones(len(wavelengths)), wavelengths, illuminant, observer)


def reflectance_to_Lab(reflectance, wavelengths, illuminant: str = "D65", observer: str = "2") -> np.ndarray:
    """CIELAB of reflectance spectra relative to the perfect white under the same illuminant and grid.

    >>> import numpy as np
    >>> wavelengths = np.arange(380.0, 781.0, 5.0)
    >>> reflectance_to_Lab(np.ones_like(wavelengths), wavelengths, "D65").round(6).tolist()  # the perfect white
    [100.0, 0.0, 0.0]
    """
    XYZ = reflectance_to_XYZ(reflectance, wavelengths, illuminant, observer)
    white = white_XYZ(wavelengths, illuminant, observer)
    return colour.XYZ_to_Lab(XYZ / 100.0, colour.XYZ_to_xy(white / 100.0))


def delta_E_2000(Lab_1, Lab_2) -> np.ndarray:
    """CIE Delta E 2000 (CIE 142-2001) between two CIELAB arrays.

    >>> # Sharma, Wu and Dalal (2005), test data pair 1: Delta E 2000 = 2.0425
    >>> round(float(delta_E_2000([50.0, 2.6772, -79.7751], [50.0, 0.0, -82.7485])), 4)
    2.0425
    """
    return np.asarray(colour.delta_E(Lab_1, Lab_2, method="CIE 2000"))


def reflectance_to_sRGB(reflectance, wavelengths, illuminant: str = "D65", observer: str = "2") -> np.ndarray:
    """Display sRGB in [0, 1] (gamma-encoded, clipped) of reflectance spectra, CAT02-adapted to D65."""
    XYZ = reflectance_to_XYZ(reflectance, wavelengths, illuminant, observer) / 100.0
    white = white_XYZ(wavelengths, illuminant, observer) / 100.0
    RGB = colour.XYZ_to_sRGB(XYZ, illuminant=colour.XYZ_to_xy(white), chromatic_adaptation_transform="CAT02")
    return np.clip(RGB, 0.0, 1.0)


def Lab_to_sRGB(Lab, wavelengths, illuminant: str = "D65", observer: str = "2") -> np.ndarray:
    """Display sRGB in [0, 1] of CIELAB relative to the perfect white under ``illuminant`` on the grid, CAT02-adapted
    to D65 as :func:`reflectance_to_sRGB` adapts (so a reflectance's Lab gives its sRGB)."""
    white = colour.XYZ_to_xy(white_XYZ(wavelengths, illuminant, observer) / 100.0)
    XYZ = colour.Lab_to_XYZ(np.asarray(Lab, dtype=np.float64), white)
    RGB = colour.XYZ_to_sRGB(XYZ, illuminant=white, chromatic_adaptation_transform="CAT02")
    return np.clip(RGB, 0.0, 1.0)
