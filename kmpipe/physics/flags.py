"""Per-wavelength (or per-channel) flags that inversions and fits attach to their results.

A flagged value is never NaN or infinite: each flag says what the value means instead.
"""

from __future__ import annotations

import enum

import numpy as np


class Flag(enum.IntFlag):
    """Why a K or S value at one wavelength is not an ordinary, well-determined estimate."""

    #: Over black and white (or film and masstone) the readings agree within tolerance: the film hides its
    #: backing, so thickness is not identifiable. K/S is exact; K and S are the lower bound at which the
    #: film would just look opaque.
    OPAQUE = 1
    #: The readings lie outside what the model and the backgrounds allow (e.g. a film over black darker
    #: than the black card). K and S are the nearest physically possible values.
    OUT_OF_RANGE = 2
    #: The background reflects as much as the masstone: a film over it does not change the reading,
    #: so S cannot be found from that pair. K/S is exact; S is 0.
    NO_CONTRAST = 4
    #: K or S ended at 0 because the readings asked for a little less (noise on a film that barely absorbs
    #: or scatters): the nearest physical value. A fit's standard error there is one-sided.
    AT_BOUND = 8


#: One line per flag, for reports and error messages.
EXPLANATIONS = {
    Flag.OPAQUE: "the film hides its backing here: K/S is exact, K and S are lower bounds (thickness not identifiable)",
    Flag.OUT_OF_RANGE: "readings outside what the model and backgrounds allow: "
    "K and S were moved to the nearest physical values",
    Flag.NO_CONTRAST: "background as bright as the masstone: S cannot be found from this pair",
    Flag.AT_BOUND: "K or S ended at 0: the readings asked for slightly less (noise); 0 is the nearest physical value",
}


def flag_names(flags: int) -> list[str]:
    """Lower-case names of the flags set in one bitmask value, e.g. ['opaque', 'out_of_range']."""
    return [f.name.lower() for f in Flag if flags & f]


def wavelengths_by_flag(flags: np.ndarray, labels) -> dict[str, list]:
    """{flag name: [labels where it is set]} for a 1-D flag array and its wavelengths or channel names."""
    flags = np.asarray(flags)
    return {f.name.lower(): [labels[i] for i in np.flatnonzero(flags & f)] for f in Flag if np.any(flags & f)}
