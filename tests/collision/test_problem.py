"""The discrete problem itself: derivatives, constraint, KKT residual."""

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel
from jko_cvx.testing import random_density, random_grid


def _problem(rng, gamma, fisher, n=11, beta=0.7):
    g = random_grid(rng, n)
    return CollisionProblem(g, PowerKernel(gamma), random_density(rng, g), 0.1, beta=beta, fisher=fisher)


@pytest.mark.parametrize("fisher", ["log", "perspective", None])
@pytest.mark.parametrize("gamma", [1.0, 1.5, 2.0, 3.0])
def test_gradient_and_hessian_match_finite_differences(rng, gamma, fisher):
    P = _problem(rng, gamma, fisher)
    n = P.n
    f = rng.uniform(0.5, 2.0, n)
    m = rng.normal(size=n - 1)
    u = np.r_[f, m]

    def J(w):
        return P.objective(w[:n], w[n:])

    def G(w):
        gf, gm = P.gradient(w[:n], w[n:])
        return np.r_[gf, gm]

    eps = 1e-6
    E = np.eye(u.size)
    g_fd = np.array([(J(u + eps * e) - J(u - eps * e)) / (2 * eps) for e in E])
    H_fd = np.array([(G(u + eps * e) - G(u - eps * e)) / (2 * eps) for e in E])
    assert np.allclose(G(u), g_fd, rtol=1e-6, atol=1e-8 * np.abs(g_fd).max())
    H = P.hessian(f, m)
    assert np.allclose(H, H.T)
    assert np.allclose(H, H_fd, rtol=1e-5, atol=1e-7 * np.abs(H).max())


def test_every_feasible_point_has_the_mass_of_f_star(rng):
    P = _problem(rng, 1.0, "perspective", n=30)
    m = rng.normal(size=P.n - 1) * 1e-2
    f = P.density_from_flux(m)
    assert np.abs(P.constraint_residual(f, m)).max() < 1e-15
    assert P.mass_error(f) < 1e-14
    # and the flux is recovered from the density
    assert np.allclose(P.flux_from_density(f), m, atol=1e-15)


def test_kkt_residual_detects_a_wrong_point(rng):
    """The residual is small only at the minimiser: a perturbed feasible point fails it."""
    from jko_cvx import solve_collision

    P = _problem(rng, 1.0, "perspective", n=41, beta=10.0)
    res = solve_collision(P, method="sqp", tol=1e-13)
    assert res.kkt_residual < 1e-9
    m_bad = res.m * (1 + 1e-3)
    f_bad = P.density_from_flux(m_bad)
    # A 0.1 % flux error raises the residual by many orders of magnitude.
    assert P.kkt_residual(f_bad, m_bad).total > 1e-5 > 1e4 * res.kkt_residual
    # and an infeasible point fails through the feasibility component
    assert P.kkt_residual(res.f * 1.001, res.m).feasibility > 1e-4


def test_objective_has_benamou_brenier_convention_at_vacuum():
    g = Grid.uniform(-1, 1, 5)
    P = CollisionProblem(g, PowerKernel(1.0), np.array([0, 0, 1.0, 1, 1]), 0.1)
    f = np.array([0.0, 0.0, 1.0, 1.0, 1.0])
    assert np.isfinite(P.objective(f, np.zeros(4)))
    assert P.objective(f, np.array([1e-3, 0, 0, 0])) == np.inf


def test_batched_problem_evaluates_rowwise(rng):
    g = random_grid(rng, 25)
    F = np.stack([random_density(rng, g) for _ in range(3)])
    B = CollisionProblem(g, PowerKernel(1.5), F, 0.05, beta=5.0)
    m = rng.normal(size=(3, g.n - 1)) * 1e-3
    f = B.density_from_flux(m)
    for i in range(3):
        S = B.slice(i)
        assert B.objective(f, m)[i] == pytest.approx(S.objective(f[i], m[i]), rel=1e-14)
        assert B.kkt_residual(f, m).total[i] == pytest.approx(S.kkt_residual(f[i], m[i]).total, rel=1e-10)


def test_batched_tridiagonal_solves_match_dense_solves_with_and_without_definiteness():
    """solve_sym_tridiagonal: a batch goes to LAPACK as one block-diagonal system; a batch with an
    indefinite row falls back to the elimination loop; a shared matrix broadcasts over rhs rows."""
    from jko_cvx.collision._linalg import solve_sym_tridiagonal

    rng = np.random.default_rng(3)
    rows, n = 7, 12
    off = -rng.uniform(0.1, 1.0, (rows, n - 1))
    diag = rng.uniform(0.1, 1.0, (rows, n))
    diag[:, :-1] -= off
    diag[:, 1:] -= off
    rhs = rng.normal(size=(rows, n))

    def dense(d, o):
        return np.diag(d) + np.diag(o, 1) + np.diag(o, -1)

    for d in (diag, diag * np.where(np.arange(rows) == 4, -1.0, 1.0)[:, None]):
        x = solve_sym_tridiagonal(d, off, rhs)
        for i in range(rows):
            np.testing.assert_allclose(x[i], np.linalg.solve(dense(d[i], off[i]), rhs[i]), rtol=1e-10, atol=1e-12)
    shared = solve_sym_tridiagonal(diag[0], off[0], rhs)
    np.testing.assert_allclose(shared, np.linalg.solve(dense(diag[0], off[0]), rhs.T).T, rtol=1e-10, atol=1e-12)
