"""Random problem families shared by the test suite, benchmarks and solver comparisons."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from jko_cvx.collision import CollisionProblem
from jko_cvx.grid import Grid
from jko_cvx.kernels import PowerKernel

__all__ = ["random_density", "random_grid", "random_problem"]


def random_grid(rng: np.random.Generator, n: int, half_width: float = 2.0, spread: float = 0.7) -> Grid:
    """Non-uniform grid on ``[-half_width, half_width]`` with spacings drawn from ``U(1-spread, 1+spread)``."""
    steps = rng.uniform(1 - spread, 1 + spread, n - 1)
    pts = np.concatenate([[0.0], np.cumsum(steps)])
    pts = -half_width + 2 * half_width * pts / pts[-1]
    return Grid(pts)


def random_density(rng: np.random.Generator, grid: Grid, floor: float = 0.05) -> NDArray[np.float64]:
    """Positive density: one to three random Gaussian bumps plus 10 % multiplicative noise, floored."""
    v = grid.points
    L = grid.length / 2
    f = np.zeros_like(v)
    for _ in range(rng.integers(1, 4)):
        f += rng.uniform(0.5, 2.0) * np.exp(-rng.uniform(1.0, 6.0) * (v - rng.uniform(-L / 2, L / 2)) ** 2)
    f *= 1 + 0.1 * rng.uniform(-1, 1, v.size)
    return np.maximum(f, floor * f.max())


def random_problem(
    rng: np.random.Generator,
    gamma: float,
    n: int | None = None,
    dt: float | None = None,
    beta: float = 10.0,
    fisher: str | None = "perspective",
) -> CollisionProblem:
    """A random problem of the agreement family: non-uniform grid, N in [31, 201], moderate dt.

    "Moderate" means ``dt = min(U(0.005, 0.02), c * min(dv) / max|a|)`` with ``c ~ U(0.3, 0.9)``
    and ``a`` the explicit collision velocity: an explicit CFL number below one, the
    regime in which the paper's SQP (whose first step is explicit) is meant to work.
    """
    n = int(rng.integers(31, 202)) if n is None else n
    grid = random_grid(rng, n)
    f_star = random_density(rng, grid)
    kernel = PowerKernel(gamma)
    if dt is None:
        probe = CollisionProblem(grid, kernel, f_star, 1.0)
        cap = rng.uniform(0.3, 0.9) * grid.dv.min() / np.abs(probe.explicit_velocity()).max()
        dt = float(min(rng.uniform(0.005, 0.02), cap))
    return CollisionProblem(grid, kernel, f_star, dt, beta=beta, fisher=fisher)
