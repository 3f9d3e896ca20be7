"""The comparison table's own judgement, tested with planted answers (not by trusting it).

A solver configured to call itself converged at a loose KKT threshold (``kkt_tol=0.5``)
while stopping early is a planted liar: the table must recompute its residual and mark the
row silently wrong; an honest tight Newton row must come out certified.
"""

import numpy as np

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
from jko_cvx.studies.compare import Configuration, compare_solvers


def test_a_planted_liar_is_reported_silently_wrong():
    grid = Grid.uniform(-2.0, 2.0, 41)
    prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), 0.01, beta=3.0)
    liar_opts = {"tol": 1e-2, "kkt_tol": 0.5}
    liar = solve_collision(prob, method="sqp", **liar_opts)
    true_kkt = float(prob.kkt_residual(liar.f, liar.m).total)
    assert liar.success and true_kkt > 1e-6  # the plant: "converged", residual too large
    configs = [
        Configuration("sqp:banded", "sqp", "liar", liar_opts),
        Configuration("newton", "newton", "tol=1e-12", {"tol": 1e-12}),
    ]
    df = compare_solvers(prob, configs, repeats=1).set_index("setting")
    assert bool(df.loc["liar", "silently_wrong"]) and not bool(df.loc["liar", "certified"])
    assert df.loc["liar", "kkt"] == true_kkt
    assert bool(df.loc["tol=1e-12", "certified"]) and not bool(df.loc["tol=1e-12", "silently_wrong"])
