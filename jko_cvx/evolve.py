"""Repeated collision steps on a fixed velocity grid (the homogeneous equation).

This is the bare time loop of ``eqn: gke_hom`` without mesh refinement:
:math:`f^{n+1} = \\text{JKO}(f^n)` with a fixed :math:`\\Delta t`, for studies on a fixed grid
such as the exact-solution convergence tests.  Scenes with refinement, adaptive steps,
blow-up detection and run directories go through :func:`jko_cvx.engine.loop.simulate`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from jko_cvx._numbers import is_real, real_array
from jko_cvx.collision import CollisionProblem, CollisionResult, solve_collision
from jko_cvx.collision._checks import check_bool
from jko_cvx.grid import Grid
from jko_cvx.kernels import PowerKernel
from jko_cvx.limits import STEPS_ENV, Limits
from jko_cvx.time_order import collision_step_order2

__all__ = ["FixedGridRun", "evolve_fixed_grid"]


@dataclass
class FixedGridRun:
    """Output of :func:`evolve_fixed_grid`.

    Attributes
    ----------
    times : ndarray, shape (n_steps + 1,)
    f : ndarray, shape (n_steps + 1, N)
        Densities at the recorded times (``f[0]`` is the initial datum).
    results : list of CollisionResult
        One per step.
    completed : bool
        False when a step failed and the loop stopped early (``stop_on_failure``).
    """

    grid: Grid
    times: NDArray[np.float64]
    f: NDArray[np.float64]
    results: list[CollisionResult] = field(default_factory=list)
    completed: bool = True

    @property
    def statuses(self) -> list[str]:
        return [r.status.name for r in self.results]


def evolve_fixed_grid(
    grid: Grid,
    kernel: PowerKernel,
    f0: ArrayLike,
    dt: float,
    t_end: float,
    *,
    strength: float = 1.0,
    beta: float = np.inf,
    fisher: str | None = "perspective",
    method: str = "newton",
    time_order: int = 1,
    stop_on_failure: bool = True,
    progress: bool = False,
    **options: Any,
) -> FixedGridRun:
    """Run :math:`\\lceil t_{end}/\\Delta t \\rceil` collision steps of size ``dt`` (last one shortened).

    Parameters
    ----------
    grid, kernel, strength, beta, fisher
        As in :class:`~jko_cvx.CollisionProblem`.
    f0 : array_like, shape (N,)
        Initial density at the grid points.
    dt : float
        Time step.
    t_end : float
        Final time (> 0).
    method : str, default "newton"
        Collision solver; ``options`` are passed to it.  Newton is the default because it
        reaches the same error against the exact solutions 4-19 times faster than the
        conic reference and converges where the paper's SQP fails on vacuum tails
        (``jko-cvx study work_precision_run``).
    time_order : {1, 2}, default 1
        1: one JKO step per time step (first order in dt).  2: the Richardson-extrapolated
        step of :func:`jko_cvx.time_order.collision_step_order2` (three solves per step,
        second order in dt; mass exact, density positive).  Its ``results`` entries are the
        combined results (the three substeps in ``info["substeps"]``).
    stop_on_failure : bool, default True
        Stop at the first step whose result is not a success (the run is marked
        ``completed=False``); otherwise carry on with the returned density.
    progress : bool, default False
        Show a tqdm progress bar.

    Examples
    --------
    gamma = 1 without the Fisher term: the maximum of :math:`f_0 = e^{-2v^2}` follows the exact
    :math:`\\max f(t) = 1/(1 - 2t)` up to the blow-up time 1/2, and the mass is conserved:

    >>> import numpy as np
    >>> from jko_cvx import Grid, PowerKernel, evolve_fixed_grid
    >>> grid = Grid.uniform(-2.0, 2.0, 41)
    >>> run = evolve_fixed_grid(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), dt=0.01, t_end=0.1)
    >>> run.completed, run.f.shape, set(run.statuses)
    (True, (11, 41), {'CONVERGED'})
    >>> f"{run.f[-1].max():.3f} (exact {1 / (1 - 2 * run.times[-1]):.3f})"
    '1.246 (exact 1.250)'
    >>> bool(np.allclose(run.f @ grid.h, run.f[0] @ grid.h, rtol=1e-12))
    True
    """
    f, n_steps = _check_evolve_args(grid, kernel, f0, dt, t_end, strength, beta, fisher, time_order)
    check_bool("stop_on_failure", stop_on_failure)
    check_bool("progress", progress)
    times, snaps, results = [0.0], [f.copy()], []
    t = 0.0
    steps = range(n_steps)
    if progress:
        from tqdm.auto import tqdm

        steps = tqdm(steps, desc="collision steps", unit="step")

    def factory(g: NDArray[np.float64], step: float) -> CollisionProblem:
        return CollisionProblem(grid, kernel, g, step, strength, beta, fisher)

    completed = True
    for _ in steps:
        h = min(dt, t_end - t)
        if time_order == 1:
            res = solve_collision(factory(f, h), method=method, **options)
        else:
            res = collision_step_order2(factory, f, h, method=method, **options)
        results.append(res)
        if not res.success and stop_on_failure:
            completed = False
            break
        f = res.f
        t += h
        times.append(t)
        snaps.append(f.copy())
    return FixedGridRun(grid, np.array(times), np.array(snaps), results, completed)


def _check_evolve_args(grid, kernel, f0, dt, t_end, strength, beta, fisher, time_order) -> tuple[NDArray, int]:
    """The checked initial density and the step count; every error names the argument, before any step."""
    if not is_real(t_end) or not (np.isfinite(t_end) and t_end > 0):
        raise ValueError(f"t_end must be a finite number > 0, got {t_end!r}")
    if time_order not in (1, 2) or isinstance(time_order, bool):
        raise ValueError(f"time_order must be 1 or 2, got {time_order!r}")
    f = real_array("f0", f0)
    if isinstance(grid, Grid) and f.shape != (grid.n,):
        raise ValueError(f"f0 must have shape ({grid.n},) (one value per grid point), got {f.shape}")
    # Validate everything (grid, f0, dt, ...) once, before the loop; the problem's own
    # checks call the density f_star, which is f0 here.
    try:
        CollisionProblem(grid, kernel, f, dt, strength, beta, fisher)
    except (TypeError, ValueError) as exc:
        raise type(exc)(str(exc).replace("f_star", "f0")) from None
    n_steps = float(np.ceil(t_end / dt - 1e-9))
    limit = Limits.from_env().max_steps
    if n_steps > limit:
        raise ValueError(
            f"dt = {dt!r} with t_end = {t_end!r} needs about {n_steps:.3g} steps, above the limit of {limit:.3g}; "
            f"raise it with the environment variable {STEPS_ENV} if that is intended"
        )
    return f, int(n_steps)
