"""Chained LAPACK calls in the structured Newton directions: a baseline commit against this tree, side by side.

``jko_cvx.collision._structured`` solves the dense-kernel Newton directions (gamma = 3: the
interleaved banded system; even gamma >= 4: banded Cholesky and Woodbury; other gamma from
N_v = 301: certified CG) slice by slice in the baseline, and as one chained LAPACK call per
chunk of slices in this tree (``_linalg.banded_lu_solve_batch``,
``pentadiagonal_cholesky_batch``, ``pentadiagonal_solve_batch``).  Both versions run in one
process (the baseline exported with ``git archive`` and imported as ``jko_cvx_base``, as in
``studies/newton_single_call.py``):

1. **Equality**: every returned f, m, objective, KKT residual, status and iteration count of
   the batches below must be bitwise the baseline's (the script exits with status 1 otherwise).
2. **Timing**: the batch of ``studies/bench_threads.py`` (slices of the ``inhom_gamma3_lambda4``
   datum on its refined v-grid, log Fisher beta = 1000, dt = 0.02, strength 2, tol = 1e-8,
   momentum conserved) for gamma = 3, 4 and 2.5, N_v = 61-481, 32 slices; CPU seconds
   (``time.process_time``) per batched solve and per slice-iteration, median over
   ``--repeats`` rounds with the two versions interleaved in every round, in the package's
   default thread setting (recorded).

Run::

    OPENBLAS_NUM_THREADS=1 python studies/bench_chained_structured.py --base 002c9b1

Writes ``studies/results/bench_chained_structured.{csv,md}`` with the environment.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from bench_threads import inhom_batch
from newton_single_call import _same, import_baseline, tree_label

import jko_cvx
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.threads import thread_environment

RESULTS = Path(__file__).parent / "results"
FIELDS = ("f", "m", "status", "iterations", "objective", "kkt_residual", "mass_error")
CASES = [(3.0, 61), (3.0, 121), (3.0, 241), (3.0, 481), (4.0, 121), (4.0, 481), (2.5, 361)]


def _as(pkg, problem):
    """The same problem built by ``pkg`` (the baseline or this tree)."""
    return pkg.CollisionProblem(pkg.Grid(problem.grid.points), pkg.PowerKernel(problem.kernel.gamma),
                                problem.f_star, problem.dt, problem.strength, problem.beta, problem.fisher,
                                conserve_momentum=problem.conserve_momentum)  # fmt: skip


def _cpu(pkg, problem, inner: int) -> tuple[float, object]:
    c0 = time.process_time()
    for _ in range(inner):
        res = pkg.solve_collision(problem, "newton", tol=1e-8)
    return (time.process_time() - c0) / inner, res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="baseline commit")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--slices", type=int, default=32)
    args = ap.parse_args(argv)
    rows, bad = [], []
    with tempfile.TemporaryDirectory() as tmp:
        base = import_baseline(args.base, Path(tmp))
        for gamma, n in CASES:
            tree_p = inhom_batch(n, gamma, slices=args.slices)
            pair = {"base": _as(base, tree_p), "tree": tree_p}
            ra = base.solve_collision(pair["base"], "newton", tol=1e-8)
            rb = jko_cvx.solve_collision(pair["tree"], "newton", tol=1e-8)
            differ = [k for k in FIELDS if not _same(getattr(ra, k), getattr(rb, k))]
            if differ:
                bad.append(f"gamma = {gamma}, N_v = {n}: {differ}")
            inner = max(1, int(0.3 / max(1e-4, rb.seconds)))
            times = {"base": [], "tree": []}
            for _ in range(args.repeats):
                for side, pkg in (("base", base), ("tree", jko_cvx)):
                    times[side].append(_cpu(pkg, pair[side], inner)[0])
            its = int(np.sum(rb.iterations))
            tb, tt = statistics.median(times["base"]), statistics.median(times["tree"])
            rows.append({"gamma": gamma, "N_v": n, "slices": args.slices, "newton_iterations": its,
                         "base_ms": 1e3 * tb, "tree_ms": 1e3 * tt, "tree/base": tt / tb,
                         "base_us_per_slice_iteration": 1e6 * tb / its, "tree_us_per_slice_iteration": 1e6 * tt / its,
                         "certified": int(np.sum(rb.kkt_residual <= 1e-8)), "bitwise_equal": not differ})  # fmt: skip
            print(rows[-1], flush=True)
    df = pd.DataFrame(rows)
    out = RESULTS / "bench_chained_structured.csv"
    df.to_csv(out, index=False)
    record_csv(out)
    write_markdown(
        RESULTS / "bench_chained_structured.md",
        "# Structured Newton directions: chained LAPACK calls against one call per slice\n\n"
        f"Baseline {args.base}, tree {tree_label()}; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.  "
        f"Threads: {thread_environment()}.  The batch of `studies/bench_threads.py` ({args.slices} slices of the "
        "inhom_gamma3_lambda4 datum on its refined v-grid, log Fisher beta = 1000, dt = 0.02, tol = 1e-8); CPU "
        f"time per batched solve, median of {args.repeats} rounds, the versions interleaved.  "
        + ("Every result is bitwise the baseline's." if not bad else f"Results differ: {bad}.")
        + "\n\n" + df.to_markdown(index=False, floatfmt=".4g") + "\n",
    )
    for line in bad:
        print("DIFFERS:", line, file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
