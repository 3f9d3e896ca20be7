"""Every stopping rule and verdict of the time loop, on tiny scenes built in code.

``alg:SPMCSL-JKO`` ends a run with ``T_b = t`` and sets ``B_x = 1`` if ``min dx < eps``,
``B_v = 1`` if ``min dv < eps`` or the exit flag ``e_f = 1``.  The package keeps one
threshold per axis (``stop.eps_x``, ``stop.eps_v``); the scenes below give them values
that differ from each other and from the spacings, so that a rule reading the wrong
threshold or the wrong spacing stops the run where it must not (or not where it must).
The oracle for "where" is the grid itself (uniform grids: the spacings are known) or a
free run of the same scene (a stopping rule must not change the trajectory before it
fires: the stopped run's diagnostics are a prefix of the free run's).
"""

import dataclasses

import numpy as np
import pandas as pd
import pytest

import jko_cvx.engine.loop as loop
from jko_cvx.engine._state import RunState
from jko_cvx.engine.loop import simulate
from jko_cvx.engine.verdict import StopReason, Verdict
from jko_cvx.grid import Grid
from jko_cvx.scene.model import SceneError, scene_from_dict

# 16 velocity points on [-1.5, 1.5]: dv = 0.2; 10 cell-centred x-points on [-4, 4): dx = 0.8.
DV, DX = 0.2, 0.8


def _scene(**changes):
    """A tiny inhomogeneous scene (about 0.05 s): log Fisher (a barrier, no vacuum cells)."""
    d = {
        "name": "tiny",
        "gamma": 1.0,
        "strength": 0.5,
        "t_end": 0.3,
        "v": {"L": 1.5, "n": 16},
        "x": {"L": 4.0, "n": 10},
        "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.0]},
        "time": {"policy": "fixed", "dt": 0.1},
        "collision": {"method": "newton", "beta": 30.0, "fisher": "log"},
        "stop": {"eps_v": 0.0, "eps_x": 0.0, "on_solver_failure": True},
    }
    d.update(changes)
    return scene_from_dict(d)


def _homogeneous(**changes):
    """A tiny homogeneous gamma = 1 scene with v-refinement (min dv falls step by step)."""
    d = {
        "name": "tiny_hom",
        "gamma": 1.0,
        "t_end": 0.3,
        "v": {"L": 2.0, "n": 41},
        "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.0]},
        "time": {"policy": "fixed", "dt": 0.02},
        "refine": {"v": {"bumps": 1, "delta0": 0.5, "delta": 0.5}},
        "collision": {"method": "newton", "beta": 1000.0, "fisher": "log"},
        "stop": {"eps_v": 0.0, "on_solver_failure": True},
    }
    d.update(changes)
    return scene_from_dict(d)


@pytest.fixture
def unguarded(monkeypatch):
    """Thresholds above a uniform grid's spacing, which simulate refuses (the rule would fire with no
    concentration: loop._check_thresholds), are what these tests need to see a rule's wiring fire: let them."""
    monkeypatch.setattr(loop, "_check_thresholds", lambda scene, state: None)


def test_the_tiny_grids_have_the_spacings_the_tests_assume():
    run = simulate(dataclasses.replace(_scene(), t_end=0.1))
    assert run.diagnostics.min_dv.iloc[-1] == pytest.approx(DV, rel=1e-12)
    assert run.diagnostics.min_dx.iloc[-1] == pytest.approx(DX, rel=1e-12)
    expected = {"blowup": False, "T_b": None, "B_x": False, "B_v": False, "e_f": False, "reason": "reached t_end"}
    assert {k: run.verdict[k] for k in expected} == expected


def test_B_x_fires_on_min_dx_against_eps_x_only(unguarded):
    """eps_x = 0.9 > dx = 0.8 > dv = 0.2 > eps_v = 0.1: only B_x may fire, at the first step.

    A rule comparing min dx with eps_v (0.8 < 0.1: never) misses it; one comparing min dv
    with eps_x (0.2 < 0.9) sets B_v as well.
    """
    run = simulate(_scene(stop={"eps_v": 0.1, "eps_x": 0.9}))
    v = run.verdict
    assert v["blowup"] and v["B_x"] and not v["B_v"] and not v["e_f"]
    assert v["T_b"] == pytest.approx(0.1) and run.t == pytest.approx(0.1) and len(run.diagnostics) == 2
    assert "min dx" in v["reason"] and "eps_x" in v["reason"]


def test_B_v_fires_on_min_dv_against_eps_v_only(unguarded):
    """eps_v = 0.3 > dv = 0.2, eps_x = 0.1 < dx = 0.8: only B_v may fire, at the first step.

    A rule comparing min dv with eps_x (0.2 < 0.1: never) misses it; one comparing min dx
    with eps_v (0.8 < 0.3: never) would not set B_x, and one that swapped the flags would.
    """
    run = simulate(_scene(stop={"eps_v": 0.3, "eps_x": 0.1}))
    v = run.verdict
    assert v["blowup"] and v["B_v"] and not v["B_x"] and not v["e_f"]
    assert v["T_b"] == pytest.approx(0.1) and len(run.diagnostics) == 2
    assert "min dv" in v["reason"] and "eps_v" in v["reason"]


@pytest.mark.parametrize("axis", ["v", "x"])
def test_the_spacing_rules_are_strict_inequalities(axis, monkeypatch):
    """``B = 1`` if ``min d < eps`` (alg:SPMCSL-JKO): a threshold equal to the spacing does not fire; one above
    it is refused before the run (it would fire with no concentration), and fires at the first step if let."""
    spacing = DV if axis == "v" else DX
    free = simulate(_scene())
    exact = float(free.diagnostics[f"min_d{axis}"].iloc[-1])
    assert exact == pytest.approx(spacing, rel=1e-12)
    at = simulate(_scene(stop={f"eps_{axis}": exact}))
    assert not at.blowup and at.t == pytest.approx(0.3)
    with pytest.raises(SceneError, match=rf"stop\.eps_{axis} = .* is not below the smallest spacing"):
        simulate(_scene(stop={f"eps_{axis}": exact * (1 + 1e-12)}))
    monkeypatch.setattr(loop, "_check_thresholds", lambda scene, state: None)
    above = simulate(_scene(stop={f"eps_{axis}": exact * (1 + 1e-12)}))
    assert above.blowup and above.verdict[f"B_{axis}"] and above.verdict["T_b"] == pytest.approx(0.1)


def test_B_v_on_a_refined_grid_stops_at_the_first_step_below_eps_v():
    """The mapped grid's min dv falls as the gamma = 1 bump concentrates; the rule stops the
    run at the first step below eps_v, and nothing before it changes."""
    free = simulate(_homogeneous())
    min_dv = free.diagnostics.min_dv.to_numpy()
    assert min_dv[-1] < 0.5 * min_dv[1], "the grid must refine during the free run"
    eps_v = 0.5 * (min_dv[1] + min_dv[-1])
    first = int(np.argmax(min_dv < eps_v))
    assert 1 < first < min_dv.size - 1
    stopped = simulate(_homogeneous().replace({"stop.eps_v": eps_v}))
    v = stopped.verdict
    assert v["blowup"] and v["B_v"] and not v["B_x"] and not v["e_f"]
    assert v["T_b"] == free.diagnostics.t.iloc[first]
    pd.testing.assert_frame_equal(stopped.diagnostics, free.diagnostics.iloc[: first + 1], check_exact=True)


def test_solver_failure_sets_e_f_and_counts_as_B_v_when_asked():
    """A collision solve that fails (Newton with one iteration) is the exit flag e_f = 1.

    With ``on_solver_failure`` the run stops at the failed step, not applying it, with T_b the
    end of that step (alg:MR_JKO_ver2 adds dt before it tests the indicators) and the failure
    counted as blow-up in v (alg:SPMCSL-JKO); when that step is the first, no step was taken and
    the run is not a blow-up (stop NO_STEP).  Without it the run goes on to t_end with e_f
    recorded, every uncertified step counted and neither verdict claimed.
    """
    from jko_cvx.engine.verdict import SolverFailureRule

    opts = {"method": "newton", "beta": 30.0, "fisher": "log", "options": {"max_iter": 1}}
    stopped = simulate(_scene(collision=opts))
    v = stopped.verdict
    assert v.stop is StopReason.NO_STEP and not v["blowup"] and v["e_f"] and not v["B_v"] and not v["B_x"]
    assert v["T_b"] is None and stopped.t == 0.0 and len(stopped.diagnostics) == 1
    assert "collision solver failed" in v["reason"] and "MAX_ITERATIONS" in v["reason"]
    # the rule itself, on a state two steps in
    state = RunState(0.2, 2, np.ones(3), Grid.uniform(-1.0, 1.0, 3), None, None, None, [], Verdict())
    assert SolverFailureRule(stop=True).record(state, ["MAX_ITERATIONS"], dt=0.1)
    assert state.verdict.stop is StopReason.SOLVER_FAILURE and state.verdict.blowup and state.verdict.B_v
    assert state.verdict.T_b == pytest.approx(0.3)
    going = simulate(_scene(collision=opts, stop={"eps_v": 0.0, "eps_x": 0.0, "on_solver_failure": False}))
    v = going.verdict
    assert v["e_f"] and not v["blowup"] and not v["B_v"] and not v["B_x"] and not v.certified
    assert going.t == pytest.approx(0.3) and v["reason"] == "reached t_end"
    assert (going.diagnostics.failed.iloc[1:] == 10).all()  # every slice of every step failed
    assert v.uncertified_steps == 3 and v.first_uncertified_t == pytest.approx(0.1)


def test_t_end_is_reached_exactly_with_a_shortened_last_step():
    run = simulate(_scene(t_end=0.35))
    d = run.diagnostics
    assert not run.blowup and run.verdict["reason"] == "reached t_end"
    assert run.t == pytest.approx(0.35, abs=1e-14) and len(d) == 5
    np.testing.assert_allclose(d.dt.to_numpy(), [0.0, 0.1, 0.1, 0.1, 0.05], atol=1e-14)
    np.testing.assert_allclose(d.t.to_numpy(), [0.0, 0.1, 0.2, 0.3, 0.35], atol=1e-14)


def test_spread_v_is_a_B_v_verdict_independent_of_eps_v():
    """stop.spread_v fires on the density's velocity spread (0.49 at t = 0, falling), never on
    the grid: with eps_v and eps_x far below the spacings, the run stops at the first step
    whose min_spread_v is below the threshold, as a blow-up in v."""
    free = simulate(_scene())
    spread = free.diagnostics.min_spread_v.to_numpy()
    assert np.all(np.diff(spread) < 0)
    threshold = 0.5 * (spread[1] + spread[2])
    stopped = simulate(_scene(stop={"eps_v": 1e-3, "eps_x": 2e-3, "spread_v": threshold}))
    v = stopped.verdict
    assert v["blowup"] and v["B_v"] and not v["B_x"] and not v["e_f"]
    assert v["T_b"] == pytest.approx(0.2) and "spread_v" in v["reason"]
