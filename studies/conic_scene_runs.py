"""How far the conic method runs the paper's gamma = 3 scene, and why it stops.

``inhom_gamma3_lambda4`` at 61 x 61 with ``collision.fisher = "perspective"`` (the form conic poses),
beta = 30, 100 and 1000, to t = 1, under ``method = "conic"`` and under Newton (with its second start,
the default, and without).  Per run: the time reached, the steps, the stop reason, wall time, max f
against the default Newton run's at the common records, and for Newton the slice-steps that jammed
and those where the second start returned a lower certified J;
where the conic run stops, each failed slice of that step: its status, KKT residual, max f*, the
smallest density relative to the largest, the explicit CFL number, the distance of the conic answer
from Newton's (tight) answer, and the weight f_j / max f of the cell that carries the residual.

Part 2 verifies each scene's Newton run against the conic reference at every step and slice
(``jko_cvx.verify``, to t = 1), with Newton's second start (``second_start``, the default) and
without it: the outcome counts, and the rows that do not agree (``conic_scene_runs_verify.csv``).
Part 3 takes the rows where both solvers are certified yet differ by more than 1e-3 in f and solves
those steps again with Newton without and with the second start (the run's options otherwise), the
conic reference and IPOPT, recording each objective (``conic_scene_runs_minima.csv``): the step is
not convex there, and certified answers may be different local minimisers.

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
from jko_cvx import shipped_scene, simulate, solve_collision, verify
from jko_cvx.collision import solve_newton
from jko_cvx.collision.estimate import solve_reference
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


def _newton_scene(beta: float, second_start: bool):
    """The scene's Newton run at ``beta``, with or without Newton's second start."""
    return shipped_scene(
        "inhom_gamma3_lambda4", {**GRID, "collision.beta": beta, "collision.options.second_start": second_start}
    )


def newton_run(beta: float, second_start: bool) -> tuple[object, dict, list]:
    """The scene's Newton run; its slice-steps (how many, how many jammed, how many the second start changed);
    and the collision problem of every step with its options, in order."""
    counts = {"slice_steps": 0, "jammed": 0, "lower_minimum": 0}
    steps: list = []
    solve = loop.solve_collision

    def watched(problem, method, **options):
        steps.append((problem, options))
        res = solve(problem, method, **options)
        counts["slice_steps"] += problem.batch_size
        counts["jammed"] += int(np.sum(res.info["jammed"]))
        counts["lower_minimum"] += int(np.sum(res.info["lower_minimum"]))
        return res

    loop.solve_collision = watched
    try:
        return simulate(_newton_scene(beta, second_start)), counts, steps
    finally:
        loop.solve_collision = solve


def verify_part(beta: float, second_start: bool, steps: list) -> tuple[dict, pd.DataFrame, list[dict]]:
    """Outcome counts of verifying the Newton run against conic, the rows that do not agree, and the objectives
    of the certified pairs that differ by more than 1e-3 in f (``steps``: the run's problems, from
    :func:`newton_run`)."""
    scene = _newton_scene(beta, second_start)
    t0 = time.perf_counter()
    ver = verify(scene, "conic")
    table = ver.table
    counts = {"beta": beta, "second_start": second_start, "compared": len(table),
              **table["outcome"].value_counts().to_dict(), "verdict": ver.verdict,
              "wall_s": round(time.perf_counter() - t0, 1)}  # fmt: skip
    bad = table[table["outcome"] != "agree"].assign(beta=beta, second_start=second_start)
    wide = bad[(bad["outcome"] == "differ") & (bad["df"] > 1e-3)]
    minima = []
    if len(wide):
        for _, row in wide.iterrows():
            problem, options = steps[int(row["step"]) - 1]
            p = problem.slice(int(row["slice"]))
            first = solve_collision(p, method="newton", **{**options, "second_start": False})
            newton = solve_collision(p, method="newton", **{**options, "second_start": True})
            conic_ref, nlp_ref = solve_reference(p, "conic", {}), solve_reference(p, "nlp", {})
            minima.append({
                "beta": beta, "run_second_start": second_start, "step": int(row["step"]), "t": row["t"],
                "slice": int(row["slice"]), "cfl": p.cfl(), "J_newton_first": p.objective(first.f, first.m),
                "J_newton": p.objective(newton.f, newton.m), "J_conic": p.objective(conic_ref.f, conic_ref.m),
                "J_nlp": p.objective(nlp_ref.f, nlp_ref.m), "newton": newton.status.name,
                "lower_minimum": bool(newton.info["lower_minimum"]), "conic": conic_ref.status.name,
                "nlp": nlp_ref.status.name,
                "df_first_conic": float(np.abs(first.f - conic_ref.f).max() / conic_ref.f.max()),
                "df_newton_conic": float(np.abs(newton.f - conic_ref.f).max() / conic_ref.f.max()),
                "df_conic_nlp": float(np.abs(conic_ref.f - nlp_ref.f).max() / conic_ref.f.max()),
            })  # fmt: skip
    return counts, bad, minima


def main() -> None:
    tree = tree_label()
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M")
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    runs, slices, problems = [], [], {}
    for beta in BETAS:
        t0 = time.perf_counter()
        conic, failed = run_conic(beta)
        t_conic = time.perf_counter() - t0
        newtons = {}
        for second_start in (True, False):
            t0 = time.perf_counter()
            run, counts, problems[beta, second_start] = newton_run(beta, second_start)
            newtons[second_start] = (run, counts, time.perf_counter() - t0)
        newton = newtons[True][0]
        b = newton.diagnostics["max_f"].to_numpy()
        labels = [("conic", conic, {}, t_conic)]
        labels += [(f"newton (second_start={flag})", r, counts, secs) for flag, (r, counts, secs) in newtons.items()]
        for name, r, counts, secs in labels:
            a = r.diagnostics["max_f"].to_numpy()
            n = min(a.size, b.size)
            runs.append({
                "date": date, "commit": tree, "threads": threads, "beta": beta, "method": name, "t": r.t,
                "steps": r.steps, "stop": r.verdict.stop.name, "reason": r.verdict.reason, "wall_s": round(secs, 2),
                "max_rel_dmax_f_vs_newton": float(np.max(np.abs(a[:n] - b[:n]) / b[:n])), **counts,
            })  # fmt: skip
        slices += [{"date": date, "commit": tree, "beta": beta, "t": conic.t, **row} for row in failed if conic.t < 1]
        print(runs[-3:], failed, flush=True)
    counts, bads, minima = [], [], []
    for beta in BETAS:
        for second_start in (True, False):
            c, b, mins = verify_part(beta, second_start, problems[beta, second_start])
            counts.append(c)
            bads.append(b)
            minima += mins
            print(c, flush=True)
    count_frame = pd.DataFrame(counts).fillna(0)
    verify_path = OUT.with_name("conic_scene_runs_verify.csv")
    minima_path = OUT.with_name("conic_scene_runs_minima.csv")
    pd.concat(bads).to_csv(verify_path, index=False)
    minima_frame = pd.DataFrame(minima)
    minima_frame.to_csv(minima_path, index=False)
    frame = pd.DataFrame(runs)
    frame.to_csv(OUT, index=False)
    failed_frame = pd.DataFrame(slices)
    failed_frame.to_csv(OUT.with_name("conic_scene_runs_failed_slices.csv"), index=False)
    record_csv(OUT, OUT.with_name("conic_scene_runs_failed_slices.csv"), verify_path, minima_path)
    text = [
        "# The conic method on the paper's gamma = 3 scene (`studies/conic_scene_runs.py`)",
        "",
        f"{date} UTC, code {tree}, OPENBLAS_NUM_THREADS={threads}.  `inhom_gamma3_lambda4`, 61 x 61, perspective "
        "form, to t = 1; runs under conic certify at its kkt_tol 1e-6, Newton's at 1e-8.  Newton runs with its second "
        "start (the default) and without it; `max_rel_dmax_f_vs_newton`: max f against the default Newton run at the "
        "common records; `slice_steps`, `jammed`, `lower_minimum`: the run's slice-steps, those whose first attempt "
        "jammed at the vacuum boundary, and those where the second start returned a lower certified J.",
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
        "## The Newton runs verified against the conic reference (every step and slice, to t = 1)",
        "",
        "`second_start`: Newton's second start on slices that jammed at the vacuum boundary (the default), or "
        "not (the first certified point, as before it existed).",
        "",
        count_frame.drop(columns=["verdict"]).to_markdown(index=False),
        "",
        *(f"- beta = {c['beta']:g}, second_start = {c['second_start']}: {c['verdict']}" for c in counts),
        "",
        "The rows that do not agree are in `conic_scene_runs_verify.csv`.  Where both solvers are certified and "
        "differ by more than 1e-3 in f, the step solved again by Newton without the second start (`J_newton_first`) "
        "and with it (`J_newton`; `lower_minimum`: the second start replaced the first certified point), the run's "
        "options otherwise, by the conic reference and by IPOPT (the objective J of each answer; the step is not "
        "convex there, and a certificate is local; `run_second_start`: the run the step comes from):",
        "",
        minima_frame.to_markdown(index=False, floatfmt=".10g") if len(minima_frame) else "(none)",
        "",
    ]
    write_markdown(OUT.with_suffix(".md"), "\n".join(text))
    print("\n".join(text))


if __name__ == "__main__":
    main()
