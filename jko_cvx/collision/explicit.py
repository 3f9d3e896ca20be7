"""The explicit step: the SQP subproblem with the diagonal Hessian of F, in O(N).

From a feasible point :math:`u = (f, m)` the paper's SQP (Algorithm ``alg:non_uni_JKO``)
takes the step :math:`p` that minimises
:math:`\\tfrac12 p^\\top \\operatorname{diag}(\\nabla^2 F)\\, p + \\nabla J^\\top p` subject to
:math:`A p = 0` (F = Wasserstein + Fisher; the energy Hessian is left out, as in the paper).
Every feasible direction is :math:`p_f = -D p_m / h`, so the QP reduces to the
tridiagonal system

.. math::  \\big(D^\\top \\operatorname{diag}(H_f/h^2) D + \\operatorname{diag}(H_m)\\big)\\,p_m
           = -\\big(\\nabla_m J - D^\\top(\\nabla_f J / h)\\big),

positive definite because :math:`H_m = 4\\Delta v/s > 0`.  From :math:`(f^*, 0)` the Hessian
has no f-m coupling and the step is the explicit-Euler step of the collision operator
(:func:`explicit_step`): the conic reference takes its scale from it and Newton starts from
it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack

from jko_cvx.collision.linalg import divergence, divergence_adjoint, solve_sym_tridiagonal
from jko_cvx.collision.problem import CollisionProblem
from jko_cvx.collision.terms import FISHER_TERMS, wasserstein_derivatives

__all__ = ["diagonal_hessian", "explicit_step", "gradient_and_sqp_step", "sqp_step", "sqp_stepper"]


def diagonal_hessian(problem: CollisionProblem, f: NDArray, m: NDArray) -> tuple[NDArray, NDArray]:
    """Diagonal of the Hessian of F (Wasserstein + Fisher) in f and in m (batched like ``f``)."""
    e = problem.edge_hessian(f, m)
    hf = np.zeros_like(f)
    hf[..., :-1] += e["xx"]
    hf[..., 1:] += e["yy"]
    return hf, e["mm"]


def sqp_step(
    problem: CollisionProblem, f: NDArray, m: NDArray, gf: NDArray, gm: NDArray
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The SQP step ``(p_f, p_m)`` from the feasible point ``(f, m)`` with gradient ``(gf, gm)``.

    One tridiagonal solve per slice (see the module docstring); ``p_f = -D p_m / h``, so
    ``(f + p_f, m + p_m)`` is feasible.
    """
    hf, hm = diagonal_hessian(problem, f, m)
    return _step_from(problem, hf, hm, gf, gm)


def _step_from(
    problem: CollisionProblem, hf: NDArray, hm: NDArray, gf: NDArray, gm: NDArray
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The step ``(p_f, p_m)`` of the tridiagonal system from the diagonal Hessian and the gradient."""
    h = problem.grid.h
    a = hf / h**2
    diag = a[..., :-1] + a[..., 1:] + hm
    off = -a[..., 1:-1]
    rhs = -(gm - divergence_adjoint(gf / h))
    pm = solve_sym_tridiagonal(diag, off, rhs)
    pf = -divergence(pm) / h
    return pf, pm


def gradient_and_sqp_step(
    problem: CollisionProblem, f: NDArray, m: NDArray
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``problem.gradient(f, m)`` and :func:`sqp_step` from it, with the shared terms evaluated once.

    One SQP iteration needs the gradient of J and the diagonal Hessian of F at the same
    point; both start from the Wasserstein derivatives in :math:`(m, s)`, :math:`s = f_k + f_{k+1}`.
    Where no edge is empty (s > 0 everywhere: every iterate of the safeguarded SQP) they
    are computed once, by the same operations as :meth:`CollisionProblem.gradient_parts` and
    :meth:`CollisionProblem.edge_hessian` (so bitwise the same step); with an empty edge the
    guarded general path runs.  Returns ``(gf, gm, pf, pm)``.
    """
    x, y = f[..., :-1], f[..., 1:]
    s = x + y
    if not np.all(s > 0):
        gf, gm = problem.gradient(f, m)
        return (gf, gm, *sqp_step(problem, f, m, gf, gm))
    wd = wasserstein_derivatives(m, s, problem.wass_coef)
    gfw = np.zeros_like(f)
    gfw[..., :-1] += wd.g_s
    gfw[..., 1:] += wd.g_s
    gff = np.zeros_like(f)
    hf = np.zeros_like(f)
    if problem.fisher is None:
        hf[..., :-1] += wd.h_ss
        hf[..., 1:] += wd.h_ss
    else:
        term = FISHER_TERMS[problem.fisher]
        gx, gy = term.gradient(x, y, s, problem.fisher_coef)
        gff[..., :-1] += gx
        gff[..., 1:] += gy
        hx, hy, _ = term.hessian(x, y, s, problem.fisher_coef)
        hf[..., :-1] += wd.h_ss + hx
        hf[..., 1:] += wd.h_ss + hy
    gf = gfw + gff + 2 * problem.energy_coef * problem.energy.matvec(f)
    return (gf, wd.g_m, *_step_from(problem, hf, wd.h_mm, gf, wd.g_m))


def sqp_stepper(problem: CollisionProblem) -> Callable[[NDArray, NDArray], tuple[NDArray, NDArray]]:
    """The banded SQP step of one unbatched problem as a function ``(f, m) -> (p_f, p_m)``, for the SQP loop.

    Bitwise the step of :func:`gradient_and_sqp_step` (its last two outputs): the same
    operations on the same operands in the same order, with what does not change between
    iterations evaluated once (``h**2``, ``-w``, ``2 w``, ``2 dt sigma``), the subexpressions
    the gradient and the Hessian share evaluated once, the mixed Hessian entries (unused by
    the step) not evaluated, and the node sums written into scratch arrays.  One iteration
    is a few dozen calls on arrays of N ~ 100 points, so their count is its cost.  An empty
    edge (some ``f_k + f_{k+1} <= 0``, or NaN) takes the guarded general path, as there.

    The returned ``p_f`` and ``p_m`` are new arrays on every call.
    """
    if problem.batched:
        raise ValueError("sqp_stepper takes one problem; pass problem.slice(i)")
    n = problem.n
    h = problem.grid.h
    h2 = h**2
    w = problem.wass_coef
    minus_w, two_w = -w, 2 * w
    c = problem.fisher_coef
    fisher = None if problem.fisher is None else FISHER_TERMS[problem.fisher].gradient_and_hessian
    energy_coef = 2 * problem.energy_coef
    matvec = problem.energy.matvec
    add, divide, subtract, negative = np.add, np.divide, np.subtract, np.negative
    smallest = np.minimum.reduce
    dptsv = lapack.dptsv
    # scratch node arrays (zeroed where the general path starts from np.zeros_like) and their
    # edge views: k-th edge to point k (lo) and to point k+1 (hi)
    gfw, gff, hf, a, gh, div = (np.empty(n) for _ in range(6))
    gfw_lo, gfw_hi, gff_lo, gff_hi, hf_lo, hf_hi = gfw[:-1], gfw[1:], gff[:-1], gff[1:], hf[:-1], hf[1:]
    a_lo, a_hi, a_mid, gh_lo, gh_hi = a[:-1], a[1:], a[1:-1], gh[:-1], gh[1:]
    div_lo, div_hi = div[:-1], div[1:]

    def step(f: NDArray, m: NDArray) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        x, y = f[:-1], f[1:]
        s = x + y
        if not smallest(s) > 0:  # as not np.all(s > 0): the minimum of an array with a NaN is NaN
            gf, gm = problem.gradient(f, m)
            return sqp_step(problem, f, m, gf, gm)
        # wasserstein_derivatives (without h_sm): -w u u, 2 w u, 2 w u u / s, 2 w / s
        u = m / s
        g_s = minus_w * u * u
        g_m = two_w * u
        h_ss = g_m * u / s
        h_mm = two_w / s
        gfw.fill(0.0)
        add(gfw_lo, g_s, out=gfw_lo)
        add(gfw_hi, g_s, out=gfw_hi)
        gff.fill(0.0)
        hf.fill(0.0)
        if fisher is None:
            add(hf_lo, h_ss, out=hf_lo)
            add(hf_hi, h_ss, out=hf_hi)
        else:
            gx, gy, hx, hy, _ = fisher(x, y, s, c, mixed=False)
            add(gff_lo, gx, out=gff_lo)
            add(gff_hi, gy, out=gff_hi)
            add(hf_lo, h_ss + hx, out=hf_lo)
            add(hf_hi, h_ss + hy, out=hf_hi)
        gf = gfw + gff
        add(gf, energy_coef * matvec(f), out=gf)
        # _step_from
        divide(hf, h2, out=a)
        diag = a_lo + a_hi
        add(diag, h_mm, out=diag)
        off = -a_mid
        divide(gf, h, out=gh)
        rhs = gh_lo - gh_hi  # divergence_adjoint(gf / h)
        subtract(g_m, rhs, out=rhs)
        negative(rhs, out=rhs)
        _, _, pm, info = dptsv(diag, off, rhs)  # solve_sym_tridiagonal's first try (inputs not overwritten)
        if info != 0:  # positive definite unless non-finite: solve_sym_tridiagonal's own fallback
            pm = solve_sym_tridiagonal(diag, off, rhs)
        # divergence(pm): zeros, [:-1] = pm, [1:] -= pm
        div[-1] = 0.0
        div_lo[...] = pm
        subtract(div_hi, pm, out=div_hi)
        pf = negative(div)
        divide(pf, h, out=pf)
        return pf, pm

    return step


def explicit_step(problem: CollisionProblem) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The explicit step from ``(f_star, 0)``: the first step of the paper's SQP, ``(p_f, p_m)``.

    Batched like ``problem.f_star``.  Non-finite entries (data with exact zeros under a
    log Fisher term, or underflowed data) are returned as they come; callers check.

    Examples
    --------
    >>> import numpy as np
    >>> from jko_cvx import CollisionProblem, Grid, PowerKernel
    >>> grid = Grid.uniform(-2.0, 2.0, 41)
    >>> prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), dt=0.01)
    >>> pf, pm = explicit_step(prob)
    >>> bool(abs(pf @ grid.h) < 1e-15)  # a feasible direction moves no mass
    True
    """
    f, m = problem.initial_point()
    with np.errstate(all="ignore"):
        gf, gm = problem.gradient(f, m)
        return sqp_step(problem, f, m, gf, gm)
