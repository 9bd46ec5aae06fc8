"""Numerical extremes (issue 12): the inversions and the forward model over all of their input range.

Every input in [0, 1]^4 (readings and backings) with a thickness > 0, including exact 0 and 1, subnormals,
equal backings and readings below the black backing, must give finite, non-negative K, S and K/S, with no
numpy RuntimeWarning; readings that no film can give must be flagged; readings simulated from a real film
(50-digit forward model in ``mp_reference``, rounded to float64) must come back unflagged and equal to the
exact 50-digit inversion of the very float64 readings, within a tolerance set by that inversion's own
condition number. The forward model must stay in [0, 1] (also for R_g = 1) without warnings for K, S, X
anywhere in [0, 1e308]. Nothing is compared with a number the code produced.
"""

from __future__ import annotations

import warnings

import mp_reference as ref
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from kmpipe.physics import inversion as inv
from kmpipe.physics import kubelka_munk as km
from kmpipe.physics.flags import Flag

EPS = np.finfo(np.float64).eps
ANY_FLAG = int(Flag.OPAQUE | Flag.OUT_OF_RANGE | Flag.NO_CONTRAST | Flag.AT_BOUND)
CLEAR = 0.02  # contrast above which a real film must not be flagged
REPRODUCE = 1e-9  # unflagged K, S must give back the readings to this (absolute reflectance)
#: K or S below this (but > 0) has lost digits to underflow: not checked against the readings
UNDERFLOW = 1e-290

EDGES = (0.0, 1.0, 5e-324, 1e-310, 1e-308, 2e-308, 1e-300, 1e-16, 0.5, 1.0 - 1e-16, 1.0 - EPS / 2)
unit = st.one_of(st.floats(0.0, 1.0), st.sampled_from(EDGES))
thickness = st.one_of(st.floats(1e-3, 10.0), st.sampled_from((5e-324, 1e-300, 1e-9, 1.0, 1e9, 1e300, 1.7e308)))
SETTINGS = settings(max_examples=300, deadline=None)
#: Real films are drawn and those that hide their backing (no contrast to invert) are filtered out, by design.
REAL_FILMS = settings(SETTINGS, suppress_health_check=[HealthCheck.filter_too_much])


def _no_warnings(fun, *args):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return fun(*args)


def _assert_sane(res):
    for name in ("K", "S", "ks_ratio"):
        v = np.asarray(getattr(res, name))
        assert np.all(np.isfinite(v)) and np.all(v >= 0.0), (name, v)


def _cond(fun, args, index):
    """Condition number of output ``index`` of a 50-digit inversion, or None where a nudge leaves the domain."""
    try:
        return float(ref.condition(fun, *args, index=index))
    except TypeError:  # the reference returned None (no film) for a nudged input
        return None


def _mp_feasibility(Rb, Rw, Gb, Gw):
    """+1 if some film (K, S >= 0, X > 0) gives these readings by a clear margin, -1 if clearly none does,
    0 near the boundary (where rounding of the readings decides). Exact 50-digit arithmetic."""
    Rb, Rw, Gb, Gw = (ref.m(v) for v in (Rb, Rw, Gb, Gw))
    if Gb > Gw:  # swapping the backings negates D, N_u, N_y: the same films
        Rb, Rw, Gb, Gw = Rw, Rb, Gw, Gb
    margin = ref.mpf("1e-9")
    D = 2 * (Gw * Rb - Gb * Rw)
    Nu = (1 - Rw) * (1 - Gw) * (Rb - Gb) - (1 - Rb) * (1 - Gb) * (Rw - Gw)
    Ny = (Rw + Gw) * (1 - Rb) * (1 - Gb) - (Rb + Gb) * (1 - Rw) * (1 - Gw)
    size = margin * (abs(Gw * Rb) + abs(Gb * Rw)) + ref.mpf("1e-300")  # readings are rounded floats
    if D < -size or Ny < -margin:
        return -1
    if D <= size:
        return 0
    u, y = Nu / D, Ny / D
    if u < -margin:
        return -1
    b2 = u * (u + 2)
    if y * y < b2 * (1 - margin) or y < 0:
        return -1
    return 1 if u > margin and y * y > b2 * (1 + margin) else 0


def _reproduces(res, i, X, Rg, R):
    """The 50-digit forward model of the returned K, S gives back the reading R over Rg."""
    K, S = float(np.ravel(res.K)[i]), float(np.ravel(res.S)[i])
    if 0.0 < K < UNDERFLOW or 0.0 < S < UNDERFLOW or X > 1e290:  # K, S lost digits to (or below) underflow
        return True
    return abs(float(ref.reflectance(K, S, X, Rg)) - R) <= REPRODUCE


# ---------------------------------------------------------------------------------------------
# the three readings of the issue
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("Rob", "Row", "Gb", "Gw", "X"),
    [
        (0.897, 0.0546, 0.950, 0.156, 8.1),  # gave S < 0
        (1.0, 0.0, 1.0, 0.5, 1.0),  # gave S = -1, unflagged
        (0.8, 0.0, 1e-308, 2e-308, 1.0),  # gave NaN
    ],
)
def test_issue_examples_are_finite_non_negative_and_flagged(Rob, Row, Gb, Gw, X):
    assert ref.black_white_inverse(Rob, Row, Gb, Gw, X) is None  # no film gives these readings
    assert _mp_feasibility(Rob, Row, Gb, Gw) == -1
    res = _no_warnings(inv.black_white, Rob, Row, Gb, Gw, X)
    _assert_sane(res)
    assert int(res.flags) & Flag.OUT_OF_RANGE


def test_thickness_near_zero_caps_k_and_s_and_flags():
    # a real film's readings, inverted with a thickness so small that S = S X / X exceeds the float64 range
    Rob, Row = (float(ref.reflectance(2.0, 30.0, 0.05, g)) for g in (0.03, 0.85))
    res = _no_warnings(inv.black_white, Rob, Row, 0.03, 0.85, 5e-324)
    _assert_sane(res)
    assert int(res.flags) & Flag.OUT_OF_RANGE
    tc = _no_warnings(inv.two_constant, float(ref.r_inf(2.0, 30.0)), Rob, 0.03, 5e-324)
    _assert_sane(tc)
    assert int(tc.flags) & Flag.OUT_OF_RANGE


def test_swapped_backings_give_the_same_film():
    K, S, X, G_dark, G_light = 1.5, 12.0, 0.07, 0.04, 0.88
    R_dark, R_light = (float(ref.reflectance(K, S, X, g)) for g in (G_dark, G_light))
    K_ref, S_ref = ref.black_white_inverse(R_dark, R_light, G_dark, G_light, X)
    res = _no_warnings(inv.black_white, R_light, R_dark, G_light, G_dark, X)
    assert int(res.flags) == 0
    assert float(res.K) == pytest.approx(float(K_ref), rel=1e-12)
    assert float(res.S) == pytest.approx(float(S_ref), rel=1e-12)


@pytest.mark.parametrize("tolerance", [0.0, -1e-3, 1.0, float("nan")])
def test_tolerance_outside_open_unit_interval_is_rejected(tolerance):
    with pytest.raises(ValueError, match="tolerance"):
        inv.black_white(0.2, 0.5, 0.03, 0.85, 0.1, tolerance=tolerance)
    with pytest.raises(ValueError, match="tolerance"):
        inv.two_constant(0.5, 0.3, 0.03, 0.1, tolerance=tolerance)


# ---------------------------------------------------------------------------------------------
# every input: finite, non-negative, no warnings; impossible readings flagged; unflagged ones reproduce
# ---------------------------------------------------------------------------------------------
@SETTINGS
@given(Rb=unit, Rw=unit, Gb=unit, Gw=unit, X=thickness)
def test_black_white_any_readings(Rb, Rw, Gb, Gw, X):
    res = _no_warnings(inv.black_white, Rb, Rw, Gb, Gw, X)
    _assert_sane(res)
    flags = int(res.flags)
    if _mp_feasibility(Rb, Rw, Gb, Gw) == -1:
        assert flags & ANY_FLAG, (Rb, Rw, Gb, Gw, X, res)
    if not flags & ANY_FLAG:
        assert _reproduces(res, 0, X, Gb, Rb) and _reproduces(res, 0, X, Gw, Rw), (Rb, Rw, Gb, Gw, X, res)


@SETTINGS
@given(Rb=unit, Rw=unit, X=thickness)
def test_curtis_any_readings(Rb, Rw, X):
    res = _no_warnings(inv.curtis, Rb, Rw, X)
    _assert_sane(res)
    flags = int(res.flags)
    if _mp_feasibility(Rb, Rw, 0.0, 1.0) == -1:
        assert flags & ANY_FLAG, (Rb, Rw, X, res)
    if not flags & ANY_FLAG:
        assert _reproduces(res, 0, X, 0.0, Rb) and _reproduces(res, 0, X, 1.0, Rw), (Rb, Rw, X, res)


@SETTINGS
@given(R_inf=unit, R=unit, Rg=unit, X=thickness)
def test_two_constant_any_readings(R_inf, R, Rg, X):
    res = _no_warnings(inv.two_constant, R_inf, R, Rg, X)
    _assert_sane(res)
    flags = int(res.flags)
    # a film over Rg reads between Rg and its masstone; a masstone below 1e-9 is outside what kmpipe represents
    if not min(Rg, R_inf) <= R <= max(Rg, R_inf) or R_inf < 1e-9:
        assert flags & ANY_FLAG, (R_inf, R, Rg, X, res)
    if not flags & ANY_FLAG:
        assert _reproduces(res, 0, X, Rg, R), (R_inf, R, Rg, X, res)
        assert abs(float(ref.r_inf(float(res.ks_ratio), 1.0)) - R_inf) <= REPRODUCE


def test_array_of_edge_readings_is_sane_without_warnings():
    edges = np.array(EDGES)
    Rb, Rw, Gb, Gw = (a.ravel() for a in np.meshgrid(edges, edges, edges, edges, indexing="ij"))
    for X in (5e-324, 1.0, 1.7e308):
        _assert_sane(_no_warnings(inv.black_white, Rb, Rw, Gb, Gw, X))
        _assert_sane(_no_warnings(inv.two_constant, Rb, Rw, Gb, X))
        _assert_sane(_no_warnings(inv.curtis, Rb, Rw, X))


# ---------------------------------------------------------------------------------------------
# readings of real films: recovered to the conditioning of the data, unflagged
# ---------------------------------------------------------------------------------------------
optical = st.one_of(st.floats(1e-3, 3.0), st.sampled_from((1e-3, 1.0, 3.0)))  # S X
ks_ratio = st.one_of(st.just(0.0), st.floats(1e-6, 100.0), st.sampled_from((1e-6, 1.0, 100.0)))  # K / S
film_thickness = st.floats(1e-3, 10.0)
dark = st.one_of(st.floats(0.0, 0.5), st.sampled_from((0.0, 5e-324, 1e-308)))
light = st.one_of(st.floats(0.8, 1.0), st.sampled_from((1.0, 1.0 - 1e-16)))


def _assert_recovers(got, exact, cond, w):
    """Within the data's condition number, plus what artanh(w) of a rounded w loses as w = b / y -> 1."""
    tol = 1e-12 + 64 * EPS * (cond + 1.0 / (1.0 - w))
    assert abs(got - float(exact)) <= tol * abs(float(exact)), (got, float(exact), cond, w)


def _w(KX, SX):
    """w = b / y = tanh(b S X) of the exact solution, from K X and S X."""
    return float(ref._ctx.tanh(ref._ctx.sqrt(KX * (KX + 2 * SX))))


def _check_black_white(SX, q, X, Gb, Gw, fun, *args):
    K, S = q * SX / X, SX / X
    Rb, Rw = (float(ref.reflectance(K, S, X, g)) for g in (Gb, Gw))
    assume(abs(Rw - Rb) > CLEAR * max(Rb, Rw))  # the film does not hide its backing
    exact = ref.black_white_inverse(Rb, Rw, Gb, Gw, X)  # of the float64 readings, at 50 digits
    assume(exact is not None)
    conds = [_cond(ref.black_white_inverse, (Rb, Rw, Gb, Gw, X), i) for i in (0, 1)]
    assume(None not in conds)
    res = _no_warnings(fun, Rb, Rw, *args)
    assert int(res.flags) == 0, (K, S, X, Gb, Gw, res)
    w = _w(exact[0] * ref.m(X), exact[1] * ref.m(X))
    _assert_recovers(float(res.K), exact[0], conds[0], w)
    _assert_recovers(float(res.S), exact[1], conds[1], w)


@REAL_FILMS
@given(SX=optical, q=ks_ratio, X=film_thickness, Gd=dark, Gl=light, swap=st.booleans())
def test_black_white_recovers_real_films(SX, q, X, Gd, Gl, swap):
    Gb, Gw = (Gl, Gd) if swap else (Gd, Gl)
    _check_black_white(SX, q, X, Gb, Gw, inv.black_white, Gb, Gw, X)


@REAL_FILMS
@given(SX=optical, q=ks_ratio, X=film_thickness)
def test_curtis_recovers_real_films(SX, q, X):
    _check_black_white(SX, q, X, 0.0, 1.0, inv.curtis, X)


@REAL_FILMS
@given(SX=optical, q=ks_ratio, X=film_thickness, Rg=st.one_of(dark, light))
def test_two_constant_recovers_real_films(SX, q, X, Rg):
    K, S = q * SX / X, SX / X
    R_inf, R = float(ref.r_inf(K, S)), float(ref.reflectance(K, S, X, Rg))
    assume(1e-9 <= R_inf < 1.0)  # (the 50-digit ln form is 0/0 at R_inf = 1)
    assume(abs(R - R_inf) > CLEAR * R_inf and abs(Rg - R_inf) > CLEAR * R_inf)
    exact = ref.two_constant_inverse(R_inf, R, Rg, X)
    assume(exact is not None)
    conds = [_cond(ref.two_constant_inverse, (R_inf, R, Rg, X), i) for i in (0, 1)]
    assume(None not in conds)
    res = _no_warnings(inv.two_constant, R_inf, R, Rg, X)
    assert int(res.flags) == 0, (K, S, X, Rg, res)
    _assert_recovers(float(res.K), exact[0], conds[0], 0.0)
    _assert_recovers(float(res.S), exact[1], conds[1], 0.0)


# ---------------------------------------------------------------------------------------------
# forward model: in [0, 1], no warnings, anywhere in [0, 1e308]
# ---------------------------------------------------------------------------------------------
extreme = st.one_of(
    st.floats(0.0, 1e308),
    st.floats(0.0, 1e-300, allow_subnormal=True),
    st.floats(0.0, 1e4),
    st.sampled_from((0.0, 5e-324, 1e-308, 1e150, 1e154, 1e200, 1e300, 1e308, 1.7976931348623157e308)),
)
background = st.one_of(st.floats(0.0, 1.0), st.sampled_from((0.0, 1.0, 1.0 - 1e-16)))


@settings(max_examples=400, deadline=None)
@given(K=extreme, S=extreme, X=extreme, Rg=background)
@example(K=7.546498765922194e307, S=9.999999999999998e307, X=2.2250738585e-313, Rg=0.0)  # (a draw: subnormal X)
def test_forward_model_stays_in_unit_interval_without_warnings(K, S, X, Rg):
    R0, T = _no_warnings(km.film_reflectance_transmittance, K, S, X)
    R = _no_warnings(km.reflectance_over_background, K, S, X, Rg)
    two = _no_warnings(km.stack_over_substrate, np.array([R0, R0]), np.array([T, T]), Rg)
    R_top, T_total, R_bottom = _no_warnings(km.stack_films, np.array([R0, R0]), np.array([T, T]))
    R_inf = _no_warnings(km.reflectance_infinite, K, S)
    for v in (R0, T, R, two, R_top, T_total, R_bottom, R_inf):
        assert np.isfinite(v) and 0.0 <= v <= 1.0, (K, S, X, Rg, v)
    assert R0 + T <= 1.0 + 4 * EPS
    # against 50 digits, relative to the value's condition; a subnormal thickness (below 2.2e-308) leaves
    # intermediates with fewer significant bits, so there the floor is 1e-11 instead of 1e-13
    R0_ref, T_ref = ref.film(K, S, X)
    floor = 1e-11 if 0.0 < X < np.finfo(float).tiny else 1e-13
    for got, exp, index in ((R0, R0_ref, 0), (T, T_ref, 1)):
        rel = min(max(floor, 4 * EPS * float(ref.condition(ref.film, K, S, X, index=index))), 1.0)
        assert abs(float(got) - float(exp)) <= rel * float(exp) + 1e-300, (K, S, X, got)


@pytest.mark.parametrize(
    ("S", "X"), [(0.0012565096061564738, 1.7334328290212393), (407.78809493343704, 0.6950259775199462)]
)
def test_lossless_film_over_white_is_exactly_one(S, X):
    # K = 0 over R_g = 1: nothing is absorbed, so R = 1 exactly (these inputs once gave 1 + 2.2e-16)
    assert ref.reflectance(0.0, S, X, 1.0) == 1
    assert float(km.reflectance_over_background(0.0, S, X, 1.0)) <= 1.0
    R0, T = km.film_reflectance_transmittance(0.0, S, X)
    assert float(km.stack_over_substrate(np.array([R0, R0]), np.array([T, T]), 1.0)) <= 1.0
    assert float(ref.stack_bottom_up([R0, R0], [T, T], 1.0)) == pytest.approx(1.0, abs=4 * EPS)


def test_forward_model_at_float_extremes_matches_mp():
    values = (0.0, 5e-324, 1e-300, 1.0, 1e150, 1e200, 1e308)
    K, S, X = (np.array(v) for v in zip(*[(k, s, x) for k in values for s in values for x in values], strict=True))
    R0, T = _no_warnings(km.film_reflectance_transmittance, K, S, X)
    R0_ref, T_ref = ref.vec(ref.film, K, S, X, nout=2)
    for got, exp, index in ((R0, R0_ref, 0), (T, T_ref, 1)):
        for i in range(K.size):
            rel = min(max(1e-13, 4 * EPS * float(ref.condition(ref.film, K[i], S[i], X[i], index=index))), 1.0)
            tol = rel * exp[i] + 1e-300
            assert abs(got[i] - exp[i]) <= tol, (K[i], S[i], X[i], got[i], exp[i])
