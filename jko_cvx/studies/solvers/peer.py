"""Accuracy per second: the JKO methods against a finite-volume peer, and the order in time.

``jko-cvx study work_precision_peer [--quick]`` writes ``work_precision_peer.{csv,md,png}`` and
``work_precision_peer_time_order.{csv,png}`` (tables in the one Markdown file).

Work-precision (``work_precision_peer.csv``, one row per run, a ``method`` column).  Three
homogeneous cases with exact solutions (:mod:`jko_cvx.exact`):

* ``smooth gamma=1``: :math:`f_0 = e^{-2(v - 0.1)^2}` on [-3, 3] to t = 0.25 (:math:`T_b = 0.5`);
* ``smooth gamma=2``: the same datum to t = 0.5 (linear contraction);
* ``blow-up gamma=1``: :math:`f_0 = e^{-2v^2}` on [-2, 2] to t = 0.475 = 0.95 T (max f = 20).

Methods: ``peer`` (:func:`jko_cvx.finite_volume.evolve_finite_volume`, uniform cells, N swept);
``newton`` / ``sqp`` / ``conic`` (:func:`jko_cvx.evolve.evolve_fixed_grid` on a uniform grid,
first order in time, N x dt swept, no Fisher term, Newton at tol 1e-8 -- the engine's
acceptance level); ``newton:order2`` (``time_order=2``); ``newton+refine`` (the study engine,
:func:`jko_cvx.engine.loop.simulate`, on a homogeneous scene with the paper's mesh refinement
remeshed every step and the default scene's log-Fisher weight beta = 1000, blow-up case only).
Errors against the exact solution: relative L1 against exact cell averages (``l1_cells``: the
peer's cells, the JKO grid's dual cells of widths h -- the same footing for every method), relative
L1 in each method's own representation (``l1``: point values with the trapezoidal weights for the
JKO grids, as in ``work_precision_run``) and W2 through quantile functions (DESIGN.md
"Benchmark conventions"): each numerical density as piecewise constant on its cells (the
peer's cells; the JKO grid's dual cells of widths h), both normalised to mass 1,
:math:`W_2^2 = \\int_0^1 |Q(s) - Q_{exact}(s)|^2 ds` by the midpoint rule on 20000 levels; the
exact quantile is closed-form in the initial one (Burgers characteristics for gamma = 1, the
contraction for gamma = 2).  Time: median wall time of whole runs, one BLAS thread
(``threadpoolctl``), runs one after the other.  A run with an uncertified step is no point
of the diagram (listed as failed).

Order in time (``work_precision_peer_time_order.csv``): Newton at first order, second order
(Richardson, :mod:`jko_cvx.time_order`) and the implicit-midpoint shortcut
:math:`2S(\\Delta t/2)f - f` (limited and mass-restored like Richardson), dt halved from 0.125:
against the exact solutions (gamma = 1, 2; N = 961, 481 in the quick form) and by self-convergence (gamma = 3/2,
N = 241; gamma = 3, N = 121, beta = 100), with the cost of each order at equal error.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from jko_cvx.collision import CollisionProblem, CollisionResult, solve_collision
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.evolve import evolve_fixed_grid
from jko_cvx.exact import GaussianMixture, exact_gamma1, exact_gamma2
from jko_cvx.finite_volume import Cells, evolve_finite_volume
from jko_cvx.grid import Grid
from jko_cvx.kernels import PowerKernel
from jko_cvx.mesh.moments import restore_moments
from jko_cvx.studies.solvers.cost import median_time
from jko_cvx.studies.solvers.figures import finish_figure, pareto_front, pyplot

__all__ = ["CASES", "Case", "errors", "work_precision_peer"]

_LEVELS = 20000  # quantile levels of the W2 midpoint rule
_NEWTON_TOL = 1e-8  # the study engine's acceptance level (simulate.py)


@dataclass(frozen=True)
class Case:
    """A homogeneous problem with an exact solution: kernel exponent, datum, final time."""

    label: str
    gamma: float
    f0: GaussianMixture
    t_end: float

    @property
    def lo(self) -> float:
        return self.f0.lo

    @property
    def hi(self) -> float:
        return self.f0.hi

    def exact(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        return (exact_gamma1 if self.gamma == 1.0 else exact_gamma2)(self.f0, self.t_end, v)


_SMOOTH = GaussianMixture([1.0], [2.0], [0.1], -3.0, 3.0)
CASES = {
    "smooth_g1": Case("smooth gamma=1", 1.0, _SMOOTH, 0.25),
    "smooth_g2": Case("smooth gamma=2", 2.0, _SMOOTH, 0.5),
    "blowup_g1": Case("blow-up gamma=1 (0.95 T)", 1.0, GaussianMixture([1.0], [2.0], [0.0], -2.0, 2.0), 0.475),
}


def _initial_quantile(f0: GaussianMixture, m: NDArray[np.float64]) -> NDArray[np.float64]:
    """:math:`F_0^{-1}(m)` by bisection (F_0 increasing on [lo, hi])."""
    a, b = np.full_like(m, f0.lo), np.full_like(m, f0.hi)
    for _ in range(60):
        mid = 0.5 * (a + b)
        below = f0.cdf(mid) < m
        a, b = np.where(below, mid, a), np.where(below, b, mid)
    return 0.5 * (a + b)


@cache
def _exact_quantile(key: str) -> NDArray[np.float64]:
    """Exact quantile at the midpoint levels, normalised mass: Q(s) = char(F_0^{-1}(s M))."""
    case = CASES[key]
    s = (np.arange(_LEVELS) + 0.5) / _LEVELS
    mass = case.f0.mass
    v0 = _initial_quantile(case.f0, s * mass)
    if case.gamma == 1.0:  # v = v0 + (M - 2 F0(v0)) t along the characteristics
        return v0 + (mass - 2 * s * mass) * case.t_end
    vbar = case.f0.moment1() / mass
    return vbar + (v0 - vbar) * np.exp(-mass * case.t_end)


def _quantile(edges: NDArray[np.float64], masses: NDArray[np.float64]) -> NDArray[np.float64]:
    """Quantile of the piecewise-constant density with these cell masses, at the midpoint levels."""
    cdf = np.concatenate([[0.0], np.cumsum(np.maximum(masses, 0.0))])
    cdf /= cdf[-1]
    s = (np.arange(_LEVELS) + 0.5) / _LEVELS
    return np.interp(s, cdf, edges)


def _exact_cdf(case: Case, v: NDArray[np.float64]) -> NDArray[np.float64]:
    """:math:`F(t, v) = \\int_{lo}^v f(t, w) dw`: :math:`F_0` at the foot of the characteristic through v."""
    f0, t, mass = case.f0, case.t_end, case.f0.mass
    if case.gamma == 2.0:
        vbar = f0.moment1() / mass
        return f0.cdf(vbar + (v - vbar) * np.exp(mass * t))
    a, b = np.full_like(v, f0.lo), np.full_like(v, f0.hi)
    for _ in range(100):  # v = v0 + (M - 2 F0(v0)) t is increasing in v0 before blow-up
        mid = 0.5 * (a + b)
        below = mid + (mass - 2 * f0.cdf(mid)) * t < v
        a, b = np.where(below, mid, a), np.where(below, b, mid)
    return f0.cdf(0.5 * (a + b))


def _cell_averages(case: Case, edges: NDArray[np.float64]) -> NDArray[np.float64]:
    """Exact cell averages from the exact cumulative mass (exact also for the sharp peak near blow-up)."""
    return np.diff(_exact_cdf(case, edges)) / np.diff(edges)


def errors(key: str, kind: str, points: NDArray[np.float64], values: NDArray[np.float64]) -> dict[str, float]:
    """Relative L1 and W2 errors of a numerical density against the exact solution of case ``key``.

    ``kind = "cells"``: ``points`` are the N + 1 cell edges, ``values`` the cell averages;
    ``kind = "grid"``: ``points`` are grid points (trapezoidal weights), ``values`` the point values,
    read as averages over the dual cells (edges at the midpoints, widths h) for ``l1_cells`` and W2.

    Returns ``l1`` (each method in its own representation: point values for a grid, as in
    ``work_precision_run``; cell averages for cells), ``l1_cells`` (cell averages for both: the
    same footing) and ``w2``.
    """
    case = CASES[key]
    if kind == "cells":
        edges = points
    else:
        edges = np.concatenate([[points[0]], (points[:-1] + points[1:]) / 2, [points[-1]]])
    widths = np.diff(edges)
    l1_cells = float(np.sum(widths * np.abs(values - _cell_averages(case, edges))) / case.f0.mass)
    if kind == "cells":
        l1 = l1_cells
    else:
        l1 = float(np.sum(Grid(points).h * np.abs(values - case.exact(points))) / case.f0.mass)
    w2 = float(np.sqrt(np.mean((_quantile(edges, values * widths) - _exact_quantile(key)) ** 2)))
    return {"l1": l1, "l1_cells": l1_cells, "w2": w2}


def _peer_point(key: str, n: int, repeats: int) -> dict[str, Any]:
    case = CASES[key]
    cells = Cells(case.lo, case.hi, n)
    f0 = cells.averages(case.f0.cdf)
    secs, run = median_time(lambda: evolve_finite_volume(cells, PowerKernel(case.gamma), f0, case.t_end), repeats)
    return {"n": n, "dt": np.nan, "steps": run.steps, "seconds": secs, **errors(key, "cells", cells.edges, run.f)}


_JKO_OPTIONS = {
    "newton": {"tol": _NEWTON_TOL},
    "sqp": {"max_iter": 2000, "kkt_tol": 1e-6},  # as in work_precision_run
    "conic": {"kkt_tol": 1e-6},
}


def _jko_point(key: str, method: str, order: int, n: int, dt: float, repeats: int, beta: float) -> dict[str, Any]:
    case = CASES[key]
    grid = Grid.uniform(case.lo, case.hi, n)

    def go():
        return evolve_fixed_grid(
            grid, PowerKernel(case.gamma), case.f0.pdf(grid.points), dt, case.t_end,
            beta=beta, method=method, time_order=order, **_JKO_OPTIONS[method],
        )  # fmt: skip

    secs, run = median_time(go, repeats)
    row = {"n": n, "dt": dt, "steps": len(run.results), "seconds": secs}
    if not run.completed:
        return {**row, "l1": np.nan, "l1_cells": np.nan, "w2": np.nan, "failed": run.statuses[-1]}
    return {**row, **errors(key, "grid", grid.points, run.f[-1])}


def _refine_point(key: str, n: int, dt: float, repeats: int) -> dict[str, Any]:
    """The study engine with mesh refinement (homogeneous scene, as the default scene but to 0.95 T)."""
    from jko_cvx.engine.loop import simulate
    from jko_cvx.scene.model import scene_from_dict

    case = CASES[key]
    f0 = case.f0
    scene = scene_from_dict(
        {
            "name": "peer_refine",
            "gamma": case.gamma,
            "t_end": case.t_end,
            "v": {"L": case.hi, "n": n},
            "initial": {"kind": "gaussians", "amplitudes": list(f0.amplitudes), "rates": list(f0.rates),
                        "centres": list(f0.centres)},
            "time": {"policy": "fixed", "dt": dt},
            "refine": {"v": {"bumps": 1, "delta0": 0.5, "delta": 0.5}},
            "collision": {"method": "newton", "beta": 1000.0, "fisher": "log"},
            "stop": {"eps_v": 0.0, "on_solver_failure": True},
            "output": {"every": 10**9, "checkpoint_every": 10**9},
        }
    )  # fmt: skip
    secs, run = median_time(lambda: simulate(scene), repeats)
    row = {"n": n, "dt": dt, "steps": len(run.diagnostics) - 1, "seconds": secs}
    if run.blowup or run.t < case.t_end * (1 - 1e-12):
        return {**row, "l1": np.nan, "l1_cells": np.nan, "w2": np.nan, "failed": run.verdict["reason"]}
    return {**row, **errors(key, "grid", run.vgrid.points, run.f)}


def _plan(quick: bool) -> list[dict[str, Any]]:
    """Every run of the work-precision study: (case, method, order, n, dt)."""
    plan: list[dict[str, Any]] = []
    keys = ("smooth_g1", "blowup_g1") if quick else tuple(CASES)
    peer_ns = (100, 400, 1600) if quick else (100, 200, 400, 800, 1600, 3200)
    ns = (121, 241) if quick else (61, 121, 241, 481)
    dts = (0.05, 0.0125) if quick else (0.05, 0.025, 0.0125, 0.00625)
    for key in keys:
        plan += [{"case": key, "method": "peer", "order": 2, "n": n, "dt": np.nan} for n in peer_ns]
        for n in ns:
            for dt in dts:
                plan.append({"case": key, "method": "newton", "order": 1, "n": n, "dt": dt})
                plan.append({"case": key, "method": "newton:order2", "order": 2, "n": n, "dt": dt})
        if not quick and key == "smooth_g1":  # the slower families on one case, a coarser sweep
            # the paper's SQP fails on the vacuum tails without a Fisher term: also at beta = 30
            for method in ("sqp", "sqp (beta=30)", "conic"):
                plan += [
                    {"case": key, "method": method, "order": 1, "n": n, "dt": dt} for n in (61, 121) for dt in dts[:3]
                ]
        if key == "blowup_g1":
            for n in ns:
                plan += [{"case": key, "method": "newton+refine", "order": 1, "n": n, "dt": dt} for dt in dts]
    return plan


def _run(point: dict[str, Any], repeats: int) -> dict[str, Any]:
    key, method, n, dt = point["case"], point["method"], point["n"], point["dt"]
    if method == "peer":
        out = _peer_point(key, n, max(repeats, 3))
    elif method == "newton+refine":
        out = _refine_point(key, n, dt, repeats)
    else:
        beta = 30.0 if "beta=30" in method else np.inf
        out = _jko_point(key, method.split(":")[0].split(" ")[0], point["order"], n, dt, repeats, beta)
    return {"case": key, "panel": CASES[key].label, "method": method, "order": point["order"], "failed": "", **out}


# --- order in time ------------------------------------------------------------------------

_KAPPA = 0.5  # the limiter of jko_cvx.time_order, applied to the midpoint shortcut as well


def _midpoint_run(
    grid: Grid, kernel: PowerKernel, f0: NDArray[np.float64], dt: float, t_end: float, beta: float
) -> tuple[NDArray[np.float64], list[CollisionResult]]:
    """The implicit-midpoint shortcut :math:`2 S(\\Delta t/2) f - f` (one solve per step), limited, mass restored."""
    f, t, results = f0.copy(), 0.0, []
    while t < t_end * (1 - 1e-12):
        h = min(dt, t_end - t)
        res = solve_collision(CollisionProblem(grid, kernel, f, h / 2, beta=beta), "newton", tol=_NEWTON_TOL)
        results.append(res)
        g = np.maximum(2 * res.f - f, _KAPPA * res.f)
        f, _ = restore_moments(g, grid.h, grid.points, grid.mass(f))
        t += h
    return f, results


@dataclass(frozen=True)
class _OrderCase:
    label: str
    gamma: float
    n: int
    beta: float
    exact: str | None  # key of CASES, or None: self-convergence against the finest order-2 run


def _order_cases(quick: bool) -> list[_OrderCase]:
    cases = [
        _OrderCase("exact gamma=2", 2.0, 481 if quick else 961, np.inf, "smooth_g2"),
        _OrderCase("self gamma=3/2", 1.5, 241, np.inf, None),
    ]
    if not quick:
        cases.insert(0, _OrderCase("exact gamma=1", 1.0, 961, np.inf, "smooth_g1"))
        # gamma = 3 at beta = inf: Newton stalls above tol on the vacuum tails at every dt
        # (pre-existing; MAX_ITERATIONS on 4-57 of the steps at N = 121); beta = 100 converges.
        cases.append(_OrderCase("self gamma=3", 3.0, 121, 100.0, None))
    return cases


def _order_rows(quick: bool) -> list[dict[str, Any]]:
    dts = (0.125, 0.0625, 0.03125) if quick else (0.125, 0.0625, 0.03125, 0.015625, 0.0078125)
    rows = []
    for oc in _order_cases(quick):
        base = CASES[oc.exact] if oc.exact else CASES["smooth_g1"]
        grid = Grid.uniform(base.lo, base.hi, oc.n)
        f0, t_end, kernel = base.f0.pdf(grid.points), (base.t_end if oc.exact else 0.32), PowerKernel(oc.gamma)
        finals: dict[tuple[str, float], NDArray[np.float64] | None] = {}
        for scheme in ("order1", "order2", "midpoint"):
            for dt in dts:
                t0 = time.perf_counter()
                if scheme == "midpoint":
                    f, results = _midpoint_run(grid, kernel, f0, dt, t_end, oc.beta)
                else:
                    run = evolve_fixed_grid(
                        grid, kernel, f0, dt, t_end, beta=oc.beta, time_order=int(scheme[-1]), tol=_NEWTON_TOL,
                        stop_on_failure=False,
                    )  # fmt: skip
                    f, results = run.f[-1], run.results
                secs = time.perf_counter() - t0
                finals[scheme, dt] = f
                rows.append(
                    {
                        "case": oc.label, "scheme": scheme, "n": oc.n, "beta": oc.beta, "dt": dt, "seconds": secs,
                        "failed_steps": sum(not np.all(r.success) for r in results),
                        "max_kkt": max(float(np.max(r.kkt_residual)) for r in results),
                    }
                )  # fmt: skip
        reference = base.exact(grid.points) if oc.exact else finals["order2", dts[-1]]
        for row in rows[-3 * len(dts) :]:
            f = finals[row["scheme"], row["dt"]]
            row["error"] = np.nan if f is None else float(grid.h @ np.abs(f - reference) / grid.mass(reference))
            nxt = finals.get((row["scheme"], row["dt"] / 2))
            row["diff_to_half_dt"] = np.nan if f is None or nxt is None else float(grid.h @ np.abs(f - nxt))
            row["reference"] = "exact" if oc.exact else f"order2 at dt={dts[-1]:g}"
    return rows


def _slope(x: pd.Series, y: pd.Series) -> float:
    """Fitted log-log slope (NaN with fewer than two points)."""
    return float(np.polyfit(np.log(x), np.log(y), 1)[0]) if len(x) > 1 else np.nan


def _order_table(df: pd.DataFrame) -> pd.DataFrame:
    """Per case and scheme: fitted orders (against the reference, and from successive differences)."""
    out = []
    for (case, scheme), b in df.groupby(["case", "scheme"], sort=False):
        b = b.sort_values("dt")
        ok = b[np.isfinite(b.error) & (b.error > 0)]
        if ok.reference.iloc[0] != "exact":  # the finest order-2 run is the reference itself
            ok = ok[~((ok.scheme == "order2") & (ok["dt"] == b["dt"].min()))]
        d = b[np.isfinite(b.diff_to_half_dt)]
        row = {"case": case, "scheme": scheme}
        row["order_vs_reference"] = _slope(ok["dt"], ok.error)
        row["order_self"] = _slope(d["dt"], d.diff_to_half_dt)
        dd = d.sort_values("dt", ascending=False).diff_to_half_dt.to_numpy()
        row["self_orders_by_dt"] = ", ".join(f"{np.log2(dd[i] / dd[i + 1]):.2f}" for i in range(len(dd) - 1))
        out.append(row)
    return pd.DataFrame(out)


def _equal_error_cost(df: pd.DataFrame) -> pd.DataFrame:
    """Seconds of the cheapest order-1 and order-2 run reaching the best order-1 error of each case."""
    out = []
    for case, b in df.groupby("case", sort=False):
        o1 = b[(b.scheme == "order1") & np.isfinite(b.error)]
        o2 = b[(b.scheme == "order2") & np.isfinite(b.error) & (b.error > 0)]
        if not len(o1):
            continue
        target = float(o1.error.min())
        hit1 = o1[o1.error <= target].seconds.min()
        hit2 = o2[o2.error <= target]
        row = {"case": case, "target_error": target, "order1_s": hit1, "order2_s": np.nan, "speed-up": np.nan}
        if len(hit2):
            best = hit2.loc[hit2.seconds.idxmin()]
            row.update({"order2_s": best.seconds, "order2_dt": best["dt"], "speed-up": hit1 / best.seconds})
        out.append(row)
    return pd.DataFrame(out)


# --- the study ----------------------------------------------------------------------------

_TARGETS = {"l1": (1e-2, 1e-3, 1e-4), "l1_cells": (1e-2, 1e-3, 1e-4), "w2": (1e-3, 1e-4, 1e-5)}


def _front(df: pd.DataFrame, metric: str) -> pd.DataFrame:
    """Per case, method and target: the cheapest run reaching it (measured, not interpolated)."""
    rows = []
    for (panel, method), b in df.groupby(["panel", "method"], sort=False):
        for target in _TARGETS[metric]:
            hit = b[b[metric] <= target]
            row = {
                "case": panel,
                "method": method,
                "target": target,
                "seconds": np.nan,
                metric: np.nan,
                "at": "not reached",
            }
            if len(hit):
                best = hit.loc[hit.seconds.idxmin()]
                at = f"N={int(best.n)}" + ("" if np.isnan(best["dt"]) else f", dt={best['dt']:g}")
                row.update({"seconds": best.seconds, metric: best[metric], "at": at})
            rows.append(row)
    return pd.DataFrame(rows)


def _plot_wp(df: pd.DataFrame, path: Path) -> None:
    plt = pyplot()
    panels = list(dict.fromkeys(df.panel))
    fig, axes = plt.subplots(2, len(panels), figsize=(5.2 * len(panels), 8), squeeze=False)
    methods = list(dict.fromkeys(df.method))
    for col, p in enumerate(panels):
        for row, metric in enumerate(("l1_cells", "w2")):
            ax = axes[row, col]
            for i, m in enumerate(methods):
                b = df[(df.panel == p) & (df.method == m) & np.isfinite(df[metric])]
                if not len(b):
                    continue
                t, e = b.seconds.to_numpy(float), np.maximum(b[metric].to_numpy(float), 1e-16)
                ax.loglog(t, e, "o", color=f"C{i}", alpha=0.3, ms=4)
                ft, fe = pareto_front(t, e)
                ax.loglog(ft, fe, "-o", color=f"C{i}", ms=3, label=m)
            ax.set_xlabel("wall time per run [s] (median, 1 BLAS thread)")
            ax.set_ylabel("relative L1 error vs exact cell averages" if metric == "l1_cells" else "W2 error vs exact")
            ax.set_title(p, fontsize=9)
    finish_figure(fig, axes.ravel(), path)


def _plot_order(df: pd.DataFrame, path: Path) -> None:
    plt = pyplot()
    cases = list(dict.fromkeys(df.case))
    fig, axes = plt.subplots(1, len(cases), figsize=(4.6 * len(cases), 4), squeeze=False)
    for ax, c in zip(axes[0], cases, strict=True):
        for i, scheme in enumerate(("order1", "order2", "midpoint")):
            b = df[(df.case == c) & (df.scheme == scheme) & np.isfinite(df.error) & (df.error > 0)]
            ax.loglog(b["dt"], b.error, "-o", ms=3, color=f"C{i}", label=scheme)
        dts = np.sort(df[df.case == c]["dt"].unique())
        ax.loglog(dts, 0.5 * dts, "k:", lw=1, label="slope 1")
        ax.loglog(dts, 0.5 * dts**2, "k--", lw=1, label="slope 2")
        ax.set_xlabel("dt")
        ax.set_ylabel("relative L1 error vs reference")
        ax.set_title(c, fontsize=9)
    finish_figure(fig, axes[0], path)


def work_precision_peer(out: Path, quick: bool = False, repeats: int | None = None, **_sweep_opts: Any) -> pd.DataFrame:
    """Run the study (module docstring); writes work_precision_peer.{csv,md,png} and _time_order.{csv,png}."""
    from threadpoolctl import threadpool_limits

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    repeats = repeats if repeats is not None else (1 if quick else 3)
    name = "work_precision_peer"
    with threadpool_limits(1):
        df = pd.DataFrame([_run(p, repeats) for p in _plan(quick)])
        order = pd.DataFrame(_order_rows(quick))
    df.to_csv(out / f"{name}.csv", index=False)
    record_csv(out / f"{name}.csv")
    order.to_csv(out / f"{name}_time_order.csv", index=False)
    record_csv(out / f"{name}_time_order.csv")
    ok = df[np.isfinite(df.l1)]
    _plot_wp(ok, out / f"{name}.png")
    _plot_order(order, out / f"{name}_time_order.png")
    failed = df[~np.isfinite(df.l1)]
    fmt = {"index": False, "floatfmt": ".3g"}
    text = "\n".join(
        [
            "# Accuracy per second: JKO methods against the finite-volume peer",
            "",
            f"{'Quick form. ' if quick else ''}Median wall time of {repeats} run(s) (the peer: at least 3), one BLAS",
            "thread (threadpoolctl), runs one after the other.  Errors against the exact solutions: relative L1",
            "against exact cell averages (`l1_cells`; JKO densities read as averages over the dual cells of",
            "widths h), in each method's own representation (`l1`) and W2 via quantile functions.",
            "Cases: `smooth gamma=1` f0 = exp(-2 (v - 0.1)^2) on [-3, 3] to t = 0.25 (T_b = 0.5); `smooth",
            "gamma=2` the same to t = 0.5; `blow-up gamma=1` f0 = exp(-2 v^2) on [-2, 2] to t = 0.475 = 0.95 T",
            "(max f = 20).  JKO: no Fisher term, Newton tol 1e-8; `newton+refine`: the study engine with the",
            "paper's mesh refinement (remesh every step, log-Fisher beta = 1000 as in the default scene).",
            "Module docstring: jko_cvx/studies/solvers/peer.py.  Figure: work_precision_peer.png.",
            "",
            "## Cheapest run reaching each L1 error (cell averages, the same footing for every method)",
            "",
            _front(ok, "l1_cells").to_markdown(**fmt),
            "",
            "## Cheapest run reaching each W2 error",
            "",
            _front(ok, "w2").to_markdown(**fmt),
            "",
            "## Cheapest run reaching each L1 error in the method's own representation",
            "",
            "JKO: point values at the grid points against the exact point values (as in work_precision_run);",
            "near blow-up this is far larger than `l1_cells` (the peak's curvature times h^2).",
            "",
            _front(ok, "l1").to_markdown(**fmt),
            "",
            "## Order in time (Newton; figure work_precision_peer_time_order.png)",
            "",
            "`order_vs_reference`: fitted log-log slope of the L1 error against dt (reference: the exact",
            "solution, or the order-2 run at the finest dt for self-convergence, which is then left out of",
            "its own fit); `order_self`: slope of |f_dt - f_dt/2|; `self_orders_by_dt`: log2 of successive",
            "ratios, coarse to fine.  `midpoint` is 2 S(dt/2) f - f (one solve per step).  Runs carry on",
            "through steps that stop short of Newton's tol 1e-8 (`failed_steps`, with the largest KKT",
            "residual of the run in `max_kkt`; a residual of 1e-7 is far below these errors).",
            "",
            _order_table(order).to_markdown(**fmt),
            "",
            "### Cost at equal error (the best order-1 error of each case)",
            "",
            _equal_error_cost(order).to_markdown(**fmt),
            "",
            "### Every time-order run",
            "",
            order.to_markdown(**fmt),
            "",
            "## Runs that failed (uncertified step, or the engine stopped)",
            "",
            failed[["panel", "method", "n", "dt", "failed", "seconds"]].to_markdown(**fmt) if len(failed) else "none",
            "",
            "## Every run",
            "",
            df.drop(columns=["case"]).to_markdown(**fmt),
            "",
        ]
    )
    write_markdown(out / f"{name}.md", text)
    return df
