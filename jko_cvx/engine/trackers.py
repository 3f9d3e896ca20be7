"""Observers of the time loop (trackers in py-pde's sense): records, stopping rules, output, progress.

The loop (:func:`jko_cvx.engine.loop.simulate`) advances a :class:`~jko_cvx.engine._state.RunState`
one accepted step at a time and then calls, in order, ``handle(state, step)`` of each
tracker; ``start(state)`` runs once before the first step (also on resume) and
``finish(state)`` once at the end.  Order matters and is fixed by :func:`default_trackers`:
the diagnostics row first, then the stopping rules that read it, then the outputs that
depend on whether the run is done.

Stopping rules (the paper's blow-up indicators, sec. ``sec:numerical``) set a new
:class:`~jko_cvx.engine.verdict.Verdict` on the state; when several fire on one step, all their
flags are set and the last one's reason is kept.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from jko_cvx.diagnostics import diagnostics
from jko_cvx.engine._state import RunState, save_npz, write_snapshot
from jko_cvx.engine.verdict import StopReason

if TYPE_CHECKING:
    from jko_cvx.collision import CollisionProblem, CollisionResult
    from jko_cvx.engine._rundir import RunDir
    from jko_cvx.scene.model import Scene
    from jko_cvx.stepping import StepPolicy

__all__ = [
    "GRID_RESOLUTION",
    "Checkpoints",
    "Diagnostics",
    "EpsT",
    "EpsV",
    "EpsX",
    "Progress",
    "Snapshots",
    "SpreadV",
    "StepInfo",
    "StopRule",
    "Tracker",
    "UnresolvedV",
    "UnresolvedX",
    "default_trackers",
]


@dataclass(frozen=True)
class StepInfo:
    """What the loop knows about the step just accepted besides the state: dt and the solve's record."""

    dt: float
    iterations: int = 0
    failed: int = 0
    retries: int = 0
    lower_minimum: int = 0  # slices where Newton's second start returned a lower certified J
    time_error: float = float("nan")  # time.order = 2: the first-order step's local error estimate (loop.time_error)


class Tracker:
    """Base class: every hook does nothing."""

    def start(self, state: RunState) -> None:
        """Before the first step (of this call: also on resume)."""

    def solved(self, state: RunState, problem: CollisionProblem | None, result: CollisionResult) -> None:
        """After the collision solve of a step the loop is about to commit (``state`` not yet advanced).

        ``problem`` is the collision problem the step posed (all x-slices, batched; None for
        ``time.order = 2``, whose step is three solves) and ``result`` its solution.  Not
        deferred: SIGINT / SIGTERM here discards the step, as during the solve.
        """

    def handle(self, state: RunState, step: StepInfo) -> None:
        """After each accepted step (``state`` already advanced)."""

    def finish(self, state: RunState) -> None:
        """Once, when the loop has ended (also after a solver-failure stop)."""


class Diagnostics(Tracker):
    """Appends the diagnostics row of each step to ``state.rows`` (the step-0 row on a fresh start)."""

    def start(self, state: RunState) -> None:
        if not state.rows:
            state.rows.append(self.row(state, StepInfo(dt=0.0)))

    def handle(self, state: RunState, step: StepInfo) -> None:
        state.rows.append(self.row(state, step))

    @staticmethod
    def row(state: RunState, step: StepInfo) -> dict[str, Any]:
        d = diagnostics(state.vgrid, state.f, state.xgrid)
        return {
            "step": state.step,
            "t": state.t,
            "dt": step.dt,
            **d,
            "iterations": step.iterations,
            "failed": step.failed,
            "retries": step.retries,
            "lower_minimum": step.lower_minimum,
            "time_error": step.time_error,
        }


class StopRule(Tracker):
    """Blow-up when the diagnostic ``column`` of the latest row falls below ``threshold`` (off at 0)."""

    reason: StopReason
    column: str
    label: str

    def __init__(self, threshold: float) -> None:
        self.threshold = float(threshold)

    def fires(self, row: dict[str, Any]) -> str | None:
        """The reason text when the rule fires on ``row``, else None (NaN never fires)."""
        value = row[self.column]
        if value < self.threshold:
            return f"{self.label} = {value:.3g} < {self.reason.name.lower()}"
        return None

    def handle(self, state: RunState, step: StepInfo) -> None:
        text = self.fires(state.rows[-1])
        if text is not None:
            state.verdict = state.verdict.stopped(self.reason, state.t, text)


class EpsV(StopRule):
    """``B_v``: the velocity mesh has concentrated, min dv < eps_v."""

    reason, column, label = StopReason.EPS_V, "min_dv", "min dv"


class EpsX(StopRule):
    """``B_x``: the space mesh has concentrated, min dx < eps_x (inhomogeneous scenes)."""

    reason, column, label = StopReason.EPS_X, "min_dx", "min dx"


GRID_RESOLUTION = 1e-12
"""The smallest spacing, relative to the axis' half-width L, on which a run goes on.

A map that concentrates further puts its points a few float64 ulps apart (a two-bump x-map
on 10 points reached spacings of 1e-17 at x ~ 1e-15), where interpolation is meaningless
and SciPy refuses the grid.  That is the paper's mesh blow-up (``B_v`` / ``B_x``) whatever
eps the scene sets (eps = 0 turns only the paper's test off); shipped runs stop on eps >=
5e-6, far above it."""


class _Unresolved(StopRule):
    def fires(self, row: dict[str, Any]) -> str | None:
        value = row[self.column]
        if value < self.threshold:
            axis = self.column[-1]
            return (
                f"{self.label} = {value:.3g} < {GRID_RESOLUTION:g} L_{axis}: the {axis}-map has concentrated "
                "below float64 resolution"
            )
        return None


class UnresolvedV(_Unresolved):
    """``B_v`` when the velocity mesh concentrates below :data:`GRID_RESOLUTION` times L_v (any eps_v)."""

    reason, column, label = StopReason.EPS_V, "min_dv", "min dv"


class UnresolvedX(_Unresolved):
    """``B_x`` when the space mesh concentrates below :data:`GRID_RESOLUTION` times L_x (any eps_x)."""

    reason, column, label = StopReason.EPS_X, "min_dx", "min dx"


class SpreadV(StopRule):
    """``B_v`` from the density itself: the velocity spread of a populated slice < spread_v."""

    reason, column, label = StopReason.SPREAD_V, "min_spread_v", "min spread_v"


class EpsT(Tracker):
    """``alg:MR_JKO_ver2`` with adaptive steps: the run ends after an accepted step that ends the
    step policy (:meth:`jko_cvx.stepping.HalvingStep.end`: a step ``<= eps_t``)."""

    def __init__(self, policy: StepPolicy) -> None:
        self.policy = policy

    def handle(self, state: RunState, step: StepInfo) -> None:
        text = self.policy.end(step.dt)  # the policy's floor (HalvingStep.end)
        if text is not None:
            state.verdict = state.verdict.stopped(StopReason.EPS_T, state.t, text)


def reaches(times: tuple[float, ...], t_prev: float, t: float) -> bool:
    """True when the step from ``t_prev`` to ``t`` reaches one of ``times`` (to rounding in t)."""
    slack = 1e-12 * max(t, 1.0)
    return any(t_prev + slack < tk <= t + slack for tk in times)


class Snapshots(Tracker):
    """Keeps snapshots: at step 0, every ``every`` steps, at the first step reaching each of ``times``,
    at the last step, and (if the run stopped on a solver failure) of the state it stopped in.

    ``path`` maps a step to its file (None: memory only), written by ``save(path, **record)`` (a run
    directory's ledger); ``taken`` are those of a resumed run.
    """

    def __init__(
        self,
        every: int,
        times: tuple[float, ...],
        t_end: float,
        path: Callable[[int], Path] | None = None,
        taken: list[dict[str, Any]] | None = None,
        save: Callable[..., None] = save_npz,
    ) -> None:
        self.every, self.times, self.t_end, self.path, self.save = every, times, t_end, path, save
        self.snapshots: list[dict[str, Any]] = list(taken or [])

    def take(self, state: RunState) -> None:
        file = None if self.path is None else self.path(state.step)
        snap = write_snapshot(file, state.step, state.t, state.xgrid, state.vgrid, state.f, self.save)
        self.snapshots.append(snap)

    def start(self, state: RunState) -> None:
        if not self.snapshots:
            self.take(state)

    def handle(self, state: RunState, step: StepInfo) -> None:
        if state.step % self.every == 0 or state.done(self.t_end) or reaches(self.times, state.t - step.dt, state.t):
            self.take(state)

    def finish(self, state: RunState) -> None:
        if state.verdict.stop is StopReason.SOLVER_FAILURE and self.snapshots[-1]["step"] != state.step:
            self.take(state)


class Checkpoints(Tracker):
    """Writes the checkpoint (and diagnostics.csv) every ``every`` steps, at the last step and at the end."""

    def __init__(self, rundir: RunDir, every: int, t_end: float) -> None:
        self.rundir, self.every, self.t_end = rundir, every, t_end

    def handle(self, state: RunState, step: StepInfo) -> None:
        if state.step % self.every == 0 or state.done(self.t_end):
            self.rundir.save_state(state)

    def finish(self, state: RunState) -> None:
        self.rundir.save_state(state)


class Progress(Tracker):
    """A tqdm progress bar over simulated time."""

    def __init__(self, t_end: float, name: str) -> None:
        self.t_end, self.name, self.bar = t_end, name, None

    def start(self, state: RunState) -> None:
        from tqdm.auto import tqdm

        fmt = "{l_bar}{bar}| t={n:.4g}/{total:.4g}"
        self.bar = tqdm(total=self.t_end, initial=state.t, unit="t", desc=self.name, bar_format=fmt)

    def handle(self, state: RunState, step: StepInfo) -> None:
        self.bar.update(step.dt)

    def finish(self, state: RunState) -> None:
        self.bar.close()


def default_trackers(
    scene: Scene, rundir: RunDir | None, snapshots: list[dict[str, Any]], progress: bool
) -> tuple[list[Tracker], Snapshots]:
    """The trackers of a run of ``scene``, in order, and the snapshot tracker among them."""
    snaps = Snapshots(
        scene.output.every,
        scene.output.times,
        scene.t_end,
        None if rundir is None else rundir.snapshot_path,
        snapshots,
        save_npz if rundir is None else rundir.save_snapshot,
    )
    trackers: list[Tracker] = [Diagnostics(), UnresolvedV(GRID_RESOLUTION * scene.v.L), EpsV(scene.stop.eps_v)]
    if not scene.homogeneous:
        trackers += [UnresolvedX(GRID_RESOLUTION * scene.x.L), EpsX(scene.stop.eps_x)]
    trackers.append(SpreadV(scene.stop.spread_v))
    policy = scene.step_policy()
    if policy.exhausted(0.0):  # a policy whose runs end on eps_t (alg:MR_JKO_ver2's halving)
        trackers.append(EpsT(policy))
    trackers.append(snaps)
    if rundir is not None:
        trackers.append(Checkpoints(rundir, scene.output.checkpoint_every, scene.t_end))
    if progress:
        trackers.append(Progress(scene.t_end, scene.name))
    return trackers, snaps
