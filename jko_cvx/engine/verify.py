"""Verify a solver along a whole run: every K-th step's collision problems re-solved by a reference.

``verify(scene, reference="conic", every=K, slices="all")`` runs the scene with its own
``collision.method``.  At every step whose number is a multiple of K, and at the run's last step (the
step at t_end, or the one after which a blow-up rule or eps_t stopped the run: the nearest the
singularity, the hardest to solve; not when a failed solve stopped it), each compared x-slice's
collision problem -- the very :class:`~jko_cvx.collision.CollisionProblem` the loop posed
(``alg:SPMCSL-JKO``'s f* after transport, the grid, dt, strength, Fisher form and weight, the
momentum constraint) -- is solved again by the reference, started cold from its own initial
point (never from the tested method's answer; posed in units of the slice's largest density and
certified against the problem itself, :func:`~jko_cvx.collision.estimate.solve_reference`), and the
two answers are compared.  The run itself goes on with the tested method's answer: the reference
only watches
(:meth:`~jko_cvx.engine.trackers.Tracker.solved`, before the step is committed).  Which step is the
last is known only once it is committed (the stop rules read its diagnostics), so the last step,
when its number is not a multiple of K, is compared in
:meth:`~jko_cvx.engine.trackers.Tracker.handle`, where signals wait until its row and the checkpoint
are written (Ctrl-C waits for those solves; a worker pool lost meanwhile, as to a signal sent to the
whole process group, is replaced by the same solves in this process).

Per step and slice (one row of ``verify.csv``): both statuses, both KKT residuals
(:meth:`~jko_cvx.collision.CollisionProblem.kkt_residual`), the discrepancy in f,
:math:`\\max_j |f_j - f^{\\rm ref}_j| / \\max_j f^{\\rm ref}_j`, the relative difference in J,
:math:`|J - J^{\\rm ref}| / |J^{\\rm ref}|`, both solve times (the tested method's is its batch
time shared equally among the slices when it solves all slices at once), and the outcome.

Tolerance: the reference's accuracy in f
----------------------------------------
Both references stop on a tolerance ``tol`` on the objective (Clarabel's duality gap inside the
convex-concave loop of :mod:`jko_cvx.collision.conic`; IPOPT's scaled NLP error for
:mod:`jko_cvx.collision.nlp`).  Near its minimiser J is flat to first order, so a point whose
J is within ``tol`` of the minimum lies within about :math:`\\sqrt{tol}` of the minimiser
(relative, in f): measured with Clarabel against the converged SQP at N = 121, tol 1e-8 gave
7e-5, 1e-10 gave 3e-6 and 1e-12 gave 2e-7.  The reference's accuracy is therefore
:math:`a = \\sqrt{tol}` (:func:`reference_accuracy`; 1e-5 for the conic default tol = 1e-10,
3.2e-5 for nlp's 1e-9) and a slice *agrees* when both discrepancies are at most
``SAFETY * a`` (:data:`SAFETY` = 10: the measured errors sit at 0.2-0.7 a, and a tested
method is allowed an error of the reference's size).

A posteriori, each answer also gets an estimate of its own distance to the minimiser
(:func:`~jko_cvx.collision.estimate.f_error_estimate`: one Newton step on the constraint's null space, the reduced
gradient over the reduced Hessian): columns ``err`` (tested) and ``err_ref`` (reference).  It
is far smaller than the a priori bound where the step is well conditioned (conic at tol 1e-10:
1e-9 to 1e-7 against :math:`\\sqrt{tol}` = 1e-5) and says when a step is too ill-conditioned for
the reference to pin f to the tolerance: ``err_ref`` above it is outcome ``ill-conditioned``.

Outcome of a slice (``outcome`` column)
---------------------------------------
* ``agree``: the reference is certified (status CONVERGED at its own ``kkt_tol``, 1e-6 for
  conic and nlp unless ``reference_options`` set it: Clarabel at tol 1e-10 ends at KKT
  residuals of 4e-9 to 8e-7 on tab_bu_g1 (61 points, perspective, beta = 1), above the engine's
  :data:`~jko_cvx.engine.loop.ACCEPT_KKT`, and its accuracy in f is judged by ``err_ref``
  below), the tested slice is one the engine accepts
  (:meth:`~jko_cvx.engine.loop.Stepper.accepted`, per slice) and both discrepancies are within
  the tolerance;
* ``differ``: both certified, a discrepancy above the tolerance;
* ``ill-conditioned``: the reference is certified but its own error estimate exceeds the
  tolerance -- unverified, whatever the discrepancy;
* ``method failed``: the reference certified, the tested slice not (the run went on with it
  only under ``stop.on_solver_failure = false``);
* ``reference failed``: the reference is not certified -- the slice is *unverified*, never
  counted as agreement.

The verdict is ``verified`` when at least one slice was compared, every compared slice
agrees and the run itself is certified (no failed solve ended it or was carried on:
:func:`~jko_cvx.engine.verdict.run_failure`); otherwise it names why: the run's failure, or the first step and slice (in
step order, then slice order) that does not agree, with both statuses and why.

Trajectory
----------
``trajectory=True`` also runs the whole scene with the reference method (into ``DIR/reference/``)
and compares the stop reason, T_b and max f(t) at the times both runs share
(:mod:`jko_cvx.engine._trajectory`); the verdict gains a trajectory part (agrees / differs, with
the first time max f parts beyond the tolerance; a reference run that carried failed solves is
judged only before the first of them: later times and its stop are "not judged", never agreement)
and ``verified`` needs both.

Run directory
-------------
With ``out`` the verification lives in a run directory of the scene
(:mod:`jko_cvx.engine._rundir`: provenance, lock, ``overwrite``, ``resume``), with, beside the
run's own files, ``verify.json`` (the settings), ``verify.csv`` (written through the run's
ledger before each checkpoint, so it never lags it), and at the end ``verify.md`` (summary,
verdict, worst rows) and ``verify.png``.  ``resume`` continues a killed verification: rows
past the checkpoint are dropped and recomputed, and since the loop and every reference solve
are deterministic (cold starts), the resumed ``verify.csv`` equals the uninterrupted one in
every column but the two solve times.  :func:`load_verification` reads ``verify.csv`` back,
checked against the ledger and the settings.
"""

from __future__ import annotations

import json
import math
import os
import signal
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from jko_cvx.collision import CollisionProblem, CollisionResult, Status
from jko_cvx.collision._checks import check_bool, check_int
from jko_cvx.collision.estimate import f_error_estimate, solve_reference
from jko_cvx.collision.solve import OPTIONS
from jko_cvx.engine._rundir import RunDir
from jko_cvx.engine._state import Ledger, RunState
from jko_cvx.engine._trajectory import TrajectoryComparison, compare_trajectories
from jko_cvx.engine.errors import RunDirError
from jko_cvx.engine.loop import ACCEPT_KKT, simulate
from jko_cvx.engine.run import Run
from jko_cvx.engine.trackers import StepInfo, Tracker
from jko_cvx.engine.verdict import StopReason, run_failure
from jko_cvx.scene.model import Scene
from jko_cvx.threads import blas_limits, usable_cores

__all__ = [
    "REFERENCES",
    "SAFETY",
    "Verification",
    "VerifySettings",
    "default_reference",
    "f_error_estimate",
    "load_verification",
    "reference_accuracy",
    "solve_reference",
    "verify",
    "verify_verdict",
]

REFERENCES = ("conic", "nlp")
"""The reference solvers: independent formulations (CVXPY + Clarabel, CVXPY + IPOPT)."""
SAFETY = 10.0
"""Agreement tolerance over the reference's accuracy (module docstring)."""
COLUMNS = ("step", "t", "dt", "slice", "x", "status", "status_ref", "kkt", "kkt_ref", "df", "dJ", "err", "err_ref",
           "tolerance", "seconds", "seconds_ref", "outcome")  # fmt: skip
"""The columns of ``verify.csv``, in order."""
TIMES = ("seconds", "seconds_ref")
"""The columns a resumed verification does not reproduce bit for bit (wall times)."""
AGREE, DIFFER, METHOD_FAILED, REFERENCE_FAILED = "agree", "differ", "method failed", "reference failed"
ILL_CONDITIONED = "ill-conditioned"
#: Each outcome of a compared slice (the ``outcome`` column of ``verify.csv``) and what it means.
OUTCOMES: dict[str, str] = {
    AGREE: "the reference is certified, the tested slice is one the engine accepts, and both discrepancies "
    "(max |f - f_ref| / max f_ref and the relative difference in J) are within the tolerance",
    DIFFER: "both are certified and a discrepancy is above the tolerance: the verification fails here",
    ILL_CONDITIONED: "the reference is certified but its own error estimate in f exceeds the tolerance: the step is "
    "too ill-conditioned for the reference to pin f down; unverified, whatever the discrepancy",
    METHOD_FAILED: "the reference is certified, the tested slice is not (the run carried it on only under "
    "stop.on_solver_failure = false)",
    REFERENCE_FAILED: "the reference is not certified: the slice is unverified, never counted as agreement "
    "(the verdict names the reference to use instead)",
}


def default_reference(scene: Scene) -> str:
    """``"nlp"`` for the log Fisher form (conic cannot pose it), else ``"conic"``."""
    return "nlp" if scene.collision.fisher == "log" else "conic"


def reference_accuracy(reference: str, options: dict[str, Any]) -> float:
    """The reference's accuracy in f, :math:`\\sqrt{tol}` with its ``tol`` (module docstring)."""
    return math.sqrt(OPTIONS[reference](**options).tol)


@dataclass(frozen=True)
class VerifySettings:
    """What a verification compares: the reference, its options, every K-th step (and, with ``last``, the run's
    last step), which slices."""

    reference: str
    options: dict[str, Any]
    every: int
    slices: str | int
    tolerance: float
    trajectory: bool = False
    last: bool = True

    def to_dict(self) -> dict[str, Any]:
        d = {"reference": self.reference, "options": self.options, "every": self.every, "slices": self.slices,
             "tolerance": self.tolerance, "last": self.last}  # fmt: skip
        # verifications written before "last" existed compared the multiples of every only: their verify.json
        # has no "last", they read as before, and a resume of one is refused (its settings differ)
        return {**d, "trajectory": True} if self.trajectory else d  # verifications without it read as before

    def slice_indices(self, n_x: int) -> np.ndarray:
        """The compared x-slices: all, or ``slices`` evenly spread indices (both ends included)."""
        if self.slices == "all" or int(self.slices) >= n_x:
            return np.arange(n_x)
        return np.unique(np.round(np.linspace(0, n_x - 1, int(self.slices))).astype(int))


def _check_settings(
    scene: Scene,
    reference: str | None,
    options: dict[str, Any] | None,
    every: int,
    slices: str | int,
    trajectory: bool = False,
) -> VerifySettings:
    """The settings, checked against the scene before any work (each refusal names the argument)."""
    if not isinstance(scene, Scene):
        raise TypeError(
            f"scene must be a jko_cvx.scene.Scene (from jko_cvx.scene.load_scene(path)), got {type(scene).__name__}"
        )
    reference = default_reference(scene) if reference is None else reference
    if not isinstance(reference, str) or reference not in REFERENCES:
        raise ValueError(f"reference must be one of {list(REFERENCES)}, got {reference!r}")
    if reference == "conic" and scene.collision.fisher == "log":
        raise ValueError(
            'reference="conic" cannot pose collision.fisher = "log" (not conic-representable): use reference="nlp" '
            'for the log form, or verify the scene with collision.fisher = "perspective"'
        )
    if reference == scene.collision.method:
        others = [r for r in REFERENCES if r != reference and not (r == "conic" and scene.collision.fisher == "log")]
        way_out = (
            f"choose reference={others[0]!r}"
            if others
            else 'no other reference poses collision.fisher = "log" (conic cannot): verify a run of another '
            'collision.method (newton, sqp) against nlp, or the scene with collision.fisher = "perspective" '
            "against conic"
        )
        raise ValueError(
            f"reference={reference!r} is the scene's own collision.method: a solver checked against itself proves "
            f"nothing; {way_out}"
        )
    if scene.time.order != 1:
        raise ValueError(
            "time.order = 2 is not supported by verify: its collision step is three solves (a Richardson "
            "combination), not one problem per slice; verify the scene with time.order = 1"
        )
    if reference == "nlp":
        from jko_cvx.collision.nlp import INSTALL_HINT, nlp_available

        if not nlp_available():
            raise ImportError(f'reference="nlp" needs IPOPT: {INSTALL_HINT}')
    every = check_int("every", every, 1)
    if isinstance(slices, str):
        if slices != "all":
            raise ValueError(f'slices must be "all" or an integer >= 1, got {slices!r}')
    else:
        slices = check_int("slices", slices, 1)
    if options is not None and not isinstance(options, dict):
        raise TypeError(f"reference_options must be a dict of {reference} options, got {type(options).__name__}")
    opts = dict(options or {})
    unknown = sorted(set(opts) - {f for f in OPTIONS[reference].__dataclass_fields__})
    if unknown:
        raise TypeError(f"unknown reference_options {unknown} for reference={reference!r}")
    tolerance = SAFETY * reference_accuracy(reference, opts)  # checks every option's value too
    check_bool("trajectory", trajectory)
    if trajectory:
        reference_scene(scene, reference, opts)  # the reference's scene must load: refused here, before any work
    return VerifySettings(reference, opts, every, slices, tolerance, trajectory)


def reference_scene(scene: Scene, reference: str, options: dict[str, Any]) -> Scene:
    """``scene`` with ``collision.method`` the reference and ``collision.options`` its options."""
    return scene.replace({"collision.method": reference, "collision.options": dict(options)})


def _tested_accepted(status: Status, kkt: float) -> bool:
    """A slice the engine accepts (:meth:`~jko_cvx.engine.loop.Stepper.accepted`, one slice)."""
    return status.success or (status is Status.NOT_CERTIFIED and kkt <= ACCEPT_KKT)


def _outcome(status: Status, kkt: float, ref: CollisionResult, df: float, dJ: float, err_ref: float, tol: float) -> str:
    if not ref.status.success:
        return REFERENCE_FAILED
    if not err_ref <= tol:  # NaN too
        return ILL_CONDITIONED
    if not _tested_accepted(status, kkt):
        return METHOD_FAILED
    return AGREE if (df <= tol and dJ <= tol) else DIFFER


def _worker_start(parent: int, lock_fd: int | None) -> None:
    """Start of a reference worker (forked from the run): it lets the run handle Ctrl-C and SIGTERM (the
    checkpoint is the run's), holds no copy of the run directory's lock, and dies with the run."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if lock_fd is not None:
        try:
            os.close(lock_fd)  # the flock stays with the run's descriptor; a killed run then frees it
        except OSError:
            pass
    if sys.platform.startswith("linux"):
        import ctypes

        try:
            ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG: killed with the run
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:  # the run died before the line above took effect
        os._exit(1)


def _compare_slice(
    problem: CollisionProblem, f: np.ndarray, m: np.ndarray, reference: str, options: dict[str, Any]
) -> tuple[CollisionResult, float, float, float]:
    """The reference's answer to one slice's problem, its solve time, and the error estimates in f of the tested
    answer ``(f, m)`` and of the reference's (:func:`f_error_estimate`); in a worker process or in this one."""
    with blas_limits():  # the same BLAS threads wherever it runs: the same bits
        t0 = time.perf_counter()
        ref = solve_reference(problem, reference, options)
        seconds = time.perf_counter() - t0
        return ref, seconds, f_error_estimate(problem, f, m), f_error_estimate(problem, ref.f, ref.m)


def _at(value: Any, i: int, batched: bool) -> Any:
    return np.atleast_1d(value)[i] if batched else value


class VerifyTracker(Tracker):
    """Re-solves the compared slices of every K-th step and of the run's last step with the reference and keeps
    the rows."""

    def __init__(self, scene: Scene, settings: VerifySettings, rundir: RunDir | None, workers: int = 1) -> None:
        self.scene, self.settings, self.rundir, self.workers = scene, settings, rundir, workers
        self.rows: list[dict[str, Any]] = []
        self.pending: list[dict[str, Any]] = []
        self.held: tuple | None = None  # the arguments of _compare for a step not compared unless it is the last
        self.pool = None

    # files ---------------------------------------------------------------
    def start(self, state: RunState) -> None:
        rd = self.rundir
        if rd is None:
            return
        path = rd.path / "verify.json"
        if rd.state is None:  # a fresh run: record the settings
            rd.ledger.save_text(path, json.dumps(self.settings.to_dict(), indent=2, sort_keys=True))
            return
        recorded = _read_settings(rd.path, rd.ledger)
        new = json.loads(json.dumps(self.settings.to_dict()))
        diff = [f"{k}: {recorded.get(k)!r} -> {new.get(k)!r}" for k in sorted(set(new) | set(recorded))
                if recorded.get(k) != new.get(k)]  # fmt: skip
        if diff:
            raise RunDirError(
                f"cannot resume the verification in {rd.path}: its settings differ ({'; '.join(diff)}); resume with "
                "the same reference, options, every and slices, or start again with --overwrite"
            )
        if (rd.path / "verify.csv").exists():
            table = _read_table(rd.path, rd.ledger)
            self.rows = [r for r in table.to_dict("records") if r["step"] <= state.step]
        ended = self.settings.last and state.done(self.scene.t_end)
        missing = _missing_steps(self.rows, self.settings.every, state.step, ended)
        if missing:
            raise RunDirError(
                f"cannot resume the verification in {rd.path}: verify.csv lacks the compared steps {missing[:5]} "
                "up to its checkpoint (the run was continued without verification); start again with --overwrite"
            )

    def _save(self) -> None:
        rd = self.rundir
        if rd is not None:
            rd.ledger.save_text(rd.path / "verify.csv", _frame(self.rows).to_csv(index=False))

    # the loop's hooks ----------------------------------------------------
    def solved(self, state: RunState, problem: CollisionProblem | None, result: CollisionResult) -> None:
        self.pending, self.held = [], None
        step = state.step + 1
        if problem is None:
            return
        xs = None if state.xgrid is None else state.xgrid.points.copy()
        if step % self.settings.every:  # compared only if the run ends with it (handle)
            self.held = (step, state.t, xs, problem, result)
            return
        self.pending = self._compare(step, state.t, xs, problem, result)

    def _compare(
        self, step: int, t: float, xs: NDArray | None, problem: CollisionProblem, result: CollisionResult
    ) -> list[dict[str, Any]]:
        """The rows of step ``step`` (from time ``t``, on the x-points ``xs``): each compared slice re-solved."""
        rows = []
        batched = problem.batched
        indices = self.settings.slice_indices(problem.batch_size) if batched else np.array([0])
        share = result.seconds / (problem.batch_size if batched else 1)
        dt = float(problem.dt)
        tasks = [
            (
                problem.slice(int(i)) if batched else problem,
                np.atleast_2d(result.f)[i] if batched else result.f,
                np.atleast_2d(result.m)[i] if batched else result.m,
                self.settings.reference,
                self.settings.options,
            )
            for i in indices
        ]
        for i, task, (ref, ref_seconds, err, err_ref) in zip(indices, tasks, self._map(tasks), strict=True):
            f = task[1]
            status = _at(result.status, i, batched)
            kkt = float(_at(result.kkt_residual, i, batched))
            J = float(_at(result.objective, i, batched))
            scale = float(np.max(ref.f)) if np.max(ref.f) > 0 else 1.0
            with np.errstate(all="ignore"):
                df = float(np.max(np.abs(f - ref.f)) / scale)
                dJ = float(abs(J - ref.objective) / max(abs(float(ref.objective)), np.finfo(float).tiny))
            df = df if np.isfinite(df) else np.inf
            dJ = dJ if np.isfinite(dJ) else np.inf
            rows.append({
                "step": step, "t": t + dt, "dt": dt, "slice": int(i),
                "x": float("nan") if xs is None else float(xs[i]),
                "status": status.name, "status_ref": ref.status.name, "kkt": kkt, "kkt_ref": float(ref.kkt_residual),
                "df": df, "dJ": dJ, "err": err, "err_ref": err_ref, "tolerance": self.settings.tolerance,
                "seconds": float(share), "seconds_ref": ref_seconds,
                "outcome": _outcome(status, kkt, ref, df, dJ, err_ref, self.settings.tolerance),
            })  # fmt: skip
        return rows

    def _map(self, tasks: list[tuple]) -> list[tuple[CollisionResult, float, float, float]]:
        """:func:`_compare_slice` of every task, in order: in worker processes where there are several tasks
        and ``workers > 1`` (each solve is cold and deterministic, so the answers are the same bits)."""
        if len(tasks) < 2 or self.workers <= 1:
            return [_compare_slice(*task) for task in tasks]
        if self.pool is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            # the start method in force, without fixing it (the first of all methods is the platform's default)
            method = multiprocessing.get_start_method(allow_none=True) or multiprocessing.get_all_start_methods()[0]
            if method != "fork" or multiprocessing.current_process().daemon:
                # a spawned worker imports the main script again (which may be an unguarded script calling
                # verify); a daemonic process (a pool's worker) may not start children
                self.workers = 1
                return self._map(tasks)
            lock = getattr(self.rundir, "_lock_fd", None)
            self.pool = ProcessPoolExecutor(
                max_workers=min(self.workers, len(tasks)),
                mp_context=multiprocessing.get_context("fork"),
                initializer=_worker_start,
                initargs=(os.getpid(), lock),
            )
        from concurrent.futures.process import BrokenProcessPool

        try:
            return list(self.pool.map(_compare_slice, *zip(*tasks, strict=True)))
        except BrokenProcessPool:
            # a worker died (a signal to the whole process group, which this process defers while it compares the
            # run's last step in handle): the same deterministic solves here, so that the row is still written
            self.close()
            self.workers = 1
            return [_compare_slice(*task) for task in tasks]

    def close(self) -> None:
        """Shut the reference solves' worker processes down (they are started at the first step that needs them)."""
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.pool = None

    def handle(self, state: RunState, step: StepInfo) -> None:
        # the run's last step is compared whatever `every` says: the stop rules ran before this tracker, so
        # the state says whether the run ends here (at t_end, or a blow-up rule fired)
        if self.held is not None and self.settings.last and state.done(self.scene.t_end):
            self.pending = self._compare(*self.held)
        self.held = None
        # saved at once (this tracker runs before the checkpoint tracker): never behind a checkpoint,
        # also not behind the one SIGINT / SIGTERM writes of the last accepted step
        if self.pending:
            self.rows += self.pending
            self.pending = []
            self._save()

    def finish(self, state: RunState) -> None:
        self._save()


@dataclass
class Verification:
    """What :func:`verify` returns: the tested run, one row per compared step and slice, the verdict."""

    run: Run
    table: pd.DataFrame
    settings: VerifySettings
    reference_run: Run | None = None
    trajectory: TrajectoryComparison | None = None

    @property
    def _failure(self) -> str | None:
        """Why the run itself is not certified (:func:`~jko_cvx.engine.verdict.run_failure`), else None."""
        return run_failure(self.run.verdict)

    @property
    def verified(self) -> bool:
        """Every compared slice agrees, the run is certified (no failed solve ended it or was carried on) and,
        with ``trajectory``, the two runs agree where the reference run is certified."""
        ok = verify_verdict(self.table, failure=self._failure)[0]
        return ok and (self.trajectory is None or self.trajectory.agree)

    @property
    def verdict(self) -> str:
        """:func:`verify_verdict`'s text; where nothing was compared, with the reason the run ended; then the
        trajectory part (:mod:`jko_cvx.engine._trajectory`)."""
        text = verify_verdict(self.table, self.settings.reference, self._failure)[1]
        text = text if len(self.table) else f"{text}; the run: {self.run.verdict.reason}"
        return text if self.trajectory is None else f"{text}; {self.trajectory.text}"


def _frame(rows: Sequence[dict[str, Any]]) -> pd.DataFrame:
    return pd.DataFrame(list(rows), columns=list(COLUMNS))


def _why(row: pd.Series) -> str:
    if row["outcome"] == REFERENCE_FAILED:
        return f"the reference is not certified ({row['status_ref']}, KKT {row['kkt_ref']:.2e}): unverified"
    if row["outcome"] == ILL_CONDITIONED:
        return (
            f"the step is too ill-conditioned for the reference to pin f to {row['tolerance']:.1e} (its answer's "
            f"error estimate is {row['err_ref']:.2e}): unverified"
        )
    if row["outcome"] == METHOD_FAILED:
        return f"the tested method is not certified ({row['status']}, KKT {row['kkt']:.2e}) where the reference is"
    return (
        f"they differ by {row['df']:.2e} in f and {row['dJ']:.2e} in J (relative), above the tolerance "
        f"{row['tolerance']:.1e}"
    )


_OTHER_REFERENCE = {
    "conic": (
        "where the conic reference is not certified, verify with reference='nlp' (--reference nlp), an independent "
        "formulation that poses the perspective form too"
    ),
    "nlp": "try reference='conic' (--reference conic) where the scene's Fisher form is not the log form",
}


def verify_verdict(table: pd.DataFrame, reference: str | None = None, failure: str | None = None) -> tuple[bool, str]:
    """``(verified, text)`` of a verification table (module docstring: verified when every compared slice agrees).

    With ``reference``, a verdict with slices the reference failed on says which reference to use instead.
    ``failure`` says why the run itself is not certified (:func:`~jko_cvx.engine.verdict.run_failure`): the
    verdict is then "not verified" whatever the rows say.
    """
    if failure is not None and len(table):
        text = verify_verdict(table, reference)[1]
        return False, f"not verified: {failure}; the compared steps: {text}"
    if len(table) == 0:
        return False, "unverified: no step was compared (no step was accepted, or a failed solve stopped the run first)"
    bad = table[table["outcome"] != AGREE]
    if len(bad) == 0:
        steps = table["step"].nunique()
        return True, (
            f"verified: {len(table)} slice solves over {steps} steps agree within {table['tolerance'].iloc[0]:.1e} "
            f"(max discrepancy in f {table['df'].max():.2e}, in J {table['dJ'].max():.2e})"
        )
    row = bad.sort_values(["step", "slice"], kind="stable").iloc[0]
    where = f"step {int(row['step'])} (t = {row['t']:.6g}), slice {int(row['slice'])}"
    if np.isfinite(row["x"]):
        where += f" (x = {row['x']:.4g})"
    counts = ", ".join(f"{n} {k}" for k, n in bad["outcome"].value_counts().sort_index().items())
    text = (
        f"not verified: first at {where}: {_why(row)}; method status {row['status']}, reference status "
        f"{row['status_ref']} ({counts} of {len(table)} compared slices)"
    )
    if reference in _OTHER_REFERENCE and (bad["outcome"] == REFERENCE_FAILED).any():
        text += f"; {_OTHER_REFERENCE[reference]}"
    return False, text


def verify(
    scene: Scene,
    reference: str | None = None,
    *,
    every: int = 1,
    slices: str | int = "all",
    reference_options: dict[str, Any] | None = None,
    out: str | Path | None = None,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = False,
    trajectory: bool = False,
    workers: int | None = None,
) -> Verification:
    """Run ``scene`` and re-solve every ``every``-th step's collision problems, and the last step's, with a reference.

    Parameters
    ----------
    scene : Scene
        Run with its own ``collision.method`` (``time.order = 1``).
    reference : {"conic", "nlp"}, optional
        Default :func:`default_reference`: conic for the perspective form and no Fisher term,
        nlp for the log form.  Refused: conic for the log form, the scene's own method.
    every : int, default 1
        Compare the steps whose number is a multiple of ``every``, and the run's last step where the run
        ended with an accepted step (at ``t_end``, on a blow-up rule or on eps_t; not when a failed solve
        stopped it).
    slices : "all" or int, default "all"
        The x-slices compared (an integer: that many, evenly spread; homogeneous scenes have one).
    reference_options : dict, optional
        Options of the reference solver (default: its own, ``kkt_tol`` = 1e-6 included); its
        ``tol`` sets the tolerance.
    out, resume, overwrite, progress
        As for :func:`~jko_cvx.engine.loop.simulate`.
    trajectory : bool, default False
        Also run the whole scene with the reference method (:func:`reference_scene`; into
        ``out/reference/``, resumed and overwritten with the verification) and compare T_b, the
        stop reason and max f(t) (:mod:`jko_cvx.engine._trajectory`: common times, the same
        tolerance); ``trajectory.csv`` beside ``verify.csv``.
    workers : int, optional
        Processes for the reference solves of a step's slices (default: the usable cores; 1: in this
        process).  They are forked workers, where ``fork`` is the platform's start method (Linux up to
        Python 3.13); elsewhere the solves run in this process.  The slices are solved cold and
        independently, so the table is the same whatever ``workers`` (but for the solve times), and
        a resumed verification may use another value.

    Raises
    ------
    ValueError, TypeError, ImportError
        A bad or impossible setting, naming it, before any work or file write.
    RunDirError
        ``out`` cannot be used as asked, or ``resume`` with other settings than the verification's.

    Examples
    --------
    Two Newton steps of a small gamma = 1 scene with the perspective Fisher form, each re-solved
    by the conic reference (the default for that form):

    >>> from jko_cvx import shipped_scene, verify
    >>> scene = shipped_scene("tab_bu_g1", {"v.n": 21, "t_end": 0.02, "collision.fisher": "perspective"})
    >>> ver = verify(scene)
    >>> ver.verified, len(ver.table), list(ver.table["outcome"])
    (True, 2, ['agree', 'agree'])
    >>> print(ver.verdict)  # doctest: +ELLIPSIS
    verified: 2 slice solves over 2 steps agree within 1.0e-04 (max discrepancy in f ...)
    """
    settings = _check_settings(scene, reference, reference_options, every, slices, trajectory)
    for name, flag in (("resume", resume), ("overwrite", overwrite), ("progress", progress)):
        check_bool(name, flag)
    workers = usable_cores() if workers is None else check_int("workers", workers, 1)
    sub = None if out is None else Path(out) / REFERENCE_DIR
    if sub is not None and (sub.is_symlink() or (sub.exists() and not sub.is_dir())):
        raise RunDirError(f"{sub} is a symbolic link or not a directory: a verification's reference run is never "
                          "followed through a link; remove it")  # fmt: skip
    holder: list[VerifyTracker] = []

    def observers(rd: RunDir | None) -> list[Tracker]:
        if rd is not None and rd.state is not None and not (rd.path / "verify.json").exists():
            raise RunDirError(f"cannot resume {rd.path} as a verification: it holds a run without verify.json")
        holder.append(VerifyTracker(scene, settings, rd, workers))
        return holder

    results: list[Verification] = []

    def finish(run: Run) -> None:
        # inside the run directory's lock (simulate's on_finish): the reference run and the report cannot land in
        # a directory another process has taken over since the tested run ended
        tracker = holder[0]
        result = Verification(run, _frame(tracker.rows), settings)
        if trajectory:
            ref_scene = reference_scene(scene, settings.reference, settings.options)
            again = resume and sub is not None and (sub / "checkpoint.npz").exists()  # killed during the reference run
            # no checkpoint there: nothing of the reference run to keep (the outer directory's own rules
            # already refused or moved aside an earlier one), so what a kill left before it is replaced
            result.reference_run = simulate(ref_scene, out=sub, resume=again, overwrite=not again and sub is not None,
                                            progress=progress)  # fmt: skip
            result.trajectory = compare_trajectories(run, result.reference_run, settings.tolerance)
        if tracker.rundir is not None:
            _write_report(result, tracker.rundir.path, tracker.rundir.ledger)
        results.append(result)

    try:
        simulate(scene, out=out, resume=resume, overwrite=overwrite, progress=progress, observers=observers,
                 on_finish=finish)  # fmt: skip
    finally:
        for t in holder:
            t.close()
    return results[0]


# ---------------------------------------------------------------- files
REFERENCE_DIR = "reference"
"""The subdirectory of a verification directory that holds the reference's run (``trajectory``)."""


# the stops decided after an accepted step (RunState.done): that step was the run's last and is compared
_ENDED_BY_A_STEP = (StopReason.T_END, StopReason.EPS_V, StopReason.EPS_X, StopReason.SPREAD_V, StopReason.EPS_T)


def _missing_steps(rows: Sequence[dict[str, Any]], every: int, last: int, ended: bool) -> list[int]:
    """The steps up to ``last`` a verification compares that have no row: the multiples of ``every`` and, where
    the run ``ended`` with step ``last`` (at t_end or on a blow-up rule, not on a failed solve), that step."""
    compared = set(range(every, last + 1, every)) | ({last} if ended and last > 0 else set())
    return sorted(compared - {int(r["step"]) for r in rows})


def _read_settings(path: Path, ledger: Ledger) -> dict[str, Any]:
    file = path / "verify.json"
    if not file.exists():
        raise RunDirError(f"{path} holds no verification (no verify.json): it is a run, not a jko-cvx verify directory")
    ledger.verify(file)
    try:
        return json.loads(file.read_text())
    except (OSError, ValueError) as exc:
        raise RunDirError(f"{file} does not read ({type(exc).__name__}: {exc})") from None


def _read_table(path: Path, ledger: Ledger) -> pd.DataFrame:
    file = path / "verify.csv"
    ledger.verify(file)
    # floats read back as written, bit for bit: pandas >= 3 by default, 2.x with "round_trip" (deprecated in 3)
    exact = {} if int(pd.__version__.split(".")[0]) >= 3 else {"float_precision": "round_trip"}
    try:
        table = pd.read_csv(file, **exact, keep_default_na=False, na_values=["", "nan", "NaN"])
    except (OSError, ValueError) as exc:
        raise RunDirError(f"{file} does not read ({type(exc).__name__}: {exc})") from None
    if list(table.columns) != list(COLUMNS):
        raise RunDirError(f"{file} is not a verification table: its columns are {list(table.columns)}")
    for c in ("status", "status_ref", "outcome"):
        table[c] = table[c].astype(str)
    return table


def load_verification(path: str | Path) -> pd.DataFrame:
    """``verify.csv`` of a verification directory as a DataFrame, checked before it is returned.

    Checked: the directory's lock-free files against the ledger (``metadata.json``), the
    settings (``verify.json``), the run has ended (``verdict.json``), and the table holds one
    row per compared slice of every K-th step the run took and of its last step (where the run ended with an
    accepted step: at t_end or on a blow-up rule); with ``trajectory``, the comparison of
    the tested and the reference run is recomputed from the two runs as loaded and must equal
    ``trajectory.csv``.  ``attrs`` holds ``settings``, ``verified`` and ``verdict`` (the
    trajectory part included) and, with ``trajectory``, the ``trajectory`` table.

    Raises
    ------
    RunDirError
        Not a verification directory, a file changed since it was written, the run has not ended,
        or rows are missing.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from jko_cvx import load_verification, shipped_scene, verify
    >>> scene = shipped_scene("tab_bu_g1", {"v.n": 21, "t_end": 0.02, "collision.fisher": "perspective"})
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     _ = verify(scene, out=Path(tmp) / "verify")
    ...     table = load_verification(Path(tmp) / "verify")
    >>> table.attrs["verified"]
    True
    >>> table[["step", "status", "status_ref", "outcome"]]
       step     status status_ref outcome
    0     1  CONVERGED  CONVERGED   agree
    1     2  CONVERGED  CONVERGED   agree
    """
    path = Path(path)
    if not path.is_dir():
        raise RunDirError(f"verification directory {path} does not exist")
    from jko_cvx.engine._rundir import refuse_links

    refuse_links(path)
    ledger = Ledger.read(path)
    settings = _read_settings(path, ledger)
    if not (path / "verdict.json").exists():
        raise RunDirError(
            f"the verification in {path} has not ended (no verdict.json): resume it with jko-cvx verify SCENE --out "
            f"{path} --resume"
        )
    ledger.verify(path / "verdict.json")
    record = json.loads((path / "verdict.json").read_text())
    steps = int(record["steps"])
    table = _read_table(path, ledger) if (path / "verify.csv").exists() else _frame([])
    ended = bool(settings.get("last")) and record.get("stop") in [s.name for s in _ENDED_BY_A_STEP]
    missing = _missing_steps(table.to_dict("records"), settings["every"], steps, ended)
    if missing:
        raise RunDirError(
            f"{path / 'verify.csv'} lacks the steps {missing[:5]}{' ...' if len(missing) > 5 else ''} of a run of "
            f"{steps} steps compared every {settings['every']}: it was continued without verification"
        )
    table.attrs["settings"] = settings
    verified, verdict = verify_verdict(table, settings.get("reference"), run_failure(record))
    if settings.get("trajectory"):
        tr = _load_trajectory(path, ledger, settings["tolerance"])
        table.attrs["trajectory"] = tr.table
        verified, verdict = verified and tr.agree, f"{verdict}; {tr.text}"
    table.attrs["verified"], table.attrs["verdict"] = verified, verdict
    return table


def _load_trajectory(path: Path, ledger: Ledger, tolerance: float) -> TrajectoryComparison:
    """The trajectory part of a verification, recomputed from the two runs as loaded (each checked by
    :func:`~jko_cvx.engine.run.load_run`) and required to equal the ``trajectory.csv`` it wrote."""
    from jko_cvx.engine.run import load_run

    file = path / "trajectory.csv"
    if not file.exists() or not (path / REFERENCE_DIR / "verdict.json").exists():
        raise RunDirError(
            f"the verification in {path} compares trajectories but its reference run ({path / REFERENCE_DIR}) or "
            f"{file.name} is missing: resume it with jko-cvx verify SCENE --out {path} --resume --trajectory"
        )
    ledger.verify(file)
    tr = compare_trajectories(load_run(path), load_run(path / REFERENCE_DIR), tolerance)
    if file.read_text() != tr.table.to_csv(index=False):
        raise RunDirError(f"{file} is not the comparison of the two runs in {path}: it was written by other code")
    return tr


def _write_report(result: Verification, path: Path, ledger: Ledger) -> None:
    """verify.md (summary, verdict, worst rows) and verify.png."""
    t, s, run = result.table, result.settings, result.run
    last = " and the last" if s.last and run.verdict.stop in _ENDED_BY_A_STEP else ""
    lines = [
        f"# Verification of {run.scene.name}: {run.scene.collision.method} against {s.reference}",
        "",
        f"- scene: {run.scene.name} ({run.scene.description}); collision.fisher = {run.scene.collision.fisher}, "
        f"beta = {run.scene.collision.beta:g}",
        f"- reference: {s.reference} with {json.dumps(s.options, sort_keys=True)}; every {s.every} step(s)"
        f"{last}; slices: {s.slices}",
        f"- tolerance: {s.tolerance:.2e} = {SAFETY:g} x sqrt(reference tol) (relative, in f and in J)",
        f"- run: {run.summary()}",
        "",
        f"**Verdict**: {result.verdict}",
        "",
    ]
    if len(t):
        counts = t["outcome"].value_counts()
        lines += ["| outcome | slices |", "|---|---|"] + [f"| {k} | {n} |" for k, n in counts.items()] + [""]
        lines += [
            f"Discrepancy in f: median {t['df'].median():.2e}, max {t['df'].max():.2e}; in J: max {t['dJ'].max():.2e}. "
            f"Reference time per slice: median {t['seconds_ref'].median():.3g} s, "
            f"total {t['seconds_ref'].sum():.3g} s; "
            f"the run's collision time {run.seconds.get('collision', float('nan')):.3g} s.",
            "",
            "## Worst rows (largest discrepancy in f)",
            "",
            t.sort_values("df", ascending=False, kind="stable").head(10).to_markdown(index=False, floatfmt=".3g"),
            "",
        ]
    tr = result.trajectory
    if tr is not None:
        ledger.save_text(path / "trajectory.csv", tr.table.to_csv(index=False))
        ref = result.reference_run
        judged = tr.table[tr.table["matched"]]
        lines += [
            f"## Trajectory: the scene run again with {s.reference} (in {REFERENCE_DIR}/)",
            "",
            f"**{tr.text}**",
            "",
            "| | tested | reference |",
            "|---|---|---|",
            f"| method | {run.scene.collision.method} | {s.reference} |",
            f"| stop | {run.verdict.reason} | {ref.verdict.reason} |",
            f"| T_b | {tr.T_b} | {tr.T_b_ref} |",
            f"| steps, t | {run.steps}, {run.t:.6g} | {ref.steps}, {ref.t:.6g} |",
            f"| collision time (s) | {run.seconds.get('collision', float('nan')):.3g} | "
            f"{ref.seconds.get('collision', float('nan')):.3g} |",
            "",
            f"max f(t) compared at {len(judged)} common times (a reference time within 1e-6 of the smaller dt; "
            f"{len(tr.table) - len(judged)} other tested times interpolated, not judged): max relative difference "
            f"{judged['dmax_f'].max() if len(judged) else float('nan'):.2e}, tolerance {tr.tolerance:.1e} "
            "(trajectory.csv).",
            "",
        ]
    ledger.save_text(path / "verify.md", "\n".join(lines))
    ledger.write(path / "verify.png", lambda tmp: _plot(result, tmp))


def _plot(result: Verification, file: str) -> None:
    """verify.png, drawn on a pyplot-free Figure: the caller's backend (a notebook's inline one) is left alone."""
    from matplotlib.figure import Figure

    t, s, tr = result.table, result.settings, result.trajectory
    if tr is None:
        fig = Figure(figsize=(7, 6))
        ax1, ax2 = fig.subplots(2, 1, sharex=True)
    else:
        fig = Figure(figsize=(7, 8.5))
        ax1, ax2, ax3 = fig.subplots(3, 1, sharex=True)
        d, r = result.run.diagnostics, result.reference_run.diagnostics
        ax3.plot(d["t"], d["max_f"], "-", label=f"max f, {result.run.scene.collision.method}")
        ax3.plot(r["t"], r["max_f"], "--", label=f"max f, {s.reference}")
        bad = tr.table[tr.table["outcome"] == "differ"]
        if len(bad):
            ax3.axvline(bad["t"].iloc[0], color="r", lw=0.8, label="max f parts")
        ax3.set_ylabel("max f")
        ax3.set_xlabel("t")
        ax3.legend(fontsize=7)
    if len(t):
        worst = t.groupby("step").agg({"t": "first", "df": "max", "dJ": "max", "kkt": "max", "kkt_ref": "max"})
        ax1.semilogy(worst["t"], np.maximum(worst["df"], 1e-17), "o-", ms=3, label="max |f - f_ref| / max f_ref")
        ax1.semilogy(worst["t"], np.maximum(worst["dJ"], 1e-17), "s-", ms=3, label="|J - J_ref| / |J_ref|")
        ax2.semilogy(worst["t"], np.maximum(worst["kkt"], 1e-17), "o-", ms=3, label="KKT residual, tested method")
        ax2.semilogy(worst["t"], np.maximum(worst["kkt_ref"], 1e-17), "s-", ms=3, label=f"KKT residual, {s.reference}")
        bad = t[t["outcome"] != AGREE]
        if len(bad):
            ax1.axvline(bad["t"].iloc[0], color="r", lw=0.8, label="first slice not agreeing")
    acc = s.tolerance / SAFETY
    ax1.axhspan(1e-17, acc, color="0.85", label=f"reference accuracy sqrt(tol) = {acc:.1e}")
    ax1.axhline(s.tolerance, color="k", ls="--", lw=0.8, label=f"tolerance {s.tolerance:.1e}")
    ax2.axhline(ACCEPT_KKT, color="k", ls="--", lw=0.8, label=f"engine's acceptance {ACCEPT_KKT:g}")
    ref_kkt = OPTIONS[s.reference](**s.options).kkt_tol
    ax2.axhline(ref_kkt, color="C1", ls=":", lw=0.8, label=f"{s.reference}'s kkt_tol {ref_kkt:g}")
    from jko_cvx.engine.plot import refinement_switches

    run, d = result.run, result.run.diagnostics
    switches = np.concatenate([refinement_switches(run, a) for a in ("v", "x")])
    for k, step in enumerate(np.unique(switches)):
        ts = float(d.loc[d["step"] == step, "t"].iloc[0])
        for ax in (ax1, ax2):
            ax.axvline(ts, color="0.6", lw=0.6, ls=":", label="remeshing" if k == 0 and ax is ax1 else None)
    if run.verdict.blowup and run.verdict.T_b is not None:
        for ax in (ax1, ax2):
            ax.axvline(run.verdict.T_b, color="m", lw=1.0, label=f"T_b = {run.verdict.T_b:.4g}" if ax is ax1 else None)
    ax1.set_ylabel("discrepancy (max over slices)")
    ax2.set_ylabel("KKT residual (max over slices)")
    if tr is None:
        ax2.set_xlabel("t")
    for ax in (ax1, ax2):
        ax.legend(fontsize=7)
    ax1.set_title(f"{result.run.scene.name}: {result.run.scene.collision.method} against {s.reference}")
    fig.tight_layout()
    fig.savefig(file, format="png", dpi=100)
