"""The verdict of a run: why it stopped, and whether that is blow-up (``B_v``, ``B_x``, ``e_f``).

The paper's blow-up indicators (sec. ``sec:numerical``): ``B_v`` when the velocity mesh
concentrates below ``eps_v`` (or, with ``stop.spread_v``, the velocity spread of a populated
slice falls below it), ``B_x`` when the space mesh concentrates below ``eps_x``, and ``e_f``
when the collision solver fails in a way the step policy cannot cure (counted as ``B_v``).
A :class:`Verdict` is immutable; the stopping rules return a new one.  It also reads as the
mapping ``run.verdict["T_b"]`` of earlier versions (keys ``blowup``, ``T_b``, ``B_x``, ``B_v``,
``e_f``, ``reason``, ``stop``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from jko_cvx.engine._state import RunState

__all__ = ["SolverFailureRule", "StopReason", "Verdict"]


class StopReason(Enum):
    """Why the time loop stopped; the value is the rule in words."""

    T_END = "reached t_end"
    EPS_V = "min dv < eps_v"
    EPS_X = "min dx < eps_x"
    SPREAD_V = "min spread_v < spread_v"
    SOLVER_FAILURE = "collision solver failed"
    EPS_T = "dt <= eps_t"
    NO_STEP = "no step was accepted"

    @property
    def blowup(self) -> bool:
        """Every reason but reaching ``t_end`` and a run that never took a step flags blow-up."""
        return self not in (StopReason.T_END, StopReason.NO_STEP)


_KEYS = ("blowup", "T_b", "B_x", "B_v", "e_f", "reason", "stop", "uncertified_steps", "first_uncertified_t")


@dataclass(frozen=True)
class Verdict(Mapping):
    """Outcome of a run.

    Attributes
    ----------
    stop : StopReason
        The rule that stopped the run (the last to fire when several fire on one step).
    T_b : float or None
        The time of the step at which a blow-up rule fired (None without blow-up).
    B_x, B_v, e_f : bool
        The paper's indicators; ``e_f`` is also set by a failed solve that did not stop the
        run (``stop.on_solver_failure = false``).
    reason : str
        The rule with the value that fired it, e.g. ``"min dv = 0.000244 < eps_v"``.
    uncertified_steps : int
        Steps whose collision solve failed and whose state the run carried on from
        (``stop.on_solver_failure = false``, as the paper's ``tab:bu`` runs); every verdict
        drawn after one is drawn from uncertified states (:attr:`certified` is False).
    first_uncertified_t : float or None
        The time of the first such state.

    A run that never accepted a step (its first solve failed and stopped it) stops with
    :attr:`StopReason.NO_STEP`: not a blow-up, ``T_b`` None.
    """

    stop: StopReason = StopReason.T_END
    T_b: float | None = None
    B_x: bool = False
    B_v: bool = False
    e_f: bool = False
    reason: str = StopReason.T_END.value
    uncertified_steps: int = 0
    first_uncertified_t: float | None = None

    @property
    def blowup(self) -> bool:
        return self.stop.blowup

    @property
    def certified(self) -> bool:
        """Every state the verdict is drawn from came from a certified collision solve."""
        return self.uncertified_steps == 0

    def describe(self) -> str:
        """The verdict in words, saying so where it is drawn from uncertified states."""
        if self.certified:
            return f"blow-up = {self.blowup}"
        claim = "undetermined" if not self.blowup else "True, from uncertified states"
        return (
            f"blow-up = {claim} (NOT CERTIFIED: {self.uncertified_steps} step(s) carried a failed collision "
            f"solve, from t = {self.first_uncertified_t:.6g}; stop.on_solver_failure = false)"
        )

    def stopped(self, stop: StopReason, t: float, reason: str) -> Verdict:
        """The verdict after rule ``stop`` fired at time ``t`` (flags accumulate; the last reason wins)."""
        if not stop.blowup:
            raise ValueError("stopped() records a blow-up rule; reaching t_end is the default verdict, no_step its own")
        flag = {"B_x": True} if stop is StopReason.EPS_X else {"B_v": True}
        # the step collapses below eps_t only through repeated failed solves (alg:MR_JKO_ver2)
        e_f = self.e_f or stop in (StopReason.SOLVER_FAILURE, StopReason.EPS_T)
        return dataclasses.replace(self, stop=stop, T_b=float(t), reason=reason, e_f=e_f, **flag)

    def no_step(self, reason: str) -> Verdict:
        """The verdict of a run whose first step failed and stopped it: no blow-up, no ``T_b``."""
        return dataclasses.replace(
            self, stop=StopReason.NO_STEP, T_b=None, B_v=False, B_x=False, e_f=True, reason=reason
        )

    def solver_failed(self, t: float) -> Verdict:
        """The verdict after a failed solve that does not stop the run: ``e_f`` set, the uncertified
        state at time ``t`` counted."""
        first = float(t) if self.first_uncertified_t is None else self.first_uncertified_t
        return dataclasses.replace(
            self, e_f=True, uncertified_steps=self.uncertified_steps + 1, first_uncertified_t=first
        )

    # the Mapping interface of the earlier dict verdict
    def __getitem__(self, key: str) -> Any:
        if key not in _KEYS:
            raise KeyError(key)
        return self.stop.name if key == "stop" else getattr(self, key)

    def __iter__(self) -> Iterator[str]:
        return iter(_KEYS)

    def __len__(self) -> int:
        return len(_KEYS)

    def __eq__(self, other: object) -> bool:
        if isinstance(other, Verdict):
            return self.to_dict() == other.to_dict()
        return NotImplemented

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON data (``stop`` by name)."""
        return {k: self[k] for k in _KEYS}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Verdict:
        """Inverse of :meth:`to_dict`; ``blowup`` must agree with ``stop``."""
        try:
            stop = StopReason[d["stop"]]
            v = cls(
                stop=stop,
                T_b=None if d["T_b"] is None else float(d["T_b"]),
                B_x=bool(d["B_x"]),
                B_v=bool(d["B_v"]),
                e_f=bool(d["e_f"]),
                reason=str(d["reason"]),
                uncertified_steps=int(d["uncertified_steps"]),
                first_uncertified_t=None if d["first_uncertified_t"] is None else float(d["first_uncertified_t"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"not a verdict record ({type(exc).__name__}: {exc}): {dict(d)!r}") from None
        if "blowup" in d and bool(d["blowup"]) != v.blowup:
            raise ValueError(f"verdict record says blowup = {d['blowup']} but stop = {stop.name}")
        return v


class SolverFailureRule:
    """``e_f``: a collision solve the step policy could not cure; stops the run (as ``B_v``) when ``stop``."""

    def __init__(self, stop: bool) -> None:
        self.stop = bool(stop)

    def record(self, state: RunState, statuses: list[str], dt: float = 0.0) -> bool:
        """Record the failure of the step of length ``dt`` from ``state.t``; True when the run must stop.

        ``T_b`` is the end of the failing step, ``state.t + dt``: ``alg:MR_JKO_ver2`` advances
        ``t`` by the step whose solve set ``e_f`` before it tests the indicators.
        """
        if self.stop:
            reason = f"{StopReason.SOLVER_FAILURE.value} ({', '.join(statuses)})"
            state.verdict = state.verdict.stopped(StopReason.SOLVER_FAILURE, state.t + dt, reason)
        else:
            state.verdict = state.verdict.solver_failed(state.t + dt)
        return self.stop
