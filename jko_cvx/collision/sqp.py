"""The paper's SQP for the collision step (Algorithm ``alg:non_uni_JKO``).

Each iteration solves the equality-constrained QP

.. math::

    z^{(l+1)} = \\arg\\min_z \\tfrac12 (z - u^{(l)})^\\top \\mathsf H^{(l)} (z - u^{(l)})
                + \\nabla J(u^{(l)})^\\top (z - u^{(l)}) \\quad \\text{s.t. } A z = b,

with :math:`\\mathsf H^{(l)}` the *diagonal* of :math:`\\nabla^2 F(u^{(l)})` (F = Wasserstein +
Fisher terms; the energy Hessian is left out, as in the paper) and the gradient of the
full :math:`J`.  It then relaxes, :math:`u^{(l+1)} = u^{(l)} + \\lambda (z^{(l+1)} - u^{(l)})`,
and stops when :math:`\\zeta = \\|u^{(l+1)} - u^{(l)}\\| / \\|u^{(l)}\\| \\le \\epsilon` or
:math:`l = I_{max}` (exit flag :math:`e_f = 1`).

The QP in O(N): every iterate is feasible (it starts at :math:`(f^*, 0)`), so the step
:math:`p = z - u` has :math:`p_f = -D p_m / h` and the QP reduces to the tridiagonal system

.. math::  \\big(D^\\top \\operatorname{diag}(H_f/h^2) D + \\operatorname{diag}(H_m)\\big)\\,p_m
           = -\\big(\\nabla_m J - D^\\top(\\nabla_f J / h)\\big),

positive definite because :math:`H_m = 4\\Delta v/s > 0` (:func:`sqp_step`; :func:`sqp_stepper` is the
same step with the per-problem constants set up once, for the loop).  From :math:`(f^*, 0)`
the Hessian has no f-m coupling and the first step is the explicit-Euler step of the
collision operator (:func:`explicit_step`): the conic reference takes its scale from it and
Newton and nlp start from it.  With ``qp="osqp"`` the same QP
is solved by OSQP with the bound :math:`z_f \\ge` ``floor`` added (the paper's QP has no
bound; the floor is the option the issue asks for).

Additions to the paper, each documented in the result: a positivity safeguard
(fraction-to-the-boundary on the relaxation step, so iterates stay positive, which
the log Fisher form needs), and a final certification by the KKT residual (the
paper's :math:`\\zeta` test measures step length only; a small step with a large KKT
residual is reported ``NOT_CERTIFIED``, never as success).

The safeguard is the option ``safeguard`` (:data:`SAFEGUARDS`): ``"floor"`` (default) cuts
the step and floors :math:`\\zeta` at :math:`2\\epsilon` on a cut step (a step shortened to
stay positive says nothing about convergence, so it never passes the test); ``"cut"`` cuts
the step and takes :math:`\\zeta` as Algorithm 1 computes it; ``"none"`` is Algorithm 1 as
written, without the cut: an iterate with some :math:`f_j \\le 0` has left the domain of
:math:`J` (the log and perspective Fisher terms, the Wasserstein term), and the solve stops
there as ``NUMERICAL_ERROR`` (``info["left_domain"]``: the iteration).  The three are compared
on the adaptive g1 runs of ``gk1_records`` (the paper-variants study).

Where it stalls.  The QP's Hessian is the diagonal of the Wasserstein and Fisher terms
alone, so the first step from :math:`(f^*, 0)` is the explicit-Euler step and every later
step is of the same kind: a step that moves the mass of a cell by the local velocity times
:math:`\\Delta t`, with no energy curvature to shorten it.  With an explicit CFL number
(:meth:`~jko_cvx.collision.problem.CollisionProblem.cfl`) above about one that step asks a
tail cell for more mass than it holds; the only curvature that could stop it is the Fisher
term's, :math:`(\\Delta t/\\beta)^2 / f` on the tails, which is negligible for large
:math:`\\beta`.  The positivity safeguard then cuts every step, the cut steps shrink
geometrically (the iterates jam at the vacuum boundary, as an undamped Newton iteration
does), and ``"floor"`` keeps :math:`\\zeta` from passing on a cut step, so the solve ends at
:math:`I_{max}` with a large KKT residual.  Measured (f* = exp(-2 v^2) on [-2, 2], N = 121,
perspective form, ``max_iter=20000``; every one of the 20000 steps cut): at
:math:`\\beta = 1000` CFL 0.5 and 0.9 converge in 16-34 iterations, CFL 1.5, 3 and 10
end ``MAX_ITERATIONS`` at KKT 2.5e-2 to 8.1e-2 for gamma = 1 and 3 (Newton: CONVERGED in
5-246 iterations); at :math:`\\beta = 10` the same steps converge (at most 305
iterations, at most 3 cut).  The gamma = 3, N = 61, :math:`\\beta = 1000` step at
dt = 0.01 (CFL 0.77) stalls the same way (KKT 7.5e-2 after 20000 cut steps, 1.1 s), as do
11 of the 64 cells of a smooth-Gaussian sweep at :math:`\\beta = 1000` (gamma 1-3,
N 61-481): the paper's SQP is an explicit-CFL-limited method unless the Fisher weight
is strong, and large steps need Newton (:mod:`~jko_cvx.collision.newton`) or the conic
reference.

The exit flag is Algorithm 1's: :math:`e_f = 1` iff :math:`l = I_{max}`, i.e. iff
:math:`I_{max}` iterations ran, also when the :math:`\\zeta` test passes on exactly the
:math:`I_{max}`-th (the loop ends on its counter before the test is read again).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.linalg import lapack

from jko_cvx.collision._checks import check_callable
from jko_cvx.collision._linalg import divergence, divergence_adjoint, solve_sym_tridiagonal
from jko_cvx.collision.certify import certify
from jko_cvx.collision.options import Options, Spec, option
from jko_cvx.collision.problem import MOMENTUM_METHODS, CollisionProblem, methods_text
from jko_cvx.collision.result import CollisionResult, Status
from jko_cvx.collision.terms import FISHER_TERMS, band_coefficients, wasserstein_derivatives

__all__ = [
    "SAFEGUARDS",
    "SqpOptions",
    "diagonal_hessian",
    "explicit_step",
    "gradient_and_sqp_step",
    "solve_sqp",
    "sqp_step",
    "sqp_stepper",
]

_FRACTION_TO_BOUNDARY = 0.995

SAFEGUARDS = ("floor", "cut", "none")
"""The positivity safeguard's variants (``solve_sqp(safeguard=...)``), see the module docstring."""


# ---- the QP of one iteration, banded (O(N)); the explicit step is its first


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
    h = band_coefficients(problem.grid, 2 if np.ndim(hf) == 2 else 1)[0]  # a (1, n) row for a batch: no broadcast
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
    if not (s > 0).all():
        gf, gm = problem.gradient(f, m)
        return (gf, gm, *sqp_step(problem, f, m, gf, gm))
    wd = wasserstein_derivatives(m, s, problem.wass_coef)
    gfw = np.zeros(f.shape)
    gfw[..., :-1] += wd.g_s
    gfw[..., 1:] += wd.g_s
    gff = np.zeros(f.shape)
    hf = np.zeros(f.shape)
    if problem.fisher is None:
        hf[..., :-1] += wd.h_ss
        hf[..., 1:] += wd.h_ss
    else:
        # gradient and hessian in one pass, bit for bit (the mixed entry is not needed)
        gx, gy, hx, hy, _ = FISHER_TERMS[problem.fisher].gradient_and_hessian(x, y, s, problem.fisher_coef, mixed=False)
        gff[..., :-1] += gx
        gff[..., 1:] += gy
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
        return gradient_and_sqp_step(problem, f, m)[2:]  # bitwise sqp_step at problem.gradient


# ---- the QP of one iteration by OSQP, the options, the iteration


class _OsqpStep:
    """The SQP subproblem solved by OSQP, with the bound ``z_f >= floor``."""

    def __init__(self, problem: CollisionProblem, floor: float, eps: float, max_iter: int) -> None:
        import osqp

        n = problem.n
        self.n = n
        self.floor = floor
        A_eq = problem.constraint_matrix()
        A_lb = sp.hstack([sp.eye(n), sp.csr_matrix((n, n - 1))])
        self.A = sp.vstack([A_eq, A_lb]).tocsc()
        self.P = sp.diags(np.ones(2 * n - 1)).tocsc()
        self.solver = osqp.OSQP()
        lo = np.r_[np.zeros(n), np.full(n, -np.inf)]
        hi = np.r_[np.zeros(n), np.full(n, np.inf)]
        self.solver.setup(
            P=sp.triu(self.P).tocsc(),
            q=np.zeros(2 * n - 1),
            A=self.A,
            l=lo,
            u=hi,
            eps_abs=eps,
            eps_rel=eps,
            max_iter=max_iter,
            polishing=True,
            verbose=False,
        )
        self.status = "unset"

    def __call__(self, problem: CollisionProblem, f, m, gf, gm) -> tuple[np.ndarray, np.ndarray]:
        n = self.n
        hf, hm = diagonal_hessian(problem, f, m)
        # OSQP needs a strictly convex diagonal for a unique step; the constraint fixes p_f anyway.
        pdiag = np.r_[np.maximum(hf, 1e-14 * max(float(hm.max()), 1.0)), hm]
        lo = np.r_[np.zeros(n), self.floor - f]
        hi = np.r_[np.zeros(n), np.full(n, np.inf)]
        self.solver.update(Px=pdiag, q=np.r_[gf, gm], l=lo, u=hi)
        # raise_error=False: a failed subproblem is reported through its status (checked below)
        try:
            res = self.solver.solve(raise_error=False)
        except TypeError:  # osqp < 1.0 has no raise_error and never raises
            res = self.solver.solve()
        self.status = str(res.info.status)
        if res.x is None or not np.all(np.isfinite(res.x)):
            raise FloatingPointError(f"OSQP failed: {self.status}")
        pm = res.x[n:]
        # Re-impose the equality exactly so the iterate stays feasible to rounding.
        return -divergence(pm) / problem.grid.h, pm


_UNIT = Spec("float", lo=0.0, hi=1.0, lo_open=True, hi_open=True)


def _check_callback(label: str, value: object) -> Any:
    """The SQP's callback is called once per iteration with four positional arguments."""
    return check_callable(label, value, signature="callback(l, f, m, zeta)")


@dataclass(frozen=True)
class SqpOptions(Options):
    """The options of :func:`solve_sqp`, checked once on construction (see its docstring for each).

    Fields are checked in this order; ``floor=None`` is resolved by :func:`solve_sqp` from the
    problem (``1e-10 * max(f_star)``).
    """

    step: float = option(1.0, Spec("float", lo=0.0, hi=1.0, lo_open=True, label="step (the relaxation step lambda)"))
    tol: float = option(1e-10, _UNIT)
    kkt_tol: float = option(1e-6, _UNIT)
    osqp_eps: float = option(1e-12, _UNIT)
    max_iter: int = option(20000, Spec("int", lo=1, label="max_iter (I_max)"))
    qp: str = option("banded", Spec("str", choices=("banded", "osqp")))
    floor: float | None = option(None, Spec("float", lo=0.0))
    check_convexity: bool = option(True, Spec("bool"))
    callback: Callable[..., Any] | None = option(None, Spec("callable", scene=False, check_with=_check_callback))
    safeguard: str = option("floor", Spec("str", choices=SAFEGUARDS))


def solve_sqp(
    problem: CollisionProblem,
    *,
    step: float = 1.0,
    tol: float = 1e-10,
    max_iter: int = 20000,
    kkt_tol: float = 1e-6,
    qp: str = "banded",
    floor: float | None = None,
    osqp_eps: float = 1e-12,
    check_convexity: bool = True,
    safeguard: str = "floor",
    callback: Any = None,
) -> CollisionResult:
    """Solve the collision step with the paper's SQP (Algorithm ``alg:non_uni_JKO``).

    Parameters
    ----------
    problem : CollisionProblem
        An unbatched problem (any Fisher form).
    step : float, default 1.0
        The relaxation step :math:`\\lambda \\in (0, 1]` of the algorithm (the paper's
        "optimization step").
    tol : float, default 1e-10
        This method's own stopping tolerance: the threshold :math:`\\epsilon` of the
        :math:`\\zeta` test (relative step length).
    max_iter : int, default 20000
        :math:`I_{max}`; running that many iterations sets the exit flag :math:`e_f = 1`
        (status ``MAX_ITERATIONS``), also when the last one passes the :math:`\\zeta` test
        (Algorithm 1: ``e_f = 1 if l = I_max``).
    kkt_tol : float, default 1e-6
        Certification threshold (the same for every method, :func:`~jko_cvx.collision.certify.certify`):
        a run that passes the :math:`\\zeta` test is ``CONVERGED`` only if its scaled KKT
        residual is at most this, else ``NOT_CERTIFIED``.
    qp : {"banded", "osqp"}, default "banded"
        How the QP of each iteration is solved: the O(N) tridiagonal reduction, or OSQP
        with the positivity floor ``z_f >= floor``.
    floor : float, optional
        Positivity floor of the OSQP path (absolute).  Default ``1e-10 * max(f_star)``,
        the floor the paper applies after transport and remapping (``eqn:semi_update``);
        a positive floor keeps the bound inactive for the positivity safeguard.
    osqp_eps : float, default 1e-12
        OSQP's absolute and relative tolerance.
    check_convexity : bool, default True
        Second-order test at a certified point; ``NONCONVEX`` if the reduced Hessian is
        not positive definite (the point is stationary but not a minimiser).
    safeguard : {"floor", "cut", "none"}, default "floor"
        The positivity safeguard (not in Algorithm 1): ``"floor"`` cuts the relaxation step
        at 0.995 of the distance to the boundary :math:`f_j = 0` and floors :math:`\\zeta` at
        :math:`2\\epsilon` after a cut step; ``"cut"`` cuts without the floor; ``"none"``
        does not cut (Algorithm 1 as written) and stops as ``NUMERICAL_ERROR`` at the first
        iterate with some :math:`f_j \\le 0`.
    callback : callable, optional
        Called as ``callback(l, f, m, zeta)`` after each iteration.

    Returns
    -------
    CollisionResult
        ``info`` holds ``exit_flag`` (:math:`e_f`), ``zeta``, ``safeguard_steps`` (iterations
        whose relaxation step the positivity safeguard shortened), ``safeguard``, ``qp`` and,
        where an iterate left the domain (``safeguard="none"``), ``left_domain`` (its iteration).
    """
    if floor is None:
        floor = 1e-10 * float(problem.f_star.max())
    _check_sqp_problem(problem)
    opts = SqpOptions(step=step, tol=tol, kkt_tol=kkt_tol, osqp_eps=osqp_eps, max_iter=max_iter, qp=qp, floor=floor,
                      check_convexity=check_convexity, callback=callback, safeguard=safeguard)  # fmt: skip
    t0 = time.perf_counter()
    qp_step = sqp_step if opts.qp == "banded" else _OsqpStep(problem, opts.floor, opts.osqp_eps, 100000)
    f, m, zeta, it, safeguarded, status = _iterate(
        problem, qp_step, opts.step, opts.tol, opts.max_iter, opts.safeguard, opts.callback
    )
    left_domain = it if status is Status.NUMERICAL_ERROR and bool(np.any(f <= 0)) else None
    # Algorithm 1, step 3: e_f = 1 if l = I_max (the loop counter reaches I_max only when
    # I_max iterations ran, whether or not the last one passed the zeta test)
    exit_flag = int(status is None and it >= opts.max_iter)
    if exit_flag:
        status = Status.MAX_ITERATIONS
    # Remove the rounding drift of many feasible updates (rebuild f from m), then clip
    # rounding negatives (~1e-25) and restore the mass exactly.
    f, m = problem.project_feasible(problem.density_from_flux(m))
    cert = certify(problem, f, m, kkt_tol=opts.kkt_tol, check_convexity=opts.check_convexity, claimed=status)
    info = {"exit_flag": exit_flag, "zeta": float(zeta), "safeguard_steps": safeguarded, "safeguard": opts.safeguard,
            "qp": opts.qp, "kkt": cert.kkt}  # fmt: skip
    if left_domain is not None:
        info["left_domain"] = left_domain
    if not cert.status.success and problem.cfl() > 1:
        # the likely cause: the explicit first step empties cells above CFL ~ 1 (CollisionProblem.cfl)
        info["hint"] = (
            f"the step's explicit CFL number is {problem.cfl():.3g} > 1, where the paper's SQP stalls "
            "(its explicit first step empties low-density cells): take a smaller dt, or method='newton' / 'conic'"
        )
    return CollisionResult.from_certificate(problem, f, m, cert, "sqp", it, time.perf_counter() - t0, info)


def _iterate(
    problem: CollisionProblem, qp_step: Any, step: float, tol: float, max_iter: int, safeguard: str, callback: Any
) -> tuple[np.ndarray, np.ndarray, float, int, int, Status | None]:
    """The SQP iterations from ``(f*, 0)``: ``(f, m, zeta, iterations, safeguarded steps, failure status)``.

    ``safeguard`` (:data:`SAFEGUARDS`): cut the step (``"floor"``, ``"cut"``) or not (``"none"``:
    an iterate with some f_j <= 0 ends the loop with ``NUMERICAL_ERROR``).
    """
    f, m = problem.initial_point()
    zeta, it, safeguarded = 1.0, 0, 0
    # the banded QP: gradient and step share their terms, the per-problem constants set up once
    banded = sqp_stepper(problem) if qp_step is sqp_step else None
    with np.errstate(all="ignore"):
        while it < max_iter and zeta > tol:
            if banded is not None:
                pf, pm = banded(f, m)
            else:
                gf, gm = problem.gradient(f, m)
                try:
                    pf, pm = qp_step(problem, f, m, gf, gm)
                except FloatingPointError:
                    return f, m, zeta, it, safeguarded, Status.NUMERICAL_ERROR
            # A finite sum of squares has finite terms (an inf or NaN entry makes it inf or NaN):
            # the entry-wise test runs only where it is not (a finite step can overflow it).
            step_sq = pf @ pf + pm @ pm
            if not math.isfinite(step_sq) and not (np.isfinite(pf).all() and np.isfinite(pm).all()):
                return f, m, zeta, it, safeguarded, Status.NUMERICAL_ERROR
            lam, truncated = (step, False) if safeguard == "none" else _relaxation(f, pf, step)
            safeguarded += truncated
            norm_u = np.sqrt(f @ f + m @ m)
            f = f + lam * pf
            m = m + lam * pm
            zeta = lam * np.sqrt(step_sq) / norm_u
            if truncated and safeguard == "floor":
                # A step cut short by the safeguard says nothing about convergence:
                # never let it pass the zeta test.
                zeta = max(zeta, 2 * tol)
            it += 1
            if callback is not None:
                callback(it, f, m, zeta)
            if safeguard == "none" and np.any(f <= 0):  # outside the domain of J: no gradient there
                return f, m, zeta, it, safeguarded, Status.NUMERICAL_ERROR
    return f, m, zeta, it, safeguarded, None


def _relaxation(f: np.ndarray, pf: np.ndarray, step: float) -> tuple[float, bool]:
    """The relaxation step lambda, shortened by the positivity safeguard (fraction to the boundary)."""
    neg = pf < 0
    # the same quotients as -f[neg] / pf[neg] and an exact minimum, without the gathers; with
    # no negative entry the minimum is inf and the step is not cut (no test needed for that)
    to_boundary = float(np.minimum.reduce(np.where(neg, -f / np.where(neg, pf, -1.0), np.inf)))
    if to_boundary * _FRACTION_TO_BOUNDARY < step:
        return to_boundary * _FRACTION_TO_BOUNDARY, True
    return step, False


def _check_sqp_problem(problem: CollisionProblem) -> None:
    """``ValueError`` unless ``problem`` is one the paper's SQP solves."""
    if problem.conserve_momentum:
        raise ValueError(
            "method='sqp' is the paper's Algorithm 1, which has no momentum constraint; use method="
            + methods_text(MOMENTUM_METHODS, "'")
            + " for conserve_momentum=True"
        )
    if problem.batched:
        raise ValueError("method='sqp' solves one problem at a time; pass problem.slice(i)")
