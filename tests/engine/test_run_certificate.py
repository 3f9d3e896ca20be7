"""A run certifies its steps at the engine's threshold for the method, whatever the solver's convergence
tolerance: a loose tol makes steps fail the certificate, never passes them; a scene's own looser kkt_tol is
honoured and named in the run's summary."""

import numpy as np
import pytest

import jko_cvx.engine.loop as loop
from jko_cvx.engine.loop import Stepper, simulate
from jko_cvx.scene import scene_from_dict
from jko_cvx.scene.options import RUN_KKT

# gamma = 1 on [-2, 2], maximum off v = 0: blows up at T = 1/(2 max f0) = 0.5
SCENE = {
    "name": "loose_tol",
    "gamma": 1.0,
    "t_end": 0.06,
    "v": {"L": 2.0, "n": 61},
    "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.5]},
    "time": {"dt": 0.02},
    "stop": {"on_solver_failure": False},
}


def _scene(method: str, **options):
    return scene_from_dict({**SCENE, "collision": {"method": method, "options": options}})


def test_a_loose_newton_tol_fails_the_certificate_rather_than_passing_it(monkeypatch):
    """Newton's kkt_tol defaults to its tol for one solve; in a run a tol of 0.5 (one iteration) must not make
    inaccurate steps count as certified: every step the engine accepts is certified at 1e-8."""
    seen = []
    real = loop.solve_collision

    def recorded(problem, **kw):
        res = real(problem, **kw)
        seen.append(res)
        return res

    monkeypatch.setattr(loop, "solve_collision", recorded)
    run = simulate(_scene("newton", tol=0.5))
    assert seen
    for res in seen:
        if Stepper.accepted(res):
            assert np.max(res.kkt_residual) <= RUN_KKT["newton"], (res.status, res.kkt_residual)
    assert not run.verdict.certified  # one iteration does not reach 1e-8: the steps fail and the run says so
    tight = simulate(_scene("newton", tol=1e-10))  # a tighter tol still certifies at that tol
    assert tight.verdict.certified


@pytest.mark.parametrize("method", ["newton", "sqp", "conic", "nlp"])
def test_a_scenes_own_certificate_is_honoured_and_a_looser_one_named(method):
    """A scene may set kkt_tol (the paper's SQP has no KKT test of its own); above the method's run threshold the
    run's summary says what 'certified' then means."""
    limit = RUN_KKT[method]
    assert Stepper(_scene(method)).opts["kkt_tol"] == limit  # the default is the run's threshold
    assert Stepper(_scene(method, kkt_tol=limit / 10)).opts["kkt_tol"] == limit / 10
    assert Stepper(_scene(method, kkt_tol=0.1)).opts["kkt_tol"] == 0.1


def test_the_summary_names_a_certificate_looser_than_the_runs():
    loose = simulate(_scene("sqp", kkt_tol=0.1))
    assert "WARNING: steps certified at collision.options.kkt_tol = 0.1" in loose.summary()
    assert "kkt_tol" not in simulate(_scene("sqp", kkt_tol=1e-7)).summary()


def test_a_newton_tol_above_the_certificate_is_named_in_the_summary():
    run = simulate(_scene("newton", tol=1e-3))
    assert not run.verdict.certified
    assert "collision.options.tol = 0.001 is above the 1e-08 at which a run certifies" in run.summary()
    assert "collision.options.tol" not in simulate(_scene("newton", tol=1e-10)).summary()
