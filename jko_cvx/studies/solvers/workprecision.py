"""Work-precision diagrams: error against wall time, one curve per solver family.

Two settings (DiffEqDevTools-style work-precision, DESIGN.md "Benchmark conventions"):

1. :func:`work_precision_step` -- one collision step (gamma = 1 and gamma = 3), every
   family over a sweep of its tolerance; error = max-norm error in f, relative to max f,
   against the high-accuracy reference of :func:`jko_cvx.studies.compare.compare_solvers`
   (Newton at tol 1e-13).  Time = median over repeats of one solve.
2. :func:`work_precision_run` -- a whole homogeneous run on a fixed uniform grid of
   [-3, 3] from :math:`f_0 = e^{-2(v - 0.1)^2}` to a time before blow-up; error = relative
   L1 error of the final density against the exact solution (gamma = 1: Burgers
   characteristics to t = 0.25, T_b = 0.5; gamma = 2: the linear contraction to t = 0.5;
   :mod:`jko_cvx.exact`).  Three sweeps, each point one cached run:

   * ``front``: every family, dt in {0.04, ..., 0.0025} x N in {61, 121, 241}, beta = 300;
   * ``tolerance``: every family, N = 241, dt = 0.005, beta = 300, the solver tolerance
     from 1e-2 to 1e-10;
   * ``bias``: Newton, N = 241, dt x beta in {1, 3, 10, 30, 100, 300, inf}: where the
     Fisher regularisation's bias dominates (the error stops falling with dt) and where
     the time discretisation does (error ~ dt).

   A run stops at its first uncertified step (``failed_step``; no error is reported for
   it): a failed run is not a point of the diagram.

Timings are taken one run at a time (``executor="serial"`` by default) so that runs do not
share the two cores; pass another executor for speed when timings do not matter.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.collision import CollisionProblem, conic_solvers
from jko_cvx.collision.nlp import nlp_available
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.evolve import evolve_fixed_grid
from jko_cvx.exact import GaussianMixture, exact_gamma1, exact_gamma2
from jko_cvx.grid import Grid
from jko_cvx.kernels import PowerKernel
from jko_cvx.studies.compare import Configuration, compare_solvers
from jko_cvx.studies.solvers.figures import finish_figure, pareto_front, pyplot
from jko_cvx.studies.sweep import run_sweep

__all__ = ["run_point", "work_precision_run", "work_precision_step"]

# Tolerance sweeps per family for one step.  SCS (first order) is bounded at 1e-7: at
# 1e-8 and beyond it needs minutes (measured 27 s at 1e-10 on N = 121).
_STEP_TOLS: dict[str, tuple[str, str, tuple[float, ...]]] = {
    "newton": ("newton", "tol", (1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12)),
    "sqp:banded": ("sqp", "tol", (1e-3, 1e-5, 1e-7, 1e-9, 1e-11, 1e-13)),
    "sqp:osqp": ("sqp", "osqp_eps", (1e-4, 1e-6, 1e-8, 1e-10)),
    "conic:CLARABEL": ("conic", "tol", (1e-4, 1e-6, 1e-8, 1e-10)),
    "conic:SCS": ("conic", "tol", (1e-3, 1e-4, 1e-5, 1e-6, 1e-7)),
    "nlp:IPOPT": ("nlp", "tol", (1e-4, 1e-6, 1e-8, 1e-10)),
}


def step_problems() -> dict[str, CollisionProblem]:
    """The two steps of the single-step diagram: gamma = 1 and gamma = 3, N = 121, dt = 0.01, beta = 10."""
    grid = Grid.uniform(-2.0, 2.0, 121)
    f0 = np.exp(-2 * grid.points**2)
    return {
        f"gamma={g:g}": CollisionProblem(grid, PowerKernel(g), f0, 0.01, beta=10.0, fisher="perspective")
        for g in (1.0, 3.0)
    }


def _step_configurations(quick: bool) -> list[Configuration]:
    installed = set(conic_solvers())
    out = []
    for family, (method, key, tols) in _STEP_TOLS.items():
        if method == "conic" and family.split(":")[1] not in installed:
            continue
        if method == "nlp" and not nlp_available():
            continue
        for tol in tols[::2] if quick else tols:
            opts: dict[str, Any] = {key: tol}
            if method == "conic":
                opts["solver"] = family.split(":")[1]
            if family == "sqp:osqp":
                opts["qp"] = "osqp"
            out.append(Configuration(family, method, f"{key}={tol:g}", opts))
    return out


def work_precision_step(out: Path, quick: bool = False, repeats: int = 5, **_sweep_opts: Any) -> pd.DataFrame:
    """Setting 1 (see the module docstring); writes ``work_precision_step.{csv,md,png}``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    frames = []
    for label, problem in step_problems().items():
        df = compare_solvers(problem, _step_configurations(quick), repeats=2 if quick else repeats)
        df.insert(0, "problem", label)
        frames.append(df)
    df = pd.concat(frames, ignore_index=True)
    cols = ["problem", "family", "setting", "status", "certified", "median_s", "iterations", "kkt", "f_error"]
    df[cols].to_csv(out / "work_precision_step.csv", index=False)
    record_csv(out / "work_precision_step.csv")
    _plot(df, "problem", "median_s", "f_error", out / "work_precision_step.png", "one collision step",
          "Newton at tol 1e-13 (compare_solvers' reference)")  # fmt: skip
    fronts = _front_table(df, "problem", "median_s", "f_error", targets=(1e-4, 1e-6, 1e-8))
    text = (
        "# Work-precision, one collision step\n\n"
        "N = 121 on [-2, 2], f* = exp(-2 v^2), dt = 0.01, perspective Fisher, beta = 10.  Error: max-norm\n"
        "error in f relative to max f against Newton at tol 1e-13; time: median of one solve.  A setting is\n"
        "`certified` when it reports success and its KKT residual, recomputed, is at most 1e-6; the\n"
        "figure shows the others hollow (their error is measured all the same).\n\n"
        "## Cheapest setting reaching each error\n\n"
        + fronts.to_markdown(index=False, floatfmt=".3g")
        + "\n\n## Every setting\n\n"
        + df[cols].to_markdown(index=False, floatfmt=".3g")
        + "\n"
    )
    write_markdown(out / "work_precision_step.md", text)
    return df


_F0 = GaussianMixture([1.0], [2.0], [0.1], -3.0, 3.0)  # off-centre: the mean velocity is not 0
_T_END = {1.0: 0.25, 2.0: 0.5}
# Solver options of each family in the whole-run study; "tol" is swept.  The paper's SQP
# with I_max = 2000 (its default 20000 spends minutes on each failing step).
_RUN_FAMILIES = {"newton": ("newton", {}), "sqp": ("sqp", {"max_iter": 2000}), "conic": ("conic", {})}


def run_point(family: str, gamma: float, n: int, dt: float, beta: float, tol: float) -> dict[str, Any]:
    """One whole run (see the module docstring): relative L1 error against the exact solution."""
    method, opts = _RUN_FAMILIES[family]
    if method != "newton":  # Newton certifies at tol itself
        opts = {**opts, "kkt_tol": max(tol, 1e-6)}
    grid = Grid.uniform(-3.0, 3.0, n)
    t_end = _T_END[gamma]
    t0 = time.perf_counter()
    run = evolve_fixed_grid(
        grid,
        PowerKernel(gamma),
        _F0.pdf(grid.points),
        dt,
        t_end,
        beta=beta,
        fisher="perspective",
        method=method,
        stop_on_failure=True,
        tol=tol,
        **opts,
    )
    seconds = time.perf_counter() - t0
    failed = [i for i, r in enumerate(run.results) if not r.success]
    if failed:
        return {"error": np.nan, "seconds": seconds, "steps": len(run.results), "failed_step": failed[0]}
    exact = (exact_gamma1 if gamma == 1.0 else exact_gamma2)(_F0, t_end, grid.points)
    err = float(np.sum(grid.h * np.abs(run.f[-1] - exact)) / np.sum(grid.h * exact))
    return {"error": err, "seconds": seconds, "steps": len(run.results), "failed_step": -1}


def _run_points(quick: bool) -> list[dict[str, Any]]:
    gammas = (1.0,) if quick else (1.0, 2.0)
    dts = (0.04, 0.01) if quick else (0.04, 0.02, 0.01, 0.005, 0.0025)
    ns = (121,) if quick else (61, 121, 241)
    n_fine = 121 if quick else 241
    tols = (1e-4, 1e-8) if quick else (1e-2, 1e-4, 1e-6, 1e-8, 1e-10)
    betas = (3.0, np.inf) if quick else (1.0, 3.0, 10.0, 30.0, 100.0, 300.0, np.inf)
    families = ("newton", "sqp") if quick else tuple(_RUN_FAMILIES)
    points: list[dict[str, Any]] = []

    def add(sweep: str, **p: Any) -> None:
        points.append({"sweep": sweep, **p})

    for g in gammas:
        for fam in families:
            for n in ns:
                for dt in dts:
                    add("front", family=fam, gamma=g, n=n, dt=dt, beta=30.0, tol=1e-8)
            for tol in tols:
                add("tolerance", family=fam, gamma=g, n=n_fine, dt=0.005 if not quick else 0.01, beta=30.0, tol=tol)
        for beta in betas:
            for dt in dts:
                add("bias", family="newton", gamma=g, n=n_fine, dt=dt, beta=beta, tol=1e-8)
    return points


def _run_point_swept(sweep: str, **point: Any) -> dict[str, Any]:
    return run_point(**point)


def work_precision_run(out: Path, quick: bool = False, **sweep_opts: Any) -> pd.DataFrame:
    """Setting 2 (see the module docstring); writes ``work_precision_run.{csv,md,png}`` and ``..._bias.png``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    sweep_opts.setdefault("executor", "serial")
    name = "work_precision_run"
    df = run_sweep(_run_point_swept, _run_points(quick), out / "cache" / name, desc=name, **sweep_opts)
    df.to_csv(out / f"{name}.csv", index=False)
    record_csv(out / f"{name}.csv")
    df["panel"] = [f"gamma={g:g}" for g in df.gamma]
    ok = df[np.isfinite(df.error)]
    _plot(ok[ok.sweep != "bias"], "panel", "seconds", "error", out / f"{name}.png", "whole run:",
          "the exact solution (gamma = 1: Burgers characteristics; gamma = 2: the linear contraction)")  # fmt: skip
    bias = _bias_table(df[df.sweep == "bias"])
    _plot_bias(df[df.sweep == "bias"], out / f"{name}_bias.png")
    failed = df[~np.isfinite(df.error)]
    fronts = _front_table(ok[ok.sweep != "bias"], "panel", "seconds", "error", targets=(3e-2, 1e-2, 3e-3))
    text = (
        "# Work-precision, whole homogeneous runs against the exact solution\n\n"
        "f0 = exp(-2 (v - 0.1)^2) on [-3, 3], uniform grid, perspective Fisher; gamma = 1 to t = 0.25\n"
        "(Burgers, T_b = 0.5), gamma = 2 to t = 0.5 (linear contraction).  Error: relative L1 error of\n"
        "the final density.  A run stops at its first uncertified step (listed below, no error).\n\n"
        "## Cheapest run reaching each error (sweeps `front` and `tolerance`)\n\n"
        + fronts.to_markdown(index=False, floatfmt=".3g")
        + "\n\n## Regularisation bias against time error (Newton, N = "
        + f"{int(df[df.sweep == 'bias'].n.max())}, tol 1e-8)\n\n"
        "`err(dt)` per beta; `dt_slope`: fitted log-log slope over dt (about 1 where the time error\n"
        "dominates, about 0 where the Fisher bias does); `bias_share`: error at the smallest dt over\n"
        "the error at the smallest dt without the Fisher term (beta = inf).\n\n"
        + bias.to_markdown(index=False, floatfmt=".3g")
        + "\n\n## Runs that failed (uncertified step)\n\n"
        + (
            failed[["sweep", "family", "gamma", "n", "dt", "beta", "tol", "failed_step", "seconds"]].to_markdown(
                index=False, floatfmt=".3g"
            )
            if len(failed)
            else "none"
        )
        + "\n\n## Every run\n\n"
        + df.drop(columns=["panel"]).to_markdown(index=False, floatfmt=".3g")
        + "\n"
    )
    write_markdown(out / f"{name}.md", text)
    return df


def _bias_table(df: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for (g, beta), b in df.groupby(["gamma", "beta"]):
        b = b.sort_values("dt")
        fin = b[np.isfinite(b.error)]
        row: dict[str, Any] = {"gamma": g, "beta": beta}
        for dt, e in zip(b["dt"], b.error, strict=True):
            row[f"err(dt={dt:g})"] = e
        row["dt_slope"] = float(np.polyfit(np.log(fin["dt"]), np.log(fin.error), 1)[0]) if len(fin) > 1 else np.nan
        rows.append(row)
    table = pd.DataFrame(rows)
    # how much the Fisher term adds to the error at the smallest dt, per gamma
    dt_min = df["dt"].min()
    base = df[(df.beta == np.inf) & (df["dt"] == dt_min)].set_index("gamma").error
    at_min = df[df["dt"] == dt_min].set_index(["gamma", "beta"]).error
    table["bias_share"] = [
        at_min.get((g, b), np.nan) / base.get(g, np.nan) for g, b in zip(table.gamma, table.beta, strict=True)
    ]
    return table


def _front_table(df: pd.DataFrame, panel: str, tcol: str, ecol: str, targets: tuple[float, ...]) -> pd.DataFrame:
    """For each panel, family and target error: the cheapest point reaching it (errors are measured, not claimed)."""
    rows = []
    for (p, fam), b in df.groupby([panel, "family"]):
        for target in targets:
            hit = b[b[ecol] <= target]
            row = {panel: p, "family": fam, "target": target, tcol: np.nan, ecol: np.nan, "at": "not reached"}
            if len(hit):
                best = hit.loc[hit[tcol].idxmin()]
                what = best["setting"] if "setting" in best else _describe(best)
                row.update({tcol: best[tcol], ecol: best[ecol], "at": what})
                if "certified" in best:
                    row["certified"] = bool(best["certified"])
            rows.append(row)
    return pd.DataFrame(rows)


def _describe(row: pd.Series) -> str:
    return f"N={int(row.n)}, dt={row['dt']:g}, tol={row.tol:g}"


def _plot(df: pd.DataFrame, panel: str, tcol: str, ecol: str, path: Path, title: str, reference: str):
    """Log-log error against time, one panel per ``panel`` value; returns the (saved, closed) figure.

    Every setting is a marker, filled when certified and hollow when not, and each family's Pareto
    front a line; the legend names each, and the title and error axis name ``reference``, the
    solution the errors are measured against.
    """
    plt = pyplot()
    panels = sorted(df[panel].unique())
    fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 4.6), squeeze=False)
    families = sorted(df.family.unique())
    for ax, p in zip(axes[0], panels, strict=True):
        block = df[df[panel] == p]
        for i, fam in enumerate(families):
            b = block[(block.family == fam) & np.isfinite(block[ecol])]
            if not len(b):
                continue
            t, e = b[tcol].to_numpy(float), np.maximum(b[ecol].to_numpy(float), 1e-16)
            cert = b["certified"].to_numpy(bool) if "certified" in b else np.ones(len(b), bool)
            if cert.any():
                ax.loglog(t[cert], e[cert], "o", color=f"C{i}", alpha=0.35, ms=4, label=f"{fam}: certified setting")
            if (~cert).any():
                ax.loglog(t[~cert], e[~cert], "o", mfc="none", color=f"C{i}", alpha=0.6, ms=5,
                          label=f"{fam}: not certified (hollow)")  # fmt: skip
            ft, fe = pareto_front(t, e)
            ax.loglog(ft, fe, "-o", color=f"C{i}", ms=3, label=f"{fam}: Pareto front")
        ax.set_xlabel("wall time per solve [s]" if tcol == "median_s" else "wall time per run [s]")
        what = "max-norm error in f / max f" if ecol == "f_error" else "relative L1 error"
        ax.set_ylabel(f"{what} against the reference", fontsize=8)
        ax.set_title(f"{title} {p}\nreference: {reference}", fontsize=8)
    finish_figure(fig, axes[0], path)
    return fig


def _plot_bias(df: pd.DataFrame, path: Path) -> None:
    plt = pyplot()
    gammas = sorted(df.gamma.unique())
    fig, axes = plt.subplots(1, len(gammas), figsize=(5.5 * len(gammas), 4.2), squeeze=False)
    for ax, g in zip(axes[0], gammas, strict=True):
        block = df[df.gamma == g]
        for i, beta in enumerate(sorted(block.beta.unique())):
            b = block[block.beta == beta].sort_values("dt")
            ax.loglog(b["dt"], b.error, "-o", ms=3, color=f"C{i}", label=f"beta={beta:g}")
        dts = np.array(sorted(block["dt"].unique()))
        ref = block[block.beta == np.inf].sort_values("dt").error.to_numpy()
        if len(ref) and np.isfinite(ref[-1]):
            ax.loglog(dts, ref[-1] * dts / dts[-1], "k:", lw=1, label="slope 1")
        ax.set_xlabel("dt")
        ax.set_ylabel("relative L1 error vs exact")
        ax.set_title(f"gamma={g:g}: Fisher bias vs time error (Newton, N={int(block.n.max())})", fontsize=9)
    finish_figure(fig, axes[0], path)
