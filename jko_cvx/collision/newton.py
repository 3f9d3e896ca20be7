"""A second-order solver for the collision step: damped Newton on the reduced KKT system.

Every feasible point is :math:`f(m) = f^* - Dm/h`, so eliminating f turns the step into an
unconstrained problem in the N-1 fluxes, :math:`\\\\phi(m) = J(f(m), m)`, with domain
:math:`f(m) > 0`.  Its gradient and Hessian are the reduced ones,

.. math::

    \\\\nabla\\\\phi = \\\\nabla_m J + T^\\\\top \\\\nabla_f J, \\\\qquad
    \\\\nabla^2\\\\phi = Z^\\\\top \\\\nabla^2 J\\\\, Z = B(m) + 2\\\\Delta t\\\\,\\\\sigma\\\\, T^\\\\top K T,
    \\\\qquad T = -\\\\operatorname{diag}(1/h) D,\\\\ Z = \\\\begin{pmatrix} T \\\\\\\\ I \\\\end{pmatrix},

where the Wasserstein and Fisher terms give a pentadiagonal :math:`B(m)` (formed from its
bands) and the energy a constant dense block, formed once per problem.  Each iteration
costs one (N-1) x (N-1) Cholesky factorisation per slice (O(N) banded ones for gamma = 1
and 2).  Where the reduced Hessian is not positive definite (the energy is concave in
some directions) a diagonally shifted one gives the step (modified Newton).  The step is
damped by the fraction to the boundary (iterates stay strictly positive) and an Armijo
backtracking line search on :math:`\\\\phi` itself (the merit function: iterates are
exactly feasible).  A slice whose iterates jam at the vacuum boundary (a run of tiny
steps while the model still promises a decrease) is solved again with interior damping:
Levenberg-Marquardt in the relative metric of f (``info["interior_damping"]``); if that
does not converge either, a third time without either device, and the attempt with the
smaller KKT residual is returned (``info["jammed"]`` marks these slices).  The
solver terminates on the KKT residual of
:class:`~jko_cvx.collision.problem.CollisionProblem`, never on step length alone.

Statuses: ``CONVERGED`` (KKT residual within tolerance and the reduced Hessian positive
definite), ``NONCONVEX`` (the reduced Hessian is not positive definite at the final
point -- a stationary point that is not a minimiser -- or no shift gave a descent direction),
``MAX_ITERATIONS``, ``NUMERICAL_ERROR`` (non-finite values, or the line search
stalled with the residual above tolerance).
"""

from __future__ import annotations

import time
import weakref
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack

from ..kernels import FluxBlock
from ..threads import blas_limited  # h15
from .certify import certify
from .checks import check_bool, check_choice, check_int, check_unit
from .explicit import explicit_step
from .linalg import divergence, divergence_adjoint
from .problem import CollisionProblem, TermParts, add_pentadiagonal
from .result import CollisionResult, Status
from .structured import dense_kernel_direction  # h15

__all__ = ["solve_newton"]

_FRACTION_TO_BOUNDARY = 0.995
_ARMIJO = 1e-4
# Interior damping (see _interior_damped): a damped step may lower no f_j below
# (1 - _KEEP) f_j.  Measured on sec:ibu to t = 1: 1230 Newton iterations at 0.99, 1413 at
# 0.9, 1782 undamped, and more with 0.5 (each step may then only halve a tail value).
_KEEP = 0.99
# Jam detection: _JAM consecutive accepted steps shorter than _JAM_STEP (while the Newton
# decrement still promises a decrease) end the undamped attempt, and solve_newton solves
# that slice again with interior damping (see _interior_damped).  The test also fires on
# slices that escape by themselves: gamma = 3, lambda = 10, 61 x 61 at t = 1 has five steps
# of 2e-4 to 1e-3 before converging in 33 iterations, while the damped attempt stalls at
# KKT 8e-4; such a slice is then solved a third time, undamped without jam detection.
# A true jam shrinks the step 200-fold per iteration (to 1e-14), so 1e-6 would also
# separate the two, but 1e-3 saves iterations: sec:ibu to t = 1 takes 1631 Newton
# iterations at 1e-3 and 1782 at 1e-6 (measured 2026-11-23).
_JAM = 5
_JAM_STEP = 1e-3
_MAX_BACKTRACKS = 60
# Tolerance of the positive-definiteness test on the Jacobi-scaled (unit-diagonal) reduced
# Hessian: smallest eigenvalue >= -_PD_TOL counts as convex (the factorised matrix is
# shifted by it, a relative perturbation of the Newton step of the same size).
_PD_TOL = 1e-10
# Consecutive residual checks without halving, with the Newton decrement at rounding level
# (<= 1e-14), after which the residual counts as stalled at its rounding floor (status
# NOT_CERTIFIED rather than iterating to max_iter).
_STALL_CHECKS = 3


_BAND_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _band_coefficients(grid) -> tuple:
    """Grid constants of the reduced-Hessian bands (T has columns a_k e_k + b_k e_{k+1}), cached per grid."""
    c = _BAND_CACHE.get(grid)
    if c is None:
        h = grid.h
        a, b = -1 / h[:-1], 1 / h[1:]
        c = (h, a, b, a * a, 2 * a * b, b * b, a[:-1] * a[1:], b[:-1] * a[1:], b[:-1] * b[1:], b[:-2] * a[2:])
        _BAND_CACHE[grid] = c
    return c


def _fused(
    problem: CollisionProblem, f: NDArray, m: NDArray, want_parts: bool = True
) -> tuple[NDArray, tuple, TermParts | None]:
    """Reduced gradient and the bands of the edge part of the reduced Hessian, in one pass.

    Same formulas as :meth:`CollisionProblem.gradient` and
    :meth:`CollisionProblem.reduced_hessian` (tests check they agree), computed once
    for the shared quantities :math:`s`, :math:`m/s` and the Fisher terms.
    """
    h, a, b, aa, ab2, bb, o1a, o1b, o1c, o2 = _band_coefficients(problem.grid)
    x, y = f[..., :-1], f[..., 1:]
    s = x + y
    w = problem.wass_coef
    u = m / s
    gm = 2 * w * u
    gs = -w * u * u
    hss = 2 * w * u * u / s
    hsm = -2 * w * u / s
    hmm = 2 * w / s
    gx = gs.copy()
    gy = gs.copy()
    xx, yy, xy = hss.copy(), hss.copy(), hss.copy()
    if problem.fisher is not None:
        c = problem.fisher_coef
        if problem.fisher == "perspective":
            r = (y - x) / s
            gx += c * (-4 * r - 2 * r * r)
            gy += c * (4 * r - 2 * r * r)
            k = 16 * c / (s * s * s)
            xx += k * y * y
            yy += k * x * x
            xy -= k * x * y
        else:
            L = np.log(y) - np.log(x)
            gx += c * (-L * s / x + 0.5 * L * L)
            gy += c * (L * s / y + 0.5 * L * L)
            q = c * (s + L * (y - x))
            xx += q / (x * x)
            yy += q / (y * y)
            xy += c * (-s + L * (x - y)) / (x * y)
    gfe = 2 * problem.energy_coef * problem.energy.matvec(f)
    gf = gfe.copy()
    gf[..., :-1] += gx
    gf[..., 1:] += gy
    g = gm - divergence_adjoint(gf / h)
    parts = None
    if want_parts:  # the per-term split, for the KKT residual's scale
        gfw = np.zeros_like(f)
        gfw[..., :-1] += gs
        gfw[..., 1:] += gs
        gff = gf - gfe - gfw
        zero = np.zeros_like(m)
        parts = TermParts((gfw, gm), (gff, zero), (gfe, zero))
    d = np.zeros_like(f)
    d[..., :-1] += xx
    d[..., 1:] += yy
    diag = hmm + aa * d[..., :-1] + ab2 * xy + bb * d[..., 1:] + 2 * (a + b) * hsm
    off1 = o1a * xy[..., :-1] + o1b * d[..., 1:-1] + o1c * xy[..., 1:] + b[:-1] * hsm[..., 1:] + a[1:] * hsm[..., :-1]
    off2 = o2 * xy[..., 1:-1]
    return g, (diag, off1, off2), parts


def _banded_cholesky(diag, off1, off2) -> tuple[NDArray | None, bool]:
    """LAPACK banded Cholesky of a symmetric pentadiagonal matrix, with the PD tolerance."""
    n1 = diag.shape[-1]
    ab = np.zeros((3, n1))
    ab[0] = diag * (1 + _PD_TOL)
    ab[1, :-1] = off1
    ab[2, :-2] = off2
    c, info = lapack.dpbtrf(ab, lower=1)
    return c, info == 0 and bool(np.isfinite(c[0, -1]))


def _structured_direction(fb: FluxBlock, scale: float, bands, rhs: NDArray) -> tuple[NDArray, NDArray[np.bool_]]:
    """``H^-1 rhs`` when the energy block is diagonal (gamma = 1) or rank one (gamma = 2).

    ``rhs`` has shape ``(B, N-1, k)``.  The reduced Hessian is then pentadiagonal, or
    pentadiagonal minus ``scale * u u'``: a banded Cholesky (O(N)) and, for the rank-one
    case, Sherman-Morrison.  By the matrix determinant lemma ``B - s u u'`` is positive
    definite iff ``B`` is and ``1 - s u' B^-1 u > 0``.
    """
    diag, off1, off2 = bands
    if fb.kind == "diagonal":
        diag = diag + scale * fb.diag
    x = np.zeros_like(rhs)
    pd = np.zeros(rhs.shape[0], dtype=bool)
    k = rhs.shape[-1]
    for i in range(rhs.shape[0]):
        if not (np.all(diag[i] > 0) and np.all(np.isfinite(diag[i]))):
            continue
        c, ok = _banded_cholesky(diag[i], off1[i], off2[i])
        if not ok:
            continue
        if fb.kind == "diagonal":
            x[i], _ = lapack.dpbtrs(c, rhs[i], lower=1)
            pd[i] = True
            continue
        y, _ = lapack.dpbtrs(c, np.concatenate([rhs[i], fb.u[:, None]], axis=1), lower=1)
        sigma = 1 - scale * (fb.u @ y[:, k])
        if sigma > _PD_TOL:
            x[i] = y[:, :k] + np.outer(y[:, k], scale * (fb.u @ y[:, :k]) / sigma)
            pd[i] = True
    return x, pd


def _finite_model(g: NDArray, bands) -> NDArray[np.bool_]:
    """Per slice: gradient and Hessian bands finite (False once an iterate reached f = 0)."""
    ok = np.all(np.isfinite(g), axis=-1)
    for band in bands:
        ok &= np.all(np.isfinite(band), axis=-1)
    return ok


def _second_order(
    problem: CollisionProblem, f: NDArray, m: NDArray, pd: NDArray[np.bool_], which: NDArray[np.bool_]
) -> NDArray[np.bool_]:
    """Second-order test at converged slices: ``pd`` (H itself positive definite) suffices.

    With ``conserve_momentum`` only the tangent space of ``a'm = 0`` counts, so where H is
    indefinite the slice is tested there (:meth:`CollisionProblem.is_local_minimiser`).
    """
    ok = pd.copy()
    if problem.conserve_momentum:
        for i in np.flatnonzero(which & ~pd):
            ok[i] = problem.with_f_star(problem.f_star[i]).is_local_minimiser(f[i], m[i])
    return ok


def _direction(problem: CollisionProblem, bands, g: NDArray) -> tuple[NDArray, NDArray[np.bool_], NDArray[np.bool_]]:
    """Newton direction ``-H^-1 g``, the per-slice positive-definiteness of H, and validity.

    With ``conserve_momentum`` the direction is the equality-constrained one: with
    ``a = dv`` (the constraint ``a'm = 0``), ``p = p0 - w (a'p0)/(a'w)``, ``p0 = -H^-1 g``,
    ``w = H^-1 a`` -- one more back-substitution with the same factorisation.

    Where H is not positive definite (the step problem is locally non-convex: the
    interaction energy is concave in some directions, more so for large dt * strength)
    the direction is taken with ``H + tau diag(H)``, tau = 1e-6, 1e-4, ..., 1e2, the first
    that factorises: a descent direction, so the iteration can still reach a local
    minimiser, which the final second-order test certifies (modified Newton).
    ``valid`` is False only where no shift helped.
    """
    fb = problem.energy.flux_structure()
    scale = 2 * problem.energy_coef
    cols = [-g]
    a = problem.grid.dv
    if problem.conserve_momentum and fb.kind == "rank1":
        # gamma = 2: the energy block -(dv)(dv)' lies along the constraint normal a = dv,
        # so it vanishes on the plane a'm = 0; the constrained direction is the same
        # without it, and the bands alone decide second-order definiteness there.  (With
        # it, H is indefinite wherever dt * strength is large although the constrained
        # problem is convex: the modified-Newton shifts then stall the iteration.)
        fb = FluxBlock("diagonal", diag=np.zeros_like(a))
    if problem.conserve_momentum:
        cols.append(np.broadcast_to(a, g.shape))
    rhs = np.stack(cols, axis=-1)
    H = None
    if fb.kind in ("diagonal", "rank1"):
        x, pd = _structured_direction(fb, scale, bands, rhs)
    else:
        # h15: dense kernels go through jko_cvx.collision.structured (exact O(N) solve for
        # gamma = 3, certified CG otherwise, the per-slice Cholesky as fallback; threaded).
        x, pd = dense_kernel_direction(problem.energy, scale, bands, rhs, _PD_TOL)
    valid = pd.copy()
    bad = np.flatnonzero(~pd)
    if bad.size:
        Hb = (
            H[bad]
            if H is not None
            else add_pentadiagonal(scale * problem.energy.flux_block(), *(b[bad] for b in bands))
        )
        d = np.einsum("...ii->...i", Hb)
        finite = np.all(np.isfinite(Hb), axis=(-2, -1)) & np.all(d > 0, axis=-1)
        todo = finite.copy()
        for tau in (1e-6, 1e-4, 1e-2, 1.0, 1e2):
            if not todo.any():
                break
            idx = np.flatnonzero(todo)
            Hs = Hb[idx].copy()
            Hs[:, np.arange(Hs.shape[-1]), np.arange(Hs.shape[-1])] += tau * d[idx]
            xs, ok = _newton_direction(Hs, rhs[bad[idx]])
            x[bad[idx[ok]]] = xs[ok]
            valid[bad[idx[ok]]] = True
            todo[idx[ok]] = False
    p = x[..., 0]
    if problem.conserve_momentum:
        w = x[..., 1]
        aw = w @ a
        p = p - w * np.divide(p @ a, aw, out=np.zeros_like(aw), where=aw > 0)[..., None]
    return p, pd, valid


def _interior_damped(
    problem: CollisionProblem, bands, g: NDArray, f: NDArray, p: NDArray, jammed: NDArray[np.bool_]
) -> tuple[NDArray, NDArray[np.float64]]:
    """Where the Newton step would leave the domain, damp it in the relative metric of f.

    A minimiser close to the vacuum boundary (a density tail of 1e-11 next to mass 1e-5)
    sits where the quadratic model is poor: the Newton step asks for more mass than the
    node holds, the fraction to the boundary cuts it to a 200-fold decrease, and the
    iterates jam geometrically at the boundary (measured: a Gaussian on [-3, 3] at
    N = 121, dt = 0.01, beta = 30 stuck at KKT 7.5e-3 with f = 5e-26).  Levenberg-Marquardt
    in the metric :math:`\\sum_j (\\delta f_j / f_j)^2` fixes the shape of the step, not
    only its length: the direction solves :math:`(H + \\mu T^\\top \\operatorname{diag}(f^{-2}) T) p = -g`
    (a tridiagonal addition to the bands), with :math:`\\mu` raised tenfold from
    :math:`10^{-2} |g^\\top p|` until the full step keeps every :math:`f_j` above
    :math:`f_j / 100`.  It is a descent direction for any :math:`\\mu \\ge 0`, and as the
    iterates settle the undamped step stays inside, so the local convergence stays Newton's.

    Returns the directions and the fraction-to-boundary step lengths, for a batch
    (arrays of shape ``(B, ...)``).
    """
    h = problem.grid.h
    _, _, _, aa, _, bb, _, o1b, _, _ = _band_coefficients(problem.grid)
    pf = -divergence(p) / h
    alpha = _boundary_step(f, pf)
    todo = jammed & (alpha < 1.0)
    mu = 1e-2 * np.abs(np.einsum("bi,bi->b", g, p))
    for _ in range(12):
        if not todo.any():
            break
        idx = np.flatnonzero(todo)
        c = mu[idx, None] / (f[idx] * f[idx])
        diag, off1, off2 = (band[idx] for band in bands)
        sub = (diag + aa * c[:, :-1] + bb * c[:, 1:], off1 + o1b * c[:, 1:-1], off2)
        q, _, valid = _direction(problem, sub, g[idx])  # uses the grid and the energy, not f*
        ok = valid & np.all(np.isfinite(q), axis=-1)
        qf = -divergence(q) / h
        inside = ok & np.all(qf >= -_KEEP * f[idx], axis=-1)
        p[idx[ok]] = q[ok]
        alpha[idx[ok]] = _boundary_step(f[idx[ok]], qf[ok])
        todo[idx[inside | ~ok]] = False
        mu[idx] *= 10.0
    return p, alpha


def _boundary_step(f: NDArray, pf: NDArray) -> NDArray[np.float64]:
    """Fraction-to-the-boundary step length along a direction with f-components ``pf``."""
    ratio = np.where(pf < 0, -f / np.where(pf < 0, pf, -1.0), np.inf)
    return np.minimum(1.0, _FRACTION_TO_BOUNDARY * ratio.min(axis=-1))


def _on_momentum_plane(problem: CollisionProblem, m: NDArray) -> NDArray:
    """Euclidean projection of fluxes onto ``sum_k m_k dv_k = 0`` (identity without the constraint)."""
    if not problem.conserve_momentum:
        return m
    a = problem.grid.dv
    return m - np.multiply.outer((m @ a) / (a @ a), a) if m.ndim > 1 else m - a * ((m @ a) / (a @ a))


def _objective_interior(problem: CollisionProblem, f: NDArray, m: NDArray) -> NDArray:
    """:math:`J(f, m)` for strictly positive f (line-search trial points), without domain guards."""
    x, y = f[..., :-1], f[..., 1:]
    s = x + y
    val = (m * m / s) @ problem.wass_coef
    if problem.fisher == "perspective":
        d = y - x
        val = val + (2 * d * d / s) @ problem.fisher_coef
    elif problem.fisher == "log":
        L = np.log(y) - np.log(x)
        val = val + (0.5 * L * L * s) @ problem.fisher_coef
    return val + problem.energy_coef * np.einsum("...i,...i->...", f, problem.energy.matvec(f))


def _newton_direction(H: NDArray, rhs: NDArray | None) -> tuple[NDArray | None, NDArray[np.bool_]]:
    """Solve ``H x = rhs`` slice by slice; flag slices whose H is not positive definite.

    ``rhs`` has shape ``(B, N-1, k)``.  With ``rhs=None`` only the positive-definiteness
    test (one Cholesky per slice) is done.  Cholesky's success does not depend on
    diagonal scaling, so the Jacobi-scaled test "H_s + tol I is PD" is run as
    "H + tol diag(H) is PD".  LAPACK (potrf/potrs) slice by slice: measured 2.6x faster
    than NumPy's batched Cholesky plus batched triangular solves at B = 121, N = 121
    (10 ms against 27 ms per direction on 2 cores), and 3.3x with two right-hand sides.
    """
    d = np.einsum("...ii->...i", H)
    ok = np.all(d > 0, axis=-1) & np.all(np.isfinite(d), axis=-1)
    x = None if rhs is None else np.zeros(rhs.shape)
    pd = ok.copy()
    n1 = H.shape[-1]
    for i in range(H.shape[0]):
        if not ok[i]:
            continue
        Hi = H[i].copy()
        Hi.flat[:: n1 + 1] += _PD_TOL * d[i]
        c, info = lapack.dpotrf(Hi, lower=1, clean=0, overwrite_a=1)
        if info != 0 or not np.isfinite(c[-1, -1]):
            pd[i] = False
        elif rhs is not None:
            x[i], _ = lapack.dpotrs(c, rhs[i], lower=1)
    return x, pd


@blas_limited  # h15: BLAS threads per jko_cvx.threads
def solve_newton(
    problem: CollisionProblem,
    *,
    tol: float = 1e-10,
    kkt_tol: float | None = None,
    max_iter: int = 100,
    m0: Any = None,
    start: str = "explicit",
    check_convexity: bool = True,
) -> CollisionResult:
    """Solve the collision step (or a batch of them) by damped Newton on the reduced KKT system.

    Parameters
    ----------
    problem : CollisionProblem
        Unbatched or batched; any Fisher form.  ``f_star`` must be strictly positive
        (the iterates are interior points); a step from data with exact zeros is
        reported ``NUMERICAL_ERROR`` without iterating.
    tol : float, default 1e-10
        This method's own stopping tolerance: iterate until the scaled KKT residual is at
        most ``tol`` (per slice), or until it stalls at its rounding floor.
    kkt_tol : float, optional
        Certification threshold (the same for every method,
        :func:`~jko_cvx.collision.certify.certify`): a slice that stopped is ``CONVERGED``
        only if its residual is at most ``kkt_tol``, else ``NOT_CERTIFIED``.  Default:
        ``tol`` -- Newton certifies what it was asked for (its iterations reach ``tol``
        quadratically, so a looser threshold would only relabel slices that stalled at
        their rounding floor above ``tol``).
    max_iter : int, default 100
        Newton iterations (status ``MAX_ITERATIONS`` beyond).
    m0 : array_like, optional
        Warm start: fluxes of shape ``(N-1,)`` or ``(B, N-1)`` (e.g. the previous
        solution's ``m``).  It is used only where it keeps ``f(m0) > 0``; otherwise the
        solver starts from ``m = 0``.  With ``conserve_momentum`` it is first projected
        onto the constraint :math:`\\sum_k m_k\\Delta v_k = 0`.
    start : {"explicit", "zero"}, default "explicit"
        Starting point without ``m0``: the explicit step (the first step of the paper's
        SQP, one tridiagonal solve; damped to keep f >= f*/2 and kept only if it lowers J;
        it saves one Newton iteration for moderate Fisher weights) or ``m = 0``.
    check_convexity : bool, default True
        Report ``NONCONVEX`` when the reduced Hessian at the final point is not positive
        definite (a stationary point that is not a minimiser).

    Returns
    -------
    CollisionResult
        One status per slice for a batched problem.  ``info`` holds ``warm_started``,
        ``jammed`` (the first, undamped attempt ended on a jam) and ``interior_damping``
        (the returned point comes from the interior-damped attempt); per slice when batched.
    """
    tol, kkt_tol, max_iter, m0 = _check_newton_args(problem, tol, kkt_tol, max_iter, m0, start, check_convexity)
    t0 = time.perf_counter()
    args = (tol, kkt_tol, max_iter, m0, start, check_convexity, t0)
    if not problem.batched:
        res = _solve_single(problem, *args, damping=False, jam_exit=True)
        res.info["interior_damping"] = False
        if res.status not in _RETRY or not np.all(problem.f_star > 0):
            return res
        again = _solve_single(problem, *args, damping=True, jam_exit=False)
        again.iterations += res.iterations
        again.info.update(interior_damping=True, jammed=res.info["jammed"])
        if not res.info["jammed"] or again.status is Status.CONVERGED:
            return again
        plain = _solve_single(problem, *args, damping=False, jam_exit=False)
        plain.iterations += again.iterations
        plain.info.update(interior_damping=False, jammed=True)
        return plain if plain.kkt_residual < again.kkt_residual else again
    res = _solve_batched(problem, *args, damping=False, jam_exit=True)
    jammed = res.info["jammed"]
    retry = np.array([st in _RETRY for st in res.status]) & np.all(problem.f_star > 0, axis=-1)
    res.info["interior_damping"] = np.zeros_like(retry)
    if retry.any():
        again = _solve_batched(
            problem.with_f_star(problem.f_star[retry]), *_subset(args, retry, res.m.shape), damping=True, jam_exit=False
        )
        _merge(res, retry, again, np.ones(int(retry.sum()), dtype=bool))
        res.info["interior_damping"][retry] = True
        fallback = retry & jammed
        fallback[fallback] = res.status[fallback] != Status.CONVERGED
        if fallback.any():
            plain = _solve_batched(
                problem.with_f_star(problem.f_star[fallback]),
                *_subset(args, fallback, res.m.shape),
                damping=False,
                jam_exit=False,
            )
            better = plain.kkt_residual < res.kkt_residual[fallback]
            _merge(res, fallback, plain, better)
            res.info["interior_damping"][np.flatnonzero(fallback)[better]] = False
    res.info["jammed"] = jammed
    res.seconds = time.perf_counter() - t0
    return res


# Statuses after which a slice is solved again with interior damping.
_RETRY = (Status.MAX_ITERATIONS, Status.NUMERICAL_ERROR)


def _subset(args: tuple, rows: NDArray[np.bool_], shape: tuple[int, int]) -> tuple:
    """The solver arguments ``(tol, kkt_tol, max_iter, m0, ...)`` restricted to the batch rows ``rows``."""
    tol, kkt_tol, max_iter, m0, *rest = args
    m0r = None if m0 is None else np.broadcast_to(np.asarray(m0, dtype=float), shape)[rows]
    return (tol, kkt_tol, max_iter, m0r, *rest)


def _merge(res: CollisionResult, rows: NDArray[np.bool_], again: CollisionResult, take: NDArray[np.bool_]) -> None:
    """Overwrite the batch rows ``rows`` of ``res`` with the rows ``take`` of a later attempt.

    Every attempt's iterations count, whether or not its point is kept.
    """
    idx = np.flatnonzero(rows)
    res.iterations[idx] += again.iterations
    for name in ("f", "m", "objective", "kkt_residual", "mass_error", "status"):
        getattr(res, name)[idx[take]] = getattr(again, name)[take]


def _solve_batched(
    P: CollisionProblem,
    tol: float,
    kkt_tol: float,
    max_iter: int,
    m0: Any,
    start: str,
    check_convexity: bool,
    t0: float,
    *,
    damping: bool,
    jam_exit: bool,
) -> CollisionResult:
    """The batched Newton loop of :func:`solve_newton`.

    ``damping`` turns interior damping on; ``jam_exit`` ends a slice whose iterates jam
    (``info["jammed"]``, status ``MAX_ITERATIONS``) so that it can be solved again.
    """
    F_star = P.f_star
    B, n = F_star.shape
    h = P.grid.h
    m = np.zeros((B, n - 1))
    warm = np.zeros(B, dtype=bool)
    if m0 is not None:
        M0 = _on_momentum_plane(P, np.broadcast_to(np.asarray(m0, dtype=float), (B, n - 1)))
        f0 = F_star - divergence(M0) / h
        warm = np.all(f0 > 0, axis=-1) & np.all(np.isfinite(M0), axis=-1)
        m[warm] = M0[warm]
    status = np.full(B, None, dtype=object)
    iters = np.zeros(B, dtype=int)
    positive = np.all(F_star > 0, axis=-1)
    status[~positive] = Status.NUMERICAL_ERROR
    if start == "explicit" and positive.any():
        with np.errstate(all="ignore"):
            m = _explicit_start(P, F_star, m, ~warm & positive)
    f = F_star - divergence(m) / h
    kkt_last = np.full(B, np.nan)
    # "near": the last Newton decrement -g.p/|phi| was small, so the KKT residual (the
    # stopping test) is worth its cost at the new point.
    near = np.zeros(B, dtype=bool)
    stall = np.zeros(B, dtype=int)
    second = np.zeros(B, dtype=bool)  # second-order test at the point where a slice stopped
    damped = np.full(B, damping)
    jammed = np.zeros(B, dtype=bool)
    flat = np.zeros(B, dtype=int)  # consecutive jammed iterations, per slice
    dec_last = np.full(B, np.inf)
    kkt_here = np.zeros(B, dtype=bool)  # kkt_last belongs to the current (f, m)
    active = status == None  # noqa: E711 (object array): slices still iterating
    with np.errstate(all="ignore"):
        phi = _objective_interior(P, f, m)
        for it in range(max_iter + 1):
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            sub = idx.size < B
            Pa = P.with_f_star(F_star[idx]) if sub else P
            fa, ma = (f[idx], m[idx]) if sub else (f, m)
            check = near[idx] | (it == max_iter)
            g, bands, parts = _fused(Pa, fa, ma, want_parts=bool(check.any()))
            p, pd, valid = _direction(Pa, bands, g)
            done = np.zeros(idx.size, dtype=bool)
            if check.any():
                kk = Pa.kkt_residual(fa, ma, parts).total
                prev = kkt_last[idx]
                kkt_last[idx[check]] = kk[check]
                kkt_here[idx[check]] = True
                done = check & (kk <= tol)
                worse = check & ~done & (prev == prev) & (kk > 0.5 * prev) & (dec_last[idx] <= 1e-14)
                stall[idx] = np.where(check, np.where(worse, stall[idx] + 1, 0), stall[idx])
                stalled = check & ~done & (stall[idx] >= _STALL_CHECKS)  # the residual's rounding floor
                # Stopped (converged, or stalled at the rounding floor): certify() judges the
                # point at the end.  pd is the (shifted) Cholesky of the reduced Hessian at
                # this very point: the second-order test comes for free.
                stop = done | stalled
                if stop.any():
                    second[idx[stop]] = _second_order(Pa, fa, ma, pd, stop)[stop]
                    status[idx[stop]] = Status.CONVERGED
                    active[idx[stop]] = False
            if it == max_iter:
                # Out of iterations where the Hessian still needed a shift: loss of convexity
                # is what stopped the solver (typically a minimiser on the vacuum boundary).
                status[idx[~done]] = [
                    Status.MAX_ITERATIONS if (ok or not check_convexity) else Status.NONCONVEX for ok in pd[~done]
                ]
                break
            if check.any():
                done = done | stalled
            go = ~done & valid & np.all(np.isfinite(p), axis=-1)
            if not go.all():
                # No descent direction even shifted: non-convexity where the Hessian is
                # finite; an iterate at the vacuum boundary (f underflowed, inf curvature)
                # is a numerical failure, which the interior-damped retry resolves.
                finite = _finite_model(g, bands)
                status[idx[~done & ~valid & finite]] = Status.NONCONVEX
                status[idx[~done & ~valid & ~finite]] = Status.NUMERICAL_ERROR
                status[idx[~done & valid & ~go]] = Status.NUMERICAL_ERROR
                active[idx[~go]] = False
            if not go.any():
                continue
            sel, g, p = idx[go], g[go], p[go]
            fa, ma = fa[go], ma[go]
            Pl = P.with_f_star(F_star[sel]) if sel.size < B else P
            p, alpha = _interior_damped(Pl, tuple(band[go] for band in bands), g, fa, p, damped[sel])
            phi0 = phi[sel]
            slope = np.einsum("bi,bi->b", g, p)
            dec = -slope / np.maximum(np.abs(phi0), np.finfo(float).tiny)
            dec_last[sel] = dec
            # Quadratic convergence: after a step with decrement dec the next decrement is
            # ~dec^2 and the residual far below dec, so the KKT residual is checked once dec
            # reaches tol (or the rounding level 1e-13, below which it cannot fall further).
            near[sel] = dec <= max(tol, 1e-13)
            # Where the predicted decrease is below the rounding of phi, Armijo cannot tell
            # (it would truncate the steps at random); the quadratic model is exact there,
            # so the full, boundary-safe Newton step is taken.
            accepted = dec <= 1e-12
            phi_new = phi0.copy()
            for _ in range(_MAX_BACKTRACKS):
                if accepted.all():
                    break
                trial = ma + alpha[:, None] * p
                ft = Pl.f_star - divergence(trial) / h
                phit = _objective_interior(Pl, ft, trial)
                ok = ~accepted & np.all(ft > 0, axis=-1) & (phit <= phi0 + _ARMIJO * alpha * slope)
                phi_new = np.where(ok, phit, phi_new)
                accepted |= ok
                alpha = np.where(accepted, alpha, 0.5 * alpha)
            if not accepted.all():
                status[sel[~accepted]] = Status.NUMERICAL_ERROR  # no decrease even along a tiny step
                active[sel[~accepted]] = False
            upd = sel[accepted]
            m[upd] = ma[accepted] + alpha[accepted, None] * p[accepted]
            f[upd] = F_star[upd] - divergence(m[upd]) / h
            full = dec[accepted] <= 1e-12
            phi[upd] = phi_new[accepted]
            if full.any():
                up = upd[full]
                Pu = P.with_f_star(F_star[up]) if up.size < B else P
                phi[up] = _objective_interior(Pu, f[up], m[up])
            iters[upd] += 1
            kkt_here[upd] = False
            if jam_exit:  # jam: tiny accepted steps where the model promises a decrease
                tiny_step = (alpha[accepted] < _JAM_STEP) & (dec[accepted] > 1e-12)
                flat[upd] = np.where(tiny_step, flat[upd] + 1, 0)
                jam = upd[flat[upd] >= _JAM]
                status[jam] = Status.MAX_ITERATIONS
                jammed[jam] = True
                active[jam] = False
        # Results: project (clip rounding, exact mass); re-evaluate the residual only where
        # the projection moved f beyond rounding or no residual was computed.
        # Iterates are feasible and positive by construction: return them as they are (the
        # reported residual is then that of the returned point); project only slices that
        # are not strictly positive (data with zeros, which never iterate).
        positive_rows = np.all(f > 0, axis=-1)
        f_out, m_out = f.copy(), m.copy()
        if not positive_rows.all():
            bad = ~positive_rows
            Pb = P.with_f_star(F_star[bad]) if bad.sum() < B else P
            f_out[bad], m_out[bad] = Pb.project_feasible(f[bad])
        kkt_all = kkt_last.copy()
        redo = ~positive_rows | ~kkt_here | ~np.isfinite(kkt_all)
        if redo.any():
            Pr = P.with_f_star(F_star[redo]) if redo.sum() < B else P
            kkt_all[redo] = Pr.kkt_residual(f_out[redo], m_out[redo]).total
        cert = certify(
            P,
            f_out,
            m_out,
            kkt_tol=kkt_tol,
            check_convexity=check_convexity,
            claimed=status,
            residual=kkt_all,
            second_order=second,
        )
    info = {"warm_started": warm, "jammed": jammed}
    return CollisionResult.from_certificate(P, f_out, m_out, cert, "newton", iters, time.perf_counter() - t0, info)


solve_newton.batched = True  # type: ignore[attr-defined]


def _explicit_start(P: CollisionProblem, F_star: NDArray, m: NDArray, use: NDArray[np.bool_] | bool) -> NDArray:
    """The damped explicit step (first SQP step) where ``use`` and where it lowers J, else ``m``.

    Works on one problem (1-D arrays) or a batch (2-D); the step is damped to keep
    ``f >= f*/2``.
    """
    zero = np.zeros_like(m)
    pf, pm = explicit_step(P)
    ratio = np.where(pf < 0, -F_star / np.where(pf < 0, pf, -1.0), np.inf).min(axis=-1)
    alpha = np.minimum(1.0, 0.5 * ratio)
    cand = _on_momentum_plane(P, np.asarray(alpha)[..., None] * pm)
    fc = F_star - divergence(cand) / P.grid.h
    better = (
        use
        & np.all(np.isfinite(cand), axis=-1)
        & np.all(fc > 0, axis=-1)
        & (_objective_interior(P, fc, cand) < _objective_interior(P, F_star, zero))
    )
    return np.where(np.asarray(better)[..., None], cand, m)


def _solve_single(
    P: CollisionProblem,
    tol: float,
    kkt_tol: float,
    max_iter: int,
    m0: Any,
    start: str,
    check_convexity: bool,
    t0: float,
    *,
    damping: bool,
    jam_exit: bool,
) -> CollisionResult:
    """The same algorithm as the batched loop of :func:`solve_newton`, on plain 1-D arrays.

    At N ~ 100 a Newton iteration costs tens of NumPy calls of ~1 microsecond each; the
    per-slice bookkeeping of the batched loop would double that, so one problem takes
    this path (tests check that both paths agree).
    """
    h = P.grid.h
    f_star = P.f_star
    n = P.n
    m = np.zeros(n - 1)
    warm = False
    if m0 is not None:
        cand = _on_momentum_plane(P, np.asarray(m0, dtype=float).reshape(n - 1))
        fc = f_star - divergence(cand) / h
        if np.all(np.isfinite(cand)) and np.all(fc > 0):
            m, warm = cand.copy(), True
    status, iters, kkt, stall, dec_last, kkt_here = None, 0, np.nan, 0, np.inf, False
    flat, jammed = 0, False  # consecutive jammed iterations; whether the attempt ended on a jam
    second = None  # second-order test at the point where the iteration stopped
    if not np.all(f_star > 0):
        status = Status.NUMERICAL_ERROR
    tiny = np.finfo(float).tiny
    with np.errstate(all="ignore"):
        if status is None and start == "explicit" and not warm:
            m = _explicit_start(P, f_star, m, True)
        f = f_star - divergence(m) / h
        phi = float(_objective_interior(P, f, m))
        near = False
        for it in range(max_iter + 1):
            if status is not None:
                break
            check = near or it == max_iter
            g, bands, parts = _fused(P, f, m, want_parts=check)
            p, pd, valid = _direction(P, tuple(b[None] for b in bands), g[None])
            p, pd, valid = p[0], bool(pd[0]), bool(valid[0])
            if check:
                prev, kkt = kkt, float(P.kkt_residual(f, m, parts).total)
                kkt_here = True  # the residual belongs to the current (f, m)
                stall = stall + 1 if (prev == prev and kkt > 0.5 * prev and dec_last <= 1e-14) else 0
                # Stopped (converged, or the residual no longer falls: its rounding floor):
                # certify() judges the point below.
                if kkt <= tol or stall >= _STALL_CHECKS:
                    second = pd or (P.conserve_momentum and P.is_local_minimiser(f, m))
                    status = Status.CONVERGED
                    break
            if it == max_iter:
                status = Status.MAX_ITERATIONS if (pd or not check_convexity) else Status.NONCONVEX
                break
            if not valid:  # no descent direction even shifted (see the batched loop)
                finite = bool(_finite_model(g[None], tuple(b[None] for b in bands))[0])
                status = Status.NONCONVEX if finite else Status.NUMERICAL_ERROR
                break
            if not np.all(np.isfinite(p)):
                status = Status.NUMERICAL_ERROR
                break
            pb, ab = _interior_damped(
                P, tuple(band[None] for band in bands), g[None], f[None], p[None].copy(), np.array([damping])
            )
            p, alpha = pb[0], float(ab[0])
            slope = float(g @ p)
            dec = dec_last = -slope / max(abs(phi), tiny)
            near = dec <= max(tol, 1e-13)
            if dec <= 1e-12:  # decrease below the rounding of phi: full, boundary-safe step
                m = m + alpha * p
                f = f_star - divergence(m) / h
                phi = float(_objective_interior(P, f, m))
            else:
                for _ in range(_MAX_BACKTRACKS):
                    trial = m + alpha * p
                    ft = f_star - divergence(trial) / h
                    phit = float(_objective_interior(P, ft, trial))
                    if np.all(ft > 0) and phit <= phi + _ARMIJO * alpha * slope:
                        m, f, phi = trial, ft, phit
                        break
                    alpha *= 0.5
                else:
                    status = Status.NUMERICAL_ERROR  # no decrease even along a tiny step
                    break
            iters += 1
            kkt_here = False
            if jam_exit:  # jam: tiny accepted steps where the model promises a decrease
                flat = flat + 1 if (alpha < _JAM_STEP and dec > 1e-12) else 0
                if flat >= _JAM:
                    status, jammed = Status.MAX_ITERATIONS, True
                    break
        # The iterates are feasible by construction (f = f* - Dm/h) and strictly positive:
        # return the last one itself, so the residual reported is that of the returned point.
        if np.all(f > 0):
            f_out, m_out = f, m
        else:
            f_out, m_out = P.project_feasible(f)
            kkt_here = False
        if not kkt_here:
            kkt = float(P.kkt_residual(f_out, m_out).total)
        cert = certify(
            P,
            f_out,
            m_out,
            kkt_tol=kkt_tol,
            check_convexity=check_convexity,
            claimed=status,
            residual=kkt,
            second_order=second,
        )
    info = {"warm_started": warm, "jammed": jammed}
    return CollisionResult.from_certificate(P, f_out, m_out, cert, "newton", iters, time.perf_counter() - t0, info)


def _check_newton_args(
    problem: CollisionProblem, tol: Any, kkt_tol: Any, max_iter: Any, m0: Any, start: Any, check_convexity: Any
) -> tuple[float, float, int, NDArray | None]:
    """Checked ``(tol, kkt_tol, max_iter, m0)``; errors name the option."""
    tol = check_unit("tol", tol)
    kkt_tol = tol if kkt_tol is None else check_unit("kkt_tol", kkt_tol)
    max_iter = check_int("max_iter", max_iter)
    check_choice("start", start, ("explicit", "zero"))
    check_bool("check_convexity", check_convexity)
    if m0 is not None:
        shape = (*problem.f_star.shape[:-1], problem.n - 1)
        try:
            m0 = np.broadcast_to(np.asarray(m0, dtype=float), shape)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"m0 must be None or fluxes of shape {(problem.n - 1,)}"
                + (f" or {shape}" if problem.batched else "")
                + f", got {np.shape(m0)}"
            ) from exc
    return tol, kkt_tol, max_iter, m0
