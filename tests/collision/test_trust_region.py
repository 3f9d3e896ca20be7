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


@pytest.mark.parametrize(
    ("lam", "c1", "radius"),
    [
        ([-1.0, 0.5, 1.0, 2.0, 3.0], 1e-12, 1e3),
        ([-1.0, 0.5, 1.0, 2.0, 3.0], 1e-13, 1e3),
        ([-1.0, 0.5, 1.0, 2.0, 3.0], 1e-13, 10.0),
        ([-1e5, 2.0, 3.0], 1e-13, 10.0),
    ],
)
def test_near_the_hard_case_the_step_still_reaches_the_boundary_and_the_minimum(lam, c1, radius):
    """g with a component along the lowest eigenvector just above the hard-case test: sigma + lam_1 is then below
    sigma's rounding, and a secular solve alone returned steps of 0.2 to 1.1 times the radius (outside the region,
    or short of the minimum by a fifth of the model's value)."""
    H = np.diag(lam)
    g = np.ones(len(lam))
    g[0] = c1
    step = trust_region_step(H, g, radius)
    assert np.linalg.norm(step.q) == pytest.approx(radius, rel=1e-8)
    _check_global_minimiser(H, g, radius, step, np.random.default_rng(1))


def test_a_lowest_eigenvalue_clustered_with_one_that_g_reaches_is_handled():
    """lam_2 = lam_1 + 1e-13 with c_2 != 0 and c_1 = 0: within the hard case's tie, so the tie's test fails, and no
    secular root lies above -lam_1; the step at -lam_1 plus the lowest eigenvector is the minimiser."""
    H = np.diag([-1.0, -1.0 + 1e-13, 1.0])
    g = np.array([0.0, 1e-9, 1.0])
    step = trust_region_step(H, g, 1e6)
    assert np.linalg.norm(step.q) == pytest.approx(1e6, rel=1e-8)
    assert -step.predicted() <= _model(H, g, np.array([1e6, 0.0, 0.0])) + 1e-6 * 1e12  # at least the lowest ray's


@pytest.mark.parametrize(
    ("lam", "scale", "radius"),
    [([-1.0, 1.0, 2.0], 1.0, 1e-160), ([1e-3, 1.0, 2.0], 1.0, 1e-160), ([-1.0, 1.0, 2.0], 1e-160, 1.0),
     ([-1.0, 1.0, 2.0], 0.0, 1e150)],
)  # fmt: skip
def test_extreme_radii_and_gradients_give_a_finite_step_on_the_boundary(lam, scale, radius):
    """No power of ||q|| in the secular Newton step (its cube underflowed at radius 1e-160: a ZeroDivisionError),
    and the hard case's step to the boundary formed without the radius squared (1e300 here)."""
    H = np.diag(lam)
    g = scale * np.ones(3)
    step = trust_region_step(H, g, radius)
    assert np.isfinite(step.q).all()
    assert np.linalg.norm(step.q) == pytest.approx(radius, rel=1e-8)
