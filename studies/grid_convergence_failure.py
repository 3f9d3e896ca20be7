"""Why the uniform 481 x 481 gamma = 3/2, lambda = 5 run of ``grid_convergence`` stops on e_f.

Reruns that point (``jko_cvx.reproduce.grid_convergence``: the ``inhom_gamma1p5_after`` scene on
a fixed uniform 481 x 481 grid, stopped at sigma_v < 0.05 or t = 0.7) with the collision
solves watched: for every solve with an uncertified slice it records the slice, its status,
its KKT residual (and the largest residual of the certified slices), Newton's iterations and
the range of f* (the density entering the collision step).  Writes
``studies/results/grid_convergence_failure.json`` with the code that ran it (package hash,
git commit) and the collapse time when the run gets there.

The record of the frozen code of the shipped sweep (commit fd12f88: the run stopped at
t = 0.389, one slice's f* at 4.8e-18 after the x-moment's tilt) is kept as
``grid_convergence_failure_before_fix.json``; since the tilt moves only the mass above the
floor (:func:`jko_cvx.conservation.restore_moments`) this script records the same point's
run on today's code.  About 5-10 minutes on one core.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np

import jko_cvx.simulate as simulate_module
from jko_cvx.reproduce.gamma1p5 import COLLAPSE_SPREAD
from jko_cvx.reproduce.grid_convergence import study_scene
from jko_cvx.sweep import code_identity

OUT = Path(__file__).parent / "results" / "grid_convergence_failure.json"


def main() -> None:
    solve = simulate_module.solve_collision
    failures: list[dict] = []

    def watched(problem, method="conic", **opts):
        res = solve(problem, method=method, **opts)
        status = np.atleast_1d(res.status)
        bad = [i for i, s in enumerate(status) if not s.success]
        if bad:
            kkt = np.atleast_1d(res.kkt_residual)
            good = np.setdiff1d(np.arange(status.size), bad)
            f_star = np.atleast_2d(problem.f_star)
            failures.append(
                {
                    "slices": bad,
                    "status": [status[i].name for i in bad],
                    "kkt_residual": kkt[bad].tolist(),
                    "largest certified kkt_residual": float(kkt[good].max()) if good.size else None,
                    "iterations": np.atleast_1d(res.iterations)[bad].tolist(),
                    "f_star min": f_star[bad].min(axis=-1).tolist(),
                    "f_star max": f_star[bad].max(axis=-1).tolist(),
                    "f_star min over all slices": float(f_star.min()),
                    "options": {k: str(v) for k, v in opts.items()},
                }
            )
        return res

    simulate_module.solve_collision = watched
    try:
        scene = study_scene("after", 481, "uniform")
        run = simulate_module.simulate(scene)
    finally:
        simulate_module.solve_collision = solve
    d = run.diagnostics
    below = d.t[d.min_spread_v < COLLAPSE_SPREAD]
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=Path(__file__).parent)
    OUT.write_text(
        json.dumps(
            {
                "verdict": run.verdict["reason"],
                "t": float(run.t),
                "steps": len(d) - 1,
                "sigma_v at the stop": float(d.min_spread_v.iloc[-1]),
                "collapse t (sigma_v < 0.05)": float(below.iloc[0]) if len(below) else None,
                "failed solves": failures,
                "code": {**code_identity(main), "git_commit": commit.stdout.strip() or None},
            },
            indent=1,
        )
    )
    print(OUT.read_text())


if __name__ == "__main__":
    main()
