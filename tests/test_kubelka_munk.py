"""Reference tests for the Kubelka-Munk forward model (kmpipe.physics.kubelka_munk, kmpipe.physics.saunderson).

Every expected value comes from ``mp_reference`` (textbook formulas at 50 digits on the exact float
inputs), from a conservation law, or from a round trip; none is a number the code produced.

Tolerances: 1e-13 relative, widened by 4 eps times the problem's own condition number (computed at 50
digits) where that is larger. The widening matters only for very thick films: T ~ exp(-x) with
x = b S X, so one rounding of x alone moves T by x * eps (x = 709 -> 1.6e-13), which no float64
evaluation can avoid.
"""

from __future__ import annotations

import itertools

import mp_reference as ref
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kmpipe.physics import kubelka_munk as km
from kmpipe.physics import saunderson as sd

EPS = np.finfo(np.float64).eps
RTOL = 1e-13
#: values below this are compared absolutely (they lie at or below the float64 underflow range)
TINY = 1e-300

GRID_KS = (0.0, 1e-12, 1e-6, 1.0, 1e3, 1e4)
GRID_X = (0.0, 1e-9, 1e-3, 1.0, 1e3)


def _grid(*axes):
    """Every combination of the axes, as one flat float64 array per axis."""
    return tuple(np.array(v, dtype=np.float64) for v in zip(*itertools.product(*axes), strict=True))


def _assert_film_matches_mp(K, S, X):
    """Compare R0 and T with the 50-digit textbook values at every element."""
    K, S, X = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (K, S, X)))
    R0, T = km.film_reflectance_transmittance(K, S, X)
    assert R0.shape == K.shape and T.shape == K.shape
    assert R0.dtype == np.float64 and T.dtype == np.float64
    R0_ref, T_ref = ref.vec(ref.film, K, S, X, nout=2, as_float=False)
    problems = []
    for idx in np.ndindex(K.shape):
        for name, got, exp, out in (("R0", R0, R0_ref, 0), ("T", T, T_ref, 1)):
            e = exp[idx]
            cond = ref.condition(ref.film, K[idx], S[idx], X[idx], index=out)
            tol = max(RTOL, 4 * EPS * float(cond)) * float(abs(e)) + TINY
            err = float(abs(ref.m(got[idx]) - e))
            if not err <= tol:
                problems.append(
                    f"{name}(K={K[idx]!r}, S={S[idx]!r}, X={X[idx]!r}) = {got[idx]!r}, "
                    f"expected {float(e)!r} (rel err {err / max(float(abs(e)), TINY):.3g}, "
                    f"cond {float(cond):.3g})"
                )
    assert not problems, "\n".join(problems)


# ---------------------------------------------------------------------------------------------
# forward model against 50-digit arithmetic
# ---------------------------------------------------------------------------------------------
def test_film_matches_mp_on_extreme_grid():
    K, S, X = _grid(GRID_KS, GRID_KS, GRID_X)
    _assert_film_matches_mp(K, S, X)


@pytest.mark.parametrize("ks_ratio", [1e-6, 1.0, 1e3])
def test_film_matches_mp_where_sinh_overflows(ks_ratio):
    # x = b S X = sqrt(K (K + 2 S)) X placed around 355 (sinh*cosh overflow) and 710 (sinh overflow)
    S = 2.0
    K = ks_ratio * S
    beta = np.sqrt(K * (K + 2 * S))
    x = np.array([1.0, 30.0, 354.0, 356.0, 700.0, 709.0, 709.8, 710.0, 711.0, 745.0, 746.0, 800.0, 1e4, 1e6])
    _assert_film_matches_mp(K, S, x / beta)


def test_film_closed_limits():
    SX = np.array([0.0, 1e-9, 0.5, 1.0, 7.0, 1e6])
    # K = 0: conservative scatterer
    R0, T = km.film_reflectance_transmittance(0.0, SX, 1.0)
    np.testing.assert_allclose(R0, ref.vec(lambda s: s / (1 + s), SX), rtol=1e-15, atol=0)
    np.testing.assert_allclose(T, ref.vec(lambda s: 1 / (1 + s), SX), rtol=1e-15, atol=0)
    # S = 0: clear absorber
    KX = np.array([0.0, 1e-9, 0.5, 3.0, 40.0, 700.0])
    R0, T = km.film_reflectance_transmittance(KX, 0.0, 1.0)
    assert np.all(R0 == 0.0)
    np.testing.assert_allclose(T, ref.vec(lambda k: ref._ctx.exp(-k), KX), rtol=1e-15, atol=0)
    # X = 0: nothing there
    R0, T = km.film_reflectance_transmittance(np.array(GRID_KS), np.array(GRID_KS)[::-1], 0.0)
    assert np.all(R0 == 0.0) and np.all(T == 1.0)


def test_reflectance_over_background_matches_mp():
    K, S, X, Rg = _grid(
        (0.0, 1e-6, 0.3, 5.0, 1e3), (0.0, 1e-6, 0.7, 20.0, 1e4), (0.01, 1.0, 50.0), (0, 0.03, 0.5, 0.85, 1)
    )
    R = km.reflectance_over_background(K, S, X, Rg)
    R_ref = ref.vec(ref.reflectance, K, S, X, Rg, as_float=False)
    errs = ref.mp_rel_err(R, R_ref)
    bad = np.flatnonzero(~(errs <= RTOL) & (R_ref.astype(float) > TINY))
    assert bad.size == 0, [(K[i], S[i], X[i], Rg[i], R[i], float(R_ref[i])) for i in bad[:5]]


def test_reflectance_over_background_is_the_printed_eq_3_5():
    """Thesis eq. 3.5 as printed, R = (1 - Rg (a - b coth(bSX))) / (a - Rg + b coth(bSX)) at 50 digits, wherever it
    is defined (K, S, X > 0): an independent check of the R0, T route kmpipe takes."""
    K, S, X, Rg = _grid((1e-6, 0.3, 5.0, 1e3), (1e-6, 0.7, 20.0, 1e4), (0.001, 0.01, 1.0, 50.0), (0, 0.035, 0.86, 1))
    R = km.reflectance_over_background(K, S, X, Rg)
    R_ref = ref.vec(ref.reflectance_coth, K, S, X, Rg, as_float=False)
    errs = ref.mp_rel_err(R, R_ref)
    bad = np.flatnonzero(~(errs <= RTOL) & (R_ref.astype(float) > TINY))
    assert bad.size == 0, [(K[i], S[i], X[i], Rg[i], R[i], float(R_ref[i])) for i in bad[:5]]


def test_film_over_background_matches_mp():
    R0, T, Rg = _grid((0.0, 1e-9, 0.2, 0.6, 0.999), (0.0, 1e-9, 0.1, 0.39, 0.999), (0.0, 0.04, 0.5, 0.9, 1.0))
    keep = R0 + T <= 1.0
    R0, T, Rg = R0[keep], T[keep], Rg[keep]
    R = km.film_over_background(R0, T, Rg)
    R_ref = ref.vec(ref.over_background, R0, T, Rg)
    np.testing.assert_allclose(R, R_ref, rtol=1e-14, atol=1e-300)


# ---------------------------------------------------------------------------------------------
# conservation and monotonicity
# ---------------------------------------------------------------------------------------------
def test_energy_conservation_on_grid():
    K, S, X = _grid(GRID_KS, GRID_KS, (*GRID_X, 0.37, 12.0))
    R0, T = km.film_reflectance_transmittance(K, S, X)
    assert np.all(np.isfinite(R0)) and np.all(np.isfinite(T))
    assert np.all(R0 >= 0) and np.all(T >= 0) and np.all(R0 <= 1) and np.all(T <= 1)
    assert np.all(R0 + T <= 1 + 1e-15)
    lossless = K == 0
    np.testing.assert_allclose((R0 + T)[lossless], 1.0, rtol=0, atol=1e-15)
    absorbing = (K > 0) & (X > 0) & (K * X > 1e-12)
    assert np.all((R0 + T)[absorbing] < 1.0)


@pytest.mark.parametrize(("K", "S"), [(0.0, 3.0), (0.2, 3.0), (5.0, 0.1), (4.0, 0.0), (1e-9, 1e3), (1e3, 1e-3)])
def test_r0_rises_and_t_falls_with_thickness(K, S):
    X = np.concatenate([[0.0], np.geomspace(1e-9, 1e4, 400)])
    R0, T = km.film_reflectance_transmittance(K, S, X)
    assert np.all(np.diff(R0) >= -4 * EPS * R0[1:])
    assert np.all(np.diff(T) <= 4 * EPS * T[:-1])
    # and the reflectance over any background moves monotonically from R_g to R_inf
    R_inf = ref.vec(ref.r_inf, K, S)
    for Rg in (0.0, 0.03, 0.85, 1.0):
        R = km.reflectance_over_background(K, S, X, Rg)
        assert R[0] == pytest.approx(Rg, abs=1e-15)
        step = np.diff(R) * np.sign(R_inf - Rg)
        assert np.all(step >= -4 * EPS)


# ---------------------------------------------------------------------------------------------
# R_inf and K/S
# ---------------------------------------------------------------------------------------------
def test_reflectance_infinite_matches_mp():
    K, S = _grid((*GRID_KS, 5e-324, 0.37), (*GRID_KS, 5e-324, 2.9))
    K, S = K[(K > 0) | (S > 0)], S[(K > 0) | (S > 0)]  # K = S = 0: see the next test
    R = km.reflectance_infinite(K, S)
    assert np.all(np.isfinite(R))
    R_ref = ref.vec(ref.r_inf, K, S, as_float=False)
    errs = ref.mp_rel_err(R, R_ref)
    zero = R_ref.astype(float) == 0
    assert np.all(R[zero] == 0.0), list(zip(K[zero], S[zero], R[zero], strict=True))
    ok = zero | (R_ref.astype(float) < TINY) | (errs <= 1e-14)
    assert ok.all(), [(K[i], S[i], R[i], float(R_ref[i])) for i in np.flatnonzero(~ok)[:8]]


@pytest.mark.parametrize("ks", [1e-6, 0.5, 1.0, 30.0])
def test_reflectance_infinite_depends_on_k_over_s_only(ks):
    # R_inf is a function of K/S: scaling K and S together (down to tiny, allowed inputs) changes nothing
    scale = np.array([1.0, 1e-100, 1e-160, 1e-200, 1e-300])
    R = km.reflectance_infinite(ks * scale, scale)
    np.testing.assert_allclose(R, float(ref.r_inf(ks, 1.0)), rtol=1e-14, atol=0)


def test_reflectance_infinite_without_scattering_is_zero():
    # S = 0 -> R_inf = 0, K = 0 included: R0 = 0 at every thickness when nothing scatters, so the
    # reflectance over black of an ever thicker film (the definition of R_inf) stays 0.
    K = np.array([0.0, 5e-324, 1e-12, 1.0, 1e4])
    assert np.all(km.reflectance_infinite(K, 0.0) == 0.0)
    assert np.all(km.reflectance_over_background(K, 0.0, 1e6, 0.0) == 0.0)


def test_ks_from_reflectance_infinite_matches_mp():
    R = np.array([1e-12, 1e-6, 0.01, 0.046, 0.3, 0.5, 0.9, 0.9974, 1 - 1e-6, 1.0])
    ks = km.ks_from_reflectance_infinite(R)
    np.testing.assert_allclose(ks, ref.vec(ref.ks_from_r, R), rtol=1e-14, atol=0)
    assert ks[-1] == 0.0


def test_ks_reflectance_round_trips():
    ks = np.array([0.0, 1e-14, 1e-10, 1e-6, 3.4e-6, 0.01, 1.0, 10.0, 700.0, 1e6, 1e12])
    R = km.reflectance_infinite_from_ks(ks)
    np.testing.assert_allclose(R, ref.vec(lambda q: ref.r_inf(q, 1), ks), rtol=1e-14, atol=0)
    # K/S -> R_inf -> K/S: 1 - R carries the information, so the round trip is as good as 1 - R is;
    # a relative error of eps in R_inf is (2 R / (1 - R) + 1) eps in K/S
    back = km.ks_from_reflectance_infinite(R)
    cond = 2 * R / np.maximum(1 - R, 1e-300) + 1
    assert np.all(np.abs(back - ks) <= 8 * EPS * cond * ks + 1e-300)
    R2 = np.array([1e-9, 0.02, 0.5, 0.97])
    ks2 = km.ks_from_reflectance_infinite(R2)
    np.testing.assert_allclose(km.reflectance_infinite(ks2, 1.0), R2, rtol=1e-14)
    np.testing.assert_allclose(km.reflectance_infinite_from_ks(ks2), R2, rtol=1e-14)


@pytest.mark.parametrize(("K", "S"), [(0.5, 2.0), (3.0, 0.3), (1e-4, 5.0), (0.0, 2.0), (30.0, 30.0)])
def test_thick_film_reaches_r_inf(K, S):
    X = np.array([1e3, 1e6, 1e12])
    R_inf = float(ref.r_inf(K, S))
    for Rg in (0.0, 0.03, 0.5, 0.85, 1.0):
        R = km.reflectance_over_background(K, S, X, Rg)
        np.testing.assert_allclose(R, ref.vec(ref.reflectance, K, S, X, Rg), rtol=RTOL, atol=0)
        if K > 0:  # T ~ exp(-b S X) is far below eps here: R is R_inf to the last digit
            np.testing.assert_allclose(R, R_inf, rtol=1e-14, atol=0)
        else:  # a lossless film approaches R_inf = 1 only as 1 / (S X)
            assert np.all(np.abs(1 - R) <= 1 / (S * X) + 4 * EPS)


# ---------------------------------------------------------------------------------------------
# layers
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("K", "S"), [(0.4, 2.5), (0.0, 3.0), (6.0, 0.05), (3.0, 0.0), (1e-8, 1e2), (200.0, 300.0)])
def test_same_material_split_equals_one_film(K, S):
    # X1 + X2 exact in binary, so both sides describe exactly the same film
    X1 = np.array([0.25, 0.5, 0.125, 3.0, 1e-3])
    X2 = np.array([0.75, 0.25, 2.0, 5.0, 2.0**-20])
    assert np.all((X1 + X2) - X1 == X2)
    R1, T1 = km.film_reflectance_transmittance(K, S, X1)
    R2, T2 = km.film_reflectance_transmittance(K, S, X2)
    R_top, T_tot, R_bot = km.stack_films(np.stack([R1, R2]), np.stack([T1, T2]))
    R_one, T_one = ref.vec(ref.film, K, S, X1 + X2, nout=2)
    np.testing.assert_allclose(R_top, R_one, rtol=1e-13, atol=1e-300)
    np.testing.assert_allclose(R_bot, R_one, rtol=1e-13, atol=1e-300)
    np.testing.assert_allclose(T_tot, T_one, rtol=1e-13, atol=1e-300)


def _three_layers():
    """R0, T of three different films (index 0 = top) over 5 'wavelengths', from the mp reference."""
    K = np.array([[0.2, 1.0, 5.0, 0.0, 40.0], [3.0, 0.1, 0.0, 2.0, 0.5], [0.05, 8.0, 1.0, 0.3, 0.0]])
    S = np.array([[4.0, 0.5, 2.0, 6.0, 1.0], [0.0, 7.0, 3.0, 1.0, 90.0], [1.5, 2.0, 0.02, 0.0, 5.0]])
    X = np.array([[0.3], [0.1], [0.7]])
    return ref.vec(ref.film, K, S, X, nout=2)


def test_stack_over_substrate_matches_bottom_up_mp():
    R0, T = _three_layers()
    for Rg in (0.0, 0.04, np.linspace(0.1, 0.9, 5), 1.0):
        got = km.stack_over_substrate(R0, T, Rg)
        Rg_arr = np.broadcast_to(np.asarray(Rg, dtype=float), (5,))
        exp = np.array([float(ref.stack_bottom_up(R0[:, j], T[:, j], Rg_arr[j])) for j in range(5)])
        assert got.shape == (5,)
        np.testing.assert_allclose(got, exp, rtol=1e-13, atol=0)


def test_stack_films_matches_two_sided_mp():
    R0, T = _three_layers()
    R_top, T_tot, R_bot = km.stack_films(R0, T)
    assert R_top.shape == T_tot.shape == R_bot.shape == (5,)
    for j in range(5):
        exp = ref.stack_two_sided(R0[:, j], T[:, j])
        got = [R_top[j], T_tot[j], R_bot[j]]
        np.testing.assert_allclose(got, [float(v) for v in exp], rtol=1e-13, atol=0)
    # the composite layer over a substrate is the stack over that substrate
    for Rg in (0.03, 0.85):
        np.testing.assert_allclose(
            R_top + T_tot**2 * Rg / (1 - R_bot * Rg), km.stack_over_substrate(R0, T, Rg), rtol=1e-13
        )


def test_stack_order_matters_and_transmittance_is_reciprocal():
    R0, T = _three_layers()
    R_top, T_tot, R_bot = km.stack_films(R0, T)
    R_top_r, T_tot_r, R_bot_r = km.stack_films(R0[::-1], T[::-1])
    np.testing.assert_allclose(T_tot_r, T_tot, rtol=1e-13, atol=0)
    np.testing.assert_allclose(R_top_r, R_bot, rtol=1e-13, atol=0)
    np.testing.assert_allclose(R_bot_r, R_top, rtol=1e-13, atol=0)
    assert np.all(np.abs(R_top - R_top_r) > 1e-3)  # these layers differ: the order shows
    over = km.stack_over_substrate(R0, T, 0.5)
    over_r = km.stack_over_substrate(R0[::-1], T[::-1], 0.5)
    assert np.all(np.abs(over - over_r) > 1e-3)


def test_stack_of_one_layer_is_the_layer_and_empty_substrate_terms():
    R0, T = _three_layers()
    R_top, T_tot, R_bot = km.stack_films(R0[:1], T[:1])
    np.testing.assert_array_equal(R_top, R0[0])
    np.testing.assert_array_equal(R_bot, R0[0])
    np.testing.assert_array_equal(T_tot, T[0])
    np.testing.assert_allclose(km.stack_over_substrate(R0[:1], T[:1], 0.0), R0[0], rtol=1e-15)


def test_stack_conserves_energy_for_lossless_layers():
    S = np.array([[1.0, 5.0], [0.2, 30.0], [3.0, 0.01]])
    R0, T = ref.vec(ref.film, 0.0, S, np.array([[0.5], [2.0], [0.1]]), nout=2)
    R_top, T_tot, R_bot = km.stack_films(R0, T)
    np.testing.assert_allclose(R_top + T_tot, 1.0, rtol=0, atol=1e-14)
    np.testing.assert_allclose(R_bot + T_tot, 1.0, rtol=0, atol=1e-14)


# ---------------------------------------------------------------------------------------------
# hiding thickness
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("target", [0.98, 0.95, 0.999])
def test_hiding_thickness_meets_contrast_ratio(target):
    K = np.array([0.0, 0.0, 0.1, 1.0, 5.0, 50.0, 1e3, 1e-6, 0.3])
    S = np.array([1.0, 1e3, 2.0, 1.0, 0.5, 3.0, 1e4, 1e-2, 1e-3])
    Rb = np.array([0.03, 0.0, 0.03, 0.05, 0.02, 0.03, 0.04, 0.03, 0.03])
    Rw = np.array([0.85, 1.0, 0.85, 0.8, 0.9, 0.85, 0.88, 0.85, 0.85])
    X = km.hiding_thickness(K, S, Rb, Rw, contrast_ratio=target)
    assert X.shape == K.shape
    assert np.all(np.isfinite(X)) and np.all(X > 0)
    ratio = ref.vec(ref.contrast_ratio, K, S, X, Rb, Rw)
    bad = np.flatnonzero(~(np.abs(ratio - target) <= 1e-9))
    assert bad.size == 0, [(K[i], S[i], Rb[i], Rw[i], X[i], ratio[i]) for i in bad]


def test_hiding_thickness_default_is_098_and_broadcasts():
    K = np.array([[0.5], [2.0]])
    S = np.array([1.0, 4.0, 9.0])
    X = km.hiding_thickness(K, S, 0.03, 0.85)
    assert X.shape == (2, 3)
    ratio = ref.vec(ref.contrast_ratio, K, S, X, 0.03, 0.85)
    np.testing.assert_allclose(ratio, 0.98, rtol=0, atol=1e-9)


def test_hiding_thickness_is_infinite_without_scattering():
    X = km.hiding_thickness(np.array([0.0, 1.0, 30.0]), 0.0, 0.03, 0.85)
    assert np.all(np.isposinf(X))


# ---------------------------------------------------------------------------------------------
# Saunderson
# ---------------------------------------------------------------------------------------------
SAUNDERSON = [(0.0, 0.0), (0.03, 0.65), (0.04, 0.4), (0.0, 0.6), (0.05, 0.0)]


@pytest.mark.parametrize(("k1", "k2"), SAUNDERSON)
def test_saunderson_matches_mp_and_round_trips(k1, k2):
    R = np.array([0.0, 1e-9, 0.01, 0.2, 0.5, 0.85, 0.99, 1.0])
    Rm = sd.saunderson_forward(R, k1, k2)
    Rm_ref = ref.vec(lambda r: ref.saunderson_forward(r, k1, k2), R)
    np.testing.assert_allclose(Rm, Rm_ref, rtol=1e-15, atol=1e-17)
    back = sd.saunderson_inverse(Rm, k1, k2)
    np.testing.assert_allclose(back, R, rtol=1e-13, atol=4 * EPS)
    Rm2 = np.array([k1, 0.04, 0.3, 0.7, 0.95])
    np.testing.assert_allclose(
        sd.saunderson_inverse(Rm2, k1, k2),
        ref.vec(lambda r: ref.saunderson_inverse(r, k1, k2), Rm2),
        rtol=1e-14,
        atol=1e-17,
    )
    back2 = sd.saunderson_forward(sd.saunderson_inverse(Rm2, k1, k2), k1, k2)
    np.testing.assert_allclose(back2, Rm2, rtol=1e-14)
    assert sd.saunderson_forward(1.0, k1, k2) == pytest.approx(1.0, abs=1e-15)  # a perfect white stays white
    assert sd.saunderson_forward(0.0, k1, k2) == pytest.approx(k1, abs=1e-17)  # a perfect black shows only k1


def test_saunderson_without_surface_is_identity():
    R = np.linspace(0.0, 1.0, 11).reshape(11, 1) * np.ones(3)
    np.testing.assert_array_equal(sd.saunderson_forward(R, 0.0, 0.0), R)
    np.testing.assert_array_equal(sd.saunderson_inverse(R, 0.0, 0.0), R)


# ---------------------------------------------------------------------------------------------
# broadcasting and properties
# ---------------------------------------------------------------------------------------------
def test_forward_broadcasts_with_wavelength_last():
    K = np.array([[0.1, 0.2, 0.3, 0.4]])  # (1, 4)
    S = np.array([[1.0], [2.0], [3.0]])  # (3, 1)
    R0, T = km.film_reflectance_transmittance(K, S, 0.5)
    assert R0.shape == T.shape == (3, 4)
    R = km.reflectance_over_background(K, S, np.array([0.1, 0.2, 0.3])[:, None, None], np.linspace(0, 1, 4))
    assert R.shape == (3, 3, 4)
    np.testing.assert_allclose(R[1], ref.vec(ref.reflectance, K, S, 0.2, np.linspace(0, 1, 4)), rtol=1e-13)
    assert km.reflectance_infinite(K, S).shape == (3, 4)


tiny_or_regular = st.one_of(
    st.just(0.0),
    st.floats(min_value=5e-324, max_value=1e-300),
    st.floats(min_value=1e-300, max_value=1e-6),
    st.floats(min_value=0.0, max_value=1e4, allow_subnormal=True),
)


@settings(max_examples=60, deadline=None)
@given(
    K=tiny_or_regular,
    S=tiny_or_regular,
    X=st.one_of(st.just(0.0), st.floats(min_value=0.0, max_value=1e3)),
    Rg=st.floats(min_value=0.0, max_value=1.0),
)
def test_forward_properties(K, S, X, Rg):
    R0, T = km.film_reflectance_transmittance(K, S, X)
    R = km.reflectance_over_background(K, S, X, Rg)
    for v in (R0, T, R):
        assert np.isfinite(v) and 0.0 <= v <= 1.0
    assert R0 + T <= 1.0 + 1e-12
    R_inf = km.reflectance_infinite(K, S)
    assert np.isfinite(R_inf) and 0.0 <= R_inf <= 1.0
    # and the values themselves, against 50 digits (R is absolute: it is at most 1)
    _assert_film_matches_mp(K, S, X)
    tol = max(RTOL, 4 * EPS * float(ref.condition(ref.film, K, S, X, index=1)))
    assert abs(float(R) - float(ref.reflectance(K, S, X, Rg))) <= tol
