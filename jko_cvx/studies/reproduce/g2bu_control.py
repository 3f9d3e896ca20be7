"""A control for ``tab:g2bu``: does the blow-up criterion fire where the theory says it must not?

For gamma = 2 the self-similar (infinite-mass) solution of ``sec:sp_inhom_gamma_2`` concentrates
in finite time only for lambda above the threshold ``thres`` = 2 / (rho0 T) = 309.8; the finite-
mass datum ``eqn:ic_g2`` of ``tab:g2bu`` resembles it near x = 0.  The paper reports T_b for
lambda from 220 to 400 only, so its table cannot show whether the criterion (min dx < eps_x or
min dv < eps_v, ``alg:SPMCSL-JKO``) also fires below the threshold, i.e. whether a reported T_b
is evidence of blow-up at all.

This entry sweeps lambda across the threshold on two grids, refined in x and v alike (the
paper's delta = delta0 = 0.5 maps on both axes): per (lambda, N_x, N_v) the verdict, T_b, the
direction, the stop reason, max f, and the blow-up fit of :mod:`jko_cvx.blowup` (T_b_fit with
its error bar and the kind).  Written: ``tab_g2bu_control.{csv,md}``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pandas as pd

from jko_cvx.engine.loop import simulate
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.reproduce.blowup_tables import FIT_COLUMNS, fit_columns
from jko_cvx.studies.reproduce.g2bu import RHO0, T, g2bu_scene
from jko_cvx.studies.sweep import run_sweep

__all__ = ["CONTROL_GRIDS", "CONTROL_LAMBDAS", "THRESHOLD", "g2bu_control_run", "reproduce_tab_g2bu_control"]

THRESHOLD = 2 / (RHO0 * T)
"""lambda above which the infinite-mass solution blows up (``thres``: 20 sqrt(240) = 309.8)."""

CONTROL_LAMBDAS = (50.0, 100.0, 150.0, 200.0, 250.0, 300.0, 310.0, 350.0, 400.0)
CONTROL_GRIDS = ((61, 101), (121, 201))
"""(N_x, N_v): the paper's 121 x 201 and half of it on each axis."""


def g2bu_control_run(lam: float, n_x: int, n_v: int, t_end: float = 0.2) -> dict[str, Any]:
    """One sweep point: the verdict of the ``tab:g2bu`` scene at (lambda, N_x, N_v) to ``t_end``."""
    t0 = time.perf_counter()
    scene = g2bu_scene(lam, n_x, n_v, t_end).replace({"output.every": 10**6})
    run = simulate(scene)
    v, d = run.verdict, run.diagnostics
    return {
        "verdict": {True: "blow-up", False: "no blow-up", None: "undetermined"}[run.blowup],
        "T_b": float(v["T_b"]) if run.blowup else float("nan"),
        "direction": "x" if v["B_x"] else ("v" if v["B_v"] else "-"),
        "stop": v.stop.name,
        "reason": v["reason"],
        **fit_columns(v),
        "t": float(run.t),
        "steps": len(d) - 1,
        "max_f": float(d.max_f.max()),
        "min_dx": float(d.min_dx.min()),
        "min_dv": float(d.min_dv.min()),
        "uncertified_steps": int(v.uncertified_steps),
        "seconds": time.perf_counter() - t0,
    }


def reproduce_tab_g2bu_control(out: Path, quick: bool = False, **sweep_opts: Any) -> pd.DataFrame:
    """lambda in :data:`CONTROL_LAMBDAS` on :data:`CONTROL_GRIDS` (``quick``: lambda = 100 and 310 on
    41 x 61 to t = 0.12); writes ``tab_g2bu_control.{csv,md}``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if quick:
        points = [{"lam": lam, "n_x": 41, "n_v": 61, "t_end": 0.12} for lam in (100.0, 310.0)]
    else:
        points = [{"lam": lam, "n_x": nx, "n_v": nv} for nx, nv in CONTROL_GRIDS for lam in CONTROL_LAMBDAS]
    df = run_sweep(g2bu_control_run, points, out / "cache" / "tab_g2bu_control", desc="tab_g2bu_control", **sweep_opts)
    df = df.rename(columns={"lam": "lambda"})
    df["above threshold"] = df["lambda"] > THRESHOLD
    cols = ["lambda", "n_x", "n_v", "above threshold", "verdict", "T_b", "direction", "stop", *FIT_COLUMNS, "max_f",
            "min_dx", "min_dv", "steps", "uncertified_steps", "reason", "seconds"]  # fmt: skip
    table = df[cols]
    csv = out / "tab_g2bu_control.csv"
    table.to_csv(csv, index=False)
    record_csv(csv)
    write_markdown(out / "tab_g2bu_control.md", _report(table, quick))
    return table


def _report(table: pd.DataFrame, quick: bool) -> str:
    below = table[~table["above threshold"]]
    fired = below[below.verdict == "blow-up"]
    lines = [
        "# tab:g2bu control: the blow-up criterion across the threshold lambda = 2/(rho0 T) = "
        f"{THRESHOLD:.1f}{' (quick form)' if quick else ''}",
        "",
        f"Runs below the threshold: {len(below)}; the criterion fired in {len(fired)} of them "
        f"(lambda = {sorted(set(fired['lambda'].astype(int)))}). A criterion that fires below the threshold "
        "does not by itself tell blow-up from a concentration the grid cannot follow; `blowup_kind` is the fit "
        "of max f(t) to a finite-time law (jko_cvx.blowup).",
        "",
    ]
    for (nx, nv), grid in table.groupby(["n_x", "n_v"]):
        fired_here = grid[grid.verdict == "blow-up"]["lambda"]
        first = f"{fired_here.min():g}" if len(fired_here) else "none"
        lines.append(f"* {nx} x {nv}: smallest lambda where the criterion fires: {first}")
    show = table.drop(columns=["reason"]).copy()
    lines += ["", show.to_markdown(index=False, floatfmt=".4g"), ""]
    return "\n".join(lines)
