"""The Newton solver: agreement with the conic reference and the SQP, batching, statuses."""

from pathlib import Path

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, Status, solve_collision
from jko_cvx.collision import solve_conic, solve_newton
from jko_cvx.collision.newton import NewtonOptions, _Attempt, _attempt, _direction, _fused, _newton_direction
from jko_cvx.collision.problem import add_pentadiagonal
from jko_cvx.evolve import evolve_fixed_grid
from jko_cvx.testing import random_problem

from .test_extremes import CASES, _w


def _rel_max(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


@pytest.mark.parametrize("fisher", ["log", "perspective", None])
@pytest.mark.parametrize("gamma", [1.0, 3.0])
def test_fused_derivatives_match_the_problem(gamma, fisher):
    rng = np.random.default_rng(3)
    prob = random_problem(rng, gamma, n=17, fisher=fisher)
    m = rng.normal(size=16) * 1e-3
    f = prob.density_from_flux(m)
    g, bands, parts = _fused(prob, f[None], m[None])
    H = add_pentadiagonal(2 * prob.energy_coef * prob.energy.flux_block(), *bands)
    ref = prob.gradient_parts(f, m)
    for mine, theirs in zip(
        (parts.wasserstein, parts.fisher, parts.energy), (ref.wasserstein, ref.fisher, ref.energy), strict=True
    ):
        assert np.allclose(mine[0][0], theirs[0], rtol=1e-12, atol=1e-15)
        assert np.allclose(mine[1][0], theirs[1], rtol=1e-12, atol=1e-15)
    Z = prob.null_space_basis()
    gf, gm = prob.gradient(f, m)
    Hd = Z.T @ (Z.T @ prob.hessian(f, m)).T  # from the dense (2N-1)^2 Hessian
    assert np.allclose(g[0], Z.T @ np.r_[gf, gm], rtol=1e-12, atol=1e-14 * np.abs(g).max())
    assert np.allclose(H[0], Hd, rtol=1e-12, atol=1e-13 * np.abs(Hd).max())


@pytest.mark.parametrize("gamma", [1.0, 2.0])
def test_structured_direction_equals_the_dense_one(gamma):
    """gamma = 1 (diagonal energy block) and gamma = 2 (rank one) take the O(N) path: same answer."""
    rng = np.random.default_rng(8)
    prob = random_problem(rng, gamma, n=40)
    m = rng.normal(size=(2, 39)) * 1e-3
    f = prob.density_from_flux(m)
    batch = prob.with_f_star(np.stack([prob.f_star, prob.f_star]))
    g, bands, _ = _fused(batch, f, m)
    p_fast, pd_fast, _ = _direction(batch, bands, g)
    H = add_pentadiagonal(2 * prob.energy_coef * prob.energy.flux_block(), *bands)
    p_dense, pd_dense = _newton_direction(H, -g[..., None])
    p_dense = p_dense[..., 0]
    assert pd_fast.all() and pd_dense.all()
    assert np.allclose(p_fast, p_dense, rtol=1e-8, atol=1e-12 * np.abs(p_dense).max())


@pytest.mark.parametrize("gamma", [1.0, 1.5, 2.0, 3.0])
@pytest.mark.parametrize("seed", [0, 1])
def test_newton_agrees_with_conic_and_sqp(gamma, seed):
    rng = np.random.default_rng(1000 * seed + int(10 * gamma))
    prob = random_problem(rng, gamma, n=int(rng.integers(31, 202)))
    newton = solve_collision(prob, method="newton")
    conic = solve_collision(prob, method="conic", tol=1e-10)
    sqp = solve_collision(prob, method="sqp", tol=1e-12)
    assert newton.success and conic.success and sqp.success
    assert newton.kkt_residual <= 1e-10 and newton.mass_error <= 1e-12
    for other in (conic, sqp):
        assert abs(newton.objective - other.objective) <= 1e-9 * abs(other.objective)
        assert _rel_max(newton.f, other.f) <= 1e-5
    assert _rel_max(newton.f, sqp.f) <= 1e-8  # both converge to machine-level residuals


@pytest.mark.parametrize("gamma", [1.0, 2.0, 3.0])
def test_newton_log_fisher_agrees_with_sqp(gamma):
    rng = np.random.default_rng(11 + int(gamma))
    prob = random_problem(rng, gamma, fisher="log")
    newton = solve_collision(prob, method="newton")
    sqp = solve_collision(prob, method="sqp", tol=1e-13)
    assert newton.success and sqp.success
    assert abs(newton.objective - sqp.objective) <= 1e-9 * abs(sqp.objective)
    assert _rel_max(newton.f, sqp.f) <= 1e-7


def test_batched_newton_equals_one_at_a_time():
    rng = np.random.default_rng(21)
    base = random_problem(rng, 1.5, n=61)
    F = np.stack([base.f_star * rng.uniform(0.5, 2.0) * (1 + 0.05 * rng.uniform(-1, 1, base.n)) for _ in range(6)])
    batch = base.with_f_star(F)
    res = solve_collision(batch, method="newton")
    assert res.f.shape == F.shape and len(res.status) == 6
    for i in range(6):
        one = solve_collision(batch.slice(i), method="newton")
        assert res.status[i] is one.status is Status.CONVERGED
        assert np.allclose(res.f[i], one.f, rtol=1e-12, atol=1e-14 * one.f.max())
        assert res.objective[i] == pytest.approx(one.objective, rel=1e-12)


NONCONVEX_PEAK = np.exp(-(_w.points**2) / (2 * 0.3**2)) + 1e-3  # dt = 0.3, no Fisher term


def test_nonconvex_step_is_reported():
    """A concentrated datum and a large step: the reduced Hessian loses definiteness."""
    for dt in (0.3, 1.0, 3.0):
        prob = CollisionProblem(_w, PowerKernel(1.0), NONCONVEX_PEAK, dt)
        res = solve_collision(prob, method="newton")
        assert res.status is Status.NONCONVEX and not res.success, (dt, res.status)
    # the same datum with a small step is convex and solved
    assert solve_collision(prob.with_dt(0.01), method="newton").status is Status.CONVERGED


def test_batched_status_is_per_slice():
    """One non-convex slice is flagged without spoiling its neighbour."""
    F = np.stack([NONCONVEX_PEAK, 0.2 * np.exp(-2 * _w.points**2)])
    res = solve_collision(CollisionProblem(_w, PowerKernel(1.0), F, 0.3), method="newton")
    assert res.status[0] is Status.NONCONVEX
    assert res.status[1] is Status.CONVERGED


def test_warm_start_from_the_previous_solution():
    rng = np.random.default_rng(4)
    prob = random_problem(rng, 1.0, n=81)
    cold = solve_collision(prob, method="newton")
    warm = solve_collision(prob, method="newton", m0=cold.m)
    assert warm.info["warm_started"] and warm.success
    assert warm.iterations <= 1 < cold.iterations
    assert np.allclose(warm.f, cold.f, rtol=1e-10)
    # an infeasible warm start (negative density) is refused, not used
    bad = solve_collision(prob, method="newton", m0=cold.m * 1e6)
    assert not bad.info["warm_started"] and bad.success


@pytest.mark.parametrize("name", list(CASES))
def test_newton_extremes_are_certified_or_flagged(name):
    grid, gamma, f_star, dt, beta = CASES[name]
    prob = CollisionProblem(grid, PowerKernel(gamma), f_star, dt, beta=beta)
    res = solve_collision(prob, method="newton")
    assert res.message and np.all(np.isfinite(res.f)) and res.f.min() >= 0
    assert res.mass_error <= 1e-12
    if res.success:
        assert res.kkt_residual <= 1e-9
        assert prob.is_local_minimiser(res.f, res.m)
        # cross-check against whichever independent solver certifies the case
        for method, opts in (("conic", {}), ("sqp", {"tol": 1e-13})):
            other = solve_collision(prob, method=method, **opts)
            if other.success:
                assert np.abs(res.f - other.f).max() <= 1e-4 * res.f.max()
    if name.startswith("non-convex"):
        # these minimisers touch f = 0 (vacuum): an interior Newton method cannot reach
        # an active positivity bound, and says so
        assert res.status in (Status.NONCONVEX, Status.MAX_ITERATIONS)


def test_newton_needs_positive_data():
    prob = CollisionProblem(_w, PowerKernel(1.0), np.where(_w.points > 1, 0.0, 1.0), 0.01)
    res = solve_collision(prob, method="newton")
    assert res.status is Status.NUMERICAL_ERROR and not res.success


@pytest.mark.parametrize("method", ["conic", "sqp", "newton"])
def test_reported_residual_is_that_of_the_returned_point(method):
    rng = np.random.default_rng(42)
    prob = random_problem(rng, 1.5, n=51)
    res = solve_collision(prob, method=method)
    assert res.kkt_residual == pytest.approx(prob.kkt_residual(res.f, res.m).total, rel=1e-9, abs=1e-15)
    assert res.objective == pytest.approx(prob.objective(res.f, res.m), rel=1e-14)
    assert np.abs(prob.constraint_residual(res.f, res.m)).max() <= 1e-14 * prob.mass


def _tail_jam_problem():
    """A step whose minimiser has f = 1.8e-11 at the left end next to 1e-5 mass (vacuum tail).

    The undamped Newton iteration jams there (each step cut by the fraction to the
    boundary, f -> 5e-26, KKT residual stuck at 7.5e-3); it is the fourth step of a
    Gaussian run on [-3, 3] with N = 121, dt = 0.01, beta = 30.
    """
    grid = Grid.uniform(-3.0, 3.0, 121)
    f0 = np.exp(-2.0 * (grid.points - 0.1) ** 2)
    run = evolve_fixed_grid(grid, PowerKernel(1.0), f0, 0.01, 0.03, beta=30.0, method="conic")
    return CollisionProblem(grid, PowerKernel(1.0), run.f[-1], 0.01, 1.0, 30.0, "perspective")


def test_vacuum_tail_jam_is_resolved_by_interior_damping():
    """The public solver and its damped path both reach the conic minimiser (f_min ~ 1e-11).

    Whether the undamped attempt jams depends on the last bits of the datum (the conic
    solve that builds it), so the damped path is also exercised directly.
    """
    P = _tail_jam_problem()
    ref = solve_conic(P, tol=1e-10)
    assert ref.success
    batch = P.with_f_star(np.stack([P.f_star, P.f_star]))
    damped = _Attempt(damping=True, jam_exit=False)
    results = [
        solve_newton(P),
        solve_newton(batch),
        _attempt(batch, None, NewtonOptions(), damped),
    ]
    for res in results:
        assert np.all(res.status == Status.CONVERGED), res.status
        assert np.all(res.kkt_residual <= 1e-10)
        assert np.max(np.abs(res.f - ref.f)) <= 1e-6 * P.f_star.max()
        assert np.all(np.abs(res.objective - ref.objective) <= 1e-8 * abs(ref.objective))


def _false_jam_problem() -> CollisionProblem:
    """A collision step from gamma = 3, lambda = 10 on 61 x 61 mapped grids at t = 1 (sec:sp_inhom_gamma_3).

    The datum is one v-slice of the run (``tests/data``); it is input, not expected output.
    The undamped iteration takes five steps of 2e-4 to 1e-3 (which the jam test reads as a
    jam), then converges; the interior-damped attempt stalls near KKT 8e-4 on it.
    """
    data = np.load(Path(__file__).parents[1] / "data" / "gamma3_lambda10_false_jam.npz")
    grid = Grid(data["points"])
    return CollisionProblem(grid, PowerKernel(3.0), data["f_star"], 0.05, 5.0, 1000.0, "log", conserve_momentum=True)


def test_a_slice_that_only_looks_jammed_still_converges():
    """Regression (0585534): the jam test ended this slice and the damped retry stalled.

    The third, undamped attempt without jam detection must certify it: the residual is
    recomputed here from the returned point, and mass and momentum are conserved.
    """
    P = _false_jam_problem()
    batch = P.with_f_star(np.stack([P.f_star, P.f_star[::-1]]))  # the mirror image jams alike
    single, batched = solve_newton(P, tol=1e-8), solve_newton(batch, tol=1e-8)
    assert single.info["jammed"] and np.all(batched.info["jammed"])
    assert not single.info["interior_damping"] and not np.any(batched.info["interior_damping"])
    for res, prob in ((single, P), (batched, batch)):
        assert np.all(res.status == Status.CONVERGED), res.status
        assert np.all(prob.kkt_residual(res.f, res.m).total <= 1e-8)
        assert np.all(res.f > 0)
        assert np.all(np.abs(prob.mass_error(res.f)) <= 1e-13 * prob.mass)
        assert np.all(np.abs(prob.momentum_change(res.f)) <= 1e-12 * prob.mass)
    np.testing.assert_allclose(batched.f[0], single.f, rtol=0, atol=1e-9 * P.f_star.max())


@pytest.mark.parametrize("gamma, fisher", [(1.0, "perspective"), (3.0, "log")])
def test_a_single_problem_is_solved_as_a_batch_of_one(gamma, fisher):
    """One algorithm: the single problem and the same problem as a batch of one give the same bits."""
    rng = np.random.default_rng(int(10 * gamma))
    prob = random_problem(rng, gamma, n=41, fisher=fisher)
    single = solve_newton(prob, tol=1e-12)
    batch = solve_newton(prob.with_f_star(prob.f_star[None]), tol=1e-12)
    np.testing.assert_array_equal(single.f, batch.f[0])
    np.testing.assert_array_equal(single.m, batch.m[0])
    assert single.status is batch.status[0] and single.iterations == batch.iterations[0]
    assert single.kkt_residual == batch.kkt_residual[0] and single.objective == batch.objective[0]
    assert single.info["interior_damping"] == batch.info["interior_damping"][0]
