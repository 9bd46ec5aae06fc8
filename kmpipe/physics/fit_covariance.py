"""Covariance of fitted K and S from every source of doubt in a sample's readings: the uncertainty budget.

The joint fit (:mod:`kmpipe.physics.joint_fit`) minimizes, times m n / 2,

    phi(theta) = 1/2 sum_ij (R_ij(theta; X_i, G_ij) - y_ij)^2
                 + 1/2 lambda m sum_j [(d2 K_j / K_bar)^2 + (d2 S_j / S_bar)^2]

over theta = (K_1, S_1, ..., K_n, S_n) (per mm, interleaved). At its minimum grad phi = 0; a small change dy of the
readings and db of the other inputs b (thicknesses, backings) moves the answer by (implicit function theorem, with
the Gauss-Newton Hessian)

    d theta = H^-1 J^T (dy - J_b db),    H = J^T J + P,    J = dR/dtheta,    P = lambda m (D2^T D2 / K_bar^2 (+) ...)

so a source whose causes are independent standard normals z with dy - J_b db = D z adds

    Cov_s = H^-1 (J^T D D^T J) H^-1

to the covariance of theta. The sources:

- **reading noise** sigma_ij (repeats or roughness): independent per reading and wavelength, so J^T D D^T J is block
  diagonal, one 2 x 2 block per wavelength, sum_i sigma_ij^2 [dK dK, dK dS; dS dK, dS dS];
- **each backing's reading** (its noise sigma_bj): independent per wavelength, shared by every film over it: a rank-one
  block c c^T per wavelength, c_j = sigma_bj sum_i (dR_ij/dK_j, dR_ij/dS_j) dR_ij/dG_bj;
- **each drawdown's thickness** u_d (``"30 um +- 2 um"``): one cause for all wavelengths and all readings of the film
  (over black and over white: one drawdown), a vector b = J^T (dR/dX u_d);
- **the white standard** (relative u_w(l) / R_w(l)): scales every reading and every backing reading at a wavelength
  alike, and is taken as one cause across wavelengths (a certificate's doubt is mostly its scale, the case that moves
  the colour most), a vector b = J^T ((y - G dR/dG) u_w / R_w).

Reading noise is kept as its blocks, each backing as its columns c (n x 2, the block c c^T at each wavelength), the
thicknesses and the white standard as their vectors b (2n): that is the compact, exact form
MATERIAL.json stores, and the form in which an added measurement (:mod:`kmpipe.physics.next_measurement`) extends
the budget. Where H is singular (an opaque film: K and S not separable) the inverse is the pseudo-inverse of H
scaled to theta, and the wavelengths are reported: the covariance there holds only along K/S.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from kmpipe.physics.joint_fit import _Model, predict_readings
from kmpipe.physics.saunderson import saunderson_inverse

#: Relative step of the central differences in thickness and backing reflectance.
STEP = 1e-6
#: K / (K + S) below which a masstone's dR/dK is taken at this ratio (:func:`sensitivity`).
BOUND_K = 1e-12
#: Eigenvalues of the scaled H below this fraction of its largest are taken as 0 (directions the data cannot see).
SINGULAR = 1e-12


@dataclass(frozen=True)
class Doubts:
    """How uncertain a sample's inputs are (standard uncertainties, k = 1); see the module docstring."""

    sigma: np.ndarray  # (m, n) reading noise, reflectance
    thickness_u: np.ndarray  # (m,) mm (0 for a masstone or an exact thickness)
    drawdown: np.ndarray  # (m,) int: readings of one film share it; -1 for a masstone
    backing: np.ndarray  # (m,) int: index of the backing under each film; -1 for a masstone
    backing_readings: np.ndarray  # (B, n) each backing as read (reflectance, surface reflection included)
    backing_sigma: np.ndarray  # (B, n) their noise, reflectance
    backing_names: tuple[str, ...] = ()
    white_u: np.ndarray | None = None  # (n,) relative: u(R_white) / R_white; None where readings came as reflectance
    drawdown_names: tuple[str, ...] = ()

    def scaled(self, factor: float) -> Doubts:
        """Every source times ``factor``."""
        return Doubts(self.sigma * factor, self.thickness_u * factor, self.drawdown, self.backing,
                      self.backing_readings, self.backing_sigma * factor, self.backing_names,
                      None if self.white_u is None else self.white_u * factor, self.drawdown_names)  # fmt: skip


@dataclass(frozen=True)
class Budget:
    """Covariance of theta (interleaved K, S) as H^-1 (sum blocks + sum columns + sum b b^T) H^-1, by source."""

    K: np.ndarray
    S: np.ndarray
    H: np.ndarray  # (2n, 2n)
    blocks: dict[str, np.ndarray]  # source -> (n, 2, 2)
    columns: dict[str, np.ndarray]  # source -> (n, 2): the block c c^T at each wavelength
    vectors: dict[str, np.ndarray]  # source -> (2n,)
    kinds: dict[str, str] = field(default_factory=dict)  # source -> "noise" | "backing" | "thickness" | "white"

    @property
    def sources(self) -> list[str]:
        return [*self.blocks, *self.columns, *self.vectors]

    def inverse(self) -> tuple[np.ndarray, np.ndarray]:
        """(H^-1 or its scaled pseudo-inverse, the parameters (2n,) that lie in a direction the data cannot see);
        computed once per budget."""
        return self._inverse

    @functools.cached_property
    def _inverse(self) -> tuple[np.ndarray, np.ndarray]:
        return pseudo_inverse(self.H, np.concatenate([self.K[:, None], self.S[:, None]], axis=1).ravel())

    def covariance(self, sources: list[str] | None = None) -> np.ndarray:
        """Cov(theta) (2n x 2n) from ``sources`` (default all)."""
        inverse, _ = self.inverse()
        return inverse @ self.information(sources) @ inverse

    def information(self, sources: list[str] | None = None) -> np.ndarray:
        """sum of J^T D D^T J over ``sources`` (2n x 2n)."""
        n = self.K.size
        total = np.zeros((2 * n, 2 * n))
        for name in self.sources if sources is None else sources:
            if name in self.blocks:
                total += block_diagonal(self.blocks[name])
            elif name in self.columns:
                c = self.columns[name]
                total += block_diagonal(c[:, :, None] * c[:, None, :])
            else:
                b = self.vectors[name]
                total += np.outer(b, b)
        return total

    def standard_uncertainty(self, source: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Standard uncertainty of K and of S (n,) from one source (None: all)."""
        variance = np.diag(self.covariance(None if source is None else [source]))
        sd = np.sqrt(np.maximum(variance, 0.0))
        return sd[0::2], sd[1::2]


def block_diagonal(blocks: np.ndarray) -> np.ndarray:
    """The (2n x 2n) matrix of n 2 x 2 ``blocks`` on its diagonal."""
    n = blocks.shape[0]
    out = np.zeros((2 * n, 2 * n))
    index = 2 * np.arange(n)
    for a in range(2):
        for b in range(2):
            out[index + a, index + b] = blocks[:, a, b]
    return out


def pseudo_inverse(H: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """H^-1 through the eigen-decomposition of D H D, D = diag(scale of theta), with eigenvalues below
    :data:`SINGULAR` of the largest dropped; and a mask of the parameters the dropped directions carry (> 1 %)."""
    scale = np.maximum(np.abs(theta), 1e-9 * max(float(np.max(np.abs(theta))), 1e-12))
    scaled = H * scale[:, None] * scale[None, :]
    values, vectors = np.linalg.eigh(scaled)
    keep = values > SINGULAR * max(float(values[-1]), 1e-300)
    inverse = (vectors[:, keep] / values[keep]) @ vectors[:, keep].T
    blind = np.zeros(theta.size, dtype=bool)
    if not keep.all():
        blind = np.sum(vectors[:, ~keep] ** 2, axis=1) > 0.01
    return inverse * scale[:, None] * scale[None, :], blind


def penalty_hessian(n: int, m: int, smoothness: float, K_bar: float, S_bar: float) -> np.ndarray:
    """P = lambda m (D2^T D2 / K_bar^2 on the K entries, D2^T D2 / S_bar^2 on the S entries), interleaved."""
    P = np.zeros((2 * n, 2 * n))
    if smoothness <= 0.0 or n < 3:
        return P
    D2 = np.zeros((n - 2, n))
    rows = np.arange(n - 2)
    D2[rows, rows], D2[rows, rows + 1], D2[rows, rows + 2] = 1.0, -2.0, 1.0
    curvature = D2.T @ D2 * smoothness * m
    P[0::2, 0::2] = curvature / K_bar**2
    P[1::2, 1::2] = curvature / S_bar**2
    return P


@dataclass(frozen=True)
class Sensitivity:
    """The model's derivatives at a fit, all (m, n): dR/dK, dR/dS, dR/dX (per mm), dR/dG (per unit of the
    backing's reading as measured)."""

    R: np.ndarray
    dK: np.ndarray
    dS: np.ndarray
    dX: np.ndarray
    dG: np.ndarray


def sensitivity(K, S, thickness, backgrounds_raw, saunderson=None) -> Sensitivity:
    """:class:`Sensitivity` of readings of films ``thickness`` (m,) mm (inf: masstone) over backings read as
    ``backgrounds_raw`` (m, n) (the surface reflection removed by ``saunderson`` as the fit removes it)."""
    X = np.asarray(thickness, dtype=np.float64)
    G_raw = np.asarray(backgrounds_raw, dtype=np.float64)
    film = np.isfinite(X)

    def body(G):
        return G if saunderson is None else saunderson_inverse(G, *saunderson)

    model, p, r = _Model.at(K, S, X, body(G_raw), saunderson)
    R, _, _, dK, dS = model.evaluate(p, r)
    # A masstone's dR/dK grows without bound as K -> 0 (where the fit rests on its bound K >= 0): there it is taken at
    # K = BOUND_K (K + S), a slope still a million times the usual (K's doubt ~0 there, which is true) that keeps
    # J^T J, the budget and the files that hold it far from overflow.
    K, S = np.asarray(K, dtype=np.float64), np.asarray(S, dtype=np.float64)
    at_bound = K < BOUND_K * (K + S)
    if at_bound.any():
        lifted, q, t = _Model.at(np.where(at_bound, BOUND_K * (K + S), K), S, X, body(G_raw), saunderson)
        dK = np.where(at_bound, lifted.evaluate(q, t)[3], dK)
    h = STEP * np.where(film, X, 1.0)
    dX = np.zeros_like(R)
    if film.any():
        Xf = X[film]
        up = predict_readings(K, S, Xf + h[film], body(G_raw[film]), saunderson)
        down = predict_readings(K, S, Xf - h[film], body(G_raw[film]), saunderson)
        dX[film] = (up - down) / (2.0 * h[film, None])
    dG = np.zeros_like(R)
    if film.any():
        Gf = G_raw[film]
        step = STEP * np.maximum(Gf, 1e-3)
        up = predict_readings(K, S, X[film], body(Gf + step), saunderson)
        down = predict_readings(K, S, X[film], body(Gf - step), saunderson)
        dG[film] = (up - down) / (2.0 * step)
    return Sensitivity(R, dK, dS, dX, dG)


def _interleave(k: np.ndarray, s: np.ndarray) -> np.ndarray:
    return np.stack([k, s], axis=-1).reshape(*k.shape[:-1], 2 * k.shape[-1])


def budget(
    K,
    S,
    thickness,
    backgrounds_raw,
    readings,
    doubts: Doubts,
    *,
    saunderson=None,
    smoothness: float = 0.0,
    penalty_scales: tuple[float, float] = (1.0, 1.0),
) -> Budget:
    """The uncertainty budget of K, S (n,) fitted to ``readings`` (m, n) of films ``thickness`` (m,) over
    ``backgrounds_raw`` (m, n), with the fit's ``smoothness`` lambda and its (K_bar, S_bar) ``penalty_scales``.

    >>> import numpy as np
    >>> K, S = np.array([2.0]), np.array([40.0])
    >>> X, G = np.array([0.02, 0.02]), np.array([[0.04], [0.85]])
    >>> from kmpipe.physics.joint_fit import predict_readings
    >>> y = predict_readings(K, S, X, G)
    >>> doubts = Doubts(np.full((2, 1), 0.001), np.zeros(2), np.zeros(2, int), np.array([0, 1]), G, np.zeros((2, 1)))
    >>> sd_K, sd_S = budget(K, S, X, G, y, doubts).standard_uncertainty()
    >>> bool(0 < sd_K[0] < 0.2 and 0 < sd_S[0] < 5)  # two exact readings: sigma (J^T J)^-1/2
    True
    """
    K = np.asarray(K, dtype=np.float64)
    S = np.asarray(S, dtype=np.float64)
    y = np.asarray(readings, dtype=np.float64)
    G_raw = np.asarray(backgrounds_raw, dtype=np.float64)
    m, n = y.shape
    sens = sensitivity(K, S, thickness, G_raw, saunderson)
    J = np.stack([sens.dK, sens.dS], axis=-1)  # (m, n, 2)
    H = block_diagonal(np.einsum("mna,mnb->nab", J, J))
    H += penalty_hessian(n, m, smoothness, *penalty_scales)
    blocks: dict[str, np.ndarray] = {}
    columns: dict[str, np.ndarray] = {}
    vectors: dict[str, np.ndarray] = {}
    kinds: dict[str, str] = {}
    sigma = np.asarray(doubts.sigma, dtype=np.float64)
    if np.any(sigma > 0.0):
        blocks["reading noise"] = np.einsum("mn,mna,mnb->nab", sigma**2, J, J)
        kinds["reading noise"] = "noise"
    for b, name in enumerate(doubts.backing_names or [f"backing {i + 1}" for i in range(len(doubts.backing_sigma))]):
        over = doubts.backing == b
        if not over.any() or not np.any(doubts.backing_sigma[b] > 0.0):
            continue
        c = np.einsum("mna,mn->na", J[over], sens.dG[over]) * doubts.backing_sigma[b][:, None]
        source = f"backing {name}"
        columns[source] = c
        kinds[source] = "backing"
    for d in sorted({int(v) for v in doubts.drawdown if v >= 0}):
        rows = doubts.drawdown == d
        u = float(np.max(doubts.thickness_u[rows]))
        if u <= 0.0:
            continue
        name = doubts.drawdown_names[d] if d < len(doubts.drawdown_names) else f"drawdown {d + 1}"
        source = f"thickness {name}"
        vectors[source] = _interleave(*np.einsum("mna,mn->an", J[rows], sens.dX[rows] * u))
        kinds[source] = "thickness"
    if doubts.white_u is not None and np.any(doubts.white_u > 0.0):
        shift = (y - sens.dG * G_raw) * np.asarray(doubts.white_u)[None, :]
        vectors["white standard"] = _interleave(*np.einsum("mna,mn->an", J, shift))
        kinds["white standard"] = "white"
    return Budget(K, S, H, blocks, columns, vectors, kinds)
