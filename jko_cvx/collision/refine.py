"""One Newton correction on the constraint's null space: the error estimate in f, and the refinement of an answer.

On the null space of ``eqn:linear_constraint`` (``f = f^* - D p / h``, ``m = p``; with
``conserve_momentum`` also :math:`\\Delta v^\\top p = 0`) the Newton correction of a feasible point is
:math:`p = -H_r^{-1} g_r` with the reduced gradient :math:`g_r = Z^\\top \\nabla J` and the reduced
Hessian :math:`H_r = Z^\\top \\nabla^2 J Z` (:meth:`~jko_cvx.collision.CollisionProblem.reduced_hessian`).
:func:`newton_correction` computes it; :func:`~jko_cvx.collision.estimate.f_error_estimate` measures it, and
:func:`refine_once` takes it (iterative refinement of an interior-point answer, as OSQP's polish
refines a first-order one).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from jko_cvx.collision._linalg import divergence, divergence_adjoint
from jko_cvx.collision.certify import Certificate, certify
from jko_cvx.collision.problem import CollisionProblem
from jko_cvx.collision.result import Status

__all__ = ["newton_correction", "refine_once"]


def newton_correction(problem: CollisionProblem, f: NDArray, m: NDArray) -> NDArray[np.float64] | None:
    """The flux part :math:`\\Delta m` of the Newton correction at the feasible point ``(f, m)`` (module docstring).

    The density part is :math:`\\Delta f = -D\\,\\Delta m / h`.  Fluxes whose curvature is not finite and
    positive (through vacuum edges) are frozen (:math:`\\Delta m_k = 0`).  None where ``f`` or ``m`` is not
    finite, where no flux has a finite curvature, or where :math:`H_r` is not positive definite or not
    finite.  One dense Cholesky factorisation of size N - 1.
    """
    import scipy.linalg as sla

    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(m))) or f.max() <= 0:
        return None
    with np.errstate(all="ignore"):
        gf, gm = problem.gradient(f, m)
        g = gm - divergence_adjoint(gf / problem.grid.h)  # Z' grad J, Z = [-D/h; I] (CollisionProblem.null_space_basis)
        H = problem.reduced_hessian(f, m)
    d = np.diag(H)
    keep = np.isfinite(d) & (d > 0)
    Hk, gk = H[np.ix_(keep, keep)], g[keep]
    if not keep.any() or not (np.all(np.isfinite(Hk)) and np.all(np.isfinite(gk))):
        return None
    s = 1 / np.sqrt(np.diag(Hk))  # Jacobi scaling: near-vacuum cells put 1e90 on the diagonal
    try:
        chol = sla.cho_factor(Hk * s[:, None] * s[None, :])
    except np.linalg.LinAlgError:
        return None

    def solve(r: np.ndarray) -> np.ndarray:
        return s * sla.cho_solve(chol, s * r)

    p = solve(gk)
    if problem.conserve_momentum and keep.sum() > 1:
        a = problem.grid.dv[keep]
        q = solve(a)
        p = p - q * (a @ p) / (a @ q)
    full = np.zeros(problem.n - 1)
    full[keep] = -p
    return full if np.all(np.isfinite(full)) else None


def refine_once(
    problem: CollisionProblem, f: NDArray, m: NDArray, *, max_move: float, kkt_tol: float, check_convexity: bool
) -> tuple[NDArray, NDArray, Certificate, float] | None:
    """The point one Newton correction from the feasible ``(f, m)``, where it is certified: ``(f, m, cert, move)``.

    The correction is taken in full, and only where it keeps every density positive and moves f by at
    most ``max_move`` (relative to max f: ``move`` is that distance); its point is certified at
    ``kkt_tol``.  None otherwise: the caller keeps its own answer.  Where an answer's KKT residual
    stalls just above the threshold while its distance to the minimiser is far below its accuracy in
    f (the conic method on low-mass slices, its residual limited by the inner solves' feasibility
    tolerance), the corrected point is the same answer, certified.
    """
    dm = newton_correction(problem, f, m)
    if dm is None:
        return None
    df = -divergence(dm) / problem.grid.h
    move = float(np.abs(df).max() / f.max())
    f_new, m_new = f + df, m + dm
    if not (move <= max_move and np.all(f_new > 0)):
        return None
    cert = certify(problem, f_new, m_new, kkt_tol=kkt_tol, check_convexity=check_convexity)
    return (f_new, m_new, cert, move) if cert.status is Status.CONVERGED else None
