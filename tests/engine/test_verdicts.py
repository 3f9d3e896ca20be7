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
    import matplotlib.pyplot as plt

    plt.close(fig)  # a figure left open fails the pyplot-free checks of tests that run later


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


def test_a_runs_figure_draws_the_fit_its_verdict_made_and_that_fit_is_fit_blowups():
    """fit_rows keeps its last fits by their inputs: the figure's fit is the very object of the verdict's,
    and it equals, field by field, an uncached fit_blowup of the same records (in this process)."""
    from jko_cvx.blowup import fit_blowup
    from jko_cvx.engine.verdict import fit_rows

    t = np.linspace(0.0, 0.45, 46)
    rows = [{"t": float(x), "max_f": float(1.0 / (1.0 - 2.0 * x)), "failed": 0} for x in t]
    v = Verdict(stop=StopReason.EPS_V, B_v=True, T_b=0.45, reason="min dv < eps_v")
    first, again = fit_rows(rows, v), fit_rows([dict(r) for r in rows], v)
    assert again is first and first.blowup_kind == "finite_time"
    fresh = fit_blowup(t, 1.0 / (1.0 - 2.0 * t), certified=np.ones(t.size, dtype=bool))
    for name in ("T_b_fit", "T_b_fit_err", "blowup_rate", "log_C", "blowup_kind", "window", "reason"):
        assert getattr(first, name) == getattr(fresh, name), name
    other = fit_rows([{**r, "max_f": 2.0 * r["max_f"]} for r in rows], v)
    assert other is not first and other.log_C != first.log_C


def test_an_uncertified_run_that_reached_t_end_is_undetermined_everywhere_it_is_read(tmp_path):
    """No blow-up rule fired, but every step carried a failed solve: the verdict is neither True nor False, in the
    API, in verdict.json, read back, and in the netCDF attributes (a boolean there read as "no blow-up")."""
    scene = scene_from_dict(with_overrides(SMALL, {**FAILING, "stop.on_solver_failure": False}))
    run = simulate(scene, out=tmp_path / "r")
    v = run.verdict
    assert v.stop is StopReason.T_END and v.uncertified_steps == run.steps > 0
    assert v.blowup is None and run.blowup is None and v["blowup"] is None and not v.certified
    record = json.loads((tmp_path / "r" / "verdict.json").read_text())
    assert record["blowup"] is None and record["certified"] is False
    back = load_run(tmp_path / "r")
    assert back.blowup is None and back.verdict == v
    pytest.importorskip("xarray")
    attrs = run.to_xarray().attrs
    assert attrs["blowup"] == "undetermined" and attrs["certified"] == 0


def test_a_run_that_took_no_step_is_undetermined_and_not_certified(tmp_path):
    scene = scene_from_dict(with_overrides(SMALL, {**FAILING, "stop.on_solver_failure": True}))
    run = simulate(scene, out=tmp_path / "r")
    v = run.verdict
    assert v.stop is StopReason.NO_STEP and v.blowup is None and not v.certified
    line = run.summary()
    assert "blow-up = undetermined" in line and "blow-up = False" not in line and "NOT CERTIFIED" in line
    assert json.loads((tmp_path / "r" / "verdict.json").read_text())["blowup"] is None
    assert load_run(tmp_path / "r").verdict == v


@pytest.mark.parametrize("stop", [StopReason.SOLVER_FAILURE, StopReason.EPS_T])
def test_a_blow_up_drawn_from_a_failed_solve_is_not_certified(stop):
    """The paper's exit-flag rule e_f (a failed solve the step policy could not cure) flags blow-up, but the
    verdict rests on a failed solve: not certified, and the words say so."""
    v = Verdict().stopped(stop, 0.03, "collision solver failed (MAX_ITERATIONS)")
    assert v.blowup is True and v.e_f and not v.certified
    text = v.describe()
    assert "NOT CERTIFIED" in text and "exit-flag rule e_f" in text and "blow-up = True (" in text
    assert Verdict.from_dict(v.to_dict()) == v
    assert v["certified"] is False and v.to_dict()["certified"] is False


def test_verdict_records_say_whether_they_are_certified_and_agree_with_their_fields(tmp_path):
    """verdict.json states ``certified`` (a reader of the file alone sees a verdict drawn from failed solves),
    and a record whose ``certified`` disagrees with its stop and uncertified steps is refused."""
    run = simulate(scene_from_dict(SMALL), out=tmp_path / "r")
    record = json.loads((tmp_path / "r" / "verdict.json").read_text())
    assert record["certified"] is True and run.verdict.certified
    failed = Verdict().stopped(StopReason.SOLVER_FAILURE, 0.03, "collision solver failed (MAX_ITERATIONS)")
    carried = Verdict().solver_failed(0.1)
    for v in (failed, carried):
        assert v.to_dict()["certified"] is False
        with pytest.raises(ValueError, match="certified"):
            Verdict.from_dict({**v.to_dict(), "certified": True})
    with pytest.raises(ValueError, match="certified"):
        Verdict.from_dict({**run.verdict.to_dict(), "certified": False})
    for bad in ("true", 1, None):
        with pytest.raises(ValueError, match="certified"):
            Verdict.from_dict({**run.verdict.to_dict(), "certified": bad})
    # records written before verdicts stated it have no such key: the other fields decide
    legacy = {k: x for k, x in failed.to_dict().items() if k != "certified"}
    assert Verdict.from_dict(legacy) == failed and not Verdict.from_dict(legacy).certified


def test_a_records_figure_of_a_blow_up_by_a_failed_solve_says_so(tmp_path):
    scene = scene_from_dict(with_overrides(SMALL, {"stop.on_solver_failure": True}))
    run = simulate(scene)
    v = run.verdict.stopped(StopReason.SOLVER_FAILURE, run.t, "collision solver failed (MAX_ITERATIONS)")
    import dataclasses

    import matplotlib.pyplot as plt

    # the paper sets B_v on e_f (alg:MR_JKO_ver2): the summary says where that B_v comes from
    assert "direction: B_v, which e_f sets" in dataclasses.replace(run, verdict=v).summary()
    fig = plot_records(dataclasses.replace(run, verdict=v))
    title = fig.axes[-1].get_title()
    plt.close(fig)
    assert "NOT CERTIFIED" in title and "e_f" in title and "blow-up at" not in title


def test_verdict_records_say_blowup_as_true_false_or_null_only():
    undetermined = Verdict().solver_failed(0.1).to_dict()
    assert undetermined["blowup"] is None and Verdict.from_dict(undetermined).blowup is None
    # a record written before undetermined verdicts were null says false there: the other fields decide
    assert Verdict.from_dict({**undetermined, "blowup": False}).blowup is None
    with pytest.raises(ValueError, match="blowup"):
        Verdict.from_dict({**undetermined, "blowup": True})
    with pytest.raises(ValueError, match="blowup"):
        Verdict.from_dict({**Verdict().to_dict(), "blowup": None})  # a certified t_end verdict is False
    for bad in ("false", 0, 1.0, "null"):
        with pytest.raises(ValueError, match="blowup"):
            Verdict.from_dict({**Verdict().to_dict(), "blowup": bad})


def test_a_run_read_back_before_it_ended_has_a_provisional_undetermined_verdict(tmp_path, monkeypatch):
    """An interrupted run loaded with allow_partial: no rule fired yet, which is no "reached t_end, no blow-up"."""
    from jko_cvx.engine import RunInterrupted
    from jko_cvx.engine.loop import Stepper

    from ._inject import interrupted_commit

    scene = scene_from_dict(with_overrides(SMALL, {"output.checkpoint_every": 1}))
    with monkeypatch.context() as m:
        m.setattr(Stepper, "commit", interrupted_commit(2))
        with pytest.raises(RunInterrupted):
            simulate(scene, out=tmp_path / "r")
    part = load_run(tmp_path / "r", allow_partial=True)
    v = part.verdict
    assert part.t < scene.t_end and v.stop is StopReason.NOT_ENDED and v.blowup is None and part.blowup is None
    assert "the run has not ended" in v.reason and "undetermined (provisional" in part.summary()
    finished = simulate(scene, out=tmp_path / "r", resume=True)  # the resumed run's verdict is its own
    assert finished.verdict.stop is StopReason.T_END and finished.blowup is False


def test_a_scene_table_of_the_callers_own_class_runs_in_memory_but_is_not_recorded(tmp_path):
    """An Initial subclass with its own density: scene.json could only record the stock kind, so a run directory
    would name a datum that did not run; the density that runs is checked, not the stock one."""
    import dataclasses

    from jko_cvx.scene import SceneError
    from jko_cvx.scene.initial import GaussiansInitial

    base = scene_from_dict(SMALL)

    @dataclasses.dataclass(frozen=True)
    class Doubled(GaussiansInitial):
        def density(self, xgrid, vgrid):
            return 2.0 * super().density(xgrid, vgrid)

    @dataclasses.dataclass(frozen=True)
    class Negative(GaussiansInitial):
        def density(self, xgrid, vgrid):
            f = super().density(xgrid, vgrid).copy()
            f[..., 3] = -5.0
            return f

    fields = {f.name: getattr(base.initial, f.name) for f in dataclasses.fields(base.initial)}
    doubled = dataclasses.replace(base, initial=Doubled(**fields))
    with pytest.raises(SceneError, match=r"initial: a .*Doubled defines density of its own, which a run directory"):
        simulate(doubled, out=tmp_path / "r")
    assert not (tmp_path / "r").exists()
    ran = simulate(doubled)  # in memory: the caller's datum, twice the stock mass
    assert ran.column("mass")[0] == pytest.approx(2 * simulate(base).column("mass")[0], rel=1e-12)
    with pytest.raises(SceneError, match=r"initial: the density of Negative .* must be finite, >= 0"):
        simulate(dataclasses.replace(base, initial=Negative(**fields)))
