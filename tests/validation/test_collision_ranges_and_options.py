"""Bad input to the collision API gets a clear error naming the argument, before any work (issue 14).

Extreme but valid data get a result with a failure status, never an exception mid-solve.
"""

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, Status, solve_collision

GRID = Grid.uniform(-2.0, 2.0, 41)
F = np.exp(-2 * GRID.points**2)
K = PowerKernel(1.0)


def _problem(**kw):
    return CollisionProblem(GRID, K, F, kw.pop("dt", 0.01), beta=kw.pop("beta", 10.0), **kw)


@pytest.mark.parametrize(
    "kwargs, names",
    [
        ({"beta": 1e-300}, "beta"),
        ({"dt": 1e300, "beta": 10.0}, "dt"),
        ({"dt": 1e300, "beta": np.inf, "strength": 1e10}, "dt"),
    ],
)
def test_out_of_range_coefficients_name_the_argument(kwargs, names):
    dt = kwargs.pop("dt", 0.01)
    with pytest.raises(ValueError, match=names):
        CollisionProblem(GRID, K, F, dt, **kwargs)


def test_empty_batch_and_overflowing_mass_are_rejected():
    with pytest.raises(ValueError, match=r"f_star .*at least one row"):
        CollisionProblem(GRID, K, np.zeros((0, GRID.n)), 0.01)
    with pytest.raises(ValueError, match=r"mass .*overflows"):
        CollisionProblem(GRID, K, 1.5e308 * F, 0.01)


@pytest.mark.parametrize("method", ["conic", "newton", "sqp"])
@pytest.mark.parametrize("scale", [1e-320, 1e-310, 1e300])
def test_data_at_the_edge_of_the_float_range_give_a_failure_status_not_an_exception(method, scale):
    prob = CollisionProblem(GRID, K, scale * F, 0.01, beta=10.0)
    res = solve_collision(prob, method)
    assert isinstance(res.status, Status)
    assert not res.success or (np.isfinite(res.objective) and res.kkt_residual <= 1e-6)


@pytest.mark.parametrize(
    "method, options, error, name",
    [
        ("newton", {"m0": np.zeros(5)}, ValueError, "m0"),
        ("newton", {"m0": np.zeros((2, GRID.n - 1))}, ValueError, "m0"),
        ("sqp", {"callback": 5}, TypeError, "callback"),
        ("conic", {"solver_options": 5}, TypeError, "solver_options"),
        ("newton", {"check_convexity": "no"}, TypeError, "check_convexity"),
        ("sqp", {"check_convexity": "no"}, TypeError, "check_convexity"),
        ("conic", {"check_convexity": "no"}, TypeError, "check_convexity"),
        ("newton", {"kkt_tol": 0.0}, ValueError, "kkt_tol"),
        ("newton", {"max_iter": 2.5}, ValueError, "max_iter"),
        ("newton", {"tol": True}, ValueError, "tol"),
        ("conic", {"max_passes": 0}, ValueError, "max_passes"),
        ("conic", {"dc_split": "svd"}, ValueError, "dc_split"),
        ("conic", {"verbose": "yes"}, TypeError, "verbose"),
        ("sqp", {"osqp_eps": 2.0}, ValueError, "osqp_eps"),
    ],
)
def test_bad_options_name_the_option(method, options, error, name):
    with pytest.raises(error, match=name):
        solve_collision(_problem(), method, **options)


@pytest.mark.parametrize("method", ["conic", "newton", "sqp"])
def test_numpy_scalars_are_accepted_as_tolerances(method):
    res = solve_collision(_problem(), method, tol=np.float32(1e-8), kkt_tol=np.float64(1e-6))
    assert res.status is Status.CONVERGED
