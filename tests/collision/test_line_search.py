"""The line searches exercised: Newton's Armijo backtracking and the SQP's positivity safeguard.

Newton: a warm start from a wiggly density (f* times exp(3 sin 12 v), mass kept) with the
log Fisher term at beta = 1.  There the full Newton step, cut by the fraction to the
boundary, *raises* J (computed below from the problem's own gradient and reduced Hessian,
independently of the solver): a solver that accepts it is wrong.  Newton has no callback,
so its iterates are read by re-solving with ``max_iter = 1, 2, ...`` (the loop is
deterministic, so the k-th solve returns the k-th iterate of the same sequence).
"""

import functools

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, Status, solve_collision

G = Grid.uniform(-2.0, 2.0, 21)
F_STAR = np.exp(-2 * G.points**2)


def _wiggly_problem(amplitude=3.0):
    prob = CollisionProblem(G, PowerKernel(1.0), F_STAR, 0.01, beta=1.0, fisher="log")
    f0 = F_STAR * np.exp(amplitude * np.sin(12.0 * G.points))
    f0 *= prob.mass / (f0 @ G.h)
    return prob, prob.flux_from_density(f0)


def _newton_step(prob, m):
    """The undamped Newton step of the reduced problem, from the public derivatives."""
    f = prob.density_from_flux(m)
    gf, gm = prob.gradient(f, m)
    g = prob.null_space_basis().T @ np.r_[gf, gm]
    H = prob.reduced_hessian(f, m)
    assert np.linalg.eigvalsh(H)[0] > 0  # convex here: the step is a descent direction
    return -np.linalg.solve(H, g), g


def test_the_full_newton_step_overshoots_on_this_problem():
    prob, m0 = _wiggly_problem()
    f0 = prob.density_from_flux(m0)
    p, g = _newton_step(prob, m0)
    pf = prob.density_from_flux(m0 + p) - f0
    neg = pf < 0
    alpha = min(1.0, 0.995 * float(np.min(-f0[neg] / pf[neg])))  # fraction to the boundary
    m1 = m0 + alpha * p
    assert g @ p < 0
    assert prob.objective(prob.density_from_flux(m1), m1) > prob.objective(f0, m0) + 0.02


def _first_trial(amplitude):
    """The first trial point of Newton's line search: the Newton step cut by the fraction to the boundary."""
    prob, m0 = _wiggly_problem(amplitude)
    f0 = prob.density_from_flux(m0)
    p, g = _newton_step(prob, m0)
    pf = prob.density_from_flux(m0 + p) - f0
    neg = pf < 0
    alpha = min(1.0, 0.995 * float(np.min(-f0[neg] / pf[neg]))) if neg.any() else 1.0
    m1 = m0 + alpha * p
    J0 = float(prob.objective(f0, m0))
    return prob, m0, p, g, alpha, float(prob.objective(prob.density_from_flux(m1), m1)) - J0, J0


def test_undamped_newton_iterates_decrease_the_objective_monotonically():
    """A large ``tol`` stops the first (undamped) attempt at an early iterate, certified, so no
    retry replaces it: tol = 0.999, 0.5, ... returns iterates 1, 2, 8, ... of one sequence."""
    prob, m0 = _wiggly_problem()
    J0 = float(prob.objective(prob.density_from_flux(m0), m0))
    seen = {0: J0}
    for tol in (0.999, 0.5, 0.3, 0.1, 1e-2, 1e-6, 1e-9):
        res = solve_collision(prob, method="newton", m0=m0, tol=tol)
        assert res.status is Status.CONVERGED and not res.info["interior_damping"]
        seen[res.iterations] = res.objective
    # seven tolerances give seven iterates here (1, 2, 8, ..., 12); near the end two tolerances may
    # fall on one iterate under another BLAS kernel's rounding, so only five distinct ones are required
    assert len(seen) >= 5 and 1 in seen
    J = [seen[k] for k in sorted(seen)]
    assert np.all(np.diff(J) < 0), seen


@functools.cache
def _borderline():
    """Tune the wiggle's amplitude (bisection between 2, where the first trial point lowers J,
    and 3, where it raises J by 0.04) until the trial point changes J by less than
    5e-5 alpha |g'p|, half the Armijo margin 1e-4 alpha |g'p|."""
    lo, hi = 2.0, 3.0
    assert _first_trial(lo)[5] < 0 < _first_trial(hi)[5]
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        prob, m0, p, g, alpha, dJ, J0 = _first_trial(mid)
        if abs(dJ) < 5e-5 * alpha * abs(g @ p):
            return prob, m0, p, g, alpha, J0
        lo, hi = (mid, hi) if dJ < 0 else (lo, mid)
    pytest.fail("no amplitude with a borderline first trial point")


@pytest.mark.parametrize("batched", [False, True])
def test_newton_accepts_only_steps_with_sufficient_decrease(batched):
    """Armijo: the accepted step length alpha satisfies J(m + alpha p) <= J(m) + 1e-4 alpha g'p.

    At the borderline amplitude a line search with the wrong sign in its sufficient-decrease
    term (or none) accepts the first trial point; the right one halves the step.  ``tol``
    = 0.999 stops the undamped attempt after one iterate (certified, so never retried).
    Both Newton paths (one problem, a batch) are checked.
    """
    prob, m0, p, g, alpha, J0 = _borderline()
    if batched:
        both = solve_collision(prob.with_f_star(np.stack([F_STAR, F_STAR])), method="newton",
                               m0=np.stack([m0, m0]), tol=0.999)
        assert not both.info["interior_damping"].any()
        iterations, m, objective = both.iterations[0], both.m[0], both.objective[0]
    else:
        res = solve_collision(prob, method="newton", m0=m0, tol=0.999)
        assert not res.info["interior_damping"]
        iterations, m, objective = res.iterations, res.m, res.objective
    assert iterations == 1
    step = m - m0
    taken = float(step @ p / (p @ p))
    np.testing.assert_allclose(step, taken * p, rtol=1e-5, atol=1e-12)  # along the Newton direction
    assert taken < alpha  # the borderline trial point was refused ...
    assert objective <= J0 + 1e-4 * taken * (g @ p)  # ... and the accepted one decreases J enough


def test_newton_iterates_decrease_the_objective_monotonically():
    prob, m0 = _wiggly_problem()
    J = [float(prob.objective(prob.density_from_flux(m0), m0))]
    for k in range(1, 9):
        res = solve_collision(prob, method="newton", m0=m0, max_iter=k, tol=1e-12)
        assert res.info["warm_started"]
        assert res.objective == pytest.approx(float(prob.objective(res.f, res.m)), rel=1e-12)
        J.append(res.objective)
    assert np.all(np.diff(J) < 0), J
    # ... down to the minimiser, which the solver certifies from the same start
    final = solve_collision(prob, method="newton", m0=m0, tol=1e-12)
    assert final.status is Status.CONVERGED and final.objective < J[-1]
    assert final.objective == pytest.approx(solve_collision(prob, method="sqp", tol=1e-13).objective, rel=1e-9)


def test_batched_newton_takes_the_same_iterates():
    """The batched path has its own line search: from the same start it returns the same points."""
    prob, m0 = _wiggly_problem()
    batch = prob.with_f_star(np.stack([F_STAR, F_STAR]))
    for k in (1, 3, 6):
        single = solve_collision(prob, method="newton", m0=m0, max_iter=k, tol=1e-12)
        both = solve_collision(batch, method="newton", m0=np.stack([m0, m0]), max_iter=k, tol=1e-12)
        np.testing.assert_allclose(both.objective, single.objective, rtol=1e-10)
        np.testing.assert_allclose(both.f[0], single.f, rtol=1e-8, atol=1e-14)


def test_sqp_steps_cut_by_the_positivity_safeguard_never_pass_the_zeta_test():
    """A peaked datum (width 0.1 on 61 points) at dt = 0.3 without Fisher term: the step is not
    convex and the SQP's relaxation steps are cut by the fraction to the boundary.  A cut step
    says nothing about convergence, so its zeta is floored at 2 epsilon: the iteration runs to
    I_max with the exit flag instead of stopping NOT_CERTIFIED after a few short steps."""
    g = Grid.uniform(-2.0, 2.0, 61)
    prob = CollisionProblem(g, PowerKernel(1.0), np.exp(-(g.points**2) / (2 * 0.1**2)) + 1e-3, 0.3)
    zetas, kept, prev = [], [], [prob.f_star]

    def watch(it, f, m, z):
        zetas.append(z)
        old = prev[0]
        normal = old > 1e-290  # away from underflow
        kept.append(float(np.min(f[normal] / old[normal])))
        prev[0] = f.copy()

    res = solve_collision(prob, method="sqp", max_iter=300, callback=watch)
    # fraction to the boundary 0.995: no step takes more than 99.5 % of any f_j
    assert min(kept) >= 0.005 * (1 - 1e-9)
    assert res.status is Status.MAX_ITERATIONS and res.iterations == 300 and res.info["exit_flag"] == 1
    assert res.info["safeguard_steps"] >= 250
    assert len(zetas) == 300 and min(zetas) >= 2e-10  # 2 x the default epsilon 1e-10
    assert sum(z == 2e-10 for z in zetas) >= 200  # the floor is what kept those steps going
