"""Where a step of the ``inhom_gamma1p5`` crawl spends its time (issue 15, item 5).

The regeneration of the numerical section is bounded by one serial run: ``inhom_gamma1p5``
lambda = 10 on 121 x 121 reaches the paper's criterion after thousands of CFL steps on a
collapsed grid.  This benchmark runs the shipped scene (``--case``, ``--n``) to ``--t-end``
and records, per step, the collision's wall time and the Newton iterations of every slice
(the engine's own solves, observed by wrapping ``jko_cvx.engine.loop.solve_collision``; nothing
else changes).  It reports the split of the run's time (collision, transport, refinement),
the distribution of iterations over slices, and the share of slice-iterations spent on
stragglers (slices needing ``--straggler`` iterations or more): the measure any faster
globalisation of Newton has to move.  A change to the solver is judged by running this
script before and after it, in one session, on the same machine.

Run: ``python studies/bench_crawl.py [--case before] [--n 121] [--t-end 0.3]``; writes
``studies/results/bench_crawl.{csv,md}`` (per step, and the summary with the BLAS setting
and the load).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
from bench_threads import blas_setting

import jko_cvx.engine.loop as engine
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.reproduce.gamma1p5 import gamma1p5_scene
from jko_cvx.studies.sweep import code_provenance

RESULTS = Path(__file__).parent / "results"


def run(case: str, n: int, t_end: float, straggler: int) -> tuple[pd.DataFrame, dict]:
    """The scene to ``t_end`` with every collision solve observed; per-step rows and the run's totals."""
    rows: list[dict] = []
    solve = engine.solve_collision

    def observed(problem, method, **opts):
        t0 = time.perf_counter()
        res = solve(problem, method=method, **opts)
        it = np.atleast_1d(res.iterations)
        slow = it >= straggler
        rows.append(
            {
                "collision_s": time.perf_counter() - t0,
                "slices": it.size,
                "iterations_sum": int(it.sum()),
                "iterations_max": int(it.max()),
                "stragglers": int(slow.sum()),
                "straggler_iterations": int(it[slow].sum()),
                "one_iteration_slices": int((it <= 1).sum()),
            }
        )
        return res

    scene = gamma1p5_scene(case, n, {"t_end": t_end, "output.times": []})
    engine.solve_collision = observed
    try:
        t0 = time.perf_counter()
        result = engine.simulate(scene)
        wall = time.perf_counter() - t0
    finally:
        engine.solve_collision = solve
    return pd.DataFrame(rows), {"wall_s": wall, **{f"{k}_s": v for k, v in result.seconds.items()}}


def report(steps: pd.DataFrame, totals: dict, args: argparse.Namespace, prov: dict) -> str:
    share = steps.straggler_iterations.sum() / steps.iterations_sum.sum()
    lines = [
        f"# inhom_gamma1p5 crawl: {args.case}, {args.n} x {args.n}, to t = {args.t_end}",
        "",
        f"Code: commit {str(prov['git_commit'])[:12]}, package sha256 {prov['package_sha256'][:12]}"
        f"{' (jko_cvx modified)' if prov['jko_cvx_modified'] else ''}; {blas_setting()}; 1-minute load "
        f"{os.getloadavg()[0]:.2f} at the end; measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.",
        "",
        f"- {len(steps)} collision solves (steps and retries), {totals['wall_s']:.1f} s of wall time: collision "
        f"{totals.get('collision_s', float('nan')):.1f} s, transport {totals.get('transport_s', float('nan')):.1f} s, "
        f"refinement {totals.get('refine_s', float('nan')):.1f} s.",
        f"- Per solve (median): {steps.collision_s.median() * 1e3:.1f} ms, {steps.iterations_sum.median():.0f} "
        f"slice-iterations over {steps.slices.median():.0f} slices, slowest slice "
        f"{steps.iterations_max.median():.0f} iterations (largest {steps.iterations_max.max()}).",
        f"- Stragglers (>= {args.straggler} iterations): {steps.stragglers.median():.0f} slices per solve (median), "
        f"{100 * share:.0f} % of all slice-iterations; slices done in one iteration: "
        f"{steps.one_iteration_slices.median():.0f} per solve (median).",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", choices=("before", "after"), default="before")
    ap.add_argument("--n", type=int, default=121, help="points per axis")
    ap.add_argument("--t-end", type=float, default=0.3)
    ap.add_argument("--straggler", type=int, default=10, help="iterations from which a slice counts as a straggler")
    args = ap.parse_args(argv)
    if args.n < 11 or not (0 < args.t_end <= 1.0) or args.straggler < 2:
        ap.error("need --n >= 11, 0 < --t-end <= 1 and --straggler >= 2")
    prov = code_provenance(engine.simulate)  # before the run: a file edited meanwhile cannot change the record
    steps, totals = run(args.case, args.n, args.t_end, args.straggler)
    RESULTS.mkdir(parents=True, exist_ok=True)
    steps.to_csv(RESULTS / "bench_crawl.csv", index=False)
    record_csv(RESULTS / "bench_crawl.csv")
    text = report(steps, totals, args, prov)
    write_markdown(RESULTS / "bench_crawl.md", text)
    print(text)


if __name__ == "__main__":
    main()
