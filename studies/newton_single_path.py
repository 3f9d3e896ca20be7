"""Interleaved timing of one Newton solve: main's scalar single-problem path against this branch.

A copy of the previous package (main at 38c1849) must be importable as ``jko_old`` from
``OLD`` (``git archive 38c1849 jko_cvx | tar -x -C DIR && mv DIR/jko_cvx OLD/jko_old``; its
imports are relative).  CPU time (``time.process_time``), median over ROUNDS rounds of 5
solves each, the two packages alternating; run with ``OPENBLAS_NUM_THREADS=1``.

    python studies/newton_single_path.py [ROUNDS] [OLD]
"""

import sys
import time

import numpy as np

ROUNDS = int(sys.argv[1]) if len(sys.argv) > 1 else 15
sys.path.insert(0, sys.argv[2] if len(sys.argv) > 2 else "/tmp/a16_old")

import jko_old  # noqa: E402
from jko_old.collision.newton import solve_newton as old_solve  # noqa: E402

import jko_cvx  # noqa: E402
from jko_cvx.collision.newton import solve_newton as new_solve  # noqa: E402


def _problem(pkg, gamma: float, n: int, beta: float, fisher: str):
    f = np.exp(-2 * np.linspace(-2, 2, n) ** 2)
    return pkg.CollisionProblem(pkg.Grid.uniform(-2, 2, n), pkg.PowerKernel(gamma), f, 0.01, beta=beta, fisher=fisher)


def _median_ms(fn, P, times: list[float]) -> None:
    t = time.process_time()
    for _ in range(5):
        fn(P)
    times.append((time.process_time() - t) / 5 * 1e3)


for gamma in (1.0, 3.0):
    for n in (61, 121, 241):
        for beta, fisher in ((10.0, "perspective"), (1000.0, "log")):
            Pn, Po = _problem(jko_cvx, gamma, n, beta, fisher), _problem(jko_old, gamma, n, beta, fisher)
            rn, ro = new_solve(Pn), old_solve(Po)
            tn, to = [], []
            for _ in range(ROUNDS):
                _median_ms(old_solve, Po, to)
                _median_ms(new_solve, Pn, tn)
            a, b = np.median(to), np.median(tn)
            print(
                f"gamma={gamma:g} N={n} fisher={fisher}: main {a:.3f} ms, branch {b:.3f} ms, ratio {b / a:.2f}; "
                f"iterations {ro.iterations}/{rn.iterations}; max|df| {np.abs(ro.f - rn.f).max():.1e}; "
                f"status {ro.status.name}/{rn.status.name}",
                flush=True,
            )
