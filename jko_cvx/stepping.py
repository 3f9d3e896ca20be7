"""Time-step policies: fixed, halving on solver failure (``alg:MR_JKO_ver2``), CFL (``alg:SPMCSL-JKO``).

Stateless controllers in the style of diffrax: ``first(state)`` proposes the step, and
``retry(dt)`` returns the next smaller step after a failed collision solve, or None when
the policy gives up (which the caller records as the solver blow-up indicator e_f).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CFLStep", "FixedStep", "HalvingStep", "StepPolicy"]


@dataclass(frozen=True)
class FixedStep:
    """Fixed :math:`\\Delta t`; a failed solve is not retried."""

    dt: float

    def first(self, min_dv: float, min_dx: float | None, L_v: float, L_x: float | None) -> float:
        return self.dt

    def retry(self, dt: float) -> float | None:
        return None


@dataclass(frozen=True)
class HalvingStep:
    """``alg:MR_JKO_ver2``: start each step at ``dt``; while the solve fails, halve it.

    Gives up (returns None) once the step would fall to ``eps_t`` or below.
    """

    dt: float
    eps_t: float

    def first(self, min_dv: float, min_dx: float | None, L_v: float, L_x: float | None) -> float:
        return self.dt

    def retry(self, dt: float) -> float | None:
        return dt / 2 if dt / 2 > self.eps_t else None


@dataclass(frozen=True)
class CFLStep:
    """``alg:SPMCSL-JKO``: the CFL-type rule.

    :math:`\\Delta t = \\min(\\Delta t_0, 0.9\\,\\Delta v_{min}/L_v, 0.9\\,\\Delta x_{min}/L_x)`.
    """

    dt: float
    factor: float = 0.9

    def first(self, min_dv: float, min_dx: float | None, L_v: float, L_x: float | None) -> float:
        dt = min(self.dt, self.factor * min_dv / L_v)
        if min_dx is not None and L_x is not None:
            dt = min(dt, self.factor * min_dx / L_x)
        return dt

    def retry(self, dt: float) -> float | None:
        return None


StepPolicy = FixedStep | HalvingStep | CFLStep
