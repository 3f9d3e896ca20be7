"""How far the conic method runs the paper's gamma = 3 scene, and why it stops.

``inhom_gamma3_lambda4`` at 61 x 61 with ``collision.fisher = "perspective"`` (the form conic poses),
beta = 30, 100 and 1000, to t = 1, under ``method = "conic"`` and under Newton.  Per run: the time
reached, the steps, the stop reason, wall time, and max f against Newton's at the common records;
where the conic run stops, each failed slice of that step: its status, KKT residual, max f*, the
smallest density relative to the largest, the explicit CFL number, the distance of the conic answer
from Newton's (tight) answer, and the weight f_j / max f of the cell that carries the residual.

Rows go to ``studies/results/conic_scene_runs.csv`` (date, commit, BLAS threads), the summary to the
Markdown report beside it::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python studies/conic_scene_runs.py
"""

from __future__ import annotations

import datetime
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd

import jko_cvx.engine.loop as loop
from jko_cvx import shipped_scene, simulate
from jko_cvx.collision import solve_newton
from jko_cvx.environment import record_csv, write_markdown
from studies.newton_single_call import tree_label

OUT = Path(__file__).parent / "results" / "conic_scene_runs.csv"
BETAS = (30.0, 100.0, 1000.0)
GRID = {"x.n": 61, "v.n": 61, "collision.fisher": "perspective", "t_end": 1.0}


def _carrier_weight(problem, f, m) -> float:
    """f_j / max f at the cell with the largest weighted stationarity term of the KKT residual."""
    parts = problem.gradient_parts(f, m)
    kkt = problem.kkt_residual(f, m)
    gf = parts.wasserstein[0] + parts.fisher[0] + parts.energy[0]
    w = np.maximum(f, 0) / f.max()
    return float(w[np.argmax(w * np.abs(gf / problem.grid.h + kkt.multiplier))])


def run_conic(beta: float) -> tuple[object, list[dict]]:
    """The conic run, and the failed slices of the step that stopped it."""
    failed: list[dict] = []
    solve = loop.solve_collision

    def watched(problem, method, **options):
        res = solve(problem, method, **options)
        ok = np.atleast_1d(res.success)
        if not ok.all():
            failed.clear()
            for i in np.flatnonzero(~ok):
                p, f, m = problem.slice(int(i)), res.f[i], res.m[i]
                ref = solve_newton(p, tol=1e-12, max_iter=500)
                failed.append({
                    "slice": int(i), "status": np.atleast_1d(res.status)[i].name,
                    "kkt": float(np.atleast_1d(res.kkt_residual)[i]), "max_f_star": float(p.f_star.max()),
                    "min_over_max_f_star": float(p.f_star.min() / p.f_star.max()), "cfl": float(p.cfl()),
                    "df_newton": float(np.abs(f - ref.f).max() / ref.f.max()), "newton": ref.status.name,
                    "carrier_weight": _carrier_weight(p, f, m),
                })  # fmt: skip
        return res

    loop.solve_collision = watched
    try:
        sc = shipped_scene("inhom_gamma3_lambda4", {**GRID, "collision.beta": beta, "collision.method": "conic"})
        return simulate(sc), failed
    finally:
        loop.solve_collision = solve


def main() -> None:
    tree = tree_label()
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M")
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    runs, slices = [], []
    for beta in BETAS:
        t0 = time.perf_counter()
        conic, failed = run_conic(beta)
        t_conic = time.perf_counter() - t0
        t0 = time.perf_counter()
        newton = simulate(shipped_scene("inhom_gamma3_lambda4", {**GRID, "collision.beta": beta}))
        t_newton = time.perf_counter() - t0
        a, b = conic.diagnostics["max_f"].to_numpy(), newton.diagnostics["max_f"].to_numpy()
        n = min(a.size, b.size)
        for name, r, secs in (("conic", conic, t_conic), ("newton", newton, t_newton)):
            runs.append({
                "date": date, "commit": tree, "threads": threads, "beta": beta, "method": name, "t": r.t,
                "steps": r.steps, "stop": r.verdict.stop.name, "reason": r.verdict.reason, "wall_s": round(secs, 2),
                "max_rel_dmax_f_vs_newton": float(np.max(np.abs(a[:n] - b[:n]) / b[:n])) if name == "conic" else 0.0,
            })  # fmt: skip
        slices += [{"date": date, "commit": tree, "beta": beta, "t": conic.t, **row} for row in failed if conic.t < 1]
        print(runs[-2], failed, flush=True)
    frame = pd.DataFrame(runs)
    frame.to_csv(OUT, index=False)
    failed_frame = pd.DataFrame(slices)
    failed_frame.to_csv(OUT.with_name("conic_scene_runs_failed_slices.csv"), index=False)
    record_csv(OUT, OUT.with_name("conic_scene_runs_failed_slices.csv"))
    text = [
        "# The conic method on the paper's gamma = 3 scene (`studies/conic_scene_runs.py`)",
        "",
        f"{date} UTC, code {tree}, OPENBLAS_NUM_THREADS={threads}.  `inhom_gamma3_lambda4`, 61 x 61, perspective "
        "form, to t = 1; runs under conic certify at its kkt_tol 1e-6, Newton's at 1e-8.",
        "",
        frame.drop(columns=["date", "commit", "threads"]).to_markdown(index=False),
        "",
        "The failed slices of the step that stopped each conic run (`df_newton`: the conic answer's distance to "
        "Newton's tight answer, relative to max f; `carrier_weight`: f_j / max f of the cell whose term carries the "
        "KKT residual):",
        "",
        failed_frame.drop(columns=["date", "commit"]).to_markdown(index=False, floatfmt=".3g")
        if len(failed_frame) else "(none: every run reached t = 1)",
        "",
    ]
    write_markdown(OUT.with_suffix(".md"), "\n".join(text))
    print("\n".join(text))


if __name__ == "__main__":
    main()
