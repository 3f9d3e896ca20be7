"""Threads across slices in batched Newton: one thread against two, side by side.

``jko_cvx.threads.map_chunks`` can run the slices' structured linear algebra (banded LU and
Cholesky chains, CG) in ``JKO_CVX_THREADS`` threads; only the LAPACK calls release the GIL, so
threads pay only where LAPACK dominates a chunk.  This benchmark times the batch of
``studies/bench_threads.py`` (slices of the ``inhom_gamma3_lambda4`` datum on its refined
v-grid, log Fisher beta = 1000, dt = 0.02, strength 2, tol = 1e-8, momentum conserved) for
several gamma, N_v and slice counts, with ``JKO_CVX_THREADS`` = 1 and 2 interleaved in every
round (wall and CPU seconds per batched solve, medians of ``--repeats`` rounds), and with
``JKO_CVX_NEWTON_LINALG=dense`` (one dense Cholesky per slice, LAPACK-bound) as a control.
Results do not depend on the thread count (checked here bitwise as well).

Run::

    OPENBLAS_NUM_THREADS=1 python studies/bench_slice_threads.py

Writes ``studies/results/bench_slice_threads.{csv,md}`` with the environment.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from bench_threads import inhom_batch
from newton_single_call import tree_label

import jko_cvx
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.threads import THREADS_ENV, thread_environment, usable_cores

RESULTS = Path(__file__).parent / "results"
CASES = [  # (gamma, N_v, slices, linear algebra)
    (1.0, 121, 32, "auto"), (1.5, 121, 32, "auto"), (1.5, 481, 32, "auto"), (1.5, 961, 32, "auto"),
    (2.5, 361, 32, "auto"), (3.0, 121, 32, "auto"), (3.0, 121, 121, "auto"), (3.0, 481, 32, "auto"),
    (3.0, 961, 32, "auto"), (4.0, 121, 32, "auto"), (4.0, 481, 32, "auto"),
    (3.0, 241, 32, "dense"), (3.0, 481, 32, "dense"),
]  # fmt: skip
FIELDS = ("f", "m", "status", "iterations", "kkt_residual")


def _solve(problem, threads: str):
    os.environ[THREADS_ENV] = threads
    w, c = time.perf_counter(), time.process_time()
    res = jko_cvx.solve_collision(problem, "newton", tol=1e-8)
    return time.perf_counter() - w, time.process_time() - c, res


def _same(a, b) -> bool:
    return all(np.array_equal(np.asarray(getattr(a, k)), np.asarray(getattr(b, k))) for k in FIELDS)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args(argv)
    saved = {k: os.environ.get(k) for k in (THREADS_ENV, "JKO_CVX_NEWTON_LINALG")}
    rows, bad = [], []
    try:
        for gamma, n, slices, linalg in CASES:
            os.environ["JKO_CVX_NEWTON_LINALG"] = linalg
            problem = inhom_batch(n, gamma, slices=slices)
            ref = {th: _solve(problem, th)[2] for th in ("1", "2")}  # warm-up, and the bitwise check
            equal = _same(ref["1"], ref["2"])
            if not equal:
                bad.append(f"gamma = {gamma}, N_v = {n}, {linalg}")
            wall, cpu = {"1": [], "2": []}, {"1": [], "2": []}
            for _ in range(args.repeats):
                for th in ("1", "2"):
                    w, c, _res = _solve(problem, th)
                    wall[th].append(w)
                    cpu[th].append(c)
            w1, w2 = statistics.median(wall["1"]), statistics.median(wall["2"])
            rows.append({"gamma": gamma, "N_v": n, "slices": slices, "linalg": linalg,
                         "wall_1_ms": 1e3 * w1, "wall_2_ms": 1e3 * w2, "wall_2/1": w2 / w1,
                         "cpu_1_ms": 1e3 * statistics.median(cpu["1"]), "cpu_2_ms": 1e3 * statistics.median(cpu["2"]),
                         "certified": int(np.sum(ref["1"].kkt_residual <= 1e-8)), "bitwise_equal": equal})  # fmt: skip
            print(rows[-1], flush=True)
    finally:
        for k, v in saved.items():
            os.environ.pop(k, None) if v is None else os.environ.__setitem__(k, v)
    df = pd.DataFrame(rows)
    out = RESULTS / "bench_slice_threads.csv"
    df.to_csv(out, index=False)
    record_csv(out)
    faster = int((df["wall_2/1"] < 1).sum())
    write_markdown(
        RESULTS / "bench_slice_threads.md",
        "# Batched Newton: one slice thread against two\n\n"
        f"Code {tree_label()}; "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {usable_cores()} usable cores.  Threads (besides "
        f"`{THREADS_ENV}`, set per row): {thread_environment()}.  The batch of `studies/bench_threads.py`; wall and "
        f"CPU milliseconds per batched solve, median of {args.repeats} rounds with the two settings interleaved.  "
        f"Two threads are faster in wall time in {faster} of {len(df)} rows (median wall ratio 2/1: "
        f"{df['wall_2/1'].median():.2f}).  "
        + ("Every result is bitwise the same for both settings." if not bad else f"Results differ: {bad}.")
        + "\n\n" + df.to_markdown(index=False, floatfmt=".4g") + "\n",
    )
    for line in bad:
        print("DIFFERS:", line, file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
