"""Interleaved timing of one Newton solve: the previous package's scalar single-problem path
(a copy of main at 38c1849 importable as ``jko_old`` from /tmp/a16_old) against this branch,
where a single problem is a batch of one.  CPU time (``time.process_time``), median of
rounds of 5 solves, OPENBLAS_NUM_THREADS=1.  Usage: python studies/newton_single_path.py [ROUNDS]."""
import sys, time, numpy as np
sys.path.insert(0, "/tmp/a16_old")
import jko_old
import jko_cvx
from jko_cvx.collision.newton import solve_newton as new_solve
from jko_old.collision.newton import solve_newton as old_solve
rows = []
for gamma in (1.0, 3.0):
    for n in (61, 121, 241):
        for beta, fisher in ((10.0, "perspective"), (1000.0, "log")):
            pts = np.linspace(-2, 2, n); f = np.exp(-2 * pts**2)
            Pn = jko_cvx.CollisionProblem(jko_cvx.Grid.uniform(-2, 2, n), jko_cvx.PowerKernel(gamma), f, 0.01, beta=beta, fisher=fisher)
            Po = jko_old.CollisionProblem(jko_old.Grid.uniform(-2, 2, n), jko_old.PowerKernel(gamma), f, 0.01, beta=beta, fisher=fisher)
            rn, ro = new_solve(Pn), old_solve(Po)
            tn, to = [], []
            for _ in range(int(sys.argv[1]) if len(sys.argv) > 1 else 15):
                for fn, P, ts in ((old_solve, Po, to), (new_solve, Pn, tn)):
                    t = time.process_time()
                    for _ in range(5): fn(P)
                    ts.append((time.process_time() - t) / 5)
            a, b = np.median(to), np.median(tn)
            print(f"gamma={gamma:g} N={n} fisher={fisher}: old {a*1e3:.3f} ms, new {b*1e3:.3f} ms, new/old {b/a:.2f}; it {ro.iterations}/{rn.iterations}; max|df| {np.abs(ro.f-rn.f).max():.1e}; status {ro.status.name}/{rn.status.name}", flush=True)
