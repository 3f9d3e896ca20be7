"""Time-step policies: fixed, halving (``alg:MR_JKO_ver2``) and CFL (``alg:SPMCSL-JKO``).

The CFL rule, read from the paper's LaTeX (``alg:SPMCSL-JKO``, step 1):
``Delta t = min{Delta t_0, min{0.9 Delta v_min / L_v, 0.9 Delta x_min / L_x}}``.  Every
number below is chosen so that swapping L_v and L_x, or dv and dx, gives a different step.
"""

import numpy as np
import pytest

from jko_cvx.engine.loop import simulate
from jko_cvx.engine.verdict import StopReason
from jko_cvx.scene.model import scene_from_dict
from jko_cvx.stepping import CFLStep, FixedStep, HalvingStep, step_policy

from ._inject import failing


def test_cfl_policy_takes_each_limit_with_its_own_axis_length():
    c = CFLStep(0.5)
    # v-limit 0.9 * 0.2 / 1.5 = 0.12 against x-limit 0.9 * 0.8 / 4 = 0.18 (swapped: 0.045)
    assert c.first(min_dv=0.2, min_dx=0.8, L_v=1.5, L_x=4.0) == pytest.approx(0.12, rel=1e-14)
    # x-limit 0.9 * 0.4 / 4 = 0.09 below the v-limit (swapped lengths: 0.045)
    assert c.first(min_dv=0.2, min_dx=0.4, L_v=1.5, L_x=4.0) == pytest.approx(0.09, rel=1e-14)
    # the step never exceeds dt0
    assert CFLStep(0.05).first(min_dv=0.2, min_dx=0.4, L_v=1.5, L_x=4.0) == 0.05
    # homogeneous: no x-limit
    assert c.first(min_dv=0.2, min_dx=None, L_v=1.5, L_x=None) == pytest.approx(0.12, rel=1e-14)
    assert c.retry(0.12) is None


def test_fixed_policy_never_retries():
    p = FixedStep(0.03)
    assert p.first(1e-9, 1e-9, 7.0, 3.0) == 0.03 and p.retry(0.03) is None


def test_halving_policy_gives_up_at_eps_t():
    """halving_reset: halve while the half step stays above eps_t; a half step equal to eps_t is refused.
    halving (alg:MR_JKO_ver2 as written): halve while the step itself is above eps_t, keep the halved
    step, and end the run after an accepted step <= eps_t."""
    h = HalvingStep(0.08, eps_t=0.01, reset=True)
    assert h.first(1e-9, None, 2.0, None) == 0.08 and h.first(1e-9, None, 2.0, None, carried=0.02) == 0.08
    assert h.retry(0.08) == 0.04 and h.retry(0.04) == 0.02
    assert h.retry(0.02) is None  # 0.01 is not > eps_t
    assert HalvingStep(0.08, eps_t=0.0099, reset=True).retry(0.02) == 0.01
    p = HalvingStep(0.08, eps_t=0.01)
    assert p.first(1e-9, None, 2.0, None) == 0.08 and p.first(1e-9, None, 2.0, None, carried=0.02) == 0.02
    assert p.retry(0.02) == 0.01 and p.retry(0.01) is None  # 0.01 is not above eps_t: no further halving
    assert p.exhausted(0.01) and not p.exhausted(0.0101) and not h.exhausted(0.0)


def test_step_policy_builds_each_policy_and_checks_its_parameters():
    """step_policy by name; HalvingStep refuses eps_t >= dt and an unknown halve_on itself, and
    halve_on other than any_failure needs a halving policy; the prefix names the scene keys."""
    assert step_policy("fixed", 0.01) == FixedStep(0.01) and step_policy("cfl", 0.01) == CFLStep(0.01)
    assert step_policy("halving", 0.01, 1e-3, "max_iterations") == HalvingStep(0.01, 1e-3, halve_on="max_iterations")
    assert step_policy("halving_reset", 0.01, 1e-3) == HalvingStep(0.01, 1e-3, reset=True)
    with pytest.raises(ValueError, match=r"^eps_t must be < dt = 0.01 \(the halving floor\), got 0.01$"):
        HalvingStep(0.01, 0.01)
    with pytest.raises(ValueError, match=r"^halve_on must be one of"):
        HalvingStep(0.01, 1e-3, halve_on="never")
    with pytest.raises(ValueError, match=r"^time\.eps_t must be < time\.dt = 0.01"):
        step_policy("halving", 0.01, 0.02, prefix="time.")
    with pytest.raises(ValueError, match=r"^halve_on = 'max_iterations' needs policy 'halving' or 'halving_reset' "):
        step_policy("fixed", 0.01, halve_on="max_iterations")
    with pytest.raises(ValueError, match=r"^policy must be one of"):
        step_policy("adaptive", 0.01)


def test_which_failures_end_the_run_instead_of_halving_and_the_eps_t_end():
    """halve_on = "max_iterations": only MAX_ITERATIONS halves, any other status ends the run; the other
    policies and halve_on = "any_failure" never refuse.  end(dt) is the EPS_T tracker's reason."""
    paper = HalvingStep(0.01, 1e-3, halve_on="max_iterations")
    assert not paper.refuses(["MAX_ITERATIONS"]) and paper.refuses(["MAX_ITERATIONS", "NOT_CERTIFIED"])
    for p in (HalvingStep(0.01, 1e-3), FixedStep(0.01), CFLStep(0.01)):
        assert not p.refuses(["NUMERICAL_ERROR"])
    assert paper.end(1e-3) == "dt = 0.001 <= eps_t = 0.001" and paper.end(2e-3) is None
    assert HalvingStep(0.01, 1e-3, reset=True).end(0.0) is None and FixedStep(0.01).end(0.0) is None


def _inhom(time, n_x=10, refine=None, t_end=0.3):
    d = {
        "name": "cfl",
        "gamma": 1.0,
        "strength": 0.5,
        "t_end": t_end,
        "v": {"L": 1.5, "n": 16},
        "x": {"L": 4.0, "n": n_x},
        "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.0]},
        "time": time,
        "collision": {"method": "newton", "beta": 30.0, "fisher": "log"},
    }
    if refine is not None:
        d.update(refine)
    return scene_from_dict(d)


def _check_cfl_steps(run, dt0, L_v, L_x):
    """Every step is the paper's CFL step on the previous step's grids (or the rest of t_end)."""
    d = run.diagnostics
    assert len(d) >= 3 and (d.failed == 0).all()
    for k in range(1, len(d)):
        prev = d.iloc[k - 1]
        expected = min(dt0, 0.9 * prev.min_dv / L_v, run.scene.t_end - prev.t)
        if L_x is not None:
            expected = min(expected, 0.9 * prev.min_dx / L_x)
        assert d.dt.iloc[k] == pytest.approx(expected, rel=1e-12), k


@pytest.mark.parametrize("n_x, active", [(10, "v"), (20, "x")])
def test_cfl_scene_steps_follow_the_rule_with_L_v_and_L_x_different(n_x, active):
    """L_v = 1.5, L_x = 4: dv = 0.2 gives 0.12; dx = 0.8 gives 0.18, dx = 0.4 gives 0.09."""
    run = simulate(_inhom({"policy": "cfl", "dt": 0.5}, n_x=n_x))
    _check_cfl_steps(run, 0.5, 1.5, 4.0)
    assert run.diagnostics.dt.iloc[1] == pytest.approx(0.12 if active == "v" else 0.09, rel=1e-12)


def test_cfl_scene_on_refined_grids_recomputes_the_step_from_the_current_spacings():
    """Two bumps in phase space, mapped v-grid: min dv changes every step, and so does dt."""
    scene = scene_from_dict(
        {
            "name": "cfl_refined",
            "gamma": 1.0,
            "strength": 2.0,
            "t_end": 0.5,
            "v": {"L": 1.5, "n": 16},
            "x": {"L": 4.0, "n": 10},
            "initial": {"kind": "two_bump_phase", "a": 1.0, "b": 2.0, "c": 1.0, "d": 0.3},
            "time": {"policy": "cfl", "dt": 0.5},
            "refine": {"v": {"bumps": 1, "delta0": 0.5, "delta": 0.5}},
            "collision": {"method": "newton", "beta": 30.0, "fisher": "log"},
        }
    )
    run = simulate(scene)
    _check_cfl_steps(run, 0.5, 1.5, 4.0)
    assert np.unique(np.round(run.diagnostics.dt.iloc[1:-1], 12)).size >= 4
    assert run.t == pytest.approx(0.5)


def test_fixed_scene_takes_dt_even_where_the_cfl_rule_would_not():
    run = simulate(_inhom({"policy": "fixed", "dt": 0.15}))
    np.testing.assert_allclose(run.diagnostics.dt.to_numpy(), [0.0, 0.15, 0.15], rtol=1e-14)


def _failing(eps_t):
    """A homogeneous scene whose steps fail above dt = 0.015 (imposed by :func:`_run`: 0.02 and 0.04 fail,
    0.01 is solved)."""
    return scene_from_dict(
        {
            "name": "halving",
            "gamma": 1.0,
            "t_end": 0.02,
            "v": {"L": 2.0, "n": 21},
            "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.0]},
            "time": {"policy": "halving", "dt": 0.04, "eps_t": eps_t},
            "collision": {"method": "newton", "beta": 30.0},
            "stop": {"on_solver_failure": True},
        }
    )


def _run(scene, **kwargs):
    """simulate(scene) with every collision solve above dt = 0.015 failing with MAX_ITERATIONS."""
    with failing(lambda attempt, accepted, dt: dt > 0.015):
        return simulate(scene, **kwargs)


def test_halving_scene_cures_the_step_when_eps_t_allows_it():
    """0.02 (t_end caps dt0 = 0.04) fails, 0.01 succeeds: two steps of 0.01."""
    run = _run(_failing(eps_t=0.0099))
    assert not run.blowup and not run.verdict["e_f"] and run.t == pytest.approx(0.02)
    np.testing.assert_allclose(run.diagnostics.dt.to_numpy(), [0.0, 0.01, 0.01], rtol=1e-14)


def test_halving_reset_scene_gives_up_when_the_half_step_reaches_eps_t():
    """halving_reset with eps_t = 0.01: the half step 0.01 is not above eps_t, the policy gives up (e_f),
    T_b the end of the failed step 0.02."""
    run = _run(_failing(eps_t=0.01).replace({"time.policy": "halving_reset"}))
    v = run.verdict
    # the first step failed: no step was accepted, which is not a blow-up at dt
    assert v.stop is StopReason.NO_STEP and not v["blowup"] and v["e_f"] and v["T_b"] is None and run.t == 0.0
    assert "collision solver failed" in v["reason"] and "MAX_ITERATIONS" in v["reason"]


def test_halving_scene_ends_on_eps_t_after_the_step_that_reaches_it():
    """halving as written with eps_t = 0.01: 0.02 fails, 0.01 succeeds and is accepted, and the run ends
    there (dt <= eps_t: StopReason.EPS_T, counted as e_f and B_v) with T_b = t = 0.01."""
    run = _run(_failing(eps_t=0.01))
    v = run.verdict
    assert v.stop is StopReason.EPS_T and v["blowup"] and v["e_f"] and v["B_v"] and not v["B_x"]
    assert v["T_b"] == pytest.approx(0.01) and run.t == pytest.approx(0.01)
    np.testing.assert_allclose(run.diagnostics.dt.to_numpy(), [0.0, 0.01], rtol=1e-14)
    assert run.diagnostics.retries.tolist() == [0, 1]


def test_a_fixed_step_that_fails_is_not_retried():
    run = _run(_failing(eps_t=1e-6).replace({"time.policy": "fixed", "time.dt": 0.02}))
    assert run.verdict.stop is StopReason.NO_STEP and not run.blowup and run.verdict["e_f"] and run.t == 0.0


def _uncertified(halve_on, on_failure=True):
    """The paper's SQP stopped by a loose zeta test (tol = 1e-3) and judged at kkt_tol = 1e-12:
    every step is NOT_CERTIFIED (the zeta test passes long before the KKT residual is small),
    at any dt, so halving cannot cure it."""
    return scene_from_dict(
        {
            "name": "uncertified",
            "gamma": 1.0,
            "t_end": 0.04,
            "v": {"L": 2.0, "n": 21},
            "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.0]},
            "time": {"policy": "halving", "dt": 0.02, "eps_t": 0.004, "halve_on": halve_on},
            "collision": {"method": "sqp", "beta": 30.0, "options": {"tol": 1e-3, "kkt_tol": 1e-12}},
            "stop": {"on_solver_failure": on_failure},
        }
    )


def test_any_failure_halves_an_uncertified_step_down_to_eps_t():
    """time.halve_on = "any_failure" (default): NOT_CERTIFIED halves 0.02 -> 0.01 -> 0.005 -> 0.0025,
    which is <= eps_t = 0.004 and still fails: the policy gives up (e_f), T_b the end of that step."""
    attempts = []
    run = simulate(_uncertified("any_failure"), attempts=attempts)
    assert [a["dt"] for a in attempts] == pytest.approx([0.02, 0.01, 0.005, 0.0025])
    assert [a["then"] for a in attempts] == ["halved", "halved", "halved", "given up"]
    assert all(a["statuses"] == ["NOT_CERTIFIED"] for a in attempts)
    v = run.verdict
    assert v["e_f"] and v.stop is StopReason.NO_STEP and v["T_b"] is None and run.t == 0.0


@pytest.mark.parametrize("on_failure", [True, False])
def test_max_iterations_rule_stops_on_an_uncertified_step_without_halving(on_failure):
    """time.halve_on = "max_iterations" (alg:MR_JKO_ver2 with alg:non_uni_JKO's e_f): NOT_CERTIFIED is not
    the exit flag, so it does not halve the step; it is not accepted either: the run stops as a solver
    failure on the first attempt, also with stop.on_solver_failure = false."""
    attempts = []
    run = simulate(_uncertified("max_iterations", on_failure), attempts=attempts)
    assert attempts == [{"t": 0.0, "dt": 0.02, "statuses": ["NOT_CERTIFIED"], "then": "stopped"}]
    v = run.verdict
    assert v["e_f"] and v.stop is StopReason.NO_STEP and v["T_b"] is None and not v["blowup"]
    assert "NOT_CERTIFIED" in v["reason"] and "halve_on = 'max_iterations'" in v["reason"]
    assert run.t == 0.0 and len(run.diagnostics) == 1  # nothing accepted


def test_max_iterations_rule_still_halves_on_the_exit_flag():
    """The step that fails with MAX_ITERATIONS is halved under both rules, with the same records."""
    base = _run(_failing(eps_t=0.0099))
    paper = _run(_failing(eps_t=0.0099).replace({"time.halve_on": "max_iterations"}))
    assert not paper.blowup and paper.t == pytest.approx(0.02)
    np.testing.assert_array_equal(paper.diagnostics.dt.to_numpy(), base.diagnostics.dt.to_numpy())
    assert paper.diagnostics.retries.tolist() == base.diagnostics.retries.tolist() == [0, 1, 0]


def test_attempts_must_be_a_list_and_is_refused_before_the_run():
    with pytest.raises(TypeError, match="attempts must be a list"):
        _run(_failing(eps_t=0.0099), attempts=())
