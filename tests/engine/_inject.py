"""Solver failures on demand for the engine's tests, independent of the BLAS kernel's rounding.

An iteration budget that a step needs exactly (``max_iter = 2`` where Newton converges in 2)
passes or fails by a rounding; these tests are about what the time loop does with a failure,
so the failure is imposed: the collision solve of a chosen attempt gets ``max_iter = 1``, which
Newton cannot meet on the steps used here (they need at least 3 iterations at the step sizes
involved), and every other attempt the default budget, which it meets with dozens to spare.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from unittest import mock

import numpy as np

import jko_cvx.engine.loop as loop


@contextmanager
def failing(rule: Callable[[int, int, float], bool]) -> Iterator[list[tuple[float, bool]]]:
    """Make the attempts for which ``rule(attempt, accepted, dt)`` is true fail with MAX_ITERATIONS.

    ``attempt`` counts collision solves from 0, ``accepted`` the certified ones before this one.
    Yields the list of ``(dt, success)`` of every attempt.
    """
    real = loop.solve_collision
    log: list[tuple[float, bool]] = []

    def solve(problem, method, **opts):
        accepted = sum(ok for _, ok in log)
        if rule(len(log), accepted, float(problem.dt)):
            res = real(problem, method=method, **{**opts, "max_iter": 1})
            assert not np.all(res.success), "the imposed failure must fail"
        else:
            res = real(problem, method=method, **opts)
        log.append((float(problem.dt), bool(np.all(res.success))))
        return res

    with mock.patch.object(loop, "solve_collision", solve):
        yield log


def interrupted_commit(at: int) -> Callable:
    """A ``Stepper.commit`` that raises KeyboardInterrupt (as SIGINT would) at its ``at``-th call (from 1),
    before the step is committed; every other call commits.  Patch it in with ``monkeypatch.setattr``."""
    calls, real = [0], loop.Stepper.commit

    def commit(self, state, out):
        calls[0] += 1
        if calls[0] == at:
            raise KeyboardInterrupt
        return real(self, state, out)

    return commit
