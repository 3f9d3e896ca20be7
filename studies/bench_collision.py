"""Benchmark of one collision step: conic reference (CVXPY + Clarabel) vs the paper's SQP.

Problem: gamma = 1, f* = exp(-2 v^2) on a uniform grid of [-2, 2], dt = 0.01,
perspective Fisher term with beta = 10.  For each N the script reports the median wall
time per solve over ``--repeats`` solves (measured side by side in one run), the
iterations, the KKT residual reached and, for CVXPY, the one-off compile time apart
from the re-solve time (the model is DPP: compiled once per N, then re-solved with new
parameter values).

Run: ``python studies/bench_collision.py [--repeats 7] [--sizes 61 121 241]``.
Writes ``studies/results/bench_collision.csv`` and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import pandas as pd

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
from jko_cvx.collision import conic


def bench(n: int, repeats: int, beta: float = 10.0, dt: float = 0.01) -> list[dict]:
    grid = Grid.uniform(-2.0, 2.0, n)
    prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), dt, beta=beta)
    rows = []
    conic._MODEL_CACHE.clear()  # measure the compile on a fresh cache
    t0 = time.perf_counter()
    first = solve_collision(prob, method="conic")
    first_wall = time.perf_counter() - t0
    for method in ("conic", "sqp"):
        times, res = [], None
        for _ in range(repeats):
            t0 = time.perf_counter()
            res = solve_collision(prob, method=method)
            times.append(time.perf_counter() - t0)
        row = {
            "N": n,
            "method": method,
            "median_s": statistics.median(times),
            "iterations": res.iterations,
            "kkt_residual": res.kkt_residual,
            "status": res.status.name,
            "objective": res.objective,
        }
        if method == "conic":
            row["passes"] = res.info["passes"]
            row["compile_s"] = first.info["compile_seconds"]
            row["first_solve_s"] = first_wall
            row["clarabel_s"] = res.info["solver_seconds"]
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--sizes", type=int, nargs="+", default=[61, 121, 241])
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_collision.csv")
    args = ap.parse_args(argv)
    rows = [r for n in args.sizes for r in bench(n, args.repeats)]
    df = pd.DataFrame(rows)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out, index=False)
    cols = ["N", "method", "median_s", "iterations", "passes", "kkt_residual", "compile_s", "clarabel_s", "status"]
    print(df[cols].to_markdown(index=False, floatfmt=".3g") if _has_tabulate() else df[cols].to_string(index=False))
    piv = df.pivot(index="N", columns="method", values="median_s")
    print(
        "\nratio conic / sqp (median per solve):",
        ", ".join(f"N={n}: {r:.2f}" for n, r in (piv.conic / piv.sqp).items()),
    )
    print(f"wrote {args.out}")


def _has_tabulate() -> bool:
    try:
        import tabulate  # noqa: F401
    except ImportError:
        return False
    return True


if __name__ == "__main__":
    main()
