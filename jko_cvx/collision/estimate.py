"""What a reference solve and an error bound need: the reference's answer in units of max f*, the distance in f.

:func:`solve_reference` solves a collision step with a reference solver (conic, nlp) in units of
the slice's largest density and certifies the answer against the problem itself;
:func:`f_error_estimate` estimates the distance in f of a feasible point to the step's minimiser
(one Newton step on the constraint's null space).  :mod:`jko_cvx.engine.verify` uses both along a
run.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from jko_cvx.collision._linalg import divergence
from jko_cvx.collision.certify import certify_rescaled
from jko_cvx.collision.problem import CollisionProblem
from jko_cvx.collision.refine import newton_correction
from jko_cvx.collision.result import CollisionResult
from jko_cvx.collision.solve import OPTIONS, solve_collision

__all__ = ["f_error_estimate", "solve_reference"]


def solve_reference(problem: CollisionProblem, reference: str, options: dict[str, Any]) -> CollisionResult:
    """The reference's answer to ``problem``, solved in units of its largest density.

    Every term of J but the energy is 1-homogeneous in ``(f, m)`` (the kinetic term
    :math:`2m^2/s`, both Fisher forms) and the energy is 2-homogeneous, so with
    :math:`c = \\max f^*` the minimiser of the step for ``(f^*, strength)`` is ``c`` times the
    minimiser for ``(f^* / c, c * strength)``: the same problem, with densities of order one.
    The reference solves that one, cold; its answer, scaled back, is certified against
    ``problem`` itself (:func:`~jko_cvx.collision.certify`, the reference's ``kkt_tol``; a
    failure status it claimed is kept).  Why: Clarabel's tolerances are partly absolute, and
    on the near-vacuum x-slices of ``inhom_gamma3_lambda4`` (perspective form, beta = 30,
    41 x 41, first step; max f* from 1e-10 to 5e-3) the conic reference returned SOLVER_ERROR or
    MAX_ITERATIONS with KKT residuals 0.08-0.8 on all 10 such slices sampled; in units of max f*
    all 10 reach 1e-8 to 1e-10, within 2e-10 of Newton.  The conic method now solves in those units
    itself (:mod:`jko_cvx.collision.conic`); IPOPT, which settled these slices either way, gets the same
    treatment here so that both references see one problem.
    """
    scaled, c = problem.in_units_of_max()
    res = solve_collision(scaled, method=reference, **options)
    if c == 1.0:
        return res
    opts = OPTIONS[reference](**options)
    return certify_rescaled(problem, res, c, kkt_tol=opts.kkt_tol, check_convexity=opts.check_convexity)


def f_error_estimate(problem: CollisionProblem, f: np.ndarray, m: np.ndarray) -> float:
    """Distance in f from the feasible point ``(f, m)`` to the step's minimiser, estimated by one Newton step.

    On the constraint's null space (``f = f^* - D p / h``, ``m = p``, ``eqn:linear_constraint``;
    with ``conserve_momentum`` also :math:`\\Delta v^\\top p = 0`) the Newton correction is
    :math:`p = H_r^{-1} g_r` with the reduced gradient :math:`g_r = Z^\\top \\nabla J` and the
    reduced Hessian :math:`H_r = Z^\\top \\nabla^2 J Z`
    (:meth:`~jko_cvx.collision.CollisionProblem.reduced_hessian`).  The estimate is
    :math:`\\max_j w_j |(D p / h)_j| / \\max_j f_j` with the certificate's weights
    :math:`w_j = f_j / \\max f` (populated cells count in full): exact to second order, and
    bounded by :math:`\\|g_r\\| / \\lambda_{\\min}(H_r)`, so it grows as the step becomes
    ill-conditioned, where a small KKT residual no longer pins f.  Fluxes through vacuum edges
    (infinite curvature) are frozen, and the correction of each cell is cut at :math:`\\pm f_j`
    (near vacuum J is not quadratic, and no solver pins those cells at these tolerances).

    Parameters
    ----------
    problem : CollisionProblem
        One (unbatched) collision step.
    f, m : ndarray
        A feasible point of it: densities (N) and edge fluxes (N - 1), e.g. ``res.f, res.m``
        of a :class:`~jko_cvx.collision.CollisionResult`.

    Returns
    -------
    float
        The estimated distance in f relative to max f; ``inf`` where ``f`` or ``m`` is not finite,
        where no flux has a finite curvature, or where :math:`H_r` is not positive definite or not
        finite.

    Notes
    -----
    The estimate assumes an interior minimiser.  Where cells of the minimiser sit at the vacuum
    bound :math:`f_j = 0` (the constraint active: a grid of a handful of points, N = 3 to 7 for
    exp(-2 v^2) on [-2, 2]) the reduced gradient does not vanish there, and the estimate
    overstates the error (measured: 1e-2 at N = 3, 3e-6 at N = 7 for answers with KKT residuals of
    1e-16; rounding level from N = 11).
    Against a tight Newton solve (N = 61, gamma = 1 and 1.5, both Fisher forms and none, with
    and without the momentum constraint, Newton stopped at 1e-2 and 1e-4) it is within 30 % of
    the same weighted distance.  It costs one dense Cholesky factorisation of size N - 1.

    Examples
    --------
    A tight answer sits at rounding level; one stopped early carries an estimate close to its
    true distance to the minimiser:

    >>> import numpy as np
    >>> from jko_cvx import CollisionProblem, Grid, PowerKernel, f_error_estimate, solve_collision
    >>> grid = Grid.uniform(-2.0, 2.0, 41)
    >>> prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), dt=0.01, beta=3.0)
    >>> tight = solve_collision(prob, method="newton", tol=1e-12)
    >>> bool(f_error_estimate(prob, tight.f, tight.m) < 1e-12)
    True
    >>> loose = solve_collision(prob, method="sqp", tol=1e-2, kkt_tol=0.5)
    >>> gap = np.max(loose.f / loose.f.max() * np.abs(loose.f - tight.f)) / loose.f.max()
    >>> bool(0.5 < f_error_estimate(prob, loose.f, loose.m) / gap < 2)
    True
    """
    if problem.batched:
        raise ValueError("f_error_estimate takes one problem; pass problem.slice(i) and that slice's f, m")
    f, m = np.asarray(f, dtype=float), np.asarray(m, dtype=float)
    if f.shape != (problem.n,) or m.shape != (problem.n - 1,):
        raise ValueError(f"f and m must have shapes ({problem.n},) and ({problem.n - 1},), got {f.shape} and {m.shape}")
    dm = newton_correction(problem, f, m)
    if dm is None:
        return np.inf  # not finite, no flux with a finite curvature, or H_r not positive definite
    # Near vacuum J is far from quadratic (the Fisher and kinetic terms curve like 1/s_k) and the
    # Newton step means nothing there: on tab_bu_g1 (61 points, beta = 30, step 5) it asked for
    # +3.7e-5 max f at the end cell, where f = 7e-10, and 1.8e-5 at its neighbours, at every point
    # tried (conic at tol 1e-12 and 1e-13, Newton at 1e-14: all within 3e-8 of one another).  So the
    # correction is cut at +-f_j and weighted by f_j / max f, the certificate's weights.
    fpos = np.maximum(f, 0.0)
    delta = np.clip(-divergence(dm) / problem.grid.h, -fpos, fpos) * (fpos / f.max())
    est = float(np.abs(delta).max() / f.max())
    return est if np.isfinite(est) else np.inf
