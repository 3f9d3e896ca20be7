"""Validation at and around each bound: the last valid value passes, the first invalid one
raises a ValueError/TypeError naming the argument (or scene key), before any work."""

import math

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PeriodicGrid, PowerKernel, Status, solve_collision
from jko_cvx.scene.model import SceneError, scene_from_dict

G = Grid.uniform(-2.0, 2.0, 21)
F = np.exp(-2 * G.points**2)
K = PowerKernel(1.0)


@pytest.mark.parametrize(
    "name, good, bad",
    [
        ("dt", [1e-12, 1e3], [0.0, -0.0, -1e-300, math.inf, math.nan]),
        ("strength", [1e-12, 1e6], [0.0, -1.0, math.inf, math.nan]),
        ("beta", [1e-3, 1e8, math.inf], [0.0, -1e-300, -math.inf, math.nan]),
    ],
)
def test_problem_scalars_at_their_bounds(name, good, bad):
    base = {"dt": 0.01, "strength": 1.0, "beta": 10.0}
    for val in good:
        prob = CollisionProblem(G, K, F, **{**base, name: val})
        assert getattr(prob, name) == val
    for val in bad:
        with pytest.raises(ValueError, match=rf"{name} must lie in \(0, inf"):
            CollisionProblem(G, K, F, **{**base, name: val})


def test_a_tiny_beta_is_accepted_or_refused_by_name():
    try:
        CollisionProblem(G, K, F, 0.01, beta=1e-300)
    except ValueError as exc:
        assert "beta" in str(exc)


def test_f_star_shapes():
    assert CollisionProblem(G, K, F, 0.01).f_star.shape == (21,)
    assert CollisionProblem(G, K, np.stack([F, 2 * F]), 0.01).batch_size == 2
    assert CollisionProblem(G, K, F[None, :], 0.01).batch_size == 1
    for bad in (F[:-1], np.r_[F, 1.0], F[:, None], F[None, None, :], np.float64(1.0)):
        with pytest.raises(ValueError, match=r"f_star must have shape \(21,\) or \(B, 21\)"):
            CollisionProblem(G, K, bad, 0.01)
    one_zero = F.copy()
    one_zero[0] = 0.0
    assert CollisionProblem(G, K, one_zero, 0.01).f_star[0] == 0.0  # zeros are allowed (perspective form)
    with pytest.raises(ValueError, match="f_star must be non-negative"):
        CollisionProblem(G, K, np.where(G.points == G.points[0], -1e-300, F), 0.01)
    with pytest.raises(ValueError, match="f_star must have positive mass"):
        CollisionProblem(G, K, np.stack([F, 0 * F]), 0.01)  # one empty slice in a batch


def test_an_empty_batch_is_refused():
    with pytest.raises(ValueError, match="f_star"):
        CollisionProblem(G, K, np.zeros((0, 21)), 0.01)


def test_grid_and_kernel_bounds():
    assert Grid([0.0, 0.5, 1.0]).n == 3 and Grid.uniform(-1, 1, 3).n == 3
    with pytest.raises(ValueError, match="at least 3"):
        Grid([0.0, 1.0])
    with pytest.raises(ValueError, match=r"n must be an integer in \[3, 10000000\]"):
        Grid.uniform(-1, 1, 2)
    with pytest.raises(ValueError, match=r"n must be an integer in \[3, 10000000\]"):
        Grid.uniform(-1, 1, 3.5)
    # the size is checked before any work (10**9 points would allocate 8 GB), and True is no count
    for n in (10_000_001, 10**9, True):
        with pytest.raises(ValueError, match=r"n must be an integer in \[3, 10000000\], got"):
            Grid.uniform(-1, 1, n)
        with pytest.raises(ValueError, match=r"n must be an integer in \[3, 10000000\], got"):
            PeriodicGrid.uniform(1.0, n)
    with pytest.raises(ValueError, match="a must be smaller than b"):
        Grid.uniform(1.0, 1.0, 5)
    with pytest.raises(ValueError, match="strictly increasing"):
        Grid([0.0, 1.0, 1.0])
    assert PowerKernel(1e-9).gamma == 1e-9
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="gamma must be a finite number > 0"):
            PowerKernel(bad)


PROB = CollisionProblem(G, K, F, 0.01, beta=10.0)


@pytest.mark.parametrize("method", ["newton", "sqp", "conic"])
def test_tol_bounds(method):
    for bad in (0.0, 1.0, -1e-12, math.nan, math.inf):
        with pytest.raises(ValueError, match="tol must lie in"):
            solve_collision(PROB, method=method, tol=bad)
    if method != "conic":  # the largest valid tolerance stops at once, certified by the residual
        res = solve_collision(PROB, method=method, tol=0.999)
        assert isinstance(res.status, Status)


@pytest.mark.parametrize("method", ["newton", "sqp"])
def test_max_iter_bounds(method):
    res = solve_collision(PROB, method=method, max_iter=1, tol=1e-14)
    assert res.status is Status.MAX_ITERATIONS
    assert solve_collision(PROB, method=method, max_iter=np.int64(50)).success
    for bad in (0, -1, 2.0, "10", None):
        with pytest.raises(ValueError, match="max_iter"):
            solve_collision(PROB, method=method, max_iter=bad)


def test_sqp_relaxation_step_bounds():
    assert solve_collision(PROB, method="sqp", step=1.0).success
    assert solve_collision(PROB, method="sqp", step=0.5).success
    for bad in (0.0, -0.5, 1.0 + 1e-12, 2):
        with pytest.raises(ValueError, match="step"):
            solve_collision(PROB, method="sqp", step=bad)
    with pytest.raises(ValueError, match="kkt_tol must lie in"):
        solve_collision(PROB, method="sqp", kkt_tol=1.0)
    with pytest.raises(ValueError, match="floor must be a finite number >= 0"):
        solve_collision(PROB, method="sqp", qp="osqp", floor=-1e-12)


# ---------------------------------------------------------------- scenes
BASE = {
    "gamma": 1.0,
    "t_end": 0.1,
    "v": {"L": 2.0, "n": 21},
    "x": {"L": 2.0, "n": 11},
    "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.0]},
    "time": {"policy": "halving", "dt": 0.01, "eps_t": 1e-12},
}


def _with(section, key, value):
    d = {k: (dict(v) if isinstance(v, dict) else v) for k, v in BASE.items()}
    if section is None:
        d[key] = value
    elif section.startswith("refine."):
        d["refine"] = {section.split(".")[1]: {key: value}}
    else:
        d.setdefault(section, {})
        d[section] = {**d[section], key: value}
    return d


@pytest.mark.parametrize(
    "section, key, good, bad",
    [
        (None, "gamma", [1e-9, 3.0], [0.0, -1.0, math.inf]),
        (None, "t_end", [1e-9], [0.0, math.inf]),
        (None, "strength", [1e-9, 155.0], [0.0, -1.0, math.inf]),
        ("v", "n", [3], [2, 3.5]),
        ("x", "n", [3], [2]),
        ("v", "L", [1e-3], [0.0, math.inf]),
        ("time", "dt", [1e-6], [0.0, -0.01, math.inf]),
        ("time", "eps_t", [1e-300], [0.0, -1e-6]),
        ("refine.v", "delta", [1e-3, 0.999], [0.0, 1.0, 1.5]),
        ("refine.v", "delta0", [1e-3, 0.999], [0.0, 1.0]),
        ("refine.x", "delta0", [0.999], [1.0]),
        ("refine.v", "tol", [0.0, 0.999], [1.0, -1e-3]),
        ("refine.v", "bumps", [1, 2], [0, 3]),
        ("collision", "beta", [1e-3, math.inf], [0.0, -1.0]),
        ("stop", "eps_v", [0.0, 1e-3], [-1e-12]),
        ("stop", "eps_x", [0.0, 1e-3], [-1e-12]),
        ("stop", "spread_v", [0.0, 0.1], [-1e-12, math.inf]),
        ("output", "every", [1], [0]),
        ("output", "checkpoint_every", [1], [0]),
    ],
)
def test_scene_values_at_their_bounds(section, key, good, bad):
    for val in good:
        scene_from_dict(_with(section, key, val))
    name = key if section is None else f"{section}.{key}"
    for val in bad:
        with pytest.raises(SceneError, match=name.replace(".", r"\.")):
            scene_from_dict(_with(section, key, val))
