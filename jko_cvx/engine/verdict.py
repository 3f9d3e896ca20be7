"""The verdict of a run: why it stopped, and whether that is blow-up (``B_v``, ``B_x``, ``e_f``).

The paper's blow-up indicators (sec. ``sec:numerical``): ``B_v`` when the velocity mesh
concentrates below ``eps_v`` (or, with ``stop.spread_v``, the velocity spread of a populated
slice falls below it), ``B_x`` when the space mesh concentrates below ``eps_x``, and ``e_f``
when the collision solver fails in a way the step policy cannot cure (counted as ``B_v``).
Beside the paper's threshold time ``T_b`` the verdict carries the estimate of
:mod:`jko_cvx.blowup` drawn from the run's certified records when the run ends: ``T_b_fit``
with its error bar ``T_b_fit_err``, the rate ``blowup_rate`` (the exponent a of
max f ~ (T - t)^-a), ``blowup_kind`` (``finite_time``, ``no_finite_time`` or
``undetermined``) and ``blowup_reason``; and ``unflagged_growth``, the factor by which max f
grew in a run that no blow-up rule stopped, when that factor is large (the mesh rule missed a
concentration).  A :class:`Verdict` is immutable; the stopping rules return a new one.  It also reads as the
mapping ``run.verdict["T_b"]`` of earlier versions (keys ``blowup``, ``T_b``, ``B_x``, ``B_v``,
``e_f``, ``reason``, ``stop``).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, Any

import numpy as np

from jko_cvx.blowup import FIRST_ORDER_LAG, KINDS, BlowupFit, fit_blowup

if TYPE_CHECKING:
    from jko_cvx.engine._state import RunState

__all__ = ["UNFLAGGED_GROWTH", "SolverFailureRule", "StopReason", "Verdict", "fit_rows", "run_failure"]


class StopReason(Enum):
    """Why the time loop stopped; the value is the rule in words."""

    T_END = "reached t_end"
    EPS_V = "min dv < eps_v"
    EPS_X = "min dx < eps_x"
    SPREAD_V = "min spread_v < spread_v"
    SOLVER_FAILURE = "collision solver failed"
    EPS_T = "dt <= eps_t"
    NO_STEP = "no step was accepted"
    NOT_ENDED = "the run has not ended"

    @property
    def blowup(self) -> bool:
        """Every reason but reaching ``t_end``, a run that never took a step and one that has not ended flags
        blow-up."""
        return self not in (StopReason.T_END, StopReason.NO_STEP, StopReason.NOT_ENDED)


_FIT_KEYS = ("T_b_fit", "T_b_fit_err", "blowup_rate", "blowup_kind", "blowup_reason", "unflagged_growth")
_KEYS = (
    "blowup", "certified", "T_b", "B_x", "B_v", "e_f", "reason", "stop", "uncertified_steps", "first_uncertified_t",
    *_FIT_KEYS,
)  # fmt: skip
#: max f growing by this factor in a run that no blow-up rule stopped is reported (``unflagged_growth``)
UNFLAGGED_GROWTH = 20.0
# the stops of the paper's mesh criteria (a threshold crossed), not of a failure
_MESH_RULES = (StopReason.EPS_V, StopReason.EPS_X, StopReason.SPREAD_V)
# the stops after which the records are cut short: a fit cannot exclude a later collapse
_EARLY = ("SOLVER_FAILURE", "EPS_T", "NO_STEP")
# what a growth no rule flagged means, by the fit's kind: only a finite-time law makes it a missed blow-up
_GROWTH_READING = {
    "finite_time": "a concentration the mesh criterion did not see, and the records fit a finite-time law",
    "no_finite_time": (
        "the records fit no finite-time law (a concentration without a singularity, as gamma >= 2's exponential "
        "contraction, or one that relaxed), so by the fit no blow-up was missed"
    ),
    None: "a concentration the mesh criterion did not see; the records neither show nor exclude a finite-time law",
}
# the stops on a failed collision solve (e_f) or before any step: nothing certified decides them
_FAILED_SOLVE_STOPS = (StopReason.SOLVER_FAILURE, StopReason.EPS_T, StopReason.NO_STEP)


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

    T_b_fit, T_b_fit_err, blowup_rate : float or None
        The fitted blow-up time, its error bar and exponent (:func:`jko_cvx.blowup.fit_blowup`
        on the certified records); None before the run ended and where the fit locates no blow-up
        time (:attr:`jko_cvx.blowup.BlowupFit.located`: no power law, its T at the horizon bound,
        records too noisy, or evidence in them against the singularity).  :attr:`blowup_reason`
        keeps the fit's numbers.
    blowup_kind : str or None
        ``"finite_time"``, ``"no_finite_time"`` or ``"undetermined"`` (None: not fitted yet).
    blowup_reason : str
        Why that kind, with the fit's numbers.
    unflagged_growth : float or None
        max f (its peak over the certified records) / max f (initial) when it is at least
        :data:`UNFLAGGED_GROWTH` and no blow-up rule fired: a concentration the mesh criterion did
        not see, even where it relaxed before the run ended.

    A run that never accepted a step (its first solve failed and stopped it) stops with
    :attr:`StopReason.NO_STEP`: blow-up undetermined (:attr:`blowup` None), not certified, ``T_b`` None.
    :attr:`blowup` is True, False or None (undetermined); verdict.json writes it as true, false or null,
    beside :attr:`certified` (true or false), which :meth:`from_dict` checks against the other fields.
    """

    stop: StopReason = StopReason.T_END
    T_b: float | None = None
    B_x: bool = False
    B_v: bool = False
    e_f: bool = False
    reason: str = StopReason.T_END.value
    uncertified_steps: int = 0
    first_uncertified_t: float | None = None
    T_b_fit: float | None = None
    T_b_fit_err: float | None = None
    blowup_rate: float | None = None
    blowup_kind: str | None = None
    blowup_reason: str = ""
    unflagged_growth: float | None = None

    @property
    def blowup(self) -> bool | None:
        """True: a blow-up rule fired (``B_v``, ``B_x`` or ``e_f``; :attr:`certified` says whether the states it
        rests on are certified).  False: the run reached ``t_end`` with every state certified and no rule fired.
        None (undetermined): no rule fired, but the run carried failed solves forward, accepted no step, or has
        not ended (read back from its checkpoint), so it is no evidence either way."""
        if self.stop.blowup:
            return True
        return False if self.certified and self.stop is StopReason.T_END else None

    @property
    def certified(self) -> bool:
        """Every state the verdict is drawn from came from a certified collision solve: no failed solve was
        carried forward (``uncertified_steps``), and the run did not stop on one (``e_f``: a solver failure or a
        step collapsed below ``eps_t`` by failed solves) or before its first step."""
        return self.uncertified_steps == 0 and self.stop not in _FAILED_SOLVE_STOPS

    def describe(self) -> str:
        """The verdict in words, saying so where it is drawn from uncertified states."""
        text = self._describe_threshold()
        if self.unflagged_growth is not None:
            reading = _GROWTH_READING.get(self.blowup_kind, _GROWTH_READING[None])
            text += f" (WARNING: max f grew by a factor {self.unflagged_growth:.3g}, no blow-up rule fired: {reading})"
        if self.blowup and self.stop in _MESH_RULES and self.blowup_kind == "undetermined":
            text += (
                f" (WARNING: a blow-up rule fired at T_b = {self.T_b:.6g}, but the records establish no finite-time "
                "law (blow-up kind undetermined): T_b is where the mesh threshold was crossed, not a measured "
                "singularity)"
            )
        if (not self.blowup and self.stop is StopReason.T_END and self.blowup_kind == "finite_time"
                and self.unflagged_growth is None and self.T_b_fit is not None):  # fmt: skip
            text += (
                " (WARNING: no blow-up rule fired, but max f fits a finite-time law with "
                f"T_b_fit = {self.T_b_fit:.6g}: a concentration the mesh criterion did not see, or a blow-up "
                "after t_end)"
            )
        if self.blowup and self.blowup_kind == "no_finite_time":
            # a threshold crossed at a finite t by a concentration that is not a singularity
            # (exponential contraction, as for gamma >= 2 by the Osgood criterion)
            text += (
                f" (WARNING: a blow-up rule fired at T_b = {self.T_b:.6g}, but the records fit no finite-time "
                "law (blow-up kind no_finite_time): the threshold time is set by the mesh threshold, "
                "not by a singularity)"
            )
        return text

    def describe_fit(self) -> str:
        """The fitted blow-up time in words (empty before the run ended)."""
        if self.blowup_kind is None:
            return ""
        if self.T_b_fit is None or self.blowup_kind != "finite_time":
            return f"blow-up kind {self.blowup_kind} ({self.blowup_reason.split(':')[0]})"
        text = f"T_b_fit = {self.T_b_fit:.6g} +- {self.T_b_fit_err:.2g} (rate a = {self.blowup_rate:.4g}, finite_time)"
        if MOVED in self.blowup_reason:
            text += f" (WARNING: {MOVED}; the bar does not hold the first-order step's lag: rerun with time.order = 2)"
        elif LAGGED in self.blowup_reason and "the bar holds" in self.blowup_reason:
            text += f" ({LAGGED}: the bar is widened for it; time.order = 2 narrows it)"
        elif LAGGED in self.blowup_reason:
            text += f" (WARNING: {LAGGED}, which the bar does not hold here: rerun with time.order = 2)"
        return text

    def _describe_threshold(self) -> str:
        if self.stop is StopReason.NOT_ENDED and self.certified:
            return "blow-up = undetermined (provisional: the run has not ended)"
        if self.certified:
            return f"blow-up = {self.blowup}"
        if self.stop is StopReason.NO_STEP:
            return "blow-up = undetermined (NOT CERTIFIED: no step was accepted)"
        if self.uncertified_steps == 0:  # stopped by the failed solve itself
            return (
                "blow-up = True (NOT CERTIFIED: the paper's exit-flag rule e_f: a failed collision solve, not a "
                "measured concentration; the blow-up kind says what the records show)"
            )
        claim = "undetermined" if self.blowup is None else "True, from uncertified states"
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

    def not_ended(self, t: float, t_end: float) -> Verdict:
        """The provisional verdict of a run read back before it ended (no rule fired by ``t`` < ``t_end``):
        undetermined.  A verdict whose rule has fired is returned as it is."""
        if self.stop is not StopReason.T_END:
            return self
        reason = f"{StopReason.NOT_ENDED.value} (at t = {t:.6g} of t_end = {t_end:.6g}: loaded from its checkpoint)"
        return dataclasses.replace(self, stop=StopReason.NOT_ENDED, reason=reason)

    def no_step(self, reason: str) -> Verdict:
        """The verdict of a run whose first step failed and stopped it: undetermined, no ``T_b``."""
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

    def with_fit(
        self,
        rows: list[dict[str, Any]],
        first_order: bool = False,
        set_points: float = 0.0,
        gamma: float = 1.0,
        homogeneous: bool = True,
    ) -> Verdict:
        """The verdict with the blow-up fit of the diagnostics ``rows`` (``t``, ``max_f``, ``failed``).

        Only certified records feed the fit (those before the first step with a failed slice);
        a run stopped by a solver failure, a collapsed step or no step is cut short, so a fit
        that does not show a finite-time law is ``undetermined`` there.  ``first_order``: the run took
        first-order steps; where its concentration moved over the fitted records (:func:`moved`, with
        ``set_points`` the grid points the v-map packs into one concentration set) the reason says that the
        fitted time lags by the step's O(dt), which the error bar does not hold, and :meth:`describe_fit` warns.
        First-order steps off the bar's calibration (``gamma`` other than 1, or a phase-space run, ``homogeneous``
        false) lag a still concentration too: on homogeneous runs the bar is widened by
        :data:`~jko_cvx.blowup.FIRST_ORDER_LAG` :math:`|\\gamma - 1|\\,\\Delta t` (measured there) and the reason
        says so; on phase-space runs the reason and :meth:`describe_fit` warn that the bar does not hold it.
        """
        fit = fit_rows(rows, self)
        if first_order and fit.window is not None and (drift := moved(rows, fit.window, set_points)) is not None:
            fit = dataclasses.replace(fit, reason=fit.reason + drift)
        if first_order and not (homogeneous and gamma == 1.0) and fit.T_b_fit_err is not None:
            if homogeneous:  # measured there (FIRST_ORDER_LAG)
                fit = fit.with_step_lag(FIRST_ORDER_LAG * abs(gamma - 1.0))
                held = f"the bar holds {FIRST_ORDER_LAG:g} |gamma - 1| dt of it"
            else:
                held = "the bar does not hold it (measured for homogeneous data only; the Lie splitting lags too)"
            fit = dataclasses.replace(
                fit, reason=f"{fit.reason}; {LAGGED} (gamma = {gamma:g}): {held}; time.order = 2 removes the lag"
            )
        growth = None
        if rows and self.stop is StopReason.T_END:
            # the peak, not the last value: a concentration that formed and relaxed was missed all the same
            # (certified records only, as the fit: a state carried on from a failed solve proves nothing)
            certified = [float(r["max_f"]) for r in itertools.takewhile(lambda r: int(r["failed"]) == 0, rows)]
            ratio = max(certified, default=float("nan")) / float(rows[0]["max_f"])
            growth = ratio if ratio >= UNFLAGGED_GROWTH else None
        # a bound of the fit (T at the horizon) or the T of a rejected law is no blow-up time: the reason keeps it
        T_b_fit, T_b_fit_err, rate = fit.estimate()
        return dataclasses.replace(
            self,
            T_b_fit=T_b_fit,
            T_b_fit_err=T_b_fit_err,
            blowup_rate=rate,
            blowup_kind=fit.blowup_kind,
            blowup_reason=fit.reason,
            unflagged_growth=growth,
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
        """Inverse of :meth:`to_dict`; ``blowup`` and ``certified`` must agree with ``stop`` and
        ``uncertified_steps``."""
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
                # a record written before the run ended has no fit yet
                **{k: _optional_float(d.get(k)) for k in ("T_b_fit", "T_b_fit_err", "blowup_rate", "unflagged_growth")},
                blowup_kind=None if d.get("blowup_kind") is None else str(d["blowup_kind"]),
                blowup_reason=str(d.get("blowup_reason", "")),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"not a verdict record ({type(exc).__name__}: {exc}): {dict(d)!r}") from None
        if "blowup" in d:
            said = d["blowup"]
            # records written before undetermined verdicts were null said false there; the other fields decide
            legacy = said is False and v.blowup is None
            if not (said is None or isinstance(said, bool)) or (said is not v.blowup and not legacy):
                raise ValueError(
                    f"verdict record says blowup = {said!r} but its stop ({stop.name}) and uncertified steps "
                    f"({v.uncertified_steps}) make it {v.blowup!r}"
                )
        # records written before verdicts stated it have no "certified": the other fields decide
        if "certified" in d and d["certified"] is not v.certified:
            raise ValueError(
                f"verdict record says certified = {d['certified']!r} but its stop ({stop.name}) and uncertified "
                f"steps ({v.uncertified_steps}) make it {v.certified!r}"
            )
        if v.blowup_kind is not None and v.blowup_kind not in KINDS:
            raise ValueError(f"verdict record says blowup_kind = {v.blowup_kind!r}, not one of {KINDS}")
        return v


def _optional_float(x: Any) -> float | None:
    return None if x is None else float(x)


MOVED = "the concentration moved"
LAGGED = "first-order steps lag the blow-up by O(dt)"
#: A concentration counts as moving when the place of max f travels, on average over the fitted records' steps,
#: more than this fraction of its refined set a step: the path in the smallest spacings at the window's end over
#: the points the map packs into one set (delta N_v / bumps).  Measured on gamma = 1 data at N_v = 121 to 601 with
#: first-order steps: still single bumps 0 to 0.006 a step; the asymmetric two_asym2 0.011 to 0.014 (fitted times
#: within 1.1e-3); tab_bu_g4's mirror bumps 0.046 to 0.061, two bumps at -+0.8 0.066 to 0.15 and two_asym 0.061 to
#: 0.15 (0.011 to 0.076 late).
MOVED_FRACTION = 0.03
#: A step of the place of max f longer than this many of that step's smallest spacings is a switch between two
#: bumps of (nearly) equal height, not motion (``tab_bu_g4``'s mirror bumps switch on rounding).
JUMP_CELLS = 100.0


def moved(rows: list[dict[str, Any]], window: tuple[int, int], set_points: float) -> str | None:
    """``"; the concentration moved ..."`` where the velocity of max f (``v_at_max``) travelled over the fitted
    records ``window`` more than :data:`MOVED_FRACTION` of its refined set a step (the path in the smallest
    v-spacings at the window's end over ``set_points``, the points the map packs into one set), switches between
    two bumps (:data:`JUMP_CELLS`) left out; None otherwise (also for records without ``v_at_max``, or
    ``set_points <= 0``).

    First-order (implicit) steps lag a moving concentration by O(dt): two bumps at -0.8 and 0.8 that move half a
    unit of v per unit of t give fitted blow-up times 0.04 to 0.1 late at dt = 0.004 to 0.008, their error bars
    covering 2 of 24 (the repository's blow-up estimator validation, held-out data ``*_pm0.8``), where second-order
    steps cover 24 of 24.
    """
    start, stop = window
    if stop - start < 3 or not set_points > 0 or any("v_at_max" not in r for r in rows[start:stop]):
        return None
    v = np.array([float(r["v_at_max"]) for r in rows[start:stop]])
    cells = np.array([float(r["min_dv"]) for r in rows[start + 1 : stop]])
    steps = np.diff(v)
    # a switch of the maximum between two equal bumps (mirror data, rounding) is a jump, not motion: no concentration
    # moved JUMP_CELLS of the smallest spacings in one step on the data measured
    kept = steps[np.abs(steps) <= JUMP_CELLS * cells]
    # the path length, not the net shift: the two mirror bumps' motions do not cancel across a switch
    per_step = float(np.abs(kept).sum()) / steps.size / cells[-1] / set_points
    if not per_step > MOVED_FRACTION:
        return None
    a, b = v[0], v[-1]
    t0, t1 = float(rows[start]["t"]), float(rows[stop - 1]["t"])
    return (
        f"; {MOVED} (max f from v = {a:.4g} to {b:.4g} over t = {t0:.4g}..{t1:.4g}, {per_step:.2g} of its refined "
        "set a step): first-order steps lag a moving concentration by O(dt), not in the error bar; "
        "time.order = 2 removes the lag"
    )


def fit_rows(rows: list[dict[str, Any]], verdict: Verdict) -> BlowupFit:
    """:func:`~jko_cvx.blowup.fit_blowup` of the diagnostics rows of a run with ``verdict``.

    The last few fits are kept by their inputs (the fit is a function of them alone): a run's
    figures draw the fit its verdict made without fitting again.
    """
    t = np.array([float(r["t"]) for r in rows])
    max_f = np.array([float(r["max_f"]) for r in rows])
    certified = np.array([int(r["failed"]) == 0 for r in rows], dtype=bool)
    early = verdict.reason if verdict.stop.name in _EARLY else None
    return _fit(t.tobytes(), max_f.tobytes(), certified.tobytes(), early)


@functools.lru_cache(maxsize=4)
def _fit(t: bytes, max_f: bytes, certified: bytes, early: str | None) -> BlowupFit:
    """:func:`~jko_cvx.blowup.fit_blowup` of the records given as the bytes of their arrays (a cache key)."""
    return fit_blowup(np.frombuffer(t), np.frombuffer(max_f), certified=np.frombuffer(certified, dtype=bool),
                      stopped_early=early)  # fmt: skip


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


def run_failure(verdict: Mapping[str, Any]) -> str | None:
    """Why a run is not certified whatever its compared steps show, from its verdict (a :class:`Verdict` or its
    ``to_dict()`` record), else None.

    A failed solve of the tested method that ended the run (``stop.on_solver_failure``: that step is never
    committed, so it has no row; a step collapsed below ``eps_t`` by failed solves; no step accepted), or failed
    solves the run went on with (``stop.on_solver_failure = false``:
    ``uncertified_steps``; ``every`` or ``slices`` may skip them, and the states after them are carried on
    from an uncertified one).
    """
    stop = verdict.get("stop")
    if stop in _FAILED_SOLVE_STOPS or stop in [s.name for s in _FAILED_SOLVE_STOPS]:  # as Verdict.certified
        return f"a failed solve stopped the run ({verdict.get('reason')})"
    n = int(verdict.get("uncertified_steps") or 0)
    if n:
        return (
            f"the run carried {n} uncertified step(s) from t = {float(verdict['first_uncertified_t']):.6g} (failed "
            "collision solves it went on with, stop.on_solver_failure = false)"
        )
    return None
