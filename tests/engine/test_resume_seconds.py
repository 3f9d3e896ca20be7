"""A resumed run counts its wall and solver seconds as an uninterrupted run does: over both legs, each
accepted step once.

The loop's clock is replaced by a counter that advances by one at every reading, so the seconds are
counts of clock readings: the same definition gives the same numbers, exactly, whatever the machine's
speed (no timing is compared).  An interrupted step is discarded and solved again after the resume;
its seconds belong to the leg that accepts it.
"""

from types import SimpleNamespace

import numpy as np
import pytest

import jko_cvx.engine.loop as loop
from jko_cvx.engine import RunInterrupted
from jko_cvx.engine.loop import Stepper, simulate
from jko_cvx.engine.run import load_run
from jko_cvx.scene import scene_from_dict, with_overrides

from ._inject import interrupted_commit
from .test_rundir import SMALL

SCENE = with_overrides(
    SMALL,
    {
        "t_end": 0.06,
        "x": {"L": 1.0, "n": 6},
        "output": {"every": 2, "checkpoint_every": 1},
        "initial": {"kind": "two_bump_phase", "a": 6.0, "b": 6.0, "c": 0.5, "d": 0.5},
    },
)


@pytest.fixture
def ticks(monkeypatch):
    """The loop's ``time.perf_counter`` as a counter: 0, 1, 2, ... (one per reading)."""
    clock = iter(range(10**9))
    monkeypatch.setattr(loop, "time", SimpleNamespace(perf_counter=lambda: float(next(clock))))


@pytest.mark.parametrize("at", [1, 2, 4])
def test_a_resumed_run_counts_wall_and_solver_seconds_as_an_uninterrupted_one(tmp_path, monkeypatch, ticks, at):
    scene = scene_from_dict(SCENE)
    whole = simulate(scene)
    assert set(whole.seconds) == {"wall", "collision", "transport", "refine"}
    assert whole.seconds["wall"] >= sum(whole.seconds[k] for k in ("collision", "transport", "refine"))
    with monkeypatch.context() as m:
        m.setattr(Stepper, "commit", interrupted_commit(at))
        with pytest.raises(RunInterrupted):
            simulate(scene, out=tmp_path / "r")
    first = load_run(tmp_path / "r", allow_partial=True)  # the first leg, as its checkpoint holds it
    assert 0 < first.seconds["wall"] < whole.seconds["wall"] or at == 1
    resumed = simulate(scene, out=tmp_path / "r", resume=True)
    assert np.array_equal(resumed.f, whole.f)
    assert resumed.seconds == whole.seconds  # the same definition: each accepted step once, both legs summed
    assert load_run(tmp_path / "r").seconds == whole.seconds  # and as the run directory records it
