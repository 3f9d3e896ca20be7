"""dc_split="truncated": the leading eigenvalues exactly, a diagonal majorant of the rest."""

import numpy as np
import pytest

import jko_cvx.collision.conic as conic
from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision


def _grid(n, seed=0):
    rng = np.random.default_rng(seed)
    return Grid(np.sort(np.r_[-3.0, 3.0, rng.uniform(-3, 3, n - 2)]))


@pytest.mark.parametrize("gamma", [2.5, 3.0, 3.7])
def test_the_truncated_convex_part_majorises_the_energy_on_mass_free_directions(gamma):
    g = _grid(60)
    op = PowerKernel(gamma).energy_operator(g)
    sp = op.split()
    P_top, rho_tail = sp.truncated(g.h, 1e-4)
    assert 0 < P_top.shape[0] < sp.P_plus.shape[0] and rho_tail > 0
    C = P_top.T @ P_top + rho_tail * np.diag(g.h**2)
    Q = np.eye(g.n) - np.outer(g.h, g.h) / (g.h @ g.h)  # onto mass-free directions
    low = np.linalg.eigvalsh(Q @ (C - op.dense()) @ Q).min()
    assert low >= -1e-12 * np.abs(op.dense()).max()
    # without the diagonal the rest is not majorised
    assert np.linalg.eigvalsh(Q @ (P_top.T @ P_top - op.dense()) @ Q).min() < -1e3 * abs(low) - 1e-14
    # the dropped eigenvalues are below 1e-4 of the centred kernel's largest (computed here)
    W = np.abs(g.points[:, None] - g.points[None, :]) ** gamma / gamma
    W = W - W.mean(axis=0) - W.mean(axis=1)[:, None] + W.mean()
    assert rho_tail <= 1e-4 * np.linalg.eigvalsh(W).max() * (1 + 1e-9)


def test_nothing_dropped_is_the_eigen_split_bit_for_bit(monkeypatch):
    g = Grid.uniform(-2.0, 2.0, 41)
    prob = CollisionProblem(g, PowerKernel(3.0), np.exp(-2 * g.points**2), 0.01, beta=10.0)
    P_top, rho_tail = prob.energy.split().truncated(g.h, 0.0)
    assert P_top.shape == prob.energy.split().P_plus.shape and rho_tail == 0.0
    monkeypatch.setattr(conic, "_TRUNCATE_BELOW", 0.0)
    a = solve_collision(prob, method="conic", dc_split="eigen")
    b = solve_collision(prob, method="conic", dc_split="truncated")
    assert a.status is b.status and np.array_equal(a.f, b.f) and np.array_equal(a.m, b.m)


@pytest.mark.parametrize("n", [61, 121])
def test_truncated_split_certifies_the_point_newton_finds(n):
    g = Grid.uniform(-2.0, 2.0, n)
    prob = CollisionProblem(g, PowerKernel(3.0), np.exp(-2 * g.points**2), 0.01, beta=10.0, fisher="perspective")
    res = solve_collision(prob, method="conic", dc_split="truncated")
    ref = solve_collision(prob, method="newton")
    assert res.status.name == "CONVERGED" and ref.status.name == "CONVERGED"
    assert res.info["passes"] <= 4
    assert np.abs(res.f - ref.f).max() <= 1e-6 * ref.f.max()
