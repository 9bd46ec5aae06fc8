"""Monte Carlo check of an uncertainty budget: refit K and S to many perturbed copies of a sample's inputs.

Each draw perturbs every source of :class:`kmpipe.physics.fit_covariance.Doubts` by its own standard normal causes:

    y' = (y + sigma z) (1 + e_w z_w),   G' = (G + sigma_b z_b) (1 + e_w z_w),   X'_d = X_d + u_d z_d,

and refits all draws at once, from where the linearized budget sends each (theta + H^-1 J^T (dy - J_b db)), by
Newton steps

    theta <- max(theta - H^-1 grad phi(theta), 0),   grad phi = J(theta)^T (R(theta; X', G') - y') + P theta,

each kept only where it lowers the objective, whose fixed point is the exact minimum of the perturbed problem
(grad phi = 0, the model fully nonlinear, K and S kept >= 0 as the fit keeps them). Without a smoothness term each
wavelength is its own 2 x 2 problem and H is each draw's own damped Gauss-Newton block (Levenberg-Marquardt, the
damping raised where a step fails: robust along the valley of a nearly opaque film); with one, H is held at the
fit's (the budget's) and a draw's step halved until it helps, which only slows convergence and does not change where
it ends. The spread of the draws'
rendered colours is then what the linearized radius should predict; it is wider where the model bends (nearly opaque
or nearly transparent films).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kmpipe.physics.fit_covariance import Budget, Doubts, penalty_hessian, sensitivity
from kmpipe.physics.joint_fit import _film_and_derivatives, _masstone_and_derivatives
from kmpipe.physics.saunderson import saunderson_forward, saunderson_inverse, saunderson_slope

#: Newton steps at most; and the relative step below which a draw has converged.
ITERATIONS = 100
TOLERANCE = 1e-5
#: A linearized start that moves some K or S by more than this fraction is checked against the fit's own answer.
FAR = 0.3


@dataclass(frozen=True)
class Draws:
    """K and S (draws, n) refitted to perturbed inputs, how many steps it took, and how many draws had not settled
    (a nearly flat valley: K and S barely told apart)."""

    K: np.ndarray
    S: np.ndarray
    iterations: int
    converged: bool
    unsettled: int = 0  # draws still moving after ITERATIONS steps


def _readings(K, S, X, G_body, masstone, saunderson):
    """Readings (D, m, n) and dR/dK, dR/dS of films X (D, m, 1) over G_body (D, m, n); K, S (D, 1, n)."""
    shape = G_body.shape
    R, dK, dS = np.empty(shape), np.empty(shape), np.empty(shape)
    film = ~masstone
    if film.any():
        part = (shape[0], int(film.sum()), shape[2])
        R[:, film], dK[:, film], dS[:, film] = _film_and_derivatives(
            np.broadcast_to(K, part), np.broadcast_to(S, part), np.broadcast_to(X[:, film], part), G_body[:, film]
        )
    if masstone.any():
        K0 = np.maximum(K[:, 0, :], 1e-150)
        Rm, dp, dSm = _masstone_and_derivatives(K[:, 0, :], S[:, 0, :], K0, np.sqrt(K[:, 0, :] / K0))
        dKm = dp / (2.0 * K0)  # dR/dK = dR/dp / (2 K0 p) at p = sqrt(K / K0)
        R[:, masstone], dK[:, masstone], dS[:, masstone] = Rm[:, None], dKm[:, None], dSm[:, None]
    if saunderson is not None:
        slope = saunderson_slope(R, *saunderson)
        R, dK, dS = saunderson_forward(R, *saunderson), slope * dK, slope * dS
    return R, dK, dS


def perturbed_fits(
    budget: Budget,
    thickness,
    backgrounds_raw,
    readings,
    doubts: Doubts,
    *,
    saunderson=None,
    smoothness: float = 0.0,
    penalty_scales: tuple[float, float] = (1.0, 1.0),
    draws: int = 1000,
    seed: int = 0,
) -> Draws:
    """Refit ``draws`` perturbed copies of the sample (module docstring); inputs as for
    :func:`kmpipe.physics.fit_covariance.budget`. ``seed`` makes the draws repeatable."""
    rng = np.random.default_rng(seed)
    y = np.asarray(readings, dtype=np.float64)
    m, n = y.shape
    X = np.asarray(thickness, dtype=np.float64)
    masstone = ~np.isfinite(X)
    G_raw = np.asarray(backgrounds_raw, dtype=np.float64)
    scale = np.ones((draws, n))
    if doubts.white_u is not None:
        scale += doubts.white_u[None, :] * rng.standard_normal((draws, 1))
    y_d = (y[None] + doubts.sigma[None] * rng.standard_normal((draws, m, n))) * scale[:, None, :]
    B = len(doubts.backing_sigma)
    backing = doubts.backing_readings[None] + doubts.backing_sigma[None] * rng.standard_normal((draws, B, n))
    G_d = np.zeros((draws, m, n))
    film = doubts.backing >= 0
    G_d[:, film] = backing[:, doubts.backing[film]]
    G_d = np.minimum(G_d * scale[:, None, :], 1.0)
    G_d[:, ~film] = G_raw[None, ~film]  # (no backing)
    G_body = G_d if saunderson is None else saunderson_inverse(G_d, *saunderson)
    groups = sorted({int(d) for d in doubts.drawdown if d >= 0})
    shift = np.zeros((draws, m))
    for d in groups:
        rows = doubts.drawdown == d
        shift[:, rows] = float(np.max(doubts.thickness_u[rows])) * rng.standard_normal((draws, 1))
    X_d = np.where(masstone[None], 1.0, X[None] + shift)[:, :, None]

    P = penalty_hessian(n, m, smoothness, *penalty_scales)
    # start each draw where the linearized budget sends it: theta + H^-1 J^T (dy - dR/dX dX - dR/dG dG)
    sens = sensitivity(budget.K, budget.S, X, G_raw, saunderson)
    moved = (y_d - y[None]) - sens.dX[None] * shift[:, :, None] - sens.dG[None] * (G_d - G_raw[None])
    pull = np.empty((draws, 2 * n))
    pull[:, 0::2] = np.einsum("dmn,mn->dn", moved, sens.dK)
    pull[:, 1::2] = np.einsum("dmn,mn->dn", moved, sens.dS)
    fitted = np.tile(np.stack([budget.K, budget.S], axis=-1).ravel(), (draws, 1))
    theta = np.maximum(fitted + pull @ budget.inverse()[0], 0.0)
    size = np.tile(np.maximum(np.abs(fitted[0]), 1e-9 * float(np.max(np.abs(fitted[0])))), (draws, 1))
    solve = _Levenberg(draws, n) if smoothness <= 0.0 else _HeldHessian(budget.inverse()[0], P, draws)

    def evaluate(at, rows):
        R, dK, dS = _readings(at[:, 0::2][:, None, :], at[:, 1::2][:, None, :], X_d[rows], G_body[rows], masstone,
                              saunderson)  # fmt: skip
        res = R - y_d[rows]
        return res, dK, dS, solve.objective(res, at)

    res, dK, dS, f = evaluate(theta, slice(None))
    # a draw sent far (a nearly singular H: the model bends before it gets there) may do better from the fit's answer
    far = np.flatnonzero(np.max(np.abs(theta - fitted) / size, axis=1) > FAR)
    if far.size:
        res_0, dK_0, dS_0, f_0 = evaluate(fitted[far], far)
        worse = f_0 < f[far]
        mask = np.repeat(worse, 2, axis=1) if worse.shape[1] > 1 else worse
        theta[far] = np.where(mask, fitted[far], theta[far])
        for whole, start in ((res, res_0), (dK, dK_0), (dS, dS_0)):
            whole[far] = np.where(worse[:, None, :], start, whole[far])
        f[far] = np.where(worse, f_0, f[far])
    separate = smoothness <= 0.0
    if separate:  # every wavelength of every draw a problem of its own: those settled drop out one by one

        def pairs(a):  # (draws, m, n) -> (draws n, m, 1)
            return np.moveaxis(a, 2, 1).reshape(draws * n, m, 1)

        theta, size = theta.reshape(draws * n, 2), size.reshape(draws * n, 2)
        res, dK, dS, y_d, G_body = (pairs(a) for a in (res, dK, dS, y_d, G_body))
        f = f.reshape(draws * n, 1)
        X_d = np.repeat(X_d, n, axis=0)
        P, solve = np.zeros((2, 2)), _Levenberg(draws * n, 1)
    active = np.arange(theta.shape[0])  # the draws (or draws and wavelengths) still moving
    iteration = 0
    while iteration < ITERATIONS and active.size:
        iteration += 1
        now = theta[active]
        grad = np.empty_like(now)
        grad[:, 0::2] = np.sum(dK * res, axis=1)
        grad[:, 1::2] = np.sum(dS * res, axis=1)
        grad += now @ P
        trial = np.maximum(now - solve.step(grad, dK, dS, active), 0.0)
        res_t, dK_t, dS_t, f_t = evaluate(trial, active)
        better = solve.accept(f_t, f, active)  # (active, n) or (active, 1): where the objective went down
        mask = np.repeat(better, 2, axis=1) if better.shape[1] > 1 else better
        theta[active] = np.where(mask, trial, now)
        keep = better[:, None, :]
        res, dK, dS = (np.where(keep, new, old) for new, old in ((res_t, res), (dK_t, dK), (dS_t, dS)))
        f = np.where(better, f_t, f)
        # a draw whose proposed step is negligible is at its minimum (a rejected one is rounding)
        moving = np.max(np.abs(trial - now) / size[active], axis=1) >= TOLERANCE
        active, res, dK, dS, f = active[moving], res[moving], dK[moving], dS[moving], f[moving]
    theta = theta.reshape(draws, 2 * n)
    unsettled = len({int(a) // n for a in active}) if separate else int(active.size)
    return Draws(theta[:, 0::2], theta[:, 1::2], iteration, active.size == 0, unsettled)


class _Levenberg:
    """Wavelengths apart (no smoothness term): each draw and wavelength its own damped 2 x 2 Gauss-Newton
    (Levenberg-Marquardt) step, kept where it lowers that wavelength's sum of squares."""

    def __init__(self, draws: int, n: int) -> None:
        self.damping = np.full((draws, n), 1e-6)

    @staticmethod
    def objective(res, theta):
        return 0.5 * np.sum(res * res, axis=1)  # (draws, n)

    def step(self, grad, dK, dS, rows):
        a11, a12, a22 = np.sum(dK * dK, axis=1), np.sum(dK * dS, axis=1), np.sum(dS * dS, axis=1)
        damping = self.damping[rows]
        b11, b22 = a11 * (1.0 + damping), a22 * (1.0 + damping)
        det = b11 * b22 - a12 * a12
        safe = np.where(det > 0.0, det, 1.0)
        gK, gS = grad[:, 0::2], grad[:, 1::2]
        out = np.empty_like(grad)
        out[:, 0::2] = np.where(det > 0.0, (b22 * gK - a12 * gS) / safe, 0.0)
        out[:, 1::2] = np.where(det > 0.0, (b11 * gS - a12 * gK) / safe, 0.0)
        return out

    def accept(self, f_new, f, rows):
        better = f_new < f
        self.damping[rows] = np.clip(np.where(better, self.damping[rows] / 3.0, self.damping[rows] * 4.0), 1e-12, 1e12)
        return better


class _HeldHessian:
    """With a smoothness term: the fit's H held for every draw (a pseudo-inverse where K and S are not separable),
    each draw's step halved until its whole objective (with the penalty) goes down."""

    def __init__(self, inverse, P, draws: int) -> None:
        self.inverse, self.P = inverse, P
        self.scale = np.ones((draws, 1))

    def objective(self, res, theta):
        return (0.5 * np.sum(res * res, axis=(1, 2)) + 0.5 * np.einsum("dp,pq,dq->d", theta, self.P, theta))[:, None]

    def step(self, grad, dK, dS, rows):
        return self.scale[rows] * (grad @ self.inverse)

    def accept(self, f_new, f, rows):
        better = f_new < f
        self.scale[rows] = np.where(better, np.minimum(self.scale[rows] * 2.0, 1.0), self.scale[rows] / 2.0)
        return better
