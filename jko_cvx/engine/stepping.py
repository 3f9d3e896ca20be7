"""Time-step policies: fixed, halving on solver failure (``alg:MR_JKO_ver2``), CFL (``alg:SPMCSL-JKO``).

Stateless controllers in the style of diffrax: ``first(..., carried)`` proposes the step
(``carried``: the last accepted step, which the paper's halving rule keeps), ``retry(dt)``
returns the next smaller step after a failed collision solve, or None when the policy gives
up (which the caller records as the solver blow-up indicator e_f), and ``exhausted(dt)``
says whether an accepted step of length dt ends the run (``eps_t`` of ``alg:MR_JKO_ver2``).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CFLStep", "FixedStep", "HalvingStep", "StepPolicy"]


@dataclass(frozen=True)
class FixedStep:
    """Fixed :math:`\\Delta t`; a failed solve is not retried."""

    dt: float

    def first(
        self, min_dv: float, min_dx: float | None, L_v: float, L_x: float | None, carried: float | None = None
    ) -> float:
        return self.dt

    def retry(self, dt: float) -> float | None:
        return None

    def exhausted(self, dt: float) -> bool:
        return False


@dataclass(frozen=True)
class HalvingStep:
    """``alg:MR_JKO_ver2`` as written: the step is set to ``dt`` once, halved while the solve
    fails (``e_f = 1``), and the halved step is carried forward: it never grows again, and the
    run ends (:attr:`~jko_cvx.engine.verdict.StopReason.EPS_T`) after the first accepted step of
    length ``<= eps_t`` (the algorithm's loop condition ``dt > eps_t``).

    The algorithm's inner loop has no floor; here a step that fails at a length already
    ``<= eps_t`` is not halved again and counts as a solver failure (``e_f``).

    Which failures reach :meth:`retry` is the scene's ``time.halve_on``
    (:class:`~jko_cvx.scene.Scene`): every step the engine does not accept (default), or, as
    the paper, only the exit flag ``e_f`` (``MAX_ITERATIONS``); the stepper
    (:class:`jko_cvx.engine.loop.Stepper`) applies it.

    With ``reset=True`` (scene policy ``"halving_reset"``, this package's earlier rule) every
    step restarts at ``dt`` and the policy gives up once the halved step would fall to
    ``eps_t`` or below; the run never ends on ``eps_t``.  Measured on ``gk1_records``: see
    ``studies/README.md``.
    """

    dt: float
    eps_t: float
    reset: bool = False

    def first(
        self, min_dv: float, min_dx: float | None, L_v: float, L_x: float | None, carried: float | None = None
    ) -> float:
        return self.dt if self.reset or carried is None else carried

    def retry(self, dt: float) -> float | None:
        if self.reset:
            return dt / 2 if dt / 2 > self.eps_t else None
        return dt / 2 if dt > self.eps_t else None

    def exhausted(self, dt: float) -> bool:
        """True when an accepted step of length ``dt`` ends the run (``dt <= eps_t``; never with reset)."""
        return not self.reset and dt <= self.eps_t


@dataclass(frozen=True)
class CFLStep:
    """``alg:SPMCSL-JKO``: the CFL-type rule.

    :math:`\\Delta t = \\min(\\Delta t_0, 0.9\\,\\Delta v_{min}/L_v, 0.9\\,\\Delta x_{min}/L_x)`.
    """

    dt: float
    factor: float = 0.9

    def first(
        self, min_dv: float, min_dx: float | None, L_v: float, L_x: float | None, carried: float | None = None
    ) -> float:
        dt = min(self.dt, self.factor * min_dv / L_v)
        if min_dx is not None and L_x is not None:
            dt = min(dt, self.factor * min_dx / L_x)
        return dt

    def retry(self, dt: float) -> float | None:
        return None

    def exhausted(self, dt: float) -> bool:
        return False


StepPolicy = FixedStep | HalvingStep | CFLStep
