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

Run (the tables of docs/guides/solvers.md):
``OPENBLAS_NUM_THREADS=1 python studies/bench_collision.py --sizes 61 121 241 481``.
Writes ``studies/results/bench_collision.csv`` (first part), ``bench_newton.csv`` (against
beta), ``bench_newton_growth.csv`` (Newton against N), ``bench_newton_batch.csv`` (the
batch) and ``bench_collision.md`` (every table, with the date, the code, the thread
setting and the machine's load), and prints the report; docs/guides/solvers.md quotes these files
(claims ``bench.*`` of ``tests/readme_claims.py``).
"""

from __future__ import annotations

import argparse
import datetime
import os
import shlex
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
from jko_cvx.collision import conic, nlp
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.sweep import code_provenance
from jko_cvx.threads import thread_environment


def bench(n: int, repeats: int, beta: float = 10.0, dt: float = 0.01, fisher: str = "perspective") -> list[dict]:
    grid = Grid.uniform(-2.0, 2.0, n)
    prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), dt, beta=beta, fisher=fisher)
    rows = []
    methods = ("conic", "sqp", "newton", "newton_compiled", "nlp")
    if fisher == "log":
        methods = methods[1:]
    first, first_wall = {}, {}
    for method in ("conic", "nlp"):
        if method not in methods:
            continue
        (conic if method == "conic" else nlp)._MODEL_CACHE.clear()  # measure the build on a fresh cache
        t0 = time.perf_counter()
        first[method] = solve_collision(prob, method=method)
        first_wall[method] = time.perf_counter() - t0
    solve_collision(prob, method="newton", compiled=True)  # numba: load (or compile) outside the timings
    for method in methods:
        times, res = [], None
        name, opts = _method(method)
        for _ in range(repeats):
            t0 = time.perf_counter()
            res = solve_collision(prob, method=name, **opts)
            times.append(time.perf_counter() - t0)
        if method == "newton_compiled" and not res.info["compiled"]:
            raise RuntimeError(f"the compiled Newton iteration handed N = {n} ({fisher}) back: not its timing")
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


def _method(label: str) -> tuple[str, dict]:
    """The method and options of a benchmark label (``newton_compiled``: Newton with ``compiled=True``)."""
    return ("newton", {"compiled": True}) if label == "newton_compiled" else (label, {})


def bench_newton_sqp(repeats: int, sizes: list[int]) -> pd.DataFrame:
    """Newton (NumPy and compiled) against the paper's SQP: both Fisher forms, beta = 10 and 1000, every N.

    The three are interleaved in each round (they share the machine's conditions), each timed over its own
    number of consecutive solves (about 20 ms of them); every solve runs at the methods' defaults (the SQP's
    zeta test, Newton's KKT tolerance 1e-10).
    """
    rows = []
    for fisher in ("perspective", "log"):
        for beta in (10.0, 1000.0):
            for n in sizes:
                grid = Grid.uniform(-2.0, 2.0, n)
                f0 = np.exp(-2 * grid.points**2)
                prob = CollisionProblem(grid, PowerKernel(1.0), f0, 0.01, beta=beta, fisher=fisher)
                calls = {k: _method(k) for k in ("sqp", "newton", "newton_compiled")}
                last = {k: solve_collision(prob, method=m, **o) for k, (m, o) in calls.items()}  # warm-up
                # each method over about 20 ms of consecutive solves (the SQP at its cap takes seconds per solve,
                # the compiled Newton about 0.1 ms)
                inner = {k: max(1, int(0.02 / max(1e-5, r.seconds))) for k, r in last.items()}
                times = {k: [] for k in calls}
                for _ in range(repeats):
                    for k, (method, opts) in calls.items():
                        t0 = time.perf_counter()
                        for _ in range(inner[k]):
                            last[k] = solve_collision(prob, method=method, **opts)
                        times[k].append((time.perf_counter() - t0) / inner[k])
                row = {"fisher": fisher, "beta": beta, "N": n}
                for k in calls:
                    row[f"{k}_s"] = statistics.median(times[k])
                    row[f"{k}_it"] = last[k].iterations
                    row[f"{k}_kkt"] = last[k].kkt_residual
                    row[f"{k}_status"] = last[k].status.name
                row["compiled_used"] = bool(last["newton_compiled"].info["compiled"])
                row["sqp/newton"] = row["sqp_s"] / row["newton_s"]
                row["sqp/newton_compiled"] = row["sqp_s"] / row["newton_compiled_s"]
                rows.append(row)
    return pd.DataFrame(rows)


def _median_time(fn, repeats: int) -> tuple[float, object]:
    fn()  # warm-up (compilation, caches)
    times, res = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), res


def bench_newton(repeats: int) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    grid = Grid.uniform(-2.0, 2.0, 121)
    f0 = np.exp(-2 * grid.points**2)
    rows = []
    opts = {
        "conic": {}, "sqp": {"tol": 1e-12, "max_iter": 100000}, "newton": {"tol": 1e-9},
        "newton_compiled": {"tol": 1e-9, "compiled": True},
    }  # fmt: skip
    # Methods are interleaved inside each round so that they share the machine's
    # conditions; Newton is timed over `inner` consecutive solves (it is ~1 ms).
    inner = {"conic": 1, "sqp": 1, "newton": 10, "newton_compiled": 20}
    for beta in (1.0, 3.0, 10.0, 30.0):
        prob = CollisionProblem(grid, PowerKernel(1.0), f0, 0.01, beta=beta)
        times = {k: [] for k in opts}
        last = {k: solve_collision(prob, method=_method(k)[0], **opts[k]) for k in opts}  # warm-up
        for r in range(repeats):
            for method in opts:
                if method == "sqp" and beta <= 1 and r >= 3:
                    continue  # 0.7 s per solve: three rounds suffice
                t0 = time.perf_counter()
                for _ in range(inner[method]):
                    last[method] = solve_collision(prob, method=_method(method)[0], **opts[method])
                times[method].append((time.perf_counter() - t0) / inner[method])
        row = {"beta": beta}
        for method in opts:
            row[f"{method}_s"] = statistics.median(times[method])
            row[f"{method}_it"] = last[method].iterations
            row[f"{method}_kkt"] = last[method].kkt_residual
        row["conic/newton"] = row["conic_s"] / row["newton_s"]
        row["sqp/newton"] = row["sqp_s"] / row["newton_s"]
        row["conic/newton_compiled"] = row["conic_s"] / row["newton_compiled_s"]
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
    batch_table = pd.DataFrame(
        [{"slices": 121, "batched_s": t_batch, "converged": ok, "max_kkt": float(np.max(res_b.kkt_residual)),
          "one_at_a_time_s": t_loop}]
    )  # fmt: skip
    # growth with N
    sizes = [61, 121, 241, 481]
    ts = []
    for n in sizes:
        g = Grid.uniform(-2.0, 2.0, n)
        p = CollisionProblem(g, PowerKernel(1.0), np.exp(-2 * g.points**2), 0.01, beta=10.0)
        ts.append(_median_time(lambda p=p: solve_collision(p, method="newton", tol=1e-9), repeats)[0])
    by_n = pd.DataFrame({"N": sizes, "newton_s": ts})
    return by_beta, by_n, batch_table


def _table(df: pd.DataFrame, floatfmt: str = ".3g") -> str:
    return df.to_markdown(index=False, floatfmt=floatfmt) if _has_tabulate() else df.to_string(index=False)


def report(
    df: pd.DataFrame,
    by_beta: pd.DataFrame | None,
    by_n: pd.DataFrame | None,
    batch: pd.DataFrame | None,
    header: str,
    newton_sqp: pd.DataFrame | None = None,
) -> str:
    """The Markdown report: the provenance ``header``, then every table the run measured."""
    parts = [header]
    for fisher, part in df.groupby("fisher", sort=False):
        parts.append(f"### {fisher} Fisher, median s per solve\n\n" + _table(part.drop(columns="fisher")))
        piv = part.pivot(index="N", columns="method", values="median_s")
        pairs = (("conic", "sqp"), ("conic", "newton"), ("sqp", "newton"), ("nlp", "conic"), ("nlp", "sqp"),
                 ("conic", "newton_compiled"), ("sqp", "newton_compiled"), ("newton", "newton_compiled"))  # fmt: skip
        for a, b in pairs:
            if a in piv and b in piv:
                text = ", ".join(f"N = {n}: {r:.3g}" for n, r in (piv[a] / piv[b]).items())
                parts.append(f"- {fisher}: {a} / {b} (medians per solve): {text}")
    if by_beta is not None:
        parts.append("### Against the Fisher weight (N = 121), median s per solve\n\n" + _table(by_beta))
    if by_n is not None:
        expo = float(np.polyfit(np.log(by_n.N), np.log(by_n.newton_s), 1)[0])
        parts.append(f"### Newton per solve against N (fitted exponent {expo:.2f})\n\n" + _table(by_n))
    if batch is not None:
        parts.append("### Batched Newton, 121 slices of N = 121\n\n" + _table(batch))
    if newton_sqp is not None:
        slowest = newton_sqp[["sqp/newton", "sqp/newton_compiled"]].min()
        parts.append(
            "### Newton against the paper's SQP (gamma = 1, dt = 0.01), median s per solve\n\n"
            f"Smallest ratio SQP / Newton over the table: {slowest['sqp/newton']:.3g} (NumPy iteration), "
            f"{slowest['sqp/newton_compiled']:.3g} (compiled).\n\n" + _table(newton_sqp)
        )
    return "\n\n".join(parts) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--sizes", type=int, nargs="+", default=[61, 121, 241])
    ap.add_argument("--no-newton", dest="newton", action="store_false", help="skip the fast-solver part")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_collision.csv")
    args = ap.parse_args(argv)
    if args.repeats < 1 or any(n < 5 for n in args.sizes):
        ap.error("--repeats must be >= 1 and every --sizes entry >= 5")
    code = code_provenance(bench)  # before the run: an edit meanwhile cannot change the record
    load0 = os.getloadavg()[0]
    rows = [r for fisher in ("perspective", "log") for n in args.sizes for r in bench(n, args.repeats, fisher=fisher)]
    df = pd.DataFrame(rows)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out, index=False)
    record_csv(args.out)
    by_beta = by_n = batch = newton_sqp = None
    if args.newton:
        by_beta, by_n, batch = bench_newton(args.repeats)
        by_beta.to_csv(args.out.with_name("bench_newton.csv"), index=False)
        record_csv(args.out.with_name("bench_newton.csv"))
        by_n.to_csv(args.out.with_name("bench_newton_growth.csv"), index=False)
        record_csv(args.out.with_name("bench_newton_growth.csv"))
        batch.to_csv(args.out.with_name("bench_newton_batch.csv"), index=False)
        record_csv(args.out.with_name("bench_newton_batch.csv"))
        newton_sqp = bench_newton_sqp(args.repeats, args.sizes)
        newton_sqp.to_csv(args.out.with_name("bench_newton_sqp.csv"), index=False)
        record_csv(args.out.with_name("bench_newton_sqp.csv"))
    header = (
        "# One collision step, four methods (`studies/bench_collision.py`)\n\n"
        f"`{shlex.join(['bench_collision.py', *(argv if argv is not None else sys.argv[1:])])}`, finished "
        f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC on this {os.cpu_count()}-core machine; "
        f"code {code['package_sha256'][:12]} (git {str(code['git_commit'])[:12]}, jko_cvx modified: "
        f"{code['jko_cvx_modified']}); threads: {thread_environment()}; 1-minute load "
        f"{load0:.2f} before, {os.getloadavg()[0]:.2f} after.  Medians of {args.repeats} solves per row, "
        "methods side by side in one process."
    )
    text = report(df, by_beta, by_n, batch, header, newton_sqp)
    write_markdown(args.out.with_suffix(".md"), text)
    print(text)
    print(f"wrote {args.out} and {args.out.with_suffix('.md').name}")


def _has_tabulate() -> bool:
    try:
        import tabulate  # noqa: F401
    except ImportError:
        return False
    return True


if __name__ == "__main__":
    main()
