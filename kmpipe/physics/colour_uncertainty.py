"""How well the rendered colour of a film is known: the covariance of its CIELAB and a Delta E 2000 radius at 95 %.

The colour a film of thickness X shows over a substrate R_g is the Kubelka-Munk reflectance R(K, S, X, R_g) (thesis
eq. 3.5) through CIELAB (XYZ = R W, CIE 15 L*a*b*). To first order its CIELAB moves by dLab = G d theta with

    G = dLab/dXYZ W^T diag(dR/dK, dR/dS),     dL/dY = 116 f'(Y/Yn)/Yn, da = 500 (f'x - f'y), db = 200 (f'y - f'z),

f(t) = t^(1/3) above (6/29)^3 and t / (3 (6/29)^2) + 4/29 below, so Cov(Lab) = G Cov(theta) G^T. Near a colour c,
Delta E 2000 is a quadratic form, Delta E^2 = dLab^T M(c) dLab (M from CIEDE2000 itself, by central differences of
pairs placed symmetrically about c). With Cov(Lab) = L L^T, Delta E^2 = z^T (L^T M L) z for a standard normal z: a
weighted sum of chi-square(1) variables with weights the eigenvalues w of L^T M L. The radius at 95 % is the square
root of that sum's 0.95 quantile (:func:`quadratic_form_quantile`).

A source's share is its part of the expected Delta E^2, trace(M Cov_s) / trace(M Cov).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize, special

from kmpipe.physics.colorimetry import delta_E_2000, reflectance_to_Lab, white_XYZ, xyz_weights
from kmpipe.physics.fit_covariance import Budget
from kmpipe.physics.joint_fit import _film_and_derivatives, _masstone_and_derivatives

#: Coverage of the reported radius.
COVERAGE = 0.95
#: Step (CIELAB units) of the central differences that give CIEDE2000's local metric.
METRIC_STEP = 1e-4
_DELTA = 6.0 / 29.0


def rendered_reflectance(K, S, thickness_mm: float, substrate) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """R (..., n) of a film ``thickness_mm`` (inf: opaque) over ``substrate`` (n,), and dR/dK, dR/dS."""
    K = np.asarray(K, dtype=np.float64)
    S = np.asarray(S, dtype=np.float64)
    if math.isinf(thickness_mm):
        K0 = np.maximum(K, 1e-150)
        R, dR_dp, dR_dS = _masstone_and_derivatives(K, S, K0, np.sqrt(K / K0))
        return R, dR_dp / (2.0 * K0), dR_dS  # dR/dK = dR/dp / (2 K0 p), p = 1 (huge but finite at K = 0)
    G = np.broadcast_to(np.asarray(substrate, dtype=np.float64), K.shape)
    return _film_and_derivatives(K, S, np.full(K.shape, float(thickness_mm)), G)


def lab_slope(reflectance: np.ndarray, wavelengths, illuminant: str, observer: str = "2") -> np.ndarray:
    """dLab/dR (3 x n) at a reflectance spectrum (n,), analytically (module docstring)."""
    W = xyz_weights(wavelengths, illuminant, observer)
    white = white_XYZ(wavelengths, illuminant, observer)
    t = (reflectance @ W) / white
    slope = np.where(t > _DELTA**3, 1.0 / (3.0 * np.cbrt(np.maximum(t, 1e-300)) ** 2), 1.0 / (3.0 * _DELTA**2))
    df = slope / white  # d f(t)/d XYZ, per component
    A = np.array([[0.0, 116.0, 0.0], [500.0, -500.0, 0.0], [0.0, 200.0, -200.0]])
    return (A * df[None, :]) @ W.T


def ciede2000_metric(lab: np.ndarray) -> np.ndarray:
    """M (3 x 3) with Delta E 2000 (c + d/2, c - d/2)^2 = d^T M d for small d, at CIELAB ``lab``."""
    lab = np.asarray(lab, dtype=np.float64)
    h = METRIC_STEP
    pairs = []
    for a in range(3):
        for b in range(3):
            for sign in (1.0, -1.0):
                d = np.zeros(3)
                d[a] += h
                d[b] += sign * h
                pairs.append(d)
    d = np.array(pairs)
    squared = delta_E_2000(lab + d / 2.0, lab - d / 2.0) ** 2
    q = squared.reshape(3, 3, 2)
    M = (q[..., 0] - q[..., 1]) / (4.0 * h * h)  # polarization: q(x + y) - q(x - y) = 4 x^T M y
    return (M + M.T) / 2.0


def _sphere_rule(points: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """Nodes (N, 3) and weights (N,) (summing to 1) of the mean over the unit sphere of an even function: Gauss-
    Legendre in cos(polar angle) on [0, 1] times Gauss-Legendre in azimuth on [0, pi/2] (one octant)."""
    x, wx = np.polynomial.legendre.leggauss(points)
    cos_t, w_t = 0.5 * (x + 1.0), 0.5 * wx
    phi, w_p = 0.25 * np.pi * (x + 1.0), 0.25 * np.pi * wx
    sin_t = np.sqrt(1.0 - cos_t**2)
    nodes = np.stack([np.outer(sin_t, np.cos(phi)), np.outer(sin_t, np.sin(phi)), np.outer(cos_t, np.ones_like(phi))],
                     axis=-1).reshape(-1, 3)  # fmt: skip
    weights = np.outer(w_t, w_p).ravel()
    return nodes, weights / weights.sum()


_NODES, _NODE_WEIGHTS = _sphere_rule()


def quadratic_form_quantile(weights, coverage: float = COVERAGE) -> float:
    """The ``coverage`` quantile of Q = sum w_k z_k^2 (z standard normal in 3 dimensions, w >= 0); 0 when every
    weight is 0.

    z = r u with r^2 chi-square(3) independent of the direction u, uniform on the sphere, so
    P(Q <= x) = mean over u of F_chi2(3)(x / sum w_k u_k^2), a smooth integral over the sphere (:func:`_sphere_rule`,
    exact to about 1e-9 relative); the quantile follows by Brent's method between those of the smallest and largest
    weight.

    >>> from scipy.stats import chi2
    >>> bool(abs(quadratic_form_quantile([1.0, 1.0, 1.0]) - chi2.ppf(0.95, 3)) < 1e-9)
    True
    >>> bool(abs(quadratic_form_quantile([1.0, 0.0, 0.0]) - chi2.ppf(0.95, 1)) < 1e-6)
    True
    """
    w = np.zeros(3)
    given = np.sort(np.asarray(weights, dtype=np.float64))[::-1][:3]
    w[: given.size] = np.maximum(given, 0.0)
    if w[0] <= 0.0:
        return 0.0
    w = w / w[0]
    q = np.maximum(_NODES**2 @ w, 1e-300)

    def below(x):
        return float(_NODE_WEIGHTS @ special.gammainc(1.5, 0.5 * x / q)) - coverage

    chi3 = float(special.gammaincinv(1.5, coverage)) * 2.0
    low, high = chi3 * w[2], chi3 * w[0]
    if high - low <= 1e-12 * high:
        return high * float(given[0])
    return float(optimize.brentq(below, max(low, 1e-300), high, xtol=1e-12 * high)) * float(given[0])


def radius(covariance_lab: np.ndarray, metric: np.ndarray, coverage: float = COVERAGE) -> float:
    """Delta E 2000 radius holding ``coverage`` of a Gaussian colour error of covariance ``covariance_lab``."""
    values, vectors = np.linalg.eigh(np.asarray(covariance_lab, dtype=np.float64))
    L = vectors * np.sqrt(np.maximum(values, 0.0))[None, :]
    weights = np.linalg.eigvalsh(L.T @ metric @ L)
    return math.sqrt(quadratic_form_quantile(np.maximum(weights, 0.0), coverage))


@dataclass(frozen=True)
class ColourDoubt:
    """The rendered colour of one film under one illuminant and how well it is known."""

    illuminant: str
    thickness_mm: float
    lab: np.ndarray  # (3,)
    covariance_lab: np.ndarray  # (3, 3)
    radius: float  # Delta E 2000 at 95 %
    sources: dict[str, tuple[float, float]]  # source -> (its own radius, its share of the expected Delta E^2)
    metric: np.ndarray  # (3, 3)

    @property
    def dominant(self) -> str | None:
        """The source with the largest share, or None when nothing is uncertain."""
        if not self.sources or self.radius <= 0.0:
            return None
        return max(self.sources, key=lambda s: self.sources[s][1])


def colour_slope(K, S, thickness_mm: float, substrate, wavelengths, illuminant: str, observer: str = "2"):
    """CIELAB (3,) of the film and G = dLab/dtheta (3 x 2n, theta interleaved K, S)."""
    R, dK, dS = rendered_reflectance(K, S, thickness_mm, substrate)
    lab = reflectance_to_Lab(R, wavelengths, illuminant, observer)
    slope = lab_slope(R, wavelengths, illuminant, observer)
    G = np.empty((3, 2 * R.size))
    G[:, 0::2] = slope * dK[None, :]
    G[:, 1::2] = slope * dS[None, :]
    return lab, G


def colour_doubt(
    budget: Budget, thickness_mm: float, substrate, wavelengths, illuminant: str, observer: str = "2"
) -> ColourDoubt:
    """The colour of the budget's film at ``thickness_mm`` over ``substrate`` (n,) under ``illuminant``, its CIELAB
    covariance, its 95 % Delta E 2000 radius and each source's part (linearized)."""
    lab, G = colour_slope(budget.K, budget.S, thickness_mm, substrate, wavelengths, illuminant, observer)
    inverse, _ = budget.inverse()
    V = G @ inverse  # d Lab per unit of J^T D z
    metric = ciede2000_metric(lab)
    total = np.zeros((3, 3))
    parts = {}
    for name in budget.sources:
        C = V @ budget.information([name]) @ V.T
        total += C
        parts[name] = C
    expected = float(np.trace(metric @ total))
    sources = {
        name: (radius(C, metric), float(np.trace(metric @ C)) / expected if expected > 0.0 else 0.0)
        for name, C in parts.items()
    }
    return ColourDoubt(illuminant, float(thickness_mm), lab, total, radius(total, metric), sources, metric)


def colour_radius(
    budget: Budget, thickness_mm: float, substrate, wavelengths, illuminant: str, observer: str = "2"
) -> float:
    """The 95 % Delta E 2000 radius of :func:`colour_doubt` alone (all sources together, linearized)."""
    lab, G = colour_slope(budget.K, budget.S, thickness_mm, substrate, wavelengths, illuminant, observer)
    V = G @ budget.inverse()[0]
    return radius(V @ budget.information() @ V.T, ciede2000_metric(lab))


def sampled_colours(K_draws, S_draws, thickness_mm: float, substrate, wavelengths, illuminant: str,
                    observer: str = "2") -> np.ndarray:  # fmt: skip
    """CIELAB (draws, 3) of the films K, S (draws, n) at ``thickness_mm`` over ``substrate``."""
    R = rendered_reflectance(K_draws, S_draws, thickness_mm, substrate)[0]
    return reflectance_to_Lab(R, wavelengths, illuminant, observer)


def sampled_radius(labs: np.ndarray, lab, coverage: float = COVERAGE) -> float:
    """The ``coverage`` quantile of Delta E 2000 between ``lab`` and sampled colours ``labs`` (draws, 3): the Monte
    Carlo counterpart of :attr:`ColourDoubt.radius`."""
    return float(np.quantile(delta_E_2000(labs, np.broadcast_to(lab, labs.shape)), coverage))
