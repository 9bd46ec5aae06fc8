"""Reference tests for the Kubelka-Munk inversions (kmpipe.physics.inversion) and their flags.

Readings are simulated from known K and S with the 50-digit textbook forward model (``mp_reference``),
rounded to float64, inverted by the code, and compared with the K and S they came from.

What "well-conditioned" means here, per element:
  * the film does not hide its backing: contrast 1 - R(over black)/R(over white) > 1e-3 for
    ``black_white`` (for ``two_constant``: |R - R_inf| > 1e-3 R_inf and |R_g - R_inf| > 1e-3 R_inf), and
  * the EXACT inversion (50 digits) of the very float64 readings that the code receives lands within
    1e-11 of the true K and S, i.e. the data themselves determine K and S to 11 digits.
Well-conditioned elements that the code does not flag must come back within 1e-9. Well-conditioned elements
with a clear contrast (> 2%, far above any measuring tolerance) must not be flagged at all. Flagged OPAQUE
elements must still give K/S to 1e-9, and K, S no larger than the truth (a lower bound).
"""

from __future__ import annotations

import functools
import warnings

import mp_reference as ref
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from simulation import cards, rit_pigments

from kmpipe.physics import inversion as inv
from kmpipe.physics import saunderson as sd
from kmpipe.physics.flags import Flag

#: the RIT table's S is relative (titanium white = 1); x10 makes it per mm for films of 10-300 um.
#: K is scaled alike so that K/S, and so the masstone, is the table's.
SCALE_PER_MM = 10.0
THICKNESSES_MM = (0.01, 0.03, 0.1, 0.3)
SAUNDERSON_K1, SAUNDERSON_K2 = 0.03, 0.65  # the constants the RIT coefficients were fitted with

WELL = 1e-9  # required accuracy where well-conditioned
INTRINSIC = 1e-11  # what the data themselves must determine for an element to count as well-conditioned
HIDES = 1e-3  # contrast below which a film is treated as hiding its backing
CLEAR = 0.02  # contrast above which no OPAQUE flag is acceptable
# AT_BOUND: K (or S) moved to 0 because the readings asked for slightly less; such values need not reproduce them.
ANY_FLAG = int(Flag.OPAQUE | Flag.OUT_OF_RANGE | Flag.NO_CONTRAST | Flag.AT_BOUND)


# ---------------------------------------------------------------------------------------------
# data
# ---------------------------------------------------------------------------------------------
@functools.cache
def rit_table():
    """(names, wavelengths_nm, K, S) of the RIT paints (``simulation.rit_pigments``), K and S x ``SCALE_PER_MM`` in
    1/mm, shape (n_pigments, n_wl)."""
    table = rit_pigments()
    K = np.array([table.K[name] for name in table.names])
    S = np.array([table.S[name] for name in table.names])
    return table.names, table.wavelengths, SCALE_PER_MM * K, SCALE_PER_MM * S


def _to_float(a):
    return np.asarray(a, dtype=object).astype(np.float64)


@functools.cache
def simulated(X: float, saunderson: bool):
    """Float64 readings of every RIT pigment film of thickness X over the two cards, and its masstone.

    With ``saunderson`` the instrument sees the surface too: every reading, the cards' and the masstone's
    included, goes through the Saunderson forward model at 50 digits, and is corrected back with the
    code's ``saunderson_inverse`` before it is inverted (as the pipeline does).
    """
    _, wl, K, S = rit_table()
    backings = cards(wl)
    Gb, Gw = backings["black"], backings["white"]
    Rob = ref.vec(ref.reflectance, K, S, X, Gb, as_float=False)
    Row = ref.vec(ref.reflectance, K, S, X, Gw, as_float=False)
    Rinf = ref.vec(ref.r_inf, K, S, as_float=False)
    contrast = 1.0 - _to_float(Rob / Row)
    readings = {"Rob": Rob, "Row": Row, "Rinf": Rinf, "Gb": Gb, "Gw": Gw}
    if saunderson:
        k1, k2 = SAUNDERSON_K1, SAUNDERSON_K2
        for key, val in readings.items():
            measured = ref.vec(lambda r: ref.saunderson_forward(r, k1, k2), _to_float(val))
            readings[key] = sd.saunderson_inverse(measured, k1, k2)
    else:
        readings = {key: _to_float(val) for key, val in readings.items()}
    return {"K": K, "S": S, "contrast": contrast, **readings}


def _intrinsic(fun, K, S, *args):
    """Largest relative error of K or S from the exact inversion of the float64 inputs (inf if none)."""
    Ki, Si = ref.vec(lambda *a: fun(*a), *args, nout=2)
    with np.errstate(invalid="ignore"):
        err = np.maximum(np.abs(Ki - K) / K, np.abs(Si - S) / S)
    return np.where(np.isfinite(err), err, np.inf)


def _rel(got, true):
    return np.abs(got - true) / true


def _check_flag_semantics(res, K, S, good, contrast, intrinsic, ks_true, what):
    """The assertions shared by the round trips; returns the number of well-conditioned unflagged elements."""
    flags = np.asarray(res.flags)
    for name in ("K", "S", "ks_ratio"):
        v = getattr(res, name)
        assert v.shape == K.shape, (what, name, v.shape)
        assert np.all(np.isfinite(v)), (what, name)
        assert np.all(v >= 0), (what, name)
    assert flags.shape == K.shape and np.issubdtype(flags.dtype, np.integer)
    unflagged = (flags & ANY_FLAG) == 0
    errK, errS, errKS = _rel(res.K, K), _rel(res.S, S), _rel(res.ks_ratio, ks_true)
    err = np.maximum(errK, errS)

    def show(mask, n=6):
        idx = np.argwhere(mask)[:n]
        out = []
        for i in map(tuple, idx):
            out.append(
                f"{i}: K={K[i]:.6g} S={S[i]:.6g} contrast={contrast[i]:.3g} got K={res.K[i]:.17g} "
                f"S={res.S[i]:.17g} flags={int(flags[i])} errK={errK[i]:.3g} errS={errS[i]:.3g} "
                f"intrinsic={intrinsic[i]:.3g}"
            )
        return out

    # 1. well-conditioned and unflagged: K, S and K/S to 1e-9
    bad = good & unflagged & ~((err <= WELL) & (errKS <= WELL))
    assert not bad.any(), (what, "well-conditioned but inaccurate", int(bad.sum()), show(bad))
    # 2. a clear contrast is never flagged
    bad = good & (contrast > CLEAR) & ~unflagged
    assert not bad.any(), (what, "flagged although well-conditioned", int(bad.sum()), show(bad))
    # 3. unflagged elsewhere: no worse than the data allow (100x the exact inversion's own error)
    bad = unflagged & ~good & ~(err <= np.maximum(WELL, 100 * intrinsic))
    assert not bad.any(), (what, "unflagged but wrong", int(bad.sum()), show(bad))
    # 4. OPAQUE: K/S exact, K and S a lower bound where the film truly hides its backing
    opaque = (flags & Flag.OPAQUE) != 0
    bad = opaque & ~(errKS <= WELL)
    assert not bad.any(), (what, "OPAQUE with wrong K/S", int(bad.sum()), show(bad))
    hides = opaque & (contrast < HIDES / 2)
    bad = hides & ~((res.K <= K * (1 + WELL)) & (res.S <= S * (1 + WELL)))
    assert not bad.any(), (what, "OPAQUE but not a lower bound", int(bad.sum()), show(bad))
    # 5. exact data are never out of range where they are well-conditioned
    bad = good & ((flags & Flag.OUT_OF_RANGE) != 0)
    assert not bad.any(), (what, "OUT_OF_RANGE on exact data", int(bad.sum()), show(bad))
    return int((good & unflagged).sum())


# ---------------------------------------------------------------------------------------------
# round trips over the 19 RIT pigments
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("saunderson", [False, True], ids=["plain", "saunderson"])
@pytest.mark.parametrize("X", THICKNESSES_MM)
def test_black_white_round_trip_rit(X, saunderson):
    d = simulated(X, saunderson)
    K, S = d["K"], d["S"]
    res = inv.black_white(d["Rob"], d["Row"], d["Gb"], d["Gw"], X)
    intrinsic = _intrinsic(ref.black_white_inverse, K, S, d["Rob"], d["Row"], d["Gb"], d["Gw"], X)
    good = (d["contrast"] > HIDES) & (intrinsic <= INTRINSIC)
    n_ok = _check_flag_semantics(res, K, S, good, d["contrast"], intrinsic, K / S, f"black_white X={X}")
    if X <= 0.1:  # the thin films of this table are mostly well-conditioned: the test is not vacuous
        assert n_ok >= 0.5 * K.size, (n_ok, K.size)
    # films that read (almost) the same over both cards must be flagged
    same = d["Rob"] == d["Row"]
    assert np.all((np.asarray(res.flags)[same] & Flag.OPAQUE) != 0)


@pytest.mark.parametrize("saunderson", [False, True], ids=["plain", "saunderson"])
@pytest.mark.parametrize("X", THICKNESSES_MM)
@pytest.mark.parametrize("card", ["black", "white"])
def test_two_constant_round_trip_rit(X, saunderson, card):
    d = simulated(X, saunderson)
    K, S = d["K"], d["S"]
    R, Rg = (d["Rob"], d["Gb"]) if card == "black" else (d["Row"], d["Gw"])
    Rg = np.broadcast_to(Rg, R.shape)
    res = inv.two_constant(d["Rinf"], R, Rg, X)
    intrinsic = _intrinsic(ref.two_constant_inverse, K, S, d["Rinf"], R, Rg, X)
    Rinf = d["Rinf"]
    contrast = np.minimum(np.abs(R - Rinf), np.abs(Rg - Rinf)) / Rinf
    good = (contrast > HIDES) & (intrinsic <= INTRINSIC)
    n_ok = _check_flag_semantics(res, K, S, good, contrast, intrinsic, K / S, f"two_constant/{card} X={X}")
    if X <= 0.1:
        assert n_ok >= 0.5 * K.size, (n_ok, K.size)
    # K/S comes from the masstone alone: always to 1e-9, whatever the film did
    np.testing.assert_allclose(res.ks_ratio, K / S, rtol=WELL, atol=0)


def test_dark_film_over_grey_black_card_is_in_range():
    # A strongly absorbing film darkens a real (0.03) black card: physical, not out of range.
    K, S, X, Gb, Gw = 50.0, 0.1, 0.02, 0.03, 0.85
    Rob, Row = (float(ref.reflectance(K, S, X, g)) for g in (Gb, Gw))
    assert Rob < Gb
    res = inv.black_white(Rob, Row, Gb, Gw, X)
    assert int(res.flags) == 0
    np.testing.assert_allclose([res.K, res.S], [K, S], rtol=WELL)
    res = inv.two_constant(float(ref.r_inf(K, S)), Rob, Gb, X)
    assert int(res.flags) == 0
    np.testing.assert_allclose([res.K, res.S], [K, S], rtol=WELL)


def test_two_constant_is_the_printed_eq_4_1_where_that_is_real():
    """Over a black card (R and R_g below R_inf) thesis eq. 4.1 and thesis eq. 4.2 as printed (arcoth,
    a = (1/R_inf + R_inf) / 2; 50 digits on the float readings) are real: the real-valued form gives the same K, S."""
    K = np.array([0.02, 0.3, 1.0, 5.0, 30.0])
    S = np.array([5.0, 1.0, 2.0, 0.5, 3.0])
    X, Rg = 0.02, 0.035
    R_inf = ref.vec(ref.r_inf, K, S)
    R = ref.vec(ref.reflectance, K, S, X, Rg)
    K_printed, S_printed = ref.vec(ref.two_constant_arcoth, R_inf, R, Rg, X, nout=2)
    res = inv.two_constant(R_inf, R, Rg, X)
    assert np.all(np.asarray(res.flags) == 0)
    np.testing.assert_allclose(res.K, K_printed, rtol=WELL)
    np.testing.assert_allclose(res.S, S_printed, rtol=WELL)
    np.testing.assert_allclose([res.K, res.S], [K, S], rtol=WELL)


def test_film_brighter_than_its_masstone_over_white_is_in_range():
    # Over a light card a weakly scattering, weakly absorbing film reads above its own masstone:
    # thesis eq. 4.1's arcoth form is complex there, the real form is not.
    K, S, X, Gw = 0.5, 1.0, 0.3, 0.85
    R_inf = float(ref.r_inf(K, S))
    R = float(ref.reflectance(K, S, X, Gw))
    assert R_inf < R
    res = inv.two_constant(R_inf, R, Gw, X)
    assert int(res.flags) == 0
    np.testing.assert_allclose([res.K, res.S], [K, S], rtol=WELL)


# ---------------------------------------------------------------------------------------------
# Curtis
# ---------------------------------------------------------------------------------------------
def test_curtis_equals_black_white_with_ideal_backings():
    K = np.array([0.1, 1.0, 5.0, 0.02, 30.0, 2.0, 0.5])
    S = np.array([2.0, 1.0, 0.3, 5.0, 1.0, 20.0, 1e-3])
    X = 0.7
    Rob = ref.vec(ref.reflectance, K, S, X, 0.0)
    Row = ref.vec(ref.reflectance, K, S, X, 1.0)
    c = inv.curtis(Rob, Row, X)
    bw = inv.black_white(Rob, Row, 0.0, 1.0, X)
    np.testing.assert_array_equal(np.asarray(c.flags), np.asarray(bw.flags))
    for name in ("K", "S", "ks_ratio"):
        np.testing.assert_allclose(getattr(c, name), getattr(bw, name), rtol=1e-12, atol=0)
    ok = (np.asarray(c.flags) & ANY_FLAG) == 0
    contrast = 1.0 - Rob / Row
    assert np.all(ok[contrast > CLEAR]) and np.all(~ok[contrast < HIDES / 10])
    np.testing.assert_allclose(c.K[ok], K[ok], rtol=WELL)
    np.testing.assert_allclose(c.S[ok], S[ok], rtol=WELL)


def test_curtis_default_thickness_is_one():
    Rob, Row = float(ref.reflectance(0.3, 2.0, 1.0, 0.0)), float(ref.reflectance(0.3, 2.0, 1.0, 1.0))
    c = inv.curtis(Rob, Row)
    np.testing.assert_allclose([c.K, c.S], [0.3, 2.0], rtol=WELL)


@pytest.mark.parametrize("X", [1.0, 0.05])
def test_curtis_matches_mp_arcoth_form_at_tiny_black_reading(X):
    Rob = np.array([1e-9, 3e-9, 1e-8, 1e-10, 1e-9, 1e-9])
    Row = np.array([0.5, 0.2, 0.8, 0.5, 0.95, 0.05])
    c = inv.curtis(Rob, Row, X)
    K_ref, S_ref = ref.vec(ref.curtis_arcoth, Rob, Row, X, nout=2)
    assert np.all((np.asarray(c.flags) & ANY_FLAG) == 0)
    np.testing.assert_allclose(c.K, K_ref, rtol=1e-10, atol=0)
    np.testing.assert_allclose(c.S, S_ref, rtol=1e-10, atol=0)
    # and the arcoth form agrees with the general 2x2 solution at 50 digits (two independent references)
    K2, S2 = ref.vec(ref.black_white_inverse, Rob, Row, 0.0, 1.0, X, nout=2)
    np.testing.assert_allclose(K2, K_ref, rtol=1e-14)
    np.testing.assert_allclose(S2, S_ref, rtol=1e-14)


def test_nearly_white_films_match_50_digits_where_artanh_w_over_w_is_near_one():
    """K/S from 1e-14 to 1e-3 puts w = b D / N_y between about 1e-7 and 0.04, where artanh(w) / w is within 1e-3 of 1
    (a two-term series there was off by up to 2e-13); readings made at 50 digits, S to 1e-13, K to the rounding of
    N_u (1e-15 S: K/S is a difference of products of readings near 1)."""
    ks = np.concatenate([np.geomspace(1e-14, 1e-3, 23), np.linspace(5e-7, 6.15e-7, 6)])  # then w 0.9e-3 .. 1e-3
    S, X, Gb, Gw = 30.0, 0.03, 0.04, 0.85
    K = ks * S
    Rob = ref.vec(ref.reflectance, K, S, X, Gb)
    Row = ref.vec(ref.reflectance, K, S, X, Gw)
    result = inv.black_white(Rob, Row, Gb, Gw, X)
    K_ref, S_ref = ref.vec(ref.black_white_inverse, Rob, Row, Gb, Gw, X, nout=2)
    assert np.all(result.flags == 0)
    np.testing.assert_allclose(result.S, S_ref, rtol=1e-13, atol=0)
    np.testing.assert_allclose(result.K, K_ref, rtol=1e-13, atol=1e-15 * S)


# ---------------------------------------------------------------------------------------------
# limits and ill-conditioned readings
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("R_white", [0.3, 0.7, 0.98])
def test_pure_absorber_limit(R_white):
    # R over black -> 0: S -> 0 and K X -> -ln(R over white) / 2 (light crosses the film twice)
    X = 0.4
    Rob = np.array([1e-3, 1e-6, 1e-9, 1e-12, 1e-15, 1e-200])
    c = inv.curtis(Rob, R_white, X)
    K_lim = -np.log(R_white) / 2 / X
    for v in (c.K, c.S, c.ks_ratio):
        assert np.all(np.isfinite(v))
    K_ref, S_ref = ref.vec(ref.black_white_inverse, Rob, R_white, 0.0, 1.0, X, nout=2)
    np.testing.assert_allclose(c.K, K_ref, rtol=1e-10)
    np.testing.assert_allclose(c.S, S_ref, rtol=1e-10)
    assert np.all(np.diff(c.S) < 0) and np.all(c.S[-3:] < 1e-11)
    # approach to the limit: |K - K_lim| shrinks with R over black, down to rounding (one ulp of K_lim,
    # itself rounded, once the gap is below 1e-15)
    gap = np.abs(c.K - K_lim) / K_lim
    assert np.all(np.diff(gap) <= np.finfo(float).eps) and gap[-1] <= 1e-13


def test_pure_absorber_reading_zero_over_black():
    c = inv.curtis(np.array([0.0, 0.0]), np.array([0.4, 0.9]), 0.5)
    for v in (c.K, c.S, c.ks_ratio):
        assert np.all(np.isfinite(v)) and np.all(v >= 0)
    np.testing.assert_allclose(c.K, -np.log([0.4, 0.9]) / 2 / 0.5, rtol=1e-9)
    assert np.all(c.S <= 1e-9 * c.K)


def test_clear_absorber_over_real_cards():
    # S = 0 film over real cards: R = T^2 R_g with T = exp(-K X)
    K, X, Gb, Gw = np.array([0.5, 3.0, 20.0]), 0.1, 0.03, 0.85
    Rob = ref.vec(ref.reflectance, K, 0.0, X, Gb)
    Row = ref.vec(ref.reflectance, K, 0.0, X, Gw)
    res = inv.black_white(Rob, Row, Gb, Gw, X)
    for v in (res.K, res.S, res.ks_ratio):
        assert np.all(np.isfinite(v)) and np.all(v >= 0)
    np.testing.assert_allclose(res.K, K, rtol=1e-9)
    assert np.all(res.S <= 1e-9 * K)


@pytest.mark.parametrize("R", [0.01, 0.2, 0.5, 0.9])
def test_equal_readings_over_both_backings_are_opaque(R):
    expected_ks = float(ref.ks_from_r(R))
    for res in (inv.black_white(R, R, 0.03, 0.85, 0.05), inv.curtis(R, R, 0.05)):
        assert int(res.flags) & Flag.OPAQUE
        for v in (res.K, res.S, res.ks_ratio):
            assert np.isfinite(v) and v >= 0
        assert float(res.ks_ratio) == pytest.approx(expected_ks, rel=1e-12)
        assert float(res.K) == pytest.approx(float(res.S) * expected_ks, rel=1e-12)
    # two_constant: the film reads its own masstone
    res = inv.two_constant(R, R, 0.03 if R > 0.1 else 0.85, 0.05)
    assert int(res.flags) & Flag.OPAQUE
    assert float(res.ks_ratio) == pytest.approx(expected_ks, rel=1e-12)


def test_background_as_bright_as_masstone_has_no_contrast():
    R_inf = np.array([0.3, 0.6, 0.85])
    res = inv.two_constant(R_inf, R_inf, R_inf, 0.1)
    assert np.all((np.asarray(res.flags) & Flag.NO_CONTRAST) != 0)
    for v in (res.K, res.S, res.ks_ratio):
        assert np.all(np.isfinite(v)) and np.all(v >= 0)
    np.testing.assert_allclose(res.ks_ratio, ref.vec(ref.ks_from_r, R_inf), rtol=1e-12)


OUT_OF_RANGE_BW = [
    # (R over black, R over white, black card, white card): why it is impossible
    (0.6, 0.4, 0.03, 0.85),  # brighter over black than over white
    (0.01, 0.9, 0.03, 0.85),  # darkens the black card (R_inf < 0.03) yet brightens the white (R_inf > 0.85)
    (0.02, 0.88, 0.04, 0.8),  # the same, other cards
    (-0.01, 0.5, 0.03, 0.85),  # negative reading
    (0.3, 1.2, 0.03, 0.85),  # reading above 1
    (0.2, 0.5, 0.0, 1.0),  # fine (control), see below
]


@pytest.mark.parametrize(("Rob", "Row", "Gb", "Gw"), OUT_OF_RANGE_BW)
def test_black_white_out_of_range(Rob, Row, Gb, Gw):
    res = inv.black_white(Rob, Row, Gb, Gw, 0.05)
    for v in (res.K, res.S, res.ks_ratio):
        assert np.isfinite(v) and v >= 0
    # is there any film that gives these readings? exact 50-digit inversion says
    feasible = 0 <= Rob <= 1 and 0 <= Row <= 1 and ref.black_white_inverse(Rob, Row, Gb, Gw, 0.05) is not None
    assert bool(int(res.flags) & Flag.OUT_OF_RANGE) == (not feasible)


OUT_OF_RANGE_2C = [
    # (R_inf, R, R_g)
    (0.5, 0.9, 0.85),  # over white: brighter than both the white card and the masstone
    (0.5, 0.01, 0.03),  # over black: darker than both the black card and the masstone
    (0.3, 0.5, 0.03),  # above both
    (0.6, 0.2, 0.85),  # below both
    (0.4, 1.1, 0.85),  # above 1
    (0.4, -0.02, 0.03),  # negative
    (0.4, 0.2, 0.03),  # fine (control)
    (0.5, 0.7, 0.85),  # fine (control)
]


@pytest.mark.parametrize(("R_inf", "R", "Rg"), OUT_OF_RANGE_2C)
def test_two_constant_out_of_range(R_inf, R, Rg):
    res = inv.two_constant(R_inf, R, Rg, 0.05)
    for v in (res.K, res.S, res.ks_ratio):
        assert np.isfinite(v) and v >= 0
    between = min(Rg, R_inf) <= R <= max(Rg, R_inf)
    assert bool(int(res.flags) & Flag.OUT_OF_RANGE) == (not between)
    assert float(res.ks_ratio) == pytest.approx(float(ref.ks_from_r(R_inf)), rel=1e-12)


def test_curtis_out_of_range_when_black_reads_brighter():
    res = inv.curtis(np.array([0.6, 0.3]), np.array([0.4, 0.5]))
    assert int(res.flags[0]) & Flag.OUT_OF_RANGE and not int(res.flags[1]) & ANY_FLAG
    assert np.all(np.isfinite(res.K)) and np.all(res.K >= 0) and np.all(res.S >= 0)


# ---------------------------------------------------------------------------------------------
# property sweeps: never NaN, never negative, and unflagged answers reproduce the readings
# ---------------------------------------------------------------------------------------------
def _assert_sane(res, shape):
    for name in ("K", "S", "ks_ratio"):
        v = np.asarray(getattr(res, name))
        assert v.shape == shape
        assert np.all(np.isfinite(v)) and np.all(v >= 0), (name, v)
    assert np.asarray(res.flags).shape == shape


def _reproduces(K, S, X, Rg, R, tol=WELL):
    return abs(float(ref.reflectance(K, S, X, Rg)) - R) <= tol


unit = st.floats(min_value=0.0, max_value=1.0)


@st.composite
def film_readings(draw, Gb, Gw):
    """Readings of some KM film (R0 >= 0, T >= 0, R0 + T <= 1) over the two backings, or arbitrary ones."""
    if draw(st.booleans()):
        return draw(unit), draw(unit)
    R0 = draw(unit)
    T = draw(unit) * (1.0 - R0)
    return tuple(float(ref.over_background(R0, T, g)) for g in (Gb, Gw))


@settings(max_examples=40, deadline=None)
@given(data=st.data(), Gb=st.floats(0.0, 0.06), Gw=st.floats(0.75, 0.95), X=st.floats(1e-3, 1.0))
def test_black_white_sweep(data, Gb, Gw, X):
    pairs = data.draw(st.lists(film_readings(Gb, Gw), min_size=1, max_size=6))
    Rob, Row = (np.array(v) for v in zip(*pairs, strict=True))
    res = inv.black_white(Rob, Row, Gb, Gw, X)
    _assert_sane(res, Rob.shape)
    for i in np.flatnonzero((np.asarray(res.flags) & ANY_FLAG) == 0):
        assert _reproduces(res.K[i], res.S[i], X, Gb, Rob[i]), (Rob[i], Row[i], res.K[i], res.S[i])
        assert _reproduces(res.K[i], res.S[i], X, Gw, Row[i]), (Rob[i], Row[i], res.K[i], res.S[i])


@settings(max_examples=40, deadline=None)
@given(data=st.data(), X=st.floats(1e-3, 1.0))
def test_curtis_sweep(data, X):
    pairs = data.draw(st.lists(film_readings(0.0, 1.0), min_size=1, max_size=6))
    Rob, Row = (np.array(v) for v in zip(*pairs, strict=True))
    res = inv.curtis(Rob, Row, X)
    _assert_sane(res, Rob.shape)
    for i in np.flatnonzero((np.asarray(res.flags) & ANY_FLAG) == 0):
        assert _reproduces(res.K[i], res.S[i], X, 0.0, Rob[i])
        assert _reproduces(res.K[i], res.S[i], X, 1.0, Row[i])


@settings(max_examples=40, deadline=None)
@given(
    rows=st.lists(st.tuples(unit, unit, unit), min_size=1, max_size=6),
    X=st.floats(1e-3, 1.0),
)
def test_two_constant_sweep(rows, X):
    R_inf, R, Rg = (np.array(v) for v in zip(*rows, strict=True))
    res = inv.two_constant(R_inf, R, Rg, X)
    _assert_sane(res, R.shape)
    for i in np.flatnonzero((np.asarray(res.flags) & ANY_FLAG) == 0):
        # the masstone through K/S (R_inf(K, S) is 0/0 at K = S = 0)
        assert abs(float(ref.r_inf(res.ks_ratio[i], 1.0)) - R_inf[i]) <= WELL
        assert res.K[i] == pytest.approx(res.ks_ratio[i] * res.S[i], rel=1e-12, abs=1e-300)
        assert _reproduces(res.K[i], res.S[i], X, Rg[i], R[i]), (R_inf[i], R[i], Rg[i], res.K[i], res.S[i])


# ---------------------------------------------------------------------------------------------
# camera data: (..., 3) works like spectra
# ---------------------------------------------------------------------------------------------
def test_three_channel_camera_data():
    names, wl, K_all, S_all = rit_table()
    channels = [int(np.flatnonzero(wl == w)[0]) for w in (610.0, 540.0, 460.0)]  # R, G, B
    pick = [names.index(n) for n in ("CadmiumRedLight", "CobaltBlue", "TitaniumWhite", "QuinacridoneMagenta")]
    K = K_all[np.ix_(pick, channels)]  # (4, 3)
    S = S_all[np.ix_(pick, channels)]
    X = np.array([0.01, 0.03]).reshape(2, 1, 1)  # -> (2, 4, 3)
    Gb, Gw = np.array([0.035, 0.03, 0.032]), np.array([0.86, 0.84, 0.83])
    Kb, Sb = np.broadcast_to(K, (2, 4, 3)), np.broadcast_to(S, (2, 4, 3))
    Rob = ref.vec(ref.reflectance, Kb, Sb, X, Gb)
    Row = ref.vec(ref.reflectance, Kb, Sb, X, Gw)
    Rinf = ref.vec(ref.r_inf, Kb, Sb)
    bw = inv.black_white(Rob, Row, Gb, Gw, X)
    tc = inv.two_constant(Rinf, Rob, Gb, X)
    for res in (bw, tc):
        _assert_sane(res, (2, 4, 3))
        assert np.all((np.asarray(res.flags) & ANY_FLAG) == 0)
        np.testing.assert_allclose(res.K, Kb, rtol=WELL)
        np.testing.assert_allclose(res.S, Sb, rtol=WELL)
    # the same numbers as one flat 'spectrum' per call
    Xf = np.broadcast_to(X, (2, 4, 3)).ravel()
    flat = inv.black_white(Rob.ravel(), Row.ravel(), np.tile(Gb, 8), np.tile(Gw, 8), Xf)
    np.testing.assert_allclose(flat.K.reshape(2, 4, 3), bw.K, rtol=1e-15)
    np.testing.assert_allclose(flat.S.reshape(2, 4, 3), bw.S, rtol=1e-15)
    cu = inv.curtis(ref.vec(ref.reflectance, Kb, Sb, X, 0.0), ref.vec(ref.reflectance, Kb, Sb, X, 1.0), X)
    _assert_sane(cu, (2, 4, 3))
    np.testing.assert_allclose(cu.K, Kb, rtol=WELL)
    np.testing.assert_allclose(cu.S, Sb, rtol=WELL)


def test_the_layout_of_the_inputs_does_not_change_a_bit():
    """Broadcast backings and thicknesses, a Fortran-ordered or read-only reading, and arrays of many blocks with hard
    (careful-path) elements scattered through them: every value as with full-size C-ordered copies of the inputs, and
    as row by row (each row inverted alone, in a block of its own)."""
    rng = np.random.default_rng(11)
    rows, wavelengths = 300, 97  # 29,100 values: two blocks and a part, cut inside a row
    Gb, Gw = rng.uniform(0.0, 0.06, wavelengths), np.float64(0.85)
    X = rng.uniform(0.005, 0.1, (rows, 1))
    Rob = rng.uniform(0.0, 0.6, (rows, wavelengths))
    Row = np.clip(Rob + rng.uniform(-0.05, 0.4, (rows, wavelengths)), 0.0, 1.0)  # some opaque, some out of range
    Rob[::7, ::5] = Row[::7, ::5]  # equal readings: opaque, redone by the careful path
    full = [np.ascontiguousarray(np.broadcast_to(v, Rob.shape)) for v in (Rob, Row, Gb, Gw, X)]
    readonly = Row.copy()
    readonly.flags.writeable = False
    for method, laid_out, expanded in (
        (inv.black_white, (np.asfortranarray(Rob), readonly, Gb, Gw, X), full),
        (inv.two_constant, (np.asfortranarray(Row), Rob, Gb, X), [full[1], full[0], full[2], full[4]]),
        (inv.curtis, (Rob.T.copy().T, readonly, X), [full[0], full[1], full[4]]),
    ):
        got, want = method(*laid_out), method(*expanded)
        assert np.count_nonzero(want.flags) > 100  # the careful path had work in several blocks
        by_row = [method(*(v[row] for v in expanded)) for row in range(rows)]
        for name in ("K", "S", "ks_ratio", "flags"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=f"{method.__name__} {name}")
            alone = np.stack([getattr(r, name) for r in by_row])
            np.testing.assert_array_equal(getattr(got, name), alone, err_msg=f"{method.__name__} {name} by row")


def test_no_warning_whatever_the_inputs_shapes():
    """Scalars, one-element arrays and broadcast backings raise no warning of any kind (numpy's FutureWarning on the
    writeable flag of broadcast views among them)."""
    calls = (
        lambda: inv.black_white(np.array([0.1]), np.array([0.5]), 0.04, 0.85, 0.03),
        lambda: inv.black_white(0.1, 0.5, np.array([0.04]), 0.85, np.array([[0.03]])),
        lambda: inv.two_constant(0.5, 0.3, 0.04, 0.03),
        lambda: inv.two_constant(np.full((2, 3), 0.5), 0.3, np.array([0.04, 0.05, 0.06]), np.ones((2, 1))),
        lambda: inv.curtis(np.full((3, 4), 0.1), 0.5, np.ones((3, 1))),
    )
    for call in calls:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            _assert_sane(call(), np.shape(call().K))


def test_the_loops_compile_where_no_cache_can_be_written():
    """A read-only install with a read-only home has nowhere to keep numba's compiled loops: they are compiled in the
    process instead of failing. A function with no source file has no cache location either."""
    import numba

    from kmpipe.physics.inversion_kernels import _compiled

    namespace: dict = {}
    exec(compile("def twice(x):\n    return 2.0 * x\n", "<no file>", "exec"), namespace)
    with pytest.raises(RuntimeError, match="cannot cache"):
        numba.njit(numba.float64(numba.float64), cache=True)(namespace["twice"])
    assert _compiled(numba.float64(numba.float64))(namespace["twice"])(3.0) == 6.0
