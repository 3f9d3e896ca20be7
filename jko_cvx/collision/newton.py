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
smaller KKT residual is returned (``info["jammed"]`` marks these slices).  A slice still
without a solution is solved once more on the barrier function
:math:`J - \\mu \\sum_j h_j \\log f_j` with :math:`\\mu \\to 0` (``info["barrier"]``): large
steps (explicit CFL numbers of 20 and more) empty cells, and a minimiser on the vacuum
boundary is no interior stationary point, which the two attempts before only creep
towards (linearly, at KKT 1e-9 to 1e-3 after their iteration limits).  The step is not
convex (the energy's concave part), and a certificate is local: a slice that jammed and was
then certified is also solved with the barrier attempt, and the certified point with the lower J
is returned (``info["lower_minimum"]``; :func:`_cascade`).  A slice left stalled or without a
descending direction is solved again with shifts of each row's own size and the barrier from the
other start (``info["row_shift"]``), at large CFL numbers by a continuation in dt
(``info["continued"]``), with the barrier from f* with a small share of its mass spread over
the interval (``info["filled_start"]``: a minimiser that fills an emptied interval is out of reach of
iterates that start at f*, whose steps into an emptied cell are bounded by its content), and last by
trust-region iterations on the barrier function, which follow negative curvature through the non-convex
region (exact subproblem on an eigendecomposition, :mod:`jko_cvx.collision._trust_region`), handing over to
the barrier attempt in its Newton region (``info["trust_region"]``).  The
solver stops on the KKT residual of
:class:`~jko_cvx.collision.problem.CollisionProblem` (``tol``), never on step length
alone, and :func:`~jko_cvx.collision.certify.certify` judges the point (``kkt_tol``).

One algorithm for one problem and for a batch (a single problem is a batch of one):
:class:`NewtonOptions` (checked once) and :class:`NewtonState` (one row per slice still
iterating), and the phases as functions -- :func:`_start`, :func:`_residual_test`,
:func:`_direction` (with the modified-Newton shifts), :func:`_step` (interior damping,
:func:`_line_search`, jam bookkeeping), :func:`_finalise` -- driven by :func:`_iterate`;
the retry cascade (:func:`_cascade`) is written once, per slice.  With ``compiled=True`` the first
attempt of each slice with a diagonal energy block (gamma = 1) or the gamma = 3 structured solve runs as
compiled code (:mod:`jko_cvx.collision._compiled`; :func:`_compiled_single`, :func:`_compiled_batch`),
judged by the same residual (compiled) and certificate, and hands back to the cascade whatever it does
not finish cleanly.

Statuses: ``CONVERGED`` (KKT residual within ``kkt_tol`` and the reduced Hessian positive
definite), ``NOT_CERTIFIED`` (stopped, at ``tol`` or at the residual's rounding floor, above
``kkt_tol``), ``NONCONVEX`` (the reduced Hessian is not positive definite at the final
point -- a stationary point that is not a minimiser -- or no shift gave a descent direction),
``MAX_ITERATIONS``, ``NUMERICAL_ERROR`` (non-finite values, or the line search
stalled with the residual above tolerance).
"""

from __future__ import annotations

import functools
import importlib.util
import time
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack

from jko_cvx.collision._linalg import (
    CHAIN_MIN as _CHAIN_MIN,  # slices from which the chained calls pay
)
from jko_cvx.collision._linalg import (
    divergence,
    divergence_adjoint,
    pentadiagonal_cholesky,
    pentadiagonal_cholesky_batch,
    pentadiagonal_solve_batch,
)
from jko_cvx.collision._structured import Semiseparable3, dense_kernel_direction, semiseparable3
from jko_cvx.collision._trust_region import Eigensystem
from jko_cvx.collision.certify import certify_validated
from jko_cvx.collision.options import Options, Spec, option
from jko_cvx.collision.problem import CollisionProblem, TermParts, add_pentadiagonal
from jko_cvx.collision.result import CollisionResult, Status
from jko_cvx.collision.sqp import explicit_step
from jko_cvx.collision.terms import (
    FISHER_TERMS,
    band_coefficients,
    reduced_bands,
    wasserstein_derivatives,
    wasserstein_value,
)
from jko_cvx.kernels import FluxBlock, PowerKernel
from jko_cvx.mesh.moments import restore_moments
from jko_cvx.threads import blas_limited, map_chunks

__all__ = ["NewtonOptions", "NewtonState", "solve_newton"]

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
_TINY = np.finfo(float).tiny
# Tolerance of the positive-definiteness test on the Jacobi-scaled (unit-diagonal) reduced
# Hessian: smallest eigenvalue >= -_PD_TOL counts as convex (the factorised matrix is
# shifted by it, a relative perturbation of the Newton step of the same size).
_PD_TOL = 1e-10
# Consecutive residual checks without halving, with the Newton decrement at rounding level
# (<= 1e-14), after which the residual counts as stalled at its rounding floor (status
# NOT_CERTIFIED rather than iterating to max_iter).
_STALL_CHECKS = 3
# The barrier attempt (see _with_barrier): the first weight, relative to the scale of the
# reduced gradient, and its reduction after each full step.
_MU_START = 1e-3
_MU_SHRINK = 0.1
_BARRIER_STALL = 8
_MU_CENTRED = 1e-3  # mu is lowered after a full step whose decrement is at most this
# The second start's certified point replaces the first one if its J is lower by more than J's rounding
# (relative; J is a sum of N non-negative terms, rounded to about N * 1e-16).  A lower J is the better
# answer to the minimisation whether it is another minimiser (1e-6 to 1e-2 lower on the paper's gamma = 3
# scene) or the same one reached more accurately (1e-10 to 1e-8 lower there, at KKT 1e-8); otherwise the
# first point is kept bit for bit.
_LOWER = 1e-12
# The filled start (_filled_start): f* with this share of its mass spread over the interval.  Measured on the
# two review steps it serves (gamma ~ 1, CFL 142 and 469, tails at 1e-22 of the maximum): both certified from
# 1e-11 to 1e-5; at 1e-14 one is not (a step into an emptied cell is still bounded by its content), at 1e-3
# neither (the filled mass itself is far from the minimiser); 1e-8 lies in the middle of that range.
_FILL = 1e-8


def _fused(
    problem: CollisionProblem, f: NDArray, m: NDArray, want_parts: bool | NDArray[np.bool_] = True
) -> tuple[NDArray, tuple, TermParts | None]:
    """Reduced gradient and the bands of the edge part of the reduced Hessian, in one pass.

    The formulas of :mod:`~jko_cvx.collision.terms` (those of :meth:`CollisionProblem.gradient`
    and :meth:`CollisionProblem.reduced_hessian`), evaluated once for the shared quantities
    :math:`s` and :math:`m/s`, at interior points (no domain guards).  ``want_parts``: the
    per-term split of the gradient for every slice (True), none (False), or for the slices
    of a boolean mask (the same numbers as those rows of the whole split).
    """
    h = band_coefficients(problem.grid, f.ndim)[0]
    x, y = f[..., :-1], f[..., 1:]
    s = x + y
    wd = wasserstein_derivatives(m, s, problem.wass_coef)
    gx = gy = wd.g_s
    xx = yy = xy = wd.h_ss
    if problem.fisher is not None:
        term = FISHER_TERMS[problem.fisher]
        c = problem.fisher_coef
        fx, fy, hx, hy, hxy = term.gradient_and_hessian(x, y, s, c)  # shared subexpressions once
        gx, gy = wd.g_s + fx, wd.g_s + fy
        xx, yy, xy = wd.h_ss + hx, wd.h_ss + hy, wd.h_ss + hxy
    gfe = 2 * problem.energy_coef * problem.energy.matvec(f)
    gf = gfe.copy()
    gf[..., :-1] += gx
    gf[..., 1:] += gy
    g = wd.g_m - divergence_adjoint(gf / h)
    parts = None
    if want_parts is not False:  # the per-term split, for the KKT residual's scale
        rows = slice(None) if want_parts is True else want_parts
        g_s, g_m, gf_r, gfe_r = wd.g_s[rows], wd.g_m[rows], gf[rows], gfe[rows]
        gfw = np.zeros(gf_r.shape)
        gfw[..., :-1] += g_s
        gfw[..., 1:] += g_s
        gff = gf_r - gfe_r - gfw
        zero = np.zeros(g_m.shape)
        parts = TermParts((gfw, g_m), (gff, zero), (gfe_r, zero))
    return g, reduced_bands(problem.grid, xx, yy, xy, wd.h_sm, wd.h_mm), parts


def _sherman_morrison(fb: FluxBlock, scale: float, y: NDArray, k: int) -> NDArray | None:
    """``(B - s u u')^-1 rhs`` from ``y = B^-1 [rhs, u]`` (Fortran-ordered), or None where not PD."""
    sigma = 1 - scale * (fb.u @ y[:, k])
    if sigma > _PD_TOL:
        return y[:, :k] + np.outer(y[:, k], scale * (fb.u @ y[:, :k]) / sigma)
    return None


def _structured_direction(fb: FluxBlock, scale: float, bands, rhs: NDArray) -> tuple[NDArray, NDArray[np.bool_]]:
    """``H^-1 rhs`` when the energy block is diagonal (gamma = 1) or rank one (gamma = 2).

    ``rhs`` has shape ``(B, N-1, k)``.  The reduced Hessian is then pentadiagonal, or
    pentadiagonal minus ``scale * u u'``: a banded Cholesky (O(N)) and, for the rank-one
    case, Sherman-Morrison.  By the matrix determinant lemma ``B - s u u'`` is positive
    definite iff ``B`` is and ``1 - s u' B^-1 u > 0``.  From ``_CHAIN_MIN`` slices the
    factorisations and solves are chained LAPACK calls
    (:func:`~jko_cvx.collision._linalg.pentadiagonal_cholesky_batch`), bitwise those of one
    call per slice; the Sherman-Morrison update is per slice.
    """
    diag, off1, off2 = bands
    if fb.kind == "diagonal":
        diag = diag + scale * fb.diag
    x = np.zeros(rhs.shape)
    pd = np.zeros(rhs.shape[0], dtype=bool)
    k = rhs.shape[-1]
    if rhs.shape[0] < _CHAIN_MIN:
        for i in range(rhs.shape[0]):
            if not ((diag[i] > 0).all() and np.isfinite(diag[i]).all()):
                continue
            c = pentadiagonal_cholesky(diag[i] * (1 + _PD_TOL), off1[i], off2[i])
            if c is None:
                continue
            if fb.kind == "diagonal":
                x[i], _ = lapack.dpbtrs(c, rhs[i], lower=1)
                pd[i] = True
                continue
            y, _ = lapack.dpbtrs(c, np.concatenate([rhs[i], fb.u[:, None]], axis=1), lower=1)
            xi = _sherman_morrison(fb, scale, y, k)
            if xi is not None:
                x[i], pd[i] = xi, True
        return x, pd
    rows = np.flatnonzero(np.all(diag > 0, axis=-1) & np.all(np.isfinite(diag), axis=-1))
    factors, ok = pentadiagonal_cholesky_batch(diag[rows] * (1 + _PD_TOL), off1[rows], off2[rows])
    rows, factors = rows[ok], factors[ok]
    if fb.kind == "diagonal":
        x[rows] = pentadiagonal_solve_batch(factors, rhs[rows])
        pd[rows] = True
        return x, pd
    cols = np.concatenate([rhs[rows], np.broadcast_to(fb.u[:, None], (rows.size, fb.u.size, 1))], axis=-1)
    Y = pentadiagonal_solve_batch(factors, cols)
    for j, i in enumerate(rows):
        xi = _sherman_morrison(fb, scale, np.asfortranarray(Y[j]), k)  # one slice's layout, as dpbtrs gives it
        if xi is not None:
            x[i], pd[i] = xi, True
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


def _direction(
    problem: CollisionProblem, bands, g: NDArray, row_shift: bool = False
) -> tuple[NDArray, NDArray[np.bool_], NDArray[np.bool_]]:
    """Newton direction ``-H^-1 g``, the per-slice positive-definiteness of H, and validity.

    With ``conserve_momentum`` the direction is the equality-constrained one: with
    ``a = dv`` (the constraint ``a'm = 0``), ``p = p0 - w (a'p0)/(a'w)``, ``p0 = -H^-1 g``,
    ``w = H^-1 a`` -- one more back-substitution with the same factorisation.

    Where H is not positive definite (the step problem is locally non-convex: the
    interaction energy is concave in some directions, more so for large dt * strength)
    the direction is taken with ``H + tau diag(H)``, tau = 1e-6, 1e-4, ..., 1e2, the first
    that factorises: a descent direction, so the iteration can still reach a local
    minimiser, which the final second-order test certifies (modified Newton).
    ``valid`` is False only where no shift helped.  Where a diagonal entry is not positive,
    ``D`` is :func:`_shift` (``row_shift``: each row's own size).
    """
    fb = problem.energy.flux_structure()
    scale = 2 * problem.energy_coef
    minus_g = -g
    cols = [minus_g]
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
    rhs = np.stack(cols, axis=-1) if len(cols) > 1 else minus_g[..., None]
    H = None
    if fb.kind in ("diagonal", "rank1"):
        x, pd = _structured_direction(fb, scale, bands, rhs)
    else:
        # dense kernels go through jko_cvx.collision._structured (exact O(N) solves for
        # gamma = 3 and even gamma >= 4, certified CG otherwise, the per-slice Cholesky as
        # fallback; threaded).  The momentum-plane flag lets a low-rank block drop its terms
        # along the constraint's normal (the constrained step is the same).
        x, pd = dense_kernel_direction(problem.energy, scale, bands, rhs, _PD_TOL, problem.conserve_momentum)
    valid = pd.copy()
    if not pd.all():
        bad = np.nonzero(~pd)[0]
        Hb = (
            H[bad]
            if H is not None
            else add_pentadiagonal(scale * problem.energy.flux_block(), *(b[bad] for b in bands))
        )
        d = np.einsum("...ii->...i", Hb)
        finite = np.all(np.isfinite(Hb), axis=(-2, -1))
        shift, big = _shift(Hb, d, row_shift)
        todo = finite & (big > 0)
        for tau in (1e-6, 1e-4, 1e-2, 1.0, 1e2, 1e4, 1e6):
            if not todo.any():
                break
            idx = np.flatnonzero(todo)
            Hs = Hb[idx].copy()
            Hs[:, np.arange(Hs.shape[-1]), np.arange(Hs.shape[-1])] += tau * shift[idx]
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


def _shift(Hb: NDArray, d: NDArray, row_shift: bool) -> tuple[NDArray, NDArray]:
    """The diagonal ``D`` of the modified-Newton shifts ``H + tau D`` (:func:`_direction`) and each slice's largest
    ``|H_kk|``, for the stacked Hessians ``Hb`` with diagonals ``d``.

    A positive diagonal is its own shift.  A diagonal entry <= 0 (a concave energy outweighing the convex
    terms: gamma < 2 at a large CFL number) is shifted by its magnitude, floored at 1e-8 of the largest, so
    that ``H + tau D`` still becomes positive definite as tau grows.  With ``row_shift`` every entry of such a
    slice is shifted by its row's own size, :math:`\\max(|H_{kk}|, \\sum_{j \\ne k} |H_{kj}|)` (diagonally dominant
    from tau = 2), floored only where the row is zero: next to an emptied cell the curvature 4 / s_k reaches
    1e40, and 1e-8 of that on every other edge makes the shifted step vanish there (the point does not move).
    """
    big = np.abs(d).max(axis=-1, keepdims=True)
    if row_shift:
        size = np.maximum(np.abs(d), np.abs(Hb).sum(axis=-1) - np.abs(d))
        other = np.where(size > 0, size, 1e-8 * big)
    else:
        other = np.maximum(np.abs(d), 1e-8 * big)
    return np.where(np.all(d > 0, axis=-1, keepdims=True), d, other), big[..., 0]


def _interior_damped(
    problem: CollisionProblem, bands, g: NDArray, f: NDArray, p: NDArray, damping: bool, row_shift: bool = False
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
    (arrays of shape ``(B, ...)``); without ``damping`` the directions are ``p`` itself.
    """
    h = band_coefficients(problem.grid, f.ndim)[0]
    pf = -divergence(p) / h
    alpha = _boundary_step(f, pf)
    if not damping:
        return p, alpha
    todo = alpha < 1.0
    if not todo.any():
        return p, alpha
    _, _, _, aa, _, bb, _, o1b, _, _, _ = band_coefficients(problem.grid)
    mu = 1e-2 * np.abs(np.einsum("bi,bi->b", g, p))
    for _ in range(12):
        if not todo.any():
            break
        idx = np.flatnonzero(todo)
        c = mu[idx, None] / (f[idx] * f[idx])
        diag, off1, off2 = (band[idx] for band in bands)
        sub = (diag + aa * c[:, :-1] + bb * c[:, 1:], off1 + o1b * c[:, 1:-1], off2)
        q, _, valid = _direction(problem, sub, g[idx], row_shift)  # uses the grid and the energy, not f*
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
    neg = pf < 0
    ratio = np.where(neg, -f / np.where(neg, pf, -1.0), np.inf)
    return np.minimum(1.0, _FRACTION_TO_BOUNDARY * ratio.min(axis=-1))


def _objective_interior(problem: CollisionProblem, f: NDArray, m: NDArray) -> NDArray:
    """:math:`J(f, m)` for strictly positive f (line-search trial points), without domain guards."""
    x, y = f[..., :-1], f[..., 1:]
    s = x + y
    val = wasserstein_value(m, s) @ problem.wass_coef
    if problem.fisher is not None:
        val = val + FISHER_TERMS[problem.fisher].value(x, y, s) @ problem.fisher_coef
    return val + problem.energy_coef * problem.energy.quadratic(f)


def _merit(problem: CollisionProblem, f: NDArray, m: NDArray, mu: NDArray | None) -> NDArray:
    """:math:`J(f, m)`, or with ``mu`` the barrier function :math:`J - \\mu \\sum_j h_j \\log f_j`."""
    val = _objective_interior(problem, f, m)
    if mu is None:
        return val
    return val - mu * (np.log(f) @ problem.grid.h)


def _with_barrier(problem: CollisionProblem, f: NDArray, mu: NDArray, g: NDArray, bands) -> tuple[NDArray, tuple]:
    """Reduced gradient and Hessian bands of the barrier function :math:`J - \\mu \\sum_j h_j \\log f_j`.

    With :math:`T = -\\operatorname{diag}(1/h) D` the barrier adds :math:`D^\\top (\\mu / f)` to the
    reduced gradient and :math:`T^\\top \\operatorname{diag}(\\mu h / f^2)\\, T` (tridiagonal) to
    the reduced Hessian.  A minimiser on the vacuum boundary (cells emptied by a large step)
    is no stationary point of J in the interior, so plain Newton only creeps towards it;
    the barrier's minimisers are interior and tend to it as :math:`\\mu \\to 0`.  At a
    minimiser of the barrier function the unconstrained gradient in :math:`f_j` is
    :math:`\\mu h_j / f_j`, which the KKT residual weighs by :math:`f_j / \\max f`: a residual of
    order :math:`\\mu`, so a small enough :math:`\\mu` passes the unmodified test.
    """
    _, _, _, aa, _, bb, _, o1b, _, _, _ = band_coefficients(problem.grid)
    h = problem.grid.h
    c = mu[:, None] * h / (f * f)
    diag, off1, off2 = bands
    g = g + divergence_adjoint(mu[:, None] / f)
    return g, (diag + aa * c[:, :-1] + bb * c[:, 1:], off1 + o1b * c[:, 1:-1], off2)


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


_UNIT = Spec("float", lo=0.0, hi=1.0, lo_open=True, hi_open=True)


@dataclass(frozen=True)
class NewtonOptions(Options):
    """The options of :func:`solve_newton`, checked once on construction (see its docstring for each).

    Fields are checked in this order; ``kkt_tol=None`` is ``tol``.  The warm start ``m0`` is
    checked against the problem by :func:`solve_newton`.
    """

    tol: float = option(1e-10, _UNIT)
    kkt_tol: float | None = option(None, _UNIT)
    max_iter: int = option(100, Spec("int", lo=1))
    start: str = option("explicit", Spec("str", choices=("explicit", "zero")))
    check_convexity: bool = option(True, Spec("bool"))
    second_start: bool = option(True, Spec("bool"))
    compiled: bool = option(False, Spec("bool"))
    m0: NDArray | None = option(None, Spec("array", scene=False))

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.kkt_tol is None:  # the iterations reach tol quadratically: certify at tol
            object.__setattr__(self, "kkt_tol", self.tol)
        if self.compiled and importlib.util.find_spec("numba") is None:
            raise ImportError(
                'compiled=True needs numba, which is not installed: python -m pip install "jko_cvx[fast]"'
            )


@dataclass(frozen=True)
class _Attempt:
    """How one pass of the iteration runs: interior damping on, and whether a jam ends it."""

    damping: bool
    jam_exit: bool
    barrier: bool = False
    row_shift: bool = False  # the modified-Newton shifts of each row's own size (_shift)


@dataclass
class NewtonState:
    """Per-slice state of the Newton iteration, one row per slice still iterating.

    ``rows`` are the slices' indices in the batch.  A slice leaves the state (its row is
    written to the result arrays by :func:`_retire`) as soon as it has a status: the
    iteration then works on whole arrays, with no per-iteration gathers, and a batch of
    one -- the single problem -- costs no more bookkeeping than a scalar loop.  ``status``
    ``CONVERGED`` means "stopped at a solution by its own rule" (residual within ``tol``, or
    stalled at its rounding floor) until :func:`~jko_cvx.collision.certify.certify` judges it.
    """

    rows: NDArray[np.int_]
    m: NDArray[np.float64]
    f: NDArray[np.float64]
    phi: NDArray[np.float64]  # J at the current iterate (the line search's merit function)
    status: NDArray  # object array of Status or None (still iterating)
    iterations: NDArray[np.int_]
    kkt: NDArray[np.float64]  # last residual computed ...
    kkt_here: NDArray[np.bool_]  # ... and whether it belongs to the current iterate
    second: NDArray[np.bool_]  # second-order test where the slice stopped
    jammed: NDArray[np.bool_]
    near: NDArray[np.bool_]  # last decrement small: check the residual at the next iterate
    stall: NDArray[np.int_]  # consecutive checks without progress at rounding level
    decrement: NDArray[np.float64]  # last Newton decrement -g.p/|phi|
    flat: NDArray[np.int_]  # consecutive jammed steps
    mu: NDArray[np.float64]  # barrier weight (0 outside the barrier attempt, see _with_barrier)

    @classmethod
    def initial(cls, m: NDArray, f: NDArray, phi: NDArray, status: NDArray) -> NewtonState:
        """The state before the first iteration."""
        b = m.shape[0]
        return cls(
            np.arange(b), m, f, phi, status, np.zeros(b, dtype=int), _filled(b, np.nan), np.zeros(b, dtype=bool),
            np.zeros(b, dtype=bool), np.zeros(b, dtype=bool), np.zeros(b, dtype=bool), np.zeros(b, dtype=int),
            _filled(b, np.inf), np.zeros(b, dtype=int), np.zeros(b),
        )  # fmt: skip

    def take(self, keep: NDArray[np.bool_] | slice) -> NewtonState:
        """The rows ``keep``."""
        return NewtonState(*(getattr(self, name)[keep] for name in _STATE_FIELDS))


_STATE_FIELDS = tuple(f.name for f in fields(NewtonState))
# What a slice hands to the result when it leaves the iteration.
_RESULT_FIELDS = ("m", "f", "phi", "status", "iterations", "kkt", "kkt_here", "second", "jammed")


def _filled(shape: int | tuple[int, ...], value: float) -> NDArray[np.float64]:
    """``np.full(shape, value)`` at a third of its cost (np.full is Python; empty and fill are not)."""
    out = np.empty(shape)
    out.fill(value)
    return out


def _explicit_start(
    P: CollisionProblem, F_star: NDArray, m: NDArray, use: NDArray[np.bool_]
) -> tuple[NDArray, NDArray]:
    """The damped explicit step (first SQP step) where ``use`` and where it lowers J, else ``m``.

    The step is damped to keep ``f >= f*/2``.  Also returns J at the chosen point where
    ``m`` is zero outside ``use`` (the explicit step's J, else J at ``(f*, 0)``).
    """
    zero = np.zeros(m.shape)
    pf, pm = explicit_step(P)
    ratio = np.where(pf < 0, -F_star / np.where(pf < 0, pf, -1.0), np.inf).min(axis=-1)
    alpha = np.minimum(1.0, 0.5 * ratio)
    cand = P.on_momentum_plane(alpha[:, None] * pm)
    fc = F_star - divergence(cand) / band_coefficients(P.grid, 2)[0]
    phi_c, phi_0 = _objective_interior(P, fc, cand), _objective_interior(P, F_star, zero)
    better = use & np.isfinite(cand).all(axis=-1) & (fc > 0).all(axis=-1) & (phi_c < phi_0)
    return np.where(better[:, None], cand, m), np.where(better, phi_c, phi_0)


def _start(P: CollisionProblem, m0: NDArray | None, opts: NewtonOptions) -> tuple[NewtonState, NDArray[np.bool_]]:
    """The first iterate (``m0`` where it keeps f > 0, else the explicit step or 0), and where m0 was used."""
    F_star = P.f_star
    B, n = F_star.shape
    h = band_coefficients(P.grid, 2)[0]  # the (1, n) row of the batch
    m = np.zeros((B, n - 1))
    warm = np.zeros(B, dtype=bool)
    if m0 is not None:
        M0 = P.on_momentum_plane(np.broadcast_to(m0, (B, n - 1)))
        warm = np.all(F_star - divergence(M0) / h > 0, axis=-1) & np.all(np.isfinite(M0), axis=-1)
        m[warm] = M0[warm]
    status = np.empty(B, dtype=object)  # None: still iterating
    positive = (F_star > 0).all(axis=-1)
    status[~positive] = Status.NUMERICAL_ERROR  # an interior method cannot start from exact zeros
    phi = None
    with np.errstate(all="ignore"):
        if opts.start == "explicit" and positive.any():
            m, phi = _explicit_start(P, F_star, m, ~warm & positive)
        f = F_star - divergence(m) / h
        if phi is None or warm.any():  # without warm rows f is f* or the explicit step's: J is known
            phi = _objective_interior(P, f, m)
    return NewtonState.initial(m, f, phi, status), warm


def _retire(Pa: CollisionProblem, st: NewtonState, out: dict[str, NDArray]) -> tuple[CollisionProblem, NewtonState]:
    """Move the slices that have a status from ``st`` to the result arrays ``out``.

    ``out`` starts empty; every slice leaves exactly once, so the result arrays are allocated
    (or, when every slice leaves at once, taken from the state) at the first call that moves any.
    """
    if all(s is None for s in st.status):  # a Python loop: cheaper than NumPy at B = 1
        return Pa, st
    done = np.not_equal(st.status, None)
    if done.all():  # every slice leaves (a single problem's last call): no masks, no empty batch
        if not out:  # ... and all at once: the state's arrays are the result's
            out.update((name, getattr(st, name)) for name in _RESULT_FIELDS)
        else:
            for name in _RESULT_FIELDS:
                out[name][st.rows] = getattr(st, name)
        return Pa, st.take(slice(0, 0))
    if not out:  # the first slices to leave: the state still holds the whole batch
        out.update((name, np.empty_like(getattr(st, name))) for name in _RESULT_FIELDS)
    rows = st.rows[done]
    for name in _RESULT_FIELDS:
        out[name][rows] = getattr(st, name)[done]
    keep = ~done
    return Pa.rows(keep), st.take(keep)


def _residual_test(
    Pa: CollisionProblem, st: NewtonState, parts, pd: NDArray, check: NDArray, opts: NewtonOptions
) -> NDArray[np.bool_]:
    """KKT residual where ``check``: slices within ``tol`` or stalled at their rounding floor stop.

    ``parts`` is the gradient split of the ``check`` slices only (``_fused``); a slice's
    residual is its own whatever the other slices of the batch
    (:func:`~jko_cvx.collision._linalg.solve_sym_tridiagonal`), so only those are computed.
    A residual that no longer halves while the Newton decrement is at rounding level
    (``_STALL_CHECKS`` times) has reached its floor.  Returns the stopped slices.
    """
    prev = st.kkt
    every = bool(check.all())  # always so for a single problem
    if every:
        kk = Pa.kkt_residual(st.f, st.m, parts).total
        st.kkt = kk
    else:
        kk = np.full(check.shape, np.nan)
        kk[check] = Pa.rows(check).kkt_residual(st.f[check], st.m[check], parts).total
        st.kkt = np.where(check, kk, st.kkt)
    st.kkt_here |= check
    done = check & (kk <= opts.tol)
    worse = check & ~done & (prev == prev) & (kk > 0.5 * prev) & (st.decrement <= 1e-14)
    # In the barrier attempt the decrement is that of the barrier function, which reaches
    # rounding level while lowering mu still lowers the residual: there a stall is a run of
    # checks in which the residual falls by less than 10 % each.
    barrier = st.mu > 0
    limit = _STALL_CHECKS
    if barrier.any():
        worse = np.where(barrier, check & ~done & (prev == prev) & (kk > 0.9 * prev) & (st.decrement <= 1e-10), worse)
        limit = np.where(barrier, _BARRIER_STALL, _STALL_CHECKS)
    stall = np.where(worse, st.stall + 1, 0)
    st.stall = stall if every else np.where(check, stall, st.stall)
    stop = done | (check & (st.stall >= limit))
    if stop.any():
        # pd is the (shifted) Cholesky of the reduced Hessian at this very point: the
        # second-order test comes for free; certify() judges the point at the end.
        st.second = np.where(stop, _second_order(Pa, st.f, st.m, pd, stop), st.second)
        st.status[stop] = Status.CONVERGED
    return stop


def _no_descent(st: NewtonState, g: NDArray, bands, p: NDArray, valid: NDArray) -> None:
    """Stop the slices without a usable direction.

    No descent direction even shifted: non-convexity where the model is finite; an
    iterate at the vacuum boundary (f underflowed, inf curvature) or a non-finite step
    is a numerical failure, which the interior-damped retry resolves.
    """
    go = valid & np.isfinite(p).all(axis=-1)
    if not go.all():
        free = np.equal(st.status, None)
        finite = _finite_model(g, bands)
        st.status[free & ~valid & finite] = Status.NONCONVEX
        st.status[free & ~valid & ~finite] = Status.NUMERICAL_ERROR
        st.status[free & valid & ~go] = Status.NUMERICAL_ERROR


def _line_search(
    Pa: CollisionProblem,
    m: NDArray,
    p: NDArray,
    alpha: NDArray,
    phi0: NDArray,
    slope: NDArray,
    dec: NDArray,
    mu: NDArray | None = None,
) -> tuple[NDArray[np.bool_], NDArray, NDArray]:
    """Armijo backtracking on J from ``m`` along ``p``, starting at the boundary-safe ``alpha``.

    Where the predicted decrease is below the rounding of J (decrement <= 1e-12) Armijo
    cannot tell (it would truncate the steps at random); the quadratic model is exact
    there, so the full, boundary-safe step is taken.  With ``mu`` the merit function is the
    barrier one (:func:`_merit`).  Returns (accepted, alpha, the merit function at the
    accepted point, NaN where it was taken without a trial, and the last trial point
    ``(m, f)`` when every slice accepted it, else None).
    """
    h = band_coefficients(Pa.grid, 2)[0]
    accepted = dec <= 1e-12
    if mu is not None and accepted.any():
        # The barrier drives f_j towards rounding level: a full step must still keep f > 0.
        accepted &= (Pa.f_star - divergence(m + alpha[:, None] * p) / h > 0).all(axis=-1)
    phi_new = _filled(phi0.shape, np.nan)
    point = None
    for _ in range(_MAX_BACKTRACKS):
        if accepted.all():
            break
        trial = m + alpha[:, None] * p
        ft = Pa.f_star - divergence(trial) / h
        phit = _merit(Pa, ft, trial, mu)
        ok = ~accepted & (ft > 0).all(axis=-1) & (phit <= phi0 + _ARMIJO * alpha * slope)
        phi_new = np.where(ok, phit, phi_new)
        accepted |= ok
        alpha = np.where(accepted, alpha, 0.5 * alpha)
        point = (trial, ft) if ok.all() else None  # every slice at this trial: the step itself
    return accepted, alpha, phi_new, point


def _step(Pa: CollisionProblem, st: NewtonState, g: NDArray, p: NDArray, bands, run: _Attempt, tol: float) -> None:
    """Damp, line-search and take the step on every slice of ``st``; jam bookkeeping.

    In the barrier attempt ``g``, ``bands`` and ``st.phi`` are those of the barrier
    function (:func:`_with_barrier`), and ``mu`` is lowered after each full step.
    """
    mu = st.mu if run.barrier else None
    p, alpha = _interior_damped(Pa, bands, g, st.f, p, run.damping, run.row_shift)
    slope = np.einsum("bi,bi->b", g, p)
    dec = -slope / np.maximum(np.abs(st.phi), _TINY)
    st.decrement = dec
    # Quadratic convergence: after a step with decrement dec the next decrement is ~dec^2
    # and the residual far below dec, so the KKT residual is checked once dec reaches tol
    # (or the rounding level 1e-13, below which it cannot fall further).
    st.near = dec <= max(tol, 1e-13)
    accepted, alpha, phi_new, point = _line_search(Pa, st.m, p, alpha, st.phi, slope, dec, mu)
    if point is not None:  # the last trial, m + alpha p and its f, bit for bit
        st.m, st.f = point
    elif accepted.all():
        st.m = st.m + alpha[:, None] * p
        st.f = Pa.f_star - divergence(st.m) / band_coefficients(Pa.grid, 2)[0]
    else:
        st.status[~accepted] = Status.NUMERICAL_ERROR  # no decrease even along a tiny step
        st.m[accepted] = st.m[accepted] + alpha[accepted, None] * p[accepted]
        st.f[accepted] = Pa.f_star[accepted] - divergence(st.m[accepted]) / Pa.grid.h
    fresh = accepted & np.isnan(phi_new)  # full steps were taken without evaluating J
    st.phi = np.where(accepted, phi_new, st.phi)
    if fresh.all():
        st.phi = _merit(Pa, st.f, st.m, mu)
    elif fresh.any():
        st.phi[fresh] = _merit(Pa.rows(fresh), st.f[fresh], st.m[fresh], None if mu is None else mu[fresh])
    if run.barrier:
        # A full step means the iterate is in the quadratic region of the barrier function
        # for this mu: move on along the central path.
        lower = accepted & (alpha >= _FRACTION_TO_BOUNDARY) & (dec <= _MU_CENTRED)
        if lower.any():
            st.mu = np.where(lower, _MU_SHRINK * st.mu, st.mu)
            Pl = Pa if lower.all() else Pa.rows(lower)
            st.phi[lower] = _merit(Pl, st.f[lower], st.m[lower], st.mu[lower])
    st.iterations += accepted
    st.kkt_here &= ~accepted
    if run.jam_exit:  # jam: tiny accepted steps where the model promises a decrease
        tiny = accepted & (alpha < _JAM_STEP) & (dec > 1e-12)
        st.flat = np.where(tiny, st.flat + 1, np.where(accepted, 0, st.flat))
        jam = st.flat >= _JAM
        if jam.any():
            st.status[jam] = Status.MAX_ITERATIONS
            st.jammed |= jam


def _iterate(P: CollisionProblem, st: NewtonState, opts: NewtonOptions, run: _Attempt) -> dict[str, NDArray]:
    """The Newton loop: residual test, direction, step, until every slice has stopped.

    Returns each slice's final ``_RESULT_FIELDS``.
    """
    out: dict[str, NDArray] = {}  # filled by _retire
    Pa = P
    with np.errstate(all="ignore"):
        for it in range(opts.max_iter + 1):
            Pa, st = _retire(Pa, st, out)
            if st.rows.size == 0:
                break
            check = np.ones_like(st.near) if (it == opts.max_iter or run.barrier) else st.near
            checking = bool(check.any())
            g, bands, parts = _fused(Pa, st.f, st.m, want_parts=check if checking else False)
            if run.barrier:
                g, bands = _with_barrier(Pa, st.f, st.mu, g, bands)
            p, pd, valid = _direction(Pa, bands, g, run.row_shift)
            if checking:
                _residual_test(Pa, st, parts, pd, check, opts)
            if it == opts.max_iter:
                # Out of iterations where the Hessian still needed a shift: loss of convexity
                # is what stopped the solver (typically a minimiser on the vacuum boundary).
                for i in np.nonzero(np.equal(st.status, None))[0]:
                    st.status[i] = Status.MAX_ITERATIONS if (pd[i] or not opts.check_convexity) else Status.NONCONVEX
                break
            if any(s is None for s in st.status):
                _no_descent(st, g, bands, p, valid)
            if not all(s is None for s in st.status):
                free = np.equal(st.status, None)
                Pa, st = _retire(Pa, st, out)
                if st.rows.size:  # (a single problem that stopped has nothing left to gather)
                    g, p, bands = g[free], p[free], tuple(band[free] for band in bands)
            if st.rows.size:
                _step(Pa, st, g, p, bands, run, opts.tol)
        _retire(Pa, st, out)
    return out


def _finalise(
    P: CollisionProblem, out: dict[str, NDArray], warm: NDArray[np.bool_], opts: NewtonOptions, t0: float
) -> CollisionResult:
    """Certify every slice at its last iterate and build the result.

    Iterates are feasible (f = f* - Dm/h) and strictly positive by construction: they are
    returned as they are, so the residual reported is that of the returned point; only
    slices that are not strictly positive (data with zeros, which never iterate) are
    projected, and the residual is recomputed only where none belongs to the returned point.
    """
    with np.errstate(all="ignore"):
        positive = (out["f"] > 0).all(axis=-1)
        f_out, m_out = out["f"], out["m"]
        if not positive.all():
            f_out[~positive], m_out[~positive] = P.rows(~positive).project_feasible(out["f"][~positive])
        kkt = out["kkt"]
        redo = ~positive | ~out["kkt_here"] | ~np.isfinite(kkt)
        if redo.any():
            Pr = P if redo.all() else P.rows(redo)
            kkt[redo] = Pr.kkt_residual(f_out[redo], m_out[redo]).total
        # J at the last iterate, as the line search evaluated it: problem.objective's value bit
        # for bit where every f_j > 0 (no guards apply), when computed on the same batch
        # shape (one problem; a batch's slices were evaluated in sub-batches as they retired);
        # the compiled iteration's to rounding (the same sums in loops).
        known = out["phi"] if out["phi"] is not None and f_out.shape[0] == 1 and positive.all() else None
        cert = certify_validated(
            P,
            f_out,
            m_out,
            opts.kkt_tol,
            opts.check_convexity,
            out["status"],
            residual=kkt,
            second_order=out["second"],
            objective=known,
        )
    info = {"warm_started": warm, "jammed": out["jammed"]}
    seconds = time.perf_counter() - t0
    return CollisionResult.from_certificate(P, f_out, m_out, cert, "newton", out["iterations"], seconds, info)


def _attempt(P: CollisionProblem, m0: NDArray | None, opts: NewtonOptions, run: _Attempt) -> CollisionResult:
    """One pass of the iteration over the batch ``P``, from the start point to certification."""
    t0 = time.perf_counter()
    st, warm = _start(P, m0, opts)
    if run.barrier:
        # The first weight: the barrier's part of J of relative size _MU_START (data near the float range's
        # edge overflow to inf here, as in the start and the loop; the certificate then refuses the slice).
        with np.errstate(all="ignore"):
            st.mu = _MU_START * np.abs(st.phi) / P.grid.length
            st.phi = _merit(P, st.f, st.m, st.mu)
    out = _iterate(P, st, opts, run)
    if run.barrier:
        # The factorised Hessian was the barrier function's (more positive definite than
        # J's): the certificate runs the second-order test on J itself.
        out["second"] = np.full(out["second"].shape, None, dtype=object)
        out["phi"] = None  # the barrier function's value, not J's
    return _finalise(P, out, warm, opts, t0)


# Statuses after which a slice is solved again with interior damping.
_RETRY = (Status.MAX_ITERATIONS, Status.NUMERICAL_ERROR)


def _nonconvex_not_stationary(res: CollisionResult, tol: float) -> NDArray[np.bool_]:
    """Per slice: NONCONVEX at a point whose KKT residual is above ``tol`` (NaN included), a point where no
    direction descended, not a stationary non-minimiser (which is an answer)."""
    status, kkt = np.atleast_1d(res.status), np.atleast_1d(res.kkt_residual)
    return np.array([s == Status.NONCONVEX and not k <= tol for s, k in zip(status, kkt, strict=True)], dtype=bool)


def _unsolved(res: CollisionResult, P: CollisionProblem, tol: float) -> NDArray[np.bool_]:
    """Per slice: stalled (``NOT_CERTIFIED``) or ``NONCONVEX`` at a point that is not stationary, on data an
    interior attempt can start from (f* > 0): the slices the cascade's stages 5 and 7 solve again.  (Statuses
    are enum members in an object array: ``==`` compares them element by element.)"""
    stalled = res.status == Status.NOT_CERTIFIED
    return (stalled | _nonconvex_not_stationary(res, tol)) & np.all(P.f_star > 0, axis=-1)


def _merge(res: CollisionResult, rows: NDArray[np.bool_], again: CollisionResult, take: NDArray[np.bool_]) -> None:
    """Overwrite the batch rows ``rows`` of ``res`` with the rows ``take`` of a later attempt.

    Every attempt's iterations count, whether or not its point is kept.
    """
    idx = np.flatnonzero(rows)
    res.iterations[idx] += again.iterations
    for name in ("f", "m", "objective", "kkt_residual", "mass_error", "status"):
        getattr(res, name)[idx[take]] = getattr(again, name)[take]


def _filled_start(P: CollisionProblem) -> NDArray:
    """Fluxes to the filled start :math:`f_0 = (1 - \\epsilon) f^* + \\epsilon u` (``_FILL``), per slice.

    ``u`` spreads f*'s mass over the whole interval with f*'s momentum (the uniform density tilted by
    :func:`~jko_cvx.mesh.moments.restore_moments`), so :math:`f_0` has f*'s mass and momentum, and every
    cell holds at least :math:`\\epsilon u_j > 0` (about :math:`\\epsilon` times the mean density where f*'s mean
    velocity is near the interval's centre, less at one end where it is not).  The fluxes solve the constraint
    :math:`h (f_0 - f^*) + D m = 0`: :math:`m_k = -\\sum_{j \\le k} h_j (f_{0,j} - f^*_j)`.
    """
    h = band_coefficients(P.grid, 2)[0]
    v = P.grid.points
    hf = h * P.f_star
    mass, momentum = hf.sum(axis=-1), (hf * v).sum(axis=-1)
    u, _ = restore_moments(np.ones_like(P.f_star), h[0], v, mass, momentum)  # no tilt found: u keeps the mass
    f0 = (1.0 - _FILL) * P.f_star + _FILL * u
    return -np.cumsum(h * (f0 - P.f_star), axis=-1)[:, :-1]


# The trust-region phase (_TrustRegionPhase): it hands over to the barrier attempt after this many consecutive
# full, interior Newton steps of the barrier function (the iterate is in that function's Newton region); a step
# is taken where the actual decrease is at least _TR_ACCEPT of the model's; the first radius (Jacobi-scaled
# units) is at most _TR_FIRST_RADIUS; _TR_SHRINKS radius reductions at one point end the phase (rounding).
_TR_HANDOVER = 2
_TR_ACCEPT = 1e-4
_TR_FIRST_RADIUS = 10.0
_TR_SHRINKS = 60


class _TrustRegionPhase:
    """Trust-region iterations on the barrier function of one slice (a batch of one), from the cold start.

    Where the step problem is not convex (a concave energy, gamma < 2, at a large CFL number) the modified-Newton
    directions of the line-search attempts are shifted towards the gradient and can crawl for hundreds of
    iterations through the non-convex region, or find no descent there.  The trust-region step
    (:class:`~jko_cvx.collision._trust_region.Eigensystem`) is the global minimiser of the quadratic model of
    :math:`J - \\mu \\sum_j h_j \\log f_j` (:func:`_with_barrier`) on a ball in the Jacobi-scaled fluxes
    (:math:`\\|D^{1/2} p\\| \\le \\Delta`, D the reduced Hessian's diagonal, on the momentum plane with
    ``conserve_momentum``): it follows negative curvature where the Hessian has it.  A step that would leave
    f > 0 is cut by the fraction to the boundary, and taken where J - mu sum h log f falls by at least
    ``_TR_ACCEPT`` of the model's decrease; the radius grows or shrinks with that ratio (Nocedal and Wright,
    Algorithm 4.1).  mu starts as in the barrier attempt and is lowered tenfold after a full interior step of
    small decrement (``_MU_CENTRED``).

    :meth:`run` iterates from where the last call stopped: with ``handover`` until ``_TR_HANDOVER`` consecutive
    full interior Newton steps, and in any case until the point is within ``tol``, ``max_iter`` iterations in
    all, or the radius collapses (``ended``).  ``m`` is the current point (a row), ``iterations`` the count.
    """

    def __init__(self, P: CollisionProblem, opts: NewtonOptions) -> None:
        st, _ = _start(P, None, replace(opts, m0=None))
        self.P, self.opts = P, opts
        self.m, self.f = st.m, st.f
        self.h = band_coefficients(P.grid, 2)[0]
        with np.errstate(all="ignore"):
            self.mu = _MU_START * np.abs(st.phi) / P.grid.length
            self.phi = _merit(P, self.f, self.m, self.mu)
        self.block = 2 * P.energy_coef * P.energy.flux_block()
        self.radius = np.nan
        self.iterations = 0
        self.ended = not np.isfinite(self.phi).all()

    def run(self, handover: bool) -> None:
        """Iterate (see the class docstring)."""
        newton_steps = 0
        with np.errstate(all="ignore"):
            while not self.ended:
                newton = self._iterate()
                newton_steps = newton_steps + 1 if newton else 0
                if handover and newton_steps >= _TR_HANDOVER:
                    return

    def _iterate(self) -> bool:
        """One iteration; returns whether it was a full interior Newton step.  Sets ``ended`` where it stops."""
        P, m, f, mu = self.P, self.m, self.f, self.mu
        g, bands, parts = _fused(P, f, m)
        if self.iterations >= self.opts.max_iter or not P.kkt_residual(f, m, parts).total[0] > self.opts.tol:
            self.ended = True  # the budget, or within tol (a residual that is not finite stops too)
            return False
        g, bands = _with_barrier(P, f, mu, g, bands)
        H = add_pentadiagonal(self.block, *bands)[0]
        d = np.sqrt(np.abs(np.diag(H)))
        if not (np.isfinite(H).all() and np.isfinite(g).all() and (d > 0).all()):
            self.ended = True
            return False
        Hs, gs = H / np.outer(d, d), g[0] / d
        Z = None
        if P.conserve_momentum:  # the momentum plane a'm = 0 in the scaled fluxes: a Householder basis
            u = P.grid.dv / d
            u = u / np.linalg.norm(u)
            u[0] += 1.0 if u[0] >= 0 else -1.0
            Z = (np.eye(u.size) - np.outer(u, u) * (2.0 / (u @ u)))[:, 1:]
            Hs, gs = Z.T @ Hs @ Z, Z.T @ gs
        try:
            eig = Eigensystem(Hs, gs)
        except np.linalg.LinAlgError:
            self.ended = True
            return False
        if not np.isfinite(self.radius):
            self.radius = min(float(np.linalg.norm(eig.c / np.maximum(np.abs(eig.lam), _TINY))), _TR_FIRST_RADIUS)
        rounding = 1e-15 * float(np.linalg.norm(d * m[0]))  # a scaled step below this leaves m as it is
        for _ in range(_TR_SHRINKS):
            if not self.radius > rounding:
                break
            step = eig.step(self.radius)
            q = step.q if Z is None else Z @ step.q
            p = (q / d)[None, :]
            alpha = float(_boundary_step(f, -divergence(p) / self.h)[0])
            predicted = step.predicted(alpha)
            mt = m + alpha * p
            ft = P.f_star - divergence(mt) / self.h
            phit = _merit(P, ft, mt, mu) if (ft > 0).all() else np.full(1, np.inf)
            ratio = float((self.phi - phit)[0]) / predicted if predicted > 0 else -np.inf
            if ratio >= _TR_ACCEPT:
                break
            self.radius = 0.25 * alpha * float(np.linalg.norm(step.q))
        else:
            self.ended = True  # the radius collapsed: the model's decrease is below J's rounding
            return False
        if not self.radius > rounding:  # ... or the steps it allows are below m's
            self.ended = True
            return False
        self.iterations += 1
        size = alpha * float(np.linalg.norm(step.q))
        self.m, self.f, self.phi = mt, ft, phit
        if ratio > 0.75 and size >= 0.99 * self.radius:
            self.radius *= 2.0
        elif ratio < 0.25:
            self.radius = 0.25 * size
        newton = step.interior and alpha == 1.0
        if newton and predicted <= _MU_CENTRED * abs(float(phit[0])):
            self.mu = _MU_SHRINK * mu
            self.phi = _merit(P, ft, mt, self.mu)
        return newton


_CONTINUATION_STAGES = 12
"""At most this many halvings of dt in the continuation (:func:`_continuation`): an explicit CFL number up to 4096
starts below 1."""


def _continuation(P: CollisionProblem, opts: NewtonOptions) -> tuple[CollisionResult | None, NDArray, NDArray]:
    """The step solved along dt / 2^k, ..., dt / 2, dt, each stage started from the last one's point.

    The constraint does not involve dt, so every stage's point is feasible for the next; the first stage's dt
    brings the explicit CFL number below one, where the start is close to the minimiser, and each doubling of
    dt then moves the minimiser by a step Newton's local convergence covers.  For steps the other attempts
    leave at a point that is not stationary with no descending direction: large CFL numbers with a concave
    energy (gamma < 2).  A slice leaves at the first stage it cannot certify (its point is no start for the
    next, and the cost of a hopeless path is bounded).

    Returns the result at dt itself of the slices that reached it (None if none did), those slices (a mask of
    P's rows), and every slice's iterations over all its stages.
    """
    k = int(np.clip(np.ceil(np.log2(max(P.cfl(), 1.0))), 1, _CONTINUATION_STAGES))
    alive = np.ones(P.batch_size, dtype=bool)
    m = np.full((P.batch_size, P.n - 1), np.nan)  # _start takes m0 only where it is finite: the first stage starts cold
    iterations = np.zeros(P.batch_size, dtype=int)
    for stage in range(k, -1, -1):
        idx = np.flatnonzero(alive)
        res = _cascade(P.rows(alive).with_dt(P.dt / 2.0**stage), m[alive], opts, continuation=False)
        iterations[idx] += res.iterations
        if stage == 0:
            return res, alive, iterations
        ok = np.array([s is Status.CONVERGED for s in res.status], dtype=bool)
        m[idx] = res.m
        alive[idx[~ok]] = False
        if not alive.any():
            break
    return None, alive, iterations


def _cascade(
    P: CollisionProblem, m0: NDArray | None, opts: NewtonOptions, continuation: bool = True
) -> CollisionResult:
    """The retry cascade, per slice.

    1. Undamped, ending a slice whose iterates jam at the vacuum boundary.
    2. Slices that ended without a solution (``_RETRY``): again with interior damping.
    3. Slices that had jammed and still are not ``CONVERGED``: a third time undamped
       without the jam test (a slice may only look jammed: gamma = 3, lambda = 10); the
       attempt with the smaller residual is kept.
    4. Slices still without a solution (``_RETRY``, ``NOT_CERTIFIED``, or ``NONCONVEX`` at a point that
       is not stationary, KKT residual above ``tol``): a barrier attempt
       (:func:`_with_barrier`), for minimisers on the vacuum boundary (large steps empty
       cells: explicit CFL numbers of 20 and more); kept where its residual is smaller.
       The same attempt is a second start for the slices that jammed and that a later attempt
       certified: the step is not convex, and the jam marks a path that met the vacuum
       boundary (two bumps facing each other across an empty gap), where the damped attempt
       creeps to a local minimiser that keeps the gap empty while the lower one fills it.  The
       barrier keeps the iterates off that boundary; this attempt starts cold (the explicit step)
       also where ``m0`` is given, which would begin in the first point's basin.  Its answer
       replaces the first only if it is certified (and, with ``check_convexity=False``, passes the
       second-order test) and its J is lower beyond rounding (``_LOWER``, relative), and
       ``info["lower_minimum"]`` marks those slices: another minimiser, or the same one reached more
       accurately.  Slices certified by the first attempt, and certified slices that did not jam, are
       never solved again, so their results do not depend on this stage.
    5. Slices ``NOT_CERTIFIED`` (a stall) or ``NONCONVEX`` at a point that is not stationary: once more with
       the modified-Newton shifts of each row's own size (:func:`_shift`; a concave energy beside an emptied
       cell, whose curvature floored the shifts so that the step vanished), kept where it certifies; then the
       slices still stalled, with the barrier from the other cold start (``start`` "zero" for "explicit" and
       the other way round), kept where it certifies or stalls at a smaller residual
       (``info["row_shift"]``).
    6. Slices ``NONCONVEX`` at a point that is not stationary, on a step of explicit CFL number above one: a
       continuation in dt (:func:`_continuation`), kept where it certifies.
    7. Slices still ``NOT_CERTIFIED`` or ``NONCONVEX`` at a point that is not stationary: the barrier attempt
       from the filled start (:func:`_filled_start`, ``info["filled_start"]``), kept where it certifies; then
       the slices it leaves without a solution, the same with the row-sized shifts (``info["row_shift"]``
       too).  Every start before it begins at f* or moves from f* by one explicit step, and where the
       minimiser fills an emptied interval (tails at 1e-22 of the maximum, the minimiser's at 1e-10) a step
       into an emptied cell is bounded by that cell's content: the iterates stall where they began.

    8. Slices still without a solution (``NOT_CERTIFIED``, ``MAX_ITERATIONS``, ``NUMERICAL_ERROR``, or
       ``NONCONVEX`` at a point that is not stationary; f* > 0): the trust-region phase
       (:class:`_TrustRegionPhase`) from the cold start to the barrier function's Newton region, then the
       barrier attempt from its point, kept where it certifies (``info["trust_region"]``, with ``barrier``);
       where that fails, the phase on from that point without the hand-over (to ``tol``, or ``max_iter``
       iterations in all) and the barrier attempt from where it ends.  A stationary point that is not a
       minimiser (``NONCONVEX`` within ``tol``) is kept too where the slice's point is not stationary.  A
       line-search attempt whose modified-Newton directions cross a non-convex region (gamma < 2 at CFL numbers
       above 100) takes shifted, gradient-like steps there: it crawls for a hundred iterations or more, or finds
       no descent; the trust-region step minimises the model on a ball and follows its negative curvature.  The
       phase and each attempt have the budget ``max_iter``.

    Stages 5 to 8 run only on slices that every stage before left without a solution, so the results of
    slices certified before them do not depend on them; ``continuation=False`` (the continuation's own
    stages) leaves out stages 6, 7 and 8.
    """
    res = _attempt(P, m0, opts, _Attempt(damping=False, jam_exit=True))
    jammed = res.info["jammed"]
    damped = np.zeros(jammed.shape, dtype=bool)
    barrier = np.zeros(jammed.shape, dtype=bool)
    if all(s is Status.CONVERGED for s in res.status):  # the common case (a jam ends a slice unconverged): no retry
        res.info.update(jammed=jammed, interior_damping=damped, barrier=barrier, lower_minimum=np.zeros_like(jammed),
                        row_shift=np.zeros_like(jammed), continued=np.zeros_like(jammed),
                        filled_start=np.zeros_like(jammed), trust_region=np.zeros_like(jammed))  # fmt: skip
        return res
    retry = np.array([s in _RETRY for s in res.status]) & np.all(P.f_star > 0, axis=-1)
    if retry.any():
        again = _attempt(P.rows(retry), _m0_rows(m0, retry), opts, _Attempt(True, False))
        _merge(res, retry, again, np.ones(int(retry.sum()), dtype=bool))
        damped[retry] = True
        fallback = retry & jammed
        fallback[fallback] = res.status[fallback] != Status.CONVERGED
        if fallback.any():
            plain = _attempt(P.rows(fallback), _m0_rows(m0, fallback), opts, _Attempt(False, False))
            better = plain.kkt_residual < res.kkt_residual[fallback]
            _merge(res, fallback, plain, better)
            damped[np.flatnonzero(fallback)[better]] = False
    # NONCONVEX above tol: the iteration limit or a failed shift ended a slice that is no stationary point (a
    # minimiser on the vacuum boundary looks so to the interior iteration); a stationary non-minimiser is kept
    # (a NaN residual is no stationary point either); such a slice keeps its NONCONVEX unless the barrier certifies
    nonconvex = _nonconvex_not_stationary(res, opts.tol)
    unfinished = np.array([s in _RETRY or s == Status.NOT_CERTIFIED for s in res.status], dtype=bool) | nonconvex
    certified = np.array([s == Status.CONVERGED for s in res.status], dtype=bool)
    rival = jammed & certified & opts.second_start  # a jam a later attempt certified: start again, for a lower J
    lower = np.zeros(jammed.shape, dtype=bool)
    todo = (unfinished | rival) & np.all(P.f_star > 0, axis=-1)
    if todo.any():
        Pt, second = P.rows(todo), rival[todo]
        start = _m0_rows(m0, todo)
        if start is not None and second.any():  # the second start is cold: a warm start begins in the first's basin
            start = start.copy()
            start[second] = np.nan  # _start takes m0 only where it is finite
        again = _attempt(Pt, start, opts, _Attempt(False, False, barrier=True))
        ok = again.status == Status.CONVERGED
        smaller = (again.kkt_residual < res.kkt_residual[todo]) & ~nonconvex[todo]
        J_first = res.objective[todo]
        with np.errstate(invalid="ignore"):  # J at the edge of the float range: inf - inf, no replacement
            below = ok & second & (again.objective < J_first - _LOWER * np.abs(J_first))
        if not opts.check_convexity:  # a certified point may then be any stationary one: replace only by a minimiser
            for k in np.flatnonzero(below):
                below[k] = Pt.slice(int(k)).is_local_minimiser(again.f[k], again.m[k])
        better = np.where(second, below, ok | smaller)
        _merge(res, todo, again, better)
        barrier[np.flatnonzero(todo)[better]] = True
        damped[np.flatnonzero(todo)[better]] = False
        lower[np.flatnonzero(todo)[better & second]] = True
    # NOT_CERTIFIED (a stall) or NONCONVEX at a point that is not stationary: where a diagonal entry of the
    # reduced Hessian was not positive, the global floor of the shifts may have frozen the step (_shift);
    # once more with each row's own shift, kept where it certifies
    shifted = np.zeros(jammed.shape, dtype=bool)
    stuck = _unsolved(res, P, opts.tol)
    if stuck.any():
        again = _attempt(P.rows(stuck), _m0_rows(m0, stuck), opts, _Attempt(False, False, row_shift=True))
        ok = again.status == Status.CONVERGED
        _merge(res, stuck, again, ok)
        won = np.flatnonzero(stuck)[ok]
        shifted[won], damped[won], barrier[won] = True, False, False
        # a slice still stalled above tol (the barrier's path met the vacuum boundary where the minimiser is not):
        # the barrier again from the cold start other than `start`, kept where it certifies or stalls lower
        stalled = stuck & (res.status == Status.NOT_CERTIFIED)
        if stalled.any():
            other = replace(opts, start="zero" if opts.start == "explicit" else "explicit", m0=None)
            again = _attempt(P.rows(stalled), None, other, _Attempt(False, False, barrier=True, row_shift=True))
            stall = again.status == Status.NOT_CERTIFIED
            better = (again.status == Status.CONVERGED) | (stall & (again.kkt_residual < res.kkt_residual[stalled]))
            _merge(res, stalled, again, better)
            won = np.flatnonzero(stalled)[better]
            shifted[won], damped[won], barrier[won] = True, False, True
    continued = np.zeros(jammed.shape, dtype=bool)
    if continuation and P.cfl() > 1.0:
        # only where no direction descended at a point that is not stationary: an iteration limit keeps its
        # meaning (max_iter=k returns the k-th iterate), and a stationary non-minimiser is the answer
        rest = _nonconvex_not_stationary(res, opts.tol) & np.all(P.f_star > 0, axis=-1)
        if rest.any():
            again, reached, iterations = _continuation(P.rows(rest), opts)
            res.iterations[np.flatnonzero(rest)] += iterations  # every stage counts, kept or not
            if again is not None:
                rows = np.zeros(rest.shape, dtype=bool)
                rows[np.flatnonzero(rest)[reached]] = True  # the slices whose last stage was dt itself
                ok = again.status == Status.CONVERGED
                again.iterations[:] = 0  # counted above
                _merge(res, rows, again, ok)
                won = np.flatnonzero(rows)[ok]
                continued[won], damped[won], barrier[won], shifted[won] = True, False, False, False
    filled = np.zeros(jammed.shape, dtype=bool)
    if continuation:
        rest = _unsolved(res, P, opts.tol)
        if rest.any():
            Pr, idx = P.rows(rest), np.flatnonzero(rest)
            m_fill = _filled_start(Pr)
            again = _attempt(Pr, m_fill, opts, _Attempt(False, False, barrier=True))
            ok = again.status == Status.CONVERGED
            _merge(res, rest, again, ok)
            filled[idx[ok]], barrier[idx[ok]] = True, True
            damped[idx[ok]], shifted[idx[ok]], continued[idx[ok]] = False, False, False
            # the same start with each row's own shifts: where a concave energy beside a cell the step empties
            # froze the globally shifted step (stage 5's mechanism, met on the way from this start)
            if not ok.all():
                left = np.zeros(rest.shape, dtype=bool)
                left[idx[~ok]] = True
                again = _attempt(P.rows(left), m_fill[~ok], opts, _Attempt(False, False, barrier=True, row_shift=True))
                ok = again.status == Status.CONVERGED
                _merge(res, left, again, ok)
                won = np.flatnonzero(left)[ok]
                filled[won], barrier[won], shifted[won] = True, True, True
                damped[won], continued[won] = False, False
    trusted = np.zeros(jammed.shape, dtype=bool)
    if continuation:
        # every slice still without a solution (the iteration limit included: each attempt keeps its budget)
        stopped = (res.status == Status.MAX_ITERATIONS) | (res.status == Status.NUMERICAL_ERROR)
        rest = _unsolved(res, P, opts.tol) | (stopped & np.all(P.f_star > 0, axis=-1))
        if rest.any():
            phases = {k: _TrustRegionPhase(P.rows(slice(k, k + 1)), opts) for k in np.flatnonzero(rest)}
            for handover in (True, False):
                # the phase to the Newton region, then (where the attempt from there fails) on from that point
                idx = np.array([k for k in np.flatnonzero(rest) if handover or not phases[k].ended], dtype=int)
                if idx.size == 0:
                    break
                counted = np.array([phases[k].iterations for k in idx])
                for k in idx:
                    phases[k].run(handover)
                rows = np.zeros(rest.shape, dtype=bool)
                rows[idx] = True
                start = np.concatenate([phases[k].m for k in idx])
                again = _attempt(P.rows(rows), start, opts, _Attempt(False, False, barrier=True))
                again.iterations = again.iterations + np.array([phases[k].iterations for k in idx]) - counted
                ok = again.status == Status.CONVERGED
                # a stationary point that is not a minimiser (NONCONVEX within tol) is an answer, as elsewhere in the
                # cascade: it replaces a point that is not stationary (the slice stays in for the second pass)
                with np.errstate(invalid="ignore"):
                    stationary = (again.status == Status.NONCONVEX) & (again.kkt_residual <= opts.tol)
                    take = ok | (stationary & ~(res.kkt_residual[idx] <= opts.tol))
                _merge(res, rows, again, take)
                won = idx[take]
                trusted[won], barrier[won] = True, True
                damped[won], shifted[won], continued[won], filled[won] = False, False, False, False
                rest[idx[ok]] = False
    res.info.update(jammed=jammed, interior_damping=damped, barrier=barrier, lower_minimum=lower, row_shift=shifted,
                    continued=continued, filled_start=filled, trust_region=trusted)  # fmt: skip
    return res


@functools.cache
def _compiled_module():
    """:mod:`jko_cvx.collision._compiled`, imported at the first solve that uses it (numba loads then)."""
    return importlib.import_module("jko_cvx.collision._compiled")


def _compiled_energy(P: CollisionProblem) -> tuple[NDArray, Semiseparable3 | None] | None:
    """What the compiled iteration needs of the energy block: its diagonal times ``2 dt sigma`` and, for gamma = 3,
    the structured solve the NumPy iteration takes (:func:`~jko_cvx.collision._structured.semiseparable3`, the
    same cached instance); None where the block is neither."""
    fb = P.energy.flux_structure()
    scale = 2 * P.energy_coef
    if fb.kind == "diagonal":
        return scale * fb.diag, None
    solve = semiseparable3(P.energy, scale)
    return None if solve is None else (scale * solve.e_diag, solve)


_CONSTANTS_PER_OPERATOR = 8
"""Steps' constants kept per energy operator (:func:`_compiled_constants`): the distinct (dt, strength, Fisher
weight, momentum constraint) of a run on one grid; an adaptive run's changing dt replaces them."""


def _compiled_constants(P: CollisionProblem) -> tuple | None:
    """The step's constants for the compiled iteration (``_compiled.constants``), None where the compiled
    iteration does not apply (:func:`_compiled_energy`); for W = |v| (gamma = 1) the products ``K f`` are
    running sums, O(N) (the dense K's to rounding).

    They are functions of the grid's points (of which the energy operator is the cached, shared function:
    :meth:`~jko_cvx.kernels.PowerKernel.energy_operator`) and of the step's scalars, and are kept with the
    operator under those scalars: the steps of a run on one grid build them once.
    """
    energy = P.energy
    key = (type(P.kernel), P.kernel.gamma, P.fisher, P.c_fisher, P.energy_coef, P.conserve_momentum)
    cache = energy.__dict__.setdefault("_compiled_constants", {})
    hit = cache.get(key)
    if hit is not None:
        return hit[0]
    block = _compiled_energy(P)
    consts = None
    if block is not None:
        energy_diag, semiseparable = block
        g = P.grid
        consts = _compiled_module().constants(
            g.h, g.points, P.wass_coef, P.fisher_coef if P.fisher else None, P.fisher, energy.dense(),
            P.energy_coef, energy_diag, g.dv if P.conserve_momentum else None,
            type(P.kernel) is PowerKernel and P.kernel.gamma == 1.0, semiseparable,
        )  # fmt: skip
    if len(cache) >= _CONSTANTS_PER_OPERATOR:
        cache.clear()
    cache[key] = (consts,)
    return consts


def _compiled_single(P: CollisionProblem, opts: NewtonOptions, t0: float) -> CollisionResult | None:
    """The first attempt of :func:`_cascade` on the unbatched problem ``P``, as compiled code, where it applies.

    :mod:`jko_cvx.collision._compiled` runs the undamped iteration from the same start (that of
    :func:`_start`) for an energy block diagonal in the fluxes (gamma = 1) or with the gamma = 3 structured
    solve (:func:`_compiled_energy`).  Its point is judged here as
    the NumPy iteration's would be -- the KKT residual (the shared one's expressions, compiled) within
    ``tol``, the reduced Hessian positive definite there -- and certified by the shared certificate.
    Anything else, a point the certificate does not accept as ``CONVERGED`` included, returns None: the
    caller then runs :func:`_cascade` from the start, so a hard step gets every device of the NumPy
    iteration (and its result bit for bit).
    """
    if not P.f_star.min() > 0:
        return None
    consts = _compiled_constants(P)
    if consts is None:
        return None
    m, phi, warm = None, np.nan, False
    if opts.m0 is not None:  # a warm start: where it is used, and J there, as the NumPy iteration decides
        st, used = _start(P.rows(slice(None)), opts.m0[None], opts)
        m, phi, warm = st.m[0], st.phi[0], bool(used[0])
    compiled = _compiled_module()
    # As in _iterate: the residual is checked where the decrement reached tol; where it is still above
    # tol the iteration goes on from there, up to _STALL_CHECKS checks (a stall is the NumPy path's case).
    m, f, phi, iterations, code, kkt = compiled.iterate(
        P.f_star, m, phi, consts, opts.start == "explicit", opts.tol, opts.max_iter, _PD_TOL, _JAM, _JAM_STEP,
        _STALL_CHECKS,
    )  # fmt: skip
    if code != compiled.HANDLED or not kkt <= opts.tol:
        return None
    # J as the compiled iteration evaluated it at the point (problem.objective's to rounding); the
    # second-order test is the factorisation's at the point (HANDLED: positive definite)
    cert = certify_validated(
        P, f, m, opts.kkt_tol, opts.check_convexity, Status.CONVERGED, residual=kkt, second_order=True,
        objective=phi,
    )  # fmt: skip
    if cert.status is not Status.CONVERGED:  # the cascade goes on from such a first attempt: solve it all there
        return None
    info = {"warm_started": warm, "jammed": False, "interior_damping": False, "barrier": False,
            "lower_minimum": False, "row_shift": False, "continued": False, "filled_start": False,
            "trust_region": False, "compiled": True}  # fmt: skip
    return CollisionResult.from_certificate(P, f, m, cert, "newton", iterations, time.perf_counter() - t0, info)


def _compiled_batch(P: CollisionProblem, opts: NewtonOptions, t0: float) -> CollisionResult | None:
    """:func:`_compiled_single` for each slice of the batch ``P``, in one compiled loop per slice thread
    (:func:`~jko_cvx.threads.map_chunks`); the rest by the cascade.

    The slices whose compiled attempt returns a point that the shared certificate accepts as ``CONVERGED``
    take it; every other slice (data with a zero, a slice the compiled attempt hands back, a point the
    certificate does not accept) is solved by :func:`_cascade` from the start, in one batch of those slices.
    None where no slice takes the compiled point (the caller then runs the cascade on the whole batch).
    """
    consts = _compiled_constants(P)
    if consts is None:
        return None
    B, n = P.f_star.shape
    eligible = P.f_star.min(axis=1) > 0
    if not eligible.any():
        return None
    compiled = _compiled_module()

    m0 = None if opts.m0 is None else np.broadcast_to(opts.m0, (B, n - 1))
    warm = np.zeros(B, dtype=bool)
    if m0 is not None:  # a warm start: where it is used, and J there, as the NumPy iteration decides
        st, warm = _start(P, m0, opts)
        m, phi, start = np.array(st.m, dtype=float), np.array(st.phi, dtype=float), 0
    else:
        m, phi, start = np.zeros((B, n - 1)), np.full(B, np.nan), 1 if opts.start == "explicit" else 2
    # m, phi: this call's own arrays, which the compiled loop overwrites in place; it writes every row of these
    f, kkt = np.empty((B, n)), np.empty(B)
    its, code = np.empty(B, dtype=np.int64), np.empty(B, dtype=np.int64)

    def work(a: int, b: int) -> None:  # the rows a:b, in the slice threads (the compiled loop releases the GIL)
        compiled.iterate_rows(
            P.f_star[a:b], m[a:b], f[a:b], phi[a:b], its[a:b], code[a:b], kkt[a:b], start, eligible[a:b], consts,
            opts.tol, opts.max_iter, _PD_TOL, _JAM, _JAM_STEP, _STALL_CHECKS,
        )  # fmt: skip

    map_chunks(work, B)  # each row's result is its own whatever the chunks: the same bits for any thread count
    with np.errstate(all="ignore"):
        done = eligible & (code == compiled.HANDLED) & (kkt <= opts.tol)
        every = bool(done.all())  # the common case: no copies of the batch
        if not every and not done.any():
            return None
        Pd = P if every else P.rows(done)
        fd, md = (f, m) if every else (f[done], m[done])
        k = Pd.batch_size
        cert = certify_validated(
            Pd, fd, md, opts.kkt_tol, opts.check_convexity, None, residual=kkt if every else kkt[done],
            second_order=np.ones(k, dtype=bool), objective=phi if every else phi[done],
        )  # fmt: skip
        accepted = cert.status == Status.CONVERGED  # statuses are enum members: equality is identity
        if every:
            mass_error = Pd.mass_error(fd)
        else:
            mass_error = np.zeros(B)
            mass_error[done] = Pd.mass_error(fd)
    done[done] = accepted
    if not done.any():
        return None
    flags = (
        "jammed", "interior_damping", "barrier", "lower_minimum", "row_shift", "continued", "filled_start",
        "trust_region",
    )  # fmt: skip
    info = {"warm_started": warm & done, **{name: np.zeros(B, dtype=bool) for name in flags}, "compiled": done}
    if done.all():  # every slice compiled and certified (so every was True): the result as it stands
        return CollisionResult(f, m, cert.status, "newton", its, phi, kkt, mass_error, time.perf_counter() - t0, info)
    res = CollisionResult(f, m, _converged(B), "newton", np.where(done, its, 0), phi, kkt, mass_error, 0.0, info)
    rest = ~done  # the cascade on those slices, from the start
    again = _cascade(P.rows(rest), _m0_rows(m0, rest), opts)
    for name in ("f", "m", "status", "iterations", "objective", "kkt_residual", "mass_error"):
        getattr(res, name)[rest] = getattr(again, name)
    for name in ("warm_started", *flags):
        info[name][rest] = again.info[name]
    res.seconds = time.perf_counter() - t0
    return res


def _converged(k: int) -> NDArray:
    """``k`` statuses ``CONVERGED`` (an object array; ``fill`` costs a fifth of ``np.full``'s object path)."""
    out = np.empty(k, dtype=object)
    out.fill(Status.CONVERGED)
    return out


def _m0_rows(m0: NDArray | None, rows: NDArray[np.bool_]) -> NDArray | None:
    """The warm start restricted to the batch rows ``rows``."""
    return None if m0 is None else m0[rows]


def _single(res: CollisionResult) -> CollisionResult:
    """The one-slice batch result as an unbatched one."""
    info = {}
    for key, value in res.info.items():
        v = value[0] if isinstance(value, np.ndarray) else value
        info[key] = bool(v) if isinstance(v, np.bool_) else v
    return CollisionResult(
        res.f[0],
        res.m[0],
        res.status[0],
        res.method,
        int(res.iterations[0]),
        float(res.objective[0]),
        float(res.kkt_residual[0]),
        float(res.mass_error[0]),
        res.seconds,
        info,
    )


@blas_limited  # BLAS threads per jko_cvx.threads
def solve_newton(
    problem: CollisionProblem,
    *,
    tol: float = 1e-10,
    kkt_tol: float | None = None,
    max_iter: int = 100,
    m0: Any = None,
    start: str = "explicit",
    check_convexity: bool = True,
    second_start: bool = True,
    compiled: bool = False,
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
        only if its residual is at most ``kkt_tol``, else ``NOT_CERTIFIED``.  Default
        ``tol``: its iterations reach ``tol`` quadratically, so a looser threshold would
        only relabel slices that stalled at their rounding floor above ``tol``.
    max_iter : int, default 100
        Newton iterations per attempt (status ``MAX_ITERATIONS`` beyond).
    m0 : array_like, optional
        Warm start: fluxes of shape ``(N-1,)`` or ``(B, N-1)`` (e.g. the previous
        solution's ``m``), used only where it keeps ``f(m0) > 0`` (else ``start``).  With
        ``conserve_momentum`` it is first projected onto :math:`\\sum_k m_k\\Delta v_k = 0`.
    start : {"explicit", "zero"}, default "explicit"
        Starting point without ``m0``: the explicit step (:func:`~jko_cvx.collision.sqp.explicit_step`,
        damped to keep f >= f*/2 and kept only if it lowers J) or ``m = 0``.
    check_convexity : bool, default True
        Report ``NONCONVEX`` when the reduced Hessian at the final point is not positive
        definite (a stationary point that is not a minimiser).
    second_start : bool, default True
        Solve a slice whose first attempt jammed at the vacuum boundary, and that a later
        attempt certified, once more with the barrier attempt (from a cold start, also with
        ``m0``), and return the certified point with the lower J (the step is not convex: the
        two can be different local minimisers; see :func:`_cascade`).  False returns the first
        certified point (cheaper, and the higher minimiser where there are two).
    compiled : bool, default False
        Run the first attempt of each slice whose energy block is diagonal in the fluxes (gamma = 1) or
        takes the exact structured solve (gamma = 3) as compiled code (:mod:`jko_cvx.collision._compiled`;
        needs numba, the ``fast`` extra; a batch in one compiled loop over its slices, in the slice
        threads): the same iteration and direction from the same start, its point judged
        by the same KKT residual (its expressions compiled) and the same certificate, equal to the NumPy
        iteration's to rounding, at a fraction of its time per solve.  A slice it does not finish
        cleanly (a Hessian that needs a shift, a run of short steps, the iteration limit, data with a
        zero) is solved by the NumPy iteration from the start, with the other such slices of the batch.
        Other kernels always take the NumPy iteration.  The first use on a machine compiles (cached on
        disk), and each process pays to import numba and load the cached code: worth it for many
        solves, not for one short run (the solver guide measures both).

    Returns
    -------
    CollisionResult
        One status per slice for a batched problem.  ``info`` holds ``warm_started`` (``m0`` was
        taken as the first attempt's start: finite, and f > 0 there; the flags below say which
        attempt the returned point comes from, some of which start cold),
        ``jammed`` (the first, undamped attempt ended on a jam), ``interior_damping``
        (the returned point comes from the interior-damped attempt) and ``barrier`` (it
        comes from the barrier attempt) and ``lower_minimum`` (the second start found a certified
        local minimiser with a lower J than the one first certified, beyond rounding, and that is
        returned: another minimiser, or the same one reached more accurately), ``row_shift`` (it comes
        from the attempt whose modified-Newton shifts have each row's own size), ``continued`` (it comes
        from the continuation in dt), ``filled_start`` (it comes from the barrier attempt started at f* with a
        floor spread over the interval; ``barrier`` is then set too, and ``row_shift`` where that attempt took
        the row-sized shifts), ``trust_region`` (it comes from the barrier attempt started where the
        trust-region phase ended, the cascade's last resort; ``barrier`` is then set too) and ``compiled`` (the
        point comes from the compiled iteration); per slice when batched.  ``iterations`` counts every
        attempt (the compiled one only where its point is returned).
        A single problem is solved as a batch of one.
    """
    opts = _check_newton_args(problem, tol, kkt_tol, max_iter, m0, start, check_convexity, second_start, compiled)
    t0 = time.perf_counter()
    if opts.compiled:
        res = _compiled_batch(problem, opts, t0) if problem.batched else _compiled_single(problem, opts, t0)
        if res is not None:
            return res
    batch = problem if problem.batched else problem.rows(slice(None))
    m0 = opts.m0
    m0 = None if m0 is None else np.broadcast_to(m0, batch.f_star.shape[:1] + m0.shape[-1:])
    res = _cascade(batch, m0, opts)
    res.info["compiled"] = np.zeros(batch.batch_size, dtype=bool)
    res.seconds = time.perf_counter() - t0
    if problem.batched:
        return res
    res = _single(res)
    if _nonconvex_not_stationary(res, opts.tol)[0]:
        # no stationary point: the modified directions found no descent there (not a saddle point it reached)
        res.info["hint"] = (
            f"at a point that is not stationary (KKT {res.kkt_residual:.1e}): no shifted Newton direction "
            "descended there, and no retry (barrier, row-sized shifts, continuation in dt, filled start, trust region) "
            "reached a minimiser; method='nlp' is the reference for such steps"
        )
    return res


solve_newton.batched = True  # type: ignore[attr-defined]


@functools.lru_cache(maxsize=64, typed=True)
def _checked_options(
    tol: Any, kkt_tol: Any, max_iter: Any, start: Any, check_convexity: Any, second_start: Any, compiled: Any
) -> NewtonOptions:
    """:class:`NewtonOptions` of these values, checked once per distinct values and types.

    ``typed=True``: ``1``, ``1.0``, ``True`` and ``np.float64(1.0)`` are separate entries, each
    checked on its own; a value that fails raises every time (exceptions are not cached).
    """
    return NewtonOptions(
        tol=tol, kkt_tol=kkt_tol, max_iter=max_iter, start=start, check_convexity=check_convexity,
        second_start=second_start, compiled=compiled,
    )  # fmt: skip


def _check_newton_args(
    problem: CollisionProblem,
    tol: Any,
    kkt_tol: Any,
    max_iter: Any,
    m0: Any,
    start: Any,
    check_convexity: Any,
    second_start: Any,
    compiled: Any,
) -> NewtonOptions:
    """The checked options, the warm start checked against ``problem``; errors name the option."""
    try:
        opts = _checked_options(tol, kkt_tol, max_iter, start, check_convexity, second_start, compiled)
    except TypeError as exc:  # an unhashable argument: check it without the cache
        if "unhashable" not in str(exc):
            raise
        opts = NewtonOptions(
            tol=tol, kkt_tol=kkt_tol, max_iter=max_iter, start=start, check_convexity=check_convexity,
            second_start=second_start, compiled=compiled,
        )  # fmt: skip
    if m0 is None:
        return opts
    shape = (*problem.f_star.shape[:-1], problem.n - 1)
    try:
        m0 = np.broadcast_to(np.asarray(m0, dtype=float), shape)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"m0 must be None or fluxes of shape {(problem.n - 1,)}"
            + (f" or {shape}" if problem.batched else "")
            + f", got {np.shape(m0)}"
        ) from exc
    return replace(opts, m0=m0)
