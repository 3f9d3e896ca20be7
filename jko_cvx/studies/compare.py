"""Solver comparison on one collision step: every method, several tolerances, one table.

:func:`compare_solvers` runs each configuration (conic with every installed CVXPY conic
solver, the paper's SQP with its banded and OSQP subproblem paths, Newton, and the
nonlinear CVXPY reference nlp with IPOPT) at several tolerances on the same
:class:`~jko_cvx.collision.problem.CollisionProblem` and judges all of them the same way:
the problem's KKT residual, the objective gap to the best certified solution, and the
max-norm error in f against a high-accuracy reference (Newton at ``tol=1e-13``,
cross-checked against the best certified conic and nlp solutions).  A method that cannot
run on the problem (conic on the log Fisher form, the SQP with the momentum constraint,
nlp without IPOPT) gets one ``NOT_RUN`` row whose setting says why.  Following
qpbenchmark, a run counts as *certified* only if its status says success **and** its KKT
residual is at most ``kkt_tol``; a success status with a larger residual is counted as
*silently wrong* (the package's statuses never do that; a third-party solver's raw status
may, which is why every result is re-checked).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.collision import CollisionProblem, conic_solvers, f_error_estimate, solve_collision
from jko_cvx.collision.nlp import nlp_available
from jko_cvx.collision.problem import LOG_FORM_METHODS, MOMENTUM_METHODS, methods_text

__all__ = ["Configuration", "compare_solvers", "default_configurations", "problem_from_scene"]

_INTERIOR_POINT = ("CLARABEL", "ECOS", "MOSEK", "CVXOPT", "GUROBI", "COPT", "XPRESS")


@dataclass(frozen=True)
class Configuration:
    """One method with one set of options, labelled for the table."""

    family: str  # "conic:CLARABEL", "sqp:banded", "newton", ...
    method: str
    setting: str
    options: dict[str, Any] = field(default_factory=dict)
    absent: str = ""  # why the method cannot run on this problem: a table row that says so, never run


def default_configurations(problem: CollisionProblem) -> list[Configuration]:
    """Every available method at three accuracies; a method that cannot run gets one row saying why.

    Conic needs a conic-representable Fisher form (not ``"log"``), the SQP has no momentum
    constraint, and nlp needs IPOPT.
    """
    out: list[Configuration] = []
    if problem.fisher == "log":
        why = f'fisher="log" is not conic-representable (method {methods_text(LOG_FORM_METHODS)} poses the log form)'
        out.append(Configuration("conic", "conic", "absent", absent=why))
    if problem.fisher != "log" and not problem.batched:
        for solver in conic_solvers():
            # first-order solvers (SCS) need thousands of iterations beyond 1e-8 (measured 27 s at 1e-10)
            tols = (1e-6, 1e-8, 1e-10) if solver in _INTERIOR_POINT else (1e-4, 1e-6, 1e-8)
            for tol in tols:
                out.append(Configuration(f"conic:{solver}", "conic", f"tol={tol:g}", {"solver": solver, "tol": tol}))
    if not problem.conserve_momentum:
        for tol in (1e-6, 1e-9, 1e-12):
            out.append(Configuration("sqp:banded", "sqp", f"tol={tol:g}", {"tol": tol}))
        for eps in (1e-6, 1e-10):
            out.append(Configuration("sqp:osqp", "sqp", f"osqp_eps={eps:g}", {"qp": "osqp", "osqp_eps": eps}))
        out.append(Configuration("sqp:banded", "sqp", "max_iter=5", {"max_iter": 5}))  # truncated: must be flagged
    else:
        why = f"the paper's SQP has no momentum constraint (method {methods_text(MOMENTUM_METHODS)} has it)"
        out.append(Configuration("sqp", "sqp", "absent", absent=why))
    if nlp_available():
        for tol in (1e-6, 1e-8, 1e-10):
            out.append(Configuration("nlp:IPOPT", "nlp", f"tol={tol:g}", {"tol": tol}))
    else:
        out.append(Configuration("nlp", "nlp", "absent", absent='IPOPT not installed (pip install "jko_cvx[nlp]")'))
    for tol in (1e-6, 1e-8, 1e-10):
        out.append(Configuration("newton", "newton", f"tol={tol:g}", {"tol": tol}))
    return out


def compare_solvers(
    problem: CollisionProblem,
    configurations: list[Configuration] | None = None,
    repeats: int = 5,
    kkt_tol: float = 1e-6,
) -> pd.DataFrame:
    """Run every configuration on ``problem``; one row per configuration.

    Parameters
    ----------
    problem : CollisionProblem
        One (unbatched) collision step.
    configurations : list of Configuration, optional
        Default: :func:`default_configurations`.
    repeats : int, default 5
        Timed solves per configuration after one untimed warm-up (which also compiles
        the CVXPY model; its compile time is reported separately).
    kkt_tol : float, default 1e-6
        Certification threshold on the KKT residual.

    Returns
    -------
    pandas.DataFrame
        Columns: family, setting, status, certified, silently_wrong, median_s,
        compile_s, iterations, objective_gap, f_error (max-norm distance to the tight Newton
        reference, relative to max f; where that reference is not certified, to the certified row of
        least J, and NaN where no row is certified), f_error_est (the row's own a posteriori estimate of that
        distance, :func:`~jko_cvx.collision.f_error_estimate`, which needs no reference; cells
        weighted by f_j / max f as in the certificate, so it lies below f_error where the answers
        part only in near-vacuum tails), kkt, mass_error, min_f.
        ``attrs["reference"]`` describes the reference solution.
    """
    if problem.batched:
        raise ValueError("compare_solvers takes one problem; pass problem.slice(i)")
    if not isinstance(repeats, int) or repeats < 1:
        raise ValueError(f"repeats must be an integer >= 1, got {repeats!r}")
    configurations = default_configurations(problem) if configurations is None else configurations
    ref = solve_collision(problem, "newton", tol=1e-13, max_iter=200)
    reference = f"newton tol=1e-13: {ref.status.name}, KKT {ref.kkt_residual:.1e}"
    rows = []
    for cfg in configurations:
        if cfg.absent:
            rows.append(_absent_row(cfg, problem.n))
            continue
        first = solve_collision(problem, cfg.method, **cfg.options)
        # CVXPY model compile (conic) or model and derivative-oracle build (nlp), when this run did it
        compile_s = float(first.info.get("compile_seconds", first.info.get("build_seconds", np.nan)))
        times = []
        res = first
        for _ in range(repeats):
            t0 = time.perf_counter()
            res = solve_collision(problem, cfg.method, **cfg.options)
            times.append(time.perf_counter() - t0)
        kkt = float(problem.kkt_residual(res.f, res.m).total)  # re-checked, whatever the solver says
        certified = bool(res.success) and kkt <= kkt_tol
        rows.append(
            {
                "family": cfg.family,
                "setting": cfg.setting,
                "status": res.status.name,
                "certified": certified,
                "silently_wrong": bool(res.success) and not kkt <= kkt_tol,
                "median_s": float(np.median(times)),
                "compile_s": compile_s,
                "iterations": int(res.iterations),
                "objective": float(res.objective),
                "f": res.f,
                "kkt": kkt,
                "f_error_est": f_error_estimate(problem, res.f, res.m),
                "mass_error": float(res.mass_error),
                "min_f": float(res.f.min()),
            }
        )
    df = pd.DataFrame(rows)
    best = df.objective[df.certified].min() if df.certified.any() else np.nan
    if ref.success and not best < ref.objective:
        best = ref.objective
    scale = max(abs(best), np.finfo(float).tiny) if np.isfinite(best) else np.nan
    df["objective_gap"] = (df.objective - best) / scale
    # f_error against a certified answer only: the tight Newton reference, else the certified row of least J
    ref_certified = bool(ref.success) and float(problem.kkt_residual(ref.f, ref.m).total) <= kkt_tol
    if ref_certified:
        against = ref.f
    elif df.certified.any():
        row = df[df.certified].objective.idxmin()
        against = df.f[row]
        reference += f" (not certified): f_error against the certified row of least J, {df.setting[row]}"
    else:
        against = None
        reference += " (not certified) and no row certified: f_error not measured"
    if against is None:
        df["f_error"] = np.nan
    else:
        fmax = float(np.abs(against).max())
        df["f_error"] = [float(np.abs(f - against).max()) / fmax for f in df.f]
    for family in ("conic", "nlp"):
        best_rows = df[df.certified & df.family.str.startswith(family)]
        if ref_certified and len(best_rows):
            agree = float(best_rows.f_error.min())
            reference += f"; best certified {family} solution within {agree:.1e} (max-norm, relative)"
    df = df.drop(columns=["f", "objective"])
    est = df.pop("f_error_est")
    df.insert(df.columns.get_loc("f_error") + 1, "f_error_est", est)  # beside the distance it estimates
    df.attrs["reference"] = reference
    return df


def _absent_row(cfg: Configuration, n: int) -> dict[str, Any]:
    """The row of a method that cannot run on the problem: the reason in ``setting``, no figures."""
    nan = float("nan")
    return {
        "family": cfg.family,
        "setting": f"absent: {cfg.absent}",
        "status": "NOT_RUN",
        "certified": False,
        "silently_wrong": False,
        "median_s": nan,
        "compile_s": nan,
        "iterations": nan,
        "objective": nan,
        "f": np.full(n, nan),
        "kkt": nan,
        "f_error_est": nan,
        "mass_error": nan,
        "min_f": nan,
    }


def problem_from_scene(scene, t: float) -> CollisionProblem:
    """The collision step a scene takes from its state at time ``t`` (run there first).

    Homogeneous scenes: the next step's problem.  Inhomogeneous ones: the x-slice with the
    largest max f (the hardest one), taken before transport.  ``t = 0`` uses the initial datum.
    """

    from jko_cvx.engine.loop import simulate
    from jko_cvx.kernels import PowerKernel

    if not (isinstance(t, (int, float)) and 0 <= t < scene.t_end):
        raise ValueError(f"t must lie in [0, t_end = {scene.t_end:g}), got {t!r}")
    if t > 0:
        # the scene's own run, cut at t: snapshot times past t dropped, and a fixed step longer than t is the
        # one step to t (the loader refuses both in a scene, where they are a mistake)
        cut = {"t_end": float(t), "output.times": [tk for tk in scene.output.times if tk <= t]}
        if scene.time.policy == "fixed" and scene.time.dt > t:
            cut["time.dt"] = float(t)
        run = simulate(scene.replace(cut))
        if run.blowup is not False:  # a blow-up, or an undetermined (uncertified) state: no density to compare
            raise ValueError(f"the scene's run to t = {t:g} gives no certified state there: {run.summary()}")
        f, grid = run.f, run.vgrid
    else:
        grid = scene.vgrid()
        f = scene.initial_density(scene.xgrid(), grid)
    if f.ndim == 2:
        f = f[int(np.argmax(f.max(axis=1)))]
    dt = scene.step_policy().first(float(grid.dv.min()), None, scene.v.L, None if scene.x is None else scene.x.L)
    return CollisionProblem(
        grid,
        PowerKernel(scene.gamma),
        f,
        dt,
        scene.strength,
        scene.collision.beta,
        scene.collision.problem_fisher,
        scene.collision.conserve_momentum,
    )
