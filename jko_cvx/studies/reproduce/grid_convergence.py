"""The grid-convergence study the paper lacks: ``jko-cvx reproduce grid_convergence``.

The paper answers "blow-up or not" on one grid per case.  This entry reruns two of its
inhomogeneous experiments on successively refined grids and asks whether the quantities
behind its conclusions converge:

``sec:sp_inhom_gamma_1p5`` (both parameter sets, :mod:`jko_cvx.studies.reproduce.gamma1p5`)
    on n x n grids, n = 121, 241, 481 per axis, each with the paper's maps (two-bump map in
    v, CFL steps of ``alg:SPMCSL-JKO``) and on a fixed uniform n x n grid (no maps: the
    map-free reference; the CFL rule then gives dt = 0.9 dv / L_v, so the step refines with
    the grid; ``v.floor_every_step`` keeps the 1e-10 floor of the remap the mapped runs do
    every step).  Every mapped and uniform run stops at the first of: the paper's criterion min dv < eps_v
    (T_b), the density criterion sigma_v < :data:`~jko_cvx.studies.reproduce.gamma1p5.COLLAPSE_SPREAD`
    (``stop.spread_v``; sigma_v is the smallest local velocity spread over slices with
    rho >= 0.1 max rho) and t = :data:`T_END`.  The paper's criterion on the mapped grids is
    reached only after thousands of CFL steps on a collapsed grid (121 x 121: 6093 steps and
    34 minutes for lambda = 10, ``inhom_gamma1p5.md``); at 481 x 481 that crawl is out of reach,
    so the study measures the density's collapse, which every grid resolves, and records
    whether the paper's criterion fired before it.  The ``continued uniform`` runs are the
    uniform runs carried on through the collapse to t = :data:`T_END` (no density stop), so that
    the record shows what follows the collapse (sigma_v's minimum and return) and the power-law
    fit of max f (:func:`~jko_cvx.blowup.fit_blowup`) sees the whole history.
``tab:g2bu`` (:mod:`jko_cvx.studies.reproduce.g2bu`)
    all nine lambda at N_x = 121 and N_v = 201, 401, 801, run to the paper's criterion
    (min dx < eps_x or min dv < eps_v, eps = 5e-6): T_b, its direction and the level-set
    check of ``thm_condbu`` (components of {f > 0.1} on each x-slice).

For a quantity q on three grids h, h/2, h/4 the table gives the successive differences
d1 = q(h/2) - q(h), d2 = q(h/4) - q(h/2), their ratio and the observed order
p = log2(d1 / d2) (defined when d1 and d2 have the same sign): a converging q has
|d2| < |d1|.  The paper's conclusions are restated from the finest grid.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.engine.loop import simulate
from jko_cvx.engine.verdict import StopReason
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.scene.model import Scene
from jko_cvx.studies.reproduce.blowup_tables import FIT_COLUMNS, fit_columns
from jko_cvx.studies.reproduce.g2bu import g2bu_run
from jko_cvx.studies.reproduce.gamma1p5 import COLLAPSE_SPREAD, gamma1p5_scene, spread_event
from jko_cvx.studies.reproduce.paper import TAB_G2BU
from jko_cvx.studies.solvers.figures import finish_figure, pyplot
from jko_cvx.studies.sweep import code_identity, run_sweep

__all__ = [
    "G2BU_N_V",
    "GRIDS",
    "GRID_KINDS",
    "T_END",
    "convergence",
    "grid_point",
    "reproduce_grid_convergence",
    "study_scene",
    "write_report",
]

GRIDS = (121, 241, 481)
"""n = N_x = N_v of the ``sec:sp_inhom_gamma_1p5`` grids (the paper's is 121)."""
G2BU_N_V = (201, 401, 801)
"""N_v of the ``tab:g2bu`` grids at N_x = 121 (the paper's is 201)."""
T_END = 0.7
"""Last time of the gamma = 3/2 runs: the bumps (x-width 0.29) stay apart until then."""
MEETING_TIME = 1.0
"""c/d: the bumps' centres meet at x = 0 at t = 1 under free transport (eqn:f0, c = d = 2.5)."""
QUICK = {"grids": (31, 41), "t_end": 0.25, "lambdas": (310.0,), "n_x": 41, "n_v": (61, 81)}
"""The quick form: coarse grids, short runs (a check of the pipeline, not of convergence)."""
_CASES = {"before": 10.0, "after": 5.0}  # lambda of each parameter set
_SPREAD_TIMES = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6)
GRID_KINDS = ("mapped", "uniform", "continued uniform")
"""The gamma = 3/2 grids: the paper's maps, the fixed uniform grid, and that grid run through the collapse."""


def study_scene(case: str, n: int, grid: str, t_end: float = T_END) -> Scene:
    """The scene of one gamma = 3/2 point on n x n: mapped or uniform (stopped at the collapse or t_end) or
    continued uniform (to t_end)."""
    if grid not in GRID_KINDS:
        raise ValueError(f"grid must be one of {list(GRID_KINDS)}, got {grid!r}")
    overrides: dict[str, Any] = {
        "stop.spread_v": 0.0 if grid == "continued uniform" else COLLAPSE_SPREAD,
        "t_end": t_end,
        "output.times": None,
        "output.every": 10**9,
    }
    if grid != "mapped":  # no maps and no mesh criterion: the map-free reference
        # the floor of the paper's every-step v-remap (eqn:mass_conserv_v) kept on the fixed
        # grid, so that the reference differs from the mapped run in the grid only
        overrides.update({"refine": None, "stop.eps_v": 0.0, "stop.eps_x": 0.0, "v.floor_every_step": True})
    return gamma1p5_scene(case, n, overrides)


def _gamma1p5(case: str, n: int, grid: str, t_end: float) -> dict[str, Any]:
    """One gamma = 3/2 run (:func:`study_scene`) to the first of T_b, the collapse (not continued runs) and t_end."""
    run = simulate(study_scene(case, n, grid, t_end))
    d = run.diagnostics
    stop = run.verdict.stop
    return {
        "stop": stop.name,
        "reason": run.verdict["reason"],
        # the paper's indicators (B_v, B_x, e_f); the density criterion is reported apart
        "T_b": float(run.verdict["T_b"]) if stop.blowup and stop is not StopReason.SPREAD_V else float("nan"),
        # the first record with sigma_v below the threshold (where a stopped run stops)
        "t_collapse": spread_event(d.t.tolist(), d.min_spread_v.tolist())["t below"],
        "t_stop": float(run.t),
        **fit_columns(run.verdict),
        "fit_reason": run.verdict["blowup_reason"],
        "steps": len(d) - 1,
        "t": d.t.tolist(),
        "min_spread_v": d.min_spread_v.tolist(),
        "min_dv": d.min_dv.tolist(),
        "max_f": d.max_f.tolist(),
        "max_rho": d.max_rho.tolist(),
        "mass_drift": float(np.abs(d.mass - d.mass.iloc[0]).max() / d.mass.iloc[0]),
        "momentum_drift": float(np.abs(d.momentum - d.momentum.iloc[0]).max() / d.mass.iloc[0]),
        "failed_slices": int(d.failed.sum()),
    }


def _g2bu(lam: float, n_x: int, n_v: int) -> dict[str, Any]:
    """One ``tab:g2bu`` run (:func:`~jko_cvx.studies.reproduce.g2bu.g2bu_run`) without its snapshot payload."""
    r = g2bu_run(lam, n_x, n_v)
    keep = ("blowup", "T_b", "B_x", "B_v", "reason", "steps", "min_dx", "min_dv", "max_f", "mass_drift")
    keep += ("failed_slices", "components", "split slices", "slices", "secondary peak", *FIT_COLUMNS)
    return {k: r[k] for k in keep}


def grid_point(study: str, **point: Any) -> dict[str, Any]:
    """One sweep point: ``study = "gamma1p5"`` (case, n, grid, t_end) or ``"g2bu"`` (lam, n_x, n_v)."""
    t0 = time.perf_counter()
    if study == "gamma1p5":
        result = _gamma1p5(**point)
    elif study == "g2bu":
        result = _g2bu(**point)
    else:
        raise ValueError(f"study must be 'gamma1p5' or 'g2bu', got {study!r}")
    return {**result, "seconds": time.perf_counter() - t0}


def convergence(values: list[float]) -> dict[str, float]:
    """Successive differences of q on grids h, h/2, h/4, ...; their last ratio and observed order.

    Returns ``d1``, ``d2`` (the last two differences), ``ratio = d1 / d2`` and
    ``order = log2(d1 / d2)`` (NaN unless d1 and d2 are nonzero with the same sign).  For
    q(h) = q* + C h^p the order is p exactly.
    """
    q = np.asarray(values, dtype=float)
    if q.size < 3:
        raise ValueError(f"values needs at least 3 grids, got {q.size}")
    d1, d2 = float(q[-2] - q[-3]), float(q[-1] - q[-2])
    ratio = d1 / d2 if d2 != 0 else float("nan")
    order = float(np.log2(ratio)) if np.isfinite(ratio) and ratio > 0 else float("nan")
    return {"d1": d1, "d2": d2, "ratio": ratio, "order": order}


def _at(t: list[float], y: list[float], tk: float) -> float:
    return float(np.interp(tk, t, y)) if tk <= t[-1] else float("nan")


def _points(quick: bool) -> list[dict[str, Any]]:
    """Every run, cheapest first (a killed sweep keeps the finished points in its cache)."""
    grids, t_end = (QUICK["grids"], QUICK["t_end"]) if quick else (GRIDS, T_END)
    lambdas = QUICK["lambdas"] if quick else tuple(float(lam) for lam in TAB_G2BU)
    n_x, n_vs = (QUICK["n_x"], QUICK["n_v"]) if quick else (121, G2BU_N_V)
    g1p5 = [
        {"study": "gamma1p5", "case": c, "n": n, "grid": g, "t_end": t_end}
        for n in grids
        for g in ("uniform", "mapped", "continued uniform")
        for c in _CASES
    ]
    g2 = [{"study": "g2bu", "lam": lam, "n_x": n_x, "n_v": n_v} for n_v in n_vs for lam in lambdas]
    # the finest of each study last: the two coarser levels of both first
    coarse = [p for p in g1p5 if p["n"] != grids[-1]] + [p for p in g2 if p["n_v"] != n_vs[-1]]
    return coarse + [p for p in g1p5 if p["n"] == grids[-1]] + [p for p in g2 if p["n_v"] == n_vs[-1]]


def _after_collapse(r: pd.Series) -> dict[str, Any]:
    """What the whole record says after the collapse: sigma_v's minimum and return, max f's peak."""
    ev = spread_event(r.t, r.min_spread_v, t_below=r.t_collapse, followed=r.grid == "continued uniform")
    k = int(np.argmax(r.max_f))
    return {
        "min sigma_v": ev["min sigma_v"],
        "t(min sigma_v)": ev["t(min sigma_v)"],
        f"t(sigma_v back >= {COLLAPSE_SPREAD:g})": ev["t back above"],
        "peak max f": float(r.max_f[k]),
        "t(peak max f)": float(r.t[k]),
        "event": ev["event"],
    }


def _gamma1p5_rows(df: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for _, r in df.iterrows():
        rows.append(
            {
                "case": r.case,
                "lambda": _CASES[r.case],
                "grid": r.grid,
                "n": int(r.n),
                "stop": r.reason,
                "t stop": r.t_stop,
                "T_b (paper's criteria)": r.T_b,
                f"t(sigma_v < {COLLAPSE_SPREAD:g})": r.t_collapse,
                **{k: r.get(k, float("nan")) for k in FIT_COLUMNS},
                "fit reason": r.get("fit_reason", ""),
                **{f"sigma_v(t={tk:g})": _at(r.t, r.min_spread_v, tk) for tk in _SPREAD_TIMES},
                "sigma_v (stop)": r.min_spread_v[-1],
                **_after_collapse(r),
                "max f (stop)": r.max_f[-1],
                "max rho (stop)": r.max_rho[-1],
                "min dv (stop)": r.min_dv[-1],
                "steps": int(r.steps),
                "mass drift": r.mass_drift,
                "momentum drift": r.momentum_drift,
                "failed slices": int(r.failed_slices),
                "seconds": r.seconds,
            }
        )
    return pd.DataFrame(rows)


def _gamma1p5_convergence(rows: pd.DataFrame) -> pd.DataFrame:
    """Per case and grid kind: the collapse time and sigma_v(t) on each n (continued runs: sigma_v's minimum and
    return, max f's peak and the fitted T), with :func:`convergence`."""
    out = []
    stopped = [f"t(sigma_v < {COLLAPSE_SPREAD:g})"] + [f"sigma_v(t={tk:g})" for tk in _SPREAD_TIMES[:3]]
    # a continued run equals the uniform one up to the collapse: its own quantities are those after it
    continued = ["min sigma_v", "t(min sigma_v)", f"t(sigma_v back >= {COLLAPSE_SPREAD:g})", "peak max f",
                 "t(peak max f)", "T_b_fit"]  # fmt: skip
    for (case, grid), g in rows.groupby(["case", "grid"], sort=False):
        g = g.sort_values("n")
        for q in continued if grid == "continued uniform" else stopped:
            values = g[q].tolist()
            conv = convergence(values) if len(values) >= 3 else {}
            out.append(
                {
                    "case": case,
                    "grid": grid,
                    "quantity": q,
                    **{f"n = {n}": v for n, v in zip(g.n, values, strict=True)},
                    **conv,
                    "converging": bool(conv and abs(conv["d2"]) < abs(conv["d1"])),
                }
            )
    return pd.DataFrame(out)


def _g2bu_table(df: pd.DataFrame) -> pd.DataFrame:
    """One row per lambda: T_b on each N_v beside the paper's, direction, level-set splits, convergence."""
    rows = []
    for lam, g in df.groupby("lam"):
        g = g.sort_values("n_v")
        row: dict[str, Any] = {"lambda": int(lam), "paper T_b": TAB_G2BU.get(int(lam), float("nan"))}
        for _, r in g.iterrows():
            n = int(r.n_v)
            row[f"T_b (N_v = {n})"] = r.T_b
            row.update({f"{k} ({n})": r.get(k, float("nan")) for k in FIT_COLUMNS})
            row[f"direction ({n})"] = "x" if r.B_x else ("v" if r.B_v else "-")
            row[f"max components ({n})"] = max(r.components) if len(r.components) else 0
            row[f"split fraction ({n})"] = r["split slices"] / max(r.slices, 1)
            row[f"seconds ({n})"] = r.seconds
        if len(g) >= 3:
            row.update({f"T_b {k}": v for k, v in convergence(g.T_b.tolist()).items()})
        rows.append(row)
    return pd.DataFrame(rows)


def _fit_words(r: pd.Series) -> str:
    """The power-law fit of max f in words (jko_cvx.blowup), or nothing where the rows predate it."""
    kind = r.get("blowup_kind")
    if not isinstance(kind, str):
        return ""
    tb = r.get("T_b_fit")
    at = f", T_b_fit = {tb:.4g} +- {r.get('T_b_fit_err'):.2g}" if tb is not None and np.isfinite(tb) else ""
    return f"; the fit of max f: {kind}{at}"


def _outcome(r: pd.Series, collapse: str) -> str:
    """One run's outcome in words: the density's collapse, the paper's T_b, or neither by its end; for a run
    continued through the collapse what followed it, and the fit's reason."""
    if r.grid != "continued uniform":
        return _outcome_paper(r, collapse) + _fit_words(r)
    why = str(r.get("fit reason", "")).split(":")[0]
    return (
        f"{r.event} (min sigma_v {r['min sigma_v']:.3g} at t = {r['t(min sigma_v)']:.3g}; max f peaks at "
        f"{r['peak max f']:.4g} at t = {r['t(peak max f)']:.3g} and is {r['max f (stop)']:.4g} at t = "
        f"{r['t stop']:.3g}){_fit_words(r)}, {why}"
    )


def _outcome_paper(r: pd.Series, collapse: str) -> str:
    side = {True: "before", False: "after"}
    if np.isfinite(r[collapse]):
        return f"collapse in v at t = {r[collapse]:.4g}, {side[r[collapse] < MEETING_TIME]} the bumps meet (t = 1)"
    tb = r["T_b (paper's criteria)"]
    if np.isfinite(tb) and str(r.stop).startswith("collision solver failed"):
        # e_f: the paper counts it as blow-up, but it says nothing about the density
        return (
            f"the collision solver failed at t = {tb:.4g} ({r.stop}: the paper's e_f indicator), "
            f"with sigma_v = {r['sigma_v (stop)']:.3g}, before any collapse"
        )
    if np.isfinite(tb):
        return f"the paper's criterion fired at T_b = {tb:.4g} ({r.stop}), {side[tb < MEETING_TIME]} the bumps meet"
    return f"neither criterion by t = {r['t stop']:.4g} ({r.stop})"


def _conclusions(rows: pd.DataFrame, g2runs: pd.DataFrame) -> list[str]:
    """The paper's conclusions restated from the finest grid each run has, in words built from the numbers."""
    lines = []
    collapse = f"t(sigma_v < {COLLAPSE_SPREAD:g})"
    for (case, grid), g in rows.groupby(["case", "grid"], sort=False):
        r = g.loc[g.n.idxmax()]
        lines.append(
            f"- gamma = 3/2, lambda = {_CASES[case]:g} ({case}), {grid} {r.n} x {r.n}: {_outcome(r, collapse)}."
        )
    if len(g2runs):
        finest = g2runs.loc[g2runs.groupby("lam").n_v.idxmax()]  # each lambda on its finest grid run
        tb = finest.T_b
        every = bool(finest.blowup.astype(str).str.lower().eq("true").all())  # an undetermined run (None) is not one
        grids = ", ".join(f"N_v = {n}" for n in sorted(finest.n_v.astype(int).unique()))
        lines.append(
            f"- tab:g2bu, each lambda on its finest grid ({grids}): T_b from {tb.min():.5g} to {tb.max():.5g} over "
            f"lambda = {int(finest.lam.min())}-{int(finest.lam.max())} (paper: {min(TAB_G2BU.values()):.5g}-"
            f"{max(TAB_G2BU.values()):.5g}); every run flagged blow-up: {every}."
        )
        if "blowup_kind" in finest:
            kinds = finest.blowup_kind.value_counts().to_dict()
            fitted = finest[finest.blowup_kind == "finite_time"]
            span = (
                f"; finite_time T_b_fit from {fitted.T_b_fit.min():.5g} to {fitted.T_b_fit.max():.5g} "
                f"(error bars up to {fitted.T_b_fit_err.max():.2g})"
                if len(fitted)
                else ""
            )
            lines.append(f"- tab:g2bu under the power-law fit of max f (jko_cvx.blowup): kinds {kinds}{span}.")
    return lines


def _figure(runs: pd.DataFrame, path: Path) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    g1p5 = runs[runs.study == "gamma1p5"]
    colours = dict(zip(sorted(g1p5.n.unique()), ("tab:blue", "tab:orange", "tab:green", "tab:red"), strict=False))
    for ax, case in zip(axes[:2], _CASES, strict=True):
        for _, r in g1p5[g1p5.case == case].iterrows():
            ax.semilogy(
                r.t,
                r.min_spread_v,
                ls="-" if r.grid == "mapped" else "--",
                color=colours[r.n],
                label=f"{r.grid} {int(r.n)}",
            )
        ax.axhline(COLLAPSE_SPREAD, color="k", lw=0.6)
        ax.set_title(f"gamma = 3/2, lambda = {_CASES[case]:g}: sigma_v(t)", fontsize=9)
        ax.set_xlabel("t")
    ax = axes[2]
    for n_v, g in runs[runs.study == "g2bu"].groupby("n_v"):
        g = g.sort_values("lam")
        ax.plot(g.lam, g.T_b, "o-", label=f"N_v = {int(n_v)}")
    ax.plot(list(TAB_G2BU), list(TAB_G2BU.values()), "k^", label="paper (N_v = 201)")
    ax.set_xlabel("lambda")
    ax.set_title("tab:g2bu: T_b against lambda", fontsize=9)
    finish_figure(fig, axes, path)


def reproduce_grid_convergence(out: Path, quick: bool = False, **sweep_opts: Any) -> pd.DataFrame:
    """Both studies on their three grids; writes ``grid_convergence.{csv,md,png}`` and ``grid_convergence_g2bu.csv``.

    ``quick``: gamma = 3/2 on 31 and 41 points per axis to t = 0.25, tab:g2bu at lambda = 310
    on 41 x 61 and 41 x 81 (a check of the pipeline: too coarse to say anything about convergence).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    runs = run_sweep(
        grid_point, _points(quick), out / "cache" / "grid_convergence", desc="grid_convergence", **sweep_opts
    )
    ident = code_identity(grid_point)
    provenance = f"package {ident['package_version']}, package sha256 {ident['package_sha256'][:12]}"
    return write_report(runs, out, wall=time.perf_counter() - t0, provenance=provenance)


def write_report(
    runs: pd.DataFrame, out: Path, *, wall: float, provenance: str, missing: list[dict[str, Any]] | None = None
) -> pd.DataFrame:
    """The tables, the Markdown report and the figure from the sweep's rows (one per point, point keys included).

    ``missing``: points of the sweep that were not run (listed in the report, so that a
    partial sweep cannot pass for a complete one); ``provenance``: the code the runs came from.
    """
    out = Path(out)
    rows = _gamma1p5_rows(runs[runs.study == "gamma1p5"].reset_index(drop=True))
    conv = _gamma1p5_convergence(rows)
    g2 = _g2bu_table(runs[runs.study == "g2bu"].reset_index(drop=True))
    rows.to_csv(out / "grid_convergence.csv", index=False)
    record_csv(out / "grid_convergence.csv")
    conv.to_csv(out / "grid_convergence_gamma1p5.csv", index=False)
    record_csv(out / "grid_convergence_gamma1p5.csv")
    g2.to_csv(out / "grid_convergence_g2bu.csv", index=False)
    record_csv(out / "grid_convergence_g2bu.csv")
    absent = ""
    if missing:
        absent = "\n\n**Points not run** (the tables leave them out):\n\n" + "\n".join(
            "- " + ", ".join(f"{k} = {v}" for k, v in p.items()) for p in missing
        )
    write_markdown(out / "grid_convergence.md",
        "# Grid convergence of sec:sp_inhom_gamma_1p5 and tab:g2bu\n\n"
        + (__doc__ or "").split("\n\n", 1)[1].split("\n\nFor a quantity")[0]
        + absent
        + "\n\n## gamma = 3/2: every run\n\n"
        + rows.drop(columns=["fit reason", "event"]).to_markdown(index=False, floatfmt=".4g")
        + "\n\n## gamma = 3/2: convergence over the grids\n\n"
        "d1, d2: the differences between successive grids; order = log2(d1/d2).\n\n"
        + conv.to_markdown(index=False, floatfmt=".4g")
        + "\n\n## tab:g2bu over N_v (N_x = 121)\n\n"
        + g2.to_markdown(index=False, floatfmt=".5g")
        + "\n\n## What the paper's conclusions become\n\n"
        + "\n".join(_conclusions(rows, runs[runs.study == "g2bu"]))
        + (f"\n\nSweep wall time {wall:.0f} s; " if np.isfinite(wall) else "\n\n")
        + f"sum of the runs' seconds {runs.seconds.sum():.0f} s "
        f"(points from the cache count their original seconds).  Code: {provenance}.\n"
    )
    _figure(runs, out / "grid_convergence.png")
    return rows
