"""The Newton iteration of one collision step as compiled code (numba): gamma = 1 and gamma = 3.

:func:`iterate` runs the undamped attempt of :mod:`jko_cvx.collision.newton` on one slice, and
:func:`iterate_rows` on the slices of a batch in one compiled loop -- the same reduced gradient and
pentadiagonal reduced Hessian (:mod:`jko_cvx.collision.terms`, written out per edge), fraction to the
boundary and Armijo backtracking on :math:`J`, the same momentum-constrained direction -- with the
direction of the NumPy iteration's linear algebra:

* an energy block diagonal in the fluxes (:math:`\\gamma = 1`, :class:`~jko_cvx.kernels.FluxBlock`
  ``"diagonal"``): the banded factorisation of the reduced Hessian with ``diag (1 + pd_tol)`` (``L D L'``,
  whose pivots decide positive definiteness as the Cholesky factorisation's do); for W = |v| the products
  ``K f`` are two running sums (O(N), :func:`_matvec`);
* :math:`\\gamma = 3`: the exact O(N) solve of
  :class:`~jko_cvx.collision._structured.Semiseparable3` (:func:`_semiseparable3`: the Cholesky of the
  pentadiagonal part G as the first test, the interleaved quasi-definite core by Gaussian elimination with
  partial pivoting in band storage, :func:`_band_lu_solve`, as LAPACK's ``dgbsv``; Woodbury's 2 x 2
  capacitance for the solve and, by Haynsworth's inertia formula, positive definiteness).

It runs only the plain path: it stops at the first iterate whose Newton decrement reached ``tol`` (where
the NumPy iteration checks the KKT residual) and hands back everything else -- a Hessian that needs a
shift, a structured solve the NumPy path would give to the dense Cholesky, a run of short steps (a
possible jam at the vacuum boundary), a failed line search, a non-finite value, the iteration limit -- as
"not handled", after which the caller runs the NumPy iteration with its retry cascade from the start.
The returned point's KKT residual is :func:`kkt_residual`'s: the expressions of the residual every method
shares (:meth:`~jko_cvx.collision.problem.CollisionProblem.kkt_residual`) in loops, equal to it to rounding
(the tests compare the two); the caller certifies the point with the certificate every method shares.

The arithmetic follows the NumPy expressions term by term, so the iterates agree with the NumPy
iteration's to rounding (not bit for bit: sums, the factorisations and the products with K run in
another order, and quotients by the same number -- an edge's ``s = f_k + f_{k+1}``, a cell width, a
pivot -- are products with its reciprocal, one division where the expressions have several).  The
scratch arrays are allocated once per call (:func:`_scratch`) and reused for every row of a batch.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

try:
    from numba import njit
except ImportError as exc:  # an optional dependency: say how to get it
    raise ImportError(
        "the compiled Newton iteration (solve_newton(..., compiled=True)) needs numba: "
        'python -m pip install "jko_cvx[fast]"'
    ) from exc

__all__ = ["HANDLED", "constants", "iterate", "iterate_rows", "kkt_residual"]


def _jit(func: Callable) -> Callable:
    """``numba.njit`` with its on-disk cache (compiled once per machine, about 10 s), or without one.

    The cache lives in ``__pycache__`` beside this file, as Python's bytecode does, keyed by numba on this
    file's contents and the CPU; where no cache directory is writable every process compiles anew.
    """
    try:
        return njit(cache=True, nogil=True, error_model="numpy")(func)
    except RuntimeError:  # numba: "cannot cache function ...: no locator available"
        return njit(nogil=True, error_model="numpy")(func)


HANDLED = 0
"""``iterate``'s code for a point where the decrement reached ``tol`` and the Hessian is positive definite."""

_NOT_HANDLED = 1
_FISHER_CODES = {None: 0, "perspective": 1, "log": 2}
_F64 = np.dtype(np.float64)
_NO_POINTS = np.zeros(0)
_NO_POINTS.flags.writeable = False


@_jit
def _evaluate(
    f, m, hinv, w, c, fisher, kf, ecoef, ediag, g, diag, off1, off2, gfw, gff, gfe, gm, work
):  # pragma: no cover - compiled
    """Reduced gradient ``g`` and the bands of the reduced Hessian at ``(f, m)``, given ``kf = K f`` (``hinv = 1/h``;
    ``work``: six rows of n scratch values).

    Also the gradient's split by term in f (``gfw``, ``gff``, ``gfe``) and in m (``gm``, the Wasserstein
    term's), which the KKT residual scales by.
    """
    n = f.size
    e = n - 1
    for i in range(n):
        gfe[i] = 2 * ecoef * kf[i]
        gfw[i] = 0.0
        gff[i] = 0.0
    xx, yy, xy, hsm, hmm, d = work[0], work[1], work[2], work[3], work[4], work[5]  # (6, n): no allocations
    for k in range(e):
        x, y = f[k], f[k + 1]
        s = x + y
        si = 1.0 / s  # one division per edge: the quotients by s below are products with si
        u = m[k] * si
        w2 = 2 * w[k]
        g_m = w2 * u
        g_s = -w[k] * u * u
        h_ss = g_m * u * si
        hsm[k] = -2 * w[k] * u * si
        hmm[k] = w2 * si
        gm[k] = g_m
        gfw[k] += g_s
        gfw[k + 1] += g_s
        hx = hy = hxy = h_ss
        if fisher == 1:
            r = (y - x) * si
            r2 = 2 * r * r
            k16 = 16 * c[k] * (si * si * si)
            gff[k] += c[k] * (-4 * r - r2)
            gff[k + 1] += c[k] * (4 * r - r2)
            hx = h_ss + k16 * y * y
            hy = h_ss + k16 * x * x
            hxy = h_ss - k16 * x * y
        elif fisher == 2:
            L = math.log(y) - math.log(x)
            half = 0.5 * L * L
            q = c[k] * (s + L * (y - x))
            gff[k] += c[k] * (-L * s / x + half)
            gff[k + 1] += c[k] * (L * s / y + half)
            hx = h_ss + q / (x * x)
            hy = h_ss + q / (y * y)
            hxy = h_ss + c[k] * (-s + L * (x - y)) / (x * y)
        xx[k], yy[k], xy[k] = hx, hy, hxy
    d[:] = 0.0
    for k in range(e):
        d[k] += xx[k]
        d[k + 1] += yy[k]
    for k in range(e):
        a_k, b_k = -hinv[k], hinv[k + 1]
        gk0 = gfe[k] + gfw[k] + gff[k]
        gk1 = gfe[k + 1] + gfw[k + 1] + gff[k + 1]
        g[k] = gm[k] - (gk0 * hinv[k] - gk1 * hinv[k + 1])
        diag[k] = (
            hmm[k] + a_k * a_k * d[k] + 2 * a_k * b_k * xy[k] + b_k * b_k * d[k + 1] + 2 * (a_k + b_k) * hsm[k]
        ) + ediag[k]
        if k < e - 1:
            a_1 = -hinv[k + 1]
            b_1 = hinv[k + 2]
            off1[k] = a_k * a_1 * xy[k] + b_k * a_1 * d[k + 1] + b_k * b_1 * xy[k + 1] + b_k * hsm[k + 1] + a_1 * hsm[k]
        if k < e - 2:
            off2[k] = b_k * (-hinv[k + 2]) * xy[k + 1]


@_jit
def _cholesky(diag, off1, off2, pd_tol, l0, l1, l2, dd):  # pragma: no cover - compiled
    """Factor the pentadiagonal matrix with ``diag (1 + pd_tol)`` as ``L D L'`` (L unit lower, sub-diagonals ``l1``,
    ``l2``; ``l0`` holds ``1 / D``: no square roots on the pivots' chain); False where a pivot is not positive
    (not positive definite, as a Cholesky factorisation fails)."""
    e = diag.size
    for k in range(e):
        if not (diag[k] > 0 and math.isfinite(diag[k])):
            return False
    for k in range(e):  # dd: the pivots D (scratch)
        piv = diag[k] * (1 + pd_tol)
        o = off1[k] if k < e - 1 else 0.0
        if k >= 1:
            t = l1[k - 1] * dd[k - 1]
            piv -= l1[k - 1] * t
            if k < e - 1:
                o -= l2[k - 1] * t
        if k >= 2:
            piv -= l2[k - 2] * l2[k - 2] * dd[k - 2]
        if not (piv > 0 and math.isfinite(piv)):
            return False
        dd[k] = piv
        inv = 1.0 / piv
        l0[k] = inv
        if k < e - 1:
            l1[k] = o * inv
        if k < e - 2:
            l2[k] = off2[k] * inv
    return True


@_jit
def _solve(l0, l1, l2, rhs, out):  # pragma: no cover - compiled
    """``out = (L D L')^-1 rhs`` for the factor of :func:`_cholesky` (``l0 = 1 / D``)."""
    e = rhs.size
    for k in range(e):
        v = rhs[k]
        if k >= 1:
            v -= l1[k - 1] * out[k - 1]
        if k >= 2:
            v -= l2[k - 2] * out[k - 2]
        out[k] = v
    for k in range(e):  # a pass of its own: the forward recurrence reads the unscaled values
        out[k] *= l0[k]
    for k in range(e - 1, -1, -1):
        v = out[k]
        if k + 1 < e:
            v -= l1[k] * out[k + 1]
        if k + 2 < e:
            v -= l2[k] * out[k + 2]
        out[k] = v


@_jit
def _band_lu_solve(W, kl, R):  # pragma: no cover - compiled
    """Solve ``A X = R`` in place for a band matrix with ``kl`` sub- and super-diagonals, by Gaussian elimination
    with partial pivoting (LAPACK's ``dgbsv``): ``W[i, j - i + kl] = A[i, j]``, ``3 kl + 1`` columns (the upper
    ``kl`` for the fill that row interchanges bring), overwritten.  False where a pivot is zero or not finite."""
    n = W.shape[0]
    nr = R.shape[1]
    top = 2 * kl  # the upper bandwidth after fill
    for j in range(n):
        last = min(j + kl, n - 1)
        piv = j
        big = abs(W[j, kl])
        for r in range(j + 1, last + 1):
            v = abs(W[r, j - r + kl])
            if v > big:
                big, piv = v, r
        if not (big > 0 and math.isfinite(big)):
            return False
        if piv != j:
            for jj in range(j, min(j + top, n - 1) + 1):
                t = W[j, jj - j + kl]
                W[j, jj - j + kl] = W[piv, jj - piv + kl]
                W[piv, jj - piv + kl] = t
            for c in range(nr):
                t = R[j, c]
                R[j, c] = R[piv, c]
                R[piv, c] = t
        inv = 1.0 / W[j, kl]
        for r in range(j + 1, last + 1):
            lr = W[r, j - r + kl] * inv
            if lr != 0.0:
                for jj in range(j + 1, min(j + top, n - 1) + 1):
                    W[r, jj - r + kl] -= lr * W[j, jj - j + kl]
                for c in range(nr):
                    R[r, c] -= lr * R[j, c]
    for i in range(n - 1, -1, -1):
        for c in range(nr):
            v = R[i, c]
            for jj in range(i + 1, min(i + top, n - 1) + 1):
                v -= W[i, jj - i + kl] * R[jj, c]
            R[i, c] = v / W[i, kl]
    return True


@_jit
def _semiseparable3(
    d, off1, off2, pd_tol, scale, lap_diag, lap_off, u0, u1, q00, rhs, k, x, l0, l1, l2, dd, W, R, sc
):  # pragma: no cover - compiled
    """``x = H_s^-1 rhs`` (the first ``k`` columns) for gamma = 3 (``_structured.Semiseparable3``, one slice), and
    whether ``H_s`` is positive definite; False also where the NumPy path would not decide it here (the dense
    path's cases: G not positive definite, a failed band solve).

    ``d``: the diagonal of H (bands and ``scale`` times the energy block's diagonal); the core
    ``[[G, diag(dv)], [diag(dv), -L_D / (4 scale)]]`` interleaved, scaled by ``|diagonal|^-1/2``, solved with the
    columns of ``V = [u0, u1]``; Woodbury's 2 x 2 capacitance ``S = -Q^-1 / (2 scale) + V' H_c^-1 V`` decides
    positive definiteness (``det S < 0``) and gives ``H_s^-1 rhs``."""
    e = d.size
    # G's factorisation only decides (it also refuses a diagonal that is not positive and finite), as in NumPy
    if not _cholesky(d, off1, off2, pd_tol, l0, l1, l2, dd):
        return False
    kl = 4
    zc = 1.0 / (4.0 * scale)
    for i in range(e):
        sc[2 * i] = abs(d[i] + pd_tol * d[i]) ** -0.5
        sc[2 * i + 1] = abs(-lap_diag[i] * zc) ** -0.5
    W[:, :] = 0.0
    R[:, :] = 0.0
    for i in range(e):
        X = 2 * i
        Z = X + 1
        W[X, kl] = (d[i] + pd_tol * d[i]) * sc[X] * sc[X]
        W[Z, kl] = (-lap_diag[i] * zc) * sc[Z] * sc[Z]
        W[X, Z - X + kl] = u0[i] * sc[X] * sc[Z]
        W[Z, X - Z + kl] = u0[i] * sc[X] * sc[Z]
        if i < e - 1:
            W[X, kl + 2] = off1[i] * sc[X] * sc[X + 2]
            W[X + 2, kl - 2] = off1[i] * sc[X] * sc[X + 2]
            W[Z, kl + 2] = (-lap_off[i] * zc) * sc[Z] * sc[Z + 2]
            W[Z + 2, kl - 2] = (-lap_off[i] * zc) * sc[Z] * sc[Z + 2]
        if i < e - 2:
            W[X, kl + 4] = off2[i] * sc[X] * sc[X + 4]
            W[X + 4, kl - 4] = off2[i] * sc[X] * sc[X + 4]
        for j in range(k):
            R[X, j] = rhs[i, j] * sc[X]
        R[X, k] = u0[i] * sc[X]
        R[X, k + 1] = u1[i] * sc[X]
    if not _band_lu_solve(W, kl, R):
        return False
    s00 = -q00 / (2.0 * scale)
    s01 = -1.0 / (2.0 * scale)
    s10 = s01
    s11 = 0.0
    for i in range(e):
        ya = R[2 * i, k] * sc[2 * i]
        yb = R[2 * i, k + 1] * sc[2 * i]
        s00 += u0[i] * ya
        s01 += u0[i] * yb
        s10 += u1[i] * ya
        s11 += u1[i] * yb
    det = s00 * s11 - s01 * s10
    if not (math.isfinite(det) and det < 0):
        return False
    for j in range(k):
        r0 = 0.0
        r1 = 0.0
        for i in range(e):
            y = R[2 * i, j] * sc[2 * i]
            r0 += u0[i] * y
            r1 += u1[i] * y
        t0 = (s11 * r0 - s01 * r1) / det
        t1 = (s00 * r1 - s10 * r0) / det
        for i in range(e):
            X = 2 * i
            x[i, j] = R[X, j] * sc[X] - (R[X, k] * sc[X] * t0 + R[X, k + 1] * sc[X] * t1)
    for i in range(e):
        for j in range(k):
            if not math.isfinite(x[i, j]):
                return False
    return True


@_jit
def _density(fstar, m, hinv, out):  # pragma: no cover - compiled
    """``f = f* - D m / h`` (zero end fluxes; ``hinv = 1/h``)."""
    n = fstar.size
    for j in range(n):
        dm = (m[j] if j < n - 1 else 0.0) - (m[j - 1] if j >= 1 else 0.0)
        out[j] = fstar[j] - dm * hinv[j]


@_jit
def _matvec(K, v, f, out):  # pragma: no cover - compiled
    """``out = K f``.  With the points ``v`` (W = |v|: K_il = |v_i - v_l| h_i h_l, ``K`` the row ``h``) in O(N)
    by two running sums, ``S_i = S_{i-1} + (v_i - v_{i-1}) sum_{l<i} h_l f_l`` and its mirror: sums of terms of
    one sign, so no cancellation; without points (``v.size == 0``) the dense product."""
    if v.size == 0:
        out[:] = np.dot(K, f)
        return
    h = K[0]
    n = f.size
    mass = 0.0
    left = 0.0
    for i in range(n):
        if i > 0:
            left += (v[i] - v[i - 1]) * mass
        out[i] = left
        mass += h[i] * f[i]
    mass = 0.0
    right = 0.0
    for i in range(n - 1, -1, -1):
        if i < n - 1:
            right += (v[i + 1] - v[i]) * mass
        out[i] = h[i] * (out[i] + right)
        mass += h[i] * f[i]


@_jit
def _objective(f, m, w, c, fisher, K, kv, ecoef, kf):  # pragma: no cover - compiled
    """:math:`J(f, m)` at interior points; ``kf = K f`` is written on the way."""
    n = f.size
    val = 0.0
    for k in range(n - 1):
        x, y = f[k], f[k + 1]
        s = x + y
        si = 1.0 / s
        val += w[k] * (m[k] * m[k] * si)
        if fisher == 1:
            dd = y - x
            val += c[k] * (2 * dd * dd * si)
        elif fisher == 2:
            L = math.log(y) - math.log(x)
            val += c[k] * (0.5 * L * L * s)
    _matvec(K, kv, f, kf)
    quad = 0.0
    for i in range(n):
        quad += f[i] * kf[i]
    return val + ecoef * quad


@_jit
def _explicit_start(
    fstar, h, hinv, w, c, fisher, K, kv, ecoef, a, conserve, m, f, kf, ws
):  # pragma: no cover - compiled
    """The damped explicit step from ``(f*, 0)`` where it lowers J, else 0 (``newton._explicit_start``).

    The first step of the paper's SQP (:func:`jko_cvx.collision.sqp.explicit_step`: the tridiagonal
    system of the diagonal Hessian at ``m = 0``, where the Wasserstein gradient and its (s, s) and
    (s, m) curvatures vanish), damped to keep ``f >= f*/2`` and projected onto the momentum plane.
    Writes ``m``, ``f`` and ``kf = K f``; returns J there.  ``ws``: ``_START_ROWS`` rows of n scratch values.
    """
    n = fstar.size
    e = n - 1
    kf0, m0, gf, hf = ws[0], ws[1, :e], ws[2], ws[3]
    dg, rhs, cp, pm = ws[4, :e], ws[5, :e], ws[6, :e], ws[7, :e]
    m0[:] = 0.0
    hf[:] = 0.0
    phi0 = _objective(fstar, m0, w, c, fisher, K, kv, ecoef, kf0)
    for i in range(n):
        gf[i] = 2 * ecoef * kf0[i]
    for k in range(e):
        x, y = fstar[k], fstar[k + 1]
        s = x + y
        if fisher == 1:
            si = 1.0 / s
            r = (y - x) * si
            r2 = 2 * r * r
            k16 = 16 * c[k] * (si * si * si)
            gf[k] += c[k] * (-4 * r - r2)
            gf[k + 1] += c[k] * (4 * r - r2)
            hf[k] += k16 * y * y
            hf[k + 1] += k16 * x * x
        elif fisher == 2:
            L = math.log(y) - math.log(x)
            half = 0.5 * L * L
            q = c[k] * (s + L * (y - x))
            gf[k] += c[k] * (-L * s / x + half)
            gf[k + 1] += c[k] * (L * s / y + half)
            hf[k] += q / (x * x)
            hf[k + 1] += q / (y * y)
    # (A + diag(hm)) pm = D'(gf / h), A = D' diag(hf / h^2) D: Thomas' algorithm (positive definite)
    # with 1/h and one reciprocal of the pivot per row: divisions are most of this loop's cost
    for j in range(n):
        hf[j] *= hinv[j] * hinv[j]  # hf / h^2 from here on
    for k in range(e):
        dg[k] = hf[k] + hf[k + 1] + 2 * w[k] / (fstar[k] + fstar[k + 1])
        rhs[k] = gf[k] * hinv[k] - gf[k + 1] * hinv[k + 1]
    piv = dg[0]
    for k in range(e):
        off = -hf[k]  # the entry (k, k-1): -a_k
        if k > 0:
            piv = dg[k] - off * cp[k - 1]
        pinv = 1.0 / piv
        pm[k] = (rhs[k] - off * pm[k - 1]) * pinv if k > 0 else rhs[k] * pinv
        if k < e - 1:
            cp[k] = -hf[k + 1] * pinv
    for k in range(e - 2, -1, -1):
        pm[k] -= cp[k] * pm[k + 1]
    ratio = np.inf
    for j in range(n):
        dm = (pm[j] if j < e else 0.0) - (pm[j - 1] if j >= 1 else 0.0)
        pf = -dm * hinv[j]
        if pf < 0:
            ratio = min(ratio, -fstar[j] / pf)
    alpha = min(1.0, 0.5 * ratio)
    for k in range(e):
        m[k] = alpha * pm[k]
    if conserve:
        ma = 0.0
        aa = 0.0
        for k in range(e):
            ma += m[k] * a[k]
            aa += a[k] * a[k]
        for k in range(e):
            m[k] = m[k] - (ma / aa) * a[k]
    _density(fstar, m, hinv, f)
    ok = True
    for k in range(e):
        if not math.isfinite(m[k]):
            ok = False
    for j in range(n):
        if not f[j] > 0:
            ok = False
    if ok:
        phic = _objective(f, m, w, c, fisher, K, kv, ecoef, kf)
        if phic < phi0:
            return phic
    m[:] = 0.0
    f[:] = fstar
    kf[:] = kf0
    return phi0


_START_ROWS = 8
"""Scratch rows of n values that :func:`_explicit_start` takes."""
_KKT_ROWS = 15
"""Scratch rows of n values that :func:`_kkt` takes."""
_ITERATE_ROWS = 26
"""Scratch rows of n values that :func:`_iterate` takes for itself (its callees' follow)."""
_SCRATCH_ROWS = _ITERATE_ROWS + _START_ROWS + _KKT_ROWS


@_jit
def _scratch(n, ss):  # pragma: no cover - compiled
    """The scratch arrays of :func:`_iterate` on slices of n points: ``(ws, cols, W, R, sc)``, allocated once per
    call of :func:`iterate` or :func:`iterate_rows` and reused for each row (every value is written before it is
    read)."""
    e = n - 1
    k = 2 * e if ss else 0
    return np.empty((_SCRATCH_ROWS, n)), np.empty((2, e, 2)), np.empty((k, 13)), np.empty((k, 4)), np.empty(k)


@_jit
def _iterate(
    fstar, m, f, phi, start, h, v, w, c, fisher, K, kv, ecoef, ediag, a, conserve, tol, max_iter, pd_tol, jam,
    jam_step, ss, ss_lap_diag, ss_lap_off, ss_u0, ss_u1, ss_q00, ws, cols, W, R, sc,
):  # pragma: no cover - compiled
    """The undamped Newton attempt (``newton._iterate`` for one slice), see :func:`iterate`; writes the point into
    ``m`` and ``f`` (the caller's) and returns ``(phi, iterations, code, kkt)``.  ``ws, cols, W, R, sc``:
    :func:`_scratch`."""
    n = fstar.size
    e = n - 1
    kf, hinv, g, diag = ws[0], ws[1], ws[2, :e], ws[3, :e]
    off1, off2, gfw, gff, gfe, gm = ws[4, : max(e - 1, 0)], ws[5, : max(e - 2, 0)], ws[6], ws[7], ws[8], ws[9, :e]
    l0, l1, l2, p, q = ws[10, :e], ws[11, : max(e - 1, 0)], ws[12, : max(e - 2, 0)], ws[13, :e], ws[14, :e]
    minus_g, trial, ft, kft, dd = ws[15, :e], ws[16, :e], ws[17], ws[18], ws[19, :e]
    work = ws[20:26]  # (6, n)
    start_ws = ws[_ITERATE_ROWS : _ITERATE_ROWS + _START_ROWS]
    kkt_ws = ws[_ITERATE_ROWS + _START_ROWS :]
    rhs, xs = cols[0], cols[1]
    for i in range(n):
        hinv[i] = 1.0 / h[i]
    if start == 1:
        phi = _explicit_start(fstar, h, hinv, w, c, fisher, K, kv, ecoef, a, conserve, m, f, kf, start_ws)
    elif start == 2:
        _density(fstar, m, hinv, f)
        phi = _objective(f, m, w, c, fisher, K, kv, ecoef, kf)
    else:  # the caller's point, with J there
        _density(fstar, m, hinv, f)
        _matvec(K, kv, f, kf)
    near = False
    iterations = 0
    flat = 0
    code = _NOT_HANDLED
    ncol = 2 if conserve else 1
    for it in range(max_iter + 1):
        _evaluate(f, m, hinv, w, c, fisher, kf, ecoef, ediag, g, diag, off1, off2, gfw, gff, gfe, gm, work)
        if ss:  # gamma = 3: the structured solve decides positive definiteness and gives both columns
            for k in range(e):
                rhs[k, 0] = -g[k]
                rhs[k, 1] = a[k]
            pd = _semiseparable3(
                diag, off1, off2, pd_tol, 2 * ecoef, ss_lap_diag, ss_lap_off, ss_u0, ss_u1, ss_q00, rhs, ncol, xs,
                l0, l1, l2, dd, W, R, sc,
            )
        else:
            pd = _cholesky(diag, off1, off2, pd_tol, l0, l1, l2, dd)
        if near:
            code = HANDLED if pd else _NOT_HANDLED
            break
        if not pd or it == max_iter:
            break
        if ss:
            for k in range(e):
                p[k] = xs[k, 0]
                q[k] = xs[k, 1]
        else:
            for k in range(e):
                minus_g[k] = -g[k]
            _solve(l0, l1, l2, minus_g, p)
            if conserve:
                _solve(l0, l1, l2, a, q)
        if conserve:
            aw = 0.0
            pa = 0.0
            for k in range(e):
                aw += q[k] * a[k]
                pa += p[k] * a[k]
            if aw > 0:
                r = pa / aw
                for k in range(e):
                    p[k] = p[k] - q[k] * r
        slope = 0.0
        finite = True
        for k in range(e):
            finite = finite and math.isfinite(p[k])
            slope += g[k] * p[k]
        if not finite:
            break
        ratio = np.inf  # fraction to the boundary along the f-components -D p / h
        for j in range(n):
            dp = (p[j] if j < e else 0.0) - (p[j - 1] if j >= 1 else 0.0)
            pf = -dp * hinv[j]
            if pf < 0:
                ratio = min(ratio, -f[j] / pf)
        alpha = min(1.0, 0.995 * ratio)
        dec = -slope / max(abs(phi), 2.2250738585072014e-308)
        near = dec <= max(tol, 1e-13)
        accepted = dec <= 1e-12  # below J's rounding: the full, boundary-safe step (as the NumPy line search)
        if accepted:
            for k in range(e):
                m[k] = m[k] + alpha * p[k]
            _density(fstar, m, hinv, f)
            phi = _objective(f, m, w, c, fisher, K, kv, ecoef, kf)
        else:
            for _ in range(60):
                for k in range(e):
                    trial[k] = m[k] + alpha * p[k]
                _density(fstar, trial, hinv, ft)
                inside = True
                for j in range(n):
                    if not ft[j] > 0:
                        inside = False
                        break
                if inside:
                    phit = _objective(ft, trial, w, c, fisher, K, kv, ecoef, kft)
                    if phit <= phi + 1e-4 * alpha * slope:
                        accepted = True
                        m[:] = trial
                        f[:] = ft
                        kf[:] = kft
                        phi = phit
                        break
                alpha = 0.5 * alpha
            if not accepted:
                break
        iterations += 1
        # a run of short steps while the model promises a decrease: a jam, which the cascade handles
        flat = flat + 1 if (alpha < jam_step and dec > 1e-12) else 0
        if flat >= jam:
            break
    kkt = np.nan
    if code == HANDLED:  # the point's KKT residual, from the gradient's split evaluated there
        stat, feas, pos, _ = _kkt(f, m, fstar, h, v, a, gfw, gff, gfe, gm, conserve, kkt_ws)
        kkt = max(stat, max(feas, pos))
    return phi, iterations, code, kkt


@_jit
def _tridiagonal_spd(diag, off, rhs, out, d, lo, c):  # pragma: no cover - compiled
    """``T x = rhs``, T symmetric tridiagonal (``diag``, ``off``): LDL' as LAPACK's ``dptsv``, Thomas' algorithm
    without pivoting where a pivot is not positive (as ``_linalg.solve_sym_tridiagonal``); ``d``, ``lo``, ``c``:
    scratch of n values."""
    n = diag.size
    spd = True
    d[0] = diag[0]
    for i in range(n - 1):
        if not d[i] > 0:
            spd = False
            break
        lo[i] = off[i] / d[i]
        d[i + 1] = diag[i + 1] - lo[i] * off[i]
    if spd and not d[n - 1] > 0:
        spd = False
    if spd:
        out[0] = rhs[0]
        for i in range(1, n):
            out[i] = rhs[i] - lo[i - 1] * out[i - 1]
        out[n - 1] = out[n - 1] / d[n - 1]
        for i in range(n - 2, -1, -1):
            out[i] = out[i] / d[i] - lo[i] * out[i + 1]
        return
    piv = diag[0]  # Thomas
    out[0] = rhs[0] / piv
    for i in range(1, n):
        c[i - 1] = off[i - 1] / piv
        piv = diag[i] - off[i - 1] * c[i - 1]
        out[i] = (rhs[i] - off[i - 1] * out[i - 1]) / piv
    for i in range(n - 2, -1, -1):
        out[i] -= c[i] * out[i + 1]


@_jit
def _kkt(f, m, fstar, h, v, dv, gfw, gff, gfe, gm, conserve, ws):  # pragma: no cover - compiled
    """:meth:`CollisionProblem.kkt_residual <jko_cvx.collision.problem.CollisionProblem.kkt_residual>` of one
    slice, term by term: ``(stationarity, feasibility, positivity)`` and the multiplier (see :func:`kkt_residual`);
    ``ws``: ``_KKT_ROWS`` rows of n scratch values (the multiplier is one of them)."""
    n = f.size
    e = n - 1
    w, a, om, gmw, o2, off, diag, rhs = ws[0], ws[1], ws[2, :e], ws[3, :e], ws[4, :e], ws[5, :e], ws[6], ws[7]
    phi, rf, rm, z, td_d, td_lo, td_c = ws[8], ws[9], ws[10, :e], ws[11], ws[12], ws[13, : max(n - 1, 0)], ws[14]
    fmax = 0.0
    for j in range(n):
        fmax = max(fmax, max(f[j], 0.0))
    if not fmax > 0:
        fmax = 1.0
    for j in range(n):
        w[j] = max(f[j], 0.0) / fmax
        a[j] = (gfw[j] + gff[j] + gfe[j]) / h[j] if w[j] > 0 else 0.0
    for k in range(e):
        om[k] = (max(f[k], 0.0) + max(f[k + 1], 0.0)) / (2 * fmax)
        gmw[k] = gm[k] if om[k] > 0 else 0.0
        o2[k] = om[k] * om[k]
        off[k] = -o2[k]
    for j in range(n):
        diag[j] = w[j] * w[j] + (o2[j] if j < e else 0.0) + (o2[j - 1] if j > 0 else 0.0)
    eps = 0.0
    for j in range(n):
        eps = max(eps, diag[j])
    eps = 1e-30 * eps
    for j in range(n):
        diag[j] += eps
        div = (o2[j] * gmw[j] if j < e else 0.0) - (o2[j - 1] * gmw[j - 1] if j > 0 else 0.0)
        rhs[j] = -(w[j] * w[j]) * a[j] - div - eps * a[j]
    _tridiagonal_spd(diag, off, rhs, phi, td_d, td_lo, td_c)
    for j in range(n):
        rf[j] = a[j] + phi[j]
    for k in range(e):
        rm[k] = gmw[k] + (phi[k] - phi[k + 1])
    if conserve:
        for j in range(n):
            rhs[j] = (o2[j] * dv[j] if j < e else 0.0) - (o2[j - 1] * dv[j - 1] if j > 0 else 0.0)
        _tridiagonal_spd(diag, off, rhs, z, td_d, td_lo, td_c)
        den = 0.0
        num = 0.0
        for j in range(n):
            den += w[j] * w[j] * z[j] * z[j]
            num -= w[j] * w[j] * rf[j] * z[j]
        for k in range(e):
            zm = dv[k] - (z[k] - z[k + 1])
            den += o2[k] * zm * zm
            num += o2[k] * rm[k] * zm
        u = -num / den if den > 0 else 0.0
        for j in range(n):
            phi[j] -= u * z[j]
            rf[j] -= u * z[j]
        for k in range(e):
            rm[k] += u * (dv[k] - (z[k] - z[k + 1]))
    stat = 0.0
    scale = 0.0
    for j in range(n):
        stat = max(stat, w[j] * abs(rf[j]))
        if w[j] > 0:
            scale = max(scale, w[j] * ((abs(gfw[j]) + abs(gff[j]) + abs(gfe[j])) / h[j]))
    for k in range(e):
        stat = max(stat, om[k] * abs(rm[k]))
        scale = max(scale, om[k] * abs(gmw[k]))
    if not scale > 0:
        scale = 2.2250738585072014e-308
    stationarity = stat / scale
    if not math.isfinite(stationarity):
        stationarity = np.inf
    res = 0.0
    mass = 0.0
    fmin = np.inf
    for j in range(n):
        div = (m[j] if j < e else 0.0) - (m[j - 1] if j > 0 else 0.0)
        res += abs(h[j] * (f[j] - fstar[j]) + div)
        mass += fstar[j] * h[j]
        fmin = min(fmin, f[j])
    feasibility = res / mass
    if conserve:
        num = 0.0
        den = 0.0
        for j in range(n):
            num += (f[j] - fstar[j]) * (v[j] * h[j])
            den += fstar[j] * (abs(v[j]) * h[j])
        feasibility = max(feasibility, abs(num) / max(den, 2.2250738585072014e-308))
    positivity = max(0.0, -fmin) / fmax
    return stationarity, feasibility, positivity, phi


def kkt_residual(
    f: NDArray, m: NDArray, f_star: NDArray, h: NDArray, v: NDArray, dv: NDArray, parts: tuple, conserve: bool
) -> tuple[float, float, float, NDArray]:
    """The shared KKT residual of one slice at a finite point, as compiled code.

    The same expressions as :meth:`~jko_cvx.collision.problem.CollisionProblem.kkt_residual` (the
    weighted least-squares multiplier, the momentum multiplier, the scaled stationarity, feasibility and
    positivity), in loops: equal to rounding (sums and the tridiagonal solves run in another order; the
    tests compare the two on random points of every Fisher form).  ``parts``: the gradient's split
    ``(Wasserstein in f, Fisher in f, energy in f, Wasserstein in m)`` at the point (as
    :meth:`~jko_cvx.collision.problem.CollisionProblem.gradient_parts` gives it, or the compiled
    iteration's).  Returns ``(stationarity, feasibility, positivity, multiplier)``.
    """
    s, fe, po, phi = _kkt(
        _read_only(f), _read_only(m), _read_only(f_star), _read_only(h), _read_only(v), _read_only(dv),
        *(_read_only(x) for x in parts), bool(conserve), np.empty((_KKT_ROWS, np.size(f))),
    )  # fmt: skip
    return float(s), float(fe), float(po), phi.copy()


@_jit
def _iterate_rows(
    fstar, m, f, phi, its, code, kkt, start, rows, h, v, w, c, fisher, K, kv, ecoef, ediag, a, conserve, tol,
    max_iter, pd_tol, jam, jam_step, checks, ss, ss_lap_diag, ss_lap_off, ss_u0, ss_u1, ss_q00,
):  # pragma: no cover - compiled
    """:func:`_iterate` on each row ``b`` with ``rows[b]``, from ``m[b]`` (J there ``phi[b]``; ``start`` as in
    :func:`_iterate`), continued from its point up to ``checks`` times while the KKT residual is above ``tol``.
    Writes each row's point, J, iterations, code and residual into ``m``, ``f``, ``phi``, ``its``, ``code`` and
    ``kkt`` (the caller's); rows not in ``rows`` get f = 0, no iterations, not handled, NaN."""
    B, n = fstar.shape
    ws, cols, W, R, sc = _scratch(n, ss)  # once for the rows
    for b in range(B):
        f[b, :] = 0.0
        its[b] = 0
        code[b] = _NOT_HANDLED
        kkt[b] = np.nan
        if not rows[b]:
            continue
        phi[b], its[b], code[b], kkt[b] = _iterate_checked(
            fstar[b], m[b], f[b], phi[b], start, h, v, w, c, fisher, K, kv, ecoef, ediag, a, conserve, tol, max_iter,
            pd_tol, jam, jam_step, checks, ss, ss_lap_diag, ss_lap_off, ss_u0, ss_u1, ss_q00, ws, cols, W, R, sc,
        )  # m[b], f[b]: written in place


@_jit
def _iterate_checked(
    fstar, m, f, phi, start, h, v, w, c, fisher, K, kv, ecoef, ediag, a, conserve, tol, max_iter, pd_tol, jam,
    jam_step, checks, ss, ss_lap_diag, ss_lap_off, ss_u0, ss_u1, ss_q00, ws, cols, W, R, sc,
):  # pragma: no cover - compiled
    """:func:`_iterate` from ``start``, continued from the point reached up to ``checks`` times in all while the
    KKT residual is above ``tol`` where the decrement reached it (the NumPy iteration's stall test is its own):
    ``(phi, iterations, code, kkt)``, the point written into ``m`` and ``f``."""
    total = 0
    code = _NOT_HANDLED
    kkt = np.nan
    for _ in range(checks):
        phi, it, code, kkt = _iterate(
            fstar, m, f, phi, start, h, v, w, c, fisher, K, kv, ecoef, ediag, a, conserve, tol, max_iter - total,
            pd_tol, jam, jam_step, ss, ss_lap_diag, ss_lap_off, ss_u0, ss_u1, ss_q00, ws, cols, W, R, sc,
        )
        total += it
        start = 0  # continued from the point reached
        if code != HANDLED or kkt <= tol:
            break
    return phi, total, code, kkt


@_jit
def _iterate_one(
    fstar, m, phi, start, h, v, w, c, fisher, K, kv, ecoef, ediag, a, conserve, tol, max_iter, pd_tol, jam, jam_step,
    checks, ss, ss_lap_diag, ss_lap_off, ss_u0, ss_u1, ss_q00,
):  # pragma: no cover - compiled
    """:func:`_iterate_checked` on one slice with its own scratch and point: ``(m, f, phi, iterations, code,
    kkt)``."""
    n = fstar.size
    f = np.empty(n)
    ws, cols, W, R, sc = _scratch(n, ss)
    phi, its, code, kkt = _iterate_checked(
        fstar, m, f, phi, start, h, v, w, c, fisher, K, kv, ecoef, ediag, a, conserve, tol, max_iter, pd_tol, jam,
        jam_step, checks, ss, ss_lap_diag, ss_lap_off, ss_u0, ss_u1, ss_q00, ws, cols, W, R, sc,
    )
    return m, f, phi, its, code, kkt


def constants(
    h: NDArray,
    points: NDArray,
    wass_coef: NDArray,
    fisher_coef: NDArray | None,
    fisher: str | None,
    K: NDArray,
    energy_coef: float,
    energy_diag: NDArray,
    momentum_normal: NDArray | None,
    abs_kernel: bool = False,
    semiseparable: object | None = None,
) -> tuple[tuple, tuple]:
    """A step's constants as :func:`iterate` and :func:`iterate_rows` take them (read-only float arrays).

    ``energy_diag``: the energy block's diagonal times ``2 dt sigma``; ``momentum_normal``: the constraint
    normal ``dv`` (or None).  ``abs_kernel``: W = |v| (``K_il = |v_i - v_l| h_i h_l``), whose products ``K f``
    are then two running sums, O(N) (``K`` is not read); otherwise the dense ``K``.  ``semiseparable``: gamma =
    3, the :class:`~jko_cvx.collision._structured.Semiseparable3` of the grid, whose structured solve (band LU
    with partial pivoting, Woodbury's 2 x 2 capacitance) then gives the directions and decides positive
    definiteness; None: a diagonal energy block, one banded factorisation.
    """
    e = h.size - 1
    c = np.zeros(e) if fisher_coef is None else fisher_coef
    a = np.zeros(e) if momentum_normal is None else momentum_normal
    K, kv = (h[None, :], points) if abs_kernel else (K, _NO_POINTS)
    problem = (
        _read_only(h), _read_only(points), _read_only(wass_coef), _read_only(c), _FISHER_CODES[fisher], _read_only(K),
        _read_only(kv), float(energy_coef), _read_only(energy_diag), _read_only(a), momentum_normal is not None,
    )  # fmt: skip
    if semiseparable is None:
        return problem, (False, _NO_POINTS, _NO_POINTS, _NO_POINTS, _NO_POINTS, 0.0)
    S = semiseparable
    structure = (True, _read_only(S.lap_diag), _read_only(np.r_[S.lap_off, 0.0]), _read_only(S.U[:, 0]),
                 _read_only(S.U[:, 1]), float(S.q_inv[0, 0]))  # fmt: skip
    return problem, structure


def iterate_rows(
    f_star: NDArray,
    m: NDArray,
    f: NDArray,
    phi: NDArray,
    its: NDArray,
    code: NDArray,
    kkt: NDArray,
    start: int,
    rows: NDArray,
    consts: tuple[tuple, tuple],
    tol: float,
    max_iter: int,
    pd_tol: float,
    jam: int,
    jam_step: float,
    checks: int,
) -> None:
    """:func:`iterate` on the rows ``rows`` of a batch ``f_star`` of shape ``(B, N)``, in one compiled loop,
    writing into the caller's arrays.

    ``m`` (``(B, N - 1)``), ``phi`` (``(B,)``): each row's start and J there (``start = 0``), or ignored with
    ``start`` 1 (the explicit step) or 2 (zero); overwritten with each row's final point and J.  ``f``
    (``(B, N)``), ``its``, ``code`` (int64) and ``kkt`` (``(B,)``) receive the densities, iterations, codes and
    residuals.  All six are C-contiguous and writeable (rows of the caller's arrays: a slice thread's rows).  A
    row whose residual is still above ``tol`` where its decrement reached ``tol`` is continued from its point, up
    to ``checks`` times (the stall test of the NumPy iteration is its own).  ``consts``: :func:`constants`.  A row
    is the caller's where ``code == HANDLED`` and ``kkt <= tol``.
    """
    problem, structure = consts
    _iterate_rows(
        _read_only(f_star), m, f, phi, its, code, kkt, int(start), np.ascontiguousarray(rows, dtype=np.bool_),
        *problem, float(tol), int(max_iter), float(pd_tol), int(jam), float(jam_step), int(checks), *structure,
    )  # fmt: skip


def iterate(
    f_star: NDArray,
    m: NDArray | None,
    phi: float,
    consts: tuple[tuple, tuple],
    explicit: bool,
    tol: float,
    max_iter: int,
    pd_tol: float,
    jam: int,
    jam_step: float,
    checks: int = 1,
) -> tuple[NDArray, NDArray, float, int, int, float]:
    """Newton iterations on one slice from ``m`` (where J is ``phi``), or, with ``m=None``, from the explicit
    step (``explicit``) or from 0; ``consts``: :func:`constants`.  Where the decrement reached ``tol`` at a point
    whose KKT residual is above ``tol``, the iteration goes on from that point, up to ``checks`` times in all.

    Returns ``(m, f, phi, iterations, code, kkt)``: ``code == HANDLED`` where the decrement reached
    ``tol`` at a point whose reduced Hessian is positive definite, anything else where the NumPy
    iteration must take over; ``kkt`` is the point's KKT residual (:func:`kkt_residual`, from the
    gradient's split evaluated there; NaN where not handled), which the caller compares with ``tol``.
    ``jam`` short steps (``alpha < jam_step``) in a row end the attempt.
    """
    problem, structure = consts
    e = f_star.size - 1
    start = 0 if m is not None else (1 if explicit else 2)
    m = np.zeros(e) if m is None else np.array(m, dtype=float)  # a copy: the iteration writes it
    m, f, phi, its, code, kkt = _iterate_one(
        _read_only(f_star), m, float(phi), start, *problem, float(tol), int(max_iter), float(pd_tol), int(jam),
        float(jam_step), int(checks), *structure,
    )  # fmt: skip
    return m, f, float(phi), int(its), int(code), float(kkt)


def _read_only(x: NDArray) -> NDArray:
    """A read-only C-contiguous float view (a copy only where needed): one numba signature for every caller.

    numba compiles (and caches) once per argument type, and a read-only array is another type than a
    writeable one; the problem's arrays come both ways (the energy matrix is read-only).
    """
    if type(x) is np.ndarray and x.dtype is _F64:
        flags = x.flags
        if flags.c_contiguous and not flags.writeable:
            return x  # already one (the grid's arrays, the energy matrix): no view to make
    v = np.ascontiguousarray(x, dtype=float).view()
    v.flags.writeable = False
    return v
