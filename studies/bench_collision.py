"""Benchmark of one collision step: conic reference (CVXPY + Clarabel), the paper's SQP, Newton, nlp (CVXPY + IPOPT).

Problem: gamma = 1, f* = exp(-2 v^2) on a uniform grid of [-2, 2], dt = 0.01,
perspective Fisher term with beta = 10 (all four methods), then the same with the log
Fisher term (the paper's; conic cannot take it).  For each N the script reports the
median wall time per solve over ``--repeats`` solves (measured side by side in one run),
the iterations, the KKT residual reached and, for CVXPY, the one-off build apart from the
re-solve time: conic's compile (the model is DPP: compiled once per N, then re-solved
with new parameter values) and nlp's model and derivative-oracle build (once per N and
Fisher form; each solve still runs CVXPY's reduction chain, ``canonicalize_s``, and IPOPT,
``ipopt_s``).

Second part (the fast solver): at N = 121, gamma = 1, f* = exp(-2 v^2), dt = 0.01 and
beta in {1, 3, 10, 30}, every method is run to a KKT residual of 1e-9 or its best
(Newton tol 1e-9; SQP zeta tolerance 1e-12; conic at its default tolerance, whose best
is about 1e-8), with the ratios conic/newton and sqp/newton from the same run; then the
batched throughput (121 slices of N = 121) and Newton's time per solve against N with
the fitted growth exponent.

Run: ``python studies/bench_collision.py [--repeats 7] [--sizes 61 121 241]``.
Writes ``studies/results/bench_collision.csv`` and ``bench_newton.csv`` and prints
Markdown tables.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import pandas as pd

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
from jko_cvx.collision import conic, nlp


def bench(n: int, repeats: int, beta: float = 10.0, dt: float = 0.01, fisher: str = "perspective") -> list[dict]:
    grid = Grid.uniform(-2.0, 2.0, n)
    prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), dt, beta=beta, fisher=fisher)
    rows = []
    methods = ("conic", "sqp", "newton", "nlp") if fisher != "log" else ("sqp", "newton", "nlp")
    first, first_wall = {}, {}
    for method in ("conic", "nlp"):
        if method not in methods:
            continue
        (conic if method == "conic" else nlp)._MODEL_CACHE.clear()  # measure the build on a fresh cache
        t0 = time.perf_counter()
        first[method] = solve_collision(prob, method=method)
        first_wall[method] = time.perf_counter() - t0
    for method in methods:
        times, res = [], None
        for _ in range(repeats):
            t0 = time.perf_counter()
            res = solve_collision(prob, method=method)
            times.append(time.perf_counter() - t0)
        row = {
            "fisher": fisher,
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
            row["compile_s"] = first[method].info["compile_seconds"]
            row["first_solve_s"] = first_wall[method]
            row["clarabel_s"] = res.info["solver_seconds"]
        if method == "nlp":
            row["compile_s"] = first[method].info["build_seconds"]
            row["first_solve_s"] = first_wall[method]
            row["canonicalize_s"] = res.info["canonicalize_seconds"]
            row["ipopt_s"] = res.info["solver_seconds"]
        rows.append(row)
    return rows


def _median_time(fn, repeats: int) -> tuple[float, object]:
    fn()  # warm-up (compilation, caches)
    times, res = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), res


def bench_newton(repeats: int) -> tuple[pd.DataFrame, pd.DataFrame, str]:
    grid = Grid.uniform(-2.0, 2.0, 121)
    f0 = np.exp(-2 * grid.points**2)
    rows = []
    opts = {"conic": {}, "sqp": {"tol": 1e-12, "max_iter": 100000}, "newton": {"tol": 1e-9}}
    # Methods are interleaved inside each round so that they share the machine's
    # conditions; Newton is timed over `inner` consecutive solves (it is ~1 ms).
    inner = {"conic": 1, "sqp": 1, "newton": 10}
    for beta in (1.0, 3.0, 10.0, 30.0):
        prob = CollisionProblem(grid, PowerKernel(1.0), f0, 0.01, beta=beta)
        times = {k: [] for k in opts}
        last = {k: solve_collision(prob, method=k, **opts[k]) for k in opts}  # warm-up
        for r in range(repeats):
            for method in opts:
                if method == "sqp" and beta <= 1 and r >= 3:
                    continue  # 0.7 s per solve: three rounds suffice
                t0 = time.perf_counter()
                for _ in range(inner[method]):
                    last[method] = solve_collision(prob, method=method, **opts[method])
                times[method].append((time.perf_counter() - t0) / inner[method])
        row = {"beta": beta}
        for method in opts:
            row[f"{method}_s"] = statistics.median(times[method])
            row[f"{method}_it"] = last[method].iterations
            row[f"{method}_kkt"] = last[method].kkt_residual
        row["conic/newton"] = row["conic_s"] / row["newton_s"]
        row["sqp/newton"] = row["sqp_s"] / row["newton_s"]
        rows.append(row)
    by_beta = pd.DataFrame(rows)
    # batched throughput: 121 slices of N = 121 (shifted and scaled Gaussians)
    rng = np.random.default_rng(0)
    F = np.stack([rng.uniform(0.5, 2) * np.exp(-2 * (grid.points - rng.uniform(-0.3, 0.3)) ** 2) for _ in range(121)])
    batch = CollisionProblem(grid, PowerKernel(1.0), F, 0.01, beta=10.0)
    t_batch, res_b = _median_time(lambda: solve_collision(batch, method="newton", tol=1e-9), max(3, repeats // 2))
    ok = int(np.sum(res_b.success))
    t_loop, _ = _median_time(
        lambda: [solve_collision(batch.slice(i), method="newton", tol=1e-9) for i in range(121)], 1
    )
    batch_line = (
        f"batched Newton, 121 slices of N = 121: {t_batch:.3f} s ({ok}/121 converged, max KKT "
        f"{np.max(res_b.kkt_residual):.1e}); one at a time: {t_loop:.3f} s"
    )
    # growth with N
    sizes = [61, 121, 241, 481]
    ts = []
    for n in sizes:
        g = Grid.uniform(-2.0, 2.0, n)
        p = CollisionProblem(g, PowerKernel(1.0), np.exp(-2 * g.points**2), 0.01, beta=10.0)
        ts.append(_median_time(lambda p=p: solve_collision(p, method="newton", tol=1e-9), repeats)[0])
    expo = float(np.polyfit(np.log(sizes), np.log(ts), 1)[0])
    by_n = pd.DataFrame({"N": sizes, "newton_s": ts})
    return by_beta, by_n, batch_line + f"\nNewton time per solve vs N: fitted exponent {expo:.2f}"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--sizes", type=int, nargs="+", default=[61, 121, 241])
    ap.add_argument("--no-newton", dest="newton", action="store_false", help="skip the fast-solver part")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_collision.csv")
    args = ap.parse_args(argv)
    rows = [r for fisher in ("perspective", "log") for n in args.sizes for r in bench(n, args.repeats, fisher=fisher)]
    df = pd.DataFrame(rows)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out, index=False)
    cols = ["fisher", "N", "method", "median_s", "iterations", "passes", "kkt_residual", "compile_s"]
    cols += ["clarabel_s", "canonicalize_s", "ipopt_s", "status"]
    print(df[cols].to_markdown(index=False, floatfmt=".3g") if _has_tabulate() else df[cols].to_string(index=False))
    for fisher, part in df.groupby("fisher", sort=False):
        piv = part.pivot(index="N", columns="method", values="median_s")
        ratios = [(a, b) for a, b in (("conic", "sqp"), ("nlp", "newton"), ("nlp", "sqp")) if a in piv and b in piv]
        for a, b in ratios:
            text = ", ".join(f"N={n}: {r:.3g}" for n, r in (piv[a] / piv[b]).items())
            print(f"{fisher}: ratio {a} / {b} (median per solve): {text}")
    print(f"wrote {args.out}")
    if args.newton:
        by_beta, by_n, lines = bench_newton(args.repeats)
        by_beta.to_csv(args.out.with_name("bench_newton.csv"), index=False)
        show = by_beta.to_markdown(index=False, floatfmt=".3g") if _has_tabulate() else by_beta.to_string(index=False)
        print("\nN = 121, gamma = 1, dt = 0.01 (median s per solve, iterations, KKT residual reached):\n" + show)
        print(by_n.to_markdown(index=False, floatfmt=".3g") if _has_tabulate() else by_n.to_string(index=False))
        print(lines)


def _has_tabulate() -> bool:
    try:
        import tabulate  # noqa: F401
    except ImportError:
        return False
    return True


if __name__ == "__main__":
    main()
