"""Cost growth: time per collision step and per time step against N_v and N_x.

Three measurements, each a median over repeats taken one after the other in one process
(so the ratios compare like with like):

* ``step``: one collision step (f* = exp(-2 v^2) on [-2, 2], dt = 0.01, perspective
  Fisher, beta = 10) for gamma = 1 (banded reduced Hessian) and gamma = 3 (dense energy
  block), N_v from 31 to 961, with Newton, the paper's SQP (banded subproblems) and the
  conic reference (Clarabel; re-solve time, the one-off compile apart);
* ``batch``: B slices of one inhomogeneous step (gamma = 3, N_v = 121, the slices of the
  ``inhom_gamma3_lambda4`` datum) solved as one batched Newton call against B single calls;
* ``time_step``: one whole time step (transport, refinement, collision) of the
  ``inhom_gamma3_lambda4`` scene against N_x (N_v = 121) and against N_v (N_x = 61).

The fitted exponent p of time ~ N^p uses the sizes N >= 121 (below that, fixed
per-call overheads dominate).
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.collision import CollisionProblem, Status, solve_collision
from jko_cvx.collision.conic import clear_model_cache
from jko_cvx.engine.verdict import StopReason
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.grid import Grid
from jko_cvx.kernels import PowerKernel
from jko_cvx.studies.solvers.figures import pyplot
from jko_cvx.studies.sweep import code_identity
from jko_cvx.threads import thread_environment, usable_cores

__all__ = ["cost_growth", "fit_exponent", "median_time"]


def fit_exponent(n: np.ndarray, seconds: np.ndarray, n_min: int = 121) -> float:
    """Least-squares slope of log(seconds) against log(n) over ``n >= n_min``."""
    n, seconds = np.asarray(n, float), np.asarray(seconds, float)
    keep = (n >= n_min) & np.isfinite(seconds)
    if keep.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(n[keep]), np.log(seconds[keep]), 1)[0])


def median_time(func: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    """The median wall time of ``repeats`` calls of ``func`` (seconds) and the last call's result."""
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = func()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def _step_rows(quick: bool, repeats: int) -> list[dict[str, Any]]:
    sizes = (31, 61, 121, 241) if quick else (31, 61, 121, 241, 481, 961)
    # conic on gamma = 3 stores the dense N x N energy: limited to N <= 481 (compile grows like N^2)
    conic_max = {1.0: 961, 3.0: 481} if not quick else {1.0: 241, 3.0: 121}
    rows = []
    for gamma in (1.0, 3.0):
        for n in sizes:
            grid = Grid.uniform(-2.0, 2.0, n)
            prob = CollisionProblem(grid, PowerKernel(gamma), np.exp(-2 * grid.points**2), 0.01, beta=10.0)
            for method in ("newton", "sqp", "conic"):
                if method == "conic" and n > conic_max[gamma]:
                    continue
                compile_s = np.nan
                if method == "conic":
                    clear_model_cache()
                    first = solve_collision(prob, method)
                    compile_s = float(first.info.get("compile_seconds", np.nan))
                secs, res = median_time(lambda m=method, p=prob: solve_collision(p, m), repeats)
                rows.append(
                    {
                        "gamma": gamma,
                        "N_v": n,
                        "method": method,
                        "median_s": secs,
                        "compile_s": compile_s,
                        "iterations": int(res.iterations),
                        "status": res.status.name,
                        "kkt": float(res.kkt_residual),
                    }
                )
    return rows


def _inhom_scene(n_x: int, n_v: int):
    from jko_cvx.studies.reproduce.inhomogeneous import inhomogeneous_scene

    return inhomogeneous_scene(4.0).replace({"x.n": n_x, "v.n": n_v})


def _inhom_slices(n_x: int, n_v: int = 121) -> CollisionProblem:
    scene = _inhom_scene(n_x, n_v)
    vgrid, xgrid = scene.vgrid(), scene.xgrid()
    f = scene.initial_density(xgrid, vgrid)
    f = np.maximum(f, 1e-300)
    return CollisionProblem(
        vgrid,
        PowerKernel(scene.gamma),
        f,
        scene.time.dt,
        scene.strength,
        scene.collision.beta,
        scene.collision.problem_fisher,
        conserve_momentum=True,
    )


def _batch_rows(quick: bool, repeats: int) -> list[dict[str, Any]]:
    rows = []
    for b in (15, 31, 61) if quick else (15, 31, 61, 121, 241):
        batch = _inhom_slices(b)
        t_batch, res = median_time(lambda p=batch: solve_collision(p, "newton", tol=1e-8), repeats)
        singles = [batch.slice(i) for i in range(b)]
        t_loop, _ = median_time(lambda s=singles: [solve_collision(p, "newton", tol=1e-8) for p in s], repeats)
        rows.append(
            {
                "B": b,
                "batched_s": t_batch,
                "one_at_a_time_s": t_loop,
                "speedup": t_loop / t_batch,
                "converged": int(sum(st is Status.CONVERGED for st in res.status)),
                "max_kkt": float(np.max(res.kkt_residual)),  # NOT_CERTIFIED slices stall just above 1e-8
            }
        )
    return rows


def _time_step_rows(quick: bool) -> list[dict[str, Any]]:
    from jko_cvx.engine.loop import simulate

    base = _inhom_scene(121, 121)
    cases = [("N_x", n, 121) for n in ((31, 61) if quick else (31, 61, 121, 241))]
    cases += [("N_v", 61, n) for n in ((61,) if quick else (61, 121, 241))]
    rows = []
    steps = 3
    for axis, n_x, n_v in cases:
        scene = base.replace({"x.n": n_x, "v.n": n_v, "t_end": steps * base.time.dt, "output.every": 10**6})
        t0 = time.perf_counter()
        run = simulate(scene)
        wall = time.perf_counter() - t0
        n_steps = max(len(run.diagnostics) - 1, 1)
        rows.append(
            {
                "axis": axis,
                "N_x": n_x,
                "N_v": n_v,
                "per_step_s": wall / n_steps,
                "collision_s": run.seconds["collision"] / n_steps,
                "transport_s": run.seconds["transport"] / n_steps,
                "refine_s": run.seconds["refine"] / n_steps,
                "steps": n_steps,
                "reached_t_end": run.verdict.stop is StopReason.T_END,
            }
        )
    return rows


def cost_growth(out: Path, quick: bool = False, repeats: int = 5, **_sweep_opts: Any) -> dict[str, pd.DataFrame]:
    """Measure (see the module docstring); writes ``cost_growth.{md,png}`` and one CSV per table."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    reps = 2 if quick else repeats
    code = code_identity(cost_growth)["package_sha256"][:12]  # before the run: an edit meanwhile cannot change it
    load0 = os.getloadavg()[0]
    step = pd.DataFrame(_step_rows(quick, reps))
    batch = pd.DataFrame(_batch_rows(quick, reps))
    tstep = pd.DataFrame(_time_step_rows(quick))
    fits = pd.DataFrame(
        [
            {"what": f"collision step, gamma={g:g}, {m}", "exponent": fit_exponent(b.N_v, b.median_s)}
            for (g, m), b in step.groupby(["gamma", "method"])
        ]
        + [
            {"what": "batched Newton vs B", "exponent": fit_exponent(batch.B, batch.batched_s, 31)},
            {"what": "one-at-a-time Newton vs B", "exponent": fit_exponent(batch.B, batch.one_at_a_time_s, 31)},
        ]
        + [
            {"what": f"time step vs {axis}", "exponent": fit_exponent(b[axis], b.per_step_s, 61)}
            for axis, b in tstep.groupby("axis")
        ]
    )
    for name, df in (("step", step), ("batch", batch), ("time_step", tstep), ("exponents", fits)):
        df.to_csv(out / f"cost_growth_{name}.csv", index=False)
        record_csv(out / f"cost_growth_{name}.csv")
    wide = step.pivot_table(index="N_v", columns=["gamma", "method"], values="median_s")
    wide.columns = [f"gamma={g:g} {m} [s]" for g, m in wide.columns]
    text = (
        "# Cost growth\n\n"
        f"Measured {datetime.now(UTC):%Y-%m-%d %H:%M} UTC on {usable_cores()} cores, code {code}"
        f"{' (quick form)' if quick else ''}; threads: {thread_environment()}; 1-minute load {load0:.2f} "
        f"before, {os.getloadavg()[0]:.2f} after; medians of {reps} repeats.\n\n"
        "## One collision step against N_v (median of one solve; conic: re-solve, compile apart)\n\n"
        + wide.reset_index().to_markdown(index=False, floatfmt=".3g")
        + "\n\n"
        + step.to_markdown(index=False, floatfmt=".3g")
        + "\n\n## Batched against one-at-a-time Newton (gamma = 3, N_v = 121, B slices of inhom_gamma3_lambda4)\n\n"
        + batch.to_markdown(index=False, floatfmt=".3g")
        + "\n\n## One time step of inhom_gamma3_lambda4 (transport + refinement + collision)\n\n"
        + tstep.to_markdown(index=False, floatfmt=".3g")
        + "\n\n## Fitted exponents p (time ~ N^p over N >= 121; B, N_x, N_v >= 31 / 61 for the last rows)\n\n"
        + fits.to_markdown(index=False, floatfmt=".2f")
        + "\n"
    )
    write_markdown(out / "cost_growth.md", text)
    _plot(step, batch, tstep, out / "cost_growth.png")
    return {"step": step, "batch": batch, "time_step": tstep, "exponents": fits}


def _plot(step: pd.DataFrame, batch: pd.DataFrame, tstep: pd.DataFrame, path: Path) -> None:
    plt = pyplot()

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.3))
    ax = axes[0]
    for i, ((g, m), b) in enumerate(step.groupby(["gamma", "method"])):
        ax.loglog(b.N_v, b.median_s, "-o" if g == 1 else "--s", ms=3, color=f"C{i % 3}", label=f"gamma={g:g} {m}")
    ax.set_xlabel("N_v")
    ax.set_ylabel("seconds per collision step")
    ax.set_title("one collision step", fontsize=9)
    ax = axes[1]
    ax.loglog(batch.B, batch.batched_s, "-o", ms=3, label="batched Newton")
    ax.loglog(batch.B, batch.one_at_a_time_s, "-s", ms=3, label="one at a time")
    ax.set_xlabel("slices B (N_v = 121, gamma = 3)")
    ax.set_ylabel("seconds")
    ax.set_title("batched against one-at-a-time", fontsize=9)
    ax = axes[2]
    for axis, b in tstep.groupby("axis"):
        ax.loglog(b[axis], b.per_step_s, "-o", ms=3, label=f"per time step vs {axis}")
    ax.set_xlabel("N_x (N_v = 121) or N_v (N_x = 61)")
    ax.set_ylabel("seconds per time step")
    ax.set_title("inhom_gamma3_lambda4, one time step", fontsize=9)
    for ax in axes:
        ax.grid(True, which="both", alpha=0.2)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
