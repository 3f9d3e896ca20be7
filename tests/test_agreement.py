"""The conic reference and the paper's SQP agree on the same discrete problem."""

import numpy as np
import pytest

from jko_cvx import solve_collision
from jko_cvx.testing import random_problem

KKT_TOL = 1e-6


def _rel_max(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


@pytest.mark.parametrize("gamma", [1.0, 1.5, 2.0, 3.0])
@pytest.mark.parametrize("seed", [0, 1])
def test_conic_and_sqp_agree(gamma, seed):
    rng = np.random.default_rng(1000 * seed + int(10 * gamma))
    prob = random_problem(rng, gamma, n=int(rng.integers(31, 202)))
    conic = solve_collision(prob, method="conic", tol=1e-10)
    sqp = solve_collision(prob, method="sqp", tol=1e-12)
    for res in (conic, sqp):
        assert res.success, f"{res.method}: {res.message} (kkt={res.kkt_residual:.2e})"
        assert res.kkt_residual <= KKT_TOL
        assert res.mass_error <= 1e-12
        assert res.f.min() >= 0
    assert abs(conic.objective - sqp.objective) <= 1e-9 * abs(sqp.objective)
    assert _rel_max(conic.f, sqp.f) <= 1e-5
    # The objective decreased below that of doing nothing (f = f*, m = 0).
    f0, m0 = prob.initial_point()
    assert sqp.objective < prob.objective(f0, m0)


@pytest.mark.parametrize("gamma", [1.0, 1.5, 2.0, 3.0])
def test_sqp_log_fisher_is_certified_by_its_kkt_residual(gamma):
    rng = np.random.default_rng(77 + int(10 * gamma))
    prob = random_problem(rng, gamma, fisher="log")
    res = solve_collision(prob, method="sqp", tol=1e-12)
    assert res.success, res.message
    assert res.kkt_residual <= 1e-8
    assert res.mass_error <= 1e-12


def test_log_and_perspective_fisher_share_the_continuum_limit():
    """Both Fisher forms differ by O(dv^2): on a fine grid their solutions nearly coincide."""
    rng = np.random.default_rng(5)
    p_log = random_problem(rng, 1.0, n=201, beta=3.0, fisher="log")
    p_per = type(p_log)(p_log.grid, p_log.kernel, p_log.f_star, p_log.dt, beta=3.0, fisher="perspective")
    r_log = solve_collision(p_log, method="sqp")
    r_per = solve_collision(p_per, method="sqp")
    assert r_log.success and r_per.success
    # different discrete problems: close, but not identical
    d = _rel_max(r_log.f, r_per.f)
    assert 1e-12 < d < 1e-2


def test_batched_problem_is_solved_slice_by_slice():
    rng = np.random.default_rng(9)
    prob = random_problem(rng, 1.5, n=41)
    F = np.stack([prob.f_star, 2 * prob.f_star[::-1]])
    batch = prob.with_f_star(F)
    res = solve_collision(batch, method="sqp")
    assert res.f.shape == F.shape and len(res.status) == 2
    for i in range(2):
        single = solve_collision(batch.slice(i), method="sqp")
        assert np.array_equal(res.f[i], single.f)
        assert res.status[i] is single.status
