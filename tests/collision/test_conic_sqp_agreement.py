"""The conic reference and the paper's SQP agree on the same discrete problem."""

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
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
    """Both Fisher forms are consistent with |grad log f|^2 f: their solutions differ by O(dv^2).

    Measured on this datum: 3.5e-5, 9.5e-6, 2.4e-6, 6.0e-7 at N = 51 ... 401 (order 1.87, 1.99,
    2.00); a wrong form (or a wrong weight in one of them) gives an O(1) difference or order 0.
    """
    diffs = []
    for n in (101, 201):
        grid = Grid.uniform(-2.0, 2.0, n)
        f_star = np.exp(-2 * grid.points**2) + 0.1 * np.exp(-8 * (grid.points - 0.7) ** 2)
        r_log, r_per = (
            solve_collision(CollisionProblem(grid, PowerKernel(1.0), f_star, 0.01, beta=3.0, fisher=form),
                            method="newton", tol=1e-12)
            for form in ("log", "perspective")
        )
        assert r_log.success and r_per.success
        diffs.append(_rel_max(r_log.f, r_per.f))
    assert 1e-6 < diffs[0] < 1e-4  # different discrete problems: close, but not identical
    assert 1.8 < np.log2(diffs[0] / diffs[1]) < 2.2  # second order in dv


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
