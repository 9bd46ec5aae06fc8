"""The ``uncertainty`` section of a material file: its uncertainty budget in the exact compact form of
:class:`kmpipe.physics.fit_covariance.Budget` (documented in docs/formats.md, "Material JSON").

theta = (K_1, S_1, ..., K_n, S_n) (1/mm, interleaved by wavelength) has the covariance

    Cov(theta) = H^-1 (sum over sources of its information) H^-1

with H banded (``H_bands[d][p]`` = H[p, p + d]); a source's information is block diagonal (reading noise:
``blocks`` [kk, ks, ss] per wavelength), a block c c^T per wavelength (a backing: ``columns`` [cK, cS]), or b b^T (a
thickness or the white standard: ``vector`` b, 2n). ``standard_uncertainty`` repeats, for people, the square root of
the diagonal: in all and by source.
"""

from __future__ import annotations

import math

import numpy as np

from kmpipe.physics.fit_covariance import Budget

KINDS = ("noise", "backing", "thickness", "white")
#: The largest standard uncertainty of K or S (1/mm) a budget may give: far beyond any measured doubt (a real one is
#: below 1e3), and small enough that the CIELAB covariance propagated from it stays finite in double precision.
LARGEST_UNCERTAINTY = 1e100
#: The largest magnitude of any number of a budget: one as kmpipe fit writes it stays below about 1e12 (the largest
#: where a masstone's K rests on its bound, :data:`kmpipe.physics.fit_covariance.BOUND_K`); products of a few such
#: numbers stay finite.
LARGEST_ENTRY = 1e100
ORDER = "theta = (K_1, S_1, ..., K_n, S_n) in 1/mm; Cov(theta) = H^-1 (sum of the sources' information) H^-1"


def _floats(values, digits: int | None = None) -> list:
    out = np.asarray(values, dtype=np.float64).ravel()
    if digits is not None:
        out = np.array([float(f"{v:.{digits}g}") for v in out])
    return [float(v) for v in out]


def budget_to_dict(budget: Budget) -> dict:
    """The JSON object of a budget."""
    H = budget.H
    size = H.shape[0]
    bands = []
    for d in range(size):
        band = np.diagonal(H, d)
        if d > 0 and not np.any(band):
            break
        bands.append(_floats(band))
    sources = []
    for name in budget.sources:
        entry = {"name": name, "kind": budget.kinds.get(name, "noise")}
        if name in budget.blocks:
            b = budget.blocks[name]
            entry["blocks"] = [[float(r[0, 0]), float(r[0, 1]), float(r[1, 1])] for r in b]
        elif name in budget.columns:
            entry["columns"] = [[float(a), float(b)] for a, b in budget.columns[name]]
        else:
            entry["vector"] = _floats(budget.vectors[name])
        sources.append(entry)
    K_u, S_u = budget.standard_uncertainty()
    by_source = {}
    for name in budget.sources:
        k, s = budget.standard_uncertainty(name)
        by_source[name] = {"K": _floats(k, 6), "S": _floats(s, 6)}
    return {"order": ORDER, "H_bands": bands, "sources": sources,
            "standard_uncertainty": {"K": _floats(K_u, 6), "S": _floats(S_u, 6), "by_source": by_source}}  # fmt: skip


def budget_from_dict(doc, K: np.ndarray, S: np.ndarray, fail) -> Budget:
    """The Budget of a material's ``uncertainty`` object for its K and S; ``fail(field, message)`` raises."""
    n = K.size
    if not isinstance(doc, dict):
        fail("uncertainty", "expected an object")

    def array(value, field: str, shape: tuple[int, ...]) -> np.ndarray:
        try:
            out = np.array(value, dtype=np.float64)
        except (TypeError, ValueError):
            fail(field, f"expected numbers of shape {shape}")
        if out.shape != shape or not np.all(np.isfinite(out)):
            fail(field, f"expected finite numbers of shape {shape}, got shape {out.shape}")
        if float(np.max(np.abs(out), initial=0.0)) > LARGEST_ENTRY:
            fail(field, f"expected numbers within +-{LARGEST_ENTRY:g} (a budget as kmpipe fit writes it)")
        return out

    bands = doc.get("H_bands")
    if not isinstance(bands, list) or not 1 <= len(bands) <= 2 * n:
        fail("uncertainty.H_bands", f"expected a list of 1 to {2 * n} bands of H")
    H = np.zeros((2 * n, 2 * n))
    for d, band in enumerate(bands):
        values = array(band, f"uncertainty.H_bands[{d + 1}]", (2 * n - d,))
        index = np.arange(2 * n - d)
        H[index, index + d] = values
        H[index + d, index] = values
    blocks, columns, vectors, kinds, fields = {}, {}, {}, {}, {}
    sources = doc.get("sources")
    if not isinstance(sources, list):
        fail("uncertainty.sources", "expected a list")
    for i, entry in enumerate(sources):
        where = f"uncertainty.sources[{i + 1}]"
        if not isinstance(entry, dict) or not isinstance(entry.get("name"), str) or entry.get("kind") not in KINDS:
            fail(where, f"expected an object with a name and a kind ({', '.join(KINDS)})")
        name = entry["name"]
        kinds[name], fields[name] = entry["kind"], where
        if "blocks" in entry:
            kk, ks, ss = array(entry["blocks"], where + ".blocks", (n, 3)).T
            with np.errstate(all="ignore"):  # each block is a sum of outer products: positive semidefinite
                if np.any(kk < 0.0) or np.any(ss < 0.0) or np.any(ks * ks > kk * ss * (1.0 + 1e-9) + 1e-300):
                    fail(where + ".blocks", "expected [kk, ks, ss] of a positive semidefinite block at each wavelength")
            blocks[name] = np.stack([np.stack([kk, ks], -1), np.stack([ks, ss], -1)], axis=1)
        elif "columns" in entry:
            columns[name] = array(entry["columns"], where + ".columns", (n, 2))
        elif "vector" in entry:
            vectors[name] = array(entry["vector"], where + ".vector", (2 * n,))
        else:
            fail(where, "expected blocks, columns or a vector")
    if not math.isfinite(float(np.sum(np.abs(H)))):
        fail("uncertainty.H_bands", "not finite")
    budget = Budget(K, S, H, blocks, columns, vectors, kinds)
    with np.errstate(all="ignore"):  # a hand-edited budget may overflow: said below, not warned about
        if not np.all(np.isfinite(budget.inverse()[0])):
            fail("uncertainty.H_bands", "H cannot be inverted in double precision")
        for name in budget.sources:
            covariance = budget.covariance([name])
            sd = np.sqrt(np.abs(np.diag(covariance)))
            if not (np.all(np.isfinite(covariance)) and float(np.max(sd, initial=0.0)) <= LARGEST_UNCERTAINTY):
                fail(
                    fields[name],
                    f"the standard uncertainty of K or S it gives is not finite or above "
                    f"{LARGEST_UNCERTAINTY:g} per mm (a budget as kmpipe fit writes it is expected)",
                )
    return budget
