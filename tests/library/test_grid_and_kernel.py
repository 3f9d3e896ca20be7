import numpy as np
import pytest

from jko_cvx import Grid, PowerKernel
from jko_cvx.testing import random_grid


def test_uniform_grid_cells_sum_to_length():
    g = Grid.uniform(-2.0, 2.0, 41)
    assert g.h.sum() == pytest.approx(4.0, rel=1e-15)
    assert np.allclose(g.dv, 0.1)
    assert g.h[0] == pytest.approx(0.05) and g.h[-1] == pytest.approx(0.05)


def test_trapezoid_quadrature_exact_for_linear(rng):
    g = random_grid(rng, 57)
    # Trapezoidal rule integrates affine functions exactly on any grid.
    assert g.integrate(3.0 + 2.0 * g.points) == pytest.approx(3.0 * g.length + (g.points[-1] ** 2 - g.points[0] ** 2))


def test_grid_is_frozen():
    g = Grid.uniform(0, 1, 5)
    with pytest.raises(ValueError):
        g.points[0] = 3.0


@pytest.mark.parametrize(
    "points, match",
    [
        ([0.0, 1.0], "at least 3"),
        ([0.0, 1.0, 1.0], "strictly increasing"),
        ([0.0, 2.0, 1.0], "strictly increasing"),
        ([0.0, np.nan, 1.0], "finite"),
        ([[0.0, 1.0, 2.0]], "one-dimensional"),
    ],
)
def test_grid_rejects_bad_points(points, match):
    with pytest.raises(ValueError, match=match):
        Grid(points)


@pytest.mark.parametrize("gamma", [0.0, -1.0, np.nan, np.inf])
def test_kernel_rejects_bad_gamma(gamma):
    with pytest.raises(ValueError, match="gamma"):
        PowerKernel(gamma)


def test_low_rank_energy_equals_dense_kernel(rng):
    g = random_grid(rng, 33)
    k = PowerKernel(2.0)
    op = k.energy_operator(g)
    v = g.points
    K = 0.5 * (v[:, None] - v[None, :]) ** 2 * np.outer(g.h, g.h)
    assert np.allclose(op.dense(), K, rtol=1e-13, atol=1e-15)
    f = rng.uniform(0.1, 1.0, (3, g.n))
    assert np.allclose(op.matvec(f), f @ K, rtol=1e-12)
    assert np.allclose(op.quadratic(f), np.einsum("bi,ij,bj->b", f, K, f), rtol=1e-12)


@pytest.mark.parametrize("gamma", [1.0, 1.5, 2.0, 3.0])
def test_energy_split_is_exact_on_mass_free_directions(rng, gamma):
    g = random_grid(rng, 40)
    op = PowerKernel(gamma).energy_operator(g)
    sp = op.split()
    K = op.dense()
    for _ in range(5):
        d = rng.normal(size=g.n)
        d -= (d @ g.h) / (g.h @ g.h) * g.h
        lhs = d @ K @ d
        rhs = np.sum((sp.P_plus @ d) ** 2) - np.sum((sp.P_minus @ d) ** 2)
        assert rhs == pytest.approx(lhs, rel=1e-10, abs=1e-14 * np.abs(K).max())
    if gamma <= 2:
        # |v|^gamma is conditionally negative definite: no convex part at all.
        assert sp.P_plus.shape[0] == 0
    else:
        assert sp.P_plus.shape[0] > 0 and sp.P_minus.shape[0] > 0
