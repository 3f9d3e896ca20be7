"""The kernel W(v) = |v|^gamma / gamma (``kernel``) and its energy matrix, against the formula written out."""

import numpy as np
import pytest

from jko_cvx import Grid, PowerKernel


@pytest.mark.parametrize("gamma", [1.0, 1.5, 2.0, 3.0])
def test_kernel_values_and_derivative(gamma):
    k = PowerKernel(gamma)
    v = np.array([-2.0, -0.5, 0.0, 0.25, 3.0])
    np.testing.assert_allclose(k(v), np.abs(v) ** gamma / gamma, rtol=1e-15)
    assert k(2.0) == pytest.approx(2.0**gamma / gamma, rel=1e-15)
    np.testing.assert_allclose(k.derivative(v), np.sign(v) * np.abs(v) ** (gamma - 1), rtol=1e-15)


@pytest.mark.parametrize("gamma", [1.0, 1.5, 2.0, 3.0])
def test_energy_matrix_and_potential(gamma):
    g = Grid(np.array([-1.0, -0.6, 0.0, 0.3, 1.1, 2.0]))
    v, h = g.points, g.h
    K = np.abs(v[:, None] - v[None, :]) ** gamma / gamma * np.outer(h, h)
    op = PowerKernel(gamma).energy_operator(g)
    np.testing.assert_allclose(op.dense(), K, rtol=1e-13, atol=1e-15)
    f = np.exp(-(v**2))
    np.testing.assert_allclose(op.quadratic(f), f @ K @ f, rtol=1e-13)
    np.testing.assert_allclose(PowerKernel(gamma).potential(g, f), (K @ f) / h, rtol=1e-13)
