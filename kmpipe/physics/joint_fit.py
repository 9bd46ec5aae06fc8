"""Joint weighted least-squares fit of K and S over all measurements of one sample (nlopt).

Model: measurement i at wavelength j reads

    R_m,ij = F(R_ij),   R_ij = R_KM(K_j, S_j, X_i, G_ij)     (film of thickness X_i over background G_ij)
                        R_ij = R_inf(K_j, S_j)                (masstone: X_i = inf)

with F the Saunderson correction (identity when off), R_KM the film-over-background reflectance of
:mod:`kmpipe.physics.kubelka_munk` (thesis eq. 3.5, evaluated as thesis eq. 3.14 with R0 and T of thesis eq. 3.8
and thesis eq. 3.9) and R_inf that of thesis eq. 3.6. The fit minimizes

    (1 / m n) sum_ij (R_m,ij - y_ij)^2 + (lambda / n) sum_j [(d2 K_j / K_bar)^2 + (d2 S_j / S_bar)^2]

(m measurements, n wavelengths, d2 the second difference across wavelength, K_bar and S_bar the mean
start values) over K, S >= 0. All readings share one noise level, so the weights are uniform and only
set the standard errors; normalizing by m n keeps the objective near the residual variance, which is
what nlopt's L-BFGS line search handles well (with 1/sigma^2 weights it fails on clean data).
The bounds are built in: K = K_0 p^2, S = S_0 r^2 with p, r free, so nlopt's L-BFGS works unconstrained
and the masstone's infinite slope dR_inf/dK at K = 0 becomes a finite dR_inf/dp. The gradient is
analytic. Standard errors come from the Gauss-Newton covariance sigma^2 (J^T W J)^-1 per wavelength.
"""

from __future__ import annotations

from dataclasses import dataclass

import nlopt
import numpy as np

from kmpipe.physics.flags import Flag
from kmpipe.physics.kubelka_munk import _sech, _tanhc
from kmpipe.physics.saunderson import saunderson_forward, saunderson_slope

ALGORITHM = "LD_LBFGS"


@dataclass(frozen=True)
class JointFit:
    """Result of :func:`fit_joint`: arrays of shape (n,) per wavelength unless noted."""

    K: np.ndarray
    S: np.ndarray
    K_stderr: np.ndarray
    S_stderr: np.ndarray
    flags: np.ndarray
    predicted: np.ndarray  # (m, n): modelled readings (with Saunderson when on)
    residuals: np.ndarray  # (m, n): predicted - measured
    sigma: float  # noise standard deviation used for the standard errors (reflectance units)
    sigma_source: str  # "given" or "residuals"
    algorithm: str
    evaluations: int
    status: str
    penalty_scales: tuple[float, float] = (1.0, 1.0)  # K_bar, S_bar of the smoothness term


def _film_and_derivatives(K, S, X, G):
    """R over background G (thesis eq. 3.5 as R0 + T^2 G / (1 - R0 G)), and dR/dK, dR/dS, for finite X."""
    s = X * X * K * (K + 2.0 * S)
    x = np.sqrt(s)
    t = _tanhc(x)
    h = _sech(x)
    small = x < 1e-3
    safe_s = np.where(small, 1.0, s)
    dt_ds = np.where(small, -1.0 / 3.0 + s * (4.0 / 15.0 - s * (51.0 / 315.0)), (h * h - t) / (2.0 * safe_s))
    ds_dK = X * X * 2.0 * (K + S)
    ds_dS = X * X * 2.0 * K
    P = X * t
    D = 1.0 + (K + S) * P
    R0 = S * P / D
    T = h / D
    out = []
    for ds, dS_self in ((ds_dK, 0.0), (ds_dS, 1.0)):
        dP = X * dt_ds * ds
        dD = P + (K + S) * dP
        dR0 = (dS_self * P + S * dP) / D - S * P * dD / (D * D)
        dT = -h * t * 0.5 * ds / D - h * dD / (D * D)
        out.append((dR0, dT))
    Q = 1.0 - R0 * G
    R = R0 + T * T * G / Q
    derivs = [dR0 + (2.0 * T * dT * G * Q + T * T * G * G * dR0) / (Q * Q) for dR0, dT in out]
    return R, derivs[0], derivs[1]


def _masstone_and_derivatives(K, S, K0, p):
    """R_inf = S / (K + S + beta), beta = sqrt(K (K + 2S)) (thesis eq. 3.6 as 1 / (a + b)); dR_inf/dp with K = K0 p^2,
    and dR_inf/dS."""
    root = np.sqrt(K + 2.0 * S)
    beta = np.sqrt(K) * root
    den = K + S + beta
    safe_den = np.where(den > 0.0, den, 1.0)
    R = np.where(den > 0.0, S / safe_den, 0.0)
    safe_root = np.where(root > 0.0, root, 1.0)
    dbeta_dp = np.sqrt(K0) * 2.0 * (K + S) / safe_root * np.where(p < 0.0, -1.0, 1.0)
    dR_dp = -S * (2.0 * K0 * p + dbeta_dp) / (safe_den * safe_den)
    # dR/dS = (den - S (1 + dbeta/dS)) / den^2, with beta - S dbeta/dS = sqrt(K)(K + S)/sqrt(K + 2S):
    # written without the cancellation as K/S -> 0.
    dR_dS = (K + np.sqrt(K) * (K + S) / safe_root) / (safe_den * safe_den)
    return R, dR_dp, dR_dS


class _Model:
    """Readings and their derivatives as functions of the scaled parameters (p, r)."""

    def __init__(self, thickness, backgrounds, saunderson, K0, S0):
        self.masstone = ~np.isfinite(thickness)
        self.X = np.where(self.masstone, 0.0, thickness)[:, None]
        self.G = backgrounds
        self.saunderson = saunderson
        self.K0, self.S0 = K0, S0

    def evaluate(self, p, r):
        """Modelled readings (m, n) and their derivatives with respect to p, r, K and S.

        dR/dK of a masstone is infinite at K = 0; there it is returned as dR/dp / (2 K_0 p) with p
        floored at 1e-150, a huge but finite slope (the standard error of K is then ~0, which is true).
        """
        K = self.K0 * p * p
        S = self.S0 * r * r
        shape = self.G.shape
        R = np.empty(shape)
        dR_dK = np.empty(shape)
        dR_dp = np.empty(shape)
        dR_dS = np.empty(shape)
        film = ~self.masstone
        if film.any():
            Kf, Sf = np.broadcast_to(K, shape)[film], np.broadcast_to(S, shape)[film]
            R[film], dR_dK[film], dR_dS[film] = _film_and_derivatives(Kf, Sf, self.X[film], self.G[film])
            dR_dp[film] = dR_dK[film] * 2.0 * self.K0 * p
        if self.masstone.any():
            count = int(self.masstone.sum())
            Rm, dp, dS = _masstone_and_derivatives(K, S, self.K0, p)
            dK = dp / (2.0 * self.K0 * np.maximum(np.abs(p), 1e-150))
            R[self.masstone], dR_dp[self.masstone], dR_dK[self.masstone], dR_dS[self.masstone] = (
                np.broadcast_to(v, (count, shape[1])) for v in (Rm, dp, dK, dS)
            )
        dR_dr = dR_dS * 2.0 * self.S0 * r
        if self.saunderson is not None:
            k1, k2 = self.saunderson
            slope = saunderson_slope(R, k1, k2)
            R = saunderson_forward(R, k1, k2)
            dR_dp, dR_dr, dR_dK, dR_dS = (slope * v for v in (dR_dp, dR_dr, dR_dK, dR_dS))
        return R, dR_dp, dR_dr, dR_dK, dR_dS

    @classmethod
    def at(cls, K, S, thickness, backgrounds, saunderson):
        """The model with scales K_0 = K, S_0 = S (floored above 0) and the p, r that give K and S."""
        K = np.asarray(K, dtype=np.float64)
        S = np.asarray(S, dtype=np.float64)
        floor = 1e-6 * np.maximum(K + S, 1e-9)
        model = cls(
            np.asarray(thickness, dtype=np.float64),
            np.asarray(backgrounds, dtype=np.float64),
            saunderson,
            np.maximum(K, floor),
            np.maximum(S, floor),
        )
        return model, np.sqrt(K / model.K0), np.sqrt(S / model.S0)


def _jacobian_KS(model, p, r):
    """Readings and their derivatives with respect to K and S (not p, r), shape (m, n) each."""
    Rm, _, _, dK, dS = model.evaluate(p, r)
    return Rm, dK, dS


def predict_readings(K, S, thickness, backgrounds, saunderson=None) -> np.ndarray:
    """Readings (m, n) that K, S (n,) predict for films of the given thickness (m,) over backgrounds (m, n).

    ``inf`` thickness marks a masstone; ``saunderson`` = (k1, k2) adds surface reflection.
    """
    model, p, r = _Model.at(K, S, thickness, backgrounds, saunderson)
    return model.evaluate(p, r)[0]


def _information(dK, dS):
    """Entries of J^T J per wavelength (J = [dR/dK, dR/dS] over the measurements), its determinant, and
    where it is singular (K and S cannot be told apart: an opaque film)."""
    a11 = np.sum(dK * dK, axis=0)
    a12 = np.sum(dK * dS, axis=0)
    a22 = np.sum(dS * dS, axis=0)
    det = a11 * a22 - a12 * a12
    return a11, a22, det, ~(det > 1e-14 * a11 * a22)


def standard_errors(K, S, thickness, backgrounds, readings, saunderson=None, sigma=None):
    """Gauss-Newton standard errors of K and S at each wavelength, and the sigma used.

    Covariance sigma^2 (J^T J)^-1 with J the (m x 2) Jacobian of the readings in (K, S) at one wavelength.
    sigma: the readings' noise standard deviation, or None to estimate it from the residuals pooled over
    wavelengths, sqrt(sum r^2 / (m n - 2 n)) (None is returned for it, and for the errors, when m <= 2:
    an exactly determined fit has no residual to learn the noise from). Where J^T J is singular the
    error is +inf (K and S not separable there).
    """
    model, p, r = _Model.at(K, S, thickness, backgrounds, saunderson)
    Rm, _, _, dK, dS = model.evaluate(p, r)
    m, n = Rm.shape
    if sigma is None:
        if m <= 2:
            return None, None, None
        residuals = Rm - np.asarray(readings, dtype=np.float64)
        sigma = float(np.sqrt(np.sum(residuals * residuals) / (m * n - 2 * n)))
    a11, a22, det, singular = _information(dK, dS)
    safe_det = np.where(singular, 1.0, det)
    K_se = np.where(singular, np.inf, sigma * np.sqrt(np.abs(a22 / safe_det)))
    S_se = np.where(singular, np.inf, sigma * np.sqrt(np.abs(a11 / safe_det)))
    return K_se, S_se, float(sigma)


def _gauss_newton_polish(model, y, p, r, iterations: int = 8):
    """Refine an L-BFGS answer with per-wavelength Gauss-Newton steps in (K, S), kept where they help.

    L-BFGS stops on a relative objective change, a few 1e-5 short of the optimum when the data are
    nearly noise-free; without a smoothness term the wavelengths are independent 2-parameter problems,
    for which Gauss-Newton converges quadratically. A step is kept only at wavelengths where it lowers
    the sum of squares, and K, S stay >= 0. Returns p, r and the number of model evaluations.
    """
    K = model.K0 * p * p
    S = model.S0 * r * r
    Rm, dK, dS = _jacobian_KS(model, p, r)
    sse = np.sum((Rm - y) ** 2, axis=0)
    evaluations = 1
    for _ in range(iterations):
        res = Rm - y
        a11, a12, a22 = (np.sum(u * v, axis=0) for u, v in ((dK, dK), (dK, dS), (dS, dS)))
        g1, g2 = np.sum(dK * res, axis=0), np.sum(dS * res, axis=0)
        det = a11 * a22 - a12 * a12
        ok = det > 1e-12 * a11 * a22
        safe = np.where(ok, det, 1.0)
        K_new = np.where(ok, np.maximum(K - (a22 * g1 - a12 * g2) / safe, 0.0), K)
        S_new = np.where(ok, np.maximum(S - (a11 * g2 - a12 * g1) / safe, 0.0), S)
        p_new, r_new = np.sqrt(K_new / model.K0), np.sqrt(S_new / model.S0)
        Rm_new, dK_new, dS_new = _jacobian_KS(model, p_new, r_new)
        evaluations += 1
        sse_new = np.sum((Rm_new - y) ** 2, axis=0)
        better = sse_new < sse
        if not better.any():
            break
        K, S, p, r = (np.where(better, a, b) for a, b in ((K_new, K), (S_new, S), (p_new, p), (r_new, r)))
        Rm, dK, dS = (np.where(better, a, b) for a, b in ((Rm_new, Rm), (dK_new, dK), (dS_new, dS)))
        sse = np.where(better, sse_new, sse)
    return p, r, evaluations


def _second_difference_penalty(v, scale):
    """sum (d2 v / scale)^2 and its gradient with respect to v."""
    if v.size < 3:
        return 0.0, np.zeros_like(v)
    d2 = (v[2:] - 2.0 * v[1:-1] + v[:-2]) / scale
    grad = np.zeros_like(v)
    grad[2:] += 2.0 * d2 / scale
    grad[1:-1] -= 4.0 * d2 / scale
    grad[:-2] += 2.0 * d2 / scale
    return float(np.sum(d2 * d2)), grad


def fit_joint(
    readings,
    backgrounds,
    thickness,
    K_start,
    S_start,
    *,
    sigma: float | None = None,
    saunderson: tuple[float, float] | None = None,
    smoothness: float = 0.0,
    max_evaluations: int = 5000,
) -> JointFit:
    """Fit K and S (per mm) at every wavelength to all readings of one sample.

    Parameters
    ----------
    readings
        (m, n) measured reflectances y_ij as read (including surface reflection if ``saunderson`` is set).
    backgrounds
        (m, n) KM reflectance of what lies under each film (ignored for masstone rows).
    thickness
        (m,) film thickness in mm; ``inf`` marks a masstone (opaque layer).
    K_start, S_start
        (n,) starting values, e.g. from a closed-form inversion.
    sigma
        Noise standard deviation of the readings (reflectance units), for the standard errors. None:
        estimated from the pooled residuals, sqrt(sum of squares / (m n - 2 n)).
    saunderson
        (k1, k2) to model surface reflection, or None.
    smoothness
        lambda of the second-difference penalty (0 = wavelengths fitted independently). The penalty
        weighs squared relative curvature against squared residuals (~1e-5 for readings with 0.3 %
        noise), so lambda ~ 1e-4 starts to smooth; 1e-6 changes K by ~1e-4 (benchmarks/bench_fit.py).

    >>> import numpy as np
    >>> from kmpipe.physics.kubelka_munk import reflectance_infinite, reflectance_over_background
    >>> K, S = np.array([1.0, 3.0]), np.array([40.0, 30.0])  # per mm at two wavelengths
    >>> thickness = np.array([np.inf, 0.01, 0.01, 0.03])  # masstone; 10 um over black and white; 30 um over black
    >>> backgrounds = np.array([[0.0, 0.0], [0.04, 0.04], [0.85, 0.85], [0.04, 0.04]])
    >>> readings = np.array([reflectance_infinite(K, S)] + [reflectance_over_background(K, S, x, g)
    ...                     for x, g in zip(thickness[1:], backgrounds[1:])])
    >>> fit = fit_joint(readings, backgrounds, thickness, K * 1.3, S * 0.8)  # started 30 % and 20 % off
    >>> np.round(fit.K, 6).tolist(), np.round(fit.S, 6).tolist()
    ([1.0, 3.0], [40.0, 30.0])
    """
    y = np.asarray(readings, dtype=np.float64)
    G = np.asarray(backgrounds, dtype=np.float64)
    X = np.asarray(thickness, dtype=np.float64)
    m, n = y.shape
    if m < 2:
        raise ValueError("a joint fit needs at least two measurements per wavelength")
    K_start = np.asarray(K_start, dtype=np.float64)
    S_start = np.asarray(S_start, dtype=np.float64)
    # Scales: the start values, kept away from 0 so that p = r = 1 is a point the optimizer can leave.
    floor = 1e-6 * np.maximum(K_start + S_start, 1e-9)
    K0 = np.maximum(K_start, floor)
    S0 = np.maximum(S_start, floor)
    model = _Model(X, G, saunderson, K0, S0)
    weight = 1.0 / (m * n)
    penalty_weight = smoothness / n
    K_bar = float(np.mean(K0))
    S_bar = float(np.mean(S0))
    evaluations = 0
    best = {"f": np.inf, "z": None}

    def objective(z, grad):
        nonlocal evaluations
        evaluations += 1
        p, r = z[:n], z[n:]
        Rm, dp, dr, _, _ = model.evaluate(p, r)
        res = Rm - y
        f = weight * float(np.sum(res * res))
        if grad.size:
            grad[:n] = 2.0 * weight * np.sum(res * dp, axis=0)
            grad[n:] = 2.0 * weight * np.sum(res * dr, axis=0)
        if smoothness > 0.0:
            fk, gk = _second_difference_penalty(K0 * p * p, K_bar)
            fs, gs = _second_difference_penalty(S0 * r * r, S_bar)
            f += penalty_weight * (fk + fs)
            if grad.size:
                grad[:n] += penalty_weight * gk * 2.0 * K0 * p
                grad[n:] += penalty_weight * gs * 2.0 * S0 * r
        if f < best["f"]:
            best["f"], best["z"] = f, z.copy()
        return f

    opt = nlopt.opt(getattr(nlopt, ALGORITHM), 2 * n)
    opt.set_min_objective(objective)
    opt.set_ftol_rel(1e-15)
    opt.set_xtol_rel(1e-12)
    opt.set_maxeval(max_evaluations)
    start = np.concatenate([np.sqrt(np.maximum(K_start, 0.0) / K0), np.sqrt(np.maximum(S_start, 0.0) / S0)])
    start = np.maximum(start, 1e-3)
    try:
        z = opt.optimize(start)
        status = _STATUS.get(opt.last_optimize_result(), str(opt.last_optimize_result()))
    except (nlopt.RoundoffLimited, nlopt.roundoff_limited, nlopt.runtime_error) as stop:
        # L-BFGS's line search gives up once the objective is flat to rounding: keep the best point seen.
        z = best["z"] if best["z"] is not None else start
        status = "line search ended" if isinstance(stop, nlopt.runtime_error) else "roundoff limited"
    p, r = np.abs(z[:n]), np.abs(z[n:])
    if smoothness == 0.0:
        p, r, polished = _gauss_newton_polish(model, y, p, r)
        evaluations += polished
    K = K0 * p * p
    S = S0 * r * r
    Rm = model.evaluate(p, r)[0]
    residuals = Rm - y

    K_se, S_se, sigma_used = standard_errors(K, S, X, G, y, saunderson, sigma)
    source = "residuals" if sigma is None else "given"
    if sigma_used is None:  # two readings per wavelength: exactly determined
        K_se = S_se = np.full(n, np.inf)
        sigma_used, source = 0.0, "none (exactly determined)"
    singular = _information(*_jacobian_KS(model, p, r)[1:])[3]
    flags = np.zeros(n, dtype=np.uint8)
    at_bound = (K <= 1e-9 * (K + S)) | (S <= 1e-9 * (K + S))
    flags[at_bound] |= np.uint8(Flag.AT_BOUND)
    flags[singular] |= np.uint8(Flag.OPAQUE)
    return JointFit(
        K=K,
        S=S,
        K_stderr=K_se,
        S_stderr=S_se,
        flags=flags,
        predicted=Rm,
        residuals=residuals,
        sigma=sigma_used,
        sigma_source=source,
        algorithm=ALGORITHM,
        evaluations=evaluations,
        status=status,
        penalty_scales=(K_bar, S_bar),
    )


_STATUS = {
    nlopt.SUCCESS: "success",
    nlopt.STOPVAL_REACHED: "stopval reached",
    nlopt.FTOL_REACHED: "converged (ftol)",
    nlopt.XTOL_REACHED: "converged (xtol)",
    nlopt.MAXEVAL_REACHED: "stopped at the evaluation limit",
    nlopt.MAXTIME_REACHED: "stopped at the time limit",
}
