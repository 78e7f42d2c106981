"""Numba kernel that describes row blocks by local subspace cells (the certified search's tight levels).

A block of a few consecutive rows of motion lies close to a low-dimensional affine subspace:
its centre plus the ``p`` principal directions of its rows. :func:`block_subspaces` finds, per
block, that centre, an orthonormal basis, the box of the rows' coordinates in it and the
radius of their residuals; :func:`._coarse_kernels.subspace_bounds` turns them into cell
costs that bound every row's distance from below. Only the bound's tightness depends on the
basis (any orthonormal basis is admissible), so the principal directions come from the
eigenvectors of the block's small Gram matrix (at most ``size x size``), not from a
``d x d`` covariance. Reference: ``naive_subspaces`` in ``tests/naive/coarse.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

#: orthogonal iterations from the pivoted Gram-Schmidt basis towards the principal directions
#: (measured: 4 come within a few per cent of the exact ones'
#: pruning, at a tenth of the time of an eigendecomposition per block)
ITERATIONS = 4


@njit(cache=True, inline="always")
def _project_off(v: np.ndarray, w: np.ndarray) -> None:  # pragma: no cover - compiled
    """``v -= (w . v) w`` in place (``w`` a unit vector): ``v``'s part orthogonal to ``w``."""
    dot = 0.0
    for k in range(v.shape[0]):
        dot += w[k] * v[k]
    for k in range(v.shape[0]):
        v[k] -= dot * w[k]


#: blocks per task of the parallel loop (scratch arrays are allocated once per task)
CHUNK = 2048


@njit(cache=True, parallel=True)
def block_subspaces(
    x: np.ndarray, bstart: np.ndarray, p: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Centre, basis, coordinate box and radii of every block ``bstart[b] .. bstart[b+1] - 1``.

    Parameters
    ----------
    x : float32 (n, d)       database rows
    bstart : int64 (nb + 1,) block starts (``_coarse_kernels.block_boxes``)
    p : int                  basis size, 1 to 3 (:func:`._coarse_kernels.subspace_bounds` takes three
                             rows: the rest, and directions beyond a block's rank, are zero)

    Returns
    -------
    cen : float32 (nb, d)        the rows' mean, rounded to float32 (the rest is relative to it)
    basis : float32 (nb, 3, d)   orthonormal rows (to float32 rounding), or zero
    alo, ahi : float32 (nb, 3)   the rows' coordinates ``basis (x_j - cen)``: minimum, maximum,
                                 rounded outwards
    rad : float32 (nb, 2)        ``rho`` (largest residual norm, computed as the norm of the
                                 residual vector: no cancellation) and ``S`` (largest ``||x_j -
                                 cen||``), both rounded up with a relative margin of 1e-6

    Blocks are independent: chunks of :data:`CHUNK` run on numba's threads, each with its own
    scratch arrays (no allocation per block), bit for bit the values of one thread.
    """
    n, d = x.shape
    nb = bstart.shape[0] - 1
    p = min(max(p, 0), 3)
    cen = np.zeros((nb, d), np.float32)
    basis = np.zeros((nb, 3, d), np.float32)
    alo = np.zeros((nb, 3), np.float32)
    ahi = np.zeros((nb, 3), np.float32)
    rad = np.zeros((nb, 2), np.float32)
    maxr = 1
    for b in range(nb):
        maxr = max(maxr, bstart[b + 1] - bstart[b])
    for ch in prange((nb + CHUNK - 1) // CHUNK):
        s = np.empty((maxr, d))
        res = np.empty((maxr, d))
        w = np.empty((maxr, 3))
        u = np.zeros((3, d))
        c = np.empty(d)
        r = np.empty(d)
        for b in range(ch * CHUNK, min(nb, (ch + 1) * CHUNK)):
            _one_block(
                x, bstart[b], bstart[b + 1] - bstart[b], p, s, res, w, u, c, r, cen[b], basis[b], alo[b], ahi[b], rad[b]
            )
    return cen, basis, alo, ahi, rad


@njit(cache=True)
def _one_block(
    x: np.ndarray,
    j0: int,
    nr: int,
    p: int,
    s: np.ndarray,
    res: np.ndarray,
    w: np.ndarray,
    u: np.ndarray,
    c: np.ndarray,
    r: np.ndarray,
    cen: np.ndarray,
    basis: np.ndarray,
    alo: np.ndarray,
    ahi: np.ndarray,
    rad: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """One block's cell into ``cen, basis, alo, ahi, rad`` (its rows of the outputs), with the
    caller's scratch ``s, res`` (rows x d), ``w`` (rows x 3), ``u`` (3 x d), ``c, r`` (d)."""
    d = x.shape[1]
    for k in range(d):
        c[k] = 0.0
    for j in range(nr):
        for k in range(d):
            c[k] += x[j0 + j, k]
    for k in range(d):
        cen[k] = np.float32(c[k] / nr)
    for j in range(nr):
        for k in range(d):
            s[j, k] = np.float64(x[j0 + j, k]) - np.float64(cen[k])
            res[j, k] = s[j, k]  # the rows' residuals after the directions taken so far
    u[:, :] = 0.0
    got = 0
    for t in range(p):  # pivoted Gram-Schmidt: the row of largest residual gives the next direction
        best = -1
        top = 0.0
        for j in range(nr):
            r2 = 0.0
            for k in range(d):
                r2 += res[j, k] * res[j, k]
            if r2 > top:
                top = r2
                best = j
        if best < 0 or top <= 1e-24:
            break
        nrm = np.sqrt(top)
        for k in range(d):
            u[t, k] = res[best, k] / nrm
        for j in range(nr):
            _project_off(res[j], u[t])
        got += 1
    for it in range(ITERATIONS + 1):
        if it > 0:  # orthogonal iteration towards the principal directions: u <- (u S^T) S
            for j in range(nr):
                for t in range(got):
                    a = 0.0
                    for k in range(d):
                        a += s[j, k] * u[t, k]
                    w[j, t] = a
            for t in range(got):
                for k in range(d):
                    a = 0.0
                    for j in range(nr):
                        a += w[j, t] * s[j, k]
                    u[t, k] = a
        for t in range(got):  # Gram-Schmidt: orthonormal to float64 rounding
            for z in range(t):
                _project_off(u[t], u[z])
            nrm = 0.0
            for k in range(d):
                nrm += u[t, k] * u[t, k]
            nrm = np.sqrt(nrm)
            if nrm <= 1e-300:
                got = t
                break
            for k in range(d):
                u[t, k] /= nrm
    for t in range(got, 3):
        for k in range(d):
            u[t, k] = 0.0
    for t in range(got):
        for k in range(d):
            basis[t, k] = np.float32(u[t, k])
    big_s = 0.0
    rho = 0.0
    for t in range(p):
        alo[t] = np.inf
        ahi[t] = -np.inf
    for j in range(nr):
        nrm2 = 0.0
        for k in range(d):
            r[k] = s[j, k]
            nrm2 += s[j, k] * s[j, k]
        big_s = max(big_s, np.sqrt(nrm2))
        for t in range(p):
            a = 0.0
            for k in range(d):
                a += np.float64(basis[t, k]) * s[j, k]
            # outward float32 rounding, with a relative margin for the float64 sums
            alo[t] = min(alo[t], np.nextafter(np.float32(a - 1e-9 * np.abs(a)), np.float32(-np.inf)))
            ahi[t] = max(ahi[t], np.nextafter(np.float32(a + 1e-9 * np.abs(a)), np.float32(np.inf)))
            for k in range(d):
                r[k] -= a * np.float64(basis[t, k])
        rr = 0.0
        for k in range(d):
            rr += r[k] * r[k]
        rho = max(rho, np.sqrt(rr))
    rad[0] = np.nextafter(np.float32(rho + 1e-6 * big_s), np.float32(np.inf))
    rad[1] = np.nextafter(np.float32(big_s * (1.0 + 1e-6)), np.float32(np.inf))
