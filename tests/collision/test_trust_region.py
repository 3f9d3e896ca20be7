"""The trust-region subproblem against its characterisation (Nocedal and Wright, Theorem 4.1).

q* is a global minimiser of g'q + q'Hq/2 on ||q|| <= radius if and only if, for some sigma >= 0,
(H + sigma I) q* = -g, sigma (radius - ||q*||) = 0 and H + sigma I is positive semidefinite.  The test
recovers sigma from the returned step and checks the three conditions, and compares the model's value with
the best of many points sampled on and inside the sphere (no point may do better).
"""

import numpy as np
import pytest

from jko_cvx.collision._trust_region import Eigensystem, trust_region_step


def _model(H, g, q):
    return g @ q + 0.5 * q @ H @ q


def _check_global_minimiser(H, g, radius, step, rng):
    q = step.q
    n = np.linalg.norm(q)
    assert n <= radius * (1 + 1e-9)
    r = H @ q + g
    # sigma from the first condition (q nonzero): (H + sigma I) q = -g  =>  sigma q = -(Hq + g)
    sigma = 0.0 if step.interior else -(q @ r) / (q @ q)
    scale = max(np.abs(H).max(), np.linalg.norm(g), 1.0)
    assert sigma >= -1e-9 * scale
    assert np.linalg.norm(r + sigma * q) <= 1e-8 * scale * max(1.0, n)
    assert np.linalg.eigvalsh(H + sigma * np.eye(len(g)))[0] >= -1e-8 * scale
    if not step.interior:
        assert abs(n - radius) <= 1e-8 * radius  # sigma > 0: on the boundary
    assert step.predicted() == pytest.approx(-_model(H, g, q), rel=1e-9, abs=1e-12 * scale)
    # no sampled point of the ball does better
    best = _model(H, g, q)
    for _ in range(2000):
        z = rng.standard_normal(len(g))
        z *= radius * rng.uniform() ** (1 / len(g)) / np.linalg.norm(z)
        assert _model(H, g, z) >= best - 1e-9 * scale * max(1.0, radius) ** 2


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("shift", [-3.0, 0.5, 5.0])  # indefinite, mildly and strongly positive definite
def test_random_subproblems_meet_the_optimality_conditions(seed, shift):
    rng = np.random.default_rng(seed)
    n = 6
    A = rng.standard_normal((n, n))
    H = (A + A.T) / 2 + shift * np.eye(n)
    g = rng.standard_normal(n)
    for radius in (1e-3, 0.1, 1.0, 10.0):
        _check_global_minimiser(H, g, radius, trust_region_step(H, g, radius), rng)


def test_the_newton_step_of_a_positive_definite_model_inside_the_region_is_returned():
    H = np.diag([1.0, 2.0, 4.0])
    g = np.array([1.0, -1.0, 2.0])
    step = trust_region_step(H, g, 10.0)
    assert step.interior and np.allclose(step.q, -g / np.diag(H), rtol=1e-14)
    assert step.lowest == pytest.approx(1.0)


def test_the_hard_case_steps_along_the_lowest_eigenvector_to_the_boundary():
    """g orthogonal to the eigenvector of the negative eigenvalue: no sigma > -lambda_1 reaches the boundary, and
    the minimiser adds that eigenvector to the step at sigma = -lambda_1."""
    H = np.diag([-1.0, 2.0, 3.0])
    g = np.array([0.0, 1.0, 1.0])
    radius = 2.0
    step = trust_region_step(H, g, radius)
    assert np.linalg.norm(step.q) == pytest.approx(radius, rel=1e-12)
    assert abs(step.q[0]) > 1.0  # along the negative-curvature direction
    _check_global_minimiser(H, g, radius, step, np.random.default_rng(0))


def test_a_negative_definite_model_steps_to_the_boundary():
    H = -np.eye(3)
    g = np.array([1e-3, 0.0, 0.0])
    step = Eigensystem(H, g).step(0.5)
    assert not step.interior and np.linalg.norm(step.q) == pytest.approx(0.5, rel=1e-10)
    assert step.q[0] < 0  # downhill along -g


@pytest.mark.parametrize("radius", [0.0, -1.0, np.inf, np.nan])
def test_a_radius_that_is_not_positive_and_finite_is_refused(radius):
    with pytest.raises(ValueError, match="radius must be positive and finite"):
        trust_region_step(np.eye(2), np.ones(2), radius)
