"""Verdicts that say what they rest on: a run that never took a step is not a blow-up, and a run
that carried failed solves forward never reports a clean verdict."""

import json

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, load_run, solve_collision
from jko_cvx.engine.loop import simulate
from jko_cvx.engine.plot import plot_records
from jko_cvx.engine.verdict import StopReason, Verdict
from jko_cvx.scene import scene_from_dict, with_overrides

from .test_rundir import SMALL

# one Newton iteration cannot certify any step of SMALL: every solve fails (MAX_ITERATIONS)
FAILING = {"collision.options": {"max_iter": 1}}


def test_a_run_whose_first_solve_fails_took_no_step_and_is_not_a_blow_up(tmp_path):
    scene = scene_from_dict(with_overrides(SMALL, {**FAILING, "stop.on_solver_failure": True}))
    run = simulate(scene, out=tmp_path / "r")
    v = run.verdict
    assert v.stop is StopReason.NO_STEP and not run.blowup and v.T_b is None and v.e_f
    assert run.steps == 0 and "no step was accepted" in run.summary() and "MAX_ITERATIONS" in v.reason
    assert load_run(tmp_path / "r").verdict == v
    assert json.loads((tmp_path / "r" / "verdict.json").read_text())["stop"] == "NO_STEP"


def test_a_run_past_failed_solves_reports_how_many_steps_were_not_certified_and_from_when(tmp_path):
    scene = scene_from_dict(with_overrides(SMALL, {**FAILING, "stop.on_solver_failure": False}))
    run = simulate(scene, out=tmp_path / "r")
    v = run.verdict
    failed = int(run.diagnostics.failed.gt(0).sum())
    assert failed == run.steps == 5
    assert not v.certified and v.uncertified_steps == failed and v.first_uncertified_t == pytest.approx(0.01)
    line = run.summary()
    assert "blow-up = undetermined" in line and "NOT CERTIFIED: 5 step(s)" in line and "blow-up = False" not in line
    back = load_run(tmp_path / "r").verdict
    assert back == v and back.uncertified_steps == 5
    fig = plot_records(run)
    assert "NOT CERTIFIED" in fig.axes[-1].get_title()


def test_a_certified_run_reports_as_before():
    run = simulate(scene_from_dict(SMALL))
    assert run.verdict.certified and run.verdict.uncertified_steps == 0
    assert "blow-up = False" in run.summary() and "NOT CERTIFIED" not in run.summary()


def test_a_blow_up_drawn_after_uncertified_steps_says_so():
    v = Verdict().solver_failed(0.2).stopped(StopReason.EPS_V, 0.5, "min dv = 1e-4 < eps_v")
    assert v.blowup and not v.certified and "True, from uncertified states" in v.describe()
    assert Verdict.from_dict(v.to_dict()) == v


def test_the_sqp_names_the_cfl_number_when_it_fails_above_one():
    grid = Grid.uniform(-2.0, 2.0, 121)
    f = np.exp(-2 * grid.points**2)
    prob = CollisionProblem(grid, PowerKernel(1.0), f, dt=0.1, beta=1000.0, fisher="perspective")
    assert prob.cfl() > 1
    res = solve_collision(prob, method="sqp", max_iter=200)
    assert not res.success and f"explicit CFL number is {prob.cfl():.3g} > 1" in res.message
    small = CollisionProblem(grid, PowerKernel(1.0), f, dt=0.1 / prob.cfl() / 2, beta=1000.0, fisher="perspective")
    failed = solve_collision(small, method="sqp", max_iter=2)
    assert not failed.success and "CFL" not in failed.message  # below one the hint would mislead
