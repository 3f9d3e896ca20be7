"""Time-step policies: fixed, halving on solver failure (``alg:MR_JKO_ver2``), CFL (``alg:SPMCSL-JKO``).

Stateless controllers in the style of diffrax: ``first(..., carried)`` proposes the step
(``carried``: the last accepted step, which the paper's halving rule keeps), ``refuses(statuses)``
says whether a failed collision solve ends the run at once instead of being retried,
``retry(dt)`` returns the next smaller step after a failed solve, or None when the policy gives
up (which the caller records as the solver blow-up indicator e_f), and ``exhausted(dt)`` /
``end(dt)`` say whether (and why) an accepted step of length dt ends the run (``eps_t`` of
``alg:MR_JKO_ver2``).  :func:`step_policy` builds a policy by name, checking its parameters.

>>> p = step_policy("halving", 0.01, eps_t=0.002)
>>> p.retry(0.01), p.retry(0.002), p.end(0.002)
(0.005, None, 'dt = 0.002 <= eps_t = 0.002')
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from jko_cvx.collision.result import Status

__all__ = ["HALVE_ON", "POLICIES", "CFLStep", "FixedStep", "HalvingStep", "StepPolicy", "step_policy"]

POLICIES = ("fixed", "halving", "halving_reset", "cfl")
"""The policies by name (a scene's ``time.policy``)."""

HALVING_POLICIES = ("halving", "halving_reset")
"""The names of :class:`HalvingStep`: as written (the halved step carried) and with reset."""

HALVE_ON = ("any_failure", "max_iterations")
"""Which failed collision solves halve the step (:attr:`HalvingStep.halve_on`)."""


def _check_halve_on(halve_on: str, prefix: str) -> None:
    if halve_on not in HALVE_ON:
        raise ValueError(f"{prefix}halve_on must be one of {list(HALVE_ON)}, got {halve_on!r}")


@dataclass(frozen=True)
class FixedStep:
    """Fixed :math:`\\Delta t`; a failed solve is not retried."""

    dt: float

    def first(
        self, min_dv: float, min_dx: float | None, L_v: float, L_x: float | None, carried: float | None = None
    ) -> float:
        return self.dt

    def refuses(self, statuses: Sequence[str]) -> bool:
        return False

    def retry(self, dt: float) -> float | None:
        return None

    def exhausted(self, dt: float) -> bool:
        return False

    def end(self, dt: float) -> str | None:
        return None


@dataclass(frozen=True)
class HalvingStep:
    """``alg:MR_JKO_ver2`` as written: the step is set to ``dt`` once, halved while the solve
    fails (``e_f = 1``), and the halved step is carried forward: it never grows again, and the
    run ends (:meth:`end`) after the first accepted step of length ``<= eps_t`` (the
    algorithm's loop condition ``dt > eps_t``).

    The algorithm's inner loop has no floor; here a step that fails at a length already
    ``<= eps_t`` is not halved again and counts as a solver failure (``e_f``).

    Which failures halve the step is ``halve_on`` (:meth:`refuses`): ``"any_failure"`` (default:
    every solve the caller does not accept) or, as the paper, ``"max_iterations"``: only the
    exit flag ``e_f`` (``MAX_ITERATIONS``); any other failure then ends the run.

    With ``reset=True`` (policy ``"halving_reset"``, this package's earlier rule) every
    step restarts at ``dt`` and the policy gives up once the halved step would fall to
    ``eps_t`` or below; the run never ends on ``eps_t``.  The two rules are compared on the
    adaptive g1 runs of ``gk1_records`` (the paper-variants study).

    Raises
    ------
    ValueError
        Unless ``eps_t < dt`` (the halving floor) and ``halve_on`` is one of :data:`HALVE_ON`.
    """

    dt: float
    eps_t: float
    reset: bool = False
    halve_on: str = "any_failure"

    def __post_init__(self) -> None:
        self.check(self.dt, self.eps_t, self.halve_on)

    @staticmethod
    def check(dt: float, eps_t: float, halve_on: str = "any_failure", prefix: str = "") -> None:
        """``ValueError`` unless ``eps_t < dt`` and ``halve_on`` is one of :data:`HALVE_ON`; the message
        names each parameter with ``prefix`` before it (a scene passes ``"time."``)."""
        _check_halve_on(halve_on, prefix)
        if not eps_t < dt:
            raise ValueError(f"{prefix}eps_t must be < {prefix}dt = {dt:g} (the halving floor), got {eps_t:g}")

    def first(
        self, min_dv: float, min_dx: float | None, L_v: float, L_x: float | None, carried: float | None = None
    ) -> float:
        return self.dt if self.reset or carried is None else carried

    def refuses(self, statuses: Sequence[str]) -> bool:
        """True when a failed solve with these statuses (names of :class:`~jko_cvx.collision.Status`) is
        not halved but ends the run: under ``halve_on = "max_iterations"``, any status but ``MAX_ITERATIONS``."""
        other = [st for st in statuses if st != Status.MAX_ITERATIONS.name]
        return self.halve_on == "max_iterations" and bool(other)

    def retry(self, dt: float) -> float | None:
        if self.reset:
            return dt / 2 if dt / 2 > self.eps_t else None
        return dt / 2 if dt > self.eps_t else None

    def exhausted(self, dt: float) -> bool:
        """True when an accepted step of length ``dt`` ends the run (``dt <= eps_t``; never with reset)."""
        return not self.reset and dt <= self.eps_t

    def end(self, dt: float) -> str | None:
        """Why an accepted step of length ``dt`` ends the run (None: it does not)."""
        return f"dt = {dt:.3g} <= eps_t = {self.eps_t:.3g}" if self.exhausted(dt) else None


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

    def refuses(self, statuses: Sequence[str]) -> bool:
        return False

    def retry(self, dt: float) -> float | None:
        return None

    def exhausted(self, dt: float) -> bool:
        return False

    def end(self, dt: float) -> str | None:
        return None


StepPolicy = FixedStep | HalvingStep | CFLStep


def step_policy(
    policy: str, dt: float, eps_t: float = 1e-6, halve_on: str = "any_failure", prefix: str = ""
) -> StepPolicy:
    """The step policy named ``policy`` (one of :data:`POLICIES`), its parameters checked.

    Parameters
    ----------
    policy : str
        ``"fixed"``, ``"halving"`` (``alg:MR_JKO_ver2`` as written), ``"halving_reset"`` or ``"cfl"``.
    dt : float
        The (first, largest) step.
    eps_t : float
        The halving floor (halving policies only).
    halve_on : str
        Which failures halve the step (:data:`HALVE_ON`); other than ``"any_failure"`` only for
        the halving policies, the others never halve.
    prefix : str
        Put before each parameter's name in error messages (a scene passes ``"time."``).

    Raises
    ------
    ValueError
        Naming the parameter: an unknown policy or ``halve_on``, ``eps_t >= dt`` for a halving
        policy, or ``halve_on`` set for a policy that never halves the step.
    """
    if policy not in POLICIES:
        raise ValueError(f"{prefix}policy must be one of {list(POLICIES)}, got {policy!r}")
    if policy in HALVING_POLICIES:
        HalvingStep.check(dt, eps_t, halve_on, prefix)  # here for the prefix; the constructor checks again
        return HalvingStep(dt, eps_t, reset=policy == "halving_reset", halve_on=halve_on)
    _check_halve_on(halve_on, prefix)
    if halve_on != "any_failure":
        raise ValueError(
            f"{prefix}halve_on = {halve_on!r} needs {prefix}policy 'halving' or 'halving_reset' "
            f"(policy {policy!r} never halves the step)"
        )
    return FixedStep(dt) if policy == "fixed" else CFLStep(dt)
