"""Benchmark of the conic reference at gamma = 3 with the energy operator shared by content.

The DC split of the energy (``EnergyOperator.split``: an eigendecomposition of the kernel on
mass-free directions) is computed once per (grid points, gamma) and then served from a bounded
cache (:func:`jko_cvx.kernels.operator_cache_info`).  This script measures, in CPU seconds of
this process (``time.process_time``: the machine is shared, so wall time says more about the
neighbours than about the code), side by side in one run:

Part A -- one conic solve at gamma = 3, N = 121, 241, 481: f* = exp(-2 v^2) on [-2, 2],
dt = 0.01, perspective Fisher beta = 10, with ``dc_split = "eigen"`` (the exact convex part) and with
``"truncated"`` (the default: the leading eigenvalues exactly, a diagonal majorant of the rest).  ``first``:
the first solve at this N in the process (the split and CVXPY's DPP compile of the model
included); ``split``: the operator and its split alone, from an empty cache; then alternating
repeats on new grid objects with equal points,
``cached`` (the split from the cache) and ``uncached`` (the cache emptied before each, so the
split is recomputed as a per-grid-object cache did every step); medians, and the growth exponent
from N = 121 to the largest N (the issue's target: at most 1.5).

Part B -- ``verify`` of ``inhom_gamma3_lambda4`` at 61 x 61 with the perspective form, beta =
30, against conic (both splits), every step, against the scene's own run (the issue's target:
at most 10x): medians of ``--repeats`` - 1 runs each after one warm-up of both (the warm-up pays
CVXPY's import and the model compiles, reported apart), then one verification under cProfile
with its time split by where it goes.  Every verification solves its references in this process
(``workers=1``): the CPU time of this process is then all of it (``studies/bench_verify.py``
measures the worker processes).

Run: ``OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 python studies/bench_conic_split.py`` (about
3 minutes on 2 shared cores; ``--sizes 61 121`` for a quick look).  Writes
``studies/results/bench_conic_split.csv`` (part A), ``bench_conic_split_verify.csv`` (part B)
and ``bench_conic_split.md`` (both, with the environment and thread setting).
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
from jko_cvx.collision.conic import clear_model_cache
from jko_cvx.engine.loop import simulate
from jko_cvx.engine.verify import verify
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.kernels import clear_operator_cache, operator_cache_info
from jko_cvx.scene import shipped_scene
from jko_cvx.threads import thread_environment

RESULTS = Path(__file__).parent / "results"


def cpu(fn: Callable[[], object]) -> tuple[float, object]:
    """(CPU seconds of this process, result) of one call."""
    t0 = time.process_time()
    out = fn()
    return time.process_time() - t0, out


def _problem(n: int) -> CollisionProblem:
    g = Grid.uniform(-2.0, 2.0, n)  # a new grid object every time: a hit is by content
    return CollisionProblem(g, PowerKernel(3.0), np.exp(-2 * g.points**2), 0.01, beta=10.0, fisher="perspective")


SPLITS = ("eigen", "truncated")


def conic_solves(sizes: list[int], repeats: int) -> pd.DataFrame:
    rows = []
    for split_name, n in ((s, n) for s in SPLITS for n in sizes):
        def one(n: int = n, split_name: str = split_name) -> object:
            return solve_collision(_problem(n), method="conic", dc_split=split_name)

        clear_operator_cache()
        clear_model_cache()
        first, res = cpu(one)
        compile_s = res.info["compile_seconds"]
        clear_operator_cache()
        split, _ = cpu(lambda n=n: _problem(n).energy.split())
        cached, uncached, out = [], [], {}
        for _ in range(repeats):  # alternate, so both see the same neighbours
            t, out["cached"] = cpu(one)
            cached.append(t)
            clear_operator_cache()
            t, out["uncached"] = cpu(one)
            uncached.append(t)
        a, b = out["cached"], out["uncached"]
        same = a.status is b.status and np.array_equal(a.f, b.f) and np.array_equal(a.m, b.m)
        rows.append({
            "dc_split": split_name, "N": n, "first_s": first, "compile_wall_s": compile_s, "split_s": split,
            "cached_s": statistics.median(cached), "uncached_s": statistics.median(uncached),
            "solver_s": out["cached"].info["solver_seconds"], "passes": out["cached"].info["passes"],
            "ipm_iterations": out["cached"].iterations, "status": out["cached"].status.name,
            "kkt_residual": float(out["cached"].kkt_residual), "identical": same,
        })  # fmt: skip
        print(rows[-1], flush=True)
    return pd.DataFrame(rows)


def exponent(df: pd.DataFrame, column: str, split: str) -> float:
    d = df[(df.N >= 121) & (df.dc_split == split)]
    return float(np.polyfit(np.log(d.N), np.log(d[column]), 1)[0]) if len(d) >= 2 else float("nan")


# Where a verification's time goes: cumulative CPU of these functions under cProfile (nested
# ones are inside their callers: the rows are not a partition).
_BUCKETS = {
    "Clarabel solve (the IPM itself)": ("solve", "builtins.DefaultSolver"),
    "CVXPY: fill parameters into the compiled data": ("apply_parameters", "cone_matrix_stuffing"),
    "CVXPY: Clarabel interface (new_solver, invert)": ("solve_via_data", "clarabel_conif"),
    "conic: certificate of each reference solve": ("certify", "certify.py"),
    "estimate: error bound in f (both solves)": ("f_error_estimate", "estimate.py"),
    "conic: option checks": ("checked", "conic.py"),
    "the scene's own solves (Newton)": ("solve_newton", "newton.py"),
    "reference solves, all (conic)": ("solve_conic", "conic.py"),
}


def buckets(stats: pstats.Stats) -> dict[str, float]:
    out = dict.fromkeys(_BUCKETS, 0.0)
    for (file, _, func), (_, _, _, ct, _) in stats.stats.items():  # type: ignore[attr-defined]
        for name, (fn, where) in _BUCKETS.items():
            if func == fn and where in file:
                out[name] += ct
            elif func == f"<method '{fn}' of '{where}' objects>":
                out[name] += ct
    return out


def verify_overhead(t_end: float, repeats: int) -> tuple[pd.DataFrame, dict[str, float], float]:
    scene = shipped_scene("inhom_gamma3_lambda4").replace({
        "v.n": 61, "x.n": 61, "collision.fisher": "perspective", "collision.beta": 30.0, "t_end": t_end,
    })  # fmt: skip
    rows = []
    for split_name in SPLITS:
        rows.append(_verify_row(scene, t_end, repeats, split_name))
    prof = cProfile.Profile()
    t0 = time.process_time()
    prof.enable()
    verify(scene, "conic", every=1, workers=1)
    prof.disable()
    profiled = time.process_time() - t0
    return pd.DataFrame(rows), buckets(pstats.Stats(prof)), profiled


def _verify_row(scene: object, t_end: float, repeats: int, split_name: str) -> dict[str, object]:
    ref_opts = {"dc_split": split_name}
    cold_verify, _ = cpu(lambda: verify(scene, "conic", every=1, reference_options=ref_opts, workers=1))
    cold_run, _ = cpu(lambda: simulate(scene))
    runs, vers, ver = [], [], None
    for _ in range(repeats):
        t, run = cpu(lambda: simulate(scene))
        runs.append(t)
        clear_operator_cache()
        t, ver = cpu(lambda: verify(scene, "conic", every=1, reference_options=ref_opts, workers=1))
        vers.append(t)
    operators = operator_cache_info()["entries"]
    table = ver.table
    row = {
        "scene": "inhom_gamma3_lambda4 61x61 perspective beta=30", "dc_split": split_name, "t_end": t_end,
        "steps": run.steps,
        "slice_solves": len(table), "run_s": statistics.median(runs), "verify_s": statistics.median(vers),
        "ratio": statistics.median(vers) / statistics.median(runs), "cold_verify_s": cold_verify,
        "cold_run_s": cold_run, "operators_built": operators,
        "ref_median_s": float(table["seconds_ref"].median()),
        "outcomes": ", ".join(f"{n} {k}" for k, n in table["outcome"].value_counts().items()),
        "verdict": ver.verdict,
    }  # fmt: skip
    print(row, flush=True)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[121, 241, 481])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--t-end", type=float, default=0.2)
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    cs = conic_solves(args.sizes, args.repeats)
    ov, where, profiled = verify_overhead(args.t_end, max(1, args.repeats - 1))
    RESULTS.mkdir(exist_ok=True)
    csv_a, csv_b = RESULTS / "bench_conic_split.csv", RESULTS / "bench_conic_split_verify.csv"
    cs.to_csv(csv_a, index=False)
    ov.to_csv(csv_b, index=False)
    record_csv(csv_a, csv_b)
    md = [
        "# The conic reference with the DC split computed once per grid (`studies/bench_conic_split.py`)",
        "",
        f"CPU seconds of one process (`time.process_time`), side by side; threads: {thread_environment()}; "
        f"1-minute load {load0:.2f} before, {os.getloadavg()[0]:.2f} after.",
        "",
        f"## One conic solve at gamma = 3 (median of {args.repeats}; `first` includes the DPP compile)",
        "",
        cs.to_markdown(index=False, floatfmt=".3g"),
        "",
        *[f"- growth exponent N = 121 .. {max(args.sizes)}, dc_split = {s}: repeated solves "
          f"{exponent(cs, 'cached_s', s):.2f} (split from the cache), {exponent(cs, 'uncached_s', s):.2f} "
          f"(split recomputed); the split alone {exponent(cs, 'split_s', s):.2f}; first solves "
          f"{exponent(cs, 'first_s', s):.2f} (target: at most 1.5)" for s in SPLITS],
        "",
        f"## verify --reference conic --every 1 against the scene's own run (median of {max(1, args.repeats - 1)})",
        "",
        ov.drop(columns=["verdict"]).to_markdown(index=False, floatfmt=".3g"),
        "",
        *[f"- dc_split = {r.dc_split}: {r.verdict}" for r in ov.itertuples()],
        "- energy operators (and DC splits) built during one verification: "
        + ", ".join(str(x) for x in ov.operators_built),
        "",
        f"### Where one verification's time goes (default eigen split; cProfile, {profiled:.3g} CPU s profiled)",
        "",
        "Cumulative CPU seconds of each function; nested rows are inside their callers.",
        "",
        pd.DataFrame({"where": list(where), "cpu_s": list(where.values())}).to_markdown(index=False, floatfmt=".3g"),
        "",
    ]
    write_markdown(RESULTS / "bench_conic_split.md", "\n".join(md))
    print("\n".join(md))


if __name__ == "__main__":
    main()
