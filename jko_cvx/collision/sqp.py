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

positive definite because :math:`H_m = 4\\Delta v/s > 0`.  With ``qp="osqp"`` the same QP
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
there as ``NUMERICAL_ERROR`` (``info["left_domain"]``: the iteration).  Measured on the
adaptive g1 runs of ``gk1_records``: ``studies/results/reproduce/paper_variants.md``.

The exit flag is Algorithm 1's: :math:`e_f = 1` iff :math:`l = I_{max}`, i.e. iff
:math:`I_{max}` iterations ran, also when the :math:`\\zeta` test passes on exactly the
:math:`I_{max}`-th (the loop ends on its counter before the test is read again).
"""

from __future__ import annotations

import math
import time
from numbers import Real
from typing import Any

import numpy as np
import scipy.sparse as sp

from jko_cvx.collision.certify import certify
from jko_cvx.collision.checks import check_bool, check_callable, check_choice, check_int, check_unit
from jko_cvx.collision.explicit import diagonal_hessian, sqp_step, sqp_stepper
from jko_cvx.collision.linalg import divergence
from jko_cvx.collision.problem import CollisionProblem
from jko_cvx.collision.result import CollisionResult, Status
from jko_cvx.mesh.moments import check_floor

__all__ = ["SAFEGUARDS", "solve_sqp"]

_FRACTION_TO_BOUNDARY = 0.995

SAFEGUARDS = ("floor", "cut", "none")
"""The positivity safeguard's variants (``solve_sqp(safeguard=...)``), see the module docstring."""


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
    _check_sqp_args(problem, step, tol, max_iter, kkt_tol, qp, floor, osqp_eps, check_convexity, callback)
    check_choice("safeguard", safeguard, SAFEGUARDS)
    step, tol, kkt_tol, floor = float(step), float(tol), float(kkt_tol), float(floor)
    t0 = time.perf_counter()
    qp_step = sqp_step if qp == "banded" else _OsqpStep(problem, floor, osqp_eps, 100000)
    f, m, zeta, it, safeguarded, status = _iterate(problem, qp_step, step, tol, max_iter, safeguard, callback)
    left_domain = it if status is Status.NUMERICAL_ERROR and bool(np.any(f <= 0)) else None
    # Algorithm 1, step 3: e_f = 1 if l = I_max (the loop counter reaches I_max only when
    # I_max iterations ran, whether or not the last one passed the zeta test)
    exit_flag = int(status is None and it >= max_iter)
    if exit_flag:
        status = Status.MAX_ITERATIONS
    # Remove the rounding drift of many feasible updates (rebuild f from m), then clip
    # rounding negatives (~1e-25) and restore the mass exactly.
    f, m = problem.project_feasible(problem.density_from_flux(m))
    cert = certify(problem, f, m, kkt_tol=kkt_tol, check_convexity=check_convexity, claimed=status)
    info = {"exit_flag": exit_flag, "zeta": float(zeta), "safeguard_steps": safeguarded, "safeguard": safeguard,
            "qp": qp, "kkt": cert.kkt}  # fmt: skip
    if left_domain is not None:
        info["left_domain"] = left_domain
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


def _check_sqp_args(problem, step, tol, max_iter, kkt_tol, qp, floor, osqp_eps, check_convexity, callback) -> None:
    if problem.conserve_momentum:
        raise ValueError(
            "method='sqp' is the paper's Algorithm 1, which has no momentum constraint; "
            "use method='newton' or 'conic' for conserve_momentum=True"
        )
    if problem.batched:
        raise ValueError("method='sqp' solves one problem at a time; pass problem.slice(i)")
    if isinstance(step, (bool, np.bool_)) or not isinstance(step, Real) or not 0 < step <= 1:
        raise ValueError(f"step (the relaxation step lambda) must lie in (0, 1], got {step!r}")
    check_unit("tol", tol)
    check_unit("kkt_tol", kkt_tol)
    check_unit("osqp_eps", osqp_eps)
    check_int("max_iter (I_max)", max_iter)
    check_choice("qp", qp, ("banded", "osqp"))
    check_floor(floor)
    check_bool("check_convexity", check_convexity)
    check_callable("callback", callback)
