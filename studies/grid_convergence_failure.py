"""Why the uniform 481 x 481 gamma = 3/2, lambda = 5 run of ``grid_convergence`` stops on e_f.

Reruns that point (``jko_cvx.reproduce.grid_convergence``: the ``inhom_gamma1p5_after`` scene on
a fixed uniform 481 x 481 grid, stopped at sigma_v < 0.05 or t = 0.7) with the collision
solves watched: for every solve with an uncertified slice it records the slice, its status,
its KKT residual (and the largest residual of the certified slices), Newton's iterations and
the range of f* (the density entering the collision step).  Writes
``studies/results/grid_convergence_failure.json``.  About 4 minutes on one core.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import jko_cvx.simulate as simulate_module
from jko_cvx.reproduce.grid_convergence import study_scene

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
    OUT.write_text(
        json.dumps(
            {
                "verdict": run.verdict["reason"],
                "t": float(run.t),
                "steps": len(d) - 1,
                "sigma_v at the stop": float(d.min_spread_v.iloc[-1]),
                "failed solves": failures,
            },
            indent=1,
        )
    )
    print(OUT.read_text())


if __name__ == "__main__":
    main()
