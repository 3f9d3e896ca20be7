"""One Newton correction on the constraint's null space (jko_cvx.collision.refine)."""

from __future__ import annotations

import numpy as np

from jko_cvx import CollisionProblem, Grid, PowerKernel, f_error_estimate, solve_collision
from jko_cvx.collision.refine import newton_correction, refine_once


def _problem(gamma: float = 1.5, momentum: bool = False) -> CollisionProblem:
    g = Grid.uniform(-2.0, 2.0, 61)
    f = np.exp(-2 * (g.points - 0.3) ** 2) + 0.5 * np.exp(-4 * (g.points + 0.7) ** 2)
    return CollisionProblem(g, PowerKernel(gamma), f, 0.02, 1.0, 10.0, "perspective", momentum)


def test_one_correction_from_a_loose_answer_lands_on_the_minimiser():
    for momentum in (False, True):
        prob = _problem(momentum=momentum)
        loose = solve_collision(prob, method="newton", tol=1e-4)
        tight = solve_collision(prob, method="newton", tol=1e-13)
        assert loose.kkt_residual > 1e-8  # the loose answer is not certified at the threshold below
        out = refine_once(prob, loose.f, loose.m, max_move=1e-2, kkt_tol=1e-8, check_convexity=True)
        assert out is not None
        f, _, cert, move = out
        assert cert.residual <= 1e-8 and abs(prob.mass_error(f)) < 1e-13
        if momentum:
            assert prob.momentum_change(f) < 1e-13
        # the move is the correction the error estimate measures, and it closes the gap to the minimiser
        assert np.isclose(move, np.abs(f - loose.f).max() / loose.f.max())
        assert np.abs(f - tight.f).max() < 1e-2 * np.abs(loose.f - tight.f).max()
        assert f_error_estimate(prob, loose.f, loose.m) > 0.3 * move


def test_a_correction_larger_than_allowed_or_not_certified_is_refused():
    prob = _problem()
    loose = solve_collision(prob, method="newton", tol=1e-4)
    dm = newton_correction(prob, loose.f, loose.m)
    move = np.abs(np.diff(np.concatenate([[0.0], dm, [0.0]])) / prob.grid.h).max() / loose.f.max()
    assert refine_once(prob, loose.f, loose.m, max_move=0.5 * move, kkt_tol=1e-8, check_convexity=True) is None
    # far from the minimiser one correction is not enough for a tight threshold
    far_f, far_m = prob.project_feasible(prob.f_star)
    assert refine_once(prob, far_f, far_m, max_move=1.0, kkt_tol=1e-12, check_convexity=True) is None


def test_no_correction_at_a_non_finite_point():
    prob = _problem()
    f, m = prob.project_feasible(prob.f_star)
    f[3] = np.nan
    assert newton_correction(prob, f, m) is None
