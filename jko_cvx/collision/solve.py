"""``solve_collision``: the one entry point for every collision solver."""

from __future__ import annotations

import functools
import inspect
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from jko_cvx.collision.conic import ConicOptions, solve_conic
from jko_cvx.collision.newton import NewtonOptions, solve_newton
from jko_cvx.collision.nlp import NlpOptions, solve_nlp
from jko_cvx.collision.options import Options
from jko_cvx.collision.problem import CollisionProblem
from jko_cvx.collision.result import CollisionResult
from jko_cvx.collision.sqp import SqpOptions, solve_sqp
from jko_cvx.threads import blas_limits

__all__ = ["METHODS", "OPTIONS", "solve_collision"]

METHODS: dict[str, Callable[..., CollisionResult]] = {
    "conic": solve_conic,
    "sqp": solve_sqp,
    "newton": solve_newton,
    "nlp": solve_nlp,
}

OPTIONS: dict[str, type[Options]] = {
    "conic": ConicOptions,
    "sqp": SqpOptions,
    "newton": NewtonOptions,
    "nlp": NlpOptions,
}
"""Per method: its options dataclass, one field per keyword option of the solver in :data:`METHODS`."""


@functools.cache
def _options_of(func: Callable[..., Any]) -> list[str]:
    return [p.name for p in inspect.signature(func).parameters.values() if p.kind is p.KEYWORD_ONLY]


def solve_collision(problem: CollisionProblem, method: str = "conic", **options: Any) -> CollisionResult:
    """Solve one collision step (or a batch of them) with the named method.

    Parameters
    ----------
    problem : CollisionProblem
        The discrete JKO step.  A batched problem (``f_star`` of shape ``(B, N)``) is
        solved slice by slice for methods without a batched form, and the result
        holds one row / one status per slice.
    method : {"conic", "sqp", "newton", "nlp"}
        ``"conic"``: the CVXPY reference (:func:`jko_cvx.collision.conic.solve_conic`);
        ``"sqp"``: the paper's Algorithm 1 (:func:`jko_cvx.collision.sqp.solve_sqp`);
        ``"newton"``: damped Newton on the reduced KKT system, batched over slices
        (:func:`jko_cvx.collision.newton.solve_newton`);
        ``"nlp"``: CVXPY's nonlinear mode with IPOPT, either Fisher form
        (:func:`jko_cvx.collision.nlp.solve_nlp`; needs ``pip install "jko_cvx[nlp]"``).
    **options
        Keyword options of the chosen method (see its docstring).  Unknown options
        raise ``TypeError`` before any work is done.

    Returns
    -------
    CollisionResult
        Always returned; check ``result.success`` / ``result.status``.

    Examples
    --------
    >>> import numpy as np
    >>> from jko_cvx import Grid, PowerKernel, CollisionProblem, solve_collision
    >>> grid = Grid.uniform(-2.0, 2.0, 61)
    >>> prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), dt=0.01, beta=10.0)
    >>> res = solve_collision(prob, method="sqp")
    >>> bool(res.success), res.kkt_residual < 1e-6
    (True, True)
    """
    if not isinstance(problem, CollisionProblem):
        raise TypeError(f"problem must be a CollisionProblem, got {type(problem).__name__}")
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"method must be one of {sorted(METHODS)}, got {method!r}")
    func = METHODS[method]
    allowed = _options_of(func)
    unknown = sorted(set(options).difference(allowed)) if options else None
    if unknown:
        raise TypeError(f"unknown option(s) {unknown} for method={method!r}; allowed: {allowed}")
    with blas_limits():  # BLAS threads per jko_cvx.threads (default 1; slices run in threads)
        if problem.batched and not getattr(func, "batched", False):
            return _solve_slices(problem, func, method, options)
        return func(problem, **options)


def _solve_slices(
    problem: CollisionProblem, func: Callable[..., CollisionResult], method: str, options
) -> CollisionResult:
    t0 = time.perf_counter()
    results = [func(problem.slice(i), **options) for i in range(problem.batch_size)]
    status = np.empty(len(results), dtype=object)
    status[:] = [r.status for r in results]
    return CollisionResult(
        f=np.stack([r.f for r in results]),
        m=np.stack([r.m for r in results]),
        status=status,
        method=method,
        iterations=np.array([r.iterations for r in results]),
        objective=np.array([r.objective for r in results]),
        kkt_residual=np.array([r.kkt_residual for r in results]),
        mass_error=np.array([r.mass_error for r in results]),
        seconds=time.perf_counter() - t0,
        info={"slices": [r.info for r in results]},
    )
