"""The time loop's parts, each alone: Verdict / StopReason, the trackers, RunState, the interrupt guard."""

import os
import signal

import numpy as np
import pandas as pd
import pytest

from jko_cvx.diagnostics import diagnostics
from jko_cvx.engine._interrupts import InterruptGuard
from jko_cvx.engine._state import RunState
from jko_cvx.engine.errors import RunDirError
from jko_cvx.engine.trackers import (
    Checkpoints,
    Diagnostics,
    EpsV,
    EpsX,
    Progress,
    Snapshots,
    SpreadV,
    StepInfo,
)
from jko_cvx.engine.verdict import SolverFailureRule, StopReason, Verdict
from jko_cvx.grid import Grid, PeriodicGrid


def _state(t=0.0, step=0, inhomogeneous=False, verdict=None):
    v = Grid.uniform(-2.0, 2.0, 21)
    x = PeriodicGrid.uniform(1.0, 6) if inhomogeneous else None
    f = np.exp(-2 * v.points**2)
    if inhomogeneous:
        f = np.outer(1 + 0.5 * np.cos(np.pi * x.points), f)
    return RunState(t, step, f, v, x, None, None, [], verdict or Verdict())


# --- Verdict and StopReason ------------------------------------------------------------------


def test_verdict_default_is_no_blowup_and_reads_as_the_old_mapping():
    v = Verdict()
    assert v.stop is StopReason.T_END and not v.blowup
    assert dict(v) == {
        "blowup": False,
        "certified": True,
        "T_b": None,
        "B_x": False,
        "B_v": False,
        "e_f": False,
        "reason": "reached t_end",
        "stop": "T_END",
        "uncertified_steps": 0,
        "first_uncertified_t": None,
        # not fitted: the blow-up fit is drawn when the run ends
        "T_b_fit": None,
        "T_b_fit_err": None,
        "blowup_rate": None,
        "blowup_kind": None,
        "blowup_reason": "",
        "unflagged_growth": None,
    }
    assert v["T_b"] is None and v["reason"] == "reached t_end"
    with pytest.raises(KeyError):
        v["colour"]


def test_stop_rules_accumulate_flags_and_the_last_reason_wins():
    v = Verdict().stopped(StopReason.EPS_V, 0.5, "min dv = 1e-05 < eps_v")
    v = v.stopped(StopReason.EPS_X, 0.5, "min dx = 1e-06 < eps_x")
    assert v.blowup and v.B_v and v.B_x and not v.e_f
    assert v.stop is StopReason.EPS_X and v.T_b == 0.5 and v.reason.startswith("min dx")
    failed = Verdict().stopped(StopReason.SOLVER_FAILURE, 0.2, "collision solver failed (MAX_ITERATIONS)")
    assert failed.B_v and failed.e_f and not failed.B_x
    with pytest.raises(ValueError, match="reaching t_end"):
        Verdict().stopped(StopReason.T_END, 1.0, "x")


def test_verdict_round_trips_and_rejects_inconsistent_records():
    v = Verdict().solver_failed(0.1).stopped(StopReason.SPREAD_V, 0.25, "min spread_v = 0.1 < spread_v")
    assert Verdict.from_dict(v.to_dict()) == v
    assert Verdict.from_dict(v.to_dict()) != Verdict()
    with pytest.raises(ValueError, match=r"blowup = False but its stop \(SPREAD_V\)"):
        Verdict.from_dict({**v.to_dict(), "blowup": False})
    with pytest.raises(ValueError, match="not a verdict record"):
        Verdict.from_dict({"blowup": True, "reason": "collision solver failed"})  # the pre-Verdict dict


# --- stopping rules ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "rule, column, reason, flag",
    [
        (EpsV, "min_dv", StopReason.EPS_V, "B_v"),
        (EpsX, "min_dx", StopReason.EPS_X, "B_x"),
        (SpreadV, "min_spread_v", StopReason.SPREAD_V, "B_v"),
    ],
)
def test_each_stop_rule_fires_strictly_below_its_threshold(rule, column, reason, flag):
    r = rule(1e-3)
    assert r.fires({column: 1e-3}) is None  # at the threshold: not below
    assert r.fires({column: np.nan}) is None  # an undefined indicator never stops a run
    assert r.fires({column: 9.99e-4}) == f"{r.label} = 0.000999 < {reason.name.lower()}"
    assert rule(0.0).fires({column: 0.0}) is None  # threshold 0: off
    state = _state(t=0.7, step=3)
    state.rows.append({column: 2e-3})
    r.handle(state, StepInfo(0.1))
    assert not state.verdict.blowup
    state.rows.append({column: 5e-4})
    r.handle(state, StepInfo(0.1))
    assert state.verdict.stop is reason and state.verdict[flag] and state.verdict.T_b == 0.7


def test_solver_failure_stops_only_when_the_scene_says_so():
    state = _state(t=0.3)
    assert not SolverFailureRule(stop=False).record(state, ["MAX_ITERATIONS"])
    assert state.verdict.e_f and not state.verdict.blowup
    assert SolverFailureRule(stop=True).record(state, ["MAX_ITERATIONS", "NOT_CERTIFIED"])
    v = state.verdict
    assert v.stop is StopReason.SOLVER_FAILURE and v.B_v and v.T_b == 0.3
    assert v.reason == "collision solver failed (MAX_ITERATIONS, NOT_CERTIFIED)"


# --- records, snapshots, checkpoints, progress -------------------------------------------------


@pytest.mark.parametrize("inhomogeneous", [False, True])
def test_diagnostics_tracker_records_step_zero_once_and_each_step(inhomogeneous):
    state = _state(inhomogeneous=inhomogeneous)
    tr = Diagnostics()
    tr.start(state)
    tr.start(state)  # a resumed run already has its step-0 row
    assert len(state.rows) == 1
    expected = diagnostics(state.vgrid, state.f, state.xgrid)
    first = dict(state.rows[0])
    assert np.isnan(first.pop("time_error"))  # no step yet: no time-error estimate
    assert first == {"step": 0, "t": 0.0, "dt": 0.0, **expected, "iterations": 0, "failed": 0, "retries": 0,
                     "lower_minimum": 0}
    state.t, state.step = 0.1, 1
    tr.handle(state, StepInfo(0.1, iterations=7, failed=2, retries=3, lower_minimum=4, time_error=0.25))
    assert state.rows[1] == {"step": 1, "t": 0.1, "dt": 0.1, **expected, "iterations": 7, "failed": 2, "retries": 3,
                             "lower_minimum": 4, "time_error": 0.25}
    assert list(state.rows[1])[:3] == ["step", "t", "dt"]  # the column order of diagnostics.csv


def _advance(state, dt, trackers):
    state.t += dt
    state.step += 1
    for tr in trackers:
        tr.handle(state, StepInfo(dt))


def test_snapshots_every_k_steps_at_the_scene_times_and_at_the_end(tmp_path):
    tr = Snapshots(every=4, times=(0.25,), t_end=1.0, path=lambda k: tmp_path / f"s{k}.npz")
    state = _state()
    tr.start(state)
    for _ in range(10):
        _advance(state, 0.1, [tr])
    # step 0; step 3 is the first reaching 0.25; steps 4 and 8; step 10 reaches t_end
    assert [s["step"] for s in tr.snapshots] == [0, 3, 4, 8, 10]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(f"s{k}.npz" for k in (0, 3, 4, 8, 10))
    tr.finish(state)  # not a solver-failure stop: nothing more
    assert len(tr.snapshots) == 5
    resumed = Snapshots(every=4, times=(), t_end=1.0, taken=tr.snapshots[:2])
    resumed.start(state)  # snapshots already taken: no second step-0 snapshot
    assert [s["step"] for s in resumed.snapshots] == [0, 3]


def test_a_solver_failure_stop_is_snapshotted_once_whatever_its_reason_text():
    tr = Snapshots(every=2, times=(), t_end=1.0)
    state = _state()
    tr.start(state)
    _advance(state, 0.1, [tr])
    state.verdict = Verdict().stopped(StopReason.SOLVER_FAILURE, state.t, "any text")
    tr.finish(state)
    assert [s["step"] for s in tr.snapshots] == [0, 1]
    _advance(state, 0.1, [tr])  # a failure right after a regular snapshot adds no duplicate
    n = len(tr.snapshots)
    tr.finish(state)
    assert len(tr.snapshots) == n and tr.snapshots[-1]["step"] == 2


def test_checkpoints_every_k_steps_at_the_last_step_and_at_the_end():
    class Dir:
        def __init__(self):
            self.saved = []

        def save_state(self, state):
            self.saved.append(state.step)

    d = Dir()
    tr = Checkpoints(d, every=3, t_end=0.7)
    state = _state()
    for _ in range(7):
        _advance(state, 0.1, [tr])
    tr.finish(state)
    assert d.saved == [3, 6, 7, 7]  # 7 reaches t_end; finish writes the final state again


def test_progress_bar_follows_simulated_time():
    tr = Progress(1.0, "p")
    state = _state(t=0.2)
    tr.start(state)
    _advance(state, 0.25, [tr])
    assert tr.bar.n == pytest.approx(0.45) and tr.bar.total == 1.0
    tr.finish(state)


# --- RunState ---------------------------------------------------------------------------------


@pytest.mark.parametrize("inhomogeneous", [False, True])
def test_run_state_checkpoint_round_trips_exactly(tmp_path, inhomogeneous):
    state = _state(t=0.30000000000000004, step=3, inhomogeneous=inhomogeneous)
    state.v_params = np.array([0.1, 0.7])
    Diagnostics().start(state)
    state.verdict = Verdict().solver_failed(0.1)
    state.seconds["collision"] = 1.25
    state.save(tmp_path / "ck.npz", {"scene_sha256": "abc", "jko_cvx": "9.9"})
    back, prov = RunState.load(tmp_path / "ck.npz", None if state.xgrid is None else state.xgrid.period)
    assert prov == {"scene_sha256": "abc", "jko_cvx": "9.9"}
    assert back.t == state.t and back.step == 3 and back.verdict == state.verdict
    assert np.array_equal(back.f, state.f) and np.array_equal(back.vgrid.points, state.vgrid.points)
    assert np.array_equal(back.v_params, state.v_params) and back.x_params is None
    pd.testing.assert_frame_equal(pd.DataFrame(back.rows), pd.DataFrame(state.rows), check_exact=True)  # NaN min_dx
    assert back.seconds == state.seconds
    if inhomogeneous:
        assert np.array_equal(back.xgrid.points, state.xgrid.points) and back.xgrid.period == state.xgrid.period


def test_a_damaged_checkpoint_is_named(tmp_path):
    state = _state()
    Diagnostics().start(state)
    path = tmp_path / "checkpoint.npz"
    state.save(path, {"scene_sha256": "abc", "jko_cvx": "1"})
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(RunDirError, match=rf"checkpoint {path} is corrupted or truncated"):
        RunState.load(path, None)
    path.write_bytes(b"not a zip file")
    with pytest.raises(RunDirError, match=rf"checkpoint {path} is corrupted or truncated"):
        RunState.load(path, None)
    np.savez(path, t=0.0)
    with pytest.raises(RunDirError, match=rf"checkpoint {path} is not a jko_cvx checkpoint: it lacks \['step'"):
        RunState.load(path, None)


# --- the interrupt guard ------------------------------------------------------------------------


def test_interrupt_guard_defers_signals_while_a_step_is_committed():
    before = signal.getsignal(signal.SIGTERM)
    guard = InterruptGuard()
    with guard:
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(1000):  # the handler runs between bytecodes
                pass
        done = []
        with pytest.raises(KeyboardInterrupt), guard.deferred():
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):
                pass
            done.append(True)  # the block runs to its end first
        assert done == [True]
        guard.hold()
        os.kill(os.getpid(), signal.SIGINT)  # held: ignored
        for _ in range(1000):
            pass
    assert signal.getsignal(signal.SIGTERM) is before


def test_the_run_is_done_at_t_end_to_rounding_or_at_blowup():
    state = _state(t=1.0 - 1e-13)
    assert state.done(1.0) and not _state(t=1.0 - 1e-9).done(1.0)  # ten steps of 0.1 sum to 0.9999999999999999
    blown = _state(t=0.2, verdict=Verdict().stopped(StopReason.EPS_V, 0.2, "min dv = 1e-05 < eps_v"))
    assert blown.done(1.0)
    assert not _state(t=0.2, verdict=Verdict().solver_failed(0.1)).done(1.0)  # e_f alone does not stop a run
