"""The time loop: ``simulate(scene)`` (``alg:MR_JKO_ver2`` homogeneous, ``alg:SPMCSL-JKO`` inhomogeneous).

Each step: choose dt (policy), transport in x (inhomogeneous scenes only), collision in v
(batched over x-slices), retry with a halved dt on solver failure (halving policy; which
failures halve it: ``time.halve_on``), mesh refinement in v and x with mass-conserving
remapping (the maps' sets: ``refine.concentration_set``).  The loop carries one
:class:`~jko_cvx.engine._state.RunState`; after each accepted step the trackers
(:mod:`jko_cvx.engine.trackers`) record the diagnostics, apply the blow-up rules (min dv < eps_v:
B_v; min dx < eps_x: B_x; min_spread_v < spread_v where the scene sets ``stop.spread_v``:
B_v), keep snapshots and write checkpoints; a solver failure the policy cannot cure is
``e_f`` (counted as B_v when ``stop.on_solver_failure``).  The outcome is a
:class:`~jko_cvx.engine.verdict.Verdict`.

With ``out`` the run lives in a directory (:mod:`jko_cvx.engine._rundir`: provenance, lock,
resume and overwrite rules): scene, metadata, diagnostics.csv, snapshots (every K steps and
at the first step reaching each of the scene's ``output.times``), a checkpoint every K
steps and the verdict, all written atomically, so a killed run loses at most K steps and
``resume=True`` continues it to exactly the result of an uninterrupted run (the loop is
deterministic and the checkpoint holds the whole state).  SIGINT / SIGTERM write a
checkpoint of the last accepted step and raise
:class:`~jko_cvx.engine._interrupts.RunInterrupted`.
"""

from __future__ import annotations

import dataclasses
import signal
import time
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jko_cvx._version import __version__
from jko_cvx.collision import CollisionProblem, Status, solve_collision
from jko_cvx.collision._checks import check_bool
from jko_cvx.engine._interrupts import InterruptGuard, RunInterrupted
from jko_cvx.engine._rundir import RunDir
from jko_cvx.engine._state import RunState
from jko_cvx.engine.run import Run, load_run
from jko_cvx.engine.trackers import Snapshots, StepInfo, Tracker, default_trackers
from jko_cvx.engine.verdict import SolverFailureRule, StopReason, Verdict
from jko_cvx.environment import code_fingerprint
from jko_cvx.kernels import PowerKernel
from jko_cvx.mesh.policy import RemeshPolicy
from jko_cvx.scene.model import Scene, SceneError
from jko_cvx.scene.options import RUN_KKT
from jko_cvx.time_order import collision_step_order2, strang_step
from jko_cvx.transport import transport_step

__all__ = ["Run", "load_run", "simulate", "snapshot_record"]

ACCEPT_KKT = RUN_KKT["newton"]
"""A step is accepted when every slice is certified at this KKT threshold (see :meth:`Stepper.accepted`);
that of Newton and nlp in a run (:data:`jko_cvx.scene.options.RUN_KKT`)."""
CONIC_RUN_KKT = RUN_KKT["conic"]
"""The certification threshold of ``method = "conic"`` in a run (its own default ``kkt_tol``), not
:data:`ACCEPT_KKT`: Clarabel pins f only to about the square root of its tolerance, and its KKT residual
stops near 1e-8 to 1e-7 (on the first step of ``inhom_gamma3_lambda4`` at 61 x 61, perspective form,
beta = 30, asked for 1e-8: 44 of 61 slices certified, the others at 1e-8 to 8e-7, also at ``tol`` =
1e-12; asked for 1e-6: 61 of 61).  A run under conic is certified to its accuracy, and stopped where
the method fails, rather than stopped at its first step by a threshold it cannot reach."""
NEWTON_MAX_ITER = 500
"""Newton's iteration budget in a run (``NewtonOptions`` defaults to 100 for one solve).  The
populated log-Fisher slices of a run need 100-111 iterations at times (inhom_gamma3 lambda = 4
on 61 x 61 near t = 0.8: damped by the positivity of the tails, then steady full steps), and
a failure should mean a step out of reach, not a short budget (as for the SQP's I_max);
stalls end earlier anyway, on Newton's jam and rounding-floor rules."""


def remesh_policy(scene: Scene) -> RemeshPolicy:
    """The scene's remeshing policy: ``[refine]``, the domains and what the remaps conserve."""
    return RemeshPolicy(
        scene.refine.v,
        scene.refine.x,
        scene.v.L,
        None if scene.x is None else scene.x.L,
        scene.refine.concentration_set,
        scene.collision.conserve_momentum,
        True if scene.x is None else scene.x.conserve_moment,
    )


def initial_state(scene: Scene) -> RunState:
    """f0 on the scene's grids, refined first where the scene refines (as the algorithms start;
    :meth:`~jko_cvx.mesh.policy.RemeshPolicy.initial`)."""
    vgrid, xgrid = scene.vgrid(), scene.xgrid()
    f = np.asarray(scene.initial_density(xgrid, vgrid), dtype=float)
    # the density that runs (an Initial of the caller's own class included), not the one the loader checked
    shape = (vgrid.n,) if xgrid is None else (xgrid.n, vgrid.n)
    if f.shape != shape or not np.isfinite(f).all() or (f < 0).any() or not f.any():
        raise SceneError(
            f"initial: the density of {type(scene.initial).__name__} on the grids must be finite, >= 0 and not all "
            f"zero, of shape {shape}; got shape {f.shape}, min {np.nanmin(f) if f.size else float('nan'):.3g}, "
            f"{int(np.count_nonzero(~np.isfinite(f)))} non-finite value(s)"
        )
    # v_params, x_params: the extent of the set each refined grid was built for
    f, vgrid, xgrid, v_params, x_params = remesh_policy(scene).initial(vgrid, xgrid, f)
    return RunState(0.0, 0, f, vgrid, xgrid, v_params, x_params, [], Verdict())


def _check_recordable(scene: Scene) -> None:
    """SceneError where a table of ``scene`` is of a class of the caller's own that brings behaviour of its own (an
    ``Initial`` with its own ``density``, say): scene.json records the loader's kind and values only, so the run
    directory would name a scene that did not run, and ``load_run`` or a rerun of it would give another result.  A
    subclass that adds nothing but the dataclass machinery records as its base does."""

    def walk(value: Any, where: str) -> None:
        if not dataclasses.is_dataclass(value) or isinstance(value, type):
            return
        for cls in type(value).__mro__:
            if cls.__module__.startswith("jko_cvx.") or cls is object:
                break
            own = sorted(n for n in vars(cls) if not n.startswith("__"))
            if own:
                raise SceneError(
                    f"{where}: a {cls.__module__}.{cls.__qualname__} defines {', '.join(own)} of its own, which a run "
                    "directory cannot record (scene.json rebuilds the package's table from its keys, which is not "
                    "what would run); run this scene in memory (out=None), or express it in scene keys"
                )
        for f in dataclasses.fields(value):
            walk(getattr(value, f.name), f"{where}.{f.name}" if where else f.name)

    walk(scene, "")


def _check_thresholds(scene: Scene, state: RunState) -> None:
    """SceneError where a blow-up threshold is not below the initial (refined) grid's smallest spacing: the
    paper's rule ``min dv < eps_v`` (``min dx < eps_x``) would fire on the first step, with no concentration."""
    for key, eps, grid, axis in (("stop.eps_v", scene.stop.eps_v, state.vgrid, "v"),
                                 ("stop.eps_x", scene.stop.eps_x, state.xgrid, "x")):  # fmt: skip
        if grid is None or not eps > 0:
            continue
        smallest = float((grid.dv if axis == "v" else grid.dx).min())  # as the diagnostics' min_dv / min_dx
        if eps > smallest:
            raise SceneError(
                f"{key} = {eps:g} is not below the smallest spacing of the {axis}-grid the run starts on "
                f"({smallest:.4g}): the rule min d{axis} < {key.split('.')[1]} holds before any concentration; "
                f"choose {key} < {smallest:.4g} (or more points on {axis})"
            )


@dataclass
class _Outcome:
    dt: float
    res: Any
    ok: bool
    retries: int = 0
    f: np.ndarray | None = None  # the density after the whole step (Strang: after the second half transport)
    f_star: np.ndarray | None = None  # the density entering the collision step (alg:SPMCSL-JKO's f*)
    stop: str | None = None  # a failure that ends the run whatever stop.on_solver_failure says (halve_on)
    problem: CollisionProblem | None = None  # the collision problem posed (time.order = 1; None for order 2)


def _not_halving(statuses: list[str]) -> str:
    """The stop reason for a failure that the halving policy refuses to halve (``time.halve_on =
    "max_iterations"``: only the exit flag e_f halves the step in alg:MR_JKO_ver2)."""
    return (
        f"{StopReason.SOLVER_FAILURE.value} ({', '.join(statuses)}): not the exit flag e_f "
        "(MAX_ITERATIONS), the only failure that halves the step under time.halve_on = 'max_iterations'"
    )


def _lower_minima(res) -> int:
    """Slice solves of a step where Newton's second start returned a lower certified J (two local minimisers;
    with ``time.order = 2``, summed over the substeps); 0 for the other methods."""
    substeps = res.info.get("substeps")
    if substeps:
        return sum(_lower_minima(r) for r in substeps)
    return int(np.sum(res.info.get("lower_minimum", False)))


def time_error(res) -> float:
    """The local error estimate of one first-order collision step, from a ``time.order = 2`` step's substeps.

    With :math:`S` the JKO step, the first-order step's local error is
    :math:`S_{\\rm exact}(\\Delta t) f - S(\\Delta t) f \\approx 2\\,(S(\\Delta t/2)^2 f - S(\\Delta t) f)` (Richardson:
    the leading :math:`c_2 \\Delta t^2` term, :mod:`jko_cvx.time_order`).  Returned relative to the largest value,
    :math:`2 \\max |S(\\Delta t/2)^2 f - S(\\Delta t) f| / \\max S(\\Delta t/2)^2 f` over every slice: how far one
    first-order step of this size is from the exact semi-discrete flow (the extrapolated step's own error is of
    higher order, :math:`O(\\Delta t^3)`).  A value of order one says the step does not resolve the dynamics of
    max f.  On inhomogeneous scenes it is the collision step's part (Strang splitting's own error is not
    included).  NaN for a first-order step, or where the second half step was not taken.
    """
    if res.info.get("order") != 2:
        return float("nan")
    full, _, second = res.info["substeps"]
    peak = float(np.max(second.f))
    return float(2 * np.max(np.abs(second.f - full.f)) / peak) if peak > 0 else float("nan")


def _failed_statuses(res) -> list[str]:
    """The distinct failure statuses of a collision result's slices, sorted by name."""
    return sorted({s.name for s in np.ravel(np.atleast_1d(res.status)) if not s.success})


class Stepper:
    """One time step of a scene: dt from the policy, transport, collision, retries, refinement.

    ``attempts`` (a list, optional) receives one record per collision attempt that was not
    accepted: ``{"t", "dt", "statuses", "then"}`` with ``then`` one of ``"halved"`` (retried at
    dt/2), ``"stopped"`` (not a halving failure under ``time.halve_on = "max_iterations"``) or
    ``"given up"`` (the policy has no smaller step).
    """

    def __init__(self, scene: Scene, attempts: list[dict[str, Any]] | None = None) -> None:
        self.scene = scene
        self.attempts = attempts
        self._f_star: np.ndarray | None = None
        self._problem: CollisionProblem | None = None
        self.kernel = PowerKernel(scene.gamma)
        self.policy = scene.step_policy()
        self.remesh = remesh_policy(scene)
        self.opts = dict(scene.collision.options)
        method = scene.collision.method
        limit = RUN_KKT[method]  # one certificate per method for the run (IPOPT's own 1e-6 suits one step)
        if method == "newton":
            # Steps certified to 1e-8.  Momentum does not depend on it when the scene conserves
            # it (the constraint holds to rounding at every iterate); without the constraint
            # the drift comes from the step itself, not from the tolerance (measured on
            # inhom_gamma3_lambda4: tol 1e-11 costs 50 % more and only lowers it 3e-9 -> 6e-10).
            self.opts.setdefault("tol", ACCEPT_KKT)
            self.opts.setdefault("max_iter", NEWTON_MAX_ITER)
            # Newton alone certifies at its tol; in a run at min(tol, RUN_KKT): a loose tol must not loosen it
            self.opts.setdefault("kkt_tol", min(self.opts["tol"], limit))
        self.opts.setdefault("kkt_tol", limit)  # a scene's own kkt_tol is honoured; Run.summary names a looser one

    @staticmethod
    def _at_accept_kkt(res) -> np.ndarray:
        """Per slice: stopped by its own rule (CONVERGED or NOT_CERTIFIED) at a KKT residual within ``ACCEPT_KKT``."""
        return (np.atleast_1d(res.kkt_residual) <= ACCEPT_KKT) & np.isin(
            np.atleast_1d(res.status), [Status.CONVERGED, Status.NOT_CERTIFIED]
        )

    @classmethod
    def accepted(cls, res) -> bool:
        """Every slice certified at ``ACCEPT_KKT``: floored near-vacuum slices stall (NOT_CERTIFIED)
        near 1e-10 while the tight target tol matters for the populated ones (momentum symmetry)."""
        return bool(np.all(res.success)) or bool(np.all(cls._at_accept_kkt(res)))

    @classmethod
    def failed_slices(cls, res) -> int:
        """The slices of a committed step the engine does not certify: none where it accepted the step
        (:meth:`accepted`, as the verdict counts it), else those neither ``success`` nor at ``ACCEPT_KKT``.  A
        method's own NOT_CERTIFIED at a tolerance tighter than the engine's is no failure: the diagnostics'
        ``failed`` column, the verdict's ``uncertified_steps`` and the fit's cut agree."""
        if cls.accepted(res):
            return 0
        ok = np.atleast_1d(res.success) | cls._at_accept_kkt(res)
        # a step the engine refused always counts (the verdict counts it uncertified): where every slice passes one
        # test or the other but not all the same one, its not-success slices
        return int(np.sum(~ok)) or int(np.sum(~np.atleast_1d(res.success)))

    def solve(self, state: RunState) -> _Outcome:
        """Transport and collision from ``state`` with the policy's dt, halved while the policy allows."""
        sc = self.scene
        xg = state.xgrid
        carried = state.rows[-1]["dt"] if state.step > 0 else None  # the last accepted step
        L_x = None if sc.x is None else sc.x.L
        dt = self.policy.first(
            float(state.vgrid.dv.min()), None if xg is None else float(xg.dx.min()), sc.v.L, L_x, carried
        )
        dt = min(dt, sc.t_end - state.t)
        retries = 0
        while True:
            f_new, res = self.step(state, dt)
            if self.accepted(res):
                return _Outcome(dt, res, True, retries, f_new, self._f_star, problem=self._problem)
            statuses = _failed_statuses(res)
            stop = _not_halving(statuses) if self.policy.refuses(statuses) else None
            retry = None if stop is not None else self.policy.retry(dt)
            if self.attempts is not None:
                then = "stopped" if stop is not None else "given up" if retry is None else "halved"
                self.attempts.append({"t": state.t, "dt": dt, "statuses": statuses, "then": then})
            if retry is None:
                return _Outcome(dt, res, False, retries, f_new, self._f_star, stop, self._problem)
            dt, retries = retry, retries + 1

    def step(self, state: RunState, dt: float) -> tuple[np.ndarray, Any]:
        """Transport and collision over ``dt`` from ``state``: the new density and the collision result.

        ``time.order = 1``: transport, then one JKO step (``alg:SPMCSL-JKO``).  ``time.order = 2``:
        the Richardson-extrapolated collision step of :mod:`jko_cvx.time_order`, and for
        inhomogeneous scenes Strang splitting (half transport, collision, half transport).
        """
        sc, xg, vg = self.scene, state.xgrid, state.vgrid
        secs = state.seconds

        def transport(g: np.ndarray, h: float) -> np.ndarray:
            t0 = time.perf_counter()
            out = transport_step(xg, vg.points, g, h, conserve_moment=sc.x.conserve_moment)
            secs["transport"] += time.perf_counter() - t0
            return out

        def problem(g: np.ndarray, h: float) -> CollisionProblem:
            return CollisionProblem(
                vg,
                self.kernel,
                g,
                h,
                sc.strength,
                sc.collision.beta,
                sc.collision.problem_fisher,
                sc.collision.conserve_momentum,
            )

        def collide(g: np.ndarray, h: float):
            self._f_star = g  # alg:SPMCSL-JKO's f*, for refine.concentration_set = "quadrant"
            t0 = time.perf_counter()
            if sc.time.order == 2:
                self._problem = None  # three substeps, no one problem
                res = collision_step_order2(problem, g, h, method=sc.collision.method, **self.opts)
            else:
                self._problem = problem(g, h)
                res = solve_collision(self._problem, method=sc.collision.method, **self.opts)
            secs["collision"] += time.perf_counter() - t0
            return res

        if xg is None:
            res = collide(state.f, dt)
            return res.f, res
        if sc.time.order == 2:
            return strang_step(transport, collide, state.f, dt)
        res = collide(transport(state.f, dt), dt)
        return res.f, res

    def commit(self, state: RunState, out: _Outcome) -> StepInfo:
        """Advance ``state`` by the solved step: refine, then t and step."""
        t2 = time.perf_counter()
        f, vgrid, xgrid, vp, xp = self.remesh.refine(
            state.vgrid, state.xgrid, out.f, out.f_star, state.v_params, state.x_params
        )
        if self.scene.v.floor_every_step and vgrid is state.vgrid:
            f = self.remesh.floor_v(vgrid, f)
        state.seconds["refine"] += time.perf_counter() - t2
        state.f, state.vgrid, state.xgrid, state.v_params, state.x_params = f, vgrid, xgrid, vp, xp
        state.t += out.dt
        state.step += 1
        it = np.atleast_1d(out.res.iterations)
        return StepInfo(
            out.dt, int(it.max()), self.failed_slices(out.res), out.retries, _lower_minima(out.res),
            time_error(out.res),
        )  # fmt: skip


class _Clock:
    """The run's seconds as an uninterrupted run counts them, whatever legs it took (``--resume``).

    ``wall`` is the time of the loop up to the last accepted step, summed over the legs (each leg from
    its start); ``collision``, ``transport`` and ``refine`` are summed by the stepper.  Both are kept as
    of the last accepted step (:meth:`accepted`): an interrupted step is discarded, so :meth:`rewind`
    drops its seconds too, and the leg that solves it again counts them once.
    """

    def __init__(self, state: RunState) -> None:
        state.seconds.setdefault("wall", 0.0)  # a checkpoint from before the run's wall was recorded: 0
        self.state = state
        self.start = time.perf_counter() - state.seconds["wall"]
        self.kept = dict(state.seconds)

    def accepted(self) -> None:
        """After a committed step (and at the end): the seconds so far are the run's."""
        self.state.seconds["wall"] = time.perf_counter() - self.start
        self.kept = dict(self.state.seconds)

    def rewind(self) -> None:
        """Back to the seconds of the last accepted step (the state the checkpoint then holds)."""
        self.state.seconds.clear()
        self.state.seconds.update(self.kept)


def _loop(
    scene: Scene, stepper: Stepper, state: RunState, trackers: list[Tracker], guard: InterruptGuard, clock: _Clock
) -> None:
    failure = SolverFailureRule(scene.stop.on_solver_failure)
    while not state.done(scene.t_end):
        out = stepper.solve(state)
        stop = out.stop is not None  # never accepted, whatever stop.on_solver_failure says
        if stop:
            state.verdict = state.verdict.stopped(StopReason.SOLVER_FAILURE, state.t + out.dt, out.stop)
        elif not out.ok:
            stop = failure.record(state, _failed_statuses(out.res), out.dt)
        if stop:
            if state.step == 0:  # a run that never took a step is not a blow-up at dt
                state.verdict = state.verdict.no_step(
                    f"{StopReason.NO_STEP.value}: the first collision solve failed ({state.verdict.reason})"
                )
            break
        for tr in trackers:  # before the commit, interruptible: a signal here discards the step
            tr.solved(state, out.problem, out.res)
        with guard.deferred():
            info = stepper.commit(state, out)
            clock.accepted()  # before the trackers: the checkpoint they write holds the seconds so far
            for tr in trackers:
                tr.handle(state, info)


def simulate(
    scene: Scene,
    out: str | Path | None = None,
    resume: bool = False,
    progress: bool = False,
    overwrite: bool = False,
    attempts: list[dict[str, Any]] | None = None,
    observers: Callable[[RunDir | None], list[Tracker]] | None = None,
    on_finish: Callable[[Run], None] | None = None,
) -> Run:
    """Run a scene; see the module docstring.

    Parameters
    ----------
    scene : Scene
    out : str or Path, optional
        The run directory (none: nothing is written).
    resume : bool
        Continue the run in ``out`` from its checkpoint (same scene and package version).
    progress : bool
        Show a progress bar.
    overwrite : bool
        Replace a run already in ``out`` (otherwise refused).
    attempts : list, optional
        Receives one record per collision attempt that was not accepted (time, dt, failure
        statuses and what followed: see :class:`Stepper`); in memory only.
    observers : callable, optional
        ``observers(rundir)`` (the open :class:`~jko_cvx.engine._rundir.RunDir`, or None without
        ``out``) returns further trackers, run after the stopping rules and before the outputs
        (snapshots, checkpoints), so what they write is never behind the checkpoint; their
        :meth:`~jko_cvx.engine.trackers.Tracker.solved` sees each committed step's collision
        problem and result (:mod:`jko_cvx.engine.verify` re-solves it with a reference).
    on_finish : callable, optional
        ``on_finish(run)``, called with the finished run while its directory is still locked: what it
        writes beside the run (the CLI's figures) cannot land in a directory another process has
        taken over since.  An exception it raises propagates; the run is complete on disk by then.

    Raises
    ------
    SceneError
        The scene is not one the loader accepts (a scene built in code with
        ``dataclasses.replace`` is checked as a file would be), its step count or memory estimate is
        beyond the limits of :mod:`jko_cvx.scene.limits`, or a blow-up threshold (``stop.eps_v``,
        ``stop.eps_x``) is not below the smallest spacing of the initial grid, where the rule would
        fire without any concentration (nothing has been written).
    RunDirError
        ``out`` cannot be used as asked (see :mod:`jko_cvx.engine._rundir`); nothing has been run.
    RunInterrupted
        SIGINT / SIGTERM arrived (only with ``out``, from the main thread); the checkpoint holds
        the last accepted step.

    Examples
    --------
    The homogeneous gamma = 1 scene of Table ``tab:bu`` (exact blow-up time 1/2), run in memory
    until the refined grid's smallest spacing falls below ``stop.eps_v``:

    >>> from jko_cvx import shipped_scene, simulate
    >>> run = simulate(shipped_scene("tab_bu_g1"))
    >>> run.blowup, run.verdict.stop.name, bool(abs(run.verdict.T_b - 0.5) < 0.05)
    (True, 'EPS_V', True)

    With ``out``, the run directory holds the checkpoint, diagnostics and snapshots
    (:func:`~jko_cvx.engine.run.load_run` reads it back; ``resume=True`` continues it).
    """
    if not isinstance(scene, Scene):
        raise TypeError(
            f"scene must be a jko_cvx.scene.Scene (from jko_cvx.scene.load_scene(path)), got {type(scene).__name__}"
        )
    for name, flag in (("resume", resume), ("overwrite", overwrite), ("progress", progress)):
        check_bool(name, flag)
    if out is None and (resume or overwrite):
        raise ValueError("resume and overwrite need a run directory: pass out=")
    # a Scene built in code (dataclasses.replace) bypasses the loader: check it as the loader would (its size
    # limits included), before anything is written, and run it in the loader's form (what scene.json rebuilds)
    scene = scene.replace({})
    if out is not None:
        _check_recordable(scene)
    else:  # (a run directory's start checks it) the code that runs must be the code its record names
        code_fingerprint()
    if attempts is not None and not isinstance(attempts, list):
        raise TypeError(f"attempts must be a list (it receives the failed attempts), got {type(attempts).__name__}")
    if observers is not None and not callable(observers):
        raise TypeError(f"observers must be a callable (rundir -> list of trackers), got {type(observers).__name__}")
    if on_finish is not None and not callable(on_finish):
        raise TypeError(f"on_finish must be a callable (run -> None), got {type(on_finish).__name__}")
    stepper = Stepper(scene, attempts)
    first = None if resume else initial_state(scene)
    if first is not None:
        _check_thresholds(scene, first)
    with RunDir.open(out, scene, resume=resume, overwrite=overwrite) if out is not None else nullcontext() as rd:
        state = rd.state if rd is not None and rd.state is not None else first
        trackers, snaps = default_trackers(scene, rd, [] if rd is None else rd.snapshots, progress)
        if observers is not None:
            at = trackers.index(snaps)
            trackers[at:at] = observers(rd)
        with InterruptGuard() if rd is not None else nullcontext(InterruptGuard()) as guard:
            clock = _Clock(state)
            try:
                with guard.deferred():
                    for tr in trackers:
                        tr.start(state)
                _loop(scene, stepper, state, trackers, guard, clock)
                guard.hold()  # the loop has ended: a signal from here on is ignored
                clock.accepted()
                run = _finish(scene, state, trackers, snaps, rd)
            except KeyboardInterrupt as exc:
                if rd is None:
                    raise
                guard.hold()
                clock.rewind()  # the interrupted step is discarded, and its seconds with it
                rd.save_state(state)
                raise RunInterrupted(rd.path, state.step, state.t, getattr(exc, "signum", signal.SIGINT)) from None
        if on_finish is not None:  # outside the guard (the run is complete), inside the lock
            on_finish(run)
        return run


def _finish(scene: Scene, state: RunState, trackers: list[Tracker], snaps: Snapshots, rd: RunDir | None) -> Run:
    # before the last checkpoint, which records it
    spec = scene.refine.v
    set_points = scene.v.n * (spec.delta / spec.bumps if spec is not None else 1.0)  # a fixed grid: the whole of it
    state.verdict = state.verdict.with_fit(
        state.rows, first_order=scene.time.order == 1, set_points=set_points, gamma=scene.gamma,
        homogeneous=scene.homogeneous,
    )  # fmt: skip
    for tr in trackers:
        tr.finish(state)
    made_by = {"jko_cvx": __version__, "code_sha256": code_fingerprint(verify=False)}  # a run directory checked it
    run = Run(scene, state.rows, snaps.snapshots, state.f, state.vgrid, state.xgrid, state.t,
              state.verdict, state.seconds, made_by)  # fmt: skip
    if rd is not None:
        rd.write_verdict(state)
    return run


def snapshot_record(snap: dict[str, Any]) -> dict[str, Any]:
    """A snapshot as plain JSON data (t as a float, the grids and f as nested lists), e.g. for sweep caches."""
    return {"t": float(snap["t"]), **{k: snap[k].tolist() for k in ("x", "v", "f") if k in snap}}
