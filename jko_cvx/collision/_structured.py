"""Newton directions for dense interaction kernels: structured solves instead of one dense Cholesky per slice.

In the flux variables the reduced Hessian of the collision step is (see
:mod:`jko_cvx.collision.newton`)

.. math::  H = B(m) + \\sigma E, \\qquad
           E_{kl} = -\\int_{v_k}^{v_{k+1}}\\!\\int_{v_l}^{v_{l+1}} W''(s - t)\\,dt\\,ds,

with :math:`B` pentadiagonal, :math:`\\sigma = 2\\Delta t\\,\\text{strength}` and :math:`E` the
energy block :meth:`~jko_cvx.kernels.EnergyOperator.flux_block` (the mixed second
difference of :math:`W(v_i - v_j)`, which is this integral exactly).  Newton factorises
the Jacobi-shifted :math:`H_s = H + \\tau\\operatorname{diag}(H)`, :math:`\\tau` = ``pd_tol``,
and reads its positive definiteness off the factorisation.  This module gives the same
solve and the same positive-definiteness verdict without the O(N^3) dense Cholesky:

* **gamma = 3** (:class:`Semiseparable3`, exact, O(N)).  :math:`W'' = 2|v|`, so with the
  cell centres :math:`c_k`, :math:`E = -2\\operatorname{diag}(\\Delta v)\\,(M + D)\\,
  \\operatorname{diag}(\\Delta v)`, :math:`M_{kl} = |c_k - c_l|`, :math:`D = \\operatorname{diag}(\\Delta v^2/3)`.
  :math:`|s - t|` is twice the Green's function of :math:`d^2/ds^2` with Dirichlet ends at
  :math:`a = v_1`, :math:`b = v_N` plus a rank-2 part: with :math:`s' = s - a`,
  :math:`W = b - a`, :math:`|s - t| = 2g(s, t) + s' + t' - 2s't'/W`,
  :math:`g(s, t) = -\\min(s', t')(W - \\max(s', t'))/W`.  So :math:`M = 2G_D + UQU^\\top`,
  :math:`U = [1, s']`, :math:`Q = \\begin{pmatrix} 0 & 1 \\\\ 1 & -2/W\\end{pmatrix}`, and
  :math:`-G_D^{-1} = L_D`, the Dirichlet Laplacian on the nodes :math:`a, c_1, \\dots, c_n, b`
  (tridiagonal, positive definite).  The reduced Hessian is then
  :math:`H_s = H_c - 2\\sigma V Q V^\\top`, :math:`V = \\operatorname{diag}(\\Delta v) U`, with the
  core :math:`H_c = G + 4\\sigma \\operatorname{diag}(\\Delta v) L_D^{-1} \\operatorname{diag}(\\Delta v)`
  (:math:`G` the pentadiagonal part of :math:`H_s`: the bands and the diagonal of
  :math:`\\sigma E`).  With :math:`z = 4\\sigma L_D^{-1}\\operatorname{diag}(\\Delta v) x`,
  :math:`H_c x = r` is the quasi-definite sparse system

  .. math::  \\begin{pmatrix} G & \\operatorname{diag}(\\Delta v) \\\\
             \\operatorname{diag}(\\Delta v) & -L_D/(4\\sigma) \\end{pmatrix}
             \\begin{pmatrix} x \\\\ z \\end{pmatrix} = \\begin{pmatrix} r \\\\ 0 \\end{pmatrix},

  banded with half-bandwidth 4 once :math:`x_k, z_k` are interleaved: one LAPACK banded
  LU (``dgbsv``) after a symmetric diagonal scaling, for the right-hand sides and the two
  columns of :math:`V`; Woodbury's 2 x 2 capacitance
  :math:`S = (-2\\sigma Q)^{-1} + V^\\top H_c^{-1} V` then gives :math:`H_s^{-1} r`.  (The
  first version inverted :math:`M` itself, :math:`M^{-1} = -\\tfrac12 L + u u^\\top/(2(c_n - c_1))`;
  its banded core is nearly singular on near-vacuum slices and Sherman-Morrison lost 4
  digits there.)  Positive definiteness, exactly: :math:`H_c \\succeq G`, so where the
  banded Cholesky of :math:`G` succeeds :math:`H_c` is positive definite, and by Haynsworth's
  inertia formula on the bordered matrix :math:`H_s` is positive definite iff :math:`S` has
  exactly one negative eigenvalue (as :math:`Q` has), i.e. iff :math:`\\det S < 0`.  Where
  :math:`G` is not positive definite the slice goes to the dense Cholesky.
* **even integer gamma >= 4** (:class:`LowRankFlux`, exact, O(N k^2)).  :math:`W = v^\\gamma/\\gamma`
  is a polynomial, so :math:`E = U C U^\\top` exactly, :math:`U_{kp} = v_{k+1}^p - v_k^p`,
  p = 1, ..., gamma - 1, C anti-diagonal (:func:`jko_cvx.kernels.even_power_flux_factors`;
  the operator uses it up to gamma = 8, where it reproduces the dense block to rounding).
  With :math:`B` the pentadiagonal part of :math:`H_s` (bands and Jacobi shift), one banded
  Cholesky of :math:`B` and Woodbury's k x k capacitance
  :math:`S = (\\sigma C)^{-1} + U^\\top B^{-1} U` give the solve, and Haynsworth's inertia
  formula the positive definiteness: :math:`H_s \\succ 0` iff :math:`S` has the inertia of
  :math:`C`.  When Newton projects onto the momentum plane :math:`\\Delta v^\\top m = 0`, the
  terms pairing the first column (:math:`\\Delta v` itself) with the last drop out: they change
  neither the constrained step nor the Hessian on the plane.
* **other gamma** (:class:`Certified`, from N - 1 = 300 fluxes; below that the dense
  Cholesky is faster).  Gershgorin: the off-diagonal part of :math:`\\sigma E`
  is :math:`\\succeq -\\sigma\\operatorname{diag}(R)`, :math:`R_k = \\sum_{l\\ne k}|E_{kl}|`, so
  :math:`H_s \\succeq C`, the pentadiagonal matrix :math:`G - \\sigma\\operatorname{diag}(R)`.  A
  banded Cholesky of :math:`C` that succeeds certifies :math:`H_s` positive definite; then
  :math:`G \\succeq C` is positive definite too and preconditions conjugate gradients on
  :math:`H_s`, whose products with :math:`E` are one matrix product per block of 32 slices
  (O(N^2)).  Slices that the certificate does not cover, or where CG does not reach its
  tolerance, go to the dense Cholesky, which then decides positive definiteness exactly as
  before.
* the **dense** path (:func:`dense_direction`): the per-slice Cholesky of
  ``newton._newton_direction``, bitwise the same, run in threads across slices.

Every path runs under :func:`jko_cvx.threads.blas_limits`, in
:func:`jko_cvx.threads.map_chunks` threads.  A chunk of at least ``_CHAIN_MIN`` slices makes
one chained LAPACK call per phase (:func:`~jko_cvx.collision._linalg.banded_lu_solve_batch`,
:func:`~jko_cvx.collision._linalg.pentadiagonal_cholesky_batch`,
:func:`~jko_cvx.collision._linalg.pentadiagonal_solve_batch`), bitwise the per-slice calls.
``JKO_CVX_NEWTON_LINALG`` selects the path: ``auto`` (default: gamma = 3 and even gamma >= 4
exact, other gamma certified CG, dense fallback) or ``dense`` (dense Cholesky for every slice;
for comparisons).
"""

from __future__ import annotations

import os
import weakref
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack

from jko_cvx.collision._linalg import (
    CHAIN_MIN as _CHAIN_MIN,  # slices from which the chained calls pay
)
from jko_cvx.collision._linalg import (
    banded_lu_solve_batch,
    pentadiagonal_cholesky,
    pentadiagonal_cholesky_batch,
    pentadiagonal_solve_batch,
)
from jko_cvx.kernels import EnergyOperator, FluxBlock
from jko_cvx.threads import map_chunks

__all__ = [
    "LINALG_ENV",
    "Certified",
    "LowRankFlux",
    "Semiseparable3",
    "dense_direction",
    "dense_kernel_direction",
    "linalg_mode",
    "semiseparable3",
]

LINALG_ENV = "JKO_CVX_NEWTON_LINALG"
_MODES = ("auto", "dense")
# CG on G^-1 H_s: stop when the G^-1-norm of the residual falls below _CG_RTOL times that
# of the right-hand side (measured on a gamma = 3/2 batch of the scale benchmark: 30
# products with E in the 6 Newton iterations at N_v = 481, 50 at 1025, each block
# iterating until its slowest slice has converged); after _CG_MAXIT iterations the slice
# goes to the dense Cholesky.
_CG_RTOL = 1e-13
_CG_MAXIT = 60
# Below this many fluxes the dense Cholesky beats certified CG (gamma = 3/2, 32 slices of
# the inhom datum, CPU seconds per batched solve, dense / CG: N_v = 241 0.031 / 0.047,
# 361 0.094 / 0.076, 481 0.19 / 0.11, 1025 1.9 / 0.38; measured 2026-12-01 under load 12,
# with the C preconditioner; G halved CG's cost since, and a lower threshold is not measured).
_CG_MIN_N = 300
_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
# gamma = 3 chains its interleaved LU only up to this many unknowns per slice: measured on
# 16 blocks with 4 right-hand sides, the chained dgbsv takes 0.49x the time of one call per
# block at 2n = 122, 0.94x at 242, 1.06x at 482 and 1.08x at 962 (the LU's own work
# dominates there).
_CHAIN_MAX_LU = 256


def linalg_mode() -> str:
    """The path selected by ``JKO_CVX_NEWTON_LINALG``: ``"auto"`` (default) or ``"dense"``."""
    mode = os.environ.get(LINALG_ENV, "").strip().lower() or "auto"
    if mode not in _MODES:
        raise ValueError(f"environment variable {LINALG_ENV} must be one of {_MODES}, got {mode!r}")
    return mode


def _shifted_diagonal(diag: NDArray, e_diag: NDArray, scale: float, pd_tol: float) -> tuple[NDArray, NDArray]:
    """``d = diag(H)`` and the diagonal of ``H_s = H + pd_tol diag(d)``, as ``newton._newton_direction`` forms them."""
    d = diag + scale * e_diag
    return d, d + pd_tol * d


def dense_direction(
    e_dense: NDArray, scale: float, bands: tuple, rhs: NDArray, pd_tol: float, rows: NDArray | None = None
) -> tuple[NDArray, NDArray[np.bool_]]:
    """``H_s^-1 rhs`` and the positive definiteness of ``H_s``: one dense Cholesky per slice, in threads.

    The arithmetic of ``newton._newton_direction`` on ``add_pentadiagonal(scale * E, *bands)``
    (the same floating-point operations on every entry that LAPACK reads, so bitwise the
    same result), with the per-slice overhead cut: the diagonal, its positivity test and
    the Jacobi shift, and the two lower bands are formed for the whole batch at once;
    each slice then copies ``scale * E`` once and writes only the bands of the lower
    triangle (``dpotrf(lower=1)`` does not read the upper one), into a Fortran-ordered
    matrix, so that LAPACK's wrapper does not copy it again.  ``rows`` restricts the solve
    to those slices (the others are left zero and not positive definite).
    """
    diag, off1, off2 = bands
    B, n1 = diag.shape
    SE, se_t = _scaled_block(e_dense, scale)
    x = np.zeros(rhs.shape)
    pd = np.zeros(B, dtype=bool)
    todo = np.arange(B) if rows is None else np.flatnonzero(rows)
    se_flat = SE.reshape(-1)
    d = se_flat[:: n1 + 1] + diag[todo]
    usable = ((d > 0).all(axis=-1) & np.isfinite(d).all(axis=-1)).tolist()
    shifted = d + pd_tol * d
    lower1 = se_flat[n1 :: n1 + 1] + off1[todo]  # H[k+1, k]
    lower2 = se_flat[2 * n1 :: n1 + 1] + off2[todo]  # H[k+2, k]
    slices = todo.tolist()

    def work(a: int, b: int) -> None:
        # One matrix per chunk, refilled from se_t for each slice: dpotrf (overwrite_a) and
        # dpotrs work in it, and x[i] receives a copy of the solution.
        Ht = np.empty_like(se_t)
        flat = Ht.reshape(-1)
        Hf = Ht.T
        for j in range(a, b):
            if not usable[j]:
                continue
            np.copyto(Ht, se_t)
            flat[:: n1 + 1] = shifted[j]
            flat[1 :: n1 + 1] = lower1[j]
            flat[2 : n1 * (n1 - 2) : n1 + 1] = lower2[j]
            c, info = lapack.dpotrf(Hf, lower=1, clean=0, overwrite_a=1)
            if info != 0 or not np.isfinite(c[-1, -1]):
                continue
            i = slices[j]
            pd[i] = True
            x[i], _ = lapack.dpotrs(c, rhs[i], lower=1)

    map_chunks(work, todo.size)
    return x, pd


_SCALED: list = []  # the last (E, scale, scale * E, its C-ordered transpose) of dense_direction


def _scaled_block(e_dense: NDArray, scale: float) -> tuple[NDArray, NDArray]:
    """``scale * e_dense`` and the C-ordered copy of its transpose, kept for the last read-only block.

    The transpose's copy for a slice is, in Fortran order, ``scale * E`` itself; its lower
    bands sit at strided positions of the C-ordered copy.  Newton calls with the same
    cached block and scale at every iteration of a step: the products are the same
    floating-point operations, so keeping them changes no bit (the key compares the
    scale's bits, so -0.0 and 0.0 differ; a writeable block is never kept).
    """
    key = float(scale).hex()
    last = _SCALED[0] if _SCALED else None
    if last is not None and last[0] is e_dense and last[1] == key:
        return last[2], last[3]
    SE = scale * e_dense
    se_t = np.ascontiguousarray(SE.T)
    if not e_dense.flags.writeable:
        SE.flags.writeable = se_t.flags.writeable = False
        _SCALED[:] = [(e_dense, key, SE, se_t)]
    return SE, se_t


class Semiseparable3:
    """Exact O(N) solve of ``H_s x = r`` for gamma = 3 (see the module docstring), on one grid.

    Parameters
    ----------
    grid : Grid
        The velocity grid (non-uniform allowed).
    """

    KL = 4  # half-bandwidth of the interleaved (x_k, z_k) system
    CHUNK = 16  # slices whose band storage is assembled at once

    def __init__(self, grid) -> None:
        v = grid.points
        dv = np.asarray(grid.dv, dtype=float)
        n = dv.size
        c = 0.5 * (v[:-1] + v[1:])
        self.n, self.dv = n, dv
        self.e_diag = -2.0 * dv**3 / 3.0  # E_kk = -2 dv_k^3 / 3 exactly
        width = float(v[-1] - v[0])
        s = c - v[0]
        # Dirichlet Laplacian on the nodes v_1, c_1, ..., c_n, v_N: the inverse of -2 G_D
        # (G_D[k, l] = -s_min (W - s_max) / W), and M = 2 G_D + U Q U', U = [1, s].
        inv_h = 1.0 / np.diff(np.concatenate([[v[0]], c, [v[-1]]]))
        self.lap_diag, self.lap_off = inv_h[:-1] + inv_h[1:], -inv_h[1:-1]
        self.U = np.stack([dv, dv * s], axis=1)  # diag(dv) U
        self.q_inv = np.array([[2.0 / width, 1.0], [1.0, 0.0]])  # Q^-1, Q = [[0, 1], [1, -2/W]]
        X = 2 * np.arange(n)
        Z = X + 1
        self.X, self.Z = X, Z
        # structural entries (i, j), in the order of the values assembled in solve
        self.rows = np.concatenate([X, X[:-1], X[:-2], X, Z, Z[:-1]])
        self.cols = np.concatenate([X, X[1:], X[2:], Z, Z, Z[1:]])
        self.mirror = self.rows != self.cols

    def _band_storage(self, vals: NDArray) -> NDArray:
        """dgbsv band storage (transposed: one C-ordered ``(2n, 3 KL + 1)`` block per slice) of the entries."""
        kl = self.KL
        ab = np.zeros((vals.shape[0], 2 * self.n, 3 * kl + 1))
        r, c, m = self.rows, self.cols, self.mirror
        ab[:, c, 2 * kl + r - c] = vals
        ab[:, r[m], 2 * kl + c[m] - r[m]] = vals[:, m]
        return ab

    def solve(self, scale: float, bands: tuple, rhs: NDArray, pd_tol: float, out: tuple, lo: int, hi: int) -> None:
        """Solve slices ``lo:hi`` into ``out = (x, pd, decided)`` (arrays of the whole batch).

        ``decided[i]`` is False where G is not positive definite (the dense path decides).
        """
        for a in range(lo, hi, self.CHUNK):
            self._solve_chunk(scale, bands, rhs, pd_tol, out, a, min(hi, a + self.CHUNK))

    def _solve_chunk(self, scale: float, bands: tuple, rhs: NDArray, pd_tol: float, out, lo: int, hi: int) -> None:
        diag, off1, off2 = (band[lo:hi] for band in bands)
        x, pd, decided = out
        b, n, k = hi - lo, self.n, rhs.shape[-1]
        d, g_diag = _shifted_diagonal(diag, self.e_diag, scale, pd_tol)
        z_diag = -self.lap_diag / (4.0 * scale)
        const = np.concatenate([self.dv, z_diag, -self.lap_off / (4.0 * scale)])
        vals = np.concatenate([g_diag, off1, off2, np.broadcast_to(const, (b, const.size))], axis=1)
        # symmetric scaling by |diagonal|^-1/2
        sc = np.empty((b, 2 * n))
        with np.errstate(divide="ignore"):
            sc[:, self.X] = np.abs(g_diag) ** -0.5
        sc[:, self.Z] = np.abs(z_diag) ** -0.5
        ab = self._band_storage(vals * sc[:, self.rows] * sc[:, self.cols])
        # not positive definite where the dense test says so (diagonal), decided either way
        finite = np.all(d > 0, axis=1) & np.all(np.isfinite(d), axis=1) & np.all(np.isfinite(vals), axis=1)
        decided[lo:hi] = True
        Y = np.zeros((b, n, k + 2))
        solved = np.zeros(b, dtype=bool)
        if b >= _CHAIN_MIN and 2 * n <= _CHAIN_MAX_LU:
            rows = np.flatnonzero(finite)
            _, g_pd = pentadiagonal_cholesky_batch(g_diag[rows], off1[rows], off2[rows])
            decided[lo + rows[~g_pd]] = False
            rows = rows[g_pd]
            sx = sc[rows][:, self.X, None]
            R = np.zeros((rows.size, 2 * n, k + 2))
            R[:, self.X, :k] = rhs[lo + rows] * sx
            R[:, self.X, k:] = self.U * sx
            sol, solved[rows] = banded_lu_solve_batch(ab[rows], R, self.KL)
            Y[rows] = sol[:, self.X] * sx
        else:
            R = np.zeros((2 * n, k + 2), order="F")
            for j in np.flatnonzero(finite):
                if pentadiagonal_cholesky(g_diag[j], off1[j], off2[j]) is None:
                    decided[lo + j] = False
                    continue
                sx = sc[j, self.X, None]
                R[:] = 0.0
                R[self.X, :k] = rhs[lo + j] * sx
                R[self.X, k:] = self.U * sx
                _, _, sol, info = lapack.dgbsv(self.KL, self.KL, ab[j].T, R, overwrite_ab=1)
                Y[j] = sol[self.X] * sx
                solved[j] = info == 0
        # Woodbury, for the chunk at once: S = (-2 sigma Q)^-1 + V' H_c^-1 V (2 x 2 per slice)
        S = -self.q_inv / (2.0 * scale) + np.einsum("ni,bnj->bij", self.U, Y[..., k:])
        ok = solved & np.all(np.isfinite(Y), axis=(1, 2)) & np.all(np.isfinite(S), axis=(1, 2))
        decided[lo:hi] &= ok | ~finite
        # inertia: H_c is positive definite, so H_s is iff S has one negative eigenvalue (as Q has)
        det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
        good = ok & (det < 0)
        pd[lo:hi] = good
        if good.any():
            t = np.linalg.solve(S[good], np.einsum("ni,bnj->bij", self.U, Y[good, :, :k]))
            # the two-term sum over the columns of V written out: the bits of einsum's, without its
            # per-call cost (measured 118 against 33 us for a chunk of 16 slices at N_v = 121)
            Yg = Y[good]
            correction = Yg[:, :, k, None] * t[:, None, 0, :] + Yg[:, :, k + 1, None] * t[:, None, 1, :]
            x[lo:hi][good] = Yg[:, :, :k] - correction


class LowRankFlux:
    """Exact O(N k^2) solve of ``H_s x = r`` when the energy block is ``E = U C U'`` (rank k).

    Even integer gamma >= 4 (:func:`jko_cvx.kernels.even_power_flux_factors`; see the module
    docstring).  ``H_s = B + sigma U C U'`` with the pentadiagonal ``B``: the bands plus the
    Jacobi shift ``pd_tol diag(H)``.  One banded Cholesky of ``B`` per slice, back-substitution
    for the right-hand sides and the k columns of ``U``, and Woodbury's k x k capacitance
    :math:`S = (\\sigma C)^{-1} + U^\\top B^{-1} U`.  Positive definiteness, exactly: with
    ``B`` positive definite, Haynsworth's inertia formula on the bordered matrix
    ``[[B, U], [U', -(sigma C)^-1]]`` gives ``H_s`` positive definite iff ``S`` has the inertia
    of ``C``.  Where ``B`` is not positive definite the dense path decides.

    Parameters
    ----------
    basis, coef : ndarray
        ``U`` (N-1, k) and the invertible symmetric ``C`` (k, k).
    """

    CHUNK = 16

    def __init__(self, basis: NDArray, coef: NDArray) -> None:
        self.U = np.asarray(basis, dtype=float)
        self.C = np.asarray(coef, dtype=float)
        self.c_inv = np.linalg.inv(self.C)
        self.negative = int(np.sum(np.linalg.eigvalsh(self.C) < 0))
        self.e_diag = np.einsum("ki,ij,kj->k", self.U, self.C, self.U)
        self._dense: NDArray | None = None

    def dense(self) -> NDArray:
        """``U C U'`` (cached): the block the dense fallback factorises with it."""
        if self._dense is None:
            self._dense = self.U @ self.C @ self.U.T
        return self._dense

    def solve(self, scale: float, bands: tuple, rhs: NDArray, pd_tol: float, out: tuple, lo: int, hi: int) -> None:
        """Solve slices ``lo:hi`` into ``out = (x, pd, decided)``; ``decided`` False where B is not PD."""
        diag, off1, off2 = (band[lo:hi] for band in bands)
        decided = out[2]
        k = rhs.shape[-1]
        d = diag + scale * self.e_diag  # diag(H), as the dense path forms it
        b_diag = diag + pd_tol * d
        s_inv = self.c_inv / scale
        decided[lo:hi] = True
        finite = np.all(d > 0, axis=1) & np.all(np.isfinite(d), axis=1)
        finite &= np.all(np.isfinite(off1), axis=1) & np.all(np.isfinite(off2), axis=1)
        rows = np.flatnonzero(finite)
        if rows.size >= _CHAIN_MIN:
            factors, ok = pentadiagonal_cholesky_batch(b_diag[rows], off1[rows], off2[rows])
            decided[lo + rows[~ok]] = False
            rows = rows[ok]
            cols = np.concatenate([rhs[lo + rows], np.broadcast_to(self.U, (rows.size, *self.U.shape))], axis=-1)
            Ys = pentadiagonal_solve_batch(factors[ok], cols)
            for j, Y in zip(rows, Ys, strict=True):
                # one slice's layout, as dpbtrs gives it: the products below round as they do there
                self._finish(np.asfortranarray(Y), 0, k, s_inv, out, lo + j)
            return
        for j in rows:
            c = pentadiagonal_cholesky(b_diag[j], off1[j], off2[j])
            if c is None:
                decided[lo + j] = False
                continue
            Y, info = lapack.dpbtrs(c, np.concatenate([rhs[lo + j], self.U], axis=1), lower=1)
            self._finish(Y, info, k, s_inv, out, lo + j)

    def _finish(self, Y: NDArray, info: int, k: int, s_inv: NDArray, out: tuple, i: int) -> None:
        """Woodbury and the inertia test of slice ``i`` from ``Y = B^-1 [rhs, U]``."""
        x, pd, decided = out
        S = s_inv + self.U.T @ Y[:, k:]
        S = 0.5 * (S + S.T)
        if info != 0 or not (np.all(np.isfinite(Y)) and np.all(np.isfinite(S))):
            decided[i] = False
            return
        eig = np.linalg.eigvalsh(S)
        if np.any(eig == 0) or int(np.sum(eig < 0)) != self.negative:
            return  # indefinite: pd stays False
        pd[i] = True
        x[i] = Y[:, :k] - Y[:, k:] @ np.linalg.solve(S, self.U.T @ Y[:, :k])


class Certified:
    """Gershgorin-certified positive definiteness and preconditioned CG for a general dense E.

    Parameters
    ----------
    e_dense : ndarray, shape (n, n)
        The energy block E (read-only; shared).
    """

    def __init__(self, e_dense: NDArray) -> None:
        n = e_dense.shape[0]
        self.E = e_dense
        self.e_diag = np.diag(e_dense).copy()
        # off-diagonal absolute row sums, rounded up by the summation's error bound
        self.radius = (np.abs(e_dense).sum(axis=1) - np.abs(self.e_diag)) * (1 + 4 * n * np.finfo(float).eps)

    CHUNK = 32  # slices per matrix product (fixed blocks: the rounding does not depend on the threads)

    def solve(self, scale: float, bands: tuple, rhs: NDArray, pd_tol: float, out: tuple, lo: int, hi: int) -> None:
        """Solve slices ``lo:hi`` into ``out = (x, pd, decided)``; undecided slices go to the dense path."""
        for a in range(lo, hi, self.CHUNK):
            self._solve_chunk(scale, bands, rhs, pd_tol, out, a, min(hi, a + self.CHUNK))

    def _solve_chunk(self, scale: float, bands: tuple, rhs: NDArray, pd_tol: float, out, lo: int, hi: int) -> None:
        diag, off1, off2 = (band[lo:hi] for band in bands)
        x, pd, decided = out
        d, h_diag = _shifted_diagonal(diag, self.e_diag, scale, pd_tol)
        usable = np.all(d > 0, axis=1) & np.all(np.isfinite(d), axis=1)
        decided[lo + np.flatnonzero(~usable)] = True  # not positive definite, as the dense test has it
        rows = np.flatnonzero(usable)
        if rows.size >= _CHAIN_MIN:
            _, cert = pentadiagonal_cholesky_batch(h_diag[rows] - scale * self.radius, off1[rows], off2[rows])
            js = rows[cert]
            factors, ok = pentadiagonal_cholesky_batch(h_diag[js], off1[js], off2[js])
            js, factors = js[ok], factors[ok]

            def precondition(Rm: NDArray) -> NDArray:
                return pentadiagonal_solve_batch(factors, Rm)
        else:
            singles = {}
            for j in rows:
                if pentadiagonal_cholesky(h_diag[j] - scale * self.radius, off1[j], off2[j]) is not None:
                    # certified; G >= C is positive definite too, and the closer preconditioner
                    # (measured, N_v = 481 / 1025: 30 / 50 CG iterations against 57 / 97 with C)
                    c = pentadiagonal_cholesky(h_diag[j], off1[j], off2[j])
                    if c is not None:
                        singles[j] = c
            js = np.fromiter(singles, dtype=int, count=len(singles))
            factor_list = [singles[j] for j in js]

            def precondition(Rm: NDArray) -> NDArray:
                return np.stack([lapack.dpbtrs(factor_list[j], Rm[j], lower=1)[0] for j in range(len(factor_list))])

        if js.size == 0:
            return
        sol, ok = self._pcg(scale, (h_diag[js], off1[js], off2[js]), rhs[lo + js], precondition)
        x[lo + js[ok]] = sol[ok]
        pd[lo + js[ok]] = True
        decided[lo + js[ok]] = True

    def _pcg(
        self, scale: float, bands: tuple, rhs: NDArray, precondition: Callable[[NDArray], NDArray]
    ) -> tuple[NDArray, NDArray[np.bool_]]:
        """Preconditioned CG on ``H_s X = rhs`` for a chunk (``rhs`` of shape ``(b, n, k)``), all columns at once.

        ``precondition(R)`` solves with the banded Cholesky factors of G, slice by slice.
        """
        h_diag, off1, off2 = bands
        b, n, k = rhs.shape
        E, e_diag = self.E, self.e_diag

        def apply(X: NDArray) -> NDArray:  # H_s X: bands plus the off-diagonal energy (one GEMM)
            Y = h_diag[..., None] * X
            Y[:, :-1] += off1[..., None] * X[:, 1:]
            Y[:, 1:] += off1[..., None] * X[:, :-1]
            Y[:, :-2] += off2[..., None] * X[:, 2:]
            Y[:, 2:] += off2[..., None] * X[:, :-2]
            EX = (E @ X.transpose(1, 0, 2).reshape(n, b * k)).reshape(n, b, k).transpose(1, 0, 2)
            return Y + scale * (EX - e_diag[:, None] * X)

        X = np.zeros_like(rhs)
        R = rhs.copy()
        Zr = precondition(R)
        rz = np.einsum("bnk,bnk->bk", R, Zr)
        stop = _CG_RTOL**2 * rz
        P = Zr.copy()
        done = rz <= stop
        for _ in range(_CG_MAXIT):
            if done.all():
                break
            AP = apply(P)
            pap = np.einsum("bnk,bnk->bk", P, AP)
            alpha = np.divide(rz, pap, out=np.zeros_like(rz), where=~done & (pap > 0))
            X += alpha[:, None, :] * P
            R -= alpha[:, None, :] * AP
            Zr = precondition(R)
            rz_new = np.einsum("bnk,bnk->bk", R, Zr)
            done |= rz_new <= stop
            beta = np.divide(rz_new, rz, out=np.zeros_like(rz), where=rz > 0)
            P = Zr + beta[:, None, :] * P
            rz = rz_new
        ok = done.all(axis=1) & np.all(np.isfinite(X), axis=(1, 2))
        return X, ok


def _plane_structure(structure: FluxBlock) -> FluxBlock:
    """The low-rank block without the pairs that involve the momentum constraint's normal.

    The first basis column is :math:`\\Delta v = a`, and in the anti-diagonal ``C`` it pairs
    only with the last column: their terms are :math:`a w^\\top + w a^\\top`, which change
    neither the Newton step constrained to :math:`a^\\top m = 0` nor the Hessian on that plane
    (the gamma = 2 block :math:`-a a^\\top` drops out entirely, see ``newton._direction``).
    """
    return FluxBlock("lowrank", basis=structure.basis[:, 1:-1], coef=structure.coef[1:-1, 1:-1])


def _solver(energy: EnergyOperator, momentum_plane: bool) -> Semiseparable3 | LowRankFlux | Certified:
    """The structured solver for this energy operator (cached with it: its grid is fixed)."""
    solvers = _CACHE.setdefault(energy, {})
    structure = energy.flux_structure()
    plane = momentum_plane and structure.kind == "lowrank" and structure.basis.shape[1] > 2
    solver = solvers.get(plane)
    if solver is None:
        if structure.kind == "lowrank":
            use = _plane_structure(structure) if plane else structure
            solver = LowRankFlux(use.basis, use.coef)
        elif getattr(energy, "gamma", None) == 3.0:
            solver = Semiseparable3(energy.grid)
        else:
            solver = Certified(energy.flux_block())
        solvers[plane] = solver
    return solver


def semiseparable3(energy: EnergyOperator, scale: float) -> Semiseparable3 | None:
    """The exact gamma = 3 solve :func:`dense_kernel_direction` takes for ``energy`` at ``scale`` (the one it
    caches with the operator), or None where it takes another path (another kernel, fewer than 3 fluxes, a
    low-rank block, ``scale <= 0``, the ``dense`` linear algebra)."""
    if getattr(energy, "gamma", None) != 3.0 or energy.grid.n - 1 < 3 or scale <= 0 or linalg_mode() != "auto":
        return None
    if energy.flux_structure().kind == "lowrank":
        return None
    return _solver(energy, False)  # the momentum plane changes only a low-rank block's solver


def dense_kernel_direction(
    energy: EnergyOperator, scale: float, bands: tuple, rhs: NDArray, pd_tol: float, momentum_plane: bool = False
) -> tuple[NDArray, NDArray[np.bool_]]:
    """``H_s^-1 rhs`` and per-slice positive definiteness of ``H_s`` for a dense energy block.

    ``H = add_pentadiagonal(scale * E, *bands)``, ``H_s = H + pd_tol diag(H)``, with ``E =
    energy.flux_block()``; ``rhs`` has shape ``(B, N-1, k)``.  Same contract as
    ``newton._newton_direction(H, rhs)``: where ``pd`` is False the returned rows are not a
    solution.  ``pd`` is decided exactly (a certificate or a factorisation; see the
    module docstring), whatever the path.  ``momentum_plane``: the caller projects onto
    :math:`\\Delta v^\\top m = 0`, so a low-rank block may drop its terms along that normal
    (:func:`_plane_structure`; ``E`` is then that block, on the dense fallback too).
    """
    lowrank = energy.flux_structure().kind == "lowrank"
    solver = _solver(energy, momentum_plane) if lowrank else None
    e_dense = solver.dense() if lowrank else energy.flux_block()
    exact = lowrank or (getattr(energy, "gamma", None) == 3.0 and e_dense.shape[0] >= 3)
    if linalg_mode() == "dense" or scale <= 0 or not (exact or e_dense.shape[0] >= _CG_MIN_N):
        return dense_direction(e_dense, scale, bands, rhs, pd_tol)
    solver = solver or _solver(energy, momentum_plane)
    B = rhs.shape[0]
    x = np.zeros(rhs.shape)
    pd = np.zeros(B, dtype=bool)
    decided = np.zeros(B, dtype=bool)

    def work(a: int, b: int) -> None:
        solver.solve(scale, bands, rhs, pd_tol, (x, pd, decided), a, b)

    map_chunks(work, B, align=solver.CHUNK)
    if not decided.all():
        xd, pdd = dense_direction(e_dense, scale, bands, rhs, pd_tol, rows=~decided)
        x[~decided], pd[~decided] = xd[~decided], pdd[~decided]
    return x, pd
