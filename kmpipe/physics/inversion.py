"""Closed-form Kubelka-Munk inversions: K and S from reflectances, per wavelength or camera channel.

All functions take KM (body) reflectances; remove surface reflection first with
:func:`kmpipe.physics.saunderson.saunderson_inverse` if the readings include it. Arrays broadcast, wavelength
(or channel) last. Nothing returned is NaN, infinite or negative, for any readings (exact 0 and 1 and
subnormals included) and any thickness X > 0, and no numpy RuntimeWarning is raised: where the readings
cannot determine K and S, the element carries a :class:`~kmpipe.physics.flags.Flag` saying what the finite value
means instead. Readings outside [0, 1] (noise on a reading near 0 or 1) are used as they are where the
model with K, S >= 0 still explains them, and are otherwise flagged OUT_OF_RANGE and taken as clipped to
[0, 1]. K or S that would exceed the float64 range (a thickness near 0 for the readings) is set to the
largest float64 and flagged OUT_OF_RANGE. ``tolerance`` must lie in (0, 1).

Notation: a = 1 + K/S, b = sqrt(a^2 - 1), R_inf = a - b, X thickness (mm), K and S per mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kmpipe.physics import inversion_kernels as kernels
from kmpipe.physics.flags import Flag
from kmpipe.physics.kubelka_munk import ks_from_reflectance_infinite

#: Readings that agree to this relative tolerance (film over black vs over white, or film vs masstone)
#: are treated as opaque: thickness is not identifiable there.
OPAQUE_TOLERANCE = 1e-3

#: Smallest masstone reflectance used when a reading is 0 or negative (K/S would be infinite).
_MIN_REFLECTANCE = 1e-9
#: ... and the K/S that goes with it (K/S of a perfect absorber is infinite).
_MAX_KS = float((1.0 - _MIN_REFLECTANCE) ** 2 / (2.0 * _MIN_REFLECTANCE))
#: The smallest normal float64.
_TINY = float(np.finfo(np.float64).tiny)
#: Elements per block in :func:`black_white` (fits the working set in a 2 MB cache).
_BLOCK = 16384
#: K and S that would exceed this (a thickness near 0 for the readings) are set to it and flagged OUT_OF_RANGE.
_MAX_FLOAT = float(np.finfo(np.float64).max)


@dataclass(frozen=True)
class Inversion:
    """K and S per unit length (1/mm when X is in mm), K/S, and a Flag bitmask, all of one shape."""

    K: np.ndarray
    S: np.ndarray
    ks_ratio: np.ndarray
    flags: np.ndarray


def _check_thickness(X) -> np.ndarray:
    X = np.asarray(X, dtype=np.float64)
    if np.any(~np.isfinite(X)) or np.any(X <= 0.0):
        raise ValueError("film thickness X must be finite and > 0 for an inversion")
    return X


def _check_tolerance(tolerance: float) -> float:
    if not 0.0 < tolerance < 1.0:
        raise ValueError(f"tolerance must lie in (0, 1), got {tolerance}")
    return float(tolerance)


def _log1pc(d: np.ndarray) -> np.ndarray:
    """log1p(d) / d for d >= 0: series 1 - d/2 + d^2/3 - d^3/4 near 0."""
    series = 1.0 + d * (-0.5 + d * (1.0 / 3.0 - d * 0.25))
    safe = np.where(d < 1e-4, 1.0, d)
    return np.where(d < 1e-4, series, np.log1p(safe) / safe)


def _opaque_lower_bound_sx(ks, R_g_dark, R_g_light, tolerance: float) -> np.ndarray:
    """Smallest S X at which a film of this K/S over the two backgrounds reaches contrast 1 - tolerance.

    Over a background G a film reads R = (G + p (1 - G a)) / (1 + p (a - G)) (thesis eq. 3.5 divided by v) with
    p = 1 / v, v = b coth(b S X), so p rises from 0 (X = 0) to 1/b (opaque). Contrast R_dark / R_light = rho
    = 1 - tolerance is the quadratic C2 p^2 + C1 p + C0 = 0 with C0 = G_d - rho G_l < 0 (the backgrounds
    do not yet meet the contrast), C1 = (1 - rho)(1 - G_d G_l) > 0 and C2 = a (1 - rho)(1 + G_d G_l)
    - G_l + rho G_d - a^2 C0 >= 0, whose positive root is p = 2 |C0| / (C1 + sqrt(C1^2 + 4 C2 |C0|)).
    With w = b p, 1 - w^2 = 2 (1 - rho) [((a - 1)(1 + G_d G_l) + (1 - G_d)(1 - G_l)) p + 1 - G_d G_l]
    / (C1 + sqrt(C1^2 + 4 C2 |C0|)), a sum of positive terms (no cancellation near w = 1), and
    S X = artanh(w) / b = p artanh(w) / w. Backgrounds that already meet the contrast (C0 >= 0) give 0.
    A tolerance below 1e-15 is taken as 1e-15, which keeps the result finite and still a lower bound.
    K/S must be finite and >= 0 (at most ``_MAX_KS``); the backgrounds in [0, 1].
    """
    rho = 1.0 - max(tolerance, 1e-15)
    gap = 1.0 - rho
    a = 1.0 + ks
    b = np.sqrt(ks * (ks + 2.0))
    product = R_g_dark * R_g_light
    C0 = R_g_dark - rho * R_g_light
    hides = C0 < 0.0
    C0 = np.where(hides, -C0, 0.0)  # |C0|
    C1 = gap * (1.0 - product)
    C2 = a * gap * (1.0 + product) - R_g_light + rho * R_g_dark + a * a * C0
    root = C1 + np.sqrt(C1 * C1 + 4.0 * np.maximum(C2, 0.0) * C0)
    root = np.where(hides, root, 1.0)
    p = 2.0 * C0 / root
    slope = ks * (1.0 + product) + (1.0 - R_g_dark) * (1.0 - R_g_light)
    one_minus_w2 = 2.0 * gap * (slope * p + 1.0 - product) / root
    one_minus_w2 = np.clip(one_minus_w2, np.finfo(float).tiny, 1.0)
    w = np.minimum(b * p, 1.0)
    return p * _artanhc_near_one(w, one_minus_w2)


def _artanhc_near_one(w: np.ndarray, one_minus_w2: np.ndarray) -> np.ndarray:
    """artanh(w) / w for 0 <= w <= 1 given 1 - w^2 > 0 accurately: numpy's artanh below 1/2 (w = 0 taken as the
    smallest normal float, where artanh(w) = w: the limit 1), else [log1p(w) - ln(1 - w^2) / 2] / w, finite (at most
    355) however close w is to 1."""
    low = w < 0.5
    small = np.where(low, np.maximum(w, _TINY), 0.5)
    large = np.where(low, 0.5, w)
    near_one = (np.log1p(large) - 0.5 * np.log(np.where(low, 0.75, one_minus_w2))) / large
    return np.where(low, np.arctanh(small) / small, near_one)


def _capped_ratio(numerator: np.ndarray, denominator: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """numerator / denominator for numerator >= 0, denominator > 0, capped at the largest float64.

    Returns the ratio and the mask where it was capped (the true ratio exceeds the float64 range), with no
    overflow raised.
    """
    over = numerator > _MAX_FLOAT * np.minimum(denominator, 1.0)
    return np.where(over, _MAX_FLOAT, numerator / np.where(over, 1.0, denominator)), over


def _blockwise(regular, careful, inputs, tolerance) -> Inversion:
    """Run an inversion in cache-sized blocks on a lean regular path, then on a careful one where needed.

    The inputs are broadcast as views (a scalar backing or a per-wavelength array is never copied to
    full size) and seen as rows of their last axis; blocks of about `_BLOCK` elements keep every
    temporary in cache (an input that is not contiguous, a broadcast one, is copied a block at a time).
    ``regular(*blocks, tolerance, K, S, ks, flags, first, second, hard)`` fills the output blocks, using the
    scratch blocks ``first`` and ``second``, and marks in ``hard`` the elements it cannot do (flagged, limiting or
    out-of-range ones); their places are kept per block, and after all blocks ``careful(*values, tolerance)``
    returns K, S, K/S and flags for those, in one call.
    """
    values = [np.asarray(v, dtype=np.float64) for v in inputs]
    shape = np.broadcast_shapes(*(v.shape for v in values))
    arrays = [v if v.shape == shape else np.broadcast_to(v, shape) for v in values]  # read-only views
    last = shape[-1] if shape and shape[-1] > 0 else 1
    rows = [a.reshape(-1, last) for a in arrays]
    count = rows[0].shape[0]
    K, S, ks = (np.empty((count, last)) for _ in range(3))
    flags = np.zeros((count, last), dtype=np.uint8)
    step = max(1, min(_BLOCK // last, count))
    copies = [None if r.flags.c_contiguous else np.empty((step, last)) for r in rows]
    first, second = np.empty((step, last)), np.empty((step, last))
    hard = np.empty((step, last), dtype=bool)
    hard_rows, hard_columns = [], []

    for lo in range(0, count, step):
        block, size = slice(lo, lo + step), min(step, count - lo)
        blocks = [r[block] if c is None else _copied(r[block], c[:size]) for r, c in zip(rows, copies, strict=True)]
        outputs = (K[block], S[block], ks[block], flags[block])
        regular(*blocks, tolerance, *outputs, first[:size], second[:size], hard[:size])
        if hard[:size].any():
            where = np.nonzero(hard[:size])
            hard_rows.append(where[0] + lo)
            hard_columns.append(where[1])
    if hard_rows:
        where = (np.concatenate(hard_rows), np.concatenate(hard_columns))
        K[where], S[where], ks[where], flags[where] = careful(*(r[where] for r in rows), tolerance)
    return Inversion(K=K.reshape(shape), S=S.reshape(shape), ks_ratio=ks.reshape(shape), flags=flags.reshape(shape))


def _copied(values: np.ndarray, into: np.ndarray) -> np.ndarray:
    """``values`` copied into the contiguous block ``into``, which is returned."""
    np.copyto(into, values)
    return into


def two_constant(R_inf, R, R_g, X, *, tolerance: float = OPAQUE_TOLERANCE) -> Inversion:
    """K and S from a masstone R_inf and a film of thickness X over a background R_g that reads R.

    S X = [arcoth((a - R)/b) - arcoth((a - R_g)/b)] / b (thesis eq. 4.1) turns complex when the film is
    brighter than its masstone over a light background (R > R_inf). The real-valued equivalent used here
    (``shared/method/notes.md``) is

        S X = ln[(1/R_inf - R)(R_inf - R_g) / ((R_inf - R)(1/R_inf - R_g))] / (1/R_inf - R_inf)
            = (R - R_g) / ((R_inf - R)(1/R_inf - R_g)) * log1p(delta) / delta,
        delta = (1/R_inf - R_inf)(R - R_g) / ((R_inf - R)(1/R_inf - R_g)),

    which stays exact as R_inf -> 1 (K -> 0, where S X -> (R - R_g) / ((1 - R)(1 - R_g))).
    K = S (a - 1) (thesis eq. 4.2) with a - 1 = K/S = (1 - R_inf)^2 / (2 R_inf) (thesis eq. 3.7).

    Flags: OPAQUE where |R - R_inf| <= tolerance R_inf (S is then the lower bound at which the film reads
    within tolerance of its masstone); NO_CONTRAST where |R_inf - R_g| <= tolerance R_inf (K = S = 0, K/S
    exact); OUT_OF_RANGE where R is not between R_g and R_inf, or R_inf is outside [1e-9, 1] (it is then
    clipped to that range).

    >>> from kmpipe.physics.kubelka_munk import reflectance_infinite, reflectance_over_background
    >>> K, S, X, R_g = 1.0, 40.0, 0.02, 0.04  # per mm, mm: a 20 um film over a black card
    >>> result = two_constant(reflectance_infinite(K, S), reflectance_over_background(K, S, X, R_g), R_g, X)
    >>> round(float(result.K), 9), round(float(result.S), 9), int(result.flags)
    (1.0, 40.0, 0)
    """
    X = _check_thickness(X)
    tolerance = _check_tolerance(tolerance)
    return _blockwise(_two_constant_regular, _two_constant_careful, (R_inf, R, R_g, X), tolerance)


def _two_constant_regular(R_inf, R, R_g, X, tolerance, K, S, ks, flags, delta, two_b_X, hard):
    """The common case of :func:`two_constant` into K, S, ks: S X = log1p(delta) / (1/R_inf - R_inf), the arithmetic
    compiled (:func:`~kmpipe.physics.inversion_kernels.two_constant_terms`), log1p numpy's.

    ``flags`` is left at 0: every flagged case is irregular. Marks in ``hard`` the elements that are flagged, out
    of range, or have delta < 1e-4 (where log1p(delta)/delta needs its series): :func:`_two_constant_careful`
    redoes those.
    """
    kernels.two_constant_terms(R_inf, R, R_g, X, tolerance, _MIN_REFLECTANCE, ks, delta, two_b_X, hard)
    with np.errstate(all="ignore"):
        np.log1p(delta, out=S)
    kernels.two_constant_scale(two_b_X, ks, S, K, hard)


def _two_constant_careful(R_inf, R, R_g, X, tolerance):
    """Every case of :func:`two_constant`, element by element in vector form: limits, flags and bounds.

    Readings and backgrounds outside [0, 1] are flagged OUT_OF_RANGE and clipped to it.
    """
    flags = np.zeros(R_inf.shape, dtype=np.uint8)
    outside = ~((R >= 0.0) & (R <= 1.0) & (R_g >= 0.0) & (R_g <= 1.0))
    R, R_g = (np.clip(np.nan_to_num(v), 0.0, 1.0) for v in (R, R_g))
    bad_masstone = ~((R_inf >= _MIN_REFLECTANCE) & (R_inf <= 1.0))
    Ri = np.clip(np.nan_to_num(R_inf), _MIN_REFLECTANCE, 1.0)
    ks = ks_from_reflectance_infinite(Ri)
    two_b = (1.0 - Ri) * (1.0 + Ri) / Ri

    no_contrast = np.abs(Ri - R_g) <= tolerance * Ri
    toward = np.sign(Ri - R_g)  # +1: the film brightens the background as it thickens
    progress = toward * (R - R_g)  # >= 0 when R lies on the masstone's side of R_g
    remaining = toward * (Ri - R)  # > 0 while the film is not yet opaque
    opaque = ~no_contrast & (np.abs(Ri - R) <= tolerance * Ri)
    beyond = ~no_contrast & ~opaque & (remaining < 0.0)  # past the masstone: brighter/darker than possible
    backwards = ~no_contrast & ~opaque & ~beyond & (progress < 0.0)  # moved away from the masstone
    # Readings past the masstone are treated like opaque ones (lower bound); behind the background: S = 0.
    # A tolerance below 1e-15 is taken as 1e-15 there: a smaller S X, still a lower bound, and finite.
    at_limit = opaque | beyond
    R_eff = np.where(at_limit, Ri - toward * max(tolerance, 1e-15) * Ri, R)
    R_eff = np.where(backwards | no_contrast, R_g, R_eff)
    numerator = np.abs(R_eff - R_g)
    # (R_i - R_eff)(1/R_i - R_g) has the sign of R_eff - R_g and is at least ~tolerance^2 R_i away from 0
    denominator = np.where(no_contrast, 1.0, np.abs((Ri - R_eff) * (1.0 / Ri - R_g)))
    ratio, _ = _capped_ratio(numerator, np.maximum(denominator, np.finfo(float).tiny))
    ratio = np.where(no_contrast, 0.0, np.minimum(ratio, 1e290))  # (at most ~1e39 for tolerance >= 1e-15)
    SX = ratio * _log1pc(two_b * ratio)

    S, S_over = _capped_ratio(SX, X)
    K, K_over = _capped_ratio(SX * ks, X)
    flags[opaque] |= np.uint8(Flag.OPAQUE)
    flags[no_contrast] |= np.uint8(Flag.NO_CONTRAST)
    flags[beyond | backwards | outside | bad_masstone | S_over | K_over] |= np.uint8(Flag.OUT_OF_RANGE)
    return K, S, ks, flags


def black_white(R_over_black, R_over_white, R_black, R_white, X, *, tolerance: float = OPAQUE_TOLERANCE) -> Inversion:
    """K and S from one film thickness X drawn over two backings of measured reflectance.

    With y = b coth(b S X), a film over background R_g,i that reads R_i satisfies
    (R_i + R_g,i) a + (R_i - R_g,i) y = 1 + R_i R_g,i (thesis eq. 3.5 multiplied out; ``shared/method/notes.md``),
    linear in (a, y).
    Substituting a = 1 + u (u = K/S) gives (R_i + R_g,i) u + (R_i - R_g,i) y = (1 - R_i)(1 - R_g,i),
    which Cramer's rule solves as u = N_u / D, y = N_y / D with

        D   = (R_w + G_w)(R_b - G_b) - (R_b + G_b)(R_w - G_w)
        N_u = (1 - R_w)(1 - G_w)(R_b - G_b) - (1 - R_b)(1 - G_b)(R_w - G_w)
        N_y = (R_w + G_w)(1 - R_b)(1 - G_b) - (R_b + G_b)(1 - R_w)(1 - G_w)

    (R_b, R_w the film over the black and white backings G_b, G_w). Then, with w = b / y
    = sqrt(N_u (N_u + 2 D)) / N_y,

        S X = artanh(w) / b = (D / N_y) artanh(w) / w,     K X = (N_u / N_y) artanh(w) / w,

    which never divides by b or D: K -> 0 and a pure absorber (R_b = G_b = 0, where K X -> artanh(w))
    are ordinary values; K = S (a - 1) as in thesis eq. 4.6. Curtis et al. 1997 (thesis eq. 4.5, which is an arcoth,
    not an arcosh) is the special case G_b = 0, G_w = 1, X = 1.

    The two backings may come in either order: swapping them (with their readings) negates D, N_u and N_y
    and leaves the solution unchanged, so a "black" backing brighter than the "white" one is the same film.

    Flags: OPAQUE where |R_w - R_b| <= tolerance max(R_b, R_w) (K/S exact from the system; S the lower
    bound at which the film reaches that contrast on these backings); OUT_OF_RANGE where no non-negative
    K, S reproduces the readings (K/S then from the mean of the two readings taken as the masstone, S as
    for OPAQUE; or K = 0 where only the absorption came out negative), e.g. a film over the dark backing
    darker than it while it brightens the light one, or equal backings with different readings;
    AT_BOUND where K/S came out negative by less than ``tolerance`` (K = 0).

    >>> from kmpipe.physics.kubelka_munk import reflectance_over_background
    >>> K, S, X, black, white = 1.0, 40.0, 0.02, 0.04, 0.85  # per mm, mm, and the cards' reflectances
    >>> over_black, over_white = (reflectance_over_background(K, S, X, g) for g in (black, white))
    >>> result = black_white(over_black, over_white, black, white, X)
    >>> round(float(result.K), 9), round(float(result.S), 9), int(result.flags)
    (1.0, 40.0, 0)
    """
    X = _check_thickness(X)
    tolerance = _check_tolerance(tolerance)
    return _blockwise(
        _black_white_regular,
        _black_white_careful,
        (R_over_black, R_over_white, R_black, R_white, X),
        tolerance,
    )


def _black_white_regular(Rb, Rw, Gb, Gw, X, tolerance, K, S, ks, flags, w, artanh_w, hard):
    """The common case of :func:`black_white` into K, S, ks (and flags): the system compiled
    (:func:`~kmpipe.physics.inversion_kernels.black_white_system`), artanh numpy's, then K, S = (N_u, D) / N_y
    artanh(w) / w / X.

    A negative K/S (noise on a nearly non-absorbing film) is taken as K = 0, S X = D / N_y, the nearest
    physical solution, flagged AT_BOUND; below -``tolerance`` it is flagged OUT_OF_RANGE instead. Marks in ``hard``
    the elements that are opaque, have N_y <= b D (no finite, positive S X; this includes N_y <= 0),
    lie near D = 0 (a clear absorber, where rounding decides the sign of D), or whose K or S is not finite
    (a thickness near 0): those are redone by :func:`_black_white_careful`. Values computed at those
    elements may be inf or nan.
    """
    kernels.black_white_system(Rb, Rw, Gb, Gw, tolerance, int(Flag.AT_BOUND), int(Flag.OUT_OF_RANGE), _TINY, _MAX_KS,
                               K, S, ks, w, flags, hard)  # fmt: skip
    with np.errstate(all="ignore"):
        np.arctanh(w, out=artanh_w)
    kernels.black_white_scale(artanh_w, w, X, K, S, hard)


def _black_white_careful(Rb, Rw, Gb, Gw, X, tolerance):
    """Every case of :func:`black_white`, element by element in vector form: limits, flags and bounds.

    Readings and backings outside [0, 1] are flagged OUT_OF_RANGE and clipped to it. The backings are
    ordered so that G_d <= G_l (with the readings R_d, R_l over them): swapping the two negates D, N_u and
    N_y, so u = N_u / D and y = N_y / D are the same. In that order D = 2 (G_l R_d - G_d R_l) (no
    cancellation of the R_d R_l terms), and a film exists iff D >= 0, N_u >= 0 and N_y > b D, where
    N_y^2 - b^2 D^2 = 4 (G_l - G_d)(R_l - R_d)(1 - G_d R_l)(1 - G_l R_d).
    """
    flags = np.zeros(Rb.shape, dtype=np.uint8)
    outside = np.zeros(Rb.shape, dtype=bool)
    for v in (Rb, Rw, Gb, Gw):
        outside |= ~((v >= 0.0) & (v <= 1.0))
    Rb, Rw, Gb, Gw = (np.clip(np.nan_to_num(v), 0.0, 1.0) for v in (Rb, Rw, Gb, Gw))
    ordered = Gb <= Gw
    Rd, Rl = np.where(ordered, Rb, Rw), np.where(ordered, Rw, Rb)
    Gd, Gl = np.where(ordered, Gb, Gw), np.where(ordered, Gw, Gb)

    D = 2.0 * (Gl * Rd - Gd * Rl)
    D = np.where(np.abs(D) <= 1e-13 * (Gl * Rd + Gd * Rl), 0.0, D)
    Nu = (1.0 - Rl) * (1.0 - Gl) * (Rd - Gd) - (1.0 - Rd) * (1.0 - Gd) * (Rl - Gl)
    Ny = (Rl + Gl) * (1.0 - Rd) * (1.0 - Gd) - (Rd + Gd) * (1.0 - Rl) * (1.0 - Gl)

    # Noise (or rounding) leaves N_u a little below 0 for a nearly non-absorbing film: K/S down to
    # -tolerance is taken as K = 0; only a clearly negative K/S is out of range.
    scale = (1.0 - Rl) * (1.0 - Gl) * np.abs(Rd - Gd) + (1.0 - Rd) * (1.0 - Gd) * np.abs(Rl - Gl)
    negative_k = Nu < -np.maximum(tolerance * D, 1e-12 * scale)
    clamped_k = (Nu < -1e-12 * scale) & ~negative_k
    Nu = np.maximum(Nu, 0.0)
    b_num = np.sqrt(Nu * (Nu + 2.0 * np.maximum(D, 0.0)))  # b D
    opaque = np.abs(Rl - Rd) <= tolerance * np.maximum(Rl, Rd)
    # y > b is what makes S X finite; D >= 0 and N_y > 0 are needed for non-negative S.
    regular = ~opaque & (D >= 0.0) & (Ny > b_num)

    safe_Ny = np.where(regular, Ny, 1.0)
    w = np.where(regular, b_num / safe_Ny, 0.0)  # < 1 where regular
    one_minus_w2 = np.where(regular, 4.0 * (Gl - Gd) * (Rl - Rd) * (1.0 - Gd * Rl) * (1.0 - Gl * Rd), 1.0)
    one_minus_w2 = np.where(clamped_k | (w < 0.5), 1.0 - w * w, one_minus_w2 / safe_Ny / safe_Ny)
    factor = _artanhc_near_one(w, np.clip(one_minus_w2, np.finfo(float).tiny, 1.0))
    SX = np.where(regular, np.minimum(D / safe_Ny, _MAX_FLOAT / factor) * factor, 0.0)
    KX = np.where(regular, np.minimum(Nu / safe_Ny, _MAX_FLOAT / factor) * factor, 0.0)

    # K/S = N_u / D wherever D > 0 (also for opaque films, where it tends to (1 - R)^2 / 2R); a pure
    # absorber (D = 0) gets the largest K/S kmpipe represents; readings the system cannot explain get the
    # K/S of the mean of the two readings taken as the masstone.
    positive_D = D > 0.0
    masstone = np.clip(0.5 * (Rb + Rw), _MIN_REFLECTANCE, 1.0)
    system_ks, _ = _capped_ratio(Nu, np.where(positive_D, D, 1.0))
    ks = np.where(
        positive_D,
        np.minimum(system_ks, _MAX_KS),
        np.where(regular, _MAX_KS, ks_from_reflectance_infinite(masstone)),
    )
    bounded = ~regular
    if np.any(bounded):
        SX_min = _opaque_lower_bound_sx(ks[bounded], Gd[bounded], Gl[bounded], tolerance)
        SX[bounded] = SX_min
        KX[bounded] = SX_min * ks[bounded]

    K, K_over = _capped_ratio(KX, X)
    S, S_over = _capped_ratio(SX, X)
    flags[opaque] |= np.uint8(Flag.OPAQUE)
    flags[(~opaque & ~regular) | negative_k | outside | K_over | S_over] |= np.uint8(Flag.OUT_OF_RANGE)
    flags[regular & clamped_k] |= np.uint8(Flag.AT_BOUND)
    return K, S, ks, flags


def curtis(R_over_black, R_over_white, X=1.0, *, tolerance: float = OPAQUE_TOLERANCE) -> Inversion:
    """Curtis et al. 1997 (thesis eq. 4.5 with arcoth, and thesis eq. 4.6): ideal backings, black 0 and white 1.

    Stable form: a - 1 = (1 - R_w)(1 - R_b) / (2 R_b), which :func:`black_white` reproduces exactly
    with G_b = 0, G_w = 1 (D = 2 R_b, N_u = (1 - R_b)(1 - R_w), N_y = (1 + R_w)(1 - R_b)), keeping full
    precision as R_b -> 0 where the textbook form loses ~9 digits at R_b ~ 1e-9.
    """
    return black_white(R_over_black, R_over_white, 0.0, 1.0, X, tolerance=tolerance)
