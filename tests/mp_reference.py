"""Independent 50-digit references for the Kubelka-Munk tests (not a test module).

Everything here is written from the textbook formulas, evaluated elementwise with mpmath at
``DPS`` significant digits on the exact binary value of each float64 input. Nothing here imports
``kmpipe``. Notation (Kubelka 1948; the thesis's equations are tagged ``thesis eq. N.M``, see docs/equations.md):

    a = 1 + K/S,  b = sqrt(a^2 - 1),  x = b S X
    R0 = sinh x / (a sinh x + b cosh x) (thesis eq. 3.8),  T = b / (a sinh x + b cosh x) (thesis eq. 3.9)
    R over Rg = R0 + T^2 Rg / (1 - R0 Rg) (thesis eq. 3.14),  R_inf = a - b (thesis eq. 3.6),
    K/S = (1 - R)^2 / (2 R) (thesis eq. 3.7)

Limits that the textbook form cannot evaluate (0/0) use their closed forms:
X = 0 -> (0, 1); S = 0 -> (0, exp(-K X)); K = 0 -> (SX / (1 + SX), 1 / (1 + SX)).
"""

from __future__ import annotations

from collections.abc import Callable

import mpmath
import numpy as np

DPS = 50
_ctx = mpmath.MPContext()
_ctx.dps = DPS
mpf = _ctx.mpf


def m(x: float) -> mpmath.mpf:
    """The exact value of a float64 as a 50-digit number."""
    return mpf(float(x))


# ---------------------------------------------------------------------------------------------
# scalar references (mp numbers in, mp numbers out)
# ---------------------------------------------------------------------------------------------
def film(K, S, X):
    """(R0, T) of a KM film over an ideal black background: textbook sinh/cosh form (thesis eq. 3.8, thesis eq. 3.9)."""
    K, S, X = mpf(K), mpf(S), mpf(X)
    if X == 0:
        return mpf(0), mpf(1)
    if S == 0:
        return mpf(0), _ctx.exp(-K * X)
    if K == 0:
        return S * X / (1 + S * X), 1 / (1 + S * X)
    a = 1 + K / S
    # b = sqrt(a^2 - 1) = sqrt(K (K + 2 S)) / S, written so that a^2 - 1 is not formed by cancellation
    b = _ctx.sqrt(K * (K + 2 * S)) / S
    x = b * S * X
    sh, ch = _ctx.sinh(x), _ctx.cosh(x)
    den = a * sh + b * ch
    return sh / den, b / den


def over_background(R0, T, Rg):
    """Film (R0, T) over a background of reflectance Rg (thesis eq. 3.14 with the background as layer 2; the thesis
    prints T2 where R2, here Rg, belongs)."""
    R0, T, Rg = mpf(R0), mpf(T), mpf(Rg)
    if T == 0:  # nothing gets through (also covers R0 = Rg = 1, a perfect mirror on a perfect mirror)
        return R0
    return R0 + T * T * Rg / (1 - R0 * Rg)


def reflectance(K, S, X, Rg):
    R0, T = film(K, S, X)
    return over_background(R0, T, Rg)


def reflectance_coth(K, S, X, Rg):
    """Thesis eq. 3.5 as printed: R = (1 - Rg (a - b coth(bSX))) / (a - Rg + b coth(bSX)); K, S, X > 0."""
    K, S, X, Rg = mpf(K), mpf(S), mpf(X), mpf(Rg)
    a = 1 + K / S
    b = _ctx.sqrt(K * (K + 2 * S)) / S
    y = b * _ctx.coth(b * S * X)
    return (1 - Rg * (a - y)) / (a - Rg + y)


def r_inf(K, S):
    """R_inf = a - b = 1 + K/S - sqrt((K/S)^2 + 2 K/S) (thesis eq. 3.6 as printed); 0 for S = 0.

    Evaluated literally, with the working precision raised by the digits that a - b cancels.
    """
    K, S = mpf(K), mpf(S)
    if S == 0:
        return mpf(0)
    q = K / S
    extra = 0 if q < 1 else 2 * int(_ctx.log10(q)) + 10
    with _ctx.extradps(extra):
        q = mpf(K) / mpf(S)
        val = 1 + q - _ctx.sqrt(q * q + 2 * q)
    return +val


def ks_from_r(R):
    """K/S from the reflectance of an opaque layer (KM convention, factor 2; thesis eq. 3.7)."""
    R = mpf(R)
    return (1 - R) ** 2 / (2 * R)


def saunderson_forward(R, k1, k2):
    R, k1, k2 = mpf(R), mpf(k1), mpf(k2)
    return k1 + (1 - k1) * (1 - k2) * R / (1 - k2 * R)


def saunderson_inverse(Rm, k1, k2):
    Rm, k1, k2 = mpf(Rm), mpf(k1), mpf(k2)
    return (Rm - k1) / (1 - k1 - k2 + k2 * Rm)


def stack_bottom_up(R0s, Ts, Rg):
    """Reflectance of layers (index 0 = top) over a substrate Rg, composed bottom-up with thesis eq. 3.14."""
    R = mpf(Rg)
    for R0, T in zip(reversed(list(R0s)), reversed(list(Ts)), strict=True):
        R0, T = mpf(R0), mpf(T)
        R = R0 + T * T * R / (1 - R0 * R)
    return R


def stack_two_sided(R0s, Ts):
    """(R_top, T_total, R_bottom) of symmetric layers (index 0 = top), adding them top-down.

    Each KM film reflects the same from both sides; the partial stack does not, so its underside
    reflectance is carried along (adding method): the top reflectance by thesis eq. 3.12 (the partial stack is layer
    1, its underside the thesis's R_I), the transmittance by thesis eq. 3.10 with R_I for R_1, the underside by
    thesis eq. 3.14 seen from below (R2 for the printed T2 throughout).
    """
    R0s, Ts = [mpf(v) for v in R0s], [mpf(v) for v in Ts]
    Rt, Tt, Rb = R0s[0], Ts[0], R0s[0]
    for R, T in zip(R0s[1:], Ts[1:], strict=True):
        den = 1 - Rb * R
        Rt, Tt, Rb = Rt + Tt * Tt * R / den, Tt * T / den, R + T * T * Rb / den
    return Rt, Tt, Rb


def contrast_ratio(K, S, X, R_black, R_white):
    """R over black / R over white for the same film."""
    R0, T = film(K, S, X)
    return over_background(R0, T, R_black) / over_background(R0, T, R_white)


def black_white_inverse(Rob, Row, Rb, Rw, X):
    """(K, S) of a film of thickness X from its reflectances over two backgrounds Rb and Rw.

    Each reading satisfies (R + Rg) a + (R - Rg) y = 1 + R Rg with y = b coth(b S X) (thesis eq. 3.5 multiplied
    out); written for
    (a - 1, y) the right-hand side is (1 - R)(1 - Rg). Solved by Cramer's rule at 50 digits.
    Returns None where the readings admit no film (a < 1 or y <= b).
    """
    Rob, Row, Rb, Rw, X = (mpf(v) for v in (Rob, Row, Rb, Rw, X))
    a11, a12, r1 = Rob + Rb, Rob - Rb, (1 - Rob) * (1 - Rb)
    a21, a22, r2 = Row + Rw, Row - Rw, (1 - Row) * (1 - Rw)
    det = a11 * a22 - a12 * a21
    if det == 0:
        return None
    am1 = (r1 * a22 - a12 * r2) / det
    y = (a11 * r2 - a21 * r1) / det
    if am1 <= 0:
        return None
    b = _ctx.sqrt(am1 * (am1 + 2))
    if y <= b:
        return None
    SX = _ctx.log((y + b) / (y - b)) / (2 * b)  # arcoth(y / b) / b
    S = SX / X
    return S * am1, S


def two_constant_inverse(Rinf, R, Rg, X):
    """(K, S) from masstone R_inf and a film of thickness X over Rg read as R (thesis eq. 4.1 in the method notes'
    real form, thesis eq. 4.2).

    S X = ln[(1/Ri - R)(Ri - Rg) / ((Ri - R)(1/Ri - Rg))] / (1/Ri - Ri), K = S (a - 1),
    a - 1 = (1 - Ri)^2 / (2 Ri). Returns None where the logarithm's argument is not positive.
    """
    Ri, R, Rg, X = (mpf(v) for v in (Rinf, R, Rg, X))
    if Ri <= 0 or Ri == R or Ri * Rg == 1:
        return None
    arg = (1 / Ri - R) * (Ri - Rg) / ((Ri - R) * (1 / Ri - Rg))
    if not arg > 0:
        return None
    SX = _ctx.log(arg) / (1 / Ri - Ri)
    S = SX / X
    return S * ks_from_r(Ri), S


def two_constant_arcoth(Rinf, R, Rg, X):
    """Thesis eq. 4.1 and thesis eq. 4.2 as printed: a = (1/R_inf + R_inf) / 2, b = sqrt(a^2 - 1),
    S = [arcoth((a - R)/b) - arcoth((a - Rg)/b)] / (b X), K = S (a - 1).

    Returns None where an arcoth argument is not above 1: the printed form is complex there (a film over a light
    background brighter than its masstone).
    """
    Ri, R, Rg, X = (mpf(v) for v in (Rinf, R, Rg, X))
    a = (1 / Ri + Ri) / 2
    b = _ctx.sqrt(a * a - 1)
    u, v = (a - R) / b, (a - Rg) / b
    if not (u > 1 and v > 1):
        return None
    S = (_ctx.acoth(u) - _ctx.acoth(v)) / (b * X)
    return S * (a - 1), S


def curtis_arcoth(Rob, Row, X=1.0):
    """Curtis et al. 1997 (thesis eq. 4.5 with arcoth, as the method notes correct it, and thesis eq. 4.6), literal
    form."""
    RB, RW, X = mpf(Rob), mpf(Row), mpf(X)
    a = (RW + (RB - RW + 1) / RB) / 2
    b = _ctx.sqrt(a * a - 1)
    S = _ctx.acoth((b * b - (a - RW) * (a - 1)) / (b * (1 - RW))) / (b * X)
    return S * (a - 1), S


# ---------------------------------------------------------------------------------------------
# condition numbers: |d ln f / d ln p| summed over the inputs, by a 1e-25 relative step at 50 digits
# ---------------------------------------------------------------------------------------------
def condition(f: Callable, *args, index: int = 0):
    """Sum over inputs p of |p df/dp / f| for output ``index`` of ``f`` (a scalar reference)."""
    args = [mpf(v) for v in args]

    def out(vals):
        r = f(*vals)
        return r[index] if isinstance(r, tuple) else r

    f0 = out(args)
    if f0 == 0:
        return mpf(0)
    h = mpf("1e-25")
    total = mpf(0)
    for i, p in enumerate(args):
        if p == 0:
            continue
        moved = list(args)
        moved[i] = p * (1 + h)
        total += abs((out(moved) - f0) / (f0 * h))
    return total


# ---------------------------------------------------------------------------------------------
# elementwise over numpy arrays
# ---------------------------------------------------------------------------------------------
def vec(f: Callable, *arrays, nout: int = 1, as_float: bool = True):
    """Apply scalar reference ``f`` elementwise over broadcast float64 arrays.

    Returns float64 arrays (correctly rounded from the 50-digit value) or object arrays of mp
    numbers when ``as_float`` is false; a tuple when ``nout`` > 1. ``None`` results become NaN.
    """
    arrays = np.broadcast_arrays(*[np.asarray(a, dtype=np.float64) for a in arrays])
    shape = arrays[0].shape
    outs = [np.empty(shape, dtype=np.float64 if as_float else object) for _ in range(nout)]
    with _ctx.workdps(DPS):
        for idx in np.ndindex(shape):
            r = f(*[m(a[idx]) for a in arrays])
            if r is None:
                r = (_ctx.nan,) * nout
            if nout == 1:
                r = (r,)
            for o, v in zip(outs, r, strict=True):
                o[idx] = float(v) if as_float else v
    return outs[0] if nout == 1 else tuple(outs)


def mp_rel_err(got, ref) -> np.ndarray:
    """|got - ref| / |ref| elementwise, with ``ref`` an object array of mp numbers (inf where ref = 0)."""
    got = np.asarray(got, dtype=np.float64)
    ref = np.asarray(ref, dtype=object)
    got, ref = np.broadcast_arrays(got, ref)
    out = np.empty(got.shape, dtype=np.float64)
    for idx in np.ndindex(got.shape):
        r = ref[idx]
        d = abs(m(got[idx]) - r)
        out[idx] = 0.0 if d == 0 else (float(d / abs(r)) if r != 0 else np.inf)
    return out
