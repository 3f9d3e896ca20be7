"""Rules of the time loop, each tested so that a weakened rule fails: a step is accepted only when
every slice is certified, and a resumed run restores everything it carries, snapshots included."""

from types import SimpleNamespace

import numpy as np
import pytest

import jko_cvx.engine.loop as loop
from jko_cvx.collision import Status
from jko_cvx.engine import RunInterrupted
from jko_cvx.engine.loop import ACCEPT_KKT, Stepper, simulate
from jko_cvx.engine.verdict import StopReason
from jko_cvx.scene import scene_from_dict, with_overrides

from ._inject import interrupted_commit
from .test_rundir import SMALL

C, M, N = Status.CONVERGED, Status.MAX_ITERATIONS, Status.NOT_CERTIFIED


def _result(statuses, kkt):
    st = np.array(statuses, dtype=object)
    return SimpleNamespace(status=st, success=np.array([s.success for s in statuses]), kkt_residual=np.array(kkt))


@pytest.mark.parametrize(
    "statuses, kkt, accepted",
    [
        ([C, C, C], [1e-10] * 3, True),
        ([C, M, C], [1e-10, 1e-3, 1e-10], False),  # one slice failed: the step is not accepted
        ([M, M, C], [1e-3, 1e-3, 1e-10], False),
        ([N, C, N], [0.5 * ACCEPT_KKT, 1e-10, 0.9 * ACCEPT_KKT], True),  # floored slices at their floor
        ([N, C, C], [10 * ACCEPT_KKT, 1e-10, 1e-10], False),
        ([M, C, C], [0.5 * ACCEPT_KKT, 1e-10, 1e-10], False),  # an iteration limit is never accepted
    ],
)
def test_a_step_is_accepted_only_when_every_slice_is_certified(statuses, kkt, accepted):
    assert Stepper.accepted(_result(statuses, kkt)) is accepted


INHOM = {
    "name": "slices",
    "gamma": 3.0,
    "strength": 2.0,
    "t_end": 0.04,
    "v": {"L": 2.0, "n": 21},
    "x": {"L": 1.0, "n": 8},
    "initial": {"kind": "two_bump_phase", "a": 6.0, "b": 6.0, "c": 0.5, "d": 0.5},
    "time": {"dt": 0.01},
    "collision": {"method": "newton", "beta": 100.0, "fisher": "log"},
}


def test_one_uncertified_slice_fails_the_whole_step(monkeypatch):
    real = loop.solve_collision

    def one_slice_fails(problem, **kw):
        res = real(problem, **kw)
        res.status = np.array([M, *list(np.ravel(res.status))[1:]], dtype=object)
        res.kkt_residual = np.array([1e-3, *list(np.ravel(res.kkt_residual))[1:]])
        return res

    monkeypatch.setattr(loop, "solve_collision", one_slice_fails)
    run = simulate(scene_from_dict(INHOM))
    assert run.verdict.stop is StopReason.NO_STEP and run.steps == 0
    carried = simulate(scene_from_dict(with_overrides(INHOM, {"stop.on_solver_failure": False})))
    assert carried.verdict.uncertified_steps == carried.steps == 4 and not carried.verdict.certified


@pytest.mark.parametrize("at", [1, 3, 4])
def test_a_resumed_run_restores_every_field_snapshots_included(tmp_path, monkeypatch, at):
    scene = scene_from_dict(with_overrides(SMALL, {"t_end": 0.06, "output": {"every": 2, "checkpoint_every": 1}}))
    whole = simulate(scene)
    monkeypatch.setattr(Stepper, "commit", interrupted_commit(at))
    with pytest.raises(RunInterrupted):
        simulate(scene, out=tmp_path / "r")
    monkeypatch.undo()
    resumed = simulate(scene, out=tmp_path / "r", resume=True)
    assert [s["step"] for s in resumed.snapshots] == [s["step"] for s in whole.snapshots]
    for a, b in zip(resumed.snapshots, whole.snapshots, strict=True):
        assert a["t"] == b["t"] and np.array_equal(a["f"], b["f"]) and np.array_equal(a["v"], b["v"])
    assert resumed.diagnostics.drop(columns=["seconds"], errors="ignore").equals(
        whole.diagnostics.drop(columns=["seconds"], errors="ignore")
    )
    assert np.array_equal(resumed.f, whole.f) and resumed.t == whole.t and resumed.verdict == whole.verdict
