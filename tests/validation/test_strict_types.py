"""Lenient numbers and arrays are refused by name: strings, booleans, complex, masked and
object arrays never reach the solvers (``float("10")``, ``float(True)`` and
``np.asarray(z, dtype=float)`` would have accepted them, the last dropping the imaginary
part or the mask)."""

from __future__ import annotations

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
from jko_cvx.collision.certify import certify
from jko_cvx.evolve import evolve_fixed_grid
from jko_cvx.grid import PeriodicGrid

GRID = Grid.uniform(-2.0, 2.0, 21)
K = PowerKernel(1.0)
F = np.exp(-2 * GRID.points**2)


@pytest.mark.parametrize("name", ["dt", "beta", "strength"])
@pytest.mark.parametrize("value", ["10", True, np.bool_(True), 1 + 0j, None])
def test_problem_numbers_must_be_real(name, value):
    kwargs = {"dt": 0.01, "beta": 10.0, "strength": 1.0, name: value}
    with pytest.raises(TypeError, match=rf"^{name} must be a real number"):
        CollisionProblem(GRID, K, F, **kwargs)


def test_numpy_numbers_and_zero_dimensional_arrays_are_numbers():
    a = CollisionProblem(GRID, K, F, dt=np.float32(0.01), beta=np.array(10.0), strength=np.int64(1))
    b = CollisionProblem(GRID, K, F, dt=float(np.float32(0.01)), beta=10.0, strength=1.0)
    assert (a.dt, a.beta, a.strength) == (b.dt, b.beta, b.strength)


@pytest.mark.parametrize("gamma", [True, "1", 1j, None])
def test_kernel_exponent_must_be_real(gamma):
    with pytest.raises(TypeError, match=r"^gamma must be a real number"):
        PowerKernel(gamma)


@pytest.mark.parametrize(
    "bad, what",
    [
        (F + 0j, "dtype complex"),
        (np.ma.masked_array(F, F < 0.1), "masked array"),
        (F.astype(object), "dtype object"),
        (np.array([*F[:-1], "x"], dtype=object), "element of type str"),
        (F > 0.5, "dtype bool"),
        (F.astype(str), "dtype <U"),
    ],
)
def test_densities_must_be_real_arrays(bad, what):
    with pytest.raises(TypeError, match=f"^f_star must be .*{what}"):
        CollisionProblem(GRID, K, bad, dt=0.01)
    with pytest.raises(TypeError, match=f"^f0 must be .*{what}"):
        evolve_fixed_grid(GRID, K, bad, 0.01, 0.02)


def test_integer_arrays_and_lists_are_real():
    a = CollisionProblem(GRID, K, np.ones(21, dtype=np.int32), dt=0.01)
    b = CollisionProblem(GRID, K, [1.0] * 21, dt=0.01)
    np.testing.assert_array_equal(a.f_star, b.f_star)


def test_grid_points_must_be_real():
    with pytest.raises(TypeError, match=r"^points must be .*dtype complex"):
        Grid(np.linspace(0, 1, 5) + 0j)
    with pytest.raises(TypeError, match=r"^points must be .*masked"):
        Grid(np.ma.masked_array(np.linspace(0, 1, 5)))
    with pytest.raises(TypeError, match=r"^points must be .*dtype bool"):
        Grid(np.array([False, True, True]))
    with pytest.raises(TypeError, match=r"^period must be a real number"):
        PeriodicGrid(np.linspace(0, 1, 5), "2")


def test_certify_refuses_complex_iterates():
    prob = CollisionProblem(GRID, K, F, dt=0.01, beta=10.0)
    res = solve_collision(prob, "newton")
    with pytest.raises(TypeError, match=r"^f must be .*complex"):
        certify(prob, res.f + 0j, res.m, kkt_tol=1e-8)


@pytest.mark.parametrize("callback", [lambda: None, lambda a, b: None, lambda a, b, c, d, e: None])
def test_sqp_callback_of_the_wrong_signature_is_refused_before_the_solve(callback):
    prob = CollisionProblem(GRID, K, F, dt=0.01, beta=10.0)
    with pytest.raises(TypeError, match=r"callback is called as callback\(l, f, m, zeta\)"):
        solve_collision(prob, "sqp", callback=callback)


def test_sqp_callbacks_that_fit_are_called():
    prob = CollisionProblem(GRID, K, F, dt=0.01, beta=10.0)
    seen = []
    solve_collision(prob, "sqp", callback=lambda *args: seen.append(len(args)))
    solve_collision(prob, "sqp", callback=lambda it, f, m, zeta, extra=None: seen.append(4))
    assert seen and set(seen) == {4}


@pytest.mark.parametrize("solver", ["CLARABEL", "SCS"])
def test_an_unknown_solver_setting_is_named_with_the_solver(solver):
    prob = CollisionProblem(GRID, K, F, dt=0.01, beta=10.0)
    with pytest.raises(TypeError, match=rf"solver_options \['eps_absolute'\] .*{solver}"):
        solve_collision(prob, "conic", solver=solver, solver_options={"eps_absolute": 1e-9})
