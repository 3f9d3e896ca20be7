"""Bad input raises ValueError/TypeError naming the argument, before any solve."""

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision

G = Grid.uniform(-2, 2, 21)
F = np.exp(-2 * G.points**2)
K = PowerKernel(1.0)


@pytest.mark.parametrize(
    "f_star, match",
    [
        (-F, "f_star must be non-negative"),
        (np.where(G.points > 0, np.nan, F), "f_star must be finite"),
        (F[:-1], r"f_star must have shape \(21,\)"),
        (np.zeros(21), "f_star must have positive mass"),
        ("abc", "f_star"),
    ],
)
def test_bad_f_star(f_star, match):
    with pytest.raises((ValueError, TypeError), match=match):
        CollisionProblem(G, K, f_star, 0.01)


@pytest.mark.parametrize("dt", [0.0, -1.0, np.nan, np.inf])
def test_bad_dt(dt):
    with pytest.raises(ValueError, match="dt must lie in"):
        CollisionProblem(G, K, F, dt)


@pytest.mark.parametrize("name, kwargs", [("strength", {"strength": 0.0}), ("beta", {"beta": -1.0})])
def test_bad_strength_or_beta(name, kwargs):
    with pytest.raises(ValueError, match=f"{name} must lie in"):
        CollisionProblem(G, K, F, 0.01, **kwargs)


def test_bad_fisher_form_and_log_with_zeros():
    with pytest.raises(ValueError, match="fisher must be one of"):
        CollisionProblem(G, K, F, 0.01, beta=1.0, fisher="sqrt")
    with pytest.raises(ValueError, match='strictly positive for fisher="log"'):
        CollisionProblem(G, K, np.where(G.points > 1, 0.0, F), 0.01, beta=1.0, fisher="log")


def test_bad_grid_and_kernel_types():
    with pytest.raises(TypeError, match="grid must be"):
        CollisionProblem(G.points, K, F, 0.01)
    with pytest.raises(TypeError, match="kernel must be"):
        CollisionProblem(G, 1.0, F, 0.01)
    with pytest.raises(ValueError, match="strictly increasing"):
        Grid(G.points[::-1])
    with pytest.raises(ValueError, match="gamma"):
        PowerKernel(0)


def test_bad_method_solver_and_options_fail_before_solving(monkeypatch):
    import jko_cvx.collision.conic as conic

    def boom(*a, **k):  # any solve attempt would fail the test
        raise AssertionError("a solve was attempted")

    monkeypatch.setattr(conic, "_build_model", boom)
    prob = CollisionProblem(G, K, F, 0.01, beta=10.0)
    with pytest.raises(ValueError, match="method must be one of"):
        solve_collision(prob, method="newtonish")
    with pytest.raises(ValueError, match="solver must be one of"):
        solve_collision(prob, method="conic", solver="NOT_A_SOLVER")
    with pytest.raises(TypeError, match=r"unknown option\(s\) \['tolerance'\]"):
        solve_collision(prob, method="conic", tolerance=1e-8)
    with pytest.raises(ValueError, match="tol must lie in"):
        solve_collision(prob, method="conic", tol=0.0)
    with pytest.raises(ValueError, match="energy must be one of"):
        solve_collision(prob, method="conic", energy="implicit")
    with pytest.raises(ValueError, match="fisher_cone must be one of"):
        solve_collision(prob, method="conic", fisher_cone="bent")
    with pytest.raises(ValueError, match="step"):
        solve_collision(prob, method="sqp", step=1.5)
    with pytest.raises(ValueError, match="max_iter"):
        solve_collision(prob, method="sqp", max_iter=0)
    with pytest.raises(ValueError, match="qp must be"):
        solve_collision(prob, method="sqp", qp="dense")
    log_prob = CollisionProblem(G, K, F, 0.01, beta=10.0, fisher="log")
    with pytest.raises(ValueError, match="not conic-representable"):
        solve_collision(log_prob, method="conic")


def test_linearized_energy_is_labelled_as_such():
    from jko_cvx import Status

    prob = CollisionProblem(G, PowerKernel(3.0), F, 0.01, beta=10.0)
    lin = solve_collision(prob, method="conic", energy="linearized")
    full = solve_collision(prob, method="conic")
    assert lin.status is Status.LINEARIZED and lin.info["passes"] == 1
    assert full.status is Status.CONVERGED
    # the semi-implicit step is a different (first-order close) answer, and its
    # residual against the full problem says so
    assert lin.kkt_residual > full.kkt_residual
    assert np.abs(lin.f - full.f).max() < 1e-2 * F.max()


# ---- an impossible pairing names the way out: the methods that do pose the problem ----


def _names(msg: str, *methods: str) -> bool:
    return all(f"'{m}'" in msg or f'"{m}"' in msg for m in methods)


def test_conic_on_the_log_form_names_every_method_that_poses_it():
    log_prob = CollisionProblem(G, K, F, 0.01, beta=10.0, fisher="log")
    with pytest.raises(ValueError) as err:
        solve_collision(log_prob, method="conic")
    assert _names(str(err.value), "nlp", "newton", "sqp"), str(err.value)


def test_sqp_with_the_momentum_constraint_names_every_method_that_has_it():
    prob = CollisionProblem(G, K, F, 0.01, beta=10.0, conserve_momentum=True)
    with pytest.raises(ValueError) as err:
        solve_collision(prob, method="sqp")
    assert _names(str(err.value), "newton", "conic", "nlp"), str(err.value)


@pytest.mark.parametrize(
    "collision, methods",
    [
        ({"method": "conic", "fisher": "log", "beta": 10.0}, ("nlp", "newton", "sqp")),
        ({"method": "sqp", "conserve_momentum": True, "beta": 10.0}, ("newton", "conic", "nlp")),
    ],
)
def test_a_scene_with_an_impossible_pairing_names_the_alternatives(collision, methods):
    from jko_cvx.scene import SceneError, scene_from_dict

    doc = {"gamma": 1.0, "t_end": 0.1, "v": {"L": 2.0, "n": 9}, "time": {"dt": 0.01}, "collision": collision,
           "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.0]}}  # fmt: skip
    with pytest.raises(SceneError) as err:
        scene_from_dict(doc)
    assert _names(str(err.value), *methods), str(err.value)


def test_verify_with_the_conic_reference_on_the_log_form_names_nlp():
    from jko_cvx.engine.verify import verify
    from jko_cvx.scene.model import default_scene

    with pytest.raises(ValueError) as err:
        verify(default_scene(), "conic")
    assert _names(str(err.value), "nlp"), str(err.value)
