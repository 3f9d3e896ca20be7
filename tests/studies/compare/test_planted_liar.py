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


def test_every_row_carries_its_own_error_estimate_that_finds_the_liar():
    """The a posteriori estimate of each row's distance in f to the minimiser (no reference needed)
    tells the liar's error, within a factor 2 of its error against the tight Newton reference, and
    puts the honest row at rounding level."""
    grid = Grid.uniform(-2.0, 2.0, 41)
    prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), 0.01, beta=3.0)
    configs = [
        Configuration("sqp:banded", "sqp", "liar", {"tol": 1e-2, "kkt_tol": 0.5}),
        Configuration("newton", "newton", "tol=1e-12", {"tol": 1e-12}),
    ]
    df = compare_solvers(prob, configs, repeats=1).set_index("setting")
    liar, honest = df.loc["liar"], df.loc["tol=1e-12"]
    assert liar.f_error > 1e-6 and liar.f_error / 2 <= liar.f_error_est <= 2 * liar.f_error
    assert honest.f_error_est < 1e-10
