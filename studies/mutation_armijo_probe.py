"""How often does Armijo refuse a first trial point where the relative Newton decrement is <= 1e-3?

Evidence for the survivor ``newton-no-armijo`` of ``studies/mutation.py`` (full steps taken without
the Armijo test where the decrement is below 1e-3).  Run: ``OPENBLAS_NUM_THREADS=1 python
studies/mutation_armijo_probe.py``; 2026-12-01: {'small_dec_trials': 85, 'small_dec_refused': 0,
'searches': 134} on 40 problems of the random agreement family.
"""

import numpy as np

import jko_cvx.collision.newton as nw
from jko_cvx import solve_collision
from jko_cvx.testing import random_problem

orig = nw._line_search
stats = {"small_dec_trials": 0, "small_dec_refused": 0, "searches": 0}

def probe(Pa, m, p, alpha, phi0, slope, dec):
    small = (dec > 1e-12) & (dec <= 1e-3)
    if small.any():
        trial = m + alpha[:, None] * p
        ft = Pa.f_star - nw.divergence(trial) / Pa.grid.h
        phit = nw._objective_interior(Pa, ft, trial)
        ok = np.all(ft > 0, axis=-1) & (phit <= phi0 + nw._ARMIJO * alpha * slope)
        stats["small_dec_trials"] += int(small.sum())
        stats["small_dec_refused"] += int((small & ~ok).sum())
    stats["searches"] += len(dec)
    return orig(Pa, m, p, alpha, phi0, slope, dec)

nw._line_search = probe
rng = np.random.default_rng(20261122)
for i in range(40):
    gamma = [1.0, 1.5, 2.0, 3.0][i % 4]
    prob = random_problem(rng, gamma, fisher=["perspective", "log"][i % 2])
    solve_collision(prob, method="newton", tol=1e-12)
print(stats)
