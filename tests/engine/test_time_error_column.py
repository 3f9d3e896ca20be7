"""The diagnostics' ``time_error``: Richardson's estimate of one first-order collision step's local error."""

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, shipped_scene, simulate, solve_collision
from jko_cvx.engine.loop import time_error
from jko_cvx.time_order import collision_step_order2


@pytest.mark.parametrize("gamma", [1.0, 3.0])
def test_the_estimate_matches_the_error_against_the_exact_flow(gamma):
    """Against the semi-discrete flow integrated with 32 second-order steps (an error 1e3 times smaller): the
    estimate is within 15 % of the first-order step's true local error, and falls about fourfold per halving of
    dt (a local error of order dt^2), on an off-centre two-bump datum."""
    grid = Grid.uniform(-2.0, 2.0, 61)
    f0 = np.exp(-2 * (grid.points - 0.2) ** 2) + 0.5 * np.exp(-8 * (grid.points + 0.6) ** 2)

    def factory(g, h):
        return CollisionProblem(grid, PowerKernel(gamma), g, h, 1.0, 1000.0, "log")

    estimates = []
    for dt in (0.04, 0.02):
        one = solve_collision(factory(f0, dt), method="newton", tol=1e-12).f
        exact = f0.copy()
        for _ in range(32):
            exact = collision_step_order2(factory, exact, dt / 32, method="newton", tol=1e-12).f
        actual = np.abs(exact - one).max() / exact.max()
        est = time_error(collision_step_order2(factory, f0, dt, method="newton", tol=1e-12))
        assert est == pytest.approx(actual, rel=0.15)
        estimates.append(est)
    assert 3.0 < estimates[0] / estimates[1] < 5.0


def test_a_first_order_step_has_no_estimate():
    grid = Grid.uniform(-2.0, 2.0, 41)
    res = solve_collision(CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), 0.01), "newton")
    assert np.isnan(time_error(res))


def test_runs_record_it_under_the_second_order_scheme_only():
    """Homogeneous and inhomogeneous (Strang: the collision step's part) second-order runs record a finite,
    positive estimate per step (NaN in the initial row); first-order runs record NaN."""
    for name, extra in (("tab_bu_g1", {"t_end": 0.03}), ("inhom_gamma3_lambda4", {"t_end": 0.1, "v.n": 21, "x.n": 21})):
        second = simulate(shipped_scene(name, {**extra, "time.order": 2})).diagnostics["time_error"].to_numpy()
        first = simulate(shipped_scene(name, extra)).diagnostics["time_error"].to_numpy()
        assert np.isnan(second[0]) and np.all(np.isfinite(second[1:])) and np.all(second[1:] > 0)
        assert np.all(np.isnan(first))
