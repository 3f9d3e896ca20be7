"""A control for the paper's blow-up criterion: does min dv < eps_v fire where the theory says it must not?

The homogeneous equation with :math:`W = |v|^\\gamma/\\gamma` concentrates in finite time exactly
when :math:`\\int_0 dr / W'(r) < \\infty` (the Osgood criterion), i.e. for :math:`\\gamma < 2`;
for :math:`\\gamma = 2` the contraction is linear (:math:`\\max f = e^{Mt}\\max f_0`) and for
:math:`\\gamma > 2` slower still, so no finite-time blow-up.  The paper's criterion
(``sec: numerics``: the first t with min dv < eps_v on the refined grid) reads any
concentration that the mesh map resolves below eps_v as blow-up.

This entry runs the ``tab:bu`` datum g1 (:func:`~jko_cvx.studies.reproduce.blowup_tables.blowup_scene`,
:data:`~jko_cvx.studies.reproduce.blowup_tables.TAB_BU_BETA`, the paper's maps) for gamma on both
sides of 2 and two grids to t = :data:`T_END`, and reads the threshold time at every eps_v of
:data:`EPS_V` off one run (:func:`~jko_cvx.studies.reproduce.blowup_tables.replayed_entry`).  A
finite-time singularity gives threshold times that converge as eps_v -> 0 (extrapolated by
:func:`~jko_cvx.blowup.extrapolate_thresholds`); an exponential contraction gives times that
grow like log(1/eps_v) without bound (the ``drift`` column: the least-squares slope of T_b
against ln(1/eps_v); a threshold that fires at the first step, above the refined grid's first
spacing, measures the map and is counted apart).  Beside them the fit of max f
(:func:`~jko_cvx.blowup.fit_blowup`) of the whole run, whose kind is checked against the Osgood
criterion.  Written:
``criterion_control.{csv,md,png}``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.engine.loop import simulate
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.reproduce.blowup_tables import (
    FIT_COLUMNS,
    TAB_BU_BETA,
    blowup_scene,
    fit_columns,
    replayed_entry,
    threshold_limit,
)
from jko_cvx.studies.solvers.figures import finish_figure, pyplot
from jko_cvx.studies.sweep import run_sweep

__all__ = ["EPS_V", "GAMMAS", "N_V", "T_END", "control_run", "osgood_finite_time", "reproduce_criterion_control"]

GAMMAS = (1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0)
"""gamma on both sides of the Osgood threshold 2."""
N_V = (121, 241)
"""The tab:bu grid (N_v = 121) and its refinement."""
EPS_V = (1e-2, 3e-3, 1e-3, 3e-4, 1e-4)
"""The thresholds read off each run (tab:bu's own reach from 1e-3 to 1e-3/16)."""
T_END = 10.0
"""Twenty times g1's gamma = 1 blow-up time 0.5: long enough for the linear contraction to reach eps_v = 3e-4."""
DT = 0.01
QUICK = {"gammas": (1.5, 2.0), "n_v": (61,), "eps_v": (1e-2, 3e-3, 1e-3), "t_end": 3.0}
"""The quick form: one grid, two gamma, three thresholds (a check of the pipeline)."""


def osgood_finite_time(gamma: float) -> bool:
    """Finite-time collapse for :math:`W = |v|^\\gamma/\\gamma`: :math:`\\int_0 r^{1-\\gamma} dr < \\infty`, i.e.
    gamma < 2."""
    return float(gamma) < 2.0


def control_run(gamma: float, n_v: int, eps_v: list[float], t_end: float = T_END, dt: float = DT) -> dict[str, Any]:
    """One sweep point: the g1 datum at ``gamma`` on ``n_v`` points, run at the smallest threshold, every
    threshold's time read off its records, and the whole run's fit of max f."""
    t0 = time.perf_counter()
    eps = sorted((float(e) for e in eps_v), reverse=True)
    scene = blowup_scene("g1", eps[-1], dt, TAB_BU_BETA, {"gamma": float(gamma), "t_end": float(t_end), "v.n": n_v})
    run = simulate(scene)
    d = run.diagnostics
    entries = [replayed_entry(d, run.verdict, e) for e in eps]
    return {
        "eps_v": eps,
        "T_b": [e["T_b"] for e in entries],
        **fit_columns(run.verdict),
        "fit_reason": run.verdict["blowup_reason"],
        "stop": run.verdict["reason"],
        "t": float(run.t),
        "max_f": float(d.max_f.max()),
        "min_dv": float(d.min_dv.min()),
        "steps": len(d) - 1,
        "failed_steps": int((d.failed > 0).sum()),
        "seconds": time.perf_counter() - t0,
    }


def _drift(eps: np.ndarray, tb: np.ndarray) -> float:
    """Least-squares slope of T_b against ln(1/eps_v) over the thresholds that fired (NaN for fewer than 2)."""
    ok = np.isfinite(tb)
    if ok.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(1 / eps[ok]), tb[ok], 1)[0])


def _row(r: pd.Series) -> dict[str, Any]:
    eps, tb = np.asarray(r.eps_v, dtype=float), np.asarray(r.T_b, dtype=float)
    # a threshold above the refined grid's first spacing fires at the first step: it measures the map, not
    # the concentration, and is left out of the drift and the extrapolation
    first = np.isfinite(tb) & (tb <= 1.5 * DT)
    fired = np.isfinite(tb) & ~first
    row: dict[str, Any] = {
        "gamma": r.gamma,
        "n_v": int(r.n_v),
        "osgood": "finite-time" if osgood_finite_time(r.gamma) else "none",
        **{f"T_b (eps_v = {e:g})": t for e, t in zip(eps, tb, strict=True)},
        "fired": int(fired.sum()),
        "fired at the first step": int(first.sum()),
        "fires where theory forbids": bool(fired.any() and not osgood_finite_time(r.gamma)),
        "drift dT_b/dln(1/eps)": _drift(eps[fired], tb[fired]),
    }
    T0, err = threshold_limit(eps[fired], tb[fired], DT)
    row.update({"T_0 (eps -> 0)": T0, "T_0 err": err})
    row.update({k: r[k] for k in FIT_COLUMNS})
    expected = "finite_time" if osgood_finite_time(r.gamma) else "no_finite_time"
    row["kind right"] = r.blowup_kind == expected
    row.update({"max f": r.max_f, "min dv": r.min_dv, "t end": r.t, "steps": int(r.steps),
                "failed steps": int(r.failed_steps), "stop": r.stop, "fit reason": r.fit_reason,
                "seconds": r.seconds})  # fmt: skip
    return row


def reproduce_criterion_control(out: Path, quick: bool = False, **sweep_opts: Any) -> pd.DataFrame:
    """gamma in :data:`GAMMAS` on :data:`N_V` (``quick``: :data:`QUICK`); writes ``criterion_control.{csv,md,png}``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    gammas, grids, eps, t_end = (
        (QUICK["gammas"], QUICK["n_v"], QUICK["eps_v"], QUICK["t_end"]) if quick else (GAMMAS, N_V, EPS_V, T_END)
    )
    points = [{"gamma": g, "n_v": n, "eps_v": list(eps), "t_end": t_end} for n in grids for g in gammas]
    df = run_sweep(control_run, points, out / "cache" / "criterion_control", desc="criterion_control", **sweep_opts)
    table = pd.DataFrame([_row(r) for _, r in df.iterrows()])
    csv = out / "criterion_control.csv"
    table.to_csv(csv, index=False)
    record_csv(csv)
    write_markdown(out / "criterion_control.md", _report(table, quick, t_end))
    _figure(table, eps, out / "criterion_control.png")
    return table


def _report(table: pd.DataFrame, quick: bool, t_end: float) -> str:
    forbidden = table[table.osgood == "none"]
    false_fire = forbidden[forbidden["fires where theory forbids"]]
    lines = [
        "# The paper's criterion against the Osgood criterion (homogeneous, datum g1)"
        + (" (quick form)" if quick else ""),
        "",
        (__doc__ or "").split("\n\n")[2].replace("\n", " "),
        "",
        f"* gamma >= 2 (no finite-time blow-up): the criterion min dv < eps_v fired in {len(false_fire)} of "
        f"{len(forbidden)} runs to t = {t_end:g} (gamma = {sorted(set(false_fire.gamma))}).",
        f"* the fit of max f gives the Osgood kind in {int(table['kind right'].sum())} of {len(table)} runs.",
    ]
    for side, g in table.groupby(table.osgood == "none"):
        drift = g["drift dT_b/dln(1/eps)"].dropna()
        if len(drift):
            lines.append(
                f"* {'gamma >= 2' if side else 'gamma < 2'}: drift of T_b per e-fold of 1/eps_v from "
                f"{drift.min():.3g} to {drift.max():.3g}"
            )
    show = table.drop(columns=["fit reason", "stop"])
    lines += ["", show.to_markdown(index=False, floatfmt=".4g"), ""]
    return "\n".join(lines)


def _figure(table: pd.DataFrame, eps: tuple[float, ...], path: Path) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    cols = [f"T_b (eps_v = {e:g})" for e in eps]
    grids = sorted(table.n_v.unique())
    for i, (gamma, g) in enumerate(table.groupby("gamma")):
        for _, r in g.iterrows():
            ls = "-" if r.n_v == grids[0] else "--"
            label = f"gamma = {gamma:g}" + ("" if osgood_finite_time(gamma) else " (no blow-up)")
            ax.semilogx(eps, r[cols].to_numpy(dtype=float), ls, marker="o", ms=3, color=f"C{i}",
                        label=label if r.n_v == grids[0] else None)  # fmt: skip
    ax.invert_xaxis()
    ax.set_xlabel("eps_v (threshold on min dv)")
    ax.set_ylabel("T_b: first t with min dv < eps_v")
    ax.set_title(f"Threshold times on N_v = {', '.join(map(str, grids))} (solid, dashed)", fontsize=9)
    finish_figure(fig, [ax], path, fontsize=8)
