"""Solver comparison: one table, every result re-certified by the same KKT residual."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel
from jko_cvx.cli import main
from jko_cvx.scene import shipped_scene
from jko_cvx.scene.model import default_scene, load_scene
from jko_cvx.studies.compare import compare_solvers, problem_from_scene

SCENES = Path(__file__).parents[3] / "jko_cvx" / "scene" / "shipped"


def test_comparison_table_certifies_every_row():
    grid = Grid(np.linspace(-2, 2, 41) + 0.02 * np.sin(np.linspace(0, 7, 41)) * (np.abs(np.linspace(-2, 2, 41)) < 1.9))
    prob = CollisionProblem(grid, PowerKernel(1.5), np.exp(-2 * grid.points**2), 0.01, beta=10.0)
    df = compare_solvers(prob, repeats=1)
    assert not df.silently_wrong.any()
    assert (df.f_error[df.certified] <= 1e-4).all()  # certified rows agree with the tight Newton reference
    assert set(df.family) >= {"conic:CLARABEL", "sqp:banded", "sqp:osqp", "newton"}
    truncated = df[df.setting == "max_iter=5"].iloc[0]
    assert truncated.status == "MAX_ITERATIONS" and not truncated.certified
    tight = df[(df.family == "newton") & (df.setting == "tol=1e-10")].iloc[0]
    assert tight.certified and tight.f_error <= 1e-9 and tight.kkt <= 1e-10
    clarabel = df[(df.family == "conic:CLARABEL") & (df.setting == "tol=1e-10")].iloc[0]
    assert clarabel.certified and clarabel.f_error <= 1e-5  # the independent reference agrees
    assert (df.mass_error <= 1e-12).all() and (df.objective_gap[df.certified] >= -1e-12).all()


def test_log_fisher_has_no_conic_rows_and_momentum_no_sqp_rows():
    grid = Grid.uniform(-2.0, 2.0, 31)
    prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), 0.01, 1.0, 10.0, "log", True)
    df = compare_solvers(prob, repeats=1)
    ran = df[df.status != "NOT_RUN"]
    assert set(ran.family) == {"newton", "nlp:IPOPT"} and ran.certified.all()
    absent = df[df.status == "NOT_RUN"].set_index("family").setting
    assert "not conic-representable" in absent["conic"] and "no momentum constraint" in absent["sqp"]
    assert (ran.f_error <= 1e-6).all() and "best certified nlp solution" in df.attrs["reference"]


def test_log_fisher_shows_nlp_and_sqp_beside_newton():
    grid = Grid.uniform(-2.0, 2.0, 31)
    prob = CollisionProblem(grid, PowerKernel(2.0), np.exp(-2 * grid.points**2), 0.01, 1.0, 100.0, "log")
    df = compare_solvers(prob, repeats=1)
    assert set(df.family) == {"conic", "newton", "nlp:IPOPT", "sqp:banded", "sqp:osqp"}
    nlp = df[(df.family == "nlp:IPOPT") & (df.setting == "tol=1e-10")].iloc[0]
    assert nlp.certified and nlp.f_error <= 1e-8 and nlp.kkt <= 1e-8
    assert not df.silently_wrong.any()


def test_problem_from_scene_takes_the_hardest_slice():
    s = load_scene(SCENES / "inhom_gamma3_lambda4.toml")
    prob = problem_from_scene(s, 0.0)
    f0 = s.initial_density(s.xgrid(), s.vgrid())
    assert not prob.batched and prob.f_star.max() == pytest.approx(f0.max())
    homogeneous = problem_from_scene(default_scene(), 0.2)
    assert homogeneous.n == 121 and homogeneous.dt == 0.01
    with pytest.raises(ValueError, match="t must lie in"):
        problem_from_scene(default_scene(), 5.0)


def test_problem_from_scene_at_any_time_of_the_scene():
    # the run to t is the scene's own, cut there: its snapshot times past t and a first step longer than t are no
    # reason to refuse (the step to t is then t itself, as a run to t takes it)
    from jko_cvx.engine.loop import simulate

    s = shipped_scene("inhom_gamma1p5_before", {"x.n": 21, "v.n": 21})
    assert s.output.times and max(s.output.times) > 0.05
    prob = problem_from_scene(s, 0.05)
    assert not prob.batched and np.isfinite(prob.f_star).all()
    early = problem_from_scene(default_scene(), 0.005)
    alone = simulate(default_scene().replace({"t_end": 0.005, "time.dt": 0.005}))
    assert np.array_equal(early.f_star, alone.f) and early.dt == 0.01


def test_compare_command_writes_its_table(tmp_path, capsys):
    args = ["compare", "--n", "31", "--repeats", "1", "--out", str(tmp_path)]
    assert main(args) == 0
    (csv,) = tmp_path.glob("*.csv")
    table = pd.read_csv(csv)
    assert len(table) >= 10 and "Reference" in capsys.readouterr().out
