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
costs one (N-1) x (N-1) Cholesky factorisation (after Jacobi scaling), batched over
slices.  The step is damped by the fraction to the boundary (iterates stay strictly
positive) and an Armijo backtracking line search on :math:`\\\\phi` itself (the merit
function: iterates are exactly feasible).  The solver terminates on the KKT residual of
:class:`~jko_cvx.collision.problem.CollisionProblem`, never on step length alone.

Statuses: ``CONVERGED`` (KKT residual within tolerance and the reduced Hessian positive
definite), ``NONCONVEX`` (the reduced Hessian is not positive definite at the final
point, or at a point where no descent was possible: loss of convexity),
``MAX_ITERATIONS``, ``NUMERICAL_ERROR`` (non-finite values, or the line search
stalled with the residual above tolerance).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack, solve_triangular

from .linalg import divergence, divergence_adjoint
from .problem import CollisionProblem, add_pentadiagonal
from .result import CollisionResult, Status

__all__ = ["solve_newton"]

_FRACTION_TO_BOUNDARY = 0.995
_ARMIJO = 1e-4
_MAX_BACKTRACKS = 60


def _fused(problem: CollisionProblem, f: NDArray, m: NDArray, E: NDArray) -> tuple[NDArray, NDArray]:
    """Reduced gradient and reduced Hessian in one pass over the edges (the hot loop).

    Same formulas as :meth:`CollisionProblem.gradient` and
    :meth:`CollisionProblem.reduced_hessian` (tests check they agree), computed once
    for the shared quantities :math:`s`, :math:`m/s` and the Fisher terms.
    """
    h = problem.grid.h
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
    gf = 2 * problem.energy_coef * problem.energy.matvec(f)
    gf[..., :-1] += gx
    gf[..., 1:] += gy
    g = gm - divergence_adjoint(gf / h)
    d = np.zeros_like(f)
    d[..., :-1] += xx
    d[..., 1:] += yy
    a, b = -1 / h[:-1], 1 / h[1:]
    diag = hmm + a * a * d[..., :-1] + 2 * a * b * xy + b * b * d[..., 1:] + 2 * (a + b) * hsm
    off1 = (
        a[:-1] * a[1:] * xy[..., :-1]
        + b[:-1] * a[1:] * d[..., 1:-1]
        + b[:-1] * b[1:] * xy[..., 1:]
        + b[:-1] * hsm[..., 1:]
        + a[1:] * hsm[..., :-1]
    )
    off2 = b[:-2] * a[2:] * xy[..., 1:-1]
    H = add_pentadiagonal(E, diag, off1, off2)
    return g, H


def _reduced_gradient(problem, f, m) -> NDArray[np.float64]:
    gf, gm = problem.gradient(f, m)
    # d phi/dm = grad_m J + T' grad_f J with T = -diag(1/h) D, i.e. grad_m J - D'(grad_f J / h).
    return gm - divergence_adjoint(gf / problem.grid.h)


def _newton_direction(H: NDArray, g: NDArray | None) -> tuple[NDArray | None, NDArray[np.bool_]]:
    """Solve ``H p = -g`` slice by slice after Jacobi scaling; flag slices whose H is not PD.

    With ``g=None`` only the positive-definiteness test (one Cholesky per slice) is done.
    """
    d = np.einsum("...ii->...i", H)
    ok = np.all(d > 0, axis=-1) & np.all(np.isfinite(d), axis=-1)
    s = 1 / np.sqrt(np.where(d > 0, d, 1.0))
    if H.shape[0] <= 4:
        # Few slices: LAPACK directly (potrf/potrs), without the batching wrappers' overhead.
        p = np.zeros(H.shape[:-1])
        pd = ok.copy()
        for i in range(H.shape[0]):
            if not ok[i]:
                continue
            c, info = lapack.dpotrf(H[i] * np.outer(s[i], s[i]), lower=1, clean=0, overwrite_a=1)
            if info != 0 or not np.isfinite(c[-1, -1]):
                pd[i] = False
            elif g is not None:
                x, _ = lapack.dpotrs(c, -g[i] * s[i], lower=1)
                p[i] = x * s[i]
        return (None if g is None else p), pd
    ok &= np.all(np.isfinite(H), axis=(-2, -1))
    Hs = H * s[..., :, None] * s[..., None, :]
    pd = ok.copy()
    eye = np.eye(H.shape[-1])
    try:
        L = np.linalg.cholesky(np.where(ok[:, None, None], Hs, eye))
    except np.linalg.LinAlgError:
        # Some slice is indefinite: factorise slice by slice, identity for the failures.
        L = np.empty_like(Hs)
        for i in range(H.shape[0]):
            try:
                L[i] = np.linalg.cholesky(Hs[i]) if ok[i] else eye
            except np.linalg.LinAlgError:
                pd[i], L[i] = False, eye
    if g is None:
        return None, pd
    y = solve_triangular(L, (-g * s)[..., None], lower=True, check_finite=False)
    p = solve_triangular(L, y, lower=True, trans="T", check_finite=False)[..., 0] * s
    return np.where(pd[:, None], p, 0.0), pd


def solve_newton(
    problem: CollisionProblem,
    *,
    tol: float = 1e-10,
    max_iter: int = 100,
    m0: Any = None,
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
        Stop when the scaled KKT residual is at most ``tol`` (per slice).
    max_iter : int, default 100
        Newton iterations (status ``MAX_ITERATIONS`` beyond).
    m0 : array_like, optional
        Warm start: fluxes of shape ``(N-1,)`` or ``(B, N-1)`` (e.g. the previous
        solution's ``m``).  It is used only where it keeps ``f(m0) > 0``; otherwise the
        solver starts from ``m = 0``.
    check_convexity : bool, default True
        Report ``NONCONVEX`` when the reduced Hessian at the final point is not positive
        definite (a stationary point that is not a minimiser).

    Returns
    -------
    CollisionResult
        One status per slice for a batched problem; ``info`` holds ``warm_started``.
    """
    _check_newton_args(problem, tol, max_iter)
    t0 = time.perf_counter()
    batched = problem.batched
    F_star = np.atleast_2d(problem.f_star)
    B, n = F_star.shape
    P = problem if batched else problem.with_f_star(F_star)
    h = P.grid.h
    m = np.zeros((B, n - 1))
    warm = np.zeros(B, dtype=bool)
    if m0 is not None:
        M0 = np.broadcast_to(np.asarray(m0, dtype=float), (B, n - 1))
        f0 = F_star - divergence(M0) / h
        warm = np.all(f0 > 0, axis=-1) & np.all(np.isfinite(M0), axis=-1)
        m[warm] = M0[warm]
    status = np.full(B, None, dtype=object)
    iters = np.zeros(B, dtype=int)
    status[np.any(F_star <= 0, axis=-1)] = Status.NUMERICAL_ERROR
    f = F_star - divergence(m) / h
    # Newton decrement -g.p of the last step relative to |phi|: the KKT residual (the
    # stopping test) is evaluated only once it is small, saving its cost far from the solution.
    decrement = np.full(B, np.inf)
    phi = P.objective(f, m)
    E = 2 * P.energy_coef * P.energy.flux_block()
    kkt_last = np.full(B, np.nan)
    with np.errstate(all="ignore"):
        for it in range(max_iter + 1):
            active = status == None  # noqa: E711 (object array)
            if not active.any():
                break
            idx = np.flatnonzero(active)
            Pa = P.with_f_star(F_star[idx]) if len(idx) < B else P
            fa, ma = f[idx], m[idx]
            near = decrement[idx] <= 1e-6
            done = np.zeros(len(idx), dtype=bool)
            if near.any() or it == max_iter:
                check = near | (it == max_iter)
                Pc = P.with_f_star(F_star[idx[check]]) if check.sum() < B else P
                kv = Pc.kkt_residual(fa[check], ma[check]).total
                kkt_last[idx[check]] = kv
                done[check] = kv <= tol
            for i in idx[done]:
                status[i] = Status.CONVERGED
            if it == max_iter:
                for i in idx[~done]:
                    status[i] = Status.MAX_ITERATIONS
                break
            go = ~done
            if not go.any():
                break
            idx, fa, ma = idx[go], fa[go], ma[go]
            Pa = P.with_f_star(F_star[idx]) if len(idx) < B else P
            g, H = _fused(Pa, fa, ma, E)
            p, pd = _newton_direction(H, g)
            for i in idx[~pd]:
                status[i] = Status.NONCONVEX  # no Newton descent direction: the step is not convex here
            keep = pd & np.all(np.isfinite(p), axis=-1)
            for i in idx[pd & ~keep]:
                status[i] = Status.NUMERICAL_ERROR
            if not keep.any():
                continue
            idx, fa, ma, g, p = idx[keep], fa[keep], ma[keep], g[keep], p[keep]
            Pa = P.with_f_star(F_star[idx]) if len(idx) < B else P
            pf = -divergence(p) / h
            ratio = np.where(pf < 0, -fa / np.where(pf < 0, pf, -1.0), np.inf)
            alpha = np.minimum(1.0, _FRACTION_TO_BOUNDARY * ratio.min(axis=-1))
            phi0 = phi[idx]
            slope = np.einsum("bi,bi->b", g, p)
            decrement[idx] = -slope / np.maximum(np.abs(phi0), np.finfo(float).tiny)
            # Where the predicted decrease is below the rounding of phi, Armijo cannot tell
            # (it would truncate the steps at random); the quadratic model is exact there,
            # so the full, boundary-safe Newton step is taken.
            accepted = -slope <= 1e-12 * np.abs(phi0)
            phi_new = phi0.copy()
            for _ in range(_MAX_BACKTRACKS):
                trial = ma + alpha[:, None] * p
                ft = Pa.f_star - divergence(trial) / h
                phit = Pa.objective(ft, trial)
                ok = np.isfinite(phit) & (phit <= phi0 + _ARMIJO * alpha * slope) & np.all(ft > 0, axis=-1)
                phi_new = np.where(ok & ~accepted, phit, phi_new)
                accepted |= ok
                if accepted.all():
                    break
                alpha = np.where(accepted, alpha, 0.5 * alpha)
            stalled = ~accepted
            for i in idx[stalled]:
                # No decrease even along a tiny step: at the limit of floating point.
                status[i] = Status.NUMERICAL_ERROR
            upd = idx[accepted]
            m[upd] = ma[accepted] + alpha[accepted, None] * p[accepted]
            phi[upd] = phi_new[accepted]
            f[upd] = F_star[upd] - divergence(m[upd]) / h
            iters[upd] += 1
        # Results: project (clip rounding, exact mass), certify, second-order check.
        f_out, m_out = P.project_feasible(f)
        # Re-evaluate the residual only where the projection moved f beyond rounding.
        moved = np.abs(f_out - f).max(axis=-1) > 1e-14 * F_star.max(axis=-1)
        kkt_all = kkt_last.copy()
        redo = moved | ~np.isfinite(kkt_all)
        if redo.any():
            Pr = P.with_f_star(F_star[redo]) if redo.sum() < B else P
            kkt_all[redo] = Pr.kkt_residual(f_out[redo], m_out[redo]).total
        for i in range(B):
            if status[i] is Status.CONVERGED and not kkt_all[i] <= 10 * tol:
                status[i] = Status.NOT_CERTIFIED
            if status[i] is Status.NUMERICAL_ERROR and kkt_all[i] <= tol:
                status[i] = Status.CONVERGED  # the line search stalled exactly at the solution
        conv = np.array([s is Status.CONVERGED for s in status])
        if check_convexity and conv.any():
            # Second-order test at the returned points: one Jacobi-scaled Cholesky per slice.
            Hc = P.reduced_hessian(f_out[conv], m_out[conv])
            _, pd = _newton_direction(Hc + 1e-9 * _diag_matrix(Hc), None)
            for i, ok in zip(np.flatnonzero(conv), pd, strict=True):
                if not ok:
                    status[i] = Status.NONCONVEX
        objective = P.objective(f_out, m_out)
    seconds = time.perf_counter() - t0
    mass_error = P.mass_error(f_out)
    if batched:
        return CollisionResult(
            f_out, m_out, status, "newton", iters, objective, kkt_all, mass_error, seconds, {"warm_started": warm}
        )
    return CollisionResult(
        f_out[0],
        m_out[0],
        status[0],
        "newton",
        int(iters[0]),
        float(objective[0]),
        float(kkt_all[0]),
        float(mass_error[0]),
        seconds,
        {"warm_started": bool(warm[0])},
    )


def _diag_matrix(H: NDArray) -> NDArray:
    """The diagonal of each matrix of a stack, as a stack of diagonal matrices."""
    d = np.einsum("...ii->...i", H)
    return d[..., :, None] * np.eye(H.shape[-1])


solve_newton.batched = True  # type: ignore[attr-defined]


def _check_newton_args(problem: CollisionProblem, tol: float, max_iter: int) -> None:
    if not (isinstance(tol, (int, float)) and np.isfinite(tol) and 0 < tol < 1):
        raise ValueError(f"tol must lie in (0, 1), got {tol!r}")
    if not (isinstance(max_iter, (int, np.integer)) and max_iter >= 1):
        raise ValueError(f"max_iter must be an integer >= 1, got {max_iter!r}")
