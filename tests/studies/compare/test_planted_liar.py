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


def test_a_failed_reference_is_never_what_f_error_is_measured_against(monkeypatch):
    """Where the tight Newton reference fails, f_error is measured against the best certified row (and the
    table says so), never against the failed answer; with no certified row it is not measured (NaN)."""
    import dataclasses

    import jko_cvx.studies.compare as compare
    from jko_cvx.collision import Status

    grid = Grid.uniform(-2.0, 2.0, 41)
    prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), 0.01, beta=3.0)
    real = compare.solve_collision

    def failing_reference(problem, method, **options):
        res = real(problem, method, **options)
        if method == "newton" and options.get("tol") == 1e-13:  # the reference: a planted failure, f far off
            return dataclasses.replace(res, status=Status.NUMERICAL_ERROR, f=res.f * 1.5)
        return res

    monkeypatch.setattr(compare, "solve_collision", failing_reference)
    configs = [
        Configuration("newton", "newton", "tol=1e-12", {"tol": 1e-12}),
        Configuration("sqp:banded", "sqp", "liar", {"tol": 1e-2, "kkt_tol": 0.5}),
    ]
    df = compare_solvers(prob, configs, repeats=1)
    rows = df.set_index("setting")
    assert bool(rows.loc["tol=1e-12", "certified"]) and rows.loc["tol=1e-12", "f_error"] == 0.0
    assert rows.loc["liar", "f_error"] > 1e-6
    assert "NUMERICAL_ERROR" in df.attrs["reference"] and "tol=1e-12" in df.attrs["reference"]
    only_liar = compare_solvers(prob, configs[1:], repeats=1)
    assert np.isnan(only_liar.f_error).all() and "not measured" in only_liar.attrs["reference"]
