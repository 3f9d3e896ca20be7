"""Why the uniform 481 x 481 gamma = 3/2, lambda = 5 run of ``grid_convergence`` stopped on e_f (fixed since).

Reruns that point (``jko_cvx.studies.reproduce.grid_convergence``: the ``inhom_gamma1p5_after`` scene on
a fixed uniform 481 x 481 grid, stopped at sigma_v < 0.05 or t = 0.7) with the collision
solves watched: for every solve with an uncertified slice it records the slice, its status,
its KKT residual (and the largest residual of the certified slices), Newton's iterations and
the range of f* (the density entering the collision step).  Writes
``studies/results/grid_convergence_failure.json`` with the code that ran it (package hash,
git commit) and the collapse time when the run gets there; ``--no-floor`` runs the reference
as the previous sweep did (``v.floor_every_step = false``) and writes
``grid_convergence_failure_no_floor.json``, with where in v each failed slice's f* is smallest
and that v-line's mass.

The record of the frozen code of the previous sweep (commit fd12f88: the run stopped after
t = 0.385, one slice's f* at 4.8e-18) is kept as ``grid_convergence_failure_before_fix.json``.
Its cause, found by rerunning: on a fixed v-grid nothing re-applies the floor of the paper's
every-step v-remap, so the collision drains the edge lines in v (mass 1e-14 per line, f*
~1e-17 after the transport's per-line mass rescaling), and Newton cannot certify a slice
whose f* spans 17 orders of magnitude.  The uniform reference now keeps that floor
(``v.floor_every_step``); this script records the same point's run on today's code.
About 5-10 minutes on one core.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import jko_cvx.engine.loop as simulate_module
from jko_cvx.environment import environment
from jko_cvx.studies.reproduce.gamma1p5 import COLLAPSE_SPREAD
from jko_cvx.studies.reproduce.grid_convergence import study_scene
from jko_cvx.studies.sweep import code_provenance

RESULTS = Path(__file__).parent / "results"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--no-floor",
        action="store_true",
        help="the reference as the shipped sweep ran it (v.floor_every_step = false): the failure's cause",
    )
    args = parser.parse_args(argv)
    out = RESULTS / ("grid_convergence_failure_no_floor.json" if args.no_floor else "grid_convergence_failure.json")

    # the code that runs, taken before the run (a file edited meanwhile must not change the record)
    code = code_provenance(main)
    solve = simulate_module.solve_collision
    failures: list[dict] = []
    x_weights: list[np.ndarray] = []

    def watched(problem, method="conic", **opts):
        res = solve(problem, method=method, **opts)
        status = np.atleast_1d(res.status)
        bad = [i for i, s in enumerate(status) if not s.success]
        if bad:
            kkt = np.atleast_1d(res.kkt_residual)
            good = np.setdiff1d(np.arange(status.size), bad)
            f_star = np.atleast_2d(problem.f_star)
            line_mass = x_weights[0] @ f_star
            failures.append(
                {
                    "slices": bad,
                    "status": [status[i].name for i in bad],
                    "kkt_residual": kkt[bad].tolist(),
                    "largest certified kkt_residual": float(kkt[good].max()) if good.size else None,
                    "iterations": np.atleast_1d(res.iterations)[bad].tolist(),
                    "f_star min": f_star[bad].min(axis=-1).tolist(),
                    # where in v, and the mass of that v-line over x (h_x @ f*): a drained edge line
                    "f_star argmin v index": f_star[bad].argmin(axis=-1).tolist(),
                    "v points": f_star.shape[-1],
                    "v-line mass at that index": [float(line_mass[j]) for j in f_star[bad].argmin(axis=-1)],
                    "f_star max": f_star[bad].max(axis=-1).tolist(),
                    "f_star min over all slices": float(f_star.min()),
                    "options": {k: str(v) for k, v in opts.items()},
                }
            )
        return res

    simulate_module.solve_collision = watched
    try:
        scene = study_scene("after", 481, "uniform")
        if args.no_floor:
            scene = scene.replace({"v.floor_every_step": False})
        x_weights.append(scene.xgrid().h)  # a fixed uniform x-grid: the same weights every step
        run = simulate_module.simulate(scene)
    finally:
        simulate_module.solve_collision = solve
    d = run.diagnostics
    below = d.t[d.min_spread_v < COLLAPSE_SPREAD]
    out.write_text(
        json.dumps(
            {
                "verdict": run.verdict["reason"],
                "t": float(run.t),
                "steps": len(d) - 1,
                "sigma_v at the stop": float(d.min_spread_v.iloc[-1]),
                "collapse t (sigma_v < 0.05)": float(below.iloc[0]) if len(below) else None,
                "v.floor_every_step": scene.v.floor_every_step,
                "failed solves": failures,
                "code": code,
                "environment": environment(),
            },
            indent=1,
        )
    )
    print(out.read_text())


if __name__ == "__main__":
    main()
