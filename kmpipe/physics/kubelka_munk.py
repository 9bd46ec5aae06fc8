"""Kubelka-Munk forward model of a film and of film stacks.

Notation (Kubelka 1948; thesis chapter 3.3): K absorption and S scattering coefficients per unit length
(kmpipe uses 1/mm), X film thickness in the same length unit (mm), R_g reflectance of what lies beneath,
a = 1 + K/S, b = sqrt(a^2 - 1), R_inf = a - b. Thesis equations are tagged ``thesis eq. N.M`` (index:
``docs/equations.md``).

Every function takes numpy arrays of any broadcastable shape (wavelength or camera channel last) and
returns float64 arrays; nothing here divides by S or by b, so K = 0, S = 0 and very thick films are
exact limits rather than special cases (see ``shared/method/notes.md``, "Forward model without
cancellation or overflow").
"""

from __future__ import annotations

import numpy as np

#: Below this optical thickness x = beta X, tanh(x)/x is evaluated by its Taylor series.
_SERIES_LIMIT = 1e-3
#: Optical thickness x = beta X beyond which tanh(x) = 1 and sech(x) = 0 in float64 (exact, not a bias).
_THICK = 800.0
#: (K + S) g above which the forward model switches to its form in 1 / g (no overflow).
_HUGE = 1e300


def _tanhc(x: np.ndarray) -> np.ndarray:
    """tanh(x) / x for x >= 0, with the series 1 - x^2/3 + 2 x^4/15 - 17 x^6/315 near 0 (error < 1e-19).

    The series is evaluated on min(x, limit) only, so x up to +inf raises no overflow.
    """
    small = x < _SERIES_LIMIT
    x2 = np.square(np.where(small, x, 0.0))
    series = 1.0 + x2 * (-1.0 / 3.0 + x2 * (2.0 / 15.0 - x2 * (17.0 / 315.0)))
    safe = np.where(small, 1.0, x)
    return np.where(small, series, np.tanh(safe) / safe)


def _sech(x: np.ndarray) -> np.ndarray:
    """sech(x) = 2 e^-x / (1 + e^-2x) for x >= 0, which never overflows."""
    e = np.exp(-x)
    return 2.0 * e / (1.0 + e * e)


def film_reflectance_transmittance(K, S, X) -> tuple[np.ndarray, np.ndarray]:
    """Reflectance R0 of a film over an ideal black background, and its diffuse transmittance T.

    Textbook form (Kubelka 1948): R0 = sinh(bSX) / (a sinh(bSX) + b cosh(bSX)) (thesis eq. 3.8, printed again as
    thesis eq. 4.4), T = b / (a sinh(bSX) + b cosh(bSX)) (thesis eq. 3.9). Evaluated as

        beta = sqrt(K (K + 2 S)),  x = beta X,  g = X tanh(x) / x,  D = 1 + (K + S) g,
        R0 = S g / D,  T = sech(x) / D,

    which is algebraically identical (b S = beta) and exact at K = 0 (R0 = SX / (1 + SX)),
    S = 0 (T = exp(-KX)), X = 0 (R0 = 0, T = 1) and for arbitrarily thick films (R0 -> R_inf, T -> 0).
    Nothing overflows or underflows for K, S, X in [0, largest float64]: beta / 2 = sqrt(K) sqrt(K/4 + S/2)
    beyond 1e150 and sqrt(K) sqrt(K + 2 S) / 2 for K below 1e-150;
    x beyond ``_THICK`` (800, where tanh x = 1 and sech x = 0 in float64) is the same film, with
    g = 1 / beta; where (K + S) g exceeds 1e300 the equivalent form with c = 1 / g,
    R0 = S / (c + K + S), T = c sech(x) / (c + K + S), is used (scaled by 1/4). R0 and T lie in [0, 1].

    Parameters
    ----------
    K, S
        Absorption and scattering coefficients, >= 0, per unit length (1/mm).
    X
        Film thickness, >= 0, in the same length unit (mm).

    >>> R0, T = film_reflectance_transmittance(0.0, 2.0, 0.5)  # no absorption: R0 = SX / (1 + SX), T = 1 - R0
    >>> float(R0), float(T)
    (0.5, 0.5)
    >>> R0, T = film_reflectance_transmittance(1.0, 4.0, 1e3)  # opaque: R0 -> R_inf = 0.5, T -> 0
    >>> float(R0), float(T)
    (0.5, 0.0)
    """
    K, S, X = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (K, S, X)))
    big = (K > 1e150) | (S > 1e150)  # K (K + 2 S) would overflow: beta / 2 = sqrt(K) sqrt(K/4 + S/2)
    tiny = (K < 1e-150) & ~big  # ... or underflow: beta / 2 = sqrt(K) sqrt(K + 2 S) / 2
    if np.any(big | tiny):
        mid = ~big & ~tiny
        K_mid, S_mid = np.where(mid, K, 0.0), np.where(mid, S, 0.0)
        K_tiny = np.where(tiny, K, 0.0)
        beta_half = np.where(
            big,
            np.sqrt(K) * np.sqrt(0.25 * K + 0.5 * S),
            np.where(
                tiny,
                0.5 * (np.sqrt(K_tiny) * np.sqrt(K_tiny + 2.0 * np.where(tiny, S, 0.0))),
                0.5 * np.sqrt(K_mid * (K_mid + 2.0 * S_mid)),
            ),
        )
    else:
        beta_half = 0.5 * np.sqrt(K * (K + 2.0 * S))
    with np.errstate(over="ignore"):  # beta X beyond the float range is a thick film: clamped right below
        x = beta_half * X * 2.0
    thick = x > _THICK
    x = np.minimum(x, _THICK)
    thick_g = 0.5 / np.where(thick, beta_half, 1.0)
    tanhc = _tanhc(x)
    g = np.where(thick, thick_g, X * tanhc)
    with np.errstate(over="ignore"):  # an overflow here means the form in 1 / g below
        # K X tanhc(x), not K (X tanhc(x)): a subnormal X would round X tanhc(x) to a handful of bits
        Kg = np.where(thick, K * thick_g, (K * X) * tanhc)
        Sg = np.where(thick, S * thick_g, (S * X) * tanhc)
        huge = Kg + Sg > _HUGE
    Kg, Sg = np.where(huge, 0.0, Kg), np.where(huge, 0.0, Sg)
    D = 1.0 + Kg + Sg
    R0 = Sg / D
    T = np.minimum(_sech(x) / D, 1.0)
    if np.any(huge):
        c_quarter = 0.25 / np.where(huge, g, 1.0)  # c / 4 <= (K + S) / 4e300: no overflow
        denominator = c_quarter + 0.25 * K + 0.25 * S
        R0 = np.where(huge, 0.25 * S / denominator, R0)
        T = np.where(huge, _sech(x) * c_quarter / denominator, T)
    return R0, T


def film_over_background(R0, T, R_g) -> np.ndarray:
    """Reflectance of a film (R0, T) lying on a background of reflectance R_g (thesis eq. 3.14).

    R = R0 + T^2 R_g / (1 - R0 R_g), thesis eq. 3.14 with the background as layer 2 (the thesis prints T2 in its
    numerator where R2, here R_g, belongs): the film's own reflectance plus the light transmitted twice
    after any number of inter-reflections between film and background. A perfect mirror on a perfect
    mirror (R0 = R_g = 1, so T = 0) gives R0. The result is clamped to [0, 1]: rounding leaves R up to
    2 ulp above 1 where R_g = 1 and the film barely absorbs.
    """
    R0, T, R_g = (np.asarray(v, dtype=np.float64) for v in (R0, T, R_g))
    return np.clip(R0 + T * T * R_g / _positive(1.0 - R0 * R_g), 0.0, 1.0)


def _positive(denominator: np.ndarray) -> np.ndarray:
    """A denominator 1 - R R' of thesis eq. 3.13 and thesis eq. 3.14, with 0 (R = R' = 1, where the numerator is 0)
    taken as 1."""
    return np.where(denominator > 0.0, denominator, 1.0)


def reflectance_over_background(K, S, X, R_g) -> np.ndarray:
    """Reflectance in [0, 1] of a film (K, S per mm; X mm) over a background of reflectance R_g (thesis eq. 3.5).

    R = (1 - R_g (a - b coth(bSX))) / (a - R_g + b coth(bSX)) (thesis eq. 3.5), evaluated as the algebraically
    identical R = R0 + T^2 R_g / (1 - R0 R_g) (:func:`film_over_background`) with R0, T from
    :func:`film_reflectance_transmittance` (no coth, so no division by S or b), clamped to [0, 1].

    >>> float(reflectance_over_background(1.0, 4.0, 0.0, 0.8))  # no film: the background itself
    0.8
    >>> round(float(reflectance_over_background(1.0, 4.0, 100.0, 0.8)), 12)  # opaque: R_inf = 0.5 on any background
    0.5
    >>> float(reflectance_over_background(0.0, 2.0, 0.5, 0.0))  # white film over black: SX / (1 + SX)
    0.5
    """
    R0, T = film_reflectance_transmittance(K, S, X)
    return film_over_background(R0, T, R_g)


def reflectance_infinite(K, S) -> np.ndarray:
    """Reflectance R_inf of an opaque (infinitely thick) layer (thesis eq. 3.6): R_inf = a - b, a = 1 + K/S.

    Computed from q = K/S by :func:`reflectance_infinite_from_ks` (so K and S near the ends of the
    floating-point range cannot underflow or overflow K (K + 2S)). S = 0 gives 0, also for K = 0: a film
    that does not scatter reflects nothing at any thickness (R0 = 0), so its limit is 0.

    >>> float(reflectance_infinite(1.0, 4.0))  # a = 1.25, b = sqrt(a^2 - 1) = 0.75
    0.5
    >>> float(reflectance_infinite(0.0, 4.0)), float(reflectance_infinite(5.0, 0.0))  # no absorption; no scattering
    (1.0, 0.0)
    """
    K, S = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (K, S)))
    scatters = S > 0.0
    with np.errstate(over="ignore"):
        q = K / np.where(scatters, S, 1.0)
    return np.where(scatters, reflectance_infinite_from_ks(q), 0.0)


def ks_from_reflectance_infinite(R_inf) -> np.ndarray:
    """K/S of an opaque layer from its reflectance, KM convention: K/S = (1 - R_inf)^2 / (2 R_inf) (thesis eq. 3.7).

    (The radiative-transfer convention uses 4 R_inf in the denominator; kmpipe never does.)
    R_inf = 0 gives +inf (a black absorber), and so does R_inf below about 3e-309 (K/S beyond the float64
    range); callers that need a finite value must clip R_inf first.

    >>> float(ks_from_reflectance_infinite(0.5))  # (1 - 0.5)^2 / (2 x 0.5)
    0.25
    >>> round(float(reflectance_infinite(ks_from_reflectance_infinite(0.3), 1.0)), 12)  # the inverse of R_inf(K/S)
    0.3
    """
    R_inf = np.asarray(R_inf, dtype=np.float64)
    with np.errstate(divide="ignore", over="ignore"):
        return (1.0 - R_inf) ** 2 / (2.0 * R_inf)


def reflectance_infinite_from_ks(ks) -> np.ndarray:
    """R_inf from K/S (KM convention, thesis eq. 3.6): R_inf = 1 / (1 + q + sqrt(q (q + 2))), q = K/S.

    This is a - b = 1 + q - sqrt(q^2 + 2 q) written as 1 / (a + b), which has no cancellation for small or large
    q; for q beyond 1e150 (where q (q + 2) would overflow) it uses 0.5 / (q + 1), the same to rounding.
    """
    q = np.asarray(ks, dtype=np.float64)
    huge = q > 1e150
    safe = np.where(huge, 0.0, q)
    return np.where(huge, 0.5 / (q + 1.0), 1.0 / (1.0 + safe + np.sqrt(safe * (safe + 2.0))))


def stack_films(R0, T) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Compose homogeneous films into one layer (thesis eq. 3.13 and thesis eq. 3.14), composed bottom-up.

    Parameters
    ----------
    R0, T
        Arrays of shape (n_layers, ...): each layer's reflectance (same from both sides for a
        homogeneous KM film) and transmittance; index 0 is the TOP layer.

    Returns
    -------
    R_top, T_total, R_bottom
        Reflectance of the stack seen from above, its transmittance (the same in both directions),
        and its reflectance seen from below. Adding layer i on top of the partial stack (r, t, r'):
        r <- R_i + T_i^2 r / (1 - R_i r) (thesis eq. 3.14, printed with T2 where R2 belongs),
        t <- T_i t / (1 - R_i r) (thesis eq. 3.13), and r' <- r' + t^2 R_i / (1 - R_i r) (thesis eq. 3.12 seen from
        below: the partial stack, whose two sides differ, is layer 1 with R_I = r; printed with T2 for R2).
        Composing top-down instead would need each partial stack's underside reflectance, which is
        why the recurrence runs from the bottom. All three are clamped to [0, 1].

    >>> import numpy as np
    >>> R0, T = film_reflectance_transmittance(1.0, 40.0, np.array([0.01, 0.01]))  # two 10 um films, top first
    >>> R_top, T_total, R_bottom = stack_films(R0, T)
    >>> whole = film_reflectance_transmittance(1.0, 40.0, 0.02)  # compose to the 20 um film of the same material
    >>> bool(np.allclose([R_top, T_total], whole, rtol=1e-12, atol=0.0)), bool(np.isclose(R_bottom, R_top))
    (True, True)
    """
    R0 = np.asarray(R0, dtype=np.float64)
    T = np.asarray(T, dtype=np.float64)
    R0, T = np.broadcast_arrays(R0, T)
    r_top, t, r_bottom = R0[-1], T[-1], R0[-1]
    for R_i, T_i in zip(R0[-2::-1], T[-2::-1], strict=True):
        denominator = _positive(1.0 - R_i * r_top)
        r_bottom = r_bottom + t * t * R_i / denominator
        t = T_i * t / denominator
        r_top = R_i + T_i * T_i * r_top / denominator
    return np.clip(r_top, 0.0, 1.0), np.clip(t, 0.0, 1.0), np.clip(r_bottom, 0.0, 1.0)


def stack_over_substrate(R0, T, R_g) -> np.ndarray:
    """Reflectance in [0, 1] of a stack of films (index 0 on top, shape (n_layers, ...)) over a substrate R_g.

    R = R_top + T_total^2 R_g / (1 - R_bottom R_g) (thesis eq. 3.12: the stack of :func:`stack_films` is layer 1, its
    underside R_bottom the thesis's R_I, the substrate layer 2; printed with T2 where R2, here R_g, belongs), clamped
    to [0, 1]: rounding leaves it up to 2 ulp above 1 where R_g = 1 and the films barely absorb.
    """
    R_top, T_total, R_bottom = stack_films(R0, T)
    R_g = np.asarray(R_g, dtype=np.float64)
    return np.clip(R_top + T_total * T_total * R_g / _positive(1.0 - R_bottom * R_g), 0.0, 1.0)


def hiding_thickness(K, S, R_black, R_white, contrast_ratio: float = 0.98) -> np.ndarray:
    """Thickness at which the film hides its backing: R(over black) / R(over white) = contrast_ratio.

    The contrast ratio of a KM film rises monotonically from R_black / R_white at X = 0 towards 1, so
    the root is bracketed and found by bisection on log X (vectorized; 64 halvings of a bracket 55 wide
    in log X leave less than one ulp). Returns +inf where the film never hides (S = 0: a clear,
    absorbing film) and 0 where the backings already meet the ratio.

    Parameters
    ----------
    K, S
        Coefficients per unit length (1/mm).
    R_black, R_white
        Reflectances of the two backings (e.g. 0.03 and 0.85 for a Leneta-style card).
    contrast_ratio
        Target ratio in (0, 1); 0.98 is the common definition of hiding.

    >>> X = hiding_thickness(1.0, 40.0, 0.04, 0.85)  # mm, for the default contrast ratio 0.98
    >>> over_black, over_white = (reflectance_over_background(1.0, 40.0, X, g) for g in (0.04, 0.85))
    >>> round(float(over_black / over_white), 9), float(hiding_thickness(1.0, 0.0, 0.04, 0.85))
    (0.98, inf)
    """
    if not 0.0 < contrast_ratio < 1.0:
        raise ValueError(f"contrast_ratio must lie in (0, 1), got {contrast_ratio}")
    K, S, R_black, R_white = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (K, S, R_black, R_white)))

    def contrast(X):
        R0, T = film_reflectance_transmittance(K, S, X)
        return film_over_background(R0, T, R_black) / film_over_background(R0, T, R_white)

    never = S <= 0.0
    S = np.where(never, 1.0, S)  # a stand-in, so that no 0/0 arises; the answer there is inf
    already = contrast(np.zeros_like(K)) >= contrast_ratio
    # Bracket in optical thickness: with s = K + S the contrast is 1 - O(e^-2x); 1e-12 .. 1e12 / s covers it.
    half_scale = np.where(never, 0.5, 0.5 * K + 0.5 * S)  # (K + S) / 2, which cannot overflow
    lo = np.full_like(K, np.log(0.5e-12)) - np.log(half_scale)
    hi = np.full_like(K, np.log(0.5e12)) - np.log(half_scale)
    for _ in range(64):
        mid = 0.5 * (lo + hi)
        below = contrast(np.exp(mid)) < contrast_ratio
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    X = np.exp(0.5 * (lo + hi))
    return np.where(never, np.inf, np.where(already, 0.0, X))
